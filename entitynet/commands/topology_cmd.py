"""`entitynet topology build | info | export`: map data -> the topology artifact, and a look inside it."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from entitynet.cli import CommandError
from entitynet.commands.options import LOCAL_COORDINATE, METRES, bounded_float


def register(sub) -> None:
    """`entitynet topology build | info | export | pvs`."""
    p = sub.add_parser("topology", help="build and inspect the topology artifact")
    tsub = p.add_subparsers(dest="topology_command", metavar="ACTION", required=True)

    b = tsub.add_parser(
        "build", help="build the artifact from OSM or GeoJSON (default: the bundled Helsinki map)"
    )
    src = b.add_mutually_exclusive_group()
    src.add_argument("--osm", metavar="FILE", help="OpenStreetMap .pbf, .osm or .osm.bz2")
    src.add_argument("--geojson", metavar="FILE", help="GeoJSON streets/areas/buildings")
    b.add_argument("--out", metavar="FILE", help="artifact to write (default: <map name>.enttopo)")
    b.add_argument("--crs", help="projected CRS in metres, e.g. EPSG:3067 (default: the UTM zone of the map)")
    b.add_argument("--force", action="store_true",
                   help="build even where --crs is not made for the map's place (outside its area of use); warns")
    b.add_argument(
        "--bbox",
        nargs=4,
        type=bounded_float(-180, 180),
        metavar=("LON_MIN", "LAT_MIN", "LON_MAX", "LAT_MAX"),
        help="keep only OSM features that meet this WGS84 box",
    )
    b.add_argument("--street-width", type=METRES, default=16.0, metavar="M", help="cell width (default 16 m)")
    b.add_argument(
        "--entity-height", type=METRES, default=4.5, metavar="M", help="cell height (default 4.5 m)"
    )
    b.add_argument(
        "--junction-radius", type=METRES, metavar="M", help="junction arm length (default: street width)"
    )
    b.add_argument(
        "--max-cell-length", type=bounded_float(5.0, 10_000.0), default=60.0, metavar="M",
        help="street cell length cap, 5 to 10,000 m (60 m; shorter cells multiply the cells and the PVS)",
    )
    b.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    b.add_argument("--no-pvs", action="store_true", help="skip view cells and the PVS (faster; no visibility)")
    _add_pvs_options(b)
    b.set_defaults(func=cmd_build)

    i = tsub.add_parser("info", help="counts, extent, CRS, digest and the build report of an artifact")
    i.add_argument("file")
    i.set_defaults(func=cmd_info)

    e = tsub.add_parser("export", help="write cells, edges, areas and buildings as WGS84 GeoJSON")
    e.add_argument("file")
    e.add_argument("--geojson", metavar="OUT", required=True, help="GeoJSON file to write")
    e.add_argument("--layers", default="cells,edges,areas,buildings", help="comma-separated layers to export")
    _add_pvs_export_options(e)
    e.set_defaults(func=cmd_export)
    _register_pvs_command(tsub)
    from entitynet.commands.regions_cmd import register as register_regions

    register_regions(tsub, load_artifact)


def _add_pvs_options(parser: argparse.ArgumentParser) -> None:
    from entitynet.commands.pvs_cmd import add_pvs_arguments

    add_pvs_arguments(parser)


def _add_pvs_export_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pvs-at",
        nargs=3,
        type=LOCAL_COORDINATE,
        metavar=("X", "Y", "Z"),
        help="also export the PVS (visible cells) of the view cell holding this local position",
    )


def _register_pvs_command(tsub) -> None:
    from entitynet.commands.pvs_cmd import register_pvs_command

    register_pvs_command(tsub, load_artifact)


def _progress(quiet: bool):
    start = time.perf_counter()

    def say(msg: str) -> None:
        if not quiet:
            print(f"[{time.perf_counter() - start:6.1f}s] {msg}", file=sys.stderr, flush=True)

    return say


def load_artifact(path: str):
    """Load an artifact, or a CommandError naming what is wrong with the file (no traceback)."""
    from topology.artifact import ArtifactError, load

    try:
        return load(path)
    except ArtifactError as exc:
        raise CommandError(str(exc)) from None


def cmd_build(args: argparse.Namespace) -> int:
    """Read, build and save; bad numbers and bad maps end with a clear error, not a half-written file."""
    from topology.artifact import save
    from topology.build import BuildConfig, BuildError, build, features_dropped, read_map
    from topology.cells import CellParams

    path = args.osm or args.geojson
    if path and not Path(path).is_file():
        raise CommandError(f"{path}: no such file")
    say = _progress(args.quiet)
    config = BuildConfig(
        cells=CellParams(
            street_width_m=_positive(args.street_width, "--street-width"),
            entity_height_m=_positive(args.entity_height, "--entity-height"),
            junction_radius_m=None
            if args.junction_radius is None
            else _positive(args.junction_radius, "--junction-radius"),
            max_street_cell_m=_positive(args.max_cell_length, "--max-cell-length"),
        ),
        crs=args.crs,
        force_crs=args.force,
    )
    config.pvs = None
    if not args.no_pvs:
        from entitynet.commands.pvs_cmd import pvs_config_from_args

        config.pvs = pvs_config_from_args(args)
    try:
        say(f"reading {path or 'the bundled Helsinki map'}")
        if args.bbox and not (args.bbox[0] < args.bbox[2] and args.bbox[1] < args.bbox[3]):
            raise CommandError("--bbox wants LON_MIN LAT_MIN LON_MAX LAT_MAX with min < max")
        raw = read_map(path, args.crs, tuple(args.bbox) if args.bbox else None)
        topo = build(
            raw, config, progress=say, source=Path(path).name if path else "helsinki.osm.pbf (bundled)",
            warn=lambda msg: print(f"entitynet: warning: {msg}", file=sys.stderr, flush=True),
        )
    except BuildError as exc:
        raise CommandError(str(exc)) from None
    out = (
        Path(args.out)
        if args.out
        else Path((Path(path).name.split(".")[0] if path else "helsinki") + ".enttopo")
    )
    digest = save(topo, out)
    c = topo.meta["counts"]
    print(
        f"{out}: {c['nodes']} nodes, {c['edges']} edges, cells: {c['cells_street']} street, "
        f"{c['cells_junction']} junction, {c['cells_area']} area; {c['buildings']} buildings; "
        f"{len(topo.routes)} routes; {features_dropped(topo.meta['report'])} features dropped; digest {digest[:16]}"
    )
    return 0


def _positive(value: float, name: str) -> float:
    if not (value > 0 and value < 1e6):
        raise CommandError(f"{name} must be a positive number of metres, not {value}")
    return value


def cmd_info(args: argparse.Namespace) -> int:
    """Print counts, extent, CRS, digest and the build report: what a user checks after a build."""
    from topology.build import report_lines

    topo = load_artifact(args.file)
    m = topo.meta
    c = m["counts"]
    xmin, ymin, xmax, ymax = m["bounds"]
    print(f"artifact:  {args.file} (format {m['format']} v{m['format_version']})")
    print(f"digest:    {m['digest']}")
    print(f"source:    {m.get('source', '')}")
    print(f"crs:       {m['crs']}, origin {m['origin'][0]:.0f} {m['origin'][1]:.0f}")
    print(
        f"extent:    {xmax - xmin:.0f} m x {ymax - ymin:.0f} m (local {xmin:.0f} {ymin:.0f} .. {xmax:.0f} {ymax:.0f})"
    )
    print(f"nodes:     {c['nodes']}   edges: {c['edges']}")
    print(f"cells:     {c['cells_street']} street, {c['cells_junction']} junction, {c['cells_area']} area")
    print(f"areas:     {c['areas']}   buildings: {c['buildings']}   routes: {len(topo.routes)}")
    if "pvs" in m:
        pv = m["pvs"]
        print(f"pvs:       {', '.join(f'{k}={v}' for k, v in pv.items() if not isinstance(v, (dict, list)))}")
    else:
        print("pvs:       none (built with --no-pvs)")
    if "timings" in m:
        print("timings:   " + ", ".join(f"{k} {v}" for k, v in m["timings"].items()))
    print("build report:")
    for line in report_lines(m.get("report", {})):
        print("  " + line)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """Write the chosen layers (and optionally one PVS) as WGS84 GeoJSON."""
    from topology.export import LAYERS, write_geojson

    layers = tuple(x.strip() for x in args.layers.split(",") if x.strip())
    unknown = [x for x in layers if x not in LAYERS]
    if unknown:
        raise CommandError(f"unknown layer(s) {', '.join(unknown)}; choose from {', '.join(LAYERS)}")
    topo = load_artifact(args.file)
    extra = []
    if args.pvs_at:
        from topology.export import pvs_geojson_features

        if "pvs" not in topo.meta:
            raise CommandError(f"{args.file} has no PVS (it was built with --no-pvs)")
        extra = pvs_geojson_features(topo, *args.pvs_at)
    n = write_geojson(topo, args.geojson, layers, extra)
    print(f"{args.geojson}: {n} features ({', '.join(layers)}{', pvs' if extra else ''}), WGS84")
    return 0
