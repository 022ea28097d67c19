"""Small frames held once (`ServerConfig.flush_min_frame`, `entitynet serve --flush-min-frame`): a connection
whose frame would carry fewer states than the setting waits for the next flush, once.

Why: a frame costs a `writev` (and its reader a wake-up) whatever it carries, and at the standard switch load
about half the frames carry one or two states. These tests check the behaviour, not the CPU (that is `python -m
sims.bench.switch_repeat`): held news still goes out on its own (the flusher wakes for it without new news),
never before the budget, a reply is never held, and bad settings are refused.
"""

from __future__ import annotations

import pytest
import trio

from entitynet import protocol as P
from entitynet.server import ConfigError, ServerConfig
from entitynet.server.app import Server
from tests.entitynet.server_helpers import DIGEST, Raw, running


async def test_a_held_state_goes_out_at_the_next_flush_without_new_news(flush_path):
    """One state, fewer than `flush_min_frame`: held by the first flush, written by the next one, which the
    flusher starts on its own (no new news arrives) within the budget, not after its idle backstop (1 s)."""
    async with running(latency_budget=0.05, flush_fill=1000, flush_min_frame=4) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()), P.Ping(1))
        await view.expect(P.Pong)
        pub = await Raw.connect(server)
        t0 = trio.current_time()
        await pub.send(P.Publish(1, 1, (3,), 10_000, b"x"))
        assert (await view.expect(P.Update, timeout=10)).payload == b"x"
        assert trio.current_time() - t0 < 0.9
        assert not server.sb.has_news()
        await pub.aclose()
        await view.aclose()


async def test_a_held_state_never_goes_before_the_budget(flush_path):
    """Held once, the state leaves at the second flush: with a 0.3 s budget, not before 0.3 s (a loaded
    machine can only make it later)."""
    async with running(latency_budget=0.3, flush_fill=1000, flush_min_frame=4) as server:
        view = await Raw.connect(server)
        await view.send(P.Subscribe((3,), ()), P.Ping(1))
        await view.expect(P.Pong)
        pub = await Raw.connect(server)
        t0 = trio.current_time()
        await pub.send(P.Publish(1, 1, (3,), 10_000, b"y"))
        assert (await view.expect(P.Update, timeout=10)).payload == b"y"
        assert trio.current_time() - t0 >= 0.3
        await pub.aclose()
        await view.aclose()


async def test_replies_are_never_held(flush_path):
    """PONG and errors are not states: a huge `flush_min_frame` holds none of them."""
    async with running(latency_budget=60.0, flush_min_frame=1_000_000) as server:
        with trio.fail_after(10):
            c = await Raw.connect(server)
            await c.send(P.Ping(5))
            assert (await c.expect(P.Pong)).client_ms == 5
            await c.send(P.Subscribe((10_000,), ()))
            await c.expect(P.Error)
        await c.aclose()


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "4", float("nan"), 10**7])
def test_a_min_frame_out_of_range_is_refused(bad):
    with pytest.raises(ConfigError, match="flush-min-frame"):
        Server(ServerConfig(port=0, digest=DIGEST, n_cells=10, open_mode=True, flush_min_frame=bad))
