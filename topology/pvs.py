"""Precomputed visibility (PVS): for every view cell, the visibility cells a camera inside it may see.

Algorithm: radial horizon sweeps through a rasterised height field (2.5D), from a lattice of viewpoints on
the *top face* of every view cell, with eroded occluders.

Why this one:
- The city is a height field (buildings are prisms standing on the ground), so visibility is 2.5D. For a
  height field a higher eye sees everything a lower eye at the same (x, y) sees: the segment from the higher
  eye to a target lies above the lower one at every (x, y). So from-region visibility of a view cell reduces
  to visibility from its top face, and the targets (footprint x [0, entity height]) to their top, the entity
  height. This is exact, not a heuristic, and it is why one sweep serves all view-cell layers of a column.
- From one eye point, rays fan out over the raster (R directions x S steps, one (R, S) gather). Along a ray
  the horizon is the running maximum of the occluder elevation slope (H - z) / s; a target pixel is visible
  iff its own slope (T - z) / s reaches the horizon. `np.maximum.accumulate` does that for all rays at once,
  and the gathered heights are reused for every layer height z, so the inner loop is a handful of
  whole-array numpy operations per eye point: no Python loop over rays or steps.
- From-region visibility by point sampling is approximate (the reference system sampled corners and centre).
  To make the samples stand for the whole face we erode the occluders by `shrink` metres (occluder shrinking,
  Wonka et al. 2000): with occluders eroded by e, an eye point sees every target that any eye within e of it
  sees in the original scene. With samples `samples` x `samples` on a face of side a, every face point lies
  within a / (samples - 1) / sqrt(2) of a sample, so shrink >= that distance (plus the raster's half-pixel
  diagonal) makes the sampling conservative. That would be 14 m for the default 2 x 2 eyes on a 20 m face
  and would erase most buildings, so the default erodes 3 m: the result is approximate, with a measured
  false-negative rate far under 1% (docs/pvs.md).
- What else is approximate: the raster (nearest pixel), the angular spacing of the rays and the two-pixel
  steps beyond `far_step_from` (a target gap narrower than the ray spacing at that distance may be missed).
  All are measured against the dense, exact reference in `topology.pvs_reference`.

Range: a visibility cell is in range of a view cell when the horizontal distance between the view cell's
square and the cell footprint is at most `view_distance` (exact, shapely). The PVS is a subset of that set.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import shapely

from topology.polygons import Polygons
from topology.pvs_index import PvsIndex as PvsIndex  # re-exported: builders make one from a PvsResult
from topology.pvs_quality import QUALITY as QUALITY  # re-exported: the presets live apart, free of shapely
from topology.pvs_raster import _erode, _Raster, _rasterise
from topology.viewcells import ViewGrid, build_view_grid, column_squares

MAX_LABEL_LAYERS = 8  # how many overlapping visibility cells one target pixel can stand for

ALGORITHM = "2.5D radial horizon sweeps from top-face viewpoint lattices over an eroded height raster"


@dataclass(frozen=True)
class PvsConfig:
    """The PVS build settings; the quality presets (QUALITY) trade build time for fewer missed cells."""

    cell_size: float = 20.0  # view-cell cube side (m)
    max_height: float = 100.0  # top of the view-cell stack (m)
    view_distance: float = 500.0  # horizontal range (m)
    raster: float = 2.0  # height-field pixel (m)
    samples: int = 2  # eye points per side of each view cell's top face (lattice shared by neighbours)
    shrink: float = 3.0  # occluder erosion (m), see module docstring
    ray_spacing: float = 2.0  # ray spacing at the far end, in raster pixels (sets the number of rays)
    far_step_from: float = 200.0  # beyond this distance (m) rays step two pixels at a time
    workers: int = 2  # processes (fork); 1 = in-process
    quality: str = "default"

    @classmethod
    def from_quality(cls, quality: str = "default", **overrides: Any) -> PvsConfig:
        """A preset, with the settings given (not None) on top: the CLI passes unset options as None."""
        if quality not in QUALITY:
            raise ValueError(f"unknown PVS quality {quality!r}; choose one of {sorted(QUALITY)}")
        preset = dict(QUALITY[quality])
        preset["samples"] = int(preset["samples"])
        preset.update({k: v for k, v in overrides.items() if v is not None})
        return cls(quality=quality, **preset)

    def validate(self) -> None:
        """Refuse settings that would loop forever or divide by zero, with a message naming the setting."""
        for name in ("cell_size", "max_height", "view_distance", "raster", "ray_spacing", "far_step_from"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"PVS {name} must be a positive finite number, got {v!r}")
        if not (math.isfinite(self.shrink) and self.shrink >= 0):
            raise ValueError(f"PVS shrink must be >= 0, got {self.shrink!r}")
        if int(self.samples) < 1 or int(self.workers) < 1:
            raise ValueError("PVS samples and workers must be >= 1")

    @property
    def n_rays(self) -> int:
        """Rays per eye point: enough that neighbouring rays are `ray_spacing` pixels apart at the far end."""
        reach = self.view_distance + self.cell_size * math.sqrt(2.0)
        n = int(math.ceil(2.0 * math.pi * reach / (self.ray_spacing * self.raster)))
        return max(64, n)


@dataclass
class PvsResult:
    """The PVS as CSR lists (`offsets`, sorted `ids` per view cell) plus the grid and statistics."""

    grid: ViewGrid
    config: PvsConfig
    offsets: np.ndarray  # (V+1,) int64
    ids: np.ndarray  # int32
    range_count: np.ndarray  # (V,) int32: cells within the view distance (the pure distance cut)
    n_cells: int
    stats: dict[str, Any] = field(default_factory=dict)

    def pvs_of(self, view_cell: int) -> np.ndarray:
        """Sorted visibility-cell ids of one view cell (a view into `ids`, no copy)."""
        return self.ids[self.offsets[view_cell] : self.offsets[view_cell + 1]]

    def to_extra(self) -> dict[str, np.ndarray]:
        """Named arrays for `Topology.extra` (prefixed `pvs_`): the grid index and the compressed lists."""
        from topology.pvs_codec import encode

        arrays = {"pvs_grid": self.grid.index}
        arrays.update(encode(self.offsets, self.ids, self.grid.index, self.n_cells).arrays())
        return arrays

    def meta(self) -> dict[str, Any]:
        """Small JSON-able description for `meta["pvs"]`."""
        return {
            **self.grid.meta(),
            "view_distance": float(self.config.view_distance),
            "n_cells": int(self.n_cells),
            "view_cells": int(self.grid.n_view_cells),
            "algorithm": ALGORITHM,
            "conservative": False,
            "config": asdict(self.config),
            "stats": self.stats,
        }


# ------------------------------------------------------------------------------------------------------------
# the sweep kernel (runs in worker processes; module globals are inherited through fork)

_K: dict[str, Any] = {}


def _sweep_chunk(args: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Sweep the eye points at flat pixels `base` for the layer heights in `levels_mask` (n, nz) bool.

    Returns (the eye indices, packed visible-cell bits (n, nz, nbytes))."""
    idx, (base, levels_mask) = args
    k = _K
    hocc, tgt, labels = k["hocc"], k["tgt"], k["labels"]
    off, inv = k["off"], k["inv"]
    tops = k["tops"]
    n_cells = k["n_cells"]
    nz = len(tops)
    out = np.zeros((len(base), nz, k["nbytes"]), dtype=np.uint8)
    mark = np.zeros(n_cells + 1, dtype=bool)
    a = np.empty(off.shape, dtype=np.float32)
    for i in range(len(base)):
        pix = off + base[i]
        lab0 = labels[0].take(pix).ravel()
        tpos = np.flatnonzero(lab0 != n_cells)
        if len(tpos) == 0:
            continue
        hs = hocc.take(pix)
        pix_t = pix.ravel()[tpos]
        ts = tgt.take(pix_t)
        invt = inv.ravel().take(tpos)
        lab0 = lab0[tpos]
        more = []  # overlapping cells: (positions in tpos-space, their labels)
        if len(labels) > 1:
            sub0 = np.flatnonzero(labels[1].take(pix_t) != n_cells)
            for lay in labels[1:]:
                lab = lay.take(pix_t[sub0])
                keep = lab != n_cells
                if keep.any():
                    more.append((sub0[keep], lab[keep]))
        for iz in range(nz):
            if not levels_mask[i, iz]:
                continue
            z = tops[iz]
            np.subtract(hs, z, out=a)
            a *= inv
            np.maximum.accumulate(a, axis=1, out=a)
            vis = (ts - z) * invt >= a.ravel().take(tpos)
            mark[:] = False
            mark[lab0[vis]] = True
            for sub, lab in more:
                mark[lab[vis[sub]]] = True
            out[i, iz] = np.packbits(mark[:n_cells])
    return idx, out


# ------------------------------------------------------------------------------------------------------------


def compute_pvs(
    building_footprints: Polygons,
    building_height: np.ndarray,
    cell_footprints: Polygons,
    cell_height: np.ndarray,
    bounds: tuple[float, float, float, float],
    config: PvsConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> PvsResult:
    """View cells and their PVS for the map. `progress(msg)` gets a line now and then (to stderr, say)."""
    cfg = config or PvsConfig()
    cfg.validate()
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    bh = np.asarray(building_height, dtype=np.float64)
    ch = np.asarray(cell_height, dtype=np.float64)
    if len(bh) != len(building_footprints) or len(ch) != len(cell_footprints):
        raise ValueError("one height per footprint expected")
    if (len(bh) and not np.all(np.isfinite(bh))) or (len(ch) and not np.all(np.isfinite(ch))):
        raise ValueError("heights must be finite")
    bounds = tuple(float(v) for v in bounds)
    grid = build_view_grid(building_footprints, bh, bounds, cfg.cell_size, cfg.max_height)
    n_cells = len(cell_footprints)
    V = grid.n_view_cells
    say(f"pvs: {V} view cells ({grid.nx}x{grid.ny}x{grid.nz}), {n_cells} visibility cells")

    bpolys = shapely.make_valid(building_footprints.to_shapely()) if len(bh) else np.empty(0, object)
    cpolys = cell_footprints.to_shapely() if n_cells else np.empty(0, object)
    reach = cfg.view_distance + cfg.cell_size * math.sqrt(2.0)
    px = cfg.raster
    pad_px = int(math.ceil(reach / px)) + 2
    xmin, ymin, xmax, ymax = bounds
    xmax_g = xmin + grid.nx * grid.size
    ymax_g = ymin + grid.ny * grid.size
    cols = int(math.ceil((xmax_g - xmin) / px)) + 2 * pad_px
    rows = int(math.ceil((ymax_g - ymin) / px)) + 2 * pad_px
    raster = _Raster(xmin - pad_px * px, ymin - pad_px * px, px, (rows, cols))
    map_box = (xmin - px, ymin - px, xmax_g + px, ymax_g + px)

    # occluder heights (pixel centre strictly inside a footprint), then eroded
    hmap = np.zeros(rows * cols, dtype=np.float32)
    if len(bpolys):
        fp, fb = _rasterise(bpolys, raster, map_box)
        np.maximum.at(hmap, fp, bh[fb].astype(np.float32))
    hmap = hmap.reshape(rows, cols)
    hocc = _erode(hmap, cfg.shrink / px).ravel()
    phase = {"grid_s": time.perf_counter() - t0}
    say(f"pvs: occluder raster done ({phase['grid_s']:.1f} s)")

    # target labels: pixel -> the cells covering it, in up to MAX_LABEL_LAYERS layers (cells overlap at
    # junctions); every cell also gets the pixel of a point on its surface, so thin cells are never lost
    if n_cells:
        tp, tc = _rasterise(cpolys, raster, map_box)
        rep = shapely.point_on_surface(cpolys)
        tp = np.concatenate([tp, raster.pixel_of(shapely.get_x(rep), shapely.get_y(rep))])
        tc = np.concatenate([tc, np.arange(n_cells)])
        key = np.unique(tp * n_cells + tc)
        tp, tc = key // n_cells, key % n_cells
    else:
        tp = tc = np.zeros(0, np.int64)
    first = np.searchsorted(tp, tp, "left")
    rank = np.arange(len(tp)) - first
    n_layers = max(1, min(MAX_LABEL_LAYERS, int(rank.max()) + 1 if len(rank) else 1))
    labels = np.full((n_layers, rows * cols), n_cells, dtype=np.int32)
    kept = rank < n_layers
    labels[rank[kept], tp[kept]] = tc[kept]
    tgt = np.zeros(rows * cols, dtype=np.float32)
    if len(tp):
        np.maximum.at(tgt, tp, ch[tc].astype(np.float32))
    dropped_labels = int((~kept).sum())

    # ray fan: offsets in flat pixels and 1/s per (ray, step)
    R = cfg.n_rays
    # steps of one pixel near the eye, two pixels beyond `far_step_from` (targets are cells many metres wide;
    # a thin occluder skipped far away costs a false positive, not a false negative)
    near = min(reach, cfg.far_step_from)
    s = (np.arange(int(math.ceil(near / px))) + 0.5) * px
    if reach > near:
        s = np.concatenate([s, s[-1] + 2 * px * (np.arange(int(math.ceil((reach - s[-1]) / (2 * px)))) + 1)])
    S = len(s)
    ang = (np.arange(R) + 0.5) * (2.0 * np.pi / R)
    dc = np.floor(np.outer(np.cos(ang), s) / px + 0.5).astype(np.int64)
    dr = np.floor(np.outer(np.sin(ang), s) / px + 0.5).astype(np.int64)
    off = (dr * cols + dc).astype(np.int64)
    inv = np.broadcast_to((1.0 / s).astype(np.float32), (R, S)).copy()

    # eye lattice on the top faces, shared between neighbouring columns
    m = int(cfg.samples)
    if m >= 2:
        lx = xmin + np.arange(grid.nx * (m - 1) + 1) * (grid.size / (m - 1))
        ly = ymin + np.arange(grid.ny * (m - 1) + 1) * (grid.size / (m - 1))
        col_step, face = m - 1, np.arange(m)
    else:
        lx = xmin + (np.arange(grid.nx) + 0.5) * grid.size
        ly = ymin + (np.arange(grid.ny) + 0.5) * grid.size
        col_step, face = 1, np.array([0])
    LX, LY = np.meshgrid(lx, ly)
    lat_x, lat_y = LX.ravel(), LY.ravel()
    n_lat = len(lat_x)
    tops = grid.layer_top(np.arange(grid.nz)).astype(np.float64)
    # exact eye validity: not strictly inside a building taller than the layer top
    lat_h = np.zeros(n_lat)
    if len(bpolys):
        ip, jp = shapely.STRtree(bpolys).query(shapely.points(lat_x, lat_y), predicate="within")
        np.maximum.at(lat_h, ip, bh[jp])
    lat_valid = lat_h[:, None] <= tops[None, :]  # (n_lat, nz)

    # which lattice points each view cell uses, and which view cells have none valid
    iz, iy, ix = grid.coords()
    uses = np.zeros((n_lat, grid.nz), dtype=bool)
    vc_samples = []
    for a in face:
        for b in face:
            li = (iy * col_step + a) * len(lx) + (ix * col_step + b)
            vc_samples.append(li)
    vc_samples = np.stack(vc_samples, axis=1) if V else np.zeros((0, len(face) ** 2), np.int64)
    vc_valid = lat_valid[vc_samples, iz[:, None]] if V else np.zeros((0, 1), bool)
    for j in range(vc_samples.shape[1]):
        uses[vc_samples[vc_valid[:, j], j], iz[vc_valid[:, j]]] = True
    # fallback eyes for view cells whose lattice points all lie inside buildings
    lonely = np.flatnonzero(~vc_valid.any(axis=1)) if V else np.zeros(0, np.int64)
    extra_x, extra_y, extra_vc = [], [], []
    unions: dict[int, Any] = {}
    for v in lonely:
        top = tops[iz[v]]
        x0, y0 = xmin + ix[v] * grid.size, ymin + iy[v] * grid.size
        sq = shapely.box(x0, y0, x0 + grid.size, y0 + grid.size)
        if int(iz[v]) not in unions:
            unions[int(iz[v])] = shapely.union_all(bpolys[bh > top]) if len(bpolys) else None
        u = unions[int(iz[v])]
        free = sq.difference(u) if u is not None else sq
        if free.is_empty:
            continue
        pt = shapely.point_on_surface(free)
        extra_x.append(pt.x)
        extra_y.append(pt.y)
        extra_vc.append(v)
    eye_x = np.concatenate([lat_x, np.array(extra_x)])
    eye_y = np.concatenate([lat_y, np.array(extra_y)])
    eye_levels = np.concatenate([uses, np.zeros((len(extra_vc), grid.nz), bool)])
    for k, v in enumerate(extra_vc):
        eye_levels[n_lat + k, iz[v]] = True
    todo = np.flatnonzero(eye_levels.any(axis=1))
    base = raster.pixel_of(eye_x, eye_y)
    phase["targets_s"] = time.perf_counter() - t0 - phase["grid_s"]
    say(f"pvs: {len(todo)} eye points x {R} rays x {S} steps, raster {rows}x{cols} @ {px} m")

    # sweep, in worker processes
    nbytes = (n_cells + 7) // 8
    _K.clear()
    _K.update(
        hocc=hocc, tgt=tgt, labels=labels, off=off, inv=inv, tops=tops.astype(np.float32),
        n_cells=n_cells, nbytes=nbytes,
    )  # fmt: skip
    eye_bits = np.zeros((len(eye_x), grid.nz, nbytes), dtype=np.uint8)
    chunk = 64
    jobs = [
        (todo[i : i + chunk], (base[todo[i : i + chunk]], eye_levels[todo[i : i + chunk]]))
        for i in range(0, len(todo), chunk)
    ]
    t_sweep = time.perf_counter()
    done = 0
    last = 0.0
    workers = min(int(cfg.workers), os.cpu_count() or 1, max(1, len(jobs)))
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(workers) as pool:
            for idx, bits in pool.imap_unordered(_sweep_chunk, jobs):
                eye_bits[idx] = bits
                done += len(idx)
                if time.perf_counter() - last > 2.0:
                    last = time.perf_counter()
                    say(f"pvs: {done}/{len(todo)} eye points ({100 * done / max(1, len(todo)):.0f}%)")
    else:
        for job in jobs:
            idx, bits = _sweep_chunk(job)
            eye_bits[idx] = bits
            done += len(idx)
            if time.perf_counter() - last > 2.0:
                last = time.perf_counter()
                say(f"pvs: {done}/{len(todo)} eye points ({100 * done / max(1, len(todo)):.0f}%)")
    _K.clear()
    sweep_s = time.perf_counter() - t_sweep

    # per view cell: OR over its valid eyes, then AND with the exact distance cut
    t_range = time.perf_counter()
    in_range = _range_bits(grid, cpolys, cfg.view_distance, n_cells)
    phase["range_s"] = time.perf_counter() - t_range
    seen = np.zeros((V, nbytes), dtype=np.uint8)
    for j in range(vc_samples.shape[1]):
        ok = vc_valid[:, j]
        seen[ok] |= eye_bits[vc_samples[ok, j], iz[ok]]
    for k, v in enumerate(extra_vc):
        seen[v] |= eye_bits[n_lat + k, iz[v]]
    offsets = np.zeros(V + 1, dtype=np.int64)
    id_chunks = []
    col_of = iy * grid.nx + ix
    range_count = in_range.sum(axis=1).astype(np.int32)[col_of] if V else np.zeros(0, np.int32)
    for c0 in range(0, V, 2048):  # vectorised in blocks to bound memory
        sl = slice(c0, min(V, c0 + 2048))
        row = np.unpackbits(seen[sl], axis=1, count=n_cells).astype(bool)
        row &= in_range[col_of[sl]]
        offsets[sl.start + 1 : sl.stop + 1] = row.sum(axis=1)
        id_chunks.append(np.nonzero(row)[1].astype(np.int32))
    np.cumsum(offsets, out=offsets)
    ids = np.concatenate(id_chunks) if id_chunks else np.zeros(0, np.int32)
    phase["combine_s"] = time.perf_counter() - t_range - phase["range_s"]
    build_s = time.perf_counter() - t0
    sizes = np.diff(offsets)
    stats = {
        "build_s": round(build_s, 3),
        "sweep_s": round(sweep_s, 3),
        **{k: round(v, 3) for k, v in phase.items()},
        "eye_points": int(len(todo)),
        "label_layers": n_layers,
        "dropped_labels": dropped_labels,
        "rays": R,
        "steps": S,
        "mean_pvs_cells": float(sizes.mean()) if V else 0.0,
        "mean_range_cells": float(range_count.mean()) if V else 0.0,
        "culled_by_layer": _culled_by_layer(sizes, range_count, iz, grid.nz),
    }
    say(f"pvs: done in {build_s:.1f} s, mean PVS {stats['mean_pvs_cells']:.0f} of {n_cells} cells")
    return PvsResult(grid, cfg, offsets, ids, range_count, n_cells, stats)


def _culled_by_layer(sizes: np.ndarray, range_count: np.ndarray, iz: np.ndarray, nz: int) -> list[dict]:
    """Fraction of the in-range cells culled by visibility, per layer (mean and quantiles)."""
    out = []
    frac = np.where(range_count > 0, 1.0 - sizes / np.maximum(range_count, 1), 0.0)
    for k in range(nz):
        f = frac[iz == k]
        if len(f) == 0:
            continue
        q = np.quantile(f, [0.1, 0.5, 0.9])
        row = {"layer": k, "view_cells": int(len(f)), "mean": round(float(f.mean()), 4)}
        row.update({name: round(float(v), 4) for name, v in zip(("p10", "p50", "p90"), q, strict=True)})
        out.append(row)
    return out


def _range_bits(grid: ViewGrid, cpolys: np.ndarray, d: float, n_cells: int) -> np.ndarray:
    """(columns, n_cells) bool: horizontal distance from the column square to the footprint <= d (exact)."""
    ncol = grid.nx * grid.ny
    out = np.zeros((ncol, n_cells), dtype=bool)
    if n_cells == 0:
        return out
    cb = shapely.bounds(cpolys)
    diag = np.hypot(cb[:, 2] - cb[:, 0], cb[:, 3] - cb[:, 1])
    iy, ix = np.divmod(np.arange(ncol), grid.nx)
    sx0 = grid.x0 + ix * grid.size
    sy0 = grid.y0 + iy * grid.size
    squares = column_squares(grid.x0, grid.y0, grid.size, grid.nx, grid.ny)
    for c0 in range(0, ncol, 256):
        sl = slice(c0, min(ncol, c0 + 256))
        gx = np.maximum(
            0.0, np.maximum(cb[None, :, 0] - (sx0[sl, None] + grid.size), sx0[sl, None] - cb[None, :, 2])
        )
        gy = np.maximum(
            0.0, np.maximum(cb[None, :, 1] - (sy0[sl, None] + grid.size), sy0[sl, None] - cb[None, :, 3])
        )
        bd = np.hypot(gx, gy)
        sure = bd + diag[None, :] <= d
        maybe = (bd <= d) & ~sure
        blk = sure
        ii, jj = np.nonzero(maybe)
        if len(ii):
            exact = shapely.distance(squares[sl][ii], cpolys[jj]) <= d
            blk[ii[exact], jj[exact]] = True
        out[sl] = blk
    return out
