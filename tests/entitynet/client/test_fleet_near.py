"""The fleet core's neighbourhood kernels against the scalar tracker's own code, bit for bit.

`s_of_rows` is `NetworkTracker._s_of` (edges that recur in the path, hints off the edge, no occurrence at all)
and `best_on_rows` is `NetworkTracker._best_on` (windows over paths that pass an edge twice, hairpins and
parallel ways): random paths and fixes around them, compared as floats with `==`. The twins in test_fleet.py
compare whole players' messages and state; these reach cases a walk meets rarely.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from entitynet.client import fleet_near as near_mod
from entitynet.client import netview
from entitynet.client.fleet_kernels import Geometry
from entitynet.client.fleet_near import NearTables, best_on_rows, s_of_rows
from entitynet.client.path import Path
from entitynet.client.placement import Fix, Placer
from entitynet.client.state import PATH_W
from entitynet.client.tracker import NetworkTracker
from tests.entitynet.client.test_fleet import _run
from tests.entitynet.client.test_player_replay import _walk_path
from tests.entitynet.client_fixtures import area_square, chain, cross, hairpin, parallel
from topology.raw import PEDESTRIAN, VEHICLE


def _paths(net, rng, n: int) -> list[Path]:
    """Walks, some doubled back on themselves so that edges recur within three edges and farther."""
    out = []
    for i in range(n):
        p = _walk_path(net, rng, VEHICLE | PEDESTRIAN)
        edges = list(p.edges)
        if i % 3 == 1:
            edges = edges + [(e, -d) for e, d in reversed(edges)]
        elif i % 3 == 2:
            edges = edges + [(e, -d) for e, d in reversed(edges)] + edges
        out.append(Path(net, edges[:PATH_W]))
    return out


def _rows(paths: list[Path]) -> tuple[np.ndarray, ...]:
    """The padded path arrays of the fleet's record: edges, directions, cumulative lengths (+inf), counts."""
    m = len(paths)
    pe, pd = np.zeros((m, PATH_W), np.int64), np.ones((m, PATH_W), np.int64)
    pc = np.full((m, PATH_W + 1), np.inf)
    pn = np.zeros(m, np.int64)
    for i, p in enumerate(paths):
        n = len(p.edges)
        pe[i, :n] = [e for e, _ in p.edges]
        pd[i, :n] = [d for _, d in p.edges]
        pc[i, : n + 1] = p.cum
        pn[i] = n
    return pe, pd, pc, pn


TOPOS = {"cross": cross(arm=100.0), "parallel": parallel(gap=12.0, length=300.0), "chain": chain(),
         "hairpin": hairpin()}


@pytest.mark.parametrize("name", sorted(TOPOS))
def test_s_of_rows_is_the_trackers_s_of(name):
    net = netview(TOPOS[name])
    rng = np.random.default_rng(3)
    paths = _paths(net, rng, 60)
    pe, pd, pc, pn = _rows(paths)
    m = len(paths)
    # per path: an edge of it (or, for some rows, one it does not hold), an offset, a prediction and a hint
    col = np.array([int(rng.integers(0, pn[i])) for i in range(m)])
    e = pe[np.arange(m), col]
    e = np.where(np.arange(m) % 7 == 3, (e + 1) % net.n_edges, e)
    off = rng.uniform(0.0, 1.0, m) * np.array(net.edge_len)[e]
    s_pred = np.array([rng.uniform(-5.0, p.length + 5.0) for p in paths])
    hint = np.clip(col + rng.integers(-2, 3, m), -1, pn)
    got = s_of_rows(pe, pd, pc, pn, Geometry(net).edge_len, e, off, s_pred, hint)
    for i, p in enumerate(paths):
        trk = SimpleNamespace(path=p, net=net)
        fix = Fix("edge", int(e[i]), float(off[i]), 0.0, 0.0, 0.0)
        assert got[i] == NetworkTracker._s_of(trk, fix, float(s_pred[i]), int(hint[i])), i


@pytest.mark.parametrize("name", sorted(TOPOS))
def test_best_on_rows_is_the_trackers_best_on(name):
    net = netview(TOPOS[name])
    geo = Geometry(net)
    placer = Placer(net, VEHICLE | PEDESTRIAN)
    rng = np.random.default_rng(5)
    paths = _paths(net, rng, 60)
    pe, pd, pc, pn = _rows(paths)
    m = len(paths)
    s_pred = np.array([rng.uniform(0.0, p.length) for p in paths])
    xy = np.array([p.xy(float(s)) for p, s in zip(paths, s_pred, strict=True)])
    x, y = xy[:, 0] + rng.normal(0.0, 6.0, m), xy[:, 1] + rng.normal(0.0, 6.0, m)
    lo = np.array([p.index(float(s) - 40.0) for p, s in zip(paths, s_pred, strict=True)])
    hi = np.array([p.index(float(s) + 60.0) for p, s in zip(paths, s_pred, strict=True)])
    ok, e, off, px, py, d = best_on_rows(geo, pe, pd, pc, pn, x, y, s_pred, lo, hi)
    assert ok.all()
    for i, p in enumerate(paths):
        trk = SimpleNamespace(path=p, net=net, placer=placer)
        trk._s_of = lambda f, s, k, trk=trk: NetworkTracker._s_of(trk, f, s, k)
        want = NetworkTracker._best_on(trk, float(x[i]), float(y[i]), float(s_pred[i]), int(lo[i]), int(hi[i]))
        assert (e[i], off[i], px[i], py[i], d[i]) == (want.index, want.offset, want.x, want.y, want.distance), i


@pytest.mark.parametrize("name", sorted(TOPOS) + ["area_square"])
def test_the_near_tables_hold_the_placers_tables(name):
    """`NearTables` per networks class and edge: the rows of `Placer.table`, in its order, and the areas of
    the placer's networks at the table's nodes, whether built many at once (`build`, half the edges in one
    pass) or one by one; a table asked for again is not built again."""
    net = netview(area_square() if name == "area_square" else TOPOS[name])
    tables = NearTables()
    for networks in (VEHICLE | PEDESTRIAN, PEDESTRIAN, VEHICLE):
        placer = Placer(net, networks)
        cls = tables.class_of(networks, net.n_edges)
        assert tables.class_of(networks, net.n_edges) == cls
        tables.build({(cls, e): placer for e in range(0, net.n_edges, 2)})
        assert (tables.start[cls, ::2] >= 0).all() and (tables.start[cls, 1::2] < 0).all()
        seen: set[int] = set()
        for e in [*range(net.n_edges), *range(net.n_edges)]:  # (twice: the second time from the index)
            size = tables.size
            tables.build({(cls, e): placer})
            start, count = int(tables.start[cls, e]), int(tables.count[cls, e])
            areas = tables.areas.get((cls, e), ())
            assert start == size if e % 2 and e not in seen else tables.size == size
            seen.add(e)
            t = placer.table(e)
            assert count == len(t.edge)
            for c in ("ax", "ay", "dx", "dy", "inv_l2", "cum0", "slen"):
                assert tables.cols[c][start : start + count].tolist() == getattr(t, c).tolist(), (e, c)
            assert tables.edge[start : start + count].tolist() == t.edge.tolist()
            assert areas == tuple(a for a in t.areas if net.topo.area_networks[a] & networks)
            assert bool(tables.has_areas[cls, e]) == bool(areas)
    assert len(tables.classes) == 3
    assert Placer(net, PEDESTRIAN).geom is Placer(net, VEHICLE).geom  # (the vertex arrays: one copy per map)
    if name == "area_square":  # (the area is pedestrian: a vehicle placer's tables hold none of it)
        assert tables.has_areas[tables.classes[PEDESTRIAN]].any()
        assert not tables.has_areas[tables.classes[VEHICLE]].any()


def _state(p) -> tuple:
    trk = p.tracker
    return trk.pending, trk.last_fix, trk.dist_ema, None if trk.kf is None else trk.kf.s


@pytest.mark.parametrize("mutation", ["weight", "count"])
def test_the_twins_see_an_error_in_the_retry_or_the_hysteresis(monkeypatch, mutation):
    """The twin comparison can fail on these kernels: `_best_on`'s along-path weight changed, or the
    hysteresis needing one fix more, shows in the messages or the state of the crossing's walk."""
    if mutation == "weight":
        monkeypatch.setattr(near_mod, "ALONG_SCALE", 1.5)
    else:
        real = near_mod.near_fixes

        def one_more(core, *a):
            core.swc[:] += 1
            try:
                return real(core, *a)
            finally:
                core.swc[:] -= 1
        monkeypatch.setattr("entitynet.client.fleet_fix.near_fixes", one_more)
    got_a, got_b, core, ents = _run(cross(arm=100.0))
    live = [slot for slot in range(len(ents)) if core.players[slot] is not None]
    assert got_a != got_b or any(_state(ents[slot][0]) != _state(core.player(slot)) for slot in live)
