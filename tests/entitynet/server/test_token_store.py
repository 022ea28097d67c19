"""A token store that cannot answer (locked by another process, damaged) refuses logins with 502
AUTH_UNAVAILABLE and a log line; the server keeps serving everyone else, and its event loop is never held by
the store (real server on loopback, real clients, a real locking process)."""

from __future__ import annotations

import logging
import subprocess
import sys

import pytest
import trio

from entitynet import protocol as P
from entitynet.auth import TokenStore
from entitynet.server import ConfigError, Server
from tests.entitynet.server_helpers import Raw, config, running

PAGE = 4096


def _store(tmp_path):
    db = tmp_path / "users.sqlite"
    store = TokenStore(db)
    tokens = store.add_user("alice"), store.add_user("bob")
    store.close()
    return str(db), *tokens


def corrupt_index(db: str, bump: bool = False) -> None:
    """Overwrite page 3 (the index on token hashes, a data page) and keep page 1 (the header and schema) as it
    is: SQLite opens the file, and a token lookup fails with "database disk image is malformed". `bump` also
    advances the file change counter so that a running server's connection drops the pages it cached."""
    with open(db, "r+b") as f:
        f.seek(2 * PAGE)
        f.write(b"\xa5" * PAGE)
        if bump:
            f.seek(24)
            counter = int.from_bytes(f.read(4), "big")
            f.seek(24)
            f.write((counter + 1).to_bytes(4, "big"))


class Locker:
    """Another process holding an exclusive lock on the store (as a long write transaction would)."""

    def __init__(self, db: str):
        code = ("import sqlite3, sys; c = sqlite3.connect(sys.argv[1], isolation_level=None); "
                "c.execute('BEGIN EXCLUSIVE'); print('locked', flush=True); sys.stdin.read()")
        self.proc = subprocess.Popen([sys.executable, "-c", code, db], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline().strip() == "locked"

    def release(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(10)


async def _refused_while_others_are_served(server, alice: Raw, token: str, store_waits: bool = False) -> None:
    """A HELLO the store cannot answer gets 502 AUTH_UNAVAILABLE, and alice, connected before, stays served.
    With `store_waits` (a lock: the read waits for it), alice's PING, sent while that HELLO waits for the
    store, is answered before the refusal comes: the wait holds the one connection, not the event loop."""
    newcomer = await Raw.connect(server, hello=False)
    await newcomer.send(P.Hello(P.PROTOCOL_VERSION, token, server.sb.config.digest))
    if store_waits:
        await trio.sleep(0.3)  # the lookup is under way (it waits up to the store's timeout for the lock)
    await alice.send(P.Ping(7))
    pong = await alice.expect(P.Pong, timeout=10)
    answered = trio.current_time()
    assert pong.client_ms == 7
    got = await newcomer.expect_closed(timeout=15)
    refused = trio.current_time()
    errors = [m for m in got if isinstance(m, P.Error)]
    assert [e.code for e in errors] == [P.ErrorCode.AUTH_UNAVAILABLE], got
    assert P.ErrorCode.AUTH_UNAVAILABLE in P.FATAL_ERRORS
    if store_waits:
        assert refused - answered > 0.2, "the PING waited for the store"
    await alice.send(P.Ping(8))
    assert (await alice.expect(P.Pong)).client_ms == 8


async def test_a_locked_store_refuses_logins_without_holding_the_loop(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="entitynet")
    db, alice_token, bob_token = _store(tmp_path)
    async with running(open_mode=False, users_db=db, auth_recheck=0.2, auth_timeout=2.0, digest="d") as server:
        alice = await Raw.connect(server, token=alice_token, digest="d")
        locker = Locker(db)
        try:
            await _refused_while_others_are_served(server, alice, bob_token, store_waits=True)  # a good token
            await _refused_while_others_are_served(server, alice, "a guess", store_waits=True)  # a bad one alike
            await trio.sleep(0.5)  # the revocation watch meets the lock too: nobody is closed for it
        finally:
            locker.release()
        bob = await Raw.connect(server, token=bob_token, digest="d")  # the store answers again
        await alice.send(P.Ping(9))
        assert (await alice.expect(P.Pong)).client_ms == 9
        await bob.aclose()
        # a refusal because of the store is not a failed login: the address is not throttled for it
        assert server.sb.errors[int(P.ErrorCode.AUTH_FAILED)] == 0
    assert "token store unavailable" in caplog.text and "locked" in caplog.text


async def test_a_store_damaged_while_serving_refuses_logins_and_serves_the_rest(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="entitynet")
    db, alice_token, bob_token = _store(tmp_path)
    async with running(open_mode=False, users_db=db, digest="d") as server:
        alice = await Raw.connect(server, token=alice_token, digest="d")
        corrupt_index(db, bump=True)
        await _refused_while_others_are_served(server, alice, bob_token)
        await _refused_while_others_are_served(server, alice, "a guess")
    assert "token store unavailable" in caplog.text and "malformed" in caplog.text


def test_a_damaged_store_stops_the_start(tmp_path):
    db, _, _ = _store(tmp_path)
    corrupt_index(db)
    with pytest.raises(ConfigError, match="damaged"):
        Server(config(open_mode=False, users_db=db))
