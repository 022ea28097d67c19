"""Invalid building and area polygons are repaired, not dropped (issue 21, item 14): a self-intersecting closed
way (a bow-tie, a common OSM mistake) is one osmium builds no ring for; the reader makes it valid
(`shapely.make_valid`), counts the repair in the build report, and drops only what cannot be repaired. A map
whose ways all sit at one point is refused with an error that says so."""

from __future__ import annotations

import pytest

from tests.topology.test_osm_reader import NODES, WAYS, osm_xml
from topology.build import BuildError, build, read_map, report_lines
from topology.osm_reader import read_osm

BOW_NODES = [(60, (7, 7), {}), (61, (7.2, 7.2), {}), (62, (7.2, 7), {}), (63, (7, 7.2), {}),
             (70, (9, 9), {}), (71, (9.4, 9.4), {}), (72, (9.4, 9), {}), (73, (9, 9.4), {}),
             (80, (11, 11), {}), (81, (11.2, 11), {}), (82, (11.4, 11), {})]  # fmt: skip
BOW_WAYS = [
    (210, [60, 61, 62, 63, 60], {"building": "yes", "height": "9"}),  # a bow-tie building
    (211, [70, 71, 72, 73, 70], {"leisure": "park"}),  # a bow-tie park
    (212, [80, 81, 82, 81, 80], {"building": "yes"}),  # collinear: nothing to repair
]


@pytest.fixture
def bowtie_map(tmp_path):
    path = tmp_path / "bow.osm"
    path.write_text(osm_xml(NODES + BOW_NODES, WAYS + BOW_WAYS))
    return path


def test_self_intersecting_ways_are_repaired_and_counted(bowtie_map):
    raw = read_osm(bowtie_map)
    r = raw.report
    bows = [b for b in raw.buildings if b.building_id == 210]
    assert len(bows) == 2  # the bow-tie's two triangles
    assert all(b.polygon.is_valid and b.polygon.area > 10.0 for b in bows)
    assert all(b.height == pytest.approx(9.0) for b in bows)
    park = [a for a in raw.areas if a.area_id == 211]
    assert len(park) == 2 and all(a.polygon.is_valid for a in park)
    assert r["repaired:building_invalid_polygon"] == 1
    assert r["repaired:area_invalid_polygon"] == 1
    # the collinear way has no area to repair: dropped, and counted
    assert not [b for b in raw.buildings if b.building_id == 212]
    assert r["dropped:building_degenerate_polygon"] == 1
    assert "dropped:building_no_rings" not in r and "dropped:area_no_rings" not in r


def test_the_repairs_reach_the_build_report(bowtie_map):
    topo = build(read_map(bowtie_map))
    report = topo.meta["report"]
    assert report["repaired:building_invalid_polygon"] == 1
    assert "  building invalid polygon: 1" in report_lines(report)
    assert len(topo.building_height) == 3  # the base map's building and the bow-tie's two halves


def test_a_map_whose_ways_sit_at_one_point_says_they_have_zero_length(tmp_path):
    nodes = [(1, (0, 0), {}), (2, (0, 0), {}), (3, (0, 0), {}), (4, (0, 0), {})]
    ways = [(100, [1, 2, 3], {"highway": "residential"}), (101, [3, 4], {"highway": "footway"})]
    path = tmp_path / "dot.osm"
    path.write_text(osm_xml(nodes, ways))
    with pytest.raises(BuildError) as exc:
        build(read_map(path))
    msg = str(exc.value)
    assert "zero length" in msg and "2 ways" in msg
    assert "no way of any modelled network" not in msg
