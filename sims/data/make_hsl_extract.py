"""Make the bundled schedule: a trimmed extract of the HSL GTFS feed with only the trips over the bundled map.

    python -m sims.data.make_hsl_extract ../shared/data/hsl-gtfs-2022-02.zip sims/data/hsl-helsinki-centre.zip

Kept: the trams' and buses' trips whose shapes run over the bundled Helsinki map (as `read_schedule` matches
them), with their routes, calendar, frequencies, shapes (the points within 1 km of the map; the rest of a
shape is not needed to place it on the map), stop times (the stops within 1 km of the map, so a trip still
enters and leaves at the map's edge at the right time) and those stops; agency.txt and feed_info.txt as they
are. Source: Helsinki Region Transport (HSL), CC BY 4.0 (see HSL-GTFS-LICENSE.md next to the output).
"""

from __future__ import annotations

import csv
import io
import sys
import zipfile
from pathlib import Path

import numpy as np

#: keep shape points and stops this far (m) around the map's bounds
MARGIN = 1000.0


def _read(zf: zipfile.ZipFile, name: str) -> tuple[list[str], list[dict]]:
    from topology.gtfs import read_table  # the one reader of GTFS files

    return read_table(zf, name)


def _write(out: zipfile.ZipFile, name: str, fields: list[str], rows: list[dict]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    out.writestr(name, buf.getvalue())


def make(src: Path, dst: Path) -> dict[str, int]:
    """Write the trimmed feed from `src` to `dst` (what is kept: the module docstring); its row counts and
    size in bytes. Trips are chosen by `read_schedule` itself, so the extract holds exactly the trips the
    simulation matches onto the bundled map."""
    from entitynet.topology_cache import bundled_topology
    from sims.engine.schedule import read_schedule
    from topology.projection import LocalProjection

    topo, _ = bundled_topology(None, with_pvs=False)
    sched = read_schedule(src, topo, date=None)
    keep_trips = {d.trip_id.split("@")[0] for d in sched.departures}
    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    x0, y0, x1, y1 = topo.meta["bounds"]

    def near(lon: list[float], lat: list[float]) -> np.ndarray:
        xy = proj.to_local(np.array(lon), np.array(lat))
        return ((xy[:, 0] > x0 - MARGIN) & (xy[:, 0] < x1 + MARGIN) & (xy[:, 1] > y0 - MARGIN)
                & (xy[:, 1] < y1 + MARGIN))

    counts = {}
    with zipfile.ZipFile(src) as zf, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as out:
        names = zf.namelist()
        tf, trips = _read(zf, "trips.txt")
        trips = [t for t in trips if t["trip_id"] in keep_trips]
        routes_used = {t["route_id"] for t in trips}
        services = {t["service_id"] for t in trips}
        shapes_used = {t["shape_id"] for t in trips if t.get("shape_id")}
        sf, stops = _read(zf, "stops.txt")
        ok = near([float(s["stop_lon"]) for s in stops], [float(s["stop_lat"]) for s in stops])
        near_stops = {s["stop_id"] for s, k in zip(stops, ok, strict=True) if k}
        stf, st = _read(zf, "stop_times.txt")
        st = [r for r in st if r["trip_id"] in keep_trips and r["stop_id"] in near_stops]
        used_stops = {r["stop_id"] for r in st}
        _write(out, "trips.txt", tf, trips)
        _write(out, "stop_times.txt", stf, st)
        _write(out, "stops.txt", sf, [s for s in stops if s["stop_id"] in used_stops])
        rf, routes = _read(zf, "routes.txt")
        _write(out, "routes.txt", rf, [r for r in routes if r["route_id"] in routes_used])
        if "shapes.txt" in names:
            shf, shapes = _read(zf, "shapes.txt")
            shapes = [s for s in shapes if s["shape_id"] in shapes_used]
            ok = near([float(s["shape_pt_lon"]) for s in shapes], [float(s["shape_pt_lat"]) for s in shapes])
            _write(out, "shapes.txt", shf, [s for s, k in zip(shapes, ok, strict=True) if k])
        if "calendar.txt" in names:
            cf, cal = _read(zf, "calendar.txt")
            _write(out, "calendar.txt", cf, [c for c in cal if c["service_id"] in services])
        if "calendar_dates.txt" in names:
            cf, cal = _read(zf, "calendar_dates.txt")
            _write(out, "calendar_dates.txt", cf, [c for c in cal if c["service_id"] in services])
        if "frequencies.txt" in names:
            ff, fr = _read(zf, "frequencies.txt")
            _write(out, "frequencies.txt", ff, [f for f in fr if f["trip_id"] in keep_trips])
        for name in ("agency.txt", "feed_info.txt"):
            if name in names:
                out.writestr(name, zf.read(name))
        counts = {"trips": len(trips), "stop_times": len(st), "stops": len(used_stops), "routes": len(routes_used)}
    counts["bytes"] = dst.stat().st_size
    return counts


if __name__ == "__main__":  # pragma: no cover - a maintenance script
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    print(make(Path(sys.argv[1]), Path(sys.argv[2])))
