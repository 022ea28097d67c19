"""The network tracker: where on the network an entity is, fix by fix (reference section 4.5, placement).

It holds the tracking state (the path being followed, the along-path filter, or the area and its plane
filter; the hysteresis against flapping between parallel ways; the recent path coordinates; re-acquisition
after a jump) and answers one question per fix: which event the fix was for the tracking (a first placement,
a jump, a change of path, off the network, or nothing). The Player decides what to publish from it; the
tracker publishes nothing. `Path` and `Placer` stay passive helpers it drives.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from struct import Struct

from entitynet.client.entities import EntityType
from entitynet.client.filters import Kinematic1D, RowKinematic
from entitynet.client.modes import AREA, EDGE, Place
from entitynet.client.network import NetView
from entitynet.client.path import Path, follow
from entitynet.client.placement import Fix, Placer
from entitynet.client.route import Route
from entitynet.client.row_fields import _RS, TrackerState
from entitynet.client.state import F_COL, I_COL, PATH_W, Record

_KS, _LF_OFF, _DIST_EMA, _REACH, _VPEAK = (F_COL[n] for n in ("ks", "lf_off", "dist_ema", "reach", "vpeak"))
_READ_SVA_T = Struct("=3d48xd")  # ks, kv, ka, (p00 .. p22,) kt: adjacent columns (filters.py checks the order)
_PEND_E, _LF_KIND = I_COL["pend_e"], I_COL["lf_kind"]
assert (I_COL["pend_n"], I_COL["lf_e"]) == (_PEND_E + 1, _LF_KIND + 1)
assert [F_COL[n] - _LF_OFF for n in ("lf_x", "lf_y", "lf_d")] == [1, 2, 3] and F_COL["vpeak_t"] == _VPEAK + 1

MAX_PATH_EDGES = PATH_W
DOPPLER_MOVING = 1.0  # m/s: a Doppler velocity at least this fast has a direction worth checking
#: a moving Doppler velocity whose component along the way is below this share of its speed is mostly across the
#: way: the fix is not taken as a move along it (the scalar tracker and the fleet's arrays both read it here)
DOPPLER_ALONG_SHARE = 0.7
# choosing among the path's edges: an along-path jump of ALONG_SCALE metres from the prediction costs as
# much as one metre off the way (the prediction is good to a few metres; the fix only to its accuracy)
ALONG_SCALE = 3.0


def placer_for(net: NetView, networks: int) -> Placer:
    """One Placer (and its segment-table cache) per topology view and network mask, shared by players."""
    cache = net.__dict__.setdefault("_placers", {})
    p = cache.get(networks)
    if p is None:
        p = cache[networks] = Placer(net, networks)
    return p


class NetworkTracker(TrackerState):
    """Placement with continuity and hysteresis, the along-path filter `kf` on an edge and the plane filters
    `kx`, `ky` in an area (only when `area_filter`: the world-frame baselines keep their own), the path
    trimmed behind and extended ahead (by the route where known, else the straightest way).

    The tracking state the fleet core also works on (the filter, the path, the recent fixes, the hysteresis
    counters, the last fix) lives in a client-state row (entitynet/client/state.py: `state`, or a record of
    its own), read and written through the properties below; the options and the area state are attributes.

    `written_out`: take `_track_on` (the usual fix written out) instead of `_track`'s general code for it."""

    def __init__(self, net: NetView, etype: EntityType, route: Route, *, body: float, margin: float,
                 lookahead: float, off_network: float, lateral: float, route_margin: float,
                 filter_q: float, filter_accel: bool, area_filter: bool, written_out: bool = True,
                 state: tuple[Record, int] | None = None) -> None:
        self._kf = RowKinematic()
        st = state if state is not None else (Record(1), 0)
        if state is None:
            st[0].new_row()
        self.bind(*st)
        self.net = net
        self.etype = etype
        self.placer = placer_for(net, etype.networks)
        # how far along the path from the prediction a fix may map before it is a jump (start afresh there):
        # the placer's `reacquire`, or what the type covers at its vmax in the feed's usual fix interval
        # (the Player sets it; a bus feed's fixes 32 s apart are 200 m apart)
        self.reach = self.placer.reacquire
        self.route = route
        self.has_route = bool(route)  # (a plain attribute: asked on every fix)
        self.body, self.margin, self.lookahead = body, margin, lookahead
        self.off_network, self.lateral = off_network, lateral
        # a route is a-priori knowledge: leaving it needs much stronger evidence than changing street
        self.switch_margin = route_margin if route else None
        self.switch_count = 3 if route else None
        self.filter_q, self.filter_accel = filter_q, filter_accel
        self.area_filter = area_filter
        self.written_out = written_out
        self.place: Place | None = None
        self.path = None
        self.kf = None
        self.area = -1
        self.kx: Kinematic1D | None = None
        self.ky: Kinematic1D | None = None
        self.pending = (-1, 0)
        self.dead_end = None
        self.dist_ema = 0.0
        self.reverse_count = 0
        self.recent_s = []  # path coordinates of the last few fixes, for a standing position
        self.vpeak = 0.0
        self.vpeak_t = -math.inf
        self.last_fix = None

    def follow_cadence(self, interval: float) -> None:
        """The feed's usual fix interval (s) changed: a fix may map as far along the path from the prediction
        as the type covers at its vmax in one interval before it is a jump (the fleet core's
        `fleet_kernels.interval_rows` repeats this)."""
        self.reach = max(self.placer.reacquire, self.etype.vmax * interval)

    def forget(self) -> None:
        """Drop the state of a lost entity: its next fix is placed afresh."""
        self.place = None
        self.path = None
        self.kf = self.kx = self.ky = None
        _RS.clear(self)

    def fuse_velocity(self, vel: tuple[float, float, float]) -> None:
        """The network state takes the velocity's component along the path where the fix landed (areas: both
        components). A moving velocity mostly across the path (a turn, or the path's other leg where it passes
        the same place twice) says nothing reliable about the speed along it and is left out; so is one against
        an a-priori route, which the entity does not reverse on."""
        vx, vy, rv = vel
        if self.place is EDGE:
            path = self.path
            s = self.recent_s[-1] if self.recent_s else self.kf.s
            hx, hy = path.xy(min(s + 1.0, path.length))
            bx, by = path.xy(max(s - 1.0, 0.0))
            n = math.hypot(hx - bx, hy - by)
            if not n > 0.0:
                return
            along = (vx * (hx - bx) + vy * (hy - by)) / n
            speed = math.hypot(vx, vy)
            across = abs(along) < DOPPLER_ALONG_SHARE * speed
            if speed >= DOPPLER_MOVING and (across or (self.has_route and along < 0.0)):
                return
            self.kf.update_speed(along, rv)
        elif self.place is AREA:
            self.kx.update_speed(vx, rv)
            self.ky.update_speed(vy, rv)

    def face_travel(self) -> None:
        """Before a publish: turn the path to the direction of travel when the filter says the entity goes
        backwards along it, whatever the hysteresis of `track` says (never on an a-priori route)."""
        if self.place is EDGE and not self.has_route and self.kf is not None and self.kf.v < -self.etype.v_stop:
            self._reverse()
            self._maintain_path()

    # ---- one fix -----------------------------------------------------------------------------------------
    def _init_at(self, fix: Fix, t: float, r: float) -> None:
        self.last_fix = fix
        if fix.kind == "area":
            self.place, self.area = AREA, fix.index
            self.path = None
            if self.area_filter:
                self.kx = Kinematic1D(fix.x, t, r, q=1.0, accel=False)
                self.ky = Kinematic1D(fix.y, t, r, q=1.0, accel=False)
            return
        self.place = EDGE
        de = (fix.index, 1)
        i = self.route.first.get(de, self.route.first.get((fix.index, -1)))
        if i is not None:
            de = self.route.edges[i]
        s = self.net.dist_of(de, fix.offset)
        behind: list = []
        if i is not None:
            # the body (and its margin) reaches back past the edge's start: the route says which way it
            # came, so the path starts far enough back for the occupation to list the cells under the aft
            # (a tram re-placed just past a node otherwise publishes no cell for most of its length)
            need, j = self.body + self.margin - s, i
            while need > 0.0 and j > 0:
                j -= 1
                behind.append(self.route.edges[j])
                need -= self.net.edge_len[self.route.edges[j][0]]
            behind.reverse()
        self.path = Path(self.net, behind + [de])
        s += self.path.cum[len(behind)]
        _RS.clear(self)
        self._start_filter(s, t, r)
        self.pending = (-1, 0)
        self.dead_end = None
        self._maintain_path()  # a publish right after a (re)placement needs the way ahead too

    def _area_update(self, x: float, y: float, t: float, r: float) -> None:
        if self.area_filter:
            self.kx.update(x, t, r)
            self.ky.update(y, t, r)

    def track(self, x: float, y: float, t: float, r: float, published: bool) -> str | None:
        """One fix (r: its variance). Returns "off" (too far from the network), "first" or "jump" (placed
        afresh; "first" while nothing is published), "path" (another way: an area entered or left, a turn,
        a reversal) or None (continued on the path or in the area)."""
        placer, place = self.placer, self.place
        if place is None:
            fix = self._first(x, y)
            if fix is None or fix.distance > self.off_network:
                return "off"
            self._init_at(fix, t, r)
            return "first" if not published else "jump"
        if place is AREA:
            if placer.inside_area(self.area, x, y):
                self._area_update(x, y, t, r)
                return None
            fix = placer.first(x, y)
            if fix is None or fix.distance > self.off_network:
                return "off"
            if fix.kind == "edge" and placer.holds_area(self.area, x, y, fix.distance, self.lateral):
                self._area_update(x, y, t, r)  # GPS noise just outside the area, no way nearer: still inside
                return None
            self._init_at(fix, t, r)
            return "path"
        # on an edge (the filter's s, v, a, t read from the row at once)
        path = self.path
        ks, kv, ka, kt = _READ_SVA_T.unpack_from(self._st.f, 8 * (self._fb + _KS))
        dt = t - kt if t > kt else 0.0
        s_pred = ks + kv * dt + 0.5 * ka * dt * dt
        edges = path.edges
        k_cur = bisect_right(path.cum, s_pred) - 1  # `path.index` written out
        if k_cur < 0:
            k_cur = 0
        elif k_cur >= len(edges):
            k_cur = len(edges) - 1
        e_cur = edges[k_cur][0]
        net = self.net
        # fast path: a fix within the switch margin of the current edge, away from its ends, cannot be won
        # by another edge (they all start `switch_margin` behind), so the neighbourhood search is skipped
        cur = placer.project_on(x, y, e_cur)
        margin = placer.switch_margin if self.switch_margin is None else self.switch_margin
        dist = cur[5]  # (cur.distance, cur.offset: the Fix's fields by index on the hot path)
        if (dist <= margin and 0.0 < cur[2] < net.edge_len[e_cur]
                and net.node_area[net.edge_from[e_cur]] < 0 and net.node_area[net.edge_to[e_cur]] < 0):
            if dist <= placer.reacquire and self.written_out:
                return self._track_on(cur, e_cur, k_cur, s_pred, t, r, path)
            fix, best_pref = cur, cur.distance
            preferred = None
        else:
            lo = path.index(s_pred - self.body - 30.0)
            hi = path.index(s_pred + 60.0)
            preferred = {path.edges[k][0] for k in range(lo, hi + 1)}
            fix, best_pref = placer.near(x, y, e_cur, preferred, margin)
            if (fix.kind == "edge" and fix.index in preferred and len(preferred) > 1
                    and abs(self._s_of(fix, s_pred, k_cur) - s_pred) > 2.0 * math.sqrt(r)):
                # the nearest edge of the path puts the fix far along it: another edge may fit better
                fix = self._best_on(x, y, s_pred, lo, hi)
        entering = None
        if fix.kind == "area":
            # a way along an area's edge: one noisy fix inside the area is not an entry. Enter when the fix is
            # farther from the path's ways than GPS noise goes (3 x accuracy), or `switch_count` fixes in a row
            on_way = self._best_on(x, y, s_pred, lo, hi)
            cand, count = self.pending
            count = count + 1 if cand == -2 - fix.index else 1
            need = placer.switch_count if self.switch_count is None else self.switch_count
            if count >= need or on_way.distance > 3.0 * math.sqrt(r):
                self._init_at(fix, t, r)
                return "path"
            fix, preferred, entering = on_way, None, (-2 - fix.index, count)
        if fix.distance > placer.reacquire:
            g = self._first(x, y)
            if g is None or g.distance > self.off_network:
                return "off"
            self._init_at(g, t, r)
            return "jump"
        reason = None
        if preferred is not None and fix.index not in preferred:
            cand, count = self.pending
            count = count + 1 if cand == fix.index else 1
            self.pending = (fix.index, count)
            need = placer.switch_count if self.switch_count is None else self.switch_count
            if count >= need or not math.isfinite(best_pref):
                if self._reroute(fix, s_pred):
                    reason = "path"
                else:
                    self._init_at(fix, t, r)
                    return "jump"
            else:
                # hysteresis: stay on the expected edges for now
                fix = self._best_on(x, y, s_pred, lo, hi)
        else:
            self.pending = (-1, 0) if entering is None else entering
        self.last_fix = fix
        # consistency: fixes that stay far from the edge we hold mean we hold the wrong one (a first fix on
        # the wrong street, or the hysteresis kept us there): ask the placement index again
        self.dist_ema = 0.7 * self.dist_ema + 0.3 * fix.distance
        # (a fix within the margin cannot be beaten by g.distance + margin, g.distance >= 0: no need to ask)
        if self.dist_ema > 1.5 * math.sqrt(r) and reason is None and fix.distance > margin:
            g = self._first(x, y)
            if g is not None and g.kind == "area":  # inside an area the neighbourhood search does not see
                self._init_at(g, t, r)
                return "path"
            if g is not None and g.kind == "edge" and g.index != fix.index and g.distance + margin < fix.distance:
                self._init_at(g, t, r)
                self.dist_ema = g.distance
                return "jump"
        s_meas = self._s_of(fix, s_pred, k_cur)
        if abs(s_meas - s_pred) > self.reach:
            self._init_at(fix, t, r)  # the measurement maps far along the path: start afresh there
            return "jump"
        if reason is not None:
            _RS.clear(self)
        _RS.push(self, s_meas)
        kf = self._kf  # (on an edge: the row's filter is on)
        _s, v = kf.update_sv(s_meas, t, r)
        if v > self.vpeak or t - self.vpeak_t > 120.0:
            self.vpeak, self.vpeak_t = v, t
        backwards = not self.has_route and v < -self.etype.v_start and v + kf.speed_sigma() < 0.0
        self.reverse_count = self.reverse_count + 1 if backwards else 0
        if self.reverse_count >= 3:
            self._reverse()
            reason = reason or "path"
        self._maintain_path()
        return reason

    def _track_on(self, fix: Fix, e_cur: int, k_cur: int, s_pred: float, t: float, r: float,
                  path: Path) -> str | None:
        """The rest of `track` for the usual fix (on the predicted edge, inside the switch margin, within
        `reacquire`): the same steps with `_s_of`'s first case and the bookkeeping written out.

        A measured fast path, kept because it is worth more than 10 % of fixes/s: `dr_bench.fixes_per_second`
        on the quick datasets (Helsinki, 6 HSL vehicles, 6 pedestrians), with and without it, alternating, 3
        rounds each, medians: vehicles 24.0k against 20.3k fixes/s (+18 %), pedestrians 13.9k against 12.7k
        (+10 %). test_fast_paths.py checks it against the general code (`written_out=False`) bit for bit."""
        # pending = (-1, 0), last_fix = fix, and the moving mean of the distance: written to the row by index
        st, fb = self._st, self._fb
        i, ib = st.i, self._ib
        i[ib + _PEND_E], i[ib + _PEND_E + 1] = -1, 0
        i[ib + _LF_KIND], i[ib + _LF_KIND + 1] = 1, fix[1]  # (an edge fix)
        f = st.f
        c = fb + _LF_OFF
        f[c], f[c + 1], f[c + 2], f[c + 3] = fix[2], fix[3], fix[4], fix[5]
        # the consistency check of `track` cannot jump here: it needs g.distance + margin < fix.distance, and
        # this fix is within the margin (so the placement index is not asked)
        f[fb + _DIST_EMA] = 0.7 * f[fb + _DIST_EMA] + 0.3 * fix[5]
        # `_s_of(fix, s_pred, k_cur)`: the fix is on edges[k_cur]; unless the edge recurs within 3 edges
        if path.edge_ids()[k_cur - 3 if k_cur > 3 else 0 : k_cur + 4].count(e_cur) == 1:
            off = fix[2]
            s_meas = path.cum[k_cur] + (off if path.edges[k_cur][1] > 0 else self.net.edge_len[e_cur] - off)
        else:
            s_meas = self._s_of(fix, s_pred, k_cur)
        if abs(s_meas - s_pred) > f[fb + _REACH]:
            self._init_at(fix, t, r)  # the measurement maps far along the path: start afresh there
            return "jump"
        _RS.push(self, s_meas)
        kf = self._kf
        s, v = kf.update_sv(s_meas, t, r)
        if v > f[fb + _VPEAK] or t - f[fb + _VPEAK + 1] > 120.0:  # vpeak, vpeak_t
            f[fb + _VPEAK], f[fb + _VPEAK + 1] = v, t
        reason = None
        if self.has_route:
            self.reverse_count = 0
        else:
            backwards = v < -self.etype.v_start and v + kf.speed_sigma() < 0.0
            self.reverse_count = self.reverse_count + 1 if backwards else 0
            if self.reverse_count >= 3:
                self._reverse()
                reason = "path"
                s, v, path = kf.s, kf.v, self.path
        # `_maintain_path` changes nothing unless the path is to be trimmed or is short of what is needed ahead
        cum = path.cum
        if ((len(cum) > 2 and s - (self.body + self.margin + 50.0) > cum[1])
                or (cum[-1] < s + self.lookahead + self.margin + 80.0 + 15.0 * (v if v > 0.0 else 0.0)
                    and len(path.edges) < MAX_PATH_EDGES and path.edges[-1] != self.dead_end)):
            self._maintain_path()
        return reason

    # ---- the path --------------------------------------------------------------------------------------------
    def _reverse(self) -> None:
        """Turn the path around (the entity walks the other way): s -> length - s, v -> -v."""
        self.reverse_count = 0
        self.path = self.path.reversed()
        self.kf.flip(self.path.length)
        self.recent_s = [self.path.length - x for x in self.recent_s]

    def _first(self, x: float, y: float) -> Fix | None:
        """First placement: on the a-priori route when it is near (its edges win over a closer other
        street within `route_margin`), else the placement index."""
        if self.has_route:
            f = self.placer.on_edges(x, y, [e for e, _d in self.route.edges])
            if f.distance <= self.off_network:
                g = self.placer.first(x, y)
                if g is None or f.distance <= g.distance + (self.switch_margin or 0.0):
                    return f
        return self.placer.first(x, y)

    def _best_on(self, x: float, y: float, s_pred: float, lo: int, hi: int) -> Fix:
        """The fix on the path edges lo..hi that best explains both the fix and the prediction: lateral
        distance plus the along-path jump from `s_pred`, each against its noise. Where the path passes near
        itself (a hairpin, a triangle of footways, a short link between parallel sidewalks) the nearest edge
        is often a piece of the path 10-30 m behind or ahead; taking it drags the filter back and forth."""
        placer, path = self.placer, self.path
        w = 1.0 / (ALONG_SCALE * ALONG_SCALE)
        best, best_cost = None, math.inf
        seen: set[int] = set()
        for k in range(lo, hi + 1):
            de = path.edges[k]
            e = de[0]
            if e in seen:
                continue
            seen.add(e)
            f = placer.project_on(x, y, e)
            ds = self._s_of(f, s_pred, k) - s_pred
            cost = f.distance * f.distance + w * ds * ds
            if cost < best_cost:
                best, best_cost = f, cost
        return best

    def _s_of(self, fix: Fix, s_pred: float, k_hint: int = 0) -> float:
        """Path coordinate of an edge fix: the occurrence of its edge nearest to the prediction."""
        path = self.path
        edges = path.edges
        n = len(edges)
        # the usual case: the edge at (or next to) the predicted one, and no other occurrence nearby
        e = fix.index
        for k in (k_hint, k_hint + 1, k_hint - 1):
            if 0 <= k < n and edges[k][0] == e:
                for j in range(max(k - 3, 0), min(k + 4, n)):
                    if j != k and edges[j][0] == e:
                        break
                else:
                    d = edges[k][1]
                    return path.cum[k] + (fix.offset if d > 0 else self.net.edge_len[e] - fix.offset)
                break
        best, best_d = None, math.inf
        for k, de in enumerate(edges):
            if de[0] != fix.index:
                continue
            s = path.cum[k] + self.net.dist_of(de, fix.offset)
            if abs(s - s_pred) < best_d:
                best, best_d = s, abs(s - s_pred)
        return s_pred if best is None else best

    def _reroute(self, fix: Fix, s_pred: float) -> bool:
        """Join a newly chosen edge to the path at a node near the prediction; False if it does not touch."""
        net, path = self.net, self.path
        ends = (net.edge_from[fix.index], net.edge_to[fix.index])
        k0 = path.index(s_pred)
        order = sorted(range(len(path.edges)), key=lambda k: (abs(k - k0), k))
        reach = 30.0 + self.body  # joints, and the fix on the joined edge, are this near the prediction
        for k in order[:8]:
            de = path.edges[k]
            for node, keep in ((net.end_node(de), k + 1), (net.start_node(de), k)):
                if abs(path.cum[keep] - s_pred) > reach:
                    continue  # a joint far along the path (a loop): not where the entity is
                if node in ends:
                    d = 1 if net.edge_from[fix.index] == node else -1
                    if keep > 0 and path.edges[keep - 1] == (fix.index, -d):
                        continue
                    if abs(path.cum[keep] + net.dist_of((fix.index, d), fix.offset) - s_pred) > reach:
                        continue  # the fix would land far along the path from the prediction: a detour
                    new = path.edges[:keep] + [(fix.index, d)]
                    if keep == 0:
                        return False
                    self.path = Path(net, new)
                    self.pending = (-1, 0)
                    return True
            if abs(path.cum[k + 1] - s_pred) > reach:
                continue
            for mid in net.choices(de, self.etype.networks):
                if net.end_node(mid) in ends:
                    node = net.end_node(mid)
                    d = 1 if net.edge_from[fix.index] == node else -1
                    s_fix = path.cum[k + 1] + net.edge_len[mid[0]] + net.dist_of((fix.index, d), fix.offset)
                    if abs(s_fix - s_pred) > reach:
                        continue
                    self.path = Path(net, path.edges[: k + 1] + [mid, (fix.index, d)])
                    self.pending = (-1, 0)
                    return True
        return False

    def _maintain_path(self) -> None:
        """Keep enough path behind (the body and margin) and ahead (lookahead and extrapolation)."""
        path, kf = self.path, self.kf
        behind = self.body + self.margin + 50.0
        cum = path.cum
        if len(cum) > 2 and kf.s - behind > cum[1]:
            newp, shift = path.trimmed(kf.s - behind)
            if shift > 0.0:
                self.path = path = newp
                kf.shift(shift)
                self.recent_s = [x - shift for x in self.recent_s]
        v = kf.v
        need = kf.s + self.lookahead + self.margin + 80.0 + 15.0 * (v if v > 0.0 else 0.0)
        if path.cum[-1] < need and len(path.edges) < MAX_PATH_EDGES and path.edges[-1] != self.dead_end:
            last = path.edges[-1]
            ahead = follow(self.net, last, self.etype.networks, need - path.length, self.route.edges,
                           self.route.index(last), max_edges=MAX_PATH_EDGES - len(path.edges))
            if ahead:
                self.path = path.extended(ahead)
            else:
                self.dead_end = last  # nothing follows this edge: do not ask again every fix
