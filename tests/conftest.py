"""Shared fixtures: the bundled Helsinki artifact, built once per test session."""

from __future__ import annotations

import pytest
from hypothesis import settings

from topology.artifact import load, save
from topology.build import build, read_map

# no per-example deadline: a timing check flakes on a shared 2-core machine (speed is checked by benchmarks)
settings.register_profile("entitynet", deadline=None)
settings.load_profile("entitynet")


@pytest.fixture(scope="session")
def helsinki_path(tmp_path_factory):
    """Path of the bundled Helsinki map's artifact (built once per session, without PVS)."""
    path = tmp_path_factory.mktemp("helsinki") / "helsinki.enttopo"
    save(build(read_map(None)), path)
    return path


@pytest.fixture(scope="session")
def helsinki(helsinki_path):
    return load(helsinki_path)


@pytest.fixture(params=["pure", "compiled"])
def fanout_path(request):
    """Run a test once with the switchboard's pure-Python fan-out loops and once with the compiled ones
    (`entitynet/switchboard/_fanout.pyx`, built by pip; skipped, saying so, where they were not built)."""
    from entitynet.switchboard import outbox

    was = outbox.compiled_in_use()
    if request.param == "compiled" and outbox.COMPILED is None:
        pytest.skip("the compiled fan-out was not built (no Cython or C compiler at install time)")
    assert outbox.use_compiled(request.param == "compiled") == (request.param == "compiled")
    yield request.param
    outbox.use_compiled(was)


@pytest.fixture(params=["pure", "compiled"])
def flush_path(request):
    """Run a test once with the server's pure-Python flush loop and once with the compiled one
    (`entitynet/server/_flushloop.pyx`, built by pip; skipped, saying so, where it was not built)."""
    from entitynet.server import flushloop

    was = flushloop.compiled_in_use()
    if request.param == "compiled" and flushloop.COMPILED is None:
        pytest.skip("the compiled flush loop was not built (no Cython or C compiler at install time)")
    assert flushloop.use_compiled(request.param == "compiled") == (request.param == "compiled")
    yield request.param
    flushloop.use_compiled(was)
