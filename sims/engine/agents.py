"""One simulated entity's truth: where it is along its route, how fast it goes, and what it is waiting for.

Plain data, moved by `World`; the behaviours (car following, stops, crossings, deadlock timeouts) live in
`sims.engine.behaviour` and `sims.engine.crossings` so each rule can be read (and tested) on its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sims.engine.params import TypeParams
from sims.engine.routes import Route


@dataclass(frozen=True)
class Stop:
    """A scheduled halt: route distance `s` (where the front stops), dwell seconds, the stop's name, and
    `arrive`: the timetable's arrival, in seconds after the trip's departure time (None: no timetable; the
    vehicle then drives at its own desired speed)."""

    s: float
    dwell: float
    name: str = ""
    arrive: float | None = None


@dataclass(frozen=True)
class AreaWalk:
    """A walk inside an area (square, park) once the route has brought the entity to the area's node: times
    from arrival and local (x, y) (`sims.mobility.area_walk`), and the area's cell."""

    t: np.ndarray
    xy: np.ndarray
    cell: int

    @property
    def duration(self) -> float:
        """Seconds from arrival to the walk's last waypoint (when the entity leaves the simulation)."""
        return float(self.t[-1])

    def at(self, dt: float) -> tuple[float, float]:
        """Local (x, y) `dt` seconds after arrival: the last waypoint reached (no interpolation; held at the
        end once the walk is over)."""
        i = min(int(np.searchsorted(self.t, dt, side="right")) - 1, len(self.t) - 1)
        x, y = self.xy[max(i, 0)]
        return float(x), float(y)


@dataclass
class Agent:
    """An entity of the simulation's truth.

    `s` is the route distance of the front; the body reaches back `params.length` metres along the route (a
    two-part tram's parts are its first `parts[0]` and next `parts[1]` metres behind the front, both on the
    rails). `lateral` is its offset to the right of the direction of travel. `v0` its desired speed now:
    `v_free` (its own) on a free run, or, for a vehicle on a timetable (`t0`: the service-day time its stops'
    `arrive` count from), the speed that reaches the next stop on time (`behaviour.timetable_speed`).
    """

    id: int
    params: TypeParams
    route: Route
    s: float
    v: float
    v0: float
    lateral: float
    born: float
    stops: list[Stop] = field(default_factory=list)
    next_stop: int = 0
    dwell_until: float | None = None
    crossings: list[tuple[float, int, int]] = field(default_factory=list)  # (s_node, node, k_out) ahead
    held: set[int] = field(default_factory=set)  # crossing nodes granted to this agent
    movements: dict = field(default_factory=dict)  # route edge index k of a crossing -> its Movement (built once)
    blocked_since: float | None = None
    cause: str = ""  # what limits the agent now: "", "leader", "crossing", "stop", "stall"
    blocker: int | None = None  # the entity (or crossing node) it yields to
    accept_until: float = -1.0  # accepts collisions (ignores other entities) until then
    stalled_until: float = -1.0  # a breakdown: stands still until then
    label: str = ""
    t0: float | None = None  # the timetable's origin (service-day seconds), None for no timetable
    v_free: float = 0.0  # its own desired speed (set on spawn), used where no timetable applies
    distance: float = 0.0  # metres travelled since spawn
    area: AreaWalk | None = None  # a walk inside an area at the end of the route (pedestrians)
    in_area_since: float | None = None
    _episode: tuple[str, int | None] = ("", None)
    _clock: float = 0.0  # the world's time at the last step (for the area walk)
    _rt: tuple[int, int] = (-1, 0)  # its route's rows in the world's `RouteTable` (first, edge count)

    @property
    def name(self) -> str:
        """The entity type's name (the params' name), used as the client core's type and in counts by type."""
        return self.params.name

    @property
    def length(self) -> float:
        """Body length in metres behind the front (0: point-like, takes no part in collision avoidance)."""
        return self.params.length

    def xy(self, behind: float = 0.0) -> tuple[float, float]:
        """Local (x, y) of the point `behind` metres behind the front, in the agent's lane (inside its area
        when it walks there)."""
        if self.area is not None and self.in_area_since is not None:
            return self.area.at(self._clock - self.in_area_since)
        return self.route.xy(max(self.s - behind, 0.0), self.lateral)

    def part_points(self) -> list[tuple[float, float]]:
        """The front, then the end of each body part (a tram: front, articulation, aft end)."""
        pts = [self.xy()]
        acc = 0.0
        for p in self.params.parts:
            acc += p
            pts.append(self.xy(acc))
        return pts

    def cells(self) -> tuple[int, ...]:
        """The visibility cells the body occupies now (front first)."""
        if self.area is not None and self.in_area_since is not None:
            return (self.area.cell,)
        route = self.route
        out = [route.cell(min(self.s, route.length))]
        if self.length > 0.0:
            k0 = route.index(max(self.s - self.length, 0.0))
            k1 = route.index(self.s)
            for k in range(k0, k1 + 1):
                lo = max(route.cum[k], self.s - self.length)
                hi = min(route.cum[k + 1], self.s)
                for a, b, c in route.net.pieces(*route.edges[k]):
                    if route.cum[k] + a <= hi and route.cum[k] + b >= lo and c not in out:
                        out.append(c)
        return tuple(out)
