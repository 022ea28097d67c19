"""The bundled Helsinki map builds into a sane topology (built once per session in conftest)."""

from __future__ import annotations

import numpy as np

from tests.topology.test_build import check_breakpoints
from topology.artifact import CELL_AREA, CELL_JUNCTION, CELL_STREET
from topology.raw import PEDESTRIAN, TRAM, VEHICLE


def test_counts_and_networks(helsinki):
    c = helsinki.meta["counts"]
    assert c["nodes"] > 1000 and c["edges"] > 1500 and c["buildings"] > 400
    for kind in (CELL_STREET, CELL_JUNCTION, CELL_AREA):
        assert (helsinki.cell_kind == kind).sum() > 10
    for bit in (PEDESTRIAN, VEHICLE, TRAM):
        assert (helsinki.edge_networks & bit).any()
    x0, y0, x1, y1 = helsinki.meta["bounds"]
    assert 900 < x1 - x0 < 1300 and 1400 < y1 - y0 < 1900  # about 1.1 x 1.7 km


def test_every_edge_is_covered_by_cells(helsinki):
    check_breakpoints(helsinki)


def test_coordinates_are_local_and_small(helsinki):
    assert np.abs(helsinki.edge_geom_xy).max() < 2000
    assert helsinki.meta["origin"][1] > 6.6e6  # UTM northing lives in the origin, not in the arrays


def test_tram_routes_follow_tram_edges(helsinki):
    trams = [r for r in helsinki.routes if r["mode"] == "tram"]
    assert len(trams) >= 5
    for r in trams:
        assert all(helsinki.edge_networks[e] & TRAM for e, _ in r["edges"])


def test_placement_index(helsinki):
    idx = helsinki.placement_index()
    e = int(np.flatnonzero(helsinki.edge_networks & VEHICLE)[0])
    x, y = helsinki.point_at(e, helsinki.edge_length[e] / 2)
    p = idx.place(x + 0.5, y + 0.5, VEHICLE)
    assert p.kind == "edge" and p.distance < 1.0
    a = helsinki.area_polygons.to_shapely()[0].representative_point()
    pa = idx.place(a.x, a.y, int(helsinki.area_networks[0]))
    assert pa.kind == "area"


def test_routes_are_connected_paths_with_stops(helsinki):
    from entitynet.client.network import netview
    from entitynet.client.path import Path

    net = netview(helsinki)
    assert len({r["id"] for r in helsinki.routes}) >= 170
    for r in helsinki.routes:  # every stored route (or piece of one) is a connected path
        Path(net, r["edges"])
    report = helsinki.meta["report"]
    assert report["read:routes_matched"] == len({r["id"] for r in helsinki.routes})
    split = {r["id"] for r in helsinki.routes if "part" in r}
    assert report.get("repaired:route_split_into_pieces", 0) == len(split)
    trams = [r for r in helsinki.routes if r["mode"] == "tram"]
    assert sum(len(r["stops"]) for r in trams) >= 20
    for r in trams:
        route_edges = {e for e, _ in r["edges"]}
        assert all(s["edge"] in route_edges for s in r["stops"])
