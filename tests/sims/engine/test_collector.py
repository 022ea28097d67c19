"""`sims.engine.collector`: the start's objects frozen out of collection, the first generation's threshold raised;
run in a child process (the collector's settings are the process's: pytest's own must stay as they are)."""

from __future__ import annotations

import gc
import subprocess
import sys

import pytest

from sims.engine.collector import SIM_GEN0, settle_after_start

CHILD = """
import gc
from sims.engine.collector import settle_after_start
held = [[i] for i in range(50_000)]  # what a run's start builds and holds to the end
frozen = settle_after_start()
cycle = []; cycle.append(cycle); del cycle  # cyclic garbage made after the start is still collected
print(frozen, gc.get_threshold()[0], gc.collect())
"""

UNSETTLE = """
import gc
from sims.engine.collector import settle_after_start, unsettle
before = gc.get_threshold()
settle_after_start()
unsettle(before)
print(gc.get_freeze_count(), gc.get_threshold() == before)
"""


def test_settling_freezes_what_the_start_built_and_raises_the_first_generation():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=60, check=True)
    frozen, gen0, collected = map(int, out.stdout.split())
    assert frozen >= 50_000 and gen0 == SIM_GEN0 and collected >= 1


@pytest.mark.parametrize("gen0", [0, -5, 10**9])
def test_a_bad_threshold_is_refused_before_anything_changes(gen0):
    before = (gc.get_threshold(), gc.get_freeze_count())
    with pytest.raises(ValueError, match="first generation"):
        settle_after_start(gen0)
    assert (gc.get_threshold(), gc.get_freeze_count()) == before


def test_unsettling_gives_the_process_its_collector_back():
    """A simulation run inside a longer-lived process (the CLI's shell in a test session) puts it back."""
    out = subprocess.run([sys.executable, "-c", UNSETTLE], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == ["0", "True"]
