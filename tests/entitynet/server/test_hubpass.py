"""The read hub's per-read path (entitynet.server.hubpass): the compiled `_hubpass` against the pure reference,
over real non-blocking socket pairs and a real core, on the same bytes: the same bytes written back, the same
calls into the server (`_hub_bytes`, `_hub_eof`, `_pong_with_states`), the same counters and core state. Bytes
are split anywhere and include malformed, oversized and near-miss PING frames."""

from __future__ import annotations

import socket
import struct
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet import protocol as P
from entitynet.server import hubpass
from entitynet.switchboard import Switchboard, SwitchConfig

IMPLS = [pytest.param(hubpass.PURE, id="pure")]
if hubpass.COMPILED is not None:
    IMPLS.append(pytest.param(hubpass.COMPILED, id="compiled"))

NOW = 1_764_000_000.25  # a fixed clock: the PONG's server_ms is the same for both paths


class _Wake:
    def __init__(self) -> None:
        self.sets = 0

    def set(self) -> None:
        self.sets += 1


class _Scope:
    def __init__(self) -> None:
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class FakeServer:
    """The server side `hubpass` uses, recording every call; a real core behind it."""

    def __init__(self, read_size: int = 64, states_answer: bool = True, now: object = NOW):
        self.now = now
        self.sb = Switchboard(SwitchConfig(n_cells=16, digest="d", open_mode=True, seed=1))
        self.config = SimpleNamespace(read_size=read_size)
        self.pacer = SimpleNamespace(n=0)
        self.pacer.woke = lambda: setattr(self.pacer, "n", self.pacer.n + 1)
        self.written = self.frames = 0
        self.calls: list[tuple] = []
        self.states_answer = states_answer

    def clock(self) -> float:
        return self.now  # type: ignore[return-value]

    def _hub_eof(self, conn) -> None:
        self.calls.append(("eof",))

    def _hub_bytes(self, conn, data: bytes) -> None:
        self.calls.append(("bytes", data))
        conn.decoder.receive_data(data)  # as the server's does: what is buffered decides `mid_frame`

    def _pong_with_states(self, conn, pong: bytes) -> bool:
        self.calls.append(("states", pong))
        return self.states_answer


def _setup(read_size: int = 64, hello: bool = True, states_answer: bool = True, now: object = NOW):
    """A server with one client connection over a socket pair: (server, conn, the client's socket)."""
    server = FakeServer(read_size, states_answer, now)
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    theirs.settimeout(2.0)
    cid = server.sb.connect(NOW)
    if hello:
        server.sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, "t", "d")], NOW)
        server.sb.outbox(cid).drain()  # the WELCOME, written by the real server
    conn = SimpleNamespace(fd=ours.fileno(), sock=ours, decoder=P.FrameDecoder(P.DEFAULT_LIMITS), busy=False,
                           closed=False, cid=cid, outbox=server.sb.outbox(cid), scope=_Scope(), rest=None,
                           wake=_Wake())
    return server, conn, theirs


def _drain(sock: socket.socket) -> bytes:
    sock.setblocking(False)
    out = b""
    try:
        while chunk := sock.recv(65536):
            out += chunk
    except BlockingIOError:
        pass
    sock.settimeout(2.0)
    return out


def _observed(server: FakeServer, conn, peer: socket.socket) -> dict:
    ob = conn.outbox
    return {"calls": server.calls, "written": server.written, "frames": server.frames, "pacer": server.pacer.n,
            "rest": conn.rest, "busy": conn.busy, "wakes": conn.wake.sets, "cancelled": conn.scope.cancelled,
            "wire": _drain(peer), "queued": len(ob) if ob is not None else None,
            "dirty": sorted(server.sb._dirty), "errors": dict(server.sb.errors)}


def _run(impl, chunks: list[bytes], **kw) -> dict:
    server, conn, peer = _setup(**kw)
    try:
        for chunk in chunks:
            peer.sendall(chunk)
            impl.hub_ready(server, conn)
        for _ in range(1000):  # what a read size left behind, until a read finds nothing (and calls nothing)
            before = len(server.calls)
            impl.hub_ready(server, conn)
            if len(server.calls) == before:
                break
        return _observed(server, conn, peer)
    finally:
        conn.sock.close()
        peer.close()


def _both(chunks: list[bytes], **kw) -> dict:
    ref = _run(hubpass.PURE, chunks, **kw)
    if hubpass.COMPILED is not None:
        assert _run(hubpass.COMPILED, chunks, **kw) == ref
    return ref


def test_a_lone_ping_gets_its_pong_at_once_and_nothing_goes_to_the_deframer():
    got = _both([P.encode_frame([P.Ping(41)])])
    assert got["calls"] == [] and got["written"] == 1 and got["frames"] == 1 and got["pacer"] == 1
    dec = P.FrameDecoder(P.DEFAULT_LIMITS)
    dec.receive_data(got["wire"])
    assert dec.next_messages() == [P.Pong(41, P.now_ms(NOW))] and not dec.mid_frame


def test_edges_of_the_ping_value_and_near_misses():
    for ms in (0, 127, 128, 255, 256, 65_535, 65_536, 2**32 - 1, 2**32, P.MAX_INT):
        assert _both([P.encode_frame([P.Ping(ms)])])["calls"] == []
    over = struct.pack(">I", 12) + b"\x91\x92\x0f\xcf" + (P.MAX_INT + 1).to_bytes(8, "big")
    signed = struct.pack(">I", 6) + b"\x91\x92\x0f\xd1\x01\x2c"
    for data in (over, signed, P.encode_frame([P.Ping(1), P.Ping(2)]), P.encode_frame([P.Pong(1, 2)]),
                 P.encode_frame([P.Ping(3)]) + b"\x00", b"\xff" * 40):
        got = _both([data])
        assert got["calls"] == [("bytes", data)] and got["wire"] == b""


def test_a_ping_split_across_reads_or_behind_a_partial_frame_goes_the_usual_way():
    ping = P.encode_frame([P.Ping(7)])
    assert _both([ping[:3], ping[3:]])["calls"] == [("bytes", ping[:3]), ("bytes", ping[3:])]
    half = P.encode_frame([P.Ping(8)])[:5]
    assert _both([half, ping])["calls"] == [("bytes", half), ("bytes", ping)]  # mid-frame: no quick answer


def test_before_the_handshake_the_core_refuses_the_quick_pong():
    ping = P.encode_frame([P.Ping(5)])
    got = _both([ping], hello=False)
    assert got["calls"] == [("bytes", ping)] and got["written"] == 0 and got["pacer"] == 0


def test_a_busy_or_closed_connection_is_not_answered_past_its_writer():
    ping = P.encode_frame([P.Ping(5)])
    for field in ("busy", "closed"):
        results = []
        for impl in [p.values[0] for p in IMPLS]:
            server, conn, peer = _setup()
            setattr(conn, field, True)
            peer.sendall(ping)
            impl.hub_ready(server, conn)
            results.append(_observed(server, conn, peer))
            conn.sock.close()
            peer.close()
        assert all(r == results[0] for r in results)
        assert results[0]["calls"] == [("bytes", ping)]


@pytest.mark.parametrize("answer", [True, False])
def test_pending_states_go_to_the_servers_frame_with_the_pong(answer):
    results = []
    for impl in [p.values[0] for p in IMPLS]:
        server, conn, peer = _setup(states_answer=answer)
        conn.outbox.put_state(1, b"\x93\x01\x02\x03")
        peer.sendall(P.encode_frame([P.Ping(9)]))
        impl.hub_ready(server, conn)
        results.append(_observed(server, conn, peer))
        conn.sock.close()
        peer.close()
    assert all(r == results[0] for r in results)
    pong = P.encode_message(P.Pong(9, P.now_ms(NOW)))
    expect = [("states", pong)] + ([] if answer else [("bytes", P.encode_frame([P.Ping(9)]))])
    assert results[0]["calls"] == expect and results[0]["wire"] == b""


def test_end_of_stream_and_a_reset_both_end_the_connection():
    for impl in [p.values[0] for p in IMPLS]:
        server, conn, peer = _setup()
        peer.close()
        impl.hub_ready(server, conn)
        assert server.calls == [("eof",)]
        conn.sock.close()
        server, conn, peer = _setup()
        peer.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        peer.sendall(b"\x00")
        conn.sock.shutdown(socket.SHUT_RD)
        impl.hub_ready(server, conn)
        impl.hub_ready(server, conn)
        assert server.calls[-1] == ("eof",)
        conn.sock.close()
        peer.close()


def test_a_full_socket_leaves_the_whole_frame_to_the_writer_task():
    results = []
    for impl in [p.values[0] for p in IMPLS]:
        server, conn, peer = _setup()
        conn.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        try:
            while True:
                conn.sock.send(b"\x00" * 65536)
        except BlockingIOError:
            pass
        peer.sendall(P.encode_frame([P.Ping(77)]))
        impl.hub_ready(server, conn)
        results.append((conn.rest, conn.busy, conn.wake.sets, server.written, server.calls))
        conn.sock.close()
        peer.close()
    assert all(r == results[0] for r in results)
    rest, busy, wakes, written, calls = results[0]
    assert busy and wakes == 1 and written == 1 and calls == []
    assert rest == P.encode_frame([P.Pong(77, P.now_ms(NOW))])


def test_a_peer_gone_before_the_pong_cancels_the_connection():
    for impl in [p.values[0] for p in IMPLS]:
        server, conn, peer = _setup()
        peer.sendall(P.encode_frame([P.Ping(1)]))
        peer.close()
        impl.hub_ready(server, conn)
        assert conn.scope.cancelled and conn.rest is None and not conn.busy
        conn.sock.close()


def test_a_read_longer_than_the_read_size_comes_in_pieces_alike():
    data = P.encode_frame([P.Publish(1, 1, (2,), 1000, b"x" * 200)])
    got = _both([data], read_size=16)
    assert b"".join(c[1] for c in got["calls"]) == data and all(len(c[1]) <= 16 for c in got["calls"])


pings = st.integers(0, 2**64 - 1).map(lambda v: struct.pack(">I", len(b := b"\x91\x92\x0f" + (
    bytes([v]) if v < 0x80 else b"\xcf" + v.to_bytes(8, "big")))) + b)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(pings, st.binary(max_size=24),
                          st.integers(0, P.MAX_INT).map(lambda ms: P.encode_frame([P.Ping(ms)]))),
                max_size=6))
def test_arbitrary_reads_never_disagree(chunks):
    _both([c for c in chunks if c])


def test_the_compiled_recogniser_matches_the_reference_on_arbitrary_bytes():
    if hubpass.COMPILED is None:
        pytest.skip("not built")

    @settings(max_examples=150, deadline=None)
    @given(st.one_of(st.binary(max_size=20), pings))
    def check(data):
        assert hubpass.COMPILED.lone_ping_ms(data) == hubpass.PURE.lone_ping_ms(data)

    check()


def _run_or_raise(impl, chunks: list[bytes], **kw) -> dict | tuple[str, str]:
    try:
        return _run(impl, chunks, **kw)
    except Exception as exc:  # the reference's ValueError for a clock now_ms refuses: the same from both
        return (type(exc).__name__, str(exc))


@pytest.mark.parametrize("now", [0.0, -0.0, -5.0, 0.0005, 0.0015, 0.0025, 1.0004999, 12.3455, NOW, 2**43 + 0.5,
                                 9.007199254740991e12, 9.007199254740992e12, 1e300, float("inf"), float("-inf"),
                                 float("nan"), 7, True])
def test_the_compiled_pong_matches_the_core_on_any_clock(now):
    """The compiled path encodes the PONG itself (`now_ms` rounding, msgpack widths): the same frame, the same
    refusal (a NaN or infinite clock raises as `now_ms` does), for ordinary, boundary and hostile clocks."""
    for ms in (0, 127, 128, 65_536, 2**32, P.MAX_INT):
        chunks = [P.encode_frame([P.Ping(ms)])]
        ref = _run_or_raise(hubpass.PURE, chunks, now=now)
        if hubpass.COMPILED is not None:
            assert _run_or_raise(hubpass.COMPILED, chunks, now=now) == ref
        if isinstance(ref, dict):
            assert ref["wire"] == P.encode_frame([P.Pong(ms, P.now_ms(max(now, 0.0)))])


def test_the_compiled_pong_encoder_matches_encode_message():
    if hubpass.COMPILED is None:
        pytest.skip("not built")

    @settings(max_examples=200, deadline=None)
    @given(st.integers(0, P.MAX_INT), st.integers(0, 2**64 - 1))
    def check(client_ms, server_ms):
        assert hubpass.COMPILED.pong_bytes(client_ms, server_ms) == P.encode_message(P.Pong(client_ms, server_ms))

    check()
