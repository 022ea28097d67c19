"""The bundled map's SUMO scenario: SUMO's network lies on our streets (same projection and origin), its demand
has cars, walks and transit lines, it is cached, and bad parameters get clear errors."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import shapely

from entitynet.cli import main
from sims.sumo import SumoError
from sims.sumo.scenario import ScenarioConfig, bundled_scenario, scenario_dir
from sims.sumo.truth import place_points
from tests.sims.sumo.conftest import NEEDS_SUMO
from topology.networks import TRAM, VEHICLE


def _lane_midpoints(net, vclass: str) -> np.ndarray:
    """The middle of the first lane open to `vclass` of every (non-internal) edge of a SUMO network."""
    pts = []
    for edge in ET.parse(net).getroot().iter("edge"):
        if edge.get("function") == "internal":
            continue
        for lane in edge.iter("lane"):
            allow, disallow = lane.get("allow"), lane.get("disallow", "").split()
            if not (vclass in allow.split() if allow is not None else vclass not in disallow):
                continue
            xy = np.array([[float(v) for v in p.split(",")[:2]] for p in lane.get("shape").split()])
            cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
            if cum[-1] < 5.0:
                break
            pts.append([np.interp(cum[-1] / 2, cum, xy[:, 0]), np.interp(cum[-1] / 2, cum, xy[:, 1])])
            break
    return np.array(pts)


@NEEDS_SUMO
@pytest.mark.parametrize("vclass, bit, within", [("passenger", VEHICLE, 4.0), ("tram", TRAM, 2.0)])
def test_sumo_lanes_lie_on_our_street_cells(helsinki, small_scenario, vclass, bit, within):
    pts = _lane_midpoints(small_scenario.parent / "net.net.xml", vclass)
    assert len(pts) >= 5
    cells, dist, _ = place_points(helsinki, pts, np.full(len(pts), bit))
    # a lane's centre is half a lane or so beside our street's centreline: the same projection and origin
    assert np.median(dist) < within and np.percentile(dist, 90) < 2 * within
    footprints = helsinki.cell_footprints.to_shapely()
    inside = [shapely.contains_xy(footprints[c], x, y) for c, (x, y) in zip(cells, pts, strict=True)]
    assert np.mean(inside) >= 0.9


@NEEDS_SUMO
def test_the_scenario_has_cars_walks_and_transit_lines(helsinki, small_scenario):
    root = ET.parse(small_scenario).getroot()
    routes = root.find("input/route-files").get("value").split(",")
    assert {"cars.rou.xml", "peds.rou.xml", "pt.rou.xml"} <= set(routes)
    folder = small_scenario.parent
    flows = list(ET.parse(folder / "pt.rou.xml").getroot().iter("flow"))
    assert flows and {f.get("type") for f in flows} <= {"bus", "tram"}
    assert all(float(f.get("period")) >= 60.0 for f in flows)
    assert list(ET.parse(folder / "peds.rou.xml").getroot().iter("person"))
    loc = ET.parse(folder / "net.net.xml").getroot().find("location")
    ox, oy = helsinki.meta["origin"]
    assert loc.get("netOffset") == f"{-ox:.2f},{-oy:.2f}"  # SUMO x/y = CRS x/y less our origin


def test_the_scenario_is_cached_by_its_parameters(helsinki, tmp_path, monkeypatch):
    monkeypatch.setenv("ENTITYNET_CACHE", str(tmp_path))
    monkeypatch.setattr("sims.sumo.scenario.sumo_version", lambda: "test")
    made = []

    def fake_generate(topo, config, out, say=None, map_path=None):
        made.append(config)
        (out / "scenario.sumocfg").write_text("<configuration/>")
        return out / "scenario.sumocfg"

    monkeypatch.setattr("sims.sumo.scenario.generate", fake_generate)
    a = bundled_scenario(helsinki, ScenarioConfig(seed=1))
    assert bundled_scenario(helsinki, ScenarioConfig(seed=1)) == a and len(made) == 1
    b = bundled_scenario(helsinki, ScenarioConfig(seed=2))
    assert b != a and len(made) == 2 and a.is_file() and b.is_file()
    assert a.parent == scenario_dir(helsinki, ScenarioConfig(seed=1)) and str(tmp_path) in str(a)
    bundled_scenario(helsinki, ScenarioConfig(seed=1), force=True)
    assert len(made) == 3


def test_a_failed_generation_leaves_no_cached_scenario(helsinki, tmp_path, monkeypatch):
    monkeypatch.setenv("ENTITYNET_CACHE", str(tmp_path))
    monkeypatch.setattr("sims.sumo.scenario.sumo_version", lambda: "test")

    def failing(topo, config, out, say=None, map_path=None):
        (out / "net.net.xml").write_text("half")
        raise SumoError("netconvert failed (exit 1): boom")

    monkeypatch.setattr("sims.sumo.scenario.generate", failing)
    with pytest.raises(SumoError, match="boom"):
        bundled_scenario(helsinki, ScenarioConfig())
    assert not scenario_dir(helsinki, ScenarioConfig()).exists()
    assert not list((tmp_path / "sumo").glob("*tmp*"))


@pytest.mark.parametrize("kwargs, message", [
    ({"cars_per_hour": -1.0}, "cars per hour"),
    ({"pedestrians_per_hour": float("nan")}, "pedestrians per hour"),
    ({"duration": 0.0}, "duration"),
    ({"start": 50 * 3600.0}, "start"),
    ({"bbox": (10.0, 0.0, -10.0, 5.0)}, "bbox"),
])
def test_bad_scenario_parameters_are_clear_errors(kwargs, message):
    with pytest.raises(SumoError, match=message):
        ScenarioConfig(**kwargs)


@pytest.mark.parametrize("argv, message", [
    (["sumo", "scenario", "--bbox", "1,2,3"], "XMIN,YMIN,XMAX,YMAX"),
    (["sumo", "scenario", "--duration", "-5"], "duration"),
])
def test_the_scenario_command_refuses_bad_input(argv, message, capsys, monkeypatch):
    monkeypatch.setattr("sims.sumo.missing", lambda: None)
    with pytest.raises(SystemExit) as info:  # refused while parsing, one usage line
        main(argv)
    assert info.value.code == 2
    assert message in capsys.readouterr().err


def test_the_scenario_command_without_the_extra_says_how_to_install(capsys, monkeypatch):
    monkeypatch.setattr("sims.sumo.missing", lambda: "SUMO is not installed (libsumo): pip install 'entitynet[sumo]'")
    assert main(["sumo", "scenario"]) == 2
    err = capsys.readouterr().err
    assert "entitynet[sumo]" in err and "Traceback" not in err
