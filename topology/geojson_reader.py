"""Read GeoJSON map data into the reader contract (`RawMap`).

- Streets: LineString / MultiLineString features with a `network` property ("pedestrian", "vehicle", "tram",
  a list of those, or "pedestrian,vehicle"), or OSM-style `highway` / `railway` properties; optional `layer`.
- Areas: Polygon / MultiPolygon features with an `area` property (square, park, parking, pedestrian, ...),
  or OSM-style tags that make an area.
- Buildings: Polygon / MultiPolygon features with a `building` property or a `height`; heights are parsed like
  OSM heights ("12.13 m", "3,5"; "tall" falls back to the default and is counted).
Coordinates are WGS84 (RFC 7946) unless the legacy top-level `crs` member names a projected CRS, which tests use
to write fixtures directly in metres. Vertices shared by coordinates (to the millimetre) join ways.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon, shape

from topology.osm_reader import MapReadError, _valid_parts
from topology.projection import LocalProjection
from topology.raw import NETWORK_NAMES, RawArea, RawBuilding, RawMap, RawWay
from topology.tags import area_kind, building_height, parse_layer, way_networks

_NETWORK_BITS = {name: bit for bit, name in NETWORK_NAMES.items()}


def _network_bits(props: dict) -> int:
    net = props.get("network")
    if net is None:
        return way_networks({k: str(v) for k, v in props.items() if v is not None})
    names = net if isinstance(net, list) else str(net).replace(";", ",").split(",")
    bits = 0
    for name in names:
        bits |= _NETWORK_BITS.get(str(name).strip().lower(), 0)
    return bits


def read_geojson(path: str | Path, crs: str | None = None) -> RawMap:
    """Read a GeoJSON file; a missing or non-GeoJSON file is a MapReadError (one clear message), bad
    features are skipped and counted."""
    path = Path(path)
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MapReadError(f"{path}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapReadError(f"{path}: not GeoJSON ({exc})") from None
    if (
        not isinstance(doc, dict)
        or doc.get("type") != "FeatureCollection"
        or not isinstance(doc.get("features"), list)
    ):
        raise MapReadError(f"{path}: not a GeoJSON FeatureCollection")
    return geojson_to_raw(doc, crs)


def geojson_to_raw(doc: dict, crs: str | None = None) -> RawMap:
    """A parsed FeatureCollection as a RawMap in local metres; apart from reading so that tests can
    pass documents directly."""
    report: Counter = Counter()
    source_crs = ((doc.get("crs") or {}).get("properties") or {}).get("name")
    lines: list[tuple[int, np.ndarray, dict]] = []
    polys: list[tuple[int, Polygon, dict]] = []
    for fid, feat in enumerate(doc["features"]):
        try:
            geom = shape(feat["geometry"])
            props = dict(feat.get("properties") or {})
        except Exception:
            report["dropped:malformed_feature"] += 1
            continue
        if geom.is_empty:
            report["dropped:empty_geometry"] += 1
            continue
        coords = shapely.get_coordinates(geom)
        if not np.all(np.isfinite(coords)):
            report["dropped:non_finite_coordinates"] += 1
            continue
        if geom.geom_type in ("LineString", "MultiLineString"):
            for part in getattr(geom, "geoms", [geom]):
                lines.append((fid, np.asarray(part.coords, np.float64)[:, :2], props))
        elif geom.geom_type in ("Polygon", "MultiPolygon"):
            for part in getattr(geom, "geoms", [geom]):
                polys.append((fid, part, props))
        else:
            report[f"skipped:{geom.geom_type}"] += 1
    if not lines and not polys:
        raise MapReadError("no streets, areas or buildings in the GeoJSON")

    allc = np.concatenate([c for _, c, _ in lines] or [np.asarray(p.exterior.coords) for _, p, _ in polys])
    lo, hi = allc.min(axis=0), allc.max(axis=0)
    if source_crs:
        if crs and crs != source_crs:
            raise MapReadError(f"GeoJSON is in {source_crs}; reprojection to {crs} is not supported")
        origin = (float(round((lo[0] + hi[0]) / 2)), float(round((lo[1] + hi[1]) / 2)))
        proj = LocalProjection(source_crs, origin)

        def to_local(c: np.ndarray) -> np.ndarray:
            return c[:, :2] - np.asarray(origin)
    else:
        if lo[1] < -90 or hi[1] > 90 or lo[0] < -180 or hi[0] > 180:
            raise MapReadError("coordinates are not WGS84 longitude/latitude (set the GeoJSON 'crs' member)")
        proj = LocalProjection.for_extent(lo[0], lo[1], hi[0], hi[1], crs)

        def to_local(c: np.ndarray) -> np.ndarray:
            return proj.to_local(c[:, 0], c[:, 1])

    raw = RawMap(crs=proj.crs, origin=proj.origin, report=report)
    vertex_ids: dict[tuple[int, int], int] = {}
    for fid, coords, props in lines:
        bits = _network_bits(props)
        if not bits:
            report["skipped:line_without_network"] += 1
            continue
        xy = to_local(coords)
        keys = [(int(math.floor(x * 1000 + 0.5)), int(math.floor(y * 1000 + 0.5))) for x, y in xy]
        ids = np.asarray([vertex_ids.setdefault(k, -1 - len(vertex_ids)) for k in keys], np.int64)
        raw.ways.append(
            RawWay(
                way_id=fid,
                xy=xy,
                node_ids=ids,
                networks=bits,
                layer=parse_layer({"layer": str(props.get("layer", 0))}),
                bridge=bool(props.get("bridge")),
                tunnel=bool(props.get("tunnel")),
                name=str(props.get("name", "")),
            )
        )
    for fid, poly, props in polys:
        local = shapely.transform(poly, to_local)
        str_props = {k: str(v) for k, v in props.items() if v is not None}
        is_building = "building" in props or "height" in props
        akind = None
        if not is_building:
            if "area" in props and props["area"] not in ("yes",):
                akind = (str(props["area"]), _network_bits(props) or 1)
            else:
                akind = area_kind(str_props)
            if akind is None:
                report["skipped:polygon_without_kind"] += 1
                continue
        for part in _valid_parts(local, report, "building" if is_building else "area"):
            if is_building:
                height, source = building_height(str_props)
                if "bad height" in source:
                    report["repaired:unparsable_height"] += 1
                raw.buildings.append(RawBuilding(fid, part, height, source))
            else:
                raw.areas.append(RawArea(fid, part, akind[0], akind[1], str(props.get("name", ""))))
    report["read:ways"] += len(raw.ways)
    report["read:areas"] += len(raw.areas)
    report["read:buildings"] += len(raw.buildings)
    all_local = to_local(allc)
    raw.bounds = (*map(float, all_local.min(axis=0)), *map(float, all_local.max(axis=0)))
    return raw
