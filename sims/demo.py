"""`entitynet demo`: a live city on loopback, as a preset of `entitynet sim`.

The preset: the bundled Helsinki map with its PVS, the bundled HSL schedule's trams and buses from 08:00 (those
under way at the start placed along their routes), a few hundred pedestrians and cars on random OD trips,
every entity deciding through its honest-client core what to publish, multiplexed over a few connections the
way a proxy carries a fleet, and viewers at street level and above the roofs subscribing to the PVS of their
view cell. One shard server runs in this process on a free loopback port; the summary line comes every few
seconds; the run stops after `duration` seconds or on Ctrl-C (SIGUSR1 pauses and resumes).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sims.engine.schedule import BUNDLED_FEED, load_schedule
from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig

Say = Callable[[str], None]


@dataclass
class DemoConfig:
    entities: int = 300
    viewers: int = 24
    connections: int = 4
    car_share: float = 0.3
    duration: float | None = None  # seconds; None = until Ctrl-C
    summary_every: float = 5.0
    fix_interval: float = 1.0
    roof_share: float = 0.25  # share of viewers flying above the roofs
    seed: int = 1
    host: str = "127.0.0.1"
    port: int = 0
    transit: bool = True  # trams and buses of the bundled schedule


@dataclass
class Stats:
    published: int = 0
    deliveries: int = 0
    rejected_fixes: int = 0
    subscribe_msgs: int = 0


def sim_config(config: DemoConfig) -> SimConfig:
    """The `entitynet sim` settings of the demo preset."""
    return SimConfig(entities=config.entities, viewers=config.viewers, connections=config.connections,
                     car_share=config.car_share, roof_share=config.roof_share, fix_interval=config.fix_interval,
                     seed=config.seed, start=8 * 3600.0, transit=config.transit, subscribe="pvs")


async def run_demo(topo, artifact: Path, config: DemoConfig, say: Say = print) -> Stats:
    from entitynet.topology_cache import cache_dir

    schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir()) if config.transit else None
    sim = Sim(topo, sim_config(config), schedule)
    shell = Shell(sim, ShellConfig(duration=config.duration, summary_every=config.summary_every,
                                   artifact=artifact, host=config.host, port=config.port, keys=False), say)
    kinds = sim.world.by_type()
    say(f"{sum(kinds.values()) or config.entities} entities, {len(sim.viewers)} viewers "
        f"({sum(v.high for v in sim.viewers)} above the roofs) subscribing by {sim.subscribe_by}, over "
        f"{config.connections} connections")
    start = time.perf_counter()
    rep = await shell.run()
    stats = Stats(published=rep["clients"]["published"], deliveries=rep["viewers"]["deliveries"],
                  rejected_fixes=rep["clients"]["rejected_fixes"], subscribe_msgs=shell.subscribe_msgs)
    say(f"stopping after {time.perf_counter() - start:.0f} s: {stats.published} updates published, "
        f"{stats.deliveries} deliveries to viewers")
    return stats
