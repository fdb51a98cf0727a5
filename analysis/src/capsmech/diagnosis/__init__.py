"""Diagnosis: what a fit leaves unexplained, the effects that may explain it, and synthetic batches to test it."""
