"""The end-to-end benchmark's wire side: the same tick's traffic through MQTT (paho-mqtt against mosquitto),
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

import selectors
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
    """paho-mqtt clients (MQTT 3.1.1, QoS 0, clean sessions) driven from one selector loop (paho's documented
    `loop_read`/`loop_write`/`loop_misc` for an external event loop)."""

    name = "mqtt"

    def __init__(self, port: int, publishers: int, viewers: int, on_message: Deliver, *, proc=None,
                 timeout: float = 10.0):
        try:
            import paho.mqtt.client as mqtt
        except ImportError:  # the package imports without it; the suite says what to install
            raise TransportError("paho-mqtt is not installed (pip install 'entitynet[bench]')") from None
        self._mqtt = mqtt
        self.proc, self.timeout, self.on_message = proc, timeout, on_message
        self.sel = selectors.DefaultSelector()
        self.tick = 0
        self.markers = [0] * viewers
        self.pending: list[set[int]] = [set() for _ in range(viewers)]  # unacknowledged (UN)SUBSCRIBE mids
        self.connected: set[int] = set()
        self.pubs = [self._client(f"e2e-pub-{k}", None) for k in range(publishers)]
        self.views = [self._client(f"e2e-view-{i}", i) for i in range(viewers)]
        for c in self.pubs + self.views:
            c.connect("127.0.0.1", port, keepalive=600)
            self.sel.register(c.socket(), selectors.EVENT_READ, c)
        self._pump(lambda: len(self.connected) == len(self.pubs) + len(self.views), "CONNACK")
        for i, c in enumerate(self.views):
            self._track(i, c.subscribe(SYNC_TOPIC, qos=0))
        self.settle()

    def _client(self, cid: str, viewer: int | None):
        mqtt = self._mqtt
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=cid, protocol=mqtt.MQTTv311)

        def on_connect(client, userdata, flags, reason, props):
            if reason.is_failure:
                raise TransportError(f"mosquitto refused {cid}: {reason}")
            self.connected.add(id(client))

        c.on_connect = on_connect
        if viewer is not None:
            def on_message(client, userdata, msg, i=viewer):
                if msg.topic == SYNC_TOPIC:
                    if msg.payload == b"%d" % self.tick:
                        self.markers[i] += 1
                    return
                self.on_message(i, msg.topic, msg.payload, mqtt_wire_size(msg.topic, msg.payload))

            def on_ack(client, userdata, mid, *rest, i=viewer):
                self.pending[i].discard(mid)

            c.on_message = on_message
            c.on_subscribe = on_ack
            c.on_unsubscribe = on_ack
        return c

    def _track(self, i: int, result) -> None:
        rc, mid = result
        if rc != self._mqtt.MQTT_ERR_SUCCESS:
            raise TransportError(f"viewer {i}: (un)subscribe failed: {self._mqtt.error_string(rc)}")
        self.pending[i].add(mid)

    def subscribe(self, viewer: int, added: list[str], removed: list[str]) -> None:
        """Change a viewer's topic filters (acknowledged by the next `settle`)."""
        c = self.views[viewer]
        if removed:
            self._track(viewer, c.unsubscribe(removed))
        if added:
            self._track(viewer, c.subscribe([(f, 0) for f in added]))

    def settle(self) -> None:
        """Until every subscription change is acknowledged."""
        self._pump(lambda: not any(self.pending), "SUBACK")

    def publish(self, conn: int, topic: str, payload: bytes) -> None:
        """Queue one QoS 0 PUBLISH on publisher connection `conn`."""
        info = self.pubs[conn].publish(topic, payload, qos=0)
        if info.rc not in (self._mqtt.MQTT_ERR_SUCCESS, self._mqtt.MQTT_ERR_QUEUE_SIZE):
            raise TransportError(f"publish failed: {self._mqtt.error_string(info.rc)}")

    def sync(self, tick: int) -> None:
        """The tick's barrier: a marker from every publisher, then until every viewer holds them all."""
        self.tick = tick
        self.markers = [0] * len(self.views)
        for c in self.pubs:
            c.publish(SYNC_TOPIC, b"%d" % tick, qos=0)
        n = len(self.pubs)
        self._pump(lambda: min(self.markers, default=n) >= n, f"tick {tick}'s markers")
        for c in self.pubs + self.views:
            c.loop_misc()

    def _pump(self, done: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + self.timeout
        clients = self.pubs + self.views
        while True:
            for c in clients:
                if c.want_write() and c.loop_write() != self._mqtt.MQTT_ERR_SUCCESS:
                    raise TransportError(f"lost the connection to mosquitto (writing) waiting for {what}")
            if done():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                _alive(self.proc)
                raise TransportError(f"no {what} from mosquitto within {self.timeout:g} s")
            for key, _ in self.sel.select(min(left, 0.5)):
                self._drain(key.data, what)
            _alive(self.proc)

    def _drain(self, c, what: str) -> None:
        sock = c.socket()
        while True:
            if c.loop_read() != self._mqtt.MQTT_ERR_SUCCESS or c.socket() is None:
                raise TransportError(f"lost the connection to mosquitto waiting for {what}")
            try:
                if not sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT):
                    raise TransportError(f"mosquitto closed the connection waiting for {what}")
            except BlockingIOError:
                return

    def close(self) -> None:
        """Disconnect every client (quietly: the broker may already be gone)."""
        for c in self.pubs + self.views:
            try:
                self.sel.unregister(c.socket())
            except (KeyError, ValueError, TypeError):
                pass
            try:
                c.disconnect()
                c.loop_write()
            except Exception:  # noqa: BLE001 - closing after a failure must not mask it
                pass
        self.sel.close()


class RedisTransport:
    """redis-py: a pipeline per publisher connection, a PubSub connection per viewer (`message` pushes read
    with `get_message`); channel per grid box, PING as the subscription barrier."""

    name = "redis"

    def __init__(self, port: int, publishers: int, viewers: int, on_message: Deliver, *, proc=None,
                 timeout: float = 10.0):
        import redis

        self._errors = (redis.ConnectionError, redis.TimeoutError, OSError)
        self.proc, self.timeout, self.on_message = proc, timeout, on_message
        try:
            self.pubs = [redis.Redis(port=port, socket_timeout=timeout) for _ in range(publishers)]
            self.pipes = [r.pipeline(transaction=False) for r in self.pubs]
            self.views = [redis.Redis(port=port, socket_timeout=timeout).pubsub() for _ in range(viewers)]
            for ps in self.views:
                ps.subscribe(SYNC_CHANNEL)
        except self._errors as exc:
            raise TransportError(f"cannot reach redis: {exc}") from None
        self.pinged: set[int] = set()
        self.settle(range(viewers))

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
        self.pubs = [self._open(port, hello) for _ in range(publishers)]
        self.views = [self._open(port, hello) for _ in range(viewers)]
        self.welcomes = [self._until(s, lambda m: isinstance(m, P.Welcome), "WELCOME", None)
                         for s in self.pubs + self.views]
        self.asked: set[int] = set()

    def _open(self, port: int, hello: bytes) -> socket.socket:
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=self.timeout)
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
