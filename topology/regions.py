"""Shard regions: K contiguous regions of visibility cells, balanced by expected load, with their borders.

Why this shape: the cluster (entitynet.cluster) gives each switchboard the entities published in its region, and
NATS carries a cell's UPDATEs to every switchboard whose viewers subscribe to it. What crosses shards is
therefore what the viewers of one region can *see* of the others: the **border** of a region is the set of
cells of other regions that appear in the PVS of the view cells over it (without a PVS: the cells of other
regions adjacent to it on the network). Small borders mean little cross-shard traffic, so regions are grown
as compact blobs over the cell adjacency graph rather than cut into stripes.

The partition (deterministic, numpy only, no geometry library):
  1. weights: a cell's footprint area (street length x street width for street cells, the area for area
     cells): the default expected load; a measured occupancy (cell -> weight) replaces it when given;
  2. seeds: K cells spread by farthest-point sampling from the weighted centre;
  3. growth: the lightest region that still has unassigned neighbours takes its nearest one (by distance to
     its seed), so regions stay contiguous and compact and their loads even out;
  4. cells the growth cannot reach (a part of the network not connected to the rest) go, a connected piece at
     a time, to the lightest region: counted as `detached_components` in the report.
A view-grid column belongs to the region of the nearest cell centre: that decides where a viewer's camera
is "in" (a viewer whose camera moves into another region is redirected there).

The result is a `RegionMap`, saved as a small JSON cluster map carrying the topology digest and its own digest
(`entitynet topology regions ART --shards K --out MAP`); switchboards refuse a peer whose map digest differs.
"""

from __future__ import annotations

import hashlib
import heapq
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "entitynet-regions"
FORMAT_VERSION = 1


class RegionError(Exception):
    """A bad request (K out of range, a map that does not match the topology, a malformed file)."""


@dataclass
class RegionMap:
    """Cell -> region, view-grid column -> region, and each region's border (other regions' cells it sees)."""

    topology_digest: str
    shards: int
    cell_region: np.ndarray  # (C,) int32
    column_region: np.ndarray | None  # (ny * nx,) int32 view-grid columns, None without a PVS
    grid: dict[str, Any] | None  # origin, cell_size, nx, ny of the view grid (None without a PVS)
    borders: list[np.ndarray]  # region -> sorted int32 cells of other regions it sees
    report: dict[str, Any] = field(default_factory=dict)

    @property
    def digest(self) -> str:
        """Content digest: what two switchboards compare before they agree to share a cluster."""
        h = hashlib.sha256()
        h.update(self.topology_digest.encode())
        h.update(str(self.shards).encode())
        h.update(np.ascontiguousarray(self.cell_region, np.int32).tobytes())
        if self.column_region is not None:
            h.update(np.ascontiguousarray(self.column_region, np.int32).tobytes())
        for b in self.borders:
            h.update(len(b).to_bytes(8, "big"))
            h.update(np.ascontiguousarray(b, np.int32).tobytes())
        return h.hexdigest()

    def region_of_cell(self, cell: int) -> int:
        """The region (shard) that owns `cell`: where a PUBLISH into it belongs, else a REDIRECT."""
        return int(self.cell_region[cell])

    def region_at(self, x: float, y: float) -> int | None:
        """The region a camera at local (x, y) is in (clamped to the grid); None without a view grid."""
        if self.column_region is None or self.grid is None:
            return None
        g = self.grid
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"position must be finite, got ({x!r}, {y!r})")
        ix = min(max(math.floor((x - g["origin"][0]) / g["cell_size"]), 0), g["nx"] - 1)
        iy = min(max(math.floor((y - g["origin"][1]) / g["cell_size"]), 0), g["ny"] - 1)
        return int(self.column_region[iy * g["nx"] + ix])

    def cells_of(self, region: int) -> np.ndarray:
        """The cells a region owns, for a survivor that takes over a dead shard's regions."""
        return np.flatnonzero(self.cell_region == region).astype(np.int32)

    # ---- persistence ---------------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """The cluster map as plain JSON, with its digest so that shards can check they share one map."""
        return {
            "format": FORMAT, "version": FORMAT_VERSION, "topology_digest": self.topology_digest,
            "shards": self.shards, "cell_region": self.cell_region.tolist(),
            "column_region": None if self.column_region is None else self.column_region.tolist(),
            "grid": self.grid, "borders": [b.tolist() for b in self.borders], "report": self.report,
            "digest": self.digest,
        }  # fmt: skip

    @classmethod
    def from_json(cls, doc: Any) -> RegionMap:
        """Read a cluster map, refusing a malformed one or one whose content no longer matches its digest."""
        try:
            if doc.get("format") != FORMAT or doc.get("version") != FORMAT_VERSION:
                raise RegionError(f"not a {FORMAT} v{FORMAT_VERSION} cluster map")
            k = int(doc["shards"])
            cr = np.asarray(doc["cell_region"], np.int32)
            col = doc["column_region"]
            rm = cls(str(doc["topology_digest"]), k, cr, None if col is None else np.asarray(col, np.int32),
                     doc["grid"], [np.asarray(b, np.int32) for b in doc["borders"]], dict(doc.get("report", {})))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise RegionError(f"malformed cluster map: {exc}") from None
        if len(rm.borders) != k or (len(cr) and (cr.min() < 0 or cr.max() >= k)):
            raise RegionError("malformed cluster map: regions out of range")
        if doc.get("digest") != rm.digest:
            raise RegionError("cluster map digest does not match its content (edited or truncated?)")
        return rm

    def save(self, path: str | Path) -> str:
        """Write the map (compact JSON) and return its digest, which the shards compare in their heartbeats."""
        Path(path).write_text(json.dumps(self.to_json(), separators=(",", ":")), encoding="utf-8")
        return self.digest

    @classmethod
    def load(cls, path: str | Path, topology_digest: str | None = None) -> RegionMap:
        """Read a map from a file; with `topology_digest`, refuse one made for another artifact."""
        try:
            doc = json.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise RegionError(f"{path}: no such file") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise RegionError(f"{path}: not a cluster map ({exc})") from None
        rm = cls.from_json(doc)
        if topology_digest is not None and rm.topology_digest != topology_digest:
            raise RegionError(f"{path} was made for topology {rm.topology_digest[:12]}, not {topology_digest[:12]}")
        return rm


# ---- geometry helpers (numpy only) ---------------------------------------------------------------------------
def cell_centres_and_areas(topo: Any) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's footprint centre (mean of its exterior ring's vertices) and area (shoelace)."""
    fp = topo.cell_footprints
    n = len(fp)
    centres = np.zeros((n, 2))
    areas = np.zeros(n)
    for i in range(n):
        ring = fp.exterior(i)
        if len(ring) == 0:
            continue
        centres[i] = ring[:-1].mean(axis=0) if len(ring) > 1 else ring[0]
        x, y = ring[:, 0], ring[:, 1]
        areas[i] = abs(float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))) / 2.0
    return centres, areas


def cell_adjacency(topo: Any) -> list[set[int]]:
    """Cells are neighbours when they share an edge (pieces of one street) or a node (a junction's arms)."""
    n = int(topo.n_cells)
    by_edge: dict[int, list[int]] = {}
    by_node: dict[int, list[int]] = {}
    for c in range(n):
        for e in topo.cell_edges_of(c).tolist():
            by_edge.setdefault(e, []).append(c)
        for v in topo.cell_nodes_of(c).tolist():
            by_node.setdefault(v, []).append(c)
    # a street cell on an edge also touches the cells holding the edge's end nodes
    for e, cells in list(by_edge.items()):
        for v in topo.edge_nodes[e].tolist():
            by_node.setdefault(v, [])
            for c in cells:
                if c not in by_node[v]:
                    by_node[v].append(c)
    adj: list[set[int]] = [set() for _ in range(n)]
    for group in (*by_edge.values(), *by_node.values()):
        for a in group:
            adj[a].update(group)
    for c in range(n):
        adj[c].discard(c)
    return adj


# ---- the partition ---------------------------------------------------------------------------------------------
def _seeds(centres: np.ndarray, weights: np.ndarray, k: int) -> list[int]:
    centre = (centres * weights[:, None]).sum(axis=0) / max(float(weights.sum()), 1e-12)
    first = int(np.argmax(((centres - centre) ** 2).sum(axis=1)))
    seeds = [first]
    dist = ((centres - centres[first]) ** 2).sum(axis=1)
    while len(seeds) < k:
        nxt = int(np.argmax(dist))
        seeds.append(nxt)
        dist = np.minimum(dist, ((centres - centres[nxt]) ** 2).sum(axis=1))
    return seeds


def partition(topo: Any, k: int, weights: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Cell -> region (int32) for K regions, and the growth's facts for the report."""
    n = int(topo.n_cells)
    if not 1 <= k <= n:
        raise RegionError(f"--shards must be between 1 and the number of cells ({n}), got {k}")
    centres, areas = cell_centres_and_areas(topo)
    w = areas.copy() if weights is None else np.asarray(weights, float)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise RegionError(f"weights must be {n} finite non-negative numbers")
    w = np.maximum(w, 1e-6 * max(float(w.max(initial=0.0)), 1.0))  # no free cells: every cell costs a little
    adj = cell_adjacency(topo)
    region = np.full(n, -1, np.int32)
    load = np.zeros(k)
    seeds = _seeds(centres, w, k)
    frontier: list[list[tuple[float, int]]] = [[] for _ in range(k)]

    def take(r: int, c: int) -> None:
        region[c] = r
        load[r] += w[c]
        sx, sy = centres[seeds[r]]
        for nb in adj[c]:
            if region[nb] < 0:
                d = (centres[nb, 0] - sx) ** 2 + (centres[nb, 1] - sy) ** 2
                heapq.heappush(frontier[r], (d, nb))

    for r, s in enumerate(seeds):
        take(r, s)
    active = [(0.0, r) for r in range(k)]
    heapq.heapify(active)
    while active:
        _, r = heapq.heappop(active)
        fr = frontier[r]
        while fr and region[fr[0][1]] >= 0:
            heapq.heappop(fr)
        if not fr:
            continue  # enclosed: this region is done
        take(r, heapq.heappop(fr)[1])
        heapq.heappush(active, (load[r], r))
    detached = 0
    for c in range(n):  # the rest of a network in several pieces: whole pieces to the lightest region
        if region[c] >= 0:
            continue
        detached += 1
        r = int(np.argmin(load))
        stack = [c]
        region[c] = r
        while stack:
            x = stack.pop()
            load[r] += w[x]
            for nb in adj[x]:
                if region[nb] < 0:
                    region[nb] = r
                    stack.append(nb)
    cut = sum(1 for a in range(n) for b in adj[a] if a < b and region[a] != region[b])
    facts = {"loads": [round(float(x), 1) for x in load], "cut_adjacencies": int(cut),
             "detached_components": detached, "seeds": seeds}
    return region, facts


def _column_regions(topo: Any, centres: np.ndarray, region: np.ndarray, grid: Any) -> np.ndarray:
    """Each view-grid column -> the region of the nearest cell centre (in chunks: columns x cells)."""
    xs = grid.x0 + (np.arange(grid.nx) + 0.5) * grid.size
    ys = grid.y0 + (np.arange(grid.ny) + 0.5) * grid.size
    px, py = np.meshgrid(xs, ys)  # (ny, nx)
    pts = np.stack([px.ravel(), py.ravel()], axis=1)
    out = np.empty(len(pts), np.int32)
    step = max(1, 2_000_000 // max(len(centres), 1))
    for i in range(0, len(pts), step):
        d = ((pts[i : i + step, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        out[i : i + step] = region[np.argmin(d, axis=1)]
    return out


def build_regions(topo: Any, k: int, weights: np.ndarray | None = None, borders: bool = True) -> RegionMap:
    """The partition, the view-grid columns' regions and each region's border, with a report. `borders=False`
    skips the borders (decoding every view cell's PVS takes seconds on a city): they are left empty."""
    region, facts = partition(topo, k, weights)
    centres, areas = cell_centres_and_areas(topo)
    w = areas if weights is None else np.asarray(weights, float)
    seen: list[set[int]] = [set() for _ in range(k)]
    seen_street: list[set[int]] = [set() for _ in range(k)]  # from the lowest layer only: cameras at street level
    column_region = grid_meta = None
    border_rule = "network adjacency (no PVS)" if borders else "not computed"
    if borders and "pvs_grid" in topo.extra and topo.meta.get("pvs"):
        from topology.pvs import PvsIndex

        idx = PvsIndex.from_topology(topo)
        g = idx.grid
        column_region = _column_regions(topo, centres, region, g)
        grid_meta = {"origin": [float(g.x0), float(g.y0)], "cell_size": float(g.size), "nx": g.nx, "ny": g.ny}
        index = np.asarray(g.index).reshape(g.nz, g.ny * g.nx)
        for iz in range(g.nz):
            for col in range(g.ny * g.nx):
                v = int(index[iz, col])
                if v >= 0:
                    r = int(column_region[col])
                    vis = idx.pvs(v).tolist()
                    seen[r].update(vis)
                    if iz == 0:
                        seen_street[r].update(vis)
        border_rule = "PVS of the region's view cells"
    elif borders:
        adj = cell_adjacency(topo)
        for c in range(len(region)):
            seen[int(region[c])].update(adj[c])
    borders = []
    for r in range(k):
        cells = np.array(sorted(seen[r]), np.int32)
        borders.append(cells[region[cells] != r] if len(cells) else cells)
    total = float(w.sum()) or 1.0
    loads = np.array([float(w[region == r].sum()) for r in range(k)])
    report = {
        "shards": k, "cells": int(len(region)), "weights": "footprint area" if weights is None else "given",
        "cells_per_region": [int((region == r).sum()) for r in range(k)],
        "load_share": [round(float(x) / total, 4) for x in loads],
        "balance": round(float(loads.max() / (total / k)), 4),
        "cut_adjacencies": facts["cut_adjacencies"], "detached_components": facts["detached_components"],
        "border_cells": [len(b) for b in borders], "border_rule": border_rule,
        "border_cells_street_level": [sum(1 for c in seen_street[r] if region[c] != r) for r in range(k)]
        if column_region is not None else None,
    }  # fmt: skip
    return RegionMap(topo.digest, k, region, column_region, grid_meta, borders, report)


def load_weights(path: str | Path, n_cells: int) -> np.ndarray:
    """A measured occupancy as JSON: a list of n_cells numbers or an object {cell: weight} (others weigh 0)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RegionError(f"{path}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RegionError(f"{path}: not JSON ({exc})") from None
    w = np.zeros(n_cells)
    try:
        if isinstance(doc, list):
            if len(doc) != n_cells:
                raise RegionError(f"{path}: {len(doc)} weights for {n_cells} cells")
            w[:] = [float(x) for x in doc]
        elif isinstance(doc, dict):
            for key, val in doc.items():
                c = int(key)
                if not 0 <= c < n_cells:
                    raise RegionError(f"{path}: cell {c} does not exist (this map has {n_cells})")
                w[c] = float(val)
        else:
            raise RegionError(f"{path}: expected a list or an object of cell weights")
    except (TypeError, ValueError) as exc:
        raise RegionError(f"{path}: bad weight ({exc})") from None
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise RegionError(f"{path}: weights must be finite and non-negative")
    return w
