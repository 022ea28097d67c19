"""The honest clients' model as a simulation setting: the periodic baseline (`bench e2e`'s ablation) publishes
a standing position at every fix, dead reckoning far less often; an unknown model is refused."""

from __future__ import annotations

import pytest

from sims.engine.local import run_local
from sims.engine.sim import Sim, SimConfig
from tests.sims.engine.test_routes import grid


def _config(**kw) -> SimConfig:
    return SimConfig(entities=12, viewers=4, connections=2, subscribe="radius", radius=400.0, transit=False,
                     start=0.0, **kw)


def test_periodic_clients_publish_every_fix_and_viewers_still_see_them():
    dr = run_local(Sim(grid(), _config()), 30.0)
    periodic = run_local(Sim(grid(), _config(client_model="periodic")), 30.0)
    assert periodic["clients"]["fixes"] == dr["clients"]["fixes"]  # the same truth and the same fixes
    assert periodic["clients"]["published"] >= 0.9 * periodic["clients"]["fixes"]
    assert periodic["clients"]["published"] > 2 * dr["clients"]["published"]
    tv = periodic["truth_vs_viewer"]["all"]
    assert tv["visible_entity_samples"] > 50 and tv["missed_visibility"] < 0.1 and tv["error_p95_m"] < 25.0


def test_an_unknown_client_model_is_refused():
    with pytest.raises(ValueError, match="client model"):
        _config(client_model="teleport")
