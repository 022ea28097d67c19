"""The update rules: when an honest client publishes (reference section 4.5), given what it published.

- `drift`: the ghost (what every receiver extrapolates) is more than `threshold` metres from where the
  entity is believed to be, `confirm` fixes in a row (or once by 1.5 x);
- `stop` / `start`: emergent behaviour the extrapolation cannot know (a start is speed *and* displacement; a
  stop where the published model halts anyway, at a known stop, is none: `HALT_NEAR`);
- `periodic`: the baseline that publishes a position every `period` seconds;
- `expiry`: the occupation's validity period ran out; `heartbeat`: nothing else for `heartbeat` seconds;
- `gap`: no fix for `gap_limit` seconds: the guess stops where it got to; `lost`: no fix for `lost_after`
  seconds, the entity is unpublished (entitynet/client/limits.py says why). `gap_limit` is the configured
  `max_gap`, or `GAP_INTERVALS` times the median of the last fix intervals (given `MIN_INTERVALS` of them)
  when the feed is that slow (a real bus feed sends a fix every 31-33 s: with a 30 s limit every interval
  was a gap and then a start), at most half of `lost_after`. At 1 Hz it is `max_gap`: nothing changes for
  fast feeds. The tracker's along-path `reach` follows the same interval (`NetworkTracker.follow_cadence`).

Where the entity "is believed to be" comes from an injected `Estimate` (default: the player's own filtered
estimate), so that a benchmark can put the truth there without overriding the player's private methods.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

from entitynet.client.entities import EntityType
from entitynet.client.motion import Model, NetworkModel
from entitynet.client.occupation import Occupation
from entitynet.client.state import F_COL, RECENT, Bound, Record, column, ring

#: an entity that stops within this share of the drift threshold of where its published model halts (a stop on
#: its route, known a priori, or its path's end) publishes no "stop": the ghost halts there by itself. Measured (`bench
#: dr` vehicles, 5 m; issue 20): 151 stop publishes of 1,839 became 143 at 0.5 and 140 at 1.0 (the drift test
#: takes some), the receiver's p95 error 7.268 / 7.264 / 7.269 m, the occupation error unchanged; at 1.0 the
#: simulation's missed visibility rose from 0.157 % to 0.160 %, at 0.5 it did not (both with the 40 m LOOKAHEAD).
HALT_NEAR = 0.5

if TYPE_CHECKING:
    from entitynet.client.player import Player


class Estimate(Protocol):
    """What the player believes about itself, where the update rules and the publish ask: the position the
    drift test compares the ghost with, and the along-path speed and acceleration a network publish carries.
    The benchmark injects the truth here to measure what the estimate's noise costs."""

    def position(self, player: Player, t: float) -> tuple[float, float]:
        """(x, y) the drift test of a moving ghost compares it with, at the fix time `t`."""
        ...

    def motion(self, player: Player, t: float) -> tuple[float, float]:
        """(v, a) along the path to publish at `t` (network model, on an edge, from a fix)."""
        ...


class OwnEstimate:
    """The player's own filtered estimate (the default `Estimate`)."""

    def position(self, player: Player, t: float) -> tuple[float, float]:
        """The filtered position."""
        return player.estimate_xy()

    def motion(self, player: Player, t: float) -> tuple[float, float]:
        """The along-path filter's speed and acceleration."""
        kf = player.tracker.kf
        return kf.v, kf.a


OWN_ESTIMATE = OwnEstimate()

#: a gap is this many of the feed's usual fix intervals without a fix (one missed fix is not yet a gap)
GAP_INTERVALS = 2.5
FIX_INTERVALS_KEPT = RECENT  # the last intervals whose median is the usual one (robust to one long hole)
MIN_INTERVALS = 3  # fewer say nothing yet (a gap right after the first fix is not the feed's cadence)


def usual_interval(intervals: list[float]) -> float:
    """The median of the observed fix intervals (non-empty), robust to one long hole (the fleet core's
    `fleet_kernels.interval_rows` repeats these operations in this order)."""
    v = sorted(intervals)
    n = len(v)
    return (v[(n - 1) // 2] + v[n // 2]) / 2.0


def gap_limit(max_gap: float, lost_after: float, interval: float) -> float:
    """Seconds without a fix before the guess halts: `max_gap`, or `GAP_INTERVALS` x the feed's usual fix
    `interval` when that is longer, at most max(max_gap, lost_after / 2)."""
    return min(max(max_gap, GAP_INTERVALS * interval), max(max_gap, 0.5 * lost_after))


_RX, _RY, _IV = ring("rx", "rr_n"), ring("ry", "rr_n"), ring("iv", "iv_n")
_INTERVAL = F_COL["interval"]


class UpdateRules(Bound):
    """The decisions between publishes, and their memory: fixes over the threshold in a row (`over`), the
    last few fix positions (`recent`, for the standing test), whether a fix gap halted the published guess
    (`halted`), and whether the next publish repositions a standing entity (`reposition`). The memory the
    fleet core also works on lives in a client-state row (entitynet/client/state.py: `state`, or a record of
    its own)."""

    over = column("over", "int")
    halted = column("halted", "bool")
    gap_limit = column("gap_lim")
    interval = column("interval")

    def __init__(self, etype: EntityType, *, periodic: bool, threshold: float, confirm: int, heartbeat: float,
                 max_validity: float, period: float, max_gap: float, lost_after: float,
                 state: tuple[Record, int] | None = None) -> None:
        st = state if state is not None else (Record(1), 0)
        if state is None:
            st[0].new_row()
        self.bind(*st)
        self.etype = etype
        self.periodic = periodic
        self.threshold, self.confirm = threshold, confirm
        self.heartbeat, self.max_validity, self.period = heartbeat, max_validity, period
        self.max_gap, self.lost_after = max_gap, lost_after
        _IV.clear(self)  # `intervals`: the last fix intervals (s), oldest first
        self.interval = 0.0  # their median (0: none observed yet)
        self.gap_limit = max_gap  # `gap_limit(max_gap, lost_after, interval)`
        self.over = 0
        self.reposition = False
        self.halted = False  # a fix gap stopped the published guess (the `gap` update)
        _RX.clear(self)  # `recent`: the last few fixes (on the network when placed)
        self._still: tuple[Model, tuple[float, float, float]] | None = None  # a standing ghost's answer

    @property
    def recent(self) -> list[tuple[float, float]]:
        """The last few fix positions, oldest first (a new list)."""
        return list(zip(_RX.get(self), _RY.get(self), strict=True))

    @property
    def intervals(self) -> list[float]:
        """The last fix intervals (s), oldest first (a new list)."""
        return _IV.get(self)

    def note_fix(self, x: float, y: float) -> None:
        """Remember a fix's position (the last five) for the standing test."""
        _RX.push(self, x)
        _RY.push(self, y, counted=False)

    def note_interval(self, dt: float) -> bool:
        """A fix came `dt` seconds after the previous one: the gap limit follows the feed's usual interval
        (an interval of `lost_after` or more is a loss, not the feed's cadence, and is not kept). Whether
        `interval` changed (and `gap_limit` with it; usually not, with a steady feed: then nothing is
        written but the interval kept)."""
        if not 0.0 < dt < self.lost_after:
            return False
        _IV.push(self, dt)
        kept = _IV.get(self)
        interval = usual_interval(kept) if len(kept) >= MIN_INTERVALS else 0.0
        f, b = self._st.f, self._fb + _INTERVAL
        if interval == f[b]:  # (`gap_limit` is a function of it and of constants: unchanged too)
            return False
        f[b] = interval
        self.gap_limit = gap_limit(self.max_gap, self.lost_after, interval)
        return True

    def forget(self) -> None:
        """A lost entity: its next fix starts afresh."""
        self._still = None
        _RX.clear(self)
        self.halted = False

    def published(self) -> None:
        """A publish went out: the drift count and a pending reposition start over."""
        self.over = 0
        self.reposition = False

    def validity(self, occupation: Occupation | None) -> float:
        """Seconds the last publish holds (its occupation's validity, or `max_validity` without cells)."""
        return occupation.validity if occupation is not None else self.max_validity

    def due(self, t: float, pub_t: float, occupation: Occupation | None) -> str | None:
        """"expiry" or "heartbeat" when the last publish (at `pub_t`) has run out at `t`, else None."""
        if t >= pub_t + self.validity(occupation):
            return "expiry"
        if t - pub_t >= self.heartbeat:
            return "heartbeat"
        return None

    def decide(self, t: float, ghost: Model, pub_t: float, occupation: Occupation | None, v_est: float,
               player: Player, estimate: Estimate = OWN_ESTIMATE) -> str | None:
        """The reason to publish after a fix at `t` (None: the ghost is still good). `v_est`: the estimated
        speed; the drift test of a moving ghost asks `estimate.position(player, t)`."""
        if self.periodic:
            if t - pub_t >= self.period - 1e-6:
                return "periodic"
            return self.due(t, pub_t, occupation)
        still = self._still
        if still is not None and still[0] is ghost:
            gx, gy, gv = still[1]
        else:
            gx, gy, gv = ghost.xy_speed_at(t)
            if isinstance(ghost, NetworkModel) and ghost.v == 0.0 and ghost.a == 0.0:
                # a standing network ghost (half the fixes of transit vehicles) answers the same at every t:
                # advance(0, 0, .) moves 0.0 and its braking plan is void (brake_plan gives inf at v = 0)
                self._still = (ghost, (gx, gy, gv))
        et = self.etype
        if gv > et.v_stop and v_est < et.v_stop and not self._halts_here(ghost, estimate, player, t):
            return "stop"
        if gv <= et.v_stop:
            # the published model stands still: judge by the mean of the last fixes, not by the filter,
            # whose speed wanders with the noise of a standing GPS (a start is speed *and* displacement)
            moved = False
            xs, ys = _RX.get(self), _RY.get(self)  # `recent`, as two lists
            for n, limit in ((5, self.threshold), (2, 1.6 * self.threshold)):
                tx, ty = xs[-n:], ys[-n:]
                mx = my = 0.0
                for px in tx:  # (the same additions in the same order as over the (x, y) pairs)
                    mx += px
                for py in ty:
                    my += py
                m = len(tx)
                moved = moved or math.hypot(mx / m - gx, my / m - gy) > limit
            if moved:
                if v_est > et.v_start:
                    return "start"
                if v_est <= et.v_stop:
                    self.reposition = True  # still standing, just somewhere else: publish standing there
                return "drift"  # (creeping between v_stop and v_start: publish the slow motion)
            return self.due(t, pub_t, occupation)
        ex, ey = estimate.position(player, t)
        drift = math.hypot(gx - ex, gy - ey)
        # `confirm` fixes in a row over the threshold (or one over 1.5x) make a drift update
        self.over = self.over + 1 if drift > self.threshold else 0
        if self.over >= self.confirm or drift > 1.5 * self.threshold:
            return "drift"
        return self.due(t, pub_t, occupation)

    def _halts_here(self, ghost: Model, estimate: Estimate, player: Player, t: float) -> bool:
        """Whether the published model halts by itself within HALT_NEAR x threshold of where the entity is now:
        at a planned halt (a transit stop on its route) or at its path's end (a terminal, a dead end), where
        every receiver's extrapolation stops. Then a stop is no news; only the drift test asks for a publish."""
        if not isinstance(ghost, NetworkModel):
            return False
        halt = ghost.path.length
        if math.isfinite(ghost.stop_s) and math.isfinite(ghost.plan[0]) and ghost.stop_s < halt:
            halt = ghost.stop_s
        hx, hy = ghost.path.xy(halt)
        ex, ey = estimate.position(player, t)
        return math.hypot(hx - ex, hy - ey) <= HALT_NEAR * self.threshold

    def on_tick(self, now: float, last_t: float | None, pub_t: float,
                occupation: Occupation | None) -> tuple[str | None, float | None]:
        """Time passes without a fix: (reason, stop_at). "lost" after `lost_after` seconds without a fix;
        "gap" once after `gap_limit` (stand where the guess was at `stop_at`); then "expiry" / "heartbeat"
        (continuing the published model, standing at `stop_at` when a gap halted it)."""
        gap = now - last_t if last_t is not None else 0.0
        if gap >= self.lost_after:
            return "lost", None
        stop_at = last_t + self.gap_limit if gap >= self.gap_limit else None
        if stop_at is not None and not self.halted:
            self.halted = True
            return "gap", stop_at
        return self.due(now, pub_t, occupation), stop_at
