"""Prometheus metrics of one server, in a registry of its own (several servers may share a process)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.exposition import choose_encoder

from entitynet.protocol import ErrorCode


class Metrics:
    """One server's Prometheus metrics, in a registry of its own so that several servers in one process
    (tests, the demo) do not collide."""

    def __init__(self) -> None:
        r = self.registry = CollectorRegistry()
        self.connections = Gauge("entitynet_connections", "open client connections", registry=r)
        self.entities = Gauge("entitynet_entities", "published entities", registry=r)
        self.subscriptions = Gauge("entitynet_subscriptions", "cell subscriptions over all clients", registry=r)
        self.follows = Gauge("entitynet_follows", "direct subscriptions over all clients", registry=r)
        self.updates_in = Counter("entitynet_updates_in", "accepted PUBLISH messages", registry=r)
        self.deliveries = Counter("entitynet_deliveries", "messages written to clients", registry=r)
        self.frames_out = Counter("entitynet_frames_out", "frames written to clients", registry=r)
        self.drops = Counter("entitynet_slow_consumer_drops", "clients dropped for not keeping up", registry=r)
        self.errors = Counter("entitynet_errors", "errors sent to clients", ["code"], registry=r)
        for code in ErrorCode:  # a zero sample per known code from the first scrape: rate() needs a baseline
            self.errors.labels(str(int(code)))
        self.latency = Histogram(
            "entitynet_queue_latency_seconds",
            "time from a connection's outbox becoming non-empty to its batch being written",
            buckets=(0.001, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5),
            registry=r,
        )
        self.gc_pause = Histogram(
            "entitynet_gc_full_pause_seconds", "scheduled full garbage collections (--gc-full-every) and their pause",
            buckets=(0.001, 0.005, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0), registry=r,
        )


def metrics_handler(registry: CollectorRegistry):
    """The /metrics route of the server's HTTP listener: the registry in the format the scraper accepts
    (Prometheus text, or OpenMetrics when asked for), negotiated as prometheus_client's own server does."""
    from entitynet.server.http import Response

    def handle(request) -> Response:
        accept = next((v.decode("latin-1") for k, v in request.headers if k == b"accept"), "")
        encode, content_type = choose_encoder(accept)
        return Response(200, encode(registry), content_type)

    return handle
