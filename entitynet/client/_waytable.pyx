# cython: language_level=3, boundscheck=False, wraparound=False
# distutils: extra_compile_args = -ffp-contract=off
"""`NearIndex.way_cells` over C tables (entitynet/client/lateral.py; the pure `_way_cells_py` and the compiled
per-object loop `_lateral.way_cells` are the references): the lateral cover was the largest part of a publish
(issue 22), and most of its cost was reading Python objects (each candidate's rows, segments and pieces as
tuples) and calling Python's `math.hypot` once per segment. Here a `WayTable` holds, once per `NearIndex`, every
widened bucket's rows as slot numbers, each edge's box, projection segments, cell pieces and geometry as C
arrays, and `py_hypot` is CPython's own `math.hypot` of two floats (`vector_norm` of Python 3.10-3.12, the
correctly rounded sum of squares and its differential correction), written out in C, so the distances are
Python's bit for bit. The same IEEE operations in the same order (no multiply-add contraction:
`-ffp-contract=off`). tests/entitynet/client/test_waytable.py holds `py_hypot` equal to `math.hypot` on hard and
random inputs, and `WayTable.way_cells` equal to the pure loop."""

from cpython.long cimport PyLong_FromDouble
from cpython.mem cimport PyMem_Free, PyMem_Malloc
from libc.math cimport INFINITY, NAN, fabs, frexp, isinf, isnan, ldexp, sqrt

cimport cython
from libc.math cimport floor as c_floor

from entitynet.client._bisect cimport bisect_right, bisect_right_c

cdef double WIDE_SIZE = 20.0  # lateral.WIDE_SIZE (a test holds them equal)


@cython.boundscheck(True)
@cython.wraparound(True)
cdef inline Py_ssize_t _bisect_left(list a, double x):
    """`bisect.bisect_left` over a list of floats (a NaN x compares false: lo ends at hi... as in the module)."""
    cdef Py_ssize_t lo = 0, hi = len(a), mid
    while lo < hi:
        mid = (lo + hi) >> 1
        if <double>a[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


cdef object _floor(double v):
    """`math.floor(v)` of a float: the int, or the same error for NaN and the infinities."""
    if v != v:
        raise ValueError("cannot convert float NaN to integer")
    if isinf(v):
        raise OverflowError("cannot convert float infinity to integer")
    return PyLong_FromDouble(c_floor(v))


cdef double py_hypot_c(double a, double b) noexcept nogil:
    """`math.hypot(a, b)` as CPython 3.11 computes it (Modules/mathmodule.c: `math_hypot`, `vector_norm`)."""
    cdef double v[2]
    cdef double mx = 0.0, x, t, hi, lo, h, oldcsum, scale
    cdef double csum = 1.0, frac1 = 0.0, frac2 = 0.0, frac3 = 0.0
    cdef double T27 = 134217729.0  # ldexp(1.0, 27) + 1.0: Veltkamp-Dekker's split
    cdef int max_e, i
    cdef bint found_nan = False
    v[0] = fabs(a)
    v[1] = fabs(b)
    for i in range(2):
        found_nan |= isnan(v[i])
        if v[i] > mx:
            mx = v[i]
    if isinf(mx):
        return mx
    if found_nan:
        return NAN
    if mx == 0.0:
        return mx
    frexp(mx, &max_e)
    if max_e < -1023:  # ldexp(1.0, -max_e) would overflow: divide by the largest instead
        for i in range(2):
            x = v[i] / mx
            x = x * x
            oldcsum = csum
            csum += x
            frac1 += (oldcsum - csum) + x
        return mx * sqrt(csum - 1.0 + frac1)
    scale = ldexp(1.0, -max_e)
    for i in range(2):
        x = v[i] * scale
        t = x * T27
        hi = t - (t - x)
        lo = x - hi
        x = hi * hi
        oldcsum = csum
        csum += x
        frac1 += (oldcsum - csum) + x
        x = 2.0 * hi * lo
        oldcsum = csum
        csum += x
        frac2 += (oldcsum - csum) + x
        frac3 += lo * lo
    h = sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    x = h
    t = x * T27
    hi = t - (t - x)
    lo = x - hi
    x = -hi * hi
    oldcsum = csum
    csum += x
    frac1 += (oldcsum - csum) + x
    x = -2.0 * hi * lo
    oldcsum = csum
    csum += x
    frac2 += (oldcsum - csum) + x
    x = -lo * lo
    oldcsum = csum
    csum += x
    frac3 += (oldcsum - csum) + x
    x = csum - 1.0 + (frac1 + frac2 + frac3)
    return (h + x / (2.0 * h)) / scale


def wide_size():
    """The widened buckets' size this module keys by (lateral.WIDE_SIZE: a test holds them equal)."""
    return WIDE_SIZE


def py_hypot(double a, double b):
    """`math.hypot(a, b)` computed in C (for the tests that hold the two equal)."""
    return py_hypot_c(a, b)


cdef class WayTable:
    """One `NearIndex`'s widened buckets and `_Way`s as C arrays (built once; read-only afterwards)."""

    cdef dict buckets  # bucket key -> (first row, row count) in `rows`
    cdef Py_ssize_t *rows  # slot of each row, bucket after bucket
    cdef double *box  # per slot: bx0, by0, bx1, by1
    cdef Py_ssize_t *seg_off  # per slot + 1: its segments in `seg`
    cdef double *seg  # per segment: ax, ay, sdx, sdy, l2, c0, sl
    cdef Py_ssize_t *piece_off  # per slot + 1: its pieces in `pa`, `pb`, `pc`
    cdef double *pa
    cdef double *pb
    cdef long *pc
    cdef double *length
    cdef Py_ssize_t *geom_lo  # per slot: its geometry's first and one-past-last point in gx, gy, gcum
    cdef Py_ssize_t *geom_hi
    cdef double *gx
    cdef double *gy
    cdef double *gcum
    cdef dict slot_of  # edge id -> its slot
    cdef list edge_obj  # per slot: the edge id as the Python int the `skip` / `only` tests look up
    cdef long *edge_id  # per slot: the edge id

    def __cinit__(self):
        self.rows = NULL
        self.box = self.seg = self.pa = self.pb = self.length = self.gx = self.gy = self.gcum = NULL
        self.seg_off = self.piece_off = self.geom_lo = self.geom_hi = NULL
        self.pc = self.edge_id = NULL

    def __init__(self, dict wide, dict ways, net):
        cdef dict slot_of = {}
        self.slot_of = slot_of
        cdef list order = []
        for e in sorted(ways):
            slot_of[e] = len(order)
            order.append(ways[e])
        cdef Py_ssize_t m = len(order), i, j, k, n_rows = 0, n_seg = 0, n_piece = 0, n_geom = len(net.gx)
        for rows in wide.values():
            n_rows += len(rows)
        for w in order:
            n_seg += len(w.segs)
            n_piece += len(w.pieces)
        self.rows = <Py_ssize_t *>_alloc((n_rows + 1) * sizeof(Py_ssize_t))
        self.box = <double *>_alloc((4 * m + 1) * sizeof(double))
        self.seg_off = <Py_ssize_t *>_alloc((m + 1) * sizeof(Py_ssize_t))
        self.seg = <double *>_alloc((7 * n_seg + 1) * sizeof(double))
        self.piece_off = <Py_ssize_t *>_alloc((m + 1) * sizeof(Py_ssize_t))
        self.pa = <double *>_alloc((n_piece + 1) * sizeof(double))
        self.pb = <double *>_alloc((n_piece + 1) * sizeof(double))
        self.pc = <long *>_alloc((n_piece + 1) * sizeof(long))
        self.length = <double *>_alloc((m + 1) * sizeof(double))
        self.edge_id = <long *>_alloc((m + 1) * sizeof(long))
        self.geom_lo = <Py_ssize_t *>_alloc((m + 1) * sizeof(Py_ssize_t))
        self.geom_hi = <Py_ssize_t *>_alloc((m + 1) * sizeof(Py_ssize_t))
        self.gx = <double *>_alloc((n_geom + 1) * sizeof(double))
        self.gy = <double *>_alloc((n_geom + 1) * sizeof(double))
        self.gcum = <double *>_alloc((n_geom + 1) * sizeof(double))
        for k in range(n_geom):
            self.gx[k], self.gy[k], self.gcum[k] = net.gx[k], net.gy[k], net.gcum[k]
        self.edge_obj = []
        k = j = 0
        self.seg_off[0] = self.piece_off[0] = 0
        for i in range(m):
            w = order[i]
            e = w.edge
            self.edge_obj.append(e)
            self.edge_id[i] = e
            self.length[i] = w.length
            self.geom_lo[i], self.geom_hi[i] = net.geom_off[e], net.geom_off[e + 1]
            for s in w.segs:
                for c in range(7):
                    self.seg[7 * k + c] = s[c]
                k += 1
            self.seg_off[i + 1] = k
            for a0, b0, cell in w.pieces:
                self.pa[j], self.pb[j], self.pc[j] = a0, b0, cell
                j += 1
            self.piece_off[i + 1] = j
        self.buckets = {}
        k = 0
        for key, rows in wide.items():
            self.buckets[key] = (k, len(rows))
            for row in rows:
                i = slot_of[row[0]]
                self.rows[k] = i
                self.box[4 * i], self.box[4 * i + 1], self.box[4 * i + 2], self.box[4 * i + 3] = (
                    row[1], row[2], row[3], row[4])
                k += 1

    def __dealloc__(self):
        PyMem_Free(self.rows)
        PyMem_Free(self.box)
        PyMem_Free(self.seg_off)
        PyMem_Free(self.seg)
        PyMem_Free(self.piece_off)
        PyMem_Free(self.pa)
        PyMem_Free(self.pb)
        PyMem_Free(self.pc)
        PyMem_Free(self.length)
        PyMem_Free(self.edge_id)
        PyMem_Free(self.geom_lo)
        PyMem_Free(self.geom_hi)
        PyMem_Free(self.gx)
        PyMem_Free(self.gy)
        PyMem_Free(self.gcum)

    cdef inline void _point(self, Py_ssize_t i, double offset, double *px, double *py) noexcept:
        """`NetView.point(edge, offset)` of slot i (and `_Way.point`, its one-segment case written out)."""
        cdef Py_ssize_t lo = self.geom_lo[i], hi = self.geom_hi[i], k
        cdef double seg, t, x0, y0
        if offset <= 0.0:
            px[0], py[0] = self.gx[lo], self.gy[lo]
            return
        if offset >= self.gcum[hi - 1]:
            px[0], py[0] = self.gx[hi - 1], self.gy[hi - 1]
            return
        if hi - lo == 2:
            k = lo
        else:
            k = bisect_right_c(self.gcum, offset, lo, hi) - 1
            k = min(max(k, lo), hi - 2)
        seg = self.gcum[k + 1] - self.gcum[k]
        t = 0.0 if seg <= 0.0 else (offset - self.gcum[k]) / seg
        x0, y0 = self.gx[k], self.gy[k]
        px[0] = x0 + t * (self.gx[k + 1] - x0)
        py[0] = y0 + t * (self.gy[k + 1] - y0)

    def way_cells(self, key, double x, double y, double dx, double dy, double r, double back, double ahead,
                  skip, only):
        """`NearIndex.way_cells` for r <= WIDE: the rows of the widened bucket `key` (that of (x, y)), their
        box test against the box of half-size r, then `_way_cells_py`'s loop, term for term."""
        hit = self.buckets.get(key)
        if hit is None:
            return []
        cdef Py_ssize_t first = hit[0], n = hit[1]
        return self._cells(self.rows + first, n, True, x, y, dx, dy, r, back, ahead, skip, only, NULL, 0)

    def edges_cells(self, edges, double x, double y, double dx, double dy, double r, double back, double ahead,
                    skip, only):
        """`way_cells`' loop over the given edges (`NearIndex.edges_near`'s answer for r > WIDE), no box test."""
        cdef Py_ssize_t n = len(edges), k = 0
        cdef Py_ssize_t *slots = <Py_ssize_t *>_alloc((n + 1) * sizeof(Py_ssize_t))
        try:
            for e in edges:
                slots[k] = self.slot_of[e]
                k += 1
            return self._cells(slots, n, False, x, y, dx, dy, r, back, ahead, skip, only, NULL, 0)
        finally:
            PyMem_Free(slots)

    def path_cells(self, path, double s, double r, double back, double ahead, only):
        """`NearIndex.path_cells` for r <= WIDE: the points at s and a metre either side (`Path.xy`), the path's
        edges in [s - back, s + ahead] and the one at s as C ids to skip (`_edges_between`, `Path.locate`), then
        `way_cells` of the position's widened bucket."""
        cdef list cum = path.cum, edges = path.edges
        cdef Py_ssize_t n = len(edges), k0, k1, k, m = 0
        cdef double length, sh = s + 1.0, sb = s - 1.0, lo = s - back, hi = s + ahead
        cdef long ids[64]
        cdef double x, y, hx, hy, bx, by
        if n == 0 or len(cum) != n + 1:
            raise ValueError("a path needs an edge and a cumulative length at each end of each")
        length = cum[n]
        xy = path.xy
        x, y = xy(s)
        hx, hy = xy(length if length < sh else sh)  # min(s + 1.0, path.length), as the builtin chooses
        bx, by = xy(0.0 if 0.0 > sb else sb)  # max(s - 1.0, 0.0)
        skip = None
        if lo == lo and hi == hi:  # `_edges_between`: none for a NaN bound
            k0 = _bisect_left(cum, lo) - 1
            k1 = bisect_right(cum, hi, 0, len(cum))
            k0 = k0 if k0 > 0 else 0
            k1 = k1 if k1 < n else n
            if k1 - k0 >= 64:  # more than the C buffer: a set, as the reference builds
                skip = {edges[k][0] for k in range(k0, k1)}
            else:
                for k in range(k0, k1):
                    ids[m] = edges[k][0]
                    m += 1
        k = bisect_right(cum, s, 0, len(cum)) - 1  # `Path.locate(s)`'s edge
        if k < 0:
            k = 0
        elif k >= n:
            k = n - 1
        if skip is None:
            ids[m] = edges[k][0]
            m += 1
        else:
            skip.add(edges[k][0])
        hit = self.buckets.get((_floor(x / WIDE_SIZE), _floor(y / WIDE_SIZE)))
        if hit is None:
            return []
        return self._cells(self.rows + <Py_ssize_t>hit[0], hit[1], True, x, y, hx - bx, hy - by, r, back, ahead,
                           skip, only, ids, m)

    cdef list _cells(self, const Py_ssize_t *slots, Py_ssize_t n, bint box, double x, double y, double dx,
                     double dy, double r, double back, double ahead, skip, only, const long *skip_ids,
                     Py_ssize_t n_skip):
        """The loop of `way_cells` over `n` slots (`box`: those whose boxes miss the box of half-size r
        skipped); `skip` a container of edge ids, or None and the ids in `skip_ids`."""
        cdef list out = []
        cdef Py_ssize_t q, i, g, p, n_out = 0
        cdef double x0 = x - r, y0 = y - r, x1 = x + r, y1 = y + r
        cdef double best_d, bu, bc0, bsl, u, dd, ax, ay, sdx, sdy, l2, offset, length, h, b, lo, hi
        cdef double hx0, hy0, bx0, by0
        cdef const double *bx
        cdef const double *sg
        cdef bint found, seen
        cdef long c, ei
        cdef long got[64]
        cdef list extra = None
        for q in range(n):
            i = slots[q]
            bx = self.box + 4 * i
            if box and (bx[0] > x1 or bx[2] < x0 or bx[1] > y1 or bx[3] < y0):
                continue
            e = self.edge_obj[i]
            if skip is not None:
                if e in skip:
                    continue
            else:
                ei = self.edge_id[i]
                seen = False
                for g in range(n_skip):
                    if skip_ids[g] == ei:
                        seen = True
                        break
                if seen:
                    continue
            if only is not None and e not in only:
                continue
            best_d = INFINITY
            found = False
            bu = bc0 = bsl = 0.0
            for g in range(self.seg_off[i], self.seg_off[i + 1]):
                sg = self.seg + 7 * g
                ax, ay, sdx, sdy, l2 = sg[0], sg[1], sg[2], sg[3], sg[4]
                if l2 <= 0.0:
                    u = 0.0
                else:
                    u = ((x - ax) * sdx + (y - ay) * sdy) / l2
                    u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
                dd = py_hypot_c(x - (ax + u * sdx), y - (ay + u * sdy))
                if dd < best_d:
                    best_d, found, bu, bc0, bsl = dd, True, u, sg[5], sg[6]
            offset = bc0 + bu * bsl if found else 0.0
            if best_d > r:
                continue
            length = self.length[i]
            h = offset + 1.0
            b = offset - 1.0
            self._point(i, length if length < h else h, &hx0, &hy0)
            self._point(i, 0.0 if 0.0 > b else b, &bx0, &by0)
            if ((hx0 - bx0) * dx + (hy0 - by0) * dy) >= 0.0:
                lo, hi = offset - back, offset + ahead
            else:
                lo, hi = offset - ahead, offset + back
            lo = 0.0 if 0.0 > lo else lo
            hi = length if length < hi else hi
            for p in range(self.piece_off[i], self.piece_off[i + 1]):
                if self.pb[p] >= lo and self.pa[p] <= hi:
                    c = self.pc[p]
                    seen = False
                    for g in range(n_out if n_out < 64 else 64):
                        if got[g] == c:
                            seen = True
                            break
                    if not seen and extra is not None:  # more cells than the C buffer: the rest in a list
                        seen = c in extra
                    if not seen:
                        if n_out < 64:
                            got[n_out] = c
                        else:
                            if extra is None:
                                extra = []
                            extra.append(c)
                        n_out += 1
                        out.append(c)
        return out


cdef void *_alloc(size_t size) except NULL:
    cdef void *p = PyMem_Malloc(size)
    if p == NULL:
        raise MemoryError()
    return p


def areas_near(dict grid, double bucket, double x, double y, double r):
    """`Placer.areas_near`'s bucket walk over its built grid `grid` of (area, bx0, by0, bx1, by1) rows (buckets
    of `bucket` metres, the 1 m pad): the areas whose boxes are within r of (x, y), sorted."""
    cdef set out = set()
    cdef double bx0, by0, bx1, by1
    cdef tuple row
    for gx in range(_floor((x - r - 1.0) / bucket), _floor((x + r + 1.0) / bucket) + 1):
        for gy in range(_floor((y - r - 1.0) / bucket), _floor((y + r + 1.0) / bucket) + 1):
            rows = grid.get((gx, gy))
            if rows is None:
                continue
            for row in rows:
                bx0, by0, bx1, by1 = row[1], row[2], row[3], row[4]
                if bx0 - r <= x and x <= bx1 + r and by0 - r <= y and y <= by1 + r:
                    out.add(row[0])
    return sorted(out)
