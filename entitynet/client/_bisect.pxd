# cython: language_level=3
"""`bisect.bisect_right` for the compiled client modules (`_geom.pyx`, `_occupy.pyx`): over a list of floats, read
with bounds checks and negative indices as Python reads it, and over a C array of doubles (the caller owns the
bounds); one definition each, inlined where it is cimported. A NaN x compares false, so lo ends at hi, as in the
bisect module. (`_fleet.pyx` keeps its own over a strided memoryview.)"""

cimport cython


@cython.boundscheck(True)
@cython.wraparound(True)
cdef inline Py_ssize_t bisect_right(list a, double x, Py_ssize_t lo, Py_ssize_t hi):
    cdef Py_ssize_t mid
    while lo < hi:
        mid = (lo + hi) >> 1
        if x < <double>a[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


cdef inline Py_ssize_t bisect_right_c(const double *a, double x, Py_ssize_t lo, Py_ssize_t hi) noexcept:
    cdef Py_ssize_t mid
    while lo < hi:
        mid = (lo + hi) >> 1
        if x < a[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo
