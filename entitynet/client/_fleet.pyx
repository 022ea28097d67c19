# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# distutils: extra_compile_args = -ffp-contract=off
"""The fleet core's per-element kernels compiled (entitynet/client/fleet_kernels.py and fleet_near.py hold the
numpy references, used where pip did not build this module or ENTITYNET_PURE_PYTHON is set): the projection
onto one edge (`Geometry.project`), the point at a path coordinate (`Geometry.path_xy`), `math.hypot`
element-wise (`hypot_py`) and the neighbourhood search over the fleet's segment tables (`NearTables.near`).

Why compiled: numpy runs these as a dozen passes over temporaries as long as all of a tick's segments (a fix's
table holds tens of them), and the distances as one Python call per element; here each fix is one loop over its
own segments. The same IEEE operations in the same order as the references (no multiply-add contraction:
`-ffp-contract=off`; `cdivision` only drops Python's zero-division check, the divisions are guarded as the
references guard them), C's `sqrt` (correctly rounded, as numpy's) and Python's own `math.hypot` (whose
rounding the references have). tests/entitynet/client/test_fleet_compiled.py holds each equal to its reference
bit for bit, hostile inputs included. The indices come from the fleet's own arrays (edges of the map, columns
of a row's path): the wrappers check their ranges once per call, so a bad one is an IndexError, not stray memory.
"""

import numpy as np

from libc.math cimport INFINITY, fabs, sqrt
from math import hypot as _hypot  # (Python's, not the C library's: the same rounding as the references)


cdef inline double _hyp(double a, double b):
    return _hypot(a, b)


ctypedef struct geo_t:
    const double* gx
    const double* gy
    const double* sdx
    const double* sdy
    const double* sl2
    const double* gcum
    const double* slen
    const long* goff
    const long* nseg
    const double* edge_len
    Py_ssize_t n_edges
    Py_ssize_t n_vert


cdef int _geo_of(geo, geo_t* g) except -1:
    """Pointers into a `Geometry`'s arrays (contiguous, held by the Geometry while it lives)."""
    cdef const double[::1] gx = geo.gx, gy = geo.gy, sdx = geo.sdx, sdy = geo.sdy, sl2 = geo.sl2
    cdef const double[::1] gcum = geo.gcum, slen = geo.slen, edge_len = geo.edge_len
    cdef const long[::1] goff = geo.geom_off, nseg = geo.nseg
    if not (gy.shape[0] == sdx.shape[0] == sdy.shape[0] == sl2.shape[0] == gcum.shape[0] == slen.shape[0]
            == gx.shape[0] >= 1 and goff.shape[0] == edge_len.shape[0] + 1 and nseg.shape[0] == edge_len.shape[0]):
        raise ValueError("the geometry's arrays do not match")
    g.gx, g.gy, g.sdx, g.sdy, g.sl2 = &gx[0], &gy[0], &sdx[0], &sdy[0], &sl2[0]
    g.gcum, g.slen, g.edge_len = &gcum[0], &slen[0], &edge_len[0]
    g.goff, g.nseg = &goff[0], &nseg[0]
    g.n_edges, g.n_vert = edge_len.shape[0], gx.shape[0]
    return 0


def _check(const long[:] idx, Py_ssize_t n, str what):
    """Every index in [0, n): else IndexError (the loops below read without bounds checks)."""
    cdef Py_ssize_t i
    for i in range(idx.shape[0]):
        if idx[i] < 0 or idx[i] >= n:
            raise IndexError(f"{what} {idx[i]} out of range 0..{n - 1}")


def hypot_rows(const double[:] dx, const double[:] dy):
    """`math.hypot(dx[i], dy[i])` for every i."""
    cdef Py_ssize_t i, n = dx.shape[0]
    if dy.shape[0] != n:
        raise ValueError("dx and dy differ in length")
    out = np.empty(n)
    cdef double[::1] o = out
    for i in range(n):
        o[i] = _hyp(dx[i], dy[i])
    return out


cdef inline Py_ssize_t _bisect_right(const double[:] a, double v, Py_ssize_t lo, Py_ssize_t hi) noexcept nogil:
    """`bisect.bisect_right(a, v, lo, hi)` (a NaN v compares false: lo ends at hi)."""
    cdef Py_ssize_t mid
    while lo < hi:
        mid = (lo + hi) // 2
        if v < a[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


def path_xy(geo, const double[:] s, const long[:, :] pe, const long[:, :] pd, const double[:, :] cum,
            const long[:] n):
    """`Geometry.path_xy`: per row the point at path coordinate s[i] of the padded path (edges pe[i], directions
    pd[i], cumulative lengths cum[i], +inf past its n[i] edges), clamped to the path."""
    cdef const double[:] edge_len = geo.edge_len, gcum = geo.gcum, gx = geo.gx, gy = geo.gy
    cdef const long[:] goff = geo.geom_off
    cdef Py_ssize_t m = s.shape[0], w = pe.shape[1], i, j, k, kk, lo, hi, e, cnt
    if pe.shape[0] != m or pd.shape[0] != m or cum.shape[0] != m or n.shape[0] != m or pd.shape[1] != w \
            or cum.shape[1] < w:
        raise ValueError("the path arrays do not match")
    for i in range(m):
        if n[i] < 1 or n[i] > w:
            raise IndexError(f"a path of {n[i]} edges in rows of {w}")
        for j in range(n[i]):
            if pe[i, j] < 0 or pe[i, j] >= edge_len.shape[0]:
                raise IndexError(f"edge {pe[i, j]} out of range")
    x_a, y_a = np.empty(m), np.empty(m)
    cdef double[::1] xo = x_a, yo = y_a
    cdef double si, length, d, offv, c0, seg, t, x0, y0
    for i in range(m):
        si = s[i]
        cnt = 0
        for j in range(cum.shape[1]):
            if cum[i, j] <= si:
                cnt += 1
        k = cnt - 1
        k = 0 if k < 0 else (n[i] - 1 if k >= n[i] else k)
        e = pe[i, k]
        length = edge_len[e]
        d = si - cum[i, k]
        d = 0.0 if d < 0.0 else (length if d > length else d)
        offv = d if pd[i, k] > 0 else length - d
        lo, hi = goff[e], goff[e + 1]
        if hi - lo < 2 or hi > gx.shape[0]:
            raise ValueError(f"edge {e} has {hi - lo} vertices (a map's edge has two at least)")
        kk = _bisect_right(gcum, offv, lo, hi) - 1
        kk = lo if kk < lo else (hi - 2 if kk > hi - 2 else kk)
        if offv <= 0.0:
            xo[i], yo[i] = gx[lo], gy[lo]
        elif offv >= gcum[hi - 1]:
            xo[i], yo[i] = gx[hi - 1], gy[hi - 1]
        else:
            c0 = gcum[kk]
            seg = gcum[kk + 1] - c0
            t = 0.0 if seg <= 0.0 else (offv - c0) / seg
            x0, y0 = gx[kk], gy[kk]
            xo[i] = x0 + t * (gx[kk + 1] - x0)
            yo[i] = y0 + t * (gy[kk + 1] - y0)
    return x_a, y_a


def near(tables, const double[:] x, const double[:] y, const long[:] start, const long[:] count,
         const double[:] margin, const long[:, :] pe, const long[:] lo, const long[:] hi):
    """`NearTables.near`: per fix i the segments start[i] .. start[i] + count[i] - 1 of the tables, cost
    d + margin[i] off the path window pe[i, lo[i]..hi[i]] (d alone on it), the first least cost winning (a NaN
    cost first of all, as numpy's argmin in `Placer._near_np`): (edge, offset, px, py, distance, preferred?,
    any segment preferred?)."""
    cols = tables.cols
    cdef const double[:] ax_ = cols["ax"], ay_ = cols["ay"], dx_ = cols["dx"], dy_ = cols["dy"]
    cdef const double[:] il2 = cols["inv_l2"], cum0 = cols["cum0"], slen = cols["slen"]
    cdef const long[:] edge = tables.edge
    cdef Py_ssize_t m = x.shape[0], w = pe.shape[1], size = tables.size, i, k, j, kb
    if y.shape[0] != m or start.shape[0] != m or count.shape[0] != m or margin.shape[0] != m \
            or pe.shape[0] != m or lo.shape[0] != m or hi.shape[0] != m:
        raise ValueError("the fixes' arrays differ in length")
    for i in range(m):
        if count[i] < 1 or start[i] < 0 or start[i] + count[i] > size:
            raise IndexError(f"table rows {start[i]}..{start[i] + count[i] - 1} outside 0..{size - 1}")
        if lo[i] < 0 or hi[i] >= w or lo[i] > hi[i]:
            raise IndexError(f"path window {lo[i]}..{hi[i]} outside 0..{w - 1}")
    e_a = np.empty(m, dtype=np.int64)
    off_a, px_a, py_a, d_a = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    pref_a, anyp_a = np.empty(m, dtype=bool), np.empty(m, dtype=bool)
    cdef long[::1] eo = e_a
    cdef double[::1] offo = off_a, pxo = px_a, pyo = py_a, do = d_a
    cdef unsigned char[::1] prefo = pref_a.view(np.uint8), anyo = anyp_a.view(np.uint8)
    cdef double xi, yi, rx, ry, u, ex, ey, d, c, bc, bu, bd, mg
    cdef bint pref, bpref, anyp, nan_best
    cdef long ek
    for i in range(m):
        xi, yi, mg = x[i], y[i], margin[i]
        kb = -1
        bc = bu = bd = 0.0
        bpref = anyp = nan_best = False
        for k in range(start[i], start[i] + count[i]):
            rx = xi - ax_[k]
            ry = yi - ay_[k]
            u = (rx * dx_[k] + ry * dy_[k]) * il2[k]
            u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
            ex = rx - u * dx_[k]
            ey = ry - u * dy_[k]
            d = sqrt(ex * ex + ey * ey)
            ek = edge[k]
            pref = False
            for j in range(lo[i], hi[i] + 1):
                if pe[i, j] == ek:
                    pref = True
                    break
            anyp = anyp or pref
            c = d + (0.0 if pref else mg)
            if nan_best:
                continue
            if kb < 0 or c != c or c < bc:
                kb, bc, bu, bd, bpref = k, c, u, d, pref
                nan_best = c != c
        eo[i] = edge[kb]
        offo[i] = cum0[kb] + bu * slen[kb]
        pxo[i] = ax_[kb] + bu * dx_[kb]
        pyo[i] = ay_[kb] + bu * dy_[kb]
        do[i] = bd
        prefo[i] = bpref
        anyo[i] = anyp
    return e_a, off_a, px_a, py_a, d_a, pref_a, anyp_a


cdef inline bint _holds(const long[:, :] pe, Py_ssize_t i, Py_ssize_t k, long n, long e, Py_ssize_t w) noexcept:
    """Column k is one of row i's path (k < n) and holds edge e."""
    return 0 <= k < n and pe[i, 0 if k < 0 else (w - 1 if k >= w else k)] == e


cdef double _s_of(const long[:, :] pe, const long[:, :] pd, const double[:, :] pc, Py_ssize_t i, long n,
                  const double* edge_len, long e, double off, double s_pred, long hint) noexcept:
    """One row of `s_of_rows` (its docstring; `_nearest_occurrence` as numpy's argmin: a NaN gap first, else
    the first least over all columns, those without the edge being inf)."""
    cdef Py_ssize_t w = pe.shape[1], kc, j
    cdef long k, kk = hint, dk
    cdef bint found = False, again = False, occ_any = False, nan_seen = False
    cdef double elen = edge_len[e], along, g, best = INFINITY
    cdef Py_ssize_t jb = 0
    for dk in (0, 1, -1):
        k = hint + dk
        if not found and _holds(pe, i, k, n, e, w):
            kk = k
            found = True
    kc = 0 if kk < 0 else (w - 1 if kk >= w else kk)
    for dk in (-3, -2, -1, 1, 2, 3):
        if _holds(pe, i, kc + dk, n, e, w):
            again = True
    if found and not again:
        return pc[i, kc] + (off if pd[i, kc] > 0 else elen - off)
    for j in range(w):
        if pe[i, j] == e and j < n:
            occ_any = True
            along = off if pd[i, j] > 0 else elen - off
            g = fabs(pc[i, j] + along - s_pred)
        else:
            g = INFINITY
        if nan_seen:
            continue
        if g != g:
            jb, nan_seen = j, True
        elif j == 0 or g < best:
            jb, best = j, g
    if not occ_any:
        return s_pred
    return pc[i, jb] + (off if pd[i, jb] > 0 else elen - off)


def s_of_rows(const long[:, :] pe, const long[:, :] pd, const double[:, :] pc, const long[:] pn,
              const double[::1] edge_len, const long[:] e, const double[:] off, const double[:] s_pred,
              const long[:] k_hint):
    """`fleet_near.s_of_rows` (its docstring): per row the path coordinate of edge e[i] at offset off[i]."""
    cdef Py_ssize_t m = pe.shape[0], i
    _rows_match(pe, pd, pc, pn, m)
    if e.shape[0] != m or off.shape[0] != m or s_pred.shape[0] != m or k_hint.shape[0] != m:
        raise ValueError("the rows' arrays differ in length")
    _check(e, edge_len.shape[0], "edge")
    if edge_len.shape[0] == 0:
        raise ValueError("no edges")
    out = np.empty(m)
    cdef double[::1] o = out
    for i in range(m):
        o[i] = _s_of(pe, pd, pc, i, pn[i], &edge_len[0], e[i], off[i], s_pred[i], k_hint[i])
    return out


cdef void _rows_match(const long[:, :] pe, const long[:, :] pd, const double[:, :] pc, const long[:] pn,
                      Py_ssize_t m) except *:
    """The padded path arrays have m rows of one width (pc one wider), and every count fits."""
    cdef Py_ssize_t i, w = pe.shape[1]
    if pe.shape[0] != m or pd.shape[0] != m or pc.shape[0] != m or pn.shape[0] != m or pd.shape[1] != w \
            or pc.shape[1] != w + 1 or w < 1:
        raise ValueError("the path arrays do not match")
    for i in range(m):
        if pn[i] < 0 or pn[i] > w:
            raise IndexError(f"a path of {pn[i]} edges in rows of {w}")


cdef bint _project1(geo_t* g, double xi, double yi, long e, double* off, double* px, double* py,
                    double* dist) except -1:
    """`Placer.project_on(xi, yi, e)` (see `project`); False where no distance is finite."""
    cdef Py_ssize_t k, k0 = g.goff[e], k1 = g.goff[e] + g.nseg[e]
    cdef double ax, ay, dx, dy, l2, u, qx, qy, dd, best = INFINITY, bu = 0.0, bc0 = 0.0, bsl = 0.0
    cdef double bpx = 0.0, bpy = 0.0
    cdef bint found = False
    for k in range(k0, k1):
        ax, ay, dx, dy, l2 = g.gx[k], g.gy[k], g.sdx[k], g.sdy[k], g.sl2[k]
        if l2 <= 0.0:
            u = 0.0
        else:
            u = ((xi - ax) * dx + (yi - ay) * dy) / l2
            u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
        qx = ax + u * dx
        qy = ay + u * dy
        dd = _hyp(xi - qx, yi - qy)
        if dd < best:
            best, found, bu, bc0, bsl, bpx, bpy = dd, True, u, g.gcum[k], g.slen[k], qx, qy
    if found:
        off[0], px[0], py[0], dist[0] = bc0 + bu * bsl, bpx, bpy, best
    else:
        off[0], px[0], py[0], dist[0] = 0.0, 0.0, 0.0, INFINITY
    return found


def best_on_rows(geo, const long[:, :] pe, const long[:, :] pd, const double[:, :] pc, const long[:] pn,
                 const double[:] x, const double[:] y, const double[:] s_pred, const long[:] lo, const long[:] hi,
                 double wt):
    """`fleet_near.best_on_rows` (its docstring; `wt` the along-path weight 1 / ALONG_SCALE**2): per row whether
    it was decided here, and (edge, offset, px, py, distance) of the window's best edge. A row not decided here
    (an edge without segments, or no finite cost) gives the first candidate's values (never used)."""
    cdef Py_ssize_t m = pe.shape[0], w = pe.shape[1], i, c, j
    _rows_match(pe, pd, pc, pn, m)
    if x.shape[0] != m or y.shape[0] != m or s_pred.shape[0] != m or lo.shape[0] != m or hi.shape[0] != m:
        raise ValueError("the rows' arrays differ in length")
    cdef geo_t g
    _geo_of(geo, &g)
    for i in range(m):
        if lo[i] < 0 or hi[i] >= w or lo[i] > hi[i] or hi[i] >= max(pn[i], 1):
            raise IndexError(f"path window {lo[i]}..{hi[i]} outside the row's {pn[i]} edges")
        for c in range(lo[i], hi[i] + 1):
            if pe[i, c] < 0 or pe[i, c] >= g.n_edges:
                raise IndexError(f"edge {pe[i, c]} out of range")
            if g.goff[pe[i, c]] + g.nseg[pe[i, c]] > g.n_vert - 1:
                raise IndexError(f"edge {pe[i, c]}'s segments run past the vertices")
    ok_a, e_a = np.empty(m, dtype=bool), np.empty(m, dtype=np.int64)
    off_a, px_a, py_a, d_a = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    cdef unsigned char[::1] oko = ok_a.view(np.uint8)
    cdef long[::1] eo = e_a
    cdef double[::1] offo = off_a, pxo = px_a, pyo = py_a, do = d_a
    cdef double coff, cpx, cpy, cd, ds, cost, bc, boff, bpx, bpy, bd
    cdef long ce, be
    cdef bint ok, seen, first, nan_best
    for i in range(m):
        ok = True
        first = True
        nan_best = False
        bc = INFINITY
        be, boff, bpx, bpy, bd = pe[i, lo[i]], 0.0, 0.0, 0.0, 0.0
        for c in range(lo[i], hi[i] + 1):
            ce = pe[i, c]
            seen = False
            for j in range(lo[i], c):
                if pe[i, j] == ce:
                    seen = True
                    break
            if seen:
                continue
            if g.nseg[ce] > 0:
                _project1(&g, x[i], y[i], ce, &coff, &cpx, &cpy, &cd)
                ds = _s_of(pe, pd, pc, i, pn[i], g.edge_len, ce, coff, s_pred[i], c) - s_pred[i]
                cost = cd * cd + wt * ds * ds
            else:
                ok = False  # (`project_on` gives an edge without segments an infinite distance: left scalar)
                coff = cpx = cpy = cd = INFINITY
                cost = INFINITY
            if nan_best:
                continue
            if first or cost != cost or cost < bc:
                be, boff, bpx, bpy, bd, bc = ce, coff, cpx, cpy, cd, cost
                nan_best = cost != cost
            first = False
        oko[i] = ok and bc < INFINITY
        eo[i], offo[i], pxo[i], pyo[i], do[i] = be, boff, bpx, bpy, bd
    return ok_a, e_a, off_a, px_a, py_a, d_a


cdef class GhostCols:
    """A new ghost read into slot s's derived columns (`fleet.ghost_row_py`'s writes, the reference) over columns
    taken once: the fleet core keeps one per size of its derived columns (made again when they grow) and writes
    each new ghost through it. Why: taking the five arrays' buffers was most of a one-call write that took them
    each time (about 3 of 3.5 us, measured warm), once per publish."""
    cdef double[:, ::1] gm, gc
    cdef long[:, ::1] ge, gd
    cdef long[::1] gn

    def __init__(self, double[:, ::1] gm, long[:, ::1] ge, long[:, ::1] gd, double[:, ::1] gc, long[::1] gn):
        if gn.shape[0] != gm.shape[0] or ge.shape[0] != gm.shape[0] or gd.shape[0] != gm.shape[0] \
                or gc.shape[0] != gm.shape[0] or gd.shape[1] != ge.shape[1] or gc.shape[1] != ge.shape[1] + 1:
            raise ValueError("the ghost columns differ in their rows or widths")
        self.gm, self.ge, self.gd, self.gc, self.gn = gm, ge, gd, gc, gn

    def write(self, Py_ssize_t s, tuple nums, path):
        """Slot s's ghost: `ghost_row_py`'s writes (an IndexError for a slot outside the columns, a ValueError for
        numbers or a path that do not fit a row, nothing written then)."""
        cdef list edges = path.edges, cum = path.cum
        cdef Py_ssize_t n = len(edges), w = self.ge.shape[1], j
        if not 0 <= s < self.gm.shape[0]:
            raise IndexError(f"slot {s} outside the derived columns")
        if len(nums) != self.gm.shape[1] or not 1 <= n <= w or len(cum) != n + 1:
            raise ValueError(f"a ghost of {len(nums)} numbers and {n} edges does not fit rows of {w}")
        for j in range(self.gm.shape[1]):
            self.gm[s, j] = nums[j]
        for j in range(n):
            e, d = edges[j]
            self.ge[s, j] = e
            self.gd[s, j] = d
        for j in range(n + 1):
            self.gc[s, j] = cum[j]
        for j in range(n + 1, w + 1):
            self.gc[s, j] = INFINITY
        self.gn[s] = n


def project(geo, const double[:] x, const double[:] y, const long[:] e):
    """`Geometry.project(x, y, e)`: per i the projection of (x[i], y[i]) onto edge e[i] as `Placer.project_on`
    does it (each segment in order, `u` clamped to [0, 1], the first least distance winning; no finite distance:
    offset 0, foot (0, 0), distance inf): (offset, px, py, distance)."""
    cdef geo_t g
    _geo_of(geo, &g)
    cdef Py_ssize_t n = e.shape[0], i
    if x.shape[0] != n or y.shape[0] != n:
        raise ValueError("x, y and e differ in length")
    _check(e, g.n_edges, "edge")
    for i in range(n):
        if g.goff[e[i]] + g.nseg[e[i]] > g.n_vert - 1:
            raise IndexError(f"edge {e[i]}'s segments run past the vertices")
    off_a, px_a, py_a, d_a = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    cdef double[::1] off = off_a, px = px_a, py = py_a, dist = d_a
    for i in range(n):
        _project1(&g, x[i], y[i], e[i], &off[i], &px[i], &py[i], &dist[i])
    return off_a, px_a, py_a, d_a
