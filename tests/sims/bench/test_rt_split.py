"""`python -m sims.bench.rt_split`: the real-time tick split into its parts (no timing is asserted, only that
every part was timed and the parts outside the sends fit in the tick)."""

from sims.bench.rt_split import split


def test_the_split_times_every_part_of_a_short_real_time_run(helsinki, helsinki_path):
    rep = split(20, 2, 2.0, 0.5, topology=(helsinki, helsinki_path))
    ms = rep["ms_per_tick"]
    assert rep["ticks"] >= 4 and rep["on_map"] == 20
    for part in ("world", "fleet", "viewer_move", "measure", "server_core", "tick"):
        assert part in ms and ms[part] >= 0.0, part
    assert sum(ms[k] for k in ("world", "fleet", "viewer_move", "measure")) <= ms["tick"]
