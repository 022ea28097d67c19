# cython: language_level=3, boundscheck=False, wraparound=False
"""Compiled accessors of a client-state row's fields (entitynet/client/state.py), where pip built them: the same
reads and writes as `state.column`'s compiled-from-a-template Python properties (the reference, used where this
module is absent), a C descriptor instead of a Python function call (about half the cost a read, a third a
write). tests/entitynet/client/test_state.py checks both kinds field for field."""

from cpython.array cimport array
from cpython.number cimport PyNumber_Index


cdef class FloatCol:
    """A float field: `obj._st.f[obj._fb + j]`."""
    cdef Py_ssize_t j

    def __init__(self, Py_ssize_t j):
        self.j = j

    def __get__(self, obj, objtype):
        if obj is None:
            return self
        cdef array f = obj._st.f
        cdef Py_ssize_t b = obj._fb
        return f.data.as_doubles[b + self.j]

    def __set__(self, obj, double v):
        cdef array f = obj._st.f
        cdef Py_ssize_t b = obj._fb
        f.data.as_doubles[b + self.j] = v


cdef class OptCol:
    """A float field that reads NaN as None and writes None as NaN."""
    cdef Py_ssize_t j

    def __init__(self, Py_ssize_t j):
        self.j = j

    def __get__(self, obj, objtype):
        if obj is None:
            return self
        cdef array f = obj._st.f
        cdef Py_ssize_t b = obj._fb
        cdef double v = f.data.as_doubles[b + self.j]
        return None if v != v else v

    def __set__(self, obj, v):
        cdef array f = obj._st.f
        cdef Py_ssize_t b = obj._fb
        f.data.as_doubles[b + self.j] = float("nan") if v is None else <double>v


cdef class IntCol:
    """An integer field: `obj._st.i[obj._ib + j]` (`as_bool`: read as a bool, written as 0 / 1)."""
    cdef Py_ssize_t j
    cdef bint as_bool

    def __init__(self, Py_ssize_t j, bint as_bool=False):
        self.j = j
        self.as_bool = as_bool

    def __get__(self, obj, objtype):
        if obj is None:
            return self
        cdef array i = obj._st.i
        cdef Py_ssize_t b = obj._ib
        cdef long long v = i.data.as_longlongs[b + self.j]
        if self.as_bool:
            return v != 0
        return v

    def __set__(self, obj, v):
        cdef array i = obj._st.i
        cdef Py_ssize_t b = obj._ib
        # an integer or what `operator.index` takes, as `array('q')` does: a float raises TypeError, not truncated
        i.data.as_longlongs[b + self.j] = (1 if v else 0) if self.as_bool else <long long>PyNumber_Index(v)


cdef class RingCols:
    """`state.Ring` compiled: RECENT columns from float column j, oldest first, right-aligned, their count in
    int column c."""
    cdef Py_ssize_t j, c, n

    def __init__(self, Py_ssize_t j, Py_ssize_t c, Py_ssize_t n):
        self.j, self.c, self.n = j, c, n

    def get(self, o):
        """The kept values, oldest first (a new list)."""
        cdef array f = o._st.f
        cdef array i = o._st.i
        cdef Py_ssize_t b = <Py_ssize_t>o._fb + self.j
        cdef Py_ssize_t k = i.data.as_longlongs[<Py_ssize_t>o._ib + self.c]
        return [f.data.as_doubles[b + self.n - k + m] for m in range(k)]

    def push(self, o, double v, bint counted=True):
        """Append `v`, dropping the oldest beyond RECENT."""
        cdef array f = o._st.f
        cdef Py_ssize_t b = <Py_ssize_t>o._fb + self.j
        cdef Py_ssize_t m
        for m in range(self.n - 1):
            f.data.as_doubles[b + m] = f.data.as_doubles[b + m + 1]
        f.data.as_doubles[b + self.n - 1] = v
        cdef array i
        cdef Py_ssize_t c
        if counted:
            i = o._st.i
            c = <Py_ssize_t>o._ib + self.c
            if i.data.as_longlongs[c] < self.n:
                i.data.as_longlongs[c] += 1

    def put(self, o, values):
        """Replace the kept values (at most RECENT, oldest first)."""
        cdef Py_ssize_t k = len(values)
        if k > self.n:
            raise ValueError(f"a ring keeps at most {self.n} values, got {k}")
        cdef array f = o._st.f
        cdef array i = o._st.i
        cdef Py_ssize_t b = <Py_ssize_t>o._fb + self.j
        cdef Py_ssize_t m
        for m in range(k):
            f.data.as_doubles[b + self.n - k + m] = values[m]
        i.data.as_longlongs[<Py_ssize_t>o._ib + self.c] = k

    def clear(self, o):
        """Keep nothing."""
        cdef array i = o._st.i
        i.data.as_longlongs[<Py_ssize_t>o._ib + self.c] = 0


cdef class FlagRef:
    """`obj.<attr>` while int column j is set, else None; set only to None (clears the flag): the tracker's
    along-path filter (`TrackerState.kf`)."""
    cdef Py_ssize_t j
    cdef str attr

    def __init__(self, Py_ssize_t j, str attr):
        self.j, self.attr = j, attr

    def __get__(self, obj, objtype):
        if obj is None:
            return self
        cdef array i = obj._st.i
        if i.data.as_longlongs[<Py_ssize_t>obj._ib + self.j]:
            return getattr(obj, self.attr)
        return None

    def __set__(self, obj, v):
        if v is not None:
            raise ValueError("the along-path filter is the row's: start it with `_start_filter`")
        cdef array i = obj._st.i
        i.data.as_longlongs[<Py_ssize_t>obj._ib + self.j] = 0


cdef class PathRef:
    """The tracker's path (`TrackerState.path`): the row's cached `Path`, else `obj._path_from_arrays()`; a new
    one is put in the cache with `pn` (int column j) -1 (the object is the truth), None clears it."""
    cdef Py_ssize_t j

    def __init__(self, Py_ssize_t j):
        self.j = j

    def __get__(self, obj, objtype):
        if obj is None:
            return self
        p = obj._st.paths[obj._row]
        if p is None:
            return obj._path_from_arrays()
        return p

    def __set__(self, obj, path):
        st = obj._st
        st.paths[obj._row] = path
        cdef array i = st.i
        i.data.as_longlongs[<Py_ssize_t>obj._ib + self.j] = 0 if path is None else -1
