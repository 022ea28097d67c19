"""Projection to a metric CRS with a local origin, so that float64 coordinates stay small and exact."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from pyproj import CRS, Proj, Transformer

MAX_SCALE_ERROR = 0.01  # a CRS that stretches lengths at the map by more than this is refused without force


class CrsError(ValueError):
    """A CRS the topology cannot be built in: unknown, not projected in metres, or wrong for the map's place."""


def check_metric(crs: str) -> CRS:
    """The CRS, if it is projected with metre axes; else a CrsError that says what is wrong and what to use.

    Degrees taken as metres shrink a town to a few hundred "metres" of noise and the cleaning then drops every
    street: the old symptom was a misleading "no streets left after cleaning"."""
    try:
        c = CRS.from_user_input(crs)
    except Exception as exc:
        raise CrsError(f"unknown CRS {crs!r}: {exc}") from None
    units = sorted({a.unit_name for a in c.axis_info[:2]})
    if not c.is_projected or units != ["metre"]:
        kind = "geographic (degrees)" if c.is_geographic else f"{'projected' if c.is_projected else 'not projected'}"
        raise CrsError(
            f"CRS {crs} ({c.name}) is {kind} with axes in {', '.join(units) or 'no units'}: a topology needs a "
            "projected CRS in metres (leave out --crs for the map's UTM zone, or e.g. EPSG:3067 in Finland)"
        )
    return c


def placement_problem(crs: str, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> str | None:
    """Why this metric CRS is wrong for a map with this WGS84 extent, or None: the extent is not inside the
    CRS's area of use, or lengths at the map's centre are stretched by more than MAX_SCALE_ERROR (EPSG:3857,
    whose area of use is the world, doubles lengths in Helsinki). A CRS without a recorded area of use is
    judged by its scale alone."""
    c = check_metric(crs)
    lon_c, lat_c = (lon_min + lon_max) / 2.0, (lat_min + lat_max) / 2.0
    try:
        f = Proj(c).get_factors(lon_c, lat_c)
        scale = max(abs(f.meridional_scale - 1.0), abs(f.parallel_scale - 1.0))
    except Exception:
        scale = math.nan
    stretch = f"; lengths there are {scale:.1%} off" if math.isfinite(scale) else ""
    extent = f"lon {lon_min:.4f}..{lon_max:.4f}, lat {lat_min:.4f}..{lat_max:.4f}"
    area = c.area_of_use
    if area is not None:
        west, south, east, north = area.bounds
        lon_ok = west <= lon_min and lon_max <= east if west <= east else lon_min >= west or lon_max <= east
        if not (lon_ok and south <= lat_min and lat_max <= north):
            return (f"the map ({extent}) is not inside the area of use of {crs} ({area.name}: lon {west}..{east}, "
                    f"lat {south}..{north}){stretch}")
    if math.isfinite(scale) and scale > MAX_SCALE_ERROR:
        return f"{crs} stretches lengths at the map ({extent}) by {scale:.1%}"
    return None


@lru_cache(maxsize=32)
def _transformer(source: str, target: str) -> Transformer:
    """The transformation between two CRSs, built once per pair: building one can cost tens of milliseconds
    (EPSG:3067 from WGS84 ~25 ms), and the readers project every building through it, so a town of 2,500
    buildings took 65 s with one built per call. pyproj's Transformer (>= 3.1) is safe to share across threads."""
    return Transformer.from_crs(source, target, always_xy=True)


def clear_transformer_cache() -> None:
    """Forget the built transformations (for tests that count how many are built)."""
    _transformer.cache_clear()


def utm_crs_for(lon: float, lat: float) -> str:
    """The UTM zone CRS (EPSG code string) that holds a WGS84 point."""
    if not (math.isfinite(lon) and math.isfinite(lat)) or not (-180 <= lon <= 180 and -80 <= lat <= 84):
        raise ValueError(f"no UTM zone for lon={lon}, lat={lat}")
    zone = min(int((lon + 180.0) // 6.0) + 1, 60)
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


@dataclass(frozen=True)
class LocalProjection:
    """WGS84 <-> local metric coordinates (CRS coordinates minus `origin`)."""

    crs: str
    origin: tuple[float, float]

    @classmethod
    def for_extent(
        cls, lon_min: float, lat_min: float, lon_max: float, lat_max: float, crs: str | None = None
    ):
        """The projection for a lon/lat box: `crs` (default: its UTM zone), origin at the box centre
        rounded to the metre, so that local coordinates stay small."""
        lon_c, lat_c = (lon_min + lon_max) / 2.0, (lat_min + lat_max) / 2.0
        crs = crs or utm_crs_for(lon_c, lat_c)
        check_metric(crs)
        x, y = _transformer("EPSG:4326", crs).transform(lon_c, lat_c)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"CRS {crs} cannot represent the map centre ({lon_c}, {lat_c})")
        return cls(crs, (float(round(x)), float(round(y))))

    def _fwd(self) -> Transformer:
        return _transformer("EPSG:4326", self.crs)

    def _inv(self) -> Transformer:
        return _transformer(self.crs, "EPSG:4326")

    def to_local(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """WGS84 lon/lat arrays -> (n, 2) local metres."""
        x, y = self._fwd().transform(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
        return np.column_stack([np.asarray(x) - self.origin[0], np.asarray(y) - self.origin[1]])

    def to_wgs84(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) local metres -> (n, 2) lon/lat, for GeoJSON export and web maps."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        lon, lat = self._inv().transform(xy[:, 0] + self.origin[0], xy[:, 1] + self.origin[1])
        return np.column_stack([lon, lat])
