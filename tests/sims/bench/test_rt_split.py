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


def test_the_split_with_the_server_in_a_child_process_counts_its_cpu(helsinki, helsinki_path):
    rep = split(20, 2, 2.0, 0.5, topology=(helsinki, helsinki_path), server_process=True)
    ms = rep["ms_per_tick"]
    assert rep["server"] == "a child process" and "server_core" not in ms
    assert ms["server_process_cpu"] >= 0.0 and "rest (sends, viewer connections)" in ms
    assert rep["cpu_ms_per_tick"]["tick"] > 0.0 and "world" in rep["cpu_ms_per_tick"]
    assert rep["viewers"] == 2 and ms["viewer_receive"] >= 0.0 and rep["deliveries_per_tick"] >= 0.0
