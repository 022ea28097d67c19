"""When the server flushes (entitynet/server/writing.py `_flusher`): as soon as it has nothing else to do, not
on a fixed timer; the timer (`flush_interval`) only bounds how long news waits while the loop stays busy. These
tests turn the latency budget off (`latency_budget=0`, tested in test_latency_budget.py): they are about what
happens once it is spent.

Why: with a fixed 10 ms timer every delivery waited for the next tick (5 ms on average, 10 ms at worst) even on
an idle server, which put our latency about 10 ms above Redis's at the same load (Redis writes after each pass
of its event loop). These tests set the timer far beyond the test's patience: on the old flusher nothing would
arrive before it fired.
"""

from __future__ import annotations

import trio
import trio.testing

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw, running

LONG = 60.0  # flush_interval: far longer than any wait below


async def test_an_idle_server_flushes_news_at_once_not_at_the_timer(flush_path):
    async with running(flush_interval=LONG, latency_budget=0.0) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()))
        pub = await Raw.connect(server)
        for seq in range(1, 6):  # each one after the previous arrived: five flushes, none by the timer
            await pub.send(P.Publish(7, seq, (3,), 10_000, b"x"))
            with trio.fail_after(10):
                got = await view.expect(P.Update, pred=lambda m, s=seq: m.seq == s)
            assert got.payload == b"x"
        await pub.stream.aclose()
        await view.stream.aclose()


async def test_coalescing_and_order_still_hold_in_one_flush(flush_path):
    """A frame fed in one go is flushed once: every entity once, at its latest state, in first-queued order."""
    async with running(flush_interval=LONG, latency_budget=0.0) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3, 4), ()))
        pub = await Raw.connect(server)
        msgs = [P.Publish(e, s, (3 + e % 2,), 10_000, b"%d" % s) for s in (1, 2, 3) for e in (5, 6, 7)]
        await pub.send(*msgs)
        with trio.fail_after(10):
            frame = await view.read()
        assert [(m.seq, m.payload) for m in frame] == [(3, b"3")] * 3
        assert len({m.entity for m in frame}) == 3
        await pub.send(P.Publish(6, 4, (4,), 10_000, b"4"), P.Publish(5, 4, (3,), 10_000, b"4"))
        with trio.fail_after(10):
            frame2 = await view.read()
        assert [m.seq for m in frame2] == [4, 4]
        assert [m.entity for m in frame2] == [frame[1].entity, frame[0].entity]  # first queued first: 6, then 5
        await pub.stream.aclose()
        await view.stream.aclose()


async def test_flush_min_interval_spaces_flushes_even_when_idle(flush_path):
    """The knob for fewer, larger frames: with a minimum interval far beyond the test, news that comes after a
    flush waits (coalescing meanwhile) even on an idle server; replies are not held back."""
    async with running(flush_interval=LONG, flush_min_interval=LONG, latency_budget=0.0) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()))
        pub = await Raw.connect(server)  # (its WELCOME went out from the reader: no flush for it)
        await pub.send(P.Publish(7, 1, (3,), 10_000, b"a"))
        await view.expect(P.Update)  # the first flush: nothing was flushed before it, so nothing held it
        await trio.testing.wait_all_tasks_blocked()
        await pub.send(P.Publish(7, 2, (3,), 10_000, b"b"), P.Publish(7, 3, (3,), 10_000, b"c"), P.Ping(2))
        await pub.expect(P.Pong)  # both states are in the core, and the reply went out at once
        with trio.move_on_after(0.5) as waited:
            await view.expect(P.Update)
        assert waited.cancelled_caught  # held back by the minimum interval
        (cid,) = [c for c in server.conns if c != max(server.conns)]
        assert server.sb.outbox(cid).n_states == 1  # coalesced to the latest state, still pending
        await pub.stream.aclose()
        await view.stream.aclose()
