"""The topology build: map file -> cleaned network -> cells -> (PVS) -> artifact.

networkx and shapely are used here, at build time only; the result is compact numpy arrays.
"""

from __future__ import annotations

import time
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from topology import BUNDLED_MAP
from topology.artifact import CELL_AREA, CELL_JUNCTION, CELL_STREET, Topology
from topology.cells import CellParams, build_cells, cumulative
from topology.clean import CleanParams, Network, clean
from topology.polygons import Polygons
from topology.raw import RawMap

Progress = Callable[[str], None]


class BuildError(Exception):
    """The map cannot become a topology (no streets, unreadable input): a clear message for the user."""


@dataclass
class BuildConfig:
    """Every knob of a build in one place; the cleaning and cell parameters are recorded in the artifact's
    meta, so a build can be repeated."""
    clean: CleanParams = field(default_factory=CleanParams)
    cells: CellParams = field(default_factory=CellParams)
    crs: str | None = None
    #: build even where the CRS is wrong for the map's place (outside its area of use, lengths stretched):
    #: warn instead of refusing
    force_crs: bool = False
    #: a topology.pvs.PvsConfig, or None to skip the PVS
    pvs: Any = None


def read_map(path: str | Path | None, crs: str | None = None, bbox: tuple[float, ...] | None = None) -> RawMap:
    """Read OSM (.pbf, .osm, .osm.bz2) or GeoJSON (.geojson, .json) by extension; None = the bundled map.

    `bbox` (lon_min, lat_min, lon_max, lat_max) keeps only OSM features that meet it."""
    from topology.geojson_reader import read_geojson
    from topology.osm_reader import MapReadError, read_osm

    path = Path(path) if path is not None else BUNDLED_MAP
    if crs is not None:
        _check_metric(crs)  # before reading: degrees would only fail much later, and misleadingly
    try:
        if path.suffix.lower() in (".geojson", ".json"):
            if bbox is not None:
                raise BuildError("--bbox applies to OpenStreetMap input only")
            return read_geojson(path, crs)
        return read_osm(path, crs, bbox)
    except MapReadError as exc:
        raise BuildError(str(exc)) from None
    except ValueError as exc:
        raise BuildError(f"{path}: {exc}") from None


def _check_metric(crs: str) -> None:
    from topology.projection import CrsError, check_metric

    try:
        check_metric(crs)
    except CrsError as exc:
        raise BuildError(str(exc)) from None


def map_extent(raw: RawMap) -> tuple[float, float, float, float] | None:
    """(lon_min, lat_min, lon_max, lat_max) of the map's ways, areas and buildings, or None when it has none."""
    from topology.projection import LocalProjection

    boxes = [np.concatenate([np.asarray(w.xy).min(axis=0), np.asarray(w.xy).max(axis=0)]) for w in raw.ways
             if len(w.xy)]
    boxes += [np.asarray(f.polygon.bounds) for f in (*raw.areas, *raw.buildings) if not f.polygon.is_empty]
    if not boxes:
        return None
    b = np.asarray(boxes)
    x0, y0, x1, y1 = b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    ll = LocalProjection(raw.crs, tuple(raw.origin)).to_wgs84(corners)
    return float(ll[:, 0].min()), float(ll[:, 1].min()), float(ll[:, 0].max()), float(ll[:, 1].max())


def check_crs(raw: RawMap, force: bool = False, warn: Progress | None = None) -> None:
    """Refuse a map whose CRS is not projected in metres, and (unless `force`, which warns and counts it in the
    build report) one whose CRS is wrong for the map's place: outside its area of use or stretching lengths
    (EPSG:3067 on an American town made every length 9-26 % too long). A UTM zone that holds the map's centre
    or a corner (the readers' default) is not judged by its area of use: a town across a zone boundary is
    still well served by either zone."""
    from topology.projection import placement_problem, utm_crs_for

    _check_metric(raw.crs)
    extent = map_extent(raw)
    if extent is None:
        return
    lon0, lat0, lon1, lat1 = extent
    places = (((lon0 + lon1) / 2.0, (lat0 + lat1) / 2.0), (lon0, lat0), (lon1, lat0), (lon1, lat1), (lon0, lat1))
    for lon, lat in places:
        try:
            if raw.crs == utm_crs_for(lon, lat):
                return  # the UTM zone of (a part of) the map: what the reader chose, or as good
        except ValueError:
            pass  # beyond the UTM zones (polar): judge the CRS as any other
    problem = placement_problem(raw.crs, *extent)
    if problem is None:
        return
    if not force:
        raise BuildError(f"{problem}; choose a CRS made for this place (leave out --crs for the map's UTM "
                         "zone), or give --force to build anyway")
    raw.report["warning:crs_not_for_this_place"] += 1
    (warn or (lambda m: warnings.warn(m, stacklevel=3)))(f"{problem} (building anyway: --force)")


def build(raw: RawMap, config: BuildConfig | None = None, progress: Progress | None = None,
          source: str = "", warn: Progress | None = None) -> Topology:  # fmt: skip
    """`warn`: where CRS warnings go (default: `warnings.warn`)."""
    config = config or BuildConfig()
    say = progress or (lambda _msg: None)
    check_crs(raw, config.force_crs, warn)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    say(f"cleaning {len(raw.ways)} ways, {len(raw.areas)} areas")
    try:
        net = clean(raw, config.clean)
    except ValueError as exc:
        raise BuildError(str(exc)) from None
    timings["clean_s"] = time.perf_counter() - t0
    say(f"cleaned: {len(net.node_xy)} nodes, {len(net.edges)} edges; building cells")
    t1 = time.perf_counter()
    cells = build_cells(net, config.cells)
    timings["cells_s"] = time.perf_counter() - t1
    topo = _assemble(raw, net, cells, config, source)
    say(f"cells: {topo.n_cells}; matching {len(raw.routes)} transit routes")
    t2 = time.perf_counter()
    from topology.routes import build_routes

    way_xy = {w.way_id: np.asarray(w.xy) for w in raw.ways}
    topo.meta["routes"] = build_routes(topo, raw.routes, way_xy, net.report)
    timings["routes_s"] = time.perf_counter() - t2
    if config.pvs is not None:
        t3 = time.perf_counter()
        from topology.pvs import compute_pvs

        say("computing view cells and their PVS")
        try:
            result = compute_pvs(
                topo.building_footprints,
                topo.building_height,
                topo.cell_footprints,
                topo.cell_height,
                tuple(topo.meta["bounds"]),
                config.pvs,
                progress=say,
            )
        except ValueError as exc:  # settings the PVS refuses (too many view cells): one line, not a traceback
            raise BuildError(str(exc)) from None
        topo.extra.update(result.to_extra())
        pvs_meta = result.meta()
        stats = pvs_meta.get("stats", {})
        pvs_phases = {k: stats.pop(k) for k in list(stats) if k.endswith("_s")}  # volatile: not in the digest
        topo.meta["pvs"] = pvs_meta
        timings["pvs_s"] = time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0
    topo.meta["report"] = dict(sorted(net.report.items()))
    topo.meta["timings"] = {k: round(v, 3) for k, v in timings.items()}
    if config.pvs is not None:
        topo.meta["timings"]["pvs_phases"] = pvs_phases
    return topo


def _csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.zeros(len(lists) + 1, np.int64)
    offsets[1:] = np.cumsum([len(x) for x in lists])
    flat = np.fromiter((v for x in lists for v in x), np.int32, count=int(offsets[-1]))
    return offsets, flat


def _assemble(raw: RawMap, net: Network, cells, config: BuildConfig, source: str) -> Topology:
    n_nodes, n_edges = len(net.node_xy), len(net.edges)
    node_area = np.full(n_nodes, -1, np.int32)
    for i, a in enumerate(net.areas):
        node_area[a.node] = i
    inc: list[list[int]] = [[] for _ in range(n_nodes)]
    for i, e in enumerate(net.edges):
        inc[e.u].append(i)
        if e.v != e.u:
            inc[e.v].append(i)
    node_edge_offsets, node_edges = _csr(inc)
    geom_offsets = np.zeros(n_edges + 1, np.int64)
    geom_offsets[1:] = np.cumsum([len(e.xy) for e in net.edges])
    geom_xy = np.vstack([e.xy for e in net.edges]).astype(np.float64)
    geom_cum = np.concatenate([cumulative(e.xy) for e in net.edges])
    lengths = geom_cum[geom_offsets[1:] - 1]
    bp_offsets, _ = _csr([[0] * len(b) for b in cells.breakpoints])
    bp_start = np.fromiter(
        (s for b in cells.breakpoints for s, _ in b), np.float64, count=int(bp_offsets[-1])
    )
    bp_cell = np.fromiter((c for b in cells.breakpoints for _, c in b), np.int32, count=int(bp_offsets[-1]))
    cell_edge_offsets, cell_edges = _csr(cells.edges)
    cell_node_offsets, cell_nodes = _csr(cells.nodes)
    kind = np.asarray(cells.kind, np.uint8)
    area_cell = np.flatnonzero(kind == CELL_AREA).astype(np.int32)
    params = {
        "clean": asdict(config.clean),
        "cells": asdict(config.cells) | {"junction_radius_m": config.cells.radius},
    }
    meta: dict[str, Any] = {
        "crs": raw.crs,
        "origin": list(raw.origin),
        "bounds": list(raw.bounds),
        "source": source,
        "params": params,
        "counts": {
            "nodes": n_nodes,
            "edges": n_edges,
            "cells_street": int((kind == CELL_STREET).sum()),
            "cells_junction": int((kind == CELL_JUNCTION).sum()),
            "cells_area": int((kind == CELL_AREA).sum()),
            "areas": len(net.areas),
            "buildings": len(raw.buildings),
        },
        "area_kinds": [a.kind for a in net.areas],
        "area_names": [a.name for a in net.areas],
    }
    return Topology(
        meta=meta,
        node_xy=np.asarray(net.node_xy, np.float64).reshape(-1, 2),
        node_area=node_area,
        node_edge_offsets=node_edge_offsets,
        node_edges=node_edges,
        edge_nodes=np.asarray([(e.u, e.v) for e in net.edges], np.int32).reshape(-1, 2),
        edge_networks=np.asarray([e.networks for e in net.edges], np.uint8),
        edge_length=lengths,
        edge_geom_offsets=geom_offsets,
        edge_geom_xy=geom_xy,
        edge_geom_cum=geom_cum,
        edge_bp_offsets=bp_offsets,
        edge_bp_start=bp_start,
        edge_bp_cell=bp_cell,
        cell_kind=kind,
        cell_height=np.full(len(kind), config.cells.entity_height_m, np.float32),
        cell_footprints=Polygons.from_shapely(cells.footprints),
        cell_edge_offsets=cell_edge_offsets,
        cell_edges=cell_edges,
        cell_node_offsets=cell_node_offsets,
        cell_nodes=cell_nodes,
        area_node=np.asarray([a.node for a in net.areas], np.int32),
        area_cell=area_cell,
        area_networks=np.asarray([a.networks for a in net.areas], np.uint8),
        area_polygons=Polygons.from_shapely([a.polygon for a in net.areas]),
        building_height=np.asarray([b.height for b in raw.buildings], np.float32),
        building_footprints=Polygons.from_shapely([b.polygon for b in raw.buildings]),
    )


def report_lines(report: dict[str, int]) -> list[str]:
    """The build report grouped as read / repaired / dropped / skipped."""
    groups: dict[str, list[str]] = {}
    for key, n in sorted(report.items()):
        head, _, what = key.partition(":")
        groups.setdefault(head, []).append(f"  {what.replace('_', ' ')}: {n}")
    lines = []
    for head in ("read", "repaired", "dropped", "skipped"):
        if head in groups:
            lines.append(f"{head}:")
            lines.extend(groups.pop(head))
    for head, rest in groups.items():
        lines.append(f"{head}:")
        lines.extend(rest)
    return lines


def features_dropped(report: dict[str, int] | Counter) -> int:
    """How many map features the build skipped (the `dropped:*` counts of a build report)."""
    return int(sum(n for k, n in report.items() if k.startswith("dropped:")))
