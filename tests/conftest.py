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
