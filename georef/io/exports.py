"""Exports of the EO table that photogrammetry and GIS software read (``--format``).

Each writer takes the EO table of :mod:`georef.eo` (degrees, metres) and writes atomically. Documentation
followed (checked 2026-11):

* ``metashape`` — a reference CSV for Agisoft Metashape's *Import Reference* (user manual 1.7-2.1,
  "Loading camera positions"/"Referencing"; the import dialog assigns columns by number and skips ``#``
  lines): label, projected X/Y/Z, omega/phi/kappa (choose *Rotation angles: Omega, Phi, Kappa* in the
  Reference settings) and their accuracies; a ``#`` comment line names the columns. Not checked against a
  running Metashape.
* ``pix4d`` — PIX4Dmapper's image geolocation and orientation file (Image Properties Editor > Image
  Geolocation > From File, "X, Y, Z, Omega, Phi, Kappa" with accuracies; Pix4D support articles "Input files -
  PIX4Dmapper" and "Image Geolocation - PIX4Dmapper"): ``imagename,X,Y,Z,omega,phi,kappa,accuracy_horz,
  accuracy_vert`` in projected coordinates, a ``#`` comment line first. PIX4Dmatic's own import format uses
  yaw/pitch/roll in a camera convention it defines differently; it is not written.
* ``odm`` — OpenDroneMap ``geo.txt`` (ODM docs, "Image Geolocation Files", ODM ≥ 2.0): the first line the
  projection (an EPSG code), then ``image_name geo_x geo_y geo_z yaw pitch roll horz_accuracy vert_accuracy``.
  ODM uses the angles only for radiometric calibration and does not document their convention, so they are
  written as 0, which its documentation allows.
* ``parge`` — the seed thesis's table: frame, latitude, longitude, height, roll, pitch, yaw minus track.
* ``geojson`` (RFC 7946, WGS84 lon/lat/height) and ``kml`` (OGC KML 2.2) — the exposure stations as points
  with every column as attributes.
"""

from __future__ import annotations

import json
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
import pandas as pd

from georef.io.atomic import atomic_write
from georef.io.eo_table import write_eo_csv

FORMATS = ("csv", "metashape", "pix4d", "odm", "parge", "geojson", "kml")
NEEDS_CRS = ("metashape", "pix4d", "odm")


def _georeferenced(table: pd.DataFrame) -> pd.DataFrame:
    """Rows with values (frames outside the navigation span cannot be exported as stations)."""
    return table[table["lat"].notna()]


def _require_grid(table: pd.DataFrame, fmt: str) -> None:
    if "easting" not in table:
        raise ValueError(f"--format {fmt} writes projected coordinates and omega/phi/kappa: give --crs EPSG:xxxx")


def write_metashape(table: pd.DataFrame, path: Path) -> None:
    _require_grid(table, "metashape")
    rows = _georeferenced(table)
    horizontal = np.hypot(rows["sigma_n"], rows["sigma_e"]) / np.sqrt(2.0)
    out = pd.DataFrame({"label": rows["frame"], "x": rows["easting"].round(4), "y": rows["northing"].round(4),
                        "z": rows["height"].round(4), "omega": rows["omega"].round(6), "phi": rows["phi"].round(6),
                        "kappa": rows["kappa"].round(6), "x_accuracy": horizontal.round(4),
                        "y_accuracy": horizontal.round(4), "z_accuracy": rows["sigma_u"].round(4),
                        "omega_accuracy": rows["sigma_roll"].round(5), "phi_accuracy": rows["sigma_pitch"].round(5),
                        "kappa_accuracy": rows["sigma_yaw"].round(5)})
    with atomic_write(path) as handle:
        handle.write("# georef EO for Agisoft Metashape Import Reference: " + ",".join(out.columns) + "\n")
        out.to_csv(handle, index=False, header=False, lineterminator="\n")


def write_pix4d(table: pd.DataFrame, path: Path) -> None:
    _require_grid(table, "pix4d")
    rows = _georeferenced(table)
    out = pd.DataFrame({"imagename": rows["frame"], "X": rows["easting"].round(4), "Y": rows["northing"].round(4),
                        "Z": rows["height"].round(4), "omega": rows["omega"].round(6), "phi": rows["phi"].round(6),
                        "kappa": rows["kappa"].round(6),
                        "accuracy_horz": np.hypot(rows["sigma_n"], rows["sigma_e"]).round(4),
                        "accuracy_vert": rows["sigma_u"].round(4)})
    with atomic_write(path) as handle:
        handle.write("#" + ",".join(out.columns) + "\n")
        out.to_csv(handle, index=False, header=False, lineterminator="\n")


def write_odm(table: pd.DataFrame, path: Path, crs: str) -> None:
    _require_grid(table, "odm")
    rows = _georeferenced(table)
    with atomic_write(path) as handle:
        handle.write(f"{crs}\n")
        for frame, e, n, h, sn, se, su in zip(rows["frame"], rows["easting"], rows["northing"], rows["height"],
                                              rows["sigma_n"], rows["sigma_e"], rows["sigma_u"], strict=True):
            handle.write(f"{frame} {e:.4f} {n:.4f} {h:.4f} 0 0 0 {np.hypot(sn, se):.4f} {su:.4f}\n")


def write_parge(table: pd.DataFrame, path: Path) -> None:
    out = table[["frame", "lat", "lon", "height", "roll", "pitch", "yaw_minus_track", "flag"]].copy()
    with atomic_write(path) as handle:
        out.to_csv(handle, sep="\t", index=False, float_format="%.9g", lineterminator="\n")


def _properties(row: pd.Series) -> dict:
    return {key: (None if isinstance(value, float) and np.isnan(value) else
                  (value.item() if hasattr(value, "item") else value)) for key, value in row.items()}


def write_geojson(table: pd.DataFrame, path: Path) -> None:
    rows = _georeferenced(table)
    features = [{"type": "Feature",
                 "geometry": {"type": "Point", "coordinates": [round(float(r["lon"]), 10), round(float(r["lat"]), 10),
                                                               round(float(r["height"]), 4)]},
                 "properties": _properties(r)} for _, r in rows.iterrows()]
    with atomic_write(path) as handle:
        json.dump({"type": "FeatureCollection", "features": features}, handle)


def write_kml(table: pd.DataFrame, path: Path) -> None:
    rows = _georeferenced(table)
    parts = ['<?xml version="1.0" encoding="UTF-8"?>', '<kml xmlns="http://www.opengis.net/kml/2.2">', "<Document>",
             "<name>georef exposure stations</name>"]
    for _, r in rows.iterrows():
        data = "".join(f'<Data name="{escape(str(k))}"><value>{escape(str(v))}</value></Data>'
                       for k, v in _properties(r).items())
        parts.append(f"<Placemark><name>{escape(str(r['frame']))}</name><ExtendedData>{data}</ExtendedData>"
                     f"<Point><altitudeMode>absolute</altitudeMode><coordinates>{r['lon']:.10f},{r['lat']:.10f},"
                     f"{r['height']:.4f}</coordinates></Point></Placemark>")
    parts += ["</Document>", "</kml>"]
    with atomic_write(path) as handle:
        handle.write("\n".join(parts) + "\n")


def write_export(table: pd.DataFrame, path: Path | str, fmt: str, crs: str | None = None) -> Path:
    """Write ``table`` in format ``fmt`` (one of :data:`FORMATS`)."""
    path = Path(path)
    if fmt not in FORMATS:
        raise ValueError(f"unknown --format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if fmt in NEEDS_CRS and not crs:
        raise ValueError(f"--format {fmt} writes projected coordinates and omega/phi/kappa: give --crs EPSG:xxxx")
    if fmt == "csv":
        write_eo_csv(table, path)
    elif fmt == "odm":
        write_odm(table, path, crs or "")
    else:
        {"metashape": write_metashape, "pix4d": write_pix4d, "parge": write_parge, "geojson": write_geojson,
         "kml": write_kml}[fmt](table, path)
    return path
