# cython: language_level=3, boundscheck=False, wraparound=False
# distutils: extra_compile_args = -ffp-contract=off
"""`NearIndex.within_ring`'s nearest segment compiled (entitynet/client/lateral.py, the pure reference used where
pip did not build this module). The same IEEE operations in the same order (no multiply-add contraction:
`-ffp-contract=off`). tests/entitynet/client/test_lateral.py holds both equal. (The lateral cover's candidate loop,
compiled here before, is `_waytable.pyx`'s now, over C tables.)"""

from libc.math cimport INFINITY, sqrt  # (sqrt correctly rounded, as Python's math.sqrt, which calls it)


def ring_nearest(tuple segs, double x, double y):
    """The distance from (x, y) to the nearest of an area ring's segments (x0, y0, dx, dy, l2): the loop of
    `NearIndex.within_ring` (the square root of the least squared distance; inf for no segment)."""
    cdef double best = INFINITY, p0x, p0y, dx, dy, l2, t, ex, ey, d2
    for seg in segs:
        p0x, p0y, dx, dy, l2 = seg
        t = ((x - p0x) * dx + (y - p0y) * dy) / l2
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        ex = p0x + t * dx - x
        ey = p0y + t * dy - y
        d2 = ex * ex + ey * ey
        if d2 < best:
            best = d2
    return sqrt(best)
