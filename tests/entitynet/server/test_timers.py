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
