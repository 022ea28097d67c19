"""Property: every point of every edge lies in exactly one cell, on random street networks."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.topology.mapfixtures import collection, street
from tests.topology.test_build import check_breakpoints
from topology.build import build
from topology.geojson_reader import geojson_to_raw


@st.composite
def random_networks(draw):
    """Streets between random lattice points (2-40 m apart), sharing vertices where they meet."""
    n = draw(st.integers(min_value=2, max_value=12))
    pts = draw(st.lists(st.tuples(st.integers(-6, 6), st.integers(-6, 6)), min_size=n, max_size=n, unique=True))
    scale = draw(st.sampled_from([3.0, 7.0, 13.0, 40.0]))
    feats = []
    for _ in range(draw(st.integers(min_value=1, max_value=10))):
        idx = draw(st.lists(st.integers(0, n - 1), min_size=2, max_size=5))
        coords = [(pts[i][0] * scale, pts[i][1] * scale) for i in idx]
        feats.append(street(coords))
    return collection(*feats)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_networks(), st.floats(min_value=0.0, max_value=1.0))
def test_every_offset_lies_in_exactly_one_cell(doc, frac):
    raw = geojson_to_raw(doc)
    try:
        topo = build(raw)
    except Exception as exc:  # only the documented "no streets" error is allowed
        assert "no streets" in str(exc)
        return
    check_breakpoints(topo)
    for e in range(topo.n_edges):
        offset = frac * topo.edge_length[e]
        starts, cells = topo.cell_pieces(e)
        containing = [
            c for k, c in enumerate(cells)
            if starts[k] <= offset < (starts[k + 1] if k + 1 < len(starts) else np.inf)
        ]  # fmt: skip
        assert len(containing) == 1
        assert topo.cell_at(e, offset) == containing[0]
