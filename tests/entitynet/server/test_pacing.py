"""Wake-up pacing (entitynet/server/pacing.py, `ServerConfig.pace`): at light load the loop is held after a
wake-up's work so that the next wake-up reads everything that arrived meanwhile; never held longer than the
pace, never when input is rare, never at all without input; nothing is lost or reordered by holding.

The unit tests give the pacer a recording sleep (no real hold); the server tests hold for real, with paces long
enough (0.3 s) that a loaded machine cannot make them pass by chance.
"""

from __future__ import annotations

import pytest
import trio

from entitynet import protocol as P
from entitynet.server import ConfigError, ServerConfig
from entitynet.server.app import Server
from entitynet.server.pacing import Pacer
from tests.entitynet.server_helpers import DIGEST, Raw, running


async def _pacer(pace: float):
    holds: list[float] = []
    pacer = Pacer(pace, sleep=holds.append)
    return pacer, holds


async def test_a_wake_up_soon_after_the_last_is_held_for_the_rest_of_the_pace():
    pacer, holds = await _pacer(0.5)
    async with trio.open_nursery() as n:
        n.start_soon(pacer.run)
        pacer.woke()
        await trio.sleep(0.05)
        assert holds == []  # the first wake-up after a quiet spell is not held
        pacer.woke()
        await trio.sleep(0.05)
        assert len(holds) == 1 and 0.0 < holds[0] <= 0.5  # held for what is left of the pace, never more
        n.cancel_scope.cancel()


async def test_without_input_the_pacer_neither_wakes_nor_holds():
    pacer, holds = await _pacer(0.01)
    async with trio.open_nursery() as n:
        n.start_soon(pacer.run)
        await trio.sleep(0.2)
        assert holds == [] and pacer.holds == 0
        n.cancel_scope.cancel()


async def test_rare_input_is_never_held():
    pacer, holds = await _pacer(0.05)
    async with trio.open_nursery() as n:
        n.start_soon(pacer.run)
        for _ in range(3):
            pacer.woke()
            await trio.sleep(0.12)  # each wake-up comes more than a pace after the last
        assert holds == []
        n.cancel_scope.cancel()


async def test_a_paced_server_reads_everything_sent_during_a_hold_in_order(flush_path):
    """Frames sent while the loop is held are all read when it polls again: the viewer gets every state, the
    latest of each entity, and the publisher its replies; a malformed frame from a third client during a hold
    closes that client only."""
    async with running(pace=0.3, latency_budget=0.0) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()), P.Ping(1))
        await view.expect(P.Pong)
        pub = await Raw.connect(server)
        bad = await Raw.connect(server)
        for seq in range(1, 6):
            await pub.send(P.Publish(seq, 1, (3,), 10_000, b"%d" % seq))
        await bad.send_bytes(b"\x00\x00\x00\x03\xc1\xc1\xc1")  # 0xc1 is never valid msgpack
        await pub.send(P.Ping(9))
        assert (await pub.expect(P.Pong, timeout=10)).client_ms == 9
        got = set()
        with trio.fail_after(10):
            while len(got) < 5:
                got |= {m.payload for m in await view.read() if isinstance(m, P.Update)}
        assert got == {b"1", b"2", b"3", b"4", b"5"}
        closing = await bad.expect_closed()
        assert [m.code for m in closing if isinstance(m, P.Error)] == [P.ErrorCode.MALFORMED]
        with trio.fail_after(10):  # the wake-ups above came within one pace: the loop is held at least once
            while server.pacer.holds == 0:
                await trio.sleep(0.05)
        await pub.send(P.Publish(1, 2, (3,), 10_000, b"again"))
        assert (await view.expect(P.Update, pred=lambda m: m.payload == b"again", timeout=10)).seq == 2


async def test_a_client_that_vanishes_during_a_hold_costs_nobody_else(flush_path):
    async with running(pace=0.3, latency_budget=0.0) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()), P.Ping(1))
        await view.expect(P.Pong)
        gone = await Raw.connect(server)
        await gone.send(P.Subscribe((3,), ()))
        pub = await Raw.connect(server)
        await pub.send(P.Publish(1, 1, (3,), 10_000, b"a"))
        await gone.send_bytes(b"\x00\x00\x00\x10\x91")  # half a frame, then gone
        await gone.aclose()
        assert (await view.expect(P.Update, timeout=10)).payload == b"a"
        with trio.fail_after(10):
            while len(server.conns) != 2:
                await trio.sleep(0.01)
        await pub.send(P.Publish(1, 2, (3,), 10_000, b"b"))
        assert (await view.expect(P.Update, pred=lambda m: m.seq == 2, timeout=10)).payload == b"b"


async def test_a_lock_steps_pings_answered_by_the_reader_are_paced_too():
    """A frame that is one PING is answered by the reader past the outbox (`Server._pong_now`); it is input all
    the same, so back-to-back PINGs wake the pacer and the loop is held between them, as for any other frame.
    The wait past the pace first makes sure the connect's wake-ups cannot be what gets held."""
    async with running(pace=0.3, latency_budget=0.0) as server:
        c = await Raw.connect(server)
        await trio.sleep(0.45)  # past the pace: the next wake-up is not held on the connect's account
        holds = server.pacer.holds
        for k in range(1, 4):
            await c.send(P.Ping(k))
            assert (await c.expect(P.Pong, timeout=10)).client_ms == k
            await trio.sleep(0.05)  # the loop goes idle: the next PING is a wake-up of its own, within the pace
        assert server.pacer.holds > holds, "the quick PONG's wake-ups bypassed the pacer"


@pytest.mark.parametrize("pace", [float("nan"), -0.01, float("inf"), 1.5, "0.01", True])
def test_a_pace_out_of_range_is_refused(pace):
    with pytest.raises(ConfigError, match="pace"):
        Server(ServerConfig(port=0, digest=DIGEST, n_cells=10, open_mode=True, pace=pace))
