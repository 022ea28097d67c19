"""Golden vectors for the browser viewer's dead reckoning, written by the real Python client code.

`python -m tests.entitynet.viewer.golden` rewrites tests/entitynet/viewer/js/golden.json: a small network (as
the viewer's geometry.json ships it), the extrapolation limits, payloads encoded by entitynet/client/payload.py,
and the positions `decode(payload).xy_at(t)` (and a tram's `parts_xy_at(t)`) gives at a range of times, plus
payloads the decoder must refuse. The node test (js/extrapolation.test.js) decodes the same bytes with the
page's modules and must land within 1 mm; test_golden.py fails when this file is stale.
"""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import msgpack

from entitynet.client.motion import AreaModel, WorldModel
from entitynet.client.network import NetView
from entitynet.client.path import Path as NetPath
from entitynet.client.payload import PayloadError, decode, encode, encode_network
from entitynet.viewer.geometry import extrapolation_limits, grid_json, net_json
from tests.entitynet.client_fixtures import make_topology

OUT = Path(__file__).parent / "js" / "golden.json"
T0 = 1_700_000_000.123  # a wall-clock t0 as players publish them (seconds)
DTS = [-1.0, 0.0, 0.25, 1.0, 3.7, 7.5, 12.0, 20.0, 33.3, 60.0, 89.9, 90.0, 90.5, 150.0]


def golden_topology():
    """A bent street A-B-C-D with a branch, a hairpin E, and an area at F: polylines with interior vertices."""
    nodes = {"A": (0.0, 0.0), "B": (120.0, 10.0), "C": (170.0, 90.0), "D": (160.0, 260.0), "E": (240.0, 40.0),
             "F": (-80.0, -60.0)}
    edges = [
        ("A", "B", 7, [(30.0, -4.0), (61.3, 2.5), (90.0, 12.25)]),
        ("B", "C", 7, [(140.0, 30.0)]),
        ("C", "D", 7, [(190.0, 140.0), (185.5, 200.0), (170.0, 240.0)]),
        ("B", "E", 7, [(180.0, 0.0), (239.0, 0.0)]),
        ("F", "A", 7),
    ]
    area = ("F", [(-110.0, -90.0), (-50.0, -90.0), (-50.0, -30.0), (-110.0, -30.0)], 7)
    return make_topology(nodes, edges, areas=[area], junction_radius=8.0, origin=(385000.0, 6672000.0))


def _net_cases(net: NetView) -> list[tuple[str, bytes]]:
    fwd = NetPath(net, [(0, 1), (1, 1), (2, 1)])
    back = NetPath(net, [(2, -1), (1, -1), (3, 1)])
    cases = []

    def add(name, path, **kw):
        args = {"t0": T0, "path": path, "s0": 3.21, "v": 1.4, "a": 0.0, "vmax": 3.0, "etype": 0, "parts": (),
                "stop_s": math.inf, "brake": 1.0} | kw
        payload, _ = encode_network(**args)
        cases.append((name, payload))

    add("pedestrian cruising", fwd)
    add("car accelerating to vmax", fwd, etype=1, v=4.0, a=2.5, vmax=13.9, parts=(4.5,), s0=10.0)
    add("car decelerating to a stop", fwd, etype=1, v=12.0, a=-1.7, vmax=13.9, parts=(4.5,), s0=40.0)
    add("car past the end of its path", back, etype=1, v=11.0, a=0.4, vmax=16.0, parts=(4.5,), s0=200.0)
    add("bus braking for a stop", fwd, etype=2, v=9.0, a=0.3, vmax=12.0, parts=(12.0,), s0=20.0, stop_s=190.0,
        brake=1.2)
    add("bus already inside its braking distance", fwd, etype=2, v=12.0, a=0.0, vmax=12.0, parts=(12.0,), s0=100.0,
        stop_s=140.0, brake=1.2)
    add("two-part tram with a stop", back, etype=3, v=7.0, a=0.6, vmax=14.0, parts=(13.8, 13.8), s0=35.0,
        stop_s=260.0, brake=1.0)
    add("tram standing", fwd, etype=3, v=0.0, a=0.0, vmax=14.0, parts=(13.8, 13.8), s0=60.0)
    add("speed over the type's cap", fwd, etype=0, v=20.0, a=1.0, vmax=30.0, s0=0.0)
    add("unknown type code", back, etype=9, v=30.0, a=3.0, vmax=60.0, parts=(5.0,), s0=1.0)
    return cases


def _other_cases() -> list[tuple[str, bytes]]:
    return [
        ("area walker", encode(AreaModel(T0, 0, -90.5, -70.25, 0.9, -0.6, 0))),
        ("area walker over the cap", encode(AreaModel(T0, 0, -90.5, -70.25, 9.0, 6.0, 0))),
        ("world FPW car", encode(WorldModel(T0, 10.0, 20.0, 8.0, -3.0, 0.0, 0.0, 1))),
        ("world FVW accelerating past the cap", encode(WorldModel(T0, 10.0, 20.0, 20.0, 5.0, 1.5, 2.0, 1))),
        ("world FVW braking", encode(WorldModel(T0, -3.0, 7.0, 5.0, 5.0, -0.8, -0.3, 2))),
        ("world start above the cap", encode(WorldModel(T0, 0.0, 0.0, 12.0, 0.0, 0.5, 0.5, 0))),
    ]


def _bad_payloads() -> list[tuple[str, bytes]]:
    pack = lambda body: msgpack.packb(body, use_bin_type=True)  # noqa: E731
    return [
        ("not msgpack", b"\xc1\xc1"),
        ("wrong version", pack([2, 1, 0, 0, 0, 0, 0, 0, [], [1], -1, 1000])),
        ("edges that do not meet", pack([1, 1, 0, 0, 0, 1000, 0, 2000, [], [1, 3], -1, 1000])),
        ("edge not in the map", pack([1, 1, 0, 0, 0, 1000, 0, 2000, [], [99], -1, 1000])),
        ("no edges", pack([1, 1, 0, 0, 0, 1000, 0, 2000, [], [], -1, 1000])),
        ("negative speed", pack([1, 1, 0, 0, 0, -5, 0, 2000, [], [1], -1, 1000])),
        ("float where an integer belongs", pack([1, 3, 0, 0, 1.5, 0, 0, 0, 0, 0])),
        ("unknown kind", pack([1, 7, 0, 0])),
    ]


def _pvs_lookups() -> dict:
    """A small view-cell grid with holes (view cells left out inside buildings, a whole column), its JSON as the
    page gets it, and the view cell `topology.pvs_index.PvsIndex.lookup_cell` answers at positions in and off it."""
    import numpy as np

    from topology.pvs_index import PvsIndex
    from topology.viewgrid import ViewGrid

    nz, ny, nx = 3, 4, 5
    index = np.arange(nz * ny * nx, dtype=np.int32).reshape(nz, ny, nx)
    index[0, 1, 1] = index[1, 1, 1] = -1  # inside a building two layers tall
    index[:, 2, 3] = -1  # a column wholly inside a building taller than the stack
    index[0, 0, 4] = -1
    grid = ViewGrid(-40.0, -30.0, 20.0, 55.0, index)
    py = PvsIndex(grid, None, 10, 500.0)
    points = [(x, y, z) for x in (-100.0, -40.0, -20.5, 0.0, 5.0, 19.99, 30.0, 41.0, 70.0, 500.0)
              for y in (-80.0, -30.0, -9.0, 10.0, 15.0, 31.0, 60.0) for z in (-5.0, 0.0, 1.7, 20.0, 39.9, 55.0, 300.0)]
    return {"grid": grid_json(grid.x0, grid.y0, grid.size, grid.max_height, grid.index, 500.0),
            "lookups": [[x, y, z, py.lookup_cell(x, y, z)] for x, y, z in points]}


def golden_vectors() -> dict:
    topo = golden_topology()
    net = NetView(topo)
    cases = []
    for name, payload in _net_cases(net) + _other_cases():
        model = decode(payload, net)
        times = [round(model.t0 + dt, 3) for dt in DTS]
        case = {"name": name, "payload": base64.b64encode(payload).decode(), "times": times,
                "xy": [list(model.xy_at(t)) for t in times]}
        if hasattr(model, "parts_xy_at"):
            case["parts"] = [[list(p) for p in model.parts_xy_at(t)] for t in times]
        cases.append(case)
    bad = []
    for name, payload in _bad_payloads():
        try:
            decode(payload, net)
        except PayloadError:
            bad.append({"name": name, "payload": base64.b64encode(payload).decode()})
        else:
            raise AssertionError(f"the Python decoder accepts {name!r}")
    return {"net": net_json(topo), "limits": extrapolation_limits(), "cases": cases, "bad": bad,
            "pvs": _pvs_lookups()}


def main() -> None:
    OUT.write_text(json.dumps(golden_vectors(), indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
