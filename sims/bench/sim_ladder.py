"""`bench sim`'s real-time ladder: the largest population that keeps real time, found by doubling and then
bisecting, several ladders (the server in this process, in a child, with counted viewers) alternating.

Why bisect: doubling alone (100, 200, ... 1,600, 3,200) says only that the limit lies between the last size kept
and the first lost, a factor of two apart; a few more trials between them say where. Bounded: at most
`bisect_steps` trials per ladder after its first loss, none finer than `resolution` (entities, or an eighth of
the size kept), and no trial started after `budget_s` wall seconds. The ladders alternate trial by trial so that
each sees the same load on a shared machine. The plan is sans-IO (`run_ladders` takes the trial as a function);
`realtime_trial` is one trial over loopback sockets.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

#: ticks of each real-time trial left out of its lateness (the start: every entity's first publish, the
#: viewers' first subscriptions and the server's first snapshots arrive together)
WARMUP_TICKS = 6
#: the real-time trials measure truth against a quarter of the (measured) viewers at each sample, in turn, as
#: `entitynet sim` does by default (`--measure-share`): the full measure is a burst that made ticks late
RT_MEASURE_SHARE = 0.25

Trial = Callable[[int], dict[str, Any]]


def run_ladders(trials: dict[str, Trial], start: int = 100, top: int = 20000, bisect_steps: int = 3,
                resolution: int = 50, budget_s: float = float("inf"), progress=lambda m: None,
                clock: Callable[[], float] = time.monotonic) -> dict[str, dict[str, Any]]:
    """Each ladder's trials, the largest size kept (`max`, 0: none) and the smallest lost above it (`lost`,
    None: none up to `top`). Sizes double from `start` until a trial is lost, then bisect between the kept and
    the lost size (rounded to `resolution`), see the module docstring. `trials[name](n)` runs one trial of n
    entities and returns a dict with `ok`."""
    t0 = clock()
    state = {name: {"trials": [], "max": 0, "lost": None, "bisected": 0} for name in trials}

    def run(name: str, n: int) -> None:
        got = trials[name](n)
        s = state[name]
        s["trials"].append(got)
        if got["ok"]:
            s["max"] = max(s["max"], n)
        else:
            s["lost"] = n if s["lost"] is None else min(s["lost"], n)
        progress(f"  {n} entities, {name}: {'ok' if got['ok'] else 'not real time'}")

    n = start
    while n <= top and clock() - t0 < budget_s:
        open_ = [name for name, s in state.items() if s["lost"] is None]
        if not open_:
            break
        for name in open_:
            run(name, n)
        n *= 2
    while clock() - t0 < budget_s:
        mids = {name: _mid(s, resolution) for name, s in state.items() if s["bisected"] < bisect_steps}
        mids = {name: m for name, m in mids.items() if m is not None}
        if not mids:
            break
        for name, m in mids.items():
            state[name]["bisected"] += 1
            run(name, m)
    return state


def _mid(s: dict, resolution: int) -> int | None:
    """The next size between the kept and the lost one, or None when there is none to try (nothing kept or lost,
    or the two closer than `resolution` or an eighth of the size kept)."""
    lo, hi = s["max"], s["lost"]
    if hi is None or lo <= 0 or hi - lo <= max(resolution, lo // 8):
        return None
    mid = round((lo + hi) / 2 / resolution) * resolution
    return mid if lo < mid < hi else None


def realtime_trial(topo, artifact, schedule, n: int, viewers: int, seconds: float, server_process: bool = False,
                   measured: int | None = None, settle_gc: bool = True) -> dict[str, Any]:
    """One real-time run of `n` entities and `viewers` viewers over loopback sockets at speed 1, the server in
    this process or in a child; `measured`: only that many viewers measured, the others counted
    (`SimConfig.measured_viewers`). Real time is kept when tick lateness p99 is under one tick and no tick is
    more than one tick behind. Also the CPU seconds of this process and the child's, and missed visibility.
    `settle_gc`: the garbage collector settled after the start as `entitynet sim` settles it in its own process
    (`ShellConfig.settle_gc`, sims/engine/collector.py; given back when the trial ends). Why by default: the
    trial measures what the command keeps in real time, and without it full collections of the run's growing
    heap (140-260 ms each at 4,000 entities, every 5-10 s) were the ticks that fell behind."""
    import trio

    from sims.engine.sim import Sim, SimConfig
    from sims.server_child import ServerChild
    from sims.shell import Shell, ShellConfig

    sim = Sim(topo, SimConfig(entities=n, viewers=viewers, seed=11, measure_share=RT_MEASURE_SHARE,
                              measured_viewers=measured), schedule)
    shell = Shell(sim, ShellConfig(duration=seconds + WARMUP_TICKS * sim.dt, speed=1.0, summary_every=1e9,
                                   artifact=artifact, keys=False, warmup_ticks=WARMUP_TICKS, settle_gc=settle_gc),
                  lambda m: None)
    cpu0, server_cpu = time.process_time(), None
    if server_process:
        with ServerChild(artifact) as child:
            shell.config.server = child.address
            rep = trio.run(child.run_shell, shell)
            server_cpu = child.cpu_seconds()
    else:
        rep = trio.run(shell.run)
    sim_cpu = time.process_time() - cpu0
    rt = rep["realtime"]
    ok = rt["tick_lateness_p99_ms"] < 1000.0 * sim.dt and rt["ticks_behind"] == 0
    tv = rep["truth_vs_viewer"]
    return {"entities": n, "on_map": sum(rep["entities"].values()), "viewers": viewers,
            "measured_viewers": tv.get("measured_viewers", viewers), "counted_viewers": tv.get("counted_viewers", 0),
            "server": "a child process" if server_process else "in this process",
            "measure_share": RT_MEASURE_SHARE, "tick_lateness_p99_ms": rt["tick_lateness_p99_ms"],
            "ticks_behind": rt["ticks_behind"], "ok": ok, "sim_process_cpu_s": sim_cpu,
            "server_process_cpu_s": server_cpu, "deliveries": rep["viewers"]["deliveries"],
            "missed_visibility": (tv.get("all") or {}).get("missed_visibility"),
            "viewer_error_p95_m": (tv.get("all") or {}).get("error_p95_m")}
