"""The saturation ladder's verdicts: offered deliveries, whole steps, capacity, and when a system stops climbing.

Why: the ladder's figures (`capacity_deliveries_per_s`, the capacity ratios) are only as honest as these rules:
a step that delivered less than was offered, or late, must not count as capacity, and the offered count must
be the union of the cells' subscribers (a viewer holding both cells of a two-cell entity is offered it once).
"""

from __future__ import annotations

from sims.bench.switch_ladder import OfferedCounter, capacity, past_saturation, ratio, step_row
from sims.bench.switch_systems import MIN_CORES_TO_PIN, pin_plan


def _row(entities, delivered, offered, p99):
    return step_row(entities, 1000, {"deliveries_per_s": delivered, "offered_deliveries_per_s": offered,
                                     "latency_p99_ms": p99})


def test_offered_counts_each_viewer_once_per_update():
    count = OfferedCounter([(0, 1), (1,), (2,), ()], n_cells=4)
    assert count((0,)) == 1
    assert count((1,)) == 2
    assert count((0, 1)) == 2  # viewer 0 holds both cells: offered once
    assert count((1, 2)) == 3
    assert count((3,)) == 0
    assert count(()) == 0
    assert count([1, 2]) == 3  # memoised by the cells' tuple, whatever sequence type comes in


def test_capacity_is_the_best_whole_step_under_the_latency_limit():
    steps = [
        _row(5000, 250_000, 252_000, 40.0),  # whole, fast
        _row(10_000, 499_000, 505_000, 95.0),  # whole, just under 100 ms: the capacity
        _row(20_000, 900_000, 1_010_000, 80.0),  # fast but not whole (89 %): not capacity
        _row(40_000, 1_300_000, 1_350_000, 450.0),  # whole but late: the maximum only
    ]
    cap = capacity(steps)
    assert cap["capacity_deliveries_per_s"] == 499_000
    assert cap["capacity_step"] == [10_000, 1000]
    assert cap["max_deliveries_per_s"] == 1_300_000
    assert cap["max_step"] == [40_000, 1000]
    assert [s["whole"] for s in steps] == [True, True, False, True]
    assert [s["p99_under_limit"] for s in steps] == [True, True, True, False]


def test_no_capacity_when_no_step_qualifies_and_ratios_say_unknown():
    cap = capacity([_row(5000, 250_000, 252_000, 300.0)])
    assert cap["capacity_deliveries_per_s"] is None
    assert cap["max_deliveries_per_s"] == 250_000
    assert capacity([])["max_deliveries_per_s"] is None
    assert ratio(None, 5.0) is None and ratio(5.0, None) is None and ratio(5.0, 0.0) is None
    assert ratio(3.0, 2.0) == 1.5


def test_a_system_stops_climbing_past_saturation():
    assert not past_saturation(_row(5000, 250_000, 252_000, 150.0))
    assert past_saturation(_row(40_000, 700_000, 1_000_000, 150.0))  # 70 % delivered
    assert past_saturation(_row(40_000, 990_000, 1_000_000, 5000.0))  # a backlog, not latency
    assert past_saturation(_row(40_000, 0.0, 1_000_000, None))  # nothing arrived


def test_pinning_needs_cores_to_spare():
    few = pin_plan([0, 1])
    assert few["pinned"] is False and few["server_core"] is None and "2 usable" in few["note"]
    many = pin_plan(list(range(16)))
    assert many["pinned"] is True and many["server_core"] == 15 and many["loadgen_cores"] == list(range(15))
    assert pin_plan(list(range(MIN_CORES_TO_PIN)))["pinned"] is True


def test_the_report_keeps_the_ladder():
    from sims.bench.report import write_report

    rows = {"entitynet": [_row(5000, 250_000, 252_000, 40.0)]}
    report = write_report("switch", {"results": {"x": 1.0}, "ladder": rows}, None)
    assert report["ladder"] == rows


def test_the_fanout_micro_benchmark_runs_every_path():
    from entitynet.switchboard import outbox
    from sims.bench.switch_fanout_micro import measure

    rows = measure(rounds=1, reps=1)
    want = {"by_id_pure", "handle_pure"} | ({"by_id_compiled", "handle_compiled"} if outbox.COMPILED else set())
    assert set(rows[0]) == want and all(v > 0 for v in rows[0].values())


def test_the_news_at_flush_comparison_and_the_flush_micro_benchmark_run():
    from entitynet.server import flushloop
    from sims.bench.switch_fanout_micro import news_at_flush
    from sims.bench.switch_flush_micro import measure

    r = news_at_flush(n_viewers=50, n_entities=200, dirty=10, reps=1)
    assert r["deliveries"] > 0 and r["stores_ms"] >= 0 and r["sets_ms"] >= 0
    rows = measure(n_conns=20, states=3, rounds=1, reps=2)
    assert set(rows[0]) == {"pure"} | ({"compiled"} if flushloop.COMPILED else set())
    assert all(v > 0 for v in rows[0].values())


def test_refinement_bisects_each_systems_bracket_geometrically():
    """The doubling steps alone tell capacities apart only by factors of two; two rounds of bisection narrow
    each system's bracket to 2^(1/4)."""
    from sims.bench.switch_ladder import bracket, refinements

    ours = [_row(5000, 250_000, 252_000, 60.0), _row(10_000, 500_000, 505_000, 125.0),
            _row(20_000, 800_000, 1_000_000, 8000.0)]
    peer = [_row(5000, 250_000, 252_000, 50.0), _row(10_000, 500_000, 505_000, 87.0),
            _row(20_000, 1_000_000, 1_010_000, 4500.0)]
    low = [_row(5000, 250_000, 252_000, 400.0), _row(625, 33_000, 33_100, 60.0), _row(1250, 66_000, 66_500, 130.0)]
    none = [_row(5000, 250_000, 252_000, 400.0)]
    top = [_row(5000, 250_000, 252_000, 40.0)]  # qualified at the highest step run: no bracket above
    assert bracket(ours) == (5000, 10_000) and bracket(peer) == (10_000, 20_000) and bracket(low) == (625, 1250)
    assert bracket(none) is None and bracket(top) is None
    first = refinements({"ours": ours, "peer": peer, "low": low, "none": none, "top": top})
    assert first == {"ours": 7070, "peer": 14_140, "low": 880}
    ours.append(_row(7070, 353_000, 354_000, 90.0))  # qualifies: the bracket becomes (7070, 10000)
    assert refinements({"ours": ours}) == {"ours": 8410}
    ours.append(_row(8410, 420_000, 421_000, 110.0))  # fails: (7070, 8410), 1.19x, still split once more
    assert bracket(ours) == (7070, 8410)
    assert refinements({"ours": ours}) == {"ours": 7710}
    ours.append(_row(7710, 385_000, 386_000, 95.0))
    assert refinements({"ours": ours}) == {}  # 8410 / 7710 < 1.1: known closely enough


def test_the_ladder_and_the_repeat_tool_share_one_workload():
    """Both take the load generator's settings from `workload_params`: more readers where cores are spared for
    the load generator, and the same seed, flush bound and connections everywhere."""
    from sims.bench.switch_systems import pin_loadgen, workload_params

    few, many = workload_params([0, 1], pin_plan([0, 1])), workload_params(list(range(16)), pin_plan(list(range(16))))
    assert few["reader_processes"] == 2 and many["reader_processes"] == 8
    assert {k: v for k, v in few.items() if k != "reader_processes"} == \
        {k: v for k, v in many.items() if k != "reader_processes"}
    pin_loadgen(pin_plan([0, 1]))()  # not pinned: nothing to move or put back
