"""`entitynet bench sim`'s worker rows: the same run in one process, with one worker and with two, and the
cost split behind the model for N machines (docs/simulation.md, "Workers").

Figures (under `results["workers"]`):
- `cost_per_entity_tick_us`: one process, timed part by part over the same run: `world` (the truth's step,
  which every worker and the coordinator repeat), `clients` (the honest clients' fixes through their cores:
  what the workers share) and `coordinator` (viewers, switchboard and measure: what stays in the coordinator);
- `runs`: the same seeded run against the in-process switchboard (`LocalSwitch`: no sockets, so only compute
  is compared), timed after a warm-up, in one process, with 1 worker and with 2 (forked, `sims.workers.local`),
  alternated `repeats` times; each with its wall seconds, the workers' step p50 and the coordinator's wait for them p50;
  `wall_s_median` per mode and the ratios `two_vs_one_worker` and `two_workers_vs_one_process` (wall time, < 1:
  faster);
- `realtime` (not with `--quick`): 1,600 entities and 160 viewers at speed 1 over loopback sockets (the CLI's
  shell, the server in the coordinator's process) in one process, with 1 and with 2 workers: tick lateness p99
  and ticks behind;
- `model`: the largest population one tick period holds with N machines, from the measured costs (see
  `model_entities`), for N = 1, 2, 4, 8.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

from sims.engine.local import LocalSwitch
from sims.engine.sim import Sim, SimConfig


def cost_split(topo, schedule, cfg: SimConfig, ticks: int, warmup: int) -> dict[str, float]:
    """Microseconds per entity-tick of the world's step, the clients' step and the coordinator's remaining
    work (viewers, switchboard, measure), timed part by part in one process after `warmup` ticks."""
    sim = Sim(topo, cfg, schedule)
    sw = LocalSwitch(sim)
    sw.exchange(*sim.start())
    t = {"world": 0.0, "clients": 0.0, "coordinator": 0.0}
    entity_ticks = 0
    for k in range(warmup + ticks):
        t0 = time.perf_counter()
        new = sim.source.step(sim.dt)
        sim.ticks += 1
        for a in new:
            sim.fleet.add(a)
        t1 = time.perf_counter()
        pubs = sim.fleet.step(sim.now)
        t2 = time.perf_counter()
        subs = [v.move(sim.dt) for v in sim.viewers]
        sw.exchange(pubs, subs)
        sim.maybe_sample(sw.eid_to_agent())
        t3 = time.perf_counter()
        if k >= warmup:
            t["world"] += t1 - t0
            t["clients"] += t2 - t1
            t["coordinator"] += t3 - t2
            entity_ticks += len(sim.world.agents)
    return {k: 1e6 * v / max(entity_ticks, 1) for k, v in t.items()}


def _run(topo, schedule, cfg: SimConfig, seconds: float, workers: int | None, warmup: int) -> dict[str, Any]:
    """One run against the in-process switchboard: wall seconds of `seconds` simulated after `warmup` ticks
    (the start, every entity's first placement and publish, and the workers' fork are not the steady state)."""
    sim: Sim
    if workers is None:
        sim = Sim(topo, cfg, schedule)
    else:
        from sims.workers.local import LocalWorkers
        from sims.workers.sim import WorkerSim

        sim = WorkerSim(topo, cfg, schedule, LocalWorkers(workers, topo, schedule), workers, transport="local",
                        timeout=60.0)
    try:
        sw = LocalSwitch(sim)
        sw.exchange(*sim.start())
        n = int(round(seconds * cfg.tick_hz))
        for k in range(warmup + n):
            if k == warmup:
                t0 = time.perf_counter()
            sw.exchange(*sim.step())
            sim.maybe_sample(sw.eid_to_agent())
        wall = time.perf_counter() - t0
        rep = sim.report()
    finally:
        close = getattr(sim, "close", None)
        if close is not None:
            close()
    out = {"workers": workers or 0, "wall_s": wall, "entities_on_map": sum(rep["entities"].values())}
    if workers:
        w = rep["workers"]
        out.update(worker_step_p50_ms=[p["step_p50_ms"] for p in w["per_worker"]],
                   coordinator_wait_p50_ms=w["coordinator_wait_p50_ms"])
    return out


def model_entities(cost: dict[str, float], machines: int, tick_s: float = 0.5) -> dict[str, float]:
    """The largest population one tick period (`tick_s`) holds with `machines` worker machines: a worker's
    tick costs E x (world + clients / N), the coordinator's E x (world + coordinator); the smaller bound wins.
    Compute only (no network, no server): an upper bound that tells which side limits."""
    w, c, rest = cost["world"], cost["clients"], cost["coordinator"]
    worker = 1e6 * tick_s / (w + c / machines)
    coordinator = 1e6 * tick_s / (w + rest)
    return {"machines": machines, "worker_bound": worker, "coordinator_bound": coordinator,
            "entities": min(worker, coordinator), "limited_by": "workers" if worker < coordinator else "coordinator"}


def realtime_trial(topo, artifact, schedule, workers: int | None, entities: int, viewers: int,
                   seconds: float, warmup_ticks: int = 6) -> dict[str, Any]:
    """One run at speed 1 over loopback sockets (the CLI's shell, the server in this process): tick lateness
    p99 and ticks behind after `warmup_ticks`, in one process or with `workers` forked workers."""
    import trio

    from sims.shell import Shell, ShellConfig

    cfg = SimConfig(entities=entities, viewers=viewers, seed=11, measure_share=0.25)
    if workers is None:
        sim = Sim(topo, cfg, schedule)
    else:
        from sims.workers.local import LocalWorkers
        from sims.workers.sim import WorkerSim

        sim = WorkerSim(topo, cfg, schedule, LocalWorkers(workers, topo, schedule), workers, transport="local",
                        timeout=60.0)
    shell = Shell(sim, ShellConfig(duration=seconds + warmup_ticks * sim.dt, speed=1.0, summary_every=1e9,
                                   artifact=artifact, keys=False, warmup_ticks=warmup_ticks), lambda m: None)
    try:
        rep = trio.run(shell.run)
    finally:
        close = getattr(sim, "close", None)
        if close is not None:
            close()
    rt = rep["realtime"]
    return {"workers": workers or 0, "entities": entities, "viewers": viewers,
            "tick_lateness_p99_ms": rt["tick_lateness_p99_ms"], "ticks_behind": rt["ticks_behind"],
            "ok": rt["tick_lateness_p99_ms"] < 1000.0 * sim.dt and rt["ticks_behind"] == 0}


def worker_rows(topo, schedule, quick: bool, progress, *, entities: int | None = None,
                viewers: int | None = None, transit: bool = True, artifact=None) -> dict[str, Any]:
    """The worker figures of `bench sim` (see the module docstring); `entities` / `viewers` / `transit`
    override the suite's sizes (tests run it on a small map)."""
    entities = entities if entities is not None else 300 if quick else 3000
    viewers = viewers if viewers is not None else 20 if quick else 100
    seconds, repeats, warmup = (5.0, 1, 4) if quick else (20.0, 3, 20)
    cfg = SimConfig(entities=entities, viewers=viewers, seed=13, measure_share=0.25, transit=transit)
    if not transit:
        cfg.subscribe, cfg.start = "radius", 0.0
    progress(f"workers: cost split per entity-tick ({entities} entities, {viewers} viewers)")
    cost = cost_split(topo, schedule, cfg, 10 if quick else 40, 4 if quick else 20)
    runs: list[dict] = []
    modes = [None, 1, 2]
    for r in range(repeats):
        for workers in modes if r % 2 == 0 else modes[::-1]:  # alternated: the same load for every mode
            run = _run(topo, schedule, cfg, seconds, workers, warmup)
            runs.append(run)
            progress(f"  {workers or 'no'} worker(s): {run['wall_s']:.1f} s wall for {seconds:g} simulated s")
    realtime: list[dict] | str = "skipped with --quick"
    if not quick and artifact is not None:
        realtime = []
        for workers in (None, 1, 2):
            trial = realtime_trial(topo, artifact, schedule, workers, 1600, 160, 20.0)
            realtime.append(trial)
            progress(f"  real time, {workers or 'no'} worker(s), 1600 entities: lateness p99 "
                     f"{trial['tick_lateness_p99_ms']:.0f} ms, {trial['ticks_behind']} ticks behind")
    med = {m: statistics.median(x["wall_s"] for x in runs if x["workers"] == (m or 0)) for m in modes}
    return {
        "entities": entities, "viewers": viewers, "sim_seconds": seconds, "warmup_ticks": warmup,
        "repeats": repeats,
        "cost_per_entity_tick_us": cost, "runs": runs,
        "wall_s_median": {"one_process": med[None], "one_worker": med[1], "two_workers": med[2]},
        "two_vs_one_worker": med[2] / med[1], "two_workers_vs_one_process": med[2] / med[None],
        "model": [model_entities(cost, n) for n in (1, 2, 4, 8)],
        "realtime": realtime,
        "note": "runs: LocalSwitch (no sockets), compute only; realtime: over loopback sockets with the server in "
                "the coordinator's process; forked workers on this machine share its cores with the coordinator",
    }
