"""The placement hold: a place that rests on one fix is published with a wider cover for a few seconds.

Why: a first placement or a jump (a fix that re-placed the entity away from the way it was tracked on) rests on
one GPS fix. In the city simulation nearly every stale ghost was a walker placed on a way about 10 m from the
one it walked (5 m RMS noise, beyond the 2 x accuracy lateral cover): outside its published cells for seconds,
until the next fixes put it back (issue 20). For JUMP_HOLD seconds after such a placement the other ways are
listed PLACED_WIDENING times as far, and after a jump also the cells under the body where the entity was
tracked before it. Measured (bench sim's PVS run, seed 7): holds of 0 / 3 / 5 / 7 / 10 s gave stale ghosts of
0.045 / 0.021 / 0.013 / 0.011 / 0.012 % for 0 / +0.8 / +1.2 / +1.5 / +2.1 % street deliveries. For walkers
and cyclists only (cars' few stale samples did not change): 0.015 % for +0.8 %.
"""

from __future__ import annotations

import math

from entitynet.client.motion import Model, NetworkModel
from entitynet.client.network import NetView
from entitynet.client.occupation import Occupation, with_cells

#: seconds a place that rests on one fix is published with the wider cover
JUMP_HOLD = 5.0
#: how much wider the lateral cover is meanwhile: by default 2.5 x accuracy instead of 2 x (96 % of a 2-D Gaussian
#: fix lies within 2.5 sigma, 86 % within 2). Measured (bench sim's PVS run, issue 20): 1.0 / 1.1 / 1.25 / 1.5x gave
#: stale ghosts of 0.042 / 0.027 / 0.014 / 0.014 %, 1.5x for 0.3 % more street deliveries. No lateral cover stays none
PLACED_WIDENING = 1.25


class PlacementHold:
    """One entity's hold: until when its place rests on one fix, and the cells it was tracked in before.
    `lateral` None: no hold (the entity's type does not need one)."""

    def __init__(self, lateral: float | None) -> None:
        self.active = lateral is not None
        self.lateral = PLACED_WIDENING * (lateral or 0.0)  # the lateral cover while held
        self.cells: tuple[int, ...] = ()
        self.until = -math.inf

    def placed(self, reason: str, t: float, before: tuple[int, ...]) -> None:
        """A publish for `reason` at `t`: a first placement or a jump starts a hold (`before`: the cells under the
        body where the entity was tracked until now)."""
        if self.active and reason in ("first", "jump"):
            self.cells = before if reason == "jump" else ()
            self.until = t + JUMP_HOLD

    def lateral_at(self, t: float) -> float | None:
        """The lateral cover to publish with at `t` (None: the usual)."""
        return self.lateral if t < self.until else None

    def widen(self, occ: Occupation, t: float) -> Occupation:
        """`occ` with the held cells listed too, while the hold lasts."""
        if t >= self.until:
            return occ
        extra = tuple(c for c in self.cells if c not in occ.cells)
        return with_cells(occ, occ.cells + extra) if extra else occ


def cells_under(net: NetView | None, ghost: Model | None, t: float, body: float, margin: float) -> tuple[int, ...]:
    """The cells under the body (and its margin) where `ghost` puts the entity at `t` (an area ghost: its area's
    cell; a world-frame one, or none: no cell)."""
    if isinstance(ghost, NetworkModel):
        s = ghost.s_at(t)
        return tuple(ghost.path.cells_between(max(s - body - margin, 0.0), min(s + margin, ghost.path.length)))
    area = getattr(ghost, "area", None)
    return (int(net.area_cell[area]),) if area is not None and net is not None else ()
