"""Flat-earth conversion between geodetic coordinates and a local NED tangent plane.

Delivery section 4.1: distances are short, so a flat-earth model maps latitude/longitude to
metres. We use the WGS-84 meridian (R_M) and prime-vertical (R_N) radii of curvature at the
reference latitude; over 1 km the error against the full geodesic is below a centimetre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


@dataclass(frozen=True)
class GeoPoint:
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    def __post_init__(self) -> None:
        for name in ("lat_deg", "lon_deg", "alt_amsl_m"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"GeoPoint.{name} must be finite, got {v}")
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ValueError(f"GeoPoint.lat_deg must be in [-90, 90], got {self.lat_deg}")
        if not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"GeoPoint.lon_deg must be in [-180, 180], got {self.lon_deg}")


def radii_of_curvature(lat_deg: float) -> tuple[float, float]:
    """The WGS-84 meridian (R_M) and prime-vertical (R_N) radii of curvature at ``lat_deg``, m."""
    phi = math.radians(lat_deg)
    w = 1.0 - WGS84_E2 * math.sin(phi) ** 2
    r_n = WGS84_A_M / math.sqrt(w)  # prime vertical
    r_m = WGS84_A_M * (1.0 - WGS84_E2) / w**1.5  # meridian
    return r_m, r_n


@dataclass(frozen=True)
class LocalTangentPlane:
    """A flat-earth NED plane tangent at ``origin``."""

    origin: GeoPoint

    @property
    def _radii(self) -> tuple[float, float]:
        return radii_of_curvature(self.origin.lat_deg)

    def to_ned(self, p: GeoPoint) -> tuple[float, float, float]:
        r_m, r_n = self._radii
        dlat = math.radians(p.lat_deg - self.origin.lat_deg)
        dlon = math.radians(_wrap_deg(p.lon_deg - self.origin.lon_deg))
        north = dlat * (r_m + self.origin.alt_amsl_m)
        east = dlon * (r_n + self.origin.alt_amsl_m) * math.cos(math.radians(self.origin.lat_deg))
        down = self.origin.alt_amsl_m - p.alt_amsl_m
        return north, east, down

    def to_geo(self, north_m: float, east_m: float, down_m: float) -> GeoPoint:
        r_m, r_n = self._radii
        lat = self.origin.lat_deg + math.degrees(north_m / (r_m + self.origin.alt_amsl_m))
        lon = self.origin.lon_deg + math.degrees(
            east_m / ((r_n + self.origin.alt_amsl_m) * math.cos(math.radians(self.origin.lat_deg)))
        )
        return GeoPoint(lat, _wrap_deg(lon), self.origin.alt_amsl_m - down_m)


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def geo_to_ned(origin: GeoPoint, p: GeoPoint) -> tuple[float, float, float]:
    return LocalTangentPlane(origin).to_ned(p)


def ned_to_geo(origin: GeoPoint, north_m: float, east_m: float, down_m: float) -> GeoPoint:
    return LocalTangentPlane(origin).to_geo(north_m, east_m, down_m)
