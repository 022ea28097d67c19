"""The dr benchmark's datasets: the truth of each entity, sampled every SAMPLE seconds.

Why apart from the runner: the datasets are the mobility model applied to real data (HSL GTFS shapes for trams
and buses, walkways and pedestrian areas of the map, the real Munich car trace), and the coming simulation
engine and other benchmarks draw the same kinds of truth. Everything is deterministic for a given
`random.Random`; the draws happen in a fixed order (vehicles, then pedestrians), which the bench's table
depends on.
"""

from __future__ import annotations

import json
import os
import random
from datetime import datetime
from pathlib import Path as FsPath

import numpy as np

from entitynet.client.network import netview
from entitynet.client.path import Path
from sims.mobility import KINDS, area_walk, profile_for, random_walk, vehicle_halts
from topology.raw import PEDESTRIAN, TRAM, VEHICLE

#: ../shared/data beside the clone (as CI has it); ENTITYNET_SHARED overrides it (a worktree elsewhere), as for the
#: proxy bench and the tests
SHARED = FsPath(os.environ.get("ENTITYNET_SHARED") or FsPath(__file__).resolve().parents[3] / "shared") / "data"
SAMPLE = 0.5  # truth (and receiver error) sampling step (s)
MAIN_PEDESTRIANS = 32  # the full bench's walkers (a quarter of them in the largest pedestrian areas)


class Entity:
    """One entity's truth sampled every SAMPLE seconds: xy, and the cells under the body (None when unknown).
    Sampled once and replayed for every model and threshold, so that their differences are the models'."""

    def __init__(self, name, etype, t, xy, cells, route=None, edge=None, edge_ok=None, stops=()):
        self.name, self.etype, self.t, self.xy, self.cells = name, etype, t, xy, cells
        self.route = route
        self.stops = stops  # (edge, offset) of the route's stops
        self.edge = edge  # true edge at each sample (network entities), for the wrong-edge rate
        self.edge_ok = edge_ok  # whether the sample is unambiguous (>= 10 m from the edge's ends)
        self.path = None  # path-driven entities: the path, the front's coordinate per sample, the body length
        self.s: np.ndarray | None = None
        self.length = 0.0

    @property
    def minutes(self) -> float:
        """Duration of the truth in minutes (the denominator of updates per entity-minute)."""
        return (self.t[-1] - self.t[0]) / 60.0


def _sample_path(path: Path, prof, length: float, name, etype, route) -> Entity:
    t = np.arange(0.0, prof.t[-1], SAMPLE)
    s = np.interp(t, prof.t, prof.s)
    xy = np.array([path.xy(v) for v in s])
    cells = [frozenset(path.cells_between(v - length, v)) for v in s]
    edges, ok = [], []
    net = path.net
    for v in s:
        k = path.index(v)
        d = v - path.cum[k]
        edges.append(path.edges[k][0])
        ok.append(10.0 <= d <= net.edge_len[path.edges[k][0]] - 10.0)
    ent = Entity(name, etype, t, xy, cells, route, np.array(edges), np.array(ok))
    ent.path, ent.s, ent.length = path, s, length  # the true front's path coordinate (dr_causes: front or aft)
    return ent


def _project_on_path(path: Path, pts: list[tuple[float, float]], tol: float = 25.0) -> list[float]:
    ss = np.arange(0.0, path.length, 2.0)
    pxy = np.array([path.xy(v) for v in ss])
    out = []
    for x, y in pts:
        d = np.hypot(pxy[:, 0] - x, pxy[:, 1] - y)
        k = int(np.argmin(d))
        if d[k] <= tol:
            out.append(float(ss[k]))
    return sorted(out)


def vehicles(topo, n: int, rng: random.Random, progress) -> list[Entity]:
    """`n` trams and buses (half each, as far as the feed has them) along distinct GTFS shapes matched onto
    the map, moved by their kind's speed profile with dwells at the shape's stops and red signals at road
    junctions: realistic transit truth, with the route and stops the network model may use."""
    from topology.gtfs import match_shapes, read_feed

    zp = SHARED / "hsl-gtfs-2022-02.zip"
    feed = read_feed(zp)
    shapes = match_shapes(feed, topo, min_length=600.0)
    net = netview(topo)
    seen, picked = set(), []
    for m in shapes:
        key = tuple(m.edges)
        if key in seen:
            continue
        seen.add(key)
        picked.append(m)
    rng.shuffle(picked)
    trams = [m for m in picked if m.mode == "tram"]
    buses = [m for m in picked if m.mode == "bus"]
    chosen = trams[: (n + 1) // 2] + buses[: n // 2]
    progress(f"dr: {len(shapes)} GTFS shapes matched onto the map, {len(picked)} distinct; using {len(chosen)}")
    out = []
    for m in chosen:
        try:
            path = Path(net, m.edges)
        except ValueError:
            continue
        stops = _project_on_path(path, [(x, y) for _n, x, y in m.stop_xy])
        # signals stand at road junctions: nodes where at least three vehicle or tram edges meet
        signals = [path.cum[k + 1] for k, de in enumerate(path.edges[:-1])
                   if sum(1 for e in net.node_edges[net.end_node(de)] if net.edge_net[e] & (VEHICLE | TRAM)) >= 3]
        k = KINDS["tram" if m.mode == "tram" else "bus"]
        halts = vehicle_halts(stops, signals, rng, k.halts)
        prof = profile_for(k, path.length, halts, rng)
        ent = _sample_path(path, prof, k.length, f"{m.mode} {m.ref} {m.shape_id}", k.name, m.edges)
        ent.stops = [path.locate(sp) for sp in stops]
        out.append(ent)
    return out


def pedestrians(topo, n: int, rng: random.Random, *, held_out: str = "") -> list[Entity]:
    """`n` walkers, a quarter of them inside pedestrian areas: the largest areas for the main set; with
    `held_out` (a name prefix, which also gives the walkers their own GPS noise) areas drawn at random from the
    next largest ones, none of which the main set walks in."""
    net = netview(topo)
    walker = KINDS["pedestrian"]
    walk_edges = [e for e in range(topo.n_edges) if topo.edge_networks[e] & PEDESTRIAN and net.edge_len[e] > 20]
    out = []
    n_area = max(1, n // 4)
    while len(out) < n - n_area:
        e = walk_edges[rng.randrange(len(walk_edges))]
        edges = random_walk(net, (e, rng.choice((1, -1))), PEDESTRIAN, 900.0, rng)
        path = Path(net, edges)
        if path.length < 300.0:
            continue
        halts = [(rng.uniform(20.0, path.length - 20.0), rng.uniform(5.0, 25.0))
                 for _ in range(int(path.length / 250.0))]
        prof = profile_for(walker, path.length, halts, rng)
        out.append(_sample_path(path, prof, walker.length, f"{held_out}walker {len(out)}", walker.name, None))
    areas = [a for a in range(len(topo.area_node)) if topo.area_networks[a] & PEDESTRIAN]
    sizes = sorted(((np.ptp(topo.area_polygons.exterior(a), axis=0).prod(), a) for a in areas), reverse=True)
    largest = [a for _size, a in sizes]
    main_areas = max(1, MAIN_PEDESTRIANS // 4)
    if held_out:
        pool = largest[main_areas:main_areas + 24]
        chosen = rng.sample(pool, min(n_area, len(pool)))
    else:
        chosen = largest[:n_area]
    for a in chosen:
        ring = topo.area_polygons.exterior(a)
        ts, xy = area_walk(ring, rng, 420.0)
        t = np.arange(0.0, ts[-1], SAMPLE)
        sxy = np.column_stack([np.interp(t, ts, xy[:, 0]), np.interp(t, ts, xy[:, 1])])
        cell = int(topo.area_cell[a])
        out.append(Entity(f"{held_out}area walker {a}", "pedestrian", t, sxy, [frozenset((cell,))] * len(t)))
    return out


def car_trace() -> Entity | None:
    """The real 1 Hz Munich car trace (None when ../shared is absent): a truth no model of ours generated,
    so the world-frame models are also judged on real driving."""
    from topology.projection import LocalProjection, utm_crs_for

    fp = SHARED / "traces" / "munich-car-1hz.json"
    if not fp.exists():
        return None
    rows = json.loads(fp.read_text())
    lonlat = np.array([[float(v) for v in r["point"][6:-1].split()] for r in rows])
    ts = np.array([datetime.strptime(r["time"], "%Y-%m-%d %H:%M:%S%z").timestamp() for r in rows])
    order = np.argsort(ts, kind="stable")
    lonlat, ts = lonlat[order], ts[order]
    keep = np.concatenate([[True], np.diff(ts) > 0])
    lonlat, ts = lonlat[keep], ts[keep] - ts[keep][0]
    c = lonlat.mean(axis=0)
    proj = LocalProjection(utm_crs_for(c[0], c[1]), (0.0, 0.0))
    xy = proj.to_local(lonlat[:, 0], lonlat[:, 1])
    xy -= np.round(xy[0])
    return Entity("munich car", "car", ts, xy, None)
