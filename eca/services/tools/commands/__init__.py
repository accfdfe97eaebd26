"""CLI subcommands: every module here defines `register(subparsers)`; services.tools.cli finds them all."""
