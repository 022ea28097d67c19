"""SUMO against our world, side by side (`entitynet bench sim`'s SUMO rows; docs/sumo.md).

- `step_cost`: the world step's CPU time per simulated vehicle-second, SUMO's (`simulationStep`, Krauss cars,
  junction right of way, signals, on SUMO's network of the bundled map) against our world's (`World.step` and
  the population, IDM cars and our junction reservations, on the artifact's network of the same map), each with
  the same number of cars kept on the map (a target population: a car that arrives is replaced at once, as our
  `Population` does; in SUMO by `vehicle.add` on a route of the scenario's random trips). CPU time of this
  process; the two worlds alternate in slices so the shared machine's drifting load falls on both alike.
- `end_to_end`: the honest clients, the in-process switchboard and the viewers driven by SUMO's motion and by
  ours, with the same mix of cars and pedestrians (SUMO's scenario after a warm-up of SUMO alone, and our
  world with its counts): updates per entity-minute, viewer error, missed visibility.
- `realtime`: how many SUMO entities (cars and walkers, topped up to a target) the honest clients keep in real
  time over loopback sockets with the server in this process, and where a tick's time goes (this process's CPU
  time per tick: SUMO's step, reading positions, the rest: clients, server, viewers, measure).
"""

from __future__ import annotations

import random
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from sims.sumo.scenario import write_config

#: walk routes routed once from the scenario's random walk trips (the top-up draws from these)
WALK_ROUTES = 300


class TopUp:
    """Keeps `cars` vehicles and `walkers` persons in a running libsumo simulation: before each step the missing
    ones are added on routes drawn (seeded) from the scenario's random trips."""

    def __init__(self, folder: Path, cars: int, walkers: int, seed: int = 1):
        import libsumo

        self.cars, self.walkers = cars, walkers
        self.rng = random.Random(seed)
        self.routes: list[str] = []
        self.walks: list[list[str]] = []
        if cars and (folder / "cars.rou.xml").exists():
            for k, r in enumerate(ET.parse(folder / "cars.rou.xml").getroot().iter("route")):
                rid = f"topup{k}"
                libsumo.route.add(rid, r.get("edges").split())
                self.routes.append(rid)
        if walkers and (folder / "peds.rou.xml").exists():
            for w in list(ET.parse(folder / "peds.rou.xml").getroot().iter("walk"))[:WALK_ROUTES]:
                edges = (w.get("edges") or "").split()
                if not edges and w.get("from") and w.get("to"):  # a walk trip: SUMO routes it once here
                    try:
                        stages = libsumo.simulation.findIntermodalRoute(w.get("from"), w.get("to"))
                    except libsumo.TraCIException:
                        continue
                    edges = list(stages[0].edges) if len(stages) == 1 else []
                if edges:
                    self.walks.append(edges)
        self._n = 0

    def __call__(self) -> None:
        """Add the missing cars and walkers (pending insertions count as there)."""
        import libsumo

        sim = libsumo.simulation
        if self.routes:
            missing = self.cars - libsumo.vehicle.getIDCount() - len(sim.getPendingVehicles())
            for _ in range(max(missing, 0)):
                self._n += 1
                libsumo.vehicle.add(f"tc{self._n}", self.rng.choice(self.routes), typeID="DEFAULT_VEHTYPE",
                                    departLane="best", departSpeed="max")
        if self.walks:
            for _ in range(max(self.walkers - libsumo.person.getIDCount(), 0)):
                self._n += 1
                edges = self.rng.choice(self.walks)
                pid = f"tp{self._n}"
                libsumo.person.add(pid, edges[0], 0.0)
                libsumo.person.appendWalkingStage(pid, edges, 0.5 * libsumo.lane.getLength(f"{edges[-1]}_0"))


def _cfg_without_demand(folder: Path, duration: float) -> Path:
    """A configuration of the scenario's network (and stops) with no demand of its own: the top-up adds it."""
    tmp = Path(tempfile.mkdtemp(prefix="entitynet-sumo-"))
    net = folder / "net.net.xml"
    cfg = tmp / "topup.sumocfg"
    write_config(cfg, str(net), [], [], duration)
    return cfg


def step_cost(topo, folder: Path, cars: int, seconds: float, dt: float = 0.5, slices: int = 6) -> dict:
    """CPU time per vehicle-second of SUMO's step and our world's, `cars` cars kept on the same map's network
    (module docstring). SUMO's figure is `simulationStep` alone; reading the positions is reported beside it."""
    import libsumo

    from sims.engine.source import OurWorld
    from sims.sumo.source import SumoSource

    src = SumoSource(topo, _cfg_without_demand(folder, 1e6), start=0.0, step=dt)
    top = TopUp(folder, cars, 0)
    ours = OurWorld(topo, seed=5, start=8 * 3600.0, entities=cars, car_share=1.0, transit=False)
    ours.start()
    spent = {"sumo": 0.0, "ours": 0.0, "sumo_read": 0.0}
    vsec = {"sumo": 0.0, "ours": 0.0}
    warm = int(30.0 / dt)  # fill SUMO's map first (insertions queue at the fringe) and let ours settle
    try:
        src.start()
        src.fast_forward(warm * dt, top)
        for _ in range(warm):
            ours.step(dt)
        per_slice = max(int(seconds / dt / slices), 1)
        for k in range(slices * 2):
            side = ("sumo", "ours")[(k + (k // 2)) % 2]  # alternating, each side first in turn
            for _ in range(per_slice):
                if side == "sumo":
                    top()
                    t = time.process_time()
                    libsumo.simulationStep(libsumo.simulation.getTime() + dt)
                    spent["sumo"] += time.process_time() - t
                    vsec["sumo"] += libsumo.vehicle.getIDCount() * dt
                    t = time.process_time()
                    src._read()
                    spent["sumo_read"] += time.process_time() - t
                else:
                    t = time.process_time()
                    ours.step(dt)
                    spent["ours"] += time.process_time() - t
                    vsec["ours"] += len(ours.world.agents) * dt
    finally:
        src.close()
    split = _our_split(ours, dt, per_slice)
    us = {k: 1e6 * spent[k] / vsec[k] if vsec[k] else None for k in ("sumo", "ours")}
    return {"cars": cars, "simulated_s_each": slices * per_slice * dt, "step_s": dt,
            "mean_cars": {k: vsec[k] / (slices * per_slice * dt) for k in vsec},
            "cpu_us_per_vehicle_s": us, "sumo_read_us_per_vehicle_s": 1e6 * spent["sumo_read"] / vsec["sumo"]
            if vsec["sumo"] else None,
            "ours_vs_sumo": us["ours"] / us["sumo"] if us["sumo"] and us["ours"] else None,
            "ours_split_share": split}


def _our_split(ours, dt: float, ticks: int) -> dict:
    """Where our world's step goes, as shares of its time over `ticks` more steps: the body index (every body
    on its edges; the array world builds it inside the leader search, so there it counts in `decide_leader`),
    each entity's decision (leader search, junction requests, IDM), the moves and timeouts after
    it, and the population's replacements (`decide_leader` and `decide_crossing` are parts of `decide`). Instance
    wrappers with a clock each (they add a little to each part)."""
    w = ours.world
    acc = dict.fromkeys(("body_index", "decide", "after_move", "population", "decide_leader", "decide_crossing"),
                        0.0)

    def wrap(obj, name: str, key: str) -> None:
        f = getattr(obj, name)

        def timed(*a, **k):
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                acc[key] += time.process_time() - t

        setattr(obj, name, timed)

    # the array world decides everyone in `_decide_all` (the leaders found for all vehicles at once by
    # `world.leaders`, which also indexes the bodies); the scalar one (`World(vectorised=False)`) indexes the
    # bodies in `_body_index`, then `_decide` per entity with its `_leader`: each part timed where it runs
    from sims.engine import world as world_module

    original_leaders = world_module.leaders
    wrap(w, "_body_index", "body_index")
    wrap(w, "_decide", "decide")
    wrap(w, "_decide_all", "decide")  # not nested with `_decide`: one or the other runs
    wrap(w, "_after_move", "after_move")
    wrap(ours.population, "step", "population")
    wrap(w, "_leader", "decide_leader")  # inside `decide`
    wrap(world_module, "leaders", "decide_leader")  # inside `decide` (`_decide_all`)
    wrap(w, "_crossing", "decide_crossing")  # inside `decide`
    t0 = time.process_time()
    try:
        for _ in range(ticks):
            ours.step(dt)
    finally:
        total = time.process_time() - t0
        for obj, name in ((w, "_body_index"), (w, "_decide"), (w, "_decide_all"), (w, "_after_move"),
                          (ours.population, "step"), (w, "_leader"), (w, "_crossing")):
            delattr(obj, name)
        world_module.leaders = original_leaders
    out = {k: v / total for k, v in acc.items()} if total > 0 else dict(acc)
    top = ("body_index", "decide", "after_move", "population")
    out["rest"] = 1.0 - sum(out[k] for k in top) if total > 0 else None
    return out


def _drive(sim, seconds: float, warmup: float) -> dict:
    """Run `sim` against the in-process switchboard core; figures after `warmup` simulated seconds."""
    from sims.engine.local import LocalSwitch

    sw = LocalSwitch(sim)
    sw.exchange(*sim.start())
    ent_s = 0.0
    pub0 = None
    n = int(round((seconds + warmup) / sim.dt))
    for k in range(n):
        sw.exchange(*sim.step())
        sim.maybe_sample(sw.eid_to_agent())
        if k * sim.dt >= warmup:
            if pub0 is None:
                pub0 = sim.fleet.counters["published"]
            ent_s += len(sim.world.agents) * sim.dt
    rep = sim.report()
    tv = rep["truth_vs_viewer"]["all"]
    published = sim.fleet.counters["published"] - (pub0 or 0)
    return {"entities": rep["entities"], "mean_entities": ent_s / seconds if seconds else 0.0,
            "updates_per_entity_min": published / (ent_s / 60.0) if ent_s else None,
            "error_p95_m": tv["error_p95_m"], "error_mean_m": tv["error_mean_m"],
            "missed_visibility": tv["missed_visibility"], "stale_ghost_fraction": tv["stale_ghost_fraction"],
            "report": rep}


def end_to_end(topo, sumocfg: Path, seconds: float, viewers: int, warmup: float, schedule=None) -> dict:
    """The honest clients and viewers on SUMO's motion and on ours (module docstring); SUMO's run first, ours
    with its mix of cars and pedestrians (SUMO's buses and trams against our schedule's)."""
    from sims.engine.sim import Sim, SimConfig
    from sims.sumo.source import SumoSource

    settle = 4.0  # the start's burst of first publishes is not the steady state
    cfg = SimConfig(entities=0, viewers=viewers, seed=7, transit=False, measure_after=settle)
    src = SumoSource(topo, sumocfg, start=cfg.start, step=1.0 / cfg.tick_hz, seed=7, warmup=warmup)
    try:
        sumo = _drive(Sim(topo, cfg, source=src), seconds, settle)
        sumo["off_network"] = src.world.off_network()
    finally:
        src.close()
    mix = sumo["entities"]
    cars, peds = mix.get("car", 0), mix.get("pedestrian", 0)
    ocfg = SimConfig(entities=cars + peds, car_share=cars / max(cars + peds, 1), viewers=viewers, seed=7,
                     transit=schedule is not None, measure_after=settle)
    ours = _drive(Sim(topo, ocfg, schedule), seconds, settle)
    for r in (sumo, ours):
        r.pop("report")
    return {"sumo": sumo, "ours": ours, "simulated_s": seconds, "warmup_s": warmup, "viewers": viewers}


def realtime(topo, artifact: Path, folder: Path, entities: int, seconds: float, viewers: int,
             car_share: float = 0.3) -> dict:
    """One real-time trial: `entities` SUMO cars and walkers (topped up) driving honest clients over loopback
    with the server in this process; pass when tick lateness p99 stays under a tick and no tick falls behind.
    Where the wall time went: SUMO's step, reading positions, and the rest of the ticks."""
    import trio

    from sims.engine.sim import Sim, SimConfig
    from sims.shell import Shell, ShellConfig
    from sims.sumo.source import SumoSource

    warm_ticks = 6
    cfg = SimConfig(entities=0, viewers=viewers, seed=11, transit=False, measure_share=0.25)
    cars = round(entities * car_share)
    src = SumoSource(topo, _cfg_without_demand(folder, 1e6), start=cfg.start, step=1.0 / cfg.tick_hz, seed=11)
    top = TopUp(folder, cars, entities - cars, seed=11)
    orig = src.step

    def step(dt: float):
        top()
        return orig(dt)

    src.step = step  # type: ignore[method-assign]

    try:
        src.fast_forward(20.0, top)  # fill the map before the clock starts (insertions queue at the fringe)
        sim = Sim(topo, cfg, source=src)
        shell = Shell(sim, ShellConfig(duration=seconds + warm_ticks * sim.dt, speed=1.0, summary_every=1e9,
                                       artifact=artifact, keys=False, warmup_ticks=warm_ticks), lambda m: None)
        t0, c0 = time.perf_counter(), time.process_time()
        rep = trio.run(shell.run)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        src.close()
    rt = rep["realtime"]
    ticks = max(rt["ticks"], 1)
    ok = rt["tick_lateness_p99_ms"] < 1000.0 * sim.dt and rt["ticks_behind"] == 0
    m = rep["mobility"]
    return {"entities": entities, "on_map": sum(rep["entities"].values()), "by_type": rep["entities"],
            "viewers": viewers, "tick_lateness_p99_ms": rt["tick_lateness_p99_ms"], "ticks_behind": rt["ticks_behind"],
            "ok": ok, "wall_s": wall, "cpu_s": cpu, "cpu_share_of_wall": cpu / wall,
            "ms_per_tick": {"cpu_all": 1000 * cpu / ticks, "sumo_step": 1000 * m["sumo_step_s"] / ticks,
                            "sumo_read": 1000 * m["read_s"] / ticks,
                            "rest": 1000 * (cpu - m["sumo_step_s"] - m["read_s"]) / ticks},
            "sumo_step_share": m["sumo_step_s"] / cpu if cpu else None, "off_network": m["off_network"]}


def bench_rows(topo, artifact: Path, schedule, quick: bool, progress) -> dict:
    """The SUMO rows of `entitynet bench sim`: step cost per vehicle-second (SUMO against ours, same cars, same
    map), the end-to-end figures on SUMO's motion and ours, the real-time ladder of SUMO entities (from 250,
    doubling, until a trial fails; one small trial with `--quick`) and where a tick goes with SUMO and the
    clients alone at 10,000 entities (`client_split`; 500 with `--quick`).
    Without the [sumo] extra: a note saying why, and no figures."""
    from sims.sumo import SumoError, missing
    from sims.sumo.scenario import bundled_scenario

    why = missing()
    if why:
        return {"skipped": why}
    try:
        cfg = bundled_scenario(topo, say=progress)
    except SumoError as exc:
        return {"skipped": f"the bundled SUMO scenario could not be made: {exc}"}
    folder = cfg.parent
    seconds = 10.0 if quick else 60.0
    out: dict = {"scenario": str(cfg)}
    out["step_cost"] = []
    for cars in ((100,) if quick else (200, 1000)):
        progress(f"SUMO against our world: step time per vehicle-second, {cars} cars on the map")
        out["step_cost"].append(step_cost(topo, folder, cars, seconds))
    progress("SUMO against our world: honest clients and viewers on each one's motion")
    out["end_to_end"] = end_to_end(topo, cfg, 15.0 if quick else 60.0, 8 if quick else 24,
                                   60.0 if quick else 300.0, schedule)
    trials = []
    n = 200 if quick else 250
    while n <= (200 if quick else 16000):  # viewers n / 10, as our world's ladder
        trial = realtime(topo, artifact, folder, n, 6.0 if quick else 20.0, max(10, n // 10))
        trials.append(trial)
        progress(f"  SUMO real time, {n} entities: lateness p99 {trial['tick_lateness_p99_ms']:.0f} ms, behind "
                 f"{trial['ticks_behind']}, SUMO step {100 * trial['sumo_step_share']:.0f}% of the CPU time -> "
                 f"{'ok' if trial['ok'] else 'not real time'}")
        if not trial["ok"]:
            break
        n *= 2
    out["realtime_trials"] = trials
    out["entities_realtime_max"] = max((t["entities"] for t in trials if t["ok"]), default=0)
    big = 500 if quick else 10000
    progress(f"SUMO and the honest clients alone: where a tick goes at {big} entities")
    out["client_split"] = client_split(topo, folder, big, 5.0 if quick else 20.0)
    return out


def client_split(topo, folder: Path, entities: int, seconds: float, car_share: float = 0.3) -> dict:
    """Where a tick goes at `entities` SUMO cars and walkers (topped up) with only the honest clients behind
    them (no server, no viewers): CPU ms per 0.5 s tick of SUMO's step, reading positions, and the clients'
    fleet step (GPS fixes, client cores, messages). Their sum against the tick says whether SUMO and our clients
    alone keep real time at that size on one core."""
    import libsumo

    from sims.engine.sim import Sim, SimConfig
    from sims.sumo.source import SumoSource

    cfg = SimConfig(entities=0, viewers=0, seed=11, transit=False)
    cars = round(entities * car_share)
    src = SumoSource(topo, _cfg_without_demand(folder, 1e6), start=cfg.start, step=1.0 / cfg.tick_hz, seed=11)
    top = TopUp(folder, cars, entities - cars, seed=11)
    spent = {"sumo_step": 0.0, "sumo_read": 0.0, "clients": 0.0}
    on_map = []
    try:
        src.fast_forward(30.0, top)  # fill the map (insertions queue at the fringe)
        sim = Sim(topo, cfg, source=src)
        sim.start()
        for _ in range(int(10 / sim.dt)):  # the first fixes' placements (shapely) are the start, not the steady state
            top()
            sim.step()
        n = int(seconds / sim.dt)
        for _ in range(n):
            top()
            t = time.process_time()
            libsumo.simulationStep(libsumo.simulation.getTime() + sim.dt)
            t1 = time.process_time()
            for e in src._read():
                sim.fleet.add(e)
            t2 = time.process_time()
            sim.fleet.step(src.world.now)
            t3 = time.process_time()
            spent["sumo_step"] += t1 - t
            spent["sumo_read"] += t2 - t1
            spent["clients"] += t3 - t2
            on_map.append(len(src.world.agents))
    finally:
        src.close()
    ms = {k: 1000 * v / n for k, v in spent.items()}
    total = sum(ms.values())
    return {"entities": entities, "mean_on_map": sum(on_map) / len(on_map), "by_type": dict(src.world.by_type()),
            "ms_per_tick": ms, "total_ms_per_tick": total, "tick_ms": 1000 * sim.dt,
            "realtime_on_one_core": total < 1000 * sim.dt}


def main(argv: list[str] | None = None) -> int:
    """`python -m sims.sumo.compare {step-cost,realtime,split} N [SECONDS] [--repeat K]`: one figure of this
    module on the bundled map and its cached SUMO scenario, as JSON lines (for repeated runs and sizes the bench
    does not run)."""
    import argparse
    import json

    from entitynet.topology_cache import bundled_topology
    from sims.sumo.scenario import bundled_scenario

    p = argparse.ArgumentParser(prog="python -m sims.sumo.compare")
    p.add_argument("what", choices=("step-cost", "realtime", "split"))
    p.add_argument("n", type=int, help="cars (step-cost) or entities (realtime, split)")
    p.add_argument("seconds", type=float, nargs="?", default=60.0)
    p.add_argument("--repeat", type=int, default=1)
    a = p.parse_args(argv)
    if not (0 < a.n <= 100000 and 0 < a.seconds <= 3600 and 0 < a.repeat <= 20):
        p.error("need 0 < N <= 100000, 0 < SECONDS <= 3600, 0 < --repeat <= 20")
    topo, artifact = bundled_topology()
    folder = bundled_scenario(topo).parent
    for _ in range(a.repeat):
        if a.what == "step-cost":
            r = step_cost(topo, folder, a.n, a.seconds)
        elif a.what == "realtime":
            r = realtime(topo, artifact, folder, a.n, a.seconds, max(10, a.n // 10))
        else:
            r = client_split(topo, folder, a.n, a.seconds)
        print(json.dumps(r, default=float), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
