"""Which OpenStreetMap tags make which network, which areas, and how tall a building is.

The tables are data so that README can print them and tests can check them. Rules in order:
- an `access`, `foot` or `motor_vehicle` of "no"/"private" removes that network from the way;
- `highway=construction|proposed|elevator|corridor|platform` and `area=yes` highways are not street centrelines
  (indoor corridors and lifts hold no visible entity; platforms and pedestrian areas become areas instead);
- `railway=tram` (and `light_rail`) is the tram network; other railways are not modelled.
"""

from __future__ import annotations

import math
import re

from topology.raw import PEDESTRIAN, TRAM, VEHICLE

#: highway=* value -> network bits
HIGHWAY_NETWORKS: dict[str, int] = {
    # drivable classes: cars on the road, people on its sidewalks
    **{
        k: VEHICLE | PEDESTRIAN
        for k in (
            "primary",
            "primary_link",
            "secondary",
            "secondary_link",
            "tertiary",
            "tertiary_link",
            "unclassified",
            "residential",
            "living_street",
            "service",
            "road",
            "busway",
        )
    },  # fmt: skip
    # fast roads: no pedestrians
    **{k: VEHICLE for k in ("motorway", "motorway_link", "trunk", "trunk_link")},
    # walkable only
    **{
        k: PEDESTRIAN
        for k in (
            "footway",
            "pedestrian",
            "path",
            "steps",
            "cycleway",
            "bridleway",
            "track",
            "trail",
            "sidewalk",
        )
    },
}

#: railway=* value -> network bits
RAILWAY_NETWORKS: dict[str, int] = {"tram": TRAM, "light_rail": TRAM}

#: highway values that are never centrelines (counted as "skipped:<value>")
NOT_CENTRELINES = {
    "construction",
    "proposed",
    "elevator",
    "corridor",
    "platform",
    "crossing",
    "raceway",
    "abandoned",
}

#: (key, value or None for any) -> (area kind, network bits); first match wins
AREA_RULES: list[tuple[str, str | None, str, int]] = [
    ("place", "square", "square", PEDESTRIAN),
    ("highway", "pedestrian", "pedestrian", PEDESTRIAN),
    ("highway", "footway", "pedestrian", PEDESTRIAN),
    ("amenity", "marketplace", "marketplace", PEDESTRIAN),
    ("leisure", "park", "park", PEDESTRIAN),
    ("leisure", "garden", "park", PEDESTRIAN),
    ("leisure", "playground", "playground", PEDESTRIAN),
    ("amenity", "parking", "parking", VEHICLE | PEDESTRIAN),
]

#: parking lots that are not open-air hold no visible entity
HIDDEN_PARKING = {"underground", "multi-storey", "rooftop", "garage_boxes", "carports"}

LEVEL_HEIGHT_M = 3.2
ROOF_ALLOWANCE_M = 1.0
#: default heights by building type where neither height nor levels is tagged (central Helsinki: 5-7 storeys)
DEFAULT_HEIGHT_BY_TYPE: dict[str, float] = {
    "church": 30.0, "cathedral": 45.0, "chapel": 12.0,
    "train_station": 20.0, "transportation": 10.0,
    "kiosk": 3.0, "shed": 3.0, "hut": 3.0, "garage": 3.0, "garages": 3.0, "carport": 3.0,
    "roof": 6.0, "toilets": 3.0, "service": 4.0, "bunker": 3.0,
    "house": 8.0, "detached": 8.0, "terrace": 10.0,
    "construction": 15.0,
}  # fmt: skip
DEFAULT_HEIGHT_M = 20.0
MAX_PLAUSIBLE_HEIGHT_M = 400.0

_NUMBER = re.compile(r"^\s*([0-9]+(?:[.,][0-9]+)?)\s*(m|meters?|metres?|ft|feet|')?\s*$", re.IGNORECASE)


class HeightError(ValueError):
    """A height tag that is not a plausible number of metres (e.g. "tall")."""


def parse_length_m(text: str) -> float:
    """Parse an OSM length such as "12.13 m", "3,5", "40 ft"; raise HeightError for anything else."""
    m = _NUMBER.match(text or "")
    if not m:
        raise HeightError(f"not a length: {text!r}")
    value = float(m.group(1).replace(",", "."))
    unit = (m.group(2) or "m").lower()
    if unit in ("ft", "feet", "'"):
        value *= 0.3048
    if not math.isfinite(value) or value <= 0.0 or value > MAX_PLAUSIBLE_HEIGHT_M:
        raise HeightError(f"implausible length: {text!r}")
    return value


def building_height(tags: dict[str, str]) -> tuple[float, str]:
    """(height in metres, source) from height, else building:levels, else a default by building type.

    Never raises: a bad `height` (e.g. "tall") falls back to levels or the default, and the source then says
    "(bad height)" so that the build report can count it.
    """
    bad = ""
    if "height" in tags:
        try:
            return parse_length_m(tags["height"]), "height"
        except HeightError:
            bad = "bad height"
    levels = tags.get("building:levels")
    if levels:
        try:
            n = float(levels.replace(",", "."))
            if math.isfinite(n) and 0 < n < 150:
                roof_levels = 0.0
                try:
                    roof_levels = max(0.0, float(tags.get("roof:levels", "0").replace(",", ".")))
                except ValueError:
                    pass
                return (n + roof_levels) * LEVEL_HEIGHT_M + ROOF_ALLOWANCE_M, "levels" + (
                    f"({bad})" if bad else ""
                )
        except ValueError:
            bad = bad or "bad levels"
    kind = tags.get("building") or tags.get("building:part") or "yes"
    height = DEFAULT_HEIGHT_BY_TYPE.get(kind, DEFAULT_HEIGHT_M)
    return height, "default" + (f"({bad})" if bad else "")


def way_networks(tags: dict[str, str]) -> int:
    """Network bits of a way from its tags (0 when the way is not a centreline of any network)."""
    bits = 0
    hw = tags.get("highway")
    if hw and hw not in NOT_CENTRELINES and tags.get("area") != "yes":
        bits |= HIGHWAY_NETWORKS.get(hw, 0)
    rw = tags.get("railway")
    if rw:
        bits |= RAILWAY_NETWORKS.get(rw, 0)
    if tags.get("access") in ("no", "private"):
        bits &= ~(PEDESTRIAN | VEHICLE)
    if tags.get("foot") in ("no", "private"):
        bits &= ~PEDESTRIAN
    if tags.get("motor_vehicle") in ("no", "private") or tags.get("motorcar") in ("no", "private"):
        bits &= ~VEHICLE
    return bits


def area_kind(tags: dict[str, str]) -> tuple[str, int] | None:
    """(kind, network bits) if these tags make a walkable/drivable area, else None."""
    for key, value, kind, bits in AREA_RULES:
        v = tags.get(key)
        if v is None or (value is not None and v != value):
            continue
        if key == "highway" and tags.get("area") != "yes":
            continue
        if kind == "parking" and tags.get("parking") in HIDDEN_PARKING:
            return None
        return kind, bits
    return None


def parse_layer(tags: dict[str, str]) -> int:
    """OSM `layer` as an int; missing or unreadable is 0 (the ground), as renderers read it."""
    try:
        return int(tags.get("layer", "0").strip())
    except ValueError:
        return 0
