"""`entitynet topology regions ART --shards K [--out MAP]`: the shard regions of a topology (topology.regions).

Prints the report (cells and load share per region, balance, cut size, border cells) and, with `--out`, writes
the cluster map that `entitynet serve --cluster ... --regions MAP` and `entitynet cluster up` use.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

from entitynet.cli import CommandError
from entitynet.commands.options import MAX_SHARDS, bounded_int


def register(tsub, load_artifact: Callable[[str], Any]) -> None:
    """The `entitynet topology regions` subcommand (`load_artifact` is passed in, as the topology command
    loads artifacts its own way)."""
    r = tsub.add_parser("regions", help="partition the cells into K shard regions with their border cells")
    r.add_argument("file", help="topology artifact")
    r.add_argument("--shards", type=bounded_int(1, MAX_SHARDS),
                   required=True, metavar="K", help="number of regions (switchboards)")
    r.add_argument("--out", metavar="MAP", help="cluster map to write (JSON)")
    r.add_argument("--weights", metavar="FILE",
                   help="expected load per cell as JSON (a list, or {cell: weight}); default: footprint area")
    r.add_argument("--json", action="store_true", help="print the report as JSON")

    def run(args: argparse.Namespace) -> int:
        from topology.regions import RegionError, build_regions, load_weights

        topo = load_artifact(args.file)
        try:
            weights = load_weights(args.weights, int(topo.n_cells)) if args.weights else None
            rm = build_regions(topo, args.shards, weights)
        except RegionError as exc:
            raise CommandError(str(exc)) from None
        if args.out:
            try:
                rm.save(args.out)
            except OSError as exc:
                raise CommandError(f"cannot write {args.out}: {exc}") from None
        rep = dict(rm.report, digest=rm.digest, topology_digest=rm.topology_digest, out=args.out)
        if args.json:
            print(json.dumps(rep, indent=1))
            return 0
        print(f"{rm.shards} regions over {rep['cells']} cells (weights: {rep['weights']}); map digest "
              f"{rm.digest[:16]}{'' if not args.out else ' -> ' + args.out}")
        print(f"balance (heaviest / mean load): {rep['balance']:.3f}; cut: {rep['cut_adjacencies']} cell "
              f"adjacencies; detached pieces: {rep['detached_components']}; borders by {rep['border_rule']}")
        street = rep.get("border_cells_street_level") or [None] * rm.shards
        for k in range(rm.shards):
            extra = "" if street[k] is None else f", {street[k]} from street level"
            print(f"  region {k}: {rep['cells_per_region'][k]:6d} cells, load {100 * rep['load_share'][k]:5.1f} %, "
                  f"border {rep['border_cells'][k]} cells{extra}")
        return 0

    r.set_defaults(func=run)
