"""`entitynet demo`: a preset of `entitynet sim` that serves the 3D browser viewer.

Why a preset and not a program of its own: the demo shows the system working, and the simulation is where the
system's behaviour is modelled and measured; two movers, two viewers and two loops drifted apart before. The
demo is now only a mapping of its options onto the simulation's configuration (`sim_config`, `shell_config`):
the same engine (pedestrians and cars on OD trips, trams and buses on the bundled HSL schedule, collision
avoidance), the same honest-client fleet and PVS viewers, the same trio shell, running in real time with the
in-process server also serving the browser viewer over HTTP and its entity feed over WebSocket. The transit
part (`--transit FEED`: trams and buses moved by the SIRI replay producer and the transit proxy) is found by
entry point, so `sims` never imports `proxies`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

import trio

from sims.engine.schedule import Schedule
from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig

Say = Callable[[str], None]


@dataclass
class DemoConfig:
    """The demo's knobs (population, viewers, connections, duration, ports) with defaults a laptop runs live."""

    entities: int = 300  # pedestrians and cars; the schedule's trams and buses come on top
    viewers: int = 24
    connections: int = 4
    car_share: float = 0.3
    duration: float | None = None  # seconds; None = until Ctrl-C
    summary_every: float = 5.0
    seed: int = 1
    host: str = "127.0.0.1"
    port: int = 0  # the server's TCP port (0: any free port)
    http_port: int | None = None  # serve the browser viewer here (0: any free port; None: none)
    start: float = 8 * 3600.0  # service-day time of the schedule the demo starts at
    transit: str | None = None  # a GTFS feed: trams and buses through the replay producer and the SIRI proxy
    tick_hz: float = 2.0


def sim_config(config: DemoConfig, *, scheduled: bool) -> SimConfig:
    """The simulation the demo runs: its population and viewers; the engine's own trams and buses when it has a
    schedule and no `--transit` part brings them instead."""
    return SimConfig(entities=config.entities, viewers=config.viewers, connections=config.connections,
                     car_share=config.car_share, tick_hz=config.tick_hz, seed=config.seed, start=config.start,
                     transit=scheduled and config.transit is None)


def shell_config(config: DemoConfig, artifact: Path, parts=()) -> ShellConfig:
    """The shell the demo runs in: real time, its own server on loopback serving the viewer, the given parts."""
    return ShellConfig(duration=config.duration, speed=1.0, summary_every=config.summary_every,
                       artifact=artifact, host=config.host, port=config.port, http_port=config.http_port,
                       parts=tuple(parts))


async def run_demo(topo, artifact: Path, config: DemoConfig, say: Say = print, schedule: Schedule | None = None,
                   task_status=trio.TASK_STATUS_IGNORED) -> dict:
    """Run the demo on loopback until `duration` or Ctrl-C (the summary line through `say`) and return the
    simulation's report. `schedule`: the trams' and buses' departures (None: no scheduled transit).
    `task_status.started(server)` once everything is connected."""
    sim = Sim(topo, sim_config(config, scheduled=schedule is not None), schedule)
    shell: Shell | None = None
    parts = []
    if config.transit:
        run_transit = demo_part("transit")  # optional part, from the proxies package

        async def transit(address, task_status=trio.TASK_STATUS_IGNORED):
            await run_transit(topo, address, config.transit, say, start=config.start, clock=shell.clock,
                              task_status=task_status)

        parts.append(transit)
    shell = Shell(sim, shell_config(config, artifact, parts), say)
    transit = ("the schedule's trams and buses" if sim.config.transit else
               "trams and buses through the transit proxy" if config.transit else "no trams or buses")
    say(f"{config.entities} pedestrians and cars and {transit} over {config.connections} connections; "
        f"{len(sim.viewers)} viewers subscribing by {sim.subscription_text()}")
    return await shell.run(task_status=task_status)


#: entry-point group through which other packages add parts to the demo (`name = "module:function"`)
DEMO_PART_GROUP = "entitynet.demo_parts"


def demo_part(name: str) -> Callable:
    """The demo part `name` that another package registers (transit: proxies' replay producer and SIRI proxy),
    found by entry point so that sims never imports proxies (the layering's arrows run one way)."""
    for ep in entry_points(group=DEMO_PART_GROUP, name=name):
        return ep.load()
    raise LookupError(f"no demo part {name!r} installed (entry-point group {DEMO_PART_GROUP})")
