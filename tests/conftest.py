"""Shared fixtures: the bundled Helsinki artifact (built once per builder version, kept in the cache), the HSL
feed matched once per session, the pure and compiled paths."""

from __future__ import annotations

import contextlib
import os
import shutil

import pytest
from hypothesis import settings

from topology.artifact import ArtifactError, load, save
from topology.build import build, read_map

# no per-example deadline: a timing check flakes on a shared 2-core machine (speed is checked by benchmarks)
settings.register_profile("entitynet", deadline=None)
settings.load_profile("entitynet")


@pytest.fixture(scope="session")
def helsinki_path(tmp_path_factory):
    """Path of the bundled Helsinki map's artifact (without PVS), a copy of the session's own file.

    Its build takes ~14 s, so it is kept beside the product's cached artifacts (`entitynet.topology_cache`)
    under a name that hashes the map and the builder's source as theirs do: a changed map or builder builds
    afresh, an unchanged one is copied. It is `build(read_map(None))` exactly (its digest differs from
    `entitynet demo`'s artifact, which names its source)."""
    from entitynet.topology_cache import bundled_artifact_path

    product = bundled_artifact_path(with_pvs=False)
    cached = product.with_name(f"tests-{product.name}")
    path = tmp_path_factory.mktemp("helsinki") / "helsinki.enttopo"
    try:
        load(cached)  # (a truncated or stale-format file is rebuilt)
        shutil.copyfile(cached, path)
    except (OSError, ValueError, ArtifactError):
        save(build(read_map(None)), path)
        with contextlib.suppress(OSError):  # (a read-only cache only costs the next session the build)
            cached.parent.mkdir(parents=True, exist_ok=True)
            part = cached.with_name(f"{cached.name}.{os.getpid()}.part")
            shutil.copyfile(path, part)
            os.replace(part, cached)  # atomic: a concurrent session reads the old file or the new one
    return path


@pytest.fixture(scope="session")
def helsinki(helsinki_path):
    return load(helsinki_path)


@pytest.fixture(scope="session")
def _gtfs_memo() -> dict:
    """Session store of `gtfs_once`: (what, arguments) -> result, holding the arguments (the map) alive so that
    an id in a key is never reused."""
    return {}


@pytest.fixture
def gtfs_once(monkeypatch, _gtfs_memo):
    """`topology.gtfs.read_feed` and `match_shapes` computed once per session for the same arguments (the HSL
    feed: ~4 s to read and ~5 s to match onto the Helsinki map, which several benchmark tests repeat for their
    entities). Both are pure functions of their arguments and their results are only read, so a test sees what a
    fresh call gives; `tests/topology/test_gtfs.py` tests the functions themselves, without this."""
    import topology.gtfs as gtfs

    read, match = gtfs.read_feed, gtfs.match_shapes

    def read_feed(path, modes=("tram", "bus")):
        st = os.stat(path)
        key = ("read", os.fspath(path), tuple(modes), st.st_size, st.st_mtime_ns)
        if key not in _gtfs_memo:
            _gtfs_memo[key] = read(path, modes)
        return _gtfs_memo[key]

    def match_shapes(feed, topo, **kw):
        key = ("match", id(feed), id(topo), tuple(sorted(kw.items())))
        if key not in _gtfs_memo:
            _gtfs_memo[key] = (match(feed, topo, **kw), feed, topo)
        return list(_gtfs_memo[key][0])

    monkeypatch.setattr(gtfs, "read_feed", read_feed)
    monkeypatch.setattr(gtfs, "match_shapes", match_shapes)


def _both_paths(request, module, what: str):
    """Select the pure or the compiled path of `module` for one test (skipped, saying so, where the compiled
    one was not built), and put back what was in use after it."""
    was = module.compiled_in_use()
    compiled = request.param == "compiled"
    if compiled and module.COMPILED is None:
        pytest.skip(f"the compiled {what} was not built (no Cython or C compiler at install time)")
    assert module.use_compiled(compiled) == compiled
    yield request.param
    module.use_compiled(was)


@pytest.fixture(params=["pure", "compiled"])
def fanout_path(request):
    """Run a test once with the switchboard's pure-Python fan-out loops and once with the compiled ones
    (`entitynet/switchboard/_fanout.pyx`, built by pip)."""
    from entitynet.switchboard import outbox

    yield from _both_paths(request, outbox, "fan-out")


@pytest.fixture(params=["pure", "compiled"])
def flush_path(request):
    """Run a test once with the server's pure-Python flush loop and once with the compiled one
    (`entitynet/server/_flushloop.pyx`, built by pip)."""
    from entitynet.server import flushloop

    yield from _both_paths(request, flushloop, "flush loop")
