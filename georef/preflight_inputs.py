"""Which of the four ways into ``georef process`` its inputs take, checked before anything is read but a log's first
bytes: an autopilot log (with its camera events, or events.csv), POS.txt with Kamera.txt, imu.csv + gnss.csv +
events.csv, or a ROS bag + events.csv (:func:`input_source`). Part of :func:`georef.preflight.preflight`; its
refusals are :class:`georef.option_values.OptionError`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from georef.option_values import OptionError

if TYPE_CHECKING:
    from georef.config import ProcessingConfig
    from georef.pipeline import ProcessResult
    from georef.preflight import OutputChecks


@dataclass(frozen=True)
class ProcessInputs:
    """The inputs ``georef process`` was given (None: not given): the log or POS.txt ``pos`` with ``camera``
    (Kamera.txt), the generic ``imu``, ``gnss`` and ``events`` files, the log's IMU instance, the ``bag`` with its
    topics, and the ``time_scale`` of an RTKLIB/Emlid .pos among them (:data:`georef.io.pos_time_scale.CHOICES`)."""

    pos: Path | None = None
    camera: Path | None = None
    imu: Path | None = None
    gnss: Path | None = None
    events: Path | None = None
    imu_instance: int | None = None
    bag: Path | None = None
    imu_topic: str | None = None
    gnss_topic: str | None = None
    time_scale: str = "auto"


@dataclass(frozen=True)
class InputSource:
    """The way in ``inputs`` take: ``way`` is "bag", "generic", "log" or "pos"."""

    way: str
    inputs: ProcessInputs

    @property
    def files(self) -> dict[str, Path | None]:
        """The input files as the run's summary names them."""
        given = self.inputs
        return {"bag": {"bag": given.bag, "events": given.events},
                "generic": {"imu": given.imu, "gnss": given.gnss, "events": given.events},
                "log": {"log": given.pos, "events": given.events},
                "pos": {"pos": given.pos, "camera": given.camera}}[self.way]

    def run(self, cfg: ProcessingConfig, progress: Callable[[str], None], given: set[str],
            checked: OutputChecks | None = None) -> ProcessResult:
        """Read, fuse and georeference with ``cfg`` (``given``: the flight.toml keys the user set, for an autopilot
        log's defaults; ``checked``: the output CRS and image names, checked by the preflight)."""
        from georef.pipeline import process, process_bag, process_generic, process_log

        inputs = self.inputs
        if self.way == "bag":
            return process_bag(inputs.bag, inputs.events, cfg, progress=progress, imu_topic=inputs.imu_topic,
                               gnss_topic=inputs.gnss_topic, time_scale=inputs.time_scale, checked=checked)
        if self.way == "generic":
            return process_generic(inputs.imu, inputs.gnss, inputs.events, cfg, progress=progress,
                                   time_scale=inputs.time_scale, checked=checked)
        if self.way == "log":
            return process_log(inputs.pos, cfg, inputs.events, progress=progress, imu_instance=inputs.imu_instance,
                               given=given, checked=checked)
        return process(inputs.pos, inputs.camera, cfg, progress=progress, checked=checked)


def input_source(inputs: ProcessInputs) -> InputSource:
    """Which of the four ways in ``inputs`` name, refused when they mix two or miss a file."""
    if inputs.bag is not None or inputs.imu_topic is not None or inputs.gnss_topic is not None:
        return _bag_source(inputs)
    if inputs.imu is not None or inputs.gnss is not None:
        if inputs.pos is not None or inputs.camera is not None:
            raise OptionError("--imu/--gnss take the place of a log: give either a log (and CAMERA for POS.txt) or "
                              "--imu, --gnss and --events")
        if inputs.imu is None or inputs.gnss is None or inputs.events is None:
            missing = ", ".join(name for name, value in (("--imu", inputs.imu), ("--gnss", inputs.gnss),
                                                         ("--events", inputs.events)) if value is None)
            raise OptionError(f"generic inputs need --imu, --gnss and --events together; missing {missing}")
        check_time_scale(inputs.time_scale, {"--gnss": inputs.gnss, "--events": inputs.events})
        return InputSource("generic", inputs)
    return _log_source(inputs)


def _bag_source(inputs: ProcessInputs) -> InputSource:
    bag_or_files(inputs.bag, inputs.imu_topic, inputs.gnss_topic, {"--imu": inputs.imu, "--gnss": inputs.gnss})
    if inputs.pos is not None or inputs.camera is not None:
        raise OptionError("--bag takes the place of a log: give either a log (and CAMERA for POS.txt) or --bag and "
                          "--events")
    if inputs.events is None:
        raise OptionError("--bag needs --events events.csv: the exposures, time [s] on the clock of the bag's "
                          "header.stamp (for a wall clock, Unix seconds)")
    if inputs.imu_instance is not None:
        raise OptionError("--imu-instance is for autopilot logs; a bag's IMU is chosen with --imu-topic")
    check_time_scale(inputs.time_scale, {"--events": inputs.events})
    # auto: a bag's stamps are Unix seconds for a wall clock, and an _events.pos goes there
    return InputSource("bag", inputs)


def _log_source(inputs: ProcessInputs) -> InputSource:
    """An autopilot log (told by its first bytes), else POS.txt with its CAMERA."""
    from georef.io.logs import sniff
    from georef.io.rosbag import is_bag

    pos, camera = inputs.pos, inputs.camera
    if pos is None:
        raise OptionError("give the flight's log (an autopilot log, or POS.txt with Kamera.txt), or --imu, --gnss "
                          "and --events")
    if inputs.time_scale != "auto":
        raise OptionError(f"--time-scale {inputs.time_scale} is for --imu/--gnss/--events and --bag/--events with "
                          "an RTKLIB/Emlid .pos or _events.pos; a log's times are on its own UTC-of-day scale")
    if is_bag(pos):
        raise OptionError(f"{pos} is a ROS bag: give it as --bag, with the exposures as --events events.csv")
    if sniff(pos) is not None:
        if camera is not None:
            raise OptionError(f"{camera}: an autopilot log brings its own camera events; give other exposure times "
                              "with --events events.csv (CAMERA is POS.txt's Kamera.txt)")
        return InputSource("log", inputs)
    if camera is None:
        raise OptionError(f"{pos} is not an autopilot log, so it is read as POS.txt, which needs its exposure "
                          "times: give Kamera.txt (or the camera's raw log) as CAMERA")
    for option, value in (("--events", inputs.events), ("--imu-instance", inputs.imu_instance)):
        if value is not None:
            raise OptionError(f"{option} is for autopilot logs and generic inputs; POS.txt takes Kamera.txt")
    return InputSource("pos", inputs)


def bag_or_files(bag: Path | None, imu_topic: str | None, gnss_topic: str | None,
                 files: dict[str, Path | None]) -> None:
    """--bag takes the place of ``files`` (option -> value: --imu, --gnss); --imu-topic/--gnss-topic need it."""
    if bag is not None:
        given = [option for option, value in files.items() if value is not None]
        if given:
            raise OptionError(f"--bag takes the place of {' and '.join(files)}: give either the bag or "
                              f"{' and '.join(files)}, not both ({', '.join(given)} given)")
        return
    for option, value in (("--imu-topic", imu_topic), ("--gnss-topic", gnss_topic)):
        if value is not None:
            raise OptionError(f"{option} picks a topic of --bag, and no --bag is given")
    missing = [option for option, value in files.items() if value is None]
    if missing:
        raise OptionError(f"give {' and '.join(files)}, or --bag; missing {', '.join(missing)}")


def check_time_scale(time_scale: str, files: dict[str, Path | None]) -> None:
    """``--time-scale`` puts an RTKLIB/Emlid .pos or _events.pos on the IMU's clock: refused when none of ``files``
    (option -> value) is one, where it would change nothing."""
    if time_scale == "auto":
        return
    from georef.io.rtklib import is_rtklib_pos

    if not any(path is not None and is_rtklib_pos(path) for path in files.values()):
        raise OptionError(f"--time-scale {time_scale} puts an RTKLIB/Emlid .pos or _events.pos on the IMU's "
                          f"clock, and {' and '.join(files)} hold none (a csv's times are on the IMU's clock "
                          "already)")
