"""The fleet core's compiled kernels (entitynet/client/_fleet.pyx) against their numpy references, bit for bit.

Each kernel gets the same inputs as its reference (`Geometry.project_np`, `Geometry.path_xy_np`, `hypot_py`'s
`math.hypot`, `NearTables.near_np`, `s_of_rows_np`, `best_on_rows_np`): realistic rows on the client fixtures'
maps, and hostile ones (NaN, +-inf, -0.0, subnormals, coordinates near the float limit, predictions far off the
path, hints outside it, a path of one edge, zero-length segments). Equality is of the bits (`_same`: NaN equals
NaN, -0.0 differs from 0.0). The twin fleets (tests/entitynet/client/test_fleet.py's drive) give the same
messages through the compiled kernels and through the references; a bad index is refused, not read.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from entitynet.client import fleet_kernels, netview
from entitynet.client.fleet_kernels import Geometry
from entitynet.client.fleet_near import NearTables, best_on_rows_np, s_of_rows_np
from entitynet.client.placement import Placer
from entitynet.client.tracker import ALONG_SCALE
from tests.entitynet.client.test_fleet import AREA, _run
from tests.entitynet.client.test_fleet_near import TOPOS, _paths, _rows
from tests.entitynet.client_fixtures import chain, cross
from topology.raw import PEDESTRIAN, VEHICLE

K = fleet_kernels.COMPILED
pytestmark = pytest.mark.skipif(K is None, reason="the compiled fleet kernels were not built (no Cython or C "
                                                   "compiler at install time)")
HOSTILE = np.array([math.nan, math.inf, -math.inf, -0.0, 0.0, 5e-324, -5e-324, 2.2e-308, 1.7e308, -1.7e308,
                    1e154, -1e154, 1e-3, 3.0])


def _same(a, b) -> bool:
    """Equal bit for bit (float arrays by their bits, others by value)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype == np.float64:
        return bool((a.view(np.int64) == b.view(np.int64)).all() or
                    ((a.view(np.int64) == b.view(np.int64)) | (np.isnan(a) & np.isnan(b))).all())
    return bool((a == b).all())


def _coords(rng, m: int, centre: np.ndarray, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """m points around `centre`, a third of them replaced by hostile values (in x, y or both)."""
    x = centre[0] + rng.normal(0.0, spread, m)
    y = centre[1] + rng.normal(0.0, spread, m)
    bad = rng.random(m) < 0.35
    x = np.where(bad & (rng.random(m) < 0.7), rng.choice(HOSTILE, m), x)
    y = np.where(bad & (rng.random(m) < 0.7), rng.choice(HOSTILE, m), y)
    return x, y


@pytest.mark.parametrize("name", sorted(TOPOS))
def test_hypot_and_project_equal_the_references(name):
    net = netview(TOPOS[name])
    geo = Geometry(net)
    rng = np.random.default_rng(11)
    m = 4000
    e = rng.integers(0, net.n_edges, m)
    e = e[geo.nseg[e] > 0]
    x, y = _coords(rng, len(e), np.array([geo.gx.mean(), geo.gy.mean()]), 150.0)
    dx, dy = rng.choice(HOSTILE, m), rng.normal(0.0, 1e3, m)
    want = np.array([math.hypot(a, b) for a, b in zip(dx.tolist(), dy.tolist(), strict=True)])
    assert _same(K.hypot_rows(dx, dy), want) and _same(K.hypot_rows(dy, dx)[::-1], np.array(
        [math.hypot(b, a) for a, b in zip(dx.tolist(), dy.tolist(), strict=True)])[::-1])
    got, ref = K.project(geo, x, y, e), geo.project_np(x, y, e)
    for g, r in zip(got, ref, strict=True):
        assert _same(g, r)
    placer = Placer(net, VEHICLE | PEDESTRIAN)  # (and the scalar original itself, on the finite rows)
    for i in np.flatnonzero(np.isfinite(x) & np.isfinite(y))[:300].tolist():
        f = placer.project_on(float(x[i]), float(y[i]), int(e[i]))
        assert (f.offset, f.x, f.y, f.distance) == tuple(float(v[i]) for v in got), i
    assert _same(K.project(geo, x[:0], y[:0], e[:0])[3], np.zeros(0))


@pytest.mark.parametrize("name", sorted(TOPOS))
def test_path_xy_equals_the_reference(name):
    net = netview(TOPOS[name])
    geo = Geometry(net)
    rng = np.random.default_rng(12)
    paths = _paths(net, rng, 200)
    pe, pd, pc, pn = _rows(paths)
    m = len(paths)
    s = np.array([rng.uniform(-20.0, p.length + 20.0) for p in paths])
    s = np.where(rng.random(m) < 0.3, rng.choice(HOSTILE, m), s)
    s[:4] = 0.0, -0.0, pc[2, pn[2]], pc[3, 1]  # (the ends and an edge's joint exactly)
    got, ref = K.path_xy(geo, s, pe, pd, pc, pn), geo.path_xy_np(s, pe, pd, pc, pn)
    assert _same(got[0], ref[0]) and _same(got[1], ref[1])
    finite = np.isfinite(s)
    assert all((float(got[0][i]), float(got[1][i])) == paths[i].xy(float(s[i])) for i in np.flatnonzero(finite))


def _near_inputs(net, rng, m: int):
    """A fleet's NearTables over every edge of the map and m fixes near a path each, with windows."""
    tables = NearTables()
    placer = Placer(net, VEHICLE | PEDESTRIAN)
    cls = tables.class_of(placer.networks, net.n_edges)
    tables.build({(cls, e): placer for e in range(net.n_edges)})
    paths = _paths(net, rng, m)
    pe, pd, pc, pn = _rows(paths)
    s_pred = np.array([rng.uniform(0.0, p.length) for p in paths])
    xy = np.array([p.xy(float(s)) for p, s in zip(paths, s_pred, strict=True)])
    x, y = _coords(rng, m, np.zeros(2), 8.0)
    x, y = np.where(np.isfinite(x) & (np.abs(x) < 1e3), x + xy[:, 0], x), np.where(
        np.isfinite(y) & (np.abs(y) < 1e3), y + xy[:, 1], y)
    lo = np.array([p.index(float(s) - 40.0) for p, s in zip(paths, s_pred, strict=True)])
    hi = np.array([p.index(float(s) + 60.0) for p, s in zip(paths, s_pred, strict=True)])
    k = np.array([p.index(float(s)) for p, s in zip(paths, s_pred, strict=True)])
    return tables, cls, pe, pd, pc, pn, s_pred, x, y, lo, hi, k


@pytest.mark.parametrize("name", sorted(TOPOS))
def test_near_s_of_and_best_on_equal_the_references(name):
    net = netview(TOPOS[name])
    geo = Geometry(net)
    rng = np.random.default_rng(13)
    tables, cls, pe, pd, pc, pn, s_pred, x, y, lo, hi, k = _near_inputs(net, rng, 300)
    m = len(x)
    e_cur = pe[np.arange(m), k]
    start, count = tables.start[cls, e_cur], tables.count[cls, e_cur]
    margin = np.where(rng.random(m) < 0.2, rng.choice(HOSTILE, m), 3.0)
    margin[:2] = math.nan, math.inf  # (NaN costs: numpy's argmin takes the first NaN)
    got = K.near(tables, x, y, start, count, margin, pe, lo, hi)
    ref = tables.near_np(x, y, start, count, margin, pe, lo, hi)
    for g, r in zip(got, ref, strict=True):
        assert _same(g, r)
    fe, off = got[0], got[1]
    s_hostile = np.where(rng.random(m) < 0.3, rng.choice(HOSTILE, m), s_pred)
    off = np.where(rng.random(m) < 0.2, rng.choice(HOSTILE, m), off)
    hint = np.clip(k + rng.integers(-5, 6, m), -3, 60)  # (hints off the path and beyond the row too)
    assert _same(K.s_of_rows(pe, pd, pc, pn, geo.edge_len, fe, off, s_hostile, hint),
                 s_of_rows_np(pe, pd, pc, pn, geo.edge_len, fe, off, s_hostile, hint))
    wt = 1.0 / (ALONG_SCALE * ALONG_SCALE)
    got = K.best_on_rows(geo, pe, pd, pc, pn, x, y, s_hostile, lo, hi, wt)
    ref = best_on_rows_np(geo, pe, pd, pc, pn, x, y, s_hostile, lo, hi)
    assert _same(got[0], ref[0]) and got[0].sum() > m // 3
    ok = got[0]
    for g, r in zip(got[1:], ref[1:], strict=True):  # (a row not decided here: its values are not used)
        assert _same(g[ok], r[ok])


def test_bad_indices_are_refused_not_read():
    net = netview(TOPOS["cross"])
    geo = Geometry(net)
    one = np.zeros(1)
    with pytest.raises(IndexError):
        K.project(geo, one, one, np.array([net.n_edges], dtype=np.int64))
    with pytest.raises(IndexError):
        K.project(geo, one, one, np.array([-1], dtype=np.int64))
    pe, pd, pc, pn = _rows(_paths(net, np.random.default_rng(1), 2))
    with pytest.raises(IndexError):
        K.path_xy(geo, np.zeros(2), pe, pd, pc, np.array([0, 1]))
    with pytest.raises(ValueError):
        K.path_xy(geo, np.zeros(3), pe, pd, pc, pn)
    with pytest.raises(IndexError):
        K.s_of_rows(pe, pd, pc, pn, geo.edge_len, np.array([net.n_edges, 0]), np.zeros(2), np.zeros(2),
                    np.zeros(2, dtype=np.int64))
    tables, cls, *_ = _near_inputs(net, np.random.default_rng(2), 2)
    with pytest.raises(IndexError):
        K.near(tables, one, one, np.array([tables.size]), np.array([1]), one, pe[:1], np.zeros(1, np.int64),
               np.zeros(1, np.int64))
    with pytest.raises(IndexError):
        K.best_on_rows(geo, pe, pd, pc, pn, np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2, np.int64),
                       np.array([0, 60]), 0.01)


@pytest.mark.parametrize(("topo", "seed"), [(cross(arm=100.0), 1), (chain(), 2), (AREA, 1)],
                         ids=["cross", "chain", "area"])
def test_twin_fleets_give_the_same_messages_through_both_kernels(topo, seed):
    """The same drive through the compiled kernels and through the numpy references: each side equal to the
    per-entity Players, and the two equal to each other, tick for tick."""
    was = fleet_kernels.compiled_in_use()
    runs = {}
    try:
        for compiled in (True, False):
            assert fleet_kernels.use_compiled(compiled) == compiled
            got_a, got_b, core, _ents = _run(topo, seed=seed)
            assert got_a == got_b
            runs[compiled] = (got_b, core.counters)
    finally:
        fleet_kernels.use_compiled(was)
    assert runs[True][0] == runs[False][0] and runs[True][1] == runs[False][1]
    assert runs[True][1]["vector_near"] > 0 and runs[True][1]["vector_best_on"] > 0


def _rows_rewritten_by_the_reference(core, rows) -> None:
    """Every row's ghost read again into the derived columns by `_refresh`'s numpy assignments (the compiled
    kernels off; the caller restores the switch)."""
    fleet_kernels.use_compiled(False)
    for s in rows:
        core._ghosts[s] = None
        core._refresh(s)


def _assert_columns(core, rows, written) -> None:
    for name, got in written.items():
        assert _same(got, getattr(core, name)[rows]), name


def test_ghost_row_writes_what_the_reference_writes():
    """`_fleet.GhostCols` (a new ghost read into the derived columns) against `_refresh`'s numpy assignments."""
    was = fleet_kernels.compiled_in_use()
    try:
        fleet_kernels.use_compiled(True)
        _a, _b, core, _ents = _run(cross(arm=100.0), seed=1)
        rows = [s for s in range(len(core.players)) if core.players[s] is not None and core._ghosts[s] is not None]
        assert len(rows) > 5
        written = {n: getattr(core, n)[rows].copy() for n in ("gm", "ge", "gd", "gc", "gn")}
        _rows_rewritten_by_the_reference(core, rows)
    finally:
        fleet_kernels.use_compiled(was)
    _assert_columns(core, rows, written)
    p = core.players[rows[0]]
    with pytest.raises(IndexError):
        K.GhostCols(core.gm, core.ge, core.gd, core.gc, core.gn).write(len(core.gm), tuple(core.gm[0]), p.ghost.path)
    with pytest.raises(ValueError):
        K.GhostCols(core.gm, core.ge, core.gd, core.gc, core.gn).write(0, (1.0,), p.ghost.path)


class _P:
    """A path as `GhostCols.write` reads it (edges, cumulative lengths)."""

    def __init__(self, edges, cum):
        self.edges, self.cum = edges, cum


def test_ghost_cols_write_what_the_numpy_reference_writes_hostile_numbers_included():
    """`_fleet.GhostCols` (the columns taken once, the fleet core's holder) against `fleet.ghost_row_py` (the
    numpy reference) on the same rows: hostile numbers, a path of one edge and of the widest a row holds;
    refusals write nothing."""
    from entitynet.client.fleet import FleetCore, W, ghost_row_py

    a, b = FleetCore(capacity=4), FleetCore(capacity=4)
    cols = K.GhostCols(b.gm, b.ge, b.gd, b.gc, b.gn)
    nums = tuple(HOSTILE[:11].tolist())
    one = _P([(7, -1)], [0.0, 12.5])
    wide = _P([(e, 1 if e % 2 else -1) for e in range(W)], [float(k) * 1.5 for k in range(W + 1)])
    for s, path in ((0, one), (3, wide), (1, one), (1, wide)):
        ghost_row_py(a.gm, a.ge, a.gd, a.gc, a.gn, s, nums, path)
        cols.write(s, nums, path)
    for name in ("gm", "ge", "gd", "gc", "gn"):
        assert _same(getattr(a, name), getattr(b, name)), name
    before = {name: getattr(b, name).copy() for name in ("gm", "ge", "gd", "gc", "gn")}
    with pytest.raises(IndexError):
        cols.write(4, nums, one)
    with pytest.raises(IndexError):
        cols.write(-1, nums, one)
    with pytest.raises(ValueError):
        cols.write(0, nums[:10], one)
    with pytest.raises(ValueError):
        cols.write(0, nums, _P([], [0.0]))
    with pytest.raises(ValueError):
        cols.write(0, nums, _P(wide.edges + [(1, 1)], wide.cum + [99.0]))
    with pytest.raises(ValueError):
        cols.write(0, nums, _P([(1, 1)], [0.0]))
    for name, was in before.items():
        assert _same(was, getattr(b, name)), name
    with pytest.raises(ValueError):
        K.GhostCols(b.gm, b.ge, b.gd, b.gc[:2], b.gn)


def test_the_fleets_ghost_columns_are_taken_again_after_they_grow():
    """The fleet core's holder of the ghost columns follows a growth of the record: a ghost written after the
    fleet grew lands in the new columns (the twin fleets' messages and columns agree with the numpy path)."""
    was = fleet_kernels.compiled_in_use()
    try:
        fleet_kernels.use_compiled(True)
        _a, _b, core, _ents = _run(cross(arm=100.0), seed=2)
        assert core._ghost_cols is not None and len(core.gm) > 4  # (grew past its first 4 slots while adding)
        rows = [s for s in range(len(core.players)) if core.players[s] is not None and core._ghosts[s] is not None]
        written = {n: getattr(core, n)[rows].copy() for n in ("gm", "ge", "gd", "gc", "gn")}
        core._grow()  # (new blocks holding the old rows, as after a growth)
        assert core._ghost_cols is None  # taken again at the next new ghost, over the blocks as they are now
        s = rows[0]
        core.gm[s], core.ge[s], core.gn[s] = 0.0, 0, 0  # (the new blocks' row wiped: the write must land there)
        core._ghosts[s] = None
        core._refresh(s)
        assert core._ghost_cols is not None
        assert _same(core.gm[s], written["gm"][0]) and _same(core.ge[s], written["ge"][0])
        assert core.gn[s] == written["gn"][0]
        _rows_rewritten_by_the_reference(core, rows)
    finally:
        fleet_kernels.use_compiled(was)
    _assert_columns(core, rows, written)
