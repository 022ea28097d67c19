"""`entitynet serve --topology FILE`: run one switchboard shard until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse

from entitynet.cli import CommandError, leaves
from entitynet.commands.options import bounded_float, bounded_int, port


def register(sub) -> None:
    """Add `entitynet serve` and its options to the CLI (called by `entitynet.cli` at start-up)."""
    p = sub.add_parser("serve", help="run a switchboard server (one shard)")
    p.add_argument("--topology", metavar="FILE", required=True,
                   help="topology artifact: the server learns its digest and cell count from it")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=port(), default=7400, help="TCP port (default 7400; 0 = any free port)")
    p.add_argument("--ws-port", type=port(), metavar="PORT",
                   help="also listen for WebSocket clients here (0 = any free port, logged)")
    p.add_argument("--metrics-port", type=port(), metavar="PORT",
                   help="serve Prometheus /metrics here (0 = any free port, logged)")
    p.add_argument("--http-port", type=port(), metavar="PORT",
                   help="serve the browser viewer (and /metrics) here; needs --ws-port (0 = any free port, logged; "
                        "docs/viewer.md)")
    p.add_argument("--tls-cert", metavar="PEM", help="TLS certificate chain (with --tls-key)")
    p.add_argument("--tls-key", metavar="PEM", help="TLS private key")
    p.add_argument("--open", action="store_true",
                   help="accept any token (local use only; said loudly in the log)")
    from entitynet.commands.users_cmd import add_users_db_option

    add_users_db_option(p, "token store, alias --db (default: see `entitynet users`)")
    p.add_argument("--flush-ms", type=bounded_float(0, 1000), default=10.0,
                   help="longest wait of news for a flush, under load (default 10 ms; an idle server flushes sooner)")
    p.add_argument("--flush-min-ms", type=bounded_float(0, 1000), default=0.0,
                   help="shortest time between two flushes, at most --flush-ms (default 0: flush whenever the "
                        "server is idle)")
    p.add_argument("--latency-budget-ms", type=bounded_float(0, 1000), default=20.0, metavar="MS",
                   help="at light load news waits up to MS for more news to share its flush (fewer wake-ups and "
                        "writes per delivery; default 20; 0 = flush as soon as the server is idle; docs/switch.md)")
    p.add_argument("--flush-fill", type=bounded_int(1, 1_000_000), default=8, metavar="N",
                   help="flush before the latency budget once N messages per waiting connection are queued "
                        "(default 8)")
    p.add_argument("--flush-min-frame", type=bounded_int(1, 1_000_000), default=1, metavar="N",
                   help="a connection with fewer than N states queued (and nothing else) waits for the next flush, "
                        "once: fewer, fuller writes; adds at most one flush interval (--flush-ms, or the latency "
                        "budget at light load) to those states' latency (default 1 = off; docs/switch.md)")
    p.add_argument("--pace-ms", type=bounded_float(0, 1000), default=0.0, metavar="MS",
                   help="at light load wake at most once per MS, reading everything that arrived meanwhile in one "
                        "go (adds up to MS of latency; default 0 = off; docs/switch.md)")
    p.add_argument("--gc-full-every", type=bounded_float(1, 86400, special={0: "Python's own policy"}),
                   default=300.0, metavar="S",
                   help="run Python's full garbage collection only every S seconds instead of whenever the heap "
                        "grows (default 300; 0 = Python's own policy; docs/switch.md)")
    p.add_argument("--grace", type=bounded_float(0, 3600), default=5.0,
                   help="seconds an entity outlives its validity (default 5, at most 3600)")
    p.add_argument("--log-json", action="store_true", help="structured logs as JSON lines")
    from entitynet.commands.cluster_cmd import add_cluster_options

    add_cluster_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the server until a signal; a bad option or a port that cannot be bound becomes a CommandError (one
    clear line for the user) instead of a traceback."""
    import logging

    from entitynet.interrupts import run_until_interrupted
    from entitynet.server import ConfigError, ServerConfig, logs, serve_until_signal

    if logging.getLogger().level > logging.INFO:  # the server's and the cluster link's events are shown
        logging.getLogger("entitynet.server").setLevel(logging.INFO)
        logging.getLogger("entitynet.cluster").setLevel(logging.INFO)
    logs.use_json(args.log_json)
    check_options(args)
    config = ServerConfig(
        host=args.host, port=args.port, ws_port=args.ws_port, metrics_port=args.metrics_port,
        http_port=args.http_port,
        tls_cert=args.tls_cert, tls_key=args.tls_key, topology=args.topology, open_mode=args.open,
        users_db=args.users_db, flush_interval=args.flush_ms / 1000.0,
        flush_min_interval=args.flush_min_ms / 1000.0, latency_budget=args.latency_budget_ms / 1000.0,
        flush_fill=args.flush_fill, flush_min_frame=args.flush_min_frame, pace=args.pace_ms / 1000.0,
        gc_full_every=args.gc_full_every or None,
        switch={"grace_s": args.grace}, log_json=args.log_json,
    )
    if args.cluster:
        from entitynet.commands.cluster_cmd import cluster_config_from

        config.cluster = cluster_config_from(args)
    try:
        run_until_interrupted(serve_until_signal, config)  # a Ctrl-C while it starts: 130, not a traceback
    except BaseExceptionGroup as group:  # raised inside the server's nurseries: the first user-facing cause
        # the first user-facing cause (a ListenError names its option and port); anything else is a bug
        first = next((e for e in leaves(group) if isinstance(e, ConfigError | OSError)), None)
        if first is None:
            raise
        raise CommandError(_message(first)) from None
    except (ConfigError, OSError) as exc:
        raise CommandError(_message(exc)) from None
    return 0


def check_options(args: argparse.Namespace) -> None:
    """What the options' ranges (checked by argparse) cannot say alone: --flush-min-ms is at most --flush-ms
    (it was capped in silence), and the cluster options need --cluster (they were ignored in silence)."""
    from entitynet.commands.cluster_cmd import check_cluster_only

    if args.flush_min_ms > args.flush_ms:
        raise CommandError(f"--flush-min-ms ({args.flush_min_ms:g}) cannot exceed --flush-ms ({args.flush_ms:g})")
    check_cluster_only(args)


def _message(exc: BaseException) -> str:
    """The one line of a ConfigError or OSError: a NatsConnectFailed (a refused NATS token, or no NATS server
    answering within the first connect's deadline: OSErrors, so that they are found here) comes from joining the
    cluster, other OSErrors from binding the ports."""
    from entitynet.cluster.nats_client import NatsConnectFailed
    from entitynet.server import ConfigError

    if isinstance(exc, ConfigError):
        return str(exc)
    return f"cannot join the cluster: {exc}" if isinstance(exc, NatsConnectFailed) else f"cannot listen: {exc}"


