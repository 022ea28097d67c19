"""`entitynet sim --shards K` (and `demo --shards K`) on a local cluster: real nats-server and switchboard processes
on loopback, entities and viewers by where they are, per-shard figures, and no process left behind however the
run ends (its duration, Ctrl-C, or a SIGKILL of the simulation itself)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import psutil
import pytest

from tests.entitynet.cluster.shard_helpers import town_artifact


@pytest.fixture(scope="module")
def town(tmp_path_factory):
    return town_artifact(tmp_path_factory, "simcluster", 5)  # 500 m x 500 m, with a PVS and a view grid


def _sim(town, *extra: str) -> subprocess.Popen:
    import os

    env = {**os.environ, "TMPDIR": str(town.parent)}  # the cluster's run folder (a SIGKILL leaves it behind)
    return subprocess.Popen([sys.executable, "-m", "entitynet", "sim", "--shards", "2", "--topology", str(town),
                             "--entities", "24", "--viewers", "6", "--connections", "2", "--gtfs", "none",
                             "--summary-every", "0.5", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _children_once_running(proc: subprocess.Popen, want: int = 3, timeout: float = 30.0) -> list[psutil.Process]:
    """The simulation's child processes (nats-server and the shards) once all `want` of them exist."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        kids = psutil.Process(proc.pid).children(recursive=True)
        if len(kids) >= want:
            return kids
        time.sleep(0.1)
    raise AssertionError("the cluster's processes did not start")


def _all_gone(kids: list[psutil.Process], timeout: float = 10.0) -> bool:
    _gone, alive = psutil.wait_procs(kids, timeout=timeout)
    return not alive


def test_sim_on_two_shards_serves_entities_on_both_and_viewers_see_them(town, tmp_path):
    report = tmp_path / "report.json"
    proc = _sim(town, "--duration", "4", "--speed", "2", "--report", str(report))
    kids = _children_once_running(proc)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert _all_gone(kids, timeout=1.0), "a cluster process outlived the simulation"
    rep = json.loads(report.read_text())
    shards = rep["cluster"]["shards"]
    assert [s["shard"] for s in shards] == [0, 1] and all(s["heard"] for s in shards)
    # both shards served entities of their own (published to them by where the entities were) ...
    assert all(s["peak"]["entities"] > 0 for s in shards), shards
    assert sum(s["updates_in"] for s in shards) > 0
    # ... and viewers saw entities, some of them across shards (mirrored through NATS)
    assert rep["viewers"]["deliveries"] > 0
    assert sum(s["deliveries"] for s in shards) > 0
    assert any(s["peak"]["mirrored"] > 0 for s in shards)
    assert rep["server"]["in_process"] is False and rep["server"]["outages"] == 0
    assert "cluster: NATS nats://127.0.0.1:" in err and "2 shards" in err
    assert any("shards #0" in line and "#1" in line for line in err.splitlines())  # the live per-shard figures


def test_ctrl_c_stops_the_cluster_with_the_simulation(town):
    proc = _sim(town)  # no duration: runs until interrupted
    kids = _children_once_running(proc)
    deadline = time.monotonic() + 30
    while "| shards #0" not in (line := proc.stderr.readline()):  # running: a summary with per-shard figures
        assert line and time.monotonic() < deadline, "no summary"
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert _all_gone(kids), "Ctrl-C left cluster processes behind"


def test_ctrl_c_while_the_cluster_starts_stops_it_too(town):
    proc = _sim(town)
    kids = _children_once_running(proc)  # the shards may still be loading, the clients not connected
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode in (0, 130) and "Traceback" not in err, err
    assert _all_gone(kids), "Ctrl-C during the start left cluster processes behind"


def test_a_killed_simulation_takes_its_cluster_along(town):
    proc = _sim(town)
    kids = _children_once_running(proc)
    proc.kill()  # no chance to clean up: the children die with their parent (PR_SET_PDEATHSIG)
    proc.communicate(timeout=10)
    assert _all_gone(kids), "a SIGKILLed simulation left orphan cluster processes"


def test_demo_with_shards_runs_as_the_sim_preset_on_a_cluster(monkeypatch):
    """`entitynet demo --shards K` hands the demo's numbers to `entitynet sim --shards K` (sims.cluster_run)."""
    from entitynet.cli import main
    from sims import sim_cmd

    seen = []
    monkeypatch.setattr(sim_cmd, "run", lambda ns: seen.append(ns) or 0)
    assert main(["demo", "--shards", "3", "--nats-nodes", "2", "--entities", "50", "--duration", "5"]) == 0
    (ns,) = seen
    assert (ns.shards, ns.nats_nodes, ns.entities, ns.duration, ns.server) == (3, 2, 50, 5.0, None)


def test_sim_refuses_bad_cluster_options(capsys):
    from entitynet.cli import main

    assert main(["sim", "--shards", "2", "--server", "127.0.0.1:7400", "--duration", "1"]) == 2
    assert "either --shards or --server" in capsys.readouterr().err
    for bad in (["--shards", "0"], ["--shards", "2", "--nats-nodes", "0"]):  # refused while parsing
        with pytest.raises(SystemExit) as info:
            main(["sim", *bad, "--duration", "1"])
        assert info.value.code == 2 and f"argument {bad[-2]}" in capsys.readouterr().err


def test_demo_with_shards_runs_end_to_end_on_a_cluster(town, tmp_path):
    """The documented `entitynet demo --shards 2` through its real argument handling, `sim`'s run and a real
    cluster, in a process of its own bounded in time (the bundled map swapped for the small town so that it
    takes seconds)."""
    import os

    report = tmp_path / "report.json"
    script = (
        "import sys, entitynet.topology_cache as cache\n"
        "from pathlib import Path\n"
        "from topology.artifact import load\n"
        "cache.bundled_topology = lambda progress=None, with_pvs=True: (load(sys.argv[1]), Path(sys.argv[1]))\n"
        "from entitynet.cli import main\n"
        "sys.exit(main(sys.argv[2:]))\n")
    proc = subprocess.run(
        [sys.executable, "-P", "-c", script, str(town), "demo", "--shards", "2", "--gtfs", "none", "--entities", "24",
         "--viewers", "4", "--connections", "2", "--duration", "2", "--summary-every", "0.5", "--report",
         str(report)], capture_output=True, text=True, timeout=120, env={**os.environ, "TMPDIR": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(report.read_text())
    assert [s["shard"] for s in rep["cluster"]["shards"]] == [0, 1]
    assert rep["viewers"]["street"] + rep["viewers"]["roof"] == 4 and rep["config"]["measure_share"] == 0.25
    assert "2 shards" in proc.stderr and "Traceback" not in proc.stderr
