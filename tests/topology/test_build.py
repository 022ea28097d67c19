"""The build on hard, degenerate and bad input: every case gets a topology or a clear error, and a report."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.topology.mapfixtures import box, collection, grid, polygon, street
from topology.artifact import CELL_AREA, CELL_JUNCTION, CELL_STREET
from topology.build import BuildError, build, read_map
from topology.geojson_reader import geojson_to_raw
from topology.raw import PEDESTRIAN, TRAM, VEHICLE


def build_doc(doc, **kw):
    return build(geojson_to_raw(doc), **kw)


def degree(topo, node):
    return len(topo.edges_of_node(node))


def check_breakpoints(topo):
    """Every edge: breakpoints start at 0, strictly increase, name real cells that list the edge."""
    for e in range(topo.n_edges):
        starts, cells = topo.cell_pieces(e)
        assert len(starts) >= 1 and starts[0] == 0.0
        assert np.all(np.diff(starts) > 0)
        assert np.all(starts < topo.edge_length[e] + 1e-9)
        for c in cells:
            assert 0 <= c < topo.n_cells
            assert e in topo.cell_edges_of(int(c))


def test_grid_makes_junction_and_street_cells():
    topo = build_doc(collection(*grid(3, 3)))
    # 9 crossings: 4 corners (degree 2, merged away), 4 T, 1 X
    degrees = sorted(degree(topo, n) for n in range(topo.n_nodes))
    assert degrees.count(4) == 1 and degrees.count(3) == 4
    assert (topo.cell_kind == CELL_JUNCTION).sum() == 5
    assert (topo.cell_kind == CELL_STREET).sum() >= 8
    check_breakpoints(topo)
    x_cell = [c for c in range(topo.n_cells) if topo.cell_kind[c] == CELL_JUNCTION and len(topo.cell_edges_of(c)) == 4]
    assert len(x_cell) == 1  # the X-shaped crossing cell has four arms


def test_zero_length_segments_and_repeated_points_are_repaired():
    doc = collection(
        street([(0, 0), (0, 0), (50, 0), (50, 0), (100, 0)]),
        street([(50, 0), (50, 0)]),  # zero-length way
        street([(50, 0), (50, 80)]),
    )
    topo = build_doc(doc)
    rep = topo.meta["report"]
    assert rep["repaired:repeated_point"] >= 2
    assert rep["dropped:zero_length_way"] == 1
    check_breakpoints(topo)
    assert np.all(topo.edge_length > 0)


def test_duplicate_ways_are_dropped_and_networks_merged():
    doc = collection(
        street([(0, 0), (100, 0)], network="vehicle"),
        street([(0, 0), (100, 0)], network="pedestrian"),
        street([(100, 0), (100, 100)]),
        street([(100, 0), (200, 0)]),
    )
    topo = build_doc(doc)
    assert topo.meta["report"]["dropped:duplicate_segment"] == 1
    (west,) = [e for e in range(topo.n_edges) if topo.edge_polyline(e)[:, 0].min() < topo.node_xy[:, 0].min() + 1]
    assert topo.edge_networks[west] == PEDESTRIAN | VEHICLE  # the kept copy carries both ways' networks


def test_ways_crossing_without_shared_node_are_not_joined():
    doc = collection(street([(0, 0), (100, 0)]), street([(50, -50), (50, 50)]))
    topo = build_doc(doc)
    assert topo.n_edges == 2
    assert (topo.cell_kind == CELL_JUNCTION).sum() == 0


def test_bridge_over_street_sharing_an_interior_node_is_not_joined():
    feats = [street([(0, 0), (50, 0), (100, 0)]), street([(50, -50), (50, 0), (50, 50)], layer=1)]
    topo = build_doc(collection(*feats))
    assert topo.meta["report"]["repaired:layer_crossing_not_joined"] >= 2
    assert all(degree(topo, n) <= 2 for n in range(topo.n_nodes))


def test_closed_way_roundabout_and_hairpin():
    arms = [street([(30, 15), (80, 15)]), street([(-50, 15), (0, 15)])]
    ring_way = street([(0, 0), (30, 0), (30, 15), (30, 30), (0, 30), (0, 15), (0, 0)])
    hairpin = street([(200, 0), (300, 0), (300, 1), (200, 1)])
    topo = build_doc(collection(ring_way, *arms, hairpin))
    check_breakpoints(topo)
    junctions = {n for n in range(topo.n_nodes) if degree(topo, n) == 3}
    assert len(junctions) == 2  # where the arms meet the ring
    ring_edges = [e for e in range(topo.n_edges) if set(topo.edge_nodes[e].tolist()) == junctions]
    assert len(ring_edges) == 2  # the closed way is split at the two arms into two edges
    lengths = sorted(np.round(topo.edge_length, 1))
    assert 201.0 in lengths  # the hairpin survives as one edge of its full length


def test_self_loop_edge_has_one_junction_cell_at_both_ends():
    loop = street([(0, 0), (100, 0), (100, 100), (0, 100), (0, 0)])
    spokes = [street([(0, 0), (-100, 0)]), street([(0, 0), (0, -100)])]
    topo = build_doc(collection(loop, *spokes))
    check_breakpoints(topo)
    loops = [e for e in range(topo.n_edges) if topo.edge_nodes[e, 0] == topo.edge_nodes[e, 1]]
    assert len(loops) == 1
    starts, cells = topo.cell_pieces(loops[0])
    assert cells[0] == cells[-1] and topo.cell_kind[cells[0]] == CELL_JUNCTION


def test_self_touching_way_splits_at_the_touch():
    way = street([(0, 0), (50, 0), (100, 0), (100, 50), (50, 50), (50, 0), (50, -60)])
    # the way passes (50, 0) twice: it touches itself there and must split into edges meeting at that node
    topo = build_doc(collection(way))
    check_breakpoints(topo)
    assert any(degree(topo, n) >= 3 for n in range(topo.n_nodes))


def test_street_shorter_than_two_junction_pieces_between_crossings():
    # two crossings 10 m apart (junction radius 16 m): merged into one junction cell
    feats = [
        street([(-100, 0), (0, 0), (10, 0), (110, 0)]),
        street([(0, -100), (0, 0), (0, 100)]),
        street([(10, -100), (10, 0), (10, 100)]),
    ]
    topo = build_doc(collection(*feats))
    check_breakpoints(topo)
    short = [e for e in range(topo.n_edges) if abs(topo.edge_length[e] - 10) < 1e-6]
    assert len(short) == 1
    starts, cells = topo.cell_pieces(short[0])
    assert len(cells) == 1 and topo.cell_kind[cells[0]] == CELL_JUNCTION
    assert len(topo.cell_nodes_of(int(cells[0]))) == 2  # one cell for both crossings


def test_short_edge_between_far_apart_clusters_is_split_not_merged():
    from topology.build import BuildConfig
    from topology.cells import CellParams

    feats = [
        street([(-100, 0), (0, 0), (20, 0), (120, 0)]),
        street([(0, -100), (0, 0), (0, 100)]),
        street([(20, -100), (20, 0), (20, 100)]),
    ]
    cfg = BuildConfig(cells=CellParams(max_junction_cluster_m=5.0))
    topo = build_doc(collection(*feats), config=cfg)
    check_breakpoints(topo)
    short = [e for e in range(topo.n_edges) if abs(topo.edge_length[e] - 20) < 1e-6][0]
    starts, cells = topo.cell_pieces(short)
    assert len(cells) == 2 and all(topo.cell_kind[c] == CELL_JUNCTION for c in cells)
    assert starts[1] == pytest.approx(10.0)


def test_long_street_is_split_into_capped_cells():
    topo = build_doc(collection(street([(0, 0), (500, 0)])))
    starts, cells = topo.cell_pieces(0)
    assert len(cells) == 9  # 500 m / 60 m cap
    assert np.allclose(np.diff(starts), 500 / 9)


def test_area_with_hole_joins_streets_that_reach_it():
    square = polygon(box(0, 0, 100, 100), holes=[box(40, 40, 60, 60)], area="square", network="pedestrian")
    feats = [square, street([(-100, 50), (0, 50)], network="pedestrian"),
             street([(100, 50), (200, 50)], network="pedestrian"),
             street([(20, 20), (80, 20)], network="pedestrian")]  # fmt: skip
    topo = build_doc(collection(*feats))
    assert (topo.cell_kind == CELL_AREA).sum() == 1
    area_node = int(topo.area_node[0])
    assert degree(topo, area_node) == 2  # the two streets that reach it; the path inside is the area itself
    assert topo.meta["report"]["repaired:edge_inside_area"] == 1
    assert len(topo.area_polygons.to_shapely()[0].interiors) == 1


def test_street_crossing_an_area_is_clipped_at_both_sides():
    square = polygon(box(0, 0, 100, 100), area="square", network="pedestrian")
    topo = build_doc(collection(square, street([(-100, 50), (200, 50)], network="pedestrian")))
    area_node = int(topo.area_node[0])
    assert degree(topo, area_node) == 2
    assert sorted(np.round(topo.edge_length)) == [100.0, 100.0]


def test_vehicle_road_through_pedestrian_square_is_not_clipped():
    square = polygon(box(0, 0, 100, 100), area="square", network="pedestrian")
    topo = build_doc(collection(square, street([(-100, 50), (200, 50)], network="vehicle")))
    assert topo.n_edges == 1 and topo.edge_length[0] == pytest.approx(300)


def test_bow_tie_polygon_is_repaired():
    bowtie = polygon([(0, 0), (50, 50), (50, 0), (0, 50), (0, 0)], building="yes", height="12.13 m")
    topo = build_doc(collection(street([(-50, -50), (100, -50)]), bowtie))
    assert topo.meta["report"]["repaired:building_invalid_polygon"] == 1
    assert len(topo.building_height) == 2  # two triangles
    assert np.allclose(topo.building_height, 12.13)
    for p in topo.building_footprints.to_shapely():
        assert p.is_valid


def test_heights_parse_and_bad_height_is_counted():
    feats = [street([(-50, -50), (100, -50)]),
             polygon(box(0, 0, 10, 10), building="yes", height="3,5"),
             polygon(box(20, 0, 30, 10), building="yes", height="tall"),
             polygon(box(40, 0, 50, 10), building="yes", **{"building:levels": "4"})]  # fmt: skip
    topo = build_doc(collection(*feats))
    h = sorted(np.round(topo.building_height, 2))
    assert 3.5 in h and 20.0 in h and 13.8 in h
    assert topo.meta["report"]["repaired:unparsable_height"] == 1


def test_missing_tags_are_skipped_and_counted():
    doc = collection(street([(0, 0), (100, 0)]), {"type": "Feature", "geometry": {"type": "LineString",
                     "coordinates": [[385000, 6672010], [385100, 6672010]]}, "properties": {}})  # fmt: skip
    topo = build_doc(doc)
    assert topo.meta["report"]["skipped:line_without_network"] == 1
    assert topo.n_edges == 1


def test_malformed_features_are_skipped():
    doc = collection(street([(0, 0), (100, 0)]))
    doc["features"] += [{"type": "Feature", "geometry": {"type": "LineString", "coordinates": "nope"}},
                        {"type": "Feature"}, street([(0, 0), (float("nan"), 5)])]  # fmt: skip
    topo = build_doc(doc)
    assert topo.meta["report"]["dropped:malformed_feature"] == 2
    assert topo.meta["report"]["dropped:non_finite_coordinates"] == 1


def test_map_without_streets_is_a_clear_error():
    doc = collection(polygon(box(0, 0, 10, 10), building="yes"))
    with pytest.raises(BuildError, match="no streets"):
        build_doc(doc)


def test_file_that_is_not_map_data_is_a_clear_error(tmp_path):
    junk = tmp_path / "junk.pbf"
    junk.write_bytes(b"\x00\x01 this is not osm \xff" * 100)
    with pytest.raises(BuildError, match="not readable OpenStreetMap data|no streets"):
        read_map(junk)
    txt = tmp_path / "notes.geojson"
    txt.write_text("hello")
    with pytest.raises(BuildError, match="not GeoJSON"):
        read_map(txt)
    wrong = tmp_path / "wrong.geojson"
    wrong.write_text(json.dumps({"type": "Point", "coordinates": [0, 0]}))
    with pytest.raises(BuildError, match="FeatureCollection"):
        read_map(wrong)


def test_tram_network_is_separate_but_shares_nodes():
    feats = [street([(0, 0), (100, 0), (200, 0)], network="tram"), street([(100, -100), (100, 0), (100, 100)])]
    topo = build_doc(collection(*feats))
    tram = np.flatnonzero(topo.edge_networks & TRAM)
    road = np.flatnonzero(topo.edge_networks & VEHICLE)
    assert len(tram) == 2 and len(road) == 2
    shared = set(topo.edge_nodes[tram].ravel()) & set(topo.edge_nodes[road].ravel())
    assert len(shared) == 1
