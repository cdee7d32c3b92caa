"""The summary of one ``georef process`` run, typed, built once from a :class:`georef.pipeline.ProcessResult`.

Three renderings read it: the JSON ``summary`` of ``--summary-json`` (:meth:`RunSummary.to_dict`, its keys are
the contract of ``docs/qc.md``), the table the terminal prints after a run and the report's "Summary" section
(:meth:`RunSummary.rows`, each row knowing where it is shown). ``georef fuse`` prints the full-state filters'
rows alone (:func:`filter_rows` of :class:`FilterFigures`).

Units are in the names: metres, degrees, seconds, ppm; times on the POS log's scale (UTC seconds of day for
POS.txt), shown in seconds on the terminal and as ``hh:mm:ss`` UTC in the report.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Literal, NamedTuple

import numpy as np

from georef.eo import FLAG_AFTER_LAST_FIX, FLAG_BEFORE_FIRST_FIX, FLAG_OUTSIDE, flag_mask
from georef.frames.rotations import wrap_pi
from georef.fusion.ins_layout import BA, BG, LEVER, NX_CAL, UNIT_DRIFT, UNIT_YAW

if TYPE_CHECKING:
    from georef.config import GnssSection
    from georef.frames.heights import OutputFrames
    from georef.fusion.solution import NavSolution
    from georef.io.logs.flightlog import FlightLog
    from georef.pipeline import ProcessResult

#: where a row is shown: the terminal's table after a run, the report's "Summary" section
Target = Literal["terminal", "report"]
TERMINAL: frozenset[Target] = frozenset({"terminal"})
REPORT: frozenset[Target] = frozenset({"report"})
BOTH: frozenset[Target] = TERMINAL | REPORT
DAY_S = 86_400.0
#: rejected fixes named in a row at most; GNSS gaps listed on the terminal, in the report
SHOWN_REJECTED = 20
SHOWN_GAPS_TERMINAL = 10
SHOWN_GAPS_REPORT = 20


class Row(NamedTuple):
    """One line of a summary table: its label, its text (None: nothing to show this time) and the JSON keys whose
    values it shows (the report lists the other keys' values on their own)."""

    label: str
    text: str | None
    keys: tuple[str, ...] = ()


class _Placed(NamedTuple):
    where: frozenset[Target]
    row: Row


def _row(where: frozenset[Target], label: str, text: str | None, *keys: str) -> _Placed:
    return _Placed(where, Row(label, text, keys))


@dataclass(frozen=True)
class Style:
    """How a rendering writes numbers: the terminal as Python formats them, the report with a true minus sign and
    a dash for a value that is not a number."""

    minus: str = "-"
    missing: str | None = None

    def number(self, value: float, digits: int = 3) -> str:
        if self.missing is not None and not math.isfinite(value):
            return self.missing
        return f"{value:.{digits}f}".replace("-", self.minus)


STYLES: dict[Target, Style] = {"terminal": Style(), "report": Style(minus="−", missing="—")}


# ---- times ----------------------------------------------------------------------------------------------------
def utc(seconds: float, digits: int = 1) -> str:
    """UTC seconds of day (continuous across midnight) as ``hh:mm:ss.s`` (``+1 d`` after midnight)."""
    if not math.isfinite(seconds):
        return "—"
    total = round(float(seconds), digits)
    day, rest = divmod(total, DAY_S)
    hours, rest = divmod(rest, 3600.0)
    minutes, secs = divmod(rest, 60.0)
    width = 2 + (digits + 1 if digits else 0)
    text = f"{int(hours):02d}:{int(minutes):02d}:{secs:0{width}.{digits}f}"
    return text + (f" (+{int(day)} d)" if day else "")


def utc_span(start: float, end: float, digits: int = 1) -> str:
    """``hh:mm:ss – hh:mm:ss UTC (n s)``."""
    return f"{utc(start, digits)} – {utc(end, digits)} UTC ({end - start:.{digits}f} s)"


def clock_name(kind: str, first_s: float) -> str:
    """What a run's times count: POS.txt and autopilot logs UTC seconds of the day; a bag's or imu.csv's stamps
    from 1e9 s on Unix seconds (georef.io.sbet.UNIX_FROM_S); other imu.csv times the IMU's own clock."""
    if first_s >= 1e9:
        return "Unix time (UTC)"
    if kind.startswith(("imu.csv", "ROS")):
        return "on the IMU's clock"
    return "UTC of day"


# ---- the full-state filters' figures ---------------------------------------------------------------------------
def floats_of(values: Sequence[float]) -> tuple[float, ...]:
    """Numbers (numpy's or a sequence's) as a tuple of Python floats, as the JSON summary holds them."""
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class GraphFigures:
    """What ``--method graph`` estimated with the trajectory: the GNSS lever arm [m, body x forward, y right,
    z down] and the GNSS time offset [s] (each fix measured that long before its tag) with marginal 1-sigmas, the
    fixes its robust pass dropped, and the scale-factor errors [ppm, body x, y, z] with their 1-sigmas and their
    prior's (None where ``graph_scale_factor_sigma`` is 0)."""

    graph_lever_arm_m: tuple[float, ...]
    graph_lever_arm_sigma_m: tuple[float, ...]
    graph_time_offset_s: float
    graph_time_offset_sigma_s: float
    graph_rejected_fixes: int
    graph_gyro_scale_ppm: tuple[float, ...] | None = None
    graph_gyro_scale_sigma_ppm: tuple[float, ...] | None = None
    graph_accel_scale_ppm: tuple[float, ...] | None = None
    graph_accel_scale_sigma_ppm: tuple[float, ...] | None = None
    graph_scale_prior_sigma_ppm: float | None = None

    @classmethod
    def of(cls, graph: object | None) -> GraphFigures | None:
        if graph is None:
            return None
        scale = graph.scale_factors

        def floats(values: Sequence[float] | None) -> tuple[float, ...] | None:
            return None if values is None else floats_of(values)

        return cls(floats_of(graph.lever_arm_m), floats_of(graph.lever_arm_sigma_m), float(graph.time_offset_s),
                   float(graph.time_offset_sigma_s), int(graph.rejected_fixes),
                   *(floats(getattr(scale, name, None)) for name in ("gyro_ppm", "gyro_sigma_ppm", "accel_ppm",
                                                                     "accel_sigma_ppm")),
                   None if scale is None else float(scale.prior_sigma_ppm))

    def to_dict(self) -> dict[str, object]:
        """The JSON keys: the scale factors' only where they were estimated."""
        every = {f.name: getattr(self, f.name) for f in fields(self)}
        return {k: v for k, v in every.items() if self.graph_gyro_scale_ppm is not None or "scale" not in k}


@dataclass(frozen=True)
class FilterFigures:
    """What the full-state filters found (``nav.diagnostics`` set); the fields are the JSON keys of
    ``docs/qc.md``:

    * ``heading_source``: where the initial heading came from;
    * ``unit_yaw_origin_deg``, ``unit_yaw_origin_sigma_deg``: the POS unit's yaw origin ``d`` (true yaw = unit
      yaw + d) at the filter's first row and its 1-sigma [deg], ``unit_yaw_drift_deg_per_min`` its drift over the
      flight (a straight line fitted to the smoothed origin) [deg/min] and ``unit_yaw_drift_sigma_deg_per_min`` the
      1-sigma of the smoothed drift state, RMS over the flight (the drift trades with the z-gyro bias wherever the
      motion does not show the heading; the frames' yaw sigmas carry that trade): only when the unit's attitude
      aided the filter;
    * ``gnss_sigma_fitted_m``: the GNSS sigmas north, east, up the fitted noise model uses [m]: sqrt(r_scale)
      times the median of the fixes' own sigmas (K, 3) [m] where the receiver gave them, else the configured
      ``gnss.sigma`` (the white part, when a correlated part was fitted too), ``vrw_m_s_sqrt_h`` the horizontal
      velocity random walk [m/s/sqrt(h)], ``arw_deg_sqrt_h`` the angle random walk about north/east [deg/sqrt(h)];
    * ``ground_vehicle``: non-holonomic constraints applied; ``noise_fit_passes``: the filter (+ smoother) passes
      the noise fit ran before the final pass (:class:`georef.fusion.ins._Estimation`), its cross-validation and
      calibration passes included;
    * ``gnss_error_model``, ``still_spans_s`` [[first, last], s], the held-out check's ``held_out_*`` (None where
      it did not run) and the sigma scale on this flight ``sigma_scale_position`` (the held-out fixes' rms(error /
      sigma), horizontal) and ``sigma_scale_attitude`` [roll, pitch, yaw] (the forward filter's separation from the
      smoothed attitude over its sigma, RMS; :meth:`georef.fusion.solution.ForwardSeparation.sigma_scale`);
    * ``accel_bias_sigma_m_s2`` [m/s^2, body x, y, z] and ``gyro_bias_sigma_deg_h`` [deg/h, body x, y, z]: the
      filter's 1-sigma of its accelerometer and gyro bias estimates (smoothed when an RTS pass ran), RMS over the
      covariance epochs of the flight; the accelerometer's x, y over g are the sigma of the INS tilt error fixed in
      the body frame (:func:`georef.frames.calibration.accel_bias_body_tilt`), which ``georef
      calibrate-boresight --process-summary`` uses. ``gnss_lever_arm_sigma_m`` [m, body] the same for the GNSS
      lever arm when the filter estimated it (else None). None for ``--method graph`` (the graph's trajectory has
      no bias marginals; the EKF + RTS it starts from are not the solution written);
    * ``graph``: what ``--method graph`` estimated with the trajectory (:class:`GraphFigures`), else None.
    """

    heading_source: str
    unit_yaw_origin_deg: float | None
    unit_yaw_origin_sigma_deg: float | None
    unit_yaw_drift_deg_per_min: float | None
    unit_yaw_drift_sigma_deg_per_min: float | None
    gnss_sigma_fitted_m: tuple[float, ...]
    vrw_m_s_sqrt_h: float
    arw_deg_sqrt_h: float
    ground_vehicle: bool
    noise_fit_passes: int
    gnss_error_model: str
    still_spans_s: list[tuple[float, ...]]
    held_out_fixes: int | None
    held_out_error_m: float | None
    held_out_interpolation_m: float | None
    held_out_z: float | None
    held_out_diverged: bool | None
    sigma_scale_position: float | None
    sigma_scale_attitude: list[float | None] | None
    accel_bias_sigma_m_s2: tuple[float, ...] | None
    gyro_bias_sigma_deg_h: tuple[float, ...] | None
    gnss_lever_arm_sigma_m: tuple[float, ...] | None
    graph: GraphFigures | None = None

    def to_dict(self) -> dict[str, object]:
        """The JSON keys, in the documented order (the graph's last)."""
        figures: dict[str, object] = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "graph"}
        if self.graph is not None:
            figures.update(self.graph.to_dict())
        return figures

    @classmethod
    def from_dict(cls, figures: Mapping[str, object]) -> FilterFigures | None:
        """The figures back from :meth:`to_dict` (None for an empty dict: not a full-state filter's run)."""
        if figures.get("heading_source") is None:
            return None
        graph_names = [f.name for f in fields(GraphFigures)]
        graph = (GraphFigures(**{k: figures.get(k) for k in graph_names})
                 if figures.get("graph_lever_arm_m") is not None else None)
        return cls(**{f.name: figures.get(f.name) for f in fields(cls) if f.name != "graph"}, graph=graph)


def filter_figures(nav: NavSolution, gnss: GnssSection, fix_sigma: np.ndarray | None = None) -> FilterFigures | None:
    """What the full-state filters found (:class:`FilterFigures`); None for other methods. ``fix_sigma`` (K, 3)
    [m]: the fixes' own sigmas north, east, up (None: the configured ``gnss.sigma`` stands)."""
    diagnostics = nav.diagnostics
    if diagnostics is None:
        return None
    noise = diagnostics.noise
    sigma = np.asarray(gnss.sigma, float) if fix_sigma is None else np.median(np.asarray(fix_sigma, float), axis=0)
    scale = np.sqrt([noise.r_scale_h, noise.r_scale_h, noise.r_scale_v])
    held = getattr(diagnostics, "held_out", None)
    return FilterFigures(
        heading_source=str(diagnostics.heading_source), **_unit_yaw_figures(nav),
        gnss_sigma_fitted_m=tuple(float(v) for v in sigma * scale),
        vrw_m_s_sqrt_h=float(noise.vrw_h), arw_deg_sqrt_h=float(noise.arw_h),
        ground_vehicle=bool(diagnostics.ground_vehicle),
        noise_fit_passes=int(getattr(diagnostics, "estimation_passes", 0)),
        gnss_error_model="white + Gauss-Markov" if getattr(diagnostics, "gnss_correlated", False) else "white",
        still_spans_s=[tuple(float(v) for v in span) for span in (getattr(diagnostics, "still_spans", None) or [])],
        **_held_out_figures(held), **_sigma_scale_figures(nav, held), **_bias_sigma_figures(nav),
        graph=GraphFigures.of(nav.graph_info))


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _held_out_figures(held: object | None) -> dict[str, object]:
    """The held-out check's figures (:class:`georef.fusion.solution.HeldOutCheck`), None where it did not run."""
    if held is None:
        return {"held_out_fixes": None, "held_out_error_m": None, "held_out_interpolation_m": None,
                "held_out_z": None, "held_out_diverged": None}
    return {"held_out_fixes": int(held.held), "held_out_error_m": _finite(held.error_rms_h),
            "held_out_interpolation_m": _finite(held.interpolation_rms_h), "held_out_z": _finite(held.z_rms),
            "held_out_diverged": bool(held.diverged)}


def _sigma_scale_figures(nav: NavSolution, held: object | None) -> dict[str, object]:
    """How far this flight bears out its own sigmas (1: as claimed; above 1: too small); None where there is
    nothing to measure."""
    position = float(held.z_rms) if held is not None and np.isfinite(held.z_rms) else None
    attitude = None
    if nav.forward is not None:
        _, scale = nav.forward.sigma_scale()
        attitude = [_finite(v) for v in scale]
    return {"sigma_scale_position": position, "sigma_scale_attitude": attitude}


def _unit_yaw_figures(nav: NavSolution) -> dict[str, float | None]:
    """The unit's yaw origin at the filter's first row, its drift and their 1-sigmas [deg, deg/min] (None without
    the unit's attitude aiding)."""
    figures: dict[str, float | None] = {"unit_yaw_origin_deg": None, "unit_yaw_origin_sigma_deg": None,
                                        "unit_yaw_drift_deg_per_min": None, "unit_yaw_drift_sigma_deg_per_min": None}
    ins_info = nav.ins_info
    if not nav.diagnostics.unit_aiding or ins_info is None or not len(ins_info.epoch_sigma):
        return figures
    origin, epoch_sigma, start = ins_info.unit_yaw_origin, ins_info.epoch_sigma, int(ins_info.start_row)
    rows = np.flatnonzero(nav.valid & np.isfinite(origin))
    rows = rows[rows >= start]
    if not len(rows):
        return figures
    d = np.unwrap(np.asarray(origin, float)[rows])
    figures["unit_yaw_origin_deg"] = float(np.degrees(wrap_pi(d[0])))
    figures["unit_yaw_origin_sigma_deg"] = float(np.degrees(epoch_sigma[0, UNIT_YAW]))
    if len(rows) > 1 and nav.time[rows[-1]] > nav.time[rows[0]]:
        slope = np.polyfit(nav.time[rows] - nav.time[rows[0]], d, 1)[0]
        figures["unit_yaw_drift_deg_per_min"] = float(np.degrees(slope) * 60.0)
        drift_sigma = np.sqrt(np.mean(epoch_sigma[:, UNIT_DRIFT] ** 2))
        figures["unit_yaw_drift_sigma_deg_per_min"] = float(np.degrees(drift_sigma) * 60.0)
    return figures


def _bias_sigma_figures(nav: NavSolution) -> dict[str, object]:
    """The sensor-bias (and estimated GNSS lever-arm) 1-sigma: RMS over the covariance epochs from the filter's
    first row (the RTS's smoothed sigmas when it ran, else the forward filter's)."""
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


def filter_rows(figures: FilterFigures | None, target: Target = "terminal") -> list[Row]:
    """The full-state filters' rows shown on ``target`` (``georef fuse`` prints the terminal's)."""
    return [p.row for p in _filter_rows(figures, STYLES[target]) if target in p.where and p.row.text is not None]


def _filter_rows(f: FilterFigures | None, style: Style) -> list[_Placed]:
    """Heading source, the unit's yaw origin, the sigma scale on this flight, the fitted noise, the ground-vehicle
    constraints, and what the graph estimated; none for the other methods."""
    if f is None:
        return []
    num = style.number
    rows = [_row(BOTH, "heading source", f.heading_source, "heading_source")]
    if f.unit_yaw_origin_deg is not None:
        drift, drift_sigma = f.unit_yaw_drift_deg_per_min, f.unit_yaw_drift_sigma_deg_per_min
        drift_text = "" if drift is None else f", drift {num(drift)}" + (
            f" ± {num(drift_sigma)}" if drift_sigma is not None else "") + " deg/min"
        rows.append(_row(BOTH, "unit yaw origin", f"{num(f.unit_yaw_origin_deg)} ± "
                         f"{num(f.unit_yaw_origin_sigma_deg)} deg at the start (true yaw = unit yaw + origin)"
                         + drift_text, "unit_yaw_origin_deg", "unit_yaw_origin_sigma_deg",
                         "unit_yaw_drift_deg_per_min", "unit_yaw_drift_sigma_deg_per_min"))
    rows.append(_sigma_scale_row(f, style))
    sigma_n, sigma_e, sigma_u = f.gnss_sigma_fitted_m
    horizontal = num(sigma_n, 2) if abs(sigma_n - sigma_e) < 0.005 else f"{num(sigma_n, 2)}/{num(sigma_e, 2)}"
    rows.append(_row(BOTH, "noise", f"GNSS σ h {horizontal} m, v {num(sigma_u, 2)} m (fitted); VRW "
                     f"{num(f.vrw_m_s_sqrt_h)} m/s/√h, ARW {num(f.arw_deg_sqrt_h)} deg/√h",
                     "gnss_sigma_fitted_m", "vrw_m_s_sqrt_h", "arw_deg_sqrt_h"))
    rows.append(_row(BOTH, "ground vehicle", "non-holonomic constraints" if f.ground_vehicle else None,
                     "ground_vehicle"))
    return rows + _graph_rows(f.graph, style)


def _sigma_scale_row(f: FilterFigures, style: Style) -> _Placed:
    position, attitude = f.sigma_scale_position, f.sigma_scale_attitude
    keys = ("sigma_scale_position", "sigma_scale_attitude")
    if position is None and attitude is None:
        return _row(REPORT, "σ scale on this flight", None, *keys)
    parts = [] if position is None else [f"position {style.number(position)} (held-out fixes)"]
    if attitude is not None:
        parts.append("roll/pitch/yaw " + "/".join("–" if v is None else style.number(v) for v in attitude)
                     + " (forward filter against the smoother)")
    return _row(REPORT, "σ scale on this flight", "; ".join(parts) + ": errors over their σ, RMS; 1 is as claimed, "
                "above 1 the σ are too small", *keys)


def _graph_rows(g: GraphFigures | None, style: Style) -> list[_Placed]:
    """The calibration ``--method graph`` estimated with the trajectory, with marginal sigmas, and the fixes its
    robust pass dropped."""
    if g is None:
        return []
    num = style.number

    def pm(values: Sequence[float], sigmas: Sequence[float], digits: int) -> str:
        return ", ".join(f"{num(v, digits)} ± {num(e, digits)}" for v, e in zip(values, sigmas, strict=True))

    rows = [_row(BOTH, "GNSS lever arm", pm(g.graph_lever_arm_m, g.graph_lever_arm_sigma_m, 3)
                 + " m (body x forward, y right, z down; estimated with the trajectory)",
                 "graph_lever_arm_m", "graph_lever_arm_sigma_m"),
            _row(BOTH, "GNSS time offset", f"{num(g.graph_time_offset_s * 1e3, 2)} ± "
                 f"{num(g.graph_time_offset_sigma_s * 1e3, 2)} ms (each fix measured that long before its time tag)",
                 "graph_time_offset_s", "graph_time_offset_sigma_s"),
            _row(BOTH, "robust pass", f"{g.graph_rejected_fixes} fix(es) dropped as outliers", "graph_rejected_fixes")]
    if g.graph_gyro_scale_ppm is not None:
        rows.append(_row(BOTH, "scale factors", f"gyro {pm(g.graph_gyro_scale_ppm, g.graph_gyro_scale_sigma_ppm, 0)} "
                         f"ppm; accelerometer {pm(g.graph_accel_scale_ppm, g.graph_accel_scale_sigma_ppm, 0)} ppm "
                         f"(prior σ {num(g.graph_scale_prior_sigma_ppm, 0)} ppm)", "graph_gyro_scale_ppm",
                         "graph_gyro_scale_sigma_ppm", "graph_accel_scale_ppm", "graph_accel_scale_sigma_ppm",
                         "graph_scale_prior_sigma_ppm"))
    return rows


# ---- the rest of a process run ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class YawOffsetFigures:
    """``--method axis``: the POS unit's yaw offset [deg] and its drift [deg/min], with 1-sigmas."""

    yaw_offset_deg: float
    yaw_offset_sigma_deg: float
    yaw_drift_deg_per_min: float
    yaw_drift_sigma_deg_per_min: float

    @classmethod
    def of(cls, yaw: object | None) -> YawOffsetFigures | None:
        if yaw is None:
            return None
        return cls(float(np.degrees(yaw.offset)), float(np.degrees(yaw.offset_sigma)),
                   float(np.degrees(yaw.drift) * 60), float(np.degrees(yaw.drift_sigma) * 60))


@dataclass(frozen=True)
class FlightFigures:
    """An autopilot log's facts: its kind and vehicle, the IMU stream used, the boot clock's rate against UTC less
    1 [ppm], the fix messages' arrival jitter [s] and the fix types counted."""

    log_kind: str
    vehicle: str | None
    imu_stream: str
    clock_rate_ppm: float
    clock_jitter_s: float
    gnss_fix_types: dict[str, int]

    @classmethod
    def of(cls, flight: FlightLog | None) -> FlightFigures | None:
        if flight is None:
            return None
        return cls(flight.kind, flight.vehicle, flight.imu.name, float((flight.clock.rate - 1.0) * 1e6),
                   float(flight.clock.residual_s), dict(flight.gnss_report.fix_types))


@dataclass(frozen=True)
class GeodesyFigures:
    """The output coordinates and what PROJ did to make them:

    * ``output_crs``: the projected CRS (None without one); ``output_heights``: "WGS 84 ellipsoidal" or the
      vertical CRS of the orthometric heights;
    * ``proj_transformations``: each transformation PROJ used, with its stated accuracy;
    * ``proj_accuracy_m``: the largest stated accuracy [m] (None: none stated or none used);
    * ``geodesy_warnings``: the transformations whose stated accuracy exceeds the median horizontal (or, for
      heights, vertical) sigma of the frames — georef's sigmas do not contain them.
    """

    output_crs: str | None = None
    output_heights: str = "WGS 84 ellipsoidal"
    proj_transformations: list[str] = field(default_factory=list)
    proj_accuracy_m: float | None = None
    geodesy_warnings: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, frames: OutputFrames | None, table: Mapping[str, object]) -> GeodesyFigures:
        """From the output frames and the EO table (columns or a DataFrame) whose sigmas the accuracies meet."""
        if frames is None:
            return cls()
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
                warnings.append(f"{t.what}: PROJ states {t.accuracy_m:g} m for {t.description}, more than the "
                                f"median {axis} sigma {limit:.2f} m; the sigma columns do not include it")
        return cls(frames.horizontal_name, frames.height_name, [str(t) for t in used],
                   max(stated) if stated else None, warnings)


@dataclass(frozen=True)
class FrameSigmas:
    """The frames' sigmas where they have one: median and largest north, east, up [m] and roll, pitch, yaw
    [deg], and the median horizontal sigma hypot(north, east) [m]."""

    median: dict[str, float]
    largest: dict[str, float]
    horizontal_median: float

    NAMES = ("n", "e", "u", "roll", "pitch", "yaw")

    @classmethod
    def of(cls, columns: Mapping[str, object]) -> FrameSigmas | None:
        sigma = {name: np.asarray(columns[f"sigma_{name}"], dtype=float) for name in cls.NAMES}
        valid = ~np.isnan(sigma["n"])
        if not valid.any():
            return None
        return cls({k: float(np.nanmedian(v[valid])) for k, v in sigma.items()},
                   {k: float(np.nanmax(v[valid])) for k, v in sigma.items()},
                   float(np.median(np.hypot(sigma["n"][valid], sigma["e"][valid]))))


@dataclass(frozen=True)
class RejectedFix:
    """A GNSS fix the gate rejected: its time [s] and its line in the input."""

    time: float
    line: int


@dataclass(frozen=True)
class RunSummary:
    """The summary of one ``georef process`` run. The fields up to ``geodesy`` are the JSON ``summary``
    (:meth:`to_dict`, ``docs/qc.md``); the rest are facts the terminal's and the report's tables show besides.

    Counts of EO rows (``frames_*``), ``time_span_s`` the first and last POS time [s], the IMU rows and rate [Hz],
    the GNSS epochs, those used, the input lines of those rejected and the gaps [[start, end], s], the POS time
    quirks repaired, the method; ``yaw`` for ``--method axis``, ``filter`` for the full-state filters, ``flight``
    for an autopilot log (each None otherwise), ``geodesy`` the output coordinates."""

    frames_written: int
    frames_flagged: int
    frames_outside_span: int
    frames_in_outage: int
    frames_after_last_fix: int
    frames_before_first_fix: int
    time_span_s: tuple[float, float]
    imu_rows: int
    imu_rate_hz: float
    gnss_epochs: int
    gnss_used: int
    gnss_rejected_lines: list[int]
    gnss_gaps: list[tuple[float, float]]
    time_quirks_repaired: int
    method: str
    yaw: YawOffsetFigures | None
    filter: FilterFigures | None
    flight: FlightFigures | None
    geodesy: GeodesyFigures
    #: what the POS log's times count (:func:`clock_name`)
    clock: str = "UTC of day"
    rejected_fixes: tuple[RejectedFix, ...] = ()
    #: GNSS epochs not processed (before the filter's start, outside the IMU's span)
    gnss_not_processed: int = 0
    #: the input lines of the repaired time quirks
    quirk_lines: tuple[int, ...] = ()
    #: frames per flag (a frame with two flags counts under each)
    flag_counts: dict[str, int] = field(default_factory=dict)
    frame_sigmas: FrameSigmas | None = None
    #: the forward filter against the smoother, RMS: horizontal, vertical [m], yaw [deg] (None: no RTS pass)
    separation_rms: tuple[float, float, float] | None = None
    #: the IMU's data gaps (None: not counted)
    imu_gaps: int | None = None
    #: each RTKLIB/Emlid .pos's time scale, as lines (:func:`georef.io.pos_time_scale.time_scale_lines`)
    time_scale_lines: tuple[str, ...] = ()

    @classmethod
    def of(cls, result: ProcessResult, imu_gaps: int | None = None,
           time_scale_lines: Sequence[str] = ()) -> RunSummary:
        """Built from a run's result; ``imu_gaps``: the IMU data gaps counted (the report counts them);
        ``time_scale_lines``: the .pos files' time scales in words (the terminal shows them; the module that
        words them imports pyproj, which a summary alone should not pay for)."""
        columns, log, nav, gnss = result.columns, result.log, result.nav, result.nav.gnss
        flags = np.asarray(columns["flag"], dtype=str)
        rejected = gnss.status == 0
        return cls(
            frames_written=len(columns["flag"]), frames_flagged=int(np.count_nonzero(flags != "")),
            frames_outside_span=int(np.count_nonzero(flag_mask(columns, FLAG_OUTSIDE))),
            frames_in_outage=int(np.count_nonzero(flag_mask(columns, "GNSS outage"))),
            frames_after_last_fix=int(np.count_nonzero(flag_mask(columns, FLAG_AFTER_LAST_FIX))),
            frames_before_first_fix=int(np.count_nonzero(flag_mask(columns, FLAG_BEFORE_FIRST_FIX))),
            time_span_s=(float(log.time[0]), float(log.time[-1])), imu_rows=len(log), imu_rate_hz=log.sample_rate_hz,
            gnss_epochs=len(log.gnss), gnss_used=int((gnss.status >= 1).sum()),
            gnss_rejected_lines=gnss.rejected_lines, gnss_gaps=log.gnss.gaps(),
            time_quirks_repaired=log.time_repairs.n_quirks, method=nav.method,
            yaw=YawOffsetFigures.of(nav.axis_info.yaw_offset if nav.axis_info is not None else None),
            filter=filter_figures(nav, result.config.gnss, log.gnss.sigma_neu),
            flight=FlightFigures.of(result.flight), geodesy=GeodesyFigures.of(result.frames, columns),
            clock=clock_name(log.kind, float(log.time[0])),
            rejected_fixes=tuple(RejectedFix(float(t), int(n)) for t, n in
                                 zip(gnss.time[rejected], gnss.line[rejected], strict=True)),
            gnss_not_processed=int((gnss.status < 0).sum()), quirk_lines=tuple(log.time_repairs.quirk_lines),
            flag_counts=_flag_counts(flags), frame_sigmas=FrameSigmas.of(columns),
            separation_rms=_separation_rms(nav), imu_gaps=imu_gaps, time_scale_lines=tuple(time_scale_lines))

    def to_dict(self) -> dict[str, object]:
        """The JSON ``summary`` of ``--summary-json`` (``docs/qc.md``): units in the keys, None where a section
        does not apply (the yaw offset's and an autopilot log's keys; the filters' are then absent)."""
        names = [f.name for f in fields(self)]
        summary: dict[str, object] = {name: getattr(self, name) for name in names[:names.index("time_quirks_repaired")]}
        yaw_names = [f.name for f in fields(YawOffsetFigures)]
        summary.update({k: None if self.yaw is None else getattr(self.yaw, k) for k in yaw_names})
        summary["time_quirks_repaired"] = self.time_quirks_repaired
        summary["method"] = self.method
        summary.update({} if self.filter is None else self.filter.to_dict())
        flight_names = [f.name for f in fields(FlightFigures)]
        summary.update({k: None if self.flight is None else getattr(self.flight, k) for k in flight_names})
        summary.update({f.name: getattr(self.geodesy, f.name) for f in fields(GeodesyFigures)})
        return summary

    def rows(self, target: Target) -> list[Row]:
        """The rows ``target`` shows, in order (rows with nothing to show left out)."""
        return [row for row in self.placed_rows(target) if row.text is not None]

    def placed_rows(self, target: Target) -> list[Row]:
        """Every row ``target`` could show, those with nothing to show this time (``text`` None) included: their
        keys are accounted for all the same."""
        style = STYLES[target]
        placed = [*_frame_rows(self), *_span_rows(self), *_gnss_rows(self, style), *_yaw_rows(self, style),
                  *_filter_rows(self.filter, style), *_closing_rows(self, style)]
        return [p.row for p in placed if target in p.where]


def _flag_counts(flags: np.ndarray) -> dict[str, int]:
    counts: dict[str, int] = {}
    for flag in flags:
        for part in (p.strip() for p in str(flag).split(";")):
            if part:
                counts[part] = counts.get(part, 0) + 1
    return counts


def _separation_rms(nav: NavSolution) -> tuple[float, float, float] | None:
    sep = nav.forward
    if sep is None or not len(sep.time):
        return None
    return (float(np.sqrt(np.mean(sep.position[:, 0] ** 2 + sep.position[:, 1] ** 2))),
            float(np.sqrt(np.mean(sep.position[:, 2] ** 2))),
            float(np.degrees(np.sqrt(np.mean(sep.attitude[:, 2] ** 2)))))


def _listed(values: Sequence[int], most: int = 12) -> str:
    """The first ``most`` values, and how many there are in all when there are more."""
    shown = ", ".join(str(v) for v in values[:most])
    return shown + (f", … ({len(values)} in all)" if len(values) > most else "")


def _frame_rows(s: RunSummary) -> list[_Placed]:
    flagged = ", ".join(f"{n} {flag}" for flag, n in s.flag_counts.items())
    frame_keys = ("frames_written", "frames_flagged", "frames_outside_span", "frames_in_outage",
                  "frames_after_last_fix", "frames_before_first_fix")
    beyond = s.frames_after_last_fix or s.frames_before_first_fix
    return [
        _row(TERMINAL, "frames written", f"{s.frames_written} ({s.frames_flagged} flagged)", *frame_keys[:2]),
        _row(REPORT, "frames", f"{s.frames_written} written, {s.frames_flagged} flagged"
             + (f" ({flagged})" if flagged else ""), *frame_keys),
        _row(TERMINAL, "outside nav span", f"{s.frames_outside_span} frames: rows kept, values empty"
             if s.frames_outside_span else None, "frames_outside_span"),
        _row(TERMINAL, "in GNSS outage", f"{s.frames_in_outage} frames" if s.frames_in_outage else None,
             "frames_in_outage"),
        _row(TERMINAL, "beyond the GNSS fixes", f"{s.frames_before_first_fix} frames before the first fix, "
             f"{s.frames_after_last_fix} after the last (inertial only)" if beyond else None,
             "frames_after_last_fix", "frames_before_first_fix"),
    ]


def _span_rows(s: RunSummary) -> list[_Placed]:
    t0, t1 = s.time_span_s
    gaps = "" if s.imu_gaps is None else f"; {s.imu_gaps} data gap(s)"
    return [
        _row(TERMINAL, "time span", f"{t0:.2f} - {t1:.2f} s {s.clock} ({t1 - t0:.1f} s), {s.imu_rows} IMU rows at "
             f"{s.imu_rate_hz:.1f} Hz", "time_span_s", "imu_rows", "imu_rate_hz"),
        _row(REPORT, "time span", utc_span(t0, t1), "time_span_s"),
        _row(REPORT, "IMU", f"{s.imu_rows:,} rows at {s.imu_rate_hz:.1f} Hz{gaps}", "imu_rows", "imu_rate_hz"),
    ]


def _gnss_rows(s: RunSummary, style: Style) -> list[_Placed]:
    """The GNSS epochs, the rejected fixes and the gaps: seconds on the terminal, UTC in the report."""
    keys = ("gnss_epochs", "gnss_used", "gnss_rejected_lines", "gnss_gaps")
    rejected = len(s.rejected_fixes)
    rows = [_row(TERMINAL, "GNSS epochs", f"{s.gnss_epochs} ({s.gnss_used} used, {len(s.gnss_rejected_lines)} "
                 f"rejected, {len(s.gnss_gaps)} gaps)", *keys),
            _row(REPORT, "GNSS", f"{s.gnss_epochs} fixes: {s.gnss_used} used, {rejected} rejected by the gate, "
                 f"{s.gnss_not_processed} not processed; {len(s.gnss_gaps)} outage(s)", *keys)]
    if s.gnss_rejected_lines:
        shown = [f"{fix.time:.0f} s (line {fix.line})" for fix in s.rejected_fixes]
        rows.append(_row(TERMINAL, "rejected fixes", ", ".join(shown[:SHOWN_REJECTED])
                         + (" ..." if len(shown) > SHOWN_REJECTED else "")))
    if rejected:
        shown = [f"{utc(fix.time)} (line {fix.line})" for fix in s.rejected_fixes]
        rows.append(_row(REPORT, "rejected fixes", ", ".join(shown[:SHOWN_REJECTED])
                         + (f", … ({len(shown)} in all)" if len(shown) > SHOWN_REJECTED else "")))
    rows += [_row(TERMINAL, "GNSS gap", f"{start:.0f} - {end:.0f} s ({end - start:.0f} s)")
             for start, end in s.gnss_gaps[:SHOWN_GAPS_TERMINAL]]
    rows += [_row(REPORT, "GNSS outage", utc_span(start, end, 0)) for start, end in s.gnss_gaps[:SHOWN_GAPS_REPORT]]
    if len(s.gnss_gaps) > SHOWN_GAPS_REPORT:
        rows.append(_row(REPORT, "GNSS outage", f"… {len(s.gnss_gaps) - SHOWN_GAPS_REPORT} more"))
    return rows


def _yaw_rows(s: RunSummary, style: Style) -> list[_Placed]:
    """The method (the report's; the terminal's title names it) and the axis method's yaw offset."""
    yaw, num = s.yaw, style.number
    return [_row(REPORT, "method", s.method, "method"),
            _row(BOTH, "yaw offset", None if yaw is None else
                 f"{num(yaw.yaw_offset_deg)} ± {num(yaw.yaw_offset_sigma_deg)} deg, drift "
                 f"{num(yaw.yaw_drift_deg_per_min)} ± {num(yaw.yaw_drift_sigma_deg_per_min)} deg/min",
                 *(f.name for f in fields(YawOffsetFigures)))]


def _closing_rows(s: RunSummary, style: Style) -> list[_Placed]:
    """The time quirks repaired, the .pos files' time scales, the output coordinates and PROJ's transformations,
    the frames' sigmas and the forward filter against the smoother."""
    g, num = s.geodesy, style.number
    quirks = s.quirk_lines
    rows = [_row(TERMINAL, "time quirks repaired", str(s.time_quirks_repaired), "time_quirks_repaired"),
            _row(REPORT, "time tags repaired", f"{len(quirks)}" + (f" (lines {_listed(quirks)})" if quirks else ""),
                 "time_quirks_repaired")]
    rows += [_row(TERMINAL, "time scale", line) for line in s.time_scale_lines]
    if g.output_crs or g.output_heights != "WGS 84 ellipsoidal":
        rows.append(_row(BOTH, "coordinates", f"{g.output_crs or 'WGS 84'}, heights {g.output_heights}",
                         "output_crs", "output_heights"))
        rows += [_row(BOTH, "PROJ", str(used), "proj_transformations") for used in g.proj_transformations]
    sig = s.frame_sigmas
    if sig is not None:
        med, top = sig.median, sig.largest
        rows.append(_row(TERMINAL, "median sigma", f"horizontal {sig.horizontal_median:.2f} m, vertical "
                         f"{med['u']:.2f} m, yaw {med['yaw']:.2f} deg"))
        rows.append(_row(REPORT, "frame σ, median (largest)", f"north {num(med['n'])} ({num(top['n'])}), east "
                         f"{num(med['e'])} ({num(top['e'])}), up {num(med['u'])} ({num(top['u'])}) m; horizontal "
                         f"{num(sig.horizontal_median)} m"))
        rows.append(_row(REPORT, "frame attitude σ, median (largest)", ", ".join(
            f"{a} {num(med[a], 4)} ({num(top[a], 4)})" for a in ("roll", "pitch", "yaw")) + " deg"))
    if s.separation_rms is not None:
        h, v, yaw = s.separation_rms
        rows.append(_row(REPORT, "forward − smoothed, RMS", f"horizontal {num(h)} m, vertical {num(v)} m, yaw "
                         f"{num(yaw, 4)} deg"))
    return rows
