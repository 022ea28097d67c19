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

from entitynet.client.ghost_table import csr_take
from entitynet.client.network import NetView
from sims.engine.route_table import route_table_of
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
        occupies; its drawn ghosts read from the viewers' ghost table over arrays (`_drawn`), and the stale test
        over (ghost, cell) pairs (`_claims_met`)."""
        truth = truth_arrays(world.agents, self._edge_arrays(world), route_table_of(world))
        n = len(truth.ids)
        pair_row = np.repeat(np.arange(n), np.diff(truth.cell_off))
        # the mask's slots: every cell id from `low` (below 0 only where another source's body says so) to past
        # the map; a subscribed id outside them holds no entity (dropped, not clipped onto an end slot)
        low = min(int(truth.cells.min()), 0) if len(truth.cells) else 0
        pair_cell = truth.cells - low
        n_cells = int(getattr(world.topo, "n_cells", 0) or 0) - low
        n_cells = max(n_cells, int(pair_cell.max()) + 1 if len(pair_cell) else 0)
        memo: dict = {}  # (table, t) -> its distinct models' xy at t (viewers share versions and models)
        # id(table) -> the truth's agent of each of its rows (-1: none), and whether no agent has two rows
        agents: dict[int, tuple[np.ndarray, bool]] = {}
        for v in viewers:
            t = self.tallies["roof" if v.high else "street"]
            t.viewer_samples += 1
            mask = np.zeros(n_cells, dtype=bool)
            sub = np.fromiter(v.subs.cells, dtype=np.int64, count=len(v.subs.cells)) - low
            mask[sub[(sub >= 0) & (sub < n_cells)]] = True
            inside_rows = _distinct_sorted(pair_row[mask[pair_cell]])
            aids, xy, vers = _drawn(v, now, memo, agents, eid_to_agent)
            t.visible += len(inside_rows)
            t.shown += len(aids)
            rows = truth.rows(aids)
            ghost_at = np.full(n, -1, dtype=np.int64)  # row -> index into `aids` of its ghost
            live = rows >= 0
            ghost_at[rows[live]] = np.flatnonzero(live)
            g = ghost_at[inside_rows]
            hit = g >= 0
            t.missed += int(len(g) - hit.sum())
            if hit.any():
                dx = (xy[g[hit], 0] - truth.x[inside_rows[hit]]).tolist()
                dy = (xy[g[hit], 1] - truth.y[inside_rows[hit]]).tolist()
                t.errors.extend(map(math.hypot, dx, dy))
            inside = np.zeros(n, dtype=bool)
            inside[inside_rows] = True
            out = np.flatnonzero(~((rows >= 0) & inside[np.maximum(rows, 0)]))  # ghosts of entities not inside
            if len(out):
                t.stale += len(out) - _claims_met(v.ghosts.table, vers[out], truth, rows[out])

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


def _drawn(v: SimViewer, now: float, memo: dict, agents: dict[int, tuple[np.ndarray, bool]],
           eid_to_agent: dict[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What `v.ghosts.positions(now)` draws (expired ghosts dropped, only the visible drawn), read from the
    viewers' ghost table over arrays: the truth's agent ids of the drawn ghosts (one per agent; ghosts of
    entities that are not simulated, such as the demo's transit proxy's, left out), their (x, y) and their
    versions (for the claimed cells). Why not `positions`: the viewers share versions and decoded models
    (`sims.engine.decode_cache`), so one model is extrapolated once per sample in `memo` (by the table's model
    index, `vmid`), not once per viewer that holds it."""
    if not math.isfinite(now):
        raise ValueError(f"now must be finite, got {now!r}")
    gs = v.ghosts
    table, col = gs.table, gs.col
    rows, vers = table.live_rows(col, now)  # (`expire` then `rows_of`, in one pass over the column)
    keep = table.visible_versions(col, vers)
    rows, vers = rows[keep], vers[keep]
    got = agents.get(id(table))
    if got is None or len(got[0]) < table.n_rows:
        ents = table.entity(np.arange(table.n_rows)).tolist()
        of_row = np.array([eid_to_agent.get(e, -1) for e in ents], dtype=np.int64)
        known = of_row[of_row >= 0]
        # (no agent with two rows in the table: no viewer's ghosts can name one agent twice, nothing to test)
        got = agents[id(table)] = (of_row, len(np.unique(known)) == len(known))
    of_row, one_row_each = got
    aids = of_row[rows]
    sim = aids >= 0
    aids, vers = aids[sim], vers[sim]
    if not one_row_each and len(np.unique(aids)) < len(aids):  # two entity ids of one agent: the later ghost's
        # position, as a dict
        last = {a: i for i, a in enumerate(aids.tolist())}
        first = dict.fromkeys(aids.tolist())
        pick = np.array([last[a] for a in first], dtype=np.int64)
        aids, vers = aids[pick], vers[pick]
    t = now - gs.clock_offset
    at = memo.get((id(table), t))  # the table's distinct models extrapolated to t, each once per sample
    if at is None:
        n = len(table.models)
        at = memo[(id(table), t)] = (np.full((n, 2), np.nan), np.zeros(n, dtype=bool))
    mxy, done = at
    mids = table.vmid[vers]
    models = table.models
    for k in np.unique(mids[~done[mids]]).tolist():
        mxy[k] = models[k].xy_at(t)
        done[k] = True
    return aids, mxy[mids], vers


def _claims_met(table, versions: np.ndarray, truth, rows: np.ndarray) -> int:
    """How many of the ghosts (`versions`, their entities' truth `rows`, -1: none) claimed a cell their entity
    truly occupies (the others are stale): each ghost's claimed cells and its entity's cells as (ghost, cell)
    pairs, sorted together, a ghost meets its claim where one pair comes from both sides."""
    co, cv = csr_take(table.voff, table.vcells, versions)
    known = np.flatnonzero(rows >= 0)
    to, tv = csr_take(truth.cell_off, truth.cells, rows[known])
    owner = np.concatenate([co, known[to]])
    cell = np.concatenate([cv, tv.astype(np.int64)])
    side = np.concatenate([np.zeros(len(co), dtype=np.int64), np.ones(len(to), dtype=np.int64)])
    if not len(owner):
        return 0
    met = np.zeros(len(versions), dtype=bool)
    low, span = int(cell.min()), int(cell.max()) - int(cell.min()) + 1
    if len(versions) * span < 2**61:  # (owner, cell, side) as one integer: one sort, in lexsort's order
        key = np.sort((owner * span + (cell - low)) * 2 + side)
        pair, side = key >> 1, key & 1
        both = (pair[1:] == pair[:-1]) & (side[1:] != side[:-1])
        met[pair[1:][both] // span] = True
    else:
        order = np.lexsort((side, cell, owner))
        owner, cell, side = owner[order], cell[order], side[order]
        both = (owner[1:] == owner[:-1]) & (cell[1:] == cell[:-1]) & (side[1:] != side[:-1])
        met[owner[1:][both]] = True
    return int(met.sum())


def _distinct_sorted(a: np.ndarray) -> np.ndarray:
    """`np.unique(a)` for `a` already sorted ascending (the truth's pair rows are), without its sort."""
    if len(a) < 2:
        return a.copy()
    return a[np.concatenate(([True], a[1:] != a[:-1]))]
