"""The command line's hand-offs: what ``process`` and ``fuse`` write after processing for geotagged image copies
(``--images``, ``--export images:DIR``) and SBETs (``--export sbet:FILE``), with RTKLIB/Emlid solutions on the
IMU's clock (``--time-scale``). What they check before processing is :func:`georef.pipeline.preflight`'s; the
formats themselves are in ``georef.io``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .output import is_stdout, write_target


def export_images(result: Any, images: Path, target: Path, clock_offset: float | None, utc_date: str | None,
                  files: dict[str, Path | None], time_scale: str) -> Any:
    """Write the geotagged copies. The run's times are put on UTC seconds of their day first, dated as an SBET's
    are (:func:`process_sbet_clock`: an autopilot log's date, a .pos's, a bag's Unix stamps, or ``--utc-date``);
    a run nothing dates (POS.txt or imu.csv without ``--utc-date``) keeps its UTC seconds of the day and the
    photos' capture times may date it."""
    from georef.frames.gpstime import utc_day_start
    from georef.io.image_export import export_images
    from georef.io.sbet import SbetExportError

    try:
        clock = process_sbet_clock(result, utc_date, files, time_scale)
    except SbetExportError:
        if utc_date is not None:
            raise
        clock = None
    columns, day_start, source = result.columns, None, None
    if clock is not None:
        source = clock.source
        if clock.scale == "utc-day":
            day_start = clock.day_start_posix
        else:  # Unix seconds or GPS seconds of a week: UTC seconds of the first exposure's day
            utc = clock.utc(np.asarray(columns["time"], dtype=float))
            finite = utc[np.isfinite(utc)]
            day_start = utc_day_start(float(finite[0])) if len(finite) else clock.day_start_posix
            columns = {**columns, "time": utc - day_start}
    return export_images(columns, images, target, frames=result.frames, fixed_offset_s=clock_offset,
                         day_start_posix=day_start, date_source=source)


def with_image_checks(verdict: Any, exports: list[Any]) -> Any:
    """The run's QC verdict with the images checks of ``exports`` (photos matched by name: docs/images.md)."""
    checks = [check for check in (done.check() for done in exports) if check is not None]
    return type(verdict)((*verdict.checks, *checks)) if checks else verdict


def solution_scale(files: dict[str, Path | None], imu_time: Any, time_scale: str, bag: bool) -> Any:
    """The scale (:class:`georef.io.pos_time_scale.ScaleChoice`) the first RTKLIB/Emlid solution file among
    ``files`` (option -> path: --gnss, a .pos; --events, an _events.pos) put the IMU's times ``imu_time`` on, as
    the readers chose it (the same choice, made again from the file), with the option's name; (None, "") when
    none is one."""
    from georef.io.pos_time_scale import choose_time_scale, is_solution_file
    from georef.io.rtklib import read_pos_solution

    for option, path in files.items():
        if path is None or not is_solution_file(path):
            continue
        solution = read_pos_solution(path)
        if option == "--events":  # as read_events_on_imu_scale: every time mark, with a position or without
            marks, what = np.sort(np.concatenate([solution.utc, solution.invalid_mark_utc])), "camera events"
        elif len(solution):
            marks, what = solution.utc, "GNSS fixes"
        else:
            continue
        return choose_time_scale(path, marks, imu_time, time_scale, what=what, bag=bag), f"{option} {path.name}"
    return None, ""


def sbet_clock(imu_time: Any, utc_date: str | None, files: dict[str, Path | None], time_scale: str = "auto",
               bag: bool = False, imu_label: str = "imu.csv", log_day_start: float | None = None) -> Any:
    """What the run's times are and their date, for an SBET (:func:`georef.io.sbet.run_clock`): an autopilot
    log's date, a solution file's among ``files`` (option -> path), Unix stamps, or ``--utc-date``."""
    from georef.io.sbet import run_clock

    choice, name = solution_scale(files, imu_time, time_scale, bag) if log_day_start is None else (None, "")
    return run_clock(imu_time, utc_date, log_day_start=log_day_start, solution=choice, solution_name=name,
                     bag=bag, imu_label=imu_label)


def write_fuse_outputs(nav: Any, gyro: Any, accel: Any, output: Path, sbet_specs: list[Any], rate: float | None,
                        clock: Any) -> list[Any]:
    """The trajectory and the SBETs asked for, all or nothing (a trajectory on standard output comes last)."""
    from georef.io.atomic import atomic_group
    from georef.io.generic import write_trajectory_csv
    from georef.io.sbet import ImuRows, write_sbet

    done = []
    with atomic_group():
        if not is_stdout(output):
            write_trajectory_csv(nav, output)
        done = [write_sbet(nav, ImuRows(gyro=gyro, accel=accel), spec.path, clock, rate) for spec in sbet_specs]
    if is_stdout(output):
        write_target(output, lambda path: write_trajectory_csv(nav, path))
    return done


def process_sbet_clock(result: Any, utc_date: str | None, files: dict[str, Path | None], time_scale: str) -> Any:
    """:func:`sbet_clock` of a ``process`` run: its inputs ``files`` as the summary names them (log, bag, imu,
    gnss, events, pos)."""
    flight = getattr(result, "flight", None)
    bag = files.get("bag") is not None
    label = "the bag's IMU" if bag else Path(files["imu"]).name if files.get("imu") is not None else "POS.txt"
    return sbet_clock(result.log.time, utc_date, {"--gnss": files.get("gnss"), "--events": files.get("events")},
                      time_scale, bag=bag, imu_label=label,
                      log_day_start=None if flight is None else float(flight.day_start_utc))
