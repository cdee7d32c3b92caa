"""Geotags of one image copy: what is read from a photo, what is written into its copy (pyexiv2, in memory).

Read: ``Make`` and the capture time (EXIF ``DateTimeOriginal`` + ``SubSecTimeOriginal``, ``OffsetTimeOriginal``
when present). Written into a copy of the photo's bytes, never into the photo:

* EXIF GPS (the GPS IFD of EXIF 2.32, which replaces any the photo had): ``GPSLatitude/Ref``,
  ``GPSLongitude/Ref`` (WGS 84, ``GPSMapDatum`` "WGS-84"), ``GPSAltitude`` + ``GPSAltitudeRef`` (0 above,
  1 below sea level) as the **EGM96 height** [m] — EXIF's altitude is "above sea level" and Pix4D takes it as
  EGM96 —, ``GPSTimeStamp`` (UTC time of the exposure) and ``GPSDateStamp`` (its UTC date, when known);
* XMP in Pix4D's ``Camera`` namespace (http://pix4d.com/camera/1.0/): ``Yaw``, ``Pitch``, ``Roll`` [deg]
  (:mod:`georef.frames.pix4d`, OpenDroneMap's reading per make applied), ``GPSXYAccuracy``, ``GPSZAccuracy`` [m,
  1 sigma per axis], ``IMUYawAccuracy``, ``IMUPitchAccuracy``, ``IMURollAccuracy`` [deg, 1 sigma].

Removed from the copy: every ``drone-dji:`` XMP tag (DJI's own position, altitude, gimbal and flight angles and
RTK sigmas, which OpenDroneMap prefers to everything else) and the XMP copies of EXIF GPS tags (``exif:GPS*``),
so no stale position from the drone's own receiver survives beside georef's.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from georef.frames.pix4d import Pix4dAngles, tag_angles_for_make
from georef.io.errors import InputError

#: Pix4D's XMP namespace and the prefix exiv2 writes
CAMERA_NAMESPACE = "http://pix4d.com/camera/1.0/"
CAMERA_PREFIX = "Camera"
#: DJI's XMP namespace (its tags are removed from every copy)
DJI_PREFIX = "drone-dji"
#: photos georef reads and tags (by extension, any case)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff")

_EXIF_TIME = re.compile(r"^(\d{4}):(\d{2}):(\d{2}) (\d{2}):(\d{2}):(\d{2})$")
_EXIF_ZONE = re.compile(r"^([+-])(\d{2}):(\d{2})$")
_registered = False


def _pyexiv2():
    """pyexiv2 with Pix4D's namespace registered (once per process)."""
    global _registered
    import pyexiv2

    if not _registered:
        pyexiv2.set_log_level(3)  # exiv2 logs errors only (they also raise), not its warnings about makers' notes
        try:
            pyexiv2.registerNs(CAMERA_NAMESPACE, CAMERA_PREFIX)
        except RuntimeError:  # registered before (another import of this module, or the caller)
            pass
        _registered = True
    return pyexiv2


@dataclass(frozen=True)
class CaptureTime:
    """A photo's capture time on the camera's clock: ``posix_s`` [s] (read as UTC without ``OffsetTimeOriginal``,
    converted to UTC with it), ``resolution_s`` [s] (1 without sub-seconds), ``zone_known``."""

    posix_s: float
    resolution_s: float
    zone_known: bool


@dataclass(frozen=True)
class SourceImage:
    """What georef reads from one photo: its ``make`` (EXIF ``Make``, empty when absent) and capture time
    (``None`` with the reason in ``capture_problem``)."""

    path: Path
    make: str
    capture: CaptureTime | None
    capture_problem: str | None


@dataclass(frozen=True)
class Geotag:
    """The tags of one copy: WGS 84 ``lat``, ``lon`` [deg], ``altitude_m`` (EGM96 height [m]), ``utc_posix`` (the
    exposure [POSIX s, UTC]) or, when the date is unknown, ``utc_seconds_of_day``; Pix4D's ``angles`` [deg];
    ``xy_accuracy_m``, ``z_accuracy_m`` [m], ``yaw/pitch/roll_accuracy_deg`` [deg], all 1 sigma."""

    lat: float
    lon: float
    altitude_m: float
    utc_posix: float | None
    utc_seconds_of_day: float
    angles: Pix4dAngles
    xy_accuracy_m: float
    z_accuracy_m: float
    yaw_accuracy_deg: float
    pitch_accuracy_deg: float
    roll_accuracy_deg: float


def _capture_time(path: Path, exif: dict[str, str]) -> tuple[CaptureTime | None, str | None]:
    text = exif.get("Exif.Photo.DateTimeOriginal", "").strip().rstrip("\x00")
    if not text:
        return None, "no EXIF DateTimeOriginal"
    match = _EXIF_TIME.match(text)
    if not match:
        raise InputError(path, None, "Exif.Photo.DateTimeOriginal", f"not an EXIF time 'YYYY:MM:DD HH:MM:SS': "
                         f"{text[:40]!r}")
    try:
        moment = dt.datetime(*(int(g) for g in match.groups()), tzinfo=dt.UTC)
    except ValueError as exc:
        raise InputError(path, None, "Exif.Photo.DateTimeOriginal", f"{text!r}: {exc}") from None
    subsec = exif.get("Exif.Photo.SubSecTimeOriginal", "").strip().rstrip("\x00").strip()
    fraction, resolution = 0.0, 1.0
    if subsec:
        if not subsec.isdigit() or not subsec.isascii():
            raise InputError(path, None, "Exif.Photo.SubSecTimeOriginal", f"not digits: {subsec[:20]!r}")
        # EXIF: the digits are the decimal fraction of the second ("05" = 0.05 s)
        fraction, resolution = int(subsec) / 10 ** len(subsec), 10.0 ** -len(subsec)
    zone = exif.get("Exif.Photo.OffsetTimeOriginal", "").strip().rstrip("\x00").strip()
    shift = 0.0
    if zone:
        zone_match = _EXIF_ZONE.match(zone)
        if not zone_match:
            raise InputError(path, None, "Exif.Photo.OffsetTimeOriginal", f"not '+HH:MM': {zone[:20]!r}")
        sign = -1.0 if zone_match.group(1) == "-" else 1.0
        shift = sign * (int(zone_match.group(2)) * 3600 + int(zone_match.group(3)) * 60)
    # local time - its offset from UTC = UTC
    return CaptureTime(moment.timestamp() + fraction - shift, resolution, bool(zone)), None


def read_source(path: Path) -> SourceImage:
    """Read a photo's make and capture time (from its bytes in memory: the file is only read)."""
    pyexiv2 = _pyexiv2()
    data = Path(path).read_bytes()
    try:
        with pyexiv2.ImageData(data) as image:
            exif = image.read_exif()
    except RuntimeError as exc:
        raise InputError(path, None, None, f"not an image exiv2 can read ({exc})") from None
    capture, problem = _capture_time(Path(path), exif)
    return SourceImage(Path(path), exif.get("Exif.Image.Make", "").strip().rstrip("\x00").strip(), capture, problem)


def _dms(value_deg: float) -> str:
    """|value| as EXIF degrees, minutes, seconds rationals (seconds to 1e-6 arcsec, about 0.03 mm)."""
    micro = round(abs(value_deg) * 3600e6)
    degrees, rest = divmod(micro, 3_600_000_000)
    minutes, seconds = divmod(rest, 60_000_000)
    return f"{degrees}/1 {minutes}/1 {seconds}/1000000"


def _time_of_day(seconds: float) -> str:
    micro = round(seconds * 1e6) % 86_400_000_000
    hours, rest = divmod(micro, 3_600_000_000)
    minutes, micros = divmod(rest, 60_000_000)
    return f"{hours}/1 {minutes}/1 {micros}/1000000"


def exif_gps(tag: Geotag) -> dict[str, str]:
    """The EXIF GPS tags of ``tag`` (pyexiv2 keys and values)."""
    tags = {
        "Exif.GPSInfo.GPSVersionID": "2 3 0 0",
        "Exif.GPSInfo.GPSLatitudeRef": "N" if tag.lat >= 0 else "S",
        "Exif.GPSInfo.GPSLatitude": _dms(tag.lat),
        "Exif.GPSInfo.GPSLongitudeRef": "E" if tag.lon >= 0 else "W",
        "Exif.GPSInfo.GPSLongitude": _dms(tag.lon),
        "Exif.GPSInfo.GPSAltitudeRef": "0" if tag.altitude_m >= 0 else "1",
        "Exif.GPSInfo.GPSAltitude": f"{round(abs(tag.altitude_m) * 1000)}/1000",
        "Exif.GPSInfo.GPSMapDatum": "WGS-84",
    }
    if tag.utc_posix is not None:
        moment = dt.datetime.fromtimestamp(tag.utc_posix, tz=dt.UTC)
        midnight = dt.datetime(moment.year, moment.month, moment.day, tzinfo=dt.UTC).timestamp()
        tags["Exif.GPSInfo.GPSTimeStamp"] = _time_of_day(tag.utc_posix - midnight)
        tags["Exif.GPSInfo.GPSDateStamp"] = moment.strftime("%Y:%m:%d")
    else:
        tags["Exif.GPSInfo.GPSTimeStamp"] = _time_of_day(tag.utc_seconds_of_day)
    return tags


def xmp_camera(tag: Geotag, make: str) -> dict[str, str]:
    """Pix4D's ``Camera`` XMP tags of ``tag`` for a photo of camera ``make``."""
    angles = tag_angles_for_make(tag.angles, make)
    prefix = f"Xmp.{CAMERA_PREFIX}."
    return {prefix + "Yaw": f"{float(angles.yaw):.6f}", prefix + "Pitch": f"{float(angles.pitch):.6f}",
            prefix + "Roll": f"{float(angles.roll):.6f}",
            prefix + "GPSXYAccuracy": f"{tag.xy_accuracy_m:.4f}", prefix + "GPSZAccuracy": f"{tag.z_accuracy_m:.4f}",
            prefix + "IMUYawAccuracy": f"{tag.yaw_accuracy_deg:.5f}",
            prefix + "IMUPitchAccuracy": f"{tag.pitch_accuracy_deg:.5f}",
            prefix + "IMURollAccuracy": f"{tag.roll_accuracy_deg:.5f}"}


def tagged_copy(data: bytes, tag: Geotag, make: str, source: Path) -> bytes:
    """The bytes of a copy of the photo ``data`` with ``tag`` written and the tags listed in the module's
    docstring removed (``source`` names the photo in errors)."""
    pyexiv2 = _pyexiv2()
    try:
        with pyexiv2.ImageData(data) as image:
            exif, xmp = image.read_exif(), image.read_xmp()
            stale_exif = {key: None for key in exif if key.startswith("Exif.GPSInfo.")}
            stale_xmp = {key: None for key in xmp if key.startswith((f"Xmp.{DJI_PREFIX}.", "Xmp.exif.GPS"))}
            if stale_exif:
                image.modify_exif(stale_exif)
            if stale_xmp:
                image.modify_xmp(stale_xmp)
            image.modify_exif(exif_gps(tag))
            image.modify_xmp(xmp_camera(tag, make))
            return image.get_bytes()
    except RuntimeError as exc:
        raise InputError(source, None, None, f"exiv2 cannot write its tags ({exc})") from None


def finite(*values: float) -> bool:
    """True when every value is a finite number."""
    return bool(np.all(np.isfinite(np.asarray(values, float))))
