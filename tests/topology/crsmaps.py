"""Tiny WGS84 maps (GeoJSON and OSM XML) placed anywhere: a 3 x 3 street grid of 100 m blocks with a building."""

from __future__ import annotations

import json
import math
from pathlib import Path

HELSINKI = (24.94, 60.17)
MINNEAPOLIS = (-93.26, 44.98)


def _lonlat(place: tuple[float, float], x: float, y: float) -> list[float]:
    lon0, lat0 = place
    return [lon0 + x / (111_320.0 * math.cos(math.radians(lat0))), lat0 + y / 110_574.0]


def grid_lines(n: int = 3, spacing: float = 100.0) -> list[list[tuple[float, float]]]:
    ticks = [i * spacing for i in range(n)]
    return [[(x, y) for x in ticks] for y in ticks] + [[(x, y) for y in ticks] for x in ticks]


def geojson_map(tmp: Path, place: tuple[float, float], name: str = "town") -> Path:
    feats = [{"type": "Feature", "properties": {"network": "pedestrian,vehicle"},
              "geometry": {"type": "LineString", "coordinates": [_lonlat(place, x, y) for x, y in line]}}
             for line in grid_lines()]
    ring = [_lonlat(place, x, y) for x, y in ((10, 10), (60, 10), (60, 60), (10, 60), (10, 10))]
    feats.append({"type": "Feature", "properties": {"building": "yes", "height": "12"},
                  "geometry": {"type": "Polygon", "coordinates": [ring]}})
    path = tmp / f"{name}.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    return path


def osm_map(tmp: Path, place: tuple[float, float], name: str = "town", buildings: int = 0) -> Path:
    """The grid as OSM XML, with `buildings` small square buildings in a row along the first block."""
    out = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="test">']
    ids: dict[tuple[float, float], int] = {}
    ways = []
    squares = [[(12 + 8 * i + dx, 12 + dy) for dx, dy in ((0, 0), (5, 0), (5, 5), (0, 5))] for i in range(buildings)]
    for line in grid_lines() + squares:
        refs = []
        for pt in line:
            if pt not in ids:
                ids[pt] = len(ids) + 1
                lon, lat = _lonlat(place, *pt)
                out.append(f'<node id="{ids[pt]}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"/>')
            refs.append(ids[pt])
        ways.append(refs)
    for k, refs in enumerate(ways, start=1):
        nd = "".join(f'<nd ref="{r}"/>' for r in refs)
        tag = '<tag k="highway" v="residential"/>' if k <= len(grid_lines()) else '<tag k="building" v="yes"/>'
        if k > len(grid_lines()):
            nd += f'<nd ref="{refs[0]}"/>'
        out.append(f'<way id="{k}" version="1">{nd}{tag}</way>')
    out.append("</osm>")
    path = tmp / f"{name}.osm"
    path.write_text("\n".join(out))
    return path
