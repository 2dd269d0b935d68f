"""Subcommands of the `civic` CLI, one module each (see civic/cli.py)."""
