"""The one reader over every viewer socket (`sims.engine.viewer_reader`): the same ghosts and truth figures as
the per-viewer path on a seeded run, with the bytes split anywhere; and bad input (a malformed or oversized
frame, a socket closed mid-frame, a server that vanishes) costs only its viewer."""

from __future__ import annotations

import functools
import random

import trio

from entitynet import protocol as P
from entitynet.session import Connect, Send
from sims.engine.sim import Sim
from sims.engine.viewer_fleet import ViewerFleet
from sims.engine.viewer_reader import ViewerReader
from tests.sims.engine.test_routes import grid
from tests.sims.engine.test_viewer_fleet import _config, _run

WELCOME = P.Welcome(P.PROTOCOL_VERSION, 1, 0, {})


def _open(reader: ViewerReader, i: int, now: float = 0.0) -> tuple[int, P.FrameDecoder]:
    """Viewer i's session dialled, connected and welcomed, sans-IO: its open link and a deframer for it."""
    session = reader.sessions[i]
    (connect,) = [a for a in session.start(now) if isinstance(a, Connect)]
    session.connection_made(connect.link, now)
    dec = P.FrameDecoder()
    rest, bad = reader.take(i, connect.link, dec, P.frame(P.encode_payload([WELCOME])), now)
    assert bad is None and all(isinstance(a, Send) for a in rest)  # the first PING: the test's shell drops it
    assert session.connected
    return connect.link, dec


def _ghosts(sim: Sim) -> list[list[tuple[int, int]]]:
    """Every viewer's ghosts as (entity, seq), sorted."""
    return [sorted((e, g.seq) for e, g in v.ghosts.ghosts.items()) for v in sim.viewers]


def test_the_reader_gives_the_per_viewer_paths_ghosts_and_report_with_bytes_split_anywhere():
    ref = Sim(grid(), _config())
    ref_fleet = ViewerFleet(ref.viewers, lambda: ref.now, one_reader=False)
    frames = [ref_fleet.on_frame(i) for i in range(len(ref.viewers))]
    for i in range(len(ref.viewers)):
        ref_fleet.on_message(i)(WELCOME)

    def whole(i: int, payload: bytes) -> None:
        frames[i](ref_fleet.messages.decode(payload))

    want = _run(ref, whole)

    sim = Sim(grid(), _config())
    fleet = ViewerFleet(sim.viewers, lambda: sim.now)
    links = []
    for i in range(len(sim.viewers)):
        fleet.connection(i, ("127.0.0.1", 9), sim.topo.digest, "")
        links.append(_open(fleet.reader, i))
    rng = random.Random(5)
    framed = [0]

    def split(i: int, payload: bytes) -> None:
        """The frame's messages re-framed as one to three frames, and their bytes handed on in random pieces (a
        frame split over reads, down to single bytes, and several frames in one read: joined whole)."""
        msgs = P.decode_payload(payload)
        cuts = sorted(rng.sample(range(1, len(msgs)), min(2, len(msgs) - 1))) if len(msgs) > 1 else []
        parts = [msgs[a:b] for a, b in zip([0, *cuts], [*cuts, len(msgs)], strict=True)]
        data = b"".join(P.frame(P.encode_payload(p)) for p in parts)
        framed[0] += len(parts)
        (link, dec), at = links[i], 0
        while at < len(data):
            step = rng.choice((1, 3, rng.randint(1, len(data)), len(data)))
            assert fleet.reader.take(i, link, dec, data[at:at + step], sim.now) == ([], None)
            at += step

    got = _run(sim, split)
    assert got["truth_vs_viewer"]["all"]["shown_ghost_samples"] > 100
    assert got == want  # field for field: deliveries, bytes, errors, missed visibility, stale ghosts
    assert _ghosts(sim) == _ghosts(ref)
    assert 0 < fleet.frames_whole < framed[0]  # some reads' frames went on joined


def test_a_bad_frame_raises_for_its_viewer_and_the_others_read_on():
    got: dict[int, list] = {0: [], 1: []}
    reader = ViewerReader(P.decode_payload, lambda i: got[i].append, lambda i: got[i].append)
    for _ in range(2):
        reader.viewer(("127.0.0.1", 9), "d")
    (l0, d0), (l1, d1) = _open(reader, 0), _open(reader, 1)
    good = P.frame(P.encode_payload([P.Update(7, 1, (3,), 1000, b"x"), P.Leave(8)]))
    for bad in (P.frame(b"\xc1\xc1"),  # not msgpack
                (P.DEFAULT_LIMITS.max_frame + 1).to_bytes(4, "big"),  # oversized, refused at its length
                P.frame(P.encode_payload([P.Leave(1)]) + b"\x90"),  # trailing bytes
                P.frame(P.encode_payload([P.Update(7, 2, (3,), 1000, b"x")])[:-2])):  # cut short
        d1 = P.FrameDecoder()
        assert isinstance(reader.take(1, l1, d1, bad, 0.0)[1], P.ProtocolError)
        assert reader.take(0, l0, d0, good, 0.0) == ([], None)
    assert got[0][0] == WELCOME and got[0][1:] == [[P.Update(7, 1, (3,), 1000, b"x"), P.Leave(8)]] * 4
    assert got[1] == [WELCOME]


def test_a_welcome_read_with_a_bad_frame_still_opens_the_link():
    """The frames before a bad one are taken (with one `Connection` per viewer they were, frame by frame)."""
    reader = ViewerReader(P.decode_payload, lambda i: lambda f: None, lambda i: lambda m: None)
    session = reader.viewer(("127.0.0.1", 9), "d").session
    (connect,) = [a for a in session.start(0.0) if isinstance(a, Connect)]
    session.connection_made(connect.link, 0.0)
    data = P.frame(P.encode_payload([WELCOME])) + P.frame(b"\xc1")
    rest, bad = reader.take(0, connect.link, P.FrameDecoder(), data, 0.0)
    assert session.connected and isinstance(bad, P.ProtocolError) and "MALFORMED" in str(bad)
    assert rest and all(isinstance(a, Send) for a in rest)


async def _serve(script: dict[str, bytes], conns: list, nursery: trio.Nursery) -> int:
    """A fake server: HELLO read, WELCOME sent, then the bytes the HELLO's token names, then the socket kept
    open (`conns`) until the test closes it. Its port."""

    async def handle(stream: trio.SocketStream) -> None:
        conns.append(stream)
        dec = P.FrameDecoder()
        while (payload := dec.next_payload()) is None:
            data = await stream.receive_some(65536)
            if not data:
                return
            dec.receive_data(data)
        (hello,) = P.decode_payload(payload)
        await stream.send_all(P.frame(P.encode_payload([WELCOME])))
        what = script.get(hello.token, b"")
        if what == b"close":
            await stream.send_all(P.frame(P.encode_payload([P.Leave(1)]))[:5])  # half a frame, then gone
            await stream.send_eof()  # an end of file, not a reset (its PING is never read)
            await trio.sleep_forever()
        await stream.send_all(what)
        await trio.sleep_forever()

    listeners = await nursery.start(functools.partial(trio.serve_tcp, handle, 0, host="127.0.0.1"))
    return listeners[0].socket.getsockname()[1]


async def test_over_sockets_bad_input_costs_only_its_viewer_and_a_vanished_server_hangs_nothing():
    ups = [P.Update(5, k, (2,), 1000, b"p") for k in range(1, 41)]
    good = b"".join(P.frame(P.encode_payload(ups[k:k + 4])) for k in range(0, 40, 4))
    script = {"good": good, "malformed": P.frame(b"\xc1"), "close": b"close",
              "oversized": (1 << 30).to_bytes(4, "big")}
    got: dict[int, list] = {}
    reader = ViewerReader(P.decode_payload, lambda i: got.setdefault(i, []).extend,
                          lambda i: got.setdefault(i, []).append)
    conns: list[trio.SocketStream] = []
    with trio.fail_after(20):
        async with trio.open_nursery() as nursery:
            port = await _serve(script, conns, nursery)
            tokens = list(script)
            vs = [reader.viewer(("127.0.0.1", port), "d", t, backoff=(5.0, 5.0)) for t in tokens]
            for v in vs:
                await nursery.start(v.run)
            while not (min(reader.errors[1:]) >= 1 and len([m for m in got.get(0, []) if type(m) is P.Update]) == 40):
                await trio.sleep(0.01)
            assert [m for m in got[0] if type(m) is P.Update] == ups  # every frame, whole and in order
            assert reader.errors[0] == 0  # each bad one ends its own link (and again on each reconnect)
            assert "malformed" in reader.last_error[1].lower() or "msgpack" in reader.last_error[1].lower()
            assert "mid-frame" in reader.last_error[2]
            assert "too large" in reader.last_error[3].lower() or "1073741824" in reader.last_error[3]
            assert vs[0].connected
            rep = reader.error_report(most=2)  # what the shell's report shows (bounded)
            assert rep["errors"] == sum(reader.errors) >= 3 and rep["viewers_with_errors"] == 3
            assert rep["last_error"] == {"1": reader.last_error[1], "2": reader.last_error[2]}
            nursery.cancel_scope.cancel()  # the listener goes
        late = ViewerReader(P.decode_payload, lambda i: lambda m: None, lambda i: lambda m: None)
        async with trio.open_nursery() as viewers:  # a server that vanishes: every viewer loses its link
            async with trio.open_nursery() as server:
                port = await _serve({}, conns, server)
                vs = [late.viewer(("127.0.0.1", port), "d", backoff=(0.05, 0.05)) for _ in range(3)]
                for v in vs:
                    await viewers.start(v.run)
                server.cancel_scope.cancel()  # the listener and every connection closed
            while min(late.errors) < 3:  # the link lost, then reconnects refused, each counted for its viewer
                await trio.sleep(0.01)
            assert not any(v.connected for v in vs) and all(late.last_error)
            viewers.cancel_scope.cancel()
    assert not late._streams and not late._by_fd  # every socket closed with the reader
