"""The latency budget (entitynet/server/writing.py `_flusher`, `ServerConfig.latency_budget` and `flush_fill`): at
light load news waits up to the budget for more news to share its flush, unless enough is queued first.

Why: at light load every delivery was its own flusher wake-up and its own `writev` (a server at 1/4 of the load
paid nearly 4 times as much CPU per delivery). These tests check the behaviour, not the CPU (that is `entitynet
bench cluster` / `bench switch`): news is held back (never early), coalesced into one frame, flushed at once
when the queue is full, replies are never held, and a peer that vanishes while its news waits costs nobody else
anything. Budgets are long (0.4-60 s) so that a loaded machine cannot make a test pass or fail by chance.
"""

from __future__ import annotations

import socket
import struct

import pytest
import trio

from entitynet import protocol as P
from entitynet.server import ConfigError, ServerConfig
from entitynet.server.app import Server
from tests.entitynet.server_helpers import DIGEST, Raw, running


async def _viewer(server, *cells: int) -> Raw:
    view = await Raw.connect(server)
    await view.send(P.Subscribe(tuple(cells), ()), P.Ping(1))
    await view.expect(P.Pong)
    return view


async def test_news_waits_for_the_budget_and_shares_one_frame(flush_path):
    """Three publishes from three publishers inside the budget leave as one frame, and not before 0.2 s of a
    0.6 s budget has passed (news is never early; how late depends on the machine, so only `never early` and
    `arrives` are checked)."""
    async with running(latency_budget=0.6, flush_fill=1000) as server:
        view = await _viewer(server, 3, 4)
        pubs = [await Raw.connect(server) for _ in range(3)]
        for p in pubs:
            await p.send(P.Ping(0))
            await p.expect(P.Pong)
        t0 = trio.current_time()
        for i, p in enumerate(pubs):
            await p.send(P.Publish(1, 1, (3 + i % 2,), 10_000, b"%d" % i))
        with trio.move_on_after(0.2) as early:
            await view.read()
        assert early.cancelled_caught, "news went out long before the budget"
        frame = await view.read(timeout=10)
        assert sorted(m.payload for m in frame) == [b"0", b"1", b"2"]  # one frame, one writev, all three
        assert trio.current_time() - t0 >= 0.2
        for p in pubs:
            await p.aclose()
        await view.aclose()


async def test_a_full_queue_is_flushed_at_once(flush_path):
    """`flush_fill` messages per waiting connection make the flush worth doing now: with a 60 s budget the
    second state (two queued for one viewer, fill 2) goes out at once, the first with it."""
    async with running(latency_budget=60.0, flush_fill=2) as server:
        view = await _viewer(server, 3)
        pub = await Raw.connect(server)
        await pub.send(P.Publish(1, 1, (3,), 10_000, b"a"))
        await pub.send(P.Ping(2))
        await pub.expect(P.Pong)  # the first state is in the core, and waits
        with trio.move_on_after(0.3) as held:
            await view.read()
        assert held.cancelled_caught
        await pub.send(P.Publish(2, 1, (3,), 10_000, b"b"))
        frame = await view.read(timeout=10)
        assert sorted(m.payload for m in frame) == [b"a", b"b"]
        await pub.aclose()
        await view.aclose()


async def test_replies_are_not_held_by_the_budget(flush_path):
    """WELCOME, PONG and errors go out at once whatever the budget (they are written by the reader, not the
    flusher); only forwarded states wait."""
    async with running(latency_budget=60.0) as server:
        with trio.fail_after(10):
            c = await Raw.connect(server)  # its WELCOME came (Raw.connect waits for it)
            await c.send(P.Ping(5))
            assert (await c.expect(P.Pong)).client_ms == 5
            await c.send(P.Subscribe((10_000,), ()))  # no such cell: an error, at once
            await c.expect(P.Error)
        await c.aclose()


async def test_zero_budget_flushes_as_soon_as_idle(flush_path):
    """`latency_budget=0` is the adaptive flush without a budget: with a 60 s timer, news still arrives."""
    async with running(latency_budget=0.0, flush_interval=60.0) as server:
        view = await _viewer(server, 3)
        pub = await Raw.connect(server)
        await pub.send(P.Publish(1, 1, (3,), 10_000, b"x"))
        assert (await view.expect(P.Update, timeout=10)).payload == b"x"
        await pub.aclose()
        await view.aclose()


@pytest.mark.parametrize("abrupt", [False, True])
async def test_a_viewer_that_vanishes_while_its_news_waits_costs_nobody_else(flush_path, abrupt):
    """A viewer closes (cleanly, or with a reset) while states for it wait out the budget: the flush skips or
    fails on it alone; the other viewer gets the same states, and the server goes on serving."""
    async with running(latency_budget=0.4, flush_fill=1000) as server:
        gone = await _viewer(server, 3)
        stays = await _viewer(server, 3)
        pub = await Raw.connect(server)
        await pub.send(P.Publish(1, 1, (3,), 10_000, b"a"), P.Ping(3))
        await pub.expect(P.Pong)
        if abrupt:  # RST instead of FIN: the server's write (or read) fails
            gone.stream.socket.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        await gone.aclose()
        assert (await stays.expect(P.Update, timeout=10)).payload == b"a"
        with trio.fail_after(10):
            while len(server.conns) != 2:
                await trio.sleep(0.01)
        await pub.send(P.Publish(1, 2, (3,), 10_000, b"b"))
        assert (await stays.expect(P.Update, timeout=10)).payload == b"b"
        await pub.aclose()
        await stays.aclose()


@pytest.mark.parametrize("kw", [{"latency_budget": float("nan")}, {"latency_budget": -0.001},
                                {"latency_budget": float("inf")}, {"latency_budget": 61.0},
                                {"latency_budget": "0.02"}, {"flush_fill": 0}, {"flush_fill": 2.5},
                                {"flush_fill": True}])
def test_a_budget_or_fill_out_of_range_is_refused(kw):
    with pytest.raises(ConfigError, match="latency-budget|flush-fill"):
        Server(ServerConfig(port=0, digest=DIGEST, n_cells=10, open_mode=True, **kw))


@pytest.mark.parametrize("answer", ["query", "follow refused", "redirect"])
async def test_a_deferred_reply_is_not_held_by_the_budget(flush_path, answer):
    """Replies the cluster completes later (a QUERY answered by the other shards, a FOLLOW no shard owns, a
    REDIRECT once NATS has the LEAVEs) reach the core outside the client's own frame, so the reader does not
    write them: they must not wait out the latency budget (60 s here) with the states either."""
    async with running(latency_budget=60.0, flush_fill=1000) as server:
        c = await Raw.connect(server)
        await c.send(P.Ping(1))
        await c.expect(P.Pong)
        (cid,) = server.conns
        if answer == "query":
            server.sb.answer_query(cid, 7, [])
            kind = P.QueryResult
        elif answer == "follow refused":
            server.sb.refuse_follow(cid, 12345)
            kind = P.Error
        else:
            server.sb.send_redirect(cid, 1, "127.0.0.1:1")
            kind = P.Redirect
        server._note_news()
        await c.expect(kind, timeout=10)
        await c.aclose()
