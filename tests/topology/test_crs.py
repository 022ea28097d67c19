"""CRS checks (issue 9, item 14): the build refuses CRSs not in metres, and CRSs that are wrong for the map's
place unless forced (then it warns and counts it in the build report)."""

from __future__ import annotations

import json

import pytest

from tests.topology.crsmaps import HELSINKI, MINNEAPOLIS, geojson_map, osm_map
from topology.build import BuildConfig, BuildError, build, read_map
from topology.geojson_reader import geojson_to_raw
from topology.projection import CrsError, check_metric, placement_problem

US_EXTENT = (MINNEAPOLIS[0], MINNEAPOLIS[1], MINNEAPOLIS[0] + 0.003, MINNEAPOLIS[1] + 0.002)
FI_EXTENT = (HELSINKI[0], HELSINKI[1], HELSINKI[0] + 0.004, HELSINKI[1] + 0.002)


@pytest.mark.parametrize("crs", ["EPSG:4326", "EPSG:4258", "EPSG:4978", "EPSG:2227", "+proj=longlat +datum=WGS84"])
def test_crs_not_projected_in_metres_is_refused(crs):
    with pytest.raises(CrsError, match="projected CRS in metres"):
        check_metric(crs)


def test_placement_problems():
    assert placement_problem("EPSG:3067", *FI_EXTENT) is None
    assert placement_problem("EPSG:32635", *FI_EXTENT) is None
    msg = placement_problem("EPSG:3067", *US_EXTENT)
    assert "area of use" in msg and "Finland" in msg and "% off" in msg
    assert "stretches lengths" in placement_problem("EPSG:3857", *FI_EXTENT)  # the world's, but 100 % long


@pytest.mark.parametrize("maker", [geojson_map, osm_map], ids=["geojson", "osm"])
def test_degrees_are_refused_before_reading_with_a_clear_error(tmp_path, maker):
    path = maker(tmp_path, HELSINKI)
    with pytest.raises(BuildError) as exc:
        build(read_map(path, "EPSG:4326"), BuildConfig(crs="EPSG:4326"))
    assert "degrees" in str(exc.value) and "no streets" not in str(exc.value)


def test_a_document_in_degrees_is_refused_by_build(tmp_path):
    # a GeoJSON whose legacy crs member names a geographic CRS: its degrees must not be taken for metres
    doc = json.loads(geojson_map(tmp_path, HELSINKI).read_text())
    doc["crs"] = {"type": "name", "properties": {"name": "EPSG:4326"}}
    raw = geojson_to_raw(doc)
    with pytest.raises(BuildError, match="projected CRS in metres"):
        build(raw)


@pytest.mark.parametrize("maker", [geojson_map, osm_map], ids=["geojson", "osm"])
def test_a_crs_outside_its_area_of_use_is_refused_unless_forced(tmp_path, maker):
    path = maker(tmp_path, MINNEAPOLIS)
    with pytest.raises(BuildError) as exc:
        build(read_map(path, "EPSG:3067"), BuildConfig(crs="EPSG:3067"))
    assert "area of use" in str(exc.value) and "--force" in str(exc.value)
    warned: list[str] = []
    topo = build(read_map(path, "EPSG:3067"), BuildConfig(crs="EPSG:3067", force_crs=True), warn=warned.append)
    assert len(warned) == 1 and "area of use" in warned[0]
    assert topo.meta["report"]["warning:crs_not_for_this_place"] == 1
    with pytest.warns(UserWarning, match="area of use"):  # without a warn hook: a Python warning
        build(read_map(path, "EPSG:3067"), BuildConfig(crs="EPSG:3067", force_crs=True))


@pytest.mark.parametrize("maker", [geojson_map, osm_map], ids=["geojson", "osm"])
def test_the_right_crs_and_the_default_build_without_warnings(tmp_path, maker, recwarn):
    fi, us = maker(tmp_path, HELSINKI, "fi"), maker(tmp_path, MINNEAPOLIS, "us")
    for path, crs in ((fi, "EPSG:3067"), (fi, None), (us, None), (us, "EPSG:32615")):
        topo = build(read_map(path, crs), BuildConfig(crs=crs))
        assert topo.n_cells > 0 and not any(k.startswith("warning:") for k in topo.meta["report"])
    assert not [w for w in recwarn if "area of use" in str(w.message)]
