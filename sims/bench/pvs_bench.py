"""`entitynet bench pvs [--quick]`: PVS build time, accuracy against the dense exact reference, culling,
storage and lookup time.

- Headline: the PVS of the whole map (or, with --quick, of a central 400 m window) at the default setting,
  2 worker processes; `build_s` is its wall time.
- Accuracy: view cells sampled at random, stratified by layer (height band); for each, the exact reference
  (`topology.pvs_reference`) against the PVS. fn_rate = pairs visible in the reference but missing in the PVS
  / pairs visible in the reference; fp_rate = pairs in the PVS the reference never sees / pairs in the PVS.
- Speed against error: the quality presets on a central window (same reference sample for all rows).
- Culling: fraction of the in-range cells (pure distance cut) that the PVS leaves out, per view cell; street
  = the lowest layer, roof = layers whose bottom is above the 90th percentile building height.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import shapely

from sims.bench.report import pyplot
from topology.polygons import Polygons
from topology.pvs import PvsConfig, PvsIndex, compute_pvs
from topology.pvs_codec import raw_nbytes
from topology.pvs_reference import ReferenceConfig, Scene, in_range, reference_visible, target_points


def _load(args, progress):
    from topology.artifact import load

    if getattr(args, "topology", None):
        return load(args.topology)
    from entitynet.topology_cache import bundled_topology

    topo, _ = bundled_topology(progress, with_pvs=False)
    return topo


def crop(bf: Polygons, bh, cf: Polygons, ch, bounds, size: float):
    """Buildings and cells meeting a central size x size window (cells clipped to it), and its bounds."""
    cx, cy = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
    win = (cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2)
    box = shapely.box(*win)
    bp, cp = bf.to_shapely(), cf.to_shapely()
    bsel = np.flatnonzero(shapely.intersects(bp, box))
    csel = np.flatnonzero(shapely.intersects(cp, box))
    clipped = shapely.intersection(cp[csel], box)
    keep = np.array([g.geom_type == "Polygon" and g.area > 1.0 for g in clipped], dtype=bool)
    return (
        Polygons.from_shapely(bp[bsel]), np.asarray(bh)[bsel],
        Polygons.from_shapely(clipped[keep]), np.asarray(ch)[csel][keep], win,
    )  # fmt: skip


class Evaluator:
    """The dense reference for a sample of view cells, computed once and compared with any PVS result."""

    def __init__(self, bf, bh, cf, ch, cfg: ReferenceConfig | None = None):
        self.scene = Scene(bf, bh)
        self.cfg = cfg or ReferenceConfig()
        self.targets, self.target_cell = target_points(cf, ch, self.cfg.target_spacing, self.cfg.target_levels)
        self.cell_polys = cf.to_shapely()
        self.refs: dict[int, np.ndarray] = {}
        self.ref_s = 0.0

    def sample(self, result, per_layer: int, seed: int = 7) -> np.ndarray:
        """`per_layer` view cells drawn from each layer (height band), so that street-level and roof-level
        accuracy are both measured; seeded, so runs compare."""
        rng = np.random.default_rng(seed)
        iz, _, _ = result.grid.coords()
        out = []
        for k in range(result.grid.nz):
            ids = np.flatnonzero(iz == k)
            if len(ids):
                out.extend(rng.choice(ids, min(per_layer, len(ids)), replace=False).tolist())
        return np.array(sorted(out), dtype=np.int64)

    def compare(self, result, views: np.ndarray, progress=None) -> dict[str, Any]:
        """False-negative and false-positive rates of `result` against the reference on `views`, overall and
        per height band; each reference is computed once and reused for every preset."""
        boxes = result.grid.boxes()
        iz, _, _ = result.grid.coords()
        per: dict[int, list[int]] = {}
        for n, v in enumerate(views):
            v = int(v)
            if v not in self.refs:
                t0 = time.perf_counter()
                cand = in_range(boxes[v], self.cell_polys, result.config.view_distance)
                self.refs[v] = reference_visible(self.scene, boxes[v], self.targets, self.target_cell, cand, self.cfg)
                self.ref_s += time.perf_counter() - t0
                if progress and (n + 1) % 5 == 0:
                    progress(f"reference: {n + 1}/{len(views)} view cells ({self.ref_s:.0f} s)")
            ref, got = self.refs[v], result.pvs_of(v)
            row = per.setdefault(int(iz[v]), [0, 0, 0, 0])
            row[0] += len(np.setdiff1d(ref, got))
            row[1] += len(ref)
            row[2] += len(np.setdiff1d(got, ref))
            row[3] += len(got)
        tot = np.sum(list(per.values()), axis=0) if per else np.zeros(4)
        bands = {}
        for k in sorted(per):
            fn, vis, fp, got = per[k]
            z0, z1 = float(result.grid.layer_bottom(k)), float(result.grid.layer_top(k))
            bands[f"{z0:.0f}-{z1:.0f} m"] = {
                "view_cells": int(np.sum(iz[views] == k)),
                "fn_rate": round(fn / vis, 5) if vis else 0.0,
                "fp_rate": round(fp / got, 5) if got else 0.0,
                "visible_pairs": int(vis),
            }
        return {
            "fn_rate": round(float(tot[0] / tot[1]), 5) if tot[1] else 0.0,
            "fp_rate": round(float(tot[2] / tot[3]), 5) if tot[3] else 0.0,
            "visible_pairs": int(tot[1]),
            "by_height": bands,
        }


def lookup_times(result, n: int = 20000, seed: int = 3) -> dict[str, float]:
    """Microseconds per `cells_at` call at random positions (in and a little outside the grid): the first
    pass (mostly cold decodes), a pass with every list cached, and one cold decode alone."""
    index = PvsIndex.from_result(result)
    g = result.grid
    rng = np.random.default_rng(seed)
    xs = rng.uniform(g.x0 - 50, g.x0 + g.nx * g.size + 50, n)
    ys = rng.uniform(g.y0 - 50, g.y0 + g.ny * g.size + 50, n)
    zs = rng.uniform(0, g.max_height + 20, n)
    t0 = time.perf_counter()
    for x, y, z in zip(xs.tolist(), ys.tolist(), zs.tolist(), strict=True):
        index.cells_at(x, y, z)
    first = (time.perf_counter() - t0) / n * 1e6
    for v in range(g.n_view_cells):  # every list decoded once: the steady state of a long-running viewer
        index.pvs(v)
    t0 = time.perf_counter()
    for x, y, z in zip(xs.tolist(), ys.tolist(), zs.tolist(), strict=True):
        index.cells_at(x, y, z)
    warm = (time.perf_counter() - t0) / n * 1e6
    cold_index = PvsIndex.from_result(result)
    cold_index._cache_size = 0
    views = rng.integers(0, g.n_view_cells, 2000)
    t0 = time.perf_counter()
    for v in views.tolist():
        cold_index._cache.clear()
        cold_index.pvs(v)
    cold = (time.perf_counter() - t0) / len(views) * 1e6
    return {"lookup_us": round(first, 2), "lookup_us_warm": round(warm, 2), "decode_us_cold": round(cold, 2)}


def culling(result, building_height) -> dict[str, Any]:
    """How much of the pure distance cut the PVS removes, at street level and above the roofs: what the PVS
    buys a viewer in subscriptions."""
    sizes = np.diff(result.offsets)
    rc = result.range_count
    frac = np.where(rc > 0, 1.0 - sizes / np.maximum(rc, 1), 0.0)
    iz, _, _ = result.grid.coords()
    roof_z = float(np.quantile(building_height, 0.9)) if len(building_height) else 0.0
    roof = result.grid.layer_bottom(iz) >= roof_z
    street = iz == 0
    return {
        "culled_fraction_street": round(float(frac[street].mean()), 4) if street.any() else None,
        "culled_fraction_roof": round(float(frac[roof].mean()), 4) if roof.any() else None,
        "roof_threshold_m": round(roof_z, 1),
        "culled_by_layer": result.stats["culled_by_layer"],
    }


def run(args, progress) -> dict:
    """The suite (`entitynet bench pvs`): headline build, accuracy, quality presets, culling, storage and
    lookup times, as the body of the report."""
    quick = bool(getattr(args, "quick", False))
    topo = _load(args, progress)
    bf, bh, cf, ch = topo.building_footprints, topo.building_height, topo.cell_footprints, topo.cell_height
    bounds = tuple(topo.meta["bounds"])
    per_layer = 2 if quick else 5
    window = 300.0 if quick else 600.0
    wb = crop(bf, bh, cf, ch, bounds, window)
    notes = []

    # headline
    if quick:
        head_in = wb
        notes.append(f"--quick: headline on a central {window:.0f} m window of the map, not the whole map")
    else:
        head_in = (bf, bh, cf, ch, bounds)
    default = PvsConfig.from_quality("default", workers=2)
    progress("headline PVS (default setting)")
    t0 = time.perf_counter()
    head = compute_pvs(*head_in, config=default, progress=progress)
    build_s = time.perf_counter() - t0
    progress(f"headline built in {build_s:.1f} s; dense reference on {per_layer} view cells per layer")
    ev_head = Evaluator(head_in[0], head_in[1], head_in[2], head_in[3])
    views = ev_head.sample(head, per_layer)
    acc = ev_head.compare(head, views, progress)
    extra = head.to_extra()
    bytes_compressed = int(sum(a.nbytes for k, a in extra.items() if k != "pvs_grid"))
    results: dict[str, Any] = {
        "view_cells": int(head.grid.n_view_cells),
        "visibility_cells": int(head.n_cells),
        "build_s": round(build_s, 2),
        "fn_rate": acc["fn_rate"],
        "fp_rate": acc["fp_rate"],
        "accuracy_by_height": acc["by_height"],
        "reference_view_cells": int(len(views)),
        "reference_visible_pairs": acc["visible_pairs"],
        "mean_pvs_cells": round(float(np.diff(head.offsets).mean()), 1),
        "mean_range_cells": round(float(head.range_count.mean()), 1),
        **culling(head, head_in[1]),
        "bytes_raw": raw_nbytes(head.offsets, head.n_cells),
        "bytes_compressed": bytes_compressed,
        "bytes_grid": int(extra["pvs_grid"].nbytes),
        **lookup_times(head),
        "reference_s": round(ev_head.ref_s, 1),
    }

    # speed against error on the central window, one reference sample for all settings
    progress(f"settings table on a central {window:.0f} m window")
    ev = ev_head if quick else Evaluator(wb[0], wb[1], wb[2], wb[3])
    table = []
    wviews = None
    settings = ["fast", "default", "default-noshrink"] + ([] if quick else ["high"])
    for name in settings:
        base_name = name.split("-")[0]
        cfg = PvsConfig.from_quality(base_name, workers=2, shrink=0.0 if name.endswith("noshrink") else None)
        if quick and name == "default":
            res, secs = head, build_s
        else:
            t0 = time.perf_counter()
            res = compute_pvs(*wb, config=cfg, progress=None)
            secs = time.perf_counter() - t0
        if wviews is None:
            wviews = views if quick else ev.sample(res, max(2, per_layer - 2), seed=11)
        a = ev.compare(res, wviews, progress)
        table.append({
            "setting": name, "raster": cfg.raster, "samples": cfg.samples, "shrink": cfg.shrink,
            "ray_spacing": cfg.ray_spacing,
            "build_s": round(secs, 2), "fn_rate": a["fn_rate"], "fp_rate": a["fp_rate"],
            "mean_pvs_cells": round(float(np.diff(res.offsets).mean()), 1),
            "fn_by_height": {k: v["fn_rate"] for k, v in a["by_height"].items()},
        })  # fmt: skip
        progress(f"setting {name}: {secs:.1f} s, FN {a['fn_rate']:.4f}, FP {a['fp_rate']:.4f}")
    results["settings"] = table
    params = {
        "quick": quick,
        "map": getattr(args, "topology", None) or "bundled Helsinki",
        "cell_size": default.cell_size,
        "max_height": default.max_height,
        "view_distance": default.view_distance,
        "workers": default.workers,
        "headline_quality": "default",
        "table_window_m": window,
        "reference": {"eyes_xy": ev_head.cfg.eyes_xy, "eyes_z": ev_head.cfg.eyes_z,
                      "target_spacing_m": ev_head.cfg.target_spacing, "target_levels": ev_head.cfg.target_levels,
                      "view_cells_per_layer": per_layer},  # fmt: skip
    }
    notes.append("fn/fp rates are over (view cell, visibility cell) pairs of the sampled view cells")
    return {"params": params, "results": results, "notes": notes}


def plot(report: dict, out: str) -> None:
    """docs/pvs.png: build time against false-negative rate per setting, and culling per layer."""
    plt = pyplot(print)
    if plt is None:
        return

    res = report["results"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for row in res["settings"]:
        ax1.scatter(row["build_s"], 100 * row["fn_rate"], s=40)
        ax1.annotate(f"{row['setting']} (FP {100 * row['fp_rate']:.0f}%)", (row["build_s"], 100 * row["fn_rate"]),
                     textcoords="offset points", xytext=(5, 5))  # fmt: skip
    ax1.axhline(1.0, ls="--", color="grey")
    ax1.annotate("target: 1%", (0, 1.0), xycoords=("axes fraction", "data"), xytext=(5, 3), textcoords="offset points")
    ax1.set_xlabel(f"build time (s), {report['params']['table_window_m']:.0f} m window")
    ax1.set_ylabel("false negatives (% of visible pairs)")
    ax1.set_title("speed against error")
    ax1.grid(alpha=0.3)
    layers = res["culled_by_layer"]
    x = [f"{20 * r['layer']}-{20 * r['layer'] + 20}" for r in layers]
    ax2.bar(x, [100 * r["mean"] for r in layers], color="tab:blue", alpha=0.7, label="mean")
    ax2.errorbar(x, [100 * r["p50"] for r in layers],
                 yerr=[[100 * (r["p50"] - r["p10"]) for r in layers], [100 * (r["p90"] - r["p50"]) for r in layers]],
                 fmt="o", color="k", label="median, p10-p90")  # fmt: skip
    ax2.set_xlabel("view-cell layer (m)")
    ax2.set_ylabel("cells culled vs distance cut (%)")
    ax2.set_title("culling against a pure 500 m distance cut")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=110)
