"""`entitynet topology build | info | export` as a user runs them; bad input gives exit 2 and no traceback."""

from __future__ import annotations

import json

import pytest
import shapely
from shapely.geometry import shape

from entitynet.cli import main
from tests.topology.mapfixtures import box, collection, grid, polygon


def write_map(tmp_path):
    path = tmp_path / "town.geojson"
    doc = collection(*grid(3, 3), polygon(box(10, 10, 60, 60), building="yes", height="15"),
                     polygon(box(110, 110, 190, 190), area="park", network="pedestrian"))  # fmt: skip
    path.write_text(json.dumps(doc))
    return path


def test_build_info_export(tmp_path, capsys):
    src = write_map(tmp_path)
    out = tmp_path / "town.enttopo"
    assert main(["topology", "build", "--geojson", str(src), "--out", str(out), "--no-pvs"]) == 0
    assert out.exists()
    assert main(["topology", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "digest:" in text and "junction" in text and "build report" in text
    gj = tmp_path / "town.json"
    assert main(["topology", "export", str(out), "--geojson", str(gj)]) == 0
    doc = json.loads(gj.read_text())
    assert doc["type"] == "FeatureCollection"
    layers = {f["properties"]["layer"] for f in doc["features"]}
    assert layers == {"cell", "edge", "area", "building"}
    for f in doc["features"]:
        g = shape(f["geometry"])
        assert g.is_valid and not g.is_empty
        if g.geom_type == "Polygon":
            assert g.exterior.is_ccw and not any(r.is_ccw for r in g.interiors)  # RFC 7946 winding
        lon, lat = shapely.get_coordinates(g).T
        assert (24 < lon).all() and (lon < 26).all() and (60 < lat).all() and (lat < 61).all()


def test_bad_inputs_exit_2_with_a_message(tmp_path, capsys):
    junk = tmp_path / "junk.osm.pbf"
    junk.write_bytes(b"\x00" * 64)
    assert main(["topology", "build", "--osm", str(junk), "--out", str(tmp_path / "o")]) == 2
    assert "entitynet: error:" in capsys.readouterr().err
    assert main(["topology", "build", "--osm", str(tmp_path / "missing.pbf")]) == 2
    assert main(["topology", "info", str(junk)]) == 2
    assert "not a topology artifact" in capsys.readouterr().err
    src = write_map(tmp_path)
    with pytest.raises(SystemExit) as info:  # a usage error: refused while parsing (entitynet/commands/options.py)
        main(["topology", "build", "--geojson", str(src), "--street-width=-3"])
    assert info.value.code == 2 and "argument --street-width" in capsys.readouterr().err
    out = tmp_path / "t.enttopo"
    assert main(["topology", "build", "--geojson", str(src), "--out", str(out), "-q"]) == 0
    assert main(["topology", "export", str(out), "--geojson", str(tmp_path / "x.json"), "--layers", "nope"]) == 2


@pytest.mark.parametrize("argv", [
    ["--view-cell-size", "0.001"], ["--view-cell-size", "0.5"], ["--max-cell-length", "0.001"],
    ["--max-cell-length", "0.5"],
])
def test_sizes_too_small_to_build_are_refused_while_parsing(tmp_path, capsys, argv):
    """0.001 m view cells ended in a numpy MemoryError traceback, 0.5 m ran for hours."""
    with pytest.raises(SystemExit) as info:
        main(["topology", "build", "--geojson", str(write_map(tmp_path)), "--out", str(tmp_path / "o"), "-q", *argv])
    err = capsys.readouterr().err
    assert info.value.code == 2 and f"argument {argv[0]}" in err and "Traceback" not in err


def test_too_many_view_cells_is_one_line_before_allocating(tmp_path, capsys):
    src = write_map(tmp_path)
    argv = ["topology", "build", "--geojson", str(src), "--out", str(tmp_path / "o"), "-q",
            "--view-cell-size", "2", "--view-max-height", "90000"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "entitynet: error:" in err and "--view-cell-size" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
