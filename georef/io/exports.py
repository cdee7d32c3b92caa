"""Exports of the EO table that photogrammetry and GIS software read (``--format``, ``--export``).

Each writer takes the EO table of :mod:`georef.eo` and writes atomically. Every station format labels a row with
its image file name (the ``image`` column of ``--image-names``; the frame id without it), writes the heights the
run asked for (:class:`georef.frames.heights.OutputFrames`) and each consumer's own angles and sigmas. What each
consumer defines, and the versions checked, are in ``docs/formats.md``; ``tests/io/test_exports.py`` reads every file
back with the consumer's own parsing code (ported, cited) or an independent validator (GDAL/OGR, fastkml):

* ``metashape`` — Agisoft Metashape *Import Reference* CSV: label, easting, northing, height, ω, φ, κ, then the
  accuracies of each: σ of easting and northing along the grid axes (``sigma_x``, ``sigma_y``), σ of the height,
  σ of ω, φ, κ (``sigma_omega..kappa``: the attitude covariance rotated into ω, φ, κ).
* ``pix4d`` — PIX4D image geolocation and orientation file: image name, the two coordinates **in the CRS's axis
  order** (northing first for EPSG:31466 or EPSG:3006), height, yaw, pitch, roll of the camera (Pix4D's
  definition: yaw 0 = top of image north, pitch 0 = nadir), horizontal and vertical accuracy as the σ of a
  normal distribution per axis.
* ``odm`` — OpenDroneMap ``geo.txt``: ``EPSG:nnnn`` line, then ``image x y z yaw pitch roll σh σv``; the angles
  are ``nan`` (ODM's "absent") unless ``odm_angles`` asks for them: ODM 3.6 turns them into ω, φ, κ with a
  frame error (docs/formats.md).
* ``parge`` — the PARGE input table of Bošnjak (2014): frame, latitude, longitude, height, roll, pitch, yaw minus track.
* ``geojson`` — RFC 7946: [longitude, latitude, WGS 84 ellipsoidal height] (the RFC's CRS), every column a
  property.
* ``kml`` — OGC KML 2.2, ``altitudeMode absolute`` ("relative to sea level") with EGM96 heights, the sea level of
  Google Earth; every column as ExtendedData.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from georef.io.atomic import atomic_write
from georef.io.eo_table import write_eo_csv

if TYPE_CHECKING:
    import pandas as pd

    from georef.eo import EoColumns
    from georef.frames.heights import OutputFrames

FORMATS = ("csv", "metashape", "pix4d", "odm", "parge", "geojson", "kml", "sbet")
NEEDS_CRS = ("metashape", "pix4d", "odm")
#: formats of the navigation solution, not of the EO table: written by their own module (``sbet``:
#: :func:`georef.io.sbet.write_sbet`, with its ``smrmsg_<name>.out`` beside it)
NAV_FORMATS = ("sbet",)
#: formats chosen from a file's extension (``-o stations.kml``, ``--export stations.geojson``)
EXTENSIONS = {".csv": "csv", ".kml": "kml", ".geojson": "geojson"}
#: file names that name their format
FILE_NAMES = {"geo.txt": "odm"}


class ExportError(ValueError):
    """An export the user asked for cannot be written as asked (reported before any processing)."""


@dataclass(frozen=True)
class ExportSpec:
    """One output file and its format."""

    fmt: str
    path: Path


def format_of(path: Path | str, fmt: str | None = None) -> str:
    """The format of an output: ``fmt`` when given (checked), else from the file name or extension."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise ExportError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
        return fmt
    name = Path(path).name.lower()
    if name in FILE_NAMES:
        return FILE_NAMES[name]
    suffix = Path(path).suffix.lower()
    if suffix in EXTENSIONS:
        return EXTENSIONS[suffix]
    raise ExportError(f"cannot tell the format of {str(path)!r} from its extension ({', '.join(EXTENSIONS)} or "
                      f"geo.txt); write FORMAT:PATH with FORMAT one of {', '.join(FORMATS)}")


#: the file each format gets in a folder of outputs (``georef batch --export FORMAT``)
DEFAULT_FILE_NAMES = {"csv": "eo.csv", "metashape": "metashape.csv", "pix4d": "pix4d.csv", "odm": "geo.txt",
                      "parge": "parge.txt", "geojson": "stations.geojson", "kml": "stations.kml"}


def parse_folder_export(text: str) -> ExportSpec:
    """An export of ``georef batch``, relative to each flight's output folder: ``FORMAT`` (its default file name,
    :data:`DEFAULT_FILE_NAMES`), ``FORMAT:NAME`` or ``NAME`` with an extension that names the format. ``NAME`` is
    a plain file name: a flight's outputs stay in its own folder."""
    if text.partition(":")[0] in NAV_FORMATS or text in NAV_FORMATS:
        raise ExportError(f"--export {text!r}: georef batch does not write SBETs (a POS.txt flight has no date for "
                          "GPS time); run georef process --export sbet:FILE --utc-date YYYY-MM-DD per flight")
    if text in FORMATS:
        return ExportSpec(text, Path(DEFAULT_FILE_NAMES[text]))
    spec = parse_export(text)
    if spec.path.name != str(spec.path) or spec.path.name in ("", ".", ".."):
        raise ExportError(f"--export {text!r}: give a plain file name; each flight's files go in its own folder")
    return spec


def parse_export(text: str) -> ExportSpec:
    """``FORMAT:PATH`` (``metashape:ms.csv``) or a path whose extension names the format (``stations.kml``)."""
    head, sep, tail = text.partition(":")
    if sep and head in FORMATS:
        if not tail:
            raise ExportError(f"--export {text!r}: no file after {head}:")
        return ExportSpec(head, Path(tail))
    if sep and head and len(head) > 1 and "/" not in head and "\\" not in head:
        raise ExportError(f"--export {text!r}: unknown format {head!r}; choose one of {', '.join(FORMATS)}")
    return ExportSpec(format_of(text), Path(text))


def check_exports(specs: Sequence[ExportSpec], frames: OutputFrames | None) -> None:
    """Everything that can be checked before processing: known formats, a projected CRS for the formats that
    need one, the EGM96 grid for KML, and no two outputs on one path."""
    seen: dict[Path, str] = {}
    for spec in specs:
        format_of(spec.path, spec.fmt)
        if spec.fmt in NEEDS_CRS and (frames is None or frames.horizontal is None):
            raise ExportError(f"{spec.fmt} ({spec.path}) writes projected coordinates and its angles: give --crs "
                              "EPSG:xxxx (e.g. EPSG:3765, HTRS96/TM)")
        if spec.fmt == "kml":
            _kml_frames(frames).egm96([45.0], [15.0], [0.0])  # the grid is there, or GeoidGridError now
        key = spec.path.resolve()
        if key in seen:
            raise ExportError(f"{spec.path} is asked for twice ({seen[key]} and {spec.fmt})")
        seen[key] = spec.fmt
        if spec.fmt == "sbet":  # its RMS file is written beside it
            from georef.io.sbet import smrmsg_path_for

            companion = smrmsg_path_for(spec.path)
            if companion.resolve() in seen:
                raise ExportError(f"{companion} (the RMS file of {spec.path}) is asked for twice")
            seen[companion.resolve()] = f"the RMS file of sbet:{spec.path}"


def _kml_frames(frames: OutputFrames | None) -> OutputFrames:
    from georef.frames.heights import OutputFrames

    return frames if frames is not None else OutputFrames()


def _georeferenced(table: pd.DataFrame) -> pd.DataFrame:
    """Rows with values (frames outside the navigation span cannot be exported as stations)."""
    return table[table["lat"].notna()]


def _labels(rows: pd.DataFrame) -> pd.Series:
    return (rows["image"] if "image" in rows else rows["frame"]).astype(str)


def _heights(rows: pd.DataFrame, frames: OutputFrames | None) -> pd.Series:
    if frames is not None and frames.height == "orthometric":
        return rows["height_orthometric"]
    return rows["height"]


def _grid(table: pd.DataFrame, fmt: str, frames: OutputFrames | None) -> pd.DataFrame:
    if frames is None or frames.horizontal is None or "easting" not in table:
        raise ExportError(f"{fmt} writes projected coordinates and its angles: give --crs EPSG:xxxx")
    return _georeferenced(table)


def _horizontal_sigma(rows: pd.DataFrame) -> pd.Series:
    """One horizontal σ per row for formats with a single value: the per-axis σ of the isotropic distribution
    with the same total variance, sqrt((σx² + σy²) / 2) — not hypot(σx, σy), which is √2 times a per-axis σ
    (:func:`georef.frames.pix4d.per_axis_sigma`, also used for the accuracies of tagged image copies)."""
    import pandas as pd

    from georef.frames.pix4d import per_axis_sigma

    return pd.Series(per_axis_sigma(rows["sigma_x"], rows["sigma_y"]), index=rows.index)


def write_metashape(table: pd.DataFrame, path: Path, frames: OutputFrames | None) -> None:
    import pandas as pd

    rows = _grid(table, "metashape", frames)
    out = pd.DataFrame({"label": _labels(rows), "x": rows["easting"].round(4), "y": rows["northing"].round(4),
                        "z": _heights(rows, frames).round(4), "omega": rows["omega"].round(6),
                        "phi": rows["phi"].round(6), "kappa": rows["kappa"].round(6),
                        "x_accuracy": rows["sigma_x"].round(4), "y_accuracy": rows["sigma_y"].round(4),
                        "z_accuracy": rows["sigma_u"].round(4), "omega_accuracy": rows["sigma_omega"].round(5),
                        "phi_accuracy": rows["sigma_phi"].round(5), "kappa_accuracy": rows["sigma_kappa"].round(5)})
    assert frames is not None
    with atomic_write(path) as handle:
        handle.write(f"# georef EO for Agisoft Metashape Import Reference ({frames.horizontal_name}, heights "
                     f"{frames.height_name}, angles in degrees, accuracies 1-sigma): " + ",".join(out.columns) + "\n")
        out.to_csv(handle, index=False, header=False, lineterminator="\n")


def northing_first(frames: OutputFrames) -> bool:
    """True when the projected CRS's first axis points north or south (EPSG:31466, EPSG:3006)."""
    assert frames.horizontal is not None
    return frames.horizontal.axis_info[0].direction.lower() in ("north", "south")


def write_pix4d(table: pd.DataFrame, path: Path, frames: OutputFrames | None) -> None:
    import pandas as pd

    rows = _grid(table, "pix4d", frames)
    assert frames is not None
    first, second = ("northing", "easting") if northing_first(frames) else ("easting", "northing")
    from georef.frames.pix4d import pix4d_angles  # the same angles as the Camera:Yaw/Pitch/Roll of image copies

    angles = pix4d_angles(rows["roll"], rows["pitch"], rows["yaw"])
    out = pd.DataFrame({"imagename": _labels(rows), first: rows[first].round(4), second: rows[second].round(4),
                        "z": _heights(rows, frames).round(4), "yaw": np.round(angles.yaw, 6),
                        "pitch": np.round(angles.pitch, 6), "roll": np.round(angles.roll, 6),
                        "accuracy_horz": _horizontal_sigma(rows).round(4), "accuracy_vert": rows["sigma_u"].round(4)})
    with atomic_write(path) as handle:
        handle.write("#" + ",".join(out.columns) + "\n")
        out.to_csv(handle, index=False, header=False, lineterminator="\n")


def odm_header(frames: OutputFrames) -> str:
    """The first line of geo.txt: ``EPSG:nnnn`` of the horizontal CRS (ODM parses nothing else but a PROJ.4
    string or ``WGS84 UTM nnX``); a CRS without an EPSG code as its PROJ.4 string."""
    assert frames.horizontal is not None
    code = frames.horizontal.to_epsg()
    return f"EPSG:{code}" if code else frames.horizontal.to_proj4()


def write_odm(table: pd.DataFrame, path: Path, frames: OutputFrames | None, angles: bool = False) -> None:
    rows = _grid(table, "odm", frames)
    assert frames is not None
    heights = _heights(rows, frames)
    horizontal = _horizontal_sigma(rows)
    with atomic_write(path) as handle:
        handle.write(odm_header(frames) + "\n")
        for i, label in enumerate(_labels(rows)):
            r = rows.iloc[i]
            ypr = f"{r['yaw']:.6f} {r['pitch']:.6f} {r['roll']:.6f}" if angles else "nan nan nan"
            handle.write(f"{label} {r['easting']:.4f} {r['northing']:.4f} {heights.iloc[i]:.4f} {ypr} "
                         f"{horizontal.iloc[i]:.4f} {r['sigma_u']:.4f}\n")


def write_parge(table: pd.DataFrame, path: Path) -> None:
    columns = ["frame", *(["image"] if "image" in table else []), "lat", "lon", "height", "roll", "pitch",
               "yaw_minus_track", "flag"]
    with atomic_write(path) as handle:
        table[columns].to_csv(handle, sep="\t", index=False, float_format="%.9g", lineterminator="\n")


def _properties(row: pd.Series) -> dict:
    return {str(key): (None if isinstance(value, float) and not np.isfinite(value) else
                       (value.item() if hasattr(value, "item") else value)) for key, value in row.items()}


def write_geojson(table: pd.DataFrame, path: Path) -> None:
    import json  # imported by the formats that use it (a run writing the CSV table does not)

    rows = _georeferenced(table)
    features = [{"type": "Feature",
                 "geometry": {"type": "Point", "coordinates": [round(float(r["lon"]), 10), round(float(r["lat"]), 10),
                                                               round(float(r["height"]), 4)]},
                 "properties": _properties(r)} for _, r in rows.iterrows()]
    with atomic_write(path) as handle:
        json.dump({"type": "FeatureCollection", "features": features}, handle, allow_nan=False)


def write_kml(table: pd.DataFrame, path: Path, frames: OutputFrames | None) -> None:
    from xml.sax.saxutils import escape, quoteattr  # pulls in urllib, http.client and ssl: only for KML

    rows = _georeferenced(table).copy()
    rows["height_egm96"] = _kml_frames(frames).egm96(rows["lat"], rows["lon"], rows["height"])
    labels = _labels(rows)
    parts = ['<?xml version="1.0" encoding="UTF-8"?>', '<kml xmlns="http://www.opengis.net/kml/2.2">', "<Document>",
             "<name>georef exposure stations</name>",
             "<description>Camera perspective centres; altitude above sea level (EGM96 height)</description>"]
    for (_, r), label in zip(rows.iterrows(), labels, strict=True):
        data = "".join(f"<Data name={quoteattr(str(k))}><value>{escape('' if v is None else str(v))}</value></Data>"
                       for k, v in _properties(r).items())
        parts.append(f"<Placemark><name>{escape(label)}</name><ExtendedData>{data}</ExtendedData>"
                     f"<Point><altitudeMode>absolute</altitudeMode><coordinates>{r['lon']:.10f},{r['lat']:.10f},"
                     f"{r['height_egm96']:.4f}</coordinates></Point></Placemark>")
    parts += ["</Document>", "</kml>"]
    with atomic_write(path) as handle:
        handle.write("\n".join(parts) + "\n")


def write_export(table: pd.DataFrame | EoColumns, path: Path | str, fmt: str, crs: str | None = None,
                 frames: OutputFrames | None = None, odm_angles: bool = False) -> Path:
    """Write ``table`` (a DataFrame, or columns as :func:`georef.eo.camera_eo_columns` gives them) in format
    ``fmt`` (one of :data:`FORMATS`). ``frames`` gives the CRS and heights of the run (``crs`` alone: ellipsoidal
    heights in that CRS). The CSV table is written without pandas; the other formats make a DataFrame."""
    path = Path(path)
    format_of(path, fmt)
    if frames is None and crs:
        from georef.frames.heights import OutputFrames

        frames = OutputFrames(crs)
    check_exports([ExportSpec(fmt, path)], frames)
    if fmt in NAV_FORMATS:
        raise ExportError(f"{fmt} is written from the navigation solution, not the EO table: georef.io.sbet.write_sbet")
    if fmt == "csv":
        write_eo_csv(table, path)
        return path
    if isinstance(table, dict):
        from georef.eo import eo_frame

        table = eo_frame(table)
    if fmt == "metashape":
        write_metashape(table, path, frames)
    elif fmt == "pix4d":
        write_pix4d(table, path, frames)
    elif fmt == "odm":
        write_odm(table, path, frames, angles=odm_angles)
    elif fmt == "parge":
        write_parge(table, path)
    elif fmt == "geojson":
        write_geojson(table, path)
    else:
        write_kml(table, path, frames)
    return path
