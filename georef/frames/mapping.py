"""Map projections through pyproj/PROJ: easting/northing, meridian convergence and scale factor.

Every CRS and projection in georef goes through this module; nothing hand-codes a projection.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pyproj import CRS, Proj, Transformer
from pyproj.exceptions import CRSError

Array = NDArray[np.float64]


class CRSChoiceError(ValueError):
    """The CRS a user named is unknown to PROJ or is not a projected CRS."""


@dataclass
class MapProjection:
    """A projected CRS named by the user (for example ``"EPSG:3765"``, HTRS96/TM).

    Geographic input is WGS84 latitude and longitude in degrees. Easting and northing are in the CRS's
    units (metres for every CRS georef accepts; others are rejected).
    """

    crs_name: str
    crs: CRS = field(init=False)
    _to_map: Transformer = field(init=False, repr=False)
    _proj: Proj = field(init=False, repr=False)

    def __post_init__(self) -> None:
        try:
            self.crs = CRS.from_user_input(self.crs_name)
        except CRSError as exc:
            raise CRSChoiceError(f"unknown CRS {self.crs_name!r}: {exc}") from exc
        if not self.crs.is_projected:
            raise CRSChoiceError(
                f"CRS {self.crs_name!r} ({self.crs.name}) is not a projected CRS; name one with easting and "
                "northing in metres, e.g. EPSG:3765 (HTRS96/TM) or a UTM zone such as EPSG:32633"
            )
        unit = self.crs.axis_info[0].unit_name
        if unit not in ("metre", "meter"):
            raise CRSChoiceError(f"CRS {self.crs_name!r} has axis unit {unit!r}; georef needs metres")
        self._to_map = Transformer.from_crs("EPSG:4326", self.crs, always_xy=True)
        self._proj = Proj(self.crs)

    def forward(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> tuple[Array, Array]:
        """WGS84 latitude, longitude [deg] to easting, northing [m]."""
        easting, northing = self._to_map.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
        return np.asarray(easting, float), np.asarray(northing, float)

    def convergence_and_scale(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> tuple[Array, Array]:
        """Meridian convergence [deg] and point scale factor [-] from PROJ's ``get_factors``.

        The convergence ``gamma`` is the angle from true north to grid north, counted clockwise, so a
        true azimuth ``alpha`` has the grid azimuth ``alpha - gamma``.
        """
        factors = self._proj.get_factors(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
        scale = np.sqrt(np.asarray(factors.meridional_scale) * np.asarray(factors.parallel_scale))
        return np.asarray(factors.meridian_convergence, float), scale
