"""Which MQTT client library `bench e2e` uses, by measurement: the load generator's CPU to receive the same
QoS 0 messages through each candidate from one mosquitto.

Why it matters: the e2e benchmark's viewers are real subscriber connections in the load generator's process,
so a slow client library would make the load generator, not the broker, the limit. Candidates: gmqtt (asyncio-native,
driven exactly as `sims.bench.e2e_transports.MqttTransport` drives it) and paho-mqtt (the Eclipse client,
driven from one selector loop; installed by hand for this measurement only: `pip install paho-mqtt`). aiomqtt
wraps paho-mqtt's protocol code, so it is not measured apart. Both see the same barrier every 100 messages.
Run: `python -m sims.bench.e2e_mqtt_clients`; it prints
one JSON object (CPU microseconds per received message, median of alternated rounds).
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

SUBSCRIBERS = 10
MESSAGES = 3000
TOPIC = "/hfp/v2/journey/ongoing/vp/bus/1234/60;24/19/85/85"
PAYLOAD = b'{"VP":{"veh":1234,"tsi":28800.123,"lat":60.1898123,"long":24.9554321,"spd":8.52,"hdg":91}}'


def gmqtt_round(port: int) -> float:
    """CPU seconds of this process to receive MESSAGES x SUBSCRIBERS through gmqtt, as the bench drives it
    (`MqttTransport`: a marker barrier every 100 messages)."""
    from sims.bench.e2e_transports import MqttTransport

    got = [0]

    def on(i, topic, payload, size):
        got[0] += 1

    t = MqttTransport(port, 1, SUBSCRIBERS, on, timeout=30.0)
    for i in range(SUBSCRIBERS):
        t.subscribe(i, ["/hfp/#"], [])
    t.settle()
    c0 = time.process_time()
    for k in range(MESSAGES):
        t.publish(0, TOPIC, PAYLOAD)
        if k % 100 == 99:
            t.sync(k)
    t.sync(MESSAGES)
    cpu = time.process_time() - c0
    t.close()
    assert got[0] == MESSAGES * SUBSCRIBERS, got[0]
    return cpu


def paho_round(port: int) -> float:
    """The same through paho-mqtt 2 driven from one selector loop (`loop_read`/`loop_write`, its documented
    way into an external event loop), the same barrier."""
    import selectors
    import socket

    import paho.mqtt.client as mqtt

    sel = selectors.DefaultSelector()
    state = {"acks": 0, "markers": 0, "got": 0, "conn": 0}

    def client(cid: str) -> mqtt.Client:
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=cid, protocol=mqtt.MQTTv311)
        c.on_connect = lambda *a: state.__setitem__("conn", state["conn"] + 1)
        c.on_subscribe = lambda *a: state.__setitem__("acks", state["acks"] + 1)

        def on_message(cl, ud, msg):
            if msg.topic == "e2e/sync":
                state["markers"] += 1
            else:
                state["got"] += 1

        c.on_message = on_message
        c.connect("127.0.0.1", port, keepalive=600)
        sel.register(c.socket(), selectors.EVENT_READ, c)
        return c

    subs = [client(f"p{i}") for i in range(SUBSCRIBERS)]
    pub = client("pp")
    everyone = [*subs, pub]

    def pump(done) -> None:
        deadline = time.monotonic() + 30
        while not done():
            for c in everyone:
                if c.want_write():
                    c.loop_write()
            if time.monotonic() > deadline:
                raise RuntimeError("paho round timed out")
            for key, _ in sel.select(0.5):
                c, sock = key.data, key.fileobj
                while True:
                    c.loop_read()
                    try:
                        sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT)
                    except BlockingIOError:
                        break

    pump(lambda: state["conn"] == len(everyone))
    for c in subs:
        c.subscribe([("/hfp/#", 0), ("e2e/sync", 0)])
    pump(lambda: state["acks"] == len(subs))
    c0 = time.process_time()
    for k in range(MESSAGES):
        pub.publish(TOPIC, PAYLOAD, qos=0)
        if k % 100 == 99 or k == MESSAGES - 1:
            state["markers"] = 0
            pub.publish("e2e/sync", b"%d" % k, qos=0)
            pump(lambda: state["markers"] == len(subs))
    cpu = time.process_time() - c0
    for c in everyone:
        c.disconnect()
    sel.close()
    assert state["got"] == MESSAGES * SUBSCRIBERS, state["got"]
    return cpu


def main() -> None:
    """Alternated rounds of each candidate against one mosquitto; prints the JSON result."""
    from sims.bench.e2e_peers import mosquitto
    from sims.bench.switch_systems import find_exe

    exe, how = find_exe("mosquitto", "mosquitto", print)
    if exe is None:
        raise SystemExit(f"mosquitto needed: {how}")
    rounds = {"paho-mqtt": [], "gmqtt": []}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp, mosquitto(exe, Path(tmp), lambda m: None) as (_proc, port, ver):
        for r in range(5):
            for name in (("paho-mqtt", "gmqtt") if r % 2 else ("gmqtt", "paho-mqtt")):
                try:
                    cpu = paho_round(port) if name == "paho-mqtt" else gmqtt_round(port)
                except ImportError:
                    continue
                rounds[name].append(1e6 * cpu / (MESSAGES * SUBSCRIBERS))
    print(json.dumps({"broker": ver, "messages": MESSAGES, "subscribers": SUBSCRIBERS,
                      "cpu_us_per_received_message": {k: statistics.median(v) for k, v in rounds.items() if v},
                      "rounds": rounds, "load_average_1_5_15_min": {"start": load_before, "end": os.getloadavg()},
                      "cpu_count": os.cpu_count()}, indent=2))


if __name__ == "__main__":
    main()
