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
                         frames: Any, image_names: str | None = None) -> None:
    """Before processing: --images and --export images:DIR come together, DIR is not the photos' folder, the
    EGM96 grid is there, the clock offset is a number and not given with image names (``image_names``: the
    --image-names option or flight.toml's, whose names some photo must have)."""
    if not targets:
        for option, value in (("--images", images), ("--camera-clock-offset", clock_offset)):
            if value is not None:
                raise typer.BadParameter(f"{option} is for --export images:DIR (geotagged copies of the photos), "
                                         "and no images export is asked for")
        return
    if clock_offset is not None and not np.isfinite(clock_offset):
        raise typer.BadParameter(f"--camera-clock-offset {clock_offset}: give the camera clock minus UTC in seconds")
    if clock_offset is not None and image_names:
        # named photos are paired by name; their offset is measured from the pairs, so a given one would be unused
        raise typer.BadParameter(f"--camera-clock-offset matches photos to frames by capture time, and image names "
                                 f"({image_names!r}, --image-names or image_names in the configuration) pair them by "
                                 "name; the offset is then measured from the named pairs and shown. Give one of them")
    from georef.io.image_export import check_image_export

    for target in targets:
        if not str(target) or str(target) == ".":
            raise typer.BadParameter("--export images:DIR: name the folder for the copies")
        check_image_export(images, target, frames, image_names)
    if len({t.resolve() for t in targets}) < len(targets):
        raise typer.BadParameter("--export images:DIR is asked for twice with one folder")


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


def check_sbet_request(specs: list[Any], utc_date: str | None, rate: float | None, dated: bool) -> None:
    """Before processing: an SBET goes to a file (two, in fact), its rate makes sense, ``--utc-date`` is a date
    with a GPS week, and it is given where nothing else can date the run (``dated``: the inputs may date
    themselves, an autopilot log, a bag or imu.csv, checked once read: :func:`georef.io.sbet.run_clock`)."""
    from georef.io.sbet import parse_utc_date

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
        parse_utc_date(utc_date)  # a date, after the GPS epoch
    elif not dated:
        raise typer.BadParameter("--export sbet needs GPS time, and POS.txt and imu.csv give UTC seconds of a day "
                                 "they do not name: add --utc-date YYYY-MM-DD")


def fuse_sbet_specs(export: list[str] | None, output: Path) -> list[Any]:
    """``georef fuse --export``: SBETs only (the other formats are of an EO table, which fuse does not make)."""
    from georef.io.exports import ExportSpec, check_exports, parse_export

    for text in export or []:  # before parse_export, whose error would list the EO table's formats as valid
        if not text.startswith("sbet:"):
            raise typer.BadParameter(f"georef fuse exports its trajectory as sbet:FILE only (an Applanix SBET), "
                                     f"not --export {text}; the EO table's formats and images:DIR are georef "
                                     "process's")
    specs = [parse_export(text) for text in export or []]
    check_exports([ExportSpec("csv", output), *specs] if not is_stdout(output) else specs, None)
    return specs


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

