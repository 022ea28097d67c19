"""Workers over NATS on loopback with real processes: a real nats-server, two `entitynet sim worker`
subprocesses and the coordinator `entitynet sim --nats`; one worker SIGKILLed mid-run is named in the report,
its entities restarted on the other, the run ends on time and no process is left behind. Bad input: a bad
URL, no NATS there, workers that never join, --workers 0 or negative: one clear error each, no hang."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from entitynet.cli import main
from entitynet.cluster.natsd import NatsCluster, free_port, nats_server_binary
from tests.sims.engine.test_routes import grid
from topology.artifact import save

try:
    nats_server_binary()
    HAVE_NATS = True
except RuntimeError:
    HAVE_NATS = False
needs_nats = pytest.mark.skipif(not HAVE_NATS, reason="nats-server is not installed")


@pytest.fixture(scope="module")
def grid_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("grid") / "grid.enttopo"
    save(grid(), path)
    return path


@pytest.fixture
def nats():
    with NatsCluster(1) as cluster:
        yield cluster.urls


def _entitynet(*args: str, log: Path, session: bool = False) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "entitynet", *args], stdout=subprocess.DEVNULL,
                            stderr=open(log, "w"), stdin=subprocess.DEVNULL,  # noqa: SIM115 (the child owns it)
                            start_new_session=session)


def _wait_for(path: Path, text: str, proc: subprocess.Popen, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in path.read_text():
            return
        assert proc.poll() is None, path.read_text()
        time.sleep(0.05)
    raise AssertionError(f"{text!r} not in {path.name} within {timeout} s: {path.read_text()}")


@needs_nats
def test_two_workers_over_nats_one_killed_mid_run(nats, grid_path, tmp_path):
    topo = ["--topology", str(grid_path)]
    logs = [tmp_path / f"worker{i}.log" for i in range(2)]
    workers = [_entitynet("sim", "worker", "--nats", nats, *topo, "--once", log=log) for log in logs]
    procs = list(workers)
    try:
        for w, log in zip(workers, logs, strict=True):
            _wait_for(log, "waiting for a run", w)
        report = tmp_path / "report.json"
        coord_log = tmp_path / "coordinator.log"
        coord = _entitynet("sim", "--nats", nats, "--workers", "2", *topo, "--gtfs", "none", "--entities", "16",
                           "--viewers", "3", "--connections", "2", "--duration", "10", "--speed", "2",
                           "--worker-timeout", "1", "--summary-every", "1", "--report", str(report), log=coord_log)
        procs.append(coord)
        for w, log in zip(workers, logs, strict=True):
            _wait_for(log, "joined run", w)
        _wait_for(coord_log, "[     2s]", coord)  # the run is under way
        victim = next(w for w, log in zip(workers, logs, strict=True) if "as worker 1" in log.read_text())
        victim.send_signal(signal.SIGKILL)
        assert coord.wait(30) == 0, coord_log.read_text()
        survivor = next(w for w in workers if w is not victim)
        assert survivor.wait(15) == 0, [log.read_text() for log in logs]
        rep = json.loads(report.read_text())
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(5)
    w = rep["workers"]
    (death,) = w["deaths"]
    assert death["worker"] == 1 and death["pid"] == victim.pid and "no answer to tick" in death["why"]
    assert death["entities"] > 0 and death["restarted"] == death["entities"] and death["restarted_on"] == [0]
    assert w["transport"] == f"nats {nats}" and w["entities_now"][1] == 0
    assert rep["sim_time_s"] == 10.0  # the run went on to its end without the dead worker
    assert "worker 1 (" in coord_log.read_text() and f"pid {victim.pid}) lost at tick" in coord_log.read_text()
    assert w["per_worker"][0]["alive"] and w["per_worker"][0]["pid"] == survivor.pid
    left = [p.pid for p in procs if psutil.pid_exists(p.pid) and psutil.Process(p.pid).status() != "zombie"]
    ours = [c for c in psutil.Process().children(recursive=True) if c.name() != "nats-server"]  # the fixture's
    assert left == [] and ours == []


@needs_nats
def test_a_worker_with_another_map_refuses_and_the_coordinator_says_why(nats, grid_path, tmp_path, capsys):
    from tests.entitynet.client_fixtures import make_topology
    from topology.raw import PEDESTRIAN, VEHICLE

    other = tmp_path / "other.enttopo"
    save(make_topology({"a": (0.0, 0.0), "b": (300.0, 0.0)}, [("a", "b", PEDESTRIAN | VEHICLE)]), other)
    log = tmp_path / "worker.log"
    w = _entitynet("sim", "worker", "--nats", nats, "--topology", str(other), "--once", log=log)
    try:
        _wait_for(log, "waiting for a run", w)
        code = main(["sim", "--nats", nats, "--workers", "1", "--topology", str(grid_path), "--gtfs", "none",
                     "--entities", "4", "--viewers", "1", "--duration", "1"])
        err = capsys.readouterr().err
        assert code == 2 and "worker 0 (" in err and "another topology than the coordinator's" in err
    finally:
        w.kill()
        w.wait(5)


@needs_nats
def test_workers_that_never_join_are_a_clear_error_after_the_join_timeout(nats, grid_path, capsys):
    t0 = time.monotonic()
    code = main(["sim", "--nats", nats, "--workers", "2", "--join-timeout", "0.5", "--topology", str(grid_path),
                 "--gtfs", "none", "--entities", "4", "--viewers", "1", "--duration", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "only 0 of 2 worker(s) joined" in err and "entitynet sim worker --nats" in err
    assert time.monotonic() - t0 < 10


def test_bad_urls_and_no_nats_there_are_clear_errors(grid_path, capsys):
    assert main(["sim", "--nats", "http://x:1", "--topology", str(grid_path), "--gtfs", "none"]) == 2
    assert "--nats: bad NATS server" in capsys.readouterr().err
    assert main(["sim", "worker", "--nats", "http://x:1"]) == 2
    assert "--nats: bad NATS server" in capsys.readouterr().err
    port = free_port()
    quick = ["--nats-connect-timeout", "0.1"]  # (the first connect gives up after 2 x 0.1 + 1 s, not 2 x 1 + 1)
    assert main(["sim", "--nats", f"nats://127.0.0.1:{port}", *quick, "--topology", str(grid_path), "--gtfs", "none",
                 "--entities", "4", "--viewers", "1", "--duration", "1"]) == 2
    assert f"cannot reach NATS at nats://127.0.0.1:{port}" in capsys.readouterr().err
    assert main(["sim", "worker", "--nats", f"nats://127.0.0.1:{port}", *quick, "--topology", str(grid_path)]) == 2
    assert "cannot reach NATS" in capsys.readouterr().err


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "1.5", "257"])
def test_worker_counts_out_of_range_are_usage_errors(bad, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["sim", "--workers", bad])
    assert exc.value.code == 2 and "--workers: expected an integer from 1 to 256" in capsys.readouterr().err


@needs_nats
def test_an_idle_worker_stops_on_ctrl_c_without_a_traceback(nats, grid_path, tmp_path):
    log = tmp_path / "worker.log"
    w = _entitynet("sim", "worker", "--nats", nats, "--topology", str(grid_path), log=log)
    try:
        _wait_for(log, "waiting for a run", w)
        w.send_signal(signal.SIGINT)
        assert w.wait(10) == 0
    finally:
        if w.poll() is None:
            w.kill()
            w.wait(5)
    text = log.read_text()
    assert "stopped" in text and "Traceback" not in text


@needs_nats
def test_a_worker_whose_coordinator_is_killed_gives_the_run_up_and_exits(nats, grid_path, tmp_path):
    log = tmp_path / "worker.log"
    w = _entitynet("sim", "worker", "--nats", nats, "--topology", str(grid_path), "--once",
                   "--coordinator-silence", "2", log=log)  # (the default is 5 s)
    coord_log = tmp_path / "coordinator.log"
    coord = None
    try:
        _wait_for(log, "waiting for a run", w)
        coord = _entitynet("sim", "--nats", nats, "--workers", "1", "--topology", str(grid_path), "--gtfs", "none",
                           "--entities", "8", "--viewers", "1", "--worker-timeout", "1", log=coord_log)  # (no 2 s
        # wait for more workers than the one there)
        _wait_for(log, "joined run", w)
        coord.send_signal(signal.SIGKILL)
        coord.wait(5)
        assert w.wait(15) == 0  # gave the run up after its silence limit, and --once ends it
    finally:
        for p in (w, coord):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(5)
    assert "run ended (the coordinator was silent for over 2 s)" in log.read_text()


def test_local_workers_die_with_a_killed_coordinator(grid_path, tmp_path):
    coord_log = tmp_path / "coordinator.log"
    coord = _entitynet("sim", "--workers", "2", "--topology", str(grid_path), "--gtfs", "none", "--entities", "8",
                       "--viewers", "1", "--summary-every", "0.5", log=coord_log)
    try:
        _wait_for(coord_log, "worker process(es) on this machine", coord)
        kids = psutil.Process(coord.pid).children(recursive=True)
        assert len(kids) == 2
        _wait_for(coord_log, "[     ", coord)  # the run is under way
        coord.send_signal(signal.SIGKILL)
        coord.wait(5)
        _gone, alive = psutil.wait_procs(kids, timeout=5)
        assert not alive, "a worker outlived its coordinator"
    finally:
        if coord.poll() is None:
            coord.kill()
            coord.wait(5)


def test_ctrl_c_ends_a_run_with_local_workers_cleanly(grid_path, tmp_path):
    coord_log = tmp_path / "coordinator.log"
    report = tmp_path / "report.json"
    coord = _entitynet("sim", "--workers", "2", "--topology", str(grid_path), "--gtfs", "none", "--entities", "8",
                       "--viewers", "1", "--summary-every", "0.5", "--report", str(report), log=coord_log,
                       session=True)
    try:
        _wait_for(coord_log, "worker process(es) on this machine", coord)
        kids = psutil.Process(coord.pid).children(recursive=True)
        _wait_for(coord_log, "[     ", coord)
        os.killpg(coord.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
        assert coord.wait(15) == 0, coord_log.read_text()
        _gone, alive = psutil.wait_procs(kids, timeout=5)
        assert not alive
    finally:
        if coord.poll() is None:
            coord.kill()
            coord.wait(5)
    assert "Traceback" not in coord_log.read_text()
    w = json.loads(report.read_text())["workers"]
    assert w["n"] == 2 and w["deaths"] == []  # the workers ignore the terminal's SIGINT: stopped in order


@needs_nats
def test_a_wrong_nats_token_is_a_clear_error_on_both_sides(grid_path, capsys):
    """At once and naming the refusal (the first connect waited out its whole deadline, retrying the token)."""
    import time

    with NatsCluster(1, token="s3cret") as cluster:
        url = cluster.urls
        t0 = time.monotonic()
        assert main(["sim", "--nats", url, "--nats-token", "wrong", "--topology", str(grid_path), "--gtfs",
                     "none", "--entities", "4", "--viewers", "1", "--duration", "1"]) == 2
        err = capsys.readouterr().err
        assert f"cannot reach NATS at {url}" in err and "Authorization Violation" in err, err
        assert "Traceback" not in err
        assert main(["sim", "worker", "--nats", url, "--nats-token", "wrong", "--topology", str(grid_path)]) == 2
        err = capsys.readouterr().err
        assert f"cannot reach NATS at {url}" in err and "Authorization Violation" in err, err
        assert time.monotonic() - t0 < 4.0  # each waited its whole first-connect deadline (3 s by default) before


@needs_nats
def test_a_worker_says_when_nats_goes_away_and_comes_back(grid_path, tmp_path):
    """A worker daemon whose NATS server dies keeps reconnecting: it says so (it was silent), and says when
    NATS is back; Ctrl-C still ends it cleanly."""
    from entitynet.cluster.natsd import NatsNode

    with NatsCluster(1) as cluster:
        node = cluster.nodes[0]
        log = tmp_path / "worker.log"
        w = _entitynet("sim", "worker", "--nats", node.url, "--topology", str(grid_path), log=log)
        again = None
        try:
            _wait_for(log, "waiting for a run", w)
            node.kill()
            _wait_for(log, "lost NATS at", w, timeout=10.0)
            again = NatsNode(node.port, None)
            again.proc = subprocess.Popen([nats_server_binary(), "-a", "127.0.0.1", "-p", str(node.port)],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            _wait_for(log, "is back", w, timeout=15.0)
            w.send_signal(signal.SIGINT)
            assert w.wait(10) == 0
            assert "Traceback" not in log.read_text()
        finally:
            if w.poll() is None:
                w.kill()
                w.wait(5)
            if again is not None:
                again.kill()


@needs_nats
def test_the_coordinator_says_when_nats_goes_away():
    from sims.workers.nats_link import NatsWorkers

    said: list[str] = []
    with NatsCluster(1) as cluster:
        link = NatsWorkers(cluster.urls, say=said.append)
        try:
            cluster.nodes[0].kill()
            deadline = time.monotonic() + 10.0
            while not said and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            link.close()
    assert said and said[0].startswith(f"lost NATS at {cluster.urls}")


@needs_nats
def test_the_announcements_kept_are_bounded():
    """Every idle worker on the NATS server announces itself each second for as long as the run lasts: the
    coordinator keeps at most MAX_WORKERS names, and none once it has chosen its workers."""
    from sims.workers import wire
    from sims.workers.nats_link import NatsWorkers

    with NatsCluster(1) as cluster:
        link = NatsWorkers(cluster.urls)
        try:
            for i in range(wire.MAX_WORKERS + 50):
                link._on_hello("", None, wire.encode("hello", worker=f"w{i}", host="h", pid=i))
            assert len(link.hellos) == wire.MAX_WORKERS
            link.hellos.clear()
            link._on_hello("", None, wire.encode("hello", worker="a", host="h", pid=1))
            assert link.choose(1, 1.0) == ["a"]
            link._on_hello("", None, wire.encode("hello", worker="b", host="h", pid=2))
            assert list(link.hellos) == ["a"]
        finally:
            link.close()
