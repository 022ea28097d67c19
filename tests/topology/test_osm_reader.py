"""Reading OpenStreetMap XML: tags -> networks, areas, building heights, layers, routes, bbox, bad files."""

from __future__ import annotations

import bz2

import pytest

from topology.artifact import CELL_AREA
from topology.build import BuildError, build, read_map
from topology.osm_reader import read_osm
from topology.raw import PEDESTRIAN, TRAM, VEHICLE

LAT0, LON0 = 60.17, 24.94
D = 0.0009  # ~100 m north, ~50 m east


def osm_xml(nodes, ways, relations=()):
    out = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="test">']
    for nid, (dx, dy), tags in nodes:
        tag = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        out.append(f'<node id="{nid}" version="1" lat="{LAT0 + dy * D}" lon="{LON0 + dx * D}">{tag}</node>')
    for wid, refs, tags in ways:
        nd = "".join(f'<nd ref="{r}"/>' for r in refs)
        tag = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        out.append(f'<way id="{wid}" version="1">{nd}{tag}</way>')
    for rid, members, tags in relations:
        mem = "".join(f'<member type="{t}" ref="{r}" role="{role}"/>' for t, r, role in members)
        tag = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        out.append(f'<relation id="{rid}" version="1">{mem}{tag}</relation>')
    out.append("</osm>")
    return "\n".join(out)


NODES = [
    (1, (0, 0), {}), (2, (1, 0), {}), (3, (2, 0), {"railway": "tram_stop", "name": "Stop A"}),
    (4, (1, -1), {}), (5, (1, 1), {}),
    (10, (3, 3), {}), (11, (3.2, 3), {}), (12, (3.2, 3.2), {}), (13, (3, 3.2), {}),
    (20, (0, 2), {}), (21, (0.5, 2), {}), (22, (0.5, 2.5), {}), (23, (0, 2.5), {}),
    (30, (5, 5), {}), (31, (6, 5), {}),
]  # fmt: skip
WAYS = [
    (100, [1, 2, 3], {"highway": "residential", "name": "Main"}),
    (101, [4, 2, 5], {"highway": "footway"}),
    (102, [1, 2, 3], {"railway": "tram"}),
    (103, [10, 11, 12, 13, 10], {"building": "yes", "height": "12.13 m"}),
    (104, [20, 21, 22, 23, 20], {"place": "square", "name": "Square"}),
    (105, [30, 31], {"highway": "construction"}),
    (106, [4, 5], {"highway": "corridor"}),
]


@pytest.fixture
def osm_file(tmp_path):
    rel = [(900, [("w", 102, ""), ("n", 3, "stop")], {"type": "route", "route": "tram", "ref": "3"})]
    path = tmp_path / "m.osm"
    path.write_text(osm_xml(NODES, WAYS, rel))
    return path


def test_networks_areas_buildings_routes(osm_file):
    raw = read_osm(osm_file)
    by_id = {w.way_id: w for w in raw.ways}
    assert by_id[100].networks == PEDESTRIAN | VEHICLE
    assert by_id[101].networks == PEDESTRIAN
    assert by_id[102].networks == TRAM
    assert 105 not in by_id and 106 not in by_id
    assert raw.report["skipped:not_a_modelled_network"] == 2
    assert [b.height for b in raw.buildings] == [pytest.approx(12.13)]
    assert [a.kind for a in raw.areas] == ["square"]
    assert raw.routes[0].mode == "tram" and raw.routes[0].stops[0].name == "Stop A"
    assert raw.crs == "EPSG:32635"


def test_bz2_and_build_with_route(osm_file, tmp_path):
    bz = tmp_path / "m.osm.bz2"
    bz.write_bytes(bz2.compress(osm_file.read_bytes()))
    topo = build(read_map(bz))
    assert (topo.cell_kind == CELL_AREA).sum() == 1
    (route,) = topo.routes
    assert route["ref"] == "3" and route["edges"]
    assert all(topo.edge_networks[e] & TRAM for e, _ in route["edges"])
    assert route["stops"] and route["stops"][0]["name"] == "Stop A"


def test_bbox_drops_features_outside(osm_file):
    raw = read_osm(osm_file, bbox=(LON0 - D, LAT0 - 2 * D, LON0 + 2.5 * D, LAT0 + 1.5 * D))
    assert raw.report["dropped:outside_bbox"] >= 2  # the building and the square lie outside
    assert not raw.buildings and not raw.areas


def test_explicit_crs(osm_file):
    raw = read_osm(osm_file, crs="EPSG:3067")
    assert raw.crs == "EPSG:3067"
    with pytest.raises(ValueError, match="unknown CRS"):
        read_osm(osm_file, crs="EPSG:999999")


def test_layers_bridge_over_street(tmp_path):
    nodes = [(1, (0, 0), {}), (2, (1, 0), {}), (3, (2, 0), {}), (4, (1, -1), {}), (5, (1, 1), {})]
    ways = [
        (1, [1, 2, 3], {"highway": "residential"}),
        (2, [4, 2, 5], {"highway": "footway", "bridge": "yes", "layer": "1"}),
    ]
    path = tmp_path / "b.osm"
    path.write_text(osm_xml(nodes, ways))
    topo = build(read_map(path))
    assert topo.n_edges == 2  # the bridge shares node 2 but is not joined to the street below


def test_building_part_above_ground_and_levels(tmp_path):
    nodes = [(1, (0, 0), {}), (2, (1, 0), {})] + [
        (10 + i, p, {}) for i, p in enumerate([(0, 1), (0.2, 1), (0.2, 1.2), (0, 1.2)])
    ]
    nodes += [(20 + i, p, {}) for i, p in enumerate([(0.5, 1), (0.7, 1), (0.7, 1.2), (0.5, 1.2)])]
    ways = [
        (1, [1, 2], {"highway": "residential"}),
        (2, [10, 11, 12, 13, 10], {"building:part": "yes", "building:levels": "5", "min_height": "10"}),
        (3, [20, 21, 22, 23, 20], {"building": "yes", "building:levels": "5", "roof:levels": "1"}),
    ]
    path = tmp_path / "p.osm"
    path.write_text(osm_xml(nodes, ways))
    raw = read_osm(path)
    assert raw.report["dropped:building_part_above_ground"] == 1
    assert [round(b.height, 1) for b in raw.buildings] == [round(6 * 3.2 + 1.0, 1)]


def test_not_osm_is_a_clear_error(tmp_path):
    bad = tmp_path / "x.osm"
    bad.write_text("<html><body>hello</body></html>")
    with pytest.raises(BuildError):
        read_map(bad)
    empty = tmp_path / "e.osm"
    empty.write_text(osm_xml([(1, (0, 0), {})], []))
    with pytest.raises(BuildError, match="no streets"):
        read_map(empty)


def test_outline_with_parts_is_replaced_by_its_parts(tmp_path):
    outline = [(30 + i, p, {}) for i, p in enumerate([(0, 1), (1, 1), (1, 2), (0, 2)])]
    part = [(40 + i, p, {}) for i, p in enumerate([(0.1, 1.1), (0.5, 1.1), (0.5, 1.5), (0.1, 1.5)])]
    nodes = [(1, (0, 0), {}), (2, (1, 0), {}), *outline, *part]
    ways = [
        (1, [1, 2], {"highway": "residential"}),
        (2, [30, 31, 32, 33, 30], {"building": "yes"}),
        (3, [40, 41, 42, 43, 40], {"building:part": "yes", "height": "33"}),
    ]
    path = tmp_path / "parts.osm"
    path.write_text(osm_xml(nodes, ways))
    raw = read_osm(path)
    assert raw.report["repaired:outline_replaced_by_parts"] == 1
    assert [b.height for b in raw.buildings] == [33.0]
