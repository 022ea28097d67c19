"""The ghost rules' one home: every viewer's received entities of a process in one table of arrays.

Why a table: a simulation holds hundreds of viewers in one process, and the server fans one UPDATE out to every
viewer of its cells, so the same message reaches each of them. A dict of `Ghost` objects per viewer cost a
`Ghost` per viewer per message and a walk of every viewer's ghosts at every truth sample (about 1 us per ghost);
reading such dicts into arrays costs as much as walking them (docs/simulation.md). Here a message becomes one
*version* (its entity's row, seq, expiry in receiver time, decoded model, claimed cells) shared by every viewer
that takes it, and a viewer holds an entity by the version index in its column of `held` (rows: entities,
columns: viewers, -1: none). The rules apply over arrays, in bulk:

- an UPDATE replaces what a viewer holds of its entity only with a higher sequence number; an undecodable
  payload (PayloadError) is counted per viewer (`bad_payloads`) when its seq is newer, and changes nothing;
- a ghost lives `min(validity, limits.HORIZON)` seconds after its UPDATE arrived (`now` at receipt), and is
  dropped when `expire(now)` finds `now >= expires` (ghosts kept while invisible: reference section 4.4);
- LEAVE drops the entity from that viewer (an unknown entity: nothing); `clear` (a WELCOME: entity ids are per
  server session) drops all of a viewer's ghosts.

Messages are queued and applied when something reads the table; a queue in which every (entity, viewer) pair
appears at most once gives the same result applied at once as one by one, so a pair seen twice applies the
queue first. The public per-viewer API is `entitynet.client.GhostStore`, a view of one column; a single
viewer is a table of one column. Bounded: versions no viewer holds any more are dropped, and rows no viewer
holds are reused, when the version count doubles (`_compact`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from itertools import chain

import numpy as np

from entitynet.client.limits import HORIZON
from entitynet.client.motion import Model
from entitynet.client.network import NetView
from entitynet.client.optional_c import compiled
from entitynet.client.payload import PayloadError, decode
from entitynet.protocol import Leave, Update

_I64 = (-(2**63), 2**63 - 1)
_COL_BITS = 24  # a queued (row, column) pair's key: row << _COL_BITS | column


def csr_take(off: np.ndarray, flat: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The entries of the CSR rows `idx` (row k holds `flat[off[k]:off[k + 1]]`), flattened in order: for each
    entry the position in `idx` of its row, and its value."""
    start = off[idx]
    n = off[idx + 1] - start
    at = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + np.repeat(start, n)
    return np.repeat(np.arange(len(idx)), n), flat[at]


def _grow(a: np.ndarray, n: int, fill) -> np.ndarray:
    """`a` with room for at least `n` along its first axis (doubling), new slots set to `fill`."""
    if n <= len(a):
        return a
    out = np.full((max(n, 2 * len(a)),) + a.shape[1:], fill, dtype=a.dtype)
    out[:len(a)] = a
    return out


def _check(m) -> None:
    """Refuse a message the table cannot take (`receive` without `decoded`): TypeError or ValueError."""
    if type(m) is not Update and type(m) is not Leave:
        raise TypeError(f"a ghost table takes UPDATE and LEAVE, not {type(m).__name__}")
    if not (type(m.entity) is int and _I64[0] <= m.entity <= _I64[1]):
        raise ValueError(f"entity must be a 64-bit integer, got {m.entity!r}")
    if type(m) is Update:
        if not (type(m.seq) is int and _I64[0] <= m.seq <= _I64[1]):
            raise ValueError(f"seq must be a 64-bit integer, got {m.seq!r}")
        try:
            np.array(m.cells, dtype=np.int64).reshape(-1)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"cells must be 64-bit integers, got {m.cells!r:.80}") from None


def queue_messages(msgs: list, col: int, version_of: dict, rows: list, row_of: dict, pairs: set, q_col: list,
                   q_ver: list, update: type, new_version: Callable, flush: Callable, now: float) -> int:
    """The table's per-message step (the reference; `_ghost_queue.pyx` compiles it): each message's version
    (`new_version` for one not seen at this `now`) or, for a LEAVE, its entity's row, queued for column `col`
    (the queue applied first, `flush`, where the (entity, viewer) pair is queued already); how many were
    LEAVEs."""
    leaves = 0
    for m in msgs:
        if type(m) is update:
            ver = version_of.get(id(m))
            if ver is None:
                ver = new_version(m, now)
            row = rows[ver]
        else:
            leaves += 1
            row = row_of.get(m.entity, -1)
            if row < 0:
                continue  # LEAVE of an entity no viewer holds
            ver = -1 - row  # a queued LEAVE: its row, below zero
        key = row << _COL_BITS | col
        if key in pairs:
            flush()
        pairs.add(key)
        q_col.append(col)
        q_ver.append(ver)
    return leaves


_queue = queue_messages
_COMPILED = compiled("_ghost_queue")  # the per-message step compiled
if _COMPILED is not None:
    _queue = _COMPILED.queue_messages


def compiled_in_use() -> bool:
    """Whether the compiled per-message step is the one running in this process."""
    return _queue is not queue_messages


class GhostTable:
    """The received entities of many viewers (columns) over shared versions of the messages (see the module
    docstring). `decoder`: payload bytes -> model, raising PayloadError (default: `payload.decode` on `net`)."""

    def __init__(self, net: NetView | None, decoder: Callable[[bytes], Model] | None = None) -> None:
        self.net = net
        self.decoder: Callable[[bytes], Model] = decoder if decoder is not None else self.decode_payload
        self.held = np.full((64, 4), -1, dtype=np.int64)  # row x column -> version (-1: none)
        self._row_of: dict[int, int] = {}  # entity id -> row
        self._entity = np.zeros(64, dtype=np.int64)  # row -> entity id
        self._free_rows: list[int] = []
        self._n_rows = 0
        self.n_cols = 0
        self.clock_offset: list[float] = []  # column -> add to a payload's t0 to get receiver time
        self.visible: list[frozenset[int]] = []  # column -> the cells it sees (its PVS)
        #: column -> (a mask over its visible cell ids or None where they are too far apart, the first id, the ids)
        self._visible_mask: list[tuple[np.ndarray | None, int, np.ndarray] | None] = []
        self.bad = np.zeros(4, dtype=np.int64)  # column -> undecodable payloads counted
        # versions: one per distinct message taken at one `now`
        self.vseq = np.zeros(64, dtype=np.int64)
        self.vexp = np.zeros(64, dtype=np.float64)
        self.vrow = np.zeros(64, dtype=np.int64)
        self.vok = np.zeros(64, dtype=bool)  # the payload decoded
        self.voff = np.zeros(65, dtype=np.int64)  # claimed cells of version k: vcells[voff[k]:voff[k + 1]]
        self.vcells = np.zeros(256, dtype=np.int64)
        self.vmid = np.zeros(64, dtype=np.int64)  # version -> its model's index in `models`
        self.models: list[Model | None] = []  # the distinct decoded models (None: undecodable), shared by versions
        self._model_of: dict[int, int] = {}  # id(model) -> its index (the model kept alive in `models`)
        self.vmsg: list[Update] = []
        self._vrow_list: list[int] = []
        self._version_of: dict[int, int] = {}  # id(message) -> its version at `_version_now`
        self._version_now: float | None = None
        self._compact_at = 4096
        #: versions taken but not yet in the arrays: (seq, expiry, row, decoded, model index, cells) (`_commit`)
        self._pending: list[tuple] = []
        # the queue (see the module docstring)
        self._q_col: list[int] = []
        self._q_ver: list[int] = []  # a version, or for a LEAVE -1 - its row
        self._q_pairs: set[int] = set()

    # ---- columns ---------------------------------------------------------------------------------------------
    def add_viewer(self, clock_offset: float = 0.0) -> int:
        """A new column (a viewer with no ghosts); its index."""
        col = self.n_cols
        if col >= 1 << _COL_BITS:
            raise ValueError(f"a ghost table holds at most {1 << _COL_BITS} viewers")
        if col >= self.held.shape[1]:
            wider = np.full((self.held.shape[0], 2 * self.held.shape[1]), -1, dtype=np.int64)
            wider[:, :col] = self.held
            self.held = wider
        self.bad = _grow(self.bad, col + 1, 0)
        self.n_cols += 1
        self.clock_offset.append(clock_offset)
        self.visible.append(frozenset())
        self._visible_mask.append(None)
        return col

    def set_visible(self, col: int, cells: Iterable[int]) -> None:
        """The cells viewer `col` currently sees (only ghosts with a claimed cell among them are drawn)."""
        self.visible[col] = frozenset(cells)
        self._visible_mask[col] = None

    @property
    def n_rows(self) -> int:
        """Rows in use or free (entity ids seen since the last compaction that freed them)."""
        return self._n_rows

    # ---- receiving -------------------------------------------------------------------------------------------
    def decode_payload(self, data: bytes) -> Model:
        """The default decoder: `payload.decode` on the table's map."""
        return decode(data, self.net)

    def receive(self, col: int, msgs: Iterable[Update | Leave], now: float, decoded: bool = False) -> int:
        """Take a frame's UPDATEs and LEAVEs for viewer `col`, in order, arrived at receiver time `now`; how many
        were LEAVEs. Anything else (another message type, an id or seq that is not a 64-bit integer, cells that
        are not 64-bit integers) is refused with TypeError or ValueError before anything of the frame is taken,
        unless `decoded`: the messages come from the protocol's codec (ids, seqs and cells in [0, 2**53]) and
        are all UPDATEs and LEAVEs (the viewer fleet's frames, which the session checked:
        `ClientSession.delivers_whole`). The frame is queued in one call (`queue_messages`, compiled where
        pip built `_ghost_queue`)."""
        if not decoded or not isinstance(msgs, list):
            msgs = list(msgs)
        if not decoded:
            for m in msgs:
                _check(m)
        if now != self._version_now:  # a version's expiry is its message's `now + life`
            self._version_of.clear()
            self._version_now = now
        return _queue(msgs, col, self._version_of, self._vrow_list, self._row_of, self._q_pairs, self._q_col,
                      self._q_ver, Update, self._new_version, self.flush, now)

    def _new_version(self, m: Update, now: float) -> int:
        """The version of message `m` taken at `now` (its payload decoded once, here). Its arrays' entries wait
        in the pending lists until something reads them (`_commit`, in bulk): growing six arrays per version
        cost about 12 us, a third of the table's work per delivery at 20-30 viewers per message."""
        if len(self.vmsg) >= self._compact_at:
            self._compact()
        row = self._row_of.get(m.entity)
        if row is None:
            row = self._new_row(m.entity)
        try:
            model: Model | None = self.decoder(m.payload)
        except PayloadError:
            model = None
        k = len(self.vmsg)
        mid = self._model_of.get(id(model))
        if mid is None:
            mid = self._model_of[id(model)] = len(self.models)
            self.models.append(model)
        self._pending.append((m.seq, now + min(m.validity_ms / 1000.0, HORIZON), row, model is not None, mid,
                              m.cells))
        self.vmsg.append(m)
        self._vrow_list.append(row)
        self._version_of[id(m)] = k
        return k

    def _commit(self) -> None:
        """The pending versions' entries into the arrays, in one pass."""
        pend = self._pending
        if not pend:
            return
        k0, n = len(self.vmsg) - len(pend), len(pend)
        k1 = k0 + n
        seq, exp, row, ok, mid, cells = zip(*pend, strict=True)
        pend.clear()
        for name, vals, fill in (("vseq", seq, 0), ("vexp", exp, 0.0), ("vrow", row, 0), ("vok", ok, False),
                                 ("vmid", mid, 0)):
            arr = _grow(getattr(self, name), k1, fill)
            arr[k0:k1] = vals
            setattr(self, name, arr)
        try:  # the codec's cells: flat tuples of ints
            lens = np.fromiter(map(len, cells), dtype=np.int64, count=n)
            flat = np.fromiter(chain.from_iterable(cells), dtype=np.int64, count=int(lens.sum()))
        except (TypeError, ValueError):  # other shapes `_check` let through (nested lists, arrays): flattened
            parts = [np.array(c, dtype=np.int64).reshape(-1) for c in cells]
            lens = np.array([len(c) for c in parts], dtype=np.int64)
            flat = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
        self.voff = _grow(self.voff, k1 + 1, 0)
        a = int(self.voff[k0])
        self.voff[k0 + 1:k1 + 1] = a + np.cumsum(lens)
        self.vcells = _grow(self.vcells, a + len(flat), 0)
        self.vcells[a:a + len(flat)] = flat

    def _new_row(self, entity: int) -> int:
        if self._free_rows:
            row = self._free_rows.pop()
        else:
            row = self._n_rows
            self._n_rows += 1
            if row >= self.held.shape[0]:
                self.held = _grow(self.held, row + 1, -1)
                self._entity = _grow(self._entity, row + 1, 0)
        self._row_of[entity] = row
        self._entity[row] = entity
        return row

    def flush(self) -> None:
        """Apply the queued messages (each (entity, viewer) pair once in the queue: as if one by one)."""
        self._commit()
        if not self._q_ver:
            return
        cols = np.array(self._q_col, dtype=np.int64)
        vers = np.array(self._q_ver, dtype=np.int64)
        self._q_col.clear()
        self._q_ver.clear()
        self._q_pairs.clear()
        leave = vers < 0
        rows = np.where(leave, -1 - vers, self.vrow[np.maximum(vers, 0)])
        vers[leave] = -1  # what a LEAVE leaves held: none
        cur = self.held[rows, cols]
        has = cur >= 0
        newer = np.ones(len(vers), dtype=bool)
        upd = ~leave
        held_seq = self.vseq[cur[upd & has]]
        newer[np.flatnonzero(upd & has)] = self.vseq[vers[upd & has]] > held_seq
        ok = self.vok[np.where(leave, 0, vers)]
        bad = upd & newer & ~ok
        if bad.any():
            np.add.at(self.bad, cols[bad], 1)
        take = leave | (newer & ok)
        self.held[rows[take], cols[take]] = vers[take]  # a LEAVE's version is -1: none

    def clear(self, col: int) -> None:
        """Drop every ghost of viewer `col` (after a WELCOME: entity ids are per server session)."""
        self.flush()
        self.held[:, col] = -1

    def expire(self, col: int, now: float) -> list[int]:
        """Drop viewer `col`'s ghosts whose validity ran out (`now >= expires`); their entity ids."""
        rows, _vers, gone = self._expire_pass(col, now)
        return self._entity[rows[gone]].tolist()

    def live_rows(self, col: int, now: float) -> tuple[np.ndarray, np.ndarray]:
        """`expire(col, now)` then `rows_of(col)` in one pass over the viewer's column (the truth measure reads
        every sampled viewer's ghosts so): the rows and versions of the ghosts still valid at `now`."""
        rows, vers, gone = self._expire_pass(col, now)
        keep = ~gone
        return rows[keep], vers[keep]

    def _expire_pass(self, col: int, now: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Viewer `col`'s held rows and versions (after the queue is applied) and which of them ran out at
        `now`, those dropped: the one pass of `expire` and `live_rows`."""
        self.flush()
        held = self.held[:self._n_rows, col]
        rows = np.flatnonzero(held >= 0)
        vers = held[rows]
        gone = now >= self.vexp[vers]
        self.held[rows[gone], col] = -1
        return rows, vers, gone

    # ---- reading ---------------------------------------------------------------------------------------------
    def rows_of(self, col: int) -> tuple[np.ndarray, np.ndarray]:
        """Viewer `col`'s ghosts: their rows and versions, in row order (after the queue is applied)."""
        self.flush()
        held = self.held[:self._n_rows, col]
        rows = np.flatnonzero(held >= 0)
        return rows, held[rows]

    def entity(self, rows: np.ndarray) -> np.ndarray:
        """The entity ids of `rows`."""
        return self._entity[rows]

    def visible_versions(self, col: int, versions: np.ndarray) -> np.ndarray:
        """Which of `versions` claim a cell that viewer `col` sees (a bool per version)."""
        vis = self.visible[col]
        if not vis or not len(versions):
            return np.zeros(len(versions), dtype=bool)
        got = self._visible_mask[col]
        if got is None:
            cells = np.fromiter(vis, dtype=np.int64, count=len(vis))
            lo = int(cells.min())
            span = int(cells.max()) - lo + 2  # the last slot: a cell outside the range
            mask = None
            if span <= 4 * len(cells) + (1 << 20):  # else a set of far-apart ids (bad input): `isin`, no mask
                mask = np.zeros(span, dtype=bool)
                mask[cells - lo] = True
            got = self._visible_mask[col] = (mask, lo, cells)
        mask, lo, vis_cells = got
        owner, cells = csr_take(self.voff, self.vcells, versions)
        seen = np.zeros(len(versions), dtype=bool)
        if mask is None:
            seen[owner[np.isin(cells, vis_cells)]] = True
            return seen
        idx = cells - lo
        idx[(idx < 0) | (idx >= len(mask) - 1)] = len(mask) - 1
        seen[owner[mask[idx]]] = True
        return seen

    def model(self, version: int) -> Model | None:
        """The decoded model of version `version` (None: its payload did not decode)."""
        self._commit()
        return self.models[self.vmid[version]]

    def cells_of(self, version: int) -> tuple[int, ...]:
        """The cells version `version`'s UPDATE claimed."""
        return self.vmsg[version].cells

    # ---- bounds ----------------------------------------------------------------------------------------------
    def _compact(self) -> None:
        """Drop the versions no viewer holds and free the rows no viewer holds (the queue applied first)."""
        self.flush()
        n = self._n_rows
        held = self.held[:n, :self.n_cols]
        live = np.unique(held[held >= 0])
        new_of = np.full(len(self.vmsg), -1, dtype=np.int64)
        new_of[live] = np.arange(len(live))
        hit = held >= 0
        held[hit] = new_of[held[hit]]
        counts = self.voff[live + 1] - self.voff[live]
        cells = csr_take(self.voff, self.vcells, live)[1]
        self.vcells = cells if len(cells) else np.zeros(256, dtype=np.int64)
        self.voff = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        for name in ("vseq", "vexp", "vrow", "vok", "vmid"):
            setattr(self, name, getattr(self, name)[live].copy())
        keep = live.tolist()
        mids, self.vmid = np.unique(self.vmid, return_inverse=True)
        self.models = [self.models[k] for k in mids.tolist()]
        self._model_of = {id(m): k for k, m in enumerate(self.models)}
        self.vmsg = [self.vmsg[k] for k in keep]
        self._vrow_list[:] = [self._vrow_list[k] for k in keep]  # in place: `receive` holds it
        # this `now`'s messages keep their versions where those live on (in place: `receive` holds the dict);
        # clearing it made every later viewer of a message in the tick take a new version of it
        moved = {key: int(new_of[k]) for key, k in self._version_of.items() if new_of[k] >= 0}
        self._version_of.clear()
        self._version_of.update(moved)
        for row in np.flatnonzero(~hit.any(axis=1)).tolist():
            ent = int(self._entity[row])
            if self._row_of.get(ent) == row:
                del self._row_of[ent]
                self._free_rows.append(row)
        self._compact_at = max(4096, 2 * len(keep))
