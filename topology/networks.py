"""The network vocabulary shared by the builder and the run-time readers: network bits and a placement.

Why its own module, with no imports beyond the standard library: the client core, the switchboard and the
protocol need these few names, and importing them from the build-time modules (`topology.raw`,
`topology.placement_index`) would load shapely into every client and server.
"""

from __future__ import annotations

from typing import NamedTuple

# Network bits: an edge may belong to several networks (a residential street is walkable and drivable).
PEDESTRIAN = 1
VEHICLE = 2
TRAM = 4
NETWORK_NAMES = {PEDESTRIAN: "pedestrian", VEHICLE: "vehicle", TRAM: "tram"}


class Placement(NamedTuple):
    """kind "area": index = area, position = (x, y) inside it; kind "edge": index = edge, offset along it."""

    kind: str
    index: int
    offset: float
    x: float
    y: float
    distance: float
