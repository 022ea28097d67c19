"""The PVS parts of `entitynet topology`: the build options for view cells and the PVS, and
`entitynet topology pvs FILE --at X Y Z [--json]`.

Why here and not in `topology.pvs`: this is command-line glue (argparse, CommandError, printing), and
`topology` imports nothing of `entitynet` (the arrows run topology <- entitynet).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from entitynet.cli import CommandError
from entitynet.commands.options import LOCAL_COORDINATE, METRES, bounded_float, bounded_int
from topology.pvs_index import PvsIndex
from topology.pvs_quality import QUALITY

if TYPE_CHECKING:
    from topology.pvs import PvsConfig

#: view-cell cube side: below 2 m a city is billions of view cells (0.001 m was a MemoryError, 0.5 m hours);
#: m-LOMA's cubes are a little under a building's height (docs/pvs.md)
VIEW_CELL_SIZE = bounded_float(2.0, 1000.0)


def add_pvs_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `entitynet topology build` for the view cells and the PVS (`--no-pvs` is the builder's)."""
    g = parser.add_argument_group("visibility (view cells and PVS)")
    g.add_argument("--pvs-quality", choices=sorted(QUALITY), default="default",
                   help="speed/accuracy preset of the PVS (default: default; see docs/pvs.md)")  # fmt: skip
    g.add_argument("--view-cell-size", type=VIEW_CELL_SIZE, metavar="M",
                   help="view-cell cube side, 2 to 1000 m (default 20 m)")  # fmt: skip
    g.add_argument("--view-max-height", type=METRES, metavar="M", help="top of the view cells (default 100 m)")
    g.add_argument("--view-distance", type=METRES, metavar="M", help="PVS range (default 500 m)")
    g.add_argument("--pvs-workers", type=bounded_int(1, 256), metavar="N", help="worker processes (default 2)")


def pvs_config_from_args(args: Any) -> PvsConfig:
    """The PvsConfig of parsed build options: the quality preset, then the options given (a worker count
    below 1 means in-process, 1, rather than an error: it is a resource hint, not a result setting)."""
    from topology.pvs import PvsConfig  # the builder (shapely) only when a PVS is built

    workers = getattr(args, "pvs_workers", None)
    if workers is not None and workers < 1:
        workers = 1
    return PvsConfig.from_quality(
        getattr(args, "pvs_quality", "default") or "default",
        cell_size=getattr(args, "view_cell_size", None),
        max_height=getattr(args, "view_max_height", None),
        view_distance=getattr(args, "view_distance", None),
        workers=workers,
    )


def register_pvs_command(tsub: Any, load_artifact: Callable[[str], Any]) -> None:
    """`entitynet topology pvs FILE --at X Y Z [--json]`: the view cell and PVS of a local position, to see
    what a viewer standing there would subscribe to."""
    p = tsub.add_parser("pvs", help="print the PVS (visible cells) of the view cell holding a position")
    p.add_argument("file")
    p.add_argument("--at", nargs=3, type=LOCAL_COORDINATE, metavar=("X", "Y", "Z"), required=True,
                   help="local position in metres (relative to the artifact's origin)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object")

    def run(args: Any) -> int:
        topo = load_artifact(args.file)
        try:
            index = PvsIndex.from_topology(topo)
            x, y, z = args.at
            own = index.view_cell_of(x, y, z)
            used = index.lookup_cell(x, y, z)
            cells = index.cells_at(x, y, z)
        except ValueError as exc:
            raise CommandError(f"{args.file}: {exc}") from None
        info = {"position": [x, y, z], "view_cell": own, "answered_by": used, "n_cells": int(len(cells)),
                "in_grid": bool(_in_grid(index, x, y, z)), "cells": cells.tolist()}  # fmt: skip
        if args.json:
            print(json.dumps(info))
        else:
            note = "" if info["in_grid"] else " (outside the grid: clamped)"
            inside = "" if own == used else f" (inside a building: answered by view cell {used})"
            print(f"view cell {own}{inside}{note}: {len(cells)} visible cells")
            print(" ".join(str(c) for c in cells))
        return 0

    p.set_defaults(func=run)


def _in_grid(index: PvsIndex, x: float, y: float, z: float) -> bool:
    g = index.grid
    return (g.x0 <= x <= g.x0 + g.nx * g.size) and (g.y0 <= y <= g.y0 + g.ny * g.size) and 0 <= z <= g.max_height
