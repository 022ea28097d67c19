"""An external server's opaque entity ids mapped back to the simulation's by payload: the rules, and the map
checked against the server's own table over a real run."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from sims.engine.payload_ids import PayloadIds
from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig
from tests.entitynet.server_helpers import config as server_config
from tests.sims.engine.test_routes import grid


def _pub(entity: int, payload: bytes) -> P.Publish:
    return P.Publish(entity, 1, (0,), 5000, payload)


def test_ids_are_learnt_from_our_payloads_and_forgotten_with_the_entity():
    ids = PayloadIds()
    ids.published([_pub(7, b"a"), _pub(8, b"b")])
    ids.learn(1001, b"a")
    ids.learn(1002, b"not ours")  # another part's entity: no truth
    ids.learn(1003, b"b")
    assert ids.local_of == {1001: 7, 1003: 8}
    ids.learn(1001, b"b")  # a learnt id keeps its entity
    assert ids.local_of[1001] == 7
    ids.published([_pub(7, b"a2")])
    ids.learn(2001, b"a")  # one publish later (a server after a reconnect): still ours
    assert ids.local_of[2001] == 7
    ids.published([_pub(7, b"a3")])
    ids.learn(3001, b"a")  # two publishes later: no longer remembered
    assert 3001 not in ids.local_of
    ids.forget(7)
    assert ids.local_of == {1003: 8}
    ids.learn(4001, b"a3")
    assert 4001 not in ids.local_of  # nothing of entity 7 is kept
    ids.forget(8)
    ids.forget(99)  # never published: nothing to do
    assert ids.local_of == {} and ids._owner == {} and ids._sent == {} and ids._ids == {}


async def test_the_map_agrees_with_the_servers_own_table():
    """Against a server the test holds, every id the shell learnt maps to the entity the switchboard has."""
    from entitynet.server import serve

    topo = grid()
    sim = Sim(topo, SimConfig(entities=12, viewers=3, connections=2, tick_hz=10.0, transit=False, start=0.0,
                              subscribe="radius"))
    async with trio.open_nursery() as nursery:
        server = await nursery.start(serve, server_config(digest=topo.digest, n_cells=int(topo.n_cells)))
        shell = Shell(sim, ShellConfig(duration=3.0, speed=4.0, summary_every=100.0,
                                       server=("127.0.0.1", server.port), keys=False), lambda m: None)
        truth: dict[int, int] = {}

        async def watch_table():
            while True:
                truth.update({eid: e.local for eid, e in server.sb.entities.items()})
                await trio.sleep(0.05)

        nursery.start_soon(watch_table)
        with trio.fail_after(30):
            rep = await shell.run()
        nursery.cancel_scope.cancel()
    learnt = shell.ids.local_of
    assert len(learnt) >= 6  # most of the entities were seen by a viewer
    assert all(truth.get(eid) == local for eid, local in learnt.items())
    assert rep["truth_vs_viewer"]["all"]["shown_ghost_samples"] > 0
