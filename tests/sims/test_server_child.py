"""`entitynet sim --server-process`: the shard server in a child `entitynet serve`, started and stopped with the
run (its end, Ctrl-C, the child dying mid-run: a clear error, no hang, no process left behind), `auto` picking
by the run's size, and truth against viewers measured through the child (ids mapped by payload)."""

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
from sims.server_child import PROCESS_MIN_ENTITIES, PROCESS_MIN_VIEWERS, wants_server_process
from tests.sims.engine.test_routes import grid
from topology.artifact import save


@pytest.fixture(scope="module")
def grid_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("grid") / "grid.enttopo"
    save(grid(), path)
    return path


def test_auto_picks_a_child_server_for_large_runs_only():
    big_e, big_v = PROCESS_MIN_ENTITIES, PROCESS_MIN_VIEWERS
    assert wants_server_process("auto", big_e, 10)[0] is True
    assert wants_server_process("auto", 100, big_v)[0] is True
    assert wants_server_process("auto", big_e - 1, big_v - 1)[0] is False
    assert wants_server_process("auto", big_e, big_v, speed=0.5)[0] is False  # a child keeps wall-clock time
    assert wants_server_process("auto", big_e, big_v, speed=10.0)[0] is True
    assert wants_server_process("auto", big_e, big_v, external=True)[0] is False
    assert wants_server_process("no", big_e, big_v)[0] is False
    assert wants_server_process("yes", 1, 0)[0] is True
    assert "large run" in wants_server_process("auto", big_e, 0)[1]
    for bad in ({"mode": "yes", "external": True}, {"mode": "yes", "speed": 0.5}, {"mode": "maybe"}):
        with pytest.raises(ValueError):
            wants_server_process(bad.pop("mode"), 10, 1, **bad)


def test_cli_refuses_a_child_server_beside_an_external_one(capsys):
    assert main(["sim", "--server", "127.0.0.1:7400", "--server-process", "yes"]) == 2
    assert "not with --server or --shards" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # argparse's own usage error
        main(["sim", "--server-process", "sometimes"])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_the_default_is_auto_a_child_for_large_runs(grid_path, tmp_path, capsys):
    from sims.sim_cmd import sim_args

    assert sim_args().server_process == "auto"
    out = tmp_path / "rep.json"  # no --server-process: PROCESS_MIN_VIEWERS viewers make it a large run
    assert main(["sim", "--topology", str(grid_path), "--gtfs", "none", "--entities", "5", "--viewers",
                 str(PROCESS_MIN_VIEWERS), "--start", "00:00", "--duration", "1", "--speed", "2",
                 "--report", str(out)]) == 0
    server = json.loads(out.read_text())["server"]
    assert server["process"] is True and "large run" in server["why"] and not psutil.pid_exists(server["pid"])
    small = tmp_path / "small.json"
    assert main(["sim", "--topology", str(grid_path), "--gtfs", "none", "--entities", "5", "--viewers", "2",
                 "--start", "00:00", "--duration", "1", "--speed", "2", "--report", str(small)]) == 0
    assert json.loads(small.read_text())["server"]["in_process"] is True


def test_sim_runs_against_a_child_server_that_it_stops(grid_path, tmp_path, capsys):
    out = tmp_path / "rep.json"
    assert main(["sim", "--topology", str(grid_path), "--gtfs", "none", "--entities", "12", "--viewers", "3",
                 "--start", "00:00", "--duration", "4", "--speed", "4", "--server-process", "yes",
                 "--report", str(out)]) == 0
    rep = json.loads(out.read_text())
    server = rep["server"]
    assert server["in_process"] is False and server["process"] is True and server["outages"] == 0
    assert not psutil.pid_exists(server["pid"])  # stopped with the run
    assert f"a child process, pid {server['pid']}" in capsys.readouterr().err
    assert rep["viewers"]["deliveries"] > 0
    tv = rep["truth_vs_viewer"]["all"]  # measured through the child: its ids mapped back by payload
    assert tv["visible_entity_samples"] > 0 and tv["shown_ghost_samples"] > 0 and tv["missed_visibility"] < 0.5


def _sim_child(grid_path: Path, tmp_path: Path) -> tuple[subprocess.Popen, int, list[str]]:
    """`entitynet sim` in a process of its own (long run, child server); its child's pid once it listens."""
    cmd = [sys.executable, "-P", "-m", "entitynet", "sim", "--topology", str(grid_path), "--gtfs", "none",
           "--entities", "12", "--viewers", "3", "--start", "00:00", "--duration", "600", "--server-process",
           "yes", "--report", str(tmp_path / "rep.json")]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1", "TMPDIR": str(tmp_path)})  # its logs
    lines: list[str] = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line)
        if "a child process, pid " in line:
            pid = int(line.split("a child process, pid ")[1].split(":")[0])
            time.sleep(1.0)  # a tick or two against it
            return proc, pid, lines
    proc.kill()
    raise AssertionError("no child server started:\n" + "".join(lines))


def test_a_child_server_killed_mid_run_ends_the_run_with_its_last_words(grid_path, tmp_path):
    proc, pid, lines = _sim_child(grid_path, tmp_path)
    try:
        os.kill(pid, signal.SIGKILL)
        _, rest = proc.communicate(timeout=30)  # no hang: the run notices and ends
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2
    errors = [line for line in rest.splitlines() if line.startswith("entitynet: error:")]
    assert len(errors) == 1 and f"(pid {pid}) was killed by SIGKILL mid-run" in errors[0]
    assert "listening" in errors[0]  # the child's own last log lines are in the one line
    assert "Traceback" not in rest and not psutil.pid_exists(pid)
    assert not (tmp_path / "rep.json").exists()


def test_ctrl_c_stops_the_run_and_its_child_server(grid_path, tmp_path):
    proc, pid, _ = _sim_child(grid_path, tmp_path)
    try:
        proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and "Traceback" not in rest
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert rep["server"]["pid"] == pid and not psutil.pid_exists(pid)


def test_a_sim_killed_outright_leaves_no_server_behind(grid_path, tmp_path):
    """SIGKILL gives the sim no chance to stop its child: the child is tied to it (PDEATHSIG) and goes too."""
    proc, pid, _ = _sim_child(grid_path, tmp_path)
    proc.kill()
    proc.communicate(timeout=30)
    deadline = time.monotonic() + 10
    while not (gone := _gone(pid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    if not gone:  # the failure must not leave it behind either
        os.kill(pid, signal.SIGKILL)
    assert gone


def _gone(pid: int) -> bool:
    """Exited (a zombie waiting for init to reap it counts: it runs nothing)."""
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True
