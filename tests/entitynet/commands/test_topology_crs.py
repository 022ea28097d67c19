"""`entitynet topology build --crs` as a user runs it: degrees and a CRS for another place are clear errors
(exit 2, no traceback); `--force` builds outside the area of use with a warning."""

from __future__ import annotations

import pytest

from entitynet.cli import main
from tests.topology.crsmaps import HELSINKI, MINNEAPOLIS, geojson_map, osm_map

BUILD = ["topology", "build", "--no-pvs", "-q"]


@pytest.mark.parametrize("maker,flag", [(geojson_map, "--geojson"), (osm_map, "--osm")], ids=["geojson", "osm"])
def test_degrees_are_refused_clearly(tmp_path, capsys, maker, flag):
    src = maker(tmp_path, HELSINKI)
    out = tmp_path / "t.enttopo"
    assert main([*BUILD, flag, str(src), "--out", str(out), "--crs", "EPSG:4326"]) == 2
    err = capsys.readouterr().err
    assert "entitynet: error:" in err and "degrees" in err and "metres" in err
    assert "no streets" not in err and "Traceback" not in err and not out.exists()
    assert main([*BUILD, flag, str(src), "--out", str(out), "--crs", "EPSG:2227"]) == 2  # US survey feet
    assert "US survey foot" in capsys.readouterr().err


@pytest.mark.parametrize("maker,flag", [(geojson_map, "--geojson"), (osm_map, "--osm")], ids=["geojson", "osm"])
def test_crs_outside_its_area_of_use_needs_force(tmp_path, capsys, maker, flag):
    src = maker(tmp_path, MINNEAPOLIS)
    out = tmp_path / "us.enttopo"
    assert main([*BUILD, flag, str(src), "--out", str(out), "--crs", "EPSG:3067"]) == 2
    err = capsys.readouterr().err
    assert "entitynet: error:" in err and "area of use of EPSG:3067" in err and "--force" in err
    assert not out.exists()
    assert main([*BUILD, flag, str(src), "--out", str(out), "--crs", "EPSG:3067", "--force"]) == 0
    err = capsys.readouterr().err
    assert "entitynet: warning:" in err and "area of use" in err and out.exists()
    assert main(["topology", "info", str(out)]) == 0
    assert "crs not for this place: 1" in capsys.readouterr().out


def test_helsinki_in_its_own_crs_and_the_default_utm_build_quietly(tmp_path, capsys):
    fi, us = geojson_map(tmp_path, HELSINKI, "fi"), geojson_map(tmp_path, MINNEAPOLIS, "us")
    assert main([*BUILD, "--geojson", str(fi), "--out", str(tmp_path / "fi.enttopo"), "--crs", "EPSG:3067"]) == 0
    assert main([*BUILD, "--geojson", str(us), "--out", str(tmp_path / "us.enttopo")]) == 0
    assert "warning" not in capsys.readouterr().err
