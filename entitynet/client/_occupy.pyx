# cython: language_level=3, boundscheck=True, wraparound=True
# distutils: extra_compile_args = -ffp-contract=off
"""`occupy` compiled as a whole (entitynet/client/occupation.py; the pure function there is the reference, used
where pip did not build this module or ENTITYNET_PURE_PYTHON is set): the choice search, the certain stretch
and its memo, the cells along the path (`Path.cell`, `cover_cells`, `cells_between`, `starts_in`,
`first_boundary_after` written out over the path's and the map's lists), the branch tree (its memo lookup as
the pure `branch_cover` does, and on a miss the search `_span`, compiled too) and the periods. Why as a whole:
issue 22 measured one more small kernel per function as not reaching the publish's target; the Python calls
between those functions were the cost.

Exactness: the arithmetic is additions, subtractions and comparisons, in the reference's order; `min` and
`max` are written as Python's builtins choose (the first argument unless the second is strictly smaller /
larger), so NaN and -0.0 come out as they do there; the travel times are the reference's own callables. Lists
are read with bounds checks and negative indices as Python reads them. tests/entitynet/client/
test_occupy_compiled.py holds it equal to the pure function on the map, synthetic paths and hostile input."""

from cpython.mem cimport PyMem_Free, PyMem_Malloc, PyMem_Realloc
from libc.math cimport INFINITY, isfinite
from libc.string cimport memset

from entitynet.client._bisect cimport bisect_right, bisect_right_c

from entitynet.client import occupation as _occ
from entitynet.client.kinematics import time_to_travel as _time_to_travel


cdef inline double _min(double a, double b):
    """Python's `min(a, b)` on floats: b only when strictly smaller."""
    return b if b < a else a


cdef inline double _max(double a, double b):
    """Python's `max(a, b)` on floats: b only when strictly larger."""
    return b if b > a else a


cdef class _Map:
    """The map's lists the occupation reads, as C arrays, built once per view (`_map`): edge lengths, the
    per-edge cell breakpoints (`NetView.cell_at`'s), and every directed edge's cell pieces (`NetView.pieces`:
    start distance and cell; directed edge (e, d) is row 2e for d > 0, 2e + 1 otherwise), and per network mask
    whether leaving a directed edge is a choice (`NetView.is_choice`, asked once per edge and mask)."""
    cdef object net
    cdef Py_ssize_t n_edges
    cdef double[::1] edge_len, bp_start, piece_a
    cdef Py_ssize_t[::1] bp_off, bp_cell, piece_off, piece_c
    cdef dict choice  # networks -> bytearray per directed edge (0: not asked yet, 1: no, 2: yes)
    cdef dict onward  # networks -> {key: `_onward`'s row}

    def __init__(self, net):
        import numpy as np
        self.net = net
        cdef Py_ssize_t n = net.n_edges, e
        self.n_edges = n
        self.edge_len = np.asarray(net.edge_len, dtype=np.float64)
        self.bp_off = np.asarray(net.bp_off, dtype=np.intp)
        self.bp_start = np.asarray(net.bp_start, dtype=np.float64)
        self.bp_cell = np.asarray(net.bp_cell, dtype=np.intp)
        off = [0]
        a_s, c_s = [], []
        for e in range(n):
            for d in (1, -1):
                for a0, _b0, c in net.pieces(e, d):
                    a_s.append(a0)
                    c_s.append(c)
                off.append(len(a_s))
        self.piece_off = np.asarray(off, dtype=np.intp)
        self.piece_a = np.asarray(a_s, dtype=np.float64)
        self.piece_c = np.asarray(c_s, dtype=np.intp)
        self.choice = {}
        self.onward = {}

    cdef bytearray choices_of(self, networks):
        """The per-directed-edge choice flags of one network mask."""
        flags = self.choice.get(networks)
        if flags is None:
            flags = self.choice[networks] = bytearray(2 * self.n_edges)
        return flags


cdef _Map _map(net):
    """The view's `_Map`, built on first use (a view's lists do not change)."""
    m = net.__dict__.get("_occupy_map")
    if m is None:
        m = net.__dict__["_occupy_map"] = _Map(net)
    return m


cdef class _P:
    """One path over the map's `_Map`: its lists read where the walks go (a path may be much longer than the
    stretch an occupation looks at, so nothing is copied up front)."""
    cdef _Map m
    cdef list edges, cum_list
    cdef Py_ssize_t n
    cdef double length

    def __cinit__(self, path, _Map m):
        self.m = m
        self.edges = path.edges
        self.cum_list = path.cum
        self.n = len(self.edges)
        if self.n < 1 or len(self.cum_list) != self.n + 1:
            raise ValueError("a path needs edges and one cumulative length more")
        self.length = self.cum_list[self.n]

    cdef inline double c(self, Py_ssize_t k) except? -1.0:
        """cum[k]."""
        return self.cum_list[k]

    cdef inline Py_ssize_t rowk(self, Py_ssize_t k) except -1:
        """The row of path edge k in the map's tables: 2e forward, 2e + 1 backward."""
        e_, d_ = self.edges[k]
        cdef Py_ssize_t e = e_
        if not 0 <= e < self.m.n_edges:
            raise IndexError(f"edge {e} is not in the map")
        return 2 * e if d_ > 0 else 2 * e + 1

    cdef inline Py_ssize_t index(self, double s) except -1:
        """`Path.index`."""
        cdef Py_ssize_t k = bisect_right(self.cum_list, s, 0, self.n + 1) - 1
        if k < 0:
            return 0
        return k if k < self.n else self.n - 1

    cdef Py_ssize_t cell(self, double s) except -1:
        """`Path.cell`."""
        cdef Py_ssize_t k = self.index(s)
        cdef Py_ssize_t r = self.rowk(k), e = r >> 1
        cdef double length = self.m.edge_len[e]
        cdef double d = s - self.c(k)
        d = 0.0 if d < 0.0 else (length if d > length else d)
        cdef double off = d if (r & 1) == 0 else length - d
        cdef Py_ssize_t lo = self.m.bp_off[e], hi = self.m.bp_off[e + 1]
        cdef Py_ssize_t j = bisect_right_c(&self.m.bp_start[0], off, lo, hi) - 1
        return self.m.bp_cell[j if j > lo else lo]

    cdef list cells_between(self, double s0, double s1):
        """`Path.cells_between`: the cells met along [s0, s1] (clamped to the path), without repeats."""
        s0 = _min(_max(s0, 0.0), self.length)
        s1 = _min(_max(s1, s0), self.length)
        cdef list out = [self.cell(s0)]
        self.starts_into(out, s0, s1)
        return out

    cdef void starts_into(self, list out, double s0, double s1) except *:
        """The cells of `Path.starts_in(s0, s1)` (pieces starting in (s0, s1], in order of travel) appended to
        `out` where not in it yet."""
        self.walk(out, s0, s1, s1, s1)

    cdef list cover_cells(self, double start, double reach, double cover_end):
        """`Path.cover_cells`."""
        cdef list cells = [self.cell(start)]
        self.walk(cells, start, cover_end if cover_end > reach else reach, reach, cover_end)
        return cells

    cdef void walk(self, list out, double s0, double s1, double reach, double cover_end) except *:
        """The pieces starting in (s0, s1] with sa <= reach or sa < cover_end, in order of travel: their cells
        appended to `out` where not in it yet (`starts_in` is reach = cover_end = s1, where the second test
        always holds; `cover_cells` the loop of its own)."""
        cdef Py_ssize_t k = self.index(s0), i, i1, r
        cdef double base, sa
        cdef _Map m = self.m
        while k < self.n and self.c(k) <= s1:
            base = self.c(k)
            r = self.rowk(k)
            i1 = m.piece_off[r + 1]
            for i in range(m.piece_off[r], i1):
                sa = base + m.piece_a[i]
                if sa > s1:
                    break
                if sa > s0 and (sa <= reach or sa < cover_end):
                    c = m.piece_c[i]
                    if c not in out:
                        out.append(c)
            k += 1

    cdef int first_boundary_after(self, double s, double limit, double *out) except -1:
        """`Path.first_boundary_after`: the first cell change in (s, min(limit, length)] into `out`; False
        when there is none (the reference's None)."""
        cdef Py_ssize_t prev = self.cell(s), k = self.index(s), i, i1, r
        cdef double base, sa
        cdef _Map m = self.m
        limit = _min(limit, self.length)
        while k < self.n and self.c(k) <= limit:
            base = self.c(k)
            r = self.rowk(k)
            i1 = m.piece_off[r + 1]
            for i in range(m.piece_off[r], i1):
                sa = base + m.piece_a[i]
                if sa > limit:
                    return 0
                if sa > s and m.piece_c[i] != prev:
                    out[0] = sa
                    return 1
            k += 1
        return 0

    cdef Py_ssize_t first_choice(self, double s_front, object networks, double known_until) except -2:
        """`_first_choice`."""
        cdef bytearray flags = self.m.choices_of(networks)
        cdef unsigned char *f = flags
        is_choice = self.m.net.is_choice
        cdef Py_ssize_t k = self.index(_max(s_front, known_until)), r
        cdef double s_node
        while k < self.n:
            s_node = self.c(k + 1)
            if s_node >= known_until and s_node >= s_front:
                r = self.rowk(k)
                if f[r] == 0:
                    f[r] = 2 if is_choice(self.edges[k], networks) else 1
                if f[r] == 2:
                    return k
            k += 1
        return -1

    cdef double certain_end_at(self, Py_ssize_t k, object networks) except? -1.0:
        """`_certain_end_at`, with its memo of the allowance per (edge, networks, cell)."""
        if k < 0:
            return self.length
        de = self.edges[k]
        cdef double s_node = self.c(k + 1)
        node_cell = self.cell(s_node - 1e-9) if s_node > 0 else self.cell(0.0)
        net = self.m.net
        cache = net.__dict__.get("_allowance")
        if cache is None:
            cache = net.__dict__.setdefault("_allowance", {})
        key = (de, networks, node_cell)
        allowance = cache.get(key)
        if allowance is None:
            if len(cache) > 65536:
                cache.clear()
            allowance = cache[key] = _occ._allowance(net, de, networks, node_cell)
        return _min(s_node + <double>allowance, self.length)


cdef struct _Heap:
    double *d
    Py_ssize_t *k
    Py_ssize_t n, cap


cdef inline bint _less(_Heap *h, Py_ssize_t i, Py_ssize_t j) noexcept:
    """(d, key) order: the order of heapq's (distance, (edge, dir)) tuples (key = 2 edge + (dir > 0))."""
    return h.d[i] < h.d[j] or (h.d[i] == h.d[j] and h.k[i] < h.k[j])


cdef inline void _swap(_Heap *h, Py_ssize_t i, Py_ssize_t j) noexcept:
    cdef double td = h.d[i]
    cdef Py_ssize_t tk = h.k[i]
    h.d[i], h.k[i] = h.d[j], h.k[j]
    h.d[j], h.k[j] = td, tk


cdef int _push(_Heap *h, double d, Py_ssize_t key) except -1:
    """Push (d, key), growing the arrays."""
    cdef Py_ssize_t i, parent
    if h.n == h.cap:
        h.cap = 2 * h.cap + 16
        h.d = <double *>PyMem_Realloc(h.d, h.cap * sizeof(double))
        h.k = <Py_ssize_t *>PyMem_Realloc(h.k, h.cap * sizeof(Py_ssize_t))
        if h.d == NULL or h.k == NULL:
            raise MemoryError()
    i = h.n
    h.d[i], h.k[i] = d, key
    h.n += 1
    while i > 0:
        parent = (i - 1) >> 1
        if not _less(h, i, parent):
            break
        _swap(h, i, parent)
        i = parent
    return 0


cdef void _pop(_Heap *h, double *d, Py_ssize_t *key) noexcept:
    """Pop the least (d, key) (the heap is not empty)."""
    cdef Py_ssize_t i = 0, l, r, m
    d[0], key[0] = h.d[0], h.k[0]
    h.n -= 1
    h.d[0], h.k[0] = h.d[h.n], h.k[h.n]
    while True:
        l = 2 * i + 1
        if l >= h.n:
            break
        r = l + 1
        m = r if r < h.n and _less(h, r, l) else l
        if not _less(h, m, i):
            break
        _swap(h, i, m)
        i = m


cdef tuple _onward(_Map m, object net, Py_ssize_t key, object networks):
    """(length, area cell at the end node or -1, the keys of the ways on) of the directed edge `key`: what the
    pure search reads of it (`_info_row`), kept per view and network mask."""
    rows = m.onward.get(networks)
    if rows is None:
        rows = m.onward[networks] = {}
    hit = rows.get(key)
    if hit is None:
        cand = (key >> 1, 1 if key & 1 else -1)
        _pieces, length, end_cell, ways = _occ._info_row(net, cand, networks)
        hit = rows[key] = (length, end_cell, tuple([2 * <Py_ssize_t>w[0] + (1 if w[1] > 0 else 0) for w in ways]))
    return hit


def span(net, de, double depth, networks, Py_ssize_t max_cells, Py_ssize_t max_edges):
    """`occupation._span` (see there): the branch tree's search, nearest first. The queue is a binary heap of
    (distance, key) in C ordered as the pure search's heap of (distance, (edge, dir)) tuples (the order is total
    for finite distances: any heap pops the same sequence), the seen set a byte per directed edge, the cell
    pieces from the view's C tables and the ways on from `_info_row`."""
    cdef _Map m = _map(net)
    cdef list cells = []
    cdef set listed = set()
    cdef double lo = -INFINITY, hi = INFINITY, shortest = INFINITY, d0, d1, x
    cdef Py_ssize_t edges = 0, e, r, i, i1, key, nk = 2 * m.n_edges
    cdef bint leaf
    cdef _Heap h
    cdef unsigned char *seen
    node = net.end_node(de)
    if net.node_area[node] >= 0:
        cells.append(net.area_cell[net.node_area[node]])
        listed.add(cells[0])
    e = de[0]
    if not 0 <= e < m.n_edges:
        raise IndexError(f"edge {e} is not in the map")
    h.d = NULL
    h.k = NULL
    h.n = h.cap = 0
    seen = <unsigned char *>PyMem_Malloc(nk + 1)
    if seen == NULL:
        raise MemoryError()
    try:
        memset(seen, 0, nk + 1)
        seen[2 * e + (1 if de[1] > 0 else 0)] = 1
        for cand in net.choices(de, networks):
            _push(&h, 0.0, 2 * <Py_ssize_t>cand[0] + (1 if cand[1] > 0 else 0))
        while h.n:
            _pop(&h, &d0, &key)
            if not 0 <= key < nk:  # a way from a malformed map: an error, not a read past `seen`
                raise IndexError(f"directed edge {key >> 1} is not in the map")
            if seen[key]:
                continue
            seen[key] = 1
            edges += 1
            if edges > max_edges or len(cells) >= max_cells:
                if d0 < shortest:
                    shortest = d0
                continue
            e = key >> 1
            r = 2 * e if key & 1 else 2 * e + 1  # (the pieces' row: forward 2e, backward 2e + 1)
            leaf = False
            i1 = m.piece_off[r + 1]
            for i in range(m.piece_off[r], i1):
                x = d0 + m.piece_a[i]
                if x > depth:
                    if x < hi:
                        hi = x
                    if x < shortest:
                        shortest = x
                    leaf = True
                    break
                if x > lo:
                    lo = x
                c = m.piece_c[i]
                if c not in listed:
                    listed.add(c)
                    cells.append(c)
            if leaf:
                continue
            length, end_cell, ways = _onward(m, net, key, networks)
            d1 = d0 + <double>length
            if end_cell >= 0:
                if end_cell not in listed:
                    listed.add(end_cell)
                    cells.append(end_cell)
                if d1 < shortest:
                    shortest = d1
                continue
            for w in ways:
                _push(&h, d1, w)
    finally:
        PyMem_Free(seen)
        PyMem_Free(h.d)
        PyMem_Free(h.k)
    return cells, (0.0 if shortest == INFINITY and not cells else shortest), lo, hi


cdef tuple _branch_cover(object net, object de, double depth, object networks):
    """`branch_cover(path, k, depth, networks)` with its default budgets (48 cells, 64 edges): the memo's
    bisection, or the search (`span`) on a miss, stored as the pure function stores it."""
    if depth != depth:  # (NaN: computed, never cached, as the pure function does)
        cells, shortest, _lo, _hi = span(net, de, depth, networks, 48, 64)
        return cells, shortest
    cdef dict cache = net.__dict__.setdefault("_branch_cover", {})
    key = (de, networks, 48, 64)
    spans = cache.get(key)
    if spans is None:
        if len(cache) > _occ.BRANCH_MEMO_KEYS:
            cache.clear()
        spans = cache[key] = ([], [])
    cdef list los = spans[0], rest = spans[1]
    cdef Py_ssize_t i = bisect_right(los, depth, 0, len(los)) - 1, j
    if i >= 0 and depth < <double>rest[i][0]:
        hit = rest[i]
        return list(hit[1]), hit[2]
    cells, shortest, lo, hi = span(net, de, depth, networks, 48, 64)
    if len(los) < 256:
        j = bisect_right(los, lo, 0, len(los))
        los.insert(j, lo)
        rest.insert(j, (hi, tuple(cells), shortest))
    return cells, shortest


def occupy(path, double s_front, double length, double v, double a, double vmax, networks, *,
           double known_until=0.0, double margin=0.0, double lookahead=0.0, tight=None,
           double max_validity=60.0, double min_validity=0.5, bint dead_end_at_path_end=False, travel=None,
           double branch_depth=40.0):
    """`occupation.occupy` (see there), compiled."""
    cdef tuple o = occupy_parts(path, s_front, length, v, a, vmax, networks, known_until, margin, lookahead, tight,
                                max_validity, min_validity, dead_end_at_path_end, travel, branch_depth)
    return _occ.make_occupation(tuple(<list>o[0]), o[1], o[2], o[3], o[4], o[5])


cdef tuple occupy_parts(path, double s_front, double length, double v, double a, double vmax, networks,
                        double known_until, double margin, double lookahead, tight, double max_validity,
                        double min_validity, bint dead_end_at_path_end, travel, double branch_depth):
    """`occupy`'s fields as (cells list, validity, front, aft, cover_start, cover_end), for a caller at C level
    (`_cover.pyx` builds its occupation once, after adding its own cells to the list)."""
    if not (isfinite(s_front) and isfinite(v) and isfinite(a)):
        raise ValueError("occupation needs finite position, speed and acceleration")
    cdef bint is_tight = (lookahead <= 0.0) if tight is None else bool(tight)
    v = _max(v, 0.0)
    cdef _P p = _P(path, _map(path.net))
    cdef double s_aft = s_front - _max(length, 0.0)
    cdef double start = _min(_max(s_aft - margin, 0.0), p.length)
    cdef double reach = _min(_max(s_front + margin, start), p.length)
    cdef Py_ssize_t k_choice = p.first_choice(s_front, networks, known_until)
    cdef double end_known = _max(p.certain_end_at(k_choice, networks), reach)
    cdef double want = reach + _max(lookahead, 0.0)
    cdef double s_node, depth, cover_end, target, front, aft, nxt, behind
    cdef list cells
    if not is_tight and k_choice >= 0 and want > end_known:
        # the way on is not known: cover every branch at the next choice node (a tree, not a line)
        s_node = p.c(k_choice + 1)
        cells = p.cells_between(start, _min(reach, s_node))
        p.starts_into(cells, _min(reach, s_node), s_node)
        depth = _min(want - s_node, _max(reach - s_node, 0.0) + branch_depth)
        extra, shortest = _branch_cover(p.m.net, p.edges[k_choice], depth, networks)
        for c in extra:
            if c not in cells:
                cells.append(c)
        cover_end = s_node + <double>shortest
    else:
        target = reach if is_tight else _min(want, end_known)
        cover_end = nxt if p.first_boundary_after(target, end_known, &nxt) else end_known
        cells = p.cover_cells(start, reach, cover_end)
    if cover_end >= p.length and dead_end_at_path_end:
        front = INFINITY
    elif travel is None:
        front = _time_to_travel(cover_end - reach, v, a, vmax)
    else:
        front = travel(cover_end - reach)
    aft = INFINITY
    if is_tight and p.first_boundary_after(start, end_known, &behind):
        aft = _time_to_travel(behind - start, v, a, vmax) if travel is None else travel(behind - start)
    validity = _max(_min(_min(front, aft), max_validity), min_validity)
    return cells, validity, front, aft, start, cover_end
