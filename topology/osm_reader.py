"""Read OpenStreetMap data (PBF, XML, .osm.bz2) through pyosmium into the reader contract (`RawMap`).

Bad features are skipped and counted; only an unreadable file or one with no map data raises MapReadError.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import osmium
import shapely
from shapely.geometry import Polygon

from topology.projection import LocalProjection
from topology.raw import RawArea, RawBuilding, RawMap, RawRoute, RawStop, RawWay
from topology.tags import area_kind, building_height, parse_layer, way_networks

ROUTE_MODES = {"tram": "tram", "light_rail": "tram", "bus": "bus", "trolleybus": "bus"}
STOP_ROLES = {"stop", "stop_entry_only", "stop_exit_only"}
#: older (PTv1) routes list only their platforms; a platform node stands beside its stop and serves instead
PLATFORM_ROLES = {"platform", "platform_entry_only", "platform_exit_only"}
MIN_POLYGON_AREA_M2 = 1.0


class MapReadError(Exception):
    """The input is not readable map data (clear message for the user, no traceback)."""


def _is_stop_node(tags) -> bool:
    return (
        tags.get("public_transport") == "stop_position"
        or tags.get("railway") == "tram_stop"
        or tags.get("highway") == "bus_stop"
        or tags.get("public_transport") == "platform"
    )


class _Collector:
    """Collects features in WGS84; projection happens once at the end, vectorised."""

    def __init__(self) -> None:
        self.report: Counter = Counter()
        self.ways: list[tuple[int, np.ndarray, np.ndarray, dict]] = []  # id, lonlat, node ids, tags
        self.polys: list[tuple[str, int, Polygon, dict]] = []  # "area"/"building", id, lonlat polygon, tags
        self.routes: list[tuple[int, dict, list[int], list[int]]] = []  # id, tags, way ids, stop node ids
        self.node_lonlat: dict[int, tuple[float, float]] = {}
        self.node_names: dict[int, str] = {}
        # polygon candidates (buildings and areas), to count the ones osmium never assembles
        self.poly_ways: dict[int, tuple[str, str]] = {}  # way id -> (kind, why it cannot become a polygon)
        self.poly_rels: dict[int, tuple[str, list[int]]] = {}  # relation id -> (kind, member way ids)
        self.seen_ways: set[int] = set()
        self.incomplete_ways: set[int] = set()  # ways with a node missing from the extract
        self.built: set[tuple[bool, int]] = set()  # (from a way, original id) of every area osmium built
        # closed polygon ways with every node located, as lon/lat rings: what `repair_unassembled` rebuilds a
        # polygon from when osmium builds no ring (a self-intersecting way, the usual OSM case)
        self.poly_rings: dict[int, tuple[np.ndarray, dict]] = {}  # lon, lat of closed polygon ways not built yet

    def node(self, n) -> None:
        if n.tags and _is_stop_node(n.tags) and n.location.valid():
            self.node_lonlat[n.id] = (n.location.lon, n.location.lat)
            self.node_names[n.id] = n.tags.get("name", "")

    def way(self, w) -> None:
        tags = dict(w.tags)
        self.seen_ways.add(w.id)
        if any(not nr.location.valid() for nr in w.nodes):
            self.incomplete_ways.add(w.id)
        kind = _polygon_kind(tags)
        if kind is not None:
            why = _why_no_polygon(w)
            self.poly_ways[w.id] = (kind, why)
            if why == "not_assembled":
                # kept until osmium builds the area (then dropped): only self-intersecting ways stay
                self.poly_rings[w.id] = (np.array([(nr.location.lon, nr.location.lat) for nr in w.nodes]), tags)
        bits = way_networks(tags)
        if not bits:
            if "highway" in tags or "railway" in tags:
                self.report["skipped:not_a_modelled_network"] += 1
            return
        ids, coords = [], []
        for nr in w.nodes:
            if not nr.location.valid():
                self.report["repaired:missing_node_location"] += 1
                continue
            ids.append(nr.ref)
            coords.append((nr.location.lon, nr.location.lat))
        if len(ids) < 2:
            self.report["dropped:way_without_geometry"] += 1
            return
        lonlat = np.asarray(coords, np.float64)
        node_ids = np.asarray(ids, np.int64)
        for i, c in zip(ids, coords, strict=True):
            self.node_lonlat.setdefault(i, c)
        self.ways.append((w.id, lonlat, node_ids, tags))

    def relation(self, r) -> None:
        tags = dict(r.tags)
        if tags.get("type") in ("multipolygon", "boundary"):
            kind = _polygon_kind(tags)
            if kind is not None:
                self.poly_rels[r.id] = (kind, [m.ref for m in r.members if m.type == "w"])
            return
        if tags.get("type") != "route" or tags.get("route") not in ROUTE_MODES:
            return
        way_ids, stop_ids, platform_ids = [], [], []
        for m in r.members:
            if m.type == "w" and m.role in ("", "forward", "backward"):
                way_ids.append(m.ref)
            elif m.type == "n" and m.role in STOP_ROLES:
                stop_ids.append(m.ref)
            elif m.type == "n" and m.role in PLATFORM_ROLES:
                platform_ids.append(m.ref)
        stop_ids = stop_ids or platform_ids
        self.routes.append((r.id, tags, way_ids, stop_ids))

    def area(self, a) -> None:
        tags = dict(a.tags)
        is_building = ("building" in tags and tags.get("building") != "no") or "building:part" in tags
        akind = None if is_building else area_kind(tags)
        if not is_building and akind is None:
            return
        kind = "building" if is_building else "area"
        rings = 0
        try:
            for outer in a.outer_rings():
                rings += 1
                shell = [(n.lon, n.lat) for n in outer]
                holes = [[(n.lon, n.lat) for n in inner] for inner in a.inner_rings(outer)]
                self.polys.append((kind, a.orig_id(), Polygon(shell, holes), tags))
        except (osmium.InvalidLocationError, ValueError):
            self.report[f"dropped:{kind}_bad_geometry"] += 1
            return
        if rings:
            self.built.add((a.from_way(), a.orig_id()))
            if a.from_way():
                self.poly_rings.pop(a.orig_id(), None)
        elif not a.from_way():  # osmium could not close a ring (an open multipolygon)
            self.built.add((False, a.orig_id()))
            self.report[f"dropped:{kind}_no_rings"] += 1
        # (a closed way without rings is self-intersecting: `repair_unassembled` rebuilds it from its nodes)

    def repair_unassembled(self) -> None:
        """Buildings and areas that osmium never turned into an area: a closed way with every node located
        (osmium builds no ring for a self-intersecting one) becomes the polygon of its nodes, which
        `_valid_parts` makes valid (`shapely.make_valid`) and counts as repaired, or drops as degenerate
        when nothing of it has an area; the others are dropped and counted by why."""
        for wid, (kind, why) in self.poly_ways.items():
            if (True, wid) in self.built:
                continue
            ring = self.poly_rings.get(wid)
            if ring is not None:
                self.polys.append((kind, wid, Polygon(ring[0]), ring[1]))
                continue
            self.report[f"dropped:{kind}_{why}"] += 1
        for rid, (kind, members) in self.poly_rels.items():
            if (False, rid) not in self.built:
                missing = not members or any(m not in self.seen_ways or m in self.incomplete_ways
                                             for m in members)
                self.report[f"dropped:{kind}_relation_members_missing" if missing
                            else f"dropped:{kind}_relation_not_assembled"] += 1


def _polygon_kind(tags: dict) -> str | None:
    """"building", "area" or None: the tags that `_Collector.area` keeps."""
    if ("building" in tags and tags.get("building") != "no") or "building:part" in tags:
        return "building"
    return "area" if area_kind(tags) is not None else None


def _why_no_polygon(w) -> str:
    """Why a polygon way would not become an area (checked only when osmium builds none from it)."""
    nodes = w.nodes
    if len(nodes) < 2:
        return "one_node_way"
    if any(not nr.location.valid() for nr in nodes):
        return "missing_node_location"
    if len(nodes) < 4 or nodes[0].ref != nodes[-1].ref:
        return "way_not_closed"
    return "not_assembled"


def read_osm(
    path: str | Path, crs: str | None = None, bbox: tuple[float, float, float, float] | None = None
) -> RawMap:
    """Read an OSM file into a projected RawMap. `bbox` = (lon_min, lat_min, lon_max, lat_max) keeps only
    features that intersect it (others are counted as dropped:outside_bbox)."""
    path = Path(path)
    if not path.is_file():
        raise MapReadError(f"{path}: no such file")
    col = _Collector()
    try:
        fp = osmium.FileProcessor(str(path)).with_locations().with_areas()
        for obj in fp:
            if obj.is_node():
                col.node(obj)
            elif obj.is_way():
                col.way(obj)
            elif obj.is_relation():
                col.relation(obj)
            elif obj.is_area():
                col.area(obj)
    except RuntimeError as exc:
        raise MapReadError(f"{path}: not readable OpenStreetMap data ({exc})") from None
    col.repair_unassembled()
    if not col.ways and not col.polys:
        raise MapReadError(f"{path}: no streets, areas or buildings found (is this OpenStreetMap data?)")
    return _assemble(col, crs, bbox)


def _assemble(col: _Collector, crs: str | None, bbox) -> RawMap:
    report = col.report
    # extent: from the centrelines (what entities use), else from the polygons
    if col.ways:
        allc = np.concatenate([w[1] for w in col.ways])
    else:
        allc = np.concatenate([np.asarray(p[2].exterior.coords) for p in col.polys if not p[2].is_empty])
    lon_min, lat_min = allc.min(axis=0)
    lon_max, lat_max = allc.max(axis=0)
    if bbox is not None:
        lon_min, lat_min, lon_max, lat_max = bbox
    proj = LocalProjection.for_extent(lon_min, lat_min, lon_max, lat_max, crs)
    box = shapely.box(lon_min, lat_min, lon_max, lat_max)

    raw = RawMap(crs=proj.crs, origin=proj.origin, report=report)
    kept_ways: set[int] = set()
    for way_id, lonlat, node_ids, tags in col.ways:
        if bbox is not None and not box.intersects(shapely.LineString(lonlat)):
            report["dropped:outside_bbox"] += 1
            continue
        kept_ways.add(way_id)
        raw.ways.append(
            RawWay(
                way_id=way_id,
                xy=proj.to_local(lonlat[:, 0], lonlat[:, 1]),
                node_ids=node_ids,
                networks=way_networks(tags),
                layer=parse_layer(tags),
                bridge=tags.get("bridge", "no") not in ("no", ""),
                tunnel=tags.get("tunnel", "no") not in ("no", "", "building_passage"),
                name=tags.get("name", ""),
                highway=tags.get("highway", tags.get("railway", "")),
            )
        )
    report["read:ways"] += len(raw.ways)

    def project_polygon(poly: Polygon):
        return shapely.transform(poly, lambda c: proj.to_local(c[:, 0], c[:, 1]))

    part_flags: list[bool] = []
    for kind, fid, poly, tags in col.polys:
        if bbox is not None and not box.intersects(poly):
            report["dropped:outside_bbox"] += 1
            continue
        for part in _valid_parts(project_polygon(poly), report, kind):
            if kind == "building":
                if _min_height(tags) > 2.0:
                    report["dropped:building_part_above_ground"] += 1
                    continue
                height, source = building_height(tags)
                if "bad height" in source:
                    report["repaired:unparsable_height"] += 1
                report[f"read:building_height_from_{source.split('(')[0]}"] += 1
                raw.buildings.append(RawBuilding(fid, part, height, source))
                part_flags.append("building:part" in tags)
            else:
                akind, bits = area_kind(tags)
                raw.areas.append(RawArea(fid, part, akind, bits, tags.get("name", "")))
    raw.buildings = _outlines_replaced_by_parts(raw.buildings, part_flags, report)
    report["read:buildings"] += len(raw.buildings)
    report["read:areas"] += len(raw.areas)

    for rel_id, tags, way_ids, stop_ids in col.routes:
        present = [w for w in way_ids if w in kept_ways]
        if not present:
            report["dropped:route_outside_map"] += 1
            continue
        if len(present) < len(way_ids):
            report["repaired:route_clipped_to_map"] += 1
        stops = []
        for sid in stop_ids:
            if sid in col.node_lonlat:
                lon, lat = col.node_lonlat[sid]
                xy = proj.to_local(np.array([lon]), np.array([lat]))[0]
                stops.append(RawStop(sid, (float(xy[0]), float(xy[1])), col.node_names.get(sid, "")))
        raw.routes.append(
            RawRoute(
                rel_id, ROUTE_MODES[tags["route"]], tags.get("ref", ""), tags.get("name", ""), present, stops
            )
        )
    report["read:routes"] += len(raw.routes)

    corners = proj.to_local(np.array([lon_min, lon_max]), np.array([lat_min, lat_max]))
    raw.bounds = (float(corners[0, 0]), float(corners[0, 1]), float(corners[1, 0]), float(corners[1, 1]))
    return raw


def _outlines_replaced_by_parts(buildings: list[RawBuilding], is_part: list[bool], report: Counter):
    """A building outline that holds building:part polygons is drawn by its parts (the OSM 3D rule): keep the
    parts, whose heights are specific, and drop the outline with its coarser height."""
    parts = [b.polygon.representative_point() for b, p in zip(buildings, is_part, strict=True) if p]
    if not parts:
        return buildings
    tree = shapely.STRtree(np.array(parts, dtype=object))
    kept = []
    for b, p in zip(buildings, is_part, strict=True):
        if not p and len(tree.query(b.polygon, predicate="contains")):
            report["repaired:outline_replaced_by_parts"] += 1
            continue
        kept.append(b)
    return kept


def _min_height(tags: dict) -> float:
    try:
        return float(tags.get("min_height", "0").replace(",", ".").rstrip(" m"))
    except ValueError:
        return 0.0


def _valid_parts(poly, report: Counter, kind: str) -> list[Polygon]:
    """Repair invalid polygons (bow-ties, self-touching rings) and split multipolygons into parts. A repair
    is counted when something with an area is left of it (`repaired:<kind>_invalid_polygon`); a polygon with
    nothing left (a ring of collinear points) is dropped and counted as degenerate."""
    if poly.is_empty:
        report[f"dropped:{kind}_empty"] += 1
        return []
    repaired = not poly.is_valid
    if repaired:
        poly = shapely.make_valid(poly)
    parts = [g for g in getattr(poly, "geoms", [poly]) if g.geom_type == "Polygon"]
    for g in getattr(poly, "geoms", []):
        if g.geom_type == "MultiPolygon":
            parts.extend(g.geoms)
    kept = [p for p in parts if p.area >= MIN_POLYGON_AREA_M2]
    if len(kept) < len(parts) or not parts:
        report[f"dropped:{kind}_degenerate_polygon"] += max(1, len(parts) - len(kept))
    if repaired and kept:
        report[f"repaired:{kind}_invalid_polygon"] += 1
    return kept
