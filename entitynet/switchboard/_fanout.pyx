# cython: language_level=3, boundscheck=False, wraparound=False
"""The compiled per-PUBLISH path: the routing of one new state and the run of PUBLISHes, in C.

Why: forwarding one PUBLISH to N viewers is, per viewer, a set insert (the new viewer set), a set difference
(who lost the entity), an outbox store and a set insert (the dirty set), and in CPython each of these goes
through the interpreter. On the compiled path the tables' id sets are C word arrays (`_viewsets.pxi`: the cell
-> subscribers sets and each entity's viewer set are `ViewerSet`s, the dirty set is `CidMarks`, one kind per
switchboard, chosen with its outboxes by `outbox.set_kinds`; they stay the core's only home of those sets): the
union of the cells' subscribers is an OR of sorted words, who keeps, gains and loses the entity come out of one
walk over the new and the old words (AND NOT), the dirty marks are one OR per 64 viewers, and no Python object is
touched per viewer; the outbox store is an append to the compiled outboxes' C arrays (`_outbox.pyx`).
`publish_run` takes the rest of a common PUBLISH (the checks, the entity's fields,
the occupants, the UPDATE's bytes, the expiry) for a run of PUBLISHes in one C loop, so that the route is
reached without a Python call per message; anything unusual it leaves to `Switchboard._publish`. The dict
outboxes of `entitynet.switchboard.outbox` and `Switchboard._route_py` are the reference (and the fallback
where these modules are not built); tests run both and compare every client's frames.
"""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize, PyBytes_GET_SIZE
from cpython.dict cimport PyDict_GetItem
from cpython.long cimport PyLong_AsLong, PyLong_AsLongLongAndOverflow
from cpython.ref cimport PyObject
from libc.stdlib cimport free, malloc, qsort, realloc
from libc.string cimport memcpy, memmove, memset

cimport cython

from entitynet.switchboard._outbox cimport OutboxTable

from entitynet.protocol.codec import encode_leave as _encode_leave
from entitynet.protocol.messages import LOCAL_ID_LIMIT, MAX_INT, UPDATE
from entitynet.switchboard.occupancy import move as _move


# ---------------------------------------------------------------------------------------------- routing
include "_viewsets.pxi"  # ViewerSet, CidMarks: the subscriber sets, viewer sets and dirty marks in C


def route(object sb, object c, object e, tuple old, tuple new):
    """`Switchboard._route` for an entity without followers whose owner shows no identity, on a switchboard
    whose outboxes are the compiled table and whose sets are `ViewerSet`s and `CidMarks` (the caller checks):
    the same stores, LEAVEs, dirty marks, counters and new viewer set, in one C pass."""
    _route(sb, c, e, old, new)


cdef int _route(object sb, object c, object e, tuple old, tuple new) except -1:
    """`route`'s body, also called by `publish_run` without a Python call in between. The viewer set is the union
    of the cells' subscriber sets (word ORs), who keeps or gains it and who loses it come out of one walk over
    the new and the old words, and the stores are appends to the compiled outboxes (`_outbox.OutboxTable`:
    `begin_plain`, `put_plain` per viewer, `end_plain`)."""
    cdef OutboxTable ot = <OutboxTable?>sb.outboxes
    cdef CidMarks dirty = <CidMarks?>sb._dirty
    cdef long t = e.viewers_tick
    cdef dict cell_tick = sb._cell_tick
    cdef object eid = e.eid
    cdef object cell, leave = None
    cdef PyObject *ct
    cdef ViewerSet nv, ov
    cdef Py_ssize_t n_leaves = 0, slot, i, j
    cdef long long idx, base
    cdef unsigned long long nb, ob, b
    cdef int vs
    ov = _as_viewer_set(e.viewers)
    if t >= <long>sb._valid_from and (old is new or old == new):
        for cell in new:
            ct = PyDict_GetItem(cell_tick, cell)
            if ct != NULL and PyLong_AsLong(<object>ct) > t:
                break
        else:  # nobody (un)subscribed to these cells: the viewers are the same
            if not ov.n:
                return 0
            ot.begin_plain(ot.slot_for(eid), <bytes?>e.enc_plain)
            try:
                for i in range(ov.n):
                    base, b = ov.w[i].idx << 6, ov.w[i].bits
                    while b:
                        ot.put_plain(ot.vslot(<long>(base + __builtin_ctzll(b))))
                        b &= b - 1
                    dirty.mark(ov.w[i].idx, ov.w[i].bits)
            finally:
                ot.end_plain()
            sb.stats["deliveries"] += ov.count
            return 0
    nv = _union_of_cells(sb.subscribers, new, c.cid)
    slot = ot.slot_for(eid)
    ot.begin_plain(slot, <bytes?>e.enc_plain)
    try:
        i = j = 0
        while i < nv.n or j < ov.n:  # the new and the old words in step: keep or gain, lose
            if j >= ov.n or (i < nv.n and nv.w[i].idx < ov.w[j].idx):
                idx, nb, ob = nv.w[i].idx, nv.w[i].bits, 0
                i += 1
            elif i >= nv.n or ov.w[j].idx < nv.w[i].idx:
                idx, nb, ob = ov.w[j].idx, 0, ov.w[j].bits
                j += 1
            else:
                idx, nb, ob = nv.w[i].idx, nv.w[i].bits, ov.w[j].bits
                i += 1
                j += 1
            base = idx << 6
            b = nb
            while b:
                ot.put_plain(ot.vslot(<long>(base + __builtin_ctzll(b))))
                b &= b - 1
            b = ob & ~nb  # LEAVE for who lost it (before `end_plain`: their pending UPDATE is replaced)
            if b:
                if leave is None:
                    leave = _encode_leave(eid)
                n_leaves += __builtin_popcountll(b)
                while b:
                    vs = ot.vslot(<long>(base + __builtin_ctzll(b)))
                    if vs >= 0:
                        ot.put_enc(vs, slot, <bytes>leave)
                    b &= b - 1
            dirty.mark(idx, nb | ob)
    finally:
        ot.end_plain()
    if nv.count:
        sb.stats["deliveries"] += nv.count
    if n_leaves:
        sb.stats["leaves"] += n_leaves
    e.viewers = nv
    e.targets = None
    e.viewers_tick = sb._tick
    return 0


# ---------------------------------------------------------------------------------------------- publishing
cdef long long _LOCAL_ID_LIMIT = LOCAL_ID_LIMIT
cdef long long _MAX_INT = MAX_INT
cdef unsigned char _UPDATE = UPDATE
cdef enum:
    MAX_FAST_CELLS = 64  # the codec's default bound on a PUBLISH's cells; longer lists take the Python path


cdef inline long long _nonneg(object v, long long hi):
    """`v` as a C integer when it is an int in [0, hi], else -1."""
    cdef int overflow = 0
    cdef long long x
    if type(v) is not int:
        return -1
    x = PyLong_AsLongLongAndOverflow(v, &overflow)
    if overflow != 0 or x < 0 or x > hi:
        return -1
    return x


cdef inline Py_ssize_t _uint_size(unsigned long long x):
    return 1 if x < 0x80 else 2 if x < 0x100 else 3 if x < 0x10000 else 5 if x < 0x100000000 else 9


cdef inline char *_put_uint(char *p, unsigned long long x):
    """msgpack's shortest form of a non-negative integer (what msgpack's Packer writes)."""
    cdef int k, n
    if x < 0x80:
        p[0] = <char>x
        return p + 1
    if x < 0x100:
        p[0] = <char>0xcc
        n = 1
    elif x < 0x10000:
        p[0] = <char>0xcd
        n = 2
    elif x < 0x100000000:
        p[0] = <char>0xce
        n = 4
    else:
        p[0] = <char>0xcf
        n = 8
    for k in range(n):
        p[n - k] = <char>(x >> (8 * k))
    return p + 1 + n


cdef bytes _encode_update(long long eid, long long seq, long long *cells, Py_ssize_t n_cells, long long validity,
                          bytes payload):
    """`codec.encode_update(eid, seq, cells, validity, payload)` (no identity) written straight into one bytes
    object: `[UPDATE, eid, seq, [cells...], validity, bin payload, nil]` in msgpack's shortest forms, the bytes
    the codec's Packer makes (tests compare them bit for bit on boundary values). Why: the Packer call builds a
    7-element list and walks it through the generic packer, once per PUBLISH."""
    cdef Py_ssize_t plen = PyBytes_GET_SIZE(payload), size, i
    size = 2 + _uint_size(eid) + _uint_size(seq) + _uint_size(validity) + 1
    size += 1 if n_cells < 16 else 3 if n_cells < 0x10000 else 5
    for i in range(n_cells):
        size += _uint_size(cells[i])
    size += (2 if plen < 0x100 else 3 if plen < 0x10000 else 5) + plen
    out = PyBytes_FromStringAndSize(NULL, size)
    cdef char *p = PyBytes_AS_STRING(out)
    p[0] = <char>0x97
    p[1] = <char>_UPDATE
    p = _put_uint(_put_uint(p + 2, eid), seq)
    if n_cells < 16:
        p[0] = <char>(0x90 | n_cells)
        p += 1
    elif n_cells < 0x10000:
        p[0], p[1], p[2] = <char>0xdc, <char>(n_cells >> 8), <char>n_cells
        p += 3
    else:
        p[0], p[1], p[2], p[3], p[4] = <char>0xdd, <char>(n_cells >> 24), <char>(n_cells >> 16), \
            <char>(n_cells >> 8), <char>n_cells
        p += 5
    for i in range(n_cells):
        p = _put_uint(p, cells[i])
    p = _put_uint(p, validity)
    if plen < 0x100:
        p[0], p[1] = <char>0xc4, <char>plen
        p += 2
    elif plen < 0x10000:
        p[0], p[1], p[2] = <char>0xc5, <char>(plen >> 8), <char>plen
        p += 3
    else:
        p[0], p[1], p[2], p[3], p[4] = <char>0xc6, <char>(plen >> 24), <char>(plen >> 16), <char>(plen >> 8), \
            <char>plen
        p += 5
    memcpy(p, PyBytes_AS_STRING(payload), plen)
    p[plen] = <char>0xc0
    return out


def encode_update_plain(long long eid, long long seq, tuple cells, long long validity, bytes payload):
    """`_encode_update` for tests: the bytes the compiled PUBLISH path queues, to compare with the codec's."""
    cdef long long buf[MAX_FAST_CELLS]
    cdef Py_ssize_t i, n = len(cells)
    if n > MAX_FAST_CELLS or eid < 0 or seq < 0 or validity < 0:
        raise ValueError("outside what the compiled path encodes")
    for i in range(n):
        buf[i] = cells[i]
        if buf[i] < 0:
            raise ValueError("outside what the compiled path encodes")
    return _encode_update(eid, seq, buf, n, validity, payload)


cdef bint _publish_one(object sb, object c, object m, dict local_ids, dict entities, dict occ, long long n_cells,
                       double now, double grace, object timers_set) except -1:
    """`Switchboard._publish` of one PUBLISH when it is the common case: a newer state of an entity this client
    already publishes, every field an int in range, at most 64 cells that exist, no followers, no identity shown,
    no cluster (the caller checks that). Returns False, having changed nothing, for anything else (errors, a new
    entity, a stale seq, a hostile field): the Python `_publish` then handles it, so every refusal and every
    unusual case has one implementation, the reference's."""
    cdef long long buf[MAX_FAST_CELLS]
    cdef long long x, eid_c, seq_c, validity_c
    cdef Py_ssize_t i, n
    cdef PyObject *p
    cdef tuple new, old_t
    local = m.entity
    if _nonneg(local, _LOCAL_ID_LIMIT - 1) < 0:
        return False
    cells = m.cells
    if type(cells) is not tuple:
        return False
    new = <tuple>cells
    n = len(new)
    if n > MAX_FAST_CELLS:
        return False
    for i in range(n):
        x = _nonneg(new[i], n_cells - 1)
        if x < 0:
            return False
        buf[i] = x
    p = PyDict_GetItem(local_ids, local)
    if p == NULL:
        return False
    eid = <object>p
    p = PyDict_GetItem(entities, eid)
    if p == NULL:
        return False
    e = <object>p
    if e.followers or e.owner.identity is not None:
        return False
    seq = m.seq
    seq_c = _nonneg(seq, _MAX_INT)
    eid_c = _nonneg(eid, _MAX_INT)
    validity = m.validity_ms
    validity_c = _nonneg(validity, _MAX_INT)
    payload = m.payload
    if seq_c < 0 or eid_c < 0 or validity_c < 0 or type(payload) is not bytes or not seq > e.seq:
        return False
    old = e.cells
    if type(old) is not tuple:
        return False
    old_t = <tuple>old
    if old_t != new:  # `_apply_state`'s own update rule (one home: the sets' iteration order depends on it)
        _move(occ, eid, old_t, new)
        e.cells = new
    e.seq = seq
    e.validity_ms = validity
    e.payload = payload
    e.enc_plain = _encode_update(eid_c, seq_c, buf, n, validity_c, <bytes>payload)
    e.enc_ident = None
    timers_set(eid, now + <double>validity_c / 1000.0 + grace)
    _route(sb, c, e, old_t, new)
    return True


def publish_run(object sb, object c, object msgs, Py_ssize_t i, object publish_cls, double now):
    """`Switchboard.receive` for the run of PUBLISHes at `msgs[i:]` that `_publish_one` takes (the common
    case), in one C loop without a Python call per message; returns the index of the first message it did not
    handle (`i` when none), which the caller's Python loop handles next. Only for a client past its handshake
    and not closing, on a switchboard without a cluster (the caller checks both; nothing here closes a client)."""
    cdef Py_ssize_t n = len(msgs), start = i
    cdef dict local_ids = c.entities, entities = sb.entities, occ = sb.occupants
    cdef long long n_cells = sb.config.n_cells
    cdef double grace = sb.config.grace_s
    timers_set = sb.timers.set
    while i < n:
        m = msgs[i]
        if type(m) is not publish_cls or not _publish_one(sb, c, m, local_ids, entities, occ, n_cells, now, grace,
                                                          timers_set):
            break
        i += 1
    if i != start:
        sb.stats["updates_in"] += i - start
    return i
