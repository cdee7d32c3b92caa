"""georef.preflight: every option of process, fuse and batch checked before any file is processed, as the library
sees it (the command line's wording of the same refusals: tests/cli/test_commands.py, tests/end_to_end/
test_bad_input.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from georef.option_values import OptionError, pairs, triple
from georef.preflight import (
    BatchRequest,
    FuseRequest,
    OptionValue,
    OutputChecks,
    ProcessInputs,
    ProcessRequest,
    configured,
    input_source,
    preflight,
)

DATA = Path(__file__).resolve().parents[1] / "data"


def _pos_request(tmp_path: Path, **changes: object) -> ProcessRequest:
    inputs = ProcessInputs(pos=DATA / "POS.txt", camera=DATA / "Kamera.txt")
    return ProcessRequest(inputs, output=tmp_path / "eo.csv", **changes)  # type: ignore[arg-type]


def test_a_pos_txt_run_is_planned_with_its_table_exports_and_checked_output_frames(tmp_path):
    plan = preflight(_pos_request(tmp_path, exports=[f"kml:{tmp_path / 'eo.kml'}"],
                                  options={"crs": OptionValue("--crs", "EPSG:3765")}))
    assert plan.source.way == "pos" and plan.source.files == {"pos": DATA / "POS.txt", "camera": DATA / "Kamera.txt"}
    assert [spec.fmt for spec in plan.specs] == ["csv", "kml"] and plan.sbet_specs == []
    assert isinstance(plan.checked, OutputChecks) and plan.checked.frames is not None
    assert plan.checked.image_names is None and plan.cfg.output.crs == "EPSG:3765"


def test_the_four_ways_in_are_told_apart_and_mixed_ones_refused(tmp_path):
    generic = ProcessInputs(imu=tmp_path / "imu.csv", gnss=tmp_path / "gnss.csv", events=tmp_path / "events.csv")
    assert input_source(generic).way == "generic"
    assert input_source(ProcessInputs(bag=tmp_path / "b.bag", events=tmp_path / "e.csv")).way == "bag"
    with pytest.raises(OptionError, match="missing --gnss, --events"):
        input_source(ProcessInputs(imu=tmp_path / "imu.csv"))
    with pytest.raises(OptionError, match="--bag takes the place of --imu and --gnss"):
        input_source(ProcessInputs(bag=tmp_path / "b.bag", imu=tmp_path / "imu.csv", events=tmp_path / "e.csv"))
    with pytest.raises(OptionError, match="POS.txt takes Kamera.txt"):
        input_source(ProcessInputs(pos=DATA / "POS.txt", camera=DATA / "Kamera.txt", events=tmp_path / "e.csv"))


def test_every_output_is_checked_before_a_file_is_read(tmp_path):
    with pytest.raises(OptionError, match="only one output can go to standard output"):
        preflight(ProcessRequest(ProcessInputs(), output=Path("-"), summary_json=Path("-")))  # before the inputs
    with pytest.raises(OptionError, match="needs -o FILE"):
        preflight(ProcessRequest(ProcessInputs(pos=DATA / "POS.txt", camera=DATA / "Kamera.txt"),
                                 output_format="metashape"))
    with pytest.raises(OptionError, match="an SBET is the trajectory"):
        preflight(_pos_request(tmp_path, output_format="sbet", utc_date="2024-05-01"))
    with pytest.raises(OptionError, match="add --utc-date"):
        preflight(_pos_request(tmp_path, exports=[f"sbet:{tmp_path / 'run.out'}"]))
    with pytest.raises(OptionError, match="no images export is asked for"):
        preflight(_pos_request(tmp_path, images=tmp_path))


def test_an_option_a_section_refuses_is_reported_against_the_option():
    cfg = configured(None, {"lever_arm_gnss": OptionValue("--gnss-lever-arm", "0.5,0,-1.2", "metres")})
    assert cfg.mounting.lever_arm_gnss == pytest.approx((0.5, 0.0, -1.2))
    with pytest.raises(OptionError, match="needs three comma-separated numbers in metres"):
        configured(None, {"lever_arm_gnss": OptionValue("--gnss-lever-arm", "0.5,0", "metres")})
    with pytest.raises(OptionError, match="^--gnss-rate: "):
        configured(None, {"gnss_rate_hz": OptionValue("--gnss-rate", -3.0)})


def test_fuse_and_batch_requests(tmp_path):
    plan = preflight(FuseRequest(imu=tmp_path / "imu.csv", gnss=tmp_path / "gnss.csv", output=tmp_path / "t.csv",
                                 exports=[f"sbet:{tmp_path / 'f.out'}"]))
    assert [spec.fmt for spec in plan.sbet_specs] == ["sbet"]
    with pytest.raises(OptionError, match="sbet:FILE only"):
        preflight(FuseRequest(imu=tmp_path / "imu.csv", gnss=tmp_path / "gnss.csv", exports=["kml:x.kml"]))
    assert preflight(BatchRequest(tmp_path, exports=["kml", "images"])).exports == (
        ("kml", "stations.kml"), ("images", "images"))
    with pytest.raises(OptionError, match="needs --method graph") as refused:
        preflight(BatchRequest(tmp_path, shared_calibration=True, method="rts"))
    assert refused.value.option == "--shared-calibration"


def test_option_text_numbers():
    assert triple(None, "--x", "m") is None and triple(" 1, 2,3", "--x", "m") == (1.0, 2.0, 3.0)
    assert pairs(["1,2", "3,4.5"], "--outage") == [(1.0, 2.0), (3.0, 4.5)]
    with pytest.raises(OptionError, match="--outage takes two numbers A,B; got '1'"):
        pairs(["1"], "--outage")
