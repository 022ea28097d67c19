"""The Player's and the network tracker's fields in a client-state row (entitynet/client/state.py): the last
fix and publish times; the along-path filter, the path, the recent path coordinates, the hysteresis candidate,
the dead end and the last fix placed, read and written by `Player` and `NetworkTracker` through these
properties and by the fleet core (fleet.py) over the columns.

Why a module of its own: the fields that are not plain numbers (a `Path`, a `Fix`, tuples, a ring) need a few
lines each to map onto columns; the tracker's decisions read better without them.
"""

from __future__ import annotations

from bisect import bisect_right

from entitynet.client.filters import RowKinematic
from entitynet.client.network import DirEdge
from entitynet.client.path import Path
from entitynet.client.placement import Fix, _new_fix
from entitynet.client.state import _COMPILED, F_COL, I_COL, PATH_W, Bound, Record, column, ring

_RS = ring("rs", "rs_n")
_LF_OFF = F_COL["lf_off"]
_KF_ON, _PN, _PEND_N, _DEAD_D, _LF_E = I_COL["kf_on"], I_COL["pn"], I_COL["pend_n"], I_COL["dead_d"], I_COL["lf_e"]
_KINDS = (None, "edge", "area")
_MX = F_COL["mx"]  # (mx, my: adjacent columns)
# the Player's per-fix fields, read and written by index in `Player.feed` (its hot path)
_LAST_T, _OFF_SINCE, _PUB_T, _KV = F_COL["last_t"], F_COL["off_since"], F_COL["pub_t"], F_COL["kv"]
_HALTED = I_COL["halted"]
assert F_COL["my"] == _MX + 1


class PlayerState(Bound):
    """The Player's row fields as attributes, and the move of its whole row (its parts' too) to a record."""

    last_t = column("last_t", "opt")
    pub_t = column("pub_t")
    off_since = column("off_since", "opt")

    def own_record(self) -> Record:
        """A record of one row for this Player alone, bound (what a Player starts with)."""
        rec = Record(1)
        self.bind(rec, rec.new_row())
        return rec

    def move_to(self, rec: Record, at: int | None = None) -> int:
        """Move this entity's row into `rec` (a fleet's record; into its row `at`, one no longer used, else a
        new one): the row there is its state from now on (the old one is left behind, unused). Returns it."""
        row = rec.take(self._st, self._row, at)
        for part in (self, self.rules, self.tracker):  # (the parts are set by the Player)
            if part is not None:
                part.bind(rec, row)
        return row

    @property
    def measured(self) -> tuple[float, float, float] | None:
        """The last fix (x, y, t) as fed, or None before the first."""
        t = self.last_t
        return None if t is None else (self._st.f[self._fb + _MX], self._st.f[self._fb + _MX + 1], t)

    @measured.setter
    def measured(self, value: tuple[float, float, float]) -> None:
        """Write the row's `measured` (the same fields the getter reads)."""
        f, b = self._st.f, self._fb + _MX
        f[b], f[b + 1] = value[0], value[1]
        self.last_t = value[2]


class TrackerState(Bound):
    """The tracker's row fields as attributes (`net` is the tracker's network view, for the `Path`)."""

    reach = column("reach")
    dist_ema = column("dist_ema")
    reverse_count = column("rev", "int")
    vpeak = column("vpeak")
    vpeak_t = column("vpeak_t")

    def bind(self, st: Record, row: int) -> None:
        """Read and write row `row` of `st` from now on (the filter too)."""
        Bound.bind(self, st, row)
        self._kf.bind(st, row)

    # ---- the row's fields that are not plain numbers -----------------------------------------------------
    @property
    def kf(self) -> RowKinematic | None:
        """The along-path filter (on an edge), or None."""
        return self._kf if self._st.i[self._ib + _KF_ON] else None

    @kf.setter
    def kf(self, value: None) -> None:
        """Write the row's `kf` (the same fields the getter reads)."""
        if value is not None:
            raise ValueError("the along-path filter is the row's: start it with `_start_filter`")
        self._st.i[self._ib + _KF_ON] = 0

    def _start_filter(self, s: float, t: float, r: float) -> None:
        self._st.i[self._ib + _KF_ON] = 1
        self._kf.reset(s, t, r, q=self.filter_q, accel=self.filter_accel)

    def _path_from_arrays(self) -> Path | None:
        """The row's path as a `Path` built from its arrays (and cached there), or None without one."""
        st, row = self._st, self._row
        n = st.i[self._ib + _PN]
        if n <= 0:
            return None
        b = row * PATH_W
        p = st.paths[row] = Path(self.net, list(zip(st.pe[b : b + n].tolist(), st.pd[b : b + n].tolist(),
                                                    strict=True)),
                                 _cum=st.pc[row * (PATH_W + 1) : row * (PATH_W + 1) + n + 1].tolist())
        return p

    def path_from(self, start: float) -> tuple[Path, float]:
        """The path followed from the edge holding `start` on (`path.suffix(path.index(start))`) and its shift
        of s (`path.cum` there). Where the path is in the row's arrays only (the fleet core trimmed or extended
        it), the part is built from them at once: the whole path as an object is not needed for a publish."""
        st, row = self._st, self._row
        n = st.i[self._ib + _PN]
        if n <= 0 or st.paths[row] is not None:
            return self.path.part_from(start)
        c = row * (PATH_W + 1)
        k = bisect_right(st.pc, start, c, c + n + 1) - 1 - c  # (`Path.index` over the same values)
        k = 0 if k < 0 else (k if k < n else n - 1)
        cum = st.pc[c + k : c + n + 1].tolist()
        c0 = cum[0]
        if k or c0 != 0.0:  # (`Path.suffix`: from edge 0 with cum[0] 0.0 the same coordinates)
            cum = [x - c0 for x in cum]
        b = row * PATH_W
        edges = list(zip(st.pe[b + k : b + n].tolist(), st.pd[b + k : b + n].tolist(), strict=True))
        return Path(self.net, edges, _cum=cum), c0

    @property
    def path(self) -> Path | None:
        """The path followed (on an edge): the row's pe/pd/pc, as an immutable `Path` built once per change
        (a cache of the arrays, dropped by whoever changes them: the setter here, the fleet core's trims)."""
        p = self._st.paths[self._row]
        return self._path_from_arrays() if p is None else p

    @path.setter
    def path(self, path: Path | None) -> None:
        """Write the row's `path` (the same fields the getter reads)."""
        self._st.paths[self._row] = path
        # the new Path is the one home of the path until the fleet core moves it into the arrays (`Record.
        # path_to_arrays`): a Player alone never needs them, and a fix often changes the path twice
        self._st.i[self._ib + _PN] = 0 if path is None else -1

    @property
    def recent_s(self) -> list[float]:
        """Path coordinates of the last few fixes (oldest first; a new list)."""
        return _RS.get(self)

    @recent_s.setter
    def recent_s(self, values: list[float]) -> None:
        """Write the row's `recent_s` (the same fields the getter reads)."""
        _RS.put(self, values)

    @property
    def pending(self) -> tuple[int, int]:
        """The hysteresis' candidate: (edge or -2 - area, fixes in a row), (-1, 0) for none."""
        i, b = self._st.i, self._ib + _PEND_N
        return i[b - 1], i[b]

    @pending.setter
    def pending(self, value: tuple[int, int]) -> None:
        """Write the row's `pending` (the same fields the getter reads)."""
        i, b = self._st.i, self._ib + _PEND_N
        i[b - 1], i[b] = value

    @property
    def dead_end(self) -> DirEdge | None:
        """The path's last edge where nothing followed (not asked again), or None."""
        i, b = self._st.i, self._ib + _DEAD_D
        return None if i[b - 1] < 0 else (i[b - 1], i[b])

    @dead_end.setter
    def dead_end(self, value: DirEdge | None) -> None:
        """Write the row's `dead_end` (the same fields the getter reads)."""
        i, b = self._st.i, self._ib + _DEAD_D
        i[b - 1], i[b] = (-1, 0) if value is None else value

    @property
    def last_fix(self) -> Fix | None:
        """The last fix as placed on the network (or in an area), or None."""
        i, b = self._st.i, self._ib + _LF_E
        kind = _KINDS[i[b - 1]]
        if kind is None:
            return None
        f, c = self._st.f, self._fb + _LF_OFF
        return _new_fix(Fix, (kind, i[b], f[c], f[c + 1], f[c + 2], f[c + 3]))

    def last_fix_xy(self) -> tuple[float, float] | None:
        """(x, y) of `last_fix`, or None (the Player's per-fix read, without building the Fix)."""
        if not self._st.i[self._ib + _LF_E - 1]:
            return None
        f, c = self._st.f, self._fb + _LF_OFF
        return f[c + 1], f[c + 2]

    @last_fix.setter
    def last_fix(self, fix: Fix | None) -> None:
        """Write the row's `last_fix` (the same fields the getter reads)."""
        i, b = self._st.i, self._ib + _LF_E
        if fix is None:
            i[b - 1] = 0
            return
        i[b - 1], i[b] = (1 if fix[0] == "edge" else 2), fix[1]
        f, c = self._st.f, self._fb + _LF_OFF
        f[c], f[c + 1], f[c + 2], f[c + 3] = fix[2], fix[3], fix[4], fix[5]


if _COMPILED is not None:  # the same accessors compiled (`_columns.pyx`), where pip built them
    TrackerState.kf = _COMPILED.FlagRef(_KF_ON, "_kf")
    TrackerState.path = _COMPILED.PathRef(_PN)
