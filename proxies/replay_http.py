"""The replay producer's HTTP service (trio + h11): SIRI StopMonitoring over SOAP and GTFS-realtime feeds from a
`ReplayWorld`, with the faults a real operator's service has, injectable.

Endpoints (any path not listed: 404):
- `POST /siri`: SOAP 1.1 GetStopMonitoring / GetMultipleStopMonitoring (the CEN RPC shape);
- `GET /gtfs-rt/vehicle-positions`, `GET /gtfs-rt/trip-updates`: protobuf FeedMessages;
- `GET /truth`: JSON {"t": service seconds, "vehicles": {id: [lon, lat, journey]}};
- `POST /control?outage=S` (no answers for S seconds: every request gets 503), `POST /control?fault=KIND&count=N`
  (the next N answers fail as KIND; `none` answers them normally, to place faults later in the queue), for tests
  and the benchmark.

Fault kinds: `soap` (a SOAP Fault, HTTP 500), `http500`, `http503`, `http404`, `garbage` (200 with bytes that
are neither XML nor protobuf), `truncated` (200 with the answer cut in half), `empty` (200, an empty delivery),
`slow` (answers after `slow_s`, past any sane client timeout). `fault_rate` draws one at random per request.
"""

from __future__ import annotations

import json
import logging
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

import h11
import trio

from proxies import gtfsrt
from proxies.replay_core import ReplayWorld
from proxies.siri_xml import ServiceClock, SiriError, build_fault, build_response, parse_request_stops

log = logging.getLogger("proxies.replay")
FAULTS = ("soap", "http500", "http503", "http404", "garbage", "truncated", "empty", "slow")
MAX_BODY = 4 << 20


@dataclass
class ReplayConfig:
    """How the replay service misbehaves (latency, fault rate, slow answers) and how much it answers,
    so a proxy's fault handling can be exercised on loopback."""
    host: str = "127.0.0.1"
    port: int = 0
    latency: float = 0.0  # seconds before every answer
    fault_rate: float = 0.0
    slow_s: float = 60.0
    seed: int = 1
    preview: float = 1800.0  # seconds of visits per stop when the request names none
    max_visits: int | None = None


@dataclass
class ReplayState:
    """What the service counts and what tests and the benchmark steer."""

    requests: int = 0
    faults: dict[str, int] = field(default_factory=dict)
    forced: list[str] = field(default_factory=list)
    outage_until: float = 0.0
    stops_asked: int = 0


class ReplayService:
    """Answers requests from `world` at service time `now_fn()`."""

    def __init__(self, world: ReplayWorld, clock: ServiceClock, now_fn: Callable[[], float],
                 config: ReplayConfig | None = None) -> None:
        self.world = world
        self.clock = clock
        self.now_fn = now_fn
        self.config = config or ReplayConfig()
        self.state = ReplayState()
        self.rng = random.Random(self.config.seed)
        self.port = 0

    # ------------------------------------------------------------------------------------------ answers
    def _fault(self) -> str | None:
        st = self.state
        if time.monotonic() < st.outage_until:
            return "http503"
        if st.forced:
            kind = st.forced.pop(0)
            return None if kind == "none" else kind
        if self.config.fault_rate > 0.0 and self.rng.random() < self.config.fault_rate:
            return self.rng.choice(FAULTS[:-1])  # random faults never hang: `slow` is asked for explicitly
        return None

    def answer(self, method: str, target: str, body: bytes) -> tuple[int, str, bytes, float]:
        """(status, content type, body, extra delay) for one request."""
        url = urlsplit(target)
        path, query = url.path.rstrip("/") or "/", parse_qs(url.query)
        if path == "/control" and method == "POST":
            if "outage" in query:
                self.state.outage_until = time.monotonic() + float(query["outage"][0])
            if "fault" in query:
                kind = query["fault"][0]
                if kind not in FAULTS and kind != "none":
                    return 400, "text/plain", f"unknown fault {kind!r}".encode(), 0.0
                self.state.forced.extend([kind] * int(query.get("count", ["1"])[0]))
            return 200, "text/plain", b"ok", 0.0
        if path == "/truth" and method == "GET":
            now = self.now_fn()
            doc = {"t": now, "vehicles": {k: list(v) for k, v in self.world.truth(now).items()}}
            return 200, "application/json", json.dumps(doc).encode(), 0.0
        kind = {"/siri": "siri", "/gtfs-rt/vehicle-positions": "vp", "/gtfs-rt/trip-updates": "tu"}.get(path)
        if kind is None:
            return 404, "text/plain", b"not found", 0.0
        if (kind == "siri") != (method == "POST"):
            return 405, "text/plain", b"method not allowed", 0.0
        self.state.requests += 1
        fault = self._fault()
        if fault is not None:
            self.state.faults[fault] = self.state.faults.get(fault, 0) + 1
        if fault in ("http500", "http503", "http404"):
            return int(fault[4:]), "text/html", b"<html><body>error</body></html>", 0.0
        if fault == "garbage":
            return 200, "text/xml" if kind == "siri" else "application/x-protobuf", b"\x00\xffgarbage<<\x01", 0.0
        if fault == "soap" and kind == "siri":
            return 500, "text/xml; charset=utf-8", build_fault("soapenv:Server", "backend unavailable"), 0.0
        now = self.now_fn()
        ctype = "text/xml; charset=utf-8"
        if kind == "siri":
            try:
                _op, stops = parse_request_stops(body)
            except SiriError as exc:
                return 500, ctype, build_fault("soapenv:Client", str(exc)), 0.0
            self.state.stops_asked += len(stops)
            visits = [] if fault == "empty" else self.world.visits(stops, now, self.config.preview,
                                                                   self.config.max_visits)
            op = _op if _op in ("GetStopMonitoring", "GetMultipleStopMonitoring") else "GetStopMonitoring"
            data = build_response(visits, now, self.clock, operation=op)
        else:
            ctype = "application/x-protobuf"
            if kind == "vp":
                data = gtfsrt.build_vehicle_positions([] if fault == "empty" else self.world.vehicle_states(now),
                                                      now, self.clock)
            else:
                stops = list(self.world.by_stop)
                data = gtfsrt.build_trip_updates([] if fault == "empty" else self.world.visits(stops, now, 1200.0),
                                                 now, self.clock)
        if fault == "truncated":
            data = data[: len(data) // 2]
        return 200, ctype, data, self.config.slow_s if fault == "slow" else 0.0

    # ------------------------------------------------------------------------------------------ HTTP
    async def serve(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Listen and answer SOAP/GTFS-rt requests until cancelled; reports itself (with the bound
        port, for port 0) through `task_status`."""
        listeners = await trio.open_tcp_listeners(self.config.port, host=self.config.host)
        self.port = listeners[0].socket.getsockname()[1]
        task_status.started(self)
        await trio.serve_listeners(self._handle, listeners)

    async def _handle(self, stream) -> None:
        conn = h11.Connection(h11.SERVER, max_incomplete_event_size=MAX_BODY)
        try:
            while True:
                req, body = await self._read_request(conn, stream)
                if req is None:
                    return
                status, ctype, data, delay = self.answer(req.method.decode(), req.target.decode("latin-1"), body)
                if self.config.latency > 0.0 or delay > 0.0:
                    await trio.sleep(self.config.latency + delay)
                headers = [("content-type", ctype), ("content-length", str(len(data)))]
                await stream.send_all(conn.send(h11.Response(status_code=status, headers=headers)))
                await stream.send_all(conn.send(h11.Data(data=data)))
                await stream.send_all(conn.send(h11.EndOfMessage()))
                if conn.our_state is h11.MUST_CLOSE:
                    return
                conn.start_next_cycle()
        except (h11.RemoteProtocolError, trio.BrokenResourceError, trio.ClosedResourceError, OSError) as exc:
            log.debug("connection dropped: %s", exc)
        finally:
            await stream.aclose()

    async def _read_request(self, conn: h11.Connection, stream):
        req, chunks, size = None, [], 0
        while True:
            ev = conn.next_event()
            if ev is h11.NEED_DATA:
                data = await stream.receive_some(65536)
                conn.receive_data(data)
                continue
            if isinstance(ev, h11.Request):
                req = ev
            elif isinstance(ev, h11.Data):
                size += len(ev.data)
                if size > MAX_BODY:
                    raise h11.RemoteProtocolError("request body too large")
                chunks.append(ev.data)
            elif isinstance(ev, h11.EndOfMessage):
                return req, b"".join(chunks)
            elif isinstance(ev, h11.ConnectionClosed):
                return None, b""


def wall_service_clock(start: float, speed: float = 1.0) -> Callable[[], float]:
    """Service seconds that run with the wall clock from `start` (service seconds) now."""
    t0 = time.monotonic()
    return lambda: start + (time.monotonic() - t0) * speed


async def record_truth(service: ReplayService, path: str, every: float = 1.0) -> None:
    """Append the true positions to `path` (JSON lines: {"t", "epoch", "vehicles"}) every `every` seconds."""
    with open(path, "a", encoding="utf-8") as fh:
        while True:
            now = service.now_fn()
            doc = {"t": now, "epoch": service.clock.epoch(now),
                   "vehicles": {k: [round(v[0], 7), round(v[1], 7)] for k, v in service.world.truth(now).items()}}
            fh.write(json.dumps(doc) + "\n")
            fh.flush()
            await trio.sleep(every)
