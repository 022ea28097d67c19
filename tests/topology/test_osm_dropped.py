"""Buildings and areas that osmium never assembles are counted in the build report (issue 9, item 15)."""

from __future__ import annotations

from tests.topology.test_osm_reader import NODES, WAYS, osm_xml
from topology.build import build, features_dropped, read_map
from topology.osm_reader import read_osm

EXTRA_NODES = [(40, (7, 7), {}), (41, (7.2, 7), {}), (42, (7.2, 7.2), {}),
               (50, (8, 8), {}), (51, (8.2, 8), {}), (52, (8.2, 8.2), {})]  # fmt: skip
EXTRA_WAYS = [
    (200, [40, 41, 42, 999, 40], {"building": "yes"}),  # node 999 is not in the extract
    (201, [40], {"building": "yes"}),  # a one-node way
    (202, [50, 51, 52], {"building": "yes"}),  # not closed
    (203, [50, 51, 52, 50, 51, 52, 50], {"building": "yes"}),  # osmium builds no rings: repaired (item 21.14)
    (204, [50, 51], {}),  # the only member of an open multipolygon (built with no rings)
    (205, [40, 41, 998, 40], {}),  # a member with a node missing from the extract
    (206, [42, 997, 40, 42], {"place": "square"}),  # an area way with a node missing
]
EXTRA_RELATIONS = [
    (300, [("w", 777, "outer"), ("w", 778, "outer")], {"type": "multipolygon", "building": "yes"}),
    (301, [("w", 204, "outer")], {"type": "multipolygon", "building": "yes"}),
    (302, [("w", 205, "outer")], {"type": "multipolygon", "building": "yes"}),
]


def test_every_kind_of_unassembled_building_is_counted(tmp_path):
    path = tmp_path / "b.osm"
    path.write_text(osm_xml(NODES + EXTRA_NODES, WAYS + EXTRA_WAYS, EXTRA_RELATIONS))
    raw = read_osm(path)
    r = raw.report
    # the one good building of the base map, and way 203 (its ring twice round a triangle) repaired to one
    assert sorted(b.building_id for b in raw.buildings) == [103, 203]
    assert r["repaired:building_invalid_polygon"] == 1
    assert r["dropped:building_missing_node_location"] == 1
    assert r["dropped:building_one_node_way"] == 1
    assert r["dropped:building_way_not_closed"] == 1
    assert r["dropped:building_no_rings"] == 1  # relation 301
    assert r["dropped:building_relation_members_missing"] == 2  # relations 300 (absent) and 302 (incomplete)
    assert r["dropped:area_missing_node_location"] == 1
    # and the totals the build report prints
    topo = build(read_map(path))
    assert features_dropped(topo.meta["report"]) >= 8


def test_a_clean_map_counts_nothing_dropped_for_polygons(tmp_path):
    path = tmp_path / "m.osm"
    path.write_text(osm_xml(NODES, WAYS))
    r = read_osm(path).report
    assert not [k for k in r if k.startswith(("dropped:building", "dropped:area"))]
