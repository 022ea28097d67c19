"""The demo's transit: replay producer -> SIRI over loopback HTTP -> proxy -> the demo's server."""

from __future__ import annotations

import trio

from proxies.demo_transit import run_transit
from tests.entitynet.server_helpers import running


async def test_transit_vehicles_reach_the_server(line_topo, line_book, line_feed):
    lines: list[str] = []
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server:
        async with trio.open_nursery() as n:
            shell = await n.start(lambda task_status: run_transit(
                line_topo, ("127.0.0.1", server.port), line_feed, lines.append, poll=0.5, start=8 * 3600 + 600.0,
                book=line_book, task_status=task_status))
            with trio.fail_after(30.0):  # (a condition's deadline, generous for a loaded machine)
                while (server.metrics.registry.get_sample_value("entitynet_entities") or 0) < 3:  # as the server counts
                    await trio.sleep(0.05)
            assert len(shell.fleet.vehicles) >= 3
            counts = shell.counts()  # what the demo's summary adds to the simulation's entities
            assert counts["entities"] == {"tram": len(shell.fleet.vehicles)} and counts["stops_served"] >= 0
            n.cancel_scope.cancel()
    assert any(line.startswith("transit: replay of") for line in lines)


def test_demo_command_refuses_a_missing_feed(tmp_path, capsys):
    from entitynet import cli

    assert cli.main(["demo", "--transit", str(tmp_path / "nope.zip"), "--duration", "1"]) == 2
    assert "GTFS feed" in capsys.readouterr().err


def test_demo_command_refuses_a_folder_as_feed(tmp_path, capsys):
    from entitynet import cli

    assert cli.main(["demo", "--transit", str(tmp_path), "--duration", "1"]) == 2
    assert "no such file" in capsys.readouterr().err


async def test_an_unreadable_feed_is_the_commands_error(line_topo, tmp_path, monkeypatch):
    """A --transit feed that is no GTFS zip ends the demo with one line (a CommandError, which the CLI prints
    even from inside the demo's nursery), not a traceback."""
    import pytest

    from entitynet.cli import CommandError

    monkeypatch.setenv("ENTITYNET_CACHE", str(tmp_path))
    garbage = tmp_path / "garbage.zip"
    garbage.write_text("not a zip\n")
    with pytest.raises(CommandError, match="--transit .*garbage.zip.*not a readable GTFS zip"):
        await run_transit(line_topo, ("127.0.0.1", 1), garbage, lambda m: None)
