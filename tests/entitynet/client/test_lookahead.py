"""How far ahead a publish reaches (issue 11): every cell listed ahead of the entity sends its updates to the
viewers who see that cell, before the entity is there and often when it never gets there. On the bundled map
40 % of a street viewer's deliveries were for entities in no visible cell, with a 150 m default look-ahead.
The default covers `LOOKAHEAD` (30 m) past the body and margin (the depth of the branch tree at a junction),
measured against the publish rates and the occupation error (issue 20, entitynet/client/occupation.py)."""

import pytest

from entitynet.client import Player, decode, netview
from entitynet.client.occupation import LOOKAHEAD
from entitynet.protocol import Publish
from tests.entitynet.client_fixtures import cross

CELL = 20.0  # street cells of the fixture (m)


def _reach_ahead(topo, m: Publish, t: float) -> float:
    """Metres from the published front (east-bound on the W arm) to the centre of the farthest cell listed."""
    b = topo.cell_footprints.bounds()
    centres = [(b[c, 0] + b[c, 2]) / 2.0 for c in m.cells]
    x, _y = decode(m.payload, netview(topo)).xy_at(t)
    return max(centres) - x


@pytest.mark.parametrize(("etype", "speed"), [("car", 10.0), ("pedestrian", 1.4)])
def test_default_lookahead_lists_about_lookahead_m_ahead_on_a_way_without_choices(etype, speed):
    topo = cross(arm=600.0, street_cell_max=CELL)  # 500 m of straight way before the only junction
    p = Player(topo, 1, etype, threshold=5.0)
    pubs = []
    for i in range(8):
        pubs += [(m, float(i)) for m in p.feed(-500.0 + speed * i, 0.0, float(i)) if isinstance(m, Publish)]
    assert pubs
    margin = p.margin
    for m, t in pubs:
        # the body, the margin, LOOKAHEAD, and the rest of the cell it ends in (half a cell to its centre)
        assert _reach_ahead(topo, m, t) <= margin + LOOKAHEAD + 1.5 * CELL, (etype, m.cells)


def test_an_explicit_lookahead_still_reaches_further():
    topo = cross(arm=600.0, street_cell_max=CELL)
    p = Player(topo, 1, "car", threshold=5.0, lookahead=150.0)
    (m,) = p.feed(-500.0, 0.0, 0.0)
    assert _reach_ahead(topo, m, 0.0) >= 150.0
