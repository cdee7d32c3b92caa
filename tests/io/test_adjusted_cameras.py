"""georef's adjusted-camera readers on files written by the photogrammetry programs themselves.

The samples and their sources and licences are listed in ``tests/data/adjusted_cameras/README.md``. Each test reads
a sample with georef's reader and compares it with the file's text read independently here (regular expressions on
the raw text, scipy for the angle-axis rotation, pyproj for the projection), value by value.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from georef.io.adjusted_cameras import read_adjusted_cameras
from georef.io.errors import InputError

DATA = Path(__file__).parents[1] / "data" / "adjusted_cameras"
# ODM 2.x output of an underwater GoPro survey without GPS (terra-submersa/odm-report-shot-coverage, MIT).
ODM_PSEUDO = DATA / "odm_shots_pseudogeo.geojson"
# ODM's pseudo-georeference (opendm/pseudogeo.py): UTM zone 30 north, WGS84, scale 0.1 -> geometry = 1/0.1**2 = 100
# times the local frame plus the centre of the pseudo-georeferenced orthophoto.
PSEUDO_UTM = "EPSG:32630"
PSEUDO_FACTOR = 100.0


def _features_from_text(text: str) -> list[dict]:
    """Filename, translation, rotation and geometry of each feature, read from the raw text without json: the
    reference the reader is compared with."""
    number = r"(-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)"
    triple = rf"\[\s*{number},\s*{number},\s*{number}\s*\]"
    pattern = re.compile(rf'"filename": "([^"]+)".*?"translation": {triple},\s*"rotation": {triple}.*?'
                         rf'"coordinates": {triple}', re.S)
    rows = []
    for match in pattern.finditer(text):
        values = [float(v) for v in match.groups()[1:]]
        rows.append({"filename": match.group(1), "translation": values[0:3], "rotation": values[3:6],
                     "geometry": values[6:9]})
    return rows


def _without_geometry(tmp_path: Path) -> Path:
    """The sample with its geometries removed (the reader then cannot check the CRS and reads the properties)."""
    document = json.loads(ODM_PSEUDO.read_text())
    for feature in document["features"]:
        del feature["geometry"]
    path = tmp_path / "shots.geojson"
    path.write_text(json.dumps(document, indent=2))
    return path


def test_odm_sample_is_pseudo_georeferenced():
    """The sample is what its README says: geometry (WGS84 lon/lat) is ODM's pseudo UTM-30 image of 100 times the
    translation plus one constant offset, and the same height; so the translation is a local frame, not a CRS."""
    rows = _features_from_text(ODM_PSEUDO.read_text())
    assert len(rows) == 6
    to_utm = Transformer.from_crs("EPSG:4326", PSEUDO_UTM, always_xy=True)
    offsets = []
    for row in rows:
        easting, northing = to_utm.transform(row["geometry"][0], row["geometry"][1])
        offsets.append([easting - PSEUDO_FACTOR * row["translation"][0],
                        northing - PSEUDO_FACTOR * row["translation"][1]])
        assert row["geometry"][2] == row["translation"][2]
    offsets = np.array(offsets)
    np.testing.assert_allclose(offsets, np.broadcast_to(offsets[0], offsets.shape), atol=1e-3)


def test_reader_refuses_pseudo_georeferenced_odm():
    """A real pseudo-georeferenced shots.geojson is refused, naming the feature whose geometry shows it, instead of
    being read as map coordinates."""
    rows = _features_from_text(ODM_PSEUDO.read_text())
    translation = np.array([r["translation"] for r in rows])
    far = int(np.argmax(np.hypot(*(translation[:, :2] - translation[0, :2]).T)))
    with pytest.raises(InputError) as caught:
        read_adjusted_cameras(ODM_PSEUDO)
    message = str(caught.value)
    assert f"features[{far}].geometry" in message
    assert "pseudo-georeferenced" in message
    ratio = float(re.search(r"but ([0-9.]+) times", message).group(1))
    # 100 divided by the UTM point scale factor near longitude -7.5 in zone 30 (~1.0027)
    assert ratio == pytest.approx(PSEUDO_FACTOR, rel=0.01)


def test_odm_properties_read_value_by_value(tmp_path):
    """Labels, camera centres and rotations of the real file (geometry removed) against its text: translation as
    given; rotation ``R_i_m = Rᵀ diag(1, -1, -1)`` with ``R`` the angle-axis world-to-camera rotation (OpenSfM,
    scipy here)."""
    rows = _features_from_text(ODM_PSEUDO.read_text())
    cameras = read_adjusted_cameras(_without_geometry(tmp_path))
    assert cameras.fmt == "odm"
    assert cameras.label == [r["filename"] for r in rows]
    assert cameras.line == list(range(1, len(rows) + 1))
    translation = np.array([r["translation"] for r in rows])
    np.testing.assert_array_equal(cameras.easting, translation[:, 0])
    np.testing.assert_array_equal(cameras.northing, translation[:, 1])
    np.testing.assert_array_equal(cameras.height, translation[:, 2])
    R_world_to_camera = Rotation.from_rotvec([r["rotation"] for r in rows]).as_matrix()
    expected = np.swapaxes(R_world_to_camera, 1, 2) @ np.diag([1.0, -1.0, -1.0])
    np.testing.assert_allclose(cameras.R_i_m, expected, atol=1e-12)
    assert cameras.sigma_position is None and cameras.sigma_angles is None


def test_odm_real_cameras_look_down(tmp_path):
    """The survey was shot from above (the source's README): every camera's image z axis (opposite to the viewing
    direction) is within 30 deg of the frame's up axis. Dropping the diag(1, -1, -1) turns it down (>150 deg)."""
    cameras = read_adjusted_cameras(_without_geometry(tmp_path))
    tilt_deg = np.degrees(np.arccos(np.clip(cameras.R_i_m[:, 2, 2], -1.0, 1.0)))
    assert np.all(tilt_deg < 30.0), tilt_deg


def test_odm_georeferenced_layout_is_accepted(tmp_path):
    """The same cameras laid out as ODM writes a georeferenced block (translation = local centre + UTM offset,
    geometry = that point in WGS84) pass the CRS check and read back unchanged."""
    document = json.loads(ODM_PSEUDO.read_text())
    crs = "EPSG:32633"
    to_geographic = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    for feature in document["features"]:
        local = feature["properties"]["translation"]
        utm = [local[0] + 433210.0, local[1] + 5123456.0, local[2] + 212.0]
        feature["properties"]["translation"] = utm
        lon, lat = to_geographic.transform(utm[0], utm[1])
        feature["geometry"]["coordinates"] = [lon, lat, utm[2]]
    path = tmp_path / "shots.geojson"
    path.write_text(json.dumps(document))
    cameras = read_adjusted_cameras(path)
    np.testing.assert_array_equal(cameras.easting, [f["properties"]["translation"][0] for f in document["features"]])
    np.testing.assert_array_equal(cameras.northing, [f["properties"]["translation"][1] for f in document["features"]])


def test_metashape_omega_phi_kappa_export_layout(tmp_path):
    """Metashape's "Omega Phi Kappa (*.txt)" camera export, as third-party readers describe it (no real file with a
    licence was found: tests/data/adjusted_cameras/README.md): a '# Cameras (n)' line, a comma-separated
    '# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11, ..., r33' header, tab-separated rows. The reader refused it ("no
    header line naming the columns"); now labels (one with a space), positions and angles read as written."""
    from georef.frames.photogrammetry import opk_to_rotation

    rows = [("DSC 0001.JPG", 430611.9777, 4879746.0978, 759.307, -1.79086, -0.286581, 158.332568),
            ("DSC_0002.JPG", 430612.5, 4879750.25, 759.4, 0.5, 0.25, -21.8)]
    text = ["# Cameras (2)", "# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11, r12, r13, r21, r22, r23, r31, r32, r33"]
    for label, *values in rows:
        matrix = np.eye(3).ravel()  # the r columns are not read; what they hold is not checked here
        text.append("\t".join([label, *(f"{v}" for v in values), *(f"{m:.6f}" for m in matrix)]))
    path = tmp_path / "cameras_opk.txt"
    path.write_text("\n".join(text) + "\n")
    cams = read_adjusted_cameras(path, "metashape")
    assert cams.label == [r[0] for r in rows] and cams.line == [3, 4]
    np.testing.assert_array_equal(cams.easting, [r[1] for r in rows])
    np.testing.assert_array_equal(cams.northing, [r[2] for r in rows])
    np.testing.assert_array_equal(cams.height, [r[3] for r in rows])
    angles = np.radians([r[4:] for r in rows])
    np.testing.assert_allclose(cams.R_i_m, opk_to_rotation(angles[:, 0], angles[:, 1], angles[:, 2]), atol=1e-15)
