"""The lateral cover's neighbourhood queries, made cheap for the publish (issue 11).

Why: a publish without a route lists the cells of the other ways within `lateral` metres of the position and
the areas next to it (`Coverage._lateral_cells`), and profiling the city simulation showed those queries as
the largest part of a publish: the edge grid's bucket walk (a dict lookup of every edge's box, a set and a
sort), and the exact distance to every nearby area's ring (its vertices converted to a list each time).

`NearIndex` answers the same questions with the same answers (tests hold them equal to `Placer.edges_near`
and to `ring_distance(...) <= r`):
- `edges_near`: each bucket holds its edges' boxes as rows, in edge order, so a query box inside one bucket
  (the usual case: buckets are 50 m, the box 2 x `lateral`) needs neither the set nor the sort;
- `within_ring`: the squared distances to the ring's segments from a per-area table of the segment terms
  (the same floating-point operations as `ring_distance`), and `ring_distance` itself only where the answer
  is within a relative 1e-9 of `r`, where rounding could decide it.
"""

from __future__ import annotations

import math

from entitynet.client.placement import Placer, ring_distance

#: relative band around `r` in which `within_ring` defers to `ring_distance` (the square root of a sum of
#: squares and `hypot` differ by a few ulps, about 1e-16 relative; far wider than that, and far narrower
#: than any distance that matters)
BAND = 1e-9


class NearIndex:
    """One placer's neighbourhood queries for the lateral cover (shared by every entity on that placer)."""

    __slots__ = ("placer", "rows", "size", "_rings")

    def __init__(self, placer: Placer) -> None:
        self.placer = placer
        grid = placer._grid
        if grid is None:
            grid = placer._grid = placer._edge_grid()
        cells, boxes, size = grid
        # per bucket: (edge, box) rows in ascending edge order (the grid is built edge by edge)
        self.rows = {key: tuple((e, *boxes[e]) for e in edges) for key, edges in cells.items()}
        self.size = size
        self._rings: dict[int, tuple[tuple[float, float, float, float, float], ...]] = {}

    def edges_near(self, x: float, y: float, r: float) -> list[int]:
        """`Placer.edges_near(x, y, r)`: the edges whose boxes meet the closed box of half-size r, in edge
        order."""
        size = self.size
        x0, y0, x1, y1 = x - r, y - r, x + r, y + r
        gx0, gx1 = math.floor(x0 / size), math.floor(x1 / size)
        gy0, gy1 = math.floor(y0 / size), math.floor(y1 / size)
        rows = self.rows
        if gx0 == gx1 and gy0 == gy1:  # one bucket: its rows are in edge order, each edge once
            return [e for e, bx0, by0, bx1, by1 in rows.get((gx0, gy0), ())
                    if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0)]
        out: set[int] = set()
        for gx in range(gx0, gx1 + 1):
            for gy in range(gy0, gy1 + 1):
                for e, bx0, by0, bx1, by1 in rows.get((gx, gy), ()):
                    if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0):
                        out.add(e)
        return sorted(out)

    def within_ring(self, area: int, x: float, y: float, r: float) -> bool:
        """`ring_distance(placer.ring(area), x, y) <= r`, decided from squared distances where rounding
        cannot change the answer."""
        segs = self._rings.get(area)
        if segs is None:
            segs = self._rings[area] = self._ring_segs(area)
        if not segs:
            return ring_distance(self.placer.ring(area), x, y) <= r
        best = math.inf
        for p0x, p0y, dx, dy, l2 in segs:  # ring_distance's projection, term for term
            t = ((x - p0x) * dx + (y - p0y) * dy) / l2
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            ex = p0x + t * dx - x
            ey = p0y + t * dy - y
            d2 = ex * ex + ey * ey
            if d2 < best:
                best = d2
        d = math.sqrt(best)
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


def near_index(placer: Placer) -> NearIndex:
    """The placer's `NearIndex`, built on first use (the placers are shared per view and network mask)."""
    idx = placer.__dict__.get("_near_index")
    if idx is None:
        idx = placer.__dict__["_near_index"] = NearIndex(placer)
    return idx
