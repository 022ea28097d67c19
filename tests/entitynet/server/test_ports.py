"""The server's listeners as a library: a port out of range is a ConfigError before anything binds (the kernel
would take 65536 as 0, any port), and a port in use is a ListenError naming the setting and the address."""

from __future__ import annotations

import socket

import pytest
import trio

from entitynet.server import ConfigError, serve
from entitynet.server.config import ListenError
from tests.entitynet.server_helpers import config


@pytest.mark.parametrize("setting", ["port", "ws_port", "metrics_port", "http_port"])
@pytest.mark.parametrize("value", [65536, -1, 7400.5, True])
def test_out_of_range_ports_are_config_errors(setting, value):
    with pytest.raises(ConfigError, match=setting.replace("_", "-")):
        trio.run(serve, config(**{setting: value}))


async def test_a_port_in_use_names_its_setting():
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    busy = holder.getsockname()[1]
    caught: list[ListenError] = []
    try:
        async with trio.open_nursery() as n:
            await n.start(serve, config(ws_port=busy))
    except* ListenError as group:  # raised inside the server's nursery (and ours)
        leaves = [group]
        while leaves and isinstance(leaves[0], BaseExceptionGroup):
            leaves = [e for g in leaves for e in g.exceptions]
        caught.extend(leaves)
    finally:
        holder.close()
    [err] = caught
    assert (err.setting, err.port) == ("ws_port", busy)
    assert f"127.0.0.1:{busy} (--ws-port)" in str(err) and "in use" in str(err)
