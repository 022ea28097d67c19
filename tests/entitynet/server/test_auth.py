"""Auth on the wire (real sockets on loopback): revocation closes open connections, failed logins are throttled
per peer, the digest is not shown before auth, identities are bound to the token's user."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from entitynet.auth import TokenStore
from tests.entitynet.server_helpers import DIGEST, Raw, running


def _store(tmp_path):
    db = tmp_path / "users.sqlite"
    store = TokenStore(db)
    return str(db), store.add_user("alice"), store.add_user("bob")


async def test_revoked_token_connections_closed_within_seconds(tmp_path):
    db, alice_token, bob_token = _store(tmp_path)
    async with running(open_mode=False, users_db=db, auth_recheck=0.2) as server:
        alice = await Raw.connect(server, token=alice_token)
        alice2 = await Raw.connect(server, token=alice_token)  # a second connection with the same token
        bob = await Raw.connect(server, token=bob_token)
        await bob.send(P.Subscribe((1,), ()), P.Ping(1))
        await bob.expect(P.Pong)
        await alice.send(P.Publish(1, 1, (1,), 60_000, b"x"))
        u = await bob.expect(P.Update)
        # `entitynet users remove alice` from another process: another connection to the store
        assert TokenStore(db).remove_user("alice") == 1
        t0 = trio.current_time()
        for c in (alice, alice2):
            got = await c.expect_closed(timeout=3.0)
            assert [(m.code, "revoked" in m.text) for m in got if isinstance(m, P.Error)] == [
                (P.ErrorCode.AUTH_FAILED, True)]
        assert trio.current_time() - t0 < 3.0
        assert (await bob.expect(P.Leave)).entity == u.entity  # her entity is gone from bob's view
        await bob.send(P.Ping(2))  # bob is served as before
        await bob.expect(P.Pong, pred=lambda m: m.client_ms == 2)
        c = await Raw.connect(server, hello=False)  # and the revoked token no longer gets in
        await c.send(P.Hello(P.PROTOCOL_VERSION, alice_token, DIGEST))
        assert [m.code for m in await c.expect_closed()] == [P.ErrorCode.AUTH_FAILED]


async def test_wrong_tokens_throttled_per_peer(tmp_path):
    db, alice_token, _ = _store(tmp_path)
    switch = {"auth_fail_free": 3, "auth_fail_base_s": 30.0}  # long blocks: no timing in the assertions
    async with running(open_mode=False, users_db=db, switch=switch) as server:
        codes = []
        for i in range(40):  # bounded: the probe of the issue tried 300 at 1,833/s
            c = await Raw.connect(server, hello=False)
            await c.send(P.Hello(P.PROTOCOL_VERSION, f"guess-{i}", DIGEST))
            codes += [m.code for m in await c.expect_closed() if isinstance(m, P.Error)]
        assert codes[:4] == [P.ErrorCode.AUTH_FAILED] * 4  # 3 free, the 4th starts a 30 s block
        assert codes[4:] == [P.ErrorCode.AUTH_THROTTLED] * 36
        c = await Raw.connect(server, hello=False)  # the right token is not even looked at now
        await c.send(P.Hello(P.PROTOCOL_VERSION, alice_token, DIGEST))
        (err,) = await c.expect_closed()
        assert err.code == P.ErrorCode.AUTH_THROTTLED and "retry in" in err.text
        assert server.sb.errors[int(P.ErrorCode.AUTH_FAILED)] == 4  # only 4 tokens were ever checked


async def test_digest_not_shown_before_auth(tmp_path):
    db, alice_token, _ = _store(tmp_path)
    async with running(open_mode=False, users_db=db, digest="s3cret-digest-of-the-server-map") as server:
        c = await Raw.connect(server, hello=False)
        await c.send(P.Hello(P.PROTOCOL_VERSION, "wrong", "client-digest"))
        (err,) = await c.expect_closed()
        assert err.code == P.ErrorCode.AUTH_FAILED and "s3cret" not in err.text
        c = await Raw.connect(server, hello=False)
        await c.send(P.Hello(P.PROTOCOL_VERSION, alice_token, "client-digest"))
        (err,) = await c.expect_closed()
        assert err.code == P.ErrorCode.TOPOLOGY_MISMATCH and "s3cret" in err.text  # authenticated: told


async def test_identity_is_the_token_user(tmp_path):
    db, alice_token, bob_token = _store(tmp_path)
    async with running(open_mode=False, users_db=db) as server:
        alice = await Raw.connect(server, token=alice_token)
        bob = await Raw.connect(server, token=bob_token)
        await bob.send(P.Privacy("bob", None), P.Subscribe((1,), ()), P.Ping(1))
        await bob.expect(P.Pong)
        await alice.send(P.Privacy("bob", None), P.Publish(1, 1, (1,), 60_000, b"x"))
        err = await alice.expect(P.Error)
        assert err.code == P.ErrorCode.NOT_OWNER and "not yours" in err.text
        assert (await bob.expect(P.Update)).identity is None  # not shown as bob
        await alice.send(P.Privacy("alice", ("bob",)), P.Publish(1, 2, (1,), 60_000, b"x"))
        assert (await bob.expect(P.Update, pred=lambda u: u.seq == 2)).identity == "alice"
