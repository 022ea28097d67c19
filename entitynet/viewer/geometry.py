"""The artifact as the browser viewer needs it: compact JSON in the artifact's local metric coordinates.

Two precisions on purpose. What is only drawn (buildings, areas, cell footprints) is rounded to 1 cm, which
halves the JSON. What the page extrapolates on (edge polylines, their cumulative lengths, edge lengths) is
rounded to 0.1 mm, so that a position the page computes from a payload stays within 1 mm of the one the Python
client computes from the same payload (the golden-vector test checks it). Lengths are the artifact's own,
never recomputed in JavaScript, for the same reason.

The PVS is not shipped whole (13.5 MB of lists for Helsinki): the page gets the view-cell grid and the
resolved grid -> view cell index (the one `topology.pvs_index.PvsIndex.lookup_cell` uses), and asks for one view
cell's list when its camera enters it (`pvs_cells`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from entitynet.client.entities import BY_CODE
from entitynet.client.limits import HORIZON, MAX_SPEED
from topology.artifact import CELL_KIND_NAMES, Topology
from topology.polygons import Polygons

FORMAT = "entitynet-viewer-geometry"
VERSION = 1


def _r(values: np.ndarray, digits: int) -> list[float]:
    """Rounded to `digits` decimals as plain floats (integers where exact, which JSON writes shorter)."""
    out = np.round(np.asarray(values, dtype=np.float64), digits).ravel().tolist()
    return [int(v) if v.is_integer() else v for v in out]


def polygons_json(polys: Polygons, digits: int = 2) -> list[list[list[float]]]:
    """Each polygon as a list of rings, each ring a flat [x0, y0, x1, y1, ...] (closed, as stored)."""
    out = []
    xy = polys.xy
    for i in range(len(polys)):
        rings = []
        for r in range(int(polys.ring_offsets[i]), int(polys.ring_offsets[i + 1])):
            a, b = int(polys.coord_offsets[r]), int(polys.coord_offsets[r + 1])
            rings.append(_r(xy[a:b], digits))
        out.append(rings)
    return out


def net_json(topo: Topology) -> dict[str, Any]:
    """What the page's NetView needs to follow a network payload's path (entitynet/client/path.py)."""
    return {
        "n_edges": int(topo.n_edges),
        "edge_from": topo.edge_nodes[:, 0].astype(int).tolist(),
        "edge_to": topo.edge_nodes[:, 1].astype(int).tolist(),
        "edge_len": _r(topo.edge_length, 4),
        "edge_net": topo.edge_networks.astype(int).tolist(),
        "geom_off": topo.edge_geom_offsets.astype(int).tolist(),
        "gx": _r(topo.edge_geom_xy[:, 0], 4),
        "gy": _r(topo.edge_geom_xy[:, 1], 4),
        "gcum": _r(topo.edge_geom_cum, 4),
    }


def extrapolation_limits() -> dict[str, Any]:
    """The limits every receiver applies (entitynet/client/limits.py), so the page uses the Python values."""
    return {
        "horizon": HORIZON,
        "max_speed_default": MAX_SPEED,
        "max_speed": {str(code): t.max_speed for code, t in sorted(BY_CODE.items())},
        "types": {str(code): {"name": t.name, "parts": list(t.parts)} for code, t in sorted(BY_CODE.items())},
    }


def grid_json(x0: float, y0: float, size: float, max_height: float, index: np.ndarray,
              view_distance: float) -> dict[str, Any]:
    """A view-cell grid (topology/viewcells.py `ViewGrid`) with every grid cell resolved to the view cell that
    answers for it (`topology.pvs_index._resolve_grid`, the table `PvsIndex.lookup_cell` reads)."""
    from topology.pvs_index import _resolve_grid

    index = np.asarray(index)
    nz, ny, nx = (int(n) for n in index.shape)
    return {"x0": float(x0), "y0": float(y0), "size": float(size), "max_height": float(max_height),
            "nx": nx, "ny": ny, "nz": nz, "view_distance": float(view_distance),
            "resolved": _resolve_grid(index).ravel().astype(int).tolist()}


def pvs_grid_json(topo: Topology) -> dict[str, Any] | None:
    """The artifact's view-cell grid for the page (`grid_json`), or None without a PVS."""
    meta = topo.meta.get("pvs")
    if meta is None or "pvs_grid" not in topo.extra:
        return None
    return grid_json(meta["origin"][0], meta["origin"][1], meta["cell_size"], meta["max_height"],
                     topo.extra["pvs_grid"], meta["view_distance"])


def export_geometry(topo: Topology) -> dict[str, Any]:
    """Everything the page draws and extrapolates on, in the artifact's local coordinates (metres)."""
    xy = topo.edge_geom_xy
    extent = [float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max())]
    meta = topo.meta
    return {
        "format": FORMAT,
        "version": VERSION,
        "digest": topo.digest,
        "crs": meta.get("crs"),
        "origin": meta.get("origin"),
        "extent": extent,
        "net": net_json(topo),
        "buildings": {"height": _r(topo.building_height, 1), "polygons": polygons_json(topo.building_footprints)},
        "areas": {"networks": topo.area_networks.astype(int).tolist(), "polygons": polygons_json(topo.area_polygons)},
        "cells": {
            "kind": topo.cell_kind.astype(int).tolist(),
            "kind_names": {str(k): v for k, v in CELL_KIND_NAMES.items()},
            "height": _r(topo.cell_height, 2),
            "polygons": polygons_json(topo.cell_footprints),
        },
        "pvs": pvs_grid_json(topo),
        "limits": extrapolation_limits(),
    }


def pvs_cells(topo: Topology, index: Any, view_cell: int) -> list[int]:
    """The sorted visibility cells of one view cell (`index`: a `topology.pvs.PvsIndex` of `topo`)."""
    return np.asarray(index.pvs(view_cell)).astype(int).tolist()
