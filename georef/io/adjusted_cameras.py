"""Readers of cameras adjusted by a photogrammetric block (bundle adjustment with ground control).

Every reader returns :class:`AdjustedCameras`: one row per camera with its label, its perspective centre in the
projected CRS the block was adjusted in (easting, northing [grid m], height [m] in the block's vertical datum) and
its rotation ``R_i_m`` (image frame to the mapping frame, :mod:`georef.frames.photogrammetry`). ``docs/boresight.md``
lists the formats, their angle conventions and what was checked.

* ``metashape`` — Agisoft Metashape's camera export from the Reference pane (CSV; a ``#Label,...`` header line,
  comma, tab or semicolon separated): label, ``X``/``Easting``, ``Y``/``Northing``, ``Z``/``Altitude`` and
  ``Omega, Phi, Kappa`` [deg]; the estimated (adjusted) columns ``X_est ... Kappa_est`` are preferred when the
  export has them, and ``*_accuracy`` columns are read as the block's sigmas. georef's own ``--format metashape``
  table reads too. Yaw/pitch/roll exports are refused (their reference frame in a projected CRS is not georef's:
  export with rotation angles set to omega, phi, kappa).
* ``pix4d`` — Pix4D's ``*_calibrated_external_camera_parameters.txt``: a header ``imageName X Y Z Omega Phi
  Kappa``, then one whitespace-separated row per camera, angles in degrees (the same ω, φ, κ as Metashape's).
* ``odm`` — OpenDroneMap's ``odm_report/shots.geojson`` (ODM ``opendm/shots.py``): per feature
  ``properties.filename``, ``properties.translation`` (the camera centre in the UTM CRS of the reconstruction,
  offset added back) and ``properties.rotation`` (OpenSfM's angle-axis world-to-camera rotation, world = grid E, N,
  up; camera x right, y down, z into the scene). ``cameras.json`` holds only the interior orientation, so it cannot
  be used.
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from georef.frames.calibration import opensfm_to_image_map
from georef.frames.earth import geodetic_to_ecef
from georef.frames.photogrammetry import opk_to_rotation
from georef.io.errors import InputError

FORMATS = ("metashape", "pix4d", "odm")


@dataclass
class AdjustedCameras:
    """Adjusted cameras of a block: ``label`` (image names), ``line`` (1-based line or feature number in the file),
    ``easting``, ``northing`` [grid m], ``height`` [m], ``R_i_m`` (n, 3, 3); ``sigma_position`` (n, 3) [m] and
    ``sigma_angles`` (n, 3) [deg, ω φ κ] when the file gives the block's accuracies (else None)."""

    path: Path
    fmt: str
    label: list[str]
    line: list[int]
    easting: np.ndarray
    northing: np.ndarray
    height: np.ndarray
    R_i_m: np.ndarray
    sigma_position: np.ndarray | None = None
    sigma_angles: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.label)


def format_of_file(path: Path, fmt: str | None) -> str:
    """The format named, else guessed from the name (``.geojson``/``.json``: odm; ``calibrated_external``: pix4d;
    else metashape)."""
    if fmt:
        if fmt not in FORMATS:
            raise InputError(path, None, None, f"unknown adjusted-camera format {fmt!r}; use one of "
                             f"{', '.join(FORMATS)}")
        return fmt
    name = path.name.lower()
    if name.endswith((".geojson", ".json")):
        return "odm"
    if "calibrated_external" in name:
        return "pix4d"
    return "metashape"


def read_adjusted_cameras(path: Path | str, fmt: str | None = None) -> AdjustedCameras:
    """Read ``path`` in ``fmt`` (``metashape``, ``pix4d``, ``odm``; None: from the file name)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, None, "adjusted-camera file not found")
    fmt = format_of_file(path, fmt)
    text = path.read_text(encoding="utf-8-sig", errors="replace")
    cameras = _read_odm(path, text) if fmt == "odm" else _read_table(path, text, fmt)
    if not len(cameras):
        raise InputError(path, None, None, f"no cameras in this {fmt} file")
    seen: dict[str, int] = {}
    for label, line in zip(cameras.label, cameras.line, strict=True):
        if label in seen:
            raise InputError(path, line, None, f"camera {label!r} appears twice (first on line {seen[label]})")
        seen[label] = line
    return cameras


#: header names of the camera label column (``PhotoID``: Metashape's "Omega Phi Kappa" camera export)
_LABEL_NAMES = ("label", "imagename", "name", "image", "camera", "filename", "photoid")


def _normal(name: str) -> str:
    """A header cell as a key: lower case, no ``#``, spaces or bracketed units (``X/Easting`` -> ``x``)."""
    name = re.sub(r"\(.*?\)", "", name.strip().lstrip("#").strip().lower()).replace(" ", "")
    first = name.split("/")[0]
    if first in _LABEL_NAMES:
        return "label"
    return {"easting": "x", "northing": "y", "altitude": "z"}.get(first, first)


def _header_and_rows(path: Path, text: str, fmt: str) -> tuple[list[str], int, list[tuple[int, list[str]]]]:
    lines = text.splitlines()
    header_line = None
    for number, line in enumerate(lines, 1):
        first = re.split(r"[,\t;\s]+", line.strip().lstrip("#").strip(), maxsplit=1)[0]
        if first and _normal(first) == "label":
            header_line = number
            break
        if line.strip() and not line.lstrip().startswith("#"):
            break
    if header_line is None:
        raise InputError(path, 1, None, f"no header line naming the columns (e.g. '#Label,X,Y,Z,Omega,Phi,Kappa' "
                         f"or 'imageName X Y Z Omega Phi Kappa') before the first {fmt} row")
    header = lines[header_line - 1]
    if fmt == "pix4d" or ("," not in header and "\t" not in header and ";" not in header):
        split = str.split
        cells = header.lstrip("#").split()
    else:
        delimiter = max((",", "\t", ";"), key=header.count)
        cells = next(csv.reader(io.StringIO(header.lstrip("#")), delimiter=delimiter))
        first_row = next((line for line in lines[header_line:] if line.strip() and not line.lstrip().startswith("#")),
                         "")
        if delimiter not in first_row:
            # Metashape's "Omega Phi Kappa" export: a comma-separated '# PhotoID, X, Y, ...' header over
            # tab-separated rows (a label may hold spaces: split on tabs where there are any)
            def split(row: str) -> list[str]:
                return [cell.strip() for cell in row.split("\t")] if "\t" in row else row.split()
        else:

            def split(row: str) -> list[str]:
                return next(csv.reader(io.StringIO(row), delimiter=delimiter), [])
    rows = [(number, split(line)) for number, line in enumerate(lines[header_line:], header_line + 1)
            if line.strip() and not line.lstrip().startswith("#")]
    return [_normal(c) for c in cells], header_line, rows


def _read_table(path: Path, text: str, fmt: str) -> AdjustedCameras:
    names, header_line, rows = _header_and_rows(path, text, fmt)
    index = {name: i for i, name in enumerate(names)}

    def pick(*choices: str) -> str | None:
        return next((c for c in choices if c in index), None)

    columns = {}
    for axis in ("x", "y", "z"):
        columns[axis] = pick(f"{axis}_est", axis)
    for angle in ("omega", "phi", "kappa"):
        columns[angle] = pick(f"{angle}_est", angle)
    if "label" not in index:
        raise InputError(path, header_line, None, "no label / image name column")
    missing = [axis.upper() for axis in ("x", "y", "z") if columns[axis] is None]
    if missing:
        raise InputError(path, header_line, None, f"no {', '.join(missing)} column; the cameras' positions in the "
                         "projected CRS are needed")
    if any(columns[a] is None for a in ("omega", "phi", "kappa")):
        if pick("yaw_est", "yaw") is not None:
            raise InputError(path, header_line, "Yaw", "yaw/pitch/roll angles are not read (their frame in a "
                             "projected CRS differs between programs); export omega, phi, kappa instead (Metashape: "
                             "Reference settings, rotation angles Omega, Phi, Kappa)")
        raise InputError(path, header_line, None, "no Omega, Phi, Kappa columns")
    sigma_pos = [pick(f"{a}_accuracy", f"accuracy_{a}") for a in ("x", "y", "z")]
    sigma_ang = [pick(f"{a}_accuracy", f"accuracy_{a}") for a in ("omega", "phi", "kappa")]
    labels, numbers, values, sig_p, sig_a = [], [], [], [], []
    wanted = [columns[k] for k in ("x", "y", "z", "omega", "phi", "kappa")]
    cell_names = {i: name for name, i in index.items()}
    for number, cells in rows:
        if len(cells) < len(names):
            raise InputError(path, number, None, f"{len(cells)} fields, the header names {len(names)}")
        labels.append(cells[index["label"]].strip())
        numbers.append(number)
        row = []
        for column in wanted:
            row.append(_number(path, number, cell_names[index[column]], cells[index[column]]))
        values.append(row)
        if all(c is not None for c in sigma_pos):
            sig_p.append([_number(path, number, c, cells[index[c]]) for c in sigma_pos])
        if all(c is not None for c in sigma_ang):
            sig_a.append([_number(path, number, c, cells[index[c]]) for c in sigma_ang])
    data = np.array(values, dtype=float).reshape(-1, 6)
    angles = np.radians(data[:, 3:])
    return AdjustedCameras(path, fmt, labels, numbers, data[:, 0], data[:, 1], data[:, 2],
                           opk_to_rotation(angles[:, 0], angles[:, 1], angles[:, 2]),
                           np.array(sig_p) if sig_p else None, np.array(sig_a) if sig_a else None)


def _number(path: Path, line: int, column: str, cell: str) -> float:
    try:
        value = float(cell)
    except ValueError:
        raise InputError(path, line, column, f"not a number: {cell.strip()[:40]!r}") from None
    if not np.isfinite(value):
        raise InputError(path, line, column, f"not a finite number: {cell.strip()!r}")
    return value


def _read_odm(path: Path, text: str) -> AdjustedCameras:
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, exc.lineno, None, f"not valid JSON: {exc.msg}") from None
    if not isinstance(document, dict) or not isinstance(document.get("features"), list):
        raise InputError(path, None, None, "not an ODM shots.geojson (a FeatureCollection with 'features'); "
                         "cameras.json holds only the interior orientation, reconstruction.json a local frame")
    labels, numbers, centre, rotation = [], [], [], []
    for k, feature in enumerate(document["features"]):
        properties = feature.get("properties") if isinstance(feature, dict) else None
        where = f"features[{k}].properties"
        if not isinstance(properties, dict):
            raise InputError(path, None, where, "missing")
        for key in ("filename", "translation", "rotation"):
            if key not in properties:
                raise InputError(path, None, f"{where}.{key}", "missing")
        for key in ("translation", "rotation"):
            value = properties[key]
            if not isinstance(value, list) or len(value) != 3 or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value):
                raise InputError(path, None, f"{where}.{key}", f"needs three finite numbers, got {value!r:.60}")
        labels.append(str(properties["filename"]))
        numbers.append(k + 1)
        centre.append(properties["translation"])
        rotation.append(properties["rotation"])
    centre_arr = np.array(centre, dtype=float).reshape(-1, 3)
    _check_odm_translation_is_map(path, document["features"], centre_arr)
    R_i_m = opensfm_to_image_map(np.array(rotation, dtype=float).reshape(-1, 3))
    return AdjustedCameras(path, "odm", labels, numbers, centre_arr[:, 0], centre_arr[:, 1], centre_arr[:, 2], R_i_m)


# Horizontal spread [m] of the translations below which the geometry check says nothing.
_ODM_MIN_SPREAD_M = 1.0
# A map CRS changes distances by its point scale factor (UTM: 0.9996 to ~1.001); a ratio outside this band means
# the translations are not in the CRS of the geometry.
_ODM_SCALE_BAND = (0.5, 2.0)


def _check_odm_translation_is_map(path: Path, features: list, centre: np.ndarray) -> None:
    """Refuse a shots.geojson whose ``translation`` is not in a map CRS.

    ODM writes ``geometry`` as the camera centre in WGS84 lon/lat. For a georeferenced reconstruction the
    horizontal distance between two cameras from their ``translation`` [grid m] equals the one from their
    ``geometry`` [m on the ellipsoid] times the CRS's point scale (~1). A reconstruction without GPS or GCPs is
    pseudo-georeferenced by ODM (``opendm/pseudogeo.py``: UTM zone 30, scale 0.1): ``translation`` stays in the
    local reconstruction frame and ``geometry`` is that frame scaled by 1/0.1² = 100 (a real ODM file,
    tests/data/adjusted_cameras/README.md), so the ratio is far from 1. Features without a Point geometry, or
    whose geometries all coincide (a placeholder), are not checked."""
    points = []
    for feature in features:
        geometry = feature.get("geometry") if isinstance(feature, dict) else None
        coords = geometry.get("coordinates") if isinstance(geometry, dict) and geometry.get("type") == "Point" else None
        if not isinstance(coords, list) or len(coords) < 2 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in coords[:2]):
            return
        points.append(coords[:2])
    lon_lat = np.radians(np.array(points, dtype=float))
    if len(lon_lat) < 2 or np.all(lon_lat == lon_lat[0]):
        return
    grid_spread = np.hypot(centre[:, 0] - centre[0, 0], centre[:, 1] - centre[0, 1])
    far = int(np.argmax(grid_spread))
    if grid_spread[far] < _ODM_MIN_SPREAD_M:
        return
    # Horizontal chord between the two cameras on the ellipsoid (heights 0): the geometry's distance [m].
    ends = geodetic_to_ecef(lon_lat[[0, far], 1], lon_lat[[0, far], 0], 0.0)
    ratio = float(np.linalg.norm(ends[1] - ends[0]) / grid_spread[far])
    if not _ODM_SCALE_BAND[0] <= ratio <= _ODM_SCALE_BAND[1]:
        raise InputError(path, None, f"features[{far}].geometry",
                         f"the cameras' 'translation' is not in a map CRS: the distance between features 0 and {far} "
                         f"is {grid_spread[far]:.3f} m from 'translation' but {ratio:.4g} times that from 'geometry' "
                         "(lon/lat). ODM writes this for a reconstruction it pseudo-georeferenced (no GPS in the "
                         "images and no GCPs): its cameras are in a local frame; georeference the block (geotagged "
                         "images or GCPs) and export again")
