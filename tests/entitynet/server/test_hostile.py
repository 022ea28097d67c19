"""What one client can make the server do (issue 9, items 3 and 7), over real loopback sockets."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from tests.entitynet.server_helpers import Raw, flows, pair, running


async def test_a_churn_flood_frame_is_refused_over_budget_and_others_keep_receiving():
    """One frame of 200 SUBSCRIBEs alternating all cells and none, with thousands of entities on the map: the
    flood client gets LIMIT_CHURN for what is over its budget, and while the server works through the frame a
    second viewer keeps receiving fresh UPDATEs (the shell serves others between slices of the frame)."""
    n_cells, n_ent = 1000, 4000
    # budget for 40 of the 200 (999 cells each): enough work to watch others being served meanwhile
    async with running(n_cells=n_cells, switch={"churn_rate": 0.0, "churn_burst": 40_000.0}) as server:
        bulk = await Raw.connect(server)
        for i in range(0, n_ent, 2000):
            await bulk.send(*[P.Publish(e, 1, (e % (n_cells - 1),), 600_000, b"b") for e in range(i, i + 2000)])
        ticker, view = await pair(server, cell=n_cells - 1)
        await flows(ticker, view, 1, cell=n_cells - 1)
        flood = await Raw.connect(server)
        all_cells = tuple(range(n_cells - 1))
        frame = [P.Subscribe(all_cells, ()) if i % 2 == 0 else P.Subscribe((), all_cells) for i in range(200)]
        state = {"seq": 1, "before_pong": None, "pong": False}

        async def tick():
            # a fresh state every 5 ms (bounded: at most 2,000)
            for seq in range(2, 2002):
                state["seq"] = seq
                await ticker.send(P.Publish(1, seq, (n_cells - 1,), 10_000, b"t"))
                await trio.sleep(0.005)

        async def watch():
            while True:
                u = await view.expect(P.Update, timeout=20)
                if not state["pong"] and u.seq > 1:
                    state["before_pong"] = (state["before_pong"] or 0) + 1

        async def drain_flood():
            with trio.fail_after(60):
                while True:
                    msgs = await flood.read(timeout=60)
                    assert msgs is not None, "the flood client was disconnected"
                    flood.pending.extend(m for m in msgs if not isinstance(m, (P.Update, P.Leave)))
                    if any(isinstance(m, P.Pong) for m in msgs):
                        state["pong"] = True
                        return

        async with trio.open_nursery() as n:
            n.start_soon(tick)
            n.start_soon(watch)
            await trio.sleep(0.05)
            n.start_soon(drain_flood)
            await flood.send(*frame, P.Ping(9))
            with trio.fail_after(60):
                while not state["pong"]:
                    await trio.sleep(0.01)
            n.cancel_scope.cancel()
        errs = [m for m in flood.pending if isinstance(m, P.Error)]
        # 40 pass; of the other 160, the 80 that subscribe are refused (unsubscribing from nothing changes nothing)
        assert {e.code for e in errs} == {ErrorCode.LIMIT_CHURN} and len(errs) == 80
        # while the flood frame was being worked through, the viewer got ticker UPDATEs
        assert (state["before_pong"] or 0) >= 3, state
        print("ticker updates seen while the flood frame was worked on:", state["before_pong"])
        await flows(ticker, view, 10_000, cell=n_cells - 1)


async def test_more_pings_in_one_frame_than_replies_allowed_get_a_clear_error_and_the_client_stays():
    async with running(metrics_port=None) as server:
        c = await Raw.connect(server)
        await c.send(*[P.Ping(i) for i in range(1001)])
        got: list[P.Message] = []
        with trio.fail_after(10):
            while not any(isinstance(m, P.Error) for m in got):
                msgs = await c.read()
                assert msgs is not None, "disconnected"
                got += msgs
        cap = server.sb.config.max_replies_per_frame
        assert [m.client_ms for m in got if isinstance(m, P.Pong)] == list(range(cap))
        (err,) = [m for m in got if isinstance(m, P.Error)]
        assert err.code == ErrorCode.TOO_MANY_REQUESTS and f"{1001 - cap} requests" in err.text
        await c.send(P.Ping(5000))
        assert (await c.expect(P.Pong)).client_ms == 5000
        assert server.sb.stats["slow_consumers"] == 0


async def test_every_slow_consumer_drop_is_counted_in_the_metrics(flush_path):
    async with running(switch={"max_pending": 5}) as server:
        pub, view = await pair(server, cell=2)
        lazies = []
        for _ in range(4):
            lazy = await Raw.connect(server)
            await lazy.send(P.Subscribe((1,), ()), P.Ping(1))
            await lazy.expect(P.Pong)
            lazies.append(lazy)
        await pub.send(*[P.Publish(i, 1, (1,), 60_000, b"") for i in range(10)])  # > 5 pending for each
        for lazy in lazies:
            got = await lazy.expect_closed()
            assert [m.code for m in got if isinstance(m, P.Error)] == [ErrorCode.SLOW_CONSUMER]
        reg = server.metrics.registry
        with trio.fail_after(5):
            while reg.get_sample_value("entitynet_errors_total", {"code": "404"}) != 4:
                await trio.sleep(0.02)
        assert reg.get_sample_value("entitynet_slow_consumer_drops_total") == 4
        await flows(pub, view, 2, cell=2)
