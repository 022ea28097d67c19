"""Fixtures of the command tests: a small artifact that `serve` can load in a fraction of a second."""

from __future__ import annotations

import pytest

from tests.topology.mapfixtures import collection, grid
from topology.artifact import save
from topology.build import build
from topology.geojson_reader import geojson_to_raw


@pytest.fixture(scope="session")
def town_path(tmp_path_factory):
    """A 3 x 3 street grid built once per session (no PVS needed by the commands under test)."""
    path = tmp_path_factory.mktemp("commands") / "town.enttopo"
    save(build(geojson_to_raw(collection(*grid(3, 3)))), path)
    return path
