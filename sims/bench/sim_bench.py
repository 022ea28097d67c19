"""`entitynet bench sim`: the city simulation's speed against what viewers see (issue 11).

Figures (keys of `results`):
- `entities_realtime_max`: the largest population (pedestrians and cars, plus the scheduled transit) that keeps
  real time with the shard server in the same process on this machine, over real loopback sockets: tick
  lateness p99 under one tick and no tick more than one tick behind (no backlog). Populations double until one
  fails, then up to 3 trials bisect between the last kept and the first lost (`sims.bench.sim_ladder`; none
  with `--quick`); `realtime_limit` gives both ends per ladder; `realtime_trials` lists every trial.
- `entities_realtime_max_counted_viewers`: the same with the server in a child and counted viewers (a tenth of
  the viewers, at least 10, measured; `entitynet sim --measured-viewers K`), trials in
  `realtime_trials_counted_viewers`.
- each real-time trial also has `sim_process_cpu_s` (this process's CPU time over the run, the in-process
  server's included) and `server_process_cpu_s` (the child server's, None in-process): what the server costs.
- `entities_realtime_max_server_process`: the same ladder with the server in a child `entitynet serve`
  (`entitynet sim --server-process yes`, sims/server_child.py), its trials in `realtime_trials_server_process`;
  the ladders alternate trial by trial, so all see the same load on the machine;
  `ratio.server_process_vs_in_process_realtime_max` their ratio.
- `fleet_fixes_per_s`: honest-client fixes per second on one core (GPS fix, client-core decision, message)
  through the fleet core (`Fleet(core="fleet")`, entitynet/client/fleet.py); `fleet_fixes_per_s_player`: the same
  population, truth and seed through per-entity Players (`core="player"`), a second fleet stepped every tick
  beside the first in alternating order (their messages are asserted equal); `fleet_core_speedup` their ratio
  and `fleet_vector_share` the fraction of fixes the fleet core's arrays decided (`fleet_scalar_share_by_reason`:
  the fraction that took the scalar path, by the first reason, `FleetCore.scalar_why`). Timed over 10 s after 20
  simulated s (3 with `--quick`) that are not: the start's burst of first placements and publishes is not the
  steady state.
  `fleet_warm`: the same figures of the same run over 10 s after 600 simulated s (not with `--quick`): in the first
  window the per-map caches are still being built as the entities reach new edges, and that is part of its cost.
- `fleet_bytes_per_entity`, `fleet_row_bytes`, `fleet_players_leaked`, `fleet_objects_per_entity_growth`
  (`sims.bench.fleet_memory`, whole report in `fleet_memory`): the client code's live bytes per tracked entity
  (tracemalloc, the per-map caches apart), the record's array state per row, Players alive beyond the entities
  tracked, and the client objects per entity at the end of an hour against half-way (a minute with `--quick`);
  `fleet_fixes_per_s_hour`: the fleet core's fixes per CPU second of its step over that hour, the median of the
  intervals between samples (no per-entity baseline beside it; the figure above is of the run's first 30 s).
- `deliveries_per_viewer_s`: UPDATEs per street-level viewer-second, subscribing by PVS and by a 500 m radius,
  from the same seeded run against the in-process switchboard core; `radius_vs_pvs_deliveries_ratio` their
  ratio; `messages_per_viewer_s` and `bytes_per_viewer_s` likewise (PVS).
- `viewer_error_p95_m`, `missed_visibility`, `stale_ghost_fraction`: truth against viewers (PVS, all viewers;
  per group and for the radius run in `truth_vs_viewer`).
- `collisions`: avoided, accepted, deleted in the PVS run; `tick_lateness_p99_ms` of the largest real-time run.
- `error_vs_updates`: ghost error p95 against updates per entity-minute for a range of client drift thresholds
  (plotted to `sim-error-vs-updates.png` next to the report when matplotlib is there).
- `workers` (issue 23, `sims.bench.sim_workers`): the same run in one process, with one worker process and with
  two, the cost split per entity-tick behind the model for N machines; ratio `two_vs_one_worker` (wall time).
- `sumo` (issue 26, `sims.sumo.compare`): SUMO's world step against ours per vehicle-second with the same cars on
  the same map (`step_cost`, ratio `world_step_ours_vs_sumo`), the end-to-end figures on SUMO's motion and ours
  (`end_to_end`) and the SUMO entities kept in real time (`realtime_trials`, `entities_realtime_max`); a
  `skipped` note instead where the [sumo] extra is not installed.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from sims.bench.report import pyplot
from sims.bench.sim_ladder import realtime_trial, run_ladders
from sims.engine.local import run_local
from sims.engine.sim import Sim, SimConfig


def _per_viewer_s(sim: Sim, seconds: float, high: bool) -> dict[str, float]:
    vs = [v for v in sim.viewers if v.high == high]
    if not vs:
        return {"deliveries": 0.0, "messages": 0.0, "bytes": 0.0}
    n = len(vs) * seconds
    return {"deliveries": sum(v.deliveries for v in vs) / n, "messages": sum(v.deliveries + v.leaves for v in vs) / n,
            "bytes": sum(v.bytes for v in vs) / n}


def _local(topo, schedule, cfg: SimConfig, seconds: float) -> tuple[Sim, dict]:
    sim = Sim(topo, cfg, schedule)
    rep = run_local(sim, seconds)
    return sim, rep


class _Removals:
    """The world as one of two fleets sees it: the same truth, and the removals taken once for both."""

    def __init__(self, world) -> None:
        self._world = world
        self.removed: list = []

    def __getattr__(self, name: str):
        return getattr(self._world, name)

    def take_removed(self) -> list:
        """The removals of this tick (taken from the world once, handed to each fleet)."""
        out, self.removed = self.removed, []
        return out


def _fleet_rates(topo, n: int, seconds: float, warmup: float = 0.0, warm: float | None = None) -> dict[str, Any]:
    """Fixes per second of the honest-client fleet alone, CPU time of this process, through the fleet core and
    through per-entity Players: two fleets with the same seed fed the same truth, both stepped every tick in
    alternating order (so the machine's drifting load falls on both alike), timed over `seconds` after `warmup`
    untimed simulated seconds (the start's burst of first placements and publishes). Their messages are the same
    (asserted); `share`: the fraction of fixes the fleet core's arrays decided; `scalar_why`: the fraction of
    fixes that took the scalar path, by the first reason that sent them there (`FleetCore.scalar_why`).
    With `warm`, the same run goes on and `warm` holds the same figures over `seconds` after `warm` simulated
    seconds: the per-map caches (segment tables, near tables) are still filling in the first window, and
    those builds are part of its figures (the "warm" window is the steadier state)."""
    from sims.engine.clients import Fleet

    if int(seconds) < 1:
        raise ValueError(f"the fleet rates need a window of at least 1 simulated s, got {seconds!r}")
    sim = Sim(topo, SimConfig(entities=n, viewers=0, transit=False, tick_hz=1.0, seed=5, core="fleet"))
    views = {"fleet": _Removals(sim.world), "player": _Removals(sim.world)}
    fleets = {core: Fleet(views[core], sim.config.connections, fix_interval=sim.config.fix_interval,
                          gps_sigma=sim.config.gps_sigma, seed=sim.config.seed, core=core) for core in views}
    for a in sim.population.start():
        for f in fleets.values():
            f.add(a)
    starts = [int(warmup)] + ([int(warm)] if warm is not None and warm > warmup + seconds else [])
    windows = [{"start": w, "spent": dict.fromkeys(fleets, 0.0), "fixes": 0} for w in starts]
    core = fleets["fleet"].fleet_core
    for k in range(starts[-1] + int(seconds) + 1):
        if k:
            sim.world.step(1.0)
            for a in sim.population.step():
                for f in fleets.values():
                    f.add(a)
        removed = sim.world.take_removed()
        win = next((w for w in windows if w["start"] < k <= w["start"] + int(seconds)), None)
        if win is not None and k == win["start"] + 1:
            core.counters.update(dict.fromkeys(core.counters, 0))
            core.scalar_why.update(dict.fromkeys(core.scalar_why, 0))
        before = fleets["fleet"].counters["fixes"]
        out = {}
        for name in (("fleet", "player") if k % 2 else ("player", "fleet")):
            views[name].removed = list(removed)
            t = time.process_time()
            out[name] = fleets[name].step(sim.now)
            if win is not None:
                win["spent"][name] += time.process_time() - t
        assert out["fleet"] == out["player"], "the fleet core's messages differ from the per-entity Players'"
        if win is not None:
            win["fixes"] += fleets["fleet"].counters["fixes"] - before
            if k == win["start"] + int(seconds):
                c = core.counters
                win["share"] = c["vector_fixes"] / max(c["vector_fixes"] + c["scalar_fixes"], 1)
                win["scalar_why"] = {why: round(m / max(win["fixes"], 1), 4) for why, m in core.scalar_why.items() if m}
    figures = []
    for w in windows:
        rate = {name: w["fixes"] / w["spent"][name] if w["spent"][name] > 0 else 0.0 for name in fleets}
        figures.append({"fleet": rate["fleet"], "player": rate["player"],
                        "ratio": rate["fleet"] / rate["player"] if rate["player"] > 0 else None,
                        "share": w["share"], "scalar_why": w["scalar_why"], "after_s": w["start"]})
    out = figures[0]
    if len(figures) > 1:
        out["warm"] = figures[1]
    return out


def run(args, progress) -> dict[str, Any]:
    """The suite: PVS and radius runs against the in-process core, the drift-threshold sweep, the fleet core's
    rate and the real-time ladder over loopback sockets; the report's params, results, peer and ratio."""
    from entitynet.topology_cache import bundled_topology, cache_dir
    from sims.engine.schedule import BUNDLED_FEED, load_schedule

    quick = bool(getattr(args, "quick", False))
    if getattr(args, "topology", None):
        from topology.artifact import load

        topo, artifact = load(args.topology), Path(args.topology)
    else:
        topo, artifact = bundled_topology(progress, with_pvs=True)
    schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir())
    seconds = getattr(args, "sim_seconds", None) or (15.0 if quick else 60.0)
    entities, viewers = (150, 16) if quick else (400, 40)

    from sims.bench.fleet_memory import measure as fleet_memory

    # (first: its census of the client objects counts the process's, before the other runs leave theirs)
    progress("fleet core: memory per tracked entity and its growth over " + ("a minute" if quick else "an hour"))
    memory = fleet_memory(topo, 100 if quick else 1000, 60.0 if quick else 3600.0, 4 if quick else 12,
                          10.0 if quick else 120.0, progress=progress)

    progress(f"PVS and radius runs: {entities} entities, {viewers} viewers, {seconds:g} simulated s")
    base = dict(entities=entities, viewers=viewers, seed=7)
    pvs_sim, pvs = _local(topo, schedule, SimConfig(**base, subscribe="pvs"), seconds)
    rad_sim, rad = _local(topo, schedule, SimConfig(**base, subscribe="radius"), seconds)
    street_pvs = _per_viewer_s(pvs_sim, seconds, high=False)
    street_rad = _per_viewer_s(rad_sim, seconds, high=False)

    progress("error against updates per entity-minute (client drift thresholds)")
    sweep = []
    for thr in ((5.0, 20.0) if quick else (3.0, 5.0, 10.0, 20.0)):
        s, r = _local(topo, schedule, SimConfig(entities=entities // 2, viewers=viewers // 2, seed=9,
                                                threshold=thr), seconds)
        ent_min = sum(r["entities"].values()) * seconds / 60.0
        tv = r["truth_vs_viewer"]["all"]
        sweep.append({"threshold_m": thr, "updates_per_entity_min": r["clients"]["published"] / max(ent_min, 1e-9),
                      "error_p95_m": tv["error_p95_m"], "error_mean_m": tv["error_mean_m"],
                      "missed_visibility": tv["missed_visibility"]})

    progress("fleet core: fixes per second on one core")
    fleet = _fleet_rates(topo, 300 if quick else 1000, 3 if quick else 10, 3 if quick else 20, None if quick else 600)

    progress("real time: the server in this process, in a child, and in a child with counted viewers (alternating)")
    rt_seconds = 6.0 if quick else 20.0  # simulated = wall seconds at speed 1, after the warm-up
    ladders = _realtime_ladders(topo, artifact, schedule, rt_seconds, quick, progress)
    best, child_best = ladders["in_process"]["max"], ladders["server_process"]["max"]

    from sims.sumo.compare import bench_rows  # skipped, with the reason, without the [sumo] extra

    sumo = bench_rows(topo, artifact, schedule, quick, progress)

    from sims.bench.sim_workers import worker_rows  # the same run in one process, with 1 and with 2 workers

    workers = worker_rows(topo, schedule, quick, progress, artifact=artifact)
    all_pvs = pvs["truth_vs_viewer"]["all"]
    results = {
        "entities_realtime_max": best,
        "entities_realtime_max_server_process": child_best,
        "tick_lateness_p99_ms_server_process": _lateness_of_max(ladders["server_process"]),
        "entities_realtime_max_counted_viewers": ladders["counted_viewers"]["max"],
        "tick_lateness_p99_ms_counted_viewers": _lateness_of_max(ladders["counted_viewers"]),
        "realtime_limit": {name: {"kept": lad["max"], "lost": lad["lost"]} for name, lad in ladders.items()},
        "fleet_fixes_per_s": fleet["fleet"],
        "fleet_fixes_per_s_player": fleet["player"],
        "fleet_core_speedup": fleet["ratio"],
        "fleet_vector_share": fleet["share"],
        "fleet_scalar_share_by_reason": fleet["scalar_why"],
        # the same run after 600 simulated s (the per-map caches warmer): both cores, the same seed and truth
        "fleet_warm": fleet.get("warm"),
        "fleet_bytes_per_entity": memory["bytes_per_entity"],
        "fleet_row_bytes": memory["row_bytes"],
        "fleet_players_leaked": memory["players_leaked"],
        "fleet_objects_per_entity_growth": memory["objects_per_entity_growth"],
        "fleet_memory": memory,
        # the fleet core alone over the hour of `fleet_memory`: the median of its intervals between samples
        "fleet_fixes_per_s_hour": memory["growth"]["fleet_fixes_per_s_median"],
        "deliveries_per_viewer_s": {"pvs": street_pvs["deliveries"], "radius": street_rad["deliveries"]},
        "radius_vs_pvs_deliveries_ratio": street_rad["deliveries"] / street_pvs["deliveries"]
        if street_pvs["deliveries"] else None,
        "messages_per_viewer_s": {"pvs": street_pvs["messages"], "radius": street_rad["messages"]},
        "bytes_per_viewer_s": {"pvs": street_pvs["bytes"], "radius": street_rad["bytes"]},
        "viewer_error_p95_m": all_pvs["error_p95_m"],
        "missed_visibility": all_pvs["missed_visibility"],
        "stale_ghost_fraction": all_pvs["stale_ghost_fraction"],
        "collisions": pvs["collisions"],
        "tick_lateness_p99_ms": _lateness_of_max(ladders["in_process"]),
        "error_vs_updates": sweep,
        "truth_vs_viewer": {"pvs": pvs["truth_vs_viewer"], "radius": rad["truth_vs_viewer"]},
        "realtime_trials": ladders["in_process"]["trials"],
        "realtime_trials_server_process": ladders["server_process"]["trials"],
        "realtime_trials_counted_viewers": ladders["counted_viewers"]["trials"],
        "sumo": sumo,
        "workers": workers,
    }
    out = getattr(args, "out", None)
    if out:
        _plot(sweep, Path(out).with_name("sim-error-vs-updates.png"), progress)
    return {
        "params": {"quick": quick, "sim_seconds": seconds, "entities": entities, "viewers": viewers,
                   "realtime_seconds": rt_seconds, "fleet_warmup_s": 3 if quick else 20, "tick_hz": 2.0,
                   "gps_sigma_m": 5.0, "fix_hz": 1.0,
                   "schedule": BUNDLED_FEED.name, "start": "08:00",
                   "fleet_core": "FleetCore (entitynet/client/fleet.py); baseline: the same core, arrays off "
                                 "(vectorised=False: Player by Player), same run"},
        "results": results,
        "peer": {"radius_500m": {"deliveries_per_viewer_s": street_rad["deliveries"],
                                 "missed_visibility": rad["truth_vs_viewer"]["all"]["missed_visibility"]}},
        "ratio": {"radius_vs_pvs_deliveries": results["radius_vs_pvs_deliveries_ratio"],
                  "fleet_core_vs_player": fleet["ratio"],
                  "server_process_vs_in_process_realtime_max": child_best / best if best else None,
                  "two_vs_one_worker": workers["two_vs_one_worker"],
                  "world_step_ours_vs_sumo": [c["ours_vs_sumo"] for c in sumo.get("step_cost", [])] or None},
    }


def _realtime_ladders(topo, artifact, schedule, seconds: float, quick: bool, progress) -> dict[str, dict]:
    """The real-time ladders (`sims.bench.sim_ladder`: doubling from 100 entities with a tenth as many viewers,
    then bisecting between the last size kept and the first lost), alternating trial by trial: the server in
    this process, in a child process, and in a child with counted viewers (a tenth of the viewers, at least 10,
    measured; the others only count what they read). `--quick`: up to 200 entities, no bisection."""
    def variant(server_process: bool, counted: bool):
        def trial(n: int) -> dict:
            v = max(10, n // 10)
            return realtime_trial(topo, artifact, schedule, n, v, seconds, server_process=server_process,
                                  measured=min(v, max(10, v // 10)) if counted else None)
        return trial

    return run_ladders({"in_process": variant(False, False), "server_process": variant(True, False),
                        "counted_viewers": variant(True, True)},
                       top=200 if quick else 20000, bisect_steps=0 if quick else 3,
                       budget_s=300.0 if quick else 2400.0, progress=progress)


def _lateness_of_max(ladder: dict) -> float | None:
    """Tick lateness p99 of the ladder's largest trial kept (None: none kept)."""
    kept = [t for t in ladder["trials"] if t["ok"] and t["entities"] == ladder["max"]]
    return kept[-1]["tick_lateness_p99_ms"] if kept else None


def _plot(sweep: list[dict], path: Path, progress) -> None:
    plt = pyplot(progress)
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    xs = [s["updates_per_entity_min"] for s in sweep]
    ax.plot(xs, [s["error_p95_m"] for s in sweep], "o-", label="p95")
    ax.plot(xs, [s["error_mean_m"] for s in sweep], "s--", label="mean")
    for s in sweep:
        ax.annotate(f"{s['threshold_m']:g} m", (s["updates_per_entity_min"], s["error_p95_m"]), fontsize=8)
    ax.set_xlabel("updates per entity-minute")
    ax.set_ylabel("ghost position error (m)")
    ax.set_title("entitynet sim: viewer error against update rate")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    progress(f"plot written to {path}")
