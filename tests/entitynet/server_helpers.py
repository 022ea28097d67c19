"""Real-socket helpers for server tests: an in-process server and a raw protocol client."""

from __future__ import annotations

import contextlib

import trio

from entitynet import protocol as P
from entitynet.server import ServerConfig, serve

DIGEST = "test-digest"


def config(**kw) -> ServerConfig:
    kw.setdefault("port", 0)
    kw.setdefault("digest", DIGEST)
    kw.setdefault("n_cells", 100)
    kw.setdefault("open_mode", True)
    kw.setdefault("flush_interval", 0.002)
    return ServerConfig(**kw)


@contextlib.asynccontextmanager
async def running(**kw):
    async with trio.open_nursery() as n:
        server = await n.start(serve, config(**kw))
        try:
            yield server
        finally:
            n.cancel_scope.cancel()


class Raw:
    """A protocol client on a raw TCP stream: send frames or arbitrary bytes, read messages."""

    def __init__(self, stream):
        self.stream = stream
        self.dec = P.FrameDecoder(P.CodecLimits(max_frame=1 << 24, max_messages=100_000))
        self.pending: list[P.Message] = []

    @classmethod
    async def connect(cls, server, hello: bool = True, token: str = "", digest: str = DIGEST) -> Raw:
        c = cls(await trio.open_tcp_stream("127.0.0.1", server.port))
        if hello:
            await c.send(P.Hello(P.PROTOCOL_VERSION, token, digest))
            w = await c.expect(P.Welcome)
            assert isinstance(w, P.Welcome)
        return c

    async def send(self, *msgs: P.Message) -> None:
        await self.stream.send_all(P.encode_frame(msgs))

    async def send_bytes(self, data: bytes) -> None:
        await self.stream.send_all(data)

    async def read(self, timeout: float = 5.0) -> list[P.Message] | None:
        """The next frame's messages; None at EOF."""
        with trio.fail_after(timeout):
            while True:
                msgs = self.dec.next_messages()
                if msgs is not None:
                    return msgs
                try:
                    data = await self.stream.receive_some(65536)
                except trio.BrokenResourceError:
                    data = b""
                if not data:
                    return None
                self.dec.receive_data(data)

    async def expect(self, kind, timeout: float = 5.0, pred=lambda m: True):
        """Read until a message of `kind` (matching pred) arrives; returns it (others are kept)."""
        with trio.fail_after(timeout):
            while True:
                for i, m in enumerate(self.pending):
                    if isinstance(m, kind) and pred(m):
                        return self.pending.pop(i)
                msgs = await self.read(timeout)
                if msgs is None:
                    raise EOFError("connection closed")
                self.pending.extend(msgs)

    async def expect_closed(self, timeout: float = 5.0) -> list[P.Message]:
        """Read everything until EOF; returns what came."""
        got = list(self.pending)
        self.pending = []
        with trio.fail_after(timeout):
            while (msgs := await self.read(timeout)) is not None:
                got.extend(msgs)
        return got

    async def aclose(self) -> None:
        await self.stream.aclose()


async def pair(server, cell: int = 1):
    """A publisher and a viewer of `cell`; check they work with `await flows(pub, view, seq)`."""
    pub = await Raw.connect(server)
    view = await Raw.connect(server)
    await view.send(P.Subscribe((cell,), ()))
    await view.send(P.Ping(1))
    await view.expect(P.Pong)  # subscription is in place
    return pub, view


async def flows(pub: Raw, view: Raw, seq: int, cell: int = 1) -> None:
    """The pair still works: a fresh publish reaches the viewer."""
    await pub.send(P.Publish(1, seq, (cell,), 10_000, b"%d" % seq))
    await view.expect(P.Update, pred=lambda u: u.seq == seq)
