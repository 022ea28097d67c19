"""`sims` has one mobility model, used by the demo and the benchmarks, in modules a newcomer can read."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

import sims
import sims.engine.sim
import sims.mobility

MAX_LINES = 500


def test_no_sims_module_is_over_500_lines():
    root = Path(sims.__file__).parent
    long = {str(p.relative_to(root)): n for p in root.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}


@pytest.mark.parametrize("gone", ["sims.movers", "sims.behaviours", "sims.mobility.movers"])
def test_the_old_mover_models_are_gone(gone):
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(gone)


def test_demo_and_benchmarks_use_the_one_model():
    from sims import demo
    from sims.bench import dr_bench, dr_data, switch_bench, switch_replay
    from sims.engine import clients, params, viewers

    # the demo is a preset of the simulation: its engine, shell and viewers, no mover or viewer of its own
    assert demo.Sim is sims.engine.sim.Sim and not hasattr(demo, "Viewer") and not hasattr(sims.mobility, "Mover")
    # the simulation engine moves and measures with the one model
    assert viewers.Trajectory is sims.mobility.Trajectory and clients.entity_gps is sims.mobility.entity_gps
    assert params.kind is sims.mobility.kind
    assert switch_bench.Walkers is sims.mobility.Walkers and switch_replay.Walkers is sims.mobility.Walkers
    assert dr_bench.gps is sims.mobility.gps
    assert dr_data.profile_for is sims.mobility.profile_for and dr_data.random_walk is sims.mobility.random_walk
    assert not hasattr(switch_bench, "SPEEDS") and not hasattr(demo, "SPEEDS")
