"""Why PVS viewers get only so many fewer deliveries than 500 m radius viewers: an instrumented run (issue 11).

Why a separate, small run: the benchmark (`sims.bench.sim_bench`) gives one ratio; this splits every UPDATE a
street-level viewer receives by the reason it was delivered, so the causes are measured rather than guessed.
The same seeded population is run against the in-process switchboard core twice (subscribing by PVS and by
radius) and, for every delivery to a street viewer, it records:

- `live` (the entity published it this tick) or `snapshot` (sent because the viewer subscribed a cell the
  entity already occupied) and, for snapshots, whether the viewer had this very update before (`resent`:
  it was dropped by a LEAVE when the cell was unsubscribed and is now sent again);
- `in_view`: the entity's true body is in a subscribed cell at delivery; else the delivery is only for
  cells of its published occupation ahead of it (look-ahead, margin, lateral cells) and
  `ever_in_view` says whether it reached the viewer's cells before the update's validity ran out;
- the entity's type and how many cells its update lists;
- duplicates (the same entity and seq delivered twice to one viewer).

Per viewer it counts SUBSCRIBE messages and the cells added and removed. Deterministic for a seed.
`python -m sims.bench.sim_causes [--entities N] [--viewers V] [--seconds S] [--out FILE.json]`.
"""

from __future__ import annotations

import argparse
from collections import Counter
from typing import Any

from entitynet import protocol as P
from sims.bench.report import print_json
from sims.engine.local import LocalSwitch
from sims.engine.sim import Sim, SimConfig


class _Recorder:
    """Wraps a `Sim`'s delivery and fleet to classify every UPDATE a street viewer receives."""

    def __init__(self, sim: Sim, sw: LocalSwitch):
        self.sim, self.sw = sim, sw
        self.published_now: set[tuple[int, int]] = set()  # (agent, seq) published this tick
        self.seen: list[set[tuple[int, int]]] = [set() for _ in sim.viewers]
        self.rows: list[dict[str, Any]] = []  # one per street delivery, resolved `ever_in_view` later
        self.pending: list[tuple[int, int, float, int]] = []  # (row, viewer, until, agent): not yet in view
        self.subs = [Counter() for _ in sim.viewers]
        self.publishes = Counter()  # by type
        self.entity_s = Counter()  # entity-seconds by type
        self.disc_inside: list[float] = []  # share of a 500 m disc round a street camera that lies on the map
        self._map = _map_box(sim.topo)
        orig_deliver = sim.deliver

        def deliver(i: int, msg: P.Message, size: int = 0) -> None:
            if isinstance(msg, P.Update) and not sim.viewers[i].high:
                self._update(i, msg)
            orig_deliver(i, msg, size)

        sim.deliver = deliver  # type: ignore[method-assign]

    def _agent(self, eid: int) -> int:
        e = self.sw.sb.entities.get(eid)
        return e.local if e is not None else -1

    def _update(self, i: int, msg: P.Update) -> None:
        sim = self.sim
        aid = self._agent(msg.entity)
        a = sim.world.agents.get(aid)
        v = sim.viewers[i]
        key = (aid, msg.seq)
        live = key in self.published_now
        in_view = a is not None and not v.subs.cells.isdisjoint(a.cells())
        row = {"viewer": i, "type": a.name if a is not None else "gone", "live": live,
               "resent": (not live) and key in self.seen[i], "dup": live and key in self.seen[i],
               "in_view": in_view, "ever_in_view": in_view, "cells": len(msg.cells)}
        self.seen[i].add(key)
        if not in_view and a is not None:
            self.pending.append((len(self.rows), i, sim.now + msg.validity_ms / 1000.0, aid))
        self.rows.append(row)

    def before_exchange(self, pubs: list[list[P.Message]], subs: list[list[P.Subscribe]]) -> None:
        """Note this tick's publishes and subscription changes before the switch forwards them."""
        self.published_now = {(m.entity, m.seq) for box in pubs for m in box if isinstance(m, P.Publish)}
        for m in (m for box in pubs for m in box if isinstance(m, P.Publish)):
            a = self.sim.world.agents.get(m.entity)
            self.publishes[a.name if a is not None else "gone"] += 1
        for i, msgs in enumerate(subs):
            for m in msgs:
                self.subs[i]["messages"] += 1
                self.subs[i]["added"] += len(m.added)
                self.subs[i]["removed"] += len(m.removed)

    def after_exchange(self, dt: float) -> None:
        """Resolve deliveries made for cells ahead: did the entity reach the viewer's cells in time?"""
        sim = self.sim
        for a in sim.world.agents.values():
            self.entity_s[a.name] += dt
        if sim.ticks % 4 == 0:
            for v in sim.viewers:
                if not v.high:
                    self.disc_inside.append(_disc_share(self._map, *v.traj.position(), sim.config.radius))
        keep = []
        for r, i, until, aid in self.pending:
            a = sim.world.agents.get(aid)
            if a is None or sim.now > until:
                continue
            if not sim.viewers[i].subs.cells.isdisjoint(a.cells()):
                self.rows[r]["ever_in_view"] = True
                continue
            keep.append((r, i, until, aid))
        self.pending = keep


def _map_box(topo):
    import shapely

    return shapely.box(*topo.meta["bounds"])


def _disc_share(box, x: float, y: float, r: float) -> float:
    """The share of the disc of radius r round (x, y) inside the map's bounding box: how much a radius set
    is clipped by the map's edge (an unbounded city would fill the rest with more cells and entities)."""
    import shapely

    disc = shapely.Point(x, y).buffer(r, 32)
    return float(shapely.intersection(disc, box).area / disc.area)


def instrumented_run(topo, schedule, cfg: SimConfig, seconds: float) -> dict[str, Any]:
    """One run with every street delivery classified; the breakdown (per street viewer-second)."""
    sim = Sim(topo, cfg, schedule)
    sw = LocalSwitch(sim)
    rec = _Recorder(sim, sw)
    pubs, subs = sim.start()
    rec.before_exchange(pubs, subs)
    sw.exchange(pubs, subs)
    n = int(round(seconds * cfg.tick_hz))
    for _ in range(n):
        pubs, subs = sim.step()
        rec.before_exchange(pubs, subs)
        sw.exchange(pubs, subs)
        rec.after_exchange(sim.dt)
        sim.maybe_sample(sw.eid_to_agent())
    street = [i for i, v in enumerate(sim.viewers) if not v.high]
    vs = max(len(street) * seconds, 1e-9)
    rows = rec.rows
    by = Counter()
    by_type = Counter()
    not_in_view_by_type = Counter()  # (type, "then" / "never")
    cells_hist = Counter()
    for r in rows:
        by["all"] += 1
        by["live" if r["live"] else "snapshot"] += 1
        by["snapshot_resent"] += r["resent"]
        by["duplicate"] += r["dup"]
        if r["in_view"]:
            by["in_view"] += 1
        elif r["ever_in_view"]:
            by["ahead_then_in_view"] += 1
            not_in_view_by_type[r["type"], "then"] += 1
        else:
            by["ahead_never_in_view"] += 1
            not_in_view_by_type[r["type"], "never"] += 1
        by_type[r["type"]] += 1
        cells_hist["1" if r["cells"] == 1 else "2-3" if r["cells"] <= 3 else "4-7" if r["cells"] <= 7
                   else "8-15" if r["cells"] <= 15 else "16+"] += 1
    tv = sim.measure.summary().get("street", {})
    ent_min = {k: s / 60.0 for k, s in rec.entity_s.items()}
    sub_tot = Counter()
    for i in street:
        sub_tot.update(rec.subs[i])
    return {
        "deliveries_per_viewer_s": by["all"] / vs,
        "by_reason_per_viewer_s": {k: by[k] / vs for k in ("live", "snapshot", "snapshot_resent", "duplicate",
                                                          "in_view", "ahead_then_in_view", "ahead_never_in_view")},
        "by_type_per_viewer_s": {k: c / vs for k, c in sorted(by_type.items())},
        # the deliveries for cells ahead of the body, by type: which types' look-ahead the viewers pay for
        "not_in_view_by_type_per_viewer_s": {f"{k}_{w}": c / vs for (k, w), c in sorted(not_in_view_by_type.items())},
        "publishes_per_entity_min": {k: rec.publishes[k] / ent_min[k] for k in sorted(ent_min) if ent_min[k]},
        "mean_entities_by_type": {k: s / seconds for k, s in sorted(rec.entity_s.items())},
        "cells_per_update": {k: cells_hist[k] / max(by["all"], 1) for k in ("1", "2-3", "4-7", "8-15", "16+")},
        "mean_cells_per_update": sum(r["cells"] for r in rows) / max(len(rows), 1),
        "subscribe_per_viewer_s": {k: sub_tot[k] / vs for k in ("messages", "added", "removed")},
        "mean_subscribed_cells": sum(len(sim.viewers[i].subs.cells) for i in street) / max(len(street), 1),
        "mean_visible_entities": tv.get("mean_visible_entities"),
        # in-view deliveries per entity-second in a subscribed cell: equal for PVS and radius when neither set
        # holds entities that publish more often (vehicles along streets) than the other
        "in_view_deliveries_per_visible_entity_s": by["in_view"] / vs / tv["mean_visible_entities"]
        if tv.get("mean_visible_entities") else None,
        "radius_disc_on_map": sum(rec.disc_inside) / max(len(rec.disc_inside), 1),
        "missed_visibility": tv.get("missed_visibility"),
        "stale_ghost_fraction": tv.get("stale_ghost_fraction"),
    }


def causes(topo, schedule, *, entities: int = 200, viewers: int = 16, seconds: float = 30.0,
           seed: int = 7) -> dict[str, Any]:
    """The PVS and radius runs side by side (street viewers only; every viewer is at street level here)."""
    base = dict(entities=entities, viewers=viewers, seed=seed, roof_share=0.0)
    out = {"params": {"entities": entities, "viewers": viewers, "seconds": seconds, "seed": seed}}
    for by in ("pvs", "radius"):
        out[by] = instrumented_run(topo, schedule, SimConfig(**base, subscribe=by), seconds)
    out["ratio"] = out["radius"]["deliveries_per_viewer_s"] / max(out["pvs"]["deliveries_per_viewer_s"], 1e-9)
    return out


def main(argv: list[str] | None = None) -> None:
    """Command line: run the breakdown on the bundled map and print (or write) the JSON."""
    from entitynet.topology_cache import bundled_topology, cache_dir
    from sims.engine.schedule import BUNDLED_FEED, load_schedule

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entities", type=int, default=200)
    ap.add_argument("--viewers", type=int, default=16)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    topo, _ = bundled_topology(with_pvs=True)
    schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir())
    rep = causes(topo, schedule, entities=a.entities, viewers=a.viewers, seconds=a.seconds, seed=a.seed)
    print_json(rep, a.out)


if __name__ == "__main__":
    main()
