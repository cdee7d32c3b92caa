"""The whole path of ``georef process``: read -> time-align -> fuse -> interpolate -> mount -> table.

>>> from georef.pipeline import process
>>> from georef.config import AxisSettings, CameraColumns, CameraSection, GnssSection, ProcessingConfig
>>> result = process("POS.txt", "Kamera.txt", ProcessingConfig().updated(lever_arm_gnss=(0.4, 0.1, -1.6)))
>>> result.table  # one row per frame, see georef.eo (a DataFrame; result.columns holds the same as numpy arrays)
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from georef.config import AxisSettings, CameraColumns, CameraSection, GnssSection, ProcessingConfig
from georef.eo import EoColumns, camera_eo_columns, eo_frame
from georef.exposure import interpolate_to_exposures
from georef.fusion import axis, ins
from georef.fusion.solution import NavSolution
from georef.io.camera import Exposures
from georef.io.camera import read_exposures as read_camera_exposures
from georef.io.errors import GeorefError, InputNotice
from georef.io.events import read_events
from georef.io.image_names import ImageNames
from georef.io.pos import PosLog, read_pos
from georef.preflight import OutputChecks, output_checks
from georef.preflight import preflight as preflight  # the commands' option checks, before any file is processed
from georef.qc import unapplied_latency
from georef.run_summary import RunSummary, filter_figures
from georef.timing import to_reference_day

if TYPE_CHECKING:
    import pandas as pd

    from georef.frames.heights import OutputFrames
    from georef.io.logs.flightlog import FlightLog

#: method -> (solver on a POS log, given the whole configuration and the campaign's calibration prior (graph
#: only), the POS columns it needs); each solver hands its method only the sections that method reads
SOLVERS: dict[str, tuple[Callable[[PosLog, ProcessingConfig, tuple | None], NavSolution], tuple[str, ...]]] = {
    "axis": (lambda log, cfg, _prior: axis.solve_axis(log, AxisSettings.of(cfg)), axis.REQUIRED_ROLES),
    "ekf": (lambda log, cfg, _prior: ins.solve_ekf(log, cfg), ins.REQUIRED_ROLES),
    "rts": (lambda log, cfg, _prior: ins.solve_rts(log, cfg), ins.REQUIRED_ROLES),
    "graph": (lambda log, cfg, prior: _solve_graph(log, cfg, prior), ins.REQUIRED_ROLES),
}


def _solve_graph(log: PosLog, cfg: ProcessingConfig, prior: tuple | None) -> NavSolution:
    """GTSAM is imported only when the graph method is used (it costs start-up time)."""
    from georef.fusion.graph import solve_graph

    return solve_graph(log, cfg, prior)

Progress = Callable[[str], None]


@dataclass
class ProcessResult:
    """Everything ``process`` produced: the EO table, the navigation solution and what was noticed.

    ``columns`` is the EO table as numpy arrays (:func:`georef.eo.camera_eo_columns`); ``table`` the same as a
    pandas DataFrame, made on first use (pandas is imported then: the CLI checks and writes the CSV table from
    ``columns`` and never pays for it). Assigning ``table`` replaces both."""

    columns: EoColumns
    nav: NavSolution
    log: PosLog
    exposures: Exposures
    config: ProcessingConfig
    notices: list[InputNotice] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    #: the output CRS and heights (None: WGS 84 ellipsoidal only)
    frames: OutputFrames | None = None
    #: the autopilot log the IMU and GNSS came from (its vehicle, clock, fix types, attitude), when one did
    flight: FlightLog | None = None
    _frame: pd.DataFrame | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def table(self) -> pd.DataFrame:
        """The EO table, one row per frame (:mod:`georef.eo`)."""
        if self._frame is None:
            self._frame = eo_frame(self.columns)
        return self._frame

    @table.setter
    def table(self, frame: pd.DataFrame) -> None:
        self._frame = frame
        self.columns = {name: frame[name].to_numpy() for name in frame.columns}

    def summary(self) -> dict[str, object]:
        """Figures for the end-of-run report (units in the keys; ``docs/qc.md``): the JSON form of
        :class:`georef.run_summary.RunSummary`."""
        return RunSummary.of(self).to_dict()


def solution_figures(nav: NavSolution, gnss: GnssSection, fix_sigma: np.ndarray | None = None) -> dict[str, object]:
    """What the full-state filters (``nav.diagnostics`` set) found, as the JSON keys of
    :class:`georef.run_summary.FilterFigures` (empty for other methods); ``fix_sigma`` (K, 3) [m]: the fixes' own
    sigmas north, east, up (None: the configured ``gnss.sigma``)."""
    figures = filter_figures(nav, gnss, fix_sigma)
    return {} if figures is None else figures.to_dict()


def recompute_unit_tilt(log: PosLog) -> None:
    """Replace the unit's ROLL and PITCH [deg] by the MEKF's from OMGS/ACCS (``--attitude-source imu``).

    The accelerometer aids only in straight, unaccelerated flight (``|f|`` within 0.1 m/s^2 of g and rotation
    below 1 deg/s): in a coordinated turn the apparent vertical is not gravity, and the gyros bridge it.
    The unit's YAW is kept: IACC is resolved on its azimuth reference.
    """
    from georef.attitude.mekf import run_mekf
    from georef.frames import dcm_to_euler

    for role in ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"):
        if role not in log.data:
            raise GeorefError(f"{log.path}: --attitude-source imu needs the raw IMU column "
                              f"{log.column_names.get(role, role)!r}")
    C_b_n, _, _ = run_mekf(log.time, np.radians(log.vector("gyro")), log.vector("acc"), gyro_noise=0.005,
                           accel_sigma=0.05, accel_gate=0.1, rate_gate=np.radians(1.0))
    roll, pitch, _ = dcm_to_euler(C_b_n)
    log.data["roll"], log.data["pitch"] = np.degrees(roll), np.degrees(pitch)
    log.notices.append(InputNotice(log.path, [], None, "roll and pitch recomputed from the raw IMU (MEKF)"))


def read_exposures(path: Path | str, camera: CameraSection, columns: CameraColumns) -> Exposures:
    """Kamera.txt or the camera's raw log, told apart by the raw log's ``Exposition`` header column (the raw log's
    clock at ``camera.utc_offset`` [h] from UTC; ``columns``: the header names of the roles)."""
    return read_camera_exposures(path, camera.utc_offset, columns.names)


def process(pos_path: Path | str, camera_path: Path | str, cfg: ProcessingConfig,
            progress: Progress | None = None, calibration_prior: tuple | None = None,
            checked: OutputChecks | None = None) -> ProcessResult:
    """Georeference every frame of ``camera_path`` from the POS log ``pos_path`` with ``cfg.processing.method``.

    Takes the whole configuration: reading, fusing and the EO table use every section between them.
    ``calibration_prior`` (``--method graph`` only): a campaign's prior on (lever arm x, y, z [m, body], GNSS time
    offset [s]) as (mean (4,), covariance (4, 4)), replacing the flight's own (``georef batch
    --shared-calibration``; :func:`georef.fusion.graph.calibration_prior`). ``checked``: the output CRS and image
    names as :func:`georef.preflight.preflight` checked them (None: checked here)."""
    if calibration_prior is not None and cfg.processing.method != "graph":
        raise ValueError("a calibration prior is a prior of the graph's variables: it needs method 'graph'")
    say = progress or (lambda _step: None)
    _, roles = SOLVERS[cfg.processing.method]
    # the output CRS, its geoid grid and the image names are checked before any reading or fusing
    frames, image_names = checked if checked is not None else output_checks(cfg)
    start = time.perf_counter()
    say("reading POS log")
    log = read_pos(pos_path, required_roles=roles, column_names=cfg.pos_columns.names, gnss_rate_hz=cfg.gnss.rate_hz)
    say("reading exposures")
    exposures = read_exposures(camera_path, cfg.camera, cfg.camera_columns)
    _shift_by_latency(exposures, cfg)
    exposures.time = to_reference_day(exposures.time, float(log.time[0]), float(log.time[-1]))
    read_s = time.perf_counter() - start
    if len(log.gnss) < 2:
        names = log.column_names
        raise GeorefError(f"{log.path}: no usable GNSS fix (columns {names.get('lat')}, {names.get('lon')}, "
                          f"{names.get('alt')} stay 0 or hold a single value); every method needs GNSS positions")
    return _georeference(log, exposures, cfg, frames, image_names, say, read_s, calibration_prior)


def _shift_by_latency(exposures: Exposures, cfg: ProcessingConfig) -> None:
    """Each exposure happened ``camera.time_offset`` [s] (the trigger latency) after its logged time, known to
    ``camera.time_sigma`` [s] where that is set (else to each source's own sigma)."""
    if cfg.camera.time_offset:
        exposures.time = exposures.time + float(cfg.camera.time_offset)
    if cfg.camera.time_sigma is not None:
        exposures.time_sigma = np.full(len(exposures), float(cfg.camera.time_sigma))


def _georeference(log: PosLog, exposures: Exposures, cfg: ProcessingConfig, frames: OutputFrames | None,
                  image_names: ImageNames | None, say: Progress, read_s: float,
                  calibration_prior: tuple | None = None, flight: FlightLog | None = None) -> ProcessResult:
    """Fuse ``log`` with ``cfg.processing.method`` and make the EO table of ``exposures`` (on the log's time
    scale): the path every input shares once it is read."""
    timings: dict[str, float] = {"read": read_s}
    if image_names is not None:
        image_names.names([str(f) for f in exposures.frame])  # a frame without a name fails before fusing
    if cfg.processing.attitude_source == "imu":
        say("recomputing roll and pitch from the raw IMU")
        recompute_unit_tilt(log)
        cfg = cfg.updated(unit_aiding=False)
    solver, _ = SOLVERS[cfg.processing.method]
    start = time.perf_counter()
    say(f"fusing ({cfg.processing.method})")
    nav = solver(log, cfg, calibration_prior)
    timings["fuse"] = time.perf_counter() - start
    start = time.perf_counter()
    say("interpolating to exposures")
    states = interpolate_to_exposures(nav, exposures.time)
    columns = camera_eo_columns(exposures, states, log.gnss, cfg.mounting, cfg.output, frames=frames,
                                image_names=image_names, position_lag_s=unapplied_latency(nav, cfg.gnss.latency))
    timings["interpolate"] = time.perf_counter() - start
    return ProcessResult(columns=columns, nav=nav, log=log, exposures=exposures, config=cfg,
                         notices=[*log.notices, *exposures.notices], timings=timings, frames=frames, flight=flight)


#: the flight.toml keys an autopilot log has defaults for: its GNSS lever arm parameters, and the IMU preset of
#: an autopilot's flight controller
LOG_DEFAULT_KEYS = ("lever_arm_gnss", "imu_preset")


def _given_keys(cfg: ProcessingConfig) -> set[str]:
    """Of LOG_DEFAULT_KEYS, those ``cfg`` holds at other than the defaults (a library caller's settings)."""
    default = ProcessingConfig()
    given = set()
    if cfg.mounting.lever_arm_gnss != default.mounting.lever_arm_gnss:
        given.add("lever_arm_gnss")
    if cfg.ins.imu_preset != default.ins.imu_preset:
        given.add("imu_preset")
    return given


def with_log_defaults(cfg: ProcessingConfig, flight: FlightLog, given: set[str] | None = None
                      ) -> tuple[ProcessingConfig, list[InputNotice]]:
    """``cfg`` with what an autopilot log says where the user said nothing (``given``: the flight.toml keys set on
    the command line or in a configuration; None: those that differ from the defaults): the GNSS lever arm from
    the autopilot's parameters and the ``autopilot`` IMU preset, each with a notice."""
    given = _given_keys(cfg) if given is None else set(given)
    notices: list[InputNotice] = []
    if "lever_arm_gnss" not in given and flight.lever_arm is not None:
        arm = flight.lever_arm.lever_arm
        cfg = cfg.updated(lever_arm_gnss=arm)
        notices.append(InputNotice(flight.path, [], flight.lever_arm.source, "GNSS lever arm "
                                   f"{arm[0]:.3f}, {arm[1]:.3f}, {arm[2]:.3f} m taken from the autopilot's "
                                   "parameters (--gnss-lever-arm overrides it)"))
    if "imu_preset" not in given:
        cfg = cfg.updated(imu_preset="autopilot")
        notices.append(InputNotice(flight.path, [], None, "IMU preset 'autopilot' (a flight controller's MEMS IMU "
                                   "with its thermal drift; --imu-preset overrides it)"))
    return cfg, notices


def process_log(log_path: Path | str, cfg: ProcessingConfig, events_path: Path | str | None = None,
                progress: Progress | None = None, imu_instance: int | None = None,
                given: set[str] | None = None, checked: OutputChecks | None = None) -> ProcessResult:
    """Georeference every camera event of an autopilot log (ArduPilot ``.bin``/``.log``, PX4 ``.ulg``, each also
    gzipped), or the exposures of ``events_path`` (events.csv, times on the log's UTC-of-day scale) instead.

    The log's lever-arm parameters and the ``autopilot`` IMU preset stand where ``cfg`` leaves them at their
    defaults (see :func:`with_log_defaults`; ``given`` names the keys the user set)."""
    from georef.io.logs import read_flight_log

    say = progress or (lambda _step: None)
    _fusable_log(cfg)
    start = time.perf_counter()
    say("reading autopilot log")
    flight = read_flight_log(log_path, imu_instance)
    exposures, names = None, None
    if events_path is not None:
        say("reading exposures")
        exposures, names = read_events(events_path)
    return process_flight(flight, cfg, exposures, names, progress, given, time.perf_counter() - start, checked)


def _fusable_log(cfg: ProcessingConfig) -> None:
    if cfg.processing.method == "axis":
        raise GeorefError("--method axis needs a POS unit's own roll, pitch and yaw (POS.txt); an autopilot log "
                          "is fused with rts, ekf or graph")


def process_flight(flight: FlightLog, cfg: ProcessingConfig, exposures: Exposures | None = None,
                   image_names: ImageNames | None = None, progress: Progress | None = None,
                   given: set[str] | None = None, read_s: float = 0.0,
                   checked: OutputChecks | None = None) -> ProcessResult:
    """Georeference an autopilot log already read (:func:`georef.io.logs.read_flight_log`): its camera events,
    or ``exposures`` (times on the log's UTC-of-day scale [s]) instead; as :func:`process_log` otherwise."""
    from georef.io.logs.flightlog import to_pos_log

    say = progress or (lambda _step: None)
    _fusable_log(cfg)
    start = time.perf_counter()
    checks = checked if checked is not None else output_checks(cfg)
    frames = checks.frames
    if checks.image_names is not None:
        image_names = checks.image_names
    cfg, notices = with_log_defaults(cfg, flight, given)
    log = to_pos_log(flight)
    log.notices.extend(notices)
    if exposures is None:
        if flight.events is None:
            raise GeorefError(f"{flight.path}: the log holds no camera events (ArduPilot CAM/TRIG, PX4 "
                              "camera_capture/camera_trigger): give the exposures with --events events.csv")
        exposures = copy.deepcopy(flight.events)
    _shift_by_latency(exposures, cfg)
    return _georeference(log, exposures, cfg, frames, image_names, say, read_s + time.perf_counter() - start,
                         flight=flight)


def process_generic(imu_path: Path | str, gnss_path: Path | str, events_path: Path | str, cfg: ProcessingConfig,
                    progress: Progress | None = None, time_scale: str = "auto",
                    checked: OutputChecks | None = None) -> ProcessResult:
    """Georeference every exposure of ``events.csv`` from the generic ``imu.csv`` and ``gnss.csv``
    (:mod:`georef.io.generic`; all three on one clock). An RTKLIB/Emlid ``.pos`` or ``_events.pos`` among them is
    put on imu.csv's time scale, ``time_scale`` or the one detected (:mod:`georef.io.pos_time_scale`)."""
    from georef.io.generic import read_generic_log

    _fusable_inputs(cfg, "imu.csv and gnss.csv")
    say = progress or (lambda _step: None)
    start = time.perf_counter()
    say("reading imu.csv and gnss.csv")
    log = read_generic_log(imu_path, gnss_path, time_scale)
    return _georeference_events(log, events_path, cfg, say, start,
                                _EventsClock(time_scale, Path(imu_path).name, bag=False), checked)


def process_bag(bag_path: Path | str, events_path: Path | str, cfg: ProcessingConfig,
                progress: Progress | None = None, imu_topic: str | None = None,
                gnss_topic: str | None = None, time_scale: str = "auto",
                checked: OutputChecks | None = None) -> ProcessResult:
    """Georeference every exposure of ``events.csv`` (times on the bag's header.stamp clock [s]) from a ROS 1 or
    ROS 2 bag's sensor_msgs/Imu and sensor_msgs/NavSatFix topics (:mod:`georef.io.rosbag`). An Emlid/RTKLIB
    ``_events.pos`` is put on ``time_scale`` (:data:`georef.io.pos_time_scale.CHOICES`): ``auto`` is ``unix``,
    a wall clock's stamps."""
    from georef.io.rosbag import read_bag

    _fusable_inputs(cfg, "a bag's IMU and GNSS")
    say = progress or (lambda _step: None)
    start = time.perf_counter()
    say("reading the bag")
    log = read_bag(bag_path, imu_topic, gnss_topic).to_pos_log()
    return _georeference_events(log, events_path, cfg, say, start, _EventsClock(time_scale, "the bag's IMU", bag=True),
                                checked)


@dataclass(frozen=True)
class _EventsClock:
    """How an events file's times reach the IMU's clock: ``time_scale`` for an RTKLIB/Emlid ``_events.pos``
    (:data:`georef.io.pos_time_scale.CHOICES`), the IMU's name for messages, whether the IMU is a bag's (Unix s)."""

    time_scale: str
    imu_name: str
    bag: bool


def _fusable_inputs(cfg: ProcessingConfig, what: str) -> None:
    if cfg.processing.method == "axis":
        raise GeorefError(f"--method axis needs a POS unit's own roll, pitch and yaw (POS.txt); {what} are fused "
                          "with rts, ekf or graph")


def _georeference_events(log: PosLog, events_path: Path | str, cfg: ProcessingConfig, say: Progress,
                         start: float, clock: _EventsClock, checked: OutputChecks | None = None) -> ProcessResult:
    """Read the exposures of ``events_path`` on ``log``'s clock and georeference them. An _events.pos whose first
    event lies past the midnight (of UTC, or of the GPS week) the IMU's first row lies before is counted from the
    IMU's day, going on past 86400 s as the IMU's times do."""
    from georef.io.pos_time_scale import read_events_on_imu_scale

    frames, image_names = checked if checked is not None else output_checks(cfg)
    say("reading exposures")
    exposures, names = read_events_on_imu_scale(events_path, log.time, clock.time_scale, clock.imu_name,
                                                bag=clock.bag)
    _shift_by_latency(exposures, cfg)
    return _georeference(log, exposures, cfg, frames, image_names or names, say, time.perf_counter() - start)
