# cython: language_level=3, boundscheck=False, wraparound=False
# distutils: extra_compile_args = -ffp-contract=off
"""`NearIndex.way_cells`'s candidate loop and `within_ring`'s nearest segment compiled (entitynet/client/lateral.py, the pure reference used where
pip did not build this module): the box test of the position's widened bucket, each candidate's projection
(`Placer.project_on`, term for term), its direction and its cell pieces. The same IEEE operations in the same
order (no multiply-add contraction: `-ffp-contract=off`), and the distance through Python's own `math.hypot`,
whose rounding the reference has. tests/entitynet/client/test_lateral.py holds both equal."""

from libc.math cimport INFINITY, sqrt  # (sqrt correctly rounded, as Python's math.sqrt, which calls it)
from math import hypot as _hypot  # (Python's, not the C library's: the same rounding as the reference)


cdef inline tuple _point(object w, double offset):
    """`_Way.point` for an edge of one segment (its operands in `w.one`), else the way's own method."""
    one = w.one
    if one is None:
        return w.point(offset)
    cdef double x0, y0, x1, y1, c0, c1, seg, ddx, ddy, t
    x0, y0, x1, y1, c0, c1, seg, ddx, ddy = one
    if offset <= 0.0:
        return (x0, y0)
    if offset >= c1:
        return (x1, y1)
    t = 0.0 if seg <= 0.0 else (offset - c0) / seg
    return (x0 + t * ddx, y0 + t * ddy)


def wide_candidates(tuple rows, double x0, double y0, double x1, double y1):
    """The `_Way`s of a widened bucket's rows (edge, bx0, by0, bx1, by1, way) whose boxes meet the closed box
    (x0, y0, x1, y1), in row order."""
    cdef list out = []
    cdef double bx0, by0, bx1, by1
    for row in rows:
        bx0, by0, bx1, by1 = row[1], row[2], row[3], row[4]
        if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0):
            out.append(row[5])
    return out


def way_cells(list cand, double x, double y, double dx, double dy, double r, double back, double ahead,
              skip, only):
    """The candidate loop of `NearIndex.way_cells` over the `_Way`s `cand` (see there)."""
    cdef list out = []
    cdef double best_d, bu, bc0, bsl, u, dd, ax, ay, sdx, sdy, l2, c0, sl, offset, length, h, b, lo, hi
    cdef double hx0, hy0, bx0, by0, a0, b0
    cdef bint found
    hypot = _hypot
    for w in cand:
        e = w.edge
        if e in skip or (only is not None and e not in only):
            continue
        best_d = INFINITY
        found = False
        bu = bc0 = bsl = 0.0
        for seg in w.segs:
            ax, ay, sdx, sdy, l2, c0, sl = seg
            if l2 <= 0.0:
                u = 0.0
            else:
                u = ((x - ax) * sdx + (y - ay) * sdy) / l2
                u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
            dd = hypot(x - (ax + u * sdx), y - (ay + u * sdy))
            if dd < best_d:
                best_d, found, bu, bc0, bsl = dd, True, u, c0, sl
        offset = bc0 + bu * bsl if found else 0.0
        if best_d > r:
            continue
        length = w.length
        h = offset + 1.0
        b = offset - 1.0
        hx0, hy0 = _point(w, length if length < h else h)
        bx0, by0 = _point(w, 0.0 if 0.0 > b else b)
        if ((hx0 - bx0) * dx + (hy0 - by0) * dy) >= 0.0:
            lo, hi = offset - back, offset + ahead
        else:
            lo, hi = offset - ahead, offset + back
        lo = 0.0 if 0.0 > lo else lo
        hi = length if length < hi else hi
        for piece in w.pieces:
            a0, b0 = piece[0], piece[1]
            if b0 >= lo and a0 <= hi:
                c = piece[2]
                if c not in out:
                    out.append(c)
    return out


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
