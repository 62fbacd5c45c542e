"""Subcommands of the ``softpend`` command line (one module each)."""
