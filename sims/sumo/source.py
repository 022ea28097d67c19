"""A SUMO scenario as `Sim`'s mobility source, stepped in process through libsumo.

Why libsumo and not TraCI: the same API without a socket round trip per call and without a second process;
measured on the bundled scenario (485 entities), a step and its reads took about half the time through libsumo
(docs/sumo.md).

Each tick SUMO advances one step of the tick's length (its `--step-length` is set to the simulation's tick),
then every vehicle and every walking person is read (through libsumo's subscriptions: one call for all of
them, not a call per entity and value): position and heading, converted into our local
coordinates (the net's own projection and offset, read from its `<location>`, to the artifact's CRS and
origin). A vehicle becomes an entity by its vehicle class (passenger, taxi, delivery, truck...: car; bus,
coach: bus; tram, rail_urban: tram; bicycle, scooter: cyclist); a person walking: pedestrian. A person riding
a vehicle is not an entity of its own while it rides (the vehicle is); classes without an entity type here
(subway, rail, ship) are skipped and counted. The scenario's time 0 (its `begin`) stands for the run's `start`
(service-day seconds); with a `warmup`, SUMO first runs that many seconds alone (a scenario that starts
empty fills its streets) and the run's start is the end of the warm-up.

A scenario whose network does not overlap the topology artifact is refused with a clear error before the
first step.
"""

from __future__ import annotations

import math
import re
import time
import warnings
from collections import Counter
from pathlib import Path
from xml.etree.ElementTree import iterparse

import numpy as np

from sims.sumo import SumoError, missing
from sims.sumo.truth import SumoEntity, SumoWorld

#: SUMO vehicle class -> our entity type (None: not an entity here, counted as skipped)
VCLASS_TYPES = {
    "passenger": "car", "private": "car", "taxi": "car", "emergency": "car", "authority": "car", "army": "car",
    "vip": "car", "delivery": "car", "truck": "car", "trailer": "car", "motorcycle": "car", "moped": "car",
    "evehicle": "car", "custom1": "car", "custom2": "car", "hov": "car",
    "bus": "bus", "coach": "bus",
    "tram": "tram", "rail_urban": "tram",
    "bicycle": "cyclist", "scooter": "cyclist",
}
#: the share of the network's bounding box that must lie on the artifact's map
MIN_OVERLAP = 0.05
#: the source whose scenario libsumo holds now (one per process)
_loaded: SumoSource | None = None


class SumoSource:
    """Steps a SUMO scenario (`sumocfg`) and keeps its truth (`world`, a `SumoWorld`); see the module docstring."""

    def __init__(self, topo, sumocfg: str | Path, *, start: float, step: float, seed: int = 1,
                 warmup: float = 0.0, extra_args: tuple[str, ...] = ()):
        cfg = Path(sumocfg)
        if not cfg.is_file():
            raise SumoError(f"{cfg}: no such SUMO configuration")
        err = missing()
        if err:
            raise SumoError(err)
        if not (0.001 <= step <= 10.0):
            raise SumoError(f"the step must be within 1 ms..10 s, got {step!r}")
        if not (0.0 <= warmup <= 86400.0):
            raise SumoError(f"the warm-up must be within 0..86400 s, got {warmup!r}")
        self.warmup = warmup
        self.topo = topo
        self.cfg = cfg
        self.step_len = step
        self.seed = seed
        self.extra_args = tuple(extra_args)
        self.world = SumoWorld(topo, start)
        self.start_time = start
        net = net_file(cfg)
        self.to_local = local_converter(net, topo)
        check_overlap(net, topo, self.to_local)
        self.ids: dict[str, int] = {}  # SUMO id -> our entity id (live ones)
        self.kind: dict[str, str] = {}  # SUMO id -> "v" (vehicle) or "p" (person)
        self._next = 1
        self.skipped: Counter = Counter()
        self.sumo_s = 0.0  # wall seconds inside SUMO's own step
        self.read_s = 0.0  # wall seconds reading positions
        self.vehicle_s = 0.0  # simulated vehicle-seconds and person-seconds stepped
        self.person_s = 0.0
        self._t0 = 0.0
        self._running = False
        self._subscribed = False  # whether the first read has subscribed to everyone on the map
        self._first: list[SumoEntity] = []  # the entities on the map at the load, handed over by `start`
        self.ended_at: float | None = None  # the world's time when the scenario ended (its end time)
        self.end_reason: str | None = None
        self._load()

    def _load(self) -> None:
        """Load the scenario into libsumo (one simulation per process) now, so that a scenario SUMO refuses is
        a clear error before the run starts; closed at exit if nobody closes it."""
        import atexit

        import libsumo

        global _loaded
        if _loaded is not None:  # libsumo holds one simulation per process: the newer source replaces the older
            _loaded.close()
        args = ["sumo", "-c", str(self.cfg), "--step-length", f"{self.step_len:g}", "--seed", str(self.seed),
                "--no-step-log", "true", "--no-warnings", "true", *self.extra_args]
        try:
            libsumo.start(args)
        except Exception as exc:  # libsumo raises its own TraCIException / FatalTraCIError
            raise SumoError(f"SUMO cannot load {self.cfg}: {exc}") from None
        self._running = True
        _loaded = self
        self._t0 = libsumo.simulation.getTime()
        atexit.register(self.close)
        if self.warmup > 0:  # SUMO runs alone first, so the run starts on a filled map (its time 0 is after it)
            self.fast_forward(self.warmup)
        self._first = self._read()  # who is on the map now (the CLI's first line counts them)

    def fast_forward(self, seconds: float, each_step=None) -> None:
        """SUMO alone for `seconds`, without reading positions (what sets off is subscribed to as it goes), and
        the world's clock does not move: to fill a scenario's streets before a run. `each_step()` runs before
        each SUMO step (a demand top-up)."""
        import libsumo

        sim = libsumo.simulation
        t0 = sim.getTime()
        end = t0 + seconds
        while sim.getTime() + 1e-9 < end:
            if each_step is not None:
                each_step()
            libsumo.simulationStep(min(sim.getTime() + self.step_len, end))
            self._subscribe()
        self._t0 += sim.getTime() - t0

    # ---- the source ------------------------------------------------------------------------------------------
    def start(self) -> list[SumoEntity]:
        """The entities on the map at the scenario's begin."""
        if not self._running:
            raise SumoError(f"the SUMO scenario {self.cfg} was closed (libsumo runs one scenario per process)")
        first, self._first = self._first, []
        return first

    def step(self, dt: float) -> list[SumoEntity]:
        """One SUMO step of `dt` (the tick; SUMO steps in its own step length up to there); the new entities."""
        import libsumo

        if not dt > 0.0:
            raise ValueError(f"a step must move time forward, got dt={dt!r}")
        if self.ended_at is None and not self._running:  # closed (or replaced by a newer source): never step
            self._end("closed")  # the libsumo simulation that may be loaded now is another source's
        if self.ended_at is not None:
            self.world.moved(self.world.now + dt)
            return []
        end = libsumo.simulation.getEndTime()  # -1: none given
        if 0 <= end <= libsumo.simulation.getTime() + 1e-9:
            self._end("the scenario's end time")
            self.world.moved(self.world.now + dt)
            return []
        t = time.perf_counter()
        try:
            libsumo.simulationStep(libsumo.simulation.getTime() + dt)
        except Exception as exc:  # noqa: BLE001 - SUMO ended the scenario itself: the map empties
            self._end(f"{exc}".strip() or "ended")
            self.world.moved(self.world.now + dt)
            return []
        self.sumo_s += time.perf_counter() - t
        return self._read()

    def _end(self, why: str) -> None:
        """SUMO has ended: every entity leaves (their clients unpublish), the clock runs on without them."""
        self.ended_at = self.world.now
        self.end_reason = why
        for sid in list(self.ids):
            self.world.remove(self.ids.pop(sid), "scenario ended")
        self.close()

    def _subscribe(self) -> None:
        """Subscribe to the position, heading (and a person's vehicle) of every vehicle and person that set off
        since the last read (all of them on the first read): one call per step then reads them all. A person
        SUMO has loaded but who has not set off yet (waiting for its departure) is not on the map."""
        import libsumo

        sim = libsumo.simulation
        if self._subscribed:
            vehicles, persons = sim.getDepartedIDList(), sim.getDepartedPersonIDList()
        else:
            self._subscribed = True
            vehicles = libsumo.vehicle.getIDList()
            persons = [p for p in libsumo.person.getIDList()
                       if libsumo.person.getStage(p, 0).type != libsumo.STAGE_WAITING_FOR_DEPART]
        for v in vehicles:
            libsumo.vehicle.subscribe(v, (libsumo.VAR_POSITION, libsumo.VAR_ANGLE))
        for p in persons:
            libsumo.person.subscribe(p, (libsumo.VAR_POSITION, libsumo.VAR_ANGLE, libsumo.VAR_VEHICLE))

    def _read(self) -> list[SumoEntity]:
        import libsumo

        t0 = time.perf_counter()
        sim = libsumo.simulation
        w = self.world
        self._subscribe()
        pos_k, ang_k, veh_k = libsumo.VAR_POSITION, libsumo.VAR_ANGLE, libsumo.VAR_VEHICLE
        # libsumo keeps results of vehicles and persons gone (and of a closed simulation's): only the live ones
        vids, pids = set(libsumo.vehicle.getIDList()), set(libsumo.person.getIDList())
        vres = {k: r for k, r in libsumo.vehicle.getAllSubscriptionResults().items() if k in vids}
        pres = {k: r for k, r in libsumo.person.getAllSubscriptionResults().items() if k in pids}
        walking = {p: r for p, r in pres.items() if not r.get(veh_k)}
        gone = [s for s in self.ids if s not in vres and s not in walking]
        for sid in gone:
            w.remove(self.ids.pop(sid), "boarded" if sid in pres else "arrived")
            self.kind.pop(sid, None)
        new: list[SumoEntity] = []
        live_v = [v for v in vres if v in self.ids or self._admit(v, "v", new)]
        live_p = [p for p in walking if p in self.ids or self._admit(p, "p", new)]
        rows = [vres[v] for v in live_v] + [walking[p] for p in live_p]
        if rows:
            xy = self.to_local(np.array([r[pos_k] for r in rows], np.float64))
            # SUMO: degrees clockwise from north
            heading = np.radians(90.0 - np.array([r[ang_k] for r in rows], np.float64))
            agents, ids = w.agents, self.ids
            for sid, (x, y), h in zip(live_v + live_p, xy.tolist(), heading.tolist(), strict=True):
                e = agents[ids[sid]]
                e.x, e.y, e.heading = x, y, h
        self.vehicle_s += len(live_v) * self.step_len
        self.person_s += len(live_p) * self.step_len
        # the report's collision counters in SUMO's terms: a teleport is SUMO's way out of a jam (ours deletes
        # after a deadlock timeout), a collision is one SUMO let happen (ours accepts one after a timeout)
        tele, coll = sim.getStartingTeleportNumber(), sim.getCollidingVehiclesNumber()
        w.counters["teleports"] += tele
        w.counters["deleted"] += tele
        w.counters["collisions"] += coll
        w.counters["accepted"] += coll
        w.counters["stops_served"] += sim.getStopEndingVehiclesNumber()
        w.moved(self.start_time + sim.getTime() - self._t0)
        self.read_s += time.perf_counter() - t0
        return new

    def _admit(self, sid: str, kind: str, new: list[SumoEntity]) -> bool:
        """A SUMO vehicle or person seen for the first time: an entity of its type, or skipped and counted."""
        import libsumo

        if kind == "p":
            name, length = "pedestrian", 0.0
        else:
            vclass = libsumo.vehicle.getVehicleClass(sid)
            name = VCLASS_TYPES.get(vclass)
            if name is None:
                if sid not in self.kind:
                    self.skipped[vclass] += 1
                    self.kind[sid] = "skipped"
                return False
            length = libsumo.vehicle.getLength(sid)
        e = SumoEntity(self.world, self._next, sid, name, length)
        self._next += 1
        self.ids[sid] = e.id
        self.kind[sid] = kind
        self.world.add(e)
        new.append(e)
        return True

    def report(self) -> dict:
        """SUMO's section of the report: the scenario, skipped classes, positions off our network, where SUMO's
        time went (its own step, reading positions) and the simulated vehicle- and person-seconds."""
        w = self.world
        return {"source": "sumo", "sumocfg": str(self.cfg), "step_length_s": self.step_len,
                "skipped_vehicle_classes": dict(self.skipped), "off_network": w.off_network(),
                "teleports": w.counters["teleports"], "collisions": w.counters["collisions"],
                "sumo_step_s": self.sumo_s, "read_s": self.read_s,
                "vehicle_seconds": self.vehicle_s, "person_seconds": self.person_s, "ended_at": self.ended_at,
                "end_reason": self.end_reason}

    def close(self) -> None:
        """Close libsumo's simulation (so another can start in this process); safe to call twice."""
        global _loaded
        if self._running:
            import libsumo

            self._running = False
            if _loaded is self:
                _loaded = None
            try:
                libsumo.close()
            except Exception:  # noqa: BLE001 - already closed by SUMO itself (end of the scenario)
                pass


# ---- the scenario's files ------------------------------------------------------------------------------------
def net_file(cfg: Path) -> Path:
    """The network file a .sumocfg names (relative to the configuration's folder); a SumoError when missing."""
    try:
        for _ev, el in iterparse(cfg):
            if el.tag in ("net-file", "n"):
                net = Path(el.get("value", ""))
                net = net if net.is_absolute() else cfg.parent / net
                if not net.is_file():
                    raise SumoError(f"{cfg}: its network {net} does not exist")
                return net
    except SyntaxError as exc:  # ParseError
        raise SumoError(f"{cfg}: not a SUMO configuration ({exc})") from None
    raise SumoError(f"{cfg}: names no net-file")


def net_location(net: Path) -> dict[str, str]:
    """The network's `<location>` (netOffset, convBoundary, projParameter), read without loading the net."""
    try:
        for _ev, el in iterparse(net):
            if el.tag == "location":
                return dict(el.attrib)
            if el.tag in ("edge", "junction"):
                break
    except SyntaxError as exc:
        raise SumoError(f"{net}: not a SUMO network ({exc})") from None
    raise SumoError(f"{net}: a SUMO network without <location> (cannot tell where it lies)")


def _pair(text: str) -> tuple[float, ...]:
    vals = tuple(float(v) for v in re.split(r"[ ,]+", text.strip()))
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(text)
    return vals


def local_converter(net: Path, topo):
    """SUMO x/y (n, 2) -> our local x/y: undo the net's offset, reproject from its projection to the artifact's
    CRS, subtract the artifact's origin. A net without a projection ("!") is taken as already local."""
    loc = net_location(net)
    proj = loc.get("projParameter", "!").strip()
    try:
        ox, oy = _pair(loc.get("netOffset", "0,0"))[:2]
    except ValueError:
        raise SumoError(f"{net}: bad netOffset {loc.get('netOffset')!r}") from None
    if proj in ("", "!"):
        return lambda xy: np.asarray(xy, np.float64).reshape(-1, 2)
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tf = Transformer.from_crs(CRS.from_user_input(proj), CRS.from_user_input(topo.meta["crs"]),
                                      always_xy=True)
    except CRSError as exc:
        raise SumoError(f"{net}: its projection {proj!r} is unknown here ({exc})") from None
    cx, cy = topo.meta["origin"]
    # the same projection as ours (the bundled scenario's): a translation, checked over the map's extent
    lo, hi = topo.node_xy.min(axis=0) - 1000.0, topo.node_xy.max(axis=0) + 1000.0
    probe = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]], (lo + hi) / 2])
    px, py = tf.transform(probe[:, 0] + cx, probe[:, 1] + cy)
    shift = np.column_stack([np.asarray(px) - cx, np.asarray(py) - cy]) - probe
    if np.isfinite(shift).all() and np.abs(shift - shift[0]).max() < 1e-3:
        d = np.array([shift[0, 0] - ox - cx, shift[0, 1] - oy - cy])  # local = sumo - offset + shift - origin

        def translate(xy: np.ndarray) -> np.ndarray:
            return np.asarray(xy, np.float64).reshape(-1, 2) + d

        return translate

    def convert(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        x, y = tf.transform(xy[:, 0] - ox, xy[:, 1] - oy)
        return np.column_stack([np.asarray(x) - cx, np.asarray(y) - cy])

    return convert


def check_overlap(net: Path, topo, to_local) -> float:
    """The share of the network's bounding box on the artifact's map; a SumoError that says where each lies
    when it is below MIN_OVERLAP (a scenario of another city)."""
    loc = net_location(net)
    try:
        x0, y0, x1, y1 = _pair(loc.get("convBoundary", ""))[:4]
    except ValueError:
        raise SumoError(f"{net}: bad convBoundary {loc.get('convBoundary')!r}") from None
    corners = to_local(np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]))
    if not np.isfinite(corners).all():
        raise SumoError(f"{net}: its boundary does not project into the map's CRS {topo.meta['crs']}")
    a0, b0 = corners.min(axis=0)
    a1, b1 = corners.max(axis=0)
    m0, n0 = topo.node_xy.min(axis=0)
    m1, n1 = topo.node_xy.max(axis=0)
    ix = max(0.0, min(a1, m1) - max(a0, m0))
    iy = max(0.0, min(b1, n1) - max(b0, n0))
    area = max((a1 - a0) * (b1 - b0), 1e-9)
    share = ix * iy / area
    if share < MIN_OVERLAP:
        raise SumoError(
            f"the SUMO scenario's network ({net.name}: local x {a0:.0f}..{a1:.0f}, y {b0:.0f}..{b1:.0f} m in "
            f"{topo.meta['crs']} around the map's origin) does not overlap the topology's map (x {m0:.0f}..{m1:.0f},"
            f" y {n0:.0f}..{n1:.0f} m): {share:.0%} of it lies on the map. Use a scenario of this map's city (e.g. "
            "`entitynet sumo scenario`) or build a topology of the scenario's city (`entitynet topology build`)")
    return share
