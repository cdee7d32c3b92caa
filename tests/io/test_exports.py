"""Every export read back by its consumer: OpenDroneMap's own parser (ported below, cited), GDAL/OGR and fastkml for
KML and GeoJSON, the documented column conventions of Metashape and PIX4D, and PROJ for every coordinate.

The references are independent of georef's code: coordinates go back through pyproj, rotations through
scipy's ``Rotation``, geoid heights through a PROJ transformation of the test's own.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from pyproj import CRS, Transformer
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from georef.config import load_config
from georef.frames.heights import GeoidGridError, OutputFrames
from georef.io.errors import GeorefError
from georef.io.exports import FORMATS, ExportError, parse_export, write_export
from georef.io.image_names import ImageNames
from georef.pipeline import process

DATA = Path(__file__).resolve().parents[2] / "data"
PATTERN = "IMG_{frame:04d}.JPG"


# ---------------------------------------------------------------------------------------------------------------
# OpenDroneMap's geo.txt reader, ported from OpenDroneMap/ODM at commit 32cfaacfe15ae0a037da25c8e544b92ddf875342
# (VERSION 3.6.0, 2026-07-22): opendm/geo.py (GeoFile, GeoEntry), opendm/location.py (parse_srs_header,
# transform3) and opendm/photo.py (ODM_Photo.update_with_geo_entry, ODM_Photo.compute_opk). Logging and the
# GDAL/osr transformation are replaced: location.transform3 converts with osr in traditional GIS (x = easting,
# longitude) order, here pyproj with always_xy=True; opensfm.geo.ecef_from_lla is pyproj's EPSG:4979 -> 4978.
# ---------------------------------------------------------------------------------------------------------------
def odm_parse_srs_header(header: str) -> CRS:
    header = header.strip()
    ref = header.split(" ")
    if ref[0] == "WGS84" and ref[1] == "UTM":
        datum = ref[0]
        utm_pole = (ref[2][len(ref[2]) - 1]).upper()
        utm_zone = int(ref[2][: len(ref[2]) - 1])
        proj4 = f"+proj=utm +zone={utm_zone} +datum={datum} +units=m +no_defs=True"
        if utm_pole == "S":
            proj4 += " +south=True"
        return CRS.from_proj4(proj4)
    if "+proj" in header:
        return CRS.from_proj4(header.strip("'"))
    if header.lower().startswith("epsg:"):
        return CRS.from_epsg(header.lower()[5:])
    raise RuntimeError(f"Could not parse coordinates. Bad SRS supplied: {header}")


class OdmGeoEntry:
    def __init__(self, filename, x, y, z, yaw=None, pitch=None, roll=None, horizontal_accuracy=None,
                 vertical_accuracy=None, extras=None):
        self.filename, self.x, self.y, self.z = filename, x, y, z
        self.yaw, self.pitch, self.roll = yaw, pitch, roll
        self.horizontal_accuracy, self.vertical_accuracy, self.extras = horizontal_accuracy, vertical_accuracy, extras


class OdmGeoFile:
    def __init__(self, geo_path):
        self.entries = {}
        with open(geo_path) as f:
            contents = f.read().strip()
        contents = contents.replace("\ufeff", "")
        lines = list(map(str.strip, contents.split("\n")))
        if lines:
            self.raw_srs = lines[0]
            self.srs = odm_parse_srs_header(self.raw_srs)
            to_ll = Transformer.from_crs(self.srs, CRS.from_epsg(4326), always_xy=True)
            for line in lines[1:]:
                if line != "" and line[0] != "#":
                    parts = line.split()
                    if len(parts) >= 3:
                        i = 3
                        filename = parts[0]
                        x, y = [float(p) for p in parts[1:3]]
                        z = float(parts[3]) if len(parts) >= 4 else None
                        if z is not None:
                            x, y, z = to_ll.transform(x, y, z)
                        else:
                            x, y = to_ll.transform(x, y)
                        yaw = pitch = roll = None
                        if len(parts) >= 7:
                            yaw, pitch, roll = [float(p) for p in parts[4:7]]
                            if math.isnan(yaw) or math.isnan(pitch) or math.isnan(roll):
                                yaw = pitch = roll = None
                            i = 7
                        horizontal_accuracy = vertical_accuracy = None
                        if len(parts) >= 9:
                            horizontal_accuracy, vertical_accuracy = [float(p) for p in parts[7:9]]
                            i = 9
                        extras = " ".join(parts[i:])
                        self.entries[filename] = OdmGeoEntry(filename, x, y, z, yaw, pitch, roll,
                                                             horizontal_accuracy, vertical_accuracy, extras)
                    else:
                        raise AssertionError(f"Malformed geo line: {line}")


def odm_ecef_from_lla(lat, lon, alt):
    return Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(lon, lat, alt)


def odm_compute_opk(entry: OdmGeoEntry, fixed_frame: bool = False):
    """ODM_Photo.update_with_geo_entry + compute_opk: (omega, phi, kappa) [deg] ODM hands to OpenSfM, or None when
    the entry has no angles. ``fixed_frame``: the NED -> ENU matrix instead of ODM 3.6's ``cen`` (its columns are
    ECEF vectors, north and [0, 0, -1]), as proposed in ODM PR #1977 — not ODM's code, the reference frame of
    OpenSfM's ``rotation_from_opk`` (topocentric east, north, up)."""
    if entry.yaw is None or entry.pitch is None or entry.roll is None:
        return None
    y, p, r = math.radians(entry.yaw), math.radians(entry.pitch), math.radians(entry.roll)
    cnb = np.array([[math.cos(y) * math.cos(p), math.cos(y) * math.sin(p) * math.sin(r) - math.sin(y) * math.cos(r),
                     math.cos(y) * math.sin(p) * math.cos(r) + math.sin(y) * math.sin(r)],
                    [math.sin(y) * math.cos(p), math.sin(y) * math.sin(p) * math.sin(r) + math.cos(y) * math.cos(r),
                     math.sin(y) * math.sin(p) * math.cos(r) - math.cos(y) * math.sin(r)],
                    [-math.sin(p), math.cos(p) * math.sin(r), math.cos(p) * math.cos(r)]])
    cbb = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    if fixed_frame:
        cen = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    else:
        delta = 1e-7
        alt = entry.z if entry.z is not None else 0.0
        p1 = np.array(odm_ecef_from_lla(entry.y + delta, entry.x, alt))
        p2 = np.array(odm_ecef_from_lla(entry.y - delta, entry.x, alt))
        xnp = p1 - p2
        xnp /= np.linalg.norm(xnp)
        znp = np.array([0, 0, -1]).T
        ynp = np.cross(znp, xnp)
        cen = np.array([xnp, ynp, znp]).T
    ceb = cen.dot(cnb).dot(cbb)
    return (math.degrees(math.atan2(-ceb[1][2], ceb[2][2])), math.degrees(math.asin(ceb[0][2])),
            math.degrees(math.atan2(-ceb[0][1], ceb[0][0])))
# ------------------------------------------------------------------------------------------------ end of port ---


def _run(tmp_path_factory, **changes):
    cfg = load_config(DATA / "flight.toml").updated(**changes)
    result = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg)
    # one frame outside the navigation span: it has no station to export
    table = result.table
    extra = table.iloc[:1].copy()
    numeric = [c for c in table.columns if c not in ("frame", "image", "time", "flag")]
    extra.loc[:, numeric] = np.nan
    extra["frame"] = "9999"
    if "image" in extra:
        extra["image"] = "IMG_9999.JPG"
    result.table = pd.concat([table, extra], ignore_index=True)
    return result


@pytest.fixture(scope="module")
def ortho(tmp_path_factory):
    """HTRS96/TM, EGM96 heights, image names from a pattern."""
    return _run(tmp_path_factory, height="orthometric", image_names=PATTERN)


@pytest.fixture(scope="module")
def sweref(tmp_path_factory):
    """SWEREF99 TM (EPSG:3006): northing is the CRS's first axis. Ellipsoidal heights, no image names."""
    return _run(tmp_path_factory, crs="EPSG:3006")


def _stations(table):
    return table[table["lat"].notna()]


def _egm96(lat, lon, h):
    """EGM96 heights by PROJ, the test's own transformation (fails when the grid is missing: never a skip)."""
    transformer = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True, allow_ballpark=False,
                                       only_best=True)
    return np.asarray(transformer.transform(np.asarray(lon), np.asarray(lat), np.asarray(h))[2])


def _opk_enu(table):
    """ω, φ, κ [deg] of the camera in local east-north-up, from the table's yaw/pitch/roll by scipy."""
    C_c_n = Rotation.from_euler("ZYX", table[["yaw", "pitch", "roll"]].to_numpy(), degrees=True).as_matrix()
    swap = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED->ENU, and image->camera axes
    return Rotation.from_matrix(swap @ C_c_n @ swap).as_euler("XYZ", degrees=True)


# ----------------------------------------------------------------------------------------- OpenDroneMap ---
def test_odm_geo_txt_read_by_odms_parser(tmp_path, ortho):
    path = write_export(ortho.table, tmp_path / "geo.txt", "odm", frames=ortho.frames)
    geo = OdmGeoFile(path)
    assert geo.raw_srs == "EPSG:3765"
    rows = _stations(ortho.table)
    assert list(geo.entries) == rows["image"].tolist()  # matched by file name
    entries = list(geo.entries.values())
    np.testing.assert_allclose([e.x for e in entries], rows["lon"], atol=1e-8)
    np.testing.assert_allclose([e.y for e in entries], rows["lat"], atol=1e-8)
    np.testing.assert_allclose([e.z for e in entries], _egm96(rows["lat"], rows["lon"], rows["height"]), atol=0.01)
    # nan angles are "absent" for ODM (PR #1476): no omega/phi/kappa reach OpenSfM, EXIF orientation is kept
    assert all(e.yaw is None and e.pitch is None and e.roll is None for e in entries)
    assert all(odm_compute_opk(e) is None for e in entries)
    # accuracies: per-axis sigma (OpenSfM's GPS dop), not hypot
    sigma = np.sqrt((rows["sigma_n"] ** 2 + rows["sigma_e"] ** 2) / 2)
    np.testing.assert_allclose([e.horizontal_accuracy for e in entries], sigma, rtol=2e-3, atol=1e-4)
    np.testing.assert_allclose([e.vertical_accuracy for e in entries], rows["sigma_u"], atol=1e-4)


def test_odm_rejects_the_old_header_and_accepts_ours():
    with pytest.raises(RuntimeError, match="Bad SRS"):
        odm_parse_srs_header("3765")  # what --crs 3765 used to write
    assert odm_parse_srs_header("EPSG:3765").to_epsg() == 3765


def test_odm_angles_are_odms_definition_and_why_they_are_not_written(tmp_path, ortho):
    """With ``odm_angles`` the file carries the camera's yaw/pitch/roll. ODM's own formula with the frame fixed
    reproduces the camera's true ω, φ, κ (so they are ODM's definition); ODM 3.6's formula turns them into a κ
    wrong by about 90° + longitude (nadir: exactly; banked: a few degrees more) — hence nan by default
    (docs/formats.md)."""
    path = write_export(ortho.table, tmp_path / "geo.txt", "odm", frames=ortho.frames, odm_angles=True)
    entries = list(OdmGeoFile(path).entries.values())
    rows = _stations(ortho.table)
    truth = _opk_enu(rows)
    fixed = np.array([odm_compute_opk(e, fixed_frame=True) for e in entries])
    np.testing.assert_allclose(fixed, truth, atol=2e-5)
    odm36 = np.array([odm_compute_opk(e) for e in entries])
    kappa_error = (odm36[:, 2] - truth[:, 2] + 180.0) % 360.0 - 180.0
    deviation = np.abs(kappa_error - (90.0 + rows["lon"].to_numpy()))
    # measured on data/: median 0.015 deg, up to 3.2 deg in the banked turns (ODM's frame also mixes tilt)
    assert np.median(deviation) < 0.1 and deviation.max() < 5.0, (np.median(deviation), deviation.max())
    wrong = Rotation.from_euler("XYZ", odm36, degrees=True) * Rotation.from_euler("XYZ", truth, degrees=True).inv()
    assert np.all(np.degrees(wrong.magnitude()) > 100.0)  # every camera turned by more than 100 deg


# ----------------------------------------------------------------------------------------------- PIX4D ---
def _read_pix4d(path):
    """PIX4Dmatic "image geolocation and orientation" import: comma separated, 7 or 9 columns, an optional first
    line starting with '#', no header; coordinates in the order of the CRS's axes."""
    lines = Path(path).read_text().splitlines()
    assert lines[0].startswith("#")
    rows = [line.split(",") for line in lines[1:]]
    assert all(len(r) == 9 for r in rows)
    return [r[0] for r in rows], np.array([[float(v) for v in r[1:]] for r in rows])


@pytest.mark.parametrize("which", ["ortho", "sweref"])
def test_pix4d_coordinates_in_the_crs_axis_order(tmp_path, which, request):
    result = request.getfixturevalue(which)
    path = write_export(result.table, tmp_path / "p4d.csv", "pix4d", frames=result.frames)
    names, values = _read_pix4d(path)
    rows = _stations(result.table)
    assert names == (rows["image"] if "image" in rows else rows["frame"]).tolist()
    crs = CRS.from_user_input(result.frames.horizontal_name)
    # the CRS's own axis order in, latitude/longitude (EPSG:4326's order) out: no always_xy
    lat, lon = Transformer.from_crs(crs, "EPSG:4326").transform(values[:, 0], values[:, 1])
    np.testing.assert_allclose(lat, rows["lat"], atol=1e-8)
    np.testing.assert_allclose(lon, rows["lon"], atol=1e-8)
    expected_z = _egm96(rows["lat"], rows["lon"], rows["height"]) if which == "ortho" else rows["height"]
    np.testing.assert_allclose(values[:, 2], expected_z, atol=0.01)
    if which == "sweref":
        assert crs.axis_info[0].direction == "north" and np.all(values[:, 0] > 4e6)  # northing first


def test_pix4d_angles_and_accuracies_in_pix4ds_definitions(tmp_path, ortho):
    """Yaw/pitch/roll (Pix4D: yaw 0 = top of image north, pitch 0 = nadir, C = Rz(yaw) Ry(pitch) Rx(roll) of the
    camera body x = top of image, z = viewing direction) turned into ω, φ, κ as Pix4D documents, then rotated by
    PROJ's meridian convergence, give the table's grid ω, φ, κ; accuracies are per-axis sigmas."""
    path = write_export(ortho.table, tmp_path / "p4d.csv", "pix4d", frames=ortho.frames)
    _, values = _read_pix4d(path)
    rows = _stations(ortho.table)
    C = Rotation.from_euler("ZYX", values[:, [3, 4, 5]], degrees=True).as_matrix()  # yaw, pitch, roll columns
    swap = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    factors = CRS("EPSG:3765")
    from pyproj import Proj

    gamma = np.radians(Proj(factors).get_factors(rows["lon"].to_numpy(), rows["lat"].to_numpy()).meridian_convergence)
    to_grid = Rotation.from_rotvec(np.outer(gamma, [0.0, 0.0, 1.0])).as_matrix()  # true az a -> grid az a - gamma
    opk = Rotation.from_matrix(to_grid @ swap @ C @ swap).as_euler("XYZ", degrees=True)
    np.testing.assert_allclose(opk, rows[["omega", "phi", "kappa"]].to_numpy(), atol=2e-5)
    # sigma of the normal distribution per axis (Pix4D FAQ on the accurate geolocation pipeline)
    per_axis = np.sqrt((rows["sigma_n"] ** 2 + rows["sigma_e"] ** 2) / 2)
    np.testing.assert_allclose(values[:, 6], per_axis, rtol=2e-3, atol=1e-4)
    assert np.all(values[:, 6] < 0.8 * np.hypot(rows["sigma_n"], rows["sigma_e"]))
    np.testing.assert_allclose(values[:, 7], rows["sigma_u"], atol=1e-4)


# ------------------------------------------------------------------------------------------- Metashape ---
def test_metashape_reference_columns(tmp_path, ortho):
    """Import Reference: '#' lines skipped, columns assigned by number; x/y easting/northing of the CRS, z the
    chosen heights, ω, φ, κ and their accuracies each in its own column."""
    path = write_export(ortho.table, tmp_path / "ms.csv", "metashape", frames=ortho.frames)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#") and "EPSG:3765" in lines[0] and "EGM96" in lines[0]
    names = lines[0].split(": ")[1].split(",")
    back = pd.read_csv(path, comment="#", header=None, names=names, dtype={"label": str})
    rows = _stations(ortho.table)
    assert back["label"].tolist() == rows["image"].tolist()
    lon, lat = Transformer.from_crs("EPSG:3765", "EPSG:4326", always_xy=True).transform(back["x"], back["y"])
    np.testing.assert_allclose(lat, rows["lat"], atol=1e-8)
    np.testing.assert_allclose(lon, rows["lon"], atol=1e-8)
    np.testing.assert_allclose(back["z"], _egm96(rows["lat"], rows["lon"], rows["height"]), atol=0.01)
    np.testing.assert_allclose(back[["omega", "phi", "kappa"]], rows[["omega", "phi", "kappa"]], atol=1e-6)
    for column, source in (("x_accuracy", "sigma_x"), ("y_accuracy", "sigma_y"), ("z_accuracy", "sigma_u"),
                           ("omega_accuracy", "sigma_omega"), ("phi_accuracy", "sigma_phi"),
                           ("kappa_accuracy", "sigma_kappa")):
        np.testing.assert_allclose(back[column], rows[source], atol=1e-4, err_msg=column)
    # omega and phi sigmas are not the roll and pitch sigmas once the line is not east-west
    assert not np.allclose(back["omega_accuracy"], rows["sigma_roll"], atol=1e-4)


# -------------------------------------------------------------------------------------- KML and GeoJSON ---
def _ogr_points(path):
    """(driver, names, x, y, z) of the point features, read by GDAL/OGR (pyogrio's bundled GDAL)."""
    import pyogrio
    from pyogrio.raw import read

    info = pyogrio.read_info(path)
    meta, _, geometry, fields = read(path)
    names = fields[list(meta["fields"]).index("Name")] if "Name" in meta["fields"] else None
    xyz = []
    for wkb in geometry:
        order = "<" if wkb[0] == 1 else ">"
        kind = struct.unpack(order + "I", wkb[1:5])[0]
        assert kind in (1001, 0x80000001), kind  # Point Z
        xyz.append(struct.unpack(order + "3d", wkb[5:29]))
    xyz = np.array(xyz)
    return info["driver"], names, xyz[:, 0], xyz[:, 1], xyz[:, 2]


def test_kml_read_by_ogr_and_fastkml_at_sea_level_heights(tmp_path, ortho):
    path = write_export(ortho.table, tmp_path / "stations.kml", "kml", frames=ortho.frames)
    rows = _stations(ortho.table)
    expected = _egm96(rows["lat"], rows["lon"], rows["height"])
    driver, names, x, y, z = _ogr_points(path)
    assert driver in ("LIBKML", "KML")
    assert list(names) == rows["image"].tolist()
    np.testing.assert_allclose(x, rows["lon"], atol=1e-9)
    np.testing.assert_allclose(y, rows["lat"], atol=1e-9)
    np.testing.assert_allclose(z, expected, atol=0.01)  # above sea level: about 44 m below the ellipsoidal height
    assert np.all(np.abs(rows["height"] - z - 44.0) < 1.5)

    from fastkml import kml
    from fastkml.enums import AltitudeMode

    document = kml.KML.parse(path)
    placemarks = list(document.features[0].features)
    assert [p.name for p in placemarks] == rows["image"].tolist()
    first = placemarks[0]
    assert first.kml_geometry.altitude_mode == AltitudeMode.absolute
    assert first.geometry.z == pytest.approx(expected[0], abs=0.01)


def test_kml_heights_do_not_depend_on_the_height_option(tmp_path, sweref):
    """Ellipsoidal runs too: KML's absolute altitude is above sea level, whatever the other exports carry."""
    path = write_export(sweref.table, tmp_path / "stations.kml", "kml", frames=sweref.frames)
    rows = _stations(sweref.table)
    *_, z = _ogr_points(path)
    np.testing.assert_allclose(z, _egm96(rows["lat"], rows["lon"], rows["height"]), atol=0.01)


def test_geojson_rfc7946_read_by_ogr(tmp_path, ortho):
    path = write_export(ortho.table, tmp_path / "stations.geojson", "geojson", frames=ortho.frames)

    def no_constants(token):
        raise AssertionError(f"{token} is not JSON (RFC 8259)")

    doc = json.loads(path.read_text(), parse_constant=no_constants)
    assert doc["type"] == "FeatureCollection" and "crs" not in doc  # RFC 7946: no crs member, WGS 84 lon/lat
    rows = _stations(ortho.table)
    driver, _, x, y, z = _ogr_points(path)
    assert driver == "GeoJSON"
    np.testing.assert_allclose(x, rows["lon"], atol=1e-9)
    np.testing.assert_allclose(y, rows["lat"], atol=1e-9)
    np.testing.assert_allclose(z, rows["height"], atol=1e-4)  # RFC 7946 §4: height above the WGS 84 ellipsoid
    assert doc["features"][0]["properties"]["image"] == rows["image"].iloc[0]


@pytest.mark.parametrize("fmt", ["geojson", "kml"])
def test_every_column_reaches_ogr_as_a_field(tmp_path, ortho, fmt):
    """GDAL/OGR (pyogrio) reads every column of every station back as a field of its feature. GeoJSON properties
    are typed by OGR's own inference: numbers as Real, equal to the table's to the last bit; ids and flags as
    String (so a frame id keeps its leading zeros). KML ExtendedData is untyped: OGR's text parses back to the
    same floats."""
    from pyogrio.raw import read

    path = write_export(ortho.table, tmp_path / f"stations.{fmt}", fmt, frames=ortho.frames)
    meta, _, _, values = read(path)
    fields = dict(zip(meta["fields"], values, strict=True))
    rows = _stations(ortho.table)
    assert set(rows.columns) <= set(fields), set(rows.columns) - set(fields)
    for column in rows.columns:
        got, expected = fields[column], rows[column]
        if expected.dtype.kind == "f":
            if fmt == "kml":
                assert got.dtype == object, column
                got = np.array([float(v) if v else np.nan for v in got])
            else:
                assert got.dtype.kind == "f", (column, got.dtype)
            np.testing.assert_array_equal(got, expected.to_numpy(float), err_msg=column)
        else:
            assert got.dtype == object, (column, got.dtype)
            assert [v or "" for v in got] == expected.astype(str).tolist(), column


def test_parge_keeps_every_frame(tmp_path, ortho):
    path = write_export(ortho.table, tmp_path / "parge.txt", "parge")
    back = pd.read_csv(path, sep="\t", dtype={"frame": str, "flag": str}, keep_default_na=False,
                       na_values={"lat": [""], "lon": [""], "height": [""], "yaw_minus_track": [""]})
    assert len(back) == len(ortho.table)  # every frame, flagged ones included
    np.testing.assert_allclose(back["yaw_minus_track"].astype(float), ortho.table["yaw_minus_track"], atol=1e-6)


# --------------------------------------------------------------------------------------------- heights ---
def test_the_egm96_grid_is_installed():
    """Orthometric heights and KML need PROJ's EGM96 grid (Debian proj-data, `make geoid`): this fails, never
    skips, when it is missing (CI installs it)."""
    try:
        frames = OutputFrames(height="orthometric")
    except GeoidGridError as exc:
        pytest.fail(f"the EGM96 grid is missing: {exc}. Run `make geoid` (apt-get install proj-data).")
    assert "WGS 84 to EGM96 height" in str(frames.describe()[0])


def test_orthometric_heights_agree_with_proj(ortho):
    rows = _stations(ortho.table)
    expected = _egm96(rows["lat"], rows["lon"], rows["height"])
    assert np.max(np.abs(rows["height_orthometric"] - expected)) < 0.01
    summary = ortho.summary()
    assert summary["output_heights"] == "EGM96 height"
    assert any("Inverse of HTRS96 to WGS 84 (1)" in t and "1 m" in t for t in summary["proj_transformations"])
    assert summary["proj_accuracy_m"] >= 1.0
    assert any("do not include it" in w for w in summary["geodesy_warnings"])


def test_compound_crs_heights():
    lat, lon, h = np.array([44.05, 45.8]), np.array([15.62, 15.9]), np.array([760.0, 300.0])
    compound = OutputFrames("EPSG:3765+5773", "orthometric")
    assert compound.horizontal_name == "EPSG:3765" and compound.height_name == "EGM96 height"
    independent = Transformer.from_crs("EPSG:4979", "EPSG:3765+5773", always_xy=True, only_best=True)
    np.testing.assert_allclose(compound.output_heights(lat, lon, h), independent.transform(lon, lat, h)[2],
                               atol=0.01)
    with pytest.raises(GeoidGridError, match="HVRS71"):  # no grid here: refused, never a ballpark 44 m off
        OutputFrames("EPSG:3765+5610", "orthometric")
    with pytest.raises(ValueError, match="--height orthometric"):
        OutputFrames("EPSG:3765+5773", "ellipsoidal")


# ----------------------------------------------------------------------------------------- image names ---
def test_image_names_pattern_and_table(tmp_path):
    assert ImageNames.parse(PATTERN).names(["7", "0012", "A3"][:2]) == ["IMG_0007.JPG", "IMG_0012.JPG"]
    with pytest.raises(GeorefError, match="A3"):
        ImageNames.parse(PATTERN).names(["A3"])  # :04d cannot format text: the frame is named
    with pytest.raises(GeorefError, match="frame"):
        ImageNames.parse("IMG_{number}.JPG")
    table = tmp_path / "names.csv"
    table.write_text("\ufeffframe,name\n1,DSC00481.JPG\n0002,DSC00482.JPG\n")
    names = ImageNames.parse(str(table))
    assert names.names(["1", "2"]) == ["DSC00481.JPG", "DSC00482.JPG"]
    with pytest.raises(GeorefError, match=r"frame\(s\) 3 "):
        names.names(["1", "2", "3"])
    table.write_text("1,a.jpg\n2,a.jpg\n")
    with pytest.raises(GeorefError, match="line 2.*'a.jpg'.*line 1"):
        ImageNames.parse(str(table))
    table.write_text("1,a.jpg\n2\n")
    with pytest.raises(GeorefError, match="line 2"):
        ImageNames.parse(str(table))


def test_exports_made_with_image_names_carry_them(tmp_path):
    """Done-when: Metashape, Pix4D and ODM files made with --image-names carry the right names."""
    frames = pd.read_csv(DATA / "Kamera.txt", sep="\t", dtype={"Number": str})["Number"]
    mapping = {f: f"flight7_{int(f) * 3 + 100}.tif" for f in frames}
    names = tmp_path / "names.csv"
    names.write_text("".join(f"{f};{n}\n" for f, n in mapping.items()))
    result = CliRunner().invoke(app, [
        "process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"),
        "-o", str(tmp_path / "eo.csv"), "--image-names", str(names), "--export", f"metashape:{tmp_path / 'ms.csv'}",
        "--export", f"pix4d:{tmp_path / 'p4d.csv'}", "--export", str(tmp_path / "geo.txt"), "-q"])
    assert result.exit_code == 0, result.output
    eo = pd.read_csv(tmp_path / "eo.csv", dtype={"frame": str})
    assert eo["image"].tolist() == [mapping[f] for f in eo["frame"]]
    stations = eo[eo["lat"].notna()]
    expected = [mapping[f] for f in stations["frame"]]
    assert list(OdmGeoFile(tmp_path / "geo.txt").entries) == expected
    assert _read_pix4d(tmp_path / "p4d.csv")[0] == expected
    ms = pd.read_csv(tmp_path / "ms.csv", comment="#", header=None, dtype={0: str})
    assert ms[0].tolist() == expected


def test_a_frame_without_a_name_fails_before_processing(tmp_path):
    names = tmp_path / "names.csv"
    names.write_text("1,a.jpg\n2,b.jpg\n")
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"),
                                      "-o", str(tmp_path / "eo.csv"), "--image-names", str(names), "-q"])
    assert result.exit_code == 2 and "no image name for frame(s) 3, 4" in result.output
    assert not (tmp_path / "eo.csv").exists()


# ------------------------------------------------------------------------------------------------- CLI ---
def test_several_outputs_in_one_run_format_from_the_extension(tmp_path):
    result = CliRunner().invoke(app, [
        "process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"),
        "-o", str(tmp_path / "stations.kml"), "--export", str(tmp_path / "eo.csv"),
        "--export", str(tmp_path / "stations.geojson"), "--export", f"odm:{tmp_path / 'odm.txt'}", "-q"])
    assert result.exit_code == 0, result.output
    assert _ogr_points(tmp_path / "stations.kml")[0] in ("LIBKML", "KML")
    assert _ogr_points(tmp_path / "stations.geojson")[0] == "GeoJSON"
    assert pd.read_csv(tmp_path / "eo.csv").columns[0] == "frame"
    assert OdmGeoFile(tmp_path / "odm.txt").raw_srs == "EPSG:3765"


@pytest.mark.parametrize(("args", "message"), [
    (["--format", "metashape"], "needs -o FILE"),  # used to write Metashape content into eo.csv
    (["--export", "shapefile:x.shp"], "unknown format 'shapefile'"),
    (["--export", "stations.txt"], "cannot tell the format"),
    (["-o", "{tmp}/p.txt", "--format", "pix4d"], "--crs"),
    (["-o", "{tmp}/a.csv", "--export", "{tmp}/a.csv"], "asked for twice"),
    (["--crs", "EPSG:3765+5610", "--height", "orthometric", "-o", "{tmp}/eo.csv"], "HVRS71"),
    (["--image-names", "IMG_{nr}.JPG", "-o", "{tmp}/eo.csv"], "{frame}"),
])
def test_outputs_are_checked_before_processing(tmp_path, args, message):
    """Exit 2 with the message before anything is read: the POS log given does not even exist."""
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    result = CliRunner().invoke(app, ["process", str(tmp_path / "missing_POS.txt"), str(DATA / "Kamera.txt"),
                                      *args, "-q"])
    assert result.exit_code == 2, result.output
    assert message in result.output, result.output
    assert "missing_POS" not in result.output
    assert not any(tmp_path.iterdir())


def test_output_settings_in_flight_toml(tmp_path):
    (tmp_path / "flight.toml").write_text('[output]\ncrs = "EPSG:3765+5773"\nheight = "orthometric"\n'
                                          'image_names = "names.csv"\nodm_angles = true\n')
    cfg = load_config(tmp_path / "flight.toml")
    assert cfg.output.image_names == str(tmp_path / "names.csv")  # beside flight.toml, wherever georef runs
    assert (cfg.output.crs, cfg.output.height, cfg.output.odm_angles) == ("EPSG:3765+5773", "orthometric", True)
    (tmp_path / "flight.toml").write_text('[output]\nheight = "geoid"\n')
    with pytest.raises(GeorefError, match="height"):
        load_config(tmp_path / "flight.toml")


def test_export_specs():
    assert parse_export("metashape:ms.csv").fmt == "metashape"
    assert parse_export("stations.kml").fmt == "kml"
    assert parse_export("out/geo.txt").fmt == "odm"
    with pytest.raises(ExportError):
        parse_export("kml:")
    assert set(FORMATS) == {"csv", "metashape", "pix4d", "odm", "parge", "geojson", "kml", "sbet"}
