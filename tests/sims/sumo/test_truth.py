"""The SUMO truth placed on our network: true cells of a body, and positions off our network counted (no SUMO
needed: entities are set by hand)."""

from __future__ import annotations

import math

import numpy as np

from sims.sumo.truth import CLIENT_OFF_NETWORK_M, OFF_STREET_M, SumoEntity, SumoWorld
from topology.networks import VEHICLE


def _entity(world: SumoWorld, eid: int, name: str, x: float, y: float, length: float = 0.0,
            heading: float = 0.0) -> SumoEntity:
    e = SumoEntity(world, eid, f"s{eid}", name, length)
    e.x, e.y, e.heading = x, y, heading
    world.add(e)
    return e


def test_on_street_bodies_get_their_cells_and_far_ones_are_counted_off_network(helsinki):
    w = SumoWorld(helsinki, 0.0)
    edge = int(np.flatnonzero(helsinki.edge_networks & VEHICLE)[0])
    mid = helsinki.edge_length[edge] / 2
    x, y = helsinki.point_at(edge, mid)
    car = _entity(w, 1, "car", float(x), float(y), 4.5)
    lo = helsinki.node_xy.min(axis=0)
    far = _entity(w, 2, "pedestrian", float(lo[0]) - 500.0, float(lo[1]) - 500.0)
    assert helsinki.cell_at(edge, mid) in car.cells()
    assert len(far.cells()) == 1  # still placed, as a phone's fix is: on the nearest street
    off = w.off_network()
    assert off["entity_samples"] == 2 and off["off_street"] == 1 and off["beyond_client_off_network"] == 1
    assert off["off_street_m"] == OFF_STREET_M and off["client_off_network_m"] == CLIENT_OFF_NETWORK_M
    w.moved(1.0)  # a new step: placed again when asked, counted again
    car.cells()
    assert w.off_network()["entity_samples"] == 4


def test_a_tram_takes_its_parts_from_its_length_and_lies_behind_its_front(helsinki):
    w = SumoWorld(helsinki, 0.0)
    tram = _entity(w, 1, "tram", 10.0, 20.0, 33.0, heading=math.pi / 2)  # heading north
    assert tram.parts == (16.5, 16.5) and tram.etype.name == "tram" and tram.etype.length == 33.0
    pts = tram.part_points()
    assert np.allclose(pts, [(10.0, 20.0), (10.0, 3.5), (10.0, -13.0)])
    walker = _entity(w, 2, "pedestrian", 0.0, 0.0, 0.0)
    assert walker.parts == () and walker.length == 0.0 and walker.part_points() == [(0.0, 0.0)]


def test_removals_are_handed_over_once_and_counted(helsinki):
    w = SumoWorld(helsinki, 0.0)
    _entity(w, 1, "car", 0.0, 0.0, 4.5)
    _entity(w, 2, "bus", 0.0, 0.0, 12.0)
    w.remove(1, "arrived")
    w.remove(1, "arrived")  # gone already: nothing more
    assert w.take_removed() == [(1, "arrived")] and w.take_removed() == []
    assert w.counters["arrived"] == 1 and w.counters["spawned"] == 2 and w.by_type() == {"bus": 1}
