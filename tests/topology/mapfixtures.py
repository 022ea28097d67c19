"""Tiny maps written directly in metres (EPSG:3067 around central Helsinki) as GeoJSON documents."""

from __future__ import annotations

from typing import Any

X0, Y0 = 385000.0, 6672000.0


def _pts(coords):
    return [[X0 + x, Y0 + y] for x, y in coords]


def street(coords, network="pedestrian,vehicle", **props) -> dict[str, Any]:
    return {"type": "Feature", "geometry": {"type": "LineString", "coordinates": _pts(coords)},
            "properties": {"network": network, **props}}  # fmt: skip


def polygon(shell, holes=(), **props) -> dict[str, Any]:
    rings = [_pts(shell)] + [_pts(h) for h in holes]
    return {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": rings}, "properties": props}


def box(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]


def collection(*features) -> dict[str, Any]:
    return {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "EPSG:3067"}},
        "features": list(features),
    }


def grid(nx: int, ny: int, spacing: float = 100.0) -> list[dict[str, Any]]:
    """An nx x ny street grid, each street one way crossing the others at shared vertices."""
    feats = []
    xs = [i * spacing for i in range(nx)]
    ys = [j * spacing for j in range(ny)]
    for y in ys:
        feats.append(street([(x, y) for x in xs]))
    for x in xs:
        feats.append(street([(x, y) for y in ys]))
    return feats
