"""The topology artifact: one versioned file loaded by clients, servers, proxies and simulations.

Layout: an uncompressed `.npz` (numpy arrays, memory-friendly and fast to load) whose `meta` entry is UTF-8
JSON. Everything is run-time ready: CSR incidence lists, edge polylines with cumulative lengths, per-edge
sorted cell breakpoints, ragged polygons. The content digest (sha256 over meta and every array) is stored in
the meta and checked on load; clients and servers compare it in the protocol handshake.

Coordinates are metres in `meta["crs"]`, relative to `meta["origin"]` (so they stay small in float64).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from topology.polygons import Polygons

FORMAT = "entitynet-topology"
FORMAT_VERSION = 1

CELL_STREET, CELL_JUNCTION, CELL_AREA = 0, 1, 2
CELL_KIND_NAMES = {CELL_STREET: "street", CELL_JUNCTION: "junction", CELL_AREA: "area"}


class ArtifactError(Exception):
    """The file is not a topology artifact, is of another version, or is corrupt."""


@dataclass
class Topology:
    """The loaded artifact: numpy arrays only (CSR incidence lists, polylines, cell breakpoints), so that
    clients and servers query it without shapely or networkx (placement builds its index lazily)."""
    meta: dict[str, Any]
    # nodes
    node_xy: np.ndarray  # (N, 2) float64
    node_area: np.ndarray  # (N,) int32: area index, or -1 for a street node
    node_edge_offsets: np.ndarray  # (N+1,) int64, CSR node -> incident edges
    node_edges: np.ndarray  # int32
    # edges
    edge_nodes: np.ndarray  # (E, 2) int32: from-node, to-node (offset 0 is at from-node)
    edge_networks: np.ndarray  # (E,) uint8 bitmask of topology.raw.PEDESTRIAN | VEHICLE | TRAM
    edge_length: np.ndarray  # (E,) float64
    edge_geom_offsets: np.ndarray  # (E+1,) int64 into edge_geom_xy / edge_geom_cum
    edge_geom_xy: np.ndarray  # (P, 2) float64 polyline vertices
    edge_geom_cum: np.ndarray  # (P,) float64 distance along the edge at each vertex
    # per-edge cell breakpoints: pieces of edge e are bp_offsets[e]:bp_offsets[e+1];
    # piece k starts at edge_bp_start[k] (the first at 0.0) and lies in cell edge_bp_cell[k]
    edge_bp_offsets: np.ndarray  # (E+1,) int64
    edge_bp_start: np.ndarray  # float64
    edge_bp_cell: np.ndarray  # int32
    # cells
    cell_kind: np.ndarray  # (C,) uint8 CELL_*
    cell_height: np.ndarray  # (C,) float32 extrusion height (the tallest entity)
    cell_footprints: Polygons
    cell_edge_offsets: np.ndarray  # (C+1,) int64, CSR cell -> edges
    cell_edges: np.ndarray  # int32
    cell_node_offsets: np.ndarray  # (C+1,) int64, CSR cell -> nodes
    cell_nodes: np.ndarray  # int32
    # areas
    area_node: np.ndarray  # (A,) int32
    area_cell: np.ndarray  # (A,) int32
    area_networks: np.ndarray  # (A,) uint8
    area_polygons: Polygons
    # buildings (occluders)
    building_height: np.ndarray  # (B,) float32
    building_footprints: Polygons
    # optional extra arrays (PVS and later additions), by name
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    # ---- sizes -------------------------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        """Network nodes, street and area nodes together."""
        return len(self.node_xy)

    @property
    def n_edges(self) -> int:
        """Network edges."""
        return len(self.edge_nodes)

    @property
    def n_cells(self) -> int:
        """Visibility cells; cell ids are 0..n_cells-1 and are the ids used on the wire."""
        return len(self.cell_kind)

    @property
    def digest(self) -> str:
        """The content digest that clients and servers compare in the handshake."""
        return self.meta["digest"]

    @property
    def routes(self) -> list[dict[str, Any]]:
        """Transit routes: {id, mode, ref, name, edges: [[edge, +1|-1], ...], stops: [{name, edge, offset}]},
        each a connected path; a route stored in pieces has one entry per piece with the same id and `part`."""
        return self.meta.get("routes", [])

    # ---- run-time queries (pure numpy, no shapely) --------------------------------------------------------
    def edges_of_node(self, node: int) -> np.ndarray:
        """Edges incident to `node` (a view into the CSR array: do not modify)."""
        return self.node_edges[self.node_edge_offsets[node] : self.node_edge_offsets[node + 1]]

    def edge_polyline(self, edge: int) -> np.ndarray:
        """The (n, 2) vertices of `edge`, from its from-node (offset 0) to its to-node (a view)."""
        return self.edge_geom_xy[self.edge_geom_offsets[edge] : self.edge_geom_offsets[edge + 1]]

    def cell_at(self, edge: int, offset: float) -> int:
        """The cell holding `offset` metres along `edge` (clamped to the edge): one binary search."""
        lo, hi = self.edge_bp_offsets[edge], self.edge_bp_offsets[edge + 1]
        k = int(np.searchsorted(self.edge_bp_start[lo:hi], offset, side="right")) - 1
        return int(self.edge_bp_cell[lo + max(k, 0)])

    def cell_pieces(self, edge: int) -> tuple[np.ndarray, np.ndarray]:
        """(starts, cells) of the pieces of `edge`; piece k spans [starts[k], starts[k+1] or length)."""
        lo, hi = self.edge_bp_offsets[edge], self.edge_bp_offsets[edge + 1]
        return self.edge_bp_start[lo:hi], self.edge_bp_cell[lo:hi]

    def point_at(self, edge: int, offset: float) -> np.ndarray:
        """The (x, y) point `offset` metres along `edge` (clamped to [0, length])."""
        lo, hi = self.edge_geom_offsets[edge], self.edge_geom_offsets[edge + 1]
        cum = self.edge_geom_cum[lo:hi]
        xy = self.edge_geom_xy[lo:hi]
        s = min(max(float(offset), 0.0), float(cum[-1]))
        k = int(np.searchsorted(cum, s, side="right")) - 1
        k = min(max(k, 0), len(cum) - 2)
        seg = cum[k + 1] - cum[k]
        t = 0.0 if seg <= 0.0 else (s - cum[k]) / seg
        return xy[k] + t * (xy[k + 1] - xy[k])

    def cell_edges_of(self, cell: int) -> np.ndarray:
        """The edges that pass through `cell` (a view), e.g. to tell which networks a cell serves."""
        return self.cell_edges[self.cell_edge_offsets[cell] : self.cell_edge_offsets[cell + 1]]

    def cell_nodes_of(self, cell: int) -> np.ndarray:
        """The nodes inside `cell`: a junction's crossings, an area's node (a view)."""
        return self.cell_nodes[self.cell_node_offsets[cell] : self.cell_node_offsets[cell + 1]]

    # ---- placement index (built lazily: shapely is only needed for the first fix of an entity) ----------
    _placement: Any = field(default=None, repr=False, compare=False)

    def placement_index(self):
        """The shapely STRtree placement index (areas first, else nearest edge), built on first use."""
        if self._placement is None:
            from topology.placement_index import PlacementIndex

            self._placement = PlacementIndex(self)
        return self._placement


_ARRAY_FIELDS = [
    "node_xy", "node_area", "node_edge_offsets", "node_edges",
    "edge_nodes", "edge_networks", "edge_length", "edge_geom_offsets", "edge_geom_xy", "edge_geom_cum",
    "edge_bp_offsets", "edge_bp_start", "edge_bp_cell",
    "cell_kind", "cell_height", "cell_edge_offsets", "cell_edges", "cell_node_offsets", "cell_nodes",
    "area_node", "area_cell", "area_networks", "building_height",
]  # fmt: skip
_POLYGON_FIELDS = ["cell_footprints", "area_polygons", "building_footprints"]


def _arrays_of(topo: Topology) -> dict[str, np.ndarray]:
    arrays = {name: np.ascontiguousarray(getattr(topo, name)) for name in _ARRAY_FIELDS}
    for name in _POLYGON_FIELDS:
        poly: Polygons = getattr(topo, name)
        arrays[f"{name}.ring_offsets"] = poly.ring_offsets
        arrays[f"{name}.coord_offsets"] = poly.coord_offsets
        arrays[f"{name}.xy"] = poly.xy
    for name, arr in topo.extra.items():
        arrays[f"extra.{name}"] = np.ascontiguousarray(arr)
    return arrays


def compute_digest(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> str:
    """sha256 over the meta (less digest and timings) and every array's name, dtype, shape and bytes: two
    builds of one map share a digest, any change of content gives another."""
    h = hashlib.sha256()
    # timings say how long this build took, not what the artifact holds: two builds of one map share a digest
    body = {k: v for k, v in meta.items() if k not in ("digest", "timings")}
    h.update(json.dumps(body, sort_keys=True, separators=(",", ":")).encode())
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{arr.dtype.str}:{arr.shape}".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def save(topo: Topology, path: str | os.PathLike) -> str:
    """Write the artifact atomically; returns (and stores in meta) its content digest."""
    arrays = _arrays_of(topo)
    topo.meta["format"] = FORMAT
    topo.meta["format_version"] = FORMAT_VERSION
    topo.meta["digest"] = compute_digest(topo.meta, arrays)
    buf = io.BytesIO()
    meta_bytes = np.frombuffer(json.dumps(topo.meta, sort_keys=True).encode(), dtype=np.uint8)
    np.savez(buf, meta=meta_bytes, **arrays)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buf.getvalue())
    os.replace(tmp, path)
    return topo.meta["digest"]


def load(path: str | os.PathLike, verify: bool = True) -> Topology:
    """Read an artifact; raises ArtifactError with a clear message for anything that is not one."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {name: npz[name] for name in npz.files}
    except FileNotFoundError:
        raise ArtifactError(f"{path}: no such file") from None
    except Exception as exc:  # zipfile.BadZipFile, ValueError, OSError...
        raise ArtifactError(f"{path}: not a topology artifact ({exc.__class__.__name__}: {exc})") from None
    if "meta" not in data:
        raise ArtifactError(f"{path}: not a topology artifact (no meta)")
    try:
        meta = json.loads(data.pop("meta").tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ArtifactError(f"{path}: corrupt meta ({exc})") from None
    if meta.get("format") != FORMAT:
        raise ArtifactError(f"{path}: not a topology artifact (format {meta.get('format')!r})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ArtifactError(
            f"{path}: artifact version {meta.get('format_version')} but this entitynet reads version "
            f"{FORMAT_VERSION}; rebuild it with `entitynet topology build`"
        )
    if verify and compute_digest(meta, data) != meta.get("digest"):
        raise ArtifactError(f"{path}: content digest mismatch (file corrupt or edited)")
    try:
        kwargs: dict[str, Any] = {name: data[name] for name in _ARRAY_FIELDS}
        for name in _POLYGON_FIELDS:
            kwargs[name] = Polygons(
                data[f"{name}.ring_offsets"], data[f"{name}.coord_offsets"], data[f"{name}.xy"]
            )
    except KeyError as exc:
        raise ArtifactError(f"{path}: missing array {exc}") from None
    extra = {k[len("extra.") :]: v for k, v in data.items() if k.startswith("extra.")}
    return Topology(meta=meta, extra=extra, **kwargs)
