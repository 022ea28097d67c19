"""The reader contract: what every map reader (OSM, GeoJSON) hands to the cleaning step.

Coordinates are already projected to the metric CRS, relative to the local origin, float64.
Readers skip bad features and count them in `report`; they never raise for one bad feature.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from shapely.geometry import Polygon

# the network bits live in the shapely-free topology.networks; re-exported here for the readers
from topology.networks import NETWORK_NAMES as NETWORK_NAMES
from topology.networks import PEDESTRIAN as PEDESTRIAN
from topology.networks import TRAM as TRAM
from topology.networks import VEHICLE as VEHICLE


@dataclass
class RawWay:
    """One street/rail centreline as read: vertex coordinates (n, 2) and the source node ids per vertex.

    `node_ids` lets the cleaner join ways at shared OSM nodes; readers without ids (GeoJSON) give
    negative synthetic ids, and the cleaner then joins by coincident coordinates.
    """

    way_id: int
    xy: np.ndarray
    node_ids: np.ndarray
    networks: int
    layer: int = 0
    bridge: bool = False
    tunnel: bool = False
    name: str = ""
    highway: str = ""


@dataclass
class RawArea:
    """A walkable/drivable area (square, pedestrian area, park, parking lot): one area node and one area cell."""

    area_id: int
    polygon: Polygon
    kind: str
    networks: int
    name: str = ""


@dataclass
class RawBuilding:
    """An occluder: footprint and height in metres; `height_source` says how the height was found."""

    building_id: int
    polygon: Polygon
    height: float
    height_source: str


@dataclass
class RawStop:
    """A stop of a transit route relation, projected, so that routes can place their stops on edges."""
    stop_id: int
    xy: tuple[float, float]
    name: str = ""


@dataclass
class RawRoute:
    """A transit route relation: ordered member ways (ids into RawWay.way_id) and ordered stops."""

    route_id: int
    mode: str
    ref: str
    name: str
    way_ids: list[int]
    stops: list[RawStop]


@dataclass
class RawMap:
    """Everything one reader produced, in local metres: the cleaner's input, with the feature counts that
    become the build report."""
    crs: str
    origin: tuple[float, float]
    ways: list[RawWay] = field(default_factory=list)
    areas: list[RawArea] = field(default_factory=list)
    buildings: list[RawBuilding] = field(default_factory=list)
    routes: list[RawRoute] = field(default_factory=list)
    #: feature counts "dropped:<why>" / "repaired:<why>" / "read:<what>"
    report: Counter = field(default_factory=Counter)
    #: map bounding box in local coordinates (xmin, ymin, xmax, ymax)
    bounds: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
