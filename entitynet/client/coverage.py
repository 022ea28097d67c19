"""Coverage: which cells a publish lists, and for how long (reference section 4.5, cell occupation).

The published model's occupation (`occupy`: the body and the margin along the path, the way ahead up to the
next choice or along the known route), and the extra cells that GPS noise makes possible: behind a standing
walker (it may turn and leave the other way), lateral ways within `lateral` metres (the other sidewalk, a way
skirting an area) and areas next to the position. Kept apart from the tracker: it reads the tracker's state
and the published ghost, and changes neither.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from entitynet.client.entities import EntityType
from entitynet.client.hold import PlacementHold, cells_under
from entitynet.client.kinematics import advance
from entitynet.client.lateral import near_index
from entitynet.client.modes import AREA
from entitynet.client.motion import AreaModel, Model, NetworkModel
from entitynet.client.network import NetView
from entitynet.client.occupation import (
    LOOKAHEAD,
    Occupation,
    lookahead_for,
    occupy,
    occupy_area,
    wire_validity,
    with_cells,
)
from entitynet.client.optional_c import compiled
from entitynet.client.path import Path, follow
from entitynet.client.placement import ring_distance
from entitynet.client.route import Route
from entitynet.client.tracker import MAX_PATH_EDGES, NetworkTracker

MAX_PUBLISH_CELLS = 64
#: seconds of the published model's travel (beyond the margin) for which the other ways within `lateral` metres
#: are covered ahead, and the least distance (m) (`Coverage._lateral_ahead`)
LATERAL_AHEAD_TIME = 12.0
LATERAL_AHEAD_MIN = 10.0

_COMPILED = compiled("_cover")  # the network model's cover compiled; else `Coverage.occupation` below
_network_occupation = _COMPILED.network_occupation if _COMPILED is not None else None


def _wire(occ: Occupation) -> Occupation:
    """The occupation with its validity as the PUBLISH carries it (`wire_validity`)."""
    v = wire_validity(occ.validity)
    if v == occ.validity:
        return occ
    return Occupation(occ.cells, v, occ.front_period, occ.aft_period, occ.cover_start, occ.cover_end)


def _way_back(net: NetView, back: tuple[int, int], networks: int, distance: float) -> Path:
    """The path from `back` on by the junction rule, `distance` metres: a function of the map alone (paths are
    not changed in place), so it is built once per (edge, direction, networks, distance) and shared."""
    cache = net.__dict__.setdefault("_way_back", {})
    key = (back, networks, distance)
    path = cache.get(key)
    if path is None:
        if len(cache) > 16384:
            cache.clear()
        path = cache[key] = Path(net, [back] + follow(net, back, networks, distance, max_edges=MAX_PATH_EDGES))
    return path


class Coverage:
    """The cells one entity publishes: its occupation from the ghost (network model) or from the tracker's
    estimate (world-frame baselines), widened by `lateral` metres where the entity may be elsewhere."""

    def __init__(self, net: NetView, etype: EntityType, route: Route, *, body: float, margin: float,
                 accuracy: float, lateral: float, lookahead: float | None, max_validity: float,
                 heartbeat: float) -> None:
        self.net = net
        self.etype = etype
        self.route = route
        self.has_route = bool(route)
        self.body, self.margin, self.accuracy, self.lateral = body, margin, accuracy, lateral
        self.lookahead, self.max_validity, self.heartbeat = lookahead, max_validity, heartbeat
        # a place that rests on one fix: a wider cover for a few seconds, for walkers and cyclists (no body), whose
        # network has the ways a few metres apart (sidewalks, footways drawn twice); it did not help cars
        self.hold = PlacementHold(lateral if etype.length == 0.0 else None)

    def placed(self, reason: str, t: float, ghost: Model, old: Model | None, trk: NetworkTracker,
               estimate_xy: Callable[[], tuple[float, float]]) -> Occupation | None:
        """The occupation of a publish for `reason` (`old`: the ghost it replaces): `occupation`, with the
        placement hold's wider cover while a place rests on one fix (hold.py)."""
        hold = self.hold
        if hold.active and reason in ("first", "jump"):
            hold.placed(reason, t, cells_under(self.net, old, t, self.body, self.margin))
        occ = self.occupation(t, ghost, trk, estimate_xy, hold.lateral_at(t))
        return hold.widen(occ, t) if occ is not None else None

    def occupation(self, t: float, ghost: Model, trk: NetworkTracker,
                   estimate_xy: Callable[[], tuple[float, float]], lateral: float | None = None) -> Occupation | None:
        """The occupation to publish with `ghost` at `t` (None while the tracker has no place). `lateral`: the
        radius of the other ways' cells on a way, when not the usual (a place that rests on one fix)."""
        if trk.place is None:
            return None
        et = self.etype
        placer = trk.placer
        if trk.place is AREA:
            x, y = ghost.xy_at(t) if isinstance(ghost, AreaModel) else estimate_xy()
            vx, vy = (ghost.vx, ghost.vy) if isinstance(ghost, AreaModel) else (0.0, 0.0)
            # the strip outside the area is covered by the lateral cells below, so the period only keeps
            # the GPS accuracy as its margin (a large drift threshold would otherwise make it vanish)
            margin = min(self.margin, self.accuracy)
            occ = occupy_area(x, y, vx, vy, placer.ring(trk.area), self.net.area_cell[trk.area],
                              margin=margin, max_validity=self.max_validity)
            if self.lateral > 0.0:
                # ways crossing or skirting the area and areas next to it: under GPS noise the entity may be
                # on one of them
                cells = list(occ.cells)
                for e in placer.edges_near(x, y, self.lateral):
                    f = placer.project_on(x, y, e)
                    if f.distance <= self.lateral:
                        for a0, b0, c in self.net.pieces(e, 1):
                            if b0 >= f.offset - self.lateral and a0 <= f.offset + self.lateral and c not in cells:
                                cells.append(c)
                for area in placer.areas_near(x, y, self.lateral):
                    c = self.net.area_cell[area]
                    if c not in cells and ring_distance(placer.ring(area), x, y) <= self.lateral:
                        cells.append(c)
                validity = occ.validity
                speed = math.hypot(vx, vy)
                if len(cells) <= MAX_PUBLISH_CELLS and speed > 0.0 and self.lateral > margin:
                    # every cell within `lateral` of the position is listed: the ghost must move
                    # `lateral - margin` before the truth can be outside them, wherever the boundary is
                    validity = max(validity, min((self.lateral - margin) / speed, self.max_validity))
                occ = Occupation(tuple(cells[:MAX_PUBLISH_CELLS]), validity, occ.front_period, occ.aft_period,
                                 occ.cover_start, occ.cover_end)
            return _wire(occ)
        if isinstance(ghost, NetworkModel):
            if _network_occupation is not None:  # this branch compiled (the usual publish; _cover.pyx)
                return _network_occupation(self, ghost, trk, lateral)
            path, s, v, a = ghost.path, ghost.s0, ghost.v, ghost.a
        else:
            # world-frame baselines: the same occupation machinery on the client's network estimate
            path, s, v, a = trk.path, trk.kf.s, max(trk.kf.v, 0.0), 0.0
        known = self.route.known_until(path, s)
        travel = ghost.time_to if isinstance(ghost, NetworkModel) else None
        # at a dead end the model halts at the path's end: nothing ahead to enter, no front period
        look = self.lookahead
        if look is None:  # the default: sized by the model along a route, else up to the next choice of way
            look = lookahead_for(v, a, et.vmax) if self.has_route else LOOKAHEAD
        occ = occupy(path, s, et.length, v, a, et.vmax, et.networks, known_until=known, margin=self.margin,
                     lookahead=look, max_validity=min(self.max_validity, self.heartbeat), travel=travel,
                     dead_end_at_path_end=path.edges[-1] == trk.dead_end)
        back = None
        if v == 0.0 and not self.has_route and self.body == 0.0 and isinstance(ghost, NetworkModel):
            # a walker standing still may turn and leave the other way, and the standing test needs a few
            # fixes to see it go: cover the way behind too, `lateral` beyond the margin (and the parallel
            # ways as far behind)
            back = self._behind(path, s, self.lateral, et.networks)
            cells = list(occ.cells)
            for c in back.cells:
                if c not in cells and len(cells) < MAX_PUBLISH_CELLS:
                    cells.append(c)
            occ = Occupation(tuple(cells), min(occ.validity, back.validity), occ.front_period, occ.aft_period,
                             occ.cover_start, occ.cover_end)
        lateral = self.lateral if lateral is None else lateral
        if lateral > 0.0:
            # with a route, only the route's own ways: where it turns back on itself (a tram's terminal
            # triangle, a bus loop) the way back lies within GPS noise of the way on, and the tracker may hold
            # the wrong one for a while (issue 20: the largest share of the vehicles' occupation error)
            extra = self._lateral_cells(trk, path, s, self._lateral_ahead(v, a, occ.cover_end - s),
                                        None if back is None else back.cover_end - back.cover_start,
                                        only=self.route.edge_ids if self.has_route else None, lateral=lateral)
            cells = list(occ.cells)
            for c in extra:
                if c not in cells and len(cells) < MAX_PUBLISH_CELLS:
                    cells.append(c)
            occ = with_cells(occ, tuple(cells))
        return _wire(occ)

    def _lateral_ahead(self, v: float, a: float, ahead: float) -> float:
        """How far ahead of the position the other ways are covered (the occupation itself reaches `ahead`):
        without a route, LATERAL_AHEAD_TIME seconds of the published model's travel (at least
        LATERAL_AHEAD_MIN) beyond the margin. Why not as far as the occupation: an entity that is on the other
        way is re-placed there by its next fixes within seconds (and a place that rests on one fix is held with
        a wider cover meanwhile, hold.py), so the other way's cells further on were deliveries to viewers for an
        entity that was not coming (issue 20). Measured (`sims.bench.sim_causes` and `bench dr`, with the 40 m
        look-ahead): the street deliveries for entities in no visible cell fell from 3.08 to 2.95 per
        viewer-second, with the walkers' occupation error 0.061 % before and 0.026 % after: the path's own
        edges beyond this reach become lateral candidates near the position (`_lateral_cells`), which covers a
        path that loops back along a way drawn twice. With a route the route's own legs are covered as far as
        the occupation (a terminal triangle, issue 20)."""
        if self.has_route:
            return ahead
        d, _v = advance(max(v, 0.0), a, self.etype.vmax, LATERAL_AHEAD_TIME)
        reach = self.margin + (d if d > LATERAL_AHEAD_MIN else LATERAL_AHEAD_MIN)
        return reach if reach < ahead else ahead

    def _behind(self, path: Path, s: float, lookahead: float, networks: int) -> Occupation:
        """The occupation of a standing entity turned around: the published path's edge at s reversed and
        followed by the junction rule, covered as `occupy` covers the way ahead (`lookahead` beyond the margin,
        every branch at a choice of way within it)."""
        net = self.net
        k = path.index(s)
        e, d = path.edges[k]
        back = (e, -d)
        s_back = path.cum[k + 1] - s
        way = _way_back(net, back, networks, lookahead + self.margin + 80.0)
        return occupy(way, s_back, 0.0, 0.0, 0.0, self.etype.vmax, networks, margin=self.margin,
                      lookahead=lookahead, max_validity=min(self.max_validity, self.heartbeat))

    def _lateral_cells(self, trk: NetworkTracker, path: Path, s: float, ahead: float,
                       behind: float | None = None, only: frozenset[int] | None = None,
                       lateral: float | None = None) -> list[int]:
        """Cells of the other edges within `lateral` metres of the position: under GPS noise the entity may
        be on a parallel way (the other sidewalk) rather than the one it was placed on. Each such edge is
        covered from `behind` metres behind the projected point (default: the margin and the body) to `ahead`
        metres on, in the direction of travel. `only`: the edges that may be candidates (a route's); then no
        area is."""
        net, placer = self.net, trk.placer
        near = near_index(placer)
        lateral = self.lateral if lateral is None else lateral
        back = self.margin + self.body if behind is None else behind  # a standing walker: both ways
        out = near.path_cells(path, s, lateral, back, ahead, only)
        if only is not None:
            return out
        x, y = path.xy(s)
        for area in near.areas_near(x, y, lateral):  # an area next to the way: maybe inside it
            if near.within_ring(area, x, y, lateral):
                c = net.area_cell[area]
                if c not in out:
                    out.append(c)
        return out
