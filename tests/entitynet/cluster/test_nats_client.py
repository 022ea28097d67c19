"""The trio NATS client against real nats-server processes on loopback."""

from __future__ import annotations

import pytest
import trio

from entitynet.cluster.nats_client import NatsAuthorizationError, NatsClient, NatsUnreachableError, parse_servers


async def _until(pred, timeout: float = 5.0) -> None:
    with trio.fail_after(timeout):
        while not pred():
            await trio.sleep(0.01)


async def _publish_until_heard(pub, subject: str, payload: bytes, got: list[bytes], timeout: float = 10.0) -> None:
    """Publish every 0.2 s until the subscriber hears it: interest crosses a cluster route after a delay that
    depends on the machine's load, and NATS drops what is published before (at most once, by design)."""
    with trio.fail_after(timeout):
        while payload not in got:
            pub.publish(subject, payload)
            await pub.flush()
            with trio.move_on_after(0.2):
                while payload not in got:
                    await trio.sleep(0.01)


def test_parse_servers():
    assert parse_servers("nats://a:1, b:2") == [("a", 1), ("b", 2)]
    assert parse_servers(["nats://h"]) == [("h", 4222)]
    for bad in ("", "http://a:1", "nats://:5"):
        with pytest.raises(ValueError):
            parse_servers(bad)


async def test_publish_subscribe_without_echo_and_request_reply(nats_server):
    got_a: list[tuple[str, bytes]] = []
    got_b: list[tuple[str, bytes]] = []
    async with NatsClient(nats_server.urls, name="a") as a, NatsClient(nats_server.urls, name="b") as b:
        a.subscribe("en.c.*", lambda s, r, p: got_a.append((s, p)))
        sid = b.subscribe("en.c.1", lambda s, r, p: got_b.append((s, p)))
        await a.flush()
        await b.flush()
        for i in range(100):
            a.publish("en.c.1", b"x%d" % i)  # a's own: never echoed back to a
        b.publish("en.c.2", b"from b")
        await _until(lambda: len(got_b) == 100 and len(got_a) == 1)
        assert got_b[0] == ("en.c.1", b"x0") and got_b[-1] == ("en.c.1", b"x99")  # in order
        assert got_a == [("en.c.2", b"from b")]
        b.unsubscribe(sid)
        await b.flush()
        a.publish("en.c.1", b"late")
        await a.flush()
        await trio.sleep(0.05)
        assert len(got_b) == 100
        # request/reply: b answers on the reply subject it was given
        b.subscribe("en.snap", lambda s, r, p: b.publish(r, b"answer to " + p))
        await b.flush()
        answers: list[bytes] = []
        inbox = a.new_inbox(lambda s, r, p: answers.append(p))
        a.publish("en.snap", b"q1", reply=inbox)
        await _until(lambda: answers == [b"answer to q1"])


async def test_a_large_burst_arrives_whole(nats_server):
    n, got = 20_000, []
    async with NatsClient(nats_server.urls) as a, NatsClient(nats_server.urls) as b:
        b.subscribe("en.c.9", lambda s, r, p: got.append(p))
        await b.flush()
        payload = b"p" * 100
        for _ in range(n):
            a.publish("en.c.9", payload)
        await _until(lambda: len(got) == n, timeout=20)
        assert a.dropped == 0


async def test_a_killed_node_is_replaced_by_another_node_of_the_cluster(nats_cluster3):
    nodes = nats_cluster3.nodes
    got: list[bytes] = []
    reconnected = []
    # the subscriber knows only node 0 (it learns the others from INFO connect_urls); the publisher node 1
    async with NatsClient(nodes[0].url, on_reconnect=lambda: reconnected.append(1)) as sub, \
            NatsClient(nodes[1].url) as pub:
        sub.subscribe("en.c.3", lambda s, r, p: got.append(p))
        await sub.flush()
        await _publish_until_heard(pub, "en.c.3", b"before", got)  # once interest has crossed the route
        assert sub.server == (nodes[0].host, nodes[0].port)
        nodes[0].kill()
        await _until(lambda: sub.connected and sub.server != (nodes[0].host, nodes[0].port), timeout=10)
        assert reconnected == [1]
        await sub.flush()
        await _publish_until_heard(pub, "en.c.3", b"after", got)  # the re-sent SUB crosses to node 1's route


async def test_cancelled_while_connecting_leaves_trio_intact():
    """A server that accepts but never says INFO: cancelling the connect (Ctrl-C while a local cluster starts)
    must close the client's own nursery, not leave trio's nursery stack corrupted."""
    listener = (await trio.open_tcp_listeners(0, host="127.0.0.1"))[0]
    port = listener.socket.getsockname()[1]
    with trio.move_on_after(0.3) as scope:
        async with NatsClient(f"nats://127.0.0.1:{port}", name="t"):
            pytest.fail("connected to a server that never answered")
    assert scope.cancelled_caught
    await trio.sleep(0.01)  # trio still runs tasks normally afterwards
    await listener.aclose()


async def test_a_flush_whose_connection_dies_fails_instead_of_confirming(nats_server):
    """A REDIRECT waits for a flush to prove NATS has the client's LEAVEs; a flush cut by the node's death must
    not pass for that proof (the bytes may have died with the node)."""
    from entitynet.cluster.nats_client import NatsConnectionLost

    async with NatsClient(nats_server.urls, name="a", reconnect_wait=0.05) as a:
        await a.flush()
        nats_server.nodes[0].kill()
        with pytest.raises(NatsConnectionLost):
            a.publish("x.y", b"lost with the node")
            await a.flush(timeout=5)


async def test_a_batch_written_from_the_caller_keeps_its_order_with_the_writer_task(nats_server):
    """`publish_batch` writes from the caller (no writer wake-up); a socket that takes only part of it leaves the
    rest to the writer task, and publications queued meanwhile the usual way follow in order."""
    import socket

    got: list[bytes] = []
    async with NatsClient(nats_server.urls, name="a") as a, NatsClient(nats_server.urls, name="b") as b:
        b.subscribe("en.c.9", lambda s, r, p: got.append(p))
        await b.flush()
        await a.flush()
        a._stream.socket.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)  # a partial write, surely
        filler = b"." * 10_000
        a.publish_batch([("en.c.9", b"%d" % i + filler, None) for i in range(200)])
        assert a._out  # 2 MB did not fit the socket: the writer task has the rest
        a.publish("en.c.9", b"200" + filler)
        a.publish_batch([("en.c.9", b"%d" % i + filler, None) for i in range(201, 210)])
        await a.flush()
        await _until(lambda: len(got) == 210, timeout=20)
        assert [int(p[: -len(filler)]) for p in got] == list(range(210))
        small = a.writes
        a.publish_batch([("en.c.9", b"last", None)])  # a small batch on an idle socket: written at once
        assert not a._out and a.writes == small + 1
        await _until(lambda: got[-1] == b"last")


async def test_a_refused_token_fails_the_first_connect_at_once(nats_server_with_token):
    """-ERR 'Authorization Violation' ends the first connect with a clear error, not after the whole deadline
    (connect_timeout x max(2, servers) + 1 s: 11 s here) spent retrying a token that stays wrong; the right
    token still connects."""
    url = nats_server_with_token.urls
    for token in ("wrong", None):
        t0 = trio.current_time()
        with pytest.raises(NatsAuthorizationError, match="Authorization Violation") as caught:
            async with NatsClient(url, name="t", token=token, connect_timeout=5.0):
                pytest.fail("connected with a wrong token")
        assert trio.current_time() - t0 < 3.0
        assert "token" in str(caught.value) and isinstance(caught.value, OSError)  # callers report OSErrors
    async with NatsClient(url, name="t", token="s3cret") as nc:
        await nc.flush()


async def test_a_refused_port_is_retried_until_the_deadline():
    """A port nobody listens on yet (a server that is starting) is retried for the whole first-connect deadline,
    then fails with one error naming the URL, the deadline and the last try (it was a bare TooSlowError in the
    client's nursery's group, which no caller reported in one line)."""
    with trio.socket.socket() as probe:  # bound, never listening: connections are refused
        await probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        url = f"nats://127.0.0.1:{port}"
        t0 = trio.current_time()
        with pytest.raises(NatsUnreachableError) as caught:  # bare, not in a group
            async with NatsClient(url, name="t", connect_timeout=0.2):
                pytest.fail("connected to a closed port")
    assert trio.current_time() - t0 >= 0.2 * 2 + 1 - 0.05
    assert str(caught.value) == (f"no NATS server answered at {url} within 1.4 s "
                                 f"(last try: 127.0.0.1:{port}: Connection refused)")
    assert isinstance(caught.value, OSError)  # what the callers report in one line


async def test_a_server_that_never_answers_fails_the_first_connect_naming_it():
    """A port that accepts but never sends INFO (a wrong service, a stuck server): each try ends after the connect
    timeout, and the deadline's error says so."""
    listener = (await trio.open_tcp_listeners(0, host="127.0.0.1"))[0]
    port = listener.socket.getsockname()[1]
    with pytest.raises(NatsUnreachableError, match=rf"within 1.6 s \(last try: 127.0.0.1:{port}: no answer within "
                                                   r"0.3 s\)"):
        async with NatsClient(f"nats://127.0.0.1:{port}", name="t", connect_timeout=0.3):
            pytest.fail("connected to a server that never answered")
    await listener.aclose()


def test_an_error_message_shows_the_urls_without_credentials():
    """A user:password@ in a server URL is ignored for the handshake (the token is its own option), and must not
    reach a terminal or a log through the first connect's error text."""
    from entitynet.cluster.nats_client import NatsClient

    nc = NatsClient("nats://alice:s3cret@127.0.0.1:4222, tls://127.0.0.2:4223,127.0.0.1:4224")
    assert nc.urls == "nats://127.0.0.1:4222,tls://127.0.0.2:4223,127.0.0.1:4224"
    assert "s3cret" not in NatsClient(["nats://tok@h:1"]).urls
