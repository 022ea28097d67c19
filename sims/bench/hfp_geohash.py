"""HFP-style geohash topics: what Helsinki's real-time feed (HFP) puts at the end of each MQTT topic.

Why not a base-32 geohash library: HFP's "geohash" is not the base-32 geohash. Its levels are decimal digits
of latitude and longitude: level 0 is `"<lat int>;<lon int>"` and level k (1..3) adds the k-th decimal digit of
the latitude followed by that of the longitude, so `60;24/19/85/85` is the box lat 60.188..60.189, lon
24.955..24.956 (about 111 m north-south by 55 m east-west in Helsinki). A map client subscribes with a
wildcard to the prefix of every box that its view touches (`.../60;24/19/85/#`); this module computes the box
of a position (`box_of`), the topic tail of a box (`topic_tail`), the boxes covering a disc (`disc_cover`,
merged to shorter prefixes where all ten-by-ten children are in) and the boxes each visibility cell's footprint
touches (`cell_boxes`, for the variant that subscribes to the PVS's boxes). Boxes are integer pairs
(floor(lat x 10^level), floor(lon x 10^level)) with a level; the finest level is 3, as in HFP.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: HFP's finest geohash level (three decimal digits of latitude and longitude)
FINEST = 3
#: metres per degree of latitude (spherical Earth of the mean radius; the error is far below a box at 500 m)
M_PER_DEG = math.pi * 6_371_008.8 / 180.0


@dataclass(frozen=True, slots=True)
class Box:
    """A geohash box: `level` decimal digits, `ilat` = floor(lat x 10^level), `ilon` likewise."""

    level: int
    ilat: int
    ilon: int

    def parent(self) -> Box:
        """The box one level up (one digit fewer)."""
        return Box(self.level - 1, self.ilat // 10, self.ilon // 10)


def _check(lat: float, lon: float) -> None:
    if not (math.isfinite(lat) and math.isfinite(lon)):
        raise ValueError(f"position must be finite, got lat={lat!r}, lon={lon!r}")
    if not (0.0 <= lat < 90.0 and 0.0 <= lon < 180.0):
        # HFP writes the digits of positive degrees; the negative hemispheres would need its sign rules
        raise ValueError(f"HFP geohash needs lat in [0, 90) and lon in [0, 180), got lat={lat}, lon={lon}")


def box_of(lat: float, lon: float, level: int = FINEST) -> Box:
    """The box at `level` that holds the position; ValueError for NaN, infinite or unsupported positions."""
    _check(lat, lon)
    s = 10 ** level
    return Box(level, math.floor(lat * s), math.floor(lon * s))


def topic_tail(box: Box) -> str:
    """The topic levels of a box as HFP writes them: `60;24`, then one `<lat digit><lon digit>` per level."""
    s = 10 ** box.level
    lat_int, lat_dec = divmod(box.ilat, s)
    lon_int, lon_dec = divmod(box.ilon, s)
    parts = [f"{lat_int};{lon_int}"]
    for k in range(box.level - 1, -1, -1):
        parts.append(f"{lat_dec // 10 ** k % 10}{lon_dec // 10 ** k % 10}")
    return "/".join(parts)


def disc_cover(lat: float, lon: float, radius_m: float) -> set[Box]:
    """The finest boxes any part of which lies within `radius_m` of the position (the subscription of a map
    client showing a disc around its camera), merged upwards where all 100 children of a box are in. Distances
    in the local equirectangular frame of the centre (an error of well under 0.1 % at 500 m)."""
    _check(lat, lon)
    if not (math.isfinite(radius_m) and radius_m > 0.0):
        raise ValueError(f"radius must be a positive number of metres, got {radius_m!r}")
    s = 10 ** FINEST
    m_lat = M_PER_DEG
    m_lon = M_PER_DEG * math.cos(math.radians(lat))
    dlat, dlon = radius_m / m_lat, radius_m / m_lon
    i0, i1 = math.floor((lat - dlat) * s), math.floor((lat + dlat) * s)
    j0, j1 = math.floor((lon - dlon) * s), math.floor(min(lon + dlon, 179.999999) * s)
    ii = np.arange(i0, i1 + 1)[:, None]
    jj = np.arange(max(j0, 0), j1 + 1)[None, :]
    # the nearest point of each box to the centre, in metres
    ny = (np.clip(lat, ii / s, (ii + 1) / s) - lat) * m_lat
    nx = (np.clip(lon, jj / s, (jj + 1) / s) - lon) * m_lon
    inside = ny * ny + nx * nx <= radius_m * radius_m
    r, c = np.nonzero(inside)
    boxes = {Box(FINEST, int(ii[a, 0]), int(jj[0, b])) for a, b in zip(r.tolist(), c.tolist(), strict=True)}
    return merge(boxes)


def merge(boxes: set[Box]) -> set[Box]:
    """Replace every complete set of 100 sibling boxes by their parent, level by level (shorter prefixes:
    fewer subscriptions for the same area)."""
    out = set(boxes)
    for level in range(FINEST, 0, -1):
        children: dict[Box, int] = {}
        for b in out:
            if b.level == level:
                p = b.parent()
                children[p] = children.get(p, 0) + 1
        for p, n in children.items():
            if n == 100:
                out = {b for b in out if not (b.level == level and b.parent() == p)}
                out.add(p)
    return out


def cell_boxes(topo) -> list[frozenset[Box]]:
    """For each visibility cell, the finest boxes its footprint touches (one bulk STRtree query over the
    map's box grid, boxes projected into the map's metric frame corner by corner)."""
    import shapely

    from topology.projection import LocalProjection

    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    polys = topo.cell_footprints.to_shapely()
    b = topo.cell_footprints.bounds()
    ll = proj.to_wgs84(np.array([[b[:, 0].min(), b[:, 1].min()], [b[:, 2].max(), b[:, 3].max()],
                                 [b[:, 0].min(), b[:, 3].max()], [b[:, 2].max(), b[:, 1].min()]]))
    s = 10 ** FINEST
    i0, i1 = math.floor(ll[:, 1].min() * s), math.floor(ll[:, 1].max() * s)
    j0, j1 = math.floor(ll[:, 0].min() * s), math.floor(ll[:, 0].max() * s)
    ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    corners = np.stack([np.column_stack([jj + dj, ii + di]) / s for di, dj in ((0, 0), (0, 1), (1, 1), (1, 0))],
                       axis=1)  # (n, 4, [lon, lat])
    local = proj.to_local(corners[..., 0].ravel(), corners[..., 1].ravel()).reshape(-1, 4, 2)
    grid = shapely.polygons(local)
    cell_idx, box_idx = shapely.STRtree(grid).query(polys, predicate="intersects")
    out: list[set[Box]] = [set() for _ in range(len(polys))]
    for c, k in zip(cell_idx.tolist(), box_idx.tolist(), strict=True):
        out[c].add(Box(FINEST, int(ii[k]), int(jj[k])))
    return [frozenset(x) for x in out]
