"""The PVS quality presets, apart from the PVS builder: the command line offers them as choices when it builds
its parser, and every `entitynet` process builds that parser, a switchboard shard's included, which must not
pay for importing shapely (about half a second) to learn three names."""

from __future__ import annotations

#: speed/accuracy presets of the PVS build (docs/pvs.md): raster cell (m), samples per view-cell side, occluder
#: shrink (m), ray spacing (m), and the distance from which far cells are stepped coarsely
QUALITY: dict[str, dict[str, float]] = {
    "fast": {"raster": 3.0, "samples": 2, "shrink": 3.0, "ray_spacing": 2.0, "far_step_from": 150.0},
    "default": {"raster": 2.0, "samples": 2, "shrink": 3.0, "ray_spacing": 2.0, "far_step_from": 200.0},
    "high": {"raster": 2.0, "samples": 3, "shrink": 2.0, "ray_spacing": 1.5, "far_step_from": 1e9},
}
