"""Command-line interface: one module per user job; ``capsmech.cli.main`` builds the parser."""
