# cython: language_level=3, boundscheck=False, wraparound=False
"""The codec's per-message loop in C for the messages that dominate a switch's input (issue 25): PUBLISH (one
per entity state) and SUBSCRIBE (a PVS viewer's difference: thousands of cell ids when it subscribes). The field
checks run on C integers and the message is built by filling its slots, without the frozen dataclass's
`__init__` (an `object.__setattr__` call per field). Every other message, and every PUBLISH or SUBSCRIBE that
fails any check or falls outside what this loop handles (a PUBLISH of more than 64 cells), goes to the codec's
Python `_decode_one`, the reference, so an error is raised by the same code with the same code and text. Built by pip where a C compiler
is found (setup.py); `entitynet.protocol.codec` uses the Python loop without it or with ENTITYNET_PURE_PYTHON=1."""

from cpython.object cimport PyObject
from cpython.ref cimport Py_INCREF
from cpython.long cimport PyLong_AsLongLongAndOverflow

cdef extern from "Python.h":
    ctypedef struct PyMemberDef:
        Py_ssize_t offset
    ctypedef struct PyMemberDescrObject:
        PyMemberDef* d_member

cdef extern from *:
    """
    static inline void entitynet_set_slot(PyObject *obj, Py_ssize_t off, PyObject *v) {
        Py_INCREF(v);
        *(PyObject **)((char *)obj + off) = v;
    }
    static inline PyObject *entitynet_alloc(PyObject *cls) {
        return ((PyTypeObject *)cls)->tp_alloc((PyTypeObject *)cls, 0);
    }
    """
    void entitynet_set_slot(object obj, Py_ssize_t off, object v)
    object entitynet_alloc(object cls)

cdef enum:
    MAX_FAST_CELLS = 64
cdef long long MAX_INT = 2 ** 53
cdef long long MAX_CELL = 2 ** 31 - 1
cdef long long MAX_VALIDITY_MS = 24 * 3600 * 1000
cdef long long PUBLISH = 4

cdef long long SUBSCRIBE = 6
cdef object _Publish = None
cdef object _Subscribe = None
cdef Py_ssize_t _off_entity, _off_seq, _off_cells, _off_validity, _off_payload, _off_added, _off_removed


cdef Py_ssize_t _offset(cls, str name) except -1:
    d = cls.__dict__[name]
    if type(d).__name__ != "member_descriptor":
        raise TypeError(f"{cls.__name__}.{name} is not a slot")
    return (<PyMemberDescrObject*><PyObject*>d).d_member.offset


def bind(publish_cls, long long publish_type, subscribe_cls, long long subscribe_type, long long max_int,
         long long max_cell, long long max_validity_ms):
    """Give the loop the message classes, their type numbers and the protocol's bounds (one home:
    entitynet.protocol.messages)."""
    global _Publish, _Subscribe, _off_entity, _off_seq, _off_cells, _off_validity, _off_payload
    global _off_added, _off_removed, PUBLISH, SUBSCRIBE, MAX_INT, MAX_CELL, MAX_VALIDITY_MS
    if tuple(publish_cls.__slots__) != ("entity", "seq", "cells", "validity_ms", "payload"):
        raise TypeError("Publish's fields changed: update entitynet/protocol/_decode.pyx")
    if tuple(subscribe_cls.__slots__) != ("added", "removed"):
        raise TypeError("Subscribe's fields changed: update entitynet/protocol/_decode.pyx")
    _off_added = _offset(subscribe_cls, "added")
    _off_removed = _offset(subscribe_cls, "removed")
    _Subscribe = subscribe_cls
    SUBSCRIBE = subscribe_type
    _off_entity = _offset(publish_cls, "entity")
    _off_seq = _offset(publish_cls, "seq")
    _off_cells = _offset(publish_cls, "cells")
    _off_validity = _offset(publish_cls, "validity_ms")
    _off_payload = _offset(publish_cls, "payload")
    _Publish = publish_cls
    PUBLISH = publish_type
    MAX_INT = max_int
    MAX_CELL = max_cell
    MAX_VALIDITY_MS = max_validity_ms


cdef inline bint _int_in(object v, long long hi):
    cdef int overflow = 0
    cdef long long x
    if type(v) is not int:
        return False
    x = PyLong_AsLongLongAndOverflow(v, &overflow)
    return overflow == 0 and 0 <= x <= hi


cdef object _publish(tuple m, Py_ssize_t max_cells, Py_ssize_t max_payload):
    """The PUBLISH `m` (a 6-tuple starting with PUBLISH) as a `Publish`, or None when any check fails."""
    cdef long long buf[MAX_FAST_CELLS]
    cdef Py_ssize_t n, i, j
    cdef int overflow = 0
    cdef long long x
    entity = m[1]
    seq = m[2]
    cells = m[3]
    validity = m[4]
    payload = m[5]
    if not _int_in(entity, MAX_INT) or not _int_in(seq, MAX_INT):
        return None
    if type(cells) is not tuple:
        return None
    n = len(<tuple>cells)
    if n > max_cells or n > MAX_FAST_CELLS:
        return None
    for i in range(n):
        c = (<tuple>cells)[i]
        if type(c) is not int:
            return None
        x = PyLong_AsLongLongAndOverflow(c, &overflow)
        if overflow != 0 or x < 0 or x > MAX_CELL:
            return None
        for j in range(i):
            if buf[j] == x:
                return None
        buf[i] = x
    if not _int_in(validity, MAX_VALIDITY_MS):
        return None
    if type(payload) is not bytes or len(<bytes>payload) > max_payload:
        return None
    p = entitynet_alloc(_Publish)
    entitynet_set_slot(p, _off_entity, entity)
    entitynet_set_slot(p, _off_seq, seq)
    entitynet_set_slot(p, _off_cells, cells)
    entitynet_set_slot(p, _off_validity, validity)
    entitynet_set_slot(p, _off_payload, payload)
    return p


cdef bint _cells_ok(object v, Py_ssize_t max_n):
    """What the codec's `_cells` accepts: an array of at most `max_n` integers in [0, MAX_CELL]."""
    cdef Py_ssize_t i
    cdef int overflow = 0
    cdef long long x
    if type(v) is not tuple or len(<tuple>v) > max_n:
        return False
    for i in range(len(<tuple>v)):
        c = (<tuple>v)[i]
        if type(c) is not int:
            return False
        x = PyLong_AsLongLongAndOverflow(c, &overflow)
        if overflow != 0 or x < 0 or x > MAX_CELL:
            return False
    return True


cdef object _subscribe(tuple m, Py_ssize_t max_cells):
    """The SUBSCRIBE `m` (a 3-tuple starting with SUBSCRIBE) as a `Subscribe`, or None when a check fails."""
    added = m[1]
    removed = m[2]
    if not _cells_ok(added, max_cells) or not _cells_ok(removed, max_cells):
        return None
    s = entitynet_alloc(_Subscribe)
    entitynet_set_slot(s, _off_added, added)
    entitynet_set_slot(s, _off_removed, removed)
    return s


def decode_messages(tuple obj, lim, Py_ssize_t max_cells, Py_ssize_t max_payload, Py_ssize_t max_subscribe_cells,
                    decode_one):
    """`[decode_one(m, lim) for m in obj]`, with PUBLISHes and SUBSCRIBEs that pass every check built here."""
    cdef list out = []
    cdef int overflow = 0
    cdef long long t
    cdef Py_ssize_t n
    for m in obj:
        if type(m) is tuple:
            n = len(<tuple>m)
            if n == 6 or n == 3:
                first = (<tuple>m)[0]
                if type(first) is int:
                    t = PyLong_AsLongLongAndOverflow(first, &overflow)
                    if overflow == 0:
                        p = None
                        if n == 6 and t == PUBLISH:
                            p = _publish(<tuple>m, max_cells, max_payload)
                        elif n == 3 and t == SUBSCRIBE:
                            p = _subscribe(<tuple>m, max_subscribe_cells)
                        if p is not None:
                            out.append(p)
                            continue
        out.append(decode_one(m, lim))
    return out
