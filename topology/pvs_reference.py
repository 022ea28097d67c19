"""Dense, exact reference visibility for checking the fast PVS, plus synthetic test cities.

Independent of `topology.pvs` on purpose (no raster, no sweeps, no erosion, no top-face argument): for a
view cell it takes a lattice of eye points through the whole cube (several heights, not only the top), dense
target points over each visibility cell's footprint at several heights, and tests every segment exactly
against the building prisms with GEOS:

- candidate (segment, building) pairs come from an STRtree query with the exact 2D `intersects` predicate;
- `intersection(segment, footprint)` gives the pieces of the segment over the footprint; a piece blocks when
  it has positive length, its midpoint lies in the footprint's *interior* (so running along a wall or
  touching a corner does not block) and the segment's height somewhere on it (z is linear, so at one of its
  ends) is below the roof (so grazing a roof edge does not block).

A cell is visible from the view cell when some eye sees some target point. Eyes strictly inside a building
are dropped (no camera there). Work is cut by testing, for each eye in turn, only the cells not seen yet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from topology.polygons import Polygons

EPS = 1e-9


@dataclass(frozen=True)
class ReferenceConfig:
    """Density of the exact reference: more eyes and targets find more visible pairs, at more time per
    view cell."""
    eyes_xy: int = 3  # eye lattice points per side of the cube
    eyes_z: int = 2  # eye lattice levels (bottom, ..., top of the cube)
    target_spacing: float = 4.0  # metres between target points over a footprint
    target_levels: tuple[float, ...] = (0.5, 1.0)  # target heights as fractions of the cell height


class Scene:
    """Buildings as exact prisms: their walls as 2D edges with the owning building's height."""

    def __init__(self, building_footprints: Polygons, building_height: np.ndarray):
        self.heights = np.asarray(building_height, dtype=np.float64)
        self.polys = building_footprints.to_shapely() if len(building_footprints) else np.empty(0, object)
        self.tree = shapely.STRtree(self.polys)
        shapely.prepare(self.polys)
        fp = building_footprints
        if len(fp):
            xy = fp.xy
            ring_of_coord = np.repeat(np.arange(len(fp.coord_offsets) - 1), np.diff(fp.coord_offsets))
            poly_of_ring = np.repeat(np.arange(len(fp)), np.diff(fp.ring_offsets))
            last = np.zeros(len(xy), dtype=bool)
            last[fp.coord_offsets[1:] - 1] = True  # the closing coordinate of each ring starts no edge
            first = np.flatnonzero(~last)
            self.p = xy[first]
            self.q = xy[first + 1]
            self.owner = poly_of_ring[ring_of_coord[first]]
        else:
            self.p = self.q = np.zeros((0, 2))
            self.owner = np.zeros(0, np.int64)
        self.h = self.heights[self.owner] if len(self.owner) else np.zeros(0)

    def inside(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """True where (x, y, z) is strictly inside a prism (interior of the footprint, below the roof)."""
        out = np.zeros(len(x), dtype=bool)
        if len(self.polys) == 0 or len(x) == 0:
            return out
        ip, jp = self.tree.query(shapely.points(x, y), predicate="within")
        below = z[ip] < self.heights[jp] - EPS
        out[ip[below]] = True
        return out

    def blocked_from(self, eye: np.ndarray, targets: np.ndarray, max_pairs: int = 400_000) -> np.ndarray:
        """For the segments eye -> targets[i]: does the segment pass through the interior of a prism?

        A segment enters a prism's interior either through a wall below the roof (a proper crossing of a
        footprint edge at z < h), or through a footprint vertex (then a point just past or before it is
        strictly inside), or it ends inside. Edges whose line passes through the eye can only meet the
        segment at the eye, so they are skipped. Candidate (edge, target) pairs come from the edge's angular
        span around the eye: targets sorted by angle, one searchsorted per edge."""
        m = len(targets)
        out = self.inside(targets[:, 0], targets[:, 1], targets[:, 2])
        if m == 0 or len(self.p) == 0:
            return out
        ex, ey, ez = (float(v) for v in eye)
        d = targets[:, :2] - (ex, ey)
        length = np.hypot(d[:, 0], d[:, 1])
        phi = np.arctan2(d[:, 1], d[:, 0])
        order = np.argsort(phi)
        phis = phi[order]
        p = self.p - (ex, ey)
        q = self.q - (ex, ey)
        w = q - p
        wl = np.hypot(w[:, 0], w[:, 1])
        cross_pw = p[:, 0] * w[:, 1] - p[:, 1] * w[:, 0]  # 0 when the edge line passes through the eye
        ok = (np.abs(cross_pw) > 1e-9 * np.maximum(wl, 1.0)) & (self.h > min(ez, float(targets[:, 2].min())))
        on_line = ~(np.abs(cross_pw) > 1e-9 * np.maximum(wl, 1.0))
        if on_line.any():
            # the eye lies on a footprint's boundary: a sight line may leave it straight into the interior
            # (then it enters through no edge); test a point just past the eye
            tpar = -(p[on_line] * w[on_line]).sum(1) / np.maximum(wl[on_line] ** 2, 1e-300)
            if ((tpar >= -1e-9) & (tpar <= 1 + 1e-9)).any():
                delta = 1e-5 / np.maximum(length, 1e-300)
                probe = np.column_stack([ex + delta * d[:, 0], ey + delta * d[:, 1], ez + delta * (targets[:, 2] - ez)])
                out |= self.inside(probe[:, 0], probe[:, 1], probe[:, 2]) & (length > 1e-9)
        edges = np.flatnonzero(ok)
        if len(edges) == 0:
            return out
        # nearest edges first: most blocked targets are blocked near the eye and then drop out of later pairs
        pe = p[edges]
        we = w[edges]
        tt = np.clip(-(pe * we).sum(1) / np.maximum(wl[edges] ** 2, 1e-300), 0.0, 1.0)
        edges = edges[np.argsort(np.hypot(pe[:, 0] + tt * we[:, 0], pe[:, 1] + tt * we[:, 1]))]
        fa = np.arctan2(p[edges, 1], p[edges, 0])
        fb = np.arctan2(q[edges, 1], q[edges, 0])
        span = (fb - fa + np.pi) % (2 * np.pi) - np.pi
        a0 = np.where(span >= 0, fa, fb) - 1e-9
        a1 = a0 + np.abs(span) + 2e-9
        # distance from the eye to the edge: targets nearer than that cannot be blocked by it
        tt = np.clip(-(p[edges] * w[edges]).sum(1) / np.maximum(wl[edges] ** 2, 1e-300), 0.0, 1.0)
        dmin = np.hypot(p[edges, 0] + tt * w[edges, 0], p[edges, 1] + tt * w[edges, 1])
        lo = np.searchsorted(phis, a0, "left")
        hi = np.searchsorted(phis, np.minimum(a1, np.pi), "right")
        wrap = a1 > np.pi  # the part of the span past +pi continues from -pi
        lo2 = np.zeros_like(lo)
        hi2 = np.where(wrap, np.searchsorted(phis, a1 - 2 * np.pi, "right"), 0)
        e_all = np.stack([edges, edges], axis=1).ravel()
        lo_all = np.stack([lo, lo2], axis=1).ravel()
        cnt = np.stack([hi - lo, hi2 - lo2], axis=1).ravel()
        dmin_all = np.stack([dmin, dmin], axis=1).ravel()
        blocked = out.copy()
        # chunk the pair expansion to bound memory
        csum = np.cumsum(cnt)
        start = 0
        while start < len(cnt):
            base = csum[start - 1] if start else 0
            stop = int(np.searchsorted(csum, base + max_pairs, "right"))
            stop = max(stop, start + 1)
            sl = slice(start, stop)
            c = cnt[sl]
            n = int(c.sum())
            if n:
                ei = np.repeat(e_all[sl], c)
                first = np.repeat(lo_all[sl], c)
                off = np.arange(n) - np.repeat(np.cumsum(c) - c, c)
                ti = order[first + off]
                keep = (length[ti] > np.repeat(dmin_all[sl], c) - 1e-9) & ~blocked[ti]
                ei, ti = ei[keep], ti[keep]
                self._test_pairs(ei, ti, d, length, ez, targets, blocked, (ex, ey))
            start = stop
        return blocked

    def _test_pairs(self, ei, ti, d, length, ez, targets, blocked, exy) -> None:
        p = self.p[ei] - exy
        w = self.q[ei] - self.p[ei]
        dd = d[ti]
        denom = dd[:, 0] * w[:, 1] - dd[:, 1] * w[:, 0]
        par = np.abs(denom) <= 1e-12 * np.maximum(1.0, length[ti] * np.hypot(w[:, 0], w[:, 1]))
        denom = np.where(par, 1.0, denom)
        s = (p[:, 0] * w[:, 1] - p[:, 1] * w[:, 0]) / denom  # along the segment
        u = (p[:, 0] * dd[:, 1] - p[:, 1] * dd[:, 0]) / denom  # along the edge
        wl = np.hypot(w[:, 0], w[:, 1])
        lt = length[ti]
        tol = 1e-7
        on_seg = (s * lt > tol) & ((1 - s) * lt > tol) & ~par
        proper = on_seg & (u * wl > tol) & ((1 - u) * wl > tol)
        z = ez + s * (targets[ti, 2] - ez)
        hb = self.h[ei]
        hit = proper & (z < hb - EPS)
        blocked[ti[hit]] = True
        # through a vertex: look just before and after it along the segment
        touch = on_seg & ~proper & (u * wl >= -tol) & ((u - 1) * wl <= tol) & ~blocked[ti]
        if touch.any():
            k = np.flatnonzero(touch)
            bld = self.owner[ei[k]]
            delta = 1e-5 / np.maximum(lt[k], 1e-300)
            for sgn in (-1.0, 1.0):
                sk = np.clip(s[k] + sgn * delta, 0.0, 1.0)
                x = exy[0] + sk * dd[k, 0]
                y = exy[1] + sk * dd[k, 1]
                zk = ez + sk * (targets[ti[k], 2] - ez)
                inside = shapely.contains_xy(self.polys[bld], x, y) & (zk < self.heights[bld] - EPS)
                blocked[ti[k[inside]]] = True


def target_points(cell_footprints: Polygons, cell_height: np.ndarray, spacing: float, levels) -> tuple:
    """Dense (x, y, z) target points per cell: a lattice over the footprint, its vertices pulled slightly
    inwards, and a point on its surface; at the given fractions of the cell height. Returns (xyz, cell)."""
    polys = cell_footprints.to_shapely()
    xs, ys, owner = [], [], []
    for c, poly in enumerate(polys):
        x0, y0, x1, y1 = poly.bounds
        gx = np.arange(x0 + spacing / 2, x1, spacing)
        gy = np.arange(y0 + spacing / 2, y1, spacing)
        GX, GY = np.meshgrid(gx, gy)
        GX, GY = GX.ravel(), GY.ravel()
        inside = shapely.contains_xy(poly, GX, GY)
        inner = poly.buffer(-min(0.25, spacing / 10))
        ring = shapely.get_coordinates(inner.exterior if not inner.is_empty and inner.geom_type == "Polygon"
                                       else poly.exterior)  # fmt: skip
        rep = poly.representative_point()
        px = np.concatenate([GX[inside], ring[:-1, 0], [rep.x]])
        py = np.concatenate([GY[inside], ring[:-1, 1], [rep.y]])
        xs.append(px)
        ys.append(py)
        owner.append(np.full(len(px), c))
    if not xs:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    x, y, cell = np.concatenate(xs), np.concatenate(ys), np.concatenate(owner)
    h = np.asarray(cell_height, dtype=np.float64)[cell]
    pts = np.concatenate([np.column_stack([x, y, f * h]) for f in levels])
    return pts, np.tile(cell, len(levels))


def eye_points(box: np.ndarray, cfg: ReferenceConfig) -> np.ndarray:
    """Lattice of eye points through the whole view-cell box (x0, y0, z0, x1, y1, z1), faces included."""
    x0, y0, z0, x1, y1, z1 = (float(v) for v in box)
    gx = np.linspace(x0, x1, cfg.eyes_xy)
    gy = np.linspace(y0, y1, cfg.eyes_xy)
    gz = np.linspace(z1, z0, cfg.eyes_z) if cfg.eyes_z > 1 else np.array([z1])
    Z, Y, X = np.meshgrid(gz, gy, gx, indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])


def reference_visible(
    scene: Scene,
    box: np.ndarray,
    targets: np.ndarray,
    target_cell: np.ndarray,
    candidates: np.ndarray,
    cfg: ReferenceConfig,
) -> np.ndarray:
    """Sorted ids of the candidate cells visible from some eye in `box`."""
    eyes = eye_points(box, cfg)
    eyes = eyes[~scene.inside(eyes[:, 0], eyes[:, 1], eyes[:, 2])]
    # start from the eye nearest the box centre's top, which usually sees most
    cx, cy = (box[0] + box[3]) / 2, (box[1] + box[4]) / 2
    eyes = eyes[np.lexsort((np.hypot(eyes[:, 0] - cx, eyes[:, 1] - cy), -eyes[:, 2]))]
    unseen = np.zeros(int(target_cell.max()) + 1 if len(target_cell) else 0, dtype=bool)
    unseen[candidates] = True
    for eye in eyes:
        sel = np.flatnonzero(unseen[target_cell])
        if len(sel) == 0:
            break
        ok = ~scene.blocked_from(eye, targets[sel])
        unseen[np.unique(target_cell[sel[ok]])] = False
    seen = np.zeros_like(unseen)
    seen[candidates] = ~unseen[candidates]
    return np.flatnonzero(seen)


def in_range(box: np.ndarray, cell_polys: np.ndarray, view_distance: float) -> np.ndarray:
    """Cells whose footprint lies within `view_distance` (horizontal) of the view cell's square."""
    sq = shapely.box(box[0], box[1], box[3], box[4])
    return np.flatnonzero(shapely.distance(sq, cell_polys) <= view_distance)


# ------------------------------------------------------------------------------------------------------------
# synthetic scenes


def synthetic_city(
    blocks_x: int = 6,
    blocks_y: int = 5,
    block: float = 70.0,
    street: float = 16.0,
    seed: int = 1,
    heights: tuple[float, float] = (8.0, 40.0),
    entity_height: float = 4.0,
) -> tuple[Polygons, np.ndarray, Polygons, np.ndarray, tuple[float, float, float, float]]:
    """An urban grid: blocks of 2-4 box buildings of random heights, streets between them split into street
    cells of at most ~50 m, junction squares at the crossings. Returns the compute_pvs inputs."""
    rng = np.random.default_rng(seed)
    pitch = block + street
    bpolys, bh = [], []
    for j in range(blocks_y):
        for i in range(blocks_x):
            x0, y0 = street + i * pitch, street + j * pitch
            nsplit = int(rng.integers(1, 3))
            cuts = np.sort(rng.uniform(0.3, 0.7, nsplit)) * block
            edges = np.concatenate([[0.0], cuts, [block]])
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                if rng.random() < 0.5:
                    bpolys.append(shapely.box(x0 + a, y0, x0 + b, y0 + block))
                else:
                    bpolys.append(shapely.box(x0, y0 + a, x0 + block, y0 + b))
                bh.append(float(rng.uniform(*heights)))
    width = street + blocks_x * pitch
    height = street + blocks_y * pitch
    cells = []
    # junction squares
    for j in range(blocks_y + 1):
        for i in range(blocks_x + 1):
            cells.append(shapely.box(i * pitch, j * pitch, i * pitch + street, j * pitch + street))
    # street pieces between junctions (split into pieces of <= 50 m)
    npieces = max(1, math.ceil(block / 50.0))
    piece = block / npieces
    for j in range(blocks_y + 1):
        for i in range(blocks_x):
            for k in range(npieces):
                xa = i * pitch + street + k * piece
                cells.append(shapely.box(xa, j * pitch, xa + piece, j * pitch + street))
    for i in range(blocks_x + 1):
        for j in range(blocks_y):
            for k in range(npieces):
                ya = j * pitch + street + k * piece
                cells.append(shapely.box(i * pitch, ya, i * pitch + street, ya + piece))
    return (
        Polygons.from_shapely(bpolys),
        np.array(bh, dtype=np.float32),
        Polygons.from_shapely(cells),
        np.full(len(cells), entity_height, dtype=np.float32),
        (0.0, 0.0, width, height),
    )
