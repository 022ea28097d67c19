"""Server settings: the listeners, TLS, auth, the topology facts the core needs, and the shell's policies."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any


class ConfigError(ValueError):
    """The server cannot start with this configuration (message says why)."""


#: the listener settings of ServerConfig, each with the `entitynet serve` option that sets it
PORT_SETTINGS = {"port": "--port", "ws_port": "--ws-port", "metrics_port": "--metrics-port",
                 "http_port": "--http-port"}


class ListenError(ConfigError):
    """A listener could not be bound: says which one (`setting`, a key of PORT_SETTINGS), where, and why, so
    that the user learns which option to change instead of reading an errno."""

    def __init__(self, setting: str, host: str, port: int, reason: str):
        self.setting, self.host, self.port, self.reason = setting, host, port, reason
        super().__init__(f"cannot listen on {host}:{port} ({PORT_SETTINGS.get(setting, setting)}): {reason}")


def bind_reason(exc: OSError) -> str:
    """Why a bind failed, in words ("address already in use"), without trio's repetition of the address (the
    server's listeners and the proxies' metrics port say it the same way)."""
    if isinstance(exc, socket.gaierror):
        return f"cannot resolve the host ({exc.strerror})"
    if exc.errno is not None and exc.errno > 0:
        return os.strerror(exc.errno).lower()
    return str(exc)


def check_ports(config: ServerConfig) -> None:
    """Refuse a port outside 0..65535 (0 = any free port) before anything binds: the kernel would silently
    take 65536 for 0 and listen on a random port."""
    for setting, option in PORT_SETTINGS.items():
        value = getattr(config, setting)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 65535):
            raise ConfigError(f"{option} must be a port from 1 to 65535 (or 0: any free port), not {value!r}")


def check_flush_policy(config: ServerConfig) -> None:
    """Refuse a latency budget that is not a finite number of seconds from 0 to 60 (the command allows up to 1 s),
    or a fill below 1: a NaN budget would never flush at light load, an infinite one never at all."""
    b = config.latency_budget
    if isinstance(b, bool) or not isinstance(b, int | float) or not 0.0 <= b <= 60.0:
        raise ConfigError(f"latency budget (--latency-budget-ms) must be from 0 to 60 s, not {b!r}")
    p = config.pace
    if isinstance(p, bool) or not isinstance(p, int | float) or not 0.0 <= p <= 1.0:
        raise ConfigError(f"wake-up pace (--pace-ms) must be from 0 to 1 s, not {p!r}")
    f = config.flush_fill
    if isinstance(f, bool) or not isinstance(f, int) or not 1 <= f <= 1_000_000:
        raise ConfigError(f"--flush-fill must be a whole number from 1 to 1000000, not {f!r}")
    m = config.flush_min_frame
    if isinstance(m, bool) or not isinstance(m, int) or not 1 <= m <= 1_000_000:
        raise ConfigError(f"--flush-min-frame must be a whole number from 1 to 1000000, not {m!r}")


@dataclass
class ServerConfig:
    """Everything `serve()` needs. Ports of 0 pick a free port (see the started `Server`'s ports).

    Give either `topology` (an artifact path: its digest and cell count are read from it) or `digest` and
    `n_cells` directly (tests, or a server started before the artifact exists).
    """

    host: str = "127.0.0.1"
    port: int | None = 7400  # TCP; None = no TCP listener
    ws_port: int | None = None  # WebSocket; None = no WebSocket listener
    metrics_port: int | None = None  # Prometheus /metrics over HTTP
    http_port: int | None = None  # the browser viewer (entitynet/viewer) and /metrics; needs ws_port, topology
    tls_cert: str | None = None
    tls_key: str | None = None
    topology: str | None = None
    digest: str | None = None
    n_cells: int | None = None
    open_mode: bool = False
    users_db: str | None = None  # None = entitynet.auth.default_db_path()
    auth_recheck: float = 1.0  # how often (s) to look for changes of the token store and re-check connections
    auth_timeout: float = 2.0  # a token store read (off the loop) answers within this (s) or the login is refused
    flush_interval: float = 0.01  # news waits at most this long (s) for a flush: one write per connection per flush
    flush_min_interval: float = 0.0  # ... and flushes (as soon as the loop is idle) are at least this far apart
    # the latency budget (s): at light load news waits up to this long for more news to share its flush (one
    # wake-up and one writev per connection carry many deliveries), unless `flush_fill` messages per waiting
    # connection are queued first; 0 flushes as soon as the loop is idle (docs/switch.md, "CPU that falls ...")
    latency_budget: float = 0.02
    flush_fill: int = 8  # queued messages per dirty connection that make a flush worth doing before the budget
    # a connection whose frame would carry fewer than this many states (and nothing else) waits for the next
    # flush, once (a frame costs a writev whatever it carries); 1 = every frame goes at once (flushloop.py)
    flush_min_frame: int = 1
    pace: float = 0.0  # at light load the loop wakes at most once per this (s): entitynet/server/pacing.py; 0 = off
    gc_full_every: float | None = None  # full garbage collections only this often (s); None = Python's (gcpolicy)
    stall_timeout: float = 5.0  # a write blocked this long without progress (client not reading) drops it
    max_batch: int = 20_000  # messages per written frame (and at most the codec's max_frame bytes)
    feed_slice: int = 256  # messages of one frame fed to the core between checkpoints (others served between)
    read_size: int = 65_536
    sndbuf: int | None = 131_072  # cap the kernel send buffer: backlog then waits in the coalescing outbox
    handshake_timeout: float = 10.0  # a connection without HELLO this long is closed (HANDSHAKE_REQUIRED)
    max_clients: int = 20_000  # connections beyond this are refused with SERVER_FULL (pending TLS/upgrades count)
    fd_reserve: int = 64  # refuse new connections while fewer descriptors than this are left (fdlimit.py)
    raise_nofile: bool = True  # raise the soft RLIMIT_NOFILE to the hard limit at start
    http_header_timeout: float = 5.0  # metrics HTTP: a request must arrive within this (http.py)
    http_idle_timeout: float = 15.0  # metrics HTTP: a kept-alive connection idle this long is closed
    http_max_connections: int = 64  # metrics HTTP: connections beyond this get 503
    http_max_request: int = 16_384  # metrics HTTP: bytes of a request head (or body)
    shutdown_grace: float = 1.0  # time to flush SHUTTING_DOWN to everyone before closing
    switch: dict[str, Any] = field(default_factory=dict)  # SwitchConfig overrides (limits)
    clock: Callable[[], float] = time.time  # the server clock reported in WELCOME/PONG and used for expiry
    log_json: bool = False
    cluster: Any = None  # entitynet.cluster.link.ClusterConfig: join a sharded cluster over NATS (docs/cluster.md)
