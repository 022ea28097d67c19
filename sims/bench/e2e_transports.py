"""The end-to-end benchmark's wire side: the same tick's traffic through MQTT (gmqtt against mosquitto),
Redis pub/sub (redis-py) or our server (our codec over plain sockets), each with a barrier per tick.

Why a barrier: the benchmark steps one world in lock step for every system, so that each tick's messages have
reached every viewer before the truth is compared with its ghosts; the figures then measure what each system
delivers, not how a shared 2-core machine happened to schedule it. The barrier is exact for each system:
- MQTT and Redis: after its tick's messages every publisher connection sends a marker on a sync topic/channel
  that every viewer subscribes to; the broker forwards one connection's messages in order, so a viewer holding
  this tick's marker from every publisher holds every message published before it.
- ours: every publisher connection PINGs and waits for its PONG (the server has applied its PUBLISHes to the
  viewers' outboxes), then every viewer PINGs; the server writes control and coalesced states of an outbox in
  one frame, so the frame with the PONG carries everything queued before.
Subscription changes are acknowledged before the tick's publishes (SUBACK, Redis's PONG, our PONG).
A broker that dies or stops answering raises `TransportError` within `timeout` seconds, never a hang.
Bytes are wire bytes as each viewer receives them: MQTT PUBLISH packets (QoS 0) and RESP pushes computed from
topic and payload lengths; ours counted from the frames read (frame headers included, PONGs excluded).
"""

from __future__ import annotations

import asyncio
import socket
import struct
import time
from collections.abc import Callable

from entitynet import protocol as P

SYNC_TOPIC = "e2e/sync"
SYNC_CHANNEL = "e2e:sync"

#: (viewer, topic or channel, payload, wire bytes) for MQTT and Redis
Deliver = Callable[[int, str, bytes, int], None]


class TransportError(RuntimeError):
    """The broker or server went away or stopped answering: the run stops with this, clearly."""


def mqtt_wire_size(topic: str, payload: bytes) -> int:
    """Bytes of an MQTT 3.1.1 QoS 0 PUBLISH packet: fixed header (type byte and the remaining length as a
    varint), topic length and topic, payload."""
    rem = 2 + len(topic.encode()) + len(payload)
    n = 1
    while rem >= 128 ** n:
        n += 1
    return 1 + n + rem


def redis_wire_size(channel: str, payload: bytes) -> int:
    """Bytes of a RESP2 pub/sub push: `*3`, `$7 message`, the channel and the payload as bulk strings."""
    c, p = len(channel.encode()), len(payload)
    return 4 + 13 + (3 + len(str(c)) + c + 2) + (3 + len(str(p)) + p + 2)


def _alive(proc) -> None:
    if proc is not None and proc.poll() is not None:
        raise TransportError(f"the broker process exited with status {proc.returncode}")


class MqttTransport:
    """gmqtt clients (MQTT 3.1.1, QoS 0, clean sessions) on a private asyncio loop that runs only inside
    `settle` and `sync` (the lock step is synchronous). gmqtt, not paho-mqtt, because it costs the load generator
    less CPU per received message (measured by `sims.bench.e2e_mqtt_clients`; the figures are in docs/e2e.md)."""

    name = "mqtt"

    def __init__(self, port: int, publishers: int, viewers: int, on_message: Deliver, *, proc=None,
                 timeout: float = 10.0):
        try:
            import gmqtt
        except ImportError:  # the package imports without it; the suite says what to install
            raise TransportError("gmqtt is not installed (pip install -e '.[bench]')") from None
        self._gmqtt = gmqtt
        self.proc, self.timeout, self.on_message = proc, timeout, on_message
        self.pubs: list = []
        self.views: list = []
        self.loop = asyncio.new_event_loop()
        try:  # a failure part way closes the clients and the loop opened so far
            self._start(port, publishers, viewers)
        except BaseException:
            self.close()
            raise

    def _start(self, port: int, publishers: int, viewers: int) -> None:
        gmqtt = self._gmqtt
        self.changed = asyncio.Event()
        self.tick = -1
        self.marker = b""
        self.markers = [0] * viewers
        self.pending: list[set[int]] = [set() for _ in range(viewers)]  # unacknowledged (UN)SUBSCRIBE mids
        self.lost: str | None = None
        self.pubs = [self._client(f"e2e-pub-{k}", None) for k in range(publishers)]
        self.views = [self._client(f"e2e-view-{i}", i) for i in range(viewers)]

        async def connect_all() -> None:
            await asyncio.gather(*[c.connect("127.0.0.1", port, keepalive=600, version=gmqtt.constants.MQTTv311)
                                   for c in self.pubs + self.views])

        try:
            self._run(connect_all(), "CONNACK")
        except (OSError, gmqtt.mqtt.handler.MQTTConnectError) as exc:
            raise TransportError(f"cannot reach mosquitto: {exc}") from None
        for i, c in enumerate(self.views):
            self.pending[i].add(c.subscribe(SYNC_TOPIC, qos=0))
        self.settle()

    def _client(self, cid: str, viewer: int | None):
        c = self._gmqtt.Client(cid, clean_session=True)

        def on_disconnect(client, packet, exc=None):
            self.lost = self.lost or f"{cid} disconnected ({exc or 'by the broker'})"
            self.changed.set()

        c.on_disconnect = on_disconnect
        if viewer is not None:
            def on_message(client, topic, payload, qos, properties, i=viewer):
                if topic == SYNC_TOPIC:
                    if payload == self.marker:
                        self.markers[i] += 1
                        self.changed.set()
                else:
                    self.on_message(i, topic, payload, mqtt_wire_size(topic, payload))
                return 0

            def on_ack(client, mid, *rest, i=viewer):
                self.pending[i].discard(mid)
                self.changed.set()

            c.on_message = on_message
            c.on_subscribe = on_ack
            c.on_unsubscribe = on_ack
        return c

    def _run(self, coro, what: str):
        try:
            return self.loop.run_until_complete(asyncio.wait_for(coro, self.timeout))
        except TimeoutError:
            _alive(self.proc)
            raise TransportError(f"no {what} from mosquitto within {self.timeout:g} s") from None

    async def _until(self, done: Callable[[], bool], what: str) -> None:
        while not done():
            if self.lost:
                _alive(self.proc)
                raise TransportError(f"lost mosquitto waiting for {what}: {self.lost}")
            self.changed.clear()
            try:
                await asyncio.wait_for(self.changed.wait(), 0.5)
            except TimeoutError:
                _alive(self.proc)

    def subscribe(self, viewer: int, added: list[str], removed: list[str]) -> None:
        """Change a viewer's topic filters (acknowledged by the next `settle`)."""
        c = self.views[viewer]
        if removed:
            self.pending[viewer].add(c.unsubscribe(removed))
        if added:
            subs = [self._gmqtt.Subscription(f, qos=0) for f in added]
            self.pending[viewer].add(c.subscribe(subs))

    def settle(self) -> None:
        """Until every subscription change is acknowledged."""
        if any(self.pending):
            self._run(self._until(lambda: not any(self.pending), "SUBACK"), "SUBACK")

    def publish(self, conn: int, topic: str, payload: bytes) -> None:
        """One QoS 0 PUBLISH on publisher connection `conn` (written when the loop next runs)."""
        if self.lost:
            raise TransportError(f"lost mosquitto: {self.lost}")
        self.pubs[conn].publish(topic, payload, qos=0)

    def sync(self, tick: int) -> None:
        """The tick's barrier: a marker from every publisher, then until every viewer holds them all."""
        self.tick, self.marker = tick, b"%d" % tick
        self.markers = [0] * len(self.views)
        for c in self.pubs:
            c.publish(SYNC_TOPIC, self.marker, qos=0)
        n = len(self.pubs)
        self._run(self._until(lambda: min(self.markers, default=n) >= n, f"tick {tick}'s markers"),
                  f"tick {tick}'s markers")

    def close(self) -> None:
        """Disconnect every client and close the loop (quietly: the broker may already be gone)."""
        async def bye():
            for c in self.pubs + self.views:
                try:
                    c.stop_reconnect()
                    await asyncio.wait_for(c.disconnect(), 1.0)
                except Exception:  # noqa: BLE001 - closing after a failure must not mask it
                    pass

        try:
            self.loop.run_until_complete(bye())
            for t in asyncio.all_tasks(self.loop):
                t.cancel()
            self.loop.run_until_complete(asyncio.sleep(0))
        finally:
            self.loop.close()


class RedisTransport:
    """redis-py: a pipeline per publisher connection, a PubSub connection per viewer (`message` pushes read
    with `get_message`); channel per grid box, PING as the subscription barrier."""

    name = "redis"

    def __init__(self, port: int, publishers: int, viewers: int, on_message: Deliver, *, proc=None,
                 timeout: float = 10.0):
        import redis

        self._errors = (redis.ConnectionError, redis.TimeoutError, OSError)
        self.proc, self.timeout, self.on_message = proc, timeout, on_message
        self.pubs: list = []
        self.pipes: list = []
        self.views: list = []
        self.pinged: set[int] = set()
        try:  # a failure part way closes the connections opened so far
            try:
                for _ in range(publishers):
                    self.pubs.append(redis.Redis(port=port, socket_timeout=timeout))
                    self.pipes.append(self.pubs[-1].pipeline(transaction=False))
                for _ in range(viewers):
                    self.views.append(redis.Redis(port=port, socket_timeout=timeout).pubsub())
                    self.views[-1].subscribe(SYNC_CHANNEL)
            except self._errors as exc:
                raise TransportError(f"cannot reach redis: {exc}") from None
            self.settle(range(viewers))
        except BaseException:
            self.close()
            raise

    def subscribe(self, viewer: int, added: list[str], removed: list[str]) -> None:
        """Change a viewer's channels (acknowledged by the next `settle`)."""
        ps = self.views[viewer]
        try:
            if removed:
                ps.unsubscribe(*removed)
            if added:
                ps.subscribe(*added)
        except self._errors as exc:
            raise TransportError(f"lost redis: {exc}") from None
        self.pinged.add(viewer)

    def settle(self, viewers=None) -> None:
        """PING every viewer whose channels changed and read until its PONG (replies come in order)."""
        todo = sorted(self.pinged if viewers is None else set(viewers))
        self.pinged = set()
        for i in todo:
            self.views[i].ping(b"settle")
        for i in todo:
            self._read(i, lambda m: m["type"] == "pong", "PONG")

    def publish(self, conn: int, channel: str, payload: bytes) -> None:
        """Queue one PUBLISH in publisher `conn`'s pipeline."""
        self.pipes[conn].publish(channel, payload)

    def sync(self, tick: int) -> None:
        """Send every pipeline with its marker, then read each viewer until it holds every marker."""
        marker = b"%d" % tick
        try:
            for p in self.pipes:
                p.publish(SYNC_CHANNEL, marker)
                p.execute()
        except self._errors as exc:
            _alive(self.proc)
            raise TransportError(f"lost redis publishing tick {tick}: {exc}") from None
        n = len(self.pipes)
        for i in range(len(self.views)):
            got = [0]

            def is_marker(m, got=got) -> bool:
                if m["type"] == "message" and m["channel"] == SYNC_CHANNEL.encode() and m["data"] == marker:
                    got[0] += 1
                return got[0] >= n

            self._read(i, is_marker, f"tick {tick}'s markers")

    def _read(self, i: int, done: Callable[[dict], bool], what: str) -> None:
        ps = self.views[i]
        deadline = time.monotonic() + self.timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                _alive(self.proc)
                raise TransportError(f"no {what} from redis within {self.timeout:g} s")
            try:
                m = ps.get_message(ignore_subscribe_messages=False, timeout=min(left, 0.5))
            except self._errors as exc:
                _alive(self.proc)
                raise TransportError(f"lost redis waiting for {what}: {exc}") from None
            if m is None:
                _alive(self.proc)
                continue
            if m["type"] == "message" and m["channel"] != SYNC_CHANNEL.encode():
                ch = m["channel"].decode()
                self.on_message(i, ch, m["data"], redis_wire_size(ch, m["data"]))
            elif done(m):
                return

    def close(self) -> None:
        """Close every connection (quietly: the server may already be gone)."""
        for c in [*self.views, *self.pubs]:
            try:
                c.close()
            except Exception:  # noqa: BLE001 - closing after a failure must not mask it
                pass


_LEN = struct.Struct(">I")


class OursTransport:
    """Our protocol over plain blocking sockets (the codec of `entitynet.protocol`): publisher connections
    carry the honest clients' PUBLISH/UNPUBLISH frames, viewer connections SUBSCRIBE and read UPDATE/LEAVE."""

    name = "entitynet"

    def __init__(self, port: int, digest: str, publishers: int, viewers: int,
                 on_message: Callable[[int, P.Message, int], None], *, proc=None, timeout: float = 10.0):
        self.proc, self.timeout, self.on_message = proc, timeout, on_message
        self.ping_no = 0
        hello = P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "e2e", digest)])
        self.pubs: list[socket.socket] = []
        self.views: list[socket.socket] = []
        self.asked: set[int] = set()
        try:  # a failure part way closes the sockets opened so far
            for _ in range(publishers):
                self.pubs.append(self._open(port, hello))
            for _ in range(viewers):
                self.views.append(self._open(port, hello))
            self.welcomes = [self._until(s, lambda m: isinstance(m, P.Welcome), "WELCOME", None)
                             for s in self.pubs + self.views]
        except BaseException:
            self.close()
            raise

    def _open(self, port: int, hello: bytes) -> socket.socket:
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=self.timeout)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.sendall(hello)
        except OSError as exc:
            raise TransportError(f"cannot reach the entitynet server: {exc}") from None
        return s

    def _send(self, s: socket.socket, data: bytes) -> None:
        try:
            s.sendall(data)
        except OSError as exc:
            _alive(self.proc)
            raise TransportError(f"lost the entitynet server: {exc}") from None

    def _recv(self, s: socket.socket, n: int, what: str) -> bytes:
        buf = bytearray()
        while len(buf) < n:
            try:
                got = s.recv(n - len(buf))
            except TimeoutError:
                _alive(self.proc)
                raise TransportError(f"no {what} from the entitynet server within {self.timeout:g} s") from None
            except OSError as exc:
                raise TransportError(f"lost the entitynet server waiting for {what}: {exc}") from None
            if not got:
                _alive(self.proc)
                raise TransportError(f"the entitynet server closed the connection waiting for {what}")
            buf += got
        return bytes(buf)

    def _until(self, s: socket.socket, done: Callable[[P.Message], bool], what: str, viewer: int | None):
        """Read frames until a message satisfies `done`; UPDATE/LEAVE go to `on_message` with their share of
        the frame's bytes (the frame header counted with the first)."""
        while True:
            (n,) = _LEN.unpack(self._recv(s, 4, what))
            body = self._recv(s, n, what)
            msgs = P.decode_payload(body)
            size = 4 + n
            found = None
            for m in msgs:
                if isinstance(m, P.Error):
                    raise TransportError(f"the entitynet server refused: {m}")
                if found is None and done(m):
                    found = m
                if not isinstance(m, P.Update | P.Leave):
                    size -= len(P.encode_message(m))
            if viewer is not None:
                data = [m for m in msgs if isinstance(m, P.Update | P.Leave)]
                for k, m in enumerate(data):
                    self.on_message(viewer, m, size if k == 0 else 0)
                    if k == 0:
                        size = 0
            if found is not None:
                return found

    def subscribe(self, viewer: int, msgs: list[P.Message]) -> None:
        """Send a viewer's SUBSCRIBE differences with a PING (answered by the next `settle`)."""
        if msgs:
            self.ping_no += 1
            self._send(self.views[viewer], P.encode_frame([*msgs, P.Ping(self.ping_no)]))
            self.asked.add(viewer)

    def settle(self) -> None:
        """Until every viewer that changed its subscription has its PONG (its SUBSCRIBE is in place)."""
        for i in sorted(self.asked):
            self._until(self.views[i], lambda m: isinstance(m, P.Pong), "PONG", i)
        self.asked = set()

    def publish(self, conn: int, msgs: list[P.Message]) -> None:
        """One frame of a publisher connection's PUBLISH/UNPUBLISH messages."""
        if msgs:
            self._send(self.pubs[conn], P.encode_frame(msgs))

    def sync(self, tick: int) -> None:
        """PING every publisher and wait, then PING every viewer and read until its PONG."""
        self.ping_no += 1
        ping = P.encode_frame([P.Ping(self.ping_no)])
        for s in self.pubs:
            self._send(s, ping)
        for s in self.pubs:
            self._until(s, lambda m: isinstance(m, P.Pong), f"tick {tick}'s PONG", None)
        for s in self.views:
            self._send(s, ping)
        for i, s in enumerate(self.views):
            self._until(s, lambda m: isinstance(m, P.Pong), f"tick {tick}'s PONG", i)

    def close(self) -> None:
        """Close every socket."""
        for s in self.pubs + self.views:
            s.close()
