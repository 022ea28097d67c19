"""The shell's truth measure samples after the tick's deliveries have arrived (issue 23): with the server in
another process the sample taken right after the sends counted every newly visible entity's first UPDATE,
still on its way, as missed."""

from __future__ import annotations

import trio

from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig


async def test_each_sample_sees_every_update_the_server_forwarded_for_its_tick(helsinki, helsinki_path):
    sim = Sim(helsinki, SimConfig(entities=40, viewers=4, connections=2, tick_hz=4.0, transit=False, seed=3,
                                  subscribe="radius", measure_after=0.5))
    shell = Shell(sim, ShellConfig(duration=3.0, speed=1.0, summary_every=1e9, artifact=helsinki_path, keys=False),
                  lambda m: None)
    seen: list[tuple[float, int, int, int]] = []
    sample = sim.maybe_sample

    def recording(eid_to_agent):
        at, ticks = sim.now, sim.ticks
        took = sample(eid_to_agent)
        if took:
            arrived = sum(v.deliveries for v in sim.viewers)
            seen.append((at, ticks, arrived, shell.server.sb.stats["deliveries"]))
        return took

    sim.maybe_sample = recording
    with trio.fail_after(60):
        rep = await shell.run()
    # one sample a simulated second from 0.5 s on, the last one (after the last tick) included
    assert [round(at - sim.config.start, 6) for at, *_ in seen] == [0.5, 1.5, 2.5]
    for at, ticks, arrived, forwarded in seen:
        assert at == sim.config.start + ticks * sim.dt  # the world had not stepped past the sampled tick
        assert forwarded > 0 and arrived == forwarded  # nothing the server forwarded was still on its way
    assert rep["truth_vs_viewer"]["all"]["visible_entity_samples"] > 0
