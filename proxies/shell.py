"""The transit proxy's trio shell: polls the tracker, runs the fleet core, publishes over one connection.

All blocking work (zeep and requests, parsing answers) runs in a worker thread (`trio.to_thread`), so the trio
loop only moves bytes and ticks. Every failure of a poll is logged, counted by kind (Prometheus) and survived:
the vehicles keep moving on their last ETAs and then on the schedule, and leave once their data is older than
`stale_after`; the next good answer brings everything back, without a restart. The one `Connection` to the
server reconnects by itself and re-publishes the fleet's latest state.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import requests
import trio
from prometheus_client import CollectorRegistry, Counter, Gauge

from entitynet.connection import Connection
from entitynet.protocol import Publish, Unpublish
from proxies import gtfsrt
from proxies.fleet import Fleet
from proxies.routes import RouteBook
from proxies.siri_client import HttpError, StopMonitoringClient, Timeout, Unreachable
from proxies.siri_xml import SiriError, SoapFault, parse_response

log = logging.getLogger("proxies.proxy")


class ProxyMetrics:
    """Counters of one proxy, in a registry of its own."""

    def __init__(self) -> None:
        r = self.registry = CollectorRegistry()
        self.polls = Counter("entitynet_proxy_polls", "polls of the tracker", registry=r)
        self.errors = Counter("entitynet_proxy_errors", "failed polls by kind", ["kind"], registry=r)
        self.request_errors = Counter("entitynet_proxy_request_errors", "failed requests of polls that went on with "
                                      "their other requests, by kind", ["kind"], registry=r)
        self.not_sent = Counter("entitynet_proxy_requests_not_sent", "requests left out of a poll once its "
                                "failures had used up its time", registry=r)
        self.calls = Counter("entitynet_proxy_calls", "stop visits / positions received", registry=r)
        self.discarded = Counter("entitynet_proxy_calls_discarded", "received but not used", registry=r)
        self.vehicles = Gauge("entitynet_proxy_vehicles", "vehicles on the map", registry=r)
        self.publishes = Counter("entitynet_proxy_publishes", "PUBLISH messages sent", registry=r)
        self.retired = Counter("entitynet_proxy_retired", "vehicles that left", ["why"], registry=r)
        self.last_success = Gauge("entitynet_proxy_last_success_timestamp", "time of the last good poll",
                                  registry=r)

    def value(self, name: str, **labels) -> float:
        """Current value of a counter or gauge sample (0 if never set): for tests and the benchmark."""
        v = self.registry.get_sample_value(name, labels or None)
        return 0.0 if v is None else v


def error_kind(exc: BaseException) -> str:
    """The metrics label of a failed poll (soap_fault, http_5xx, timeout, ...), so operators can tell
    an overloaded service from an unreachable one."""
    if isinstance(exc, SoapFault):
        return "soap_fault"
    if isinstance(exc, HttpError):
        return f"http_{exc.status // 100}xx"
    if isinstance(exc, Timeout):
        return "timeout"
    if isinstance(exc, Unreachable):
        return "unreachable"
    if isinstance(exc, gtfsrt.FeedError):
        return "malformed_protobuf"
    if isinstance(exc, SiriError):
        return "malformed"
    return "other"


@dataclass
class ProxyConfig:
    """Where the proxy publishes and how often it polls; `stale_after` retires vehicles the tracker
    has stopped reporting."""
    server: tuple[str, int] | str
    token: str = ""
    poll: float = 20.0
    tick: float = 1.0
    timeout: float = 10.0
    stale_after: float = 300.0
    poll_grace: float = 5.0  # seconds a poll may take past three timeouts (parsing its answers) before it is dropped

    @property
    def poll_limit(self) -> float:
        """Seconds one poll may take before the shell gives up on it (and on all its answers)."""
        return 3.0 * self.timeout + self.poll_grace

    @property
    def send_budget(self) -> float:
        """Seconds into a poll after which no more requests are sent: the last one sent may take a timeout more,
        which still leaves half the grace under `poll_limit` for parsing, so the answers got are kept."""
        return 2.0 * self.timeout + self.poll_grace / 2.0


class ProxyShell:
    """Runs one fleet against one source (`source` is a blocking callable returning the poll's news)."""

    def __init__(self, topo, book: RouteBook, config: ProxyConfig, *, fleet: Fleet | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        from topology.projection import LocalProjection

        self.topo = topo
        self.book = book
        self.config = config
        self.clock = clock
        self.fleet = fleet or Fleet(topo, book, stale_after=config.stale_after)
        self.metrics = ProxyMetrics()
        self.conn = Connection(config.server, topo.digest, config.token, on_message=self._on_message)
        self._proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
        self.good_polls = 0
        self.last_error: str | None = None
        self.ready = trio.Event()  # set after the first good poll
        # one poll thread at a time: a poll abandoned at its time limit still runs (and uses its client) until its
        # request ends, and the next poll waits for it instead of sharing the client with it
        self._poll_thread = trio.CapacityLimiter(1)

    def counts(self) -> dict:
        """Its vehicles by mode and the stops they served, in the shape of the simulation's counts: the demo runs
        the proxy as a part that publishes into its server, and its summary adds these to its own."""
        return {"entities": self.fleet.by_mode(), "stops_served": self.fleet.stops_served()}

    def to_local(self, lon: float, lat: float) -> tuple[float, float]:
        """Map a reported lon/lat into the artifact's local frame (VehicleLocation, GTFS-rt positions)."""
        p = self._proj.to_local(np.array([lon]), np.array([lat]))[0]
        return float(p[0]), float(p[1])

    def _on_message(self, m) -> None:
        pass  # the proxy only publishes; errors from the server are logged by the connection

    # ---- the loop --------------------------------------------------------------------------------------------
    async def run(self, poller: Callable[[], list], task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Connect, then poll and tick until cancelled. `poller` is blocking: it runs in a worker thread."""
        async with trio.open_nursery() as n:
            await n.start(self.conn.run)
            n.start_soon(self._poll_loop, poller)
            n.start_soon(self._tick_loop)
            task_status.started(self)

    async def _poll_loop(self, poller) -> None:
        while True:
            t0 = self.clock()
            self.metrics.polls.inc()
            try:
                with trio.fail_after(self.config.poll_limit):
                    news = await trio.to_thread.run_sync(poller, abandon_on_cancel=True, limiter=self._poll_thread)
                self.last_error = None  # a poll that went on past failed requests names them (`_partly_failed`)
                for apply in news:  # the fleet is only touched on the trio thread
                    apply()
                self.good_polls += 1
                self.metrics.last_success.set(self.clock())
                self.ready.set()
            except trio.TooSlowError:
                self._failed("timeout", "the poll did not finish")
            except (SiriError, gtfsrt.FeedError, requests.RequestException) as exc:
                self._failed(error_kind(exc), str(exc))
            except Exception as exc:  # noqa: BLE001 - an answer nobody foresaw must not stop the proxy
                log.exception("poll failed unexpectedly")
                self._failed("other", f"{type(exc).__name__}: {exc}")
            self.metrics.vehicles.set(len(self.fleet.vehicles))
            await trio.sleep(max(self.config.poll - (self.clock() - t0), 0.0))

    def _failed(self, kind: str, text: str) -> None:
        self.metrics.errors.labels(kind).inc()
        self.last_error = kind
        log.warning("poll failed (%s): %.300s", kind, text)

    def _partly_failed(self, failures: list[SiriError], not_sent: int, requests: int) -> None:
        """A poll that used its good answers although some requests failed: each failure counted by kind."""
        kinds = [error_kind(exc) for exc in failures]
        for kind in kinds:
            self.metrics.request_errors.labels(kind).inc()
        self.metrics.not_sent.inc(not_sent)
        self.last_error = ",".join(sorted(set(kinds)))
        log.warning("poll went on past %d failed request(s) of %d (%s), %d not sent: %.300s", len(failures),
                    requests, self.last_error, not_sent, failures[0] if failures else "")

    async def _tick_loop(self) -> None:
        last_pub = 0
        while True:
            msgs = self.fleet.tick(self.clock())
            pubs = [m for m in msgs if isinstance(m, Publish)]
            if pubs:
                await self.conn.publish(*pubs)
            for m in msgs:
                if isinstance(m, Unpublish):
                    await self.conn.unpublish(m.entity)
            c = self.fleet.counters
            self.metrics.publishes.inc(c.publishes - last_pub)
            last_pub = c.publishes
            await trio.sleep(self.config.tick)

    # ---- sources -----------------------------------------------------------------------------------------
    def siri_poller(self, client: StopMonitoringClient) -> Callable[[], None]:
        """A blocking poll of every route stop over SIRI (called in a worker thread)."""
        stops = list(self.book.stops)

        def poll() -> list[Callable[[], None]]:
            deadline = time.monotonic() + self.config.send_budget  # the answers got by then are kept
            fetched = client.fetch(stops, deadline)  # raises when every request failed: the poll failed
            received = self.clock()
            news, failures = [], list(fetched.failures)
            for raw in fetched.answers:
                try:
                    d = parse_response(raw)  # every answer parses before any is used
                except SiriError as exc:  # an unusable answer is one more failed request
                    failures.append(exc)
                    continue
                news.append(lambda d=d: self._count(len(d.calls), lambda: self.fleet.ingest(
                    d.calls, d.response_time, received, to_local=self.to_local)))
            if failures and not news:
                raise failures[0]
            if failures or fetched.not_sent:
                requests = len(fetched.answers) + len(fetched.failures) + fetched.not_sent
                news.append(lambda: self._partly_failed(failures, fetched.not_sent, requests))
            return news
        return poll

    def gtfsrt_poller(self, vehicle_positions: str | None, trip_updates: str | None,
                      session: requests.Session | None = None) -> Callable[[], None]:
        """A blocking poller for `run`: fetch the GTFS-rt feeds, classify failures as the SIRI ones
        (so they share metrics) and feed positions and trip updates to the fleet."""
        session = session or requests.Session()
        timeout = self.config.timeout

        def get(url: str) -> bytes:
            try:
                r = session.get(url, timeout=timeout)
            except requests.Timeout as exc:
                raise Timeout(f"no answer from {url} within {timeout} s") from exc
            except requests.RequestException as exc:
                raise Unreachable(f"cannot reach {url}: {exc}") from exc
            if r.status_code >= 400:
                raise HttpError(r.status_code, r.reason or "")
            return r.content

        def poll() -> list[Callable[[], None]]:
            news = []
            if trip_updates:
                data = get(trip_updates)
                r1 = self.clock()
                s1, calls = gtfsrt.parse_trip_updates(data)
                news.append(lambda: self._count(len(calls), lambda: self.fleet.ingest(
                    calls, s1, r1, to_local=self.to_local)))
            if vehicle_positions:
                data = get(vehicle_positions)
                r2 = self.clock()
                s2, positions = gtfsrt.parse_vehicle_positions(data)
                news.append(lambda: self._count(len(positions), lambda: self.fleet.ingest_positions(
                    positions, self.fleet.clock_offset(s2, r2), self.to_local)))
            return news
        return poll

    def _count(self, n: int, ingest) -> None:
        c = self.fleet.counters
        used0 = c.used
        ingest()
        self.metrics.calls.inc(n)
        self.metrics.discarded.inc(max(n - (c.used - used0), 0))

