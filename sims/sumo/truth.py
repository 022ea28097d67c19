"""The truth of a SUMO scenario as the fleet and the measure read it (`sims.engine.source.Truth`).

Positions arrive from SUMO each step in our local coordinates (the source converts them). What our own world
knows from its routes, the true cells of a body, is found here by placing the true position on our network,
vectorised over every entity at once and only when asked (the measure samples once a second): inside an area
of the entity's networks its area cell, else the cell of the nearest edge of its networks at the projected
offset; a vehicle's body adds the cells under its back end (and a tram's articulation), placed the same way,
the body lying straight behind the front along SUMO's heading.

A position farther than `OFF_STREET_M` from every edge of the entity's networks (and in no area) is *off our
network*: a SUMO lane our topology does not have, a person inside a building. It is still fed to the honest
client as a phone's fix (the client's own placement decides what to publish, and refuses fixes farther than
its `off_network` distance), its true cells are those of the nearest street, and it is counted in the report
(entity-samples, and the share beyond the client's 60 m).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from entitynet.client import entity_type, netview
from topology.networks import PEDESTRIAN, TRAM, VEHICLE

#: metres from the nearest edge of its networks beyond which a true position counts as off our network (a
#: street cell is as wide as the widest street; a lane of a wide street lies within this of its centreline)
OFF_STREET_M = 15.0
#: the honest client's default distance beyond which it refuses a fix as off the network (Player.off_network)
CLIENT_OFF_NETWORK_M = 60.0


class SumoEntity:
    """One SUMO vehicle or person as an entity: its type, its body and where its front is now."""

    __slots__ = ("id", "sumo_id", "etype", "parts", "world", "x", "y", "heading", "stops", "label", "route")

    def __init__(self, world: SumoWorld, eid: int, sumo_id: str, name: str, length: float):
        self.world = world
        self.id = eid
        self.sumo_id = sumo_id
        base = entity_type(name)
        # a tram's length gives its parts (two equal halves, as our two-part tram); a car's or bus's one part
        if base.parts and length > 0:
            n = len(base.parts)
            self.parts = tuple([length / n] * n)
        else:
            self.parts = base.parts
        self.etype = base if self.parts == base.parts else _with_parts(base, self.parts)
        self.x = self.y = 0.0
        self.heading = 0.0  # radians, counter-clockwise from +x
        self.stops: list = []  # no route known a priori: the client places itself from its fixes alone
        self.label = ""
        self.route = None

    @property
    def name(self) -> str:
        """The client core's entity type name."""
        return self.etype.name

    @property
    def length(self) -> float:
        """Body length behind the front (0 for a pedestrian or cyclist)."""
        return float(sum(self.parts))

    def xy(self, behind: float = 0.0) -> tuple[float, float]:
        """Local (x, y) of the front, or `behind` metres behind it along the heading."""
        if behind == 0.0:
            return self.x, self.y
        return self.x - behind * math.cos(self.heading), self.y - behind * math.sin(self.heading)

    def part_points(self) -> list[tuple[float, float]]:
        """The front, then the end of each body part."""
        pts = [self.xy()]
        acc = 0.0
        for p in self.parts:
            acc += p
            pts.append(self.xy(acc))
        return pts

    def cells(self) -> tuple[int, ...]:
        """The cells the true body occupies now, placed on our network (computed for every entity at once)."""
        return self.world.cells_of(self.id)


def _with_parts(base, parts: tuple[float, ...]):
    from dataclasses import replace

    return replace(base, parts=parts)


class SumoWorld:
    """The live SUMO entities, the clock and the counters (see the module docstring)."""

    def __init__(self, topo, start: float):
        self.topo = topo
        self.net = netview(topo)
        self.now = start
        self.agents: dict[int, SumoEntity] = {}
        self.counters: Counter = Counter()
        self.stop_lateness: list[float] = []  # SUMO's vehicles keep no timetable of ours: none measured
        self.removed: list[tuple[int, str]] = []
        self._cells: dict[int, tuple[int, ...]] | None = None  # this step's true cells, when asked
        self.off = Counter()  # entity-samples placed: "samples", "off_street", "beyond_client"

    def add(self, e: SumoEntity) -> None:
        """A new entity (appeared in SUMO this step)."""
        self.agents[e.id] = e
        self.counters["spawned"] += 1
        self.counters[f"spawned:{e.name}"] += 1

    def remove(self, eid: int, why: str) -> None:
        """An entity gone from SUMO (arrived, teleported away, boarded a vehicle), counted under `why`."""
        if self.agents.pop(eid, None) is not None:
            self.removed.append((eid, why))
            self.counters[why] += 1

    def moved(self, now: float) -> None:
        """The positions of this step are in: the clock moves and the cells are placed afresh when asked."""
        self.now = now
        self._cells = None

    def take_removed(self) -> list[tuple[int, str]]:
        """The (id, why) removed since the last call, once."""
        out, self.removed = self.removed, []
        return out

    def by_type(self) -> Counter:
        """Live entities counted by type name."""
        return Counter(a.name for a in self.agents.values())

    def cells_of(self, eid: int) -> tuple[int, ...]:
        """The true cells of entity `eid` this step (every entity placed in one vectorised pass)."""
        if self._cells is None:
            self._cells = self.place_all()
        return self._cells.get(eid, ())

    def place_all(self) -> dict[int, tuple[int, ...]]:
        """Place every live entity's body on our network (module docstring); counts off-network fronts."""
        ents = list(self.agents.values())
        if not ents:
            return {}
        pts, owner, nets = [], [], []
        for i, e in enumerate(ents):
            for p in e.part_points():
                pts.append(p)
                owner.append(i)
                nets.append(e.etype.networks)
        cells, dist, fronts = place_points(self.topo, np.asarray(pts, np.float64), np.asarray(nets))
        out: dict[int, list[int]] = {}
        first = np.ones(len(pts), bool)
        first[1:] = np.asarray(owner[1:]) != np.asarray(owner[:-1])
        for k, (i, c) in enumerate(zip(owner, cells.tolist(), strict=True)):
            lst = out.setdefault(ents[i].id, [])
            if c >= 0 and c not in lst:
                lst.append(c)
            if first[k]:
                self.off["samples"] += 1
                if not fronts[k] and dist[k] > OFF_STREET_M:
                    self.off["off_street"] += 1
                    if dist[k] > CLIENT_OFF_NETWORK_M:
                        self.off["beyond_client"] += 1
        return {k: tuple(v) for k, v in out.items()}

    def off_network(self) -> dict:
        """The report's count of true positions off our network (per entity-sample of the measure)."""
        n = self.off["samples"]
        return {"entity_samples": n, "off_street": self.off["off_street"],
                "off_street_share": self.off["off_street"] / n if n else 0.0,
                "beyond_client_off_network": self.off["beyond_client"], "off_street_m": OFF_STREET_M,
                "client_off_network_m": CLIENT_OFF_NETWORK_M}


def place_points(topo, xy: np.ndarray, networks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells of points (n, 2) on the networks (bitmask per point): an area of theirs holding the point, else the
    nearest edge of theirs at the projected offset. Returns (cell, distance to that edge, inside an area)."""
    import shapely

    pi = topo.placement_index()
    n = len(xy)
    cell = np.full(n, -1, np.int64)
    dist = np.full(n, np.inf)
    in_area = np.zeros(n, bool)
    pts = shapely.points(xy)
    src, area = pi.area_tree.query(pts, predicate="intersects")
    for s, a in sorted(zip(src.tolist(), area.tolist(), strict=True)):
        if not in_area[s] and topo.area_networks[a] & networks[s]:
            in_area[s] = True
            cell[s] = int(topo.area_cell[a])
            dist[s] = 0.0
    for nets in np.unique(networks):
        sel = np.flatnonzero((networks == nets) & ~in_area)
        if not len(sel):
            continue
        e, d = pi.nearest_edges(xy[sel], int(nets) & (PEDESTRIAN | VEHICLE | TRAM))
        ok = e >= 0
        sel, e, d = sel[ok], e[ok], d[ok]
        off = shapely.line_locate_point(pi.lines[e], pts[sel])
        dist[sel] = d
        for s, ee, o in zip(sel.tolist(), e.tolist(), off.tolist(), strict=True):
            cell[s] = topo.cell_at(ee, o)
    return cell, dist, in_area
