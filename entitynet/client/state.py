"""One entity's client state, declared once and stored column-wise: the one home of every field that the
scalar client core (`Player` and its parts) and the fleet core's arrays (fleet.py) both read or write.

Why: a fleet of thousands of honest clients decides most fixes over arrays, and a phone decides its one
entity field by field. Both work on the same `Record`: a `Player` alone owns a record of one row; a
`FleetCore` owns one record of many rows, and adding a Player moves its row there once (`Record.take`), it
does not mirror it. The parts read and write their fields through `column` descriptors (one row, Python
floats and ints); the fleet core reads and writes whole columns through numpy views of the same memory
(`Record.view`). Nothing is copied between them, so no field has two homes.

Layout: the float fields are the columns of one row-major block `f` (`FLOATS`, then the rings `RINGS`, each
`RECENT` columns, oldest first, right-aligned, with a count in `INTS`); the integer fields of a block `i`;
the path the tracker follows is three row arrays `pe` (edge), `pd` (direction), `pc` (cumulative length,
`PATH_W + 1`), with `pn` edges used, or the immutable `Path` object in `paths[row]`: one of the two is the truth,
the other at most its cache. The scalar code sets a new `Path` (`pn` -1: the object is the truth); the fleet
core moves it into the arrays before it works on the row (`path_to_arrays`; the object stays as their cache),
and when it trims or extends a path in the arrays it drops the object, built again from them when asked. A
path wider than `PATH_W` (rare) stays in its object.
"""

from __future__ import annotations

import math
from array import array
from struct import Struct

import numpy as np

try:  # the compiled field accessors, where pip built them (setup.py; optional)
    from entitynet.client import _columns as _COMPILED  # type: ignore[attr-defined]
except ImportError:  # the pure reference
    _COMPILED = None

RECENT = 5  # fixes kept by the tracker's `recent_s` and the rules' `recent` (and fix intervals kept)
_TAIL = Struct(f"={RECENT - 1}d")  # a ring's newest columns, read and written one place down at once
PATH_W = 48  # the widest path a row holds in arrays (the tracker keeps at most MAX_PATH_EDGES)

# (name, initial value, meaning): the float fields of a row
FLOATS = (
    ("last_t", math.nan, "time of the last fix (NaN: none yet)"),
    ("mx", 0.0, "the last fix, x (local metres)"),
    ("my", 0.0, "the last fix, y"),
    ("off_since", math.nan, "first fix off the network in the current run (NaN: on it)"),
    ("pub_t", -math.inf, "time of the last publish"),
    ("ks", 0.0, "along-path filter: position s on the path (m)"),
    ("kv", 0.0, "along-path filter: speed (m/s)"),
    ("ka", 0.0, "along-path filter: acceleration (m/s2)"),
    ("p00", 0.0, "along-path filter: covariance"), ("p01", 0.0, "covariance"), ("p02", 0.0, "covariance"),
    ("p11", 0.0, "covariance"), ("p12", 0.0, "covariance"), ("p22", 0.0, "covariance"),
    ("kt", 0.0, "along-path filter: time of its state"),
    ("kq", 0.0, "along-path filter: process noise density"),
    ("dist_ema", 0.0, "tracker: moving mean of the fixes' distance from the way held"),
    ("vpeak", 0.0, "tracker: recent peak speed (the publish's cruising speed)"),
    ("vpeak_t", -math.inf, "tracker: when vpeak was set"),
    ("lf_off", 0.0, "tracker: last fix on the network, offset on its edge"),
    ("lf_x", 0.0, "last fix on the network, x"), ("lf_y", 0.0, "last fix on the network, y"),
    ("lf_d", 0.0, "last fix on the network, distance from the fix"),
    ("reach", 0.0, "tracker: how far along the path from the prediction a fix may map (not a jump)"),
    ("gap_lim", 0.0, "rules: seconds without a fix before the guess halts"),
    ("interval", 0.0, "rules: the feed's usual fix interval (0: not known yet)"),
)
# ring columns, RECENT each (oldest first, the last `<count>` used)
RINGS = (
    ("rs", "rs_n", "tracker: path coordinates of the last fixes"),
    ("rx", "rr_n", "rules: x of the last fixes (on the network when placed)"),
    ("ry", "rr_n", "rules: y of the last fixes"),
    ("iv", "iv_n", "rules: the last fix intervals (s)"),
)
INTS = (
    ("kf_on", 0, "along-path filter in use (placed on an edge)"),
    ("kacc", 0, "along-path filter: acceleration modelled"),
    ("halted", 0, "rules: a fix gap stopped the published guess"),
    ("rev", 0, "tracker: fixes in a row going backwards"),
    ("over", 0, "rules: fixes in a row over the drift threshold"),
    ("lf_kind", 0, "tracker: last fix placed 0 none, 1 on an edge, 2 in an area"),
    ("lf_e", 0, "tracker: last fix's edge (or area)"),
    ("dead_e", -1, "tracker: the path's last edge where nothing followed (-1: none)"),
    ("dead_d", 0, "its direction"),
    ("pend_e", -1, "tracker: a candidate edge of the hysteresis (-1: none)"),
    ("pend_n", 0, "its count of fixes"),
    ("rs_n", 0, "count of rs"), ("rr_n", 0, "count of rx, ry"), ("iv_n", 0, "count of iv"),
    ("pn", 0, "edges of the path in pe/pd/pc (0: no path; -1: in the `Path` of `paths` only, set by the scalar "
               "code, until `path_to_arrays`)"),
)
F_NAMES = tuple(n for n, _v, _m in FLOATS) + tuple(f"{r}{k}" for r, _c, _m in RINGS for k in range(RECENT))
I_NAMES = tuple(n for n, _v, _m in INTS)
NF, NI = len(F_NAMES), len(I_NAMES)
F_COL = {n: j for j, n in enumerate(F_NAMES)}
I_COL = {n: j for j, n in enumerate(I_NAMES)}
_F_INIT = array("d", [v for _n, v, _m in FLOATS] + [0.0] * (RECENT * len(RINGS)))
_I_INIT = array("q", [v for _n, v, _m in INTS])


class Record:
    """The client state of `rows` entities (see the module docstring). Rows are appended, never reused while
    the record lives; growing re-allocates the blocks (numpy views taken before then are stale: `view` again)."""

    def __init__(self, capacity: int = 1, *, fleet: bool = False) -> None:
        self.rows = 0
        self.fleet = fleet  # a fleet core's record: a Player bound to it is in that fleet core already
        self.cap = 0
        self.f = array("d")
        self.i = array("q")
        self.pe = array("q")
        self.pd = array("q")
        self.pc = array("d")
        self.paths: list = []
        self._grow(max(int(capacity), 1))

    def _grow(self, cap: int) -> None:
        """New blocks of `cap` rows holding the old rows (array.array cannot resize while numpy views it)."""
        add = cap - self.cap
        for name, typecode, width in (("f", "d", NF), ("i", "q", NI), ("pe", "q", PATH_W), ("pd", "q", PATH_W),
                                      ("pc", "d", PATH_W + 1)):
            old = getattr(self, name)
            new = array(typecode, bytes(8 * width * cap))
            new[: len(old)] = old
            setattr(self, name, new)
        self.paths.extend([None] * add)
        self.cap = cap

    def new_row(self) -> int:
        """A fresh row (the fields' initial values); grows the record by doubling when full."""
        if self.rows == self.cap:
            self._grow(2 * self.cap)
        r = self.rows
        self.rows += 1
        self.f[r * NF : (r + 1) * NF] = _F_INIT
        self.i[r * NI : (r + 1) * NI] = _I_INIT
        self.paths[r] = None
        return r

    def take(self, other: Record, row: int, at: int | None = None) -> int:
        """Move `other`'s row here (into row `at`, a row no longer used, else a new row); the caller rebinds
        its parts."""
        for rec, r in ((other, row), (self, at)):  # (a slice past a block's end would resize it)
            if r is not None and not 0 <= r < rec.rows:
                raise IndexError(f"row {r} is not a row in use of the record ({rec.rows} rows)")
        r = self.new_row() if at is None else at
        self.f[r * NF : (r + 1) * NF] = other.f[row * NF : (row + 1) * NF]
        self.i[r * NI : (r + 1) * NI] = other.i[row * NI : (row + 1) * NI]
        for name, width in (("pe", PATH_W), ("pd", PATH_W), ("pc", PATH_W + 1)):
            getattr(self, name)[r * width : (r + 1) * width] = getattr(other, name)[row * width : (row + 1) * width]
        self.paths[r] = other.paths[row]
        return r

    def path_to_arrays(self, row: int) -> bool:
        """Move the row's path from its `Path` object (where the scalar code put it: `pn` -1) into the arrays
        (the object stays as their cache). False where it does not fit (wider than PATH_W) or there is none."""
        i, k = self.i, row * NI + I_COL["pn"]
        if i[k] >= 0:
            return i[k] > 0
        path = self.paths[row]
        n = len(path.edges)
        if n > PATH_W:
            return False
        if _COMPILED is not None:  # the same copy in C (`_columns.path_into_row`)
            _COMPILED.path_into_row(self.pe, self.pd, self.pc, row, PATH_W, path.edges, path.cum)
            i[k] = n
            return True
        if len(path.cum) != n + 1:  # (a slice of another length would resize the block)
            raise ValueError("a path's cum must be one longer than its edges, and the edges fit the row")
        b = row * PATH_W
        self.pe[b : b + n] = array("q", [de[0] for de in path.edges])
        self.pd[b : b + n] = array("q", [de[1] for de in path.edges])
        c = row * (PATH_W + 1)
        self.pc[c : c + PATH_W + 1] = array("d", path.cum + [math.inf] * (PATH_W - n))
        i[k] = n
        return True

    def view(self) -> dict[str, np.ndarray]:
        """numpy views of the same memory (valid until the record grows): every column by its name (a float
        or int field, rows long), the rings by their prefix (rows x RECENT), and pe, pd, pc (rows x width)."""
        fm = np.frombuffer(self.f, dtype=np.float64).reshape(self.cap, NF)
        im = np.frombuffer(self.i, dtype=np.int64).reshape(self.cap, NI)
        out = {n: fm[:, j] for n, j in F_COL.items()}
        out.update({n: im[:, j] for n, j in I_COL.items()})
        for ring, _count, _m in RINGS:
            j = F_COL[f"{ring}0"]
            out[ring] = fm[:, j : j + RECENT]
        out["pe"] = np.frombuffer(self.pe, dtype=np.int64).reshape(self.cap, PATH_W)
        out["pd"] = np.frombuffer(self.pd, dtype=np.int64).reshape(self.cap, PATH_W)
        out["pc"] = np.frombuffer(self.pc, dtype=np.float64).reshape(self.cap, PATH_W + 1)
        return out

    def nbytes_per_row(self) -> int:
        """Bytes of array state per row (the path cache's objects not counted)."""
        return 8 * (NF + NI + 3 * PATH_W + 1)


class Bound:
    """A part of one entity's client core whose fields live in a `Record` row (`bind` points it at one)."""

    __slots__ = ("_st", "_row", "_fb", "_ib")

    def bind(self, st: Record, row: int) -> None:
        """Read and write row `row` of `st` from now on: one of its rows in use (the compiled accessors do not
        check bounds, so a row outside the blocks is refused here, not read or written as stray memory)."""
        if not 0 <= row < st.rows:
            raise IndexError(f"row {row} is not a row in use of the record ({st.rows} rows)")
        self._st, self._row, self._fb, self._ib = st, row, row * NF, row * NI


def column(name: str, kind: str = "float", compiled: bool | None = None):
    """A descriptor for field `name` of the bound row: kind "float", "opt" (a float; NaN reads as None and
    None writes as NaN), "int" or "bool". The compiled one (`_columns.pyx`) where pip built it and `compiled` is
    not False, else a property whose accessors are compiled from one template (the reference: the fastest plain
    Python access, about 0.1 us a read; `name` is one of the declared fields, nothing else is formatted in)."""
    if _COMPILED is not None and compiled is not False:
        if kind in ("float", "opt"):
            return (_COMPILED.FloatCol if kind == "float" else _COMPILED.OptCol)(F_COL[name])
        return _COMPILED.IntCol(I_COL[name], kind == "bool")
    blk, base, j = ("f", "_fb", F_COL[name]) if name in F_COL else ("i", "_ib", I_COL[name])
    at = f"o._st.{blk}[o.{base} + {j}]"
    put = f"lambda o, v: o._st.{blk}.__setitem__(o.{base} + {j}, %s)"
    get, value = {"float": (at, "v"), "int": (at, "v"), "bool": (f"{at} != 0", "1 if v else 0"),
                  "opt": (None, "math.nan if v is None else v")}[kind]
    env = {"math": math}
    if get is None:  # (a statement: the value read once)
        exec(f"def get(o):\n    v = {at}\n    return None if v != v else v", env)
        fget = env["get"]
    else:
        fget = eval(f"lambda o: {get}", env)
    return property(fget, eval(put % value, env), doc=f"the row's `{name}` (entitynet/client/state.py)")


class Ring:
    """Ring `prefix` of a bound part's row as a list-like value: `get` the kept values (oldest first), `push`
    one (dropping the oldest beyond RECENT), `clear`, `put` a whole list."""

    __slots__ = ("j", "c")

    def __init__(self, prefix: str, count: str) -> None:
        self.j, self.c = F_COL[f"{prefix}0"], I_COL[count]

    def get(self, o: Bound) -> list[float]:
        """The kept values, oldest first (a new list)."""
        n = o._st.i[o._ib + self.c]
        b = o._fb + self.j
        return o._st.f[b + RECENT - n : b + RECENT].tolist()

    def push(self, o: Bound, v: float, counted: bool = True) -> None:
        """Append `v`, dropping the oldest beyond RECENT (`counted=False`: a ring sharing its count with
        another, pushed second)."""
        f, j = o._st.f, o._fb + self.j
        tail = _TAIL.unpack_from(f, 8 * (j + 1))
        f[j + RECENT - 1] = v  # (first: a value that is no number is refused, TypeError, before anything moves)
        _TAIL.pack_into(f, 8 * j, *tail)
        if counted:
            i, c = o._st.i, o._ib + self.c
            if i[c] < RECENT:
                i[c] += 1

    def put(self, o: Bound, values: list[float]) -> None:
        """Replace the kept values (at most RECENT, oldest first)."""
        n = len(values)
        if n > RECENT:
            raise ValueError(f"a ring keeps at most {RECENT} values, got {n}")
        b = o._fb + self.j
        o._st.f[b + RECENT - n : b + RECENT] = array("d", values)
        o._st.i[o._ib + self.c] = n

    def clear(self, o: Bound) -> None:
        """Keep nothing."""
        o._st.i[o._ib + self.c] = 0


def ring(prefix: str, count: str, compiled: bool | None = None):
    """Ring `prefix` (count in `count`): the compiled one (`_columns.RingCols`, the same operations) where pip
    built it and `compiled` is not False, else `Ring` (the reference)."""
    if _COMPILED is not None and compiled is not False:
        return _COMPILED.RingCols(F_COL[f"{prefix}0"], I_COL[count], RECENT)
    return Ring(prefix, count)
