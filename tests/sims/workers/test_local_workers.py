"""`WorkerSim` over forked local workers: with one worker and with two the report is the run in one process
(the GPS noise is per entity, not per worker), and a worker killed mid-run is named in the report with its
entities restarted on the survivor; no child process is left behind."""

from __future__ import annotations

import contextlib
import os
import signal

import psutil
import pytest

from sims.engine.local import LocalSwitch, run_local
from sims.engine.sim import Sim, SimConfig
from sims.workers.local import LocalWorkers
from sims.workers.sim import SAME_NOTE, WorkerSim
from tests.sims.engine.test_routes import grid

#: the timeout of the tick in which a test silences a worker (SIGSTOP): long enough that the other worker, only
#: slow (the 2-core CI machine running the suite: at 0.5 s both workers of a run were once declared dead), is not
#: taken for the silenced one, short enough to wait out once per test
SILENT_TIMEOUT_S = 3.0
#: the timeout of the ticks before it: a worker slowed by a loaded machine must not be declared dead (and told to
#: stop) before the test silences it (seen: worker 1 gone after 10 ticks at 3 s, the SIGSTOP then found no process)
WARM_TIMEOUT_S = 60.0


def _silence(sim: WorkerSim, pid: int) -> None:
    """Stop worker `pid` (alive but silent) after checking that no worker was lost so far, and give the coming
    tick the short timeout that declares it dead."""
    assert not sim.deaths, f"a worker was lost before the test silenced one: {sim.deaths}"
    sim.core.timeout = SILENT_TIMEOUT_S
    os.kill(pid, signal.SIGSTOP)


def config() -> SimConfig:
    return SimConfig(entities=16, viewers=4, connections=2, tick_hz=2.0, subscribe="radius", radius=400.0,
                     transit=False, start=0.0, seed=5)


@pytest.fixture(scope="module")
def topo():
    return grid()


def worker_run(topo, n: int, seconds: float = 15.0) -> tuple[dict, list[int]]:
    link = LocalWorkers(n, topo, None)
    pids = link.pids
    sim = WorkerSim(topo, config(), None, link, n, transport="local", timeout=5.0)
    try:
        rep = run_local(sim, seconds)
    finally:
        sim.close()
    return rep, pids


def no_children_left(pids: list[int]) -> bool:
    return not [p for p in pids if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]


def test_one_worker_gives_the_report_of_the_run_in_one_process(topo):
    alone = run_local(Sim(topo, config()), 15.0)
    rep, pids = worker_run(topo, 1)
    w = rep.pop("workers")
    assert rep == alone
    assert w["n"] == 1 and w["deaths"] == [] and w["interactions_missed_across_workers"] == 0
    assert w["per_worker"][0]["ticks"] == 31 and w["per_worker"][0]["pid"] == pids[0]
    assert no_children_left(pids)


def test_two_workers_give_the_report_of_the_run_in_one_process(topo):
    alone = run_local(Sim(topo, config()), 15.0)
    rep, pids = worker_run(topo, 2)
    w = rep.pop("workers")
    assert rep == alone  # fixes, messages, viewer figures: the noise is per entity, whoever takes its fixes
    assert rep["clients"]["published"] > 0 and rep["truth_vs_viewer"]["all"]["visible_entity_samples"] > 0
    assert w["differs"] == SAME_NOTE and w["deaths"] == []
    assert sum(w["entities_now"]) == sum(rep["entities"].values()) and min(w["entities_now"]) > 0
    assert no_children_left(pids)


def test_a_worker_killed_mid_run_is_named_and_its_entities_restarted(topo):
    link = LocalWorkers(2, topo, None)
    pids = link.pids
    sim = WorkerSim(topo, config(), None, link, 2, transport="local", timeout=5.0)
    sw = LocalSwitch(sim)
    try:
        sw.exchange(*sim.start())
        for k in range(30):
            if k == 10:
                os.kill(pids[1], signal.SIGKILL)
            sw.exchange(*sim.step())
            sim.maybe_sample(sw.eid_to_agent())
        rep = sim.report()
    finally:
        sim.close()
    (death,) = rep["workers"]["deaths"]
    assert death["worker"] == 1 and death["pid"] == pids[1] and "ended" in death["why"]
    assert death["entities"] > 0 and death["restarted"] == death["entities"] and death["lost"] == 0
    assert death["restarted_on"] == [0] and 5.0 <= death["sim_time_s"] <= 6.0
    live = sum(rep["entities"].values())
    assert rep["workers"]["entities_now"] == [live, 0]  # the survivor carries everyone
    published = {e.local for e in sw.sb.entities.values()}
    assert published == set(sim.world.agents)  # and every live entity is on the server again
    assert no_children_left(pids)


def test_when_every_worker_is_gone_the_run_ends_and_says_so(topo):
    link = LocalWorkers(1, topo, None)
    sim = WorkerSim(topo, config(), None, link, 1, transport="local", timeout=5.0)
    try:
        sim.start()
        os.kill(link.pids[0], signal.SIGKILL)
        sim.step()
        assert "every worker is gone" in sim.ended_early
        ticks = sim.ticks
        pubs, _subs = sim.step()  # nothing moves any more: the drivers stop on ended_early
        assert sim.ticks == ticks and not any(pubs)
        rep = sim.report()["workers"]
        assert rep["entities_lost"] == 16 and rep["deaths"][0]["lost"] == 16
    finally:
        sim.close()
    assert no_children_left(link.pids)


def test_a_worker_too_slow_for_the_timeout_is_declared_dead_and_told_so(topo):
    link = LocalWorkers(2, topo, None)
    sim = WorkerSim(topo, config(), None, link, 2, transport="local", timeout=WARM_TIMEOUT_S)
    try:
        sim.start()
        _silence(sim, link.pids[1])  # alive but silent: only the timeout can tell
        sim.step()
        (death,) = sim.deaths
        assert death["worker"] == 1 and f"no answer to tick 1 within {SILENT_TIMEOUT_S:g} s" in death["why"]
        sim.core.timeout = WARM_TIMEOUT_S  # worker 0, alone now, only slow on a loaded machine, stays
        os.kill(link.pids[1], signal.SIGCONT)
        for _ in range(3):
            sim.step()  # its late answer is stray; the run goes on with worker 0 alone
        link.procs[1].join(5)
        assert link.procs[1].exitcode == 0  # it got the stop and ended its run
        assert sim.assignment.counts(sim.world.agents)[1] == 0
    finally:
        sim.close()
    assert no_children_left(link.pids)


def test_an_entity_that_leaves_the_world_in_the_tick_its_worker_dies_is_unpublished(topo):
    """Entity 13 (worker 1's: id mod 2) arrives and leaves the world in the 11th tick of this seeded run. Its worker,
    silent in that very tick, never sends its UNPUBLISH: the coordinator sends it in its stead, or the server
    keeps a ghost of an entity that no longer exists until its validity runs out."""
    link = LocalWorkers(2, topo, None)
    sim = WorkerSim(topo, config(), None, link, 2, transport="local", timeout=WARM_TIMEOUT_S)
    sw = LocalSwitch(sim)
    try:
        sw.exchange(*sim.start())
        for _ in range(10):
            sw.exchange(*sim.step())
        assert 13 in sim.world.agents and 13 in {e.local for e in sw.sb.entities.values()}
        _silence(sim, link.pids[1])
        sw.exchange(*sim.step())
        assert [d["worker"] for d in sim.deaths] == [1] and 13 not in sim.world.agents  # left in this tick
        assert 13 not in {e.local for e in sw.sb.entities.values()}
        assert 13 not in sim.published_ids
    finally:
        with contextlib.suppress(ProcessLookupError):  # gone already: the assertion above says why
            os.kill(link.pids[1], signal.SIGCONT)
        sim.close()
    assert no_children_left(link.pids)


def test_frames_the_transport_dropped_are_in_the_report(topo):
    class Dropping(LocalWorkers):
        dropped = 3  # as `NatsWorkers` counts the frames its full queue turned away

    link = Dropping(1, topo, None)
    sim = WorkerSim(topo, config(), None, link, 1, transport="local", timeout=5.0)
    try:
        rep = run_local(sim, 1.0)
    finally:
        sim.close()
    assert rep["workers"]["frames_dropped"] == 3
    assert no_children_left(link.pids)
