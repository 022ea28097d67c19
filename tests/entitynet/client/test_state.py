"""The client-state record (entitynet/client/state.py): fields declared once, rows column-wise, rings and
path rows, growth that keeps the rows, and the clear errors of a wrong use."""

from __future__ import annotations

import math
import struct
import subprocess
import sys
from array import array
from pathlib import Path

import numpy as np
import pytest

from entitynet.client.filters import Kinematic1D, RowKinematic
from entitynet.client.player import Player
from entitynet.client.state import F_COL, FLOATS, INTS, NF, NI, PATH_W, RECENT, Bound, Record, Ring, column
from tests.entitynet.client_fixtures import cross


class _Part(Bound):
    __slots__ = ()
    last_t = column("last_t", "opt")
    ks = column("ks")
    rev = column("rev", "int")
    halted = column("halted", "bool")


def test_fields_read_and_write_one_row_and_the_views_see_them():
    rec = Record(1)
    a, b = _Part(), _Part()
    a.bind(rec, rec.new_row())
    b.bind(rec, rec.new_row())  # (grows the record: a's row is kept)
    assert a.last_t is None and a.ks == 0.0 and a.rev == 0 and a.halted is False
    a.last_t, a.ks, a.rev, a.halted = 2.5, 7.0, 3, True
    assert (a.last_t, a.ks, a.rev, a.halted) == (2.5, 7.0, 3, True) and b.ks == 0.0 and b.last_t is None
    v = rec.view()
    assert v["ks"][0] == 7.0 and v["rev"][0] == 3 and math.isnan(v["last_t"][1])
    v["ks"][1] = -1.5  # the arrays write the same memory
    assert b.ks == -1.5
    a.last_t = None
    assert a.last_t is None and math.isnan(rec.view()["last_t"][0])
    assert type(a.ks) is float  # Python floats, not numpy scalars, for the scalar code


def test_rings_keep_the_last_values_oldest_first():
    rec = Record(1)
    p = _Part()
    p.bind(rec, rec.new_row())
    ring = Ring("rs", "rs_n")
    for k in range(8):
        ring.push(p, float(k))
    assert ring.get(p) == [3.0, 4.0, 5.0, 6.0, 7.0]
    assert rec.view()["rs"][0].tolist() == [3.0, 4.0, 5.0, 6.0, 7.0] and rec.view()["rs_n"][0] == RECENT
    ring.put(p, [1.0, 2.0])
    assert ring.get(p) == [1.0, 2.0]
    ring.clear(p)
    assert ring.get(p) == []
    with pytest.raises(ValueError, match="at most 5"):
        ring.put(p, [0.0] * 6)


def test_growth_keeps_rows_and_a_moved_row_is_the_same_state():
    rec = Record(2)
    for _ in range(5):
        rec.new_row()
    other = Record(1)
    p = _Part()
    p.bind(other, other.new_row())
    p.ks, p.rev = 4.25, 9
    row = rec.take(other, 0)
    p.bind(rec, row)
    assert (row, p.ks, p.rev, rec.rows) == (5, 4.25, 9, 6) and rec.cap == 8
    # the declared fields and the bytes a row costs
    assert NF == len(FLOATS) + 4 * RECENT and NI == len(INTS)
    assert rec.nbytes_per_row() == 8 * (NF + NI + 3 * PATH_W + 1)


def test_the_filter_and_the_path_belong_to_the_row():
    p = Player(cross(arm=100.0), 1, "car", accuracy=4.0)
    for k in range(3):
        p.feed(10.0 + 5.0 * k, 1.0, float(k + 1))
    trk = p.tracker
    with pytest.raises(ValueError, match="the row's"):
        trk.kf = object()  # the along-path filter is not replaced by another object
    path = trk.path
    v = p._st.view()
    assert v["pn"][0] == -1  # set by the scalar code: the `Path` is the one home, until the fleet core moves it
    assert p._st.path_to_arrays(0) and trk.path is path
    n = int(v["pn"][0])
    assert [de[0] for de in path.edges] == v["pe"][0, :n].tolist() and path.cum == v["pc"][0, : n + 1].tolist()
    assert np.isinf(v["pc"][0, n + 1 :]).all()  # (the arrays' search needs the padding)
    trk.path = None
    assert trk.path is None and v["pn"][0] == 0 and not p._st.path_to_arrays(0)


@pytest.mark.parametrize("accel", [True, False])
def test_the_row_filter_is_the_slot_filter_bit_for_bit(accel):
    rec = Record(1)
    row = RowKinematic()
    row.bind(rec, rec.new_row())
    row.reset(3.0, 0.0, 25.0, q=0.3, accel=accel)
    own = Kinematic1D(3.0, 0.0, 25.0, q=0.3, accel=accel)
    rng = np.random.default_rng(3)
    for k in range(1, 40):
        z, t = 1.7 * k + rng.normal() * 5.0, float(k) + (0.5 if k % 7 == 0 else 0.0)
        assert row.update(z, t, 25.0) == own.update(z, t, 25.0)
        assert [getattr(row, f) for f in row.FIELDS] == [getattr(own, f) for f in own.FIELDS]
    row.update(0.0, 50.0, -1e9)  # an innovation variance <= 0: the prediction only, in both
    own.update(0.0, 50.0, -1e9)
    assert [getattr(row, f) for f in row.FIELDS] == [getattr(own, f) for f in own.FIELDS]


def test_the_compiled_accessors_read_and_write_what_the_reference_does():
    """`column` gives the compiled descriptors (`_columns.pyx`) where pip built them; each kind reads and
    writes the same memory as the pure reference, the same values and types."""
    from entitynet.client import state

    if state._COMPILED is None:
        pytest.skip("the compiled accessors are not built here (the reference is in use)")

    def part(compiled: bool):
        class P(Bound):
            __slots__ = ()
            t = column("last_t", "opt", compiled=compiled)
            s = column("ks", compiled=compiled)
            n = column("rev", "int", compiled=compiled)
            b = column("halted", "bool", compiled=compiled)
        return P

    rec = Record(3)
    rec.new_row()
    rec.new_row()
    fast, ref = part(True)(), part(False)()
    assert not isinstance(type(fast).__dict__["s"], property)  # (the compiled kind is in use)
    fast.bind(rec, 1)
    ref.bind(rec, 1)
    for t, s, n, b in ((None, 0.0, 0, False), (2.5, -1.25, 7, True), (np.float64(3.0), np.float64(1e300),
                                                                      np.int64(-4), 1)):
        fast.t, fast.s, fast.n, fast.b = t, s, n, b
        got = (ref.t, ref.s, ref.n, ref.b)
        ref.t, ref.s, ref.n, ref.b = t, s, n, b
        want = (fast.t, fast.s, fast.n, fast.b)
        assert got == want and [type(v) for v in got] == [type(v) for v in want]
    assert rec.view()["ks"][0] == 0.0 and rec.view()["rev"][1] == -4  # the row bound, not another


def test_the_compiled_ring_keeps_what_the_reference_keeps():
    from entitynet.client import state

    if state._COMPILED is None:
        pytest.skip("the compiled accessors are not built here (the reference is in use)")
    rec = Record(2)
    a, b = _Part(), _Part()
    a.bind(rec, rec.new_row())
    b.bind(rec, rec.new_row())
    fast, ref = state.ring("iv", "iv_n"), Ring("iv", "iv_n")
    assert type(fast) is not Ring
    for k in range(7):
        fast.push(a, 0.5 * k)
        ref.push(b, 0.5 * k)
        assert fast.get(a) == ref.get(b) == ref.get(a)  # (the same memory: the other reads it alike)
    fast.put(a, [1.0, 2.0])
    assert ref.get(a) == [1.0, 2.0]
    with pytest.raises(ValueError, match="at most 5"):
        fast.put(a, [0.0] * 6)
    fast.clear(a)
    assert ref.get(a) == [] and ref.get(b) == [1.0, 1.5, 2.0, 2.5, 3.0]
    for ring in (fast, ref):  # a value that is no number: the same error from both, the ring unchanged
        for bad in ("x", None):
            with pytest.raises(TypeError):
                ring.push(b, bad)
        assert ref.get(b) == [1.0, 1.5, 2.0, 2.5, 3.0]


def test_the_compiled_accessors_refuse_what_the_reference_refuses():
    """An integer field takes integers only (as `array('q')` and the reference do): a float written there is a
    TypeError, not silently truncated (2.7 read back as 2) by the compiled kind alone."""
    from entitynet.client import state

    if state._COMPILED is None:
        pytest.skip("the compiled accessors are not built here (the reference is in use)")
    rec = Record(1)
    rec.new_row()
    for compiled in (True, False):
        class P(Bound):
            __slots__ = ()
            n = column("rev", "int", compiled=compiled)
        p = P()
        p.bind(rec, 0)
        p.n = np.int32(5)
        for bad in (2.7, np.float64(2.0), "3", None):
            with pytest.raises(TypeError):
                p.n = bad
        with pytest.raises(OverflowError):
            p.n = 2**70
        assert p.n == 5 and type(p.n) is int


def test_without_the_compiled_module_the_reference_gives_the_pinned_messages():
    """Where pip built no `_columns`, `_lateral`, `_waytable`, `_geom`, `_occupy`, `_cover` nor `_payload` (no C
    compiler: setup.py goes on without them), the Python accessors, filter update, lateral loop, path point,
    occupation and its publish cover and payload quantisation are the only ones, and no other test runs them where
    the modules are built. In a child with the modules hidden: the pinned replay digests, and a fleet core's
    messages and paths (rebuilt from the row's arrays) equal to its twin Players'."""
    code = ("import sys\nsys.modules['entitynet.client._columns'] = None\n"
            "sys.modules['entitynet.client._lateral'] = sys.modules['entitynet.client._geom'] = None\n"
            "sys.modules['entitynet.client._occupy'] = sys.modules['entitynet.client._cover'] = None\n"
            "sys.modules['entitynet.client._waytable'] = sys.modules['entitynet.client._payload'] = None\n"
            "from entitynet.client import coverage, lateral, occupation, path, payload, state\n"
            "assert state._COMPILED is lateral._COMPILED is path._COMPILED is occupation._COMPILED is None\n"
            "assert coverage._COMPILED is coverage._network_occupation is None\n"
            "assert lateral._WayTable is lateral._areas_near is payload._COMPILED is None\n"
            "assert payload.encode_network is payload.encode_network_reference\n"
            "from tests.entitynet.client import test_fleet_state as f, test_player_replay as r\n"
            "from tests.entitynet.client_fixtures import cross\n"
            "r.test_every_walk_gives_the_recorded_messages()\n"
            "f.test_paths_extended_in_arrays_give_the_players_messages_and_state(cross(arm=100.0))\n"
            "f.test_the_arrays_and_the_player_are_one_state()\nprint('reference ok')\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).parents[3], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "reference ok", done.stderr[-3000:]


def test_a_row_outside_the_record_is_refused_not_read_as_stray_memory():
    """The compiled accessors index the blocks without bounds checks: binding a part (or moving a row) to a row
    the record does not hold is an IndexError, for both kinds, before any read or write."""
    rec, one = Record(4), Record(1)
    rec.new_row()
    one.new_row()
    p = _Part()
    for row in (1, 4, 100_000, -1):  # (1: allocated, not in use: its fields were never initialised)
        with pytest.raises(IndexError, match="not a row in use"):
            p.bind(rec, row)
        with pytest.raises(IndexError, match="not a row in use"):
            rec.take(one, 0, at=row)
        with pytest.raises(IndexError, match="not a row in use"):
            rec.take(one, row)  # (from a row the other record does not hold: an empty slice would shrink `f`)
    p.bind(rec, 0)
    assert p.last_t is None and rec.rows == 1 and len(rec.f) == 4 * NF
    assert rec.take(one, 0, at=0) == 0 and rec.take(one, 0) == 1 and rec.rows == 2


def test_the_compiled_filter_update_is_the_reference_bit_for_bit():
    """`RowKinematic.update_sv` (compiled `_columns.kalman_row` where built) leaves the row and returns the
    (s, v) that the reference `KinematicMath.update_sv` does, bit for bit, over random states, both models
    (with and without acceleration), time standing still and a covariance that is no longer positive."""
    from entitynet.client import state
    from entitynet.client.filters import KinematicMath

    if state._COMPILED is None:
        pytest.skip("the compiled accessors are not built here (the reference is in use)")
    rng = np.random.default_rng(22)
    rec = Record(2)
    fast, ref = RowKinematic(), RowKinematic()
    fast.bind(rec, rec.new_row())
    ref.bind(rec, rec.new_row())
    for k in range(3000):
        accel = bool(k % 2)
        s0, t0 = float(rng.normal(0.0, 500.0)), float(rng.uniform(0.0, 1e5))
        r0, q = (float(rng.uniform(0.1, 100.0)) if k % 50 else -1e9), float(rng.uniform(0.01, 3.0))
        for f in (fast, ref):
            f.reset(s0, t0, r0, q=q, accel=accel)
        rng2 = np.random.default_rng(k)
        t = t0
        for _ in range(6):
            t += float(rng2.choice([0.0, rng2.uniform(0.01, 40.0)]))
            z, r = float(s0 + rng2.normal(0.0, 30.0)), float(rng2.uniform(0.5, 400.0))
            got, want = fast.update_sv(z, t, r), KinematicMath.update_sv(ref, z, t, r)
            assert got == want
            assert fast._state() == ref._state()
    with pytest.raises(IndexError):
        state._COMPILED.kalman_row(rec.f, len(rec.f) - 3, True, 0.0, 1.0, 1.0)


def _bits(values) -> list:
    """Each float's IEEE bit pattern ("nan" for any NaN): `==` would take -0.0 for 0.0 and fail on NaN."""
    return ["nan" if v != v else struct.pack("=d", v) for v in values]


def test_the_compiled_filter_update_is_the_reference_on_hard_inputs():
    """`_columns.kalman_row` against `KinematicMath.update_sv` where the random test above never goes: NaN,
    infinities, -0.0, subnormals and values near the float range in the row and the arguments, compared by bit
    pattern (row and result; an exception must be the same exception)."""
    import random

    from entitynet.client import state
    from entitynet.client.filters import KinematicMath

    if state._COMPILED is None:
        pytest.skip("the compiled accessors are not built here (the reference is in use)")
    hard = [0.0, -0.0, 5e-324, -5e-324, 1e-300, 1e308, -1e308, math.inf, -math.inf, math.nan, 1.0, -3.5]
    rng = random.Random(22)
    rec = Record(2)
    fast, ref = RowKinematic(), RowKinematic()
    fast.bind(rec, rec.new_row())
    ref.bind(rec, rec.new_row())

    def call(fn, *args):
        try:
            return _bits(fn(*args))
        except ArithmeticError as exc:
            return type(exc).__name__

    for _ in range(4000):
        vals = [rng.choice(hard) if rng.random() < 0.5 else rng.uniform(-1e3, 1e3) for _ in range(11)]
        accel = rng.random() < 0.5
        z, t, r = (rng.choice(hard) if rng.random() < 0.5 else rng.uniform(-1e3, 1e3) for _ in range(3))
        for f in (fast, ref):
            rec.f[f._fb + F_COL["ks"] : f._fb + F_COL["ks"] + 11] = array("d", vals)
            f.accel = accel
        got, want = call(fast.update_sv, z, t, r), call(KinematicMath.update_sv, ref, z, t, r)
        assert got == want, (vals, accel, z, t, r)
        assert _bits(fast._state()[:11]) == _bits(ref._state()[:11]), (vals, accel, z, t, r)
