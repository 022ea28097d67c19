"""The fleet core's neighbourhood search: `Placer.near` for many fixes at once, over the placers' own tables.

Why: with 5 m GPS noise more than half the fixes land farther than the switch margin (3 m) from the edge the
entity is on, and `NetworkTracker.track` then asks `Placer.near` which edge of the neighbourhood explains the fix
(its path's edges with a head start). Those fixes are as common as the written-out ones, so the fleet core runs
the same search in arrays: every segment of the current edge's two-hop table (the placer's own `_SegTable`,
rows in its order), the cost `d + margin` off the path window, the first minimum winning, the same IEEE
operations as `Placer._near_np` (which `_near_py` equals bit for bit). A table that holds an area of the placer's
networks is taken too: `near` tests the fix inside each such area first, and so does `near_fixes`.

The rest of `track`'s general branch is here too, over arrays: the tables that hold areas (each area's
point-in-polygon test is `Placer.inside_area` itself, called per fix: a fix inside one keeps the entity on its
path's ways through `_best_on` until `track` would enter the area, which the scalar code does), the
`_best_on` retry when the nearest preferred edge puts the fix far along the path, the hysteresis that keeps an
entity on its path's edges while another edge wins fewer than `switch_count` fixes in a row (`pending`), and
`_s_of` in full (the occurrence of an edge nearest the prediction). `near_fixes` returns, per fix, either the
fix `track` would continue with or the reason the scalar code must decide it.
"""

from __future__ import annotations

import math

import numpy as np

from entitynet.client.fleet_kernels import compiled
from entitynet.client.placement import segment_rows
from entitynet.client.tracker import ALONG_SCALE

_COLS = ("ax", "ay", "dx", "dy", "inv_l2", "cum0", "slen")


class NearTables:
    """The segment rows of every table asked for so far, concatenated, and where each table lies: per class of
    networks (a placer's `networks`, numbered in the order met) and edge, its first row (`start`, -1: not built
    yet), its row count and whether the placer's areas lie at its nodes (`areas`: their tuples, in `near`'s
    order). The rows are those of `Placer.table` (the same lists and arithmetic: `Placer.neighbourhood`,
    `segment_rows`), built for all of a tick's new tables at once (tests/entitynet/client/test_fleet_near.py
    holds them equal to the placer's tables)."""

    def __init__(self) -> None:
        self.classes: dict[int, int] = {}  # networks -> class
        self.start = np.zeros((0, 0), dtype=np.int64)
        self.count = np.zeros((0, 0), dtype=np.int64)
        self.has_areas = np.zeros((0, 0), dtype=bool)
        self.areas: dict[tuple[int, int], tuple[int, ...]] = {}
        self.size = 0
        self.cols = {c: np.zeros(1024) for c in _COLS}
        self.edge = np.zeros(1024, dtype=np.int64)

    def class_of(self, networks: int, n_edges: int) -> int:
        """The class number of a placer's networks (a new row of the lookup arrays the first time)."""
        c = self.classes.get(networks)
        if c is None:
            c = self.classes[networks] = len(self.classes)
            grow = ((self.start, -1, np.int64), (self.count, 0, np.int64), (self.has_areas, False, bool))
            self.start, self.count, self.has_areas = (
                np.concatenate([old.reshape(-1, n_edges), np.full((1, n_edges), fill, dtype=dtype)])
                for old, fill, dtype in grow)
        return c

    def build(self, wanted: dict[tuple[int, int], object]) -> None:
        """The tables (class, edge) -> placer not built yet, all in one pass: each table's edges and areas
        from `Placer.neighbourhood` (what `Placer.table` holds), the rows by `segment_rows` (its arithmetic)."""
        wanted = {key: placer for key, placer in wanted.items() if self.start[key] < 0}
        if not wanted:
            return
        tables, flat = [], []
        for (cls, e), placer in wanted.items():
            edges, at_nodes = placer.neighbourhood(e)
            tables.append((cls, e, len(edges), tuple(a for a in at_nodes
                                                     if placer.topo.area_networks[a] & placer.networks)))
            flat += edges
        per, rows = segment_rows(next(iter(wanted.values())).geom, np.array(flat, dtype=np.int64))
        n_edges = np.array([t[2] for t in tables], dtype=np.int64)
        counts = np.add.reduceat(per, np.cumsum(n_edges) - n_edges)  # (a table holds at least its own edge)
        total = int(counts.sum())
        if self.size + total > len(self.edge):
            cap = max(2 * len(self.edge), self.size + total)
            for c in _COLS:
                grown = np.zeros(cap)
                grown[: self.size] = self.cols[c][: self.size]
                self.cols[c] = grown
            grown_e = np.zeros(cap, dtype=np.int64)
            grown_e[: self.size] = self.edge[: self.size]
            self.edge = grown_e
        for c in _COLS:
            self.cols[c][self.size : self.size + total] = rows[c]
        self.edge[self.size : self.size + total] = rows["edge"]
        starts = self.size + np.cumsum(counts) - counts
        for (cls, e, _n, areas), start, count in zip(tables, starts.tolist(), counts.tolist(), strict=True):
            self.start[cls, e], self.count[cls, e], self.has_areas[cls, e] = start, count, bool(areas)
            if areas:
                self.areas[(cls, e)] = areas
        self.size += total

    def near(self, x: np.ndarray, y: np.ndarray, start: np.ndarray, count: np.ndarray, margin: np.ndarray,
             pe: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
        """`Placer.near(x[i], y[i], ., preferred_i, margin[i])` for tables (start[i], count[i]) without areas,
        preferred_i being the edges pe[i, lo[i]..hi[i]]: (edge, offset, px, py, distance, preferred?, whether
        any segment of the table is preferred: `near`'s best preferred distance is finite). The first least
        cost wins, a NaN cost before any (numpy's argmin in `Placer._near_np`). The compiled kernel
        (`_fleet.near`) where in use, else `near_np`."""
        k = compiled()
        if k is not None:
            return k.near(self, x, y, start, count, margin, pe, lo, hi)
        return self.near_np(x, y, start, count, margin, pe, lo, hi)

    def near_np(self, x: np.ndarray, y: np.ndarray, start: np.ndarray, count: np.ndarray, margin: np.ndarray,
                pe: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
        """`near` in numpy (the reference)."""
        n = len(x)
        gstart = np.cumsum(count) - count
        rep = np.repeat(np.arange(n), count)
        k = np.arange(int(count.sum())) - gstart[rep] + start[rep]
        cols = self.cols
        ax, ay, dx, dy = cols["ax"][k], cols["ay"][k], cols["dx"][k], cols["dy"][k]
        rx = x[rep] - ax
        ry = y[rep] - ay
        u = np.clip((rx * dx + ry * dy) * cols["inv_l2"][k], 0.0, 1.0)
        ex = rx - u * dx
        ey = ry - u * dy
        d = np.sqrt(ex * ex + ey * ey)
        edge = self.edge[k]
        # preferred: (fix, edge) among the (fix, window edge) pairs, as one sorted search of int64 keys
        span = hi - lo + 1
        wrep = np.repeat(np.arange(n), span)
        wcol = np.arange(int(span.sum())) - np.repeat(np.cumsum(span) - span, span) + lo[wrep]
        big = int(max(int(pe.max()), int(edge.max()))) + 1
        keys = np.sort(wrep * big + pe[wrep, wcol])
        want = rep * big + edge
        at = np.minimum(np.searchsorted(keys, want), len(keys) - 1)
        pref = keys[at] == want
        cost = d + np.where(pref, 0.0, margin[rep])
        cmin = np.minimum.reduceat(cost, gstart)
        hit = np.flatnonzero((cost == cmin[rep]) | np.isnan(cost))  # (a row's NaN makes its cmin NaN)
        b = hit[np.searchsorted(rep[hit], np.arange(n))]
        kb = k[b]
        any_pref = np.logical_or.reduceat(pref, gstart)
        return (edge[b], cols["cum0"][kb] + u[b] * cols["slen"][kb], ax[b] + u[b] * dx[b], ay[b] + u[b] * dy[b],
                d[b], pref[b], any_pref)


def s_of_rows(pe: np.ndarray, pd: np.ndarray, pc: np.ndarray, pn: np.ndarray, edge_len: np.ndarray, e: np.ndarray,
              off: np.ndarray, s_pred: np.ndarray, k_hint: np.ndarray) -> np.ndarray:
    """`NetworkTracker._s_of(fix, s_pred, k_hint)` for rows of padded paths (edges `pe`, directions `pd`,
    cumulative lengths `pc`, `pn` edges): the fix's edge at the hint (or next to it: k, k + 1, k - 1 in that
    order) with no other occurrence within three edges, else its occurrence nearest `s_pred` (the first of
    equals), else `s_pred`. The same additions as the scalar code (`dist_of`: offset, or length - offset).
    The compiled kernel (`_fleet.s_of_rows`) where in use, else `s_of_rows_np`."""
    k = compiled()
    if k is not None:
        return k.s_of_rows(pe, pd, pc, pn, edge_len, e, off, s_pred, k_hint)
    return s_of_rows_np(pe, pd, pc, pn, edge_len, e, off, s_pred, k_hint)


def s_of_rows_np(pe: np.ndarray, pd: np.ndarray, pc: np.ndarray, pn: np.ndarray, edge_len: np.ndarray,
                 e: np.ndarray, off: np.ndarray, s_pred: np.ndarray, k_hint: np.ndarray) -> np.ndarray:
    """`s_of_rows` in numpy (the reference)."""
    m, w = pe.shape
    rows = np.arange(m)
    elen = edge_len[e]

    def holds(k: np.ndarray) -> np.ndarray:  # column k is one of the path's and holds the fix's edge
        return (k >= 0) & (k < pn) & (pe[rows, np.clip(k, 0, w - 1)] == e)
    kk = k_hint.copy()
    found = np.zeros(m, dtype=bool)
    for k in (k_hint, k_hint + 1, k_hint - 1):
        at = ~found & holds(k)
        kk = np.where(at, k, kk)
        found |= at
    kc = np.clip(kk, 0, w - 1)
    again = np.zeros(m, dtype=bool)  # another occurrence within three columns of kc (only these are looked at)
    for d in (-3, -2, -1, 1, 2, 3):
        again |= holds(kc + d)
    out = pc[rows, kc] + np.where(pd[rows, kc] > 0, off, elen - off)  # (`dist_of` at kc)
    far = np.flatnonzero(~(found & ~again))  # (rows that need the nearest occurrence: the whole path is searched)
    if len(far):
        out[far] = _nearest_occurrence(pe[far], pd[far], pc[far], pn[far], e[far], off[far], elen[far], s_pred[far])
    return out


def _nearest_occurrence(pe: np.ndarray, pd: np.ndarray, pc: np.ndarray, pn: np.ndarray, e: np.ndarray,
                        off: np.ndarray, elen: np.ndarray, s_pred: np.ndarray) -> np.ndarray:
    """`_s_of`'s second case: the path coordinate of the occurrence of edge e nearest `s_pred` (the first of
    equals), or `s_pred` where the path does not hold e."""
    m, w = pe.shape
    rows = np.arange(m)
    occ = (pe == e[:, None]) & (np.arange(w)[None, :] < pn[:, None])
    along = np.where(pd > 0, off[:, None], (elen - off)[:, None])  # `dist_of` per column
    with np.errstate(invalid="ignore"):
        gap = np.where(occ, np.abs(pc[:, :w] + along - s_pred[:, None]), np.inf)
    jb = np.argmin(gap, axis=1)  # (the first minimum: the scalar loop takes a later one only if smaller)
    return np.where(occ.any(axis=1), pc[rows, jb] + along[rows, jb], s_pred)


def best_on_rows(geo, pe: np.ndarray, pd: np.ndarray, pc: np.ndarray, pn: np.ndarray, x: np.ndarray, y: np.ndarray,
                 s_pred: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """`NetworkTracker._best_on(x, y, s_pred, lo, hi)` for rows of padded paths: each distinct edge of the
    window lo..hi (its first occurrence) projected as `Placer.project_on` does (`Geometry.project`), cost
    d * d + w * ds * ds with ds from `_s_of` hinted at that occurrence, the first minimum winning. Returns (per
    row whether it was decided here: every window edge has a segment and some cost is finite, edge, offset, px,
    py, distance; the values of a row not decided here are not used). The compiled kernel
    (`_fleet.best_on_rows`) where in use, else `best_on_rows_np`."""
    k = compiled()
    if k is not None:
        return k.best_on_rows(geo, pe, pd, pc, pn, x, y, s_pred, lo, hi, 1.0 / (ALONG_SCALE * ALONG_SCALE))
    return best_on_rows_np(geo, pe, pd, pc, pn, x, y, s_pred, lo, hi)


def best_on_rows_np(geo, pe: np.ndarray, pd: np.ndarray, pc: np.ndarray, pn: np.ndarray, x: np.ndarray,
                    y: np.ndarray, s_pred: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """`best_on_rows` in numpy (the reference: `Geometry.project_np`, `s_of_rows_np`)."""
    m, w = pe.shape
    span = hi - lo + 1
    rep = np.repeat(np.arange(m), span)
    col = np.arange(int(span.sum())) - np.repeat(np.cumsum(span) - span, span) + lo[rep]
    ce = pe[rep, col]
    cols = np.arange(w)[None, :]
    earlier = ((pe[rep] == ce[:, None]) & (cols >= lo[rep][:, None]) & (cols < col[:, None])).any(axis=1)
    keep = ~earlier  # (`seen`: an edge's first occurrence in the window only)
    rep, col, ce = rep[keep], col[keep], ce[keep]
    segs = geo.nseg[ce] > 0
    ok = np.ones(m, dtype=bool)
    ok[rep[~segs]] = False  # (`project_on` gives an edge without segments an infinite distance: left scalar)
    n = len(ce)
    off, px, py, d = (np.full(n, np.inf) for _ in range(4))
    c = np.flatnonzero(segs)
    if len(c):
        off[c], px[c], py[c], d[c] = geo.project_np(x[rep[c]], y[rep[c]], ce[c])
    with np.errstate(invalid="ignore"):
        ds = s_of_rows_np(pe[rep], pd[rep], pc[rep], pn[rep], geo.edge_len, ce, off, s_pred[rep], col) - s_pred[rep]
        wt = 1.0 / (ALONG_SCALE * ALONG_SCALE)
        cost = d * d + wt * ds * ds
    cost = np.where(segs, cost, np.inf)
    start = np.cumsum(np.bincount(rep, minlength=m)) - np.bincount(rep, minlength=m)
    cmin = np.minimum.reduceat(cost, start) if n else np.zeros(0)
    ok &= cmin < math.inf
    hit = np.flatnonzero(cost == cmin[rep])
    b = hit[np.searchsorted(rep[hit], np.arange(m))] if len(hit) else np.zeros(m, dtype=np.int64)
    b = np.minimum(b, max(n - 1, 0))
    return ok, ce[b], off[b], px[b], py[b], d[b]


def near_fixes(core, sl: np.ndarray, x: np.ndarray, y: np.ndarray, s_pred: np.ndarray, pe: np.ndarray,
               pd: np.ndarray, pc: np.ndarray, pn: np.ndarray, k_cur: np.ndarray, r: float,
               code: dict[str, int]) -> tuple[np.ndarray, ...]:
    """`track`'s general branch for fixes beyond the switch margin (or near an edge's end) of fleet core
    `core`'s slots `sl`, where it ends in the usual update: `Placer.near` over the path window [s_pred - body -
    30, s_pred + 60] (or, where an area of the table holds the fix, `_best_on` until the area is entered), then
    `_best_on` where the nearest preferred edge puts the fix farther along than 2 sigma, or the hysteresis
    where a foreign edge wins (its count below `switch_count`), within `reacquire`, and the consistency query
    of the placement index (asked per fix) placing nothing afresh. Returns (per row 0 where it qualifies, else
    `code` of the first test it fails; edge, offset, px, py, distance, path coordinate of the fix `track` goes
    on with; the hysteresis candidate and its count; whether `_best_on` chose it)."""
    m = len(sl)
    rows = np.arange(m)
    area_in = np.full(m, -1, dtype=np.int64)  # the area `near` finds the fix in (its first, in table order)
    near, players = core._near, core.players
    e_cur = pe[rows, k_cur]
    cls = core.ncls[sl]
    missing = np.flatnonzero(near.start[cls, e_cur] < 0).tolist()
    if missing:  # tables not built yet (once in a run, all of a tick's together)
        near.build({(int(cls[i]), int(e_cur[i])): players[int(sl[i])].tracker.placer for i in missing})
    start, count = near.start[cls, e_cur], near.count[cls, e_cur]
    for i in np.flatnonzero(near.has_areas[cls, e_cur]).tolist():
        placer = players[int(sl[i])].tracker.placer
        for a in near.areas[(int(cls[i]), int(e_cur[i]))]:  # `near` tests the fix inside each area first
            if placer.inside_area(a, float(x[i]), float(y[i])):  # (`inside_area` itself)
                area_in[i] = a
                break
    entering = area_in >= 0  # (`track`: one noisy fix inside an area is not an entry yet: `_best_on`)
    usable = (count > 0) & ~entering
    start = np.where(usable, start, 0)  # (a table not taken: any one row, searched and dropped)
    count = np.where(usable, count, 1)
    lo = (pc <= (s_pred - core.body[sl] - 30.0)[:, None]).sum(axis=1) - 1
    lo = np.where(lo < 0, 0, np.where(lo >= pn, pn - 1, lo))
    hi = (pc <= (s_pred + 60.0)[:, None]).sum(axis=1) - 1
    hi = np.where(hi < 0, 0, np.where(hi >= pn, pn - 1, hi))
    swm, reacq = core.swm[sl], core.reacq[sl]
    fe, off, px, py, d, pref, any_pref = near.near(x, y, start, count, swm, pe, lo, hi)
    why = np.where(usable | entering, 0, code["near_area"])
    sig = math.sqrt(r)
    cols = np.arange(pe.shape[1])[None, :]
    several = ((pe != pe[rows, lo][:, None]) & (cols >= lo[:, None]) & (cols <= hi[:, None])).any(axis=1)
    s_fix = s_of_rows(pe, pd, pc, pn, core.geo.edge_len, fe, off, s_pred, k_cur)
    retry = pref & several & (np.abs(s_fix - s_pred) > 2.0 * sig) & ~entering  # `_best_on`, not the nearest
    # a foreign edge: the reacquire test on it, then the hysteresis (`pending`) or the switch (scalar)
    foreign = ~pref & ~entering
    why = np.where((why == 0) & foreign & (d > reacq), code["near_reacquire"], why)
    pend_n = np.where(core.pend_e[sl] == fe, core.pend_n[sl] + 1, 1)
    switch = foreign & ((pend_n >= core.swc[sl]) | ~any_pref)
    why = np.where((why == 0) & switch, code["near_switch"], why)
    enter_n = np.where(core.pend_e[sl] == -2 - area_in, core.pend_n[sl] + 1, 1)
    pend_e = np.where(foreign, fe, np.where(entering, -2 - area_in, -1))
    pend_n = np.where(foreign, pend_n, np.where(entering, enter_n, 0))
    bo = np.flatnonzero((why == 0) & (retry | foreign | entering))
    if len(bo):
        b_ok, be, boff, bpx, bpy, bd = best_on_rows(core.geo, pe[bo], pd[bo], pc[bo], pn[bo], x[bo], y[bo],
                                                    s_pred[bo], lo[bo], hi[bo])
        why[bo] = np.where(b_ok, 0, code["near_best_on"])
        # the area entered: after `switch_count` fixes in a row, or a fix farther from the path's ways than
        # GPS noise goes (scalar: `_init_at` the area)
        enters = entering[bo] & ((enter_n[bo] >= core.swc[sl[bo]]) | (bd > 3.0 * sig))
        why[bo] = np.where((why[bo] == 0) & enters, code["near_area"], why[bo])
        fe, off, px, py, d = fe.copy(), off.copy(), px.copy(), py.copy(), d.copy()
        fe[bo], off[bo], px[bo], py[bo], d[bo] = be, boff, bpx, bpy, bd
        s_fix = s_fix.copy()
        s_fix[bo] = s_of_rows(pe[bo], pd[bo], pc[bo], pn[bo], core.geo.edge_len, be, boff, s_pred[bo], k_cur[bo])
    why = np.where((why == 0) & ~foreign & (d > reacq), code["near_reacquire"], why)  # (the retried fix's)
    ema = 0.7 * core.dist_ema[sl] + 0.3 * d
    # the consistency test: where it asks the placement index (`_first`, the tracker's own call), the fix goes
    # on in arrays unless the answer is an area or a nearer other edge (then `track` places afresh)
    asks = np.flatnonzero((why == 0) & (ema > 1.5 * sig) & (d > swm))
    if len(asks):
        afresh = placed_afresh(players, sl[asks], x[asks], y[asks], fe[asks], d[asks], swm[asks])
        why[asks[afresh]] = code["near_consistency"]
    retried = np.zeros(m, dtype=bool)
    retried[bo] = True
    return why, fe, off, px, py, d, s_fix, pend_e, pend_n, retried


def by_placement_index(rows_and_trackers) -> list[tuple[object, list[int]]]:
    """The (row, tracker) pairs grouped by what their placement-index queries share (the map's index and the
    placer's network mask): per group one of its placers and its rows, in first-seen order. One batch query per
    group (`placed_afresh`, `FleetCore._prime_places`)."""
    groups: dict[tuple[int, int], tuple[object, list[int]]] = {}
    for i, trk in rows_and_trackers:
        groups.setdefault((id(trk.placer.topo), trk.placer.networks), (trk.placer, []))[1].append(i)
    return list(groups.values())


def placed_afresh(players, sl: np.ndarray, x: np.ndarray, y: np.ndarray, fe: np.ndarray, d: np.ndarray,
                  swm: np.ndarray) -> np.ndarray:
    """Per fix whether `track`'s consistency query (`NetworkTracker._first`) places the entity afresh: an area,
    or another edge nearer by more than the switch margin than the fix's edge `fe` at distance `d`. `_first`'s
    answer over arrays: the placement index's (`Placer.first`, which `_first` asks in every case) for all of a
    tick's fixes of one network class at once (`PlacementIndex.place_many`, the same answers as `place`: one
    STRtree query instead of one per fix); where the tracker has an a-priori route, the nearest point of the
    route (`Placer.on_edges`, per fix) wins instead when it is within `off_network` and not farther than the
    index's answer plus the route margin, as in `_first`."""
    m = len(sl)
    kind, index, dist = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64), np.zeros(m)
    trackers = [players[s].tracker for s in sl.tolist()]
    for placer, rows in by_placement_index(enumerate(trackers)):
        w = np.array(rows, dtype=np.int64)
        kind[w], index[w], dist[w] = placer.topo.placement_index().place_many(np.column_stack([x[w], y[w]]),
                                                                              placer.networks)
    for i, trk in enumerate(trackers):
        if trk.has_route:  # (`_first`: the route's nearest point first)
            f = trk.placer.on_edges(float(x[i]), float(y[i]), [e for e, _d in trk.route.edges])
            if f.distance <= trk.off_network and (kind[i] == 0 or
                                                  f.distance <= dist[i] + (trk.switch_margin or 0.0)):
                kind[i], index[i], dist[i] = 1, f.index, f.distance
    return (kind == 2) | ((kind == 1) & (index != fe) & (dist + swm < d))
