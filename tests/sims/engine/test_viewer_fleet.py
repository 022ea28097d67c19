"""The viewer fleet (whole frames into the shared ghost table) against viewers that each take their messages one
by one into a store of their own, as per-viewer `Connection`s did: the same report, field for field, on a small
simulation whose frames are the in-process switchboard's, encoded and decoded as over a socket."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from entitynet.client import GhostStore
from sims.engine.local import LocalSwitch
from sims.engine.sim import Sim, SimConfig
from sims.engine.viewer_fleet import ViewerFleet
from tests.sims.engine.test_routes import grid


def _config() -> SimConfig:
    return SimConfig(entities=30, viewers=6, connections=2, tick_hz=2.0, subscribe="radius", radius=400.0,
                     transit=False, start=0.0, seed=9)


def _run(sim: Sim, take, seconds: float = 30.0) -> dict:
    """`run_local` with each viewer's frame payload handed to `take(viewer, payload)`."""
    sw = LocalSwitch(sim)

    def flush(now: float) -> None:
        for i, encoded in sw.drained():
            take(i, P.payload_from_encoded(encoded))

    sw.flush = flush
    sw.exchange(*sim.start())
    for _ in range(int(seconds * sim.config.tick_hz)):
        sw.exchange(*sim.step())
        sim.maybe_sample(sw.eid_to_agent())
    return sim.report()


def test_the_fleet_gives_the_report_of_viewers_taking_messages_one_by_one():
    fast = Sim(grid(), _config())
    fleet = ViewerFleet(fast.viewers, lambda: fast.now)
    frames = [fleet.on_frame(i) for i in range(len(fast.viewers))]

    def whole(i: int, payload: bytes) -> None:
        frames[i](fleet.messages.decode(payload))  # the switchboard's viewer frames hold UPDATEs and LEAVEs

    rep = _run(fast, whole)
    slow = Sim(grid(), _config())
    for v in slow.viewers:  # each its own store, as before the table
        v.ghosts = GhostStore(slow.world.net)

    def one_by_one(i: int, payload: bytes) -> None:
        for m in P.decode_payload(payload):
            slow.deliver(i, m, len(P.encode_message(m)))

    want = _run(slow, one_by_one)
    tv = rep["truth_vs_viewer"]["all"]
    assert tv["visible_entity_samples"] > 100 and tv["shown_ghost_samples"] > 100
    assert fleet.frames_whole > 0 and fleet.messages.hits > 0  # messages fanned out, decoded once
    assert rep == want


async def test_over_real_sockets_the_viewers_frames_reach_the_table_whole():
    from entitynet.server import serve
    from sims.shell import Shell, ShellConfig
    from tests.entitynet.server_helpers import config as server_config

    sim = Sim(grid(), _config())
    async with trio.open_nursery() as nursery:
        server = await nursery.start(serve, server_config(digest=sim.topo.digest, n_cells=int(sim.topo.n_cells)))
        shell = Shell(sim, ShellConfig(duration=3.0, speed=4.0, summary_every=100.0, keys=False,
                                       server=("127.0.0.1", server.port)), lambda m: None)
        with trio.fail_after(60):
            rep = await shell.run()
        nursery.cancel_scope.cancel()
    fleet = shell.viewer_fleet
    assert fleet.frames_whole > 0 and rep["viewers"]["deliveries"] > 0
    assert sum(len(v.ghosts) for v in sim.viewers) > 0
    assert rep["truth_vs_viewer"]["all"]["shown_ghost_samples"] > 0
