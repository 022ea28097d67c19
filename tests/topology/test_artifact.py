"""The artifact file: round trip, digest, clear errors for anything that is not one."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from tests.topology.mapfixtures import collection, grid
from topology.artifact import ArtifactError, load, save
from topology.build import build
from topology.geojson_reader import geojson_to_raw


@pytest.fixture
def small_topo():
    return build(geojson_to_raw(collection(*grid(3, 2))))


def test_round_trip_keeps_every_array_and_the_digest(small_topo, tmp_path):
    path = tmp_path / "t.enttopo"
    digest = save(small_topo, path)
    back = load(path)
    assert back.digest == digest and len(digest) == 64
    assert np.array_equal(back.edge_geom_xy, small_topo.edge_geom_xy)
    assert np.array_equal(back.edge_bp_cell, small_topo.edge_bp_cell)
    assert back.meta["counts"] == small_topo.meta["counts"]
    assert [p.wkt for p in back.cell_footprints.to_shapely()] == [
        p.wkt for p in small_topo.cell_footprints.to_shapely()
    ]


def test_digest_depends_on_content(small_topo, tmp_path):
    d1 = save(small_topo, tmp_path / "a")
    small_topo.edge_length[0] += 1.0
    d2 = save(small_topo, tmp_path / "b")
    assert d1 != d2


def test_extra_arrays_round_trip(small_topo, tmp_path):
    small_topo.extra["pvs_test"] = np.arange(5, dtype=np.uint16)
    save(small_topo, tmp_path / "x")
    assert np.array_equal(load(tmp_path / "x").extra["pvs_test"], np.arange(5))


def test_edited_file_fails_the_digest(small_topo, tmp_path):
    path = tmp_path / "t.enttopo"
    save(small_topo, path)
    with np.load(path) as npz:
        data = {k: npz[k] for k in npz.files}
    data["edge_length"] = data["edge_length"] + 1
    np.savez(path.with_suffix(".npz"), **data)
    with pytest.raises(ArtifactError, match="digest mismatch"):
        load(path.with_suffix(".npz"))


def test_not_an_artifact(tmp_path):
    junk = tmp_path / "junk"
    junk.write_bytes(b"garbage" * 10)
    with pytest.raises(ArtifactError, match="not a topology artifact"):
        load(junk)
    with pytest.raises(ArtifactError, match="no such file"):
        load(tmp_path / "missing")
    other = tmp_path / "other.npz"
    np.savez(other, meta=np.frombuffer(json.dumps({"format": "x"}).encode(), np.uint8))
    with pytest.raises(ArtifactError, match="format"):
        load(other)


def test_other_version_is_refused_with_advice(small_topo, tmp_path):
    path = tmp_path / "t.enttopo"
    save(small_topo, path)
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
    with np.load(path) as npz:
        data = {k: npz[k] for k in npz.files}
    meta = json.loads(data["meta"].tobytes())
    meta["format_version"] = 99
    data["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(tmp_path / "v99.npz", **data)
    assert "meta.npy" in names
    with pytest.raises(ArtifactError, match="rebuild"):
        load(tmp_path / "v99.npz")


def test_run_time_queries(small_topo):
    e = 0
    length = small_topo.edge_length[e]
    start = small_topo.point_at(e, 0.0)
    end = small_topo.point_at(e, length)
    assert np.allclose(start, small_topo.edge_polyline(e)[0])
    assert np.allclose(end, small_topo.edge_polyline(e)[-1])
    assert np.allclose(small_topo.point_at(e, -5), start) and np.allclose(small_topo.point_at(e, length + 5), end)
    assert small_topo.cell_at(e, -1.0) == small_topo.cell_at(e, 0.0)


def test_two_builds_of_one_map_share_a_digest(tmp_path):
    from topology.build import BuildConfig
    from topology.pvs import PvsConfig

    doc = collection(*grid(3, 2))
    cfg = BuildConfig(pvs=PvsConfig(workers=1))
    a = build(geojson_to_raw(doc), cfg)
    b = build(geojson_to_raw(doc), cfg)
    assert save(a, tmp_path / "a") == save(b, tmp_path / "b")
    assert "pvs" in a.meta and "pvs_s" in a.meta["timings"]
