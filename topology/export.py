"""GeoJSON export of an artifact in WGS84 (RFC 7946): cells, edges, areas, buildings — opens in QGIS."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely import GeometryType

from topology.artifact import CELL_KIND_NAMES, Topology
from topology.projection import LocalProjection
from topology.raw import NETWORK_NAMES

LAYERS = ("cells", "edges", "areas", "buildings")


def _networks(bits: int) -> list[str]:
    return [name for bit, name in NETWORK_NAMES.items() if bits & bit]


def _to_wgs84(geoms: np.ndarray, proj: LocalProjection) -> np.ndarray:
    """WGS84, with polygon rings in RFC 7946 winding (exteriors counter-clockwise, holes clockwise)."""
    return shapely.orient_polygons(shapely.transform(geoms, proj.to_wgs84), exterior_cw=False)


def _features(geoms: np.ndarray, props: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for g, p in zip(geoms, props, strict=True):
        if g is None or g.is_empty:
            continue
        out.append(
            {"type": "Feature", "geometry": json.loads(shapely.to_geojson(g, indent=None)), "properties": p}
        )
    return out


def to_geojson(topo: Topology, layers: tuple[str, ...] = LAYERS, extra_features: list | None = None) -> dict:
    """The artifact's layers as one WGS84 FeatureCollection, for QGIS and other GIS tools."""
    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    features: list[dict[str, Any]] = []
    if "cells" in layers and topo.n_cells:
        geoms = _to_wgs84(topo.cell_footprints.to_shapely(), proj)
        props = [
            {
                "layer": "cell",
                "cell": i,
                "kind": CELL_KIND_NAMES[int(k)],
                "height_m": float(topo.cell_height[i]),
                "edges": topo.cell_edges_of(i).tolist(),
                "nodes": topo.cell_nodes_of(i).tolist(),
            }
            for i, k in enumerate(topo.cell_kind)
        ]
        features += _features(geoms, props)
    if "edges" in layers and topo.n_edges:
        lines = shapely.from_ragged_array(
            GeometryType.LINESTRING, topo.edge_geom_xy, (topo.edge_geom_offsets,)
        )
        props = [
            {
                "layer": "edge",
                "edge": i,
                "from": int(topo.edge_nodes[i, 0]),
                "to": int(topo.edge_nodes[i, 1]),
                "networks": _networks(int(topo.edge_networks[i])),
                "length_m": round(float(topo.edge_length[i]), 2),
            }
            for i in range(topo.n_edges)
        ]
        features += _features(_to_wgs84(lines, proj), props)
    if "areas" in layers and len(topo.area_node):
        kinds = topo.meta.get("area_kinds", [])
        names = topo.meta.get("area_names", [])
        props = [
            {
                "layer": "area",
                "area": i,
                "node": int(topo.area_node[i]),
                "cell": int(topo.area_cell[i]),
                "kind": kinds[i] if i < len(kinds) else "",
                "name": names[i] if i < len(names) else "",
                "networks": _networks(int(topo.area_networks[i])),
            }
            for i in range(len(topo.area_node))
        ]
        features += _features(_to_wgs84(topo.area_polygons.to_shapely(), proj), props)
    if "buildings" in layers and len(topo.building_height):
        props = [{"layer": "building", "building": i, "height_m": round(float(h), 2)}
                 for i, h in enumerate(topo.building_height)]  # fmt: skip
        features += _features(_to_wgs84(topo.building_footprints.to_shapely(), proj), props)
    features += extra_features or []
    return {"type": "FeatureCollection", "features": features}


def write_geojson(
    topo: Topology, out: str | Path, layers: tuple[str, ...] = LAYERS, extra_features=None
) -> int:
    """Write `to_geojson` compactly; returns the number of features written."""
    doc = to_geojson(topo, layers, extra_features)
    Path(out).write_text(json.dumps(doc, separators=(",", ":")))
    return len(doc["features"])


def pvs_geojson_features(topo: Any, x: float, y: float, z: float) -> list[dict]:
    """WGS84 GeoJSON features for one view cell's PVS: the view cell's square (layer "pvs_view_cell") and
    every visible cell's footprint (layer "pvs_cell"), for `topology.export.write_geojson(extra_features=)`."""
    from topology.pvs_index import PvsIndex

    index = PvsIndex.from_topology(topo)
    v = index.lookup_cell(x, y, z)
    cells = index.cells_at(x, y, z)
    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    iz, iy, ix = (int(a[0]) for a in np.nonzero(index.grid.index == v)) if v >= 0 else (0, 0, 0)
    g = index.grid
    sq = shapely.box(g.x0 + ix * g.size, g.y0 + iy * g.size, g.x0 + (ix + 1) * g.size, g.y0 + (iy + 1) * g.size)
    head = {"layer": "pvs_view_cell", "view_cell": v, "position": [x, y, z], "visible_cells": int(len(cells)),
            "z_min": float(g.layer_bottom(iz)), "z_max": float(g.layer_top(iz))}  # fmt: skip
    feats = _features(_to_wgs84(np.array([sq], dtype=object), proj), [head])
    polys = topo.cell_footprints.to_shapely()[cells] if len(cells) else np.empty(0, object)
    props = [{"layer": "pvs_cell", "cell": int(c), "view_cell": v} for c in cells]
    return feats + _features(_to_wgs84(polys, proj), props)
