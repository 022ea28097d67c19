"""The shell wakes the core at its next deadline instead of polling it (issue 10 item 5), over real sockets."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw, running


async def test_expiry_is_driven_by_next_deadline_not_by_polling():
    async with running(switch={"grace_s": 0.05}) as server:
        calls: list[float] = []
        expire = server.sb.expire

        def counted(now: float) -> int:
            calls.append(now)
            return expire(now)

        server.sb.expire = counted
        await trio.sleep(0.35)  # nothing is due: an idle server does not call the core at all
        assert calls == []
        pub, view = await Raw.connect(server), await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()))
        await view.send(P.Ping(1))
        await view.expect(P.Pong)
        await pub.send(P.Publish(1, 1, (3,), 100, b"x"))  # valid 0.1 s + 0.05 s grace, then silent
        upd = await view.expect(P.Update)
        leave = await view.expect(P.Leave, timeout=5.0)
        assert leave.entity == upd.entity
        assert 1 <= len(calls) <= 5  # woken for the deadline (a few wakes at most), not every 0.1 s


async def test_an_idle_flusher_sleeps_until_something_is_queued():
    """The flusher used to wake every `flush_interval` (10 ms) whatever the load: 100 wake-ups a second per
    process, most of an idle shard's CPU in a cluster (issue 13). Now it sleeps until the core has news."""
    async with running() as server:
        pub, view = await Raw.connect(server), await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()))
        await view.send(P.Ping(1))
        await view.expect(P.Pong)
        await trio.sleep(0.05)
        flushes: list[int] = []
        sb = server.sb
        take = sb.take_dirty

        def counted(check: bool = True) -> set[int]:
            flushes.append(1)
            return take(check)

        sb.take_dirty = counted
        await trio.sleep(0.3)  # idle: 30 flushes before, none now (the backstop is 1 s)
        assert len(flushes) <= 1
        for seq in (1, 2):  # and what is queued still goes out at once, batched as before
            await pub.send(P.Publish(1, seq, (3,), 5000, b"x%d" % seq))
            assert (await view.expect(P.Update, timeout=2.0)).seq == seq
