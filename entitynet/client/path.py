"""A path: consecutive directed edges with a 1D coordinate `s` (metres from the start of the first edge).

Network dead reckoning, cell occupation and receivers all work on this one coordinate, so an entity longer
than a chain of short edges, a hairpin, or junction cells back to back need no special cases: the body is
the interval [s - length, s] of the path.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence

from entitynet.client.network import DirEdge, NetView

try:  # `Path.xy` compiled, where pip built it (setup.py; optional)
    from entitynet.client import _geom as _COMPILED  # type: ignore[attr-defined]
except ImportError:  # the pure method below
    _COMPILED = None


class Path:
    """Consecutive directed edges with one coordinate s, so that long bodies, hairpins and short edges
    need no special cases. Paths are not changed in place (cached ids and cumulative lengths stay valid)."""
    __slots__ = ("net", "edges", "cum", "_ids", "_sub", "_sub_k")

    def __init__(self, net: NetView, edges: Sequence[DirEdge], *, _cum: list[float] | None = None) -> None:
        self._ids: list[int] | None = None
        self._sub: Path | None = None  # the last `suffix` made (from edge `_sub_k`): a publish asks it again
        self._sub_k: int | None = None
        if _cum is not None:  # a slice of a path already checked: no validation needed
            self.net, self.edges, self.cum = net, list(edges), _cum
            return
        if not edges:
            raise ValueError("a path needs at least one edge")
        self.net = net
        self.edges: list[DirEdge] = [(int(e), 1 if d > 0 else -1) for e, d in edges]
        cum = [0.0]
        for e, _ in self.edges:
            if not 0 <= e < net.n_edges:
                raise ValueError(f"edge {e} is not in the topology")
            cum.append(cum[-1] + net.edge_len[e])
        self.cum = cum
        for a, b in zip(self.edges, self.edges[1:], strict=False):
            if net.end_node(a) != net.start_node(b):
                raise ValueError(f"path edges {a} and {b} do not meet at a node")

    @property
    def length(self) -> float:
        """Total length in metres (the last cumulative length): `xy` and `cell` clamp s to [0, length]."""
        return self.cum[-1]

    def edge_ids(self) -> list[int]:
        """The undirected edge ids in path order (computed once per path: paths are not changed in place)."""
        ids = self._ids
        if ids is None:
            ids = self._ids = [e for e, _d in self.edges]
        return ids

    def index(self, s: float) -> int:
        """Index of the edge holding s (clamped to the path)."""
        k = bisect_right(self.cum, s) - 1
        if k < 0:
            return 0
        n = len(self.edges)
        return k if k < n else n - 1

    def locate(self, s: float) -> tuple[int, float]:
        """(edge, offset on that edge) at path coordinate s, clamped to the path."""
        cum = self.cum
        k = bisect_right(cum, s) - 1
        if k < 0:
            k = 0
        elif k >= len(self.edges):
            k = len(self.edges) - 1
        e, d_ = self.edges[k]
        length = self.net.edge_len[e]
        d = s - cum[k]
        d = 0.0 if d < 0.0 else (length if d > length else d)
        return e, (d if d_ > 0 else length - d)

    def xy(self, s: float) -> tuple[float, float]:
        """Local (x, y) at path coordinate s, clamped to the path; `locate` and `NetView.point` written out
        because it runs twice per fix."""
        cum = self.cum
        k = bisect_right(cum, s) - 1
        if k < 0:
            k = 0
        elif k >= len(self.edges):
            k = len(self.edges) - 1
        e, d_ = self.edges[k]
        net = self.net
        length = net.edge_len[e]
        d = s - cum[k]
        d = 0.0 if d < 0.0 else (length if d > length else d)
        offset = d if d_ > 0 else length - d
        geom_off = net.geom_off
        lo, hi = geom_off[e], geom_off[e + 1]
        if offset <= 0.0:
            return net.gx[lo], net.gy[lo]
        gcum = net.gcum
        if offset >= gcum[hi - 1]:
            return net.gx[hi - 1], net.gy[hi - 1]
        if hi - lo == 2:  # one segment: the bisection below can only give lo
            k = lo
        else:
            k = bisect_right(gcum, offset, lo, hi) - 1
            k = min(max(k, lo), hi - 2)
        c0 = gcum[k]
        seg = gcum[k + 1] - c0
        t = 0.0 if seg <= 0.0 else (offset - c0) / seg
        gx, gy = net.gx, net.gy
        x0, y0 = gx[k], gy[k]
        return x0 + t * (gx[k + 1] - x0), y0 + t * (gy[k + 1] - y0)

    def cell(self, s: float) -> int:
        """Visibility cell at path coordinate s, clamped to the path; `locate` and `NetView.cell_at`
        written out because it runs several times per publish."""
        cum = self.cum
        k = bisect_right(cum, s) - 1
        if k < 0:
            k = 0
        elif k >= len(self.edges):
            k = len(self.edges) - 1
        e, d_ = self.edges[k]
        net = self.net
        length = net.edge_len[e]
        d = s - cum[k]
        d = 0.0 if d < 0.0 else (length if d > length else d)
        off = d if d_ > 0 else length - d
        lo, hi = net.bp_off[e], net.bp_off[e + 1]
        j = bisect_right(net.bp_start, off, lo, hi) - 1
        return net.bp_cell[j if j > lo else lo]

    def starts_in(self, s0: float, s1: float) -> list[tuple[float, int]]:
        """(s, cell) of every cell piece that starts in (s0, s1], in order of travel."""
        out: list[tuple[float, int]] = []
        k = self.index(s0)
        edges, cum, pieces = self.edges, self.cum, self.net.pieces
        n = len(edges)
        while k < n and cum[k] <= s1:
            base = cum[k]
            e, d = edges[k]
            for a, _b, c in pieces(e, d):
                sa = base + a
                if sa > s1:
                    break
                if sa > s0:
                    out.append((sa, c))
            k += 1
        return out

    def cover_cells(self, start: float, reach: float, cover_end: float) -> list[int]:
        """Cells of [start, cover_end) and of the body (start, reach], in order, without repeats: the cell at
        `start`, then those of `starts_in(start, max(reach, cover_end))` with sa <= reach or sa < cover_end
        (that loop written out, without its list)."""
        cells = [self.cell(start)]
        s1 = cover_end if cover_end > reach else reach  # max(reach, cover_end)
        k = self.index(start)
        edges, cum, pieces = self.edges, self.cum, self.net.pieces
        n = len(edges)
        while k < n and cum[k] <= s1:
            base = cum[k]
            e, d = edges[k]
            for a, _b, c in pieces(e, d):
                sa = base + a
                if sa > s1:
                    break
                if sa > start and (sa <= reach or sa < cover_end) and c not in cells:
                    cells.append(c)
            k += 1
        return cells

    def cells_between(self, s0: float, s1: float) -> list[int]:
        """Cells met along [s0, s1] (clamped to the path), in order of travel, without repeats."""
        s0 = min(max(s0, 0.0), self.length)
        s1 = min(max(s1, s0), self.length)
        out = [self.cell(s0)]
        for _s, c in self.starts_in(s0, s1):
            if c not in out:
                out.append(c)
        return out

    def boundaries_after(self, s: float, limit: float) -> list[tuple[float, int]]:
        """(s_boundary, cell entered) for every change of cell in (s, min(limit, length)]."""
        prev = self.cell(s)
        out: list[tuple[float, int]] = []
        for sa, c in self.starts_in(s, min(limit, self.length)):
            if c != prev:
                out.append((sa, c))
                prev = c
        return out

    def suffix(self, k: int) -> Path:
        """The path from edge k on (s shifts by cum[k]); no re-validation. Paths are not changed in place, so
        the path itself is its suffix from edge 0 (where cum[0] is 0.0: c - 0.0 is c), and the last suffix made
        is kept and handed out again (a publish asks for the same one while the tracker's path stays: issue 22)."""
        if k == 0 and self.cum[0] == 0.0:
            return self
        if self._sub_k == k:
            return self._sub
        c0 = self.cum[k]
        path = self._sub = Path(self.net, self.edges[k:], _cum=[c - c0 for c in self.cum[k:]])
        self._sub_k = k  # (two fields, not a (k, path) tuple: one object less for the collector a publish)
        return path

    def part_from(self, s: float) -> tuple[Path, float]:
        """The path from the edge holding s on (`suffix(index(s))`) and its shift of s (`cum` there): what a
        publish sends."""
        k = self.index(s)
        return self.suffix(k), self.cum[k]

    def first_boundary_after(self, s: float, limit: float) -> float | None:
        """The first cell change in (s, min(limit, length)], or None (stops at the first one found)."""
        prev = self.cell(s)
        limit = min(limit, self.length)
        k = self.index(s)
        edges, cum, pieces = self.edges, self.cum, self.net.pieces
        n = len(edges)
        while k < n and cum[k] <= limit:
            base = cum[k]
            e, d = edges[k]
            for a, _b, c in pieces(e, d):
                sa = base + a
                if sa > limit:
                    return None
                if sa > s and c != prev:
                    return sa
            k += 1
        return None

    def extended(self, ahead: Sequence[DirEdge]) -> Path:
        """This path plus `ahead`; only the new joints are checked."""
        net = self.net
        ahead = [(int(e), 1 if d > 0 else -1) for e, d in ahead]
        cum = list(self.cum)
        prev = self.edges[-1]
        for de in ahead:
            if not 0 <= de[0] < net.n_edges or net.end_node(prev) != net.start_node(de):
                raise ValueError(f"path edges {prev} and {de} do not meet at a node")
            cum.append(cum[-1] + net.edge_len[de[0]])
            prev = de
        return Path(net, self.edges + ahead, _cum=cum)

    def reversed(self) -> Path:
        """The same way travelled the other way (s becomes length - s): for an entity that turns round. A path's
        edges meet end to start, so turned round they do too: no check again, the lengths summed afresh in the
        new order as the checking constructor sums them (`reversed_reference`)."""
        edge_len = self.net.edge_len
        edges = [(e, -d) for e, d in reversed(self.edges)]
        cum = [0.0]
        c = 0.0
        for e, _d in edges:
            c = c + edge_len[e]
            cum.append(c)
        return Path(self.net, edges, _cum=cum)

    def trimmed(self, keep_from: float) -> tuple[Path, float]:
        """Drop whole edges that end before `keep_from`; returns the new path and the shift of s."""
        k = self.index(keep_from)
        if k == 0:
            return self, 0.0
        return self.suffix(k), self.cum[k]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Path) and other.net is self.net and other.edges == self.edges

    def __hash__(self) -> int:
        return hash(tuple(self.edges))

    def __repr__(self) -> str:
        return f"Path({self.edges!r})"


def reversed_reference(path: Path) -> Path:
    """`Path.reversed` through the checking constructor (tests hold the two equal)."""
    return Path(path.net, [(e, -d) for e, d in reversed(path.edges)])


xy_reference = Path.xy  # the pure `Path.xy` (tests hold the compiled one equal to it)
if _COMPILED is not None:
    Path.xy = _COMPILED.path_xy  # type: ignore[method-assign]


def follow(net: NetView, start: DirEdge, networks: int, distance: float,
           route: Sequence[DirEdge] | None = None, route_index: int | None = None,
           max_edges: int = 256) -> list[DirEdge]:
    """Directed edges after `start` covering `distance` metres: the route when known, else the junction rule.

    `route_index` is the position of `start` in `route`. Stops early at dead ends and area nodes.
    """
    out: list[DirEdge] = []
    cur = start
    ri = route_index
    gone = 0.0
    while gone < distance and len(out) < max_edges:
        nxt: DirEdge | None = None
        if route is not None and ri is not None and ri + 1 < len(route):
            cand = route[ri + 1]
            if net.start_node(cand) == net.end_node(cur):
                nxt = cand
                ri += 1
            else:
                ri = None
        elif ri is not None:
            ri = None
        if nxt is None:
            nxt = net.next_edge(cur, networks)
        if nxt is None:
            break
        out.append(nxt)
        gone += net.edge_len[nxt[0]]
        cur = nxt
    return out
