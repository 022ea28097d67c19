"""Micro-benchmark of the lock step's barrier: the server's CPU per PING round trip, `bench e2e`'s traffic alone.

Why: idle, `bench e2e`'s lock step (every tick 4 publisher connections PING and wait, then 30 viewers PING and
wait, a viewer whose camera moved sending its SUBSCRIBE difference in the same frame) is most of what our server
spends there, and a 40-second e2e run is too coarse to iterate on. This starts `entitynet serve` (from `--tree`:
another checkout, run with that checkout's `--python`, to compare with it), opens the same 34 connections,
and runs `--rounds` lock-step rounds; every `--sub-every`-th round the viewers send a small SUBSCRIBE
difference with their PING. The figure is the server process's user + system CPU (psutil) over the rounds
divided by the round trips, medians of `--reps` runs; the kernel's share of the client side is not in it.

    python -m sims.bench.switch_ping_micro --reps 3
    python -m sims.bench.switch_ping_micro --tree /work/base --python /work/base/.venv/bin/python
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

from entitynet import protocol as P

_LEN = struct.Struct(">I")


def _recv_frame(s: socket.socket) -> list[P.Message]:
    buf = b""
    while len(buf) < 4:
        got = s.recv(4 - len(buf))
        if not got:
            raise ConnectionError("server closed")
        buf += got
    (n,) = _LEN.unpack(buf)
    body = bytearray()
    while len(body) < n:
        got = s.recv(n - len(body))
        if not got:
            raise ConnectionError("server closed")
        body += got
    return P.decode_payload(bytes(body))


def _until_pong(s: socket.socket) -> None:
    while not any(isinstance(m, P.Pong) for m in _recv_frame(s)):
        pass


def one_run(port: int, digest: str, proc: psutil.Process, rounds: int, sub_every: int, entities: int = 0,
            viewers: int = 30, publishers: int = 4) -> dict[str, float]:
    """`rounds` lock-step rounds over fresh connections; the server's CPU per round trip in µs. With
    `entities`, every round first publishes each of them once (spread over the publishers, each in one of 20
    cells; every viewer subscribes to 4 of those cells, so that each UPDATE reaches 6 viewers, about `bench
    e2e`'s fan-out), so that the viewers' PINGs find states queued, as in a loaded tick."""
    hello = P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "micro", digest)])
    socks = [socket.create_connection(("127.0.0.1", port), timeout=10.0) for _ in range(publishers + viewers)]
    try:
        for s in socks:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.sendall(hello)
        for s in socks:
            while not any(isinstance(m, P.Welcome) for m in _recv_frame(s)):
                pass
        pubs, views = socks[:publishers], socks[publishers:]
        if entities:
            for i, s in enumerate(views):
                s.sendall(P.encode_frame([P.Subscribe(tuple((i + k) % 20 for k in range(4)), ()), P.Ping(0)]))
                _until_pong(s)
        t0 = proc.cpu_times()
        w0 = time.perf_counter()
        trips = 0
        for r in range(rounds):
            ping = P.encode_frame([P.Ping(r + 1)])
            for k, s in enumerate(pubs):
                mine = [P.Publish(e, r + 1, (e % 20,), 10_000, b"p" * 40) for e in range(k, entities, publishers)]
                s.sendall((P.encode_frame(mine) if mine else b"") + ping)
            for s in pubs:
                _until_pong(s)
            for i, s in enumerate(views):
                if sub_every and r % sub_every == 0:
                    cells = [(i * 7 + r) % 500 + k * 500 for k in range(3)]
                    old = [(i * 7 + r - sub_every) % 500 + k * 500 for k in range(3)] if r else []
                    s.sendall(P.encode_frame([P.Subscribe(tuple(cells), tuple(c for c in old if c not in cells)),
                                              P.Ping(r + 1)]))
                else:
                    s.sendall(ping)
            for s in views:
                _until_pong(s)
            trips += len(socks)
        wall = time.perf_counter() - w0
        t1 = proc.cpu_times()
    finally:
        for s in socks:
            s.close()
    cpu = (t1.user - t0.user) + (t1.system - t0.system)
    return {"server_us_per_round_trip": 1e6 * cpu / trips, "wall_us_per_round_trip": 1e6 * wall / trips,
            "round_trips": trips}


def main(argv: list[str] | None = None) -> int:
    """Start a fresh server per repetition (from `--tree` with `--python`), run the rounds, print the JSON."""
    ap = argparse.ArgumentParser(prog="python -m sims.bench.switch_ping_micro", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", default=str(Path(__file__).parents[2]), help="checkout whose server runs")
    ap.add_argument("--python", default=sys.executable, help="that checkout's interpreter")
    ap.add_argument("--rounds", type=int, default=600)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--sub-every", type=int, default=0, help="a SUBSCRIBE difference with the PING every N rounds")
    ap.add_argument("--entities", type=int, default=0, help="entities published every round (0: the idle barrier)")
    ap.add_argument("--env", action="append", default=[], help="KEY=VALUE for the server (repeatable)")
    a = ap.parse_args(argv)
    if not 1 <= a.rounds <= 100_000 or not 1 <= a.reps <= 20 or not 0 <= a.entities <= 10_000:
        ap.error("--rounds must be 1-100000, --reps 1-20 and --entities 0-10000")
    from entitynet.topology_cache import bundled_topology
    from sims.bench.switch_systems import free_port, wait_port

    topo, artifact = bundled_topology(lambda m: print(m, file=sys.stderr), with_pvs=True)
    env = {**os.environ, "PYTHONPATH": a.tree, **dict(kv.split("=", 1) for kv in a.env)}
    runs = []
    with tempfile.TemporaryDirectory(prefix="entitynet-ping-micro-") as tmp:
        for _ in range(a.reps):
            port = free_port()
            log = open(Path(tmp) / "server.log", "w")
            p = subprocess.Popen([a.python, "-m", "entitynet", "serve", "--topology", str(artifact), "--port",
                                  str(port), "--open"], cwd=a.tree, env=env, stdout=log, stderr=subprocess.STDOUT)
            try:
                wait_port(port, p, log=Path(tmp) / "server.log")
                runs.append(one_run(port, topo.digest, psutil.Process(p.pid), a.rounds, a.sub_every, a.entities))
            finally:
                p.terminate()
                p.wait(10)
                log.close()
    med = statistics.median(r["server_us_per_round_trip"] for r in runs)
    print(json.dumps({"tree": a.tree, "sub_every": a.sub_every, "entities": a.entities,
                      "median_server_us_per_round_trip": round(med, 2),
                      "runs": [{k: round(v, 2) for k, v in r.items()} for r in runs]}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
