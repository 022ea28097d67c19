"""Subcommands of the `entitynet` console command; each module has `register(subparsers)`."""
