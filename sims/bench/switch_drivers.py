"""The switch benchmark's load-generator drivers: the same workload spoken to entitynet, Redis and NATS.

Why apart from the benchmark: a driver is only the wire dialect (what a publisher and a viewer send, and how a
delivered payload is found in what a viewer reads); the load generator, the accounting and the ladder are the
same for every system, so that their figures compare like with like. Every payload is the same 48 bytes: a
16-byte head (send time, entity, seq) that the readers pull out with one regex, and 32 zero bytes standing in
for a dead-reckoning model.
"""

from __future__ import annotations

import struct

import msgpack

from entitynet import protocol as P
from sims.bench.switch_readers import Ready

PAYLOAD = struct.Struct("<dII")  # send time, loadgen entity id, seq  (+ padding: a dead-reckoning model)
PAD = b"\x00" * 32
TICK = 0.005


class OursDriver:
    """The load generator speaking entitynet's protocol: HELLO, SUBSCRIBE and PUBLISH frames, UPDATE heads."""

    name = "entitynet"
    # an UPDATE's payload: bin8 of 48 bytes (c4 30), our 16-byte head, 32 zero bytes, identity nil (c0)
    pattern = rb"\xc4\x30(.{16})\x00{32}\xc0"

    def __init__(self, port: int, digest: str):
        self.port, self.digest = port, digest

    def publisher_hello(self) -> bytes:
        """What a publisher connection sends first."""
        return P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "bench", self.digest)])

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        """A viewer's opening bytes and the marker that says its subscription is in place."""
        data = P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "bench", self.digest), P.Subscribe(tuple(cells), ()),
                               P.Ping(1)])
        return data, Ready(P.encode_message(P.Pong(1, 0))[:3], 1)  # the PONG after the subscription

    def publish_bytes(self, batch, now: float) -> bytes:
        """One frame of PUBLISHes for (entity, seq, cells, validity_ms) items, stamped with `now`."""
        msgs = [msgpack.packb([P.PUBLISH, i, seq, cells, val, PAYLOAD.pack(now, i, seq) + PAD])
                for i, seq, cells, val in batch]
        return P.frame(P.payload_from_encoded(msgs))


def _resp(*args: bytes) -> bytes:
    out = [b"*%d\r\n" % len(args)]
    for a in args:
        out.append(b"$%d\r\n%s\r\n" % (len(a), a))
    return b"".join(out)


class RedisDriver:
    """The same load against Redis pub/sub: one channel per cell, PUBLISH to every occupied cell."""

    name = "redis"
    # a pub/sub message: ... $48 CRLF, our 16-byte head, 32 zero bytes, CRLF
    pattern = rb"\$48\r\n(.{16})\x00{32}\r\n"

    def __init__(self, port: int):
        self.port = port

    def publisher_hello(self) -> bytes:
        """Redis needs no handshake."""
        return b""

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        """SUBSCRIBE to the cells' channels; ready when every channel is acknowledged."""
        return _resp(b"SUBSCRIBE", *[b"c%d" % c for c in cells]), Ready(b"$9\r\nsubscribe\r\n", len(cells))

    def publish_bytes(self, batch, now: float) -> bytes:
        """A pipeline of PUBLISH commands, one per occupied cell of each item."""
        out = []
        for i, seq, cells, _val in batch:
            payload = PAYLOAD.pack(now, i, seq) + PAD
            for c in cells:
                out.append(_resp(b"PUBLISH", b"c%d" % c, payload))
        return b"".join(out)


_NATS_CONNECT = b'CONNECT {"verbose":false,"pedantic":false,"echo":false,"name":"bench"}\r\n'


class NatsDriver:
    """The same load against core NATS (the text protocol, no JetStream): one subject per cell, PUB to every
    occupied cell's subject, each viewer a connection with one SUB per cell. `verbose: false`, so the server
    sends no +OK per command; the server's keep-alive PING comes every 2 minutes, longer than one run, so the
    readers need not answer it."""

    name = "nats"
    # a delivered message: MSG <subject> <sid> 48 CRLF, our 16-byte head, 32 zero bytes, CRLF
    pattern = rb"MSG c\d+ \d+ 48\r\n(.{16})\x00{32}\r\n"

    def __init__(self, port: int):
        self.port = port

    def publisher_hello(self) -> bytes:
        """CONNECT (no acknowledgements wanted)."""
        return _NATS_CONNECT

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        """CONNECT, one SUB per cell, then PING: the PONG says every SUB before it is in place (NATS handles a
        connection's commands in order)."""
        subs = b"".join(b"SUB c%d %d\r\n" % (c, k + 1) for k, c in enumerate(cells))
        return _NATS_CONNECT + subs + b"PING\r\n", Ready(b"PONG\r\n", 1)

    def publish_bytes(self, batch, now: float) -> bytes:
        """PUB commands, one per occupied cell of each item."""
        out = []
        for i, seq, cells, _val in batch:
            payload = PAYLOAD.pack(now, i, seq) + PAD
            for c in cells:
                out.append(b"PUB c%d 48\r\n%s\r\n" % (c, payload))
        return b"".join(out)
