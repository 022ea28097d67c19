"""The one schedule model (issue 21, item 16): one time parser, frequencies expanded (exact_times kept), stops
without times interpolated, times that run backwards and trips off the service day skipped and counted; and
one reader: no module outside `topology` parses a GTFS file."""

from __future__ import annotations

import ast
import zipfile
from pathlib import Path

import numpy as np
import pytest

from topology.gtfs import GtfsError, parse_time, read_feed
from topology.schedule import build_timetable, service_day

ROOT = Path(__file__).resolve().parents[2]
STOPS = "stop_id,stop_name,stop_lat,stop_lon\na,A,60.17,24.94\nb,B,60.171,24.941\nc,C,60.172,24.942\n"


def write_feed(path: Path, *, trips: str, stop_times: str, frequencies: str | None = None,
               calendar: str | None = None, calendar_dates: str | None = None) -> Path:
    files = {
        "routes.txt": "route_id,route_short_name,route_type\nR,4,0\nF,ferry,4\n",
        "trips.txt": "route_id,service_id,trip_id,direction_id\n" + trips,
        "stops.txt": STOPS,
        "stop_times.txt": "trip_id,arrival_time,departure_time,stop_id,stop_sequence\n" + stop_times,
    }
    for name, text in (("frequencies.txt", frequencies), ("calendar.txt", calendar),
                       ("calendar_dates.txt", calendar_dates)):
        if text is not None:
            files[name] = text
    with zipfile.ZipFile(path, "w") as zf:
        for name, text in files.items():
            zf.writestr(name, text)
    return path


def test_parse_time_keeps_hours_past_midnight_and_refuses_the_rest():
    assert parse_time("08:01:30") == 8 * 3600 + 90
    assert parse_time(" 7:00:00") == 7 * 3600
    assert parse_time("25:10:00") == 90600
    for bad in ("8:00", "xx:00:00", "08:61:00", "08:00:-1", "", "08:00:00:00", "nan:00:00"):
        with pytest.raises(GtfsError, match="not a GTFS time"):
            parse_time(bad)


def test_frequencies_are_expanded_and_exact_times_kept(tmp_path):
    feed = read_feed(write_feed(
        tmp_path / "f.zip",
        trips="R,S,t1,0\nR,S,t2,1\nR,S,t3,0\n",
        stop_times="t1,06:00:00,06:00:00,a,1\nt1,06:02:00,06:02:30,b,2\nt1,06:05:00,06:05:00,c,3\n"
                   "t2,06:00:00,06:00:00,c,1\nt2,06:04:00,06:04:00,a,2\n"
                   "t3,07:00:00,07:00:00,a,1\nt3,07:03:00,07:03:00,c,2\n",
        frequencies="trip_id,start_time,end_time,headway_secs,exact_times\n"
                    "t1,08:00:00,08:30:00,600,1\nt1,08:30:00,08:40:00,300,1\nt2,24:50:00,25:10:00,600,0\n"
                    "t3,09:00:00,08:00:00,600,1\nt3,09:00:00,10:00:00,0,1\n"))
    tt = build_timetable(feed)
    t1 = [d.start for d in tt.departures if d.trip.trip_id == "t1"]
    # from each start every headway while before the end; the template's own 06:00 is only the pattern
    assert t1 == [parse_time(t) for t in ("08:00:00", "08:10:00", "08:20:00", "08:30:00", "08:35:00")]
    t2 = [d for d in tt.departures if d.trip.trip_id == "t2"]
    assert [d.start for d in t2] == [parse_time("24:50:00"), parse_time("25:00:00")]
    assert all(d.frequency for d in t2) and not any(d.exact for d in t2)  # exact_times=0: headway-based
    assert all(d.exact for d in tt.departures if d.trip.trip_id == "t1")
    # t3's frequencies are malformed (ends before it starts, headway 0): counted, and it runs at its own time
    assert feed.report["skipped:frequencies_bad_row"] == 2
    (t3,) = [d for d in tt.departures if d.trip.trip_id == "t3"]
    assert t3.start == parse_time("07:00:00") and not t3.frequency
    trip = tt.trips["t1"]
    assert list(trip.arr) == [0.0, 120.0, 300.0] and list(trip.dep) == [0.0, 150.0, 300.0]
    assert [d.start for d in tt.departures] == sorted(d.start for d in tt.departures)
    assert tt.report["read:frequency_trips_expanded"] == 7


def test_stops_without_times_are_interpolated_and_bad_trips_skipped(tmp_path):
    feed = read_feed(write_feed(
        tmp_path / "f.zip",
        trips="R,S,ok,0\nR,S,back,0\nR,S,open,0\nR,S,one,0\nF,S,ferry,0\n",
        stop_times="ok,08:00:00,08:00:00,a,1\nok,,,b,2\nok,08:10:00,08:10:00,c,3\n"
                   "back,08:00:00,08:00:00,a,1\nback,07:59:00,07:59:00,b,2\n"
                   "open,08:00:00,08:00:00,a,1\nopen,,,b,2\n"
                   "one,08:00:00,08:00:00,a,1\none,08:01:00,08:01:00,nowhere,2\n"
                   "ok,8h,8h,c,4\n"))
    tt = build_timetable(feed)
    assert list(tt.trips) == ["ok"]
    assert list(tt.trips["ok"].arr) == [0.0, 300.0, 600.0]
    r = tt.report
    assert r["skipped:trip_times_missing_or_backwards"] == 2  # "back" runs backwards, "open" ends untimed
    assert r["skipped:trip_with_fewer_than_two_stops"] == 1  # "one": its second stop is not in stops.txt
    assert r["skipped:stop_times_bad_row"] == 1 and r["skipped:unknown_route_type"] == 1


def test_the_service_day_from_calendar_and_calendar_dates(tmp_path):
    cal = ("service_id,monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,end_date\n"
           "W,1,1,1,1,1,0,0,20220221,20220306\nE,0,0,0,0,0,1,1,20220221,20220306\n")
    dates = "service_id,date,exception_type\nW,20220223,2\nX,20220226,1\n"
    feed = read_feed(write_feed(tmp_path / "f.zip", trips="R,W,w,0\nR,E,e,0\nR,X,x,0\n",
                                stop_times="".join(f"{t},08:00:00,08:00:00,a,1\n{t},08:05:00,08:05:00,b,2\n"
                                                   for t in "wex"),
                                calendar=cal, calendar_dates=dates))
    assert service_day(feed, "20220222") == ({"W"}, "20220222")
    assert service_day(feed, "20220223")[0] == set()  # removed that day
    assert service_day(feed, "20220226")[0] == {"E", "X"}  # added that day
    assert service_day(feed)[1] == "20220226"  # the busiest of the first two weeks (the earliest of equals)
    tt = build_timetable(feed, date="20220222")
    assert list(tt.trips) == ["w"] and tt.report["skipped:not_in_service"] == 2
    with pytest.raises(GtfsError, match="not a service date"):
        build_timetable(feed, date="2022-02-22")
    nocal = read_feed(write_feed(tmp_path / "n.zip", trips="R,W,w,0\n",
                                 stop_times="w,08:00:00,08:00:00,a,1\nw,08:05:00,08:05:00,b,2\n"))
    assert service_day(nocal) == (None, "") and list(build_timetable(nocal).trips) == ["w"]


def test_trips_without_a_shape_share_the_one_of_their_stop_sequence(tmp_path):
    feed = read_feed(write_feed(
        tmp_path / "f.zip", trips="R,S,t2,0\nR,S,t1,0\nR,S,t3,1\n",
        stop_times="".join(f"{t},08:00:00,08:00:00,a,1\n{t},08:05:00,08:05:00,b,2\n{t},08:09:00,08:09:00,c,3\n"
                           for t in ("t1", "t2")) + "t3,09:00:00,09:00:00,c,1\nt3,09:05:00,09:05:00,a,2\n"))
    tt = build_timetable(feed)
    assert tt.trips["t1"].shape_id == tt.trips["t2"].shape_id == "stops:t1"
    assert tt.trips["t3"].shape_id == "stops:t3"
    assert np.allclose(feed.shapes["stops:t3"], [[24.942, 60.172], [24.94, 60.17]])


def _parses_gtfs(path: Path) -> list[str]:
    """Why a module outside topology reads GTFS itself: a GTFS file name opened or a csv reader."""
    tree = ast.parse(path.read_text())
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in ("DictReader", "reader") and \
                isinstance(node.value, ast.Name) and node.value.id == "csv":
            out.append(f"csv.{node.attr}")
        name = node.name.lower() if isinstance(node, ast.FunctionDef) else ""
        if "parse" in name and "time" in name and ("gtfs" in name or "GTFS" in (ast.get_docstring(node) or "")):
            out.append(f"def {node.name}")  # a GTFS time parser of its own
    return out


def test_no_gtfs_parsing_outside_topology():
    found = {}
    for package in ("sims", "proxies", "entitynet"):
        for path in sorted((ROOT / package).rglob("*.py")):
            why = _parses_gtfs(path)
            if why:
                found[str(path.relative_to(ROOT))] = why
    assert not found, found
