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
from georef.eo import (
    FLAG_AFTER_LAST_FIX,
    FLAG_BEFORE_FIRST_FIX,
    FLAG_OUTSIDE,
    EoColumns,
    camera_eo_columns,
    eo_frame,
    flag_mask,
)
from georef.exposure import interpolate_to_exposures
from georef.frames.rotations import wrap_pi
from georef.fusion import axis, ins
from georef.fusion.ins_layout import BA, BG, LEVER, NX_CAL, UNIT_DRIFT, UNIT_YAW
from georef.fusion.solution import NavSolution
from georef.io.camera import Exposures
from georef.io.camera import read_exposures as read_camera_exposures
from georef.io.errors import GeorefError, InputNotice
from georef.io.events import read_events
from georef.io.image_names import ImageNames
from georef.io.pos import PosLog, read_pos
from georef.qc import unapplied_latency
from georef.timing import to_reference_day

if TYPE_CHECKING:
    from collections.abc import Mapping

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
        """Figures for the end-of-run report (units in the keys). The yaw-offset figures are those of
        ``--method axis`` (None otherwise); the heading source, the unit's yaw origin and the fitted noise those of
        the full-state filters (see :func:`solution_figures`)."""
        yaw = self.nav.axis_info.yaw_offset if self.nav.axis_info is not None else None
        gnss = self.nav.gnss
        summary: dict[str, object] = {
            "frames_written": len(self.columns["flag"]),
            "frames_flagged": int(np.count_nonzero(np.asarray(self.columns["flag"], dtype=str) != "")),
            "frames_outside_span": int(np.count_nonzero(flag_mask(self.columns, FLAG_OUTSIDE))),
            "frames_in_outage": int(np.count_nonzero(flag_mask(self.columns, "GNSS outage"))),
            "frames_after_last_fix": int(np.count_nonzero(flag_mask(self.columns, FLAG_AFTER_LAST_FIX))),
            "frames_before_first_fix": int(np.count_nonzero(flag_mask(self.columns, FLAG_BEFORE_FIRST_FIX))),
            "time_span_s": (float(self.log.time[0]), float(self.log.time[-1])),
            "imu_rows": len(self.log),
            "imu_rate_hz": self.log.sample_rate_hz,
            "gnss_epochs": len(self.log.gnss),
            "gnss_used": int((gnss.status >= 1).sum()),
            "gnss_rejected_lines": gnss.rejected_lines,
            "gnss_gaps": self.log.gnss.gaps(),
            "yaw_offset_deg": None if yaw is None else float(np.degrees(yaw.offset)),
            "yaw_offset_sigma_deg": None if yaw is None else float(np.degrees(yaw.offset_sigma)),
            "yaw_drift_deg_per_min": None if yaw is None else float(np.degrees(yaw.drift) * 60),
            "yaw_drift_sigma_deg_per_min": None if yaw is None else float(np.degrees(yaw.drift_sigma) * 60),
            "time_quirks_repaired": self.log.time_repairs.n_quirks,
            "method": self.nav.method,
        }
        summary.update(solution_figures(self.nav, self.config.gnss, self.log.gnss.sigma_neu))
        summary.update(_flight_figures(self.flight))
        summary.update(geodesy_figures(self.frames, self.columns))
        return summary


def _held_out_figures(held: object) -> dict[str, object]:
    """The held-out check's figures (:class:`georef.fusion.solution.HeldOutCheck`), None where it did not run."""
    if held is None:
        return {"held_out_fixes": None, "held_out_error_m": None, "held_out_interpolation_m": None,
                "held_out_z": None, "held_out_diverged": None}

    def number(value: float) -> float | None:
        return float(value) if np.isfinite(value) else None

    return {"held_out_fixes": int(held.held), "held_out_error_m": number(held.error_rms_h),
            "held_out_interpolation_m": number(held.interpolation_rms_h), "held_out_z": number(held.z_rms),
            "held_out_diverged": bool(held.diverged)}


def _sigma_scale_figures(nav: NavSolution) -> dict[str, object]:
    """How far this flight bears out its own sigmas (1: as claimed; above 1: too small): ``sigma_scale_position``
    the held-out fixes' rms(error / sigma) (horizontal), ``sigma_scale_attitude`` [roll, pitch, yaw] the forward
    filter's separation from the smoothed attitude over that separation's sigma, RMS over the flight
    (:meth:`georef.fusion.solution.ForwardSeparation.sigma_scale`); None where there is nothing to measure."""
    held = getattr(nav.diagnostics, "held_out", None)
    position = float(held.z_rms) if held is not None and np.isfinite(held.z_rms) else None
    attitude = None
    if nav.forward is not None:
        _, scale = nav.forward.sigma_scale()
        attitude = [float(v) if np.isfinite(v) else None for v in scale]
    return {"sigma_scale_position": position, "sigma_scale_attitude": attitude}


def _flight_figures(flight: FlightLog | None) -> dict[str, object]:
    """An autopilot log's facts for the summary: its kind and vehicle, the IMU stream used, the boot clock's rate
    against UTC [ppm] and the fix messages' arrival jitter [s], and the fix types counted (None without a log)."""
    if flight is None:
        return {"log_kind": None, "vehicle": None, "imu_stream": None, "clock_rate_ppm": None,
                "clock_jitter_s": None, "gnss_fix_types": None}
    return {"log_kind": flight.kind, "vehicle": flight.vehicle, "imu_stream": flight.imu.name,
            "clock_rate_ppm": float((flight.clock.rate - 1.0) * 1e6), "clock_jitter_s": float(flight.clock.residual_s),
            "gnss_fix_types": dict(flight.gnss_report.fix_types)}


def geodesy_figures(frames: OutputFrames | None, table: Mapping[str, object]) -> dict[str, object]:
    """The output coordinates and what PROJ did to make them:

    * ``output_crs``: the projected CRS (None without one); ``output_heights``: "WGS 84 ellipsoidal" or the
      vertical CRS of the orthometric heights;
    * ``proj_transformations``: each transformation PROJ used, with its stated accuracy;
    * ``proj_accuracy_m``: the largest stated accuracy [m] (None: none stated or none used);
    * ``geodesy_warnings``: the transformations whose stated accuracy exceeds the median horizontal (or, for
      heights, vertical) sigma of the table (columns or a DataFrame) — georef's sigmas do not contain them.
    """
    if frames is None:
        return {"output_crs": None, "output_heights": "WGS 84 ellipsoidal", "proj_transformations": [],
                "proj_accuracy_m": None, "geodesy_warnings": []}
    used = frames.describe()
    stated = [t.accuracy_m for t in used if t.accuracy_m is not None]
    n, e, u = (np.asarray(table[name], dtype=float) for name in ("sigma_n", "sigma_e", "sigma_u"))
    valid = ~(np.isnan(n) | np.isnan(e) | np.isnan(u))
    horizontal = float(np.median(np.sqrt((n[valid] ** 2 + e[valid] ** 2) / 2))) if valid.any() else 0.0
    vertical = float(np.median(u[valid])) if valid.any() else 0.0
    warnings = []
    for t in used:
        height = t.what.startswith("WGS 84 ellipsoidal height")
        limit = vertical if height else horizontal
        if t.accuracy_m is None:
            warnings.append(f"{t.what}: PROJ states no accuracy for {t.description}")
        elif t.accuracy_m > limit:
            axis = "vertical" if height else "per-axis horizontal"
            warnings.append(f"{t.what}: PROJ states {t.accuracy_m:g} m for {t.description}, more than the median "
                            f"{axis} sigma {limit:.2f} m; the sigma columns do not include it")
    return {"output_crs": frames.horizontal_name, "output_heights": frames.height_name,
            "proj_transformations": [str(t) for t in used], "proj_accuracy_m": max(stated) if stated else None,
            "geodesy_warnings": warnings}


def solution_figures(nav: NavSolution, gnss: GnssSection, fix_sigma: np.ndarray | None = None) -> dict[str, object]:
    """What the full-state filters (``nav.diagnostics`` set) found, for summaries (empty for other methods):

    * ``heading_source``: where the initial heading came from;
    * ``unit_yaw_origin_deg``, ``unit_yaw_origin_sigma_deg``: the POS unit's yaw origin ``d`` (true yaw = unit
      yaw + d) at the filter's first row and its 1-sigma [deg], ``unit_yaw_drift_deg_per_min`` its drift over the
      flight (a straight line fitted to the smoothed origin) [deg/min] and ``unit_yaw_drift_sigma_deg_per_min`` the
      1-sigma of the smoothed drift state, RMS over the flight (the drift trades with the z-gyro bias wherever the
      motion does not show the heading; the frames' yaw sigmas carry that trade): only when the unit's attitude
      aided the filter;
    * ``gnss_sigma_fitted_m``: the GNSS sigmas north, east, up the fitted noise model uses [m]: sqrt(r_scale)
      times the median of the fixes' own sigmas ``fix_sigma`` (K, 3) [m] where the receiver gave them, else the
      configured ``gnss.sigma`` (the white part, when a correlated part was fitted too), ``vrw_m_s_sqrt_h`` the
      horizontal velocity random walk [m/s/sqrt(h)], ``arw_deg_sqrt_h`` the angle random walk about north/east
      [deg/sqrt(h)];
    * ``ground_vehicle``: non-holonomic constraints applied;
    * ``graph_lever_arm_m``, ``graph_lever_arm_sigma_m`` (``--method graph`` only): the GNSS lever arm [m, body x
      forward, y right, z down] estimated with the trajectory, and its marginal 1-sigma; ``graph_time_offset_s``,
      ``graph_time_offset_sigma_s`` the GNSS time offset [s] (each fix measured that long before its tag) and its
      1-sigma; ``graph_rejected_fixes`` the fixes the robust pass dropped; ``graph_gyro_scale_ppm``,
      ``graph_accel_scale_ppm`` and their ``..._sigma_ppm`` the scale-factor errors [ppm, body x, y, z] estimated
      with the trajectory (absent when ``graph_scale_factor_sigma`` is 0), ``graph_scale_prior_sigma_ppm`` their
      prior's 1-sigma: an axis whose sigma stays near it was not observable in this flight's motion;
    * ``accel_bias_sigma_m_s2`` [m/s^2, body x, y, z] and ``gyro_bias_sigma_deg_h`` [deg/h, body x, y, z]: the
      filter's 1-sigma of its accelerometer and gyro bias estimates (smoothed when an RTS pass ran), RMS over the
      covariance epochs of the flight; the accelerometer's x, y over g are the sigma of the INS tilt error fixed in
      the body frame (:func:`georef.frames.calibration.accel_bias_body_tilt`), which ``georef
      calibrate-boresight --process-summary`` uses. ``gnss_lever_arm_sigma_m`` [m, body] the same for the GNSS
      lever arm when the filter estimated it (else None). None for ``--method graph`` (the graph's trajectory has
      no bias marginals; the EKF + RTS it starts from are not the solution written).
    """
    diagnostics = nav.diagnostics
    if diagnostics is None:
        return {}
    noise = diagnostics.noise
    sigma = np.asarray(gnss.sigma, float) if fix_sigma is None else np.median(np.asarray(fix_sigma, float), axis=0)
    scale = np.sqrt([noise.r_scale_h, noise.r_scale_h, noise.r_scale_v])
    figures: dict[str, object] = {
        "heading_source": str(diagnostics.heading_source),
        "unit_yaw_origin_deg": None, "unit_yaw_origin_sigma_deg": None, "unit_yaw_drift_deg_per_min": None,
        "unit_yaw_drift_sigma_deg_per_min": None,
        "gnss_sigma_fitted_m": tuple(float(v) for v in sigma * scale),
        "vrw_m_s_sqrt_h": float(noise.vrw_h), "arw_deg_sqrt_h": float(noise.arw_h),
        "ground_vehicle": bool(diagnostics.ground_vehicle),
        "gnss_error_model": "white + Gauss-Markov" if getattr(diagnostics, "gnss_correlated", False) else "white",
        "still_spans_s": [tuple(float(v) for v in span) for span in (getattr(diagnostics, "still_spans", None) or [])],
        **_held_out_figures(getattr(diagnostics, "held_out", None)),
        **_sigma_scale_figures(nav),
        **_bias_sigma_figures(nav),
    }
    ins_info = nav.ins_info
    if diagnostics.unit_aiding and ins_info is not None and len(ins_info.epoch_sigma):
        origin, epoch_sigma, start = ins_info.unit_yaw_origin, ins_info.epoch_sigma, int(ins_info.start_row)
        rows = np.flatnonzero(nav.valid & np.isfinite(origin))
        rows = rows[rows >= start]
        if len(rows):
            d = np.unwrap(np.asarray(origin, float)[rows])
            figures["unit_yaw_origin_deg"] = float(np.degrees(wrap_pi(d[0])))
            figures["unit_yaw_origin_sigma_deg"] = float(np.degrees(epoch_sigma[0, UNIT_YAW]))
            if len(rows) > 1 and nav.time[rows[-1]] > nav.time[rows[0]]:
                slope = np.polyfit(nav.time[rows] - nav.time[rows[0]], d, 1)[0]
                figures["unit_yaw_drift_deg_per_min"] = float(np.degrees(slope) * 60.0)
                drift_sigma = np.sqrt(np.mean(epoch_sigma[:, UNIT_DRIFT] ** 2))
                figures["unit_yaw_drift_sigma_deg_per_min"] = float(np.degrees(drift_sigma) * 60.0)
    graph = nav.graph_info
    if graph is not None:  # --method graph: the lever arm estimated with the trajectory
        figures["graph_lever_arm_m"] = tuple(float(v) for v in graph.lever_arm_m)
        figures["graph_lever_arm_sigma_m"] = tuple(float(v) for v in graph.lever_arm_sigma_m)
        figures["graph_time_offset_s"] = float(graph.time_offset_s)
        figures["graph_time_offset_sigma_s"] = float(graph.time_offset_sigma_s)
        figures["graph_rejected_fixes"] = int(graph.rejected_fixes)
        scale = graph.scale_factors
        if scale is not None:
            for key, values in (("graph_gyro_scale_ppm", scale.gyro_ppm),
                                ("graph_gyro_scale_sigma_ppm", scale.gyro_sigma_ppm),
                                ("graph_accel_scale_ppm", scale.accel_ppm),
                                ("graph_accel_scale_sigma_ppm", scale.accel_sigma_ppm)):
                figures[key] = tuple(float(v) for v in values)
            figures["graph_scale_prior_sigma_ppm"] = float(scale.prior_sigma_ppm)
    return figures


def _bias_sigma_figures(nav: NavSolution) -> dict[str, object]:
    """The sensor-bias (and estimated GNSS lever-arm) 1-sigma of :func:`solution_figures`: RMS over the covariance
    epochs from the filter's first row (the RTS's smoothed sigmas when it ran, else the forward filter's)."""
    figures: dict[str, object] = {"accel_bias_sigma_m_s2": None, "gyro_bias_sigma_deg_h": None,
                                  "gnss_lever_arm_sigma_m": None}
    ins_info = nav.ins_info
    if nav.graph_info is not None or ins_info is None or not len(ins_info.epoch_sigma):
        return figures
    epochs = np.asarray(ins_info.epoch_rows) >= int(ins_info.start_row)
    sigma = np.asarray(ins_info.epoch_sigma, float)[epochs]
    if not len(sigma):
        return figures

    def rms(first: int) -> np.ndarray:
        return np.sqrt(np.mean(sigma[:, first:first + 3] ** 2, axis=0))

    figures["accel_bias_sigma_m_s2"] = tuple(float(v) for v in rms(BA))
    figures["gyro_bias_sigma_deg_h"] = tuple(float(v) for v in np.degrees(rms(BG)) * 3600.0)
    if sigma.shape[1] >= NX_CAL:
        figures["gnss_lever_arm_sigma_m"] = tuple(float(v) for v in rms(LEVER))
    return figures


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


def _output_frames(cfg: ProcessingConfig) -> OutputFrames | None:
    """The output CRS and heights, checked (grid installed, CRS known) before any input is read."""
    if cfg.output.crs or cfg.output.height != "ellipsoidal":
        from georef.frames.heights import OutputFrames

        return OutputFrames(cfg.output.crs, cfg.output.height, cfg.output.vertical_crs)
    return None


def process(pos_path: Path | str, camera_path: Path | str, cfg: ProcessingConfig,
            progress: Progress | None = None, calibration_prior: tuple | None = None) -> ProcessResult:
    """Georeference every frame of ``camera_path`` from the POS log ``pos_path`` with ``cfg.processing.method``.

    Takes the whole configuration: reading, fusing and the EO table use every section between them.
    ``calibration_prior`` (``--method graph`` only): a campaign's prior on (lever arm x, y, z [m, body], GNSS time
    offset [s]) as (mean (4,), covariance (4, 4)), replacing the flight's own (``georef batch
    --shared-calibration``; :func:`georef.fusion.graph.calibration_prior`)."""
    if calibration_prior is not None and cfg.processing.method != "graph":
        raise ValueError("a calibration prior is a prior of the graph's variables: it needs method 'graph'")
    say = progress or (lambda _step: None)
    _, roles = SOLVERS[cfg.processing.method]
    # the output CRS, its geoid grid and the image names are checked before any reading or fusing
    frames = _output_frames(cfg)
    image_names = ImageNames.parse(cfg.output.image_names) if cfg.output.image_names else None
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
                given: set[str] | None = None) -> ProcessResult:
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
    return process_flight(flight, cfg, exposures, names, progress, given, time.perf_counter() - start)


def _fusable_log(cfg: ProcessingConfig) -> None:
    if cfg.processing.method == "axis":
        raise GeorefError("--method axis needs a POS unit's own roll, pitch and yaw (POS.txt); an autopilot log "
                          "is fused with rts, ekf or graph")


def process_flight(flight: FlightLog, cfg: ProcessingConfig, exposures: Exposures | None = None,
                   image_names: ImageNames | None = None, progress: Progress | None = None,
                   given: set[str] | None = None, read_s: float = 0.0) -> ProcessResult:
    """Georeference an autopilot log already read (:func:`georef.io.logs.read_flight_log`): its camera events,
    or ``exposures`` (times on the log's UTC-of-day scale [s]) instead; as :func:`process_log` otherwise."""
    from georef.io.logs.flightlog import to_pos_log

    say = progress or (lambda _step: None)
    _fusable_log(cfg)
    start = time.perf_counter()
    frames = _output_frames(cfg)
    if cfg.output.image_names:
        image_names = ImageNames.parse(cfg.output.image_names)
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
                    progress: Progress | None = None, time_scale: str = "auto") -> ProcessResult:
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
                                _EventsClock(time_scale, Path(imu_path).name, bag=False))


def process_bag(bag_path: Path | str, events_path: Path | str, cfg: ProcessingConfig,
                progress: Progress | None = None, imu_topic: str | None = None,
                gnss_topic: str | None = None, time_scale: str = "auto") -> ProcessResult:
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
    return _georeference_events(log, events_path, cfg, say, start, _EventsClock(time_scale, "the bag's IMU", bag=True))


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
                         start: float, clock: _EventsClock) -> ProcessResult:
    """Read the exposures of ``events_path`` on ``log``'s clock and georeference them. An _events.pos whose first
    event lies past the midnight (of UTC, or of the GPS week) the IMU's first row lies before is counted from the
    IMU's day, going on past 86400 s as the IMU's times do."""
    from georef.io.pos_time_scale import read_events_on_imu_scale

    frames = _output_frames(cfg)
    image_names = ImageNames.parse(cfg.output.image_names) if cfg.output.image_names else None
    say("reading exposures")
    exposures, names = read_events_on_imu_scale(events_path, log.time, clock.time_scale, clock.imu_name,
                                                bag=clock.bag)
    _shift_by_latency(exposures, cfg)
    return _georeference(log, exposures, cfg, frames, image_names or names, say, time.perf_counter() - start)
