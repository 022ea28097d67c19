"""The schedule-adherence measurement on a small feed: the tram's two stops on the map, never early, and late
at the second only by the dwell the simulation adds at the first beyond the feed's 10 s."""

from __future__ import annotations

from sims.bench.timetable import adherence
from sims.engine.schedule import read_schedule
from tests.sims.engine.test_schedule import line_map, write_feed


def test_adherence_on_a_small_feed(tmp_path):
    topo = line_map()
    schedule = read_schedule(write_feed(tmp_path / "f.zip"), topo, date="20220222")
    (tram,) = [d for d in schedule.departures if d.trip_id == "t1"]
    out = adherence(topo, schedule, entities=0, start=8 * 3600.0 - 120.0, seconds=420.0)
    assert out["stops"] == 2  # 08:01:30 and 08:02:30, unobstructed
    assert out["early_over_30s"] == 0.0 and out["lateness_p50_s"] >= -1.0
    assert out["lateness_max_s"] <= tram.stops[0].dwell - 10.0  # the feed's dwell there is 10 s
    assert out["collisions"] == {"avoided": 0, "accepted": 0, "deleted": 0}
