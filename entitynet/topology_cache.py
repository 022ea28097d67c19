"""The cached artifact of the bundled map, so that `entitynet demo` builds it once per machine.

The cache key hashes the map file and the builder's own source (every module of the `topology` package), so a
new map, a new entitynet or a changed builder rebuilds instead of serving stale lists.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import topology
from entitynet import __version__
from topology import BUNDLED_MAP
from topology.artifact import ArtifactError, Topology, load, save


def cache_dir() -> Path:
    """Where built artifacts are cached: $ENTITYNET_CACHE, else $XDG_CACHE_HOME/entitynet
    (~/.cache/entitynet)."""
    base = os.environ.get("ENTITYNET_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "entitynet"
    )
    return Path(base)


def bundled_artifact_path(with_pvs: bool = True) -> Path:
    """The cache file of the bundled map; its name hashes the map and the builder's source, so any change
    to either builds afresh instead of loading stale cells."""
    h = hashlib.sha256(BUNDLED_MAP.read_bytes())
    for src in sorted(Path(topology.__file__).parent.glob("*.py")):
        h.update(src.name.encode())
        h.update(src.read_bytes())
    digest = h.hexdigest()[:12]
    return cache_dir() / f"helsinki-{digest}-v{__version__}{'' if with_pvs else '-nopvs'}.enttopo"


def bundled_topology(progress: Callable[[str], None] | None = None, with_pvs: bool = True) -> tuple[Topology, Path]:
    """Load the cached Helsinki artifact, building (and caching) it when missing or unreadable."""
    say = progress or (lambda _m: None)
    path = bundled_artifact_path(with_pvs)
    if path.exists():
        try:
            return load(path), path
        except ArtifactError as exc:
            say(f"cached artifact unusable ({exc}); rebuilding")
    from topology.build import BuildConfig, build, read_map

    config = BuildConfig()
    if with_pvs:
        try:
            from topology.pvs import PvsConfig

            config.pvs = PvsConfig()
        except ImportError:
            config.pvs = None
    say(f"building the Helsinki topology once (cached in {path.parent})")
    topo = build(read_map(None), config, progress=say, source="helsinki.osm.pbf (bundled)")
    save(topo, path)
    return load(path), path
