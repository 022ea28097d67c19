"""The local projection builds its pyproj transformations once (issue 21, item 10): EPSG:3067's transformation
takes tens of milliseconds to build, and a reader that projected each of a town's 2,500 buildings through a
fresh one took 65 s instead of under one."""

from __future__ import annotations

import numpy as np
import pytest

import topology.projection as projection
from topology.projection import LocalProjection


@pytest.fixture
def built(monkeypatch):
    """Counts the transformations `topology.projection` builds, by (source, target) CRS."""
    counts: dict[tuple[str, str], int] = {}
    real = projection.Transformer

    class Counting:
        @staticmethod
        def from_crs(src, dst, **kw):
            counts[(str(src), str(dst))] = counts.get((str(src), str(dst)), 0) + 1
            return real.from_crs(src, dst, **kw)

    monkeypatch.setattr(projection, "Transformer", Counting)
    getattr(projection, "clear_transformer_cache", lambda: None)()
    yield counts
    getattr(projection, "clear_transformer_cache", lambda: None)()


def test_many_small_projections_build_each_transformation_once(built):
    proj = LocalProjection("EPSG:3067", (385000.0, 6672000.0))
    lon, lat = np.array([24.94, 24.95]), np.array([60.17, 60.168])
    first = proj.to_local(lon, lat)
    for _ in range(200):  # one call per building, as the OSM reader projects polygons
        assert np.array_equal(proj.to_local(lon, lat), first)
        back = proj.to_wgs84(first)
    assert np.allclose(back, np.column_stack([lon, lat]), atol=1e-9)
    assert built == {("EPSG:4326", "EPSG:3067"): 1, ("EPSG:3067", "EPSG:4326"): 1}
    # another projection in the same CRS (the proxies make one per start) reuses them
    LocalProjection("EPSG:3067", (0.0, 0.0)).to_local(lon, lat)
    assert built[("EPSG:4326", "EPSG:3067")] == 1


def test_each_crs_gets_its_own_transformation(built):
    a = LocalProjection("EPSG:3067", (0.0, 0.0)).to_local(np.array([24.94]), np.array([60.17]))
    b = LocalProjection("EPSG:32634", (0.0, 0.0)).to_local(np.array([24.94]), np.array([60.17]))
    assert not np.allclose(a, b)  # not the cached transformation of the other CRS
    assert built == {("EPSG:4326", "EPSG:3067"): 1, ("EPSG:4326", "EPSG:32634"): 1}


def test_reading_a_town_builds_one_transformation(built, tmp_path):
    from tests.topology.crsmaps import HELSINKI, osm_map
    from topology.build import read_map

    raw = read_map(osm_map(tmp_path, HELSINKI, buildings=10), "EPSG:3067")
    assert len(raw.buildings) == 10
    assert built.get(("EPSG:4326", "EPSG:3067"), 0) == 1
