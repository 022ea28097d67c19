"""The two sans-IO sides of the worker protocol, driven with a fake clock: ticks answered in order, a worker
that misses a tick's deadline declared dead (and named), stray and malformed frames counted and dropped, a
refusal for another map, a worker that gives a silent coordinator up."""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from sims.engine.sim import SimConfig
from sims.workers import wire
from sims.workers.coordinator import CoordinatorCore
from sims.workers.run import RefusedRun, WorkerShare, config_from_wire, config_to_wire, run_digests
from sims.workers.worker import SILENCE_MIN_S, WorkerCore
from tests.sims.engine.test_routes import grid

CONFIG = SimConfig(entities=10, viewers=0, transit=False, start=0.0, subscribe="radius")


@pytest.fixture(scope="module")
def topo():
    return grid()


def worker(topo, name="w"):
    digests = run_digests(topo, None)

    def build(config, want, index, n):
        if want != digests:
            raise RefusedRun("another map")
        return WorkerShare(topo, None, config_from_wire(config), index, n)

    return WorkerCore(name, "host", 1, build)


def test_two_workers_answer_each_tick_and_together_carry_every_entity(topo):
    core = CoordinatorCore("r", 2, config_to_wire(CONFIG), run_digests(topo, None), timeout=5.0)
    ws = [worker(topo, f"w{i}") for i in range(2)]
    for i, w in enumerate(ws):
        for f in w.receive(core.assign_frame(i), 0.0):
            core.receive(f, 0.0)
    assert core.all_ready() and [s.worker for s in core.slots] == ["w0", "w1"]
    published = set()
    for k in range(6):
        frame = core.tick(k, float(k))
        assert core.waiting() == [0, 1]
        for w in ws:
            for f in w.receive(frame, float(k)):
                core.receive(f, float(k))
        assert core.waiting() == []
        for data in filter(None, core.outs.values()):
            published |= {m.entity for m in P.decode_payload(data) if isinstance(m, P.Publish)}
    assert published == set(ws[0].share.world.agents)  # every entity published, by one worker or the other
    assert [s.owned for s in core.slots] == [5, 5]


def test_a_worker_that_misses_the_deadline_is_declared_dead_and_named(topo):
    core = CoordinatorCore("r", 2, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    ws = [worker(topo, f"w{i}") for i in range(2)]
    for i, w in enumerate(ws):
        for f in w.receive(core.assign_frame(i), 0.0):
            core.receive(f, 0.0)
    frame = core.tick(0, 10.0)
    for f in ws[0].receive(frame, 10.0):
        core.receive(f, 10.0)
    assert core.expire(11.9) == [] and core.waiting() == [1]
    assert core.expire(12.0) == [1]
    assert core.slots[1].dead == "no answer to tick 0 within 2 s" and core.alive == [0]
    for f in ws[1].receive(frame, 12.5):  # it answers after all: too late, counted, not used
        core.receive(f, 12.5)
    assert core.stray == 1 and 1 not in core.outs
    assert wire.decode(core.tick(1, 13.0))["dead"] == [1]  # the survivors learn it with the next tick


def test_stray_and_malformed_frames_are_counted_and_dropped(topo):
    core = CoordinatorCore("r", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    core.receive(b"\xc1garbage", 0.0)
    core.receive(wire.encode("ready", run="other", index=0, worker="x", host="h", pid=1), 0.0)
    core.receive(wire.encode("ready", run="r", index=7, worker="x", host="h", pid=1), 0.0)
    assert core.bad_frames == 1 and core.stray == 2 and not core.all_ready()
    w = worker(topo)
    assert w.receive(b"junk", 0.0) == [] and w.bad_frames == 1
    assert w.receive(wire.encode("tick", run="r", k=0, dead=[]), 0.0) == [] and w.ignored == 1  # not in a run


def test_another_map_is_refused_with_why_and_a_busy_worker_refuses_a_second_run(topo):
    core = CoordinatorCore("r", 1, config_to_wire(CONFIG), {"topology": "x", "schedule": ""}, timeout=2.0)
    w = worker(topo)
    for f in w.receive(core.assign_frame(0), 0.0):
        core.receive(f, 0.0)
    assert core.refusals() == ["worker 0 (?): another map"] and w.idle
    good = CoordinatorCore("r2", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    w.receive(good.assign_frame(0), 0.0)
    third = CoordinatorCore("r3", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    assert wire.decode(w.receive(third.assign_frame(0), 0.0)[0])["why"] == "busy in run r2"


def test_unknown_settings_are_a_refusal_not_a_crash(topo):
    w = worker(topo)
    bad = CoordinatorCore("r", 1, {**config_to_wire(CONFIG), "warp": 9}, run_digests(topo, None), timeout=2.0)
    assert "warp" in wire.decode(w.receive(bad.assign_frame(0), 0.0)[0])["why"]
    bad = CoordinatorCore("r", 1, {**config_to_wire(CONFIG), "tick_hz": -1.0}, run_digests(topo, None), timeout=2.0)
    assert "tick rate" in wire.decode(w.receive(bad.assign_frame(0), 0.0)[0])["why"]


def test_ticks_out_of_order_are_ignored_and_a_silent_coordinator_is_given_up(topo):
    core = CoordinatorCore("r", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=1.0)
    w = worker(topo)
    w.receive(core.assign_frame(0), 0.0)
    assert w.receive(wire.encode("tick", run="r", k=3, dead=[]), 0.0) == [] and w.ignored == 1
    assert w.receive(wire.encode("alive", run="r"), 4.0) == []  # the coordinator's heartbeat
    assert not w.expire(4.0 + SILENCE_MIN_S)  # never sooner than SILENCE_MIN_S, whatever the timeout
    assert w.expire(4.1 + SILENCE_MIN_S) and w.idle and "silent" in w.ended


def test_time_and_counts_are_checked(topo):
    with pytest.raises(ValueError):
        CoordinatorCore("r", 0, {}, {}, 1.0)
    with pytest.raises(ValueError):
        CoordinatorCore("r", 1, {}, {}, 0.0)
    core = CoordinatorCore("r", 1, {}, {}, 1.0)
    core.tick(0, 0.0)
    with pytest.raises(ValueError, match="tick 2 after tick 0"):
        core.tick(2, 1.0)
    share = WorkerShare(topo, None, CONFIG, 0, 1)
    with pytest.raises(ValueError, match="in order"):
        share.tick(1, [])


@pytest.mark.parametrize("bad", [{"entities": "many"}, {"seed": "x"}, {"start": None}])
def test_an_assign_whose_settings_break_the_build_is_a_refusal_and_the_worker_stays(topo, bad):
    """An assign arrives from the network (any NATS publisher): settings of a wrong type that the config does not
    check must not kill the worker daemon with a traceback; it refuses, naming why, and takes the next run."""
    w = worker(topo)
    core = CoordinatorCore("r", 1, {**config_to_wire(CONFIG), **bad}, run_digests(topo, None), timeout=2.0)
    (answer,) = w.receive(core.assign_frame(0), 0.0)
    f = wire.decode(answer)
    assert f["kind"] == "refuse" and "bad run settings" in f["why"] and next(iter(bad)) in f["why"] and w.idle
    good = CoordinatorCore("r2", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    assert wire.decode(w.receive(good.assign_frame(0), 0.0)[0])["kind"] == "ready"


def test_a_build_that_fails_otherwise_is_a_refusal_naming_the_error(topo):
    def build(config, want, index, n):
        raise KeyError("schedule")  # whatever else a share's build may raise on what the frame carries

    w = WorkerCore("w", "host", 1, build)
    core = CoordinatorCore("r", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    f = wire.decode(w.receive(core.assign_frame(0), 0.0)[0])
    assert f["kind"] == "refuse" and f["why"] == "cannot build the run: KeyError: 'schedule'" and w.idle


def test_a_tick_in_parts_is_bounded_like_one_frame(topo, monkeypatch):
    """A worker (a bug, another version) that sends parts and never the last: the coordinator holds at most one
    frame's worth (`wire.MAX_FRAME`), counts the output as bad and drops it; the worker then misses the tick."""
    monkeypatch.setattr(wire, "MAX_FRAME", 1000)
    core = CoordinatorCore("r", 1, config_to_wire(CONFIG), run_digests(topo, None), timeout=2.0)
    core.tick(0, 0.0)
    for i in range(3):
        core.receive(wire.encode("out", run="r", index=0, k=0, part=i, last=False, frame=b"x" * 400, counters={},
                                 step_s=0.1, owned=0), 0.0)
    assert core.bad_frames == 1 and core.slots[0].parts == [] and core.waiting() == [0]
    assert core.expire(2.0) == [0]
