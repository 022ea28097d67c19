"""Where `bench dr`'s occupation error comes from: every sample outside the published cells, classified (issue 20).

Why a separate run: the benchmark gives one fraction per dataset; this replays the same vehicles (the HSL GTFS
shapes over the map, 5 m GPS, 0.5 s samples, network model at 5 m) or walkers through the client core and, for
every sample whose true body is not inside the last published, unexpired occupation, records

- `where`: `expired` (the validity ran out before a new PUBLISH), `front` (the cell under the true front is not
  listed), `aft` (the cell under the aft is not), `mid` (a cell in between), or `body` (a walker's);
- the reason of the PUBLISH in force (drift, start, stop, expiry, jump, ...) and whether its model stood still;
- the entity's type, its true speed and acceleration, and how long after that PUBLISH it happened.

Consecutive bad samples of one entity are one *episode*; the largest episodes are listed, so that one
manoeuvre (a tram turning back at a terminal triangle, a ghost halting at a stop the vehicle passes) is seen
as one. Deterministic: the datasets and the noise are `bench dr`'s.
`python -m sims.bench.dr_causes [--topology FILE] [--dataset vehicles|pedestrians] [--lookahead M] [--out FILE]`.
"""

from __future__ import annotations

import argparse
import random
import zlib
from collections import Counter

import numpy as np

from entitynet.client.player import Player
from entitynet.protocol import Publish
from sims.bench.dr_data import MAIN_PEDESTRIANS, SAMPLE, SHARED, Entity, pedestrians, vehicles
from sims.bench.report import print_json
from sims.mobility import gps

SEED = 20260221  # bench dr's: the same entities in the same order


def _episodes(topo, ent: Entity, lookahead: float | None, counts: Counter) -> list[dict]:
    """Replay one entity (bench dr's fixes) and return its episodes outside the published cells; `counts` gets
    every bad sample by (where, reason, model still) and the totals."""
    kw = {} if lookahead is None else {"lookahead": lookahead}
    p = Player(topo, 1, ent.etype, model="network", route=ent.route, stops=ent.stops, threshold=5.0, **kw)
    step = int(round(1.0 / SAMPLE))
    fix_idx = np.arange(0, len(ent.t), step)
    fixes = gps(ent.xy[fix_idx], np.random.default_rng(zlib.crc32(ent.name.encode())))
    speed = np.hypot(*np.gradient(ent.xy, ent.t, axis=0).T)
    accel = np.gradient(speed, ent.t)
    last: Publish | None = None
    reason = ""
    episodes: list[dict] = []
    run: dict | None = None
    for i in range(len(ent.t)):
        now = float(ent.t[i])
        before = dict(p.stats)
        out = p.feed(float(fixes[i // step, 0]), float(fixes[i // step, 1]), now) if i % step == 0 else p.tick(now)
        for m in out:
            if isinstance(m, Publish):
                last = m
                reason = next((k for k in p.stats if p.stats[k] != before.get(k, 0)), "?")
        if last is None or ent.cells is None:
            continue
        counts["samples"] += 1
        truth = ent.cells[i]
        valid = now < p.pub_t + last.validity_ms / 1000.0
        if valid and truth.issubset(last.cells):
            run = None
            continue
        counts["bad"] += 1
        missing = truth - set(last.cells)
        if not valid:
            where = "expired"
        elif ent.path is None:  # a walker: no body, one place
            where = "body"
        else:
            s = float(ent.s[i])
            where = ("front" if ent.path.cell(s) in missing else
                     "aft" if ent.path.cell(max(s - ent.length, 0.0)) in missing else "mid")
        still = p.ghost is not None and p.ghost.xy_speed_at(now)[2] == 0.0
        counts[f"{where} / {reason} / {'standing' if still else 'moving'} model"] += 1
        if run is None:
            run = {"entity": ent.name, "type": ent.etype, "t": now, "where": where, "publish": reason,
                   "model_standing": still, "since_publish_s": round(now - p.pub_t, 1),
                   "validity_s": last.validity_ms / 1000.0, "true_speed": round(float(speed[i]), 2),
                   "true_accel": round(float(accel[i]), 2), "samples": 0}
            episodes.append(run)
        run["samples"] += 1
    return episodes


def causes(topo, dataset: str = "vehicles", lookahead: float | None = None, progress=print,
           walkers: int = MAIN_PEDESTRIANS) -> dict:
    """The breakdown for one of bench dr's datasets (its main draw; `walkers`: fewer of them, for a test)."""
    rng = random.Random(SEED)
    if dataset == "pedestrians":
        if (SHARED / "hsl-gtfs-2022-02.zip").exists():
            vehicles(topo, 36, rng, progress)  # drawn first in bench dr: the walkers' draw depends on it
        ents = pedestrians(topo, walkers, rng)
    else:
        ents = vehicles(topo, 36, rng, progress)
    counts: Counter = Counter()
    episodes: list[dict] = []
    by_type: Counter = Counter()
    bad_by_type: Counter = Counter()
    for ent in ents:
        n0, b0 = counts["samples"], counts["bad"]
        episodes += _episodes(topo, ent, lookahead, counts)
        by_type[ent.etype] += counts["samples"] - n0
        bad_by_type[ent.etype] += counts["bad"] - b0
    total, bad = counts.pop("samples", 0), counts.pop("bad", 0)
    episodes.sort(key=lambda e: -e["samples"])
    look = "default" if lookahead is None else lookahead
    return {"params": {"dataset": dataset, "entities": len(ents), "lookahead_m": look, "sample_s": SAMPLE},
            "occupation_error": bad / total if total else None,
            "occupation_error_by_type": {k: bad_by_type[k] / n for k, n in by_type.items() if n},
            "bad_samples_by_cause": dict(counts.most_common()),
            "episodes": len(episodes), "largest_episodes": episodes[:15]}


def main(argv: list[str] | None = None) -> None:
    """Command line: print (or write) the breakdown as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--topology", help="artifact (default: the bundled map, built and cached)")
    ap.add_argument("--dataset", choices=("vehicles", "pedestrians"), default="vehicles")
    ap.add_argument("--lookahead", type=float, help="a fixed look-ahead in metres (default: the client's rule)")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    if a.dataset == "vehicles" and not (SHARED / "hsl-gtfs-2022-02.zip").exists():
        raise SystemExit(f"entitynet: error: the vehicle set needs {SHARED / 'hsl-gtfs-2022-02.zip'}")
    if a.topology:
        from topology.artifact import load

        topo = load(a.topology)
    else:
        from entitynet.topology_cache import bundled_topology

        topo, _ = bundled_topology(with_pvs=False)
    rep = causes(topo, a.dataset, a.lookahead, progress=lambda msg: None)
    print_json(rep, a.out)


if __name__ == "__main__":
    main()
