"""`entitynet bench SUITE [--quick] --out FILE.json`."""

from __future__ import annotations

import argparse
import importlib
import json
import sys


def register(sub) -> None:
    from sims.bench import SUITES

    p = sub.add_parser("bench", help="run a benchmark suite and write its JSON report")
    p.add_argument("suite", choices=sorted(SUITES), help="which suite")
    p.add_argument("--quick", action="store_true", help="a smaller run that finishes in under a minute")
    p.add_argument("--out", metavar="FILE.json", help="write the JSON report here (default: print it)")
    p.add_argument("--topology", metavar="FILE", help="topology artifact (default: the bundled Helsinki map)")
    p.set_defaults(func=run)


def progress(msg: str) -> None:
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    from sims.bench import SUITES
    from sims.bench.report import write_report

    module = importlib.import_module(SUITES[args.suite])
    body = module.run(args, progress)
    report = write_report(args.suite, body, args.out)
    print(json.dumps(report["results"], indent=2, default=float))
    if args.out:
        progress(f"report written to {args.out}")
    return 0
