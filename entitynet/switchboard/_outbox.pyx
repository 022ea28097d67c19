# cython: language_level=3, boundscheck=False, wraparound=False
"""The compiled outboxes: every client's pending entity states in C arrays instead of a Python dict per client.

Why: at the standard load the route stores each PUBLISH's UPDATE into a few hundred per-viewer dicts, and each
store is a chain of dependent cache misses (the dict, its keys object, the index slot, the entry): `perf` put
39 % of the server's samples there and in the set work around it. Here a store is an append of an int:

- per viewer (a *viewer slot*, reused after a client is gone) a growable C array of pending items in
  first-queued order, each an *entity slot* and either NULL ("the entity's shared bytes") or bytes of its own;
- per entity (an *entity slot*, keyed by entity id, freed once the entity is gone and nothing is pending) the
  shared bytes `cur` that plain items read when they are taken, and a row of 2 bits per viewer slot (pending;
  own bytes) that deduplicates: an entity's row is contiguous within a block, so the route's checks for its
  few hundred viewers touch a few cache lines, not a dict per viewer.

The (entity slot x viewer slot) 2-bit matrix is kept in blocks of 64 entity slots x 256 viewer slots (4 KiB),
a block allocated only while one of its entries is pending (emptied blocks go to a small pool): memory is
bounded by the pending states (at most 4 KiB each, never more than the dense E x V / 4 bytes) plus a pointer
per block position (E x V / 2048 bytes), not by every entity times every connection (a publisher that views
nothing costs its viewer slot's box, never a column of bits).

The same bytes for many viewers (`fan_out`, `fan_out_to` and the compiled route: the UPDATE of a PUBLISH) are
stored once, as the slot's `cur`, and each viewer gets a plain item (or keeps the one it has: coalescing). Any
other store (`put_state`, a LEAVE, an identity's encoding) is an item with its own bytes. Exactly the dict
outboxes' behaviour (`entitynet.switchboard.outbox.Outbox`, the reference): a newer state replaces a pending
one and keeps its place; a viewer keeps the bytes it was last given: when a fan-out changes `cur`, plain items
of viewers it did not reach (a client detached while its states wait behind its last word, or any caller of
the table) first get the old bytes as their own (`end_plain`; the core never needs it on its hot path).
Tests compare both outboxes on hostile sequences (tests/entitynet/switchboard/test_outbox_compiled.py).
"""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize, PyBytes_GET_SIZE
from cpython.dict cimport PyDict_GetItem
from cpython.ref cimport Py_DECREF, Py_INCREF, PyObject
from libc.stdlib cimport calloc, free, realloc
from libc.string cimport memcpy, memmove, memset

cimport cython

cdef enum:
    SHRINK_ABOVE = 1024  # an emptied box with more room than this gives it back

# A client id indexes an int array (`vslot_of`): ids beyond this are refused rather than sizing it past 1 GiB.
MAX_CID = (1 << 28) - 1


include "_blocks.pxi"  # the 2-bit matrix in blocks: `_st`, `_set`, `_reserve`, grid growth


cdef inline PyObject *_enc(OutboxTable t, Item *it) noexcept:
    """An item's bytes: its own, or its entity's shared ones."""
    return it.enc if it.enc != NULL else t.ents[it.slot].cur


@cython.no_gc_clear  # a collected table must outlive its outboxes' `__dealloc__` (they give their slots back)
@cython.auto_pickle(False)
cdef class OutboxTable:
    """The outboxes of all clients (`Outboxes`' API): `open(cid)` gives a client's `COutbox` (the `Outbox` API),
    the fan-out calls queue the same bytes for many clients, `forget(eid)` says an entity is gone."""

    def __cinit__(self, Py_ssize_t max_states, Py_ssize_t max_control):
        self.max_states = max_states
        self.max_control = max_control
        self.slot_of = {}
        self.free_vs = []
        self.free_es = []
        self._boxes = {}
        self.f_slot = -1
        self._grow_v(64)
        self._grow_e(256)

    def __dealloc__(self):
        cdef Py_ssize_t s, vs, i, k
        for vs in range(self.n_vslots):
            for i in range(self.boxes[vs].n):
                if self.boxes[vs].items[i].enc != NULL:
                    Py_DECREF(<object>self.boxes[vs].items[i].enc)
            free(self.boxes[vs].items)
        for s in range(self.n_eslots):
            if self.ents[s].cur != NULL:
                Py_DECREF(<object>self.ents[s].cur)
            if self.ents[s].eid != NULL:
                Py_DECREF(<object>self.ents[s].eid)
        for k in range((self.ecap >> BR) * self.nbv):
            free(self.blk[k])
        for k in range(self.n_pool):
            free(self.pool[k])
        free(self.pool)
        free(self.blk)
        free(self.blk_n)
        free(self.boxes)
        free(self.ents)
        free(self.vstamp)
        free(self.vslot_of)

    # -------------------------------------------------------------------------------------- growth, slots
    def __copy__(self):
        raise TypeError("an OutboxTable cannot be copied (it owns C arrays)")

    def __deepcopy__(self, memo):
        raise TypeError("an OutboxTable cannot be copied (it owns C arrays)")

    def __reduce__(self):
        raise TypeError("an OutboxTable cannot be pickled (it owns C arrays)")

    # -------------------------------------------------------------------------------------- growth, slots
    cdef int _grow_v(self, Py_ssize_t need) except -1:
        """Room for viewer slots below `need`: boxes, stamps, and a wider block grid (no bits move)."""
        cdef Py_ssize_t cap
        if need <= self.vcap:
            return 0
        cap = max(need, 2 * self.vcap, 1 << BV)
        cap = (cap + VMASK) >> BV << BV
        boxes = <Box *>realloc(self.boxes, cap * sizeof(Box))
        if boxes == NULL:
            raise MemoryError()
        self.boxes = boxes
        stamp = <unsigned int *>realloc(self.vstamp, cap * sizeof(unsigned int))
        if stamp == NULL:
            raise MemoryError()
        self.vstamp = stamp
        _regrid(self, self.ecap >> BR, cap >> BV)
        memset(self.boxes + self.vcap, 0, (cap - self.vcap) * sizeof(Box))
        memset(self.vstamp + self.vcap, 0, (cap - self.vcap) * sizeof(unsigned int))
        self.vcap = cap
        return 0

    cdef int _grow_e(self, Py_ssize_t need) except -1:
        """Room for entity slots below `need`: entities and a taller block grid."""
        cdef Py_ssize_t cap
        if need <= self.ecap:
            return 0
        cap = max(need, 2 * self.ecap, 1 << BR)
        cap = (cap + RMASK) >> BR << BR
        ents = <Ent *>realloc(self.ents, cap * sizeof(Ent))
        if ents == NULL:
            raise MemoryError()
        self.ents = ents
        _regrid(self, cap >> BR, self.nbv)
        memset(self.ents + self.ecap, 0, (cap - self.ecap) * sizeof(Ent))
        self.ecap = cap
        return 0

    cdef Py_ssize_t slot_for(self, object eid) except -1:
        """The entity's slot, made on its first store."""
        cdef PyObject *p = PyDict_GetItem(self.slot_of, eid)
        cdef Py_ssize_t s
        if p != NULL:
            return <Py_ssize_t><object>p
        if self.free_es:
            s = self.free_es.pop()
        else:
            self._grow_e(self.n_eslots + 1)
            s = self.n_eslots
            self.n_eslots += 1
        self.slot_of[eid] = s
        Py_INCREF(eid)
        self.ents[s].eid = <PyObject *>eid
        self.ents[s].released = False
        return s

    cdef void _free_ent(self, Py_ssize_t s) noexcept:
        cdef Ent *e = &self.ents[s]
        cdef object eid = <object>e.eid
        if e.cur != NULL:
            Py_DECREF(<object>e.cur)
            e.cur = NULL
        Py_DECREF(eid)  # `eid` holds its own reference until the end of this function
        e.eid = NULL
        e.released = False
        try:
            del self.slot_of[eid]
            self.free_es.append(s)
        except BaseException:  # only MemoryError is possible: the slot stays unused
            pass

    cdef int vslot(self, long cid) noexcept:
        """The open client's viewer slot, -1 for a client id that is not open."""
        if cid < 0 or cid >= self.n_cid:
            return -1
        return self.vslot_of[cid]

    # -------------------------------------------------------------------------------------- storing
    cdef int _append(self, int vs, Py_ssize_t s, PyObject *enc) except -1:
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t cap
        cdef Item *items
        if b.n == b.cap:
            cap = max(8, 2 * b.cap)
            items = <Item *>realloc(b.items, cap * sizeof(Item))
            if items == NULL:
                raise MemoryError()
            b.items, b.cap = items, cap
        b.items[b.n].slot = s
        b.items[b.n].enc = enc
        b.n += 1
        self.ents[s].pending += 1
        return 0

    cdef Py_ssize_t _find(self, int vs, Py_ssize_t s) noexcept:
        """The position of the entity's pending item in the box (one is pending: its bit says so)."""
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t i
        for i in range(b.n):
            if b.items[i].slot == s:
                return i
        return -1

    cdef int begin_plain(self, Py_ssize_t s, bytes enc) except -1:
        """Start a fan-out of `enc` for entity slot `s` (then `put_plain` per viewer, then `end_plain`)."""
        cdef Ent *e = &self.ents[s]
        self.fgen += 1
        if self.fgen == 0:
            memset(self.vstamp, 0, self.vcap * sizeof(unsigned int))
            self.fgen = 1
        self.f_slot, self.f_before, self.f_hits, self.f_active = s, e.plain, 0, True
        self.f_kbase, self.f_wbase = (s >> BR) * self.nbv, (s & RMASK) * RWORDS  # (no slot opens mid-fan-out)
        self.f_prev = e.cur  # its reference moves to f_prev until `end_plain`
        Py_INCREF(enc)
        e.cur = <PyObject *>enc
        return 0

    cdef int put_plain(self, int vs) except -1:
        """The fan-out's bytes for viewer slot `vs` (once per fan-out; coalesced with a pending state). The route's
        hot path: `_st`/`_set` inlined here, the block and word found once."""
        cdef Py_ssize_t s = self.f_slot, i, k
        cdef unsigned long long *w
        cdef unsigned long long st
        cdef int sh
        if vs < 0 or self.vstamp[vs] == self.fgen:
            return 0
        self.vstamp[vs] = self.fgen
        k = self.f_kbase + (vs >> BV)
        if self.blk[k] == NULL:
            _reserve(self, s, vs)
        w = &self.blk[k][self.f_wbase + ((vs & VMASK) >> 5)]
        sh = (vs & 31) * 2
        st = (w[0] >> sh) & 3
        if st == 0:
            self._append(vs, s, NULL)
            w[0] |= <unsigned long long>1 << sh
            self.blk_n[k] += 1
            self.ents[s].plain += 1
        elif st == 1:
            self.f_hits += 1
        else:
            i = self._find(vs, s)
            Py_DECREF(<object>self.boxes[vs].items[i].enc)
            self.boxes[vs].items[i].enc = NULL
            w[0] &= ~(<unsigned long long>2 << sh)  # 3 -> 1: reads the shared bytes
            self.ents[s].plain += 1
        return 0

    cdef int end_plain(self) except -1:
        """End the fan-out: plain items it did not reach keep the bytes they had (as their own)."""
        cdef Py_ssize_t s = self.f_slot, i
        cdef Ent *e = &self.ents[s]
        cdef PyObject *prev = self.f_prev
        cdef int vs
        self.f_prev = NULL
        self.f_active = False
        if prev != NULL:
            if prev != e.cur and self.f_before > self.f_hits:
                for vs in range(self.n_vslots):
                    if self.vstamp[vs] != self.fgen and _st(self, s, vs) == 1:
                        i = self._find(vs, s)
                        Py_INCREF(<object>prev)
                        self.boxes[vs].items[i].enc = prev
                        _set(self, s, vs, 3)
                        e.plain -= 1
            Py_DECREF(<object>prev)
        if e.plain == 0:
            Py_DECREF(<object>e.cur)
            e.cur = NULL
        return 0

    cdef int put_enc(self, int vs, Py_ssize_t s, bytes enc) except -1:
        """`enc` as viewer slot `vs`'s own bytes for entity slot `s`, replacing a pending state in its place; also
        between `begin_plain` and `end_plain` of the same slot (the route's LEAVEs: no stale scan for them)."""
        cdef Py_ssize_t i
        cdef Item *it
        if _st(self, s, vs) == 0:
            _reserve(self, s, vs)
            Py_INCREF(enc)
            try:
                self._append(vs, s, <PyObject *>enc)
            except MemoryError:
                Py_DECREF(enc)
                raise
            _set(self, s, vs, 3)
            return 0
        Py_INCREF(enc)
        it = &self.boxes[vs].items[self._find(vs, s)]
        if it.enc == NULL:
            self.ents[s].plain -= 1
            if self.f_active and s == self.f_slot:
                self.f_before -= 1  # (a LEAVE during the route's fan-out: `end_plain` owns `cur` until it ends)
            elif self.ents[s].plain == 0:
                Py_DECREF(<object>self.ents[s].cur)
                self.ents[s].cur = NULL
        else:
            Py_DECREF(<object>it.enc)
        it.enc = <PyObject *>enc
        _set(self, s, vs, 3)
        return 0

    # -------------------------------------------------------------------------------------- taking
    cdef void _release(self, int vs, Item *it) noexcept:
        """One item leaves its box: clear its bits, drop its references, free its entity's slot when due."""
        cdef Py_ssize_t s = it.slot
        cdef Ent *e = &self.ents[s]
        _set(self, s, vs, 0)
        e.pending -= 1
        if it.enc == NULL:
            e.plain -= 1
            if e.plain == 0 and e.cur != NULL:
                Py_DECREF(<object>e.cur)
                e.cur = NULL
        else:
            Py_DECREF(<object>it.enc)
        if e.released and e.pending == 0:
            self._free_ent(s)

    cdef Py_ssize_t _size(self, int vs) noexcept:
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t i, size = 0
        for i in range(b.n):
            size += PyBytes_GET_SIZE(<object>_enc(self, &b.items[i]))
        return size

    cdef Py_ssize_t _fit(self, int vs, Py_ssize_t n_max, Py_ssize_t b_max, Py_ssize_t size, bint nonempty) noexcept:
        """How many items from the front fit `n_max` messages and `b_max` bytes (< 0: any) after `size` bytes
        (`nonempty`: something is already in the frame; else the first item goes whatever its size)."""
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t k = 0, m
        while k < b.n and k < n_max:
            m = PyBytes_GET_SIZE(<object>_enc(self, &b.items[k]))
            if (nonempty or k) and b_max >= 0 and size + m > b_max:
                break
            size += m
            k += 1
        return k

    cdef void _drop(self, int vs, Py_ssize_t k) noexcept:
        """Release the first `k` items and move the rest to the front."""
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t i
        for i in range(k):
            self._release(vs, &b.items[i])
        b.n -= k
        if b.n:
            memmove(b.items, b.items + k, b.n * sizeof(Item))
        elif b.cap > SHRINK_ABOVE:
            free(b.items)
            b.items, b.cap = NULL, 0

    cdef bytes _join_take(self, int vs, Py_ssize_t k):
        """The first `k` items' bytes joined, taken."""
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t i, size = 0, m
        cdef PyObject *p
        for i in range(k):
            size += PyBytes_GET_SIZE(<object>_enc(self, &b.items[i]))
        out = PyBytes_FromStringAndSize(NULL, size)
        cdef char *dst = PyBytes_AS_STRING(out)
        for i in range(k):
            p = _enc(self, &b.items[i])
            m = PyBytes_GET_SIZE(<object>p)
            memcpy(dst, PyBytes_AS_STRING(<object>p), m)
            dst += m
        self._drop(vs, k)
        return out

    cdef list _list_take(self, int vs, Py_ssize_t k):
        """The first `k` items' bytes as a list, taken."""
        cdef Box *b = &self.boxes[vs]
        cdef Py_ssize_t i
        cdef list out = [<object>_enc(self, &b.items[i]) for i in range(k)]
        self._drop(vs, k)
        return out

    cdef void _close_box(self, int vs) noexcept:
        """The client's outbox object is gone: drop what it held and let the slot be reused."""
        self._drop(vs, self.boxes[vs].n)
        free(self.boxes[vs].items)
        self.boxes[vs].items, self.boxes[vs].cap = NULL, 0
        if self.free_vs is None:  # (never cleared by the collector: `no_gc_clear`; a guard all the same)
            return
        try:
            self.free_vs.append(vs)
        except BaseException:  # only MemoryError is possible: the slot stays unused
            pass

    cdef int _new_vslot(self) except -1:
        """A viewer slot for a new outbox: a freed one, else the next one."""
        cdef int vs
        if self.free_vs:
            return self.free_vs.pop()
        self._grow_v(self.n_vslots + 1)
        vs = self.n_vslots
        self.n_vslots += 1
        return vs

    # -------------------------------------------------------------------------------------- `Outboxes` API
    def open(self, long cid):
        """A new client's outbox."""
        cdef Py_ssize_t n
        cdef COutbox ob
        if cid < 0 or cid in self._boxes:
            raise ValueError(f"client id {cid} is negative or open")
        if cid > MAX_CID:
            raise ValueError(f"client id {cid} is beyond the compiled outboxes' bound {MAX_CID}")
        if cid >= self.n_cid:
            n = max(cid + 1, 2 * self.n_cid, 1024)
            grown = <int *>realloc(self.vslot_of, n * sizeof(int))
            if grown == NULL:
                raise MemoryError()
            memset(grown + self.n_cid, 0xff, (n - self.n_cid) * sizeof(int))  # -1: not open
            self.vslot_of, self.n_cid = grown, n
        ob = COutbox(self)
        self.vslot_of[cid] = ob.vs
        self._boxes[cid] = ob
        return ob

    def close(self, long cid):
        """The client is gone: nothing more is queued for it (its outbox object stays valid for the shell, and
        its slot is reused once that object is gone)."""
        if self._boxes.pop(cid, None) is not None:
            self.vslot_of[cid] = -1

    def forget(self, object eid):
        """The entity is gone (after its LEAVEs were queued): its slot is freed once nothing of it is pending."""
        cdef PyObject *p = PyDict_GetItem(self.slot_of, eid)
        cdef Py_ssize_t s
        if p == NULL:
            return
        s = <Py_ssize_t><object>p
        self.ents[s].released = True
        if self.ents[s].pending == 0:
            self._free_ent(s)

    def targets(self, object cids):
        """A handle on the outboxes of `cids` (all open) for `fan_out_to`: their viewer slots."""
        cdef list out = []
        cdef int vs
        for v in cids:
            vs = self.vslot(v)
            if vs < 0:
                raise KeyError(v)
            out.append(vs)
        return tuple(out)

    def fan_out_to(self, tuple targets, object entity, bytes encoded not None):
        """`put_state(entity, encoded)` on every outbox of a `targets` handle."""
        self.begin_plain(self.slot_for(entity), encoded)
        try:
            for vs in targets:
                self.put_plain(vs)
        finally:
            self.end_plain()

    def fan_out(self, object cids, object entity, bytes encoded not None):
        """`put_state(entity, encoded)` on the outbox of every client in `cids` (all open)."""
        self.fan_out_to(self.targets(cids), entity, encoded)

    def fan_out_open(self, object cids, object entity, bytes encoded not None):
        """As `fan_out`, skipping clients that are gone; each gets the bytes as its own (LEAVEs: one per entity)."""
        cdef Py_ssize_t s = self.slot_for(entity)
        cdef int vs
        for v in cids:
            vs = self.vslot(v)
            if vs >= 0:
                self.put_enc(vs, s, encoded)
        if self.ents[s].pending == 0 and self.ents[s].released:
            self._free_ent(s)

    def slots_in_use(self):
        """(entity slots, viewer slots) in use: what tests check for leaks."""
        return self.n_eslots - len(self.free_es), self.n_vslots - len(self.free_vs)

    def blocks_in_use(self):
        """(blocks of the 2-bit matrix in use, emptied ones pooled): what tests check memory by."""
        return self.n_blocks, self.n_pool


include "_coutbox.pxi"  # COutbox: one client's outbox (the `Outbox` API) over this table
