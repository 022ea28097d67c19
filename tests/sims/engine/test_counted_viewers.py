"""Counted viewers (`SimConfig.measured_viewers`, `entitynet sim --measured-viewers K`, issue 23): only K viewers
keep ghosts and enter the truth figures, the others subscribe and receive every message as before and only
count it; the report says how many viewers were measured and how many counted."""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from sims.engine.local import run_local
from sims.engine.sim import Sim, SimConfig
from sims.engine.viewers import measured_indices

CFG = dict(entities=40, viewers=8, connections=2, transit=False, seed=5)


@pytest.fixture(scope="module")
def runs(helsinki):
    """The same seeded run (in-process switchboard core) with every viewer measured and with 3 of 8."""
    out = {}
    for k in (None, 3):
        sim = Sim(helsinki, SimConfig(**CFG, measured_viewers=k))
        out[k] = (sim, run_local(sim, 5.0))
    return out


def test_counted_viewers_receive_what_measured_ones_do(runs):
    (full, full_rep), (part, part_rep) = runs[None], runs[3]
    counted = [v for v in part.viewers if v.counted]
    assert len(counted) == 5 and all(v.ghosts is None for v in counted)
    assert sum(v.deliveries for v in counted) > 0 and sum(v.leaves for v in counted) > 0
    for a, b in zip(full.viewers, part.viewers, strict=True):  # each viewer: the same messages and bytes
        assert (a.deliveries, a.leaves, a.bytes) == (b.deliveries, b.leaves, b.bytes)
    assert part_rep["switch"] == full_rep["switch"]  # the server's work is the same


def test_the_report_says_how_many_were_measured_and_counted(runs):
    full_rep, part_rep = runs[None][1], runs[3][1]
    v = part_rep["viewers"]
    assert (v["measured"], v["counted"], v["street"] + v["roof"]) == (3, 5, 8)
    assert (full_rep["viewers"]["measured"], full_rep["viewers"]["counted"]) == (8, 0)
    tv = part_rep["truth_vs_viewer"]
    assert (tv["measured_viewers"], tv["counted_viewers"]) == (3, 5)
    # the truth figures rest on the measured sample only: fewer viewer-samples than with all 8 measured
    assert 0 < tv["all"]["visible_entity_samples"] < full_rep["truth_vs_viewer"]["all"]["visible_entity_samples"]


def test_a_counted_viewer_counts_a_whole_frame_as_a_measured_one_takes_it(helsinki):
    sim = Sim(helsinki, SimConfig(**CFG, measured_viewers=1))
    measured, counted = sim.viewers[0], sim.viewers[1]
    assert not measured.counted and counted.counted
    frame = [P.Update(1, 1, (3,), 4000, b"\x90"), P.Leave(9), P.Update(2, 1, (4,), 4000, b"\x90"), P.Leave(1)]
    for v in (measured, counted):
        v.receive_frame(frame, sim.now, 57, True)
        v.receive(P.Welcome(1, 2, 0, {}), sim.now, 11)  # clears ghosts (none for a counted viewer)
    assert (measured.deliveries, measured.leaves, measured.bytes) == (counted.deliveries, counted.leaves,
                                                                      counted.bytes) == (2, 2, 68)


def test_the_sample_is_spread_over_street_and_roof_viewers():
    assert measured_indices(8, None) == frozenset(range(8)) == measured_indices(8, 8)
    assert measured_indices(100, 10) == frozenset(range(0, 100, 10))
    assert measured_indices(1000, 100) & frozenset(range(250)) and len(measured_indices(1000, 100)) == 100
    with pytest.raises(ValueError, match="measured viewers"):
        SimConfig(viewers=4, measured_viewers=5)
    with pytest.raises(ValueError, match="measured viewers"):
        SimConfig(viewers=4, measured_viewers=0)


def test_the_cli_refuses_more_measured_viewers_than_viewers(capsys):
    from entitynet.cli import main

    assert main(["sim", "--viewers", "4", "--measured-viewers", "5", "--duration", "1"]) == 2
    assert "measured viewers must be between 1 and the 4 viewers" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:  # refused while parsing
        main(["sim", "--measured-viewers", "0", "--duration", "1"])
    assert info.value.code == 2 and "argument --measured-viewers" in capsys.readouterr().err
