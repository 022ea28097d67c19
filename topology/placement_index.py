"""Placement index for the first fix of an entity: areas first, else the nearest edge of its networks.

Built lazily from the artifact (shapely STRtree; a few ms for the Helsinki map). Later fixes use continuity on
the compiled arrays in the client core, not this index.

Answers for many points at once: `place_many` (kind, index, distance) and `prime`, which computes `place`'s whole
answer for a batch of points in one vectorised pass and keeps it until the next `prime`, so that the `place`
calls a fleet's scalar fixes then make for those points are dictionary lookups. Why: one `place` is a dozen
shapely calls (40-100 us on the 2-core machine), the batch about 10 us a point; a fleet's first fixes, its
re-placements and its fixes leaving an area ask it for hundreds of points a tick (issue 23: the start's burst).
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely import GeometryType

from topology.networks import PEDESTRIAN, TRAM, VEHICLE, Placement

_MISSING = object()
PRIMED_MAX = 1_000_000  # the most answers `prime` keeps (a caller that keeps adding batches starts afresh)


class PlacementIndex:
    """STRtrees over the edges of each network and the areas: the first fix of an entity, before it
    has a position to continue from (shapely, so it is built only on first use)."""

    def __init__(self, topo) -> None:
        self.topo = topo
        lines = shapely.from_ragged_array(
            GeometryType.LINESTRING, topo.edge_geom_xy, (topo.edge_geom_offsets,)
        ) if topo.n_edges else np.empty(0, dtype=object)  # fmt: skip
        self.lines = lines
        self.trees: dict[int, tuple[shapely.STRtree, np.ndarray]] = {}
        for bit in (PEDESTRIAN, VEHICLE, TRAM):
            idx = np.flatnonzero(topo.edge_networks & bit)
            self.trees[bit] = (shapely.STRtree(lines[idx]), idx)
        self.areas = topo.area_polygons.to_shapely()
        self.area_tree = shapely.STRtree(self.areas)
        # `prime`'s answers, by (x, y, networks): only the latest batch's (a memo of a pure function)
        self._primed: dict[tuple[float, float, int], Placement | None] = {}
        self.primed_hits = 0

    def place(self, x: float, y: float, networks: int = PEDESTRIAN | VEHICLE | TRAM) -> Placement | None:
        """Where a point is on the networks `networks` (bitmask); None if the map has no such network.

        Deterministic: equidistant edges resolve to the lowest edge id."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"cannot place a non-finite point ({x}, {y})")
        primed = self._primed
        if primed:
            hit = primed.get((x, y, networks), _MISSING)
            if hit is not _MISSING:
                self.primed_hits += 1
                return hit
        pt = shapely.Point(x, y)
        for a in sorted(self.area_tree.query(pt, predicate="intersects")):
            if self.topo.area_networks[a] & networks:
                return Placement("area", int(a), 0.0, x, y, 0.0)
        best: tuple[float, int] | None = None
        for bit, (tree, idx) in self.trees.items():
            if not (bit & networks) or len(idx) == 0:
                continue
            hits, dists = tree.query_nearest(pt, return_distance=True, all_matches=True)
            for h, d in zip(hits, dists, strict=True):
                cand = (float(d), int(idx[h]))
                if best is None or cand < best:
                    best = cand
        if best is None:
            return None
        dist, edge = best
        offset = float(shapely.line_locate_point(self.lines[edge], pt))
        px, py = self.topo.point_at(edge, offset)
        return Placement("edge", edge, offset, float(px), float(py), dist)

    def place_many(self, xy: np.ndarray, networks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`place` for every point of the (n, 2) array `xy` at once, without the offset and the foot (what the
        fleet core's consistency query reads): per point its kind (0 none, 1 edge, 2 area), index and distance,
        the same answers as `place` (the first area in id order, else the nearest edge, equidistant edges
        resolving to the lowest id). Why: one STRtree query for a tick's points instead of one per point."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if not np.isfinite(xy).all():
            raise ValueError("cannot place a non-finite point")
        n = len(xy)
        kind, index, dist = np.zeros(n, np.int64), np.full(n, -1, np.int64), np.full(n, math.nan)
        if not n:
            return kind, index, dist
        pts = shapely.points(xy)
        src, a = self.area_tree.query(pts, predicate="intersects")
        use = (np.asarray(self.topo.area_networks)[a] & networks) != 0
        src, a = src[use], a[use]
        if len(src):
            o = np.lexsort((a, src))
            src, a = src[o], a[o]
            first = np.r_[True, src[1:] != src[:-1]]
            kind[src[first]], index[src[first]], dist[src[first]] = 2, a[first], 0.0
        rest = np.flatnonzero(kind == 0)
        cand_s, cand_e, cand_d = [], [], []
        for bit, (tree, idx) in self.trees.items():
            if not (bit & networks) or len(idx) == 0 or not len(rest):
                continue
            (s, h), d = tree.query_nearest(pts[rest], return_distance=True, all_matches=True)
            cand_s.append(rest[s])
            cand_e.append(idx[h])
            cand_d.append(d)
        if cand_s:
            s, e, d = np.concatenate(cand_s), np.concatenate(cand_e), np.concatenate(cand_d)
            o = np.lexsort((e, d, s))  # per point the least (distance, edge), as `place`'s tuple compare
            s, e, d = s[o], e[o], d[o]
            first = np.r_[True, s[1:] != s[:-1]]
            kind[s[first]], index[s[first]], dist[s[first]] = 1, e[first], d[first]
        return kind, index, dist

    def prime(self, xy: np.ndarray, networks: int, *, keep: bool = False) -> int:
        """Compute `place(x, y, networks)` for every finite point of the (n, 2) array `xy` in one pass and keep the
        answers for the `place` calls that follow, in place of the earlier batches' (`keep`: beside them, for a
        caller priming several network masks for one step), so the memo holds one step's points.
        Points with a coordinate of 0.0 are left out (0.0 and -0.0 are one key, and an area's answer keeps the
        point's own coordinates). The answers are `place`'s exactly: the same GEOS queries, distances and
        projections, vectorised (tests/topology/test_placement_index.py). Returns how many points were kept."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        finite = np.isfinite(xy).all(axis=1) & (xy != 0.0).all(axis=1)
        xy = xy[finite]
        if not keep or len(self._primed) + len(xy) > PRIMED_MAX:
            self._primed = {}
        if not len(xy):
            return 0
        kind, index, dist = self.place_many(xy, networks)
        on_edge = np.flatnonzero(kind == 1)
        offsets = np.zeros(len(xy))
        if len(on_edge):
            offsets[on_edge] = shapely.line_locate_point(self.lines[index[on_edge]], shapely.points(xy[on_edge]))
        memo = self._primed
        point_at = self.topo.point_at
        for (x, y), k, i, d, off in zip(xy.tolist(), kind.tolist(), index.tolist(), dist.tolist(),
                                        offsets.tolist(), strict=True):
            if k == 2:
                memo[(x, y, networks)] = Placement("area", i, 0.0, x, y, 0.0)
            elif k == 1:
                px, py = point_at(i, off)
                memo[(x, y, networks)] = Placement("edge", i, off, float(px), float(py), d)
            else:
                memo[(x, y, networks)] = None
        return len(xy)

    def nearest_edges(self, xy: np.ndarray, networks: int) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised: (edge id, distance) of the nearest edge of `networks` for each point in (n, 2) `xy`."""
        pts = shapely.points(np.asarray(xy, np.float64))
        best_e = np.full(len(pts), -1, np.int64)
        best_d = np.full(len(pts), np.inf)
        for bit, (tree, idx) in self.trees.items():
            if not (bit & networks) or len(idx) == 0:
                continue
            (src, hit), d = tree.query_nearest(pts, return_distance=True)
            e = idx[hit]
            better = (d < best_d[src]) | ((d == best_d[src]) & (e < best_e[src]))
            best_d[src[better]] = d[better]
            best_e[src[better]] = e[better]
        return best_e, best_d
