"""The published part of the path (issue 22, round 7): built from the fleet row's arrays where the path is there
only, the last suffix of a path handed out again, and the fleet's tick after a publish asked only where the
slot's deadline has come; each gives exactly what the code before gave."""

from __future__ import annotations

import math

import numpy as np
import pytest

from entitynet.client import netview
from entitynet.client.fleet import FleetCore
from entitynet.client.path import Path
from entitynet.client.player import Player
from entitynet.client.state import I_COL, PATH_W
from tests.entitynet.client.test_fleet import _run
from tests.entitynet.client_fixtures import chain, cross, parallel

_COLUMNS = __import__("entitynet.client.state", fromlist=["_COMPILED"])._COMPILED  # (before any test patches it)
HOSTILE = (math.nan, math.inf, -math.inf, -0.0, 0.0, -1e300, 1e300, 5e-324)


def _suffix_reference(path: Path, k: int) -> Path:
    """`Path.suffix` as written before round 7: a new path every call."""
    if k == 0 and path.cum[0] == 0.0:
        return Path(path.net, path.edges, _cum=list(path.cum))
    c0 = path.cum[k]
    return Path(path.net, path.edges[k:], _cum=[c - c0 for c in path.cum[k:]])


def _same(a: Path, b: Path) -> None:
    assert a.edges == b.edges and a.net is b.net
    assert [x.hex() for x in a.cum] == [x.hex() for x in b.cum]


def _starts(path: Path, rng: np.random.Generator) -> list[float]:
    """Path coordinates that a publish may ask from: every joint, a hair either side, random, beyond the ends."""
    out = list(HOSTILE)
    for c in path.cum:
        out += [c, math.nextafter(c, -math.inf), math.nextafter(c, math.inf)]
    out += rng.uniform(-50.0, path.length + 50.0, 40).tolist()
    return out


@pytest.mark.parametrize("topo", [parallel(gap=12.0, length=300.0), chain(), cross(arm=100.0)])
def test_the_part_from_the_rows_arrays_is_the_paths_suffix(topo):
    """Rows whose path the fleet core trimmed or extended (in the arrays only): `path_from` gives the edges, the
    cumulative lengths (bit for bit) and the shift that the path built from the arrays and its suffix give."""
    _a, _b, core, _ents = _run(topo, n=12, ticks=160)
    rng = np.random.default_rng(3)
    checked = 0
    for s, p in enumerate(core.players):
        if p is None or core.pn[s] <= 0:
            continue
        trk = p.tracker
        for start in _starts(trk.path, rng):
            core.rec.paths[s] = None  # (a cache of the arrays: dropped, as the fleet core's trims do)
            got, shift = trk.path_from(start)
            assert core.rec.paths[s] is None  # the whole path was not built for it
            whole = trk.path
            k = whole.index(start)
            _same(got, _suffix_reference(whole, k))
            assert shift == whole.cum[k] and (got.cum == whole.part_from(start)[0].cum)
            checked += 1
    assert checked > 100


def test_the_part_from_a_path_held_as_an_object():
    """A lone Player's path is in its object only (the scalar code's, `pn` -1): the object's part."""
    p = Player(chain(), 1, "car", accuracy=4.0)
    for k in range(6):
        p.feed(10.0 + 8.0 * k, 0.5, float(k + 1))
    trk = p.tracker
    assert trk._st.i[trk._ib + I_COL["pn"]] == -1
    for start in (*HOSTILE, 3.0, trk.path.length):
        got, shift = trk.path_from(start)
        k = trk.path.index(start)
        _same(got, _suffix_reference(trk.path, k))
        assert shift == trk.path.cum[k]


def test_a_paths_suffix_is_kept_and_equal_to_a_new_one():
    net = netview(chain())
    path = Path(net, [(e, 1) for e in range(net.n_edges)][:3]) if net.n_edges >= 3 else Path(net, [(0, 1)])
    assert path.suffix(0) is path  # cum[0] is 0.0: the same coordinates
    for k in range(len(path.edges)):
        a = path.suffix(k)
        _same(a, _suffix_reference(path, k))
        assert path.suffix(k) is a
    shifted = Path(net, path.edges, _cum=[c + 0.1 for c in path.cum])  # cum[0] not 0.0: shifted, not itself
    _same(shifted.suffix(0), _suffix_reference(shifted, 0))
    assert shifted.suffix(0) is not shifted


def test_the_fleets_ticks_after_a_fix_give_the_lone_players_messages():
    """The fleet asks `tick` after a fix or a publish only where the slot's deadline has come: the same messages
    as lone Players fed and ticked every time, with fixes sparse, a fix gap (the ghost halts, then is lost) and
    fixes arriving after the publish has run out."""
    topo = cross(arm=200.0)
    kinds = ("car", "pedestrian", "cyclist")
    lone = [Player(topo, i, kinds[i % 3], accuracy=4.0, max_validity=1.0, max_gap=3.0, lost_after=8.0)
            for i in range(6)]
    mine = [Player(topo, i, kinds[i % 3], accuracy=4.0, max_validity=1.0, max_gap=3.0, lost_after=8.0)
            for i in range(6)]
    core = FleetCore()
    slots = [core.add(p) for p in mine]
    rng = np.random.default_rng(5)
    spoke = 0
    for k in range(120):
        t = 0.5 * (k + 1)
        due = [i for i in range(6) if (k % (1 + i % 3) == 0) and not (i == 4 and 20 <= k < 45)]
        xs = [-150.0 + 0.4 * (1 + i) * k + float(rng.normal(0.0, 3.0)) for i in due]
        ys = [float(rng.normal(0.0, 3.0)) for _i in due]
        want = {}
        for j, i in enumerate(due):
            want[i] = lone[i].feed(xs[j], ys[j], t, 4.0) + lone[i].tick(t)
        for i in set(range(6)) - set(due):
            want[i] = lone[i].tick(t)
        got, rejected = core.step(t, [slots[i] for i in due], np.array(xs), np.array(ys), 4.0)
        assert rejected == 0
        assert dict(got) == {slots[i]: m for i, m in want.items() if m}, k
        spoke += sum(len(m) for m in want.values())
    assert spoke > 50


@pytest.mark.parametrize("topo", [parallel(gap=12.0, length=300.0), chain(), cross(arm=100.0)])
def test_a_path_turned_round_is_the_checked_one(topo):
    """`Path.reversed` without the constructor's checks: the same edges and cumulative lengths (bit for bit) as
    the checking constructor gives, on every path the twins' trackers held and on those turned round twice."""
    from entitynet.client.path import reversed_reference

    _a, _b, core, _ents = _run(topo, n=12, ticks=120)
    seen = 0
    for p in core.players:
        if p is None or p.tracker is None or p.tracker.path is None:
            continue
        path = p.tracker.path
        for q in (path, path.reversed(), path.suffix(len(path.edges) - 1)):
            _same(q.reversed(), reversed_reference(q))
            _same(q.reversed().reversed(), reversed_reference(reversed_reference(q)))
            seen += 1
    assert seen > 10


def _copy_both(monkeypatch, path: Path, cap: int = 3, row: int = 1):
    """`Record.path_to_arrays` of `path` into row `row`, compiled and pure: the two records' blocks (or the
    errors)."""
    from entitynet.client import state

    if _COLUMNS is None:
        pytest.skip("the compiled accessors are not built here")
    out = []
    for compiled in (_COLUMNS, None):
        monkeypatch.setattr(state, "_COMPILED", compiled)
        rec = state.Record(cap)
        for _ in range(cap):
            rec.new_row()
        rec.paths[row] = path
        rec.i[row * state.NI + state.I_COL["pn"]] = -1
        try:
            got = rec.path_to_arrays(row)
        except (ValueError, TypeError, OverflowError) as err:
            out.append(type(err))
            continue
        out.append((got, rec.pe.tobytes(), rec.pd.tobytes(), rec.pc.tobytes(), rec.i.tobytes()))
    return out


@pytest.mark.parametrize("topo", [parallel(gap=12.0, length=300.0), chain(), cross(arm=100.0)])
def test_a_path_copied_into_a_row_in_c_is_the_references_copy(topo, monkeypatch):
    _a, _b, core, _ents = _run(topo, n=8, ticks=80)
    paths = [p.tracker.path for p in core.players if p is not None and p.tracker and p.tracker.path is not None]
    assert paths
    for path in paths:
        a, b = _copy_both(monkeypatch, path)
        assert a == b and a[0] is True


def test_a_malformed_path_is_refused_by_both_copies(monkeypatch):
    net = netview(chain())
    good = Path(net, [(0, 1)])
    for edges, cum in (([(0, 1)], [0.0]), ([(0, 1)], [0.0, 1.0, 2.0]), ([(0.5, 1)], [0.0, 1.0]),
                       ([(0, 1)], [0.0, "x"]), ([(2**70, 1)], [0.0, 1.0]),
                       ([(0, 1)], [0.0, math.nan]), ([(0, 1)] * (PATH_W + 1), [0.0] * (PATH_W + 2))):
        bad = Path(net, edges, _cum=cum)
        a, b = _copy_both(monkeypatch, bad)
        if len(edges) > PATH_W:
            assert a[0] is False and b[0] is False  # too wide: stays in its object
        else:
            assert a == b, (edges, cum, a, b)
    a, b = _copy_both(monkeypatch, Path(net, good.edges, _cum=[0.0, math.inf]))
    assert a == b


def test_a_suffix_from_a_negative_edge_is_the_references():
    net = netview(chain())
    path = Path(net, [(0, 1)])
    for k in (-1, 0, -1):
        _same(path.suffix(k), _suffix_reference(path, k))
