"""`bench sim`'s real-time ladder plan (`sims.bench.sim_ladder.run_ladders`), sans-IO with fake trials: doubling
until a loss, then bisecting between the last size kept and the first lost, bounded in trials and time, the
ladders alternating trial by trial."""

from __future__ import annotations

from sims.bench.sim_ladder import run_ladders


def _limit(at: int, order: list):
    def trial(n: int) -> dict:
        order.append((at, n))
        return {"entities": n, "ok": n <= at}
    return trial


def test_the_ladder_bisects_between_the_last_kept_and_the_first_lost():
    order: list = []
    got = run_ladders({"a": _limit(2300, order), "b": _limit(700, order)}, bisect_steps=3)
    a, b = got["a"], got["b"]
    assert [t["entities"] for t in a["trials"]][:7] == [100, 200, 400, 800, 1600, 3200, 2400]
    assert a["max"] == 2200 and a["lost"] == 2400  # within the resolution: an eighth of the size kept
    assert [t["entities"] for t in a["trials"]] == [100, 200, 400, 800, 1600, 3200, 2400, 2000, 2200]
    assert b["max"] == 700 and b["lost"] == 750 and len(b["trials"]) == 4 + 3  # 800 lost: 600, 700, 750
    # alternating: each round runs one trial of each ladder still open, in order
    assert order[:8] == [(2300, 100), (700, 100), (2300, 200), (700, 200), (2300, 400), (700, 400),
                         (2300, 800), (700, 800)]


def test_the_ladder_is_bounded_in_trials_and_time():
    order: list = []
    quick = run_ladders({"a": _limit(150, order)}, top=200, bisect_steps=0)["a"]
    assert [t["entities"] for t in quick["trials"]] == [100, 200] and (quick["max"], quick["lost"]) == (100, 200)
    none_lost = run_ladders({"a": _limit(10**9, order)}, top=800)["a"]
    assert none_lost["max"] == 800 and none_lost["lost"] is None and len(none_lost["trials"]) == 4
    first_lost = run_ladders({"a": _limit(50, order)})["a"]  # nothing kept: nothing to bisect
    assert (first_lost["max"], first_lost["lost"], len(first_lost["trials"])) == (0, 100, 1)
    ticks = iter(range(1000))
    timed = run_ladders({"a": _limit(10**9, order)}, budget_s=2.5, clock=lambda: next(ticks))["a"]
    assert len(timed["trials"]) == 2  # no trial started once the budget is spent
