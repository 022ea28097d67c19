"""The NATS client's once-per-read hook (`NatsClient.on_batch`, entitynet/cluster/nats_client.py): what a handler
would otherwise do per message (the cluster link wakes the server's flusher) is done once per socket read, also
when a malformed or oversized message ends the read, and never before the messages it covers were dispatched.

Why a scripted server here: the batching depends on how bytes arrive, which a real nats-server does not let a
test decide; this one writes the bursts in one write each. (The real server is test_nats_client.py's.)
"""

from __future__ import annotations

from functools import partial

import trio

from entitynet.cluster.nats_client import NatsClient


def _msg(i: int) -> bytes:
    payload = b"state-%d" % i
    return b"MSG en.c.1 1 %d\r\n%s\r\n" % (len(payload), payload)


async def _scripted_server(bursts: list[bytes], go: trio.Event):
    """A listener that greets, accepts the CONNECT (its PING answered), then writes each burst in one write."""
    first = [True]

    async def handle(stream: trio.SocketStream) -> None:
        await stream.send_all(b'INFO {"max_payload":1048576}\r\n')
        seen = b""
        while b"PING\r\n" not in seen:
            data = await stream.receive_some(4096)
            if not data:
                return
            seen += data
        await stream.send_all(b"PONG\r\n")
        if first[0]:
            first[0] = False
            await go.wait()
            for burst in bursts:
                await stream.send_all(burst)
                await trio.sleep(0.2)
        await trio.sleep_forever()

    return handle


async def test_a_burst_is_one_batch_and_a_bad_message_still_ends_its_batch(nursery):
    bursts = [b"".join(_msg(i) for i in range(50)),
              _msg(50) + _msg(51) + b"MSG en.c.1 1 99999999999\r\n"]  # the last one beyond max_payload
    go = trio.Event()
    handler = await _scripted_server(bursts, go)
    listeners = await nursery.start(partial(trio.serve_tcp, handler, 0, host="127.0.0.1"))
    port = listeners[0].socket.getsockname()[1]
    log: list = []
    lost: list[str] = []
    nc = NatsClient(f"nats://127.0.0.1:{port}", on_batch=lambda: log.append("batch"),
                    on_disconnect=lost.append, reconnect_wait=5.0)
    async with nc:
        nc.subscribe("en.c.1", lambda s, r, p: log.append(p))
        log.clear()  # (the handshake's own hook call)
        go.set()
        with trio.fail_after(10):
            while not lost:
                await trio.sleep(0.01)
    msgs = [x for x in log if x != "batch"]
    assert msgs == [b"state-%d" % i for i in range(52)]  # every good message, in order, none after the bad one
    batches = log.count("batch")
    assert 2 <= batches < 10  # one per read: far fewer than the 52 messages
    assert log[-1] == "batch"  # the bad message ended the read, and its good messages still got their hook
    assert log.index(b"state-49") < log.index("batch", log.index(b"state-49")) < log.index(b"state-50")
    assert "max_payload" in lost[0]
