"""The flush loop (entitynet/server/flushloop.py and its compiled twin `_flushloop.pyx`): one frame per dirty
connection with one `writev`, the same bytes and the same effects on both paths.

Why: the compiled loop replaces the reference on the server's hottest path (about 60 % of the server's time
at the standard switch load), so it must be indistinguishable from it: every case of the loop (gone, busy,
closed, no plain socket, replies waiting, more than one frame, a write the kernel takes only in part, a peer
that is gone) is run on real loopback sockets through both, and the bytes each peer receives, the returned
lists and the connections' fields are compared.
"""

from __future__ import annotations

import random
import socket

import pytest

from entitynet import protocol as P
from entitynet.server import flushloop
from entitynet.switchboard.outbox import Outbox


def _pair(sndbuf: int | None = None) -> tuple[socket.socket, socket.socket]:
    """A connected TCP pair on loopback: (server side, non-blocking; client side)."""
    with socket.socket() as lst:
        lst.bind(("127.0.0.1", 0))
        lst.listen(1)
        cli = socket.create_connection(lst.getsockname())
        srv, _ = lst.accept()
    if sndbuf:
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, sndbuf)
    srv.setblocking(False)
    return srv, cli


def _read_all(sock: socket.socket) -> bytes:
    sock.setblocking(False)
    out = b""
    while True:
        try:
            data = sock.recv(1 << 20)
        except BlockingIOError:
            return out
        if not data:
            return out
        out += data


def _case(seed: int):
    """A random set of connections covering every branch of the loop; returns (dirty, conns, sockets)."""
    rng = random.Random(seed)
    conns: dict[int, flushloop.FlushConn] = {}
    socks = []
    dirty = []
    for cid in range(1, 41):
        kind = rng.choice(["short", "short", "short", "gone", "busy", "closed", "nofd", "control", "big",
                           "partial", "dead", "since"])
        dirty.append(cid)
        if kind == "gone":
            continue
        ob = Outbox(max_states=500, max_control=10)
        n = rng.randrange(1, 40) if kind != "big" else 300
        for e in range(n):
            size = rng.randrange(1, 60) if kind != "partial" else 4000
            ob.put_state(1000 + e, P.encode_update(1000 + e, cid, (e % 7,), 1000, bytes([cid]) * size))
        if kind == "control":
            ob.put_control(P.encode_message(P.Pong(1, 2)))
        srv, cli = _pair(sndbuf=4096 if kind == "partial" else None)
        socks.append((cid, srv, cli))
        conn = flushloop.FlushConn(cid, ob, None if kind == "nofd" else srv.fileno())
        conn.busy = kind == "busy"
        conn.closed = kind == "closed"
        if kind == "since":
            conn.dirty_since = 5.0
        if kind == "dead":
            cli.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
            cli.close()  # RST: the server side's write fails
        conns[cid] = conn
    return dirty, conns, socks


def _run(impl, seed: int, max_messages: int = 100, sure_fit: int = 50, max_body: int = 20_000, lat_n0: int = 0,
         hold_below: int = 0):
    dirty, conns, socks = _case(seed)
    res = impl.flush_short(dirty, conns, 7.0, max_messages, sure_fit, max_body, lat_n0, hold_below)
    n_msgs, n_frames, lat_n, samples, slow, blocked, failed, held = res
    received = {}
    for cid, srv, cli in socks:
        if cli.fileno() >= 0:
            received[cid] = _read_all(cli)
            cli.close()
        srv.close()
    fields = {cid: (c.busy, c.closed, c.dirty_since, c.rest, len(c.outbox), c.outbox.has_control)
              for cid, c in conns.items()}
    return {
        "counts": (n_msgs, n_frames, lat_n, len(samples)),
        "slow": [c.cid for c in slow], "blocked": [c.cid for c in blocked], "failed": [c.cid for c in failed],
        "held": held, "received": received, "fields": fields,
    }


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_loop_writes_the_same_bytes_with_the_same_effects(seed):
    if flushloop.COMPILED is None:
        pytest.skip("the compiled flush loop was not built (no Cython or C compiler at install time)")
    pure = _run(flushloop.PURE, seed)
    comp = _run(flushloop.COMPILED, seed)
    assert comp == pure
    assert pure["counts"][1] > 0  # frames were written on the short path


@pytest.mark.parametrize("seed", range(3))
def test_both_loops_sample_the_queue_latency_once_per_latency_every_frames(seed):
    """One latency sample per `LATENCY_EVERY` whole frames, counted across flushes (`lat_n` carries over), on
    both paths alike: a count one short of it makes the first whole frame a sample."""
    if flushloop.COMPILED is None:
        pytest.skip("the compiled flush loop was not built (no Cython or C compiler at install time)")
    start = flushloop.LATENCY_EVERY - 1
    pure = _run(flushloop.PURE, seed, lat_n0=start)
    comp = _run(flushloop.COMPILED, seed, lat_n0=start)
    assert comp["counts"] == pure["counts"]
    whole = pure["counts"][2] - start
    assert whole > 0 and pure["counts"][3] == 1 + (whole - 1) // flushloop.LATENCY_EVERY


def test_each_branch_of_the_loop(flush_path):
    res = _run(flushloop, 3)
    _dirty, kinds, socks = _case(3)
    for _cid, srv, cli in socks:
        srv.close()
        cli.close()
    for cid in res["slow"]:  # handed back untouched: replies waiting, no plain socket, or more than a frame
        assert res["fields"][cid][4] == len(kinds[cid].outbox) > 0
    for cid, data in res["received"].items():
        if data and cid not in res["blocked"]:  # a whole frame decodes: all the outbox's states, in order
            dec = P.FrameDecoder(P.CodecLimits(max_frame=1 << 24, max_messages=100_000))
            dec.receive_data(data)
            msgs = dec.next_messages()
            assert msgs is not None and dec.next_messages() is None
            assert [m.entity for m in msgs] == list(range(1000, 1000 + len(msgs)))
            assert all(m.seq == cid for m in msgs)
    assert res["counts"][2] == res["counts"][1] - len(res["blocked"]) - len(res["failed"])  # one per whole frame
    assert res["slow"] and res["blocked"] and res["failed"] and res["counts"][1] > len(res["blocked"])


@pytest.mark.parametrize("n", [1, 15, 16, 300, 0x10000])
def test_frames_of_every_array_header_size_decode(flush_path, n):
    """The prefix is the codec's `frame_prefix` (fixarray, array16, array32 headers)."""
    srv, cli = _pair()
    ob = Outbox(max_states=n + 1, max_control=1)
    for e in range(n):
        ob.put_state(e, P.encode_leave(e + P.LOCAL_ID_LIMIT))
    conn = flushloop.FlushConn(1, ob, srv.fileno())
    n_msgs, n_frames, *_rest = flushloop.flush_short([1], {1: conn}, 1.0, n + 1, n + 1, 1 << 22, 0)
    assert (n_msgs, n_frames) == (n, 1)
    data = conn.rest or b""
    cli.setblocking(True)
    cli.settimeout(5)
    got = b""
    want = len(P.frame_prefix(n, sum(len(P.encode_leave(e + P.LOCAL_ID_LIMIT)) for e in range(n))))
    total = want + sum(len(P.encode_leave(e + P.LOCAL_ID_LIMIT)) for e in range(n))
    srv.setblocking(True)
    if data:
        srv.sendall(data)  # what the writer task would send
    while len(got) < total:
        got += cli.recv(1 << 20)
    dec = P.FrameDecoder(P.CodecLimits(max_frame=1 << 24, max_messages=100_000))
    dec.receive_data(got)
    msgs = dec.next_messages()
    assert [m.entity - P.LOCAL_ID_LIMIT for m in msgs] == list(range(n))
    srv.close()
    cli.close()


def test_a_partial_write_leaves_the_rest_for_the_writer(flush_path):
    srv, cli = _pair(sndbuf=4096)
    ob = Outbox(max_states=100, max_control=1)
    for e in range(50):
        ob.put_state(e, P.encode_update(e + P.LOCAL_ID_LIMIT, 1, (1,), 1000, b"p" * 2000))
    conn = flushloop.FlushConn(1, ob, srv.fileno())
    *_c, slow, blocked, failed, _held = flushloop.flush_short([1], {1: conn}, 1.0, 100, 100, 1 << 20, 0)
    assert blocked == [conn] and not slow and not failed
    assert conn.busy and conn.rest and len(ob) == 0 and conn.dirty_since == 1.0  # latency counted when done
    srv.close()
    cli.close()


@pytest.mark.parametrize("hold_below", [-5, 0, 1, 2, 5, 41, 2**40])
@pytest.mark.parametrize("seed", range(4))
def test_both_loops_hold_the_same_small_frames(seed, hold_below):
    """`hold_below`: both loops hold the same connections (fresh ones with only states, fewer than it) and
    write the same bytes to the rest; hostile values (negative, 0, 1: off; huge: every fresh state-only one)."""
    if flushloop.COMPILED is None:
        pytest.skip("the compiled flush loop was not built (no Cython or C compiler at install time)")
    pure = _run(flushloop.PURE, seed, hold_below=hold_below)
    comp = _run(flushloop.COMPILED, seed, hold_below=hold_below)
    assert comp == pure
    if hold_below <= 1:
        assert pure["held"] == []


def test_a_small_frame_is_held_once_then_written(flush_path):
    """A fresh connection with fewer states than `hold_below` is held (nothing written, its states kept,
    `dirty_since` set: the flush that first saw it), and the next flush writes it whatever its size; a reply
    queued beside the states is never held; with as many states as `hold_below` it is written at once."""
    srv, cli = _pair()
    ob = Outbox(max_states=100, max_control=2)
    ob.put_state(1, P.encode_leave(1 + P.LOCAL_ID_LIMIT))
    conn = flushloop.FlushConn(1, ob, srv.fileno())
    res = flushloop.flush_short([1], {1: conn}, 3.0, 100, 100, 1 << 20, 0, 4)
    assert res[:2] == (0, 0) and res[7] == [1] and len(ob) == 1 and conn.dirty_since == 3.0
    assert _read_all(cli) == b""
    res = flushloop.flush_short([1], {1: conn}, 4.0, 100, 100, 1 << 20, 0, 4)
    assert res[:2] == (1, 1) and res[7] == [] and len(ob) == 0 and conn.dirty_since is None
    for k, control in ((4, True), (3, False)):
        for e in range(3):
            ob.put_state(e, P.encode_leave(e + P.LOCAL_ID_LIMIT))
        if control:
            ob.put_control(P.encode_message(P.Pong(1, 2)))
        res = flushloop.flush_short([1], {1: conn}, 5.0, 100, 100, 1 << 20, 0, k)
        assert res[7] == []  # a reply waits for nobody; 3 states are not fewer than 3
        if control:
            assert res[4] == [conn]  # the writer's long path
            ob.drain()
            conn.dirty_since = None
        else:
            assert res[:2] == (3, 1)
    _read_all(cli)
    srv.close()
    cli.close()
