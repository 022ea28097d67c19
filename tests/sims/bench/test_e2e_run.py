"""The end-to-end benchmark against real brokers on loopback (mosquitto, redis-server, `entitynet serve`):
every system's viewers get updates and the figures are computed; a malformed report is counted; a broker
that dies mid-run stops the run with a clear error, not a hang. Skipped where a broker binary is missing."""

from __future__ import annotations

import shutil
import time

import pytest

from sims.bench import e2e_run
from sims.bench.e2e_bench import SYSTEMS, run_one
from sims.bench.e2e_run import RunParams, System
from sims.bench.e2e_transports import MqttTransport, OursTransport, RedisTransport, TransportError
from sims.engine.viewers import radius_cells_at

pytest.importorskip("gmqtt")


def _exe(name: str) -> str | None:
    for exe in (shutil.which(name), f"/usr/sbin/{name}", f"/usr/bin/{name}"):
        if exe and shutil.os.path.exists(exe):
            return exe
    return None


EXES = {"mosquitto": _exe("mosquitto"), "redis-server": _exe("redis-server")}
P = RunParams(entities=40, viewers=4, seconds=4.0, speed=4.0, transit=False, measure_after=1.0, timeout_s=3.0,
              radius_m=400.0)
BY_NAME = {s.name: s for s in SYSTEMS}


def _needs(system: System) -> None:
    exe = {"mqtt": "mosquitto", "redis": "redis-server"}.get(system.transport)
    if exe and EXES[exe] is None:
        pytest.skip(f"{exe} not installed")


def _run(system: System, helsinki, helsinki_path, tmp_path, boxes=None) -> dict:
    _needs(system)
    return run_one(system, helsinki, helsinki_path, None, P, EXES, boxes, tmp_path, lambda m: None,
                   seen_at=radius_cells_at(helsinki, 300.0))


@pytest.fixture(scope="module")
def boxes(helsinki):
    from sims.bench.hfp_geohash import cell_boxes

    return cell_boxes(helsinki)


@pytest.mark.parametrize("name", ["entitynet", "entitynet-periodic", "mqtt-disc", "mqtt-pvs", "redis-disc"])
def test_each_system_delivers_updates_and_is_measured(name, helsinki, helsinki_path, tmp_path, boxes):
    r = _run(BY_NAME[name], helsinki, helsinki_path, tmp_path, boxes)
    assert r["messages_per_viewer_s"] > 0.5 and r["bytes_per_viewer_s"] > 20 * r["messages_per_viewer_s"]
    tv = r["truth_vs_viewer"]["all"]
    assert tv["visible_entity_samples"] > 0 and tv["shown_ghost_samples"] > 0
    assert r["error_p95_m"] is not None and 0.0 < r["error_p95_m"] < 100.0
    assert r["missed_visibility"] < 0.5 and r["malformed_payloads"] == 0
    assert r["server_cpu_s"] >= 0.0 and r["loadgen_cpu_s"] > 0.0 and r["subscriptions_mean"] > 0


def test_a_malformed_report_is_counted_and_the_run_goes_on(helsinki, helsinki_path, tmp_path, monkeypatch):
    orig = e2e_run.PeriodicFeed.step
    sent = []

    def with_garbage(self, now):
        out = orig(self, now)
        if out and not sent:
            aid, box, _payload = out[0]
            out.append((aid, box, b'{"VP":{"veh":'))  # truncated JSON on a topic some viewer holds
            sent.append(aid)
        return out

    monkeypatch.setattr(e2e_run.PeriodicFeed, "step", with_garbage)
    r = _run(BY_NAME["mqtt-disc"], helsinki, helsinki_path, tmp_path)
    assert sent and r["malformed_payloads"] >= 1 and r["messages_per_viewer_s"] > 0.5


@pytest.mark.parametrize("name, cls", [("mqtt-disc", MqttTransport), ("redis-disc", RedisTransport),
                                       ("entitynet", OursTransport)])
def test_a_broker_dying_mid_run_is_an_error_not_a_hang(name, cls, helsinki, helsinki_path, tmp_path, monkeypatch):
    orig = cls.sync
    killed_at: list[float] = []

    def dying(self, tick):
        if tick == 3:
            self.proc.kill()
            self.proc.wait()
            killed_at.append(time.monotonic())
        return orig(self, tick)

    monkeypatch.setattr(cls, "sync", dying)
    with pytest.raises(TransportError):
        _run(BY_NAME[name], helsinki, helsinki_path, tmp_path)
    # timed from the kill (not the broker's start and the world's build, slow on a loaded machine): the error
    # comes within the transport's timeout plus the time to stop the run
    assert killed_at and time.monotonic() - killed_at[0] < P.timeout_s + 5.0


def test_the_suite_reports_a_broker_failure_as_a_command_error(helsinki, helsinki_path, tmp_path, monkeypatch):
    from entitynet.cli import CommandError
    from sims.bench import e2e_bench

    _needs(BY_NAME["mqtt-disc"])

    def refused(self, *a, **kw):
        raise TransportError("cannot reach mosquitto: connection refused")

    monkeypatch.setattr(MqttTransport, "__init__", refused)
    with pytest.raises(CommandError, match="mqtt-disc: cannot reach mosquitto"):
        e2e_bench._guarded(BY_NAME["mqtt-disc"], helsinki, helsinki_path, None, P, EXES, None, tmp_path,
                           lambda m: None, seen_at=radius_cells_at(helsinki, 300.0))


def test_our_transport_turns_nagle_off_as_the_mqtt_and_redis_clients_do():
    """gmqtt (asyncio) and redis-py set TCP_NODELAY on their sockets; ours must too, or a PING sent right after
    a publisher's PUBLISH frame waits for the server's delayed ACK (about 40 ms a tick)."""
    import socket

    with socket.create_server(("127.0.0.1", 0)) as srv:
        t = object.__new__(OursTransport)
        t.timeout, t.proc = 2.0, None
        s = t._open(srv.getsockname()[1], b"")
        try:
            assert s.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
        finally:
            s.close()
