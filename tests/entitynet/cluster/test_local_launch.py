"""Shard processes are launched so that the folder they are started from cannot shadow the installed
`entitynet` (a checkout of another version beside the user's files), and a shard that dies at start says why."""

from __future__ import annotations

import subprocess
import sys

import pytest

from entitynet.cluster.local import LocalShards
from tests.entitynet.cluster.shard_helpers import town_artifact


@pytest.fixture(scope="module")
def town(tmp_path_factory):
    return town_artifact(tmp_path_factory, "launch", 3)


@pytest.fixture
def decoy_folder(tmp_path):
    """A working folder holding another `entitynet/` package, which fails on import."""
    decoy = tmp_path / "entitynet"
    decoy.mkdir()
    (decoy / "__init__.py").write_text('raise ImportError("the decoy entitynet in the working folder")\n')
    (decoy / "__main__.py").write_text('raise SystemExit("the decoy entitynet in the working folder")\n')
    return tmp_path


def test_cluster_up_from_a_folder_with_another_entitynet(town, decoy_folder):
    state = decoy_folder / "cluster.json"
    # the parent started so that it, too, imports the installed package (what the console script does)
    up = subprocess.run([sys.executable, "-P", "-m", "entitynet", "cluster", "up", "--shards", "2", "--topology",
                         str(town), "--duration", "1", "--state", str(state)], cwd=decoy_folder,
                        capture_output=True, text=True, timeout=90)
    assert up.returncode == 0, up.stdout + up.stderr
    assert "2 shards: 0=127.0.0.1:" in up.stdout and "decoy" not in up.stdout + up.stderr
    assert not state.exists()  # removed at the end


def test_a_shard_that_dies_at_start_shows_its_last_error_lines(town, tmp_path):
    map_path = tmp_path / "regions.json"
    from topology.artifact import load
    from topology.regions import build_regions

    build_regions(load(town), 2).save(map_path)
    shards = LocalShards(town, map_path, "nats://127.0.0.1:1", 2, tmp_path, extra=["--no-such-option"])
    with pytest.raises(RuntimeError) as err:
        shards.start(timeout=30)
    text = str(err.value)
    assert "unrecognized arguments: --no-such-option" in text, text
    assert "shard-0.log" in text
    assert all(pr.poll() is not None for pr in shards.procs)  # nothing left running


def test_children_are_launched_with_the_safe_path(tmp_path, decoy_folder):
    """The argv every launcher uses runs the installed entitynet even from the decoy's folder."""
    from entitynet.child_process import entitynet_argv

    out = subprocess.run(entitynet_argv("--version"), cwd=decoy_folder, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.startswith("entitynet "), out.stdout + out.stderr


def test_a_nats_server_that_dies_at_start_shows_its_last_error_lines(tmp_path, monkeypatch):
    from entitynet.cluster import natsd

    fake = tmp_path / "nats-server"
    fake.write_text("#!/bin/sh\necho 'nats: listen on 127.0.0.1 failed: permission denied' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setattr(natsd, "nats_server_binary", lambda: str(fake))
    with pytest.raises(RuntimeError, match="exited with 1; the end of .*nats-0.log:\nnats: listen on .* failed"):
        natsd.NatsCluster(1, log_dir=tmp_path).start(timeout=10)
