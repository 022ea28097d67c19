"""Viewers in their own processes (`sims.viewers`): a run measures its viewers there and gathers the figures,
a viewer process killed mid-run is named and the run ends on time with no process left, and the frames and the
share refuse what they must. Forked before trio runs (a fork inside a running trio loop cannot start its own),
so these tests are plain functions around `trio.run`."""

from __future__ import annotations

import os
import signal
import time

import pytest
import trio

from sims.engine.local import LocalSwitch
from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig
from sims.viewers import wire
from sims.viewers.procs import ViewerProcesses
from sims.viewers.share import ViewerShare, share_of

SPEED = 1.0  # real time: where viewer processes are meant to run (faster, the ids race the ticks more)


def _config(**kw) -> SimConfig:
    base = dict(entities=40, viewers=6, connections=2, tick_hz=4.0, transit=False, seed=3, subscribe="radius",
                radius=400.0, measure_after=0.5)
    return SimConfig(**{**base, **kw})


def _run(topo, path, config: SimConfig, processes: int, duration: float, kill_at: float | None = None,
         sig: int = signal.SIGKILL, timeout: float = 10.0, max_frame: int | None = None):
    sim = Sim(topo, config)
    sim.viewers = []
    vp = ViewerProcesses(processes, topo, None, config, timeout=timeout)
    if max_frame is not None:  # the coordinator reads no frame over this
        vp._readers = [wire.FrameReader(max_frame) for _ in range(processes)]
    lines: list[str] = []
    shell = Shell(sim, ShellConfig(duration=duration, speed=SPEED, summary_every=100.0, artifact=path, keys=False,
                                   viewer_processes=vp), lines.append)

    async def main():
        async with trio.open_nursery() as n:
            if kill_at is not None:
                async def killer():
                    while vp.k < 2:  # mid-run: once the ticks flow (building a share may take a while)
                        await trio.sleep(0.05)
                    await trio.sleep(kill_at)
                    os.kill(vp.pids[0], sig)
                n.start_soon(killer)
            with trio.fail_after(90):
                rep = await shell.run()
            n.cancel_scope.cancel()
        return rep

    try:
        rep = trio.run(main)
        vp.procs[0].join(2.0)
        vp.first_alive_before_close = vp.procs[0].is_alive()
    finally:
        vp.close()
    assert not any(p.is_alive() for p in vp.procs)  # no process left behind
    return rep, lines, vp


def test_viewers_in_two_processes_are_measured_and_gathered(helsinki, helsinki_path):
    rep, lines, vp = _run(helsinki, helsinki_path, _config(), 2, 4.0)
    assert rep["sim_time_s"] == 4.0
    assert rep["viewer_processes"]["deaths"] == [] and rep["viewer_processes"]["measured_viewers"] == 6
    assert rep["viewers"]["street"] + rep["viewers"]["roof"] == 6
    assert rep["viewers"]["deliveries"] > 0
    tv = rep["truth_vs_viewer"]["all"]
    assert tv["visible_entity_samples"] > 0 and tv["shown_ghost_samples"] > 0
    # the server's ids were mapped back to the truth from the payloads: ghosts are near their entities
    assert tv["missed_visibility"] < 0.3 and tv["error_p95_m"] < 60.0
    assert all(p.exitcode == 0 for p in vp.procs)


def test_a_viewer_process_killed_mid_run_is_named_and_the_run_ends_on_time(helsinki, helsinki_path):
    rep, lines, vp = _run(helsinki, helsinki_path, _config(), 2, 4.0, kill_at=0.3)  # (killed at ~0.8 s)
    deaths = rep["viewer_processes"]["deaths"]
    assert [d["index"] for d in deaths] == [0] and deaths[0]["pid"] == vp.pids[0]
    assert deaths[0]["viewers"] == 3
    assert rep["sim_time_s"] == 4.0
    assert rep["viewer_processes"]["measured_viewers"] == 3  # the survivor's viewers only, and it says so
    assert rep["truth_vs_viewer"]["all"]["visible_entity_samples"] > 0
    assert any("viewer process 0" in line and "gone" in line for line in lines)


def test_a_viewer_process_that_stops_answering_is_named_and_nothing_hangs(helsinki, helsinki_path):
    rep, lines, vp = _run(helsinki, helsinki_path, _config(), 2, 3.0, kill_at=0.2, sig=signal.SIGSTOP,
                          timeout=2.0)
    deaths = rep["viewer_processes"]["deaths"]
    # no report within the timeout (or, its socket buffer full, no tick read within it)
    assert [d["index"] for d in deaths] == [0] and "within 2 s" in deaths[0]["why"]
    assert rep["viewer_processes"]["measured_viewers"] == 3
    assert not vp.first_alive_before_close  # declared dead, it is ended then, not left stopped till the end


def test_a_share_moves_the_same_cameras_as_one_process(helsinki):
    config = _config()
    one = Sim(helsinki, config)
    sw = LocalSwitch(one)
    subs0 = sw.sim.start()[1]
    share = ViewerShare(helsinki, None, config, share_of(6, 2, 1))
    assert [v.index for v in share.viewers] == [1, 3, 5]
    mine = share.tick(0, [], [])
    assert [s for i, s in enumerate(subs0) if i % 2 == 1] == mine
    for k in range(1, 6):
        subs = one.step()[1]
        assert [s for i, s in enumerate(subs) if i % 2 == 1] == share.tick(k, [], [])
    assert share.now == one.now
    with pytest.raises(ValueError):
        share.tick(9, [], [])  # ticks come in order


def test_bad_frames_and_bad_sizes_are_refused():
    r = wire.FrameReader(max_frame=100)
    r.feed(wire.encode("tick", k=1, pub=[], unpub=[], sent=0.0))
    assert r.frames()[0]["k"] == 1
    for bad in (b"\x00\x00\x00\x02\xc1\xc1", wire.HEADER.pack(1000)):  # not msgpack; over the limit
        r = wire.FrameReader(max_frame=100)
        r.feed(bad)
        with pytest.raises(wire.WireError):
            r.frames()
    for frame in ([1, 2], {"t": "nope"}, {"t": "tick", "k": "1", "pub": [], "unpub": [], "sent": 0.0},
                  {"t": "tick", "k": True, "pub": [], "unpub": [], "sent": 0.0},
                  {"t": "start", "host": "h", "port": 1}):
        with pytest.raises(wire.WireError):
            wire.check(frame)
    r = wire.FrameReader()
    whole = wire.encode("stop")
    r.feed(whole[:3])
    assert r.frames() == []  # a frame in pieces waits for its rest
    r.feed(whole[3:])
    assert r.frames() == [{"t": "stop"}]


def test_a_bad_number_of_viewer_processes_is_refused(helsinki):
    with pytest.raises(ValueError):
        ViewerProcesses(0, helsinki, None, _config())
    with pytest.raises(ValueError):
        ViewerProcesses(7, helsinki, None, _config())
    with pytest.raises(ValueError):
        share_of(6, 2, 2)
    sim = Sim(helsinki, _config())
    with pytest.raises(ValueError):  # the simulation must hand its viewers over
        Shell(sim, ShellConfig(keys=False, viewer_processes=object()), lambda m: None)


def test_the_command_refuses_viewer_processes_it_cannot_run(capsys):
    from entitynet.cli import main

    for args, said in ((["--viewers", "3", "--viewer-processes", "4"], "more than the 3 viewers"),
                       (["--viewer-processes", "2", "--shards", "2"], "does not go with --shards"),
                       (["--viewer-processes", "2", "--mobility", "sumo"], "not with --mobility sumo")):
        assert main(["sim", *args, "--duration", "1"]) == 2
        assert said in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["sim", "--viewer-processes", "-1", "--duration", "1"])
    assert info.value.code == 2


def test_the_default_takes_one_viewer_process_on_a_small_machine_for_large_runs():
    from sims.sim_cmd import auto_viewer_processes

    assert auto_viewer_processes(1000, 2) == 1 and auto_viewer_processes(1000, 4) == 1
    assert auto_viewer_processes(200, 2) == 1 and auto_viewer_processes(199, 2) == 0
    assert auto_viewer_processes(1000, 1) == 0 and auto_viewer_processes(1000, None) == 0
    assert auto_viewer_processes(100, 16) == 0
    assert auto_viewer_processes(1000, 16) == 4 and auto_viewer_processes(1000, 5) == 3


def test_a_report_that_does_not_read_is_named_and_the_others_still_count(helsinki):
    vp = ViewerProcesses(2, helsinki, None, _config())
    try:
        good = {"viewers": {"street": 2, "roof": 1, "deliveries": 5, "leaves": 0, "bytes": 50}, "subscribe_msgs": 3,
                "tallies": {"street": {"errors": [1.0, 2.0], "visible": 4, "missed": 1, "shown": 3, "stale": 0,
                                       "viewer_samples": 2}}, "cpu_s": 0.1, "tick_delay_p99_ms": 1.0}
        vp.reports = [good, {**good, "tallies": {"street": {"errors": ["x"]}}}]
        rep = vp.merge({})
    finally:
        vp.close()
    assert [d["index"] for d in rep["viewer_processes"]["deaths"]] == [1]
    assert "does not read" in rep["viewer_processes"]["deaths"][0]["why"]
    assert rep["viewers"]["deliveries"] == 5 and rep["truth_vs_viewer"]["all"]["visible_entity_samples"] == 4
    assert rep["truth_vs_viewer"]["all"]["missed_visibility"] == 0.25


def test_the_default_is_never_refused_where_viewer_processes_cannot_run(monkeypatch, capsys):
    """On a large machine the default would fork viewer processes for 300 viewers: with --shards or --mobility
    sumo it must keep them in this process, not refuse an option the user never gave."""
    from entitynet.cli import main
    from sims import sim_cmd

    monkeypatch.setattr(sim_cmd.os, "cpu_count", lambda: 16)
    for args in (["--shards", "2"], ["--mobility", "sumo", "--sumocfg", "/nonexistent.sumocfg"]):
        main(["sim", "--viewers", "300", *args, "--duration", "1", "--gtfs", "/nonexistent.zip"])
        err = capsys.readouterr().err
        assert "cannot read the feed" in err  # the run's own usage error, found before anything loads
        assert "viewer-processes" not in err


def test_a_viewer_process_ends_when_the_coordinator_closes_its_socket(helsinki):
    """A process the coordinator lets go (declared dead, or the coordinator gone without `close`) sees its
    socket close and ends by itself: no child may hold another copy of the coordinator's end."""
    vp = ViewerProcesses(3, helsinki, None, _config())
    try:
        for s in vp._socks:
            s.close()
        deadline = time.monotonic() + 10.0
        for p in vp.procs:
            p.join(max(0.0, deadline - time.monotonic()))
        assert [p.exitcode for p in vp.procs] == [0, 0, 0]
    finally:
        vp.close()


def test_a_report_that_does_not_read_does_not_break_the_last_line(helsinki):
    """The run's last line counts the deliveries of the reports that read, as the report does; one without its
    counters is named dead before that line, not a traceback from it."""
    vp = ViewerProcesses(2, helsinki, None, _config())
    try:
        good = {"viewers": {"street": 2, "roof": 1, "deliveries": 5, "leaves": 0, "bytes": 50}, "subscribe_msgs": 3,
                "tallies": {}, "cpu_s": 0.1, "tick_delay_p99_ms": 1.0}
        vp.reports = [good, {**good, "viewers": [], "tallies": {"street": None}}]
        sim = Sim(helsinki, _config())
        sim.viewers = []
        shell = Shell(sim, ShellConfig(keys=False, viewer_processes=vp), lambda m: None)
        assert "5 deliveries" in shell.final_line()
        assert [d["index"] for d in vp.deaths] == [1]
        assert shell.report()["viewers"]["deliveries"] == 5 and len(vp.deaths) == 1  # named once
    finally:
        vp.close()


def test_the_shares_measure_the_viewers_one_process_would_at_each_sample(helsinki):
    """With measure share 0.25, one process measures ceil(0.25 x V) viewers per sample in turn; the shares
    together must measure exactly those (each share rounding its own quarter up measured 3 of 7 per sample,
    and the viewers of the smaller shares more often than the others: the summed tallies weighted them more)."""
    config = _config(viewers=7, measure_share=0.25)
    one = Sim(helsinki, config)
    shares = [ViewerShare(helsinki, None, config, share_of(7, 3, i)) for i in range(3)]
    for _ in range(8):
        want = sorted(v.index for v in one.measured_viewers())
        got = sorted(v.index for s in shares for v in s.sim.measured_viewers())
        assert got == want


def test_a_sample_with_no_viewer_to_measure_costs_nothing(helsinki, monkeypatch):
    """The coordinator of viewer processes holds no viewers, and a share may have none in a sample's window:
    the truth is not read into arrays for nobody (a cost the processes are meant to take off the coordinator)."""
    sim = Sim(helsinki, _config(measure_after=0.0))
    sim.viewers = []
    calls = []
    monkeypatch.setattr(sim.measure, "sample", lambda *a: calls.append(a))
    sim.start()
    assert sim.maybe_sample({}) and calls == []


def test_the_live_line_shows_no_viewer_figures_it_does_not_have(helsinki):
    """With the viewers in their processes the coordinator has no deliveries or measure until the end: its
    live line must not print 0 deliveries/s and 0.0 % missed as if measured."""
    from types import SimpleNamespace

    sim = Sim(helsinki, _config())
    sim.viewers = []
    vp = SimpleNamespace(n=2, live=lambda: [0, 1])
    shell = Shell(sim, ShellConfig(keys=False, viewer_processes=vp), lambda m: None)
    sim.start()
    line = shell.summary_line(5.0)
    assert "deliveries" not in line and "missed" not in line and "viewer error" not in line
    assert "viewers in 2 of 2 processes" in line and "collisions avoided" in line


def test_a_viewer_process_whose_coordinator_goes_mid_start_ends_quietly(helsinki, capfd):
    """The coordinator gone (Ctrl-C while it waits for `ready`) as the process answers: the process ends with
    status 0 and says nothing (trio's nursery wraps the broken socket in an exception group, which printed
    "ExceptionGroup: Exceptions from Trio nursery" and exited 1)."""
    vp = ViewerProcesses(1, helsinki, None, _config(viewers=0))
    try:
        vp._socks[0].sendall(wire.encode("start", host="127.0.0.1", port=9, token=""))
        vp._socks[0].close()
        vp.procs[0].join(10.0)
        assert vp.procs[0].exitcode == 0
        assert "viewer process" not in capfd.readouterr().err
    finally:
        vp.close()


def test_a_report_with_more_error_samples_than_a_frame_holds_still_arrives(helsinki, helsinki_path, monkeypatch):
    """A report's error samples grow with the run (which goes on until Ctrl-C by default): they follow it in
    frames of their own, so a long run's report is not refused as over the frame limit (the process was named
    dead and every figure of its viewers lost)."""
    monkeypatch.setattr(wire, "ERROR_CHUNK", 32)  # 256 bytes of samples per frame (set before the fork)
    rep, lines, vp = _run(helsinki, helsinki_path, _config(), 2, 4.0, max_frame=1024)
    assert rep["viewer_processes"]["deaths"] == []
    tv = rep["truth_vs_viewer"]["all"]
    assert tv["shown_ghost_samples"] > 2 * 1024 / 8  # more samples than the limit could hold in one frame
    assert tv["error_p95_m"] is not None and tv["visible_entity_samples"] > 0
