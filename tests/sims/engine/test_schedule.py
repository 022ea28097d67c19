"""Spawning from GTFS: frequencies expanded, times past 24:00, trips that cross only part of the map, feeds
without shapes, unknown route types and trips that never touch the map; and the bundled HSL extract."""

from __future__ import annotations

import functools
import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from sims.engine.schedule import GtfsError, read_schedule
from tests.entitynet.client_fixtures import make_topology
from topology.gtfs import parse_time
from topology.raw import PEDESTRIAN, TRAM, VEHICLE

ORIGIN = (385000.0, 6672000.0)
ALLNET = PEDESTRIAN | VEHICLE | TRAM
BUNDLED = Path(__file__).resolve().parents[3] / "sims" / "data" / "hsl-helsinki-centre.zip"


def line_map():
    """A 1 km east-west street (y = 150, a node every 100 m) with a side street, in EPSG:3067 near Helsinki."""
    nodes = {f"P{i}": (100.0 * i, 150.0) for i in range(11)}
    nodes |= {"S": (500.0, 0.0), "N": (500.0, 300.0)}
    edges = [(f"P{i}", f"P{i + 1}", ALLNET) for i in range(10)] + [("P5", "S", ALLNET), ("P5", "N", ALLNET)]
    return make_topology(nodes, edges, origin=ORIGIN)


@functools.cache
def lonlat(x: float, y: float) -> tuple[float, float]:
    lon, lat = _inverse().transform(x + ORIGIN[0], y + ORIGIN[1])
    return float(lon), float(lat)


@functools.cache
def _inverse() -> Transformer:
    return Transformer.from_crs("EPSG:3067", "EPSG:4326", always_xy=True)


def write_feed(path: Path, *, shapes: bool = True) -> Path:
    stops = {"s0": (-400.0, 150.0), "s1": (300.0, 150.0), "s2": (700.0, 150.0), "s3": (1400.0, 150.0),
             "far1": (0.0, 5000.0), "far2": (900.0, 5000.0)}
    files = {
        "agency.txt": "agency_id,agency_name,agency_url,agency_timezone\nA,A,http://a,Europe/Helsinki\n",
        "routes.txt": "route_id,route_short_name,route_type\nT,7,0\nB,55,3\nF,ferry,4\nX,far,3\n",
        "calendar.txt": "service_id,monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,end_date\n"
                        "W,1,1,1,1,1,0,0,20220101,20221231\n",
        "trips.txt": "route_id,service_id,trip_id,shape_id\nT,W,t1,sh1\nB,W,b1,\nF,W,f1,\nX,W,x1,shx\n",
        "stops.txt": "stop_id,stop_name,stop_lat,stop_lon\n" + "".join(
            f"{k},{k},{lonlat(*v)[1]},{lonlat(*v)[0]}\n" for k, v in stops.items()),
        "stop_times.txt": "trip_id,arrival_time,departure_time,stop_id,stop_sequence\n"
                          "t1,08:00:00,08:00:00,s0,1\nt1,08:01:30,08:01:40,s1,2\nt1,08:02:30,08:02:30,s2,3\n"
                          "t1,08:04:00,08:04:00,s3,4\n"
                          "b1,25:00:00,25:00:00,s1,1\nb1,25:01:00,25:01:00,s2,2\n"
                          "f1,09:00:00,09:00:00,s1,1\nf1,09:05:00,09:05:00,s2,2\n"
                          "x1,10:00:00,10:00:00,far1,1\nx1,10:03:00,10:03:00,far2,2\n",
        "frequencies.txt": "trip_id,start_time,end_time,headway_secs\nb1,25:00:00,25:30:00,600\n",
    }
    if shapes:
        pts = [(x, 150.0) for x in np.arange(-500.0, 1501.0, 25.0)]  # shapes are dense polylines
        far = [(x, 5000.0) for x in np.arange(0.0, 901.0, 25.0)]
        files["shapes.txt"] = "shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\n" + "".join(
            f"sh1,{lonlat(*p)[1]},{lonlat(*p)[0]},{i}\n" for i, p in enumerate(pts)) + "".join(
            f"shx,{lonlat(*p)[1]},{lonlat(*p)[0]},{i}\n" for i, p in enumerate(far))
    with zipfile.ZipFile(path, "w") as zf:
        for name, text in files.items():
            zf.writestr(name, text)
    return path


def test_parse_time_keeps_hours_past_midnight():
    assert parse_time("08:01:30") == 8 * 3600 + 90
    assert parse_time("25:10:00") == 90600
    for bad in ("8:00", "xx:00:00", "08:61:00"):
        with pytest.raises(ValueError):
            parse_time(bad)


def test_departures_of_a_small_feed(tmp_path):
    topo = line_map()
    sched = read_schedule(write_feed(tmp_path / "f.zip"), topo, date="20220222")
    by_trip = {d.trip_id: d for d in sched.departures}
    tram = by_trip["t1"]
    assert tram.mode == "tram" and tram.ref == "7"
    # the tram enters at the map's west edge (its shape starts 500 m outside) and stops at s1 and s2 only
    assert tram.edges[0] == (0, 1) and [s.s for s in tram.stops] == pytest.approx([300.0, 700.0], abs=2.5)
    assert tram.stops[0].dwell >= 10.0  # 08:01:30 -> 08:01:40
    cruise = 9.0
    assert tram.time == pytest.approx(parse_time("08:01:30") - tram.stops[0].s / cruise, abs=1.0)
    # the bus has no shape: routed from stop to stop; its frequencies are expanded past 24:00
    buses = sorted(d.time for d in sched.departures if d.mode == "bus")
    assert len(buses) == 3
    assert np.diff(buses) == pytest.approx([600.0, 600.0])
    assert buses[0] > 24 * 3600
    assert sched.report["skipped:unknown_route_type"] == 1
    assert sched.report["skipped:trip_off_map"] == 1
    assert [d.trip_id for d in sched.due(0.0, 9 * 3600)] == ["t1"]


def test_a_feed_without_shapes_routes_from_stop_to_stop(tmp_path):
    topo = line_map()
    sched = read_schedule(write_feed(tmp_path / "f.zip", shapes=False), topo, date="20220222")
    assert {d.mode for d in sched.departures} == {"tram", "bus"}


def test_not_a_service_day_and_bad_feeds(tmp_path):
    topo = line_map()
    sched = read_schedule(write_feed(tmp_path / "f.zip"), topo, date="20220226")  # a Saturday
    assert sched.departures == [] and sched.report["warning:no_departure_over_the_map"] == 1
    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(bad, "w") as zf:
        zf.writestr("routes.txt", "route_id\n")
    with pytest.raises(GtfsError, match="stop_times.txt"):
        read_schedule(bad, topo)
    (tmp_path / "junk.zip").write_bytes(b"not a zip")
    with pytest.raises(GtfsError, match="not a readable GTFS zip"):
        read_schedule(tmp_path / "junk.zip", topo)


def test_bundled_extract_is_small_credited_and_complete():
    assert BUNDLED.stat().st_size < 1_000_000
    credit = (BUNDLED.parent / "HSL-GTFS-LICENSE.md").read_text()
    assert "CC BY 4.0" in credit and "Helsinki Region Transport" in credit
    with zipfile.ZipFile(BUNDLED) as zf:
        names = set(zf.namelist())
        assert {"routes.txt", "trips.txt", "stops.txt", "stop_times.txt", "shapes.txt", "calendar.txt"} <= names
        trips = io.TextIOWrapper(zf.open("trips.txt"), encoding="utf-8-sig").read().count("\n") - 1
        assert trips > 100
