"""Map data -> topology artifact: reading, cleaning, graph, visibility cells, view cells and PVS.

This package imports nothing from `entitynet`, `proxies` or `sims`.
"""

from pathlib import Path

BUNDLED_MAP = Path(__file__).parent / "data" / "helsinki.osm.pbf"
