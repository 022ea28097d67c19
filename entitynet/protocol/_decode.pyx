# cython: language_level=3, boundscheck=False, wraparound=False
"""The codec's per-message loop in C for the one message that dominates a switch's input, PUBLISH (issue 25):
the field checks in C integers and the `Publish` built by filling its slots, without the frozen dataclass's
`__init__` (five `object.__setattr__` calls). Every other message, and every PUBLISH that fails any check or
falls outside what this loop handles (more than 64 cells), goes to the codec's Python `_decode_one`, the
reference, so an error is raised by the same code with the same code and text. Built by pip where a C compiler
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

cdef object _Publish = None
cdef Py_ssize_t _off_entity, _off_seq, _off_cells, _off_validity, _off_payload


cdef Py_ssize_t _offset(cls, str name) except -1:
    d = cls.__dict__[name]
    if type(d).__name__ != "member_descriptor":
        raise TypeError(f"{cls.__name__}.{name} is not a slot")
    return (<PyMemberDescrObject*><PyObject*>d).d_member.offset


def bind(publish_cls, long long publish_type, long long max_int, long long max_cell, long long max_validity_ms):
    """Give the loop the `Publish` class and the protocol's bounds (one home: entitynet.protocol.messages)."""
    global _Publish, _off_entity, _off_seq, _off_cells, _off_validity, _off_payload
    global PUBLISH, MAX_INT, MAX_CELL, MAX_VALIDITY_MS
    if tuple(publish_cls.__slots__) != ("entity", "seq", "cells", "validity_ms", "payload"):
        raise TypeError("Publish's fields changed: update entitynet/protocol/_decode.pyx")
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


def decode_messages(tuple obj, lim, Py_ssize_t max_cells, Py_ssize_t max_payload, decode_one):
    """`[decode_one(m, lim) for m in obj]`, with PUBLISHes that pass every check built here."""
    cdef list out = []
    cdef int overflow = 0
    for m in obj:
        if type(m) is tuple and len(<tuple>m) == 6:
            t = (<tuple>m)[0]
            if type(t) is int and PyLong_AsLongLongAndOverflow(t, &overflow) == PUBLISH and overflow == 0:
                p = _publish(<tuple>m, max_cells, max_payload)
                if p is not None:
                    out.append(p)
                    continue
        out.append(decode_one(m, lim))
    return out
