"""The Player: an honest client's sans-IO core (reference section 4.5), the coordinator of its parts.

Fed GPS fixes (`feed`) and the time (`tick`), it returns the `Publish` / `Unpublish` messages to send. The
work is done by parts, each in its own module:
- `NetworkTracker` (tracker.py): placement, the path and its filter, hysteresis, re-acquisition;
- `UpdateRules` (rules.py): when to publish (`first`, `jump`, `path`, `drift`, `stop`, `start`, `periodic`,
  `expiry`, `heartbeat`, `gap`, `lost`), with an injected `Estimate` of where the entity is;
- `Coverage` (coverage.py): which cells a publish lists and for how long;
- `WorldFilter` and `plane_model` (baselines.py): the world-frame baselines and the area model.
The Player keeps what was published (the ghost: the decoded payload, exactly as every receiver extrapolates
it) and builds the messages.

`model` selects what is published: "network" (path-constrained dead reckoning, the default), or the
world-frame baselines "fpw", "fvw" and "periodic" (a position every `period` seconds). With no topology
only the world-frame models work and no cells are published.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from entitynet.client.baselines import WorldFilter, plane_model
from entitynet.client.coverage import MAX_PUBLISH_CELLS, Coverage
from entitynet.client.entities import EntityType, entity_type
from entitynet.client.filters import Kinematic1D, KinematicMath
from entitynet.client.fixes import FixRejected, check_fix, velocity
from entitynet.client.frozen import maker
from entitynet.client.limits import HORIZON, max_speed
from entitynet.client.modes import AREA, EDGE, MODELS, ModelKind, Place
from entitynet.client.motion import Model, NetworkModel
from entitynet.client.network import NetView, netview
from entitynet.client.occupation import LOOKAHEAD, Occupation
from entitynet.client.path import Path
from entitynet.client.payload import encode_network, encode_quantized
from entitynet.client.route import Route
from entitynet.client.row_fields import _HALTED, _KV, _LAST_T, _MX, _OFF_SINCE, _PUB_T, PlayerState
from entitynet.client.rules import OWN_ESTIMATE, Estimate, UpdateRules
from entitynet.client.tracker import NetworkTracker, placer_for
from entitynet.protocol import Publish, Unpublish

__all__ = ["MODELS", "FixRejected", "Player", "placer_for"]


_make_publish = maker(Publish)  # Publish(...) without the frozen dataclass __init__ (once per publish)


class Player(PlayerState):
    """One entity's honest client: fixes and time in, PUBLISH / UNPUBLISH out. The parameters tune the parts
    (docs/dead-reckoning.md); `estimate` is where the update rules and the publish ask what the entity is
    believed to be doing (default: its own filtered estimate; the benchmark injects the truth). Its state lives
    in a client-state row (state.py): a record of its own, or a `FleetCore`'s once added there (`move_to`)."""

    def __init__(
        self, topo, entity: int, etype: str | EntityType, *, model: str | ModelKind = ModelKind.NETWORK,
        route: Sequence[Sequence[int]] | None = None, stops: Sequence[tuple[int, float]] = (),
        accuracy: float = 5.0, threshold: float | None = None, margin: float | None = None,
        lookahead: float | None = None, heartbeat: float = 60.0, max_validity: float = 60.0, period: float = 1.0,
        off_network: float = 60.0, off_network_timeout: float = 30.0, route_margin: float = 15.0,
        lateral: float | None = None, confirm: int = 1, filter_q: float | None = None,
        filter_accel: bool | None = None, max_gap: float | None = None, lost_after: float | None = None,
        estimate: Estimate = OWN_ESTIMATE,
    ) -> None:
        kind = ModelKind.parse(model)
        if topo is None and kind == ModelKind.NETWORK:
            raise ValueError("the network model needs a topology")
        self.etype = et = entity_type(etype)
        for name, value in (("heartbeat", heartbeat), ("max_validity", max_validity)):
            if not (0.0 < value <= HORIZON):
                raise ValueError(f"{name} must be in (0, {HORIZON:g}] s (the models' horizon), got {value!r}")
        if et.vmax > max_speed(et.code):
            raise ValueError(f"entity type {et.name!r}: vmax {et.vmax} exceeds the speed cap "
                             f"{max_speed(et.code)} m/s that receivers apply to its code")
        max_gap = et.max_gap if max_gap is None else float(max_gap)
        lost_after = et.lost_after if lost_after is None else float(lost_after)
        if not (0.0 < max_gap <= lost_after < math.inf):
            raise ValueError(f"need 0 < max_gap <= lost_after < inf, got {max_gap!r}, {lost_after!r}")
        self.body = et.length  # sum of the parts, once (a property on the type)
        self.entity = entity
        self.model = kind
        self.accuracy = accuracy
        self.threshold = float(threshold) if threshold is not None else max(accuracy, 1.0)
        # the truth may be `threshold` from the ghost *and* the estimate off by about the GPS accuracy
        self.margin = max(self.threshold, accuracy) if margin is None else float(margin)
        self.max_validity = max_validity
        self.off_network_timeout = off_network_timeout
        self.estimate = estimate
        lateral = 2.0 * accuracy if lateral is None else float(lateral)
        rec = self.own_record()
        self.net: NetView | None = netview(topo) if topo is not None else None
        self.route = Route(self.net, route, stops)
        self.rules = UpdateRules(et, periodic=kind == ModelKind.PERIODIC, threshold=self.threshold,
                                 confirm=max(int(confirm), 1), heartbeat=heartbeat, max_validity=max_validity,
                                 period=period, max_gap=max_gap, lost_after=lost_after, state=(rec, 0))
        self.world = WorldFilter(kind, et) if kind != ModelKind.NETWORK else None
        self.tracker: NetworkTracker | None = None
        self.coverage: Coverage | None = None
        if self.net is not None:
            self.tracker = NetworkTracker(
                self.net, et, self.route, body=self.body, margin=self.margin,
                lookahead=LOOKAHEAD if lookahead is None else lookahead,  # the way kept ahead
                off_network=off_network, lateral=lateral, route_margin=route_margin,
                filter_q=et.jerk_q if filter_q is None else float(filter_q),
                filter_accel=et.accel if filter_accel is None else bool(filter_accel),
                area_filter=kind == ModelKind.NETWORK, state=(rec, 0))
            self.coverage = Coverage(self.net, et, self.route, body=self.body, margin=self.margin,
                                     accuracy=accuracy, lateral=lateral, lookahead=lookahead,
                                     max_validity=max_validity, heartbeat=heartbeat)
        # what was published, and the fix history
        self.seq = 0  # (last_t, measured, pub_t, off_since: the row's, none yet)
        self.ghost: Model | None = None
        self.occupation: Occupation | None = None
        self.published = False
        self.stats: dict[str, int] = {}

    # ---- the tracker's state, read through (None without a topology) -------------------------------------
    @property
    def mode(self) -> Place | None:
        """Where the tracker holds the entity: Place.EDGE, Place.AREA (equal to "edge", "area") or None."""
        return self.tracker.place if self.tracker is not None else None

    @property
    def path(self) -> Path | None:
        """The path the tracker follows (on an edge)."""
        return self.tracker.path if self.tracker is not None else None

    @property
    def kf(self) -> KinematicMath | None:
        """The along-path filter (on an edge): the row's (`RowKinematic`, state.py), live, not a snapshot."""
        return self.tracker.kf if self.tracker is not None else None

    def _plane(self) -> tuple[Kinematic1D | None, Kinematic1D | None]:
        """The plane filters (x, y): the tracker's in an area (network model), else the baseline's."""
        return (self.tracker.kx, self.tracker.ky) if self.world is None else (self.world.kx, self.world.ky)

    @property
    def inferred(self) -> tuple[str, int, float, float, float] | None:
        """(kind, edge or area, offset, x, y) of the filtered position, or None before the first placement."""
        mode = self.mode
        if mode is EDGE and self.path is not None:
            e, off = self.path.locate(self.kf.s)
            x, y = self.net.point(e, off)
            return "edge", e, off, x, y
        kx, ky = self._plane()
        if mode is AREA:
            return "area", self.tracker.area, 0.0, kx.s, ky.s
        if kx is not None:
            return "world", -1, 0.0, kx.s, ky.s
        return None

    def estimate_xy(self) -> tuple[float, float]:
        """The filtered position (local metres)."""
        trk = self.tracker
        if trk is not None and trk.place is EDGE:
            return trk.path.xy(trk.kf.s)
        kx, ky = self._plane()
        return kx.s, ky.s

    # ---- input ----------------------------------------------------------------------------------------------
    def feed(self, x: float, y: float, t: float, accuracy: float | None = None, *,
             speed: float | None = None, heading: float | None = None,
             speed_accuracy: float = 0.5) -> list[Publish | Unpublish]:
        """One GPS fix (local metres, seconds). Returns the messages to send now (usually none).

        `speed` (m/s) and `heading` (degrees clockwise from north: the course over ground) are the receiver's Doppler
        velocity when it reports one (phones and vehicle locators do), `speed_accuracy` its RMS per axis (m/s).
        Optional: without them the speed comes from differences of positions, about ten times noisier at 5 m, 1 Hz."""
        acc = self.accuracy if accuracy is None else float(accuracy)
        # the row's fields read and written by index (the hot path: a block read, not one descriptor a field)
        f, b = self._st.f, self._fb
        last_t = None if f[b + _LAST_T] != f[b + _LAST_T] else f[b + _LAST_T]  # (NaN: no fix yet)
        check_fix(x, y, t, acc, last_t)
        vel = velocity(speed, heading, speed_accuracy)
        rules, trk = self.rules, self.tracker
        # (`note_interval` is True only when the usual interval changed: `reach` follows it)
        if last_t is not None and rules.note_interval(t - last_t) and trk is not None:
            trk.follow_cadence(rules.interval)
        self._st.i[self._ib + _HALTED] = 0  # rules.halted = False
        f[b + _MX], f[b + _MX + 1], f[b + _LAST_T] = x, y, t  # measured = (x, y, t), last_t = t
        r = acc * acc
        reason = None
        world = self.world
        if world is not None:  # the baselines' state, and the only state without a topology
            world.update(x, y, t, r, vel)
        if trk is not None:
            reason = trk.track(x, y, t, r, self.published)
            if reason == "off":
                return self._off_network(t)
            if vel is not None and world is None:
                trk.fuse_velocity(vel)
        on_edge = world is None and trk.place is EDGE
        lf_xy = trk.last_fix_xy() if on_edge else None  # (lf.x, lf.y) of `last_fix`, without the Fix
        rules.note_fix(*(lf_xy or (x, y)))
        f[b + _OFF_SINCE] = math.nan  # off_since = None
        if reason is None:
            if not self.published or self.ghost is None:
                reason = "first"
            else:  # the estimated speed: trk.kf.v on an edge, else the plane filters'
                v_est = f[b + _KV] if on_edge else math.hypot(*(k.v for k in self._plane()))
                reason = rules.decide(t, self.ghost, f[b + _PUB_T], self.occupation, v_est, self, self.estimate)
        if reason is None:
            return []
        return [self._publish(t, reason)]

    def tick(self, now: float) -> list[Publish | Unpublish]:
        """Time passes without a fix: re-publish when the validity or the heartbeat runs out; a gap limit after the
        last fix (rules.py) publish the guess standing, `lost_after` after it unpublish (a fix publishes afresh)."""
        if not math.isfinite(now):
            raise ValueError(f"now must be finite, got {now!r}")
        last_t = self.last_t
        if last_t is not None and now < last_t:
            raise ValueError(f"now {now!r} is before the last fix at {last_t!r}")
        if not self.published or self.ghost is None:
            return []
        reason, stop_at = self.rules.on_tick(now, last_t, self.pub_t, self.occupation)
        if reason == "lost":
            self.stats["lost"] = self.stats.get("lost", 0) + 1
            self._forget()
            return self.leave()
        if reason is None:
            return []
        return [self._publish(now, reason, from_ghost=True, stop_at=stop_at)]

    def _forget(self) -> None:
        """Drop the tracking state of a lost entity: its next fix is placed and published afresh."""
        if self.tracker is not None:
            self.tracker.forget()
        if self.world is not None:
            self.world.forget()
        self.ghost = None
        self.occupation = None
        self.rules.forget()

    def leave(self) -> list[Unpublish]:
        """Unpublish the entity (if published): receivers drop it at once instead of waiting for expiry."""
        was = self.published
        self.published = False
        return [Unpublish(self.entity)] if was else []

    def _off_network(self, t: float) -> list[Publish | Unpublish]:
        if self.off_since is None:
            self.off_since = t
        self.stats["off_network"] = self.stats.get("off_network", 0) + 1
        if self.published and t - self.off_since >= self.off_network_timeout:
            self.tracker.place = None
            return self.leave()
        return []

    # ---- publishing ----------------------------------------------------------------------------------------
    def _publish(self, t: float, reason: str, from_ghost: bool = False, stop_at: float | None = None) -> Publish:
        """`from_ghost`: continue the published model (no fix to go on); `stop_at`: and stand where that model
        was at this time (a fix gap, `tick`)."""
        self.stats[reason] = self.stats.get(reason, 0) + 1
        trk = self.tracker
        if not from_ghost and trk is not None:
            trk.face_travel()  # publish in the direction of travel, whatever the filter's hysteresis says
        # ghost == decode(payload, net), without the round trip
        if self.world is None and trk.place is EDGE:
            payload, ghost = encode_network(*self._network_fields(t, from_ghost, stop_at))
        else:
            area = trk.area if self.world is None and trk.place is AREA else None
            payload, ghost = encode_quantized(plane_model(self.model, self.etype, t, *self._plane(), area,
                                                          self.ghost, from_ghost, stop_at))
        self.rules.published()
        old, self.ghost = self.ghost, ghost
        occ = self.occupation = self.coverage.placed(reason, t, ghost, old, trk, self.estimate_xy) if trk else None
        self.pub_t = t
        self.seq += 1
        self.published = True
        validity_ms = int(occ.validity * 1000.0) if occ else int(self.max_validity * 1000)
        cells = occ.cells[:MAX_PUBLISH_CELLS] if occ else ()
        return _make_publish(self.entity, self.seq, tuple(cells), validity_ms, payload)

    def _network_fields(self, t: float, from_ghost: bool, stop_at: float | None = None) -> tuple:
        """The NetworkModel's fields (t0, path, s0, v, a, vmax, etype, parts, stop_s, brake) to publish
        (`stop_at`: from the ghost, standing where it was at that time)."""
        et = self.etype
        trk = self.tracker
        if from_ghost and isinstance(self.ghost, NetworkModel):
            g = self.ghost
            if stop_at is not None:
                s_abs, v, a = g.s_at(stop_at), 0.0, 0.0
            else:
                s_abs, v, a = g.s_at(t), g.speed_at(t), g.a
            path_from, s = g.path.part_from, s_abs
        else:
            kf = trk.kf
            s = kf.s
            v, a = (kf.v, kf.a) if from_ghost else self.estimate.motion(self, t)
            path_from = trk.path_from  # (from the row's arrays where the path is there only)
            if self.rules.reposition:
                v = a = 0.0
            if v < et.v_stop and len(trk.recent_s) >= 2:
                # standing: the mean of the last fixes is a better position than the lagging filter
                near = trk.recent_s[-3:]
                s = sum(near) / len(near)
        if v < et.v_stop:
            v, a = 0.0, 0.0
        v = min(v, et.vmax)  # a noisy filter must not publish a walker at 6 m/s
        a = min(max(a, -et.amax), et.amax) if et.accel else 0.0
        start_s = s - self.body - self.margin
        sub, c0 = path_from(start_s)  # the path from the edge holding start_s on, and its shift of s
        s_sub = s - c0
        # an accelerating vehicle is expected to reach its usual cruising speed, not the type's maximum
        vmax = et.vmax
        if a > 0.0 and trk.vpeak > v:
            vmax = min(max(trk.vpeak, 4.0), et.vmax)
        stop_s = self.route.next_stop(sub, s_sub) if v > 0.0 else math.inf
        return t, sub, s_sub, max(v, 0.0), a, vmax, et.code, et.parts, stop_s, et.brake
