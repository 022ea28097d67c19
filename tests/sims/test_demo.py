"""`entitynet demo` as a preset of `entitynet sim`, end to end on real loopback sockets: the same engine, fleet and
viewers, scheduled trams and buses, readiness through `task_status`, the browser viewer's HTTP and WebSocket
feed served by the in-process server on the simulation's clock, the live summary and the final report."""

from __future__ import annotations

import json
import urllib.request

import trio

from sims.demo import DemoConfig, run_demo, sim_config
from sims.engine.agents import Stop
from sims.engine.schedule import Departure, Schedule
from sims.engine.sim import SimConfig


def _one_tram(topo) -> Schedule:
    """A tram of the schedule on Helsinki's first tram edge long enough to run on (departing at 08:00:00)."""
    from entitynet.client import netview
    from topology.raw import TRAM

    net = netview(topo)
    e = max((e for e in range(len(net.edge_len)) if net.edge_net[e] & TRAM), key=lambda e: net.edge_len[e])
    length = float(net.edge_len[e])
    return Schedule([Departure(8 * 3600.0, "t1", "tram", "7", ((e, 1),), (Stop(length / 2, 10.0, "mid", 30.0),))])


async def test_demo_is_a_sim_preset_with_viewer_and_readiness(helsinki, helsinki_path):
    lines: list[str] = []
    config = DemoConfig(entities=40, viewers=4, connections=2, duration=3.0, summary_every=1.0, seed=3, http_port=0)
    with trio.fail_after(60):
        async with trio.open_nursery() as nursery:
            result: dict = {}

            async def demo(task_status=trio.TASK_STATUS_IGNORED):
                result["report"] = await run_demo(helsinki, helsinki_path, config, lines.append, _one_tram(helsinki),
                                                  task_status=task_status)

            server = await nursery.start(demo)  # ready: every connection up, the viewer served
            assert server.http_port and server.ws_port
            url = f"http://127.0.0.1:{server.http_port}/viewer/config.json"
            page = await trio.to_thread.run_sync(lambda: json.loads(urllib.request.urlopen(url, timeout=10).read()))
            assert page["ws_port"] == server.ws_port and page["digest"] == helsinki.digest
            # the server runs on the simulation's clock (service-day seconds from 08:00), which the page's
            # WELCOME / PONG clock offset maps onto the publishers' time
            assert 8 * 3600.0 <= server.clock() < 8 * 3600.0 + 60.0
            assert 8 * 3600.0 <= await trio.to_thread.run_sync(server.clock) < 8 * 3600.0 + 60.0  # from threads too
    rep = result["report"]
    assert rep["entities"]["tram"] == 1 and rep["config"]["entities"] == 40 and rep["config"]["transit"] is True
    assert rep["clients"]["published"] >= 40 and rep["viewers"]["deliveries"] > 0
    assert rep["server"]["in_process"] and rep["sim_time_s"] == 3.0
    assert any("open the 3D viewer: http://127.0.0.1:" in line for line in lines)
    assert any("deliveries" in line and "collisions avoided" in line for line in lines)  # the live summary
    assert "stopped after 3 simulated s" in lines[-1]


def test_the_demo_options_map_onto_the_sim():
    config = DemoConfig(entities=50, viewers=3, connections=2, car_share=0.4, seed=9, start=9 * 3600.0)
    sim = sim_config(config, scheduled=True)
    assert sim == SimConfig(entities=50, viewers=3, connections=2, car_share=0.4, seed=9, start=9 * 3600.0,
                            tick_hz=2.0, transit=True)
    assert sim_config(config, scheduled=False).transit is False
    # --transit FEED: the proxy brings the trams and buses, not the engine's schedule as well
    assert sim_config(DemoConfig(transit="feed.zip"), scheduled=True).transit is False


async def test_the_transit_part_runs_with_the_servers_address_and_clock(helsinki, helsinki_path, monkeypatch):
    import sims.demo

    calls: list[dict] = []

    async def fake_transit(topo, address, feed, say, *, start, clock, task_status=trio.TASK_STATUS_IGNORED):
        calls.append({"address": address, "feed": feed, "start": start,
                      "clock": await trio.to_thread.run_sync(clock)})  # the proxy polls in a worker thread
        task_status.started(None)
        await trio.sleep_forever()

    monkeypatch.setattr(sims.demo, "demo_part", lambda name: fake_transit)
    config = DemoConfig(entities=5, viewers=1, connections=1, duration=1.0, summary_every=10.0, transit="feed.zip",
                        start=9 * 3600.0)
    with trio.fail_after(60):
        async with trio.open_nursery() as nursery:
            server = await nursery.start(run_demo, helsinki, helsinki_path, config, lambda m: None, _one_tram(helsinki))
            assert calls == [{"address": ("127.0.0.1", server.port), "feed": "feed.zip", "start": 9 * 3600.0,
                              "clock": 9 * 3600.0}]  # the simulation's clock, from before its first tick
            assert server.http_port is None  # no viewer asked for
