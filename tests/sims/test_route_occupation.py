"""Buses driven along an OSM route relation stay inside their published occupation (issue 9, item 16).

The cause of the misses on other towns' maps: relations whose member ways are unsorted, drawn backwards or
missing one were stored as routes that turn back at their first edge, take a cross street at their last, or
jump between pieces. A bus given such a route publishes the cells of a way it does not drive, with long
validity, and is outside its occupation until the client notices. Measured here through the client core
(sims.bench.dr_bench.run_entity: 5 m GPS noise, 0.5 s samples), the bus driving the true path with the stored
route as its a-priori route."""

from __future__ import annotations

import random

import pytest

from entitynet.client.network import netview
from entitynet.client.path import Path
from sims.bench.dr_bench import _new_acc, run_entity
from sims.bench.dr_data import _sample_path
from sims.mobility import Halts, speed_profile, vehicle_halts
from tests.topology.routemaps import route_map_xml, true_route
from topology.build import build, read_map


@pytest.mark.parametrize("variant", ["ok", "mixed"])
def test_bus_on_a_spoiled_relation_stays_in_its_published_occupation(tmp_path, variant):
    osm = tmp_path / "m.osm"
    osm.write_text(route_map_xml(variant))
    topo = build(read_map(osm))
    (route,) = topo.routes
    stored = [tuple(de) for de in route["edges"]]
    net = netview(topo)
    truth = Path(net, true_route(topo))
    acc = _new_acc()
    for seed in range(6):  # bounded: 6 runs of about 80 s of simulated time each
        rng = random.Random(seed)
        halts = vehicle_halts([truth.length / 2], [], rng, Halts(dwell=(10.0, 20.0), p_red=0.0, red=(0.0, 0.0)))
        prof = speed_profile(truth.length, halts, rng, cruise=10.5, accel=1.2, decel=1.5)
        ent = _sample_path(truth, prof, 12.0, f"bus {variant} {seed}", "bus", stored)
        run_entity(topo, ent, "network", 5.0, acc)
    assert acc["occ_n"] > 1000
    assert acc["occ_bad"] / acc["occ_n"] < 0.001
