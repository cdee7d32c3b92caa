"""The run summary on the terminal: the table ``georef process`` prints after a run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape

from .output import is_stdout

#: notices go to standard error, as every other message of the commands
console = Console(stderr=True, soft_wrap=True, emoji=False)


def target_text(path: Path) -> str:
    """Where an output went, as rich markup: the escaped path, or "standard output" for ``-``."""
    return "standard output" if is_stdout(path) else escape(str(path))


def filter_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    """Summary rows of the full-state filters (``georef.pipeline.solution_figures``): heading source, the unit's
    yaw origin, the fitted noise, the ground-vehicle constraints. Empty for the other methods."""
    rows: list[tuple[str, str]] = []
    if s.get("heading_source") is None:
        return rows
    rows.append(("heading source", escape(str(s["heading_source"]))))
    if s.get("unit_yaw_origin_deg") is not None:
        drift, drift_sigma = s.get("unit_yaw_drift_deg_per_min"), s.get("unit_yaw_drift_sigma_deg_per_min")
        drift_text = "" if drift is None else f", drift {drift:.3f}" + (
            f" ± {drift_sigma:.3f}" if drift_sigma is not None else "") + " deg/min"
        rows.append(("unit yaw origin", f"{s['unit_yaw_origin_deg']:.3f} ± {s['unit_yaw_origin_sigma_deg']:.3f} deg "
                     "at the start (true yaw = unit yaw + origin)" + drift_text))
    sigma_n, sigma_e, sigma_u = s["gnss_sigma_fitted_m"]
    horizontal = f"{sigma_n:.2f}" if abs(sigma_n - sigma_e) < 0.005 else f"{sigma_n:.2f}/{sigma_e:.2f}"
    rows.append(("noise", f"GNSS σ h {horizontal} m, v {sigma_u:.2f} m (fitted); VRW {s['vrw_m_s_sqrt_h']:.3f} "
                 f"m/s/√h, ARW {s['arw_deg_sqrt_h']:.3f} deg/√h"))
    if s.get("ground_vehicle"):
        rows.append(("ground vehicle", "non-holonomic constraints"))
    rows.extend(graph_rows(s))
    return rows


def graph_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    """Summary rows of ``--method graph``: the calibration it estimated with the trajectory (GNSS lever arm, time
    offset, scale factors when on) with marginal sigmas, and the fixes its robust pass dropped."""
    if s.get("graph_lever_arm_m") is None:
        return []

    def pm(values: Any, sigmas: Any, digits: int) -> str:
        return ", ".join(f"{v:.{digits}f} ± {e:.{digits}f}" for v, e in zip(values, sigmas, strict=True))

    rows = [("GNSS lever arm", pm(s["graph_lever_arm_m"], s["graph_lever_arm_sigma_m"], 3)
             + " m (body x forward, y right, z down; estimated with the trajectory)"),
            ("GNSS time offset", f"{s['graph_time_offset_s'] * 1e3:.2f} ± "
             f"{s['graph_time_offset_sigma_s'] * 1e3:.2f} ms (each fix measured that long before its time tag)"),
            ("robust pass", f"{s['graph_rejected_fixes']} fix(es) dropped as outliers")]
    if s.get("graph_gyro_scale_ppm") is not None:
        rows.append(("scale factors", f"gyro {pm(s['graph_gyro_scale_ppm'], s['graph_gyro_scale_sigma_ppm'], 0)} ppm; "
                     f"accelerometer {pm(s['graph_accel_scale_ppm'], s['graph_accel_scale_sigma_ppm'], 0)} ppm "
                     f"(prior σ {s['graph_scale_prior_sigma_ppm']:.0f} ppm)"))
    return rows


def clock_name(kind: str, first_s: float) -> str:
    """What a run's times count: POS.txt and autopilot logs UTC seconds of the day; a bag's or imu.csv's stamps
    from 1e9 s on Unix seconds (georef.io.sbet.UNIX_FROM_S); other imu.csv times the IMU's own clock."""
    if first_s >= 1e9:
        return "Unix time (UTC)"
    if kind.startswith(("imu.csv", "ROS")):
        return "on the IMU's clock"
    return "UTC of day"


def print_summary(result: Any, output: Path, verbose: bool, to: Console) -> None:
    s = result.summary()
    from rich.table import Table

    table = Table(title=f"georef process ({escape(str(s['method']))}) -> {target_text(output)}", show_header=False,
                  title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    t0, t1 = s["time_span_s"]
    table.add_row("frames written", f"{s['frames_written']} ({s['frames_flagged']} flagged)")
    if s["frames_outside_span"]:
        table.add_row("outside nav span", f"{s['frames_outside_span']} frames: rows kept, values empty")
    if s["frames_in_outage"]:
        table.add_row("in GNSS outage", f"{s['frames_in_outage']} frames")
    if s["frames_after_last_fix"] or s["frames_before_first_fix"]:
        table.add_row("beyond the GNSS fixes", f"{s['frames_before_first_fix']} frames before the first fix, "
                      f"{s['frames_after_last_fix']} after the last (inertial only)")
    table.add_row("time span", f"{t0:.2f} - {t1:.2f} s {clock_name(result.log.kind, t0)} ({t1 - t0:.1f} s), "
                  f"{s['imu_rows']} IMU rows at {s['imu_rate_hz']:.1f} Hz")
    gaps = s["gnss_gaps"]
    table.add_row("GNSS epochs", f"{s['gnss_epochs']} ({s['gnss_used']} used, "
                  f"{len(s['gnss_rejected_lines'])} rejected, {len(gaps)} gaps)")
    if s["gnss_rejected_lines"]:
        rejected = result.nav.gnss
        shown = [f"{t:.0f} s (line {line})" for t, line in
                 zip(rejected.time[rejected.status == 0], rejected.line[rejected.status == 0], strict=True)]
        table.add_row("rejected fixes", ", ".join(shown[:20]) + (" ..." if len(shown) > 20 else ""))
    for start, end in gaps[:10]:
        table.add_row("GNSS gap", f"{start:.0f} - {end:.0f} s ({end - start:.0f} s)")
    if s["yaw_offset_deg"] is not None:
        table.add_row("yaw offset", f"{s['yaw_offset_deg']:.3f} ± {s['yaw_offset_sigma_deg']:.3f} deg, drift "
                      f"{s['yaw_drift_deg_per_min']:.3f} ± {s['yaw_drift_sigma_deg_per_min']:.3f} deg/min")
    for what, text in filter_rows(s):
        table.add_row(what, text)
    table.add_row("time quirks repaired", str(s["time_quirks_repaired"]))
    from georef.io.pos_time_scale import time_scale_lines

    for line in time_scale_lines(result.notices):  # a .pos's scale, GPST vs UTC: never only a notice cut off
        table.add_row("time scale", escape(line))
    if s.get("output_crs") or s.get("output_heights") != "WGS 84 ellipsoidal":
        table.add_row("coordinates", escape(f"{s.get('output_crs') or 'WGS 84'}, heights {s['output_heights']}"))
        for used in s.get("proj_transformations", []):
            table.add_row("PROJ", escape(str(used)))
    eo = result.columns  # numpy arrays: pandas is not imported for a summary
    valid = ~np.isnan(np.asarray(eo["sigma_n"], dtype=float))
    if valid.any():
        horizontal = np.hypot(eo["sigma_n"][valid], eo["sigma_e"][valid])
        table.add_row("median sigma", f"horizontal {np.median(horizontal):.2f} m, vertical "
                      f"{np.median(eo['sigma_u'][valid]):.2f} m, yaw {np.median(eo['sigma_yaw'][valid]):.2f} deg")
    to.print(table)
    notices = result.notices
    if notices:
        shown = notices if verbose else notices[:5]
        for notice in shown:
            console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)
        if len(notices) > len(shown):
            console.print(f"[yellow]notice:[/] ... {len(notices) - len(shown)} more (use --verbose)")
