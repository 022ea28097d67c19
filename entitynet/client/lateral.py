"""The lateral cover's neighbourhood queries, made cheap for the publish (issue 11).

Why: a publish without a route lists the cells of the other ways within `lateral` metres of the position and
the areas next to it (`Coverage._lateral_cells`), and profiling the city simulation showed those queries as
the largest part of a publish: the edge grid's bucket walk (a dict lookup of every edge's box, a set and a
sort), and the exact distance to every nearby area's ring (its vertices converted to a list each time).

`NearIndex` answers the same questions with the same answers (tests hold them equal to `Placer.edges_near`
and to `ring_distance(...) <= r`):
- `edges_near`: each bucket holds its edges' boxes as rows, in edge order, so a query box inside one bucket
  (the usual case: buckets are 50 m, the box 2 x `lateral`) needs neither the set nor the sort;
- `way_cells`: the cells of the other ways near the position, with each candidate's projection and direction
  from per-edge tables built once (`_Way`: the placer's segment rows, the edge's cell pieces, its one segment's
  end points), the same float operations as `Placer.project_on` and `NetView.point` in the same order
  (issue 22: the lateral cover was half of a publish);
- `within_ring`: the squared distances to the ring's segments from a per-area table of the segment terms
  (the same floating-point operations as `ring_distance`), and `ring_distance` itself only where the answer
  is within a relative 1e-9 of `r`, where rounding could decide it.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Container

from entitynet.client.optional_c import compiled
from entitynet.client.path import Path
from entitynet.client.placement import AREA_BUCKET, Placer, ring_distance

_COMPILED = compiled("_lateral")  # the compiled ring distance
_WAYTABLE = compiled("_waytable")  # the candidate loop over C tables of the map, the whole `way_cells`
_WayTable = _WAYTABLE.WayTable if _WAYTABLE is not None else None
_areas_near = _WAYTABLE.areas_near if _WAYTABLE is not None else None

#: the largest query radius (m) that `edges_near` and `way_cells` answer from the one bucket holding the
#: position (each bucket also lists the edges whose boxes reach within WIDE + 1 m of it): about two thirds of the
#: lateral cover's boxes (20 m wide, 50 m buckets) straddle a bucket boundary, and those took the walk over
#: several buckets with a set and a sort. Larger radii take that walk.
WIDE = 25.0
#: the widened buckets' own size (m): smaller than the grid's 50 m, so that a bucket and its WIDE + 1 m rim list
#: fewer edges for the box test to reject
WIDE_SIZE = 20.0

#: relative band around `r` in which `within_ring` defers to `ring_distance` (the square root of a sum of
#: squares and `hypot` differ by a few ulps, about 1e-16 relative; far wider than that, and far narrower
#: than any distance that matters)
BAND = 1e-9


class NearIndex:
    """One placer's neighbourhood queries for the lateral cover (shared by every entity on that placer)."""

    __slots__ = ("placer", "rows", "wide", "size", "_rings", "_ways", "_table")

    def __init__(self, placer: Placer) -> None:
        self.placer = placer
        grid = placer._grid
        if grid is None:
            grid = placer._grid = placer._edge_grid()
        cells, boxes, size = grid
        # per bucket: (edge, box, its `_Way`) rows in ascending edge order (the grid is built edge by edge)
        ways = self._ways = {e: _Way(placer, e) for e in boxes}
        self.rows = {key: tuple((e, *boxes[e], ways[e]) for e in edges) for key, edges in cells.items()}
        self.size = size
        # per bucket: the rows of every edge whose box meets the bucket widened by WIDE + 1 m, in edge order
        # (the 1 m absorbs the rounding of x - r and of x / size: a box within r <= WIDE of a point in the
        # bucket meets the widened bucket with room to spare)
        wide: dict[tuple[int, int], list] = {}
        pad = WIDE + 1.0
        for e in sorted(boxes):
            bx0, by0, bx1, by1 = boxes[e]
            row = (e, bx0, by0, bx1, by1, ways[e])
            for gx in range(math.floor((bx0 - pad) / WIDE_SIZE), math.floor((bx1 + pad) / WIDE_SIZE) + 1):
                for gy in range(math.floor((by0 - pad) / WIDE_SIZE), math.floor((by1 + pad) / WIDE_SIZE) + 1):
                    wide.setdefault((gx, gy), []).append(row)
        self.wide = {key: tuple(rows) for key, rows in wide.items()}
        self._rings: dict[int, tuple[tuple[float, float, float, float, float], ...]] = {}
        self._table = None  # the `_waytable.WayTable` of `wide` and the ways, built on the first query

    def edges_near(self, x: float, y: float, r: float) -> list[int]:
        """`Placer.edges_near(x, y, r)`: the edges whose boxes meet the closed box of half-size r, in edge
        order."""
        size = self.size
        x0, y0, x1, y1 = x - r, y - r, x + r, y + r
        if r <= WIDE:  # the widened bucket of the position: its rows are in edge order, each edge once
            key = (math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE))
            return [e for e, bx0, by0, bx1, by1, _w in self.wide.get(key, ())
                    if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0)]
        gx0, gx1 = math.floor(x0 / size), math.floor(x1 / size)
        gy0, gy1 = math.floor(y0 / size), math.floor(y1 / size)
        rows = self.rows
        if gx0 == gx1 and gy0 == gy1:  # one bucket: its rows are in edge order, each edge once
            return [e for e, bx0, by0, bx1, by1, _w in rows.get((gx0, gy0), ())
                    if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0)]
        out: set[int] = set()
        for gx in range(gx0, gx1 + 1):
            for gy in range(gy0, gy1 + 1):
                for e, bx0, by0, bx1, by1, _w in rows.get((gx, gy), ()):
                    if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0):
                        out.add(e)
        return sorted(out)

    def way_cells(self, x: float, y: float, dx: float, dy: float, r: float, back: float, ahead: float,
                  skip: Container[int], only: Container[int] | None) -> list[int]:
        """The cells of the ways within `r` of (x, y) (`edges_near`, then `Placer.project_on`'s distance), each
        covered from `back` metres behind its projected point to `ahead` metres on in the direction (dx, dy)
        (an edge running against it: the other way round), clamped to the edge; in edge order, without repeats.
        `skip`: edges that are no candidates; `only`: the edges that may be (None: any)."""
        if _WayTable is not None:  # the compiled loop over the C tables
            if r <= WIDE:
                return self._waytable().way_cells((math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE)), x, y, dx,
                                                  dy, r, back, ahead, skip, only)
            return self._waytable().edges_cells(self.edges_near(x, y, r), x, y, dx, dy, r, back, ahead, skip, only)
        x0, y0, x1, y1 = x - r, y - r, x + r, y + r
        if r <= WIDE:  # the widened bucket of the position (`edges_near`)
            rows = self.wide.get((math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE)), ())
            cand = [w for e, bx0, by0, bx1, by1, w in rows if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0)]
        else:
            ways = self._ways
            cand = [ways[e] for e in self.edges_near(x, y, r)]
        return _way_cells_py(cand, x, y, dx, dy, r, back, ahead, skip, only)

    def _waytable(self):
        """The `_waytable.WayTable` of `wide` and the ways, built on first use."""
        table = self._table
        if table is None:
            table = self._table = _WayTable(self.wide, self._ways, self.placer.net)
        return table

    def path_cells(self, path: Path, s: float, r: float, back: float, ahead: float,
                   only: Container[int] | None) -> list[int]:
        """The cells of the other ways within `r` of the point at `s` on `path` (`way_cells` in the path's
        direction there), each covered `back` behind to `ahead` on; the path's own edges are no candidates
        where the occupation runs (from `back` behind to `ahead` on) nor the edge at `s`: one the path reaches
        only further on (it loops back along the parallel way) still is. Compiled as a whole where the C
        tables are built and r <= WIDE (`_waytable.WayTable.path_cells`)."""
        if r <= WIDE and _WayTable is not None:
            return self._waytable().path_cells(path, s, r, back, ahead, only)
        x, y = path.xy(s)
        hx, hy = path.xy(min(s + 1.0, path.length))
        bx, by = path.xy(max(s - 1.0, 0.0))
        skip = _edges_between(path, s - back, s + ahead)
        skip.add(path.locate(s)[0])  # the edge it is on
        return self.way_cells(x, y, hx - bx, hy - by, r, back, ahead, skip, only)

    def areas_near(self, x: float, y: float, r: float) -> list[int]:
        """`Placer.areas_near(x, y, r)`, its bucket walk compiled (`_waytable.areas_near`) once the placer's
        grid is built (its first call builds it)."""
        grid = self.placer._area_rows
        if grid is None or _areas_near is None:
            return self.placer.areas_near(x, y, r)
        return _areas_near(grid, AREA_BUCKET, x, y, r)

    def within_ring(self, area: int, x: float, y: float, r: float) -> bool:
        """`ring_distance(placer.ring(area), x, y) <= r`, decided from squared distances where rounding
        cannot change the answer."""
        segs = self._rings.get(area)
        if segs is None:
            segs = self._rings[area] = self._ring_segs(area)
        if not segs:
            return ring_distance(self.placer.ring(area), x, y) <= r
        d = (_ring_nearest_py if _COMPILED is None else _COMPILED.ring_nearest)(segs, x, y)
        if d < r * (1.0 - BAND):
            return True
        if d > r * (1.0 + BAND) and math.isfinite(d):
            return False
        return ring_distance(self.placer.ring(area), x, y) <= r

    def _ring_segs(self, area: int) -> tuple[tuple[float, float, float, float, float], ...]:
        """(x0, y0, dx, dy, l2 or 1) per segment of the area's ring: the terms `ring_distance` computes per call
        (the same operations, so the same values); empty for a ring without segments."""
        pts = self.placer.ring(area).tolist()
        out = []
        for (p0x, p0y), (p1x, p1y) in zip(pts, pts[1:], strict=False):
            dx = p1x - p0x
            dy = p1y - p0y
            l2 = dx * dx + dy * dy
            out.append((p0x, p0y, dx, dy, l2 if l2 > 0 else 1.0))
        return tuple(out)


class _Way:
    """What `NearIndex.way_cells` reads of one edge: the placer's projection rows, the edge's length and cell
    pieces, and its geometry for `point` (the map's data, fetched once)."""

    __slots__ = ("edge", "segs", "length", "pieces", "net", "one")

    def __init__(self, placer: Placer, edge: int) -> None:
        net = self.net = placer.net
        self.edge = edge
        segs = placer._segs.get(edge)
        if segs is None:
            segs = placer._segs[edge] = placer._edge_segs(edge)
        self.segs = tuple(segs)
        self.length = net.edge_len[edge]
        self.pieces = tuple(net.pieces(edge, 1))
        lo, hi = net.geom_off[edge], net.geom_off[edge + 1]
        # one segment (most edges): `NetView.point`'s operands, taken once
        gx, gy, gcum = net.gx, net.gy, net.gcum
        self.one = (gx[lo], gy[lo], gx[lo + 1], gy[lo + 1], gcum[lo], gcum[lo + 1], gcum[lo + 1] - gcum[lo],
                    gx[lo + 1] - gx[lo], gy[lo + 1] - gy[lo]) if hi - lo == 2 else None

    def point(self, offset: float) -> tuple[float, float]:
        """`NetView.point(edge, offset)`: the same operations, from the operands taken once."""
        one = self.one
        if one is None:
            return self.net.point(self.edge, offset)
        x0, y0, x1, y1, c0, c1, seg, ddx, ddy = one
        if offset <= 0.0:
            return x0, y0
        if offset >= c1:
            return x1, y1
        t = 0.0 if seg <= 0.0 else (offset - c0) / seg
        return x0 + t * ddx, y0 + t * ddy


def _edges_between(path: Path, lo: float, hi: float) -> set[int]:
    """The path's edges k (undirected ids) with cum[k + 1] >= lo and cum[k] <= hi: cum never decreases, so
    they are one run of indices, found by two bisections (a NaN bound: none, as the comparisons say)."""
    if lo != lo or hi != hi:
        return set()
    cum, edges = path.cum, path.edges
    k0 = bisect_left(cum, lo) - 1  # the first k with cum[k + 1] >= lo
    k1 = bisect_right(cum, hi)  # past the last k with cum[k] <= hi
    return {edges[k][0] for k in range(k0 if k0 > 0 else 0, k1 if k1 < len(edges) else len(edges))}


def _way_cells_py(cand: list, x: float, y: float, dx: float, dy: float, r: float, back: float, ahead: float,
                  skip: Container[int], only: Container[int] | None) -> list[int]:
    """The candidate loop of `NearIndex.way_cells` over the `_Way`s `cand`: the pure reference of the compiled
    `_waytable.WayTable` loop (used where pip did not build it)."""
    out: list[int] = []
    hypot = math.hypot
    for w in cand:
        e = w.edge
        if e in skip or (only is not None and e not in only):
            continue
        # Placer.project_on, term for term
        best_d = math.inf
        found = False
        bu = bc0 = bsl = 0.0
        for ax, ay, sdx, sdy, l2, c0, sl in w.segs:
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
        # min(h, length) and max(b, 0.0), as the builtins choose
        hx0, hy0 = w.point(length if length < h else h)
        bx0, by0 = w.point(0.0 if 0.0 > b else b)
        if ((hx0 - bx0) * dx + (hy0 - by0) * dy) >= 0.0:
            lo, hi = offset - back, offset + ahead
        else:
            lo, hi = offset - ahead, offset + back
        lo = 0.0 if 0.0 > lo else lo
        hi = length if length < hi else hi
        for a0, b0, c in w.pieces:
            if b0 >= lo and a0 <= hi and c not in out:
                out.append(c)
    return out


def _ring_nearest_py(segs: tuple, x: float, y: float) -> float:
    """The distance to the nearest of a ring's segments (`NearIndex._ring_segs` rows): `ring_distance`'s
    projection, term for term (the pure reference of the compiled `_lateral.ring_nearest`)."""
    best = math.inf
    for p0x, p0y, dx, dy, l2 in segs:
        t = ((x - p0x) * dx + (y - p0y) * dy) / l2
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        ex = p0x + t * dx - x
        ey = p0y + t * dy - y
        d2 = ex * ex + ey * ey
        if d2 < best:
            best = d2
    return math.sqrt(best)


def near_index(placer: Placer) -> NearIndex:
    """The placer's `NearIndex`, built on first use (the placers are shared per view and network mask)."""
    idx = placer.__dict__.get("_near_index")
    if idx is None:
        idx = placer.__dict__["_near_index"] = NearIndex(placer)
    return idx
