"""`sims.engine.idm_arrays.moves` against the scalar `behaviour.accel_for` on odd inputs, and its bad input."""

from __future__ import annotations

import random

import pytest

from sims.engine.agents import Agent
from sims.engine.behaviour import Obstacle, accel_for
from sims.engine.idm_arrays import moves
from sims.engine.params import params
from sims.engine.routes import Route
from sims.engine.world import World
from tests.entitynet.client_fixtures import make_topology


def _agents(n: int, seed: int) -> tuple[list[Agent], list[list[Obstacle]]]:
    topo = make_topology({"A": (0.0, 0.0), "B": (500.0, 0.0)}, [("A", "B")])
    route = Route(World(topo).net, [(0, 1)])
    rng = random.Random(seed)
    agents, obstacles = [], []
    for i in range(n):
        v = rng.choice([0.0, -0.0, 1e-12, rng.uniform(0.0, 20.0)])
        v0 = rng.choice([0.0, v, rng.uniform(0.5, 15.0)])
        s = rng.uniform(0.0, 300.0)
        agents.append(Agent(i + 1, params(rng.choice(["car", "bus", "tram", "pedestrian"])), route, s, v, v0, 0.0,
                            0.0))
        obs = []
        for kind in ("stop", "leader", "crossing"):
            if rng.random() < 0.5:
                at = s + rng.choice([0.0, 1e-7, rng.uniform(-1.0, 60.0)])
                obs.append(Obstacle(at, rng.uniform(-5.0, 10.0) if kind == "leader" else 0.0, kind, i,
                                    s0=None if kind == "leader" else rng.choice([0.5, 1.0]),
                                    headway=0.0 if kind == "stop" else None))
        obstacles.append(obs)
    return agents, obstacles


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_moves_match_the_scalar_model_bit_for_bit(seed):
    agents, obstacles = _agents(400, seed)
    new_s, new_v, limits = moves(agents, obstacles, 0.5)
    for a, obs, si, vi, lim in zip(agents, obstacles, new_s, new_v, limits, strict=True):
        acc, limit = accel_for(a, obs)
        v = max(0.0, a.v + acc * 0.5)
        ds = a.v * a.v / (-2.0 * acc) if acc < 0 and a.v > 0 and v == 0.0 else 0.5 * (a.v + v) * 0.5
        s = a.s + max(ds, 0.0)
        if limit is not None and limit.kind != "stop" and s > max(limit.at - 0.3, a.s):
            s, v = max(limit.at - 0.3, a.s), 0.0
        assert lim is limit and repr((si, vi)) == repr((s, v))


def test_no_entity_and_too_many_obstacles():
    assert moves([], [], 0.5) == ([], [], [])
    agents, _ = _agents(1, 1)
    ob = Obstacle(agents[0].s + 10.0, 0.0, "stop")
    with pytest.raises(ValueError, match="at most 3"):
        moves(agents, [[ob, ob, ob, ob]], 0.5)
