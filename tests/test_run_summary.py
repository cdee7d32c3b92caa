"""The typed run summary: one source for the JSON ``summary``, the terminal's table and the report's; the JSON's
keys are those docs/qc.md documents; a section that does not apply gives no row; the rows show the JSON's values."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from georef.run_summary import (
    FilterFigures,
    FlightFigures,
    GeodesyFigures,
    GraphFigures,
    RejectedFix,
    RunSummary,
    YawOffsetFigures,
    filter_rows,
)

DOCS = Path(__file__).resolve().parents[1] / "docs" / "qc.md"


def _filter(**changes: object) -> FilterFigures:
    figures = FilterFigures(
        heading_source="motion", unit_yaw_origin_deg=-57.0371, unit_yaw_origin_sigma_deg=0.1671,
        unit_yaw_drift_deg_per_min=0.5081, unit_yaw_drift_sigma_deg_per_min=0.0941,
        gnss_sigma_fitted_m=(1.04, 1.041, 1.83), vrw_m_s_sqrt_h=0.0612, arw_deg_sqrt_h=0.1543, ground_vehicle=False,
        noise_fit_passes=9, gnss_error_model="white", still_spans_s=[], held_out_fixes=45, held_out_error_m=3.66,
        held_out_interpolation_m=58.7, held_out_z=2.39, held_out_diverged=False, sigma_scale_position=2.39,
        sigma_scale_attitude=[1.1, None, 0.9], accel_bias_sigma_m_s2=(0.01, 0.01, 0.02),
        gyro_bias_sigma_deg_h=(10.0, 10.0, 12.0), gnss_lever_arm_sigma_m=None)
    return dataclasses.replace(figures, **changes)


def _graph(scale: bool) -> GraphFigures:
    return GraphFigures((0.457, 0.156, -1.648), (0.05, 0.05, 0.05), -0.00033, 0.00198, 1,
                        *(((120.0, -80.0, 3.0), (40.0, 40.0, 900.0), (-10.0, 5.0, 0.0), (50.0, 50.0, 50.0), 1000.0)
                          if scale else ()))


def _summary(**changes: object) -> RunSummary:
    summary = RunSummary(
        frames_written=513, frames_flagged=32, frames_outside_span=0, frames_in_outage=32, frames_after_last_fix=0,
        frames_before_first_fix=0, time_span_s=(24513.01, 24692.99), imu_rows=9000, imu_rate_hz=50.0,
        gnss_epochs=167, gnss_used=165, gnss_rejected_lines=[3016], gnss_gaps=[(24607.0, 24618.0)],
        time_quirks_repaired=2, method="rts", yaw=None, filter=_filter(), flight=None, geodesy=GeodesyFigures(),
        rejected_fixes=(RejectedFix(24573.2, 3016),), quirk_lines=(1852, 6052), flag_counts={"GNSS outage": 32})
    return dataclasses.replace(summary, **changes)


def _documented_keys() -> set[str]:
    text = DOCS.read_text(encoding="utf-8")
    section = text[text.index("`summary` of `process`:"):text.index("`batch`:")]
    return set(re.findall(r"`([a-z][a-z0-9_]*)`", section))


@pytest.mark.parametrize("summary", [
    _summary(), _summary(filter=None, method="axis", yaw=YawOffsetFigures(57.77, 0.139, 0.48, 0.23)),
    _summary(filter=_filter(graph=_graph(scale=True)), method="graph"),
    _summary(flight=FlightFigures("ArduPilot .bin", "copter", "IMU[0]", 12.5, 0.004, {"3D": 100}))],
    ids=["rts", "axis", "graph", "autopilot"])
def test_every_json_key_is_documented_and_the_order_is_kept(summary):
    keys = list(summary.to_dict())
    assert set(keys) <= _documented_keys(), set(keys) - _documented_keys()
    assert keys[:13] == ["frames_written", "frames_flagged", "frames_outside_span", "frames_in_outage",
                         "frames_after_last_fix", "frames_before_first_fix", "time_span_s", "imu_rows",
                         "imu_rate_hz", "gnss_epochs", "gnss_used", "gnss_rejected_lines", "gnss_gaps"]
    assert keys[13:19] == ["yaw_offset_deg", "yaw_offset_sigma_deg", "yaw_drift_deg_per_min",
                           "yaw_drift_sigma_deg_per_min", "time_quirks_repaired", "method"]
    assert keys[-5:] == ["output_crs", "output_heights", "proj_transformations", "proj_accuracy_m",
                         "geodesy_warnings"]
    # the sections that do not apply: the axis method's and the autopilot log's keys are null, the filters' absent
    document = summary.to_dict()
    assert (document["yaw_offset_deg"] is None) == (summary.yaw is None)
    assert (document["log_kind"] is None) == (summary.flight is None)
    assert ("heading_source" in document) == (summary.filter is not None)


def test_the_graphs_scale_factors_appear_only_when_estimated():
    without = _filter(graph=_graph(scale=False)).to_dict()
    with_scale = _filter(graph=_graph(scale=True)).to_dict()
    assert "graph_lever_arm_m" in without and not any("scale" in k for k in without if k.startswith("graph"))
    assert with_scale["graph_scale_prior_sigma_ppm"] == 1000.0 and with_scale["graph_gyro_scale_ppm"][2] == 3.0
    assert "graph_lever_arm_m" not in _filter().to_dict()


@pytest.mark.parametrize("figures", [_filter(), _filter(graph=_graph(scale=True)), _filter(graph=_graph(False))])
def test_filter_figures_come_back_from_their_json_keys(figures):
    """``georef fuse`` hands the terminal the JSON keys (``solution_figures``): the same figures, the same rows."""
    assert FilterFigures.from_dict(figures.to_dict()) == figures
    assert FilterFigures.from_dict({}) is None


def test_terminal_rows_show_the_json_values():
    summary = _summary(filter=_filter(graph=_graph(scale=True)))
    document = summary.to_dict()
    rows = dict((row.label, row.text) for row in summary.rows("terminal"))
    assert rows["frames written"] == f"{document['frames_written']} ({document['frames_flagged']} flagged)"
    assert rows["in GNSS outage"] == f"{document['frames_in_outage']} frames"
    assert rows["GNSS epochs"] == "167 (165 used, 1 rejected, 1 gaps)"
    assert rows["rejected fixes"] == "24573 s (line 3016)"
    assert rows["unit yaw origin"] == ("-57.037 ± 0.167 deg at the start (true yaw = unit yaw + origin), drift "
                                       "0.508 ± 0.094 deg/min")
    assert rows["noise"] == "GNSS σ h 1.04 m, v 1.83 m (fitted); VRW 0.061 m/s/√h, ARW 0.154 deg/√h"
    assert rows["GNSS time offset"] == "-0.33 ± 1.98 ms (each fix measured that long before its time tag)"
    assert rows["scale factors"].startswith("gyro 120 ± 40, -80 ± 40, 3 ± 900 ppm")
    assert rows["time quirks repaired"] == str(document["time_quirks_repaired"])
    # the report shows the same figures, with a true minus sign and its UTC times
    report = dict((row.label, row.text) for row in summary.rows("report"))
    assert report["unit yaw origin"] == rows["unit yaw origin"].replace("-", "−")
    assert report["time span"] == "06:48:33.0 – 06:51:33.0 UTC (180.0 s)"
    assert report["time tags repaired"] == "2 (lines 1852, 6052)"
    assert report["frames"] == "513 written, 32 flagged (32 GNSS outage)"


def test_a_section_that_does_not_apply_gives_no_row():
    axis = _summary(filter=None, yaw=YawOffsetFigures(57.77, 0.139, 0.48, 0.23), gnss_rejected_lines=[],
                    rejected_fixes=(), gnss_gaps=[], frames_in_outage=0)
    labels = [row.label for row in axis.rows("terminal")]
    assert "yaw offset" in labels
    for absent in ("heading source", "unit yaw origin", "noise", "ground vehicle", "GNSS lever arm",
                   "rejected fixes", "GNSS gap", "in GNSS outage", "coordinates", "PROJ", "median sigma"):
        assert absent not in labels, absent
    assert filter_rows(None) == []
    no_origin = [row.label for row in filter_rows(_filter(unit_yaw_origin_deg=None))]
    assert no_origin == ["heading source", "noise"]
    assert [row.label for row in filter_rows(_filter(ground_vehicle=True))][-1] == "ground vehicle"
    assert "yaw offset" not in [row.label for row in _summary().rows("report")]


def test_the_report_accounts_for_keys_its_empty_rows_would_show():
    """A row with nothing to show (no GNSS outage, not a ground vehicle) still names its keys, so the report's list
    of the other figures does not repeat them; the figures no row shows are left to that list."""
    summary = _summary()
    placed = summary.placed_rows("report")
    keys = {key for row in placed for key in row.keys}
    assert {"ground_vehicle", "frames_outside_span", "sigma_scale_attitude", "time_span_s"} <= keys
    assert not {"held_out_z", "noise_fit_passes", "geodesy_warnings", "gnss_error_model"} & keys
    assert any(row.text is None for row in placed)
    assert all(row.text is not None for row in summary.rows("report"))
