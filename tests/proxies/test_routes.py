"""Every trip of a feed without shapes.txt is placed on the map (issue 21, item 11): the GTFS reader made one
stop-made shape per route and direction while the proxy's schedule gave each shapeless trip its own, so the
proxy found a matched route for one trip in each group (53 of 2,077 trips of a real feed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from proxies.routes import build_routes
from tests.proxies.conftest import LINE_Y, STOP_X, _lonlat, write_zip


def write_shapeless_feed(path: Path, runs: int = 6) -> Path:
    """The test tram line without shapes.txt or frequencies: `runs` trips each way, 10 minutes apart, and two
    short-turn trips east that skip the last stop (another stop sequence)."""
    stop_ll = _lonlat(np.array(STOP_X), np.full(len(STOP_X), LINE_Y + 3.0))
    trips = ["route_id,service_id,trip_id,direction_id"]
    rows = ["trip_id,arrival_time,departure_time,stop_id,stop_sequence"]
    plans = [(f"east {k}", 0, list(range(len(STOP_X))), 8 * 3600 + 600 * k) for k in range(runs)]
    plans += [(f"west {k}", 1, list(reversed(range(len(STOP_X)))), 8 * 3600 + 600 * k + 300) for k in range(runs)]
    plans += [(f"short {k}", 0, list(range(len(STOP_X) - 1)), 9 * 3600 + 900 * k) for k in range(2)]
    for trip, direction, order, t0 in plans:
        trips.append(f"1001,S,{trip},{direction}")
        for seq, i in enumerate(order):
            t = t0 + seq * 90
            rows.append(f"{trip},{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d},"
                        f"{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d},S{i},{seq + 1}")
    files = {
        "agency.txt": "agency_id,agency_name,agency_url,agency_timezone\nA,Test,http://x,Europe/Helsinki\n",
        "calendar.txt": "monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,end_date,service_id\n"
                        "1,1,1,1,1,1,1,20220222,20220222,S\n",
        "routes.txt": "route_id,route_short_name,route_type\n1001,1,0\n",
        "stops.txt": "stop_id,stop_name,stop_lat,stop_lon\n"
                     + "".join(f"S{i},Stop {i},{lat:.7f},{lon:.7f}\n" for i, (lon, lat) in enumerate(stop_ll)),
        "trips.txt": "\n".join(trips) + "\n",
        "stop_times.txt": "\n".join(rows) + "\n",
    }
    return write_zip(path, files)


def test_every_trip_of_a_feed_without_shapes_gets_its_route(tmp_path, line_topo):
    feed = write_shapeless_feed(tmp_path / "noshapes.zip")
    book = build_routes(line_topo, feed, modes=("tram",))
    trips = {d.pattern.trip_id for d in book.schedule.departures}
    assert len(trips) == 14
    assert set(book.routes) == trips  # main: 2 of 14 (one per route and direction)
    # the trips of one stop sequence share one route; the short turns have their own, one stop shorter
    assert book.routes["east 0"] is book.routes["east 5"]
    assert book.routes["short 0"] is book.routes["short 1"] is not book.routes["east 0"]
    short = [s.stop_id for s in book.routes["short 0"].stops]
    assert short[:4] == ["S0", "S1", "S2", "S3"] and "S5" not in short  # (S4 is 50 m past its nearest node)
    assert book.routes["short 0"].length < book.routes["east 0"].length - 300.0
    west = book.routes["west 3"]
    assert [s.stop_id for s in west.stops] == [f"S{i}" for i in reversed(range(len(STOP_X)))]
    assert np.all(np.diff([s.s for s in west.stops]) > 300.0)  # along its route, in travel order
