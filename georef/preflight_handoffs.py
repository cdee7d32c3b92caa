"""The hand-offs' options, checked before processing (part of :func:`georef.preflight.preflight`): SBETs
(``--export sbet:FILE``, ``--utc-date``, ``--sbet-rate``) and geotagged image copies (``--images``,
``--export images:DIR``, ``--camera-clock-offset``). Refusals are :class:`georef.option_values.OptionError`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from georef.option_values import OptionError, is_stdout

if TYPE_CHECKING:
    from georef.frames.heights import OutputFrames
    from georef.io.exports import ExportSpec


def check_image_request(images: Path | None, targets: list[Path], clock_offset: float | None,
                        frames: OutputFrames | None, names: str | None = None) -> None:
    """--images and --export images:DIR come together, DIR is not the photos' folder, the EGM96 grid is there,
    the clock offset [s] is a number and not given with image names (``names``: the --image-names option or
    flight.toml's, whose names some photo must have)."""
    import numpy as np

    if not targets:
        for option, value in (("--images", images), ("--camera-clock-offset", clock_offset)):
            if value is not None:
                raise OptionError(f"{option} is for --export images:DIR (geotagged copies of the photos), and no "
                                  "images export is asked for")
        return
    if clock_offset is not None and not np.isfinite(clock_offset):
        raise OptionError(f"--camera-clock-offset {clock_offset}: give the camera clock minus UTC in seconds")
    if clock_offset is not None and names:
        # named photos are paired by name; their offset is measured from the pairs, so a given one would be unused
        raise OptionError(f"--camera-clock-offset matches photos to frames by capture time, and image names "
                          f"({names!r}, --image-names or image_names in the configuration) pair them by name; the "
                          "offset is then measured from the named pairs and shown. Give one of them")
    from georef.io.image_export import check_image_export

    for target in targets:
        if not str(target) or str(target) == ".":
            raise OptionError("--export images:DIR: name the folder for the copies")
        check_image_export(images, target, frames, names)
    if len({t.resolve() for t in targets}) < len(targets):
        raise OptionError("--export images:DIR is asked for twice with one folder")


def check_sbet_request(specs: list[ExportSpec], utc_date: str | None, rate: float | None, dated: bool) -> None:
    """An SBET goes to a file (two, in fact), its rate [Hz] makes sense, ``--utc-date`` is a date with a GPS week,
    and it is given where nothing else can date the run (``dated``: the inputs may date themselves, an autopilot
    log, a bag or imu.csv, checked once read: :func:`georef.io.sbet.run_clock`)."""
    import numpy as np

    from georef.io.sbet import parse_utc_date

    if not specs:
        if rate is not None:
            raise OptionError("--sbet-rate is the rate of --export sbet:FILE, and no SBET is asked for")
        return
    for spec in specs:
        if is_stdout(spec.path):
            raise OptionError("an SBET is written with its smrmsg file beside it: give a file, not -")
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise OptionError(f"--sbet-rate {rate}: give a positive rate in Hz")
    if utc_date is not None:
        parse_utc_date(utc_date)  # a date, after the GPS epoch
    elif not dated:
        raise OptionError("--export sbet needs GPS time, and POS.txt and imu.csv give UTC seconds of a day they do "
                          "not name: add --utc-date YYYY-MM-DD")


def fuse_sbet_specs(exports: list[str], output: Path) -> list[ExportSpec]:
    """``georef fuse --export``: SBETs only (the other formats are of an EO table, which fuse does not make)."""
    from georef.io.exports import ExportSpec, check_exports, parse_export

    for text in exports:  # before parse_export, whose error would list the EO table's formats as valid
        if not text.startswith("sbet:"):
            raise OptionError(f"georef fuse exports its trajectory as sbet:FILE only (an Applanix SBET), not "
                              f"--export {text}; the EO table's formats and images:DIR are georef process's")
    specs = [parse_export(text) for text in exports]
    check_exports([ExportSpec("csv", output), *specs] if not is_stdout(output) else specs, None)
    return specs
