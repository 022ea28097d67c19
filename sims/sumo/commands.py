"""`entitynet sumo scenario` and the SUMO source of `entitynet sim --mobility sumo`.

Registered through the entry-point group `entitynet.commands` (pyproject.toml), like every subcommand of `sims`.
Everything SUMO is imported inside the functions, so the CLI works (and says what is missing) without the
`[sumo]` extra.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from entitynet.cli import CommandError

#: seconds SUMO runs the bundled scenario alone before the run (it starts with empty streets)
BUNDLED_WARMUP_S = 300.0


def _bbox(text: str) -> tuple[float, float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected XMIN,YMIN,XMAX,YMAX in local metres, got {text!r}")
    return vals  # type: ignore[return-value]


def register(sub) -> None:
    """Add `entitynet sumo` (subcommand `scenario`) to the CLI's subparsers."""
    from entitynet.commands.options import SEED, bounded_float, positive_seconds, time_of_day

    p = sub.add_parser("sumo", help="Eclipse SUMO scenarios for `entitynet sim --mobility sumo` (needs the [sumo] "
                                    "extra)")
    subs = p.add_subparsers(dest="sumo_command", metavar="COMMAND")
    s = subs.add_parser("scenario", help="make a SUMO scenario from the bundled map (network in the topology's "
                                         "projection, random cars and walks, bus and tram lines at the bundled "
                                         "GTFS feed's frequencies), cached; prints its .sumocfg")
    s.add_argument("--cars-per-hour", type=bounded_float(0, 100_000), default=1800.0,
                   help="car trips inserted per hour (default 1800)")
    s.add_argument("--pedestrians-per-hour", type=bounded_float(0, 100_000), default=3600.0,
                   help="walks inserted per hour (default 3600)")
    s.add_argument("--duration", type=positive_seconds(7 * 86400.0), default=3600.0,
                   help="scenario length in seconds (default 3600)")
    s.add_argument("--start", type=time_of_day, default=8 * 3600.0, metavar="HH:MM",
                   help="service-day time the scenario's time 0 stands for (the GTFS window; default 08:00)")
    s.add_argument("--seed", type=SEED, default=1, help="random seed of the trips (default 1)")
    s.add_argument("--no-transit", action="store_true", help="no bus and tram lines")
    s.add_argument("--bbox", type=_bbox, metavar="XMIN,YMIN,XMAX,YMAX",
                   help="keep only the streets inside this box (local metres of the topology): a small scenario")
    s.add_argument("--out", metavar="DIR", help="write the scenario here (default: the user cache folder)")
    s.add_argument("--force", action="store_true", help="generate again even when cached")
    s.add_argument("--topology", metavar="FILE", help="the artifact whose projection the network takes (default: "
                                                      "the bundled map's)")
    s.set_defaults(func=run_scenario)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _load_topology(path: str | None, say):
    if path:
        from entitynet.commands.topology_cmd import load_artifact

        return load_artifact(path)
    from entitynet.topology_cache import bundled_topology

    return bundled_topology(say, with_pvs=True)[0]


def run_scenario(args: argparse.Namespace) -> int:
    """Generate (or find cached) the bundled map's SUMO scenario; its .sumocfg path on stdout."""
    from sims.sumo import SumoError, missing

    err = missing()
    if err:
        raise CommandError(err)
    from sims.sumo.scenario import ScenarioConfig, bundled_scenario, generate

    t0 = time.perf_counter()

    def say(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)

    try:
        config = ScenarioConfig(cars_per_hour=args.cars_per_hour, pedestrians_per_hour=args.pedestrians_per_hour,
                                duration=args.duration, start=args.start, seed=args.seed,
                                transit=not args.no_transit, bbox=args.bbox)
        topo = _load_topology(args.topology, say)
        if args.out:
            out = Path(args.out)
            if out.exists() and any(out.iterdir()) and not args.force:
                raise CommandError(f"{out} is not empty (give --force to write over it)")
            out.mkdir(parents=True, exist_ok=True)
            cfg = generate(topo, config, out, say)
        else:
            cfg = bundled_scenario(topo, config, say, force=args.force)
    except SumoError as exc:
        raise CommandError(str(exc)) from None
    print(cfg)
    return 0


def sumo_source(topo, sumocfg: str | None, config, say):
    """The SUMO source for `entitynet sim --mobility sumo`: the given scenario, or the bundled map's (generated
    once, cached); stepped at the simulation's tick. A clear CommandError for anything that cannot run."""
    from sims.sumo import SumoError, missing

    if sumocfg is not None and not Path(sumocfg).is_file():  # the user's own mistake first
        raise CommandError(f"{sumocfg}: no such SUMO configuration")
    err = missing()
    if err:
        raise CommandError(err)
    from sims.sumo.scenario import ScenarioConfig, bundled_scenario
    from sims.sumo.source import SumoSource

    try:
        warmup = 0.0
        if sumocfg is None:  # it starts empty: SUMO fills the streets alone first
            sumocfg = bundled_scenario(topo, ScenarioConfig(start=config.start, seed=config.seed), say)
            warmup = BUNDLED_WARMUP_S
            say(f"SUMO scenario of the bundled map: {sumocfg} (SUMO runs {warmup:g} s alone first)")
        return SumoSource(topo, sumocfg, start=config.start, step=1.0 / config.tick_hz, seed=config.seed,
                          warmup=warmup)
    except SumoError as exc:
        raise CommandError(str(exc)) from None
