"""Every vehicle's leader at once: the body index and the leader search of `World` over arrays.

Why: with the free walkers over arrays (`free_flow`), the vehicles' step is most of the world's, and of that
the body index (which edge holds which part of which body) and the leader search (the nearest body ahead in
the lane) are half: Python loops over every body's edges and every vehicle's edges ahead. Here the bodies'
pieces are computed for all at once from the world's `RouteTable`, sorted by edge, and each vehicle's edges
ahead are joined with the pieces on them (sort and searchsorted), the candidates filtered and the nearest one
taken per vehicle.

Same leader, bit for bit, as `World._leader` over `World._body_index`: the same arithmetic in the same order
(the pieces' offsets, `near`, the lanes' sideways overlap), the same rule (the first edge ahead that holds a
candidate; on it the nearest, the first in the index's order on a tie: bodies in the world's id order, each
body's edges in route order). tests/sims/engine/test_free_flow.py compares whole runs with the scalar step.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sims.engine.agents import Agent
from sims.engine.behaviour import Obstacle
from sims.engine.route_table import RouteTable


def _expand(start: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ranges [start, stop): (which range, value) of every member, ranges in order, members ascending."""
    n = np.maximum(stop - start, 0)
    owner = np.repeat(np.arange(len(start)), n)
    first = np.concatenate([[0], np.cumsum(n)[:-1]]) if len(n) else n
    return owner, start[owner] + (np.arange(int(n.sum())) - first[owner])


def leaders(table: RouteTable, bodies: Sequence[Agent], movers: Sequence[Agent],
            ahead: Sequence[float]) -> list[Obstacle | None]:
    """The leader of each of `movers` (vehicles), looking `ahead[i]` (a route distance) along its route, among
    `bodies` (every entity with a length, in the world's id order): `World._leader` for each."""
    if not movers:
        return []
    t = table
    # ---- the body index: pieces (edge, lo, hi, body, direction), as `World._body_index` lists them
    brt = np.array([b._rt for b in bodies], dtype=np.int64).reshape(-1, 2)
    bs = np.array([b.s for b in bodies])
    blen = np.array([b.params.length for b in bodies])
    back = bs - blen
    back = np.where(0.0 > back, 0.0, back)  # max(s - length, 0.0)
    lo_r, hi_r = brt[:, 0], brt[:, 0] + brt[:, 1]
    k0 = np.clip(t.first_row(lo_r, hi_r, back, strict=False) - 1, lo_r, hi_r - 1)
    k1 = np.clip(t.first_row(lo_r, hi_r, bs, strict=False) - 1, lo_r, hi_r - 1)
    pb, pk = _expand(k0, k1 + 1)
    pe, pd, L, c = t.edge[pk], t.dirn[pk], t.elen[pk], t.cum[pk]
    lo = back[pb] - c
    lo = np.where(0.0 > lo, 0.0, lo)  # max(back - cum, 0.0)
    hi = bs[pb] - c
    hi = np.where(L < hi, L, hi)  # min(s - cum, edge length)
    rev = pd < 0
    lo, hi = np.where(rev, L - hi, lo), np.where(rev, L - lo, hi)
    order = np.argsort(pe, kind="stable")  # by edge, keeping the index's order within an edge
    pe, lo, hi, pb, pd = pe[order], lo[order], hi[order], pb[order], pd[order]
    # ---- each mover's edges ahead: from the edge holding its front while the edge starts before `ahead`
    row_of = {b.id: i for i, b in enumerate(bodies)}
    me = np.array([row_of.get(a.id, -1) for a in movers], dtype=np.int64)
    mrt = np.array([a._rt for a in movers], dtype=np.int64).reshape(-1, 2)
    ms = np.array([a.s for a in movers])
    mah = np.array(ahead, dtype=np.float64)
    mlo, mhi = mrt[:, 0], mrt[:, 0] + mrt[:, 1]
    ka = np.clip(t.first_row(mlo, mhi, ms, strict=False) - 1, mlo, mhi - 1)
    kend = np.maximum(t.first_row(ka, mhi, mah, strict=True), ka)  # rows with cum < ahead
    qm, qk = _expand(ka, kend)
    qe = t.edge[qk]
    first = np.searchsorted(pe, qe, side="left")
    last = np.searchsorted(pe, qe, side="right")
    cq, cp = _expand(first, last)  # (pair, piece) candidates, pairs in (mover, route order), pieces in order
    cm, ck = qm[cq], qk[cq]
    d = t.dirn[ck]
    near = t.cum[ck] + np.where(d > 0, lo[cp], t.elen[ck] - hi[cp])
    behind = ms[cm] - 0.01
    mlat = np.array([a.lateral for a in movers])
    mwid = np.array([a.params.width for a in movers])
    blat = np.array([b.lateral for b in bodies])
    bwid = np.array([b.params.width for b in bodies])
    b = pb[cp]
    overlap = np.abs(d * mlat[cm] - pd[cp] * blat[b]) < 0.5 * (mwid[cm] + bwid[b])  # behaviour.lanes_overlap
    ok = (b != me[cm]) & ~(near < behind) & ~(near > mah[cm]) & overlap
    idx = np.flatnonzero(ok)
    out: list[Obstacle | None] = [None] * len(movers)
    if not len(idx):
        return out
    # per mover: the first route edge with a candidate, on it the nearest, the first listed on a tie
    pick = np.lexsort((idx, near[idx], ck[idx], cm[idx]))
    chosen = idx[pick]
    movers_of = cm[chosen]
    keep = np.concatenate([[True], movers_of[1:] != movers_of[:-1]])
    for j in chosen[keep].tolist():
        m, body = int(cm[j]), bodies[int(b[j])]
        same = int(pd[cp[j]]) == int(d[j])
        out[m] = Obstacle(float(near[j]), body.v if same else -body.v, "leader", body.id)
    return out
