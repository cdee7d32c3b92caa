"""The command line's hand-offs: what ``process`` and ``fuse`` check before processing and write after it for
geotagged image copies (``--images``, ``--export images:DIR``), SBETs (``--export sbet:FILE``), ROS bags (``--bag``)
and RTKLIB/Emlid solutions on the IMU's clock (``--time-scale``). The formats themselves are in ``georef.io``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import typer

from .output import is_stdout, write_target


def check_image_request(images: Path | None, targets: list[Path], clock_offset: float | None,
                         frames: Any) -> None:
    """Before processing: --images and --export images:DIR come together, DIR is not the photos' folder, the
    EGM96 grid is there, the clock offset is a number."""
    if not targets:
        for option, value in (("--images", images), ("--camera-clock-offset", clock_offset)):
            if value is not None:
                raise typer.BadParameter(f"{option} is for --export images:DIR (geotagged copies of the photos), "
                                         "and no images export is asked for")
        return
    if clock_offset is not None and not np.isfinite(clock_offset):
        raise typer.BadParameter(f"--camera-clock-offset {clock_offset}: give the camera clock minus UTC in seconds")
    from georef.io.image_export import check_image_export

    for target in targets:
        if not str(target) or str(target) == ".":
            raise typer.BadParameter("--export images:DIR: name the folder for the copies")
        check_image_export(images, target, frames)
    if len({t.resolve() for t in targets}) < len(targets):
        raise typer.BadParameter("--export images:DIR is asked for twice with one folder")


def export_images(result: Any, images: Path, target: Path, clock_offset: float | None,
                   utc_date: str | None) -> Any:
    """Write the geotagged copies; the flight's UTC day from the autopilot log or --utc-date when known."""
    from georef.io.image_export import export_images

    flight = getattr(result, "flight", None)
    logged = None if flight is None else getattr(flight, "day_start_utc", None)
    day_start, source = None, None
    if utc_date is not None or logged is not None:
        from georef.io.sbet import day_start_of

        day_start = day_start_of(utc_date, None if logged is None else float(logged))
        source = "the log's own date" if logged is not None else f"--utc-date {utc_date}"
    return export_images(result.columns, images, target, frames=result.frames, fixed_offset_s=clock_offset,
                         day_start_posix=day_start, date_source=source)


def check_sbet_request(specs: list[Any], utc_date: str | None, rate: float | None, dated: bool) -> None:
    """Before processing: an SBET goes to a file (two, in fact), its date is known, its rate makes sense."""
    from georef.io.sbet import day_start_of

    if not specs:
        if rate is not None:
            raise typer.BadParameter("--sbet-rate is the rate of --export sbet:FILE, and no SBET is asked for")
        return
    for spec in specs:
        if is_stdout(spec.path):
            raise typer.BadParameter("an SBET is written with its smrmsg file beside it: give a file, not -")
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise typer.BadParameter(f"--sbet-rate {rate}: give a positive rate in Hz")
    if utc_date is not None:
        day_start_of(utc_date, None)  # the date parses
    elif not dated:
        raise typer.BadParameter("--export sbet needs GPS time, and POS.txt and imu.csv give UTC seconds of a day "
                                 "they do not name: add --utc-date YYYY-MM-DD")


def fuse_sbet_specs(export: list[str] | None, output: Path) -> list[Any]:
    """``georef fuse --export``: SBETs only (the other formats are of an EO table, which fuse does not make)."""
    from georef.io.exports import ExportSpec, check_exports, parse_export

    specs = [parse_export(text) for text in export or []]
    for text, spec in zip(export or [], specs, strict=True):
        if spec.fmt != "sbet":
            raise typer.BadParameter(f"--export {text}: georef fuse writes a trajectory, and exports it as sbet:FILE "
                                     "only (the other formats are of the EO table: georef process)")
    check_exports([ExportSpec("csv", output), *specs] if not is_stdout(output) else specs, None)
    return specs


def fuse_day_start(utc_date: str | None, bag: bool, time_s: Any) -> float:
    """00:00 UTC [POSIX s] of the day fuse's times count from: ``--utc-date`` (imu.csv, .pos), else a bag's
    stamps taken as Unix seconds (the day 1970-01-01), refused when they cannot be (a simulated clock)."""
    from georef.io.sbet import SbetExportError, day_start_of

    if utc_date is not None or not bag:
        return day_start_of(utc_date, None)
    if float(time_s[0]) < 1e9:  # before 2001-09-09: not a wall clock
        raise SbetExportError(f"the bag's stamps start at {float(time_s[0]):.3f} s, not Unix time: give --utc-date "
                              "YYYY-MM-DD to take them as UTC seconds of that day")
    return 0.0


def write_fuse_outputs(nav: Any, gyro: Any, accel: Any, output: Path, sbet_specs: list[Any], rate: float | None,
                        day_start: float) -> list[Any]:
    """The trajectory and the SBETs asked for, all or nothing (a trajectory on standard output comes last)."""
    from georef.io.atomic import atomic_group
    from georef.io.generic import write_trajectory_csv
    from georef.io.sbet import ImuRows, write_sbet

    done = []
    with atomic_group():
        if not is_stdout(output):
            write_trajectory_csv(nav, output)
        done = [write_sbet(nav, ImuRows(gyro=gyro, accel=accel), spec.path, day_start, rate) for spec in sbet_specs]
    if is_stdout(output):
        write_target(output, lambda path: write_trajectory_csv(nav, path))
    return done


def sbet_day_start(result: Any, utc_date: str | None) -> float:
    """00:00 UTC [POSIX s] of the day the run's times count from: the autopilot log's, or ``--utc-date``."""
    from georef.io.sbet import day_start_of

    flight = getattr(result, "flight", None)
    return day_start_of(utc_date, None if flight is None else float(flight.day_start_utc))


def bag_or_files(bag: Path | None, imu_topic: str | None, gnss_topic: str | None,
                  files: dict[str, Path | None]) -> None:
    """--bag takes the place of ``files`` (option -> value: --imu, --gnss); --imu-topic/--gnss-topic need it."""
    if bag is not None:
        given = [option for option, value in files.items() if value is not None]
        if given:
            raise typer.BadParameter(f"--bag takes the place of {' and '.join(files)}: give either the bag or "
                                     f"{' and '.join(files)}, not both ({', '.join(given)} given)")
        return
    for option, value in (("--imu-topic", imu_topic), ("--gnss-topic", gnss_topic)):
        if value is not None:
            raise typer.BadParameter(f"{option} picks a topic of --bag, and no --bag is given")
    missing = [option for option, value in files.items() if value is None]
    if missing:
        raise typer.BadParameter(f"give {' and '.join(files)}, or --bag; missing {', '.join(missing)}")


def check_time_scale(time_scale: str, files: dict[str, Path | None]) -> None:
    """``--time-scale`` puts an RTKLIB/Emlid .pos or _events.pos on the IMU's clock: refused when none of ``files``
    (option -> value) is one, where it would change nothing."""
    if time_scale == "auto":
        return
    from georef.io.rtklib import is_rtklib_pos

    if not any(path is not None and is_rtklib_pos(path) for path in files.values()):
        raise typer.BadParameter(f"--time-scale {time_scale} puts an RTKLIB/Emlid .pos or _events.pos on the IMU's "
                                 f"clock, and {' and '.join(files)} hold none (a csv's times are on the IMU's clock "
                                 "already)")

