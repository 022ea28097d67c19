"""`entitynet sim` over real loopback sockets: the trio shell, an in-process or external server, the server
going away mid-run, and the command line's errors."""

from __future__ import annotations

import pytest
import trio

from entitynet.cli import main
from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig
from tests.entitynet.server_helpers import config as server_config
from tests.sims.engine.test_routes import grid


async def test_sim_on_helsinki_with_an_in_process_server(helsinki, helsinki_path):
    lines: list[str] = []
    sim = Sim(helsinki, SimConfig(entities=30, viewers=3, connections=2, tick_hz=4.0, transit=False, seed=2))
    shell = Shell(sim, ShellConfig(duration=4.0, speed=4.0, summary_every=0.2, artifact=helsinki_path,
                                   keys=False), lines.append)
    with trio.fail_after(60):
        rep = await shell.run()
    assert rep["sim_time_s"] == 4.0
    assert rep["clients"]["published"] >= 30 and rep["viewers"]["deliveries"] > 0
    assert rep["truth_vs_viewer"]["all"]["visible_entity_samples"] > 0
    assert rep["server"] == {"in_process": True, "gap_s": 0.0, "outages": 0}
    assert rep["viewer_errors"] == {"errors": 0, "viewers_with_errors": 0, "last_error": {}}
    assert "tick_lateness_p99_ms" in rep["realtime"]
    assert any("deliveries" in line and "collisions avoided" in line for line in lines)


async def test_server_going_away_mid_run_is_survived_and_reported():
    from entitynet.server import serve

    topo = grid()
    sim = Sim(topo, SimConfig(entities=10, viewers=2, connections=2, tick_hz=10.0, transit=False, start=0.0,
                              subscribe="radius"))
    port = 0
    shell_result: dict = {}
    first_scope = trio.CancelScope()

    async def first_server(task_status=trio.TASK_STATUS_IGNORED):
        with first_scope:
            await serve(server_config(digest=topo.digest, n_cells=int(topo.n_cells)), task_status=task_status)

    async with trio.open_nursery() as outer:
        first = await outer.start(first_server)
        port = first.port
        shell = Shell(sim, ShellConfig(duration=12.0, speed=4.0, summary_every=100.0, server=("127.0.0.1", port),
                                       keys=False), lambda m: None)

        async def outage():
            await trio.sleep(0.6)
            first_scope.cancel()  # the server goes away ...
            await trio.sleep(0.6)
            shell_result["second"] = await outer.start(  # ... and comes back on the same port
                serve, server_config(digest=topo.digest, n_cells=int(topo.n_cells), port=port))

        outer.start_soon(outage)
        with trio.fail_after(30):
            shell_result["rep"] = await shell.run()
        outer.cancel_scope.cancel()
    result = shell_result
    rep = result["rep"]
    assert rep["sim_time_s"] == 12.0  # the simulation kept stepping through the outage
    assert rep["server"]["outages"] >= 1 and rep["server"]["gap_s"] > 0.0
    ve = rep["viewer_errors"]  # each viewer's lost link counted, with its reason
    assert ve["errors"] >= ve["viewers_with_errors"] == len(sim.viewers) and all(ve["last_error"].values())
    assert result["second"].sb.stats["updates_in"] > 0  # the honest clients re-published to the new server
    assert "ids" in rep["truth_vs_viewer"]  # an external server's ids, mapped to the truth by payload


def test_cli_refuses_bad_options(capsys):
    for option, value, said in (("--speed", "0", "expected a number above 0"),  # refused while parsing
                                ("--tick-hz", "0", "expected a number from 0.1 to 100"),  # SimConfig's range
                                ("--tick-hz", "500", "expected a number from 0.1 to 100")):
        with pytest.raises(SystemExit) as info:
            main(["sim", option, value, "--duration", "1"])
        assert info.value.code == 2 and f"argument {option}: {said}" in capsys.readouterr().err


def test_cli_refuses_a_missing_feed(capsys, tmp_path):
    assert main(["sim", "--gtfs", str(tmp_path / "nope.zip"), "--duration", "1"]) == 2
    assert "cannot read the feed" in capsys.readouterr().err


async def test_entities_another_part_publishes_are_not_mapped_to_the_truth(helsinki, helsinki_path):
    """The demo's transit proxy publishes into the same server with local ids of its own (1, 2, ...): they
    must not be taken for the simulated entities of the same local id when truth is compared with viewers."""
    from entitynet import protocol as P
    from entitynet.connection import Connection

    owner: dict = {}

    async def other_publisher(address, task_status=trio.TASK_STATUS_IGNORED):
        async with trio.open_nursery() as n:
            conn = Connection(address, helsinki.digest, on_message=lambda m: None)
            await n.start(conn.run)
            await conn.publish(P.Publish(1, 1, (0,), 5000, b"\x00"))  # local id 1, as the sim's first entity
            owner["session"] = conn.welcome.session
            task_status.started()

    sim = Sim(helsinki, SimConfig(entities=3, viewers=0, connections=1, transit=False, seed=2))
    shell = Shell(sim, ShellConfig(duration=30.0, summary_every=100.0, artifact=helsinki_path, keys=False,
                                   parts=(other_publisher,)), lambda m: None)
    with trio.fail_after(30):
        async with trio.open_nursery() as nursery:
            server = await nursery.start(shell.run)
            while len(server.sb.entities) < 4:  # the other's entity and the sim's three
                await trio.sleep(0.05)
            ids = shell._eid_map(shell.publishers)
            theirs = [eid for eid, e in server.sb.entities.items() if e.owner.session == owner["session"]]
            assert len(theirs) == 1 and theirs[0] not in ids
            assert sorted(ids.values()) == sorted(sim.world.agents)
            nursery.cancel_scope.cancel()


def test_the_shell_clock_runs_between_ticks_stops_while_paused_and_never_goes_back():
    import time

    sim = Sim(grid(), SimConfig(entities=0, viewers=0, tick_hz=2.0, transit=False, start=100.0))
    shell = Shell(sim, ShellConfig(keys=False), lambda m: None)
    assert shell.clock() == 100.0  # before the first tick: the simulation's time
    shell._tick_wall = time.monotonic() - 0.3  # 0.3 s after a tick
    before = shell.clock()
    assert 100.29 <= before <= 100.5  # at most one tick on
    shell._toggle()  # pause
    at = shell.clock()
    assert at >= before
    time.sleep(0.05)
    assert shell.clock() == at  # stands still while paused
    shell._toggle()  # resume: on from where it stood
    assert at <= shell.clock() <= 100.5


async def test_the_parts_trams_and_buses_are_in_the_summary_and_the_report(tmp_path):
    """`demo --transit FEED`: the transit proxy is a part that publishes its trams and buses into the same server;
    the summary, the final line and the report count them (and the stops they served) with the simulation's."""
    from topology.artifact import save

    class ProxyLike:
        def counts(self) -> dict:
            return {"entities": {"tram": 2, "bus": 1}, "stops_served": 4}

    async def transit(address, task_status=trio.TASK_STATUS_IGNORED):
        task_status.started(ProxyLike())
        await trio.sleep_forever()

    topo = grid()
    path = tmp_path / "grid.enttopo"
    save(topo, path)
    lines: list[str] = []
    sim = Sim(topo, SimConfig(entities=3, viewers=1, connections=1, transit=False, start=0.0, subscribe="radius"))
    shell = Shell(sim, ShellConfig(duration=2.0, speed=4.0, summary_every=0.1, artifact=path, keys=False,
                                   parts=(transit,)), lines.append)
    with trio.fail_after(30):
        rep = await shell.run()
    summaries = [line for line in lines if "collisions avoided" in line]
    assert summaries and all("1 bus" in line and "2 tram" in line for line in summaries), summaries
    assert "4 bus and tram stops served" in lines[-1]
    assert rep["entities"]["tram"] == 2 and rep["entities"]["bus"] == 1 and rep["stops_served"] == 4
    assert rep["parts"] == [ProxyLike().counts()]


def _small_run(tmp_path, tick_hz: float):
    """Three entities and a viewer on the small grid, its artifact saved for the in-process server."""
    from topology.artifact import save

    topo = grid()
    path = tmp_path / "grid.enttopo"
    save(topo, path)
    return Sim(topo, SimConfig(entities=3, viewers=1, connections=1, tick_hz=tick_hz, transit=False, start=0.0,
                               subscribe="radius")), path


async def test_a_run_behind_real_time_says_so_once_per_interval_and_in_the_summary(tmp_path):
    """A tick that takes longer than the tick period: the live summary shows the lateness, and a warning says
    the run is behind and what to do, once and then again only after `behind_warn_every` wall seconds."""
    import time as wall

    sim, path = _small_run(tmp_path, tick_hz=10.0)
    lines: list[str] = []
    warned_at: list[float] = []

    def say(line: str) -> None:
        lines.append(line)
        if "warning: behind real time" in line:
            warned_at.append(wall.monotonic())

    step = sim.step

    def slow_step():
        wall.sleep(0.15)  # each tick 0.15 s of work at a 0.1 s period: behind from the start
        return step()

    sim.step = slow_step
    shell = Shell(sim, ShellConfig(duration=2.5, speed=1.0, summary_every=0.5, artifact=path, keys=False,
                                   behind_warn_every=1.5), say)
    with trio.fail_after(60):
        rep = await shell.run()
    warnings = [line for line in lines if "warning: behind real time" in line]
    assert warnings, lines
    assert all(b - a >= 1.5 - 0.05 for a, b in zip(warned_at, warned_at[1:], strict=False)), warned_at
    assert "--viewers" in warnings[0] and "--measured-viewers" in warnings[0] and "--speed" in warnings[0]
    summaries = [line for line in lines if "collisions avoided" in line]
    assert summaries and all("late p99" in line for line in summaries)
    assert any("ticks behind" in line for line in summaries)
    assert rep["realtime"]["ticks_behind"] > 0


async def test_a_run_that_keeps_real_time_gives_no_warning(tmp_path):
    sim, path = _small_run(tmp_path, tick_hz=2.0)
    lines: list[str] = []
    shell = Shell(sim, ShellConfig(duration=2.0, speed=1.0, summary_every=0.5, artifact=path, keys=False,
                                   warmup_ticks=1), lines.append)
    with trio.fail_after(60):
        await shell.run()
    assert not [line for line in lines if "warning: behind" in line]


def test_pausing_against_a_server_in_another_process_says_its_clock_runs_on():
    # a child server (the default for large runs), --server or a cluster keeps the wall clock: validity periods
    # run out there while the simulation stands still, and the user is told so when pausing
    sim = Sim(grid(), SimConfig(entities=0, viewers=0, tick_hz=2.0, transit=False, start=100.0))
    lines: list[str] = []
    shell = Shell(sim, ShellConfig(keys=False, server=("127.0.0.1", 1)), lines.append)
    shell._toggle()
    assert "paused" in lines[-1] and "wall clock" in lines[-1] and "--server-process no" in lines[-1]
    shell._toggle()
    assert "resumed" in lines[-1]
    own: list[str] = []
    in_process = Shell(sim, ShellConfig(keys=False), own.append)
    in_process._toggle()
    assert own[-1].endswith("paused")  # the in-process server's clock stops with the simulation's
