# cython: language_level=3, boundscheck=False, wraparound=False
"""The compiled per-PUBLISH path: the switchboard's fan-out loops and the routing of one new state, in C.

Why: forwarding one PUBLISH to N viewers is, per viewer, a set insert (the new viewer set), a set difference
(who lost the entity), a dict store (the outbox) and a set insert (the dirty set), and in CPython each of these
goes through the interpreter and builds a temporary set. `route` does them in one pass over the cells'
subscribers with a per-client stamp array (a C array indexed by client id: "seen in this PUBLISH"), so the
union, the deduplication of viewers in two cells and the difference against the old viewers cost a C array
access each instead of a hashed set operation, and no temporary set is built. The tables stay the core's own
Python sets and dicts (one home per state: `Switchboard.subscribers`, `EntityState.viewers`, the outboxes);
this module keeps only scratch space. `publish_run` takes the rest of a common PUBLISH (the checks, the entity's
fields, the occupants, the UPDATE's bytes, the expiry) for a run of PUBLISHes in one C loop, so that the route is
reached without a Python call per message; anything unusual it leaves to `Switchboard._publish`. The pure functions of `entitynet.switchboard.outbox` and
`Switchboard._route_py` are the reference (and the fallback where this module is not built); tests run both
and compare every client's frames.
"""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize, PyBytes_GET_SIZE
from cpython.dict cimport PyDict_GetItem, PyDict_SetItem
from cpython.long cimport PyLong_AsLong, PyLong_AsLongLongAndOverflow
from cpython.ref cimport PyObject
from cpython.set cimport PySet_Add
from libc.stdlib cimport free, realloc
from libc.string cimport memcpy, memset

from entitynet.protocol.codec import encode_leave as _encode_leave
from entitynet.protocol.messages import LOCAL_ID_LIMIT, MAX_INT, UPDATE
from entitynet.switchboard.occupancy import move as _move


cdef extern from "Python.h":
    void PyObject_GC_UnTrack(void *op)
    PyObject **PySequence_Fast_ITEMS(object o)
    ctypedef struct PySetObject:
        Py_ssize_t used
        Py_ssize_t mask


cdef extern from *:
    """
    /* Prefetching a dict's memory ahead of a store into it (see _store_all). Only public fields of PyDictObject
       are read in general; the keys object's layout (to reach the index slot) only on the CPython versions whose
       layout this states (3.11, 3.12), else the index slot is not prefetched. */
    #define ENT_PREFETCH(p) __builtin_prefetch((const void *)(p), 1, 3)
    static inline void ent_prefetch_dict(PyObject *d) { ENT_PREFETCH(d); }
    static inline void ent_prefetch_keys(PyObject *d) { ENT_PREFETCH(((PyDictObject *)d)->ma_keys); }
    static inline void ent_prefetch_slot(PyObject *d, Py_ssize_t h) {
    #if PY_VERSION_HEX >= 0x030B0000 && PY_VERSION_HEX < 0x030D0000
        const unsigned char *k = (const unsigned char *)((PyDictObject *)d)->ma_keys;
        unsigned int log2_size = k[sizeof(Py_ssize_t)], log2_index_bytes = k[sizeof(Py_ssize_t) + 1];
        size_t slot = ((size_t)h & (((size_t)1 << log2_size) - 1)) << (log2_index_bytes - log2_size);
        ENT_PREFETCH(k + 4 * sizeof(Py_ssize_t) + slot);
    #else
        (void)d; (void)h;
    #endif
    }
    static inline void ent_prefetch_entry(PyObject *d, Py_ssize_t h) {
    #if PY_VERSION_HEX >= 0x030B0000 && PY_VERSION_HEX < 0x030D0000
        const unsigned char *k = (const unsigned char *)((PyDictObject *)d)->ma_keys;
        unsigned int log2_size = k[sizeof(Py_ssize_t)], log2_index_bytes = k[sizeof(Py_ssize_t) + 1];
        unsigned int width = log2_index_bytes - log2_size;
        size_t slot = (size_t)h & (((size_t)1 << log2_size) - 1);
        const unsigned char *indices = k + 4 * sizeof(Py_ssize_t);
        Py_ssize_t ix;
        if (k[sizeof(Py_ssize_t) + 2] != 0) return;  /* not DICT_KEYS_GENERAL: entries of another size */
        switch (width) {
            case 0: ix = ((const int8_t *)indices)[slot]; break;
            case 1: ix = ((const int16_t *)indices)[slot]; break;
            case 2: ix = ((const int32_t *)indices)[slot]; break;
            default: ix = ((const int64_t *)indices)[slot]; break;
        }
        if (ix >= 0) ENT_PREFETCH(indices + ((size_t)1 << log2_index_bytes) + (size_t)ix * 3 * sizeof(void *));
    #else
        (void)d; (void)h;
    #endif
    }
    """
    void ent_prefetch_dict(PyObject *d)
    void ent_prefetch_keys(PyObject *d)
    void ent_prefetch_slot(PyObject *d, Py_ssize_t h)
    void ent_prefetch_entry(PyObject *d, Py_ssize_t h)


cdef enum:
    PF_STEP = 4  # stores between the stages of prefetching one dict's memory ahead of its store
    PF_ENTRY = 2  # the entry's stage: this far ahead of the store, after the index slot's (PF_STEP ahead)


cdef inline void _prefetch_ahead(PyObject **items, Py_ssize_t n, Py_ssize_t i, Py_ssize_t h) noexcept:
    """Prefetch, for the coming stores `items[j][key] = ...` (key hashing to `h`), the memory of the dict
    3 x PF_STEP ahead of `i`, the keys object 2 x ahead, the index slot PF_STEP ahead and the entry PF_ENTRY ahead.

    Why: per delivery the route stores into a different client's outbox dict, one after the other, and each
    store's lookup is a chain of dependent cache misses (the dict, its keys object, the index slot, the entry):
    one at a time, the CPU waits for each in turn. Prefetched in stages, the misses of several stores overlap
    (measured: the store's CPU 0.5-0.9x, the more pending per outbox the more it saves). Only a hint: nothing is
    written, the stores themselves are unchanged; each stage reads only what the stage before prefetched."""
    if i + 3 * PF_STEP < n:
        ent_prefetch_dict(items[i + 3 * PF_STEP])
    if i + 2 * PF_STEP < n:
        ent_prefetch_keys(items[i + 2 * PF_STEP])
    if i + PF_STEP < n:
        ent_prefetch_slot(items[i + PF_STEP], h)
    if i + PF_ENTRY < n:
        ent_prefetch_entry(items[i + PF_ENTRY], h)


cdef int _store_all(tuple dicts, object key, object value) except -1:
    """`d[key] = value` for every dict of `dicts` (outboxes), with `_prefetch_ahead`."""
    cdef Py_ssize_t n = len(dicts), i
    cdef Py_ssize_t h = hash(key)
    cdef PyObject **items = PySequence_Fast_ITEMS(dicts)
    for i in range(n):
        _prefetch_ahead(items, n, i, h)
        PyDict_SetItem(<dict>items[i], key, value)
    return 0


def fan_out(dict states, object cids, object entity, object encoded):
    """`states[v][entity] = encoded` for every v in `cids` (all present)."""
    cdef object v
    for v in cids:
        (<dict>states[v])[entity] = encoded


def fan_out_open(dict states, object cids, object entity, object encoded):
    """As `fan_out`, skipping client ids not in `states`."""
    cdef object v, st
    for v in cids:
        st = states.get(v)
        if st is not None:
            (<dict>st)[entity] = encoded


def fan_out_to(tuple targets, object entity, object encoded):
    """`st[entity] = encoded` for every dict of `targets`."""
    _store_all(targets, entity, encoded)


# ---------------------------------------------------------------------------------------------- routing
# stamp[cid] == _gen: the client was met in the current PUBLISH. One array for the process (the core is
# single-threaded and a route call never re-enters), grown to the largest client id seen; cleared when the
# generation counter wraps.
cdef unsigned int *_stamp = NULL
cdef Py_ssize_t _n_stamp = 0
cdef unsigned int _gen = 0


cdef int _reserve(Py_ssize_t n) except -1:
    """Make `_stamp` hold client ids below `n`."""
    global _stamp, _n_stamp
    cdef Py_ssize_t size
    cdef unsigned int *grown
    if n <= _n_stamp:
        return 0
    size = max(n, 2 * _n_stamp, 1024)
    grown = <unsigned int *>realloc(_stamp, size * sizeof(unsigned int))
    if grown == NULL:
        raise MemoryError()
    memset(grown + _n_stamp, 0, (size - _n_stamp) * sizeof(unsigned int))
    _stamp, _n_stamp = grown, size
    return 0


cdef unsigned int _next_gen():
    global _gen
    _gen += 1
    if _gen == 0:  # wrapped: forget every stamp
        memset(_stamp, 0, _n_stamp * sizeof(unsigned int))
        _gen = 1
    return _gen


cdef tuple _cell_entry(object sb, object cell, set members, dict handles, dict cell_tick, long tick,
                       long valid_from):
    """The cell's cached `(tick made, outbox handle)` in `sb._cell_targets` (the entries `_deliver_to_cells`
    makes too), remade when the cell's subscribers changed since; the handle lists the outboxes of `members`
    in the set's iteration order, which stays the same while the set is unchanged (the tick says so)."""
    cdef PyObject *p = PyDict_GetItem(handles, cell)
    cdef PyObject *ct
    cdef tuple h
    cdef long made
    if p != NULL:
        h = <tuple><object>p
        made = PyLong_AsLong(h[0])
        ct = PyDict_GetItem(cell_tick, cell)
        if made >= valid_from and (ct == NULL or made >= PyLong_AsLong(<object>ct)) \
                and len(<tuple>h[1]) == len(members):
            return h
    h = (tick, sb.outboxes.targets(members))
    handles[cell] = h
    return h


def route(object sb, object c, object e, tuple old, tuple new):
    """`Switchboard._route` for an entity without followers whose owner shows no identity (the caller checks):
    the same stores, LEAVEs, dirty marks, counters and new viewer set, in one C pass."""
    _route(sb, c, e, old, new)


cdef int _route(object sb, object c, object e, tuple old, tuple new) except -1:
    """`route`'s body, also called by `publish_run` without a Python call in between."""
    cdef long t = e.viewers_tick
    cdef long valid_from = sb._valid_from
    cdef long tick = sb._tick
    cdef long owner = c.cid
    cdef dict cell_tick = sb._cell_tick
    cdef dict subs = sb.subscribers
    cdef dict handles = sb._cell_targets
    cdef set dirty = sb._dirty
    cdef set viewers, old_viewers, members
    cdef dict states
    cdef object eid = e.eid
    cdef object enc = e.enc_plain
    cdef object cell, v, leave
    cdef tuple h, dicts
    cdef PyObject *ct
    cdef Py_ssize_t i, n, n_leaves
    cdef long iv
    cdef unsigned int gen
    cdef PyObject **items
    cdef Py_ssize_t eh = hash(eid)
    if t >= valid_from and (old is new or old == new):
        for cell in new:
            ct = PyDict_GetItem(cell_tick, cell)
            if ct != NULL and PyLong_AsLong(<object>ct) > t:
                break
        else:  # nobody (un)subscribed to these cells: the viewers are the same
            viewers = e.viewers
            if not viewers:
                return 0
            if e.targets is None:  # the set's second use: resolve its outboxes once
                e.targets = sb.outboxes.targets(viewers)
            _store_all(<tuple>e.targets, eid, enc)
            for v in viewers:
                PySet_Add(dirty, v)
            sb.stats["deliveries"] += len(viewers)
            return 0
    _reserve(sb._next_cid)
    gen = _next_gen()
    viewers = set()
    for cell in new:
        ct = PyDict_GetItem(subs, cell)
        if ct == NULL or not <set><object>ct:
            continue
        members = <set><object>ct
        h = _cell_entry(sb, cell, members, handles, cell_tick, tick, valid_from)
        dicts = <tuple>h[1]
        items = PySequence_Fast_ITEMS(dicts)
        n = len(dicts)
        i = 0
        for v in members:  # the handle's order (see _cell_entry)
            _prefetch_ahead(items, n, i, eh)
            iv = PyLong_AsLong(v)
            if _stamp[iv] != gen and iv != owner:
                _stamp[iv] = gen
                PyDict_SetItem(<dict>dicts[i], eid, enc)
                PySet_Add(viewers, v)
                PySet_Add(dirty, v)
            i += 1
    if (<PySetObject *>viewers).mask + 1 > 4 * (<PySetObject *>viewers).used + 8:
        # grown one add at a time, the table can be 2-4 times what a union's presized one is: compact it (a copy
        # presizes), so that the sets take no more memory than the reference's
        viewers = set(viewers)
    if viewers:
        sb.stats["deliveries"] += len(viewers)
    old_viewers = e.viewers
    n_leaves = 0
    leave = None
    if old_viewers:
        states = sb.outboxes._states
        for v in old_viewers:
            iv = PyLong_AsLong(v)
            if iv < _n_stamp and _stamp[iv] == gen:
                continue
            if leave is None:
                leave = _encode_leave(eid)
            ct = PyDict_GetItem(<dict>states, v)
            if ct != NULL:
                PyDict_SetItem(<dict><object>ct, eid, leave)
            PySet_Add(dirty, v)
            n_leaves += 1
        if n_leaves:
            sb.stats["leaves"] += n_leaves
    # A set of client ids (ints) can be part of no reference cycle, yet a tracked set is walked by every young
    # collection until it is promoted: at the standard load the live viewer sets (one per moving entity, each
    # of a few hundred ids) made young collections of 15-30 ms of CPU. Untracked, the collector never sees them.
    PyObject_GC_UnTrack(<void *>viewers)
    e.viewers = viewers
    e.targets = None
    e.viewers_tick = tick
    return 0


# ---------------------------------------------------------------------------------------------- taking
def take_states(object ob, Py_ssize_t max_messages, Py_ssize_t sure_fit, Py_ssize_t max_body):
    """`Outbox.take_states` in C (installed as the method by `outbox.use_compiled`): the flush loop calls it
    once per frame, and in Python its frame cost as much as the join."""
    cdef dict states = ob._states
    cdef Py_ssize_t n = len(states), size
    cdef object m
    if 0 < n <= max_messages and not ob._control and not ob._close_after and not ob._overflow:
        if n > sure_fit:
            size = 0
            for m in states.values():
                size += len(<bytes>m)
            if size > max_body:
                return None
        body = b"".join(states.values())
        states.clear()
        return n, body
    return None


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
