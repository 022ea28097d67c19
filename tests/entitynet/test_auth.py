"""SQLite token store and the `entitynet users` command."""

from __future__ import annotations

import sqlite3

import pytest

from entitynet.auth import TokenStore
from entitynet.cli import main


def test_tokens_map_to_users_and_are_not_stored_in_clear(tmp_path):
    db = tmp_path / "u.sqlite"
    s = TokenStore(db)
    t1, t2 = s.add_user("alice"), s.add_user("alice")
    t3 = s.add_user("bob")
    assert len({t1, t2, t3}) == 3
    assert s.authenticate(t1) == s.authenticate(t2) == "alice" and s.authenticate(t3) == "bob"
    assert s.authenticate("nope") is None and s.authenticate("") is None
    raw = b"".join(str(r).encode() for r in sqlite3.connect(db).execute("SELECT * FROM tokens"))
    assert t1.encode() not in raw
    assert s.users() == [("alice", 2), ("bob", 1)]
    assert s.remove_user("alice") == 2 and s.authenticate(t1) is None
    with pytest.raises(ValueError):
        s.add_user("no spaces")


def test_users_cli(tmp_path, capsys):
    db = str(tmp_path / "x" / "u.sqlite")
    assert main(["users", "--db", db, "add", "carol"]) == 0
    token = capsys.readouterr().out.strip()
    assert TokenStore(db).authenticate(token) == "carol"
    assert main(["users", "--db", db, "list"]) == 0
    assert "carol\t1" in capsys.readouterr().out
    assert main(["users", "--db", db, "add", "bad name"]) == 2
    assert main(["users", "--db", db, "remove", "nobody"]) == 2


def test_users_db_spelled_the_same_before_or_after_the_action(tmp_path, capsys):
    """`--users-db` (canonical, as on `serve`) and its alias `--db`, before or after the action."""
    db = str(tmp_path / "u.sqlite")
    assert main(["users", "add", "dave", "--db", db]) == 0
    token = capsys.readouterr().out.strip()
    assert TokenStore(db).authenticate(token) == "dave"
    assert main(["users", "add", "erin", "--users-db", db]) == 0
    assert main(["users", "--users-db", db, "add", "erin"]) == 0
    capsys.readouterr()
    assert main(["users", "list", "--users-db", db]) == 0
    assert capsys.readouterr().out.splitlines() == ["dave\t1", "erin\t2"]
    # given before and not repeated after the action: the first one holds
    assert main(["users", "--db", db, "remove", "erin"]) == 0
    assert main(["users", "remove", "dave", "--db", db]) == 0
    assert TokenStore(db).users() == []


def test_serve_takes_db_alias(tmp_path, capsys):
    """`serve --db FILE` parses (an unknown option would exit through argparse with SystemExit)."""
    from entitynet.cli import build_parser

    for flag in ("--db", "--users-db"):
        args = build_parser().parse_args(["serve", "--topology", "t.enttopo", flag, "x.sqlite"])
        assert args.users_db == "x.sqlite"
    missing = str(tmp_path / "missing.enttopo")
    assert main(["serve", "--topology", missing, "--db", str(tmp_path / "u.sqlite")]) == 2
    assert "cannot load topology" in capsys.readouterr().err


def test_store_created_private(tmp_path):
    """A new store is 0600 and the folder we create for it 0700, whatever the umask allows."""
    import os
    import stat

    old = os.umask(0o022)
    try:
        db = tmp_path / "new" / "deeper" / "users.sqlite"
        TokenStore(db).add_user("alice")
    finally:
        os.umask(old)
    assert stat.S_IMODE(db.stat().st_mode) == 0o600
    assert stat.S_IMODE(db.parent.stat().st_mode) == 0o700


def test_store_readable_by_others_is_reported(tmp_path, caplog):
    db = tmp_path / "users.sqlite"
    TokenStore(db).add_user("alice")
    db.chmod(0o644)
    with caplog.at_level("WARNING", logger="entitynet.auth"):
        assert TokenStore(db).users() == [("alice", 1)]
    assert "readable by others" in caplog.text


def test_data_version_changes_when_another_connection_writes(tmp_path):
    db = tmp_path / "users.sqlite"
    server_side = TokenStore(db)
    v0 = server_side.data_version()
    assert server_side.data_version() == v0
    TokenStore(db).add_user("alice")  # another connection, as `entitynet users add` in another process
    assert server_side.data_version() != v0
