"""Fixtures of the proxy tests: a small synthetic GTFS feed on a synthetic tram line (fast), and the real HSL feed
on the bundled Helsinki map (skipped when ../shared is absent)."""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

# ../shared beside the clone (as CI has it); ENTITYNET_SHARED overrides (a worktree elsewhere)
SHARED = Path(os.environ.get("ENTITYNET_SHARED") or Path(__file__).resolve().parents[2] / ".." / "shared")
FEED = SHARED / "data" / "hsl-gtfs-2022-02.zip"
XSD_DIR = SHARED / "siri" / "xsd"
CEN_WSDL = XSD_DIR / "siri_wsProducer.wsdl"
CEN_SERVICES_XSD = XSD_DIR / "wsdl_model" / "siri_wsProducer-Services.xsd"

needs_feed = pytest.mark.skipif(not FEED.exists(), reason="../shared/data/hsl-gtfs-2022-02.zip absent")
needs_xsd = pytest.mark.skipif(not CEN_SERVICES_XSD.exists(), reason="../shared/siri/xsd absent")

CRS = "EPSG:32635"
ORIGIN = (385945.0, 6672301.0)  # the bundled map's origin
LINE_Y = 0.0
STOP_X = [0.0, 400.0, 800.0, 1200.0, 1600.0, 2000.0]  # local metres along the line
LINE_X = (-100.0, 2100.0)


def _lonlat(xs, ys):
    from topology.projection import LocalProjection

    return LocalProjection(CRS, ORIGIN).to_wgs84(np.column_stack([xs, ys]).astype(np.float64))


def write_feed(path: Path, *, headway: int = 300, start: str = "07:50:00", end: str = "09:00:00") -> Path:
    """One tram line (route 1001, short name 1) along the x axis, six stops 400 m apart, 90 s between stops,
    run every `headway` s (frequencies, exact_times) in both directions."""
    shape_x = np.linspace(LINE_X[0], LINE_X[1], 23)
    shape_ll = _lonlat(shape_x, np.full_like(shape_x, LINE_Y))
    stop_ll = _lonlat(np.array(STOP_X), np.full(len(STOP_X), LINE_Y + 3.0))
    files = {
        "agency.txt": "agency_id,agency_name,agency_url,agency_timezone\nA,Test,http://x,Europe/Helsinki\n",
        "calendar.txt": "monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,end_date,service_id\n"
                        "1,1,1,1,1,1,1,20220222,20220222,S\n",
        "routes.txt": "route_id,route_short_name,route_type\n1001,1,0\n",
        "stops.txt": "stop_id,stop_name,stop_lat,stop_lon\n"
                     + "".join(f"S{i},Stop {i},{lat:.7f},{lon:.7f}\n" for i, (lon, lat) in enumerate(stop_ll)),
        "trips.txt": "route_id,service_id,trip_id,direction_id,shape_id\n1001,S,T east,0,SH0\n1001,S,T west,1,SH1\n",
        "shapes.txt": "shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\n"
                      + "".join(f"SH0,{lat:.7f},{lon:.7f},{i}\n" for i, (lon, lat) in enumerate(shape_ll))
                      + "".join(f"SH1,{lat:.7f},{lon:.7f},{i}\n" for i, (lon, lat) in enumerate(shape_ll[::-1])),
        "frequencies.txt": "trip_id,start_time,end_time,headway_secs,exact_times\n"
                           f"T east,{start},{end},{headway},1\nT west,{start},{end},{headway},1\n",
    }
    rows = ["trip_id,arrival_time,departure_time,stop_id,stop_sequence"]
    for trip, order in (("T east", range(len(STOP_X))), ("T west", reversed(range(len(STOP_X))))):
        for seq, i in enumerate(order):
            t = 8 * 3600 + seq * 90
            hms = f"{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d}"
            rows.append(f"{trip},{hms},{hms},S{i},{seq + 1}")
    files["stop_times.txt"] = "\n".join(rows) + "\n"
    return write_zip(path, files)


def write_zip(path: Path, files: dict[str, str]) -> Path:
    """A GTFS zip of the given files (name -> CSV text) at `path`."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, text in files.items():
            zf.writestr(name, text)
    path.write_bytes(buf.getvalue())
    return path


def make_line_topology():
    """A tram line (two tracks' worth: one edge each way is not needed, edges are two-way) along the x axis."""
    from tests.entitynet.client_fixtures import make_topology
    from topology.raw import TRAM, VEHICLE

    xs = np.arange(LINE_X[0], LINE_X[1] + 1.0, 110.0)
    nodes = {f"N{i}": (float(x), LINE_Y) for i, x in enumerate(xs)}
    nodes["B"] = (1000.0, 300.0)  # a side street, so the line has a junction
    names = [f"N{i}" for i in range(len(xs))]
    edges = [(a, b, TRAM | VEHICLE) for a, b in zip(names, names[1:], strict=False)]
    edges.append((names[10], "B", VEHICLE))
    topo = make_topology(nodes, edges)
    topo.meta.update(crs=CRS, origin=list(ORIGIN), bounds=[LINE_X[0] - 150.0, -400.0, LINE_X[1] + 150.0, 400.0])
    return topo


@pytest.fixture(scope="session")
def line_feed(tmp_path_factory) -> Path:
    return write_feed(tmp_path_factory.mktemp("feed") / "line.zip")


@pytest.fixture(scope="session")
def line_topo():
    return make_line_topology()


@pytest.fixture(scope="session")
def line_book(line_topo, line_feed):
    from proxies.routes import build_routes

    return build_routes(line_topo, line_feed, modes=("tram",))


@pytest.fixture(scope="session")
def hsl_tram_book(helsinki):
    """The HSL trams over the bundled Helsinki map (a few seconds: shape matching and stop_times)."""
    if not FEED.exists():
        pytest.skip("../shared/data/hsl-gtfs-2022-02.zip absent")
    from proxies.routes import build_routes

    return build_routes(helsinki, FEED, modes=("tram",))
