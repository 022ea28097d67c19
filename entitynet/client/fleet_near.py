"""The fleet core's neighbourhood search: `Placer.near` for many fixes at once, over the placers' own tables.

Why: with 5 m GPS noise more than half the fixes land farther than the switch margin (3 m) from the edge the
entity is on, and `NetworkTracker.track` then asks `Placer.near` which edge of the neighbourhood explains the fix
(its path's edges with a head start). Those fixes are as common as the written-out ones, so the fleet core runs
the same search in arrays: every segment of the current edge's two-hop table (the placer's own `_SegTable`,
rows in its order), the cost `d + margin` off the path window, the first minimum winning, the same IEEE
operations as `Placer._near_np` (which `_near_py` equals bit for bit). A table that holds an area of the placer's
networks is not taken (`near` would test the fix inside it first): those fixes stay with the scalar code.
"""

from __future__ import annotations

import numpy as np

_COLS = ("ax", "ay", "dx", "dy", "inv_l2", "cum0", "slen")


class NearTables:
    """The rows of every table asked for so far, concatenated: (networks, edge) -> (start, count, usable)."""

    def __init__(self) -> None:
        self.index: dict[tuple[int, int], tuple[int, int, bool]] = {}
        self.size = 0
        self.cols = {c: np.zeros(1024) for c in _COLS}
        self.edge = np.zeros(1024, dtype=np.int64)

    def rows_of(self, placer, e: int) -> tuple[int, int, bool]:
        """Where edge e's table of `placer` lies in the concatenated rows (built on first use)."""
        key = (placer.networks, e)
        hit = self.index.get(key)
        if hit is None:
            t = placer.table(e)
            n = len(t.edge)
            usable = n > 0 and not any(placer.topo.area_networks[a] & placer.networks for a in t.areas)
            if self.size + n > len(self.edge):
                cap = max(2 * len(self.edge), self.size + n)
                for c in _COLS:
                    grown = np.zeros(cap)
                    grown[: self.size] = self.cols[c][: self.size]
                    self.cols[c] = grown
                grown_e = np.zeros(cap, dtype=np.int64)
                grown_e[: self.size] = self.edge[: self.size]
                self.edge = grown_e
            for c in _COLS:
                self.cols[c][self.size : self.size + n] = getattr(t, c)
            self.edge[self.size : self.size + n] = t.edge
            hit = self.index[key] = (self.size, n, usable)
            self.size += n
        return hit

    def near(self, x: np.ndarray, y: np.ndarray, start: np.ndarray, count: np.ndarray, margin: np.ndarray,
             pe: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
        """`Placer.near(x[i], y[i], ., preferred_i, margin[i])` for tables (start[i], count[i]) without areas,
        preferred_i being the edges pe[i, lo[i]..hi[i]]: (edge, offset, px, py, distance, preferred?)."""
        n = len(x)
        gstart = np.cumsum(count) - count
        rep = np.repeat(np.arange(n), count)
        k = np.arange(int(count.sum())) - gstart[rep] + start[rep]
        cols = self.cols
        ax, ay, dx, dy = cols["ax"][k], cols["ay"][k], cols["dx"][k], cols["dy"][k]
        rx = x[rep] - ax
        ry = y[rep] - ay
        u = np.clip((rx * dx + ry * dy) * cols["inv_l2"][k], 0.0, 1.0)
        ex = rx - u * dx
        ey = ry - u * dy
        d = np.sqrt(ex * ex + ey * ey)
        edge = self.edge[k]
        # preferred: (fix, edge) among the (fix, window edge) pairs, as one sorted search of int64 keys
        span = hi - lo + 1
        wrep = np.repeat(np.arange(n), span)
        wcol = np.arange(int(span.sum())) - np.repeat(np.cumsum(span) - span, span) + lo[wrep]
        big = int(max(int(pe.max()), int(edge.max()))) + 1
        keys = np.sort(wrep * big + pe[wrep, wcol])
        want = rep * big + edge
        at = np.minimum(np.searchsorted(keys, want), len(keys) - 1)
        pref = keys[at] == want
        cost = d + np.where(pref, 0.0, margin[rep])
        cmin = np.minimum.reduceat(cost, gstart)
        hit = np.flatnonzero(cost == cmin[rep])
        b = hit[np.searchsorted(rep[hit], np.arange(n))]
        kb = k[b]
        return (edge[b], cols["cum0"][kb] + u[b] * cols["slen"][kb], ax[b] + u[b] * dx[b], ay[b] + u[b] * dy[b],
                d[b], pref[b])
