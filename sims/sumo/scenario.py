"""A SUMO scenario from the bundled map: the network, random trips and public transport, cached.

Why: a new user can run `entitynet sim --mobility sumo` without a scenario of their own. The network comes from
the same OpenStreetMap extract as the topology artifact, converted by SUMO's own netconvert (OSM import with
sidewalks, crossings and guessed signals) in the artifact's projection: netconvert projects with the artifact's
CRS and shifts by minus its local origin (`--offset.*` with normalisation off), so SUMO's x/y are our local
coordinates and a SUMO edge lies on our street (tests/sims/sumo/test_scenario.py measures it).

Demand: cars and pedestrians on SUMO's randomTrips.py (seeded), and the bus and tram lines that netconvert
reads from the map's route relations (`--ptline-output`, routes along OSM's ways, stops from OSM) turned into
flows by ptlines2flows.py, each line's period set from the bundled GTFS feed (through the project's one GTFS
reader, `sims.engine.schedule`): the number of its departures over the map in the scenario's window (at least
the hour from its start). A line the feed does not run in that window is left out; subway and train lines are
left out (underground, or not on our networks). What is not there: GTFS trips' own timetables and shapes
(SUMO's gtfs2pt.py maps them, at the cost of pandas and a routing pass per trip); the lines run at the feed's
frequency on OSM's routes.

The scenario is cached under the user cache folder (`entitynet.topology_cache.cache_dir()/sumo`), keyed by the
map, the artifact's projection, the SUMO version, this module's source and the parameters.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import warnings
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from pathlib import Path

from sims.sumo import SumoError, sumo_home

#: bus and tram types of ptlines2flows; other lines (subway, train, ferry) are left out
TRANSIT_TYPES = ("bus", "tram")
TOOL_TIMEOUT_S = 600.0


@dataclass(frozen=True)
class ScenarioConfig:
    """What a generated scenario holds. `cars_per_hour` and `pedestrians_per_hour`: trips inserted (SUMO's
    randomTrips period is 3600 / rate); `start`: the service-day second the scenario's time 0 stands for (the
    GTFS window for the lines' frequencies); `bbox`: local (xmin, ymin, xmax, ymax) to keep only the streets
    inside it (a small scenario for tests), None for the whole map."""

    cars_per_hour: float = 1800.0
    pedestrians_per_hour: float = 3600.0
    duration: float = 3600.0
    start: float = 8 * 3600.0
    seed: int = 1
    transit: bool = True
    bbox: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        problems = []
        for name in ("cars_per_hour", "pedestrians_per_hour"):
            v = getattr(self, name)
            if not (v >= 0 and v < 1e6):
                problems.append(f"{name.replace('_', ' ')} must be within 0..1e6, got {v!r}")
        if not (0 < self.duration <= 86400):
            problems.append(f"duration must be within (0, 86400] s, got {self.duration!r}")
        if not (0 <= self.start < 48 * 3600):
            problems.append(f"start must be a service-day second (0..48 h), got {self.start!r}")
        if self.bbox is not None:
            x0, y0, x1, y1 = self.bbox
            if not (x0 < x1 and y0 < y1):
                problems.append(f"bbox must be xmin,ymin,xmax,ymax with min < max, got {self.bbox!r}")
        if problems:
            raise SumoError("; ".join(problems))


def scenario_dir(topo, config: ScenarioConfig, map_path: Path | None = None) -> Path:
    """The cache folder of this scenario: its name hashes the map, the projection, SUMO's version, this
    module's source and the parameters, so a change to any of them generates afresh."""
    from entitynet.topology_cache import cache_dir
    from topology import BUNDLED_MAP

    h = hashlib.sha256((map_path or BUNDLED_MAP).read_bytes())
    h.update(json.dumps([topo.meta["crs"], list(topo.meta["origin"]), asdict(config)], sort_keys=True).encode())
    h.update(Path(__file__).read_bytes())
    h.update(sumo_version().encode())
    return cache_dir() / "sumo" / f"helsinki-{h.hexdigest()[:12]}"


def sumo_version() -> str:
    """The installed eclipse-sumo's version (part of the cache key)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-sumo")
    except PackageNotFoundError:
        return "unknown"


def bundled_scenario(topo, config: ScenarioConfig | None = None, say=lambda m: None, force: bool = False) -> Path:
    """The .sumocfg of the bundled map's scenario, generated into the cache on first use (`force`: again)."""
    config = config or ScenarioConfig()
    out = scenario_dir(topo, config)
    cfg = out / "scenario.sumocfg"
    if cfg.exists() and not force:
        return cfg
    if out.exists():
        shutil.rmtree(out)
    tmp = out.with_name(out.name + f".tmp{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        generate(topo, config, tmp, say)
        tmp.rename(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return cfg


def generate(topo, config: ScenarioConfig, out: Path, say=lambda m: None, map_path: Path | None = None) -> Path:
    """Write the scenario into `out` (network, demand, configuration); the .sumocfg's path."""
    from topology import BUNDLED_MAP

    home = sumo_home()
    osm = out / "map.osm"
    say("SUMO scenario: the OSM extract as XML for netconvert")
    pbf_to_xml(map_path or BUNDLED_MAP, osm)
    say("SUMO scenario: netconvert in the topology's projection")
    netconvert(home, topo, osm, out, config.bbox)
    osm.unlink()
    routes = []
    dur = config.duration
    if config.cars_per_hour > 0:
        say("SUMO scenario: random car trips")
        _tool(home, "randomTrips.py", "-n", "net.net.xml", "-o", "cars.trips.xml", "-r", "cars.rou.xml",
              "-b", "0", "-e", f"{dur:g}", "-p", f"{3600.0 / config.cars_per_hour:.4f}", "--seed",
              str(config.seed), "--validate", "--fringe-factor", "5", "--prefix", "car", "--vclass", "passenger",
              "--trip-attributes", 'departLane="best" departSpeed="max"', cwd=out)
        routes.append("cars.rou.xml")
    if config.pedestrians_per_hour > 0:
        say("SUMO scenario: random walks")
        _tool(home, "randomTrips.py", "-n", "net.net.xml", "-o", "peds.rou.xml", "-b", "0", "-e", f"{dur:g}",
              "-p", f"{3600.0 / config.pedestrians_per_hour:.4f}", "--seed", str(config.seed + 1), "--pedestrians",
              "--max-distance", "1500", "--prefix", "ped", cwd=out)
        routes.append("peds.rou.xml")
    additional = []
    if config.transit:
        say("SUMO scenario: bus and tram lines at the bundled GTFS feed's frequencies")
        if transit_flows(home, topo, config, out):
            routes.insert(0, "pt.rou.xml")
            additional.append("stops.add.xml")
    cfg = out / "scenario.sumocfg"
    write_config(cfg, "net.net.xml", routes, additional, dur)
    (out / "scenario.json").write_text(json.dumps({**asdict(config), "sumo": sumo_version()}, indent=1) + "\n")
    return cfg


def pbf_to_xml(pbf: Path, osm: Path) -> None:
    """netconvert reads OSM XML only: the extract rewritten by pyosmium (nodes, ways, relations, unchanged)."""
    import osmium

    if osm.exists():
        osm.unlink()
    w = osmium.SimpleWriter(str(osm))
    try:
        for o in osmium.FileProcessor(str(pbf)):
            if o.is_node():
                w.add_node(o)
            elif o.is_way():
                w.add_way(o)
            else:
                w.add_relation(o)
    finally:
        w.close()


def netconvert(home: str, topo, osm: Path, out: Path, bbox: tuple[float, float, float, float] | None) -> None:
    """SUMO's OSM import in the artifact's CRS, shifted by minus its origin (SUMO x/y = our local x/y)."""
    from pyproj import CRS

    with warnings.catch_warnings():  # "may lose projection information": a UTM zone's proj4 string is exact
        warnings.simplefilter("ignore")
        proj4 = CRS.from_user_input(topo.meta["crs"]).to_proj4()
    ox, oy = topo.meta["origin"]
    types = ",".join(str(Path(home) / "data" / "typemap" / t)
                     for t in ("osmNetconvert.typ.xml", "osmNetconvertPedestrians.typ.xml"))
    args = [str(Path(home) / "bin" / "netconvert"), "--osm-files", osm.name, "--type-files", types,
            "--proj", proj4, "--offset.disable-normalization", "--offset.x", f"{-ox:.3f}",
            "--offset.y", f"{-oy:.3f}", "--sidewalks.guess", "--crossings.guess", "--geometry.remove",
            "--junctions.join", "--tls.guess-signals", "--tls.discard-simple", "--tls.join",
            "--ptstop-output", "stops.add.xml", "--ptline-output", "ptlines.xml", "--output.street-names",
            "--no-warnings", "-o", "net.net.xml"]
    if bbox is not None:
        args += ["--keep-edges.in-boundary", ",".join(f"{v:.2f}" for v in bbox)]
    _run(args, out, "netconvert")
    # ptlines2flows's check run refuses a stop whose `lines` is empty (a stop no OSM route names)
    stops = out / "stops.add.xml"
    if stops.exists():
        stops.write_text(stops.read_text().replace(' lines=""', ""))


def transit_flows(home: str, topo, config: ScenarioConfig, out: Path) -> bool:
    """The map's bus and tram lines as SUMO flows, each at its GTFS frequency in the scenario's window (see the
    module docstring); False when no line runs."""
    if not (out / "ptlines.xml").exists():
        return False
    dur = config.duration
    _tool(home, "ptlines2flows.py", "-n", "net.net.xml", "-l", "ptlines.xml", "-s", "stops.add.xml", "-o",
          "pt.rou.xml", "-b", "0", "-e", f"{dur:g}", "-p", "600", "--use-osm-routes", "--ignore-errors",
          "--seed", str(config.seed), "--multistart", cwd=out)
    window = max(dur, 3600.0)  # a short scenario takes its frequencies from the hour it starts in
    counts = gtfs_departures(topo, config.start, config.start + window)
    tree = ET.parse(out / "pt.rou.xml")
    root = tree.getroot()
    kept = 0
    for flow in list(root.iter("flow")):
        mode = flow.get("type", "")
        ref = flow.get("line", "").split(":")[0]
        n = counts.get((mode, ref), 0)
        if mode not in TRANSIT_TYPES or n == 0:
            root.remove(flow)
            continue
        # the feed's departures count both directions; ptlines2flows made one flow per direction
        flow.set("period", f"{max(2.0 * window / n, 60.0):.1f}")
        kept += 1
    tree.write(out / "pt.rou.xml", encoding="UTF-8", xml_declaration=True)
    return kept > 0


def gtfs_departures(topo, t0: float, t1: float) -> dict[tuple[str, str], int]:
    """(mode, route short name) -> departures over the map in [t0, t1) of the bundled GTFS feed, read and
    matched by the project's one GTFS reader (the schedule the simulation spawns from)."""
    from collections import Counter

    from entitynet.topology_cache import cache_dir
    from sims.engine.schedule import BUNDLED_FEED, load_schedule

    schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir())
    return dict(Counter((d.mode, d.ref) for d in schedule.departures if t0 <= d.time < t1))


def write_config(path: Path, net: str, routes: list[str], additional: list[str], duration: float) -> None:
    """The .sumocfg: network, demand, the window, and route errors skipped (a trip without a way is dropped)."""
    root = ET.Element("configuration")
    inp = ET.SubElement(root, "input")
    ET.SubElement(inp, "net-file", value=net)
    if routes:
        ET.SubElement(inp, "route-files", value=",".join(routes))
    if additional:
        ET.SubElement(inp, "additional-files", value=",".join(additional))
    t = ET.SubElement(root, "time")
    ET.SubElement(t, "begin", value="0")
    ET.SubElement(t, "end", value=f"{duration:g}")
    proc = ET.SubElement(root, "processing")
    ET.SubElement(proc, "ignore-route-errors", value="true")
    ET.SubElement(proc, "time-to-teleport", value="120")
    rep = ET.SubElement(root, "report")
    ET.SubElement(rep, "no-step-log", value="true")
    ET.SubElement(rep, "no-warnings", value="true")
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="UTF-8", xml_declaration=True)


def _env(home: str) -> dict[str, str]:
    env = dict(os.environ, SUMO_HOME=home)
    try:  # duarouter (randomTrips --validate) looks for proj.db; pyproj ships one
        from pyproj.datadir import get_data_dir

        env.setdefault("PROJ_DATA", get_data_dir())
    except ImportError:
        pass
    return env


def _tool(home: str, script: str, *args: str, cwd: Path) -> None:
    """Run one of SUMO's Python tools (SUMO_HOME/tools) with this interpreter."""
    _run([sys.executable, str(Path(home) / "tools" / script), *args], cwd, script)


def _run(args: list[str], cwd: Path, what: str) -> None:
    try:
        r = subprocess.run(args, cwd=cwd, env=_env(sumo_home()), capture_output=True, text=True,
                           timeout=TOOL_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SumoError(f"{what} could not run: {exc}") from None
    if r.returncode != 0:
        tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-5:])
        raise SumoError(f"{what} failed (exit {r.returncode}): {tail}")
