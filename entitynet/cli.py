"""The `entitynet` console command.

This is the composition root: each subcommand lives in its own module with a `register(subparsers)`
function, imported here by name so that `entitynet --help` stays fast and a broken optional part
cannot stop the others from running.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from entitynet import __version__

#: modules providing subcommands (each defines `register(subparsers)`)
COMMAND_MODULES = [
    "entitynet.commands.topology_cmd",
    "entitynet.commands.bench_cmd",
    "entitynet.commands.demo_cmd",
    "entitynet.commands.serve_cmd",
    "entitynet.commands.users_cmd",
    "entitynet.commands.cluster_cmd",
]


class CommandError(Exception):
    """A user-facing error: printed as `entitynet: error: ...` with exit status 2, no traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="entitynet",
        description="Dynamic entities on mobile 3D city maps: topology, visibility, honest clients, switchboards.",
    )
    parser.add_argument("--version", action="version", version=f"entitynet {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except CommandError as exc:
        print(f"entitynet: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("entitynet: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    # run the imported module's main, not this __main__ copy: commands raise entitynet.cli.CommandError
    from entitynet.cli import main as cli_main

    sys.exit(cli_main())
