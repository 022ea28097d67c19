"""The trio shell joining one switchboard server to the cluster: NATS in and out for the sans-IO ClusterCore.

Why so thin: everything that decides (what to publish, what to subscribe, ownership, REDIRECTs, failover) is in
entitynet.cluster.core and tested without sockets; this task only moves bytes. NATS messages are handled in the
NATS reader task, synchronously (the core is sans-IO, the switchboard's outboxes are written by the server's
flusher); publications queued by the core are handed to the NATS client when the core wakes the pump (after up to
the server's latency budget, so that a light shard's publications share one write), and SUB/UNSUB follow the
switchboard's subscribed cells.
"""

from __future__ import annotations

import logging
import math
import ssl
from dataclasses import dataclass
from typing import Any

import trio

from entitynet.cluster.core import ClusterCore
from entitynet.cluster.defaults import CONNECT_TIMEOUT_S, DEAD_AFTER_S
from entitynet.cluster.nats_client import NatsClient, NatsConnectionLost

log = logging.getLogger("entitynet.cluster")


@dataclass
class ClusterConfig:
    """What `entitynet serve --cluster ... --shard N --regions MAP` gives a server."""

    servers: str  # nats://host:port[,...]
    shard: int
    regions: Any  # topology.regions.RegionMap (loaded and checked against the topology)
    address: str | None = None  # what clients are REDIRECTed to (default: the server's host:port)
    token: str | None = None  # NATS auth token
    tls: ssl.SSLContext | None = None  # TLS to NATS
    heartbeat_s: float = 0.5
    dead_after_s: float = DEAD_AFTER_S
    connect_timeout_s: float = CONNECT_TIMEOUT_S  # one NATS connect attempt (NatsClient's connect_timeout)
    redirect_viewers: bool = True  # a client without entities whose cells lie mostly elsewhere moves there
    # cell -> neighbour cells (topology.regions.cell_adjacency): publishers near a border are served on here
    # within a band of `publisher_margin_cells` and for `publisher_linger_s` (roaming.py); None: no band
    cell_adjacency: Any = None
    publisher_margin_cells: int = 2
    publisher_linger_s: float = 30.0


class ClusterLink:
    """Run with `await nursery.start(link.run)` once the server listens (its port is the default address)."""

    def __init__(self, server: Any, config: ClusterConfig):
        self.server = server
        self.config = config
        self.core: ClusterCore | None = None
        self.nc: NatsClient | None = None
        # when the pump must next run for what the core has queued (inf: nothing queued since the last pump); the
        # loop waits in `_scope`, whose deadline a poke brings forward: no Event, so a poke wakes nobody early
        self._due = math.inf
        self._scope: trio.CancelScope | None = None
        self._sids: dict[str, int] = {}
        self._releasing = False
        self._nursery: trio.Nursery | None = None
        self._lost_at: float | None = None  # trio time the NATS connection was lost (None: connected)

    def _poke(self, urgent: bool = False) -> None:
        """The core has something for NATS (or new interest): the pump runs one latency budget after the first
        poke since it last ran, so that one pass of the loop and one NATS write carry all of it (and the other
        shards read it in one go) instead of one each. A REDIRECT waiting for its LEAVEs, a request of ours (a
        viewer's snapshot, QUERY or FOLLOW waits on it), or an answer another shard's request waits for
        (`urgent`) is pumped now: each would otherwise add a budget to the documented bound of two. Only the
        wait's deadline moves: the loop wakes once, when it is due (a wake-up and then a timed wait for the
        budget cost a shard two passes of trio's scheduler per write)."""
        core = self.core
        now = trio.current_time()
        if urgent or (core is not None and (core.redirects or (core.out and core.out[-1][2] is not None))):
            due = now  # (the last publication names a reply subject: our own request)
        elif self._due == math.inf:
            due = now + max(0.0, self.server.config.latency_budget)
        else:
            return  # already due no later than a budget from the first poke
        if due < self._due:
            self._due = due
            if self._scope is not None:
                self._scope.deadline = min(self._scope.deadline, due)

    def _wait_until(self) -> float:
        """The trio time the loop sleeps until: the pump's due time, but never past the core's next deadline
        (heartbeats and failover decisions are not postponed by a long budget)."""
        core = self.core
        return min(self._due, trio.current_time() + max(0.0, core.next_deadline() - self.server.clock()))

    async def _serve_core(self) -> None:
        """Until cancelled: sleep until the pump is due or the core's deadline, then tick and pump; whatever the
        tick and the pump queue themselves (a heartbeat) is handed over in the same pass."""
        while True:
            with trio.CancelScope(deadline=self._wait_until()) as scope:
                self._scope = scope
                await trio.sleep_forever()
            self._scope = None
            self.core.tick(self.server.clock())
            self._pump()
            self._due = math.inf
            self.server._note_news()  # LEAVEs of a dead shard's mirrors, answers to queries and follows

    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Join NATS, build the core, subscribe to the cluster-wide subjects, then pump until cancelled:
        `started` is reported only after the first flush, so the shard is on the cluster before it is used."""
        cfg, server = self.config, self.server
        clock = server.clock
        address = cfg.address or f"{server.config.host}:{server.port}"
        nc = NatsClient(cfg.servers, name=f"entitynet-shard-{cfg.shard}", token=cfg.token, tls=cfg.tls,
                        connect_timeout=cfg.connect_timeout_s, on_reconnect=self._reconnected,
                        on_disconnect=self._lost, on_batch=self._after_read)
        async with nc, trio.open_nursery() as nursery:
            self._nursery = nursery
            self.nc = nc
            inbox = nc.new_inbox(self._on_msg)
            self.core = ClusterCore(server.sb, cfg.regions, cfg.shard, address, now=clock(), inbox=inbox,
                                    heartbeat_s=cfg.heartbeat_s, dead_after_s=cfg.dead_after_s,
                                    redirect_viewers=cfg.redirect_viewers, wake=self._poke,
                                    cell_adjacency=cfg.cell_adjacency,
                                    publisher_margin_cells=cfg.publisher_margin_cells,
                                    publisher_linger_s=cfg.publisher_linger_s)
            self.core.extra_counts = lambda: {"nats_in": nc.received, "nats_out": nc.published,
                                              "nats_writes": nc.writes, "nats_dropped": nc.dropped,
                                              "nats_reconnects": nc.reconnects}
            p = self.core.prefix
            for sub in ("snap", "hb", "f", "q", "i"):
                nc.subscribe(f"{p}.{sub}", self._on_msg)
            self._pump()
            await nc.flush()
            log.info("shard %d joined the cluster at %s (map %s)", cfg.shard, nc.server, cfg.regions.digest[:12])
            task_status.started(self)
            await self._serve_core()

    def _on_msg(self, subject: str, reply: str | None, payload: bytes) -> None:
        if self.core is None:
            return
        self.core.on_message(subject, reply, payload, self.server.clock())
        if self.core.out:
            # a request (it names a reply subject: a QUERY, FOLLOW or snapshot another shard, and maybe its
            # client, waits on) is answered now, not after the latency budget
            self._poke(urgent=reply is not None)

    def _after_read(self) -> None:
        """Every message of one NATS read is in the core: wake the flusher once for their mirrored states (not once
        per message; a heartbeat wakes nobody)."""
        self.server._note_news()

    def _where(self) -> str:
        """host:port of the NATS node the shard is (or was last) connected to, else the configured URLs."""
        nc = self.nc
        return f"{nc.server[0]}:{nc.server[1]}" if nc is not None and nc.server else self.config.servers

    def _lost(self, why: str) -> None:
        """The NATS connection is gone: said once (a warning), however many reconnect attempts fail after."""
        self._lost_at = trio.current_time()
        where = self._where()
        log.warning("shard %d lost its NATS connection to %s (%s); reconnecting, publications are buffered",
                    self.config.shard, where, why)

    def _reconnected(self) -> None:
        """Back on NATS: said once, with how long the shard was cut off; the core re-syncs (snapshots)."""
        down = 0.0 if self._lost_at is None else trio.current_time() - self._lost_at
        self._lost_at = None
        where = self._where()
        log.info("shard %d NATS connection restored to %s after %.1f s", self.config.shard, where, down)
        if self.core is not None:
            self.core.resync()
            self._poke()

    def _pump(self) -> None:
        """Hand the core's publications to NATS, and follow its interest with SUB/UNSUB."""
        core, nc = self.core, self.nc
        subs, unsubs = core.interest_changes()
        for subject in unsubs:
            sid = self._sids.pop(subject, None)
            if sid is not None:
                nc.unsubscribe(sid)
        for subject in subs:
            if subject not in self._sids:
                self._sids[subject] = nc.subscribe(subject, self._on_msg)
        nc.publish_batch(core.take_out())  # written now, in one system call (no wake-up of the writer task)
        if core.redirects and not self._releasing:
            self._releasing = True
            self._nursery.start_soon(self._release)

    async def _release(self) -> None:
        """Held REDIRECTs go out once NATS has confirmed everything published before them (a PING round trip):
        the client's LEAVEs are then ahead of anything it can publish on its new shard. A flush that loses its
        connection proves nothing (the LEAVEs may have died with the node): wait for the reconnect, whose
        resync publishes recent LEAVEs again, and flush there."""
        try:
            with trio.move_on_after(1.0):  # NATS unreachable: redirect anyway, a duplicate beats a stuck client
                while True:
                    try:
                        await self.nc.flush()
                        break
                    except NatsConnectionLost:
                        while not self.nc.connected:
                            await trio.sleep(0.01)
        except trio.TooSlowError:
            pass
        finally:
            self._releasing = False
            if self.core.release_redirects():
                self.server._wake_dirty()
            if self.core.redirects:
                self._poke()
