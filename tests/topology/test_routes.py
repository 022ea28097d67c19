"""Transit routes are stored as connected paths: unordered, reversed and gappy relations (item 12)."""

from __future__ import annotations

import pytest

from entitynet.client.network import netview
from entitynet.client.path import Path
from tests.topology.routemaps import route_map_xml, true_route
from topology.build import build, read_map


def build_route_map(tmp_path, variant, **kw):
    path = tmp_path / f"{variant}.osm"
    path.write_text(route_map_xml(variant, **kw))
    return build(read_map(path))


@pytest.mark.parametrize("variant", ["ok", "unordered", "reversed", "gap", "mixed"])
def test_relation_is_stored_as_the_connected_path_the_bus_drives(tmp_path, variant):
    topo = build_route_map(tmp_path, variant)
    (route,) = topo.routes
    assert [tuple(de) for de in route["edges"]] == true_route(topo)
    Path(netview(topo), route["edges"])  # raises if two consecutive edges do not meet
    assert [s["name"] for s in route["stops"]] == ["First", "Last"]


def test_gap_closed_by_the_network_is_counted(tmp_path):
    topo = build_route_map(tmp_path, "gap")
    assert topo.meta["report"]["repaired:route_gap_joined"] == 1


def test_a_route_that_cannot_be_joined_is_split_into_connected_pieces(tmp_path):
    topo = build_route_map(tmp_path, "ok", island=True)
    pieces = [r for r in topo.routes if r["id"] == 5000]
    assert len(pieces) == 2 and [r["part"] for r in pieces] == [0, 1]
    assert [tuple(de) for de in pieces[0]["edges"]] == true_route(topo)
    net = netview(topo)
    for r in pieces:
        Path(net, r["edges"])
    assert topo.meta["report"]["repaired:route_split_into_pieces"] == 1
    assert topo.meta["report"]["read:routes_matched"] == 1
