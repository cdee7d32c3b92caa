"""``georef calibrate-boresight``: reading the inputs, writing calibration.toml and printing the table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from georef.calibration.boresight import BoresightCalibration, calibrate, calibration_toml, match_photos
from georef.io.adjusted_cameras import read_adjusted_cameras
from georef.io.atomic import atomic_write
from georef.io.errors import InputError


def run(eo_path: Path, adjusted_path: Path, fmt: str | None, crs: str, boresight_deg: Any, lever_arm_m: Any,
        output: Path, ellipsoidal: bool, process_summary: Path | None = None) -> BoresightCalibration:
    """Read both tables (and the process run's ``--summary-json`` when given), estimate, write ``output``
    (calibration.toml) atomically; the result."""
    from georef.io.eo_table import read_eo_csv
    from georef.io.process_summary import read_process_summary

    if not eo_path.is_file():
        raise InputError(eo_path, None, None, "EO table not found")
    try:
        eo = read_eo_csv(eo_path)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(eo_path, None, None, f"not a readable EO table: {exc}") from None
    process = None if process_summary is None else read_process_summary(process_summary)
    cameras = read_adjusted_cameras(adjusted_path, fmt)
    photos = match_photos(eo, eo_path, cameras, crs, use_orthometric=not ellipsoidal)
    result = calibrate(photos, boresight_deg, lever_arm_m, source=f"{eo_path} + {adjusted_path}", process=process)
    text = calibration_toml(result, eo_path.name, adjusted_path.name)
    with atomic_write(output) as handle:
        handle.write(text)
    return result


def print_result(result: BoresightCalibration, output: Path, to: Console, warn: Console) -> None:
    """The calibration as a table (configured, correction, sigma, jackknife, calibrated) plus the reasons."""
    from rich import box

    table = Table(title=escape(f"boresight [deg] / camera lever arm [m, body] -> {output}: {result.photos_used} "
                               f"photos in {len(result.strips)} strips ({result.photos_in_turns} in turns not used); "
                               "sigma = total, strips = between-strip part, jackk. = jackknife over strips"),
                  title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    for column in ("", "config", "corr", "sigma", "strips", "jackk.", "new", "applied"):
        table.add_column(column, justify="left" if not column else "right")
    for c in result.boresight + result.lever_arm:
        digits = 4 if c.unit == "deg" else 3
        what = c.name if c.unit == "deg" else f"lever {c.name}"
        jk = "-" if c.jackknife_sigma is None else f"{c.jackknife_sigma:.{digits}f}"
        table.add_row(what, f"{c.configured:.{digits}f}", f"{c.value:+.{digits}f}", f"{c.sigma:.{digits}f}",
                      f"{c.model_sigma:.{digits}f}", jk, f"{c.calibrated:.{digits}f}",
                      "yes" if c.estimated else "[yellow]no[/]")
    to.print(table)
    to.print(f"body-fixed INS errors in the sigmas: {escape(result.sigma_source)}", highlight=False)
    for c in result.boresight + result.lever_arm:
        if c.why:
            kind = "boresight" if c.unit == "deg" else "lever arm"
            to.print(f"[bold]{kind} {c.name}:[/] {escape(c.why)}", highlight=False)
    if result.ins_tilt_deg is not None:
        to.print(f"INS flight-constant tilt (N, E) separated by the headings: {result.ins_tilt_deg[0]:+.4f}, "
                 f"{result.ins_tilt_deg[1]:+.4f} deg", highlight=False)
    if result.unmatched_labels:
        shown = ", ".join(result.unmatched_labels[:5])
        warn.print(f"[yellow]notice:[/] {len(result.unmatched_labels)} adjusted camera(s) match no EO row: "
                   f"{escape(shown)}{' ...' if len(result.unmatched_labels) > 5 else ''}", highlight=False)
    if result.eo_rows_flagged:
        warn.print(f"[yellow]notice:[/] {result.eo_rows_flagged} matched EO row(s) are flagged or lack a value and "
                   "were not used", highlight=False)
    for problem in result.problems:
        warn.print(f"[bold red]weak:[/] {escape(problem)}", highlight=False)
    for advice in dict.fromkeys(result.advice):
        warn.print(f"[yellow]advice:[/] {escape(advice)}", highlight=False)
