"""Every export format is written and parsed back."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.config import load_config
from georef.io.exports import FORMATS, write_export
from georef.pipeline import process

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="module")
def table():
    cfg = load_config(DATA / "flight.toml")
    result = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg)
    # one frame outside the navigation span: it has no station to export
    extra = result.table.iloc[:1].copy()
    extra.loc[:, ["lat", "lon", "height", "easting", "northing", "omega", "phi", "kappa"]] = np.nan
    extra["frame"] = "9999"
    return pd.concat([result.table, extra], ignore_index=True)


def _stations(table):
    return table[table["lat"].notna()]


def test_metashape(tmp_path, table):
    path = write_export(table, tmp_path / "ref.csv", "metashape", "EPSG:3765")
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#") and "omega" in lines[0]
    names = lines[0].split(": ")[1].split(",")
    back = pd.read_csv(path, comment="#", header=None, names=names, dtype={"label": str})
    rows = _stations(table)
    assert back["label"].tolist() == rows["frame"].tolist()
    np.testing.assert_allclose(back["x"], rows["easting"], atol=1e-4)
    np.testing.assert_allclose(back["kappa"], rows["kappa"], atol=1e-6)


def test_pix4d(tmp_path, table):
    path = write_export(table, tmp_path / "pix4d.txt", "pix4d", "EPSG:3765")
    back = pd.read_csv(path, comment="#", header=None, dtype={0: str})
    rows = _stations(table)
    assert back.shape == (len(rows), 9)
    np.testing.assert_allclose(back[2], rows["northing"], atol=1e-4)
    np.testing.assert_allclose(back[[4, 5, 6]].to_numpy(),
                               rows[["omega", "phi", "kappa"]].to_numpy(), atol=1e-6)


def test_odm_geo_txt(tmp_path, table):
    path = write_export(table, tmp_path / "geo.txt", "odm", "EPSG:3765")
    lines = path.read_text().splitlines()
    assert lines[0] == "EPSG:3765"
    fields = [line.split() for line in lines[1:]]
    assert all(len(f) == 9 for f in fields)
    rows = _stations(table)
    np.testing.assert_allclose([float(f[1]) for f in fields], rows["easting"], atol=1e-4)
    np.testing.assert_allclose([float(f[3]) for f in fields], rows["height"], atol=1e-4)


def test_parge(tmp_path, table):
    path = write_export(table, tmp_path / "parge.txt", "parge")
    back = pd.read_csv(path, sep="\t", dtype={"frame": str, "flag": str}, keep_default_na=False,
                       na_values={"lat": [""], "lon": [""], "height": [""]})
    assert len(back) == len(table)  # every frame, flagged ones included
    np.testing.assert_allclose(back["yaw_minus_track"].astype(float), table["yaw_minus_track"], atol=1e-6)


def test_geojson(tmp_path, table):
    path = write_export(table, tmp_path / "stations.geojson", "geojson")
    doc = json.loads(path.read_text())
    assert doc["type"] == "FeatureCollection"
    rows = _stations(table)
    coords = np.array([f["geometry"]["coordinates"] for f in doc["features"]])
    np.testing.assert_allclose(coords, rows[["lon", "lat", "height"]].to_numpy(), atol=1e-6)
    assert doc["features"][0]["properties"]["frame"] == rows["frame"].iloc[0]


def test_kml(tmp_path, table):
    path = write_export(table, tmp_path / "stations.kml", "kml")
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.parse(path).getroot()
    placemarks = root.findall(".//k:Placemark", ns)
    rows = _stations(table)
    assert len(placemarks) == len(rows)
    lon, lat, h = (float(x) for x in placemarks[0].find(".//k:coordinates", ns).text.split(","))
    assert (lon, lat) == pytest.approx((rows["lon"].iloc[0], rows["lat"].iloc[0]), abs=1e-9)


def test_formats_needing_a_crs_say_so(tmp_path):
    runner = CliRunner()
    result = runner.invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--format", "pix4d",
                                 "-o", str(tmp_path / "p.txt"), "-q"])
    assert result.exit_code == 2 and "--crs" in result.output
    assert set(FORMATS) == {"csv", "metashape", "pix4d", "odm", "parge", "geojson", "kml"}
