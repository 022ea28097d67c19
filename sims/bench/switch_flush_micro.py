"""Micro-benchmark of the server's flush loop: one frame per connection over real loopback TCP, pure vs compiled.

Why: the flush is most of the server's time under load (the `writev` system calls and the Python around them);
this isolates it, in CPU time of this process (`time.process_time`: the kernel's work for the write is counted,
preemption by other processes is not). `python -m sims.bench.switch_flush_micro` prints µs per frame for 1,000
connections, each with `--states` coalesced UPDATEs of the switch benchmark's size, for both loops.
"""

from __future__ import annotations

import socket
import time

from entitynet import protocol as P
from entitynet.server import flushloop
from entitynet.switchboard.outbox import Outbox


def measure(n_conns: int = 1000, states: int = 10, rounds: int = 3, reps: int = 20) -> list[dict[str, float]]:
    """µs of CPU per frame written, per loop and round (the peers' reads are not timed)."""
    lst = socket.socket()
    lst.bind(("127.0.0.1", 0))
    lst.listen(n_conns)
    pairs = []
    for _ in range(n_conns):
        cli = socket.create_connection(lst.getsockname())
        srv, _ = lst.accept()
        srv.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        srv.setblocking(False)
        cli.setblocking(False)
        pairs.append((srv, cli))
    lst.close()
    enc = [P.encode_update(P.LOCAL_ID_LIMIT + e, 1, (e, e + 1), 5000, b"p" * 66) for e in range(states)]
    conns = {i: flushloop.FlushConn(i, Outbox(1000, 10), srv.fileno()) for i, (srv, _cli) in enumerate(pairs)}
    paths = {"pure": flushloop.PURE}
    if flushloop.COMPILED is not None:
        paths["compiled"] = flushloop.COMPILED
    out = []
    try:
        for _ in range(rounds):
            row = {}
            for name, impl in paths.items():
                spent = 0.0
                frames = 0
                for _ in range(reps):
                    for c in conns.values():
                        for e, b in enumerate(enc):
                            c.outbox.put_state(e, b)
                    t = time.process_time()
                    res = impl.flush_short(conns, conns, 0.0, 1000, 300, 1 << 20, 0)
                    spent += time.process_time() - t
                    frames += res[1]
                    for c in res[5]:  # blocked (should not happen here): forget the rest
                        c.busy, c.rest = False, None
                    for _srv, cli in pairs:
                        try:
                            while cli.recv(1 << 20):
                                pass
                        except BlockingIOError:
                            pass
                row[name] = spent / max(frames, 1) * 1e6
            out.append(row)
    finally:
        for srv, cli in pairs:
            srv.close()
            cli.close()
    return out


if __name__ == "__main__":  # pragma: no cover - a small report tool
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=10, help="states per frame (the standard load has about 10)")
    ns = ap.parse_args()
    for row in measure(states=ns.states):
        print("  ".join(f"{k} {v:.2f} µs/frame" for k, v in row.items()))
