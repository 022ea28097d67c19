"""GTFS reading and shape matching on the real HSL feed (skipped when ../shared is absent)."""

import os
from pathlib import Path

import numpy as np
import pytest

# ../shared beside the clone; ENTITYNET_SHARED overrides (a worktree elsewhere), as in tests/proxies/conftest.py
SHARED = Path(os.environ.get("ENTITYNET_SHARED") or Path(__file__).resolve().parents[3] / "shared")
FEED = SHARED / "data" / "hsl-gtfs-2022-02.zip"
pytestmark = pytest.mark.skipif(not FEED.exists(), reason="../shared/data/hsl-gtfs-2022-02.zip absent")


def test_read_feed_keeps_tram_and_bus_shapes_with_their_stops():
    from topology.gtfs import read_feed, trip_stops

    feed = read_feed(FEED, modes=("tram",))
    assert feed.shapes and all(feed.routes[feed.shape_route[s]][0] == "tram" for s in feed.shapes)
    lonlat = np.concatenate(list(feed.shapes.values()))
    assert (24.8 < lonlat[:, 0]).all() and (lonlat[:, 0] < 25.3).all() and (60.1 < lonlat[:, 1]).all()
    sid = sorted(feed.shapes)[0]
    stops = trip_stops(FEED, {feed.shape_trip[sid]})[feed.shape_trip[sid]]
    assert len(stops) > 5 and all(s in feed.stops for s in stops)


def test_tram_shapes_match_onto_the_tram_network_of_a_synthetic_map():
    """A synthetic tram line laid along one real tram shape (projected): the matcher must find it."""
    from tests.entitynet.client_fixtures import make_topology
    from topology.gtfs import match_shapes, read_feed
    from topology.projection import LocalProjection
    from topology.raw import TRAM

    feed = read_feed(FEED, modes=("tram",))
    sid = sorted(feed.shapes)[0]
    raw = LocalProjection("EPSG:3067", (0.0, 0.0)).to_local(feed.shapes[sid][:, 0], feed.shapes[sid][:, 1])
    origin = np.round(raw[len(raw) // 2])
    xy = (raw - origin)[len(raw) // 2 : len(raw) // 2 + 60]
    assert len(xy) >= 10
    nodes = {f"N{i}": tuple(p) for i, p in enumerate(xy[::6])}
    names = list(nodes)
    topo = make_topology(nodes, [(a, b, TRAM) for a, b in zip(names, names[1:], strict=False)])
    lo, hi = xy.min(axis=0) - 100.0, xy.max(axis=0) + 100.0
    topo.meta.update(crs="EPSG:3067", origin=[float(origin[0]), float(origin[1])],
                     bounds=[lo[0], lo[1], hi[0], hi[1]])
    feed.shapes = {sid: feed.shapes[sid]}
    got = match_shapes(feed, topo, modes=("tram",), min_length=100.0)
    assert got and got[0].shape_id == sid
    edges = [e for e, _d in got[0].edges]
    assert len(edges) >= len(names) // 2 and edges == sorted(edges)  # in travel order along the line
