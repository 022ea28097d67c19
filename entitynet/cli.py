"""The `entitynet` console command.

This is the composition root: each subcommand lives in its own module with a `register(subparsers)`
function, imported here by name so that `entitynet --help` stays fast and a broken optional part
cannot stop the others from running.

Packages that sit above `entitynet` (`sims`, `proxies`) add their own subcommands through the entry-point
group `entitynet.commands` (see `discover_plugins`): the arrows run one way, so `entitynet` never imports
them by name.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Callable, Iterator
from importlib.metadata import entry_points

from entitynet import __version__, interrupts

#: modules providing subcommands (each defines `register(subparsers)`)
COMMAND_MODULES = [
    "entitynet.commands.topology_cmd",
    "entitynet.commands.serve_cmd",
    "entitynet.commands.users_cmd",
    "entitynet.commands.cluster_cmd",
]

#: entry-point group through which other packages register subcommands: `name = "module:register"`
PLUGIN_GROUP = "entitynet.commands"


class CommandError(Exception):
    """A user-facing error: printed as `entitynet: error: ...` with exit status 2, no traceback."""


def discover_plugins(group: str = PLUGIN_GROUP) -> list[tuple[str, Callable]]:
    """`(name, register)` of every installed subcommand plugin, sorted by name.

    Why a warning and not an error: a plugin that fails to import (a missing optional dependency, a bug in
    it) must not take the whole CLI down with it; the other commands keep working and the user is told which
    one is missing and why."""
    found = []
    for ep in sorted(entry_points(group=group), key=lambda e: e.name):
        try:
            found.append((ep.name, ep.load()))
        except Exception as exc:  # any failure of a plugin is reported, not fatal
            print(f"entitynet: warning: command {ep.name!r} ({ep.value}) unavailable: {exc}", file=sys.stderr)
    return found


def build_parser() -> argparse.ArgumentParser:
    """The full parser: the built-in COMMAND_MODULES, then the plugins (a plugin cannot shadow a built-in)."""
    parser = argparse.ArgumentParser(
        prog="entitynet",
        description="Dynamic entities on mobile 3D city maps: topology, visibility, honest clients, switchboards.",
    )
    parser.add_argument("--version", action="version", version=f"entitynet {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    for name, register in discover_plugins():
        if name in sub.choices:
            print(f"entitynet: warning: plugin command {name!r} ignored: the name is taken", file=sys.stderr)
            continue
        try:
            register(sub)
        except Exception as exc:  # see discover_plugins
            print(f"entitynet: warning: command {name!r} unavailable: {exc}", file=sys.stderr)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse, set up logging, run the command; user errors become exit status 2 and Ctrl-C exit status 130,
    each with one line on stderr and no traceback (also when they arrive inside an exception group, as they do
    out of a trio nursery, when Python had to drop the KeyboardInterrupt, or when it turned into another error:
    see `entitynet.interrupts`)."""
    with interrupts.catching_interrupts():
        status = _run(argv)
        return _interrupted() if status != 130 and interrupts.take_lost_interrupt() else status


def _run(argv: list[str] | None) -> int:
    """`main` less the watch for dropped interrupts: the command, and what each way out of it means."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        level = logging.WARNING - 10 * min(args.verbose, 2)
        logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
        return int(args.func(args) or 0)
    except CommandError as exc:
        return _command_failed(exc)
    except KeyboardInterrupt:
        return _interrupted()
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    except BaseExceptionGroup as group:
        found = list(leaves(group))
        errors = [e for e in found if isinstance(e, CommandError)]
        if errors:
            return _command_failed(errors[0])
        if any(isinstance(e, KeyboardInterrupt) for e in found) and all(
                isinstance(e, KeyboardInterrupt) or _is_cancellation(e) for e in found):
            return _interrupted()
        raise  # a bug: its traceback is what a report needs
    except Exception as exc:
        if interrupts.caused_by_interrupt(exc):  # e.g. a RuntimeError around a Ctrl-C in class creation
            return _interrupted()
        raise


def _command_failed(exc: CommandError) -> int:
    print(f"entitynet: error: {exc}", file=sys.stderr)
    return 2


def _interrupted() -> int:
    interrupts.forget_unhandled_flag()  # else `python -m entitynet` may die by SIGINT instead of exiting 130
    print("entitynet: interrupted", file=sys.stderr)
    return 130


def leaves(exc: BaseException) -> Iterator[BaseException]:
    """The exceptions in `exc` and in the groups nested in it, in order, groups themselves left out: the one
    walker of exception groups (trio nurseries raise them) for the CLI, `serve` and the proxies."""
    if isinstance(exc, BaseExceptionGroup):
        for inner in exc.exceptions:
            yield from leaves(inner)
    else:
        yield exc


def _is_cancellation(exc: BaseException) -> bool:
    """A trio or anyio task cancelled by the interrupt that stops the command (checked by name: the CLI does not
    import trio for `--help`)."""
    return type(exc).__name__ in ("Cancelled", "CancelledError")


if __name__ == "__main__":
    # run the imported module's main, not this __main__ copy: commands raise entitynet.cli.CommandError
    from entitynet.cli import main as cli_main

    sys.exit(cli_main())
