"""Crossings: vehicles wait at a junction and the first to arrive passes first (reference section 5.3).

Why reservations on bounding boxes: a movement through a junction (from `radius` metres before the node to
`radius` after it, in the vehicle's lane) is summed up by its axis-aligned bounding box; two movements conflict
when their boxes overlap (the fast bounding-box test), unless they come from the same directed edge (those
follow each other, which car following handles). A vehicle asks for the junction when it could still stop
before it; it is granted the junction when no vehicle holding it and no earlier asker has a conflicting
movement. Opposite straight movements in their own virtual lanes do not overlap, so they pass together; a left
turn across them waits its turn. Ties in arrival time go to the lower entity id, so runs are deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

from entitynet.client.network import DirEdge

Box = tuple[float, float, float, float]


def boxes_overlap(a: Box, b: Box) -> bool:
    """Whether two axis-aligned boxes (x0, y0, x1, y1) overlap (touching counts as apart)."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


@dataclass(frozen=True)
class Movement:
    """One vehicle's way through one junction: the directed edges in and out, and its bounding box."""

    into: DirEdge
    out: DirEdge
    box: Box

    def conflicts(self, other: Movement) -> bool:
        """Whether the two movements cannot share the junction: overlapping boxes from different entry edges
        (vehicles from the same edge follow each other, which car following handles)."""
        return self.into != other.into and boxes_overlap(self.box, other.box)


class Crossings:
    """Reservations of junction nodes: who holds each, who waits since when."""

    def __init__(self) -> None:
        self.held: dict[int, dict[int, Movement]] = {}
        self.waiting: dict[int, dict[int, tuple[float, Movement]]] = {}

    def request(self, node: int, agent: int, movement: Movement, now: float) -> bool:
        """Ask for `node`; True when granted now (or already held). A refused asker keeps its arrival time."""
        held = self.held.setdefault(node, {})
        if agent in held:
            return True
        queue = self.waiting.setdefault(node, {})
        arrived = queue.setdefault(agent, (now, movement))[0]
        for other, m in held.items():
            if other != agent and movement.conflicts(m):
                return False
        for other, (t, m) in queue.items():
            if other != agent and (t, other) < (arrived, agent) and movement.conflicts(m):
                return False
        del queue[agent]
        held[agent] = movement
        return True

    def release(self, node: int, agent: int) -> None:
        """The agent's body has left the junction (or it gave up)."""
        self.held.get(node, {}).pop(agent, None)
        self.waiting.get(node, {}).pop(agent, None)

    def forget(self, agent: int, nodes) -> None:
        """Drop every reservation and request of a removed agent at `nodes`."""
        for n in nodes:
            self.release(n, agent)

    def holders(self, node: int) -> list[int]:
        """The agents holding `node` now, by id (sorted, so inspection is deterministic)."""
        return sorted(self.held.get(node, {}))
