"""What `entitynet sim` and `entitynet demo` tell the user about the run they start: how the viewers subscribe
(a map without a PVS falls back to the radius and says so) and a GTFS feed that puts nothing on the map (a feed of
another city) is a clear warning, not a quiet "0 departures"."""

from __future__ import annotations

import pytest

from entitynet.cli import main
from sims.engine.sim import Sim, SimConfig
from tests.topology.mapfixtures import collection, grid, street
from topology.artifact import load, save
from topology.build import build
from topology.geojson_reader import geojson_to_raw


@pytest.fixture(scope="module")
def town_without_pvs(tmp_path_factory):
    path = tmp_path_factory.mktemp("nopvs") / "town.enttopo"
    save(build(geojson_to_raw(collection(*grid(3, 3)))), path)  # the default build: no PVS
    return path


@pytest.fixture(scope="module")
def town_far_away(tmp_path_factory):
    """A 200 m street grid 200 km north of Helsinki: the bundled HSL feed runs nowhere on it."""
    path = tmp_path_factory.mktemp("far") / "far.enttopo"
    north = 200_000.0
    rows = [street([(x, north + y) for x in (0.0, 100.0, 200.0)]) for y in (0.0, 100.0, 200.0)]
    cols = [street([(x, north + y) for y in (0.0, 100.0, 200.0)]) for x in (0.0, 100.0, 200.0)]
    save(build(geojson_to_raw(collection(*rows, *cols))), path)
    return path


def test_a_map_without_pvs_subscribes_by_radius_and_says_so(town_without_pvs, tmp_path, monkeypatch, capsys):
    topo = load(town_without_pvs)
    assert "pvs" not in topo.meta
    sim = Sim(topo, SimConfig(entities=4, viewers=2, subscribe="pvs", transit=False))
    assert sim.subscribe_by == "radius"
    assert sim.report()["subscribe_by"] == "radius"
    monkeypatch.setenv("ENTITYNET_CACHE", str(tmp_path))
    assert main(["sim", "--topology", str(town_without_pvs), "--gtfs", "none", "--entities", "4", "--viewers", "2",
                 "--duration", "1", "--speed", "4", "--report", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err
    assert "subscribing by radius" in err and "subscribing by pvs" not in err, err
    assert "no PVS" in err


def test_a_feed_of_another_city_is_a_clear_warning(town_far_away, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("ENTITYNET_CACHE", str(tmp_path))
    assert main(["sim", "--topology", str(town_far_away), "--entities", "4", "--viewers", "2", "--duration", "1",
                 "--speed", "4", "--report", str(tmp_path / "r.json")]) == 0  # the bundled HSL feed
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if "warning" in line]
    assert warning and "does not overlap the map" in warning[0], err


def test_a_day_without_service_is_a_warning_of_its_own(town_far_away, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("ENTITYNET_CACHE", str(tmp_path))
    assert main(["sim", "--topology", str(town_far_away), "--date", "20200101", "--entities", "4", "--viewers", "2",
                 "--duration", "1", "--speed", "4", "--report", str(tmp_path / "r.json")]) == 0
    warning = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warning and "in service on 20200101" in warning[0], warning
