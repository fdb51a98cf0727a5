"""Workflow glue: parameter grids, the kernel runner, the paper's figures from database files."""
