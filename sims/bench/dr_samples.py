"""`bench dr`'s per-entity accounting: an entity's fixes (5 m GPS on its truth, or a real trace's own) and what
its client core's messages and ghost show at every 0.5 s sample, whichever way the client core is stepped.

Why a module of its own: the table's figures are counted the same way for a Player stepped entity by entity
(`dr_bench.run_entity`) and for a dataset stepped together through the fleet core (`dr_fleet.run_fleet`), so
the counting has one home; the two differ only in who calls `feed` and `tick`.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from entitynet.protocol import Publish
from sims.bench.dr_data import SAMPLE, Entity
from sims.mobility import gps


class Samples:
    """One entity's fixes (`is_fix[i]`, `fix_of[i]` -> k of `fixes`, with `speeds[k]`, `headings[k]` where
    `doppler`) at its samples `ts`, and its counts so far (`observe` per sample, `add_to` at the end)."""

    def __init__(self, ent: Entity, model: str, noisy: bool = True, doppler: float | None = None) -> None:
        self.ent, self.model = ent, model
        self.doppler = doppler if noisy else None
        if noisy:
            fix_idx = np.arange(0, len(ent.t), int(round(1.0 / SAMPLE)))
            # the same noise for every model and threshold: differences are the models', not the dice's
            self.fixes = gps(ent.xy[fix_idx], np.random.default_rng(zlib.crc32(ent.name.encode())))
            self.is_fix = np.zeros(len(ent.t), bool)
            self.is_fix[fix_idx] = True
            self.fix_of = {int(i): k for k, i in enumerate(fix_idx)}
            self.ts, self.txy = ent.t, ent.xy
            if doppler:
                vel = np.gradient(ent.xy, ent.t, axis=0)[fix_idx]
                vel = vel + np.random.default_rng(zlib.crc32(ent.name.encode()) + 1).normal(0.0, doppler, vel.shape)
                self.speeds = np.hypot(vel[:, 0], vel[:, 1]).tolist()
                self.headings = np.degrees(np.arctan2(vel[:, 0], vel[:, 1])).tolist()
        else:  # a real trace: its fixes are the reference; sample between them by interpolation
            t = np.arange(ent.t[0], ent.t[-1], SAMPLE)
            self.txy = np.column_stack([np.interp(t, ent.t, ent.xy[:, 0]), np.interp(t, ent.t, ent.xy[:, 1])])
            fix_samples = np.searchsorted(t, ent.t).clip(0, len(t) - 1)
            self.is_fix = np.zeros(len(t), bool)
            self.is_fix[fix_samples] = True
            self.fixes = self.txy[fix_samples]
            self.fix_of = {int(i): k for k, i in enumerate(fix_samples)}
            self.ts = t
        self.last: Publish | None = None
        self.errs = np.full(len(self.ts), np.nan)
        self.occ_bad = self.occ_n = self.pub_cells = self.true_cells = self.updates = self.wrong = self.checked = 0

    def observe(self, i: int, now: float, out: list, p) -> None:
        """Sample i at `now`: the messages `out` the player `p` sent there, its ghost's error, the occupation."""
        ent = self.ent
        for m in out:
            if isinstance(m, Publish):
                self.updates += 1
                self.last = m
        if p.ghost is not None:
            gx, gy = p.ghost.xy_at(now)
            self.errs[i] = math.hypot(gx - self.txy[i, 0], gy - self.txy[i, 1])
        last = self.last
        if ent.cells is not None and last is not None:
            self.occ_n += 1
            truth = ent.cells[i]
            valid = now < p.pub_t + last.validity_ms / 1000.0
            if not valid or not truth.issubset(last.cells):
                self.occ_bad += 1
            self.pub_cells += len(last.cells) if valid else 0
            self.true_cells += len(truth)
        if ent.edge is not None and self.is_fix[i] and ent.edge_ok[i] and self.model == "network":
            inf = p.inferred
            if inf is not None and inf[0] == "edge":
                self.checked += 1
                self.wrong += inf[1] != ent.edge[i]

    def add_to(self, acc: dict, p) -> None:
        """The entity's counts into the accumulator `acc` (`dr_bench._new_acc`), with the player's reasons."""
        ts = self.ts
        acc["updates"] += self.updates
        acc["minutes"] += (ts[-1] - ts[0]) / 60.0
        acc["errs"].append(self.errs[~np.isnan(self.errs)])
        for key in ("occ_bad", "occ_n", "pub_cells", "true_cells", "wrong", "checked"):
            acc[key] += getattr(self, key)
        acc["reasons"].update(p.stats)
