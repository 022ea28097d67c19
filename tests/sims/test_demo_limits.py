"""The simulation's viewers (the demo's too) apply WELCOME's limits, over real loopback sockets.

A viewer whose PVS is larger than the `max_subscriptions` a server announces must subscribe to at most that many
cells: the server refuses a SUBSCRIBE over the limit whole, so a viewer that ignored it would see nothing.
"""

from __future__ import annotations

import random

import trio

from entitynet.client import netview
from entitynet.connection import Connection
from entitynet.protocol import ErrorCode
from sims.engine.viewers import SimViewer
from tests.entitynet.client_fixtures import cross
from tests.entitynet.server_helpers import running

CAP = 10


async def test_a_viewer_subscribes_within_the_announced_max_subscriptions():
    topo = cross(street_cell_max=5.0)  # 65 cells: more than the cap
    assert topo.n_cells > 4 * CAP
    pvs = list(range(topo.n_cells))[::-1]  # the whole map is "visible"; the order is the viewer's priority
    viewer = SimViewer(netview(topo), 0, False, lambda x, y, z: pvs, random.Random(1))
    async with running(digest=topo.digest, n_cells=topo.n_cells, switch={"max_subscriptions": CAP}) as server:
        async with trio.open_nursery() as nursery:
            conn = Connection(("127.0.0.1", server.port), topo.digest, on_message=lambda m: viewer.receive(m, 0.0))
            await nursery.start(conn.run)  # returns once WELCOME was delivered to the viewer
            subs = [m for _ in range(3) for m in viewer.move(1.0)]
            for sub in subs:
                await conn.subscribe(sub.added, sub.removed)
            assert viewer.subs.cells == frozenset(pvs[:CAP])
            with trio.fail_after(5.0):  # bounded: the server applies it within a flush or two
                while not any(c.subs for c in server.sb.clients.values()):
                    await trio.sleep(0.01)
            (state,) = [c for c in server.sb.clients.values() if c.subs]
            assert state.subs == set(pvs[:CAP])
            assert server.sb.errors[ErrorCode.LIMIT_SUBSCRIPTIONS] == 0
            nursery.cancel_scope.cancel()
