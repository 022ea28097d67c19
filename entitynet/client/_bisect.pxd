# cython: language_level=3
"""`bisect.bisect_right` over a list of floats for the compiled client modules (`_geom.pyx`, `_occupy.pyx`): one
definition, inlined where it is cimported. The list is read with bounds checks and negative indices as Python
reads it; a NaN x compares false, so lo ends at hi, as in the bisect module."""

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
