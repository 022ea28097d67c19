"""`entitynet users add NAME | list | remove NAME`: the server's auth tokens (SQLite).

The store is named with `--users-db FILE` (alias `--db`), the same spelling as `entitynet serve`, and it is
accepted before or after the action (`users --db F add x` and `users add x --db F`): people type it where they
think of it.
"""

from __future__ import annotations

import argparse
import contextlib
import sqlite3
import sys
from collections.abc import Iterator

from entitynet.cli import CommandError


def register(sub) -> None:
    """Add `entitynet users add|list|remove`, with `--users-db` accepted before and after the action."""
    from entitynet.auth import default_db_path

    help_db = f"token store (default: $ENTITYNET_USERS_DB or {default_db_path()})"
    p = sub.add_parser("users", help="manage auth tokens of the switchboard server")
    add_users_db_option(p, help_db)
    usub = p.add_subparsers(dest="users_command", metavar="ACTION", required=True)
    a = usub.add_parser("add", help="create a token for NAME and print it (shown only once)")
    a.add_argument("name")
    a.set_defaults(func=run_add)
    ls = usub.add_parser("list", help="users and how many tokens each holds")
    ls.set_defaults(func=run_list)
    r = usub.add_parser("remove", help="revoke all tokens of NAME (the server closes their connections)")
    r.add_argument("name")
    r.set_defaults(func=run_remove)
    for action in (a, ls, r):
        # after the action too; SUPPRESS keeps a value given before the action when it is not repeated
        add_users_db_option(action, help_db, default=argparse.SUPPRESS)


def add_users_db_option(parser: argparse.ArgumentParser, help_text: str, default=None) -> None:
    """`--users-db FILE` with its alias `--db`, the one spelling of `users` and `serve`."""
    parser.add_argument("--users-db", "--db", dest="users_db", metavar="FILE", default=default, help=help_text)


def _store(args: argparse.Namespace):
    from entitynet.auth import TokenStore, default_db_path

    path = args.users_db or default_db_path()
    try:
        return TokenStore(path)
    except Exception as exc:  # sqlite3.Error, OSError: a bad path or a file that is not a database
        raise CommandError(f"cannot open token store {path}: {exc}") from None


@contextlib.contextmanager
def _store_errors(args: argparse.Namespace) -> Iterator[None]:
    """A store that cannot be written (read-only file or folder) or read (a damaged page), or that another
    process keeps locked, is one `entitynet: error:` line naming the file, not a traceback."""
    try:
        yield
    except sqlite3.Error as exc:
        from entitynet.auth import default_db_path

        raise CommandError(f"token store {args.users_db or default_db_path()}: {exc}") from None


def run_add(args: argparse.Namespace) -> int:
    """Print a new token on stdout (for scripts to capture) and, on stderr, that it cannot be shown again:
    only its hash is stored."""
    try:
        with _store_errors(args):
            token = _store(args).add_user(args.name)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    print(token)
    print(f"token for {args.name} created; it is not stored in clear and cannot be shown again", file=sys.stderr)
    return 0


def run_list(args: argparse.Namespace) -> int:
    """One line per user: name, a tab, how many tokens they hold (never the tokens: only hashes exist)."""
    with _store_errors(args):
        users = _store(args).users()
    for user, n in users:
        print(f"{user}\t{n}")
    return 0


def run_remove(args: argparse.Namespace) -> int:
    """Revoke every token of a user; an unknown user is an error so that a typo does not pass silently.
    A running server notices the change (data_version) and closes their connections."""
    with _store_errors(args):
        n = _store(args).remove_user(args.name)
    if n == 0:
        raise CommandError(f"no user {args.name!r}")
    print(f"revoked {n} token(s) of {args.name}", file=sys.stderr)
    return 0
