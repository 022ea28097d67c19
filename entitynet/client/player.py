"""The Player: an honest client's sans-IO core (reference section 4.5).

Fed GPS fixes (`feed`) and the time (`tick`), it keeps its measured and inferred positions, extrapolates its
own published model exactly as every receiver does (its ghost: the decoded payload), and returns the
`Publish` messages to send:
- `first`, `jump`: first placement, or a re-acquisition far from the predicted place;
- `drift`: the ghost is more than `threshold` metres from the filtered estimate;
- `stop` / `start`: emergent behaviour the extrapolation cannot know;
- `path`: the entity left the predicted path (turned at a junction, reversed, entered or left an area);
- `expiry`: the occupation's validity period ran out;
- `heartbeat`: nothing else was sent for `heartbeat` seconds;
- `gap`: no fix for `max_gap` seconds: the guess stops where it got to and a standing model is published
  (and re-published standing on expiry); after `lost_after` seconds without a fix the entity is unpublished
  (defaults per entity type; entitynet/client/limits.py says why).

`model` selects what is published: "network" (path-constrained dead reckoning, the default), or the
world-frame baselines "fpw", "fvw" and "periodic" (a position every `period` seconds). With no topology
only the world-frame models work and no cells are published.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

from entitynet.client.entities import EntityType, entity_type
from entitynet.client.filters import Kinematic1D
from entitynet.client.frozen import maker
from entitynet.client.limits import HORIZON, max_speed
from entitynet.client.motion import AreaModel, Model, NetworkModel, WorldModel
from entitynet.client.network import DirEdge, NetView, netview
from entitynet.client.occupation import Occupation, make_occupation, occupy, occupy_area, wire_validity
from entitynet.client.path import Path, follow
from entitynet.client.payload import encode_network, encode_quantized
from entitynet.client.placement import Fix, Placer, ring_distance
from entitynet.protocol import Publish, Unpublish

MODELS = ("network", "fpw", "fvw", "periodic")
MAX_PUBLISH_CELLS = 64
MAX_PATH_EDGES = 48
DOPPLER_MOVING = 1.0  # m/s: a Doppler velocity at least this fast has a direction worth checking
# choosing among the path's edges: an along-path jump of ALONG_SCALE metres from the prediction costs as
# much as one metre off the way (the prediction is good to a few metres; the fix only to its accuracy)
ALONG_SCALE = 3.0


def _with_cells(occ: Occupation, cells: tuple[int, ...]) -> Occupation:
    """`dataclasses.replace(occ, cells=cells)` without its generic field walk (once per publish)."""
    return make_occupation(cells, occ.validity, occ.front_period, occ.aft_period, occ.cover_start, occ.cover_end)


_make_publish = maker(Publish)  # Publish(...) without the frozen dataclass __init__ (once per publish)


def _wire(occ: Occupation) -> Occupation:
    """The occupation with its validity as the PUBLISH carries it (`wire_validity`)."""
    v = wire_validity(occ.validity)
    if v == occ.validity:
        return occ
    return Occupation(occ.cells, v, occ.front_period, occ.aft_period, occ.cover_start, occ.cover_end)


class FixRejected(ValueError):
    """A fix that cannot be used: NaN/inf, time not after the previous fix, or a bad accuracy."""


def placer_for(net: NetView, networks: int) -> Placer:
    """One Placer (and its segment-table cache) per topology view and network mask, shared by players."""
    cache = net.__dict__.setdefault("_placers", {})
    p = cache.get(networks)
    if p is None:
        p = cache[networks] = Placer(net, networks)
    return p


class Player:
    FAST_TRACK = True  # `_track_on` for the usual fix (False: the general code below it, the test's reference)

    def __init__(
        self,
        topo,
        entity: int,
        etype: str | EntityType,
        *,
        model: str = "network",
        route: Sequence[Sequence[int]] | None = None,
        stops: Sequence[tuple[int, float]] = (),
        accuracy: float = 5.0,
        threshold: float | None = None,
        margin: float | None = None,
        lookahead: float | None = None,
        heartbeat: float = 60.0,
        max_validity: float = 60.0,
        period: float = 1.0,
        off_network: float = 60.0,
        off_network_timeout: float = 30.0,
        route_margin: float = 15.0,
        lateral: float | None = None,
        confirm: int = 1,
        filter_q: float | None = None,
        filter_accel: bool | None = None,
        max_gap: float | None = None,
        lost_after: float | None = None,
    ) -> None:
        if model not in MODELS:
            raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
        if topo is None and model == "network":
            raise ValueError("the network model needs a topology")
        self.etype = entity_type(etype)
        for name, value in (("heartbeat", heartbeat), ("max_validity", max_validity)):
            if not (0.0 < value <= HORIZON):
                raise ValueError(f"{name} must be in (0, {HORIZON:g}] s (the models' horizon), got {value!r}")
        if self.etype.vmax > max_speed(self.etype.code):
            raise ValueError(f"entity type {self.etype.name!r}: vmax {self.etype.vmax} exceeds the speed cap "
                             f"{max_speed(self.etype.code)} m/s that receivers apply to its code")
        self.max_gap = self.etype.max_gap if max_gap is None else float(max_gap)
        self.lost_after = self.etype.lost_after if lost_after is None else float(lost_after)
        if not (0.0 < self.max_gap <= self.lost_after < math.inf):
            raise ValueError(f"need 0 < max_gap <= lost_after < inf, got {self.max_gap!r}, {self.lost_after!r}")
        self.body = self.etype.length  # sum of the parts, once (a property on the type)
        self.entity = entity
        self.model = model
        self.accuracy = accuracy
        self.threshold = float(threshold) if threshold is not None else max(accuracy, 1.0)
        # the truth may be `threshold` from the ghost *and* the estimate off by about the GPS accuracy
        self.margin = max(self.threshold, accuracy) if margin is None else float(margin)
        self.route: list[DirEdge] = [(int(e), 1 if d > 0 else -1) for e, d in (route or [])]
        self.route_pairs = set(zip(self.route, self.route[1:], strict=False))
        self.route_first: dict[DirEdge, int] = {}
        for i, de in enumerate(self.route):
            self.route_first.setdefault(de, i)
        if lookahead is None:
            lookahead = 150.0  # without a route `occupy` stops it at the next choice of way anyway
        self.lookahead = lookahead
        self.heartbeat = heartbeat
        self.max_validity = max_validity
        self.period = period
        self.off_network = off_network
        self.off_network_timeout = off_network_timeout
        # a route is a-priori knowledge: leaving it needs much stronger evidence than changing street
        self.switch_margin = route_margin if self.route else None
        self.switch_count = 3 if self.route else None
        self.filter_q = self.etype.jerk_q if filter_q is None else float(filter_q)
        self.filter_accel = self.etype.accel if filter_accel is None else bool(filter_accel)
        self.reverse_count = 0
        self._ku_memo: tuple[Path, int, float] | None = None
        self.dead_end: DirEdge | None = None
        self.dist_ema = 0.0
        self.reposition = False
        self.lateral = 2.0 * accuracy if lateral is None else float(lateral)
        self.confirm = max(int(confirm), 1)
        self.over = 0
        self.stops: dict[int, list[float]] = {}
        for e, off in stops:
            self.stops.setdefault(int(e), []).append(float(off))
        self.vpeak = 0.0
        self.vpeak_t = -math.inf
        self.recent: list[tuple[float, float]] = []  # the last few fixes (on the network when placed)
        self.recent_s: list[float] = []  # their path coordinates (network mode), for a standing position
        self.net: NetView | None = netview(topo) if topo is not None else None
        self.placer = placer_for(self.net, self.etype.networks) if self.net is not None else None
        # state
        self.seq = 0
        self.last_t: float | None = None
        self.measured: tuple[float, float, float] | None = None
        self.mode: str | None = None  # "edge" | "area" | None
        self.path: Path | None = None
        self.kf: Kinematic1D | None = None
        self.area = -1
        self.kx: Kinematic1D | None = None
        self.ky: Kinematic1D | None = None
        self.pending: tuple[int, int] = (-1, 0)
        self.ghost: Model | None = None
        self._still: tuple[Model, tuple[float, float, float]] | None = None  # a standing ghost's answer
        self.occupation: Occupation | None = None
        self.pub_t = -math.inf
        self.off_since: float | None = None
        self.published = False
        self.halted = False  # a fix gap stopped the published guess (the `gap` update)
        self.stats: dict[str, int] = {}
        self.last_fix: Fix | None = None

    # ---- inferred state -----------------------------------------------------------------------------------
    @property
    def inferred(self) -> tuple[str, int, float, float, float] | None:
        """(kind, edge or area, offset, x, y) of the filtered position, or None before the first placement."""
        if self.mode == "edge" and self.path is not None:
            e, off = self.path.locate(self.kf.s)
            x, y = self.net.point(e, off)
            return "edge", e, off, x, y
        if self.mode == "area":
            return "area", self.area, 0.0, self.kx.s, self.ky.s
        if self.kx is not None:
            return "world", -1, 0.0, self.kx.s, self.ky.s
        return None

    def estimate_xy(self) -> tuple[float, float]:
        if self.mode == "edge":
            return self.path.xy(self.kf.s)
        return self.kx.s, self.ky.s

    def _drift_reference(self) -> tuple[float, float]:
        """Where the drift test believes the entity is (the filtered estimate). A hook: the benchmark's bounds
        replace it with the truth to measure what the estimate's noise costs."""
        return self.estimate_xy()

    # ---- input ----------------------------------------------------------------------------------------------
    def _check(self, x: float, y: float, t: float, acc: float) -> None:
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(t)):
            raise FixRejected(f"fix with non-finite value ({x!r}, {y!r}, t={t!r})")
        if not (math.isfinite(acc) and acc > 0.0):
            raise FixRejected(f"fix accuracy must be finite and positive, got {acc!r}")
        if self.last_t is not None and not t > self.last_t:
            raise FixRejected(f"fix time {t!r} is not after the previous fix at {self.last_t!r}")

    def feed(self, x: float, y: float, t: float, accuracy: float | None = None, *,
             speed: float | None = None, heading: float | None = None,
             speed_accuracy: float = 0.5) -> list[Publish | Unpublish]:
        """One GPS fix (local metres, seconds). Returns the messages to send now (usually none).

        `speed` (m/s) and `heading` (degrees clockwise from north: the course over ground) are the receiver's
        Doppler velocity when it reports one (phones and vehicle locators do), `speed_accuracy` its RMS per
        axis (m/s). Optional: without them the speed comes from differences of positions, which at 5 m GPS
        and 1 Hz is about ten times noisier."""
        acc = self.accuracy if accuracy is None else float(accuracy)
        self._check(x, y, t, acc)
        vel = self._velocity(speed, heading, speed_accuracy)
        self.last_t = t
        self.halted = False
        self.measured = (x, y, t)
        r = acc * acc
        reason = None
        # world-frame filter: the baselines' state, and the only state without a topology
        if self.model != "network" or self.net is None:
            if self.kx is None:
                accel = self.model == "fvw"
                self.kx = Kinematic1D(x, t, r, q=self.etype.jerk_q if accel else 1.0, accel=accel)
                self.ky = Kinematic1D(y, t, r, q=self.etype.jerk_q if accel else 1.0, accel=accel)
            else:
                self.kx.update(x, t, r)
                self.ky.update(y, t, r)
            if vel is not None:
                self.kx.update_speed(vel[0], vel[2])
                self.ky.update_speed(vel[1], vel[2])
        if self.net is not None:
            reason = self._track(x, y, t, r)
            if reason == "off":
                return self._off_network(t)
            if vel is not None:
                self._fuse_velocity(vel)
        lf = self.last_fix
        self.recent.append((lf.x, lf.y) if lf is not None and self.mode == "edge" and self.model == "network"
                           else (x, y))
        if len(self.recent) > 5:
            del self.recent[0]
        self.off_since = None
        if reason is None:
            reason = self._decide(t)
        if reason is None:
            return []
        return [self._publish(t, reason)]

    @staticmethod
    def _velocity(speed: float | None, heading: float | None,
                  speed_accuracy: float) -> tuple[float, float, float] | None:
        """(vx, vy, variance per axis) of a reported Doppler velocity, or None when there is none."""
        if speed is None:
            return None
        if heading is None and speed == 0.0:
            heading = 0.0  # receivers give no course when standing still; none is needed
        if heading is None:
            raise FixRejected("a fix's speed needs its heading (degrees clockwise from north)")
        if not (math.isfinite(speed) and speed >= 0.0 and math.isfinite(heading)):
            raise FixRejected(f"fix speed must be finite and >= 0 and heading finite, got {speed!r}, {heading!r}")
        if not (math.isfinite(speed_accuracy) and speed_accuracy > 0.0):
            raise FixRejected(f"speed accuracy must be finite and positive, got {speed_accuracy!r}")
        h = math.radians(heading)
        return speed * math.sin(h), speed * math.cos(h), speed_accuracy * speed_accuracy

    def _fuse_velocity(self, vel: tuple[float, float, float]) -> None:
        """The network state takes the velocity's component along the path where the fix landed (areas: both
        components). A moving velocity mostly across the path (a turn, or the path's other leg where it passes
        the same place twice) says nothing reliable about the speed along it and is left out; so is one against
        an a-priori route, which the entity does not reverse on."""
        vx, vy, rv = vel
        if self.mode == "edge" and self.model == "network":
            path = self.path
            s = self.recent_s[-1] if self.recent_s else self.kf.s
            hx, hy = path.xy(min(s + 1.0, path.length))
            bx, by = path.xy(max(s - 1.0, 0.0))
            n = math.hypot(hx - bx, hy - by)
            if not n > 0.0:
                return
            along = (vx * (hx - bx) + vy * (hy - by)) / n
            speed = math.hypot(vx, vy)
            if speed >= DOPPLER_MOVING and (abs(along) < 0.7 * speed or (self.route and along < 0.0)):
                return
            self.kf.update_speed(along, rv)
        elif self.mode == "area" and self.model == "network":
            self.kx.update_speed(vx, rv)
            self.ky.update_speed(vy, rv)

    def tick(self, now: float) -> list[Publish | Unpublish]:
        """Time passes without a fix: re-publish when the validity period or the heartbeat runs out; `max_gap`
        seconds after the last fix publish the guess standing where it got to then, and `lost_after` seconds
        after it unpublish (a later fix publishes afresh)."""
        if not math.isfinite(now):
            raise ValueError(f"now must be finite, got {now!r}")
        if self.last_t is not None and now < self.last_t:
            raise ValueError(f"now {now!r} is before the last fix at {self.last_t!r}")
        if not self.published or self.ghost is None:
            return []
        gap = now - self.last_t if self.last_t is not None else 0.0
        if gap >= self.lost_after:
            self.stats["lost"] = self.stats.get("lost", 0) + 1
            self._forget()
            return self.leave()
        stop_at = self.last_t + self.max_gap if gap >= self.max_gap else None
        if stop_at is not None and not self.halted:
            self.halted = True
            return [self._publish(now, "gap", from_ghost=True, stop_at=stop_at)]
        if now >= self.pub_t + self._validity() or now - self.pub_t >= self.heartbeat:
            reason = "expiry" if now >= self.pub_t + self._validity() else "heartbeat"
            return [self._publish(now, reason, from_ghost=True, stop_at=stop_at)]
        return []

    def _forget(self) -> None:
        """Drop the tracking state of a lost entity: its next fix is placed and published afresh."""
        self.mode = None
        self.path = None
        self.kf = self.kx = self.ky = None
        self.ghost = None
        self._still = None
        self.occupation = None
        self.recent.clear()
        self.recent_s.clear()
        self.halted = False

    def leave(self) -> list[Unpublish]:
        was = self.published
        self.published = False
        return [Unpublish(self.entity)] if was else []

    # ---- tracking on the network -------------------------------------------------------------------------
    def _off_network(self, t: float) -> list[Publish | Unpublish]:
        if self.off_since is None:
            self.off_since = t
        self.stats["off_network"] = self.stats.get("off_network", 0) + 1
        if self.published and t - self.off_since >= self.off_network_timeout:
            self.mode = None
            return self.leave()
        return []

    def _init_at(self, fix: Fix, t: float, r: float) -> None:
        if fix.kind == "area":
            self.mode, self.area = "area", fix.index
            self.path = None
            if self.model == "network":
                self.kx = Kinematic1D(fix.x, t, r, q=1.0, accel=False)
                self.ky = Kinematic1D(fix.y, t, r, q=1.0, accel=False)
            return
        self.mode = "edge"
        de = (fix.index, 1)
        i = self.route_first.get(de, self.route_first.get((fix.index, -1)))
        if i is not None:
            de = self.route[i]
        self.path = Path(self.net, [de])
        self.recent_s.clear()
        s = self.net.dist_of(de, fix.offset)
        self.kf = Kinematic1D(s, t, r, q=self.filter_q, accel=self.filter_accel)
        self.pending = (-1, 0)
        self.dead_end = None
        self._maintain_path()  # a publish right after a (re)placement needs the way ahead too

    def _track(self, x: float, y: float, t: float, r: float) -> str | None:
        placer = self.placer
        if self.mode is None:
            fix = self._first(x, y)
            if fix is None or fix.distance > self.off_network:
                return "off"
            self._init_at(fix, t, r)
            self.last_fix = fix
            return "first" if not self.published else "jump"
        if self.mode == "area":
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
            self.last_fix = fix
            return "path"
        # on an edge
        path, kf = self.path, self.kf
        kt = kf.t
        dt = t - kt if t > kt else 0.0
        s_pred = kf.s + kf.v * dt + 0.5 * kf.a * dt * dt
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
        if (cur.distance <= margin and 0.0 < cur.offset < net.edge_len[e_cur]
                and net.node_area[net.edge_from[e_cur]] < 0 and net.node_area[net.edge_to[e_cur]] < 0):
            if cur.distance <= placer.reacquire and self.FAST_TRACK:
                return self._track_on(cur, e_cur, k_cur, s_pred, t, r)
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
                self.last_fix = fix
                return "path"
            fix, preferred, entering = on_way, None, (-2 - fix.index, count)
        if fix.distance > placer.reacquire:
            g = self._first(x, y)
            if g is None or g.distance > self.off_network:
                return "off"
            self._init_at(g, t, r)
            self.last_fix = g
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
                    self.last_fix = fix
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
                self.last_fix = g
                return "path"
            if g is not None and g.kind == "edge" and g.index != fix.index and g.distance + margin < fix.distance:
                self._init_at(g, t, r)
                self.last_fix = g
                self.dist_ema = g.distance
                return "jump"
        s_meas = self._s_of(fix, s_pred, k_cur)
        if abs(s_meas - s_pred) > placer.reacquire:
            self._init_at(fix, t, r)  # the measurement maps far along the path: start afresh there
            self.last_fix = fix
            return "jump"
        if reason is not None:
            self.recent_s.clear()
        self.recent_s.append(s_meas)
        if len(self.recent_s) > 5:
            del self.recent_s[0]
        self.kf.update(s_meas, t, r)
        kf = self.kf
        if kf.v > self.vpeak or t - self.vpeak_t > 120.0:
            self.vpeak, self.vpeak_t = kf.v, t
        backwards = not self.route and kf.v < -self.etype.v_start and kf.v + kf.speed_sigma() < 0.0
        self.reverse_count = self.reverse_count + 1 if backwards else 0
        if self.reverse_count >= 3:
            self._reverse()
            reason = reason or "path"
        self._maintain_path()
        return reason

    def _track_on(self, fix: Fix, e_cur: int, k_cur: int, s_pred: float, t: float, r: float) -> str | None:
        """The rest of `_track` for the usual fix (on the predicted edge, inside the switch margin, within
        `reacquire`): the same steps with `_s_of`'s first case and the bookkeeping written out."""
        self.pending = (-1, 0)
        self.last_fix = fix
        # the consistency check of `_track` cannot jump here: it needs g.distance + margin < fix.distance, and
        # this fix is within the margin (so the placement index is not asked)
        self.dist_ema = 0.7 * self.dist_ema + 0.3 * fix.distance
        path = self.path
        # `_s_of(fix, s_pred, k_cur)`: the fix is on edges[k_cur]; unless the edge recurs within 3 edges
        if path.edge_ids()[k_cur - 3 if k_cur > 3 else 0 : k_cur + 4].count(e_cur) == 1:
            off = fix.offset
            s_meas = path.cum[k_cur] + (off if path.edges[k_cur][1] > 0 else self.net.edge_len[e_cur] - off)
        else:
            s_meas = self._s_of(fix, s_pred, k_cur)
        placer = self.placer
        if abs(s_meas - s_pred) > placer.reacquire:
            self._init_at(fix, t, r)  # the measurement maps far along the path: start afresh there
            self.last_fix = fix
            return "jump"
        recent_s = self.recent_s
        recent_s.append(s_meas)
        if len(recent_s) > 5:
            del recent_s[0]
        kf = self.kf
        kf.update(s_meas, t, r)
        v = kf.v
        if v > self.vpeak or t - self.vpeak_t > 120.0:
            self.vpeak, self.vpeak_t = v, t
        reason = None
        if self.route:
            self.reverse_count = 0
        else:
            backwards = v < -self.etype.v_start and v + kf.speed_sigma() < 0.0
            self.reverse_count = self.reverse_count + 1 if backwards else 0
            if self.reverse_count >= 3:
                self._reverse()
                reason = "path"
        # `_maintain_path` changes nothing unless the path is to be trimmed or is short of what is needed ahead
        path = self.path
        cum = path.cum
        s = kf.s
        v = kf.v
        if ((len(cum) > 2 and s - (self.body + self.margin + 50.0) > cum[1])
                or (cum[-1] < s + self.lookahead + self.margin + 80.0 + 15.0 * (v if v > 0.0 else 0.0)
                    and len(path.edges) < MAX_PATH_EDGES and path.edges[-1] != self.dead_end)):
            self._maintain_path()
        return reason

    def _reverse(self) -> None:
        """Turn the path around (the entity walks the other way): s -> length - s, v -> -v."""
        self.reverse_count = 0
        self.path = self.path.reversed()
        self.kf.flip(self.path.length)
        self.recent_s = [self.path.length - x for x in self.recent_s]

    def _first(self, x: float, y: float) -> Fix | None:
        """First placement: on the a-priori route when it is near (its edges win over a closer other
        street within `route_margin`), else the placement index."""
        if self.route:
            f = self.placer.on_edges(x, y, [e for e, _d in self.route])
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
            ri = self._route_index(last)
            ahead = follow(self.net, last, self.etype.networks, need - path.length, self.route, ri,
                           max_edges=MAX_PATH_EDGES - len(path.edges))
            if ahead:
                self.path = path.extended(ahead)
            else:
                self.dead_end = last  # nothing follows this edge: do not ask again every fix

    def _next_stop(self, path: Path, s: float, v: float) -> float:
        """Path coordinate of the next known stop on the a-priori route ahead (inf if none known)."""
        if not self.stops:
            return math.inf
        known = self._known_until(path, s)
        k = path.index(s)
        edges, cum, stops = path.edges, path.cum, self.stops
        n = len(edges)
        while k < n and cum[k] <= known:
            e, d = edges[k]
            offs = stops.get(e)
            if offs:  # the same steps as before, on the few edges that have stops
                for off in sorted(offs, reverse=d < 0):
                    sp = cum[k] + self.net.dist_of((e, d), off)
                    if sp > s + 2.0 and sp <= known:
                        return sp
            k += 1
        return math.inf

    def _route_index(self, de: DirEdge) -> int | None:
        return self.route_first.get(de)

    def _known_until(self, path: Path, s: float) -> float:
        """Path coordinate up to which the path follows the a-priori route from the edge holding s."""
        if not self.route:
            return 0.0
        k0 = path.index(s)
        memo = self._ku_memo
        if memo is not None and memo[0] is path and memo[1] == k0:
            return memo[2]
        k = k0
        edges = path.edges
        i = self.route_first.get(edges[k])
        if i is None:
            out = 0.0
        elif edges[k:] == self.route[i : i + len(edges) - k]:
            # the rest of the path is a stretch of the route (the usual case): all its pairs are route pairs,
            # so the walk below would reach the path's end
            out = path.cum[len(edges)]
        else:
            pairs = self.route_pairs
            n = len(edges)
            while k + 1 < n and (edges[k], edges[k + 1]) in pairs:
                k += 1
            out = path.cum[k + 1]
        self._ku_memo = (path, k0, out)
        return out

    def _area_update(self, x: float, y: float, t: float, r: float) -> None:
        if self.model == "network":
            self.kx.update(x, t, r)
            self.ky.update(y, t, r)

    # ---- decisions -----------------------------------------------------------------------------------------
    def _validity(self) -> float:
        return self.occupation.validity if self.occupation is not None else self.max_validity

    def _decide(self, t: float) -> str | None:
        if not self.published or self.ghost is None:
            return "first"
        if self.model == "periodic":
            if t - self.pub_t >= self.period - 1e-6:
                return "periodic"
            return self._expiry_or_heartbeat(t)
        g = self.ghost
        edge = self.model == "network" and self.mode == "edge"
        v_est = self.kf.v if edge else math.hypot(self.kx.v, self.ky.v)
        still = self._still
        if still is not None and still[0] is g:
            gx, gy, gv = still[1]
        else:
            gx, gy, gv = g.xy_speed_at(t)
            if isinstance(g, NetworkModel) and g.v == 0.0 and g.a == 0.0:
                # a standing network ghost (half the fixes of transit vehicles) answers the same at every t:
                # advance(0, 0, .) moves 0.0 and its braking plan is void (brake_plan gives inf at v = 0)
                self._still = (g, (gx, gy, gv))
        et = self.etype
        if gv > et.v_stop and v_est < et.v_stop:
            return "stop"
        if gv <= et.v_stop:
            # the published model stands still: judge by the mean of the last fixes, not by the filter,
            # whose speed wanders with the noise of a standing GPS (a start is speed *and* displacement)
            moved = False
            for n, limit in ((5, self.threshold), (2, 1.6 * self.threshold)):
                pts = self.recent[-n:]
                mx = my = 0.0
                for px, py in pts:
                    mx += px
                    my += py
                m = len(pts)
                moved = moved or math.hypot(mx / m - gx, my / m - gy) > limit
            if moved:
                if v_est > et.v_start:
                    return "start"
                if v_est <= et.v_stop:
                    self.reposition = True  # still standing, just somewhere else: publish standing there
                return "drift"  # (creeping between v_stop and v_start: publish the slow motion)
            return self._expiry_or_heartbeat(t)
        ex, ey = self._drift_reference()
        drift = math.hypot(gx - ex, gy - ey)
        # `confirm` fixes in a row over the threshold (or one over 1.5x) make a drift update
        self.over = self.over + 1 if drift > self.threshold else 0
        if self.over >= self.confirm or drift > 1.5 * self.threshold:
            return "drift"
        return self._expiry_or_heartbeat(t)

    def _expiry_or_heartbeat(self, t: float) -> str | None:
        if t >= self.pub_t + self._validity():
            return "expiry"
        if t - self.pub_t >= self.heartbeat:
            return "heartbeat"
        return None

    # ---- publishing ----------------------------------------------------------------------------------------
    def _publish(self, t: float, reason: str, from_ghost: bool = False, stop_at: float | None = None) -> Publish:
        """`from_ghost`: continue the published model (no fix to go on); `stop_at`: and stand where that model
        was at this time (a fix gap, `tick`)."""
        self.stats[reason] = self.stats.get(reason, 0) + 1
        self.over = 0
        if (not from_ghost and self.mode == "edge" and not self.route and self.kf is not None
                and self.kf.v < -self.etype.v_stop):
            self._reverse()  # publish in the direction of travel, whatever the filter's hysteresis says
            self._maintain_path()
        # ghost == decode(payload, net), without the round trip
        if self.model == "network" and self.mode == "edge":
            payload, ghost = encode_network(*self._network_fields(t, from_ghost, stop_at))
        else:
            payload, ghost = encode_quantized(self._build_model(t, from_ghost, stop_at))
        self.reposition = False
        self.ghost = ghost
        self.occupation = self._occupation(t, ghost)
        self.pub_t = t
        self.seq += 1
        self.published = True
        validity_ms = int(self.occupation.validity * 1000.0) if self.occupation else int(self.max_validity * 1000)
        cells = self.occupation.cells[:MAX_PUBLISH_CELLS] if self.occupation else ()
        return _make_publish(self.entity, self.seq, tuple(cells), validity_ms, payload)

    def _build_model(self, t: float, from_ghost: bool, stop_at: float | None = None) -> Model:
        et = self.etype
        if self.model == "network" and self.mode == "edge":
            return NetworkModel(*self._network_fields(t, from_ghost, stop_at))
        if stop_at is not None and from_ghost and isinstance(self.ghost, (AreaModel, WorldModel)):
            x, y = self.ghost.xy_at(stop_at)
            if isinstance(self.ghost, AreaModel):
                return AreaModel(t, self.ghost.area, x, y, 0.0, 0.0, et.code)
            return WorldModel(t, x, y, 0.0, 0.0, 0.0, 0.0, et.code)
        if self.model == "network" and self.mode == "area":
            vx, vy = self.kx.v, self.ky.v
            if math.hypot(vx, vy) < et.v_stop:
                vx = vy = 0.0
            return AreaModel(t, self.area, self.kx.s, self.ky.s, vx, vy, et.code)
        if from_ghost and isinstance(self.ghost, WorldModel):
            x, y = self.ghost.xy_at(t)
            g = self.ghost
            dt = max(t - g.t0, 0.0)
            return WorldModel(t, x, y, g.vx + g.ax * dt, g.vy + g.ay * dt, g.ax, g.ay, et.code)
        if self.model == "periodic":
            return WorldModel(t, self.kx.s, self.ky.s, 0.0, 0.0, 0.0, 0.0, et.code)
        vx, vy = self.kx.v, self.ky.v
        ax, ay = (self.kx.a, self.ky.a) if self.model == "fvw" else (0.0, 0.0)
        if math.hypot(vx, vy) < et.v_stop:
            vx = vy = ax = ay = 0.0
        return WorldModel(t, self.kx.s, self.ky.s, vx, vy, ax, ay, et.code)

    def _network_fields(self, t: float, from_ghost: bool, stop_at: float | None = None) -> tuple:
        """The NetworkModel's fields (t0, path, s0, v, a, vmax, etype, parts, stop_s, brake) to publish
        (`stop_at`: from the ghost, standing where it was at that time)."""
        et = self.etype
        if from_ghost and isinstance(self.ghost, NetworkModel):
            g = self.ghost
            if stop_at is not None:
                s_abs, v, a = g.s_at(stop_at), 0.0, 0.0
            else:
                s_abs, v, a = g.s_at(t), g.speed_at(t), g.a
            path, s = g.path, s_abs
        else:
            s, v, a = self.kf.s, self.kf.v, self.kf.a
            path = self.path
            if self.reposition:
                v = a = 0.0
            if v < et.v_stop and len(self.recent_s) >= 2:
                # standing: the mean of the last fixes is a better position than the lagging filter
                near = self.recent_s[-3:]
                s = sum(near) / len(near)
        if v < et.v_stop:
            v, a = 0.0, 0.0
        v = min(v, et.vmax)  # a noisy filter must not publish a walker at 6 m/s
        a = min(max(a, -et.amax), et.amax) if et.accel else 0.0
        start_s = s - self.body - self.margin
        k0 = path.index(start_s)
        sub = path.suffix(k0)
        s_sub = s - path.cum[k0]
        # an accelerating vehicle is expected to reach its usual cruising speed, not the type's maximum
        vmax = et.vmax
        if a > 0.0 and self.vpeak > v:
            vmax = min(max(self.vpeak, 4.0), et.vmax)
        stop_s = self._next_stop(sub, s_sub, v) if v > 0.0 else math.inf
        return t, sub, s_sub, max(v, 0.0), a, vmax, et.code, et.parts, stop_s, et.brake

    def _occupation(self, t: float, ghost: Model) -> Occupation | None:
        if self.net is None or self.mode is None:
            return None
        et = self.etype
        if self.mode == "area":
            x, y = ghost.xy_at(t) if isinstance(ghost, AreaModel) else self.estimate_xy()
            vx, vy = (ghost.vx, ghost.vy) if isinstance(ghost, AreaModel) else (0.0, 0.0)
            # the strip outside the area is covered by the lateral cells below, so the period only keeps
            # the GPS accuracy as its margin (a large drift threshold would otherwise make it vanish)
            margin = min(self.margin, self.accuracy)
            occ = occupy_area(x, y, vx, vy, self.placer.ring(self.area), self.net.area_cell[self.area],
                              margin=margin, max_validity=self.max_validity)
            if self.lateral > 0.0:
                # ways crossing or skirting the area and areas next to it: under GPS noise the entity may be
                # on one of them
                cells = list(occ.cells)
                for e in self.placer.edges_near(x, y, self.lateral):
                    f = self.placer.project_on(x, y, e)
                    if f.distance <= self.lateral:
                        for a0, b0, c in self.net.pieces(e, 1):
                            if b0 >= f.offset - self.lateral and a0 <= f.offset + self.lateral and c not in cells:
                                cells.append(c)
                for area in self.placer.areas_near(x, y, self.lateral):
                    c = self.net.area_cell[area]
                    if c not in cells and ring_distance(self.placer.ring(area), x, y) <= self.lateral:
                        cells.append(c)
                validity = occ.validity
                speed = math.hypot(vx, vy)
                if len(cells) <= MAX_PUBLISH_CELLS and speed > 0.0 and self.lateral > margin:
                    # every cell within `lateral` of the position is listed: the ghost must move
                    # `lateral - margin` before the truth can be outside them, wherever the boundary is
                    validity = max(validity, min((self.lateral - margin) / speed, self.max_validity))
                occ = Occupation(tuple(cells[:MAX_PUBLISH_CELLS]), validity, occ.front_period, occ.aft_period,
                                 occ.cover_start, occ.cover_end)
            return _wire(occ)
        if isinstance(ghost, NetworkModel):
            path, s, v, a = ghost.path, ghost.s0, ghost.v, ghost.a
            known = self._known_until(path, s)
            lookahead = self.lookahead
        else:
            # world-frame baselines: the same occupation machinery on the client's network estimate
            path, s, v, a = self.path, self.kf.s, max(self.kf.v, 0.0), 0.0
            known, lookahead = self._known_until(path, s), self.lookahead
        travel = ghost.time_to if isinstance(ghost, NetworkModel) else None
        # at a dead end the model halts at the path's end: nothing ahead to enter, no front period
        occ = occupy(path, s, et.length, v, a, et.vmax, et.networks, known_until=known, margin=self.margin,
                     lookahead=lookahead, max_validity=min(self.max_validity, self.heartbeat), travel=travel,
                     dead_end_at_path_end=path.edges[-1] == self.dead_end)
        back = None
        if v == 0.0 and not self.route and self.body == 0.0 and isinstance(ghost, NetworkModel):
            # a walker standing still may turn and leave the other way, and the standing test needs a few
            # fixes to see it go: cover the way behind too, `lateral` beyond the margin (and the parallel
            # ways as far behind)
            back = self._behind(path, s, self.lateral, et.networks)
            cells = list(occ.cells)
            for c in back.cells:
                if c not in cells and len(cells) < MAX_PUBLISH_CELLS:
                    cells.append(c)
            occ = Occupation(tuple(cells), min(occ.validity, back.validity), occ.front_period, occ.aft_period,
                             occ.cover_start, occ.cover_end)
        if self.lateral > 0.0 and not self.route:
            extra = self._lateral_cells(path, s, occ.cover_end - s,
                                        None if back is None else back.cover_end - back.cover_start)
            cells = list(occ.cells)
            for c in extra:
                if c not in cells and len(cells) < MAX_PUBLISH_CELLS:
                    cells.append(c)
            occ = _with_cells(occ, tuple(cells))
        return _wire(occ)

    def _behind(self, path: Path, s: float, lookahead: float, networks: int) -> Occupation:
        """The occupation of a standing entity turned around: the published path's edge at s reversed and
        followed by the junction rule, covered as `occupy` covers the way ahead (`lookahead` beyond the margin,
        every branch at a choice of way within it)."""
        net = self.net
        k = path.index(s)
        e, d = path.edges[k]
        back = (e, -d)
        s_back = path.cum[k + 1] - s
        edges = [back] + follow(net, back, networks, lookahead + self.margin + 80.0, max_edges=MAX_PATH_EDGES)
        return occupy(Path(net, edges), s_back, 0.0, 0.0, 0.0, self.etype.vmax, networks, margin=self.margin,
                      lookahead=lookahead, max_validity=min(self.max_validity, self.heartbeat))

    def _lateral_cells(self, path: Path, s: float, ahead: float, behind: float | None = None) -> list[int]:
        """Cells of the other edges within `lateral` metres of the position: under GPS noise the entity may
        be on a parallel way (the other sidewalk) rather than the one it was placed on. Each such edge is
        covered from `behind` metres behind the projected point (default: the margin and the body) to `ahead`
        metres on, in the direction of travel."""
        net = self.net
        x, y = path.xy(s)
        hx, hy = path.xy(min(s + 1.0, path.length))
        bx, by = path.xy(max(s - 1.0, 0.0))
        dx, dy = hx - bx, hy - by
        e_cur = path.locate(s)[0]
        back = self.margin + self.body if behind is None else behind  # a standing walker: both ways
        # the path's own edges are covered where the occupation runs; one the path reaches only further on
        # (it loops back along the parallel way) is still a lateral candidate here
        cum, edges = path.cum, path.edges
        on_path = {edges[k][0] for k in range(len(edges)) if cum[k + 1] >= s - back and cum[k] <= s + ahead}
        out: list[int] = []
        # every way near the position, connected or not (footways drawn twice, a few metres apart)
        for e in self.placer.edges_near(x, y, self.lateral):
            if e == e_cur or e in on_path:
                continue
            f = self.placer.project_on(x, y, e)
            if f.distance > self.lateral:
                continue
            hx0, hy0 = net.point(e, min(f.offset + 1.0, net.edge_len[e]))
            bx0, by0 = net.point(e, max(f.offset - 1.0, 0.0))
            fwd = ((hx0 - bx0) * dx + (hy0 - by0) * dy) >= 0.0
            length = net.edge_len[e]
            lo, hi = (f.offset - back, f.offset + ahead) if fwd else (f.offset - ahead, f.offset + back)
            lo, hi = max(lo, 0.0), min(hi, length)
            for a0, b0, c in net.pieces(e, 1):
                if b0 >= lo and a0 <= hi and c not in out:
                    out.append(c)
        for area in self.placer.areas_near(x, y, self.lateral):  # an area next to the way: maybe inside it
            if ring_distance(self.placer.ring(area), x, y) <= self.lateral:
                c = net.area_cell[area]
                if c not in out:
                    out.append(c)
        return out
