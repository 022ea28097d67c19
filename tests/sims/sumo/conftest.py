"""A small SUMO scenario of the bundled map (a few hundred metres round the map's origin, a few minutes of
demand), generated once per test session; tests that need SUMO skip, saying why, where the extra is absent."""

from __future__ import annotations

import pytest

from sims.sumo import missing

NEEDS_SUMO = pytest.mark.skipif(missing() is not None, reason=f"{missing()} (the [sumo] extra is not installed)")

#: local metres round the map's origin: the streets of the test scenario
BBOX = (-200.0, -200.0, 200.0, 200.0)


@pytest.fixture(scope="session")
def small_scenario(helsinki, tmp_path_factory):
    """The .sumocfg of a small scenario of the bundled map, in the test artifact's projection: cars and walks
    at a few a minute, the bus and tram lines of those streets, two minutes long."""
    if missing() is not None:
        pytest.skip(missing())
    from sims.sumo.scenario import ScenarioConfig, generate

    out = tmp_path_factory.mktemp("sumo")
    return generate(helsinki, ScenarioConfig(cars_per_hour=1800, pedestrians_per_hour=2400, duration=120.0,
                                             bbox=BBOX, seed=3), out)
