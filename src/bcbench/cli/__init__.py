"""The command line: `bcbench SUBCOMMAND` (parser.py declares the options, main.py runs them)."""

from bcbench.cli.main import main

__all__ = ["main"]
