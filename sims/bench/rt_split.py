"""Where a real-time tick's time goes: `python -m sims.bench.rt_split ENTITIES VIEWERS [SECONDS] [SHARE]
[--server-process] [--per-viewer] [--measured K]`.

Why: `entities_realtime_max` says only pass or fail; to cut a tick one needs its parts. This builds the sim and
shell as the bench's real-time trial does (server in this process, loopback), runs the shell as fast as it can
(speed 1000, so a tick's cost is its wall time), and wraps the parts in wall-clock timers: the world's step,
the fleet, the viewers' camera moves and arrivals, the measure, the shell's sends and the server's
switchboard core. The sends await the sockets, so the server shell and the viewer connections run inside
them: `rest` = the tick less the parts outside the sends. Figures are ms per tick after `WARM` ticks (the
start's burst), in wall time (`ms_per_tick`) and in this process's CPU time (`cpu_ms_per_tick`, steadier when
other processes load the machine; the tick's CPU less the parts is then the sends and the connections' CPU).
`--per-viewer`: each viewer its own `Connection` and tasks (the reference path) instead of the one reader over
every viewer socket (`sims.engine.viewer_reader`), for A/B runs in one tree. `--measured K`: only K viewers
keep ghosts and are measured, the others are counted viewers (`SimConfig.measured_viewers`).
`coordinator_us_per_delivery`: the viewers' side (the sends and connections, the camera moves, the measure) in
CPU us per UPDATE delivered.
Timings move with the machine's load: say the load average with them.
"""

from __future__ import annotations

import functools
import json
import os
import sys
import time
from collections import defaultdict

WARM = 6


def split(n: int, viewers: int, seconds: float = 10.0, share: float = 0.25, topology=None,
          server_process: bool = False, per_viewer: bool = False, measured: int | None = None) -> dict:
    """The per-tick split (ms) of a real-time run of `n` entities and `viewers` viewers (see the docstring).
    `topology`: (topo, artifact path) to run on instead of the bundled map and schedule (no transit then).
    `server_process`: the server in a child `entitynet serve` (as `entitynet sim` runs large runs): its CPU time
    per tick is `server_process_cpu`, and `rest` is then the sends and the viewer connections only."""
    import trio

    from entitynet.topology_cache import bundled_topology, cache_dir
    from sims.engine.schedule import BUNDLED_FEED, load_schedule
    from sims.engine.sim import Sim, SimConfig
    from sims.shell import Shell, ShellConfig

    if topology is None:
        topo, artifact = bundled_topology(lambda m: None, with_pvs=True)
        schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir())
    else:
        (topo, artifact), schedule = topology, None
    counted = {} if measured is None else {"measured_viewers": measured}  # (runs on a tree without the option)
    sim = Sim(topo, SimConfig(entities=n, viewers=viewers, seed=11, measure_share=share,
                              transit=schedule is not None, **counted), schedule)
    acc: dict[str, float] = defaultdict(float)
    cpu: dict[str, float] = defaultdict(float)  # the same parts in this process's CPU time (steadier under load)
    calls: dict[str, int] = defaultdict(int)  # timed calls per part (each costs the timer's own time)

    def timed(obj, name: str, key: str) -> None:
        """Time `obj.name` under `key`, in wall and in this process's CPU time. Each timed call costs the timers
        themselves, about 14 us on this VM (`process_time` is a system call, about 6 us), counted in
        `timed_calls_per_tick` (a viewer's frames: about 640 calls a tick at 3,000 / 300)."""
        f = getattr(obj, name)

        @functools.wraps(f)
        def wrapper(*a, **k):
            t, c = time.perf_counter(), time.process_time()
            try:
                return f(*a, **k)
            finally:
                if sim.ticks >= WARM:
                    acc[key] += time.perf_counter() - t
                    cpu[key] += time.process_time() - c
                    calls[key] += 1
        setattr(obj, name, wrapper)

    def atimed(obj, name: str, key: str) -> None:
        f = getattr(obj, name)

        async def wrapper(*a, **k):
            t = time.perf_counter()
            try:
                return await f(*a, **k)
            finally:
                if sim.ticks >= WARM:
                    acc[key] += time.perf_counter() - t
        setattr(obj, name, wrapper)

    timed(sim.world, "step", "world")
    timed(sim.fleet, "step", "fleet")
    timed(sim.population, "step", "population")
    for v in sim.viewers:
        timed(v, "move", "viewer_move")
        timed(v, "receive", "viewer_receive")
        timed(v, "receive_frame", "viewer_receive")  # the viewer fleet's whole frames
    timed(sim, "maybe_sample", "measure")
    shell = Shell(sim, ShellConfig(duration=seconds + WARM * sim.dt, speed=1000.0, summary_every=1e9,
                                   artifact=artifact, keys=False), lambda m: None)
    if per_viewer:
        from sims.engine.viewer_fleet import ViewerFleet

        shell.viewer_fleet = ViewerFleet(sim.viewers, lambda: sim.now, shell._learn, one_reader=False)
    atimed(shell, "_send", "send (server and viewer connections inside)")
    t0: list[float] = []
    step = sim.step

    delivered: list[int] = []
    c0: list[float] = []

    def first_timed_step():
        if sim.ticks == WARM:
            t0.append(time.perf_counter())
            c0.append(time.process_time())
            delivered.append(sum(v.deliveries for v in sim.viewers))
        return step()
    sim.step = first_timed_step

    async def main() -> None:
        async with trio.open_nursery() as nursery:
            server = await nursery.start(shell.run)
            timed(server.sb, "receive", "server_core")

    server_cpu = None
    if server_process:
        from sims.server_child import ServerChild

        with ServerChild(artifact) as child:
            shell.config.server = child.address
            child_cpu0: list[float | None] = []

            def mark_child_cpu():
                if sim.ticks == WARM:
                    child_cpu0.append(child.cpu_seconds())
                return first_timed_step()
            sim.step = mark_child_cpu
            trio.run(child.run_shell, shell)
            end = child.cpu_seconds()
            if child_cpu0 and child_cpu0[0] is not None and end is not None:
                server_cpu = end - child_cpu0[0]
    else:
        trio.run(main)
    ticks = sim.ticks - WARM
    out = {k: round(1000 * x / ticks, 1) for k, x in sorted(acc.items())}
    cpu_out = {k: round(1000 * x / ticks, 1) for k, x in sorted(cpu.items())}
    cpu_out["tick"] = round(1000 * (time.process_time() - c0[0]) / ticks, 1)
    if server_cpu is not None:
        out["server_process_cpu"] = cpu_out["server_process_cpu"] = round(1000 * server_cpu / ticks, 1)
    out["tick"] = round(1000 * (time.perf_counter() - t0[0]) / ticks, 1)
    outside = ("world", "fleet", "population", "viewer_move", "measure")
    rest = "rest (sends, viewer connections)" if server_process else "rest (sends, server, viewer connections)"
    out[rest] = round(out["tick"] - sum(out.get(k, 0.0) for k in outside), 1)
    cpu_out[rest] = round(cpu_out["tick"] - sum(cpu_out.get(k, 0.0) for k in outside), 1)
    deliveries = (sum(v.deliveries for v in sim.viewers) - delivered[0]) / ticks if delivered else None
    side = cpu_out[rest] + cpu_out.get("viewer_move", 0.0) + cpu_out.get("measure", 0.0)
    per = round(1000 * side / deliveries, 2) if deliveries else None
    return {"entities": n, "viewers": viewers, "measured_viewers": measured or viewers, "one_reader": not per_viewer,
            "coordinator_us_per_delivery": per, "on_map": len(sim.world.agents), "ticks": ticks,
            "deliveries_per_tick": deliveries,
            "measure_share": share, "server": "a child process" if server_process else "in this process",
            "load": os.getloadavg()[0], "ms_per_tick": out, "cpu_ms_per_tick": cpu_out,
            "timed_calls_per_tick": {k: round(x / ticks, 1) for k, x in sorted(calls.items())}}


if __name__ == "__main__":
    a = sys.argv[1:]
    if len(a) < 2:
        sys.exit(__doc__.splitlines()[0])
    child, per_viewer = "--server-process" in a, "--per-viewer" in a
    k = None
    if "--measured" in a:
        at = a.index("--measured")
        k = int(a[at + 1])
        del a[at:at + 2]
    a = [x for x in a if x not in ("--server-process", "--per-viewer")]
    print(json.dumps(split(int(a[0]), int(a[1]), float(a[2]) if len(a) > 2 else 10.0,
                           float(a[3]) if len(a) > 3 else 0.25, server_process=child,
                           per_viewer=per_viewer, measured=k), indent=1))
