"""Benchmark suites: `entitynet bench SUITE [--quick] --out FILE.json`.

Each suite is a module with `run(args, progress) -> dict` returning `params`, `results` and, for
comparisons, `peer` and `ratio` (see `sims.bench.report.write_report`).

Why a registry with an entry-point group: the suites live in several packages (`sims` has the topology,
PVS, dead-reckoning and switch suites; `proxies` brings its own), and `entitynet` must import none of them
by name. A package adds a suite with `[project.entry-points."entitynet.bench_suites"]`
`NAME = "package.module"` (the value is the suite's module path; it is imported only when that suite runs).
"""

from __future__ import annotations

from importlib.metadata import entry_points

#: entry-point group through which other packages add suites: `name = "module.path"`
SUITE_GROUP = "entitynet.bench_suites"

#: the suites of this package: name -> module path
SUITES = {
    "topology": "sims.bench.topology_bench",
    "dr": "sims.bench.dr_bench",
    "switch": "sims.bench.switch_bench",
    "pvs": "sims.bench.pvs_bench",
    "sim": "sims.bench.sim_bench",
    "cluster": "sims.bench.cluster_bench",
    "e2e": "sims.bench.e2e_bench",
}


def all_suites(group: str = SUITE_GROUP) -> dict[str, str]:
    """Suite name -> module path: this package's SUITES plus every installed `entitynet.bench_suites` entry
    (a built-in name wins: a plugin cannot silently replace a suite whose numbers the docs quote)."""
    found = {ep.name: ep.value for ep in entry_points(group=group)}
    return {**found, **SUITES}
