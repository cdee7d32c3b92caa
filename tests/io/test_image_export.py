"""Geotagged image copies (``--export images:DIR``) read back by exiftool and by OpenDroneMap's own reading code
(ported below, cited), value by value against the EO table of the bundled flight; the originals untouched; photos
matched to frames by capture time, with the camera clock's offset, and the ambiguity of regular triggering.

The references are independent of georef's code: EGM96 heights by a PROJ transformation of the test's own, the
horizontal accuracy from sigma_n and sigma_e here, exiftool (a Perl program) for the tags.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import io
import json
import math
import re
import shutil
import subprocess
from pathlib import Path
from xml.dom import minidom

import numpy as np
import pytest
from georef_cli.main import app
from PIL import Image
from pyproj import Transformer
from typer.testing import CliRunner

from georef.config import load_config
from georef.eo import FLAG_DUPLICATE, FLAG_OUTSIDE
from georef.io.image_export import (
    NOT_TAGGED,
    REPORT_NAME,
    TAGGED,
    TAGGED_FLAGGED,
    check_image_export,
    export_images,
)
from georef.io.image_match import ClockMatchError, match_capture_times
from georef.pipeline import process

DATA = Path(__file__).resolve().parents[2] / "data"
PATTERN = "IMG_{frame:04d}.JPG"
DAY = dt.datetime(2025, 6, 14, tzinfo=dt.UTC).timestamp()  # the flight's UTC date in these tests
DJI_NS = "http://www.dji.com/drone-dji/1.0/"


# ---------------------------------------------------------------------------------------------------------------
# OpenDroneMap's photo reading, ported from OpenDroneMap/ODM at commit 32cfaacfe15ae0a037da25c8e544b92ddf875342
# (VERSION 3.6.0, 2026-07-22): opendm/photo.py, ODM_Photo.parse_exif_values (the geotag, make, capture-time and
# XMP parts), get_xmp, get_xmp_tag, set_attr_from_xmp_tag, dms_to_decimal. Replaced: exifread by Pillow's EXIF
# reader (the same IFD entries: Make, GPSLatitude/Ref, GPSLongitude/Ref, GPSAltitude/Ref), xmltodict.parse by the
# minimal equivalent below (attributes as '@prefix:name', elements as 'prefix:name', qualified names kept as
# written, as xmltodict does without namespace processing); logging dropped.
# ---------------------------------------------------------------------------------------------------------------
def _xmltodict_like(node) -> dict | str:
    attributes = {f"@{k}": v for k, v in node.attributes.items()} if node.attributes else {}
    children = [c for c in node.childNodes if c.nodeType == c.ELEMENT_NODE]
    if not children and not attributes:
        return "".join(c.data for c in node.childNodes if c.nodeType == c.TEXT_NODE)
    out: dict = dict(attributes)
    for child in children:
        value = _xmltodict_like(child)
        if child.tagName in out:
            out[child.tagName] = [*(out[child.tagName] if isinstance(out[child.tagName], list)
                                    else [out[child.tagName]]), value]
        else:
            out[child.tagName] = value
    return out


def odm_get_xmp(img_bytes: bytes) -> list[dict]:
    xmp_start = img_bytes.find(b"<x:xmpmeta")
    xmp_end = img_bytes.find(b"</x:xmpmeta")
    if xmp_start < xmp_end:
        xmp_str = img_bytes[xmp_start:xmp_end + 12].decode("utf8")
        root = minidom.parseString(xmp_str).documentElement
        xdict = {root.tagName: _xmltodict_like(root)}
        xdict = xdict.get("x:xmpmeta", {})
        xdict = xdict.get("rdf:RDF", {})
        xdict = xdict.get("rdf:Description", {})
        return xdict if isinstance(xdict, list) else [xdict]
    return []


def odm_get_xmp_tag(xmp_tags, tags):
    if isinstance(tags, str):
        tags = [tags]
    for tag in tags:
        if tag in xmp_tags:
            t = xmp_tags[tag]
            if isinstance(t, str):
                return str(t)
            if isinstance(t, dict):
                items = t.get("rdf:Seq", {}).get("rdf:li", {})
                if items:
                    return items if isinstance(items, str) else " ".join(items)
            elif isinstance(t, int | float):
                return t
    return None


class OdmPhoto:
    """The attributes of ODM_Photo that its geotag reading sets."""

    def __init__(self, path: Path):
        self.camera_make = ""
        self.latitude = self.longitude = self.altitude = None
        self.yaw = self.pitch = self.roll = None
        self.gps_xy_stddev = self.gps_z_stddev = None
        self.utc_time = None
        data = path.read_bytes()
        with Image.open(io.BytesIO(data)) as image:
            exif = image.getexif()
            gps = exif.get_ifd(0x8825)
        if 0x010F in exif:
            self.camera_make = str(exif[0x010F]).strip()
        if 6 in gps:
            self.altitude = float(gps[6])
            # exifread gives GPSAltitudeRef (a BYTE) as an int, Pillow as bytes
            if 5 in gps and (gps[5][0] if isinstance(gps[5], bytes) else int(gps[5])) > 0:
                self.altitude *= -1
        if 2 in gps:
            self.latitude = self.dms_to_decimal(gps[2], gps.get(1, "N"))
        if 4 in gps:
            self.longitude = self.dms_to_decimal(gps[4], gps.get(3, "E"))
        for xtags in odm_get_xmp(data):
            self.set_attr_from_xmp_tag("longitude", xtags, ["@drone-dji:Longitude"], float)
            self.set_attr_from_xmp_tag("latitude", xtags, ["@drone-dji:Latitude"], float)
            self.set_attr_from_xmp_tag("altitude", xtags, ["@drone-dji:AbsoluteAltitude"], float)
            if "@drone-dji:RtkStdLon" in xtags:
                y = float(odm_get_xmp_tag(xtags, "@drone-dji:RtkStdLon"))
                x = float(odm_get_xmp_tag(xtags, "@drone-dji:RtkStdLat"))
                self.gps_xy_stddev = max(x, y)
                if "@drone-dji:RtkStdHgt" in xtags:
                    self.gps_z_stddev = float(odm_get_xmp_tag(xtags, "@drone-dji:RtkStdHgt"))
            else:
                self.set_attr_from_xmp_tag("gps_xy_stddev", xtags, ["@Camera:GPSXYAccuracy", "GPSXYAccuracy"], float)
                self.set_attr_from_xmp_tag("gps_z_stddev", xtags, ["@Camera:GPSZAccuracy", "GPSZAccuracy"], float)
            # Account for over-estimation
            if self.gps_xy_stddev is not None:
                self.gps_xy_stddev *= 2.0
            if self.gps_z_stddev is not None:
                self.gps_z_stddev *= 2.0
            self.set_attr_from_xmp_tag("yaw", xtags, ["@drone-dji:FlightYawDegree", "@Camera:Yaw", "Camera:Yaw"],
                                       float)
            self.set_attr_from_xmp_tag("pitch", xtags,
                                       ["@drone-dji:GimbalPitchDegree", "@Camera:Pitch", "Camera:Pitch"], float)
            self.set_attr_from_xmp_tag("roll", xtags, ["@drone-dji:GimbalRollDegree", "@Camera:Roll", "Camera:Roll"],
                                       float)
            if self.yaw is not None and self.pitch is not None and self.roll is not None:
                if self.camera_make.lower() in ["dji", "hasselblad"]:
                    self.pitch = 90 + self.pitch
                if self.camera_make.lower() == "sensefly":
                    self.roll *= -1

    def set_attr_from_xmp_tag(self, attr, xmp_tags, tags, cast=None):
        v = odm_get_xmp_tag(xmp_tags, tags)
        if v is not None:
            if cast is None:
                setattr(self, attr, v)
            else:
                if cast in (float, int) and "/" in v:
                    num, den = map(float, v.split("/"))
                    v = num / den if den != 0 else v
                setattr(self, attr, cast(v))

    @staticmethod
    def dms_to_decimal(dms, sign):
        degrees, minutes, seconds = (float(v) for v in dms)
        return (-1 if sign[0] in "SWsw" else 1) * (degrees + minutes / 60 + seconds / 3600)
# ------------------------------------------------------------------------------------------------ end of port ---


def _jpeg(path: Path, make: str, capture_posix: float | None = None, zone: str | None = None) -> None:
    """A 64x48 JPEG with EXIF Make (and a capture time on the camera's clock, written as local time)."""
    exif = Image.Exif()
    exif[0x010F] = make
    if capture_posix is not None:
        local = dt.datetime.fromtimestamp(capture_posix, tz=dt.UTC)
        sub = exif.get_ifd(0x8769)
        sub[0x9003] = local.strftime("%Y:%m:%d %H:%M:%S")  # DateTimeOriginal
        sub[0x9291] = f"{local.microsecond // 1000:03d}"  # SubSecTimeOriginal, ms
        if zone is not None:
            sub[0x9011] = zone  # OffsetTimeOriginal
    buffer = io.BytesIO()
    Image.new("RGB", (64, 48), (90, 120, 60)).save(buffer, "JPEG", exif=exif.tobytes())
    path.write_bytes(buffer.getvalue())


def _dji_original(path: Path) -> None:
    """A DJI-like original: Make DJI, its own (wrong) EXIF GPS and drone-dji XMP with wrong values."""
    import pyexiv2

    _jpeg(path, "DJI")
    pyexiv2.registerNs(DJI_NS, "drone-dji")
    with pyexiv2.Image(str(path)) as image:
        image.modify_exif({"Exif.GPSInfo.GPSLatitudeRef": "S", "Exif.GPSInfo.GPSLatitude": "10/1 0/1 0/1",
                           "Exif.GPSInfo.GPSLongitudeRef": "W", "Exif.GPSInfo.GPSLongitude": "20/1 0/1 0/1",
                           "Exif.GPSInfo.GPSAltitude": "5000/1", "Exif.GPSInfo.GPSSpeed": "12/1"})
        image.modify_xmp({"Xmp.drone-dji.AbsoluteAltitude": "+1234.5", "Xmp.drone-dji.Latitude": "-10.0",
                          "Xmp.drone-dji.Longitude": "-20.0", "Xmp.drone-dji.GimbalYawDegree": "-170.0",
                          "Xmp.drone-dji.GimbalPitchDegree": "-45.0", "Xmp.drone-dji.GimbalRollDegree": "12.0",
                          "Xmp.drone-dji.FlightYawDegree": "33.0", "Xmp.drone-dji.RtkStdLon": "9.9",
                          "Xmp.drone-dji.RtkStdLat": "9.9", "Xmp.drone-dji.RtkStdHgt": "9.9",
                          "Xmp.exif.GPSLatitude": "10,0.0S"})


def _egm96(lat, lon, h):
    """EGM96 heights by PROJ, the test's own transformation (fails when the grid is missing: never a skip)."""
    transformer = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True, allow_ballpark=False,
                                       only_best=True)
    return np.asarray(transformer.transform(np.asarray(lon), np.asarray(lat), np.asarray(h))[2])


def _exiftool(paths: list[Path]) -> dict[str, dict]:
    exe = shutil.which("exiftool")
    assert exe is not None, "exiftool is not installed (make test installs it: apt-get install libimage-exiftool-perl)"
    out = subprocess.run([exe, "-j", "-n", "-G1", *map(str, paths)], capture_output=True, text=True, check=True)
    return {Path(item["SourceFile"]).name: item for item in json.loads(out.stdout)}


def _gps_posix(tags: dict) -> float:
    """exiftool's GPSDateTime ("YYYY:MM:DD HH:MM:SS[.sss]Z", UTC) as POSIX seconds."""
    stamp = tags["Composite:GPSDateTime"].rstrip("Z")
    fmt = "%Y:%m:%d %H:%M:%S.%f" if "." in stamp else "%Y:%m:%d %H:%M:%S"
    return dt.datetime.strptime(stamp, fmt).replace(tzinfo=dt.UTC).timestamp()


def _fingerprint(folder: Path) -> dict[str, tuple[str, int]]:
    return {p.name: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns) for p in folder.iterdir()}


@pytest.fixture(scope="module")
def flight():
    """The bundled flight's EO table with image names (one frame made outside the span, one a duplicate)."""
    result = process(DATA / "POS.txt", DATA / "Kamera.txt",
                     load_config(DATA / "flight.toml").updated(image_names=PATTERN))
    columns = {name: np.array(values, copy=True) for name, values in result.columns.items()}
    flags = columns["flag"].astype(object)
    outside, duplicate = 5, 6  # frames 6 and 7 (rows 5, 6): made into what a real log gives such frames
    for name in ("lat", "lon", "height", "roll", "pitch", "yaw", "sigma_n", "sigma_e", "sigma_u", "sigma_roll",
                 "sigma_pitch", "sigma_yaw"):
        columns[name] = columns[name].astype(float)
        columns[name][outside] = np.nan
    flags[outside], flags[duplicate] = FLAG_OUTSIDE, FLAG_DUPLICATE
    columns["flag"] = flags
    return result, columns


# frames: 1 plain, 2 the DJI-like original, 3 a senseFly, 500 in the GNSS outage (flagged), 6 outside the span,
# 7 a duplicate frame number; IMG_9999.JPG has no frame
PHOTOS = {"IMG_0001.JPG": "SONY", "IMG_0002.JPG": "DJI", "IMG_0003.JPG": "senseFly", "IMG_0006.JPG": "SONY",
          "IMG_0007.JPG": "SONY", "IMG_9999.JPG": "SONY"}


@pytest.fixture(scope="module")
def exported(flight, tmp_path_factory):
    result, columns = flight
    src = tmp_path_factory.mktemp("src")
    outage = int(np.flatnonzero(np.char.find(columns["flag"].astype(str), "GNSS outage") >= 0)[0])
    photos = {**PHOTOS, f"IMG_{int(columns['frame'][outage]):04d}.JPG": "SONY"}
    for name, make in photos.items():
        if make == "DJI":
            _dji_original(src / name)
        else:
            _jpeg(src / name, make)
    before = _fingerprint(src)
    out = tmp_path_factory.mktemp("copies") / "tagged"
    check_image_export(src, out, result.frames)
    done = export_images(columns, src, out, frames=result.frames, day_start_posix=DAY, date_source="test")
    return {"columns": columns, "src": src, "out": out, "done": done, "before": before, "outage": outage}


def _row(columns, name: str) -> int:
    return int(np.flatnonzero(columns["image"].astype(str) == name)[0])


def test_copies_read_back_by_exiftool(exported):
    columns, out = exported["columns"], exported["out"]
    copies = sorted(out.glob("*.JPG"))
    assert [p.name for p in copies] == ["IMG_0001.JPG", "IMG_0002.JPG", "IMG_0003.JPG",
                                        f"IMG_{int(columns['frame'][exported['outage']]):04d}.JPG"]
    tags = _exiftool(copies)
    for path in copies:
        t, j = tags[path.name], _row(columns, path.name)
        lat, lon, h = columns["lat"][j], columns["lon"][j], columns["height"][j]
        assert t["GPS:GPSLatitude"] == pytest.approx(lat, abs=1e-9)  # 0.1 mm
        assert t["GPS:GPSLongitude"] == pytest.approx(lon, abs=1e-9)
        assert t["GPS:GPSAltitudeRef"] == 0
        assert t["GPS:GPSAltitude"] == pytest.approx(float(_egm96(lat, lon, h)), abs=1e-3)
        assert abs(t["GPS:GPSAltitude"] - h) > 40  # EGM96, not ellipsoidal (N is about 44 m here)
        assert t["GPS:GPSMapDatum"] == "WGS-84"
        when = dt.datetime.fromtimestamp(DAY + columns["time"][j], tz=dt.UTC)
        assert t["GPS:GPSDateStamp"] == when.strftime("%Y:%m:%d")
        assert _gps_posix(t) == pytest.approx(DAY + columns["time"][j], abs=1e-3)
        pitch = columns["pitch"][j] - (90.0 if path.name == "IMG_0002.JPG" else 0.0)  # DJI: ODM adds 90 back
        roll = -columns["roll"][j] if path.name == "IMG_0003.JPG" else columns["roll"][j]  # senseFly: ODM negates
        assert t["XMP-Camera:Yaw"] == pytest.approx(columns["yaw"][j], abs=1e-6)
        assert t["XMP-Camera:Pitch"] == pytest.approx(pitch, abs=1e-6)
        assert t["XMP-Camera:Roll"] == pytest.approx(roll, abs=1e-6)
        horizontal = math.sqrt((columns["sigma_n"][j] ** 2 + columns["sigma_e"][j] ** 2) / 2.0)
        assert t["XMP-Camera:GPSXYAccuracy"] == pytest.approx(horizontal, abs=5e-5)
        assert t["XMP-Camera:GPSZAccuracy"] == pytest.approx(columns["sigma_u"][j], abs=5e-5)
        assert t["XMP-Camera:IMUYawAccuracy"] == pytest.approx(columns["sigma_yaw"][j], abs=5e-6)
        assert t["XMP-Camera:IMUPitchAccuracy"] == pytest.approx(columns["sigma_pitch"][j], abs=5e-6)
        assert t["XMP-Camera:IMURollAccuracy"] == pytest.approx(columns["sigma_roll"][j], abs=5e-6)
        assert not [key for key in t if "drone-dji" in key.lower()]
        assert "GPS:GPSSpeed" not in t and "XMP-exif:GPSLatitude" not in t  # the drone's own GPS tags are gone


def test_copies_read_back_by_odm(exported):
    columns, out = exported["columns"], exported["out"]
    for path in sorted(out.glob("*.JPG")):
        assert b"drone-dji" not in path.read_bytes()
        assert len(odm_get_xmp(path.read_bytes())) == 1  # ODM doubles the accuracies once per rdf:Description
        photo, j = OdmPhoto(path), _row(columns, path.name)
        assert photo.latitude == pytest.approx(columns["lat"][j], abs=1e-9)
        assert photo.longitude == pytest.approx(columns["lon"][j], abs=1e-9)
        lat, lon, h = columns["lat"][j], columns["lon"][j], columns["height"][j]
        assert photo.altitude == pytest.approx(float(_egm96(lat, lon, h)), abs=1e-3)
        # ODM's reading, +90 on DJI's pitch and the sign of senseFly's roll included, gives the EO table's angles
        assert photo.yaw == pytest.approx(columns["yaw"][j], abs=1e-6)
        assert photo.pitch == pytest.approx(columns["pitch"][j], abs=1e-6)
        assert photo.roll == pytest.approx(columns["roll"][j], abs=1e-6)
        # ODM doubles what it reads ("over-estimation"): its dop is twice our 1-sigma
        horizontal = math.sqrt((columns["sigma_n"][j] ** 2 + columns["sigma_e"][j] ** 2) / 2.0)
        assert photo.gps_xy_stddev == pytest.approx(2.0 * horizontal, abs=1e-4)
        assert photo.gps_z_stddev == pytest.approx(2.0 * columns["sigma_u"][j], abs=1e-4)
    assert OdmPhoto(out / "IMG_0002.JPG").camera_make == "DJI"  # the make is kept: ODM's camera model needs it


def test_the_dji_original_would_have_misled_odm(exported):
    """The port is not blind: on the DJI-like original it reads DJI's (wrong) tags, which the copy no longer has."""
    photo = OdmPhoto(exported["src"] / "IMG_0002.JPG")
    assert (photo.latitude, photo.longitude, photo.altitude) == (-10.0, -20.0, 1234.5)
    assert (photo.yaw, photo.pitch, photo.gps_xy_stddev) == (33.0, 45.0, 19.8)


def test_every_photo_reported_and_originals_untouched(exported):
    done, columns = exported["done"], exported["columns"]
    assert _fingerprint(exported["src"]) == exported["before"]  # bytes and mtimes
    status = {row.image: (row.status, row.reason) for row in done.rows}
    outage_name = f"IMG_{int(columns['frame'][exported['outage']]):04d}.JPG"
    assert status["IMG_0001.JPG"] == (TAGGED, "")
    assert status[outage_name][0] == TAGGED_FLAGGED and "GNSS outage" in status[outage_name][1]
    assert status["IMG_0006.JPG"][0] == NOT_TAGGED and FLAG_OUTSIDE in status["IMG_0006.JPG"][1]
    assert status["IMG_0007.JPG"][0] == NOT_TAGGED and FLAG_DUPLICATE in status["IMG_0007.JPG"][1]
    assert status["IMG_9999.JPG"][0] == NOT_TAGGED and "no frame" in status["IMG_9999.JPG"][1]
    assert not (exported["out"] / "IMG_0006.JPG").exists() and not (exported["out"] / "IMG_9999.JPG").exists()
    with open(exported["out"] / REPORT_NAME) as handle:
        table = handle.read().splitlines()
    assert len(table) == 1 + len(status) and table[0].startswith("image,frame,status,reason")
    lines = "\n".join(done.lines())
    assert "EGM96 height (EPSG:5773)" in lines and "3 photos not copied" in lines and "1 copies are of flagged" in lines


def _irregular(columns, keep_runs):
    """The EO table's times of the frames in ``keep_runs`` (row ranges): a camera paused in the turns."""
    rows = np.concatenate([np.arange(a, b) for a, b in keep_runs])
    return rows, np.asarray(columns["time"], float)


def test_capture_time_offset_recovered_on_irregular_triggering(flight):
    _, columns = flight
    rows, times = _irregular(columns, [(0, 40), (52, 95), (130, 200), (230, 260), (300, 330)])
    table = np.full(len(times), np.nan)
    table[rows] = times[rows]  # the frames the camera did not expose are not in this flight's table
    rng = np.random.default_rng(3)
    offset, drift = 7200.0 + 0.317, 25e-6  # a camera on UTC+2, 0.317 s fast, running 25 ppm fast
    camera = DAY + times[rows] + offset + drift * (times[rows] - times[rows].mean()) + rng.normal(0, 0.002, len(rows))
    camera = np.floor(camera * 1000) / 1000  # SubSecTimeOriginal in ms, truncated
    match = match_capture_times(camera, np.full(len(rows), 1e-3), table)
    assert match.offset_s == pytest.approx(offset, abs=0.003)
    assert match.drift_ppm == pytest.approx(25.0, abs=10.0)
    assert np.array_equal(match.frame_index, rows)  # every photo on its own frame
    assert match.spread_s < 0.004
    assert match.day_start_posix == DAY


def test_capture_time_is_ambiguous_on_regular_triggering(flight):
    _, columns = flight
    times = np.asarray(columns["time"], float)
    rows = np.arange(100, 160)  # one straight line at a 0.33 s interval
    camera = DAY + times[rows] + 3.25 + np.random.default_rng(4).normal(0, 0.002, len(rows))
    with pytest.raises(ClockMatchError, match="not unique") as err:
        match_capture_times(camera, np.full(len(rows), 1e-3), times)
    assert "--image-names" in str(err.value) and "--camera-clock-offset" in str(err.value)
    # the user's offset settles it: every photo on its own frame
    match = match_capture_times(camera, np.full(len(rows), 1e-3), times, fixed_offset_s=3.25)
    assert np.array_equal(match.frame_index, rows) and match.fixed


def _irregular_photos(result, tmp_path: Path, clock_minus_utc_s: float, zone: str | None = None):
    """Three lines of the flight's frames (turns left out) as freely named photos in ``tmp_path/src`` whose
    capture times run ``clock_minus_utc_s`` ahead of UTC; the frames' rows of the EO table (without names)."""
    columns = {k: v for k, v in result.columns.items() if k != "image"}
    rows, times = _irregular(columns, [(10, 22), (40, 47), (80, 95)])
    src = tmp_path / "src"
    src.mkdir()
    for k, j in enumerate(rows):
        _jpeg(src / f"DSC{k:05d}.JPG", "SONY", DAY + times[j] + clock_minus_utc_s, zone=zone)
    return {k: np.asarray(v)[rows] for k, v in columns.items()}, src


def test_capture_time_matching_end_to_end_with_a_time_zone(flight, tmp_path):
    """Photos named freely, matched by capture time; OffsetTimeOriginal +02:00 makes the camera clock UTC."""
    result, _ = flight
    # the camera shows local time (UTC+2) and knows it; its clock is 1.5 s slow
    table, src = _irregular_photos(result, tmp_path, 7200.0 - 1.5, zone="+02:00")
    done = export_images(table, src, tmp_path / "out", frames=result.frames)
    assert done.clock is not None and done.clock.offset_s == pytest.approx(-1.5, abs=0.002)
    assert done.count(TAGGED) == len(table["frame"])
    tags = _exiftool(sorted((tmp_path / "out").glob("*.JPG")))
    for k in range(len(table["frame"])):
        t = tags[f"DSC{k:05d}.JPG"]
        assert t["GPS:GPSLatitude"] == pytest.approx(table["lat"][k], abs=1e-9)
        assert _gps_posix(t) == pytest.approx(DAY + table["time"][k], abs=1e-3)
    assert "from the photos' capture times" in "\n".join(done.lines())


def test_named_photos_report_their_clock_and_a_photo_off_its_frame(flight, tmp_path):
    result, _ = flight
    columns = result.columns
    src = tmp_path / "src"
    src.mkdir()
    for j in (0, 1, 2, 3, 40):
        late = 30.0 if j == 40 else 0.0  # IMG_0041.JPG was taken 30 s later than frame 41: a wrong name
        _jpeg(src / str(columns["image"][j]), "SONY", DAY + columns["time"][j] - 0.25 + late)
    done = export_images(columns, src, tmp_path / "out", frames=result.frames)
    assert done.clock is not None and done.clock.offset_s == pytest.approx(-0.25, abs=0.002)
    lines = "\n".join(done.lines())
    assert "1 photos' capture times disagree with their named frame" in lines and "IMG_0041.JPG" in lines
    assert done.date_source is not None and "capture times" in done.date_source


def test_cli_regular_triggering_fails_then_the_offset_settles_it(tmp_path):
    src = tmp_path / "photos"
    src.mkdir()
    frames = np.loadtxt(DATA / "Kamera.txt", skiprows=1)
    for number, second, ms in frames[200:215]:
        _jpeg(src / f"P{int(number):04d}.JPG", "SONY", DAY + second + ms / 1000 + 0.8)
    before = _fingerprint(src)
    base = ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"),
            "-o", str(tmp_path / "eo.csv"), "--images", str(src), "--export", f"images:{tmp_path / 'out'}", "-q"]
    runner = CliRunner()
    failed = runner.invoke(app, base)
    assert failed.exit_code == 2, failed.output
    assert "not unique" in failed.output and "--camera-clock-offset" in failed.output
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
    assert not (tmp_path / "eo.csv").exists()  # all or nothing
    ok = runner.invoke(app, [*base, "--camera-clock-offset", "0.8", "--summary-json", str(tmp_path / "s.json")])
    assert ok.exit_code in (0, 4), ok.output
    summary = json.loads((tmp_path / "s.json").read_text())["summary"]["images"][0]
    assert summary["tagged"] + summary["tagged_flagged"] == 15 and summary["camera_clock"]["given"]
    assert _fingerprint(src) == before


@pytest.mark.parametrize(("extra", "message"), [
    (["--images", "{src}"], "no images export"),
    (["--export", "images:{out}"], "--images SRC_DIR"),
    (["--images", "{src}", "--export", "images:{src}"], "own folder"),
])
def test_image_export_checked_before_processing(tmp_path, extra, message):
    src = tmp_path / "photos"
    src.mkdir()
    _jpeg(src / "a.jpg", "SONY")
    args = [a.format(src=src, out=tmp_path / "out") for a in extra]
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"),
                                      "-o", str(tmp_path / "eo.csv"), *args])
    assert result.exit_code == 2 and message in result.output.replace("\n", " ")


def test_batch_flight_with_its_images_folder(tmp_path):
    """``georef batch --export images``: a flight folder's images/ gets copies in its output folder; a flight
    without one fails as an input error naming the folder, before processing."""
    from georef.batch import discover, process_flight

    flights = tmp_path / "flights"
    for name in ("with", "without"):
        folder = flights / name
        folder.mkdir(parents=True)
        for data in ("POS.txt", "Kamera.txt"):
            (folder / data).symlink_to(DATA / data)
        toml = (DATA / "flight.toml").read_text().replace("[output]\n", f'[output]\nimage_names = "{PATTERN}"\n')
        (folder / "flight.toml").write_text(toml)
    (flights / "with" / "images").mkdir()
    for name in ("IMG_0001.JPG", "IMG_0002.JPG"):
        _jpeg(flights / "with" / "images" / name, "SONY")
    jobs = {job.flight: job for job in discover(flights)}
    assert jobs["with"].images == str(flights / "with" / "images") and jobs["without"].images is None
    out = tmp_path / "out"
    missing = process_flight(jobs["without"], str(out), exports=(("images", "images"),))
    assert missing["status"] == "failed" and missing["failure"] == "input" and "images/" in missing["message"]
    row = process_flight(jobs["with"], str(out), exports=(("images", "images"),))
    assert row["status"] == "ok", row["message"]
    tags = _exiftool(sorted((out / "with" / "images").glob("*.JPG")))
    eo = np.genfromtxt(out / "with" / "eo.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    for k, name in enumerate(("IMG_0001.JPG", "IMG_0002.JPG")):
        assert tags[name]["GPS:GPSLatitude"] == pytest.approx(float(eo["lat"][k]), abs=1e-8)
    assert "images: 2 of 2 photos" in (out / "with" / "georef.log").read_text()


# ---------------------------------------------------------------------------------------------------------------
# The new-user trial's findings (issue 25): a given offset an interval off, exports that copy nothing, a wrong
# date, batch's advice, image names with an offset.
# ---------------------------------------------------------------------------------------------------------------
def _regular_run(columns, first: int, last: int):
    """Rows first..last-1 of the bundled flight (one straight line, 0.33 s interval) and a table of only them."""
    times = np.asarray(columns["time"], float)
    rows = np.arange(first, last)
    table = np.full(len(times), np.nan)
    table[rows] = times[rows]
    return rows, times, table


def test_given_offset_an_interval_off_is_refused(flight):
    """The trial: a photo for every frame, a given offset 0.317 s off (the interval 0.333 s): every photo was tagged
    with the next frame and only 'one photo not copied' told. Now the neighbouring pairing's extra photo refuses it,
    either way off; the right offset passes with every photo on its own frame."""
    _, columns = flight
    rows, times, table = _regular_run(columns, 100, 160)
    interval = float(np.median(np.diff(times[rows])))
    true = 7200.317
    camera = np.floor((DAY + times[rows] + true) * 1000) / 1000
    resolution = np.full(len(rows), 1e-3)
    for given in (true - 0.317, true + 0.333):
        with pytest.raises(ClockMatchError, match="one trigger interval off") as err:
            match_capture_times(camera, resolution, table, fixed_offset_s=given)
        text = str(err.value)
        assert f"+-{interval / 2:.3f} s" in text and "--image-names" in text
        assert f"matches {len(rows) - 1} of {len(rows)}" in text and f"matches {len(rows)}" in text
    match = match_capture_times(camera, resolution, table, fixed_offset_s=true)
    assert np.array_equal(match.frame_index, rows) and match.alternatives == []
    # within half an interval of the truth still picks the right frames (no local search: the given value holds)
    near = match_capture_times(camera, resolution, table, fixed_offset_s=true + 0.04)
    assert np.array_equal(near.frame_index, rows) and near.offset_s == true + 0.04


def test_given_offset_on_a_subset_of_a_regular_run_is_accepted_with_a_warning(flight, tmp_path):
    """Photos of the middle of a regular run: the pairings one interval either side match as many photos, so the
    data cannot check the given offset; it is used, and the output says the pairing rests on it."""
    result, _ = flight
    columns = {k: v for k, v in result.columns.items() if k != "image"}
    times = np.asarray(columns["time"], float)
    src = tmp_path / "src"
    src.mkdir()
    rows = np.arange(120, 130)
    for k, j in enumerate(rows):
        _jpeg(src / f"DSC{k:05d}.JPG", "SONY", DAY + times[j] + 3.25)
    done = export_images(columns, src, tmp_path / "out", frames=result.frames, fixed_offset_s=3.25)
    assert [row.frame for row in done.rows] == [str(columns["frame"][j]) for j in rows]
    # one and two exposures either way (rows 120..129 have frames on both sides): an interval apart each
    assert done.clock is not None and [fit.matched for fit in done.clock.alternatives] == [len(rows)] * 4
    steps = np.diff(times[rows[0] - 2: rows[0] + 3])
    expected = [-(steps[2] + steps[3]), -steps[2], steps[1], steps[0] + steps[1]]  # anchor row 120's neighbours
    assert sorted(fit.offset_s - 3.25 for fit in done.clock.alternatives) == pytest.approx(expected, abs=0.002)
    assert "the pairing rests on the given offset" in "\n".join(done.lines())
    assert done.to_dict()["camera_clock"]["equal_offsets_s"]
    assert done.check() is None  # matched by capture time: no images check (that match is refused below half)


@pytest.mark.parametrize(("pattern", "message"), [
    ("IMG_{frame:04d}.jpg", "differ only in case (e.g. IMG_0001.JPG)"),
    ("DSC_{frame:04d}.JPG", "none of its 2 photos"),
])
def test_image_names_that_name_no_photo_fail_before_processing(tmp_path, pattern, message):
    """The trial: names that match no photo copied nothing and said 'QC passed', exit 0 (with -q: nothing)."""
    src = tmp_path / "photos"
    src.mkdir()
    for name in ("IMG_0001.JPG", "IMG_0002.JPG"):
        _jpeg(src / name, "SONY")
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "-q",
                                      "-o", str(tmp_path / "eo.csv"), "--images", str(src),
                                      "--export", f"images:{tmp_path / 'out'}", "--image-names", pattern])
    assert result.exit_code == 2, result.output
    assert message in result.output.replace("\n", " ")
    assert not (tmp_path / "eo.csv").exists()
    from georef.io.image_export import ImageExportError

    with pytest.raises(ImageExportError, match=message.replace("(", r"\(").replace(")", r"\)")):
        check_image_export(src, tmp_path / "out", None, pattern)  # the check before processing itself
    check_image_export(src, tmp_path / "out", None, PATTERN)  # the folder's own names pass


def test_image_names_that_name_no_photo_of_the_frames_fail(flight, tmp_path):
    """A pattern the folder's names fit (IMG_*.JPG) but no frame's name is there (five digits): nothing matched is
    an error, never an empty export that passes."""
    from georef.io.image_export import ImageExportError

    result, _ = flight
    columns = dict(result.columns)
    columns["image"] = np.array([f"IMG_{int(f):05d}.JPG" for f in columns["frame"]], dtype=object)
    src = tmp_path / "src"
    src.mkdir()
    for name in ("IMG_0001.JPG", "IMG_0002.JPG"):
        _jpeg(src / name, "SONY")
    check_image_export(src, tmp_path / "out", result.frames, "IMG_{frame:05d}.JPG")  # the shapes fit
    with pytest.raises(ImageExportError, match="none of its 2 photos") as err:
        export_images(columns, src, tmp_path / "out", frames=result.frames)
    assert "IMG_00001.JPG" in str(err.value)
    assert not (tmp_path / "out").exists()


def test_partly_named_folders_warn_and_mostly_unnamed_ones_fail(flight, exported, tmp_path):
    """Some photos without a named frame (or named photos missing): a QC warning; fewer than half the folder's
    photos with a frame: a QC failure (exit 4), with advice about --image-names."""
    check = exported["done"].check()
    assert check is not None and check.status == "warn"
    assert "6 of 7 photos" in check.message and "IMG_9999.JPG" in check.message
    result, _ = flight
    src = tmp_path / "src"
    src.mkdir()
    for name in ("IMG_0001.JPG", "IMG_0002.JPG", "DSC_0003.JPG", "DSC_0004.JPG", "DSC_0005.JPG"):
        _jpeg(src / name, "SONY")
    done = export_images(result.columns, src, tmp_path / "out", frames=result.frames)
    check = done.check()
    assert check is not None and check.status == "fail" and "2 of 5 photos" in check.message
    assert "--image-names" in check.message
    from georef_cli.handoffs import with_image_checks

    from georef.qc import Verdict

    assert not with_image_checks(Verdict(()), [done]).passed


def test_a_date_that_puts_the_camera_beyond_any_time_zone_is_refused(flight, tmp_path):
    """The trial: --utc-date a day late gave an offset of -22 h, accepted, and a wrong GPSDateStamp."""
    from georef.io.image_export import ImageExportError

    result, _ = flight
    columns = result.columns
    src = tmp_path / "src"
    src.mkdir()
    for j in (0, 1, 2, 3):
        _jpeg(src / str(columns["image"][j]), "SONY", DAY + columns["time"][j] + 7200.317)  # UTC+2, no zone
    with pytest.raises(ImageExportError, match="beyond any time zone") as err:
        export_images(columns, src, tmp_path / "out", frames=result.frames, day_start_posix=DAY + 86400.0,
                      date_source="--utc-date 2025-06-15")
    assert "2025-06-14" in str(err.value) and "--utc-date 2025-06-15" in str(err.value)
    assert "-79199.68" in str(err.value)
    done = export_images(columns, src, tmp_path / "out", frames=result.frames, day_start_posix=DAY,
                         date_source="--utc-date 2025-06-14")
    assert done.clock is not None and done.clock.offset_s == pytest.approx(7200.317, abs=0.002)
    # a camera on UTC+14 (Kiribati) on the right date is not refused
    src14 = tmp_path / "src14"
    src14.mkdir()
    for j in (0, 1, 2, 3):
        _jpeg(src14 / str(columns["image"][j]), "SONY", DAY + columns["time"][j] + 14 * 3600.0)
    done = export_images(columns, src14, tmp_path / "out14", frames=result.frames, day_start_posix=DAY,
                         date_source="--utc-date 2025-06-14")
    assert done.clock is not None and done.clock.offset_s == pytest.approx(14 * 3600.0, abs=0.002)


def test_a_given_offset_that_puts_the_photos_on_another_day_is_refused(flight, tmp_path):
    from georef.io.image_export import ImageExportError

    result, _ = flight
    table, src = _irregular_photos(result, tmp_path, 7200.0)
    with pytest.raises(ImageExportError, match="exposed on 2025-06-14 UTC, and --utc-date 2025-06-15 says"):
        export_images(table, src, tmp_path / "out", frames=result.frames, fixed_offset_s=7200.0,
                      day_start_posix=DAY + 86400.0, date_source="--utc-date 2025-06-15")


def test_image_names_with_a_clock_offset_are_refused(tmp_path):
    src = tmp_path / "photos"
    src.mkdir()
    _jpeg(src / "IMG_0001.JPG", "SONY")
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"),
                                      "-o", str(tmp_path / "eo.csv"), "--images", str(src),
                                      "--export", f"images:{tmp_path / 'out'}", "--image-names", PATTERN,
                                      "--camera-clock-offset", "3"])
    assert result.exit_code == 2 and "pair them by name" in result.output.replace("\n", " ")


def test_batch_regular_triggering_points_to_flight_toml(tmp_path):
    """batch has neither --image-names nor --camera-clock-offset: its advice names flight.toml's image_names."""
    from georef.batch import discover, process_flight

    folder = tmp_path / "flights" / "f1"
    folder.mkdir(parents=True)
    for data in ("POS.txt", "Kamera.txt", "flight.toml"):
        (folder / data).symlink_to(DATA / data)
    (folder / "images").mkdir()
    frames = np.loadtxt(DATA / "Kamera.txt", skiprows=1)
    for number, second, ms in frames[200:215]:
        _jpeg(folder / "images" / f"P{int(number):04d}.JPG", "SONY", DAY + second + ms / 1000 + 0.8)
    job = next(iter(discover(tmp_path / "flights")))
    row = process_flight(job, str(tmp_path / "out"), exports=(("images", "images"),))
    assert row["status"] == "failed" and row["failure"] == "input", row["message"]
    assert "not unique" in row["message"] and "image_names in the flight's flight.toml" in row["message"]
    assert "--image-names" not in row["message"]


# The hand-off benchmark's findings (benchmarks/handoffs.py): a long flight on a drifting camera clock.
def _long_regular_flight(count: int, drift_ppm: float, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Exposures every 2.0 s (2 ms jitter) and their capture times on a camera 7200.317 s ahead of UTC (UTC+2, no
    zone tag) running ``drift_ppm`` fast, in ms: (EO times [UTC s of day], camera POSIX [s], true offset [s])."""
    rng = np.random.default_rng(seed)
    eo_time = 36000.0 + 2.0 * np.arange(count) + rng.normal(0.0, 0.002, count)
    offset = 7200.317
    camera = (DAY + eo_time + offset + drift_ppm * 1e-6 * (eo_time - eo_time.mean())
              + rng.normal(0.0, 0.002, count))
    return eo_time, np.floor(camera * 1000.0) / 1000.0, offset


def test_a_given_offset_on_a_drifting_clock_matches_every_photo():
    """3000 photos over 100 min, 25 ppm fast: +-75 ms of drift at the ends, beyond the 50 ms tolerance. Unfitted,
    a third of the photos found no frame and an offset two intervals away matched more by chance, so the right
    offset was refused. The drift is fitted from the middle outwards: every photo on its own frame, the drift
    recovered; an offset an interval off is still refused, one 30 ms off still pairs every photo and shows it."""
    eo_time, camera, offset = _long_regular_flight(3000, 25.0, 31)
    resolution = np.full(len(camera), 1e-3)
    match = match_capture_times(camera, resolution, eo_time, fixed_offset_s=offset)
    assert np.array_equal(match.frame_index, np.arange(len(camera))) and match.fixed
    assert match.offset_s == offset and match.drift_ppm == pytest.approx(25.0, abs=0.5)
    assert match.alternatives == [] and match.spread_s < 0.003
    for given in (offset - 2.0, offset + 2.0):
        with pytest.raises(ClockMatchError, match="one trigger interval off") as err:
            match_capture_times(camera, resolution, eo_time, fixed_offset_s=given)
        assert "matches 2999 of 3000" in str(err.value) and "matches 3000" in str(err.value)
    near = match_capture_times(camera, resolution, eo_time, fixed_offset_s=offset + 0.03)
    assert np.array_equal(near.frame_index, np.arange(len(camera))) and near.offset_s == offset + 0.03
    # the residuals are taken from the given offset: their median shows it 30 ms too large
    assert float(np.median(near.residual_s)) == pytest.approx(-0.03, abs=0.002)


def test_not_unique_lists_the_best_fitting_offset_first():
    """1200 photos every 2 s, 50 ppm fast: scored without drift, the true offset lost photos at both ends and one
    shifted by 53 intervals (1147 photos of the overlap) was named best, the true one (1200) only a rival. Each
    offset's drift is fitted before they are ranked."""
    eo_time, camera, offset = _long_regular_flight(1200, 50.0, 32)
    with pytest.raises(ClockMatchError, match="not unique") as err:
        match_capture_times(camera, np.full(len(camera), 1e-3), eo_time)
    listed = re.search(r"fit about equally[^:]*: (.*)", str(err.value)).group(1)
    assert listed.startswith(f"{offset:+.3f} s (1200 of 1200 photos")
    # then the offsets an interval either side, each matching all but one photo
    rivals = listed.split("tolerance), ")[1]
    assert rivals.startswith((f"{offset - 2.0:+.3f} s (1199), {offset + 2.0:+.3f} s (1199)",
                              f"{offset + 2.0:+.3f} s (1199), {offset - 2.0:+.3f} s (1199)"))


@pytest.mark.parametrize("regular", [True, False])
def test_the_pruned_search_finds_every_rival_that_refining_every_proposal_finds(monkeypatch, regular):
    """The search scores its proposals coarsely on a sample of photos and refines only those that can still rival
    the best (it was 7 n proposals x n photos). Checked against refining every proposal: the same best offset and
    the same rivals, with the sample (here 40 of 150 photos) smaller than the flight."""
    from georef.io import image_match

    monkeypatch.setattr(image_match, "SAMPLE_PHOTOS", 40)
    monkeypatch.setattr(image_match, "SAMPLE_END_PHOTOS", 5)
    rng = np.random.default_rng(33)
    steps = np.full(150, 2.0) if regular else rng.uniform(1.2, 3.0, 150)
    if regular:
        steps[60] += 0.7  # a turn: one interval away loses a photo there and one at an end, two away four
    eo_time = 36000.0 + np.cumsum(steps) + rng.normal(0.0, 0.002, 150)
    camera_s = eo_time + 7200.317 + 40e-6 * (eo_time - eo_time.mean()) + rng.normal(0.0, 0.002, 150)
    tol = np.full(150, image_match.CLOCK_TOLERANCE_S)
    order = np.arange(150)
    reference = float(np.mean(camera_s))
    pruned = image_match._search(eo_time, order, camera_s, tol, reference)
    proposals = image_match._cluster((camera_s[image_match._anchors(150)][:, None] - eo_time[None, :]).ravel(),
                                     float(np.min(tol)))
    every = [image_match._refine(eo_time, order, camera_s, tol, float(d), reference) for d in proposals]
    best = max(fit.matched for fit in every)
    assert pruned[0].matched == best == 150 and pruned[0].offset == pytest.approx(7200.317, abs=0.002)

    def rivals(fits):
        margin = image_match.MIN_UNMATCHED_MARGIN
        close = {round(fit.offset, 1): fit.matched for fit in fits if fit.matched > best - margin}
        return sorted(close.items())

    assert rivals(pruned) == rivals(every)
    assert len(rivals(every)) == (3 if regular else 1)  # the best itself and, regular, one interval either way


def test_proposals_cluster_into_groups_no_wider_than_the_tolerance():
    """A chain of proposals 30 ms apart is cut into groups no wider than 50 ms, each stood for by its middle (so
    within 25 ms of every member: the search's coarse tolerance allows for that)."""
    from georef.io.image_match import _cluster

    offsets = np.array([1.0, 0.09, 0.0, 0.06, 0.03, 2.0, 2.02])
    assert _cluster(offsets, 0.05) == pytest.approx([0.015, 0.075, 1.0, 2.01])
