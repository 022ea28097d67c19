# cython: language_level=3, boundscheck=False, wraparound=False
# distutils: extra_compile_args = -ffp-contract=off
"""Compiled accessors of a client-state row's fields (entitynet/client/state.py), where pip built them: the same
reads and writes as `state.column`'s compiled-from-a-template Python properties (the reference, used where this
module is absent), a C descriptor instead of a Python function call (about half the cost a read, a third a
write). tests/entitynet/client/test_state.py checks both kinds field for field. And the along-path filter's
update on a row (`kalman_row`), the one arithmetic of the usual fix worth compiling (no multiply-add
contraction: `-ffp-contract=off`, so that the C operations round as Python's do)."""

from cpython.array cimport array
from cpython.number cimport PyNumber_Index
from libc.math cimport INFINITY


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


def kalman_row(array f, Py_ssize_t b, bint accel, double z, double t, double r):
    """`filters.kalman_update` on the filter fields of a row in place (ks, kv, ka, p00 .. p22, kt, kq from
    float column b, `accel` the row's kacc): the same IEEE operations in the same order, written out in C
    (x86-64 without FMA: no contraction). Returns the new (s, v). The pure `RowKinematic.update_sv` is the
    reference; tests/entitynet/client/test_state.py holds them equal bit for bit."""
    if b < 0 or b + 11 > len(f):
        raise IndexError("the filter's fields are outside the block")
    cdef double* p = f.data.as_doubles + b
    cdef double s = p[0], v = p[1], a = p[2], p00 = p[3], p01 = p[4], p02 = p[5]
    cdef double p11 = p[6], p12 = p[7], p22 = p[8], t0 = p[9], q = p[10]
    cdef double dt = t - t0, h, r00, r01, r02, r11, r12, dt2, dt3, y, sden, k0, k1, k2
    if dt > 0.0:
        h = 0.5 * dt * dt
        if accel:
            s += v * dt + a * h
            v += a * dt
            r00 = p00 + dt * p01 + h * p02
            r01 = p01 + dt * p11 + h * p12
            r02 = p02 + dt * p12 + h * p22
            r11 = p11 + dt * p12
            r12 = p12 + dt * p22
            dt2 = dt * dt
            dt3 = dt2 * dt
            p00 = r00 + dt * r01 + h * r02 + q * dt3 * dt2 / 20.0
            p01 = r01 + dt * r02 + q * dt2 * dt2 / 8.0
            p02 = r02 + q * dt3 / 6.0
            p11 = r11 + dt * r12 + q * dt3 / 3.0
            p12 = r12 + q * dt2 / 2.0
            p22 = p22 + q * dt
        else:
            s += v * dt
            p00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q * dt * dt * dt / 3.0
            p01 = p01 + dt * p11 + q * dt * dt / 2.0
            p11 = p11 + q * dt
        t0 = t
    y = z - s
    sden = p00 + r
    if not sden > 0.0:
        p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9] = s, v, a, p00, p01, p02, p11, p12, p22, t0
        return s, v
    k0, k1, k2 = p00 / sden, p01 / sden, p02 / sden
    p[0] = s + k0 * y
    p[1] = v + k1 * y
    p[2] = a + k2 * y
    p[3] = p00 - k0 * p00
    p[4] = p01 - k0 * p01
    p[5] = p02 - k0 * p02
    p[6] = p11 - k1 * p01
    p[7] = p12 - k1 * p02
    p[8] = p22 - k2 * p02
    p[9] = t0
    return p[0], p[1]



def path_into_row(array pe, array pd, array pc, Py_ssize_t row, Py_ssize_t width, list edges, list cum):
    """`Record.path_to_arrays`' copy of a `Path` (its `edges` and `cum`) into row `row` of the path blocks (edge
    and direction ints, cumulative lengths, inf after the last), in C: no array built per call. The same
    values as the reference's slice assignments; a path wider than `width` (or than 64), a `cum` that is not
    one longer than `edges`, a row outside the blocks or a value that is no int / float is refused
    (ValueError / IndexError / TypeError) with nothing written."""
    cdef Py_ssize_t n = len(edges), b = row * width, c = row * (width + 1), k
    cdef long long ev[64]
    cdef long long dv[64]
    cdef double sv[65]
    cdef tuple de
    if n > width or n > 64 or len(cum) != n + 1:
        raise ValueError("a path's cum must be one longer than its edges, and the edges fit the row")
    if row < 0 or b + width > len(pe) or b + width > len(pd) or c + width + 1 > len(pc):
        raise IndexError("the row is outside the path blocks")
    for k in range(n):  # (all converted first, as the reference builds its arrays before writing)
        de = edges[k]
        ev[k] = PyNumber_Index(de[0])  # (an int, as array("q") takes: a float is refused, not truncated)
        dv[k] = PyNumber_Index(de[1])
    for k in range(n + 1):
        sv[k] = cum[k]
    cdef long long *e = pe.data.as_longlongs + b
    cdef long long *d = pd.data.as_longlongs + b
    cdef double *s = pc.data.as_doubles + c
    for k in range(n):
        e[k] = ev[k]
        d[k] = dv[k]
    for k in range(n + 1):
        s[k] = sv[k]
    for k in range(n + 1, width + 1):
        s[k] = INFINITY
