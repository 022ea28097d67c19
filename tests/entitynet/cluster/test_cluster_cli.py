"""`entitynet cluster up` / `cluster status` / `serve --cluster` as real processes: a publisher on one
switchboard process is seen by a viewer on another, `status` lists both, and a SIGKILLed switchboard's
entities leave the survivor's viewers within the dead-shard time."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import trio

from entitynet import protocol as P
from entitynet.cli import main
from tests.entitynet.server_helpers import Raw
from tests.topology.mapfixtures import collection, grid
from topology.artifact import load, save
from topology.build import build
from topology.geojson_reader import geojson_to_raw
from topology.regions import RegionMap


@pytest.fixture(scope="module")
def small_town(tmp_path_factory):
    path = tmp_path_factory.mktemp("cluster") / "town.enttopo"
    save(build(geojson_to_raw(collection(*grid(5, 5)))), path)
    return path


class _Port:
    def __init__(self, port: int):
        self.port = port


async def test_cluster_up_status_and_a_killed_switchboard_process(small_town, tmp_path, capsys, nats_server):
    del nats_server  # only for the skip when nats-server is missing: `cluster up` starts its own
    state = tmp_path / "cluster.json"
    up = subprocess.Popen([sys.executable, "-m", "entitynet", "cluster", "up", "--shards", "2", "--topology",
                           str(small_town), "--duration", "30", "--state", str(state)],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        with trio.fail_after(20):
            while not state.exists():
                assert up.poll() is None, up.stdout.read().decode()
                await trio.sleep(0.1)
        st = json.loads(state.read_text())
        regions = RegionMap.load(st["regions"], topology_digest=load(small_town).digest)
        digest = load(small_town).digest
        ports = [int(s["address"].rsplit(":", 1)[1]) for s in st["shards"]]
        with trio.fail_after(20):  # both switchboards listen
            while True:
                try:
                    for p in ports:
                        await (await trio.open_tcp_stream("127.0.0.1", p)).aclose()
                    break
                except OSError:
                    await trio.sleep(0.1)
        cell = int(regions.cells_of(0)[0])
        pub = await Raw.connect(_Port(ports[0]), digest=digest)
        view = await Raw.connect(_Port(ports[1]), digest=digest)
        # the viewer looks mostly at its own shard's region (else it would be redirected to shard 0)
        await view.send(P.Subscribe((cell, *[int(c) for c in regions.cells_of(1)[:5]]), ()))
        await view.send(P.Ping(1))
        await view.expect(P.Pong)
        with trio.fail_after(30):  # until shard 1 has heard shard 0 and its NATS interest is in place
            seq = 0
            while True:
                seq += 1
                await pub.send(P.Publish(1, seq, (cell,), 60_000, b"x"))
                try:
                    u = await view.expect(P.Update, timeout=0.3)
                    break
                except trio.TooSlowError:
                    pass
        args = ["cluster", "status", "--state", str(state), "--json", "--listen", "1.2"]
        assert await trio.to_thread.run_sync(main, args) == 0  # the command runs its own trio loop
        status = json.loads(capsys.readouterr().out)
        assert sorted(s["shard"] for s in status) == [0, 1]
        by = {s["shard"]: s for s in status}
        assert by[0]["entities"] == 1 and by[1]["mirrored"] == 1 and by[0]["owned_regions"] == 1
        os.kill(st["shards"][0]["pid"], signal.SIGKILL)
        t0 = time.monotonic()
        lv = await view.expect(P.Leave, timeout=10)
        assert lv.entity == u.entity
        assert time.monotonic() - t0 < 5.0  # dead after 2 s without heartbeats, not the 60 s validity
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(10)
        except subprocess.TimeoutExpired:
            up.kill()
    assert not state.exists()  # cluster up cleaned up after itself


def test_serve_cluster_option_errors(small_town, tmp_path, capsys):
    base = ["serve", "--topology", str(small_town), "--open", "--port", "0"]
    assert main([*base, "--cluster", "http://x:1", "--shard", "0", "--shards", "2"]) == 2
    assert main([*base, "--cluster", "nats://127.0.0.1:1", "--shards", "2"]) == 2
    assert main([*base, "--cluster", "nats://127.0.0.1:1", "--shard", "0"]) == 2
    assert main([*base, "--cluster", "nats://127.0.0.1:1", "--shard", "5", "--shards", "2"]) == 2
    bad = tmp_path / "r.json"
    bad.write_text("{}")
    assert main([*base, "--cluster", "nats://127.0.0.1:1", "--shard", "0", "--regions", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("entitynet: error:") == 5 and "Traceback" not in err


def test_serve_cluster_with_no_nats_there_is_one_line_after_the_deadline(small_town):
    """No NATS server at --cluster (a port nothing listens on): a real `serve` process ends promptly after the first
    connect's deadline (`--nats-connect-timeout 0.5` x 2 + 1 = 2 s; the default's is 5 s) with one line naming
    the URL and the deadline, and exit status 2 (it was a TooSlowError traceback and exit status 1)."""
    import socket

    with socket.socket() as probe:  # bound, never listening: connections are refused
        probe.bind(("127.0.0.1", 0))
        url = f"nats://127.0.0.1:{probe.getsockname()[1]}"
        t0 = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "entitynet", "serve", "--topology", str(small_town), "--open",
                               "--port", "0", "--cluster", url, "--shard", "0", "--shards", "1",
                               "--nats-connect-timeout", "0.5"],
                              capture_output=True, text=True, timeout=60)
        took = time.monotonic() - t0
    assert done.returncode == 2, done.stderr
    assert f"entitynet: error: cannot join the cluster: no NATS server answered at {url} within 2 s" in done.stderr
    assert "Traceback" not in done.stderr and done.stderr.count("entitynet: error:") == 1, done.stderr
    assert 2 <= took < 12, took  # (the interpreter's start and the imports come on top of the deadline)


def test_cluster_status_with_no_nats_there_is_one_line(capsys):
    """`cluster status` against a port nothing listens on: one line after the first connect's deadline (it was a
    TooSlowError traceback: its `except` never saw the error inside the client's nursery's group)."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        url = f"nats://127.0.0.1:{probe.getsockname()[1]}"
        assert main(["cluster", "status", "--nats", url]) == 2
    err = capsys.readouterr().err
    assert f"cannot reach NATS at {url}: no NATS server answered at {url} within 5 s" in err and "Traceback" not in err


def test_serve_cluster_with_a_refused_nats_token_is_one_line_at_once(small_town, capsys, monkeypatch,
                                                                     nats_server_with_token):
    """A wrong (or missing) --nats-token: one line naming the refusal, at once (it was a TooSlowError traceback
    after the whole first-connect deadline)."""
    import time

    monkeypatch.delenv("ENTITYNET_NATS_TOKEN", raising=False)

    base = ["serve", "--topology", str(small_town), "--open", "--port", "0", "--cluster", nats_server_with_token.urls,
            "--shard", "0", "--shards", "1"]
    for token in (["--nats-token", "wrong"], []):
        t0 = time.monotonic()
        assert main([*base, *token]) == 2
        err = capsys.readouterr().err
        assert "entitynet: error: cannot join the cluster: NATS at" in err and "Authorization Violation" in err, err
        assert "Traceback" not in err and time.monotonic() - t0 < 4.0


def test_cluster_status_passes_the_nats_token(capsys, monkeypatch, nats_server_with_token):
    """`cluster status` took no token, so against a NATS that wants one (docs/deploy.md runs it with
    $ENTITYNET_NATS_TOKEN) it could only fail: with the token, from the option or the environment, it connects
    (no shard runs, so it hears none: exit 1); without it or with a wrong one, one line naming the refusal."""
    monkeypatch.delenv("ENTITYNET_NATS_TOKEN", raising=False)
    base = ["cluster", "status", "--nats", nats_server_with_token.urls, "--listen", "0.2"]
    assert main([*base, "--nats-token", "s3cret"]) == 1
    assert "no switchboard heard on" in capsys.readouterr().out
    monkeypatch.setenv("ENTITYNET_NATS_TOKEN", "s3cret")
    assert main(base) == 1
    monkeypatch.delenv("ENTITYNET_NATS_TOKEN")
    for token in (["--nats-token", "wrong"], []):
        assert main([*base, *token]) == 2
        err = capsys.readouterr().err
        assert "cannot reach NATS at" in err and "Authorization Violation" in err and "Traceback" not in err, err


@pytest.mark.parametrize("command", ["status", "serve"])
def test_an_unreadable_nats_ca_is_one_line(small_town, tmp_path, capsys, command):
    """A --nats-ca that is missing or not PEM: one line naming it, before anything connects (serve's was an
    uncaught FileNotFoundError or SSLError)."""
    junk = tmp_path / "junk.pem"
    junk.write_text("not a certificate\n")
    for ca in (tmp_path / "missing.pem", junk):
        args = (["cluster", "status", "--nats", "nats://127.0.0.1:1", "--nats-ca", str(ca)] if command == "status"
                else ["serve", "--topology", str(small_town), "--open", "--port", "0", "--cluster",
                      "nats://127.0.0.1:1", "--shard", "0", "--shards", "1", "--nats-ca", str(ca)])
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"entitynet: error: --nats-ca {ca}:" in err and "Traceback" not in err, err
