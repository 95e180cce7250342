"""CLI subcommands, one module per stage (see :mod:`polarref.cli` for the protocol)."""
