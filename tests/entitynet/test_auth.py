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
