"""Truth against what viewers see (issue 11, "speed against error").

At each sample, for every viewer and every entity whose true body occupies a cell the viewer subscribes to:
- the ghost position error (metres between the ghost the viewer draws and the true position), when shown;
- missed visibility: the entity is not shown at all (join latency included: a fresh subscription's entities
  count as missed until their first UPDATE arrives);
and for every ghost the viewer shows:
- stale: its entity is truly in none of the viewer's cells and in none of the cells the ghost's UPDATE
  claimed (it moved past what that update's validity covered, or left the map) while the ghost is still
  drawn. A ghost drawn because the cells ahead on its claimed way are visible is not stale: that is the
  validity period working as designed.
Samples are taken at a fixed interval, so counts are proportional to entity-time. Viewers at street level and
above the roofs are kept apart (the PVS matters at street level). Ghost ids are the switchboard's opaque ids;
`eid_to_agent` maps them back to the truth (known when the switchboard runs in this process).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from entitynet.client.network import NetView
from sims.engine.source import Truth
from sims.engine.truth_arrays import EdgeArrays, truth_arrays
from sims.engine.viewers import SimViewer


@dataclass
class Tally:
    """Raw counts of one viewer group, kept apart so groups can be summed into "all" before the fractions
    are taken (fractions of fractions would weight the groups wrongly)."""

    errors: list[float] = field(default_factory=list)
    visible: int = 0  # entity-samples in a visible cell
    missed: int = 0
    shown: int = 0  # ghost-samples drawn
    stale: int = 0
    viewer_samples: int = 0

    def summary(self) -> dict:
        """The group's figures: error mean, p95 and max (None without a shown ghost), missed-visibility and stale
        fractions, and the sample counts they rest on."""
        e = np.array(self.errors) if self.errors else np.zeros(0)
        return {
            "error_mean_m": float(e.mean()) if e.size else None,
            "error_p95_m": float(np.percentile(e, 95)) if e.size else None,
            "error_max_m": float(e.max()) if e.size else None,
            "missed_visibility": self.missed / self.visible if self.visible else 0.0,
            "stale_ghost_fraction": self.stale / self.shown if self.shown else 0.0,
            "visible_entity_samples": self.visible,
            "shown_ghost_samples": self.shown,
            "mean_visible_entities": self.visible / self.viewer_samples if self.viewer_samples else 0.0,
        }


class Measure:
    """Accumulates samples; `summary()` gives the figures per viewer group ("street", "roof") and "all"."""

    def __init__(self) -> None:
        self.tallies: dict[str, Tally] = defaultdict(Tally)
        self._edges: EdgeArrays | None = None
        self._edges_net: NetView | None = None

    def sample(self, now: float, world: Truth, viewers: list[SimViewer], eid_to_agent: dict[int, int]) -> None:
        """One sample of every viewer against the truth at `now`: errors of shown entities in subscribed cells,
        misses, and stale ghosts (see the module docstring for the rules). Over arrays: the truth once
        (`truth_arrays`), then per viewer its subscribed cells as a mask over every (entity, cell) the truth
        occupies; only the viewer's ghosts are walked one by one (`_drawn`)."""
        truth = truth_arrays(world.agents, self._edge_arrays(world))
        n = len(truth.ids)
        pair_row = np.repeat(np.arange(n), np.diff(truth.cell_off))
        # the mask's slots: every cell id from `low` (below 0 only where another source's body says so) to past
        # the map; a subscribed id outside them holds no entity (dropped, not clipped onto an end slot)
        low = min(int(truth.cells.min()), 0) if len(truth.cells) else 0
        pair_cell = truth.cells - low
        n_cells = int(getattr(world.topo, "n_cells", 0) or 0) - low
        n_cells = max(n_cells, int(pair_cell.max()) + 1 if len(pair_cell) else 0)
        memo: dict[tuple[int, float], tuple[float, float]] = {}  # (model, t) -> xy: viewers share models
        for v in viewers:
            t = self.tallies["roof" if v.high else "street"]
            t.viewer_samples += 1
            mask = np.zeros(n_cells, dtype=bool)
            sub = np.fromiter(v.subs.cells, dtype=np.int64, count=len(v.subs.cells)) - low
            mask[sub[(sub >= 0) & (sub < n_cells)]] = True
            inside_rows = np.unique(pair_row[mask[pair_cell]])
            shown: dict[int, tuple[float, float]] = {}
            claimed: dict[int, tuple[int, ...]] = {}
            for eid, (xy, cells) in _drawn(v, now, memo).items():
                aid = eid_to_agent.get(eid, -1)
                if aid < 0:  # not a simulated entity (the demo's transit proxy publishes its own): no truth
                    continue
                shown[aid] = xy
                claimed[aid] = cells
            t.visible += len(inside_rows)
            t.shown += len(shown)
            aids = np.fromiter(shown, dtype=np.int64, count=len(shown))
            rows = truth.rows(aids)
            ghost_at = np.full(n, -1, dtype=np.int64)  # row -> index into `aids` of its ghost
            live = rows >= 0
            ghost_at[rows[live]] = np.flatnonzero(live)
            g = ghost_at[inside_rows]
            hit = g >= 0
            t.missed += int(len(g) - hit.sum())
            if hit.any():
                xy = np.array(list(shown.values()), dtype=np.float64).reshape(-1, 2)
                dx = (xy[g[hit], 0] - truth.x[inside_rows[hit]]).tolist()
                dy = (xy[g[hit], 1] - truth.y[inside_rows[hit]]).tolist()
                t.errors.extend(map(math.hypot, dx, dy))
            inside = np.zeros(n, dtype=bool)
            inside[inside_rows] = True
            for aid, row in zip(aids.tolist(), rows.tolist(), strict=True):
                if row >= 0 and inside[row]:
                    continue
                own = truth.cells_of(row) if row >= 0 else ()
                if set(own).isdisjoint(claimed[aid]):
                    t.stale += 1

    def _edge_arrays(self, world: Truth) -> EdgeArrays | None:
        """The map's `EdgeArrays` for the truth's positions (built once per map)."""
        net = getattr(world, "net", None)
        if not isinstance(net, NetView):
            return None
        if self._edges is None or self._edges_net is not net:
            self._edges, self._edges_net = EdgeArrays(net), net
        return self._edges

    def summary(self) -> dict:
        """The figures per group ("roof", "street") and "all", the latter from the groups' summed raw counts."""
        out = {k: t.summary() for k, t in sorted(self.tallies.items())}
        total = Tally()
        for t in self.tallies.values():
            total.errors += t.errors
            total.visible += t.visible
            total.missed += t.missed
            total.shown += t.shown
            total.stale += t.stale
            total.viewer_samples += t.viewer_samples
        out["all"] = total.summary()
        return out


def _drawn(v: SimViewer, now: float, memo: dict) -> dict[int, tuple[tuple[float, float], tuple[int, ...]]]:
    """What `v.ghosts.positions(now)` gives (expired ghosts dropped, only the visible drawn), with each ghost's
    claimed cells. Why not call it: the viewers share decoded models (`sims.engine.decode_cache`), so one
    entity's ghost is extrapolated once per sample in `memo`, not once per viewer that holds it (the per-viewer
    calls were most of a sample's cost). Keyed by the model object's id, alive while the ghosts hold it."""
    gs = v.ghosts
    if not math.isfinite(now):
        raise ValueError(f"now must be finite, got {now!r}")
    gs.expire(now)
    t = now - gs.clock_offset
    visible = gs.visible_cells
    out = {}
    for e, g in gs.ghosts.items():
        if visible.isdisjoint(g.cells):
            continue
        key = (id(g.model), t)
        xy = memo.get(key)
        if xy is None:
            xy = memo[key] = g.model.xy_at(t)
        out[e] = (xy, g.cells)
    return out
