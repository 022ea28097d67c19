"""`bench dr`'s network-model rows through the fleet core, as the simulator runs its entities.

Why: the simulator steps every entity's client core through one `entitynet.client.fleet.FleetCore` (the usual
fix and the timers in arrays, the entity's Player only where something happens). The dr table's network rows
step a dataset the same way, so the table measures the core the simulator uses and says what share of its
fixes the arrays decided and why the others went to the Players (`FleetCore.scalar_why`). The fleet core
sends what each Player alone sends (tests/entitynet/client/test_fleet.py), so the table is the one that
stepping entity by entity (`dr_bench.run_entity`) gives, row for row.

All entities of a dataset are sampled on one grid (0.0, 0.5, 1.0, ... s, `dr_data`), so they step in lockstep:
at every sample the entities with a fix there take it (`step`'s due), the others' timers run; an entity whose
samples end stays idle (its counts are taken in the entities' order at the end).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from entitynet.client.fleet import FleetCore
from entitynet.client.player import Player
from sims.bench.dr_data import Entity
from sims.bench.dr_samples import Samples


def run_fleet(topo, ents: list[Entity], threshold: float, acc: dict, doppler: float | None = None,
              split: Counter | None = None) -> None:
    """`dr_bench.run_entity` (network model, 5 m GPS) for every entity of `ents` at once through one fleet
    core: their counts into `acc`; `split` (when given) gets the fixes decided in arrays (`arrays`), those
    left to the Players (`scalar`) and the latter by reason (`scalar:<why>`)."""
    core = FleetCore(capacity=len(ents))
    smps, players, slots = [], [], []
    for ent in ents:
        if ent.cells is None:
            raise ValueError(f"{ent.name}: the fleet core runs network-model entities on the map only")
        p = Player(topo, 1, ent.etype, model="network", route=ent.route, stops=getattr(ent, "stops", ()),
                   threshold=threshold)
        smps.append(Samples(ent, "network", True, doppler))
        players.append(p)
        slots.append(core.add(p))
    if not ents:
        return
    grid = max((s.ts for s in smps), key=len)
    for s in smps:  # (the same sample times, bit for bit: one `now` per step serves them all)
        if not np.array_equal(s.ts, grid[:len(s.ts)]):
            raise ValueError(f"{s.ent.name}: its samples are not on the dataset's grid")
    accuracy = players[0].accuracy
    if any(p.accuracy != accuracy for p in players):
        raise ValueError("the fleet core takes one fix accuracy per step: the players differ")
    live = list(range(len(ents)))
    idle: list[int] = []  # the slots of the entities whose samples ended: no fix and no timers any more
    for i in range(len(grid)):
        now = float(grid[i])
        due, fx = [], []
        for j in live:
            s = smps[j]
            if s.is_fix[i]:
                k = s.fix_of[i]
                due.append(slots[j])
                fx.append((*s.fixes[k], *((s.speeds[k], s.headings[k]) if s.doppler else (np.nan, np.nan))))
        f = np.array(fx, dtype=float).reshape(len(fx), 4)
        vel = {"speed": f[:, 2], "heading": f[:, 3], "speed_accuracy": doppler} if doppler else {}
        out = dict(core.step(now, due, f[:, 0], f[:, 1], accuracy, idle=idle, **vel)[0])
        for j in live:
            smps[j].observe(i, now, out.get(slots[j], []), players[j])
        for j in [j for j in live if i == len(smps[j].ts) - 1]:
            idle.append(slots[j])
            live.remove(j)
    for s, p in zip(smps, players, strict=True):  # (in the entities' order: the error samples' order too)
        s.add_to(acc, p)
    if split is not None:
        split["arrays"] += core.counters["vector_fixes"]
        split["scalar"] += core.counters["scalar_fixes"]
        split.update({f"scalar:{why}": k for why, k in core.scalar_why.items() if k})


def split_summary(split: Counter) -> dict:
    """The shares of a `run_fleet` split: fixes, the share in arrays, and the scalar share by reason."""
    n = split["arrays"] + split["scalar"]
    return {"fixes": n, "in_arrays": round(split["arrays"] / n, 4) if n else None,
            "scalar_by_reason": {k.split(":", 1)[1]: round(v / n, 4) for k, v in sorted(split.items())
                                 if k.startswith("scalar:") and v}}
