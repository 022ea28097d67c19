"""Projection to a metric CRS with a local origin, so that float64 coordinates stay small and exact."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pyproj import CRS, Transformer


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
        lon_c, lat_c = (lon_min + lon_max) / 2.0, (lat_min + lat_max) / 2.0
        crs = crs or utm_crs_for(lon_c, lat_c)
        try:
            CRS.from_user_input(crs)
        except Exception as exc:
            raise ValueError(f"unknown CRS {crs!r}: {exc}") from None
        fwd = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        x, y = fwd.transform(lon_c, lat_c)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"CRS {crs} cannot represent the map centre ({lon_c}, {lat_c})")
        return cls(crs, (float(round(x)), float(round(y))))

    def _fwd(self) -> Transformer:
        return Transformer.from_crs("EPSG:4326", self.crs, always_xy=True)

    def _inv(self) -> Transformer:
        return Transformer.from_crs(self.crs, "EPSG:4326", always_xy=True)

    def to_local(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        x, y = self._fwd().transform(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
        return np.column_stack([np.asarray(x) - self.origin[0], np.asarray(y) - self.origin[1]])

    def to_wgs84(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        lon, lat = self._inv().transform(xy[:, 0] + self.origin[0], xy[:, 1] + self.origin[1])
        return np.column_stack([lon, lat])
