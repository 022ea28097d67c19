"""Small synthetic GTFS feeds written in the test: optional files are optional, required ones are named,
malformed rows are skipped and counted (issue 9, item 11)."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from entitynet.client.network import netview
from entitynet.client.path import Path
from tests.topology.routemaps import route_map_xml, true_route
from tests.topology.test_osm_reader import LAT0, LON0, D
from topology.build import build, read_map
from topology.gtfs import STOP_SHAPE, GtfsError, match_shapes, read_feed

# the stops of the route map's bus route (grid units: 2 east per node, 1 north), near its corner nodes
STOPS = [("s1", "First", 0.5, 1), ("s2", "Corner", 6, 1), ("s3", "North", 6, 4), ("s4", "Last", 9.5, 4)]


def write_feed(path, *, shapes: str | None = None, drop: str = "", extra_rows: bool = False, shape_id: str = ""):
    files = {
        "agency.txt": "agency_id,agency_name,agency_url,agency_timezone\na,A,http://a,Europe/Helsinki\n",
        "routes.txt": "route_id,route_short_name,route_type\nr1,1,3\n"
        + ("r2,2,notanumber\nr3,3\n" if extra_rows else ""),
        "trips.txt": "route_id,service_id,trip_id,shape_id,direction_id\n"
        + f"r1,wk,t1,{shape_id},0\nr1,wk,t2,{shape_id},0\n"
        + ("r9,wk,t9,,0\n" if extra_rows else ""),
        "stops.txt": "stop_id,stop_name,stop_lat,stop_lon\n"
        + "".join(f"{i},{n},{LAT0 + y * D},{LON0 + x * D}\n" for i, n, x, y in STOPS)
        + ("bad,Bad,north,east\n" if extra_rows else ""),
        "stop_times.txt": "trip_id,arrival_time,departure_time,stop_id,stop_sequence\n"
        + "".join(f"t{k},08:0{j}:00,08:0{j}:00,{i},{j + 1}\n" for k in (1, 2) for j, (i, *_r) in enumerate(STOPS))
        + ("t1,08:09:00,08:09:00,s4,\n" if extra_rows else ""),
    }
    if shapes is not None:
        files["shapes.txt"] = shapes
    files.pop(drop, None)
    with zipfile.ZipFile(path, "w") as zf:
        for name, text in files.items():
            zf.writestr(name, text)
    return path


@pytest.fixture(scope="module")
def route_map(tmp_path_factory):
    osm = tmp_path_factory.mktemp("gtfsmap") / "m.osm"
    osm.write_text(route_map_xml("ok"))
    return build(read_map(osm))


def _matched(feed, topo):
    got = match_shapes(feed, topo, modes=("bus",), min_length=100.0)
    assert len(got) == 1
    Path(netview(topo), got[0].edges)  # a connected path
    return got[0]


def test_a_feed_without_shapes_is_routed_from_stop_to_stop(tmp_path, route_map):
    feed = read_feed(write_feed(tmp_path / "f.zip"), modes=("bus",))
    # t1 and t2 stop at the same stops: one shape made of them, which both trips run on
    assert list(feed.shapes) == [STOP_SHAPE + "t1"] and feed.report["read:trips_without_shape"] == 2
    assert feed.report["read:shapes_made_of_stops"] == 1
    assert {t.shape_id for t in feed.trips.values()} == {STOP_SHAPE + "t1"}
    m = _matched(feed, route_map)
    assert m.edges == true_route(route_map)
    assert [s[0] for s in m.stop_xy] == ["First", "Corner", "North", "Last"]


def test_a_shape_id_that_shapes_txt_lacks_is_routed_by_its_stops(tmp_path, route_map):
    shapes = "shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\nother,60.17,24.94,1\n"
    feed = read_feed(write_feed(tmp_path / "f.zip", shapes=shapes, shape_id="sh1"), modes=("bus",))
    assert _matched(feed, route_map).edges == true_route(route_map)


@pytest.mark.parametrize("missing", ["routes.txt", "trips.txt", "stops.txt", "stop_times.txt"])
def test_a_required_file_missing_is_a_clear_error(tmp_path, missing):
    with pytest.raises(GtfsError, match=f"required file\\(s\\) missing: {missing}"):
        read_feed(write_feed(tmp_path / "f.zip", drop=missing))


def test_not_a_zip_is_a_clear_error(tmp_path):
    bad = tmp_path / "f.zip"
    bad.write_text("route_id\n")
    with pytest.raises(GtfsError, match="not a readable GTFS zip"):
        read_feed(bad)


def test_malformed_rows_are_skipped_and_counted(tmp_path, route_map):
    shapes = ("shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\n"
              + "".join(f"sh1,{LAT0 + y * D},{LON0 + x * D},{k}\n" for k, (_i, _n, x, y) in enumerate(STOPS))
              + "sh1,sixty,24.9,9\n")
    feed = read_feed(write_feed(tmp_path / "f.zip", shapes=shapes, shape_id="sh1", extra_rows=True), modes=("bus",))
    r = feed.report
    assert r["skipped:routes_bad_row"] == 2 and r["skipped:shapes_bad_row"] == 1
    assert r["skipped:stops_bad_row"] == 1
    assert "bad" not in feed.stops and set(feed.stops) == {i for i, *_ in STOPS}
    assert list(feed.shapes) == ["sh1"] and len(feed.shapes["sh1"]) == 4
    m = _matched(feed, route_map)
    assert len(m.stop_xy) == 4  # the stop_times row without a sequence is skipped


def _append(path, name: str, rows: str):
    """The feed at `path` with `rows` added to its file `name`."""
    with zipfile.ZipFile(path) as zf:
        files = {n: zf.read(n).decode() for n in zf.namelist()}
    files[name] += rows
    with zipfile.ZipFile(path, "w") as zf:
        for n, body in files.items():
            zf.writestr(n, body)
    return path


def test_a_repeated_stop_sequence_is_a_counted_bad_row_not_a_crash(tmp_path):
    """Two rows with one stop_sequence, one timed and one not: sorting whole rows compared None with an int."""
    path = _append(write_feed(tmp_path / "f.zip"), "stop_times.txt", "t1,,,s2,2\n")
    feed = read_feed(path, modes=("bus",))
    assert feed.report["skipped:stop_times_bad_row"] == 1
    assert [s for _q, s, *_t in feed.stop_times["t1"]] == [i for i, *_ in STOPS]
    assert all(a is not None for _q, _s, a, _d in feed.stop_times["t1"])


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "200", "1e400"])
def test_a_non_finite_or_out_of_range_coordinate_is_a_counted_bad_row(tmp_path, value):
    """One stop at stop_lat=nan made every stop-to-stop shape all NaN, silently."""
    shapes = ("shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\n"
              + "".join(f"sh1,{LAT0 + y * D},{LON0 + x * D},{k}\n" for k, (_i, _n, x, y) in enumerate(STOPS))
              + f"sh1,{value},{LON0},9\nsh1,{LAT0},{value},10\n")
    path = _append(write_feed(tmp_path / "f.zip", shapes=shapes, shape_id="sh1"), "stops.txt",
                   f"x1,Lat,{value},{LON0}\nx2,Lon,{LAT0},{value}\n")
    feed = read_feed(path, modes=("bus",))
    assert feed.report["skipped:stops_bad_row"] == 2 and feed.report["skipped:shapes_bad_row"] == 2
    assert set(feed.stops) == {i for i, *_ in STOPS}
    assert len(feed.shapes["sh1"]) == 4
    assert all(np.isfinite(s).all() for s in feed.shapes.values())
