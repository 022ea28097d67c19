"""ETA-driven motion of one vehicle along its route (sans-IO, explicit `now`).

The tracker says, a few times a minute and several seconds late, which stop a vehicle goes to next and when it
is expected there (to the minute). From that the vehicle is moved continuously along its route's path
coordinate `s`:
- **never backwards** and **never standing between stops**: the speed is at least `v_min` while the next stop
  is ahead, zero only at a stop;
- towards the next stop at the speed that reaches it at its ETA, from the remaining distance and time, within
  the type's maximum, with acceleration `accel` and braking `brake` (a vehicle brakes into the stop in time);
- when the ETA has passed and the vehicle was not reported past the stop it arrives as soon as it can and waits
  there (the stop is where a late vehicle stands);
- when it is reported past stops it has not reached yet, it goes on through them without stopping until it has
  caught up (`behind`);
- at a stop it dwells until the expected departure (or `dwell` seconds), then goes on to the following stop on
  its last ETAs, and past those on the schedule's run times plus its last known delay.

One-minute ETA granularity makes the arrival time uncertain by half a minute either way: the target is the
middle of what is still possible (`_arrival`), and a departure is taken from the tracker's next answer rather
than from a rounded departure time that may be early.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

STEP = 0.5  # s: integration step


@dataclass
class Limits:
    """Motion bounds of one vehicle type: the floor `v_min` keeps a vehicle from standing between stops,
    `dwell` is the stop time when no departure is known."""
    vmax: float
    accel: float = 1.0
    brake: float = 1.0
    v_min: float = 1.5  # m/s while between stops
    dwell: float = 15.0  # s at a stop when no departure time is known


class EtaMotion:
    """The motion of one vehicle. Stops are given as path coordinates in travel order (`stop_s`) with their
    schedule (`sched`: seconds of arrival and departure from the trip's start, for the fallback)."""

    def __init__(self, stop_s: list[float], sched: list[tuple[float, float]], limits: Limits, *,
                 granularity: float = 60.0) -> None:
        if len(stop_s) != len(sched) or not stop_s:
            raise ValueError("a route needs its stops with their schedule")
        if any(b < a for a, b in zip(stop_s, stop_s[1:], strict=False)):
            raise ValueError("stop coordinates must not decrease")
        self.stop_s = list(stop_s)
        self.sched = list(sched)
        self.lim = limits
        self.granularity = float(granularity)
        self.dwell_slack = 0.5  # a rounded departure time may be this many granularities early
        self.t: float | None = None
        self.s = stop_s[0]
        self.v = 0.0
        self.target = 0  # index of the stop we move to (or stand at)
        self.eta: dict[int, float] = {}  # stop index -> expected arrival (local seconds)
        self.etd: dict[int, float] = {}
        self.delay = 0.0  # last known (expected - scheduled), for the schedule fallback
        self.trip_start: float | None = None  # local time of the trip's scheduled first departure, if known
        self.dwell_until: float | None = None
        self.left_at: float | None = None  # when we left the last stop (for the schedule's run time)
        self.standing = True
        self.last_obs: float | None = None
        self.creep_until = -math.inf
        self.stops_served = 0  # stops it came to stand at (passing through one does not serve it)

    # ---- observations -------------------------------------------------------------------------------------
    def place(self, s: float, now: float, target: int) -> None:
        """Start at path coordinate `s` moving to stop `target` (a vehicle first seen between stops)."""
        self.t, self.s, self.target = now, float(s), target
        self.v = 0.0
        self.standing = False
        self.left_at = now

    def observe(self, now: float, etas: dict[int, float], etds: dict[int, float] | None = None,
                at_stop: int | None = None, aimed: dict[int, float] | None = None,
                location_s: float | None = None) -> None:
        """A poll's news: ETAs (and departures) of the stops ahead by stop index; `at_stop` when the tracker
        says the vehicle stands at that stop; `aimed` scheduled arrivals (for the delay); `location_s` the
        path coordinate of a reported VehicleLocation."""
        self.advance(now)
        self.last_obs = now
        if etas:
            self.eta = dict(etas)
            self.etd = dict(etds or {})
            nxt = min(etas)
            if aimed:
                k = min(aimed, key=lambda i: abs(i - nxt))
                if k in etas:
                    self.delay = etas[k] - aimed[k]
                    self.trip_start = aimed[k] - self.sched[k][0]
            if at_stop is not None and at_stop < nxt:
                nxt = at_stop
            if nxt > self.target:
                # reported past the stop we were going to (or standing at): go on, through it
                self.target = nxt
                if self.standing:
                    self._depart(now)
        if location_s is not None and location_s > self.s + 5.0:
            # a reported position ahead of ours: move up to it at once along the route (never back)
            self.s = min(location_s, self.stop_s[self.target])
            self.v = max(self.v, self.lim.v_min)
            self.standing = False
        elif location_s is not None and location_s < self.s - 5.0 and not self.standing:
            # we are ahead of the reported position: creep (never back, never standing) until it has caught up
            # at the speed it needs for the ETA
            lead = self.s - location_s
            self.creep_until = now + lead / max(self.v, 4.0)

    def _depart(self, now: float) -> None:
        self.standing = False
        self.dwell_until = None
        self.left_at = now

    # ---- the target time ------------------------------------------------------------------------------------
    def _arrival(self, j: int, t: float) -> float | None:
        """When to reach stop j, as seen at time t: with an ETA rounded to `granularity` the true arrival lies
        anywhere in ETA +- granularity/2; a vehicle not there yet will arrive in [max(t, ETA - g/2), ETA + g/2],
        and the middle of that is the target (it moves later while the vehicle is not seen at the stop). Without
        an ETA: the schedule plus the last delay; else None (no opinion: cruise)."""
        eta = self.eta.get(j)
        if eta is not None:
            half = 0.5 * self.granularity
            if half <= 0.0:
                return eta
            lo, hi = max(eta - half, t), eta + half
            return 0.5 * (lo + hi) if hi > t else t
        if self.trip_start is not None:
            return self.trip_start + self.sched[j][0] + self.delay
        return None

    # ---- motion ---------------------------------------------------------------------------------------------
    def advance(self, now: float) -> tuple[float, float]:
        """Move to `now`; returns (s, v)."""
        if self.t is None:
            self.t = now
            return self.s, self.v
        if self.standing and (self.target >= len(self.stop_s) - 1
                              or self.dwell_until is not None and now < self.dwell_until):
            # dwelling (or at the end of the route) until after `now`: every step would leave it standing
            self.t = max(self.t, now)
            return self.s, self.v
        while self.t < now - 1e-9:
            dt = min(STEP, now - self.t)
            self._step(self.t, dt)
            self.t += dt
        return self.s, self.v

    def _step(self, t: float, dt: float) -> None:
        lim = self.lim
        n = len(self.stop_s)
        if self.standing:
            if self.target >= n - 1:
                return  # at the end of the route
            until = self.dwell_until
            if until is None:
                # a rounded departure time may be half a granularity early; the next poll showing the vehicle
                # past the stop (`observe`) ends the dwell sooner
                etd = self.etd.get(self.target)
                until = t + lim.dwell if etd is None else etd + self.dwell_slack * self.granularity
                self.dwell_until = until
            if t + dt < until:
                return
            self.target += 1
            self._depart(t)
        j = self.target
        goal = self.stop_s[j]
        dist = goal - self.s
        if dist <= 0.05:
            self._arrive(t)
            return
        arrive = self._arrival(j, t)
        v_brake = math.sqrt(2.0 * lim.brake * dist)
        if arrive is None or arrive - t <= dt:
            v_des = lim.vmax  # late (or no time known): as fast as allowed
        else:
            T = arrive - t
            # cruise speed v so that cruising then braking at `brake` covers dist in T: dist = vT - v^2/(2b)
            bt = lim.brake * T
            disc = bt * bt - 2.0 * lim.brake * dist
            v_des = bt - math.sqrt(disc) if disc >= 0.0 else lim.vmax
        v_des = min(v_des, lim.vmax, v_brake)
        if t < self.creep_until:
            v_des = lim.v_min
        v_des = max(v_des, min(lim.v_min, v_brake))
        if v_des > self.v:
            v = min(v_des, self.v + lim.accel * dt)
        else:
            v = max(v_des, self.v - lim.brake * dt * 1.5)
        v = max(v, min(lim.v_min, v_brake))
        ds = 0.5 * (self.v + v) * dt
        if ds >= dist:
            self.s = goal
            self._arrive(t + dt)
            return
        self.s += ds
        self.v = v

    def _arrive(self, t: float) -> None:
        self.s = self.stop_s[self.target]
        ahead = [k for k in self.eta if k > self.target]
        if self.eta and min(self.eta) > self.target and ahead:
            # the tracker already has it past this stop: we are behind, go straight on
            self.target = min(ahead)
            self.left_at = t
            return
        self.v = 0.0
        self.standing = True
        self.dwell_until = None
        self.stops_served += 1

    @property
    def finished(self) -> bool:
        """Standing at the last stop of the route: the vehicle can leave the map."""
        return self.standing and self.target >= len(self.stop_s) - 1
