"""Benchmark suites: `entitynet bench SUITE [--quick] --out FILE.json`.

Each suite module `sims.bench.<suite>` defines `add_arguments(parser)` (optional) and
`run(args, progress) -> dict` returning `params`, `results` and, for comparisons, `peer` and `ratio`.
"""

SUITES = {
    "topology": "sims.bench.topology_bench",
    "dr": "sims.bench.dr_bench",
    "switch": "sims.bench.switch_bench",
    "pvs": "sims.bench.pvs_bench",
    "cluster": "sims.bench.cluster_bench",
}
