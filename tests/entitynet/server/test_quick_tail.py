"""A frame that ends with its only PING (`Server._quick_tail`): the rest is fed to the core, the PING answered
past it (`Server._pong_now`) with the states waiting, in one frame. Over real loopback sockets, each scenario is
run twice on fresh servers with a fixed clock, once with the quick tail and once with it turned off (the frame fed
whole, as before), and with the pure and the compiled read path: every client must read the same messages in the
same frames. Hostile frames too: an ERROR before the PING, a frame past the reply bound, two PINGs, huge ids, a
HELLO and its PING in one frame."""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from entitynet.server import hubpass
from entitynet.server.app import Server
from tests.entitynet.server_helpers import Raw, running

NOW = 1_764_000_000.25  # a fixed server clock: PONGs carry the same server_ms in every run
QUIET = dict(clock=lambda: NOW, flush_interval=30.0, flush_min_interval=30.0, latency_budget=30.0,
             flush_fill=1_000_000)  # nothing is flushed on its own: states wait for the PONG's frame
SYNC = 999_999


def _norm(msgs: list[P.Message]) -> list:
    """A frame's messages, comparable across runs (a WELCOME's session id is random)."""
    return [type(m).__name__ if isinstance(m, P.Welcome) else m for m in msgs]


async def _frames_until_sync(c: Raw) -> list[list]:
    """Every frame up to and including the one with the sync PONG (sent right after the frame under test), or
    up to the close (a frame the server refuses)."""
    await c.send(P.Ping(SYNC))
    out: list[list] = []
    while True:
        msgs = await c.read()
        if msgs is None:
            out.append(["closed"])
            return out
        out.append(_norm(msgs))
        if any(isinstance(m, P.Pong) and m.client_ms == SYNC for m in msgs):
            return out


async def _scenario(frames: list[list[P.Message]], quick: bool, compiled: bool, switch: dict | None = None):
    """A publisher with three entities in cells 2 and 3, a viewer of cell 2; then each frame of `frames` is sent
    by the viewer, each followed by a sync PING. Returns what the viewer read, frame by frame, and how many
    times the core was fed."""
    was = hubpass.compiled_in_use()
    hubpass.use_compiled(compiled)
    saved = Server._quick_tail
    if not quick:
        Server._quick_tail = lambda self, conn, msgs: False  # type: ignore[method-assign]
    try:
        async with running(switch={"seed": 1, **(switch or {})}, **QUIET) as server:
            pub = await Raw.connect(server)
            view = await Raw.connect(server)
            await view.send(P.Subscribe((2,), ()), P.Ping(1))
            await view.expect(P.Pong)
            await pub.send(P.Publish(1, 5, (2,), 10_000, b"a"), P.Publish(2, 5, (3,), 10_000, b"b"),
                           P.Publish(3, 5, (2, 3), 10_000, b"c"), P.Ping(2))
            await pub.expect(P.Pong)
            fed = 0
            receive = server.sb.receive

            def counted(*a, **kw):
                nonlocal fed
                fed += 1
                return receive(*a, **kw)

            server.sb.receive = counted
            got = []
            for frame in frames:
                await view.send_bytes(P.encode_frame(frame))
                got.append(await _frames_until_sync(view))
                if got[-1][-1] == ["closed"]:
                    break
            return got, fed, server.sb.has_news()
    finally:
        Server._quick_tail = saved  # type: ignore[method-assign]
        hubpass.use_compiled(was)


PATHS = [pytest.param(False, id="pure")]
if hubpass.COMPILED is not None:
    PATHS.append(pytest.param(True, id="compiled"))

SCENARIOS = {
    "subscribe-and-ping": [[P.Subscribe((3,), ()), P.Ping(7)]],
    "unsubscribe-and-ping": [[P.Subscribe((), (2,)), P.Ping(7)], [P.Subscribe((2, 3), ()), P.Ping(8)]],
    "publishes-and-ping": [[P.Publish(9, 1, (2,), 10_000, b"v"), P.Publish(10, 1, (4,), 10_000, b"w"),
                            P.Ping(7)]],
    "error-before-ping": [[P.Subscribe((10**9,), ()), P.Ping(7)]],
    "huge-id-before-ping": [[P.Publish(2**40, 1, (2,), 10_000, b"x"), P.Ping(7)]],
    "huge-ping": [[P.Subscribe((3,), ()), P.Ping(2**63 - 1)]],
    "subscribe-error-publish-ping": [[P.Subscribe((3,), ()), P.Publish(2**40, 1, (2,), 10_000, b"x"), P.Ping(7)]],
    "two-pings": [[P.Subscribe((3,), ()), P.Ping(7), P.Ping(8)]],
    "ping-not-last": [[P.Ping(7), P.Subscribe((3,), ())]],
    "query-before-ping": [[P.Query(5, P.QUERY_CELLS, (2,)), P.Ping(7)]],
}


@pytest.mark.parametrize("compiled", PATHS)
@pytest.mark.parametrize("name", sorted(SCENARIOS))
async def test_the_quick_tail_reads_the_same_as_the_whole_frame(name, compiled):
    frames = SCENARIOS[name]
    quick, _fed_q, news_q = await _scenario(frames, True, compiled)
    whole, _fed_w, news_w = await _scenario(frames, False, compiled)
    assert quick == whole
    assert not news_q and not news_w  # everything went with the PONGs: nothing for the flusher


@pytest.mark.parametrize("compiled", PATHS)
async def test_a_subscribe_and_its_ping_come_back_in_one_frame_past_the_core(compiled):
    got, fed, news = await _scenario([[P.Subscribe((3,), ()), P.Ping(7)]], True, compiled)
    first = got[0][0]
    assert first[0] == P.Pong(7, P.now_ms(NOW))
    assert all(isinstance(m, P.Update) for m in first[1:])  # the new cell's states, after the PONG
    assert b"b" in {m.payload for m in first[1:]}
    assert fed == 1  # the core was fed the SUBSCRIBE only (the sync PING is a lone frame: not fed either)
    assert not news


async def test_an_error_before_the_ping_keeps_the_replies_in_order():
    got, _fed, _news = await _scenario([[P.Subscribe((10**9,), ()), P.Ping(7)]], True, True)
    kinds = [type(m) for frame in got[0] for m in frame]
    assert kinds.index(P.Error) < kinds.index(P.Pong)  # the SUBSCRIBE's ERROR first, as the core queued it


async def test_past_the_reply_bound_the_frame_is_fed_whole_and_the_ping_refused_alike():
    bad = [P.Publish(2**40 + k, 1, (2,), 10_000, b"x") for k in range(3)]  # an ERROR each
    frames = [[*bad, P.Ping(7)]]
    switch = {"max_replies_per_frame": 3}
    quick, _, _ = await _scenario(frames, True, True, switch)
    whole, _, _ = await _scenario(frames, False, True, switch)
    assert quick == whole
    flat = [m for frame in quick[0] for m in frame]
    assert not any(isinstance(m, P.Pong) and m.client_ms == 7 for m in flat)  # refused, as the core says
    assert any(isinstance(m, P.Error) and m.code == P.ErrorCode.TOO_MANY_REQUESTS for m in flat)


async def _hello_frames(quick: bool) -> list[list]:
    saved = Server._quick_tail
    if not quick:
        Server._quick_tail = lambda self, conn, msgs: False  # type: ignore[method-assign]
    try:
        async with running(switch={"seed": 1}, **QUIET) as server:
            c = await Raw.connect(server, hello=False)
            await c.send(P.Hello(P.PROTOCOL_VERSION, "", "test-digest"), P.Ping(4))
            return await _frames_until_sync(c)
    finally:
        Server._quick_tail = saved  # type: ignore[method-assign]


async def test_a_hello_and_its_ping_in_one_frame_come_back_in_one_frame_either_way():
    quick, whole = await _hello_frames(True), await _hello_frames(False)
    assert quick == whole
    assert quick[0] == ["Welcome", P.Pong(4, P.now_ms(NOW))]  # the WELCOME waited for the PING's frame
