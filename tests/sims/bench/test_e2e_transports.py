"""The e2e transports against real brokers: a constructor that fails part way closes what it opened."""

from __future__ import annotations

import psutil
import pytest

from sims.bench.e2e_transports import MqttTransport, OursTransport, RedisTransport, TransportError
from tests.sims.bench.test_e2e_run import BY_NAME, _run

pytest.importorskip("gmqtt")


def _open_sockets() -> int:
    return len(psutil.Process().net_connections(kind="all"))


def _failing(*a, **kw):
    raise TransportError("failed part way (test)")


@pytest.mark.parametrize("name, cls, method", [("entitynet", OursTransport, "_until"),
                                               ("mqtt-disc", MqttTransport, "settle"),
                                               ("redis-disc", RedisTransport, "settle")])
def test_a_constructor_that_fails_part_way_leaves_nothing_open(name, cls, method, helsinki, helsinki_path, tmp_path,
                                                               monkeypatch):
    """Every connection is open when the first answer (WELCOME, SUBACK, PONG) is awaited: failing there must
    close them all (and MQTT's event loop), not leave them to the garbage collector."""
    before = _open_sockets()
    monkeypatch.setattr(cls, method, _failing)
    with pytest.raises(TransportError, match="failed part way") as failed:
        _run(BY_NAME[name], helsinki, helsinki_path, tmp_path)
    # the traceback (held by `failed`) keeps the half-built transport alive: only closing can free its sockets
    assert failed.traceback and _open_sockets() == before
