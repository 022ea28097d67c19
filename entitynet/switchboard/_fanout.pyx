# cython: language_level=3, boundscheck=False, wraparound=False
"""The compiled per-PUBLISH path: the switchboard's fan-out loops and the routing of one new state, in C.

Why: forwarding one PUBLISH to N viewers is, per viewer, a set insert (the new viewer set), a set difference
(who lost the entity), a dict store (the outbox) and a set insert (the dirty set), and in CPython each of these
goes through the interpreter and builds a temporary set. `route` does them in one pass over the cells'
subscribers with a per-client stamp array (a C array indexed by client id: "seen in this PUBLISH"), so the
union, the deduplication of viewers in two cells and the difference against the old viewers cost a C array
access each instead of a hashed set operation, and no temporary set is built. The tables stay the core's own
Python sets and dicts (one home per state: `Switchboard.subscribers`, `EntityState.viewers`, the outboxes);
this module keeps only scratch space. The pure functions of `entitynet.switchboard.outbox` and
`Switchboard._route_py` are the reference (and the fallback where this module is not built); tests run both
and compare every client's frames.
"""

from cpython.dict cimport PyDict_GetItem, PyDict_SetItem
from cpython.long cimport PyLong_AsLong
from cpython.ref cimport PyObject
from cpython.set cimport PySet_Add
from libc.stdlib cimport free, realloc
from libc.string cimport memset

from entitynet.protocol.codec import encode_leave as _encode_leave


cdef extern from "Python.h":
    void PyObject_GC_UnTrack(void *op)
    ctypedef struct PySetObject:
        Py_ssize_t used
        Py_ssize_t mask


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
    cdef object st
    for st in targets:
        (<dict>st)[entity] = encoded


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
    cdef tuple h, dicts, targets
    cdef PyObject *ct
    cdef Py_ssize_t i, n, n_leaves
    cdef long iv
    cdef unsigned int gen
    if t >= valid_from and (old is new or old == new):
        for cell in new:
            ct = PyDict_GetItem(cell_tick, cell)
            if ct != NULL and PyLong_AsLong(<object>ct) > t:
                break
        else:  # nobody (un)subscribed to these cells: the viewers are the same
            viewers = e.viewers
            if not viewers:
                return
            if e.targets is None:  # the set's second use: resolve its outboxes once
                e.targets = sb.outboxes.targets(viewers)
            targets = e.targets
            for i in range(len(targets)):
                PyDict_SetItem(<dict>targets[i], eid, enc)
            for v in viewers:
                PySet_Add(dirty, v)
            sb.stats["deliveries"] += len(viewers)
            return
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
        i = 0
        for v in members:  # the handle's order (see _cell_entry)
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
