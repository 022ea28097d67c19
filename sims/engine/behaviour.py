"""Behaviours: the intelligent driver model and the obstacles an entity reacts to.

Why IDM: it is the car-following model traffic engineers know (SUMO ships it), it is collision-free for a
leader that brakes within reason, and one formula covers free road, following, and stopping at a point (a bus
stop, a stop line, a standing vehicle): each obstacle is a (distance, closing speed, minimum gap), and the
entity takes the strongest braking among them. Pedestrians (no body length) take part in none of this: they
walk at their own speed with their lateral spread across the walkway, as the reference's pedestrians do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sims.engine.agents import Agent

#: the hardest braking the model will ask for (m/s^2), whatever an obstacle demands
EMERGENCY = 9.0


def idm(v: float, v0: float, a: float, b: float, headway: float, s0: float,
        gap: float = math.inf, dv: float = 0.0) -> float:
    """IDM acceleration for speed `v` and desired speed `v0` behind an obstacle `gap` metres ahead that we
    close on at `dv` m/s. Defined at every input: v0 <= 0 means stand, gap <= 0 means brake hardest."""
    if v0 <= 0.0:
        return -b if v > 0 else 0.0
    free = a * (1.0 - (max(v, 0.0) / v0) ** 4)
    if gap == math.inf:
        return free
    if gap <= 1e-6:
        return -EMERGENCY
    s_star = s0 + max(0.0, v * headway + v * dv / (2.0 * math.sqrt(a * b)))
    return max(free - a * (s_star / gap) ** 2, -EMERGENCY)


@dataclass(frozen=True, slots=True)
class Obstacle:
    """Something ahead on the route: at route distance `at`, moving along it at `speed` (negative: towards
    us); `kind` is "leader" (another entity), "crossing", "stop" or "end"; `who` the entity or node; `s0` and
    `headway` replace the type's minimum gap and time headway for this obstacle (a stop keeps no headway)."""

    at: float
    speed: float
    kind: str
    who: int | None = None
    s0: float | None = None
    headway: float | None = None


def accel_for(agent: Agent, obstacles: list[Obstacle]) -> tuple[float, Obstacle | None]:
    """The acceleration the agent takes and the obstacle that limits it (None on a free road)."""
    p = agent.params
    best = idm(agent.v, agent.v0, p.accel, p.decel, p.headway, p.gap)
    limit = None
    for ob in obstacles:
        s0 = p.gap if ob.s0 is None else ob.s0
        hw = p.headway if ob.headway is None else ob.headway
        acc = idm(agent.v, agent.v0, p.accel, p.decel, hw, s0, ob.at - agent.s, agent.v - ob.speed)
        if acc < best - 1e-9:
            best, limit = acc, ob
    return best, limit


def lookahead(agent: Agent) -> float:
    """How far ahead the agent looks for obstacles: its braking distance, headway and gap, and 30 m at least."""
    p = agent.params
    v = max(agent.v, agent.v0)
    return max(30.0, v * v / (2.0 * p.decel) + v * p.headway + p.gap + 10.0)


def lane_pos(agent: Agent, direction: int) -> float:
    """The agent's lateral position across an edge, measured to the right of the edge's forward direction."""
    return direction * agent.lateral


def lanes_overlap(a: Agent, da: int, b: Agent, db: int) -> bool:
    """Whether two bodies on one edge (in directions da, db) overlap sideways (their lanes touch)."""
    return abs(lane_pos(a, da) - lane_pos(b, db)) < 0.5 * (a.params.width + b.params.width)


#: a timetabled vehicle never crawls slower than this between stops (m/s): far ahead of its time it still moves
TIMETABLE_VMIN = 1.0
#: IDM comes to a stop without a time headway (see `world`), braking harder near the end than at `decel`: the
#: approach takes about the time of constant braking at this multiple of it (measured on a straight street,
#: buses and trams: on time within half a tick)
APPROACH_BRAKING = 1.6


def timetable_speed(d: float, T: float, v: float, accel: float, decel: float, vmax: float) -> float:
    """The cruise speed that covers `d` metres to the next stop in `T` seconds, from speed `v`: accelerate at
    `accel` to it, cruise, brake to a stand at `APPROACH_BRAKING * decel`, so that the stop is reached at the
    timetable's time. Why this and not d / T: a vehicle that starts from a stop and halts at the next one
    spends time accelerating and braking, and d / T would make it late at every stop. Recomputed every tick,
    this closes the loop (a vehicle held up drives faster afterwards). Clamped to TIMETABLE_VMIN..vmax; a time
    that cannot be made (T <= 0, or too short at any speed) gives vmax: late, never teleported.

    Derivation: with cruise c >= v, T*c = (c - v)^2 / (2a) + d + c^2 / (2b); the smaller root in c."""
    if not (d > 0.0 and T > 0.0):
        return vmax if d > 0.0 else TIMETABLE_VMIN
    a, b = max(accel, 1e-3), max(decel * APPROACH_BRAKING, 1e-3)
    k = 1.0 / (2.0 * a) + 1.0 / (2.0 * b)
    p = T + v / a
    q = d + v * v / (2.0 * a)
    disc = p * p - 4.0 * k * q
    if disc < 0.0:
        return vmax
    c = (p - math.sqrt(disc)) / (2.0 * k)
    return min(max(c, TIMETABLE_VMIN), vmax)
