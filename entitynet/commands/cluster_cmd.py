"""`entitynet cluster up | status` and the `--cluster` options of `entitynet serve` (docs/cluster.md).

`cluster up` starts a local cluster for the demo and tests: nats-server nodes (routed when more than one) and K
`entitynet serve --cluster` processes on loopback, one per region, and keeps them until Ctrl-C or `--duration`;
it writes a state file that `cluster status` reads. `cluster status` listens to the shards' heartbeats on NATS
and prints regions, owners, clients, entities and load.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path

from entitynet.cli import CommandError
from entitynet.cluster.defaults import CONNECT_TIMEOUT_S, DEAD_AFTER_S
from entitynet.commands.options import MAX_SHARDS, bounded_float, bounded_int, positive_seconds

#: the options of `serve` that only mean something with --cluster (dest -> option)
CLUSTER_ONLY = {"shard": "--shard", "regions": "--regions", "shards": "--shards", "advertise": "--advertise",
                "nats_token": "--nats-token", "nats_ca": "--nats-ca", "dead_after": "--dead-after",
                "nats_connect_timeout": "--nats-connect-timeout"}

DEFAULT_STATE = Path(os.environ.get("ENTITYNET_CLUSTER_STATE", Path.home() / ".cache/entitynet/cluster.json"))


def add_cluster_options(p: argparse.ArgumentParser) -> None:
    """The `--cluster ...` options of `entitynet serve`; `cluster_config_from` checks them together."""
    g = p.add_argument_group("cluster (sharded switchboards over NATS)")
    g.add_argument("--cluster", metavar="URLS", help="join a cluster: NATS servers nats://HOST:PORT[,...]")
    g.add_argument("--shard", type=bounded_int(0, MAX_SHARDS - 1),
                   metavar="N", help="this switchboard's shard (owns region N)")
    g.add_argument("--regions", metavar="MAP", help="cluster map from `entitynet topology regions`")
    g.add_argument("--shards", type=bounded_int(1, MAX_SHARDS),
                   metavar="K", help="or compute K regions from the topology at start")
    g.add_argument("--advertise", metavar="HOST:PORT", help="address clients are redirected to (default: listen)")
    g.add_argument("--nats-token", metavar="TOKEN", help="NATS auth token (default: $ENTITYNET_NATS_TOKEN)")
    g.add_argument("--nats-ca", metavar="PEM", help="CA bundle for TLS to NATS (tls:// or a server that needs it)")
    g.add_argument("--dead-after", type=bounded_float(0.5, 3600), metavar="S",
                   help=f"a shard silent this long is dead and its regions pass on (default {DEAD_AFTER_S:g} s)")
    g.add_argument("--nats-connect-timeout", type=bounded_float(0.1, 60), metavar="S",
                   help=f"one NATS connect attempt's timeout (default {CONNECT_TIMEOUT_S:g} s); joining gives up "
                        "after this x max(2, servers) + 1 s with one line (a far or slow NATS may need more)")


def cluster_config_from(args: argparse.Namespace):
    """The ClusterConfig of `serve --cluster ...` (errors are CommandErrors)."""
    from entitynet.cluster.link import ClusterConfig
    from entitynet.cluster.nats_client import parse_servers
    from topology import artifact
    from topology.regions import RegionError, RegionMap, build_regions, cell_adjacency

    try:
        parse_servers(args.cluster)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    if args.shard is None:
        raise CommandError("--cluster needs --shard N")
    if (args.regions is None) == (args.shards is None):
        raise CommandError("--cluster needs either --regions MAP or --shards K")
    try:
        topo = artifact.load(args.topology)
    except (OSError, artifact.ArtifactError) as exc:
        raise CommandError(f"cannot load topology {args.topology}: {exc}") from None
    try:
        regions = (RegionMap.load(args.regions, topology_digest=topo.digest) if args.regions
                   else build_regions(topo, args.shards))
    except RegionError as exc:
        raise CommandError(str(exc)) from None
    if not 0 <= args.shard < regions.shards:
        raise CommandError(f"--shard must be between 0 and {regions.shards - 1}")
    tls = nats_tls(args.nats_ca, args.cluster)
    dead_after = DEAD_AFTER_S if args.dead_after is None else args.dead_after
    return ClusterConfig(args.cluster, args.shard, regions, address=args.advertise,
                         token=args.nats_token or os.environ.get("ENTITYNET_NATS_TOKEN"), tls=tls,
                         heartbeat_s=min(0.5, dead_after / 4), dead_after_s=dead_after,
                         connect_timeout_s=(CONNECT_TIMEOUT_S if args.nats_connect_timeout is None
                                            else args.nats_connect_timeout),
                         cell_adjacency=[sorted(a) for a in cell_adjacency(topo)])  # publishers' border band


def nats_tls(ca: str | None, urls: str):
    """The TLS context for NATS (`--nats-ca`, or a tls:// URL with the system's CAs), None for plain TCP; a CA
    bundle that cannot be read is a CommandError naming it."""
    import ssl

    if not ca and not urls.startswith("tls://"):
        return None
    try:
        return ssl.create_default_context(cafile=ca)
    except (OSError, ssl.SSLError) as exc:
        raise CommandError(f"--nats-ca {ca}: {exc}") from None


def check_cluster_only(args: argparse.Namespace) -> None:
    """Without --cluster, a cluster option would be ignored in silence: refuse it, naming the options."""
    if args.cluster:
        return
    given = [option for dest, option in CLUSTER_ONLY.items() if getattr(args, dest, None) is not None]
    if given:
        raise CommandError(f"{', '.join(given)} only take effect with --cluster URLS")


def register(sub) -> None:
    """The `entitynet cluster up | status` subcommands."""
    p = sub.add_parser("cluster", help="a local sharded cluster (nats-server + switchboards) and its status")
    csub = p.add_subparsers(dest="cluster_command", metavar="ACTION", required=True)
    up = csub.add_parser("up", help="start nats-server nodes and K switchboards on loopback")
    up.add_argument("--shards", type=bounded_int(1, 64),
                    default=2, metavar="K", help="switchboards, one per region (default 2)")
    up.add_argument("--nats-nodes", type=bounded_int(1, 16),
                    default=1, metavar="N", help="nats-server nodes (default 1)")
    up.add_argument("--topology", metavar="FILE", help="artifact (default: the bundled Helsinki map)")
    up.add_argument("--duration", type=positive_seconds(), help="stop after this many seconds (default: until Ctrl-C)")
    up.add_argument("--state", default=str(DEFAULT_STATE), help=f"state file (default {DEFAULT_STATE})")
    up.set_defaults(func=cmd_up)
    st = csub.add_parser("status", help="regions, owners, clients, entities and load of a running cluster")
    st.add_argument("--nats", metavar="URLS", help="NATS servers (default: from the state file of `cluster up`)")
    st.add_argument("--nats-token", metavar="TOKEN", help="NATS auth token (default: $ENTITYNET_NATS_TOKEN)")
    st.add_argument("--nats-ca", metavar="PEM", help="CA bundle for TLS to NATS (tls:// or a server that needs it)")
    st.add_argument("--state", default=str(DEFAULT_STATE))
    st.add_argument("--listen", type=bounded_float(0.1, 3600),
                    default=1.5, metavar="S", help="how long to listen (default 1.5 s)")
    st.add_argument("--json", action="store_true")
    st.set_defaults(func=cmd_status)


def cmd_up(args: argparse.Namespace) -> int:
    """Start NATS and one switchboard per region on loopback, write the state file `cluster status` reads, and
    keep running until Ctrl-C, `--duration` or every shard dying (one dying is the failover demo)."""
    from entitynet.cluster.natsd import NatsCluster, NatsServerMissing
    from topology.regions import build_regions

    if args.shards < 1 or args.nats_nodes < 1:
        raise CommandError("--shards and --nats-nodes must be at least 1")
    if args.topology:
        from entitynet.commands.topology_cmd import load_artifact

        topo, path = load_artifact(args.topology), Path(args.topology)
    else:
        from entitynet.topology_cache import bundled_topology

        topo, path = bundled_topology(lambda m: print(m, file=sys.stderr))
    state_path = Path(args.state)
    state_path.parent.mkdir(parents=True, exist_ok=True)
    run_dir = state_path.parent / "cluster-run"
    run_dir.mkdir(exist_ok=True)
    regions = build_regions(topo, args.shards)
    map_path = run_dir / "regions.json"
    regions.save(map_path)
    nats = NatsCluster(args.nats_nodes, log_dir=run_dir)
    try:
        nats.start()
    except (NatsServerMissing, RuntimeError) as exc:
        raise CommandError(str(exc)) from None
    from entitynet.cluster.local import LocalShards

    shards = LocalShards(path, map_path, nats.urls, args.shards, run_dir)
    try:
        shards.start()
        procs, ports = shards.procs, shards.ports
        state = {"nats": nats.urls, "nats_pids": [n.proc.pid for n in nats.nodes], "regions": str(map_path),
                 "topology": str(path), "digest": regions.digest,
                 "shards": [{"shard": i, "address": f"127.0.0.1:{p}", "pid": pr.pid}
                            for i, (p, pr) in enumerate(zip(ports, procs, strict=True))]}
        state_path.write_text(json.dumps(state, indent=1))
        print(f"NATS {nats.urls}; {args.shards} shards: "
              + ", ".join(f"{i}=127.0.0.1:{p}" for i, p in enumerate(ports)), flush=True)
        print(f"state in {state_path}; logs in {run_dir}; Ctrl-C stops everything", flush=True)
        stop_at = None if args.duration is None else time.monotonic() + args.duration
        signal.signal(signal.SIGTERM, _interrupt)
        reported: set[int] = set()
        while stop_at is None or time.monotonic() < stop_at:
            for i, pr in enumerate(procs):  # a dead shard is the failover demo, not the end of the cluster
                if pr.poll() is not None and i not in reported:
                    reported.add(i)
                    print(f"shard {i} exited with {pr.returncode} (its regions pass to the others); "
                          f"see {run_dir}/shard-{i}.log", file=sys.stderr, flush=True)
            if len(reported) == len(procs):
                raise CommandError("every shard has exited")
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    except RuntimeError as exc:
        raise CommandError(str(exc)) from None
    finally:
        shards.stop()
        nats.stop()
        state_path.unlink(missing_ok=True)
    return 0


def _interrupt(*_args) -> None:
    raise KeyboardInterrupt


def cmd_status(args: argparse.Namespace) -> int:
    """Listen to the shards' heartbeats on NATS and print one line per shard; NATS comes from `--nats` or the
    state file of `cluster up`. Exit 1 when no switchboard is heard."""
    import trio

    urls = args.nats
    if urls is None:
        try:
            urls = json.loads(Path(args.state).read_text())["nats"]
        except (OSError, ValueError, KeyError) as exc:
            raise CommandError(f"no --nats and no running `cluster up` state ({args.state}): {exc}") from None
    tls = nats_tls(args.nats_ca, str(urls))
    token = args.nats_token or os.environ.get("ENTITYNET_NATS_TOKEN")
    try:
        shards = trio.run(_listen, urls, args.listen, token, tls)
    except (OSError, trio.TooSlowError) as exc:
        raise CommandError(f"cannot reach NATS at {urls}: {exc}") from None
    if args.json:
        print(json.dumps(shards, indent=1))
        return 0
    if not shards:
        print("no switchboard heard on", urls)
        return 1
    print(f"{'cluster':14} {'shard':>5} {'address':>21} {'regions':>7} {'clients':>7} {'entities':>8} "
          f"{'mirrored':>8} {'subs':>6} {'updates/s':>9}")
    for s in shards:
        print(f"{s['cluster']:14} {s['shard']:5d} {s['address']:>21} {s['owned_regions']:7d} {s['clients']:7d} "
              f"{s['entities']:8d} {s['mirrored']:8d} {s['subscriptions']:6d} {s['updates_per_s']:9.1f}")
    return 0


async def _listen(urls: str, seconds: float, token: str | None = None, tls=None) -> list[dict]:
    """Heartbeats of every cluster on these NATS servers for `seconds`: the latest per shard, with load (`token`
    and `tls` as a shard's: a NATS that wants a token refuses a status without it)."""
    import msgpack
    import trio

    from entitynet.cluster.core import HEARTBEAT
    from entitynet.cluster.nats_client import NatsClient

    seen: dict[tuple[str, int], list] = {}

    def on_hb(subject: str, reply, data: bytes) -> None:
        try:
            m = msgpack.unpackb(data, raw=False, strict_map_key=False)
            if m[0] == HEARTBEAT:
                seen.setdefault((subject.split(".")[1], int(m[1])), []).append((trio.current_time(), m))
        except Exception:  # someone else's message on a matching subject
            pass

    async with NatsClient(urls, name="entitynet-status", token=token, tls=tls) as nc:
        nc.subscribe("en.*.hb", on_hb)
        await trio.sleep(seconds)
    out = []
    for (cluster, shard), beats in sorted(seen.items()):
        t1, last = beats[-1]
        counts = last[4] if isinstance(last[4], dict) else {}
        t0, first = beats[0]
        c0 = first[4] if isinstance(first[4], dict) else {}
        rate = (counts.get("updates_in", 0) - c0.get("updates_in", 0)) / (t1 - t0) if t1 > t0 else 0.0
        out.append({"cluster": cluster, "shard": shard, "address": str(last[2]),
                    "owned_regions": int(counts.get("owned_regions", 0)), "clients": int(counts.get("clients", 0)),
                    "entities": int(counts.get("entities", 0)) - int(counts.get("mirrored", 0)),
                    "mirrored": int(counts.get("mirrored", 0)), "subscriptions": int(counts.get("subscriptions", 0)),
                    "updates_per_s": round(rate, 1)})
    return out
