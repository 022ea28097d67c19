"""`entitynet sim --mobility sumo`: a SUMO scenario drives honest clients end to end (real server, viewers, truth
measure, report), reproducibly for a seed; scenarios that cannot be used get clear errors."""

from __future__ import annotations

import json
import math

import pytest

from entitynet.cli import main
from sims.engine.local import run_local
from sims.engine.sim import Sim, SimConfig
from sims.sumo import SumoError
from sims.sumo.source import SumoSource, check_overlap, local_converter, net_file
from tests.sims.sumo.conftest import NEEDS_SUMO


@NEEDS_SUMO
def test_sim_mobility_sumo_end_to_end(helsinki_path, small_scenario, tmp_path, capsys):
    out = tmp_path / "report.json"
    code = main(["sim", "--mobility", "sumo", "--sumocfg", str(small_scenario), "--topology", str(helsinki_path),
                 "--duration", "40", "--speed", "8", "--viewers", "4", "--connections", "2", "--gtfs", "none",
                 "--summary-every", "0.5", "--report", str(out), "--measure-share", "1"])
    err = capsys.readouterr().err
    assert code == 0, err
    rep = json.loads(out.read_text())
    assert rep["mobility"]["source"] == "sumo" and rep["mobility"]["sumocfg"] == str(small_scenario)
    assert rep["sim_time_s"] == 40.0
    assert rep["entities"].get("car", 0) > 0 and rep["entities"].get("pedestrian", 0) > 0
    assert rep["clients"]["fixes"] > 100 and rep["clients"]["published"] > 10
    assert rep["viewers"]["deliveries"] > 0  # through the real server in this process to the viewers
    tv = rep["truth_vs_viewer"]["all"]
    assert tv["visible_entity_samples"] > 0 and tv["error_p95_m"] is not None
    assert rep["mobility"]["off_network"]["entity_samples"] > 0
    assert rep["mobility"]["vehicle_seconds"] > 0 and rep["mobility"]["sumo_step_s"] > 0
    assert "entities" in err and "viewer error" in err and "Traceback" not in err


@NEEDS_SUMO
def test_a_sumo_run_is_reproducible_and_measured_against_the_truth(helsinki, small_scenario):
    def run() -> dict:
        cfg = SimConfig(entities=0, viewers=6, seed=4, transit=False)
        src = SumoSource(helsinki, small_scenario, start=cfg.start, step=1.0 / cfg.tick_hz, seed=cfg.seed)
        try:
            sim = Sim(helsinki, cfg, source=src)
            rep = run_local(sim, 40.0)
            kinds = {a.name for a in sim.world.agents.values()}
            tram = [a for a in sim.world.agents.values() if a.name == "tram"]
        finally:
            src.close()
        return rep, kinds, tram

    a, kinds, trams = run()
    b, _, _ = run()
    assert a["clients"] == b["clients"] and a["entities"] == b["entities"]
    assert a["truth_vs_viewer"] == b["truth_vs_viewer"]
    assert {"car", "pedestrian"} <= kinds and kinds <= {"car", "pedestrian", "bus", "tram", "cyclist"}
    assert a["truth_vs_viewer"]["all"]["error_mean_m"] < 15.0  # ghosts of honest clients follow SUMO's truth
    assert a["truth_vs_viewer"]["all"]["missed_visibility"] < 0.2
    for t in trams:  # a tram's SUMO length gives its two parts, to its client too
        assert len(t.parts) == 2 and math.isclose(sum(t.parts), t.length) and t.etype.parts == t.parts
    assert a["mobility"]["ended_at"] is None


@NEEDS_SUMO
def test_the_scenario_ending_empties_the_map_and_the_clock_runs_on(helsinki, small_scenario):
    cfg = SimConfig(entities=0, viewers=2, seed=1, transit=False)
    src = SumoSource(helsinki, small_scenario, start=cfg.start, step=0.5, seed=1, warmup=100.0)
    try:
        sim = Sim(helsinki, cfg, source=src)
        assert sim.now == cfg.start  # the warm-up is SUMO's alone: the run starts at its start
        rep = run_local(sim, 30.0)  # the scenario is 120 s long: it ends 20 s into the run
    finally:
        src.close()
    assert rep["mobility"]["ended_at"] == pytest.approx(cfg.start + 20.0, abs=0.6)
    assert sum(rep["entities"].values()) == 0 and rep["mobility"]["end_reason"] == "the scenario's end time"
    assert rep["sim_time_s"] == 30.0 and rep["clients"]["unpublished"] > 0
    with pytest.raises(ValueError, match="forward"):
        src.step(0.0)


@NEEDS_SUMO
def test_a_second_source_replaces_the_first_in_libsumo(helsinki, small_scenario):
    a = SumoSource(helsinki, small_scenario, start=0.0, step=0.5)
    b = SumoSource(helsinki, small_scenario, start=0.0, step=0.5)  # libsumo holds one: `a` is closed
    try:
        b.start()
        assert b.step(0.5) is not None and a.step(0.5) == [] and a.ended_at is not None
    finally:
        a.close()
        b.close()
        b.close()


def _write(path, text: str):
    path.write_text(text)
    return path


def test_a_scenario_of_another_city_is_refused_clearly(helsinki, tmp_path):
    net = _write(tmp_path / "berlin.net.xml", '<net><location netOffset="-390000.00,-5818000.00" '
                 'convBoundary="0.00,0.00,2000.00,1500.00" origBoundary="13.3,52.5,13.4,52.52" '
                 'projParameter="+proj=utm +zone=33 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"/>'
                 '<edge id="a"/></net>')
    with pytest.raises(SumoError, match="does not overlap the topology's map"):
        check_overlap(net, helsinki, local_converter(net, helsinki))


def test_a_net_in_our_local_frame_overlaps(helsinki, tmp_path):
    ox, oy = helsinki.meta["origin"]
    net = _write(tmp_path / "h.net.xml", f'<net><location netOffset="{-ox:.2f},{-oy:.2f}" '
                 'convBoundary="-300.00,-300.00,300.00,300.00" origBoundary="0,0,0,0" '
                 'projParameter="+proj=utm +zone=35 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"/></net>')
    conv = local_converter(net, helsinki)
    assert check_overlap(net, helsinki, conv) == pytest.approx(1.0)
    xy = conv([[10.0, -20.0]])
    assert abs(xy[0, 0] - 10.0) < 0.01 and abs(xy[0, 1] + 20.0) < 0.01  # our local frame, unchanged


@pytest.mark.parametrize("cfg_text, message", [
    ("this is not xml", "not a SUMO configuration"),
    ("<configuration><input/></configuration>", "names no net-file"),
    ('<configuration><input><net-file value="gone.net.xml"/></input></configuration>', "does not exist"),
])
def test_bad_configurations_are_clear_errors(tmp_path, cfg_text, message):
    cfg = _write(tmp_path / "bad.sumocfg", cfg_text)
    with pytest.raises(SumoError, match=message):
        net_file(cfg)


@pytest.mark.parametrize("net_text, message", [
    ("<net><edge id='a'/></net>", "without <location>"),
    ('<net><location netOffset="0,0" convBoundary="nan,0,1,1" projParameter="!"/></net>', "bad convBoundary"),
    ('<net><location netOffset="x" convBoundary="0,0,1,1" projParameter="+proj=utm"/></net>', "bad netOffset"),
    ('<net><location netOffset="0,0" convBoundary="0,0,1,1" projParameter="+proj=nonsense"/></net>', "unknown"),
])
def test_bad_networks_are_clear_errors(helsinki, tmp_path, net_text, message):
    net = _write(tmp_path / "bad.net.xml", net_text)
    with pytest.raises(SumoError, match=message):
        check_overlap(net, helsinki, local_converter(net, helsinki))


@pytest.mark.parametrize("argv, message", [
    (["--sumocfg", "x.sumocfg"], "--sumocfg needs --mobility sumo"),
    (["--mobility", "sumo", "--sumocfg", "/nonexistent/x.sumocfg"], "no such SUMO configuration"),
])
def test_sim_command_errors(helsinki_path, argv, message, capsys):
    code = main(["sim", "--topology", str(helsinki_path), "--duration", "1", *argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err


def test_sim_mobility_sumo_without_the_extra_says_how_to_install(helsinki_path, capsys, monkeypatch):
    monkeypatch.setattr("sims.sumo.missing", lambda: "SUMO is not installed (libsumo): pip install 'entitynet[sumo]'")
    code = main(["sim", "--mobility", "sumo", "--topology", str(helsinki_path), "--duration", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "entitynet[sumo]" in err and "Traceback" not in err
