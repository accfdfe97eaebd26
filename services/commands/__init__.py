"""CLI subcommands: every module here defines `register(subparsers)`; services.cli finds them all."""
