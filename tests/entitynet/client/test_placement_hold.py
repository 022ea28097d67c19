"""A place that rests on one fix is published with a wider cover for JUMP_HOLD seconds (issue 20).

In the city simulation nearly every stale ghost was a walker placed on a way about 10 m from the one it walked
(one fix of 5 m RMS noise, beyond the 2 x accuracy lateral cover): outside its published cells until the next
fixes put it back. A first placement and a jump therefore list the other ways PLACED_WIDENING times as far,
and a jump also the cells where the entity was tracked before it, until JUMP_HOLD s have confirmed the place."""

from __future__ import annotations

from entitynet.client import Player
from entitynet.client.hold import JUMP_HOLD, PLACED_WIDENING
from entitynet.client.network import netview
from tests.entitynet.client_fixtures import parallel


def _cells(topo, edge: int) -> set[int]:
    return {c for _a, _b, c in netview(topo).pieces(edge, 1)}


def test_a_first_placement_and_a_jump_keep_the_wider_cover_for_the_hold_only():
    topo = parallel(gap=12.0, length=600.0)  # 12 m apart: beyond 2 x 5 m, within 3 x 5 m
    assert 2.0 * 5.0 < 12.0 <= PLACED_WIDENING * 2.0 * 5.0
    south, north = _cells(topo, 0), _cells(topo, 1)
    p = Player(topo, 1, "pedestrian", accuracy=5.0, threshold=5.0)
    pubs = []
    for i in range(30):  # east at 1.4 m/s on the southern way, then (i >= 15) on the northern one
        y = 0.0 if i < 15 else 12.0
        for m in p.feed(50.0 + 1.4 * i, y + (1.0 if i % 2 else -1.0), float(i)):
            pubs.append((float(i), dict(p.stats), set(m.cells)))
    first_t, _stats, first_cells = pubs[0]
    assert first_cells & north, "the first placement rests on one fix: the street 12 m away is listed"
    steady = [(t, c) for t, st, c in pubs if JUMP_HOLD < t < 15.0]
    assert steady and all(not c & north for _t, c in steady), "after the hold, the usual 10 m cover"
    jumps = [(t, c) for t, st, c in pubs if st.get("jump")]
    assert jumps, "the move to the northern street is a jump"
    t_jump = jumps[0][0]
    held = [c for t, c in jumps if t < t_jump + JUMP_HOLD]
    assert all(c & south and c & north for c in held), "where it was tracked stays listed during the hold"
    later = [c for t, c in jumps if t >= t_jump + JUMP_HOLD]
    assert later and all(not c & south for c in later), "and is dropped once the hold is over"


def test_a_car_has_no_hold():
    """Cars' roads are not drawn twice a few metres apart as footways are: their first placement lists the usual
    2 x accuracy only (the hold did not change the cars' stale ghosts in the simulation)."""
    topo = parallel(gap=12.0, length=600.0)
    p = Player(topo, 1, "car", accuracy=5.0, threshold=5.0)
    (m,) = p.feed(50.0, 1.0, 0.0)
    assert not set(m.cells) & _cells(topo, 1)
