"""Cell occupation and its validity period, from the entity's front and aft (reference section 4.3).

The body of an entity of length L whose front is at path coordinate s is [s - L, s]; a pedestrian has L = 0,
a two-part tram the sum of its parts (both follow the rails, so the body is still one path interval).

- *front period*: time until the front enters a cell that is not in the occupation;
- *aft period*: time until the aft leaves its first cell (only in the reference's tight mode: with a
  lookahead the cells behind are merely over-coverage, not an error);
- the shorter decides; the player recomputes when it expires or when it sends an update.

`margin` widens the body on both sides by the drift threshold: while the truth stays within the threshold of
the published extrapolation, the true body stays inside the published cells. `lookahead` extends the
occupation along the known path (a-priori route, or up to the next real choice of way), so fewer periods
expire, at the price of deliveries to viewers who see those cells before the entity gets there.

Where the path ahead is not known (no route), the reference's tight occupation may only reach past the next
choice node as far as every branch stays in the junction cell (the front period is the minimum over the
branches). With a lookahead the occupation becomes a tree: every way on from that node, through further
junctions, is covered to its first cell boundary `lookahead` metres beyond the body and its margin (the
players' default `LOOKAHEAD`, 30 m; at most `branch_depth`, default 40, past the node, or past the body and
its margin where they reach beyond the node), and the front
period ends when the shortest branch of the tree runs out.
"""

from __future__ import annotations

import heapq
import math
from bisect import bisect_right
from collections.abc import Callable
from dataclasses import dataclass

from entitynet.client.frozen import maker
from entitynet.client.kinematics import INF, advance, time_to_travel
from entitynet.client.optional_c import compiled
from entitynet.client.path import Path

#: metres the occupation reaches past the body and its margin up to the next choice of way when no route is
#: known (the branch tree at a junction reaches no deeper past the body and margin), and the least along a route
#: (`lookahead_for`); also the way the tracker keeps ahead beyond the extrapolation. Every cell listed ahead
#: sends the entity's updates to viewers before it is there: with 150 m, 40 % of a street viewer's deliveries
#: in the city simulation were for entities in no visible cell (issue 11, docs/simulation.md). Measured with
#: the lateral cover's reach (coverage.py), seed 7 (issue 20): 40 / 30 / 25 / 20 m gave street deliveries for
#: entities in no visible cell (`sims.bench.sim_causes`) of 2.95 / 2.56 / 2.40 / 2.22 per viewer-s, publishes
#: +0 / +1.3 / +2.6 / +4.8 % (more validity expiries), walkers' occupation error (`bench dr`) 0.026 / 0.032 /
#: 0.032 / 0.051 %; 30 m is the knee.
LOOKAHEAD = 30.0

#: seconds of the published model's travel that the occupation of an entity on a known route lists ahead of
#: its body and margin: a vehicle's drift rule re-publishes about every 6 s (`bench dr`), so a cover that lasts
#: 12 s seldom expires first. With the fixed 40 m a tram at 12 m/s re-published every 4 s for the validity
#: alone, and a ghost halting at a stop the vehicle passed left it outside its cells (issue 20). 10 s and 8 s
#: cut the deliveries for entities in no visible cell by 0.6 % and 1 % but re-published the vehicles 0.5 % and
#: 2 % more often (validity expiries). Without a route the occupation stops at the next choice of way, and
#: LOOKAHEAD (the junction tree's depth) stays.
LOOKAHEAD_TIME = 12.0
#: the most (m): the viewers of every cell listed receive the entity's updates before it is there
LOOKAHEAD_MAX = 150.0


def lookahead_for(v: float, a: float, vmax: float) -> float:
    """The look-ahead (m) along a known route of an occupation published with model (v, a, vmax): how far that
    model travels in LOOKAHEAD_TIME seconds, within [LOOKAHEAD, LOOKAHEAD_MAX]. The least is what a standing
    vehicle covers from rest at up to 1.3 m/s^2 in the 5 s the start rule needs to see it go (16 m) and more."""
    d, _v = advance(max(v, 0.0), a, vmax, LOOKAHEAD_TIME)
    if not d < LOOKAHEAD_MAX:  # also NaN
        return LOOKAHEAD_MAX if d == d else LOOKAHEAD
    return d if d > LOOKAHEAD else LOOKAHEAD

#: the most (directed edge, networks, budgets) keys the branch-tree memo (`branch_cover`) keeps before it starts
#: afresh. The keys are bounded by the map (two per edge and network mask); the city simulation's 2,000 entities
#: reached 4,096 (the earlier bound) after about 4 minutes, and each clearing sent the memo's misses from 23 % of
#: the searches back to 70 % for minutes (issue 22). A key holds a few intervals of a few cells each.
BRANCH_MEMO_KEYS = 65536


@dataclass(frozen=True, slots=True)
class Occupation:
    """The cells to publish and how long they stay right: the validity period is the shorter of the
    front and aft periods, and the covered interval tells the player when to recompute."""
    cells: tuple[int, ...]
    validity: float  # seconds (the shorter period, capped and floored), finite
    front_period: float  # seconds, may be math.inf
    aft_period: float  # seconds, may be math.inf
    cover_start: float  # path coordinates covered by `cells`
    cover_end: float


make_occupation = maker(Occupation)  # Occupation(...) without the frozen dataclass __init__ (once per publish)


def with_cells(occ: Occupation, cells: tuple[int, ...]) -> Occupation:
    """`dataclasses.replace(occ, cells=cells)` without its generic field walk (once per publish)."""
    return make_occupation(cells, occ.validity, occ.front_period, occ.aft_period, occ.cover_start, occ.cover_end)


def certain_end(path: Path, s_front: float, networks: int, known_until: float) -> float:
    """How far along `path` the entity's way is certain: to the first choice node beyond `known_until`
    (after the front), plus the stretch every branch stays in the cell at that node."""
    return _certain_end_at(path, _first_choice(path, s_front, networks, known_until), networks)


def choice_node(path: Path, s_front: float, networks: int, known_until: float) -> tuple[int, float] | None:
    """(index of the path edge ending at it, its path coordinate) of the first real choice of way ahead of
    the front that the a-priori route does not decide; None when the path ends first."""
    k = _first_choice(path, s_front, networks, known_until)
    return (k, path.cum[k + 1]) if k >= 0 else None


def _first_choice(path: Path, s_front: float, networks: int, known_until: float) -> int:
    """Index of the path edge ending at the first choice node ahead of the front beyond `known_until`, or -1
    (the search `certain_end` and `choice_node` share: `occupy` runs it once for both)."""
    is_choice = path.net.is_choice
    cum, edges = path.cum, path.edges
    n = len(edges)
    k = path.index(max(s_front, known_until))
    while k < n:
        s_node = cum[k + 1]
        if s_node >= known_until and s_node >= s_front and is_choice(edges[k], networks):
            return k
        k += 1
    return -1


def _certain_end_at(path: Path, k: int, networks: int) -> float:
    """`certain_end` given the choice edge index from `_first_choice`."""
    if k < 0:
        return path.length
    net = path.net
    de = path.edges[k]
    s_node = path.cum[k + 1]
    node_cell = path.cell(s_node - 1e-9) if s_node > 0 else path.cell(0.0)
    cache = net.__dict__.setdefault("_allowance", {})
    key = (de, networks, node_cell)
    allowance = cache.get(key)
    if allowance is None:
        if len(cache) > 65536:
            cache.clear()
        allowance = cache[key] = _allowance(net, de, networks, node_cell)
    return min(s_node + allowance, path.length)


def _allowance(net, de, networks: int, node_cell: int) -> float:
    """How far every way on from the end node of `de` stays in `node_cell` (0 where one leaves it at once, or
    none goes on): a function of the map alone, so `_certain_end_at` keeps it per (edge, networks, cell)."""
    allowance = INF
    for cand in net.choices(de, networks):
        pieces = net.pieces(*cand)
        a0, b0, c0 = pieces[0]
        allowance = min(allowance, b0 if c0 == node_cell else 0.0)
    if not net.choices(de, networks):
        allowance = 0.0
    return allowance


def branch_cover(path: Path, k: int, depth: float, networks: int, max_cells: int = 48,
                 max_edges: int = 64) -> tuple[list[int], float]:
    """Cells of every way on from the end node of path edge k, through further junctions, each way down to
    its first cell boundary beyond `depth` metres from the node (a tree; dead ends bound nothing). Returns the
    cells and the shortest covered distance (where the first uncovered cell could be entered).

    The tree depends only on the directed edge, the budgets and on which side of `depth` each distance the
    search compares with it falls: one computation answers every depth in an interval [lo, hi) (`_span`),
    so the memo keeps, per directed edge and budgets, the intervals found so far (sorted, disjoint) and a
    publish without a route, whose depth is a fresh float each time, finds its tree by one bisection."""
    net = path.net
    de = path.edges[k]
    if depth != depth:  # NaN: no interval holds it (every comparison is false); computed, never cached
        return _branch_cover(net, de, depth, networks, max_cells, max_edges)
    cache = net.__dict__.setdefault("_branch_cover", {})
    key = (de, networks, max_cells, max_edges)
    spans = cache.get(key)
    if spans is None:
        if len(cache) > BRANCH_MEMO_KEYS:
            cache.clear()
        spans = cache[key] = ([], [])  # interval starts, (end, cells, shortest): sorted by start
    los, rest = spans
    i = bisect_right(los, depth) - 1
    if i >= 0 and depth < rest[i][0]:
        hit = rest[i]
        return list(hit[1]), hit[2]
    cells, shortest, lo, hi = _span(net, de, depth, networks, max_cells, max_edges)
    if len(los) < 256:
        j = bisect_right(los, lo)
        los.insert(j, lo)
        rest.insert(j, (hi, tuple(cells), shortest))
    return cells, shortest


def _branch_cover(net, de, depth: float, networks: int, max_cells: int, max_edges: int) -> tuple[list[int], float]:
    """The tree of `branch_cover`, computed (the reference for the memo)."""
    cells, shortest, _lo, _hi = _span(net, de, depth, networks, max_cells, max_edges)
    return cells, shortest


def _span(net, de, depth: float, networks: int, max_cells: int,
          max_edges: int) -> tuple[list[int], float, float, float]:
    """`_branch_cover` and the interval [lo, hi) of depths it answers alike: `depth` enters the search only
    through `x > depth` for distances x, so every depth with the same outcomes for the same x (at least the
    largest x not above it, below the smallest x above it) runs the same search to the same result."""
    cells: list[int] = []
    listed: set[int] = set()  # `cells` as a set: the membership test of every piece
    lo, hi = -INF, INF
    node = net.end_node(de)
    if net.node_area[node] >= 0:
        cells.append(net.area_cell[net.node_area[node]])
        listed.add(cells[0])
    shortest = INF
    info = _edge_info(net, networks)
    # nearest first (Dijkstra order), so that when the cell budget runs out the tree is cut at its far end
    queue = [(0.0, cand) for cand in net.choices(de, networks)]
    heapq.heapify(queue)
    pop, push = heapq.heappop, heapq.heappush
    seen = {de}
    edges = 0
    while queue:
        d0, cand = pop(queue)
        if cand in seen:
            continue
        seen.add(cand)
        edges += 1
        if edges > max_edges or len(cells) >= max_cells:
            if d0 < shortest:
                shortest = d0  # budget spent: nothing beyond here is covered
            continue
        row = info.get(cand)
        if row is None:
            row = info[cand] = _info_row(net, cand, networks)
        pieces, length, end_cell, onward = row
        leaf = False
        for a0, _b0, c in pieces:
            x = d0 + a0
            if x > depth:
                if x < hi:
                    hi = x
                if x < shortest:
                    shortest = x
                leaf = True
                break
            if x > lo:
                lo = x
            if c not in listed:
                listed.add(c)
                cells.append(c)
        if leaf:
            continue
        d1 = d0 + length
        if end_cell >= 0:
            if end_cell not in listed:
                listed.add(end_cell)
                cells.append(end_cell)
            if d1 < shortest:
                shortest = d1  # into an area: the area cell is covered, not beyond
            continue
        for nxt in onward:
            push(queue, (d1, nxt))
    return cells, (0.0 if shortest == INF and not cells else shortest), lo, hi


def occupy(
    path: Path,
    s_front: float,
    length: float,
    v: float,
    a: float,
    vmax: float,
    networks: int,
    *,
    known_until: float = 0.0,
    margin: float = 0.0,
    lookahead: float = 0.0,
    tight: bool | None = None,
    max_validity: float = 60.0,
    min_validity: float = 0.5,
    dead_end_at_path_end: bool = False,
    travel: Callable[[float], float] | None = None,
    branch_depth: float = 40.0,
) -> Occupation:
    """Occupation of an entity moving along `path` with front at `s_front`, modelled by (v, a, vmax).

    `known_until`: path coordinate up to which the way is known a priori (route); pass `path.length` for a
    fully known path, 0 for none. `tight` (default: lookahead == 0) adds the aft period. `travel(d)`, when
    given, is the time the published model needs to advance d metres (e.g. `NetworkModel.time_to`, which
    knows about a planned halt); by default the (v, a, vmax) kinematics.
    """
    if not (math.isfinite(s_front) and math.isfinite(v) and math.isfinite(a)):
        raise ValueError("occupation needs finite position, speed and acceleration")
    if tight is None:
        tight = lookahead <= 0.0
    v = max(v, 0.0)
    if travel is None:
        def travel(d: float) -> float:
            return time_to_travel(d, v, a, vmax)

    s_aft = s_front - max(length, 0.0)
    start = min(max(s_aft - margin, 0.0), path.length)
    reach = min(max(s_front + margin, start), path.length)
    k_choice = _first_choice(path, s_front, networks, known_until)
    end_known = max(_certain_end_at(path, k_choice, networks), reach)
    choice = None if tight or k_choice < 0 else (k_choice, path.cum[k_choice + 1])
    want = reach + max(lookahead, 0.0)
    if choice is not None and want > end_known:
        # the way on is not known: cover every branch at the next choice node (a tree, not a line)
        k, s_node = choice
        cells = path.cells_between(start, min(reach, s_node))
        for _sa, c in path.starts_in(min(reach, s_node), s_node):
            if c not in cells:
                cells.append(c)
        depth = min(want - s_node, max(reach - s_node, 0.0) + branch_depth)
        extra, shortest = branch_cover(path, k, depth, networks)
        for c in extra:
            if c not in cells:
                cells.append(c)
        cover_end = s_node + shortest
    else:
        target = reach if tight else min(want, end_known)
        nxt = path.first_boundary_after(target, end_known)
        cover_end = nxt if nxt is not None else end_known
        # cells of [start, cover_end): the cell starting exactly at cover_end is not covered. One pass for
        # the cells under the body (start, reach], as `cells_between` lists them, and those ahead of it
        cells = path.cover_cells(start, reach, cover_end)
    if cover_end >= path.length and dead_end_at_path_end:
        front = INF
    else:
        front = travel(cover_end - reach)
    aft = INF
    if tight:
        behind = path.first_boundary_after(start, end_known)
        if behind is not None:
            aft = travel(behind - start)
    validity = max(min(front, aft, max_validity), min_validity)
    return make_occupation(tuple(cells), validity, front, aft, start, cover_end)


def _edge_info(net, networks: int) -> dict:
    """Per directed edge, what the branch search reads of it (`_info_row`), kept per view and networks."""
    return net.__dict__.setdefault("_branch_info", {}).setdefault(networks, {})


def _info_row(net, cand, networks: int) -> tuple[list, float, int, list]:
    """(cell pieces, length, the area cell at its end node or -1, the ways on from it): the map's data the
    branch search reads at every directed edge it visits, fetched once."""
    end = net.end_node(cand)
    area = net.node_area[end]
    return (net.pieces(*cand), net.edge_len[cand[0]], int(net.area_cell[area]) if area >= 0 else -1,
            net.choices(cand, networks))


def wire_validity(validity: float) -> float:
    """The validity as a PUBLISH carries it, in seconds q with `int(q * 1000) / 1000 == q`: whole milliseconds
    that the wire carries and decodes back to exactly q. q is the validity cut to the millisecond, or one
    millisecond less where ms / 1000 would encode to ms - 1 (binary fractions; about 0.6 % of values). The
    player expires its occupation with q, so it re-publishes exactly when the receivers' copy runs out, never
    after it."""
    ms = int(validity * 1000.0)
    q = ms / 1000.0
    while ms > 0 and int(q * 1000.0) < ms:  # ms / 1000 may encode one below ms (binary fractions)
        ms -= 1
        q = ms / 1000.0
    return q


def occupy_area(x: float, y: float, vx: float, vy: float, ring_xy, area_cell: int, *,
                margin: float = 0.0, max_validity: float = 60.0, min_validity: float = 0.5) -> Occupation:
    """An entity inside an area occupies the area cell until it could reach the area's boundary.

    Conservative in every direction: (distance to the nearest boundary point - margin) / speed.
    """
    import numpy as np

    from entitynet.client.placement import ring_distance

    dist = ring_distance(np.asarray(ring_xy, dtype=np.float64), x, y)
    dist = 0.0 if math.isinf(dist) else dist
    speed = math.hypot(vx, vy)
    # a standing model never reaches the boundary, even one within the margin (the strip beyond it is the
    # lateral cover's): its cells do not change, as for a standing entity on a way
    period = INF if speed == 0.0 else time_to_travel(dist - margin, speed, 0.0, speed)
    validity = max(min(period, max_validity), min_validity)
    return Occupation((int(area_cell),), validity, period, INF, 0.0, 0.0)


#: the pure `occupy` above: the reference the compiled one is held equal to (tests/entitynet/client/
#: test_occupy_compiled.py), and the one used where pip did not build `_occupy` or ENTITYNET_PURE_PYTHON is set
occupy_reference = occupy
_COMPILED = compiled("_occupy")  # `occupy` compiled as a whole; else the pure function above
if _COMPILED is not None:
    occupy = _COMPILED.occupy  # noqa: F811 (the compiled twin of the reference above)
