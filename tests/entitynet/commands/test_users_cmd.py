"""`entitynet users` on a store it cannot use: damaged (a data page overwritten, the header intact), read-only
(the file and its folder not writable by the user), locked by another process: one `entitynet: error:` line
naming the store, exit status 2, no traceback."""

from __future__ import annotations

import os
import pwd
import stat
import sys

import pytest

from entitynet.auth import TokenStore
from entitynet.cli import build_parser, main
from tests.entitynet.server.test_token_store import Locker, corrupt_index


def _store(folder) -> str:
    db = folder / "users.sqlite"
    store = TokenStore(db)
    store.add_user("alice")
    store.add_user("bob")
    store.close()
    return str(db)


def _one_error(err: str, db: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("entitynet: error:"), err
    assert "token store" in lines[0] and db in lines[0], err
    assert "Traceback" not in err


@pytest.mark.parametrize("action", [["add", "carol"], ["remove", "bob"]])
def test_a_damaged_store_is_one_error_line(tmp_path, action, capsys):
    db = _store(tmp_path)
    corrupt_index(db)
    assert main(["users", "--db", db, *action]) == 2
    err = capsys.readouterr().err
    _one_error(err, db)
    assert "malformed" in err


def test_a_locked_store_is_one_error_line(tmp_path, capsys, monkeypatch):
    db = _store(tmp_path)
    locker = Locker(db)
    monkeypatch.setattr(TokenStore.__init__, "__defaults__", (0.2,))  # SQLite's lock wait: 0.2 s, not 5 s
    try:
        assert main(["users", "--db", db, "add", "carol"]) == 2
    finally:
        locker.release()
    err = capsys.readouterr().err
    _one_error(err, db)
    assert "locked" in err


def _run_as_nobody(argv: list[str]) -> tuple[int, str]:
    """`main(argv)` in a forked child that gave up root for `nobody` (root writes any file, whatever its
    mode); the child imports nothing new (the parent built the parser), so it needs no access to /root."""
    build_parser()
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        code = 99
        try:
            os.close(read_fd)
            os.dup2(write_fd, 2)
            nobody = pwd.getpwnam("nobody")
            os.setgroups([])
            os.setgid(nobody.pw_gid)
            os.setuid(nobody.pw_uid)
            sys.stderr = os.fdopen(2, "w", closefd=False)
            code = main(argv)
        except BaseException as exc:  # noqa: BLE001 - reported to the parent as the child's output
            print(f"child failed: {exc!r}", file=sys.stderr)
        finally:
            sys.stderr.flush()
            os._exit(code if isinstance(code, int) else 98)
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        err = pipe.read()
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), err


@pytest.mark.parametrize("action", [["add", "carol"], ["remove", "bob"]])
def test_a_read_only_store_is_one_error_line(tmp_path_factory, action, capsys):
    folder = tmp_path_factory.mktemp("readonly")
    db = _store(folder)
    os.chmod(db, 0o444)
    os.chmod(folder, 0o555)  # nor can a journal be created beside it
    opened: dict = {}  # pytest's base folder is private to its owner: let `nobody` through it for this test
    for parent in folder.parents:
        if parent == parent.parent or not str(parent).startswith(str(tmp_path_factory.getbasetemp().parent)):
            break
        opened[parent] = os.stat(parent).st_mode
        os.chmod(parent, opened[parent] | stat.S_IXOTH)
    try:
        if os.geteuid() == 0:
            code, err = _run_as_nobody(["users", "--db", db, *action])
        else:
            code, err = main(["users", "--db", db, *action]), capsys.readouterr().err
    finally:
        os.chmod(folder, 0o755)
        for parent, mode in opened.items():
            os.chmod(parent, stat.S_IMODE(mode))
    assert code == 2, err
    _one_error(err, db)
    assert "readonly" in err or "read-only" in err or "unable to open" in err
