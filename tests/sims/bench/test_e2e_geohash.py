"""HFP geohash boxes, topics and the cover of a disc (sims.bench.hfp_geohash), and the wire sizes the
end-to-end benchmark counts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sims.bench import hfp_geohash as gh
from sims.bench.e2e_run import PeriodicDecoder, filter_of, topic_of
from sims.bench.e2e_transports import mqtt_wire_size, redis_wire_size


def _finest(boxes: set[gh.Box]) -> set[tuple[int, int]]:
    """Every finest box inside `boxes` (merged prefixes expanded)."""
    out = set()
    for b in boxes:
        k = 10 ** (gh.FINEST - b.level)
        out |= {(b.ilat * k + i, b.ilon * k + j) for i in range(k) for j in range(k)}
    return out


def _check_cover(lat: float, lon: float, r: float) -> set[tuple[int, int]]:
    """The cover holds the box of every point of the disc, and no box wholly farther than r (+1 %)."""
    cover = _finest(gh.disc_cover(lat, lon, r))
    rng = np.random.default_rng(3)
    m_lon = gh.M_PER_DEG * math.cos(math.radians(lat))
    for _ in range(3000):
        a, d = rng.uniform(0, 2 * math.pi), r * math.sqrt(rng.uniform(0, 1))
        p = gh.box_of(lat + d * math.sin(a) / gh.M_PER_DEG, lon + d * math.cos(a) / m_lon)
        assert (p.ilat, p.ilon) in cover
    s = 10 ** gh.FINEST
    for i, j in cover:
        ny = (min(max(lat, i / s), (i + 1) / s) - lat) * gh.M_PER_DEG
        nx = (min(max(lon, j / s), (j + 1) / s) - lon) * m_lon
        assert math.hypot(nx, ny) <= r * 1.01
    return cover


def test_box_and_topic_follow_hfp_digits():
    b = gh.box_of(60.18856, 24.95571)
    assert (b.level, b.ilat, b.ilon) == (3, 60188, 24955)
    assert gh.topic_tail(b) == "60;24/19/85/85"
    assert gh.topic_tail(b.parent()) == "60;24/19/85"
    assert gh.topic_tail(gh.Box(0, 60, 24)) == "60;24"
    t = topic_of(b, "bus", 17)
    assert t.endswith("/bus/17/60;24/19/85/85") and filter_of(b).endswith("/+/+/60;24/19/85/85/#")


def test_disc_cover_holds_the_whole_disc_and_nothing_far():
    cover = _check_cover(60.1699, 24.9384, 500.0)
    assert 100 < len(cover) < 250  # about (1000/111 + 1) x (1000/55 + 1) boxes, fewer in the disc


def test_disc_across_degree_boundaries_reaches_both_sides():
    cover = _check_cover(59.9999, 24.9999, 500.0)  # the corner of four integer-degree boxes
    assert {i // 1000 for i, _ in cover} == {59, 60} and {j // 1000 for _, j in cover} == {24, 25}
    tails = {gh.topic_tail(b).split("/")[0] for b in gh.disc_cover(59.9999, 24.9999, 500.0)}
    assert tails == {"59;24", "59;25", "60;24", "60;25"}


def test_disc_at_the_map_edge_still_covers_around_the_camera(helsinki):
    from topology.projection import LocalProjection

    b = helsinki.cell_footprints.bounds()
    proj = LocalProjection(helsinki.meta["crs"], tuple(helsinki.meta["origin"]))
    lon, lat = proj.to_wgs84(np.array([[b[:, 0].min(), b[:, 1].min()]]))[0]  # the map's south-west corner
    cover = _check_cover(float(lat), float(lon), 500.0)
    own = gh.box_of(float(lat), float(lon))
    assert (own.ilat, own.ilon) in cover


def test_complete_children_merge_into_their_parent():
    kids = {gh.Box(3, 60180 + i, 24950 + j) for i in range(10) for j in range(10)}
    assert gh.merge(kids) == {gh.Box(2, 6018, 2495)}
    assert gh.merge(kids - {gh.Box(3, 60180, 24950)}) == kids - {gh.Box(3, 60180, 24950)}
    big = gh.disc_cover(60.17, 24.94, 3000.0)  # 6 km across: whole level-2 boxes inside
    assert any(b.level == 2 for b in big)


@pytest.mark.parametrize("lat, lon, r", [(math.nan, 24.9, 500.0), (60.1, math.inf, 500.0), (60.1, 24.9, math.nan),
                                         (60.1, 24.9, 0.0), (-33.9, 151.2, 500.0), (60.1, 24.9, -5.0)])
def test_bad_cameras_and_radii_are_refused(lat, lon, r):
    with pytest.raises(ValueError):
        gh.disc_cover(lat, lon, r)


def test_cell_boxes_cover_each_cells_footprint(helsinki):
    import shapely

    from topology.projection import LocalProjection

    boxes = gh.cell_boxes(helsinki)
    assert len(boxes) == helsinki.n_cells and all(boxes)
    proj = LocalProjection(helsinki.meta["crs"], tuple(helsinki.meta["origin"]))
    polys = helsinki.cell_footprints.to_shapely()
    for c in range(0, helsinki.n_cells, 97):
        pt = shapely.point_on_surface(polys[c])
        lon, lat = proj.to_wgs84(np.array([[pt.x, pt.y]]))[0]
        assert gh.box_of(float(lat), float(lon)) in boxes[c]


def test_wire_sizes_are_the_packets_and_pushes():
    assert mqtt_wire_size("a/b", b"xyz") == 1 + 1 + 2 + 3 + 3
    assert mqtt_wire_size("t", b"x" * 200) == 1 + 2 + 2 + 1 + 200  # remaining length 203: two varint bytes
    push = b"*3\r\n$7\r\nmessage\r\n$4\r\ng:ab\r\n$3\r\nxyz\r\n"
    assert redis_wire_size("g:ab", b"xyz") == len(push)


def test_malformed_position_reports_are_refused_and_good_ones_decoded(helsinki):
    from topology.projection import LocalProjection

    proj = LocalProjection(helsinki.meta["crs"], tuple(helsinki.meta["origin"]))
    dec = PeriodicDecoder(proj)
    lon, lat = proj.to_wgs84(np.array([[10.0, 20.0]]))[0]
    veh, seq, model = dec.decode(b'{"VP":{"veh":5,"tsi":28800.5,"lat":%.7f,"long":%.7f}}' % (lat, lon))
    assert (veh, seq) == (5, 28800500) and model.xy_at(28801.0) == pytest.approx((10.0, 20.0), abs=0.05)
    for bad in (b"not json", b'{"VP":{"veh":5}}', b'{"VP":{"veh":5,"tsi":1,"lat":NaN,"long":24}}', b"[]",
                b'{"VP":{"veh":"x","tsi":1,"lat":60,"long":24}}', b"\xff\xfe"):
        with pytest.raises(ValueError):
            dec.decode(bad)
        with pytest.raises(ValueError):  # cached: refused again, not re-parsed into something else
            dec.decode(bad)


@pytest.mark.parametrize("missing", ["gmqtt", "redis"])
def test_the_suite_names_a_missing_client_library(missing, monkeypatch):
    import argparse
    import sys

    from entitynet.cli import CommandError
    from sims.bench import e2e_bench

    monkeypatch.setitem(sys.modules, missing, None)  # import fails as if not installed
    with pytest.raises(CommandError, match=f"needs {missing}.*bench"):
        e2e_bench.run(argparse.Namespace(quick=True, out=None, topology=None), lambda m: None)
