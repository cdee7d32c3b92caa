"""Output coordinates through PROJ: the projected CRS, orthometric heights from a geoid grid, and what PROJ used.

georef computes WGS 84 latitude, longitude and **ellipsoidal** height [deg, deg, m]. A client usually wants
heights above a geoid ("above sea level"): ``H = h - N`` with ``N`` the geoid undulation of a height model.
Every such conversion here is PROJ's own (``pyproj.Transformer``), never an interpolation of our own:

* ``height = "orthometric"`` with a projected CRS (``EPSG:3765``) or none: the vertical CRS ``vertical_crs``
  (default ``EPSG:5773``, EGM96 height, grid ``us_nga_egm96_15.tif`` / ``egm96_15.gtx``);
* a compound CRS (``EPSG:3765+5773``, ``EPSG:3765+5610``): its vertical part, transformed from WGS 84 with the
  horizontal datum PROJ chooses for the whole CRS;
* KML's ``altitudeMode absolute`` means above sea level, which Google Earth takes as EGM96: :meth:`egm96`.

PROJ is never allowed a *ballpark* vertical transformation (which keeps ``h`` and calls it ``H``, 40-50 m wrong
over Europe) nor one whose grid is missing: both are errors that name the grids. The grids are looked for in
pyproj's data directory, ``$PROJ_DATA``/``$PROJ_LIB`` and Debian's ``/usr/share/proj`` (package ``proj-data``,
which ships ``egm96_15.gtx``); PROJ's network is not used.

Every transformation is reported by name with PROJ's stated accuracy [m] (:meth:`OutputFrames.describe`): for
HTRS96/TM that is "Inverse of HTRS96 to WGS 84 (1)", 1 m — a datum realisation difference that georef's
sigmas do not contain.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pyproj import CRS, Transformer, datadir
from pyproj.crs import CompoundCRS
from pyproj.exceptions import CRSError, ProjError
from pyproj.transformer import TransformerGroup

from georef.frames.mapping import CRSChoiceError

Array = NDArray[np.float64]

HEIGHTS = ("ellipsoidal", "orthometric")
#: EGM96 height: Google Earth's "sea level" and the default geoid for ``height = "orthometric"``
EGM96_HEIGHT = "EPSG:5773"
#: WGS 84 geographic 3D (latitude, longitude, ellipsoidal height): georef's own coordinates
WGS84_3D = "EPSG:4979"
#: where Debian's proj-data puts the grids (egm96_15.gtx)
SYSTEM_GRID_DIRS = ("/usr/share/proj", "/usr/local/share/proj")


class GeoidGridError(CRSChoiceError):
    """PROJ cannot convert to the asked height system with the grids installed here."""


def _add_grid_directories() -> list[str]:
    """Make the system's PROJ grid directories visible to pyproj's own PROJ (idempotent); the directories."""
    present = [d for d in datadir.get_user_data_dir(False).split(os.pathsep) if d]
    try:
        present += datadir.get_data_dir().split(os.pathsep)
    except Exception:  # pragma: no cover - pyproj without a data directory cannot work anyway
        pass
    wanted = [os.environ.get("PROJ_DATA", ""), os.environ.get("PROJ_LIB", ""), *SYSTEM_GRID_DIRS]
    for directory in wanted:
        for part in directory.split(os.pathsep):
            if part and Path(part).is_dir() and part not in present:
                datadir.append_data_dir(part)
                present.append(part)
    return present


def _epsg_name(crs: CRS) -> str:
    code = crs.to_epsg()
    return f"EPSG:{code}" if code else crs.to_wkt()


def _parse(name: str) -> CRS:
    try:
        return CRS.from_user_input(name)
    except CRSError as exc:
        raise CRSChoiceError(f"unknown CRS {name!r}: {exc}") from exc


@dataclass(frozen=True)
class Transformation:
    """One PROJ transformation used for the outputs: its description and stated accuracy [m] (None: unknown)."""

    what: str
    description: str
    accuracy_m: float | None

    def __str__(self) -> str:
        accuracy = "accuracy not stated" if self.accuracy_m is None else f"stated accuracy {self.accuracy_m:g} m"
        return f"{self.what}: {self.description} ({accuracy})"


def _transformation(what: str, transformer: Transformer) -> Transformation:
    accuracy = float(transformer.accuracy)
    return Transformation(what, transformer.description, accuracy if accuracy >= 0 else None)


@dataclass
class OutputFrames:
    """The coordinate systems of the outputs: ``crs`` (projected, or compound projected + vertical, or None)
    and the height kind (``"ellipsoidal"`` or ``"orthometric"``; ``vertical_crs`` for the latter when ``crs``
    has no vertical part).

    Raises :class:`CRSChoiceError` for a CRS PROJ does not know or that does not fit, and
    :class:`GeoidGridError` when the heights asked for need a grid that is not installed.
    """

    crs: str | None = None
    height: str = "ellipsoidal"
    vertical_crs: str = EGM96_HEIGHT
    horizontal: CRS | None = field(init=False, default=None)
    vertical: CRS | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        if self.height not in HEIGHTS:
            raise ValueError(f"height must be one of {', '.join(HEIGHTS)}, got {self.height!r}")
        _add_grid_directories()
        if self.crs:
            full = _parse(self.crs)
            if full.is_compound:
                parts = full.sub_crs_list
                self.horizontal, self.vertical = parts[0], parts[1] if len(parts) > 1 else None
                if self.vertical is None or not self.vertical.is_vertical:
                    raise CRSChoiceError(f"compound CRS {self.crs!r} has no vertical part")
                if self.height != "orthometric":
                    raise CRSChoiceError(
                        f"CRS {self.crs!r} names the height system {self.vertical.name!r}: add --height orthometric "
                        f"(heights in {self.vertical.name}), or give only the horizontal CRS "
                        f"{_epsg_name(self.horizontal)} for ellipsoidal heights")
            else:
                self.horizontal = full
            from georef.frames.mapping import MapProjection

            MapProjection(self.horizontal_name or self.crs)  # a projected CRS in metres, or a message saying why
        if self.height == "orthometric" and self.vertical is None:
            vertical = _parse(self.vertical_crs)
            if not vertical.is_vertical:
                raise CRSChoiceError(f"vertical_crs {self.vertical_crs!r} ({vertical.name}) is not a vertical CRS")
            self.vertical = vertical
        self._height_transformer: Transformer | None = None
        self._egm96: Transformer | None = None
        if self.height == "orthometric":
            self._height_transformer = self._vertical_transformer(self.vertical)

    # -- names --------------------------------------------------------------------------------------------------
    @property
    def horizontal_name(self) -> str | None:
        """The horizontal (projected) CRS as ``EPSG:nnnn`` (WKT when it has no EPSG code), or None."""
        return None if self.horizontal is None else _epsg_name(self.horizontal)

    @property
    def height_name(self) -> str:
        """What the output heights are: ``"WGS 84 ellipsoidal"`` or the vertical CRS's name."""
        return "WGS 84 ellipsoidal" if self.vertical is None else self.vertical.name

    # -- heights ------------------------------------------------------------------------------------------------
    def _vertical_transformer(self, vertical: CRS) -> Transformer:
        horizontal = self.horizontal if self.horizontal is not None else CRS.from_epsg(4326)
        target = CompoundCRS(name=f"{horizontal.name} + {vertical.name}", components=[horizontal, vertical])
        try:
            return Transformer.from_crs(WGS84_3D, target, always_xy=True, allow_ballpark=False, only_best=True)
        except ProjError:
            pass
        group = TransformerGroup(WGS84_3D, target, always_xy=True, allow_ballpark=False)
        missing = sorted({grid.short_name for op in group.unavailable_operations for grid in op.grids
                          if not grid.available})
        if missing:
            detail = f"the grid(s) {', '.join(missing)} are not installed"
        else:
            detail = "PROJ's database has no transformation to it other than a ballpark (which keeps h as H)"
        raise GeoidGridError(
            f"cannot compute heights in {vertical.name} from WGS 84 ellipsoidal heights: {detail}. Install the grid "
            f"into a PROJ data directory (searched: {', '.join(_add_grid_directories())}); Debian's proj-data "
            f"ships EGM96 (egm96_15.gtx, vertical CRS {EGM96_HEIGHT})")

    def output_heights(self, lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike) -> Array:
        """The heights the exports carry [m]: ``height_m`` (WGS 84 ellipsoidal) or the orthometric heights."""
        h = np.asarray(height_m, float)
        if self._height_transformer is None:
            return h.copy()
        return self._transform_height(self._height_transformer, lat_deg, lon_deg, h)

    def egm96(self, lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike) -> Array:
        """EGM96 heights [m] of WGS 84 points (KML's "above sea level"), whatever the output heights are."""
        if self._egm96 is None:
            target = CompoundCRS(name="WGS 84 + EGM96 height", components=[CRS.from_epsg(4326),
                                                                           _parse(EGM96_HEIGHT)])
            try:
                self._egm96 = Transformer.from_crs(WGS84_3D, target, always_xy=True, allow_ballpark=False,
                                                   only_best=True)
            except ProjError:
                self._egm96 = self._vertical_transformer(_parse(EGM96_HEIGHT))
        return self._transform_height(self._egm96, lat_deg, lon_deg, np.asarray(height_m, float))

    @staticmethod
    def _transform_height(transformer: Transformer, lat_deg: ArrayLike, lon_deg: ArrayLike, h: Array) -> Array:
        lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
        out = np.full(h.shape, np.nan)
        ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
        if ok.any():
            _, _, z = transformer.transform(lon[ok], lat[ok], h[ok], errcheck=True)
            out[ok] = z
        return out

    # -- report -------------------------------------------------------------------------------------------------
    def describe(self) -> list[Transformation]:
        """The transformations PROJ uses for the outputs: WGS 84 to the projected CRS (the same call as
        :class:`georef.frames.mapping.MapProjection`), and to the output heights."""
        out: list[Transformation] = []
        if self.horizontal is not None:
            transformer = Transformer.from_crs("EPSG:4326", self.horizontal, always_xy=True)
            out.append(_transformation("WGS 84 -> " + self.horizontal.name, transformer))
        if self._height_transformer is not None:
            out.append(_transformation("WGS 84 ellipsoidal height -> " + self.height_name, self._height_transformer))
        return out


def ellipsoidal_from_orthometric(lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike,
                                 vertical_crs: str = EGM96_HEIGHT) -> tuple[Array, Transformation]:
    """WGS 84 ellipsoidal heights [m] of heights above the geoid of ``vertical_crs`` (``h = H + N``), and the PROJ
    transformation that did it. Raises :class:`GeoidGridError` when its grid is not installed (never a ballpark)."""
    _add_grid_directories()
    vertical = _parse(vertical_crs)
    if not vertical.is_vertical:
        raise CRSChoiceError(f"{vertical_crs!r} ({vertical.name}) is not a vertical CRS")
    source = CompoundCRS(name=f"WGS 84 + {vertical.name}", components=[CRS.from_epsg(4326), vertical])
    try:
        transformer = Transformer.from_crs(source, WGS84_3D, always_xy=True, allow_ballpark=False, only_best=True)
    except ProjError as exc:
        raise GeoidGridError(
            f"cannot compute WGS 84 ellipsoidal heights from {vertical.name}: {exc}. Install its grid into a PROJ "
            f"data directory (searched: {', '.join(_add_grid_directories())}); Debian's proj-data ships EGM96 "
            f"(egm96_15.gtx, vertical CRS {EGM96_HEIGHT})") from exc
    h = OutputFrames._transform_height(transformer, lat_deg, lon_deg, np.asarray(height_m, float))
    return h, _transformation(f"{vertical.name} -> WGS 84 ellipsoidal height", transformer)
