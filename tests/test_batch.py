"""`georef batch` on a real Dask LocalCluster: every good flight written, a broken one reported."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.batch import discover, run_batch
from georef.io.errors import InputError
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("flights")
    for seed in (1, 2, 3):
        write_flight(simulate(SimConfig(seed=seed, plan=FlightPlan(duration_s=90.0))), root / f"flight{seed}")
    broken = root / "broken"
    shutil.copytree(root / "flight1", broken)
    lines = (broken / "POS.txt").read_text().splitlines(keepends=True)
    cells = lines[499].split("\t")
    cells[1] = "12..5"
    lines[499] = "\t".join(cells)
    (broken / "POS.txt").write_text("".join(lines))
    return root


def test_batch_on_a_local_cluster(flights, tmp_path):
    jobs = discover(flights)
    assert [job.flight for job in jobs] == ["broken", "flight1", "flight2", "flight3"]
    summary = run_batch(jobs, tmp_path, workers=2)
    ok = summary[summary["status"] == "ok"]
    assert sorted(ok["flight"]) == ["flight1", "flight2", "flight3"]
    for flight in ok["flight"]:
        table = pd.read_csv(tmp_path / flight / "eo.csv")
        kamera = pd.read_csv(flights / flight / "Kamera.txt", sep="\t")
        assert len(table) == len(kamera) == int(ok.loc[ok["flight"] == flight, "frames"].iloc[0])
        assert "status ok" in (tmp_path / flight / "georef.log").read_text()
    # the verdict, judged on the worker, came back as text
    assert list(ok["qc"]) == ["passed"] * 3, list(ok["qc_details"])
    assert "QC pass innovations" in (tmp_path / "flight1" / "georef.log").read_text()
    broken = summary[summary["flight"] == "broken"].iloc[0]
    assert broken["status"] == "failed" and pd.isna(broken["qc"])
    assert "line 500" in broken["message"] and "ACCS_X" in broken["message"]
    assert "FAILED" in (tmp_path / "broken" / "georef.log").read_text()
    on_disk = pd.read_csv(tmp_path / "batch_summary.csv")
    assert list(on_disk["flight"]) == ["broken", "flight1", "flight2", "flight3"]
    assert (on_disk["runtime_s"] > 0).all()
    assert {"innovation_mean_nis", "rejected_fixes", "method", "qc", "qc_details"} <= set(on_disk.columns)


def test_batch_from_a_manifest_via_the_cli(flights, tmp_path):
    manifest = tmp_path / "flights.csv"
    pd.DataFrame({"flight": ["a", "b"],
                  "pos": [str(flights / "flight2" / "POS.txt"), str(flights / "flight3" / "POS.txt")],
                  "camera": [str(flights / "flight2" / "Kamera.txt"), str(flights / "flight3" / "Kamera.txt")],
                  "config": [str(flights / "flight2" / "flight.toml"), ""]}).to_csv(manifest, index=False)
    result = CliRunner().invoke(app, ["batch", str(manifest), "-o", str(tmp_path / "out"), "--method", "axis",
                                      "--workers", "2", "-q"])
    assert result.exit_code == 0, result.output
    summary = pd.read_csv(tmp_path / "out" / "batch_summary.csv")
    assert list(summary["status"]) == ["ok", "ok"] and set(summary["method"]) == {"axis"}


def test_bad_manifest_is_a_clear_error(tmp_path):
    manifest = tmp_path / "m.csv"
    manifest.write_text("name,pos\nx,y\n")
    with pytest.raises(InputError, match="flight, pos, camera"):
        discover(manifest)


def test_a_flight_that_fails_qc_makes_the_batch_exit_4(flights, tmp_path):
    shifted = tmp_path / "Kamera_shifted.txt"
    kamera = pd.read_csv(flights / "flight3" / "Kamera.txt", sep="\t")
    kamera["Time"] += 7200                      # a camera clock two hours off
    kamera.to_csv(shifted, sep="\t", index=False)
    manifest = tmp_path / "flights.csv"
    pd.DataFrame({"flight": ["good", "clock"],
                  "pos": [str(flights / "flight2" / "POS.txt"), str(flights / "flight3" / "POS.txt")],
                  "camera": [str(flights / "flight2" / "Kamera.txt"), str(shifted)]}).to_csv(manifest, index=False)
    result = CliRunner().invoke(app, ["batch", str(manifest), "-o", str(tmp_path / "out"), "--method", "axis",
                                      "--workers", "2"])
    assert result.exit_code == 4, result.output
    assert "QC failed: clock: fail frames:" in result.output
    summary = pd.read_csv(tmp_path / "out" / "batch_summary.csv")
    assert list(summary["status"]) == ["ok", "ok"]
    assert list(summary["qc"]) == ["passed", "failed: frames"]
    assert "--camera-utc-offset" in summary.loc[1, "qc_details"]
    # the outputs of the failed flight are written all the same
    assert len(pd.read_csv(tmp_path / "out" / "clock" / "eo.csv")) == len(kamera)


def test_a_batch_where_every_flight_failed_to_run_exits_2(flights, tmp_path):
    manifest = tmp_path / "flights.csv"
    pd.DataFrame({"flight": ["broken"], "pos": [str(flights / "broken" / "POS.txt")],
                  "camera": [str(flights / "broken" / "Kamera.txt")]}).to_csv(manifest, index=False)
    result = CliRunner().invoke(app, ["batch", str(manifest), "-o", str(tmp_path / "out"), "--workers", "1", "-q"])
    assert result.exit_code == 2, result.output
    assert "failed: broken" in result.output and "QC failed" not in result.output


def test_batch_writes_each_flights_exports(tmp_path):
    """``--export`` in a batch: every flight's folder gets the files, with the flight's own CRS; a flight whose
    configuration lacks the CRS a format needs fails on its input before it is processed, and writes nothing."""
    from georef.batch import FlightJob, process_flight
    from georef.io.exports import parse_folder_export

    flight = simulate(SimConfig(seed=4, plan=FlightPlan(duration_s=60.0)))
    with_crs = write_flight(flight, tmp_path / "with_crs", crs="EPSG:3765")
    without = write_flight(flight, tmp_path / "without_crs")
    exports = tuple((spec.fmt, str(spec.path)) for spec in map(parse_folder_export, ["metashape", "kml:st.kml"]))
    out = tmp_path / "out"
    row = process_flight(FlightJob("with_crs", str(with_crs["POS.txt"]), str(with_crs["Kamera.txt"]),
                                   str(with_crs["flight.toml"])), str(out), exports=exports)
    assert row["status"] == "ok", row["message"]
    table = pd.read_csv(out / "with_crs" / "eo.csv")
    metashape = pd.read_csv(out / "with_crs" / "metashape.csv", comment="#", header=None)
    assert len(metashape) == table["lat"].notna().sum() > 0
    assert metashape[1].to_numpy() == pytest.approx(table.loc[table["lat"].notna(), "easting"].to_numpy(), abs=1e-3)
    assert (out / "with_crs" / "st.kml").read_text().count("<Placemark>") == len(metashape)
    assert {o["path"] for o in row["outputs"]} >= {str(out / "with_crs" / n) for n in ("eo.csv", "metashape.csv",
                                                                                      "st.kml")}
    row = process_flight(FlightJob("without_crs", str(without["POS.txt"]), str(without["Kamera.txt"]),
                                   str(without["flight.toml"])), str(out), exports=exports)
    assert row["status"] == "failed" and row["failure"] == "input" and "crs" in row["message"].lower()
    assert sorted(p.name for p in (out / "without_crs").iterdir()) == ["georef.log"]


@pytest.mark.parametrize("text", ["nonsense", "metashape:../ms.csv", "sub/stations.kml"])
def test_batch_refuses_a_bad_export_before_any_flight(flights, tmp_path, text):
    result = CliRunner().invoke(app, ["batch", str(flights), "-o", str(tmp_path / "out"), "--export", text, "-q"])
    assert result.exit_code == 2, result.output
    assert not (tmp_path / "out").exists()
