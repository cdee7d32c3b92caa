"""Boresight and camera lever-arm calibration from a block adjusted with ground control (``docs/boresight.md``).

Per photo the EO table's camera (``georef process``) is compared with the adjusted one: the small rotation
``rho`` [rad, camera frame] between them and the position difference ``p`` [m] mapped into the body frame.
Model (first order, :mod:`georef.frames.calibration`)::

    rho_i = b  + C_n_c,i eps_i      (b: boresight correction, eps: INS attitude error, NED)
    p_i   = dl + C_n_b,i e_i        (dl: lever-arm correction, body; e: INS/GNSS position error and datum, NED)

The INS errors are strongly time-correlated, so photos are grouped into strips and the strip means carry the
information: a between-strip variance component per axis (estimated from the scatter), a flight-constant NED error
whose horizontal part is estimated when the strips fly in different headings (its sign in the body frame flips
with the heading) and whose down part (yaw; height) is not separable from ``b_z`` / ``dl_z``. For the boresight the
flight-constant yaw error the EO's own sigmas give is added to the variance: no number of photos averages it out.
A jackknife over strips checks the between-strip part of the sigma.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from georef.distributions import chi2_isf
from georef.frames import euler_to_dcm, wrap_pi
from georef.frames.calibration import (
    accel_bias_tilt_covariance_camera,
    body_offset,
    boresight_angle_jacobian,
    camera_rotation_residual,
    corrected_boresight,
    grid_offset_to_ned,
    image_to_ned,
)
from georef.frames.earth import STANDARD_GRAVITY, normal_gravity
from georef.frames.mounting import boresight_dcm
from georef.io.adjusted_cameras import AdjustedCameras
from georef.io.errors import InputError
from georef.io.process_summary import ProcessFigures

#: fewest matched, usable photos to estimate anything (three axes, a variance and a check)
MIN_PHOTOS = 10
#: fewest photos of a strip (fewer: a turn's tail, not used)
MIN_STRIP_PHOTOS = 5
#: a photo belongs to a strip while the camera's heading stays within this of the strip's first photo [deg]
STRIP_HEADING_TOL_DEG = 15.0
#: faster heading changes than this are turns [deg/s]
TURN_RATE_DEG_S = 2.0
#: more roll than this is a banked turn [deg]
TURN_ROLL_DEG = 10.0
#: a time gap larger than this many median photo intervals starts a new strip
GAP_INTERVALS = 5.0
#: the flight-constant horizontal NED error is estimated when the design's weakest direction keeps this share
HEADING_DIVERSITY_MIN = 0.2
#: strips needed for a between-strip variance and a jackknife worth the name
MIN_STRIPS_GOOD = 3
#: chi-square test level of the strip residuals against the EO's sigmas
CHI2_LEVEL = 0.999
#: a lever-arm correction is applied only when larger than this many sigmas (a taped lever arm is good to ~1 cm;
#: a correction within its noise would only add noise)
SIGNIFICANT = 2.0
#: jackknife sigma larger than this times the model sigma (between-strip part): the sigma is not trusted
JACKKNIFE_RATIO_MAX = 2.5
#: photos this far outside the process summary's POS time span [s] mean the summary is of another flight
SPAN_TOLERANCE_S = 1.0
#: named axes of the (3,) vectors: boresight roll, pitch, yaw angles; body x, y, z; NED north, east, down
ROLL, PITCH, YAW = 0, 1, 2
BODY_X, BODY_Y, BODY_Z = 0, 1, 2
NORTH, EAST, DOWN = 0, 1, 2
#: the level angles (roll, pitch) and the horizontal NED axes (north, east)
LEVEL = slice(ROLL, PITCH + 1)
HORIZONTAL = slice(NORTH, EAST + 1)
#: where the body-fixed INS errors in the sigmas come from
SIGMA_FROM_FILTER = "the navigation filter's bias sigmas (process summary)"
SIGMA_CONSERVATIVE = "conservative bounds from the EO's sigmas (no process summary)"


class CalibrationInputError(InputError):
    """The inputs cannot give a calibration (no matching names, too few photos or strips)."""


@dataclass
class MatchedPhotos:
    """Photos found in both the EO table and the adjusted block, sorted by time.

    ``C_c_n_eo``/``C_c_n_adjusted`` (n, 3, 3) camera attitudes; ``d_ned`` (n, 3) adjusted minus EO camera
    position [m, local NED]; ``sigma_attitude`` (n, 3) the EO's roll, pitch, yaw sigmas [rad]; ``sigma_position``
    (n, 3) its north, east, up sigmas [m]; ``roll_deg``, ``heading_deg`` the EO camera's [deg]; ``grid`` (n, 2) EO
    easting, northing [m]."""

    label: np.ndarray
    frame: np.ndarray
    time: np.ndarray
    C_c_n_eo: np.ndarray
    C_c_n_adjusted: np.ndarray
    d_ned: np.ndarray
    sigma_attitude: np.ndarray
    sigma_position: np.ndarray
    roll_deg: np.ndarray
    heading_deg: np.ndarray
    grid: np.ndarray
    unmatched_labels: list[str] = field(default_factory=list)
    eo_rows_flagged: int = 0
    eo_rows_without_camera: int = 0
    #: normal gravity at the photos [m/s^2] (median): an accelerometer bias over it is a tilt
    gravity_m_s2: float = STANDARD_GRAVITY

    def __len__(self) -> int:
        return len(self.time)


#: the EO columns a usable row has finite values in
EO_NUMERIC = ("lat", "lon", "height", "roll", "pitch", "yaw", "sigma_n", "sigma_e", "sigma_u", "sigma_roll",
              "sigma_pitch", "sigma_yaw")
EO_NEEDED = ("frame", "time", *EO_NUMERIC, "flag")


def _stem(name: str) -> str:
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    return base.rsplit(".", 1)[0].lower() if "." in base else base.lower()


@dataclass(frozen=True)
class _Pairing:
    """EO rows paired with adjusted cameras by name: EO table row ``eo_row[k]`` is adjusted camera ``camera[k]``
    (index into the block)."""

    eo_row: np.ndarray
    camera: np.ndarray
    #: adjusted cameras no EO row names
    unmatched_labels: list[str]
    #: distinct EO rows some camera matched (usable or not)
    eo_rows_matched: int
    #: pairs dropped because the EO row is flagged or has a non-finite value
    flagged: int = 0


def _name_keys(frames: list[str], images: list[str]) -> dict[str, int]:
    """EO row of each name a camera label may match: the image name, it without folder and extension
    (lower case), the frame number; the first row wins."""
    keys: dict[str, int] = {}
    for row, (frame, image) in enumerate(zip(frames, images, strict=True)):
        for key in (image, _stem(image) if image else "", frame):
            if key and key not in keys:
                keys[key] = row
    return keys


def _pair_by_name(frames: list[str], images: list[str], cameras: AdjustedCameras) -> _Pairing:
    """Pair each adjusted camera with the EO row its label names (exact, then stem, then lower case); raises
    :class:`CalibrationInputError` when no label matches."""
    keys = _name_keys(frames, images)
    pairs: list[tuple[int, int]] = []
    unmatched: list[str] = []
    for k, label in enumerate(cameras.label):
        row = next((keys[key] for key in (label, _stem(label), label.lower()) if key in keys), None)
        if row is None:
            unmatched.append(label)
        else:
            pairs.append((row, k))
    if not pairs:
        shown = ", ".join(repr(x) for x in cameras.label[:3])
        eo_shown = ", ".join(repr(x) for x in (images if images[0] else frames)[:3])
        raise CalibrationInputError(cameras.path, None, None, f"no camera label matches an EO row (labels such as "
                                    f"{shown}; EO images/frames such as {eo_shown}): process with --image-names so "
                                    "the EO table names the images")
    return _Pairing(eo_row=np.array([r for r, _ in pairs]), camera=np.array([c for _, c in pairs]),
                    unmatched_labels=unmatched, eo_rows_matched=len(set(int(r) for r, _ in pairs)))


def _usable_in_time_order(eo: Any, pairing: _Pairing) -> _Pairing:
    """The pairs whose EO row is not flagged and has finite ``EO_NUMERIC`` values, sorted by EO time [s]
    (stable); ``flagged`` counts the pairs dropped."""
    flags = np.asarray(eo["flag"].fillna("").astype(str))
    rows, cams = pairing.eo_row, pairing.camera
    numeric = np.column_stack([np.asarray(eo[c], float)[rows] for c in EO_NUMERIC])
    usable = (flags[rows] == "") & np.all(np.isfinite(numeric), axis=1)
    rows, cams = rows[usable], cams[usable]
    order = np.argsort(np.asarray(eo["time"], float)[rows], kind="stable")
    return _Pairing(eo_row=rows[order], camera=cams[order], unmatched_labels=pairing.unmatched_labels,
                    eo_rows_matched=pairing.eo_rows_matched, flagged=int(np.count_nonzero(~usable)))


def match_photos(eo: Any, eo_path: Any, cameras: AdjustedCameras, crs: str, use_orthometric: bool = True
                 ) -> MatchedPhotos:
    """Pair the EO table's rows (a DataFrame of ``georef process``'s EO table) with the adjusted cameras by image
    name (the EO's ``image`` column: exact, then without folder and extension, case-insensitive) or frame number.

    ``crs``: the projected CRS the block was adjusted in (the adjusted X, Y). Heights: the EO's
    ``height_orthometric`` when it has one and ``use_orthometric``, else its ellipsoidal ``height``; a datum
    difference goes into the vertical terms, which are not estimated. Flagged EO rows are not used (counted)."""
    from georef.frames.mapping import MapProjection

    missing = [c for c in EO_NEEDED if c not in eo.columns]
    if missing:
        raise CalibrationInputError(eo_path, 1, missing[0], f"not an EO table of georef process: no column(s) "
                                    f"{', '.join(missing)}")
    frames = [str(f) for f in eo["frame"]]
    images = [str(v) for v in eo["image"]] if "image" in eo.columns else [""] * len(frames)
    pairing = _usable_in_time_order(eo, _pair_by_name(frames, images, cameras))
    rows, cams = pairing.eo_row, pairing.camera

    def col(name: str) -> np.ndarray:
        return np.asarray(eo[name], float)[rows]

    projection = MapProjection(crs)
    lat, lon = col("lat"), col("lon")
    easting, northing = projection.forward(lat, lon)
    convergence, scale = projection.convergence_and_scale(lat, lon)
    height = col("height_orthometric") if use_orthometric and "height_orthometric" in eo.columns else col("height")
    d_ned = grid_offset_to_ned(cameras.easting[cams] - easting, cameras.northing[cams] - northing,
                               cameras.height[cams] - height, convergence, scale)
    C_c_n_eo = euler_to_dcm(np.radians(col("roll")), np.radians(col("pitch")), np.radians(col("yaw")))
    C_c_n_adjusted = image_to_ned(cameras.R_i_m[cams], convergence)
    return MatchedPhotos(
        label=np.array([cameras.label[c] for c in cams], dtype=object), frame=np.array(frames, dtype=object)[rows],
        time=col("time"), C_c_n_eo=C_c_n_eo, C_c_n_adjusted=C_c_n_adjusted, d_ned=d_ned,
        sigma_attitude=np.radians(np.column_stack([col("sigma_roll"), col("sigma_pitch"), col("sigma_yaw")])),
        sigma_position=np.column_stack([col("sigma_n"), col("sigma_e"), col("sigma_u")]),
        roll_deg=col("roll"), heading_deg=col("yaw"), grid=np.column_stack([easting, northing]),
        unmatched_labels=pairing.unmatched_labels, eo_rows_flagged=pairing.flagged,
        eo_rows_without_camera=len(frames) - pairing.eo_rows_matched,
        gravity_m_s2=float(np.median(normal_gravity(np.radians(lat), col("height")))))


@dataclass
class Strips:
    """``index`` (n,): the strip of each photo, -1 for photos in turns or too short runs (``in_turns`` of them)."""

    index: np.ndarray
    count: int
    in_turns: int


def split_strips(time: np.ndarray, heading_deg: np.ndarray, roll_deg: np.ndarray) -> Strips:
    """Strips: runs of photos (sorted by time) flown straight: heading rate below ``TURN_RATE_DEG_S``, roll below
    ``TURN_ROLL_DEG``, heading within ``STRIP_HEADING_TOL_DEG`` of the run's first photo, no time gap over
    ``GAP_INTERVALS`` median intervals; runs shorter than ``MIN_STRIP_PHOTOS`` are not used."""
    n = len(time)
    index = np.full(n, -1)
    if n == 0:
        return Strips(index, 0, 0)
    heading = np.unwrap(np.radians(heading_deg))
    dt = np.diff(time)
    step = float(np.median(dt)) if n > 1 else 1.0
    rate = np.zeros(n)
    if n > 1:
        rate_edges = np.degrees(np.abs(np.diff(heading))) / np.maximum(dt, 1e-6)
        rate[:-1] = rate_edges
        rate[1:] = np.maximum(rate[1:], rate_edges)
    straight = (rate < TURN_RATE_DEG_S) & (np.abs(roll_deg) < TURN_ROLL_DEG)
    runs: list[list[int]] = []
    current: list[int] = []
    for i in range(n):
        if not straight[i]:
            if current:
                runs.append(current)
            current = []
            continue
        if current and (time[i] - time[current[-1]] > GAP_INTERVALS * step
                        or np.degrees(abs(heading[i] - heading[current[0]])) > STRIP_HEADING_TOL_DEG):
            runs.append(current)
            current = []
        current.append(i)
    if current:
        runs.append(current)
    count = 0
    for run in runs:
        if len(run) >= MIN_STRIP_PHOTOS:
            index[run] = count
            count += 1
    return Strips(index, count, int(np.count_nonzero(index < 0)))


@dataclass
class OffsetFit:
    """A constant offset (3, in the camera or body frame) fitted to strip means.

    ``offset``/``cov`` the estimate and its covariance from the strips (between-strip part, without any
    flight-constant floor); ``tilt``/``tilt_cov`` the flight-constant horizontal NED error (N, E) when estimated;
    ``between_sigma`` (3) the between-strip sigma of the INS error, N, E, D; ``chi2`` of the strip residuals
    against the EO's sigmas
    with ``dof`` degrees of freedom; ``residuals`` (strips, 3)."""

    offset: np.ndarray
    cov: np.ndarray
    tilt: np.ndarray | None
    tilt_cov: np.ndarray | None
    between_sigma: np.ndarray
    chi2: float
    dof: int
    residuals: np.ndarray


def _effective_count(v: np.ndarray) -> float:
    """Photos' worth of independent information in a strip's residuals (n, 3): ``n (1 - r1) / (1 + r1)`` with
    r1 the lag-one autocorrelation (the INS errors and the wobble are correlated from photo to photo)."""
    n = len(v)
    if n < 3:
        return float(n)
    d = v - v.mean(axis=0)
    denominator = np.sum(d * d, axis=0)
    r1 = np.where(denominator > 0, np.sum(d[1:] * d[:-1], axis=0) / np.where(denominator > 0, denominator, 1), 0.0)
    r1 = float(np.clip(np.max(r1), 0.0, 0.98))
    return max(1.0, n * (1.0 - r1) / (1.0 + r1))


@dataclass(frozen=True)
class StripMeans:
    """One quantity averaged per strip, in its frame (the camera frame for the attitude residual [rad], the body
    frame for the position difference [m]).

    ``means`` (strips, 3); ``columns`` (strips, 3, 3) the strip's mean NED->frame rotation; ``within`` (strips, 3)
    the variance of the mean from the within-strip scatter over its effective photo count; ``eo_var`` (strips, 3)
    the median EO variance in that frame (variances in the quantity's unit squared)."""

    means: np.ndarray
    columns: np.ndarray
    within: np.ndarray
    eo_var: np.ndarray

    def subset(self, keep: np.ndarray) -> StripMeans:
        """The strips ``keep`` selects (boolean or index array)."""
        return StripMeans(self.means[keep], self.columns[keep], self.within[keep], self.eo_var[keep])


def _strip_means(values: np.ndarray, frame_of: np.ndarray, eo_var: np.ndarray, strips: Strips) -> StripMeans:
    """Per strip: mean of ``values`` (n, 3), mean of the NED->frame rotations ``frame_of`` (n, 3, 3), the variance
    of the mean from the within-strip scatter and its effective photo count, the median of ``eo_var`` (n, 3)."""
    means, columns, within, eo = [], [], [], []
    for s in range(strips.count):
        members = strips.index == s
        v = values[members]
        means.append(v.mean(axis=0))
        columns.append(frame_of[members].mean(axis=0))
        within.append(v.var(axis=0, ddof=1) / _effective_count(v))
        eo.append(np.median(eo_var[members], axis=0))
    return StripMeans(np.array(means), np.array(columns), np.array(within), np.array(eo))


def _design(columns: np.ndarray, with_tilt: bool) -> np.ndarray:
    """(strips * 3, 3 [+ 2]) design of the strip means: the offset, plus the N and E error columns."""
    X = np.vstack([np.eye(3)] * len(columns))
    if with_tilt:
        X = np.hstack([X, np.vstack([c[:, :2] for c in columns])])
    return X


def heading_diversity(columns: np.ndarray) -> float:
    """How well strips separate the offset from a flight-constant horizontal NED error: the smallest singular
    value of the (unit-weighted) normal matrix relative to the largest (0: all strips on one heading)."""
    X = _design(columns, True)
    singular = np.linalg.svd(X.T @ X / max(len(columns), 1), compute_uv=False)
    return float(singular[-1] / singular[0])


def fit_offset(strip_means: StripMeans, with_tilt: bool, iterations: int = 200) -> OffsetFit:
    """Generalised least squares of the strip means with a between-strip INS error in NED.

    Strip s: ``y_s = offset + A_s (e0 + eta_s) + w_s`` with ``A_s`` the strip's mean NED->frame rotation, ``e0``
    the flight-constant NED error (its N and E estimated with ``with_tilt``; its D is not separable from the
    offset), ``eta_s ~ N(0, diag(tau_N^2, tau_E^2, tau_D^2))`` the strip's own INS error and ``w_s`` the
    within-strip noise of the mean (``within``). Modelling ``eta`` in NED keeps the coupling between axes: a yaw
    error leaks into the camera's x and y through its pitch and roll, on every heading alike, and the GLS removes
    the part of that leak that varies from strip to strip. ``tau`` by EM-REML (Harville 1977; never negative);
    with no degrees of freedom left ``tau`` is the EO's median sigma."""
    means, columns, within, eo_var = strip_means.means, strip_means.columns, strip_means.within, strip_means.eo_var
    n = len(means)
    y = means.reshape(-1)
    X = _design(columns, with_tilt)
    Z = np.zeros((3 * n, 3 * n))
    for s in range(n):
        Z[3 * s:3 * s + 3, 3 * s:3 * s + 3] = columns[s]
    R = np.diag(np.maximum(within.reshape(-1), 1e-30))
    p = X.shape[1]
    if 3 * n - p <= 0:
        tau2 = np.median(eo_var, axis=0)
        iterations = 0
    else:
        tau2 = np.median(eo_var, axis=0) * 0.25 + 1e-20
    for _ in range(iterations):
        G = np.kron(np.eye(n), np.diag(tau2))
        V = Z @ G @ Z.T + R
        Vi = np.linalg.inv(V)
        XtVi = X.T @ Vi
        P = Vi - XtVi.T @ np.linalg.pinv(XtVi @ X) @ XtVi
        u = G @ Z.T @ P @ y
        C = G - G @ Z.T @ P @ Z @ G
        new = np.array([(np.sum(u[k::3] ** 2) + np.sum(np.diag(C)[k::3])) / n for k in range(3)])
        new = np.maximum(new, 1e-20)
        if np.allclose(new, tau2, rtol=1e-5, atol=1e-16):
            tau2 = new
            break
        tau2 = new
    G = np.kron(np.eye(n), np.diag(tau2))
    Vi = np.linalg.inv(Z @ G @ Z.T + R)
    cov = np.linalg.pinv(X.T @ Vi @ X)
    theta = cov @ (X.T @ Vi @ y)
    r = y - X @ theta
    chi2 = float(np.sum(r**2 / (eo_var.reshape(-1) + within.reshape(-1))))
    return OffsetFit(offset=theta[:3], cov=cov[:3, :3], tilt=theta[3:] if with_tilt else None,
                     tilt_cov=cov[3:, 3:] if with_tilt else None, between_sigma=np.sqrt(tau2), chi2=chi2,
                     dof=int(3 * n - p), residuals=r.reshape(n, 3))


def jackknife(strip_means: StripMeans, with_tilt: bool) -> np.ndarray | None:
    """Delete-one-strip jackknife sigma (3) of the offset [the strip means' unit and frame]; None with fewer than
    ``MIN_STRIPS_GOOD`` strips or when a strip's removal leaves the tilt unobservable."""
    n = len(strip_means.means)
    if n < MIN_STRIPS_GOOD:
        return None
    estimates = []
    for s in range(n):
        keep = np.arange(n) != s
        if with_tilt and heading_diversity(strip_means.columns[keep]) < HEADING_DIVERSITY_MIN * 0.25:
            return None
        estimates.append(fit_offset(strip_means.subset(keep), with_tilt).offset)
    estimates_arr = np.array(estimates)
    return np.sqrt((n - 1) / n * np.sum((estimates_arr - estimates_arr.mean(axis=0)) ** 2, axis=0))


@dataclass
class Component:
    """One estimated quantity: ``value`` (the correction), ``sigma``, the ``model_sigma`` without the
    flight-constant floor, the ``jackknife_sigma`` (None: not computed), ``estimated`` and, when not, ``why``."""

    name: str
    unit: str
    configured: float
    value: float
    sigma: float
    model_sigma: float
    jackknife_sigma: float | None
    estimated: bool
    why: str = ""
    #: the block observes it (False: combined with another quantity, the value is that combination)
    observed: bool = True

    @property
    def calibrated(self) -> float:
        """The configured value plus the correction when estimated, else the configured value."""
        return self.configured + self.value if self.estimated else self.configured


@dataclass
class BoresightCalibration:
    """The calibration (``docs/boresight.md``): boresight angles [deg] and lever arm [m, body], strips, checks."""

    boresight: list[Component]
    lever_arm: list[Component]
    photos_matched: int
    photos_used: int
    photos_in_turns: int
    strips: list[dict[str, Any]]
    tilt_estimated: bool
    heading_diversity: float
    ins_tilt_deg: list[float] | None
    between_strip_attitude_deg: list[float]
    between_strip_position_m: list[float]
    chi2_attitude: float
    chi2_position: float
    dof_attitude: int
    dof_position: int
    unmatched_labels: list[str]
    eo_rows_flagged: int
    eo_rows_without_camera: int
    problems: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    #: where the body-fixed INS errors in the roll, pitch and lever-y sigmas come from
    sigma_source: str = SIGMA_CONSERVATIVE

    @property
    def weak(self) -> bool:
        """The estimate is written but weak or inconsistent (exit code 4)."""
        return bool(self.problems)

    def summary(self) -> dict[str, Any]:
        """Figures for ``--summary-json`` (units in the keys)."""
        def comps(items: list[Component]) -> dict[str, Any]:
            return {c.name: {"configured": c.configured, "correction": c.value, "sigma": c.sigma,
                             "model_sigma_between_strips": c.model_sigma, "jackknife_sigma": c.jackknife_sigma,
                             "estimated": c.estimated, "observed": c.observed, "calibrated": c.calibrated,
                             "why": c.why or None}
                    for c in items}

        return {"boresight_deg": comps(self.boresight), "lever_arm_camera_m": comps(self.lever_arm),
                "photos_matched": self.photos_matched, "photos_used": self.photos_used,
                "photos_in_turns": self.photos_in_turns, "strips": self.strips,
                "ins_tilt_estimated": self.tilt_estimated, "heading_diversity": self.heading_diversity,
                "ins_tilt_deg": self.ins_tilt_deg, "between_strip_attitude_sigma_deg": self.between_strip_attitude_deg,
                "between_strip_position_sigma_m": self.between_strip_position_m,
                "chi2_attitude": self.chi2_attitude, "dof_attitude": self.dof_attitude,
                "chi2_position": self.chi2_position, "dof_position": self.dof_position,
                "unmatched_labels": self.unmatched_labels, "eo_rows_flagged": self.eo_rows_flagged,
                "eo_rows_without_adjusted_camera": self.eo_rows_without_camera,
                "sigma_body_fixed_source": self.sigma_source, "problems": self.problems, "advice": self.advice}


def _check_photos(photos: MatchedPhotos, source: Any, process: ProcessFigures | None) -> None:
    """Raise :class:`CalibrationInputError` with fewer than ``MIN_PHOTOS`` photos, or photos more than
    ``SPAN_TOLERANCE_S`` outside the process summary's POS time span [s UTC of day] (another flight's summary)."""
    if len(photos) < MIN_PHOTOS:
        raise CalibrationInputError(source, None, None, f"{len(photos)} usable photos match (need at least "
                                    f"{MIN_PHOTOS}; {photos.eo_rows_flagged} matched rows are flagged in the EO)")
    if process is not None:
        first, last = process.time_span_s
        outside = int(np.count_nonzero((photos.time < first - SPAN_TOLERANCE_S)
                                       | (photos.time > last + SPAN_TOLERANCE_S)))
        if outside:
            raise CalibrationInputError(process.path, None, "summary.time_span_s", f"{outside} of the {len(photos)} "
                                        f"photos lie outside this run's POS time span {first:.1f}-{last:.1f} s: the "
                                        "summary of another flight? Pass the --summary-json of the run that wrote "
                                        "the EO table")


def _straight_strips(photos: MatchedPhotos, source: Any) -> Strips:
    """The photos' strips (:func:`split_strips`); raises :class:`CalibrationInputError` when there is none."""
    strips = split_strips(photos.time, photos.heading_deg, photos.roll_deg)
    if strips.count == 0:
        raise CalibrationInputError(source, None, None, f"no strip: none of the {len(photos)} matched photos form a "
                                    f"straight run of {MIN_STRIP_PHOTOS} or more (heading steady within "
                                    f"{STRIP_HEADING_TOL_DEG:g} deg, roll under {TURN_ROLL_DEG:g} deg)")
    return strips


@dataclass(frozen=True)
class PhotoResiduals:
    """Per photo (n), the EO camera against the adjusted one in the frames of the model (module docstring).

    ``rho`` (n, 3) the small rotation from the EO to the adjusted camera [rad, camera frame]; ``p`` (n, 3) the
    adjusted minus the EO camera position [m, body frame]; ``C_c_b`` (3, 3) camera->body of the configured
    boresight; ``C_n_c``, ``C_n_b`` (n, 3, 3) the EO's NED->camera and NED->body rotations; ``att_var_n`` (n, 3) the
    EO's roll, pitch, yaw variances taken as NED tilt variances [rad^2]; ``att_var_c`` (n, 3) those in the camera
    axes [rad^2]; ``pos_var_b`` (n, 3) the EO's north, east, up position variances in the body axes [m^2]."""

    rho: np.ndarray
    p: np.ndarray
    C_c_b: np.ndarray
    C_n_c: np.ndarray
    C_n_b: np.ndarray
    att_var_n: np.ndarray
    att_var_c: np.ndarray
    pos_var_b: np.ndarray


def _photo_residuals(photos: MatchedPhotos, boresight_rad: np.ndarray) -> PhotoResiduals:
    """The per-photo residuals and EO variances, with the configured boresight ``boresight_rad`` (roll_b, pitch_b,
    yaw_b) [rad]."""
    C_c_b = boresight_dcm(boresight_rad)
    C_b_n = photos.C_c_n_eo @ C_c_b.T
    C_n_c = np.swapaxes(photos.C_c_n_eo, -1, -2)
    C_n_b = np.swapaxes(C_b_n, -1, -2)
    # EO variances in the camera / body axes: the EO's roll, pitch, yaw sigmas taken as NED tilt sigmas
    # (small roll and pitch), its N, E, U position sigmas as NED
    att_var_n = photos.sigma_attitude**2
    return PhotoResiduals(rho=camera_rotation_residual(photos.C_c_n_eo, photos.C_c_n_adjusted),
                          p=body_offset(C_b_n, photos.d_ned), C_c_b=C_c_b, C_n_c=C_n_c, C_n_b=C_n_b,
                          att_var_n=att_var_n, att_var_c=np.einsum("nij,nj->ni", C_n_c**2, att_var_n),
                          pos_var_b=np.einsum("nij,nj->ni", C_n_b**2, photos.sigma_position**2))


@dataclass(frozen=True)
class StripFits:
    """The variance-component fits (:func:`fit_offset`) of the strip means of the attitude residual [rad, camera
    frame] and the position difference [m, body frame], with their delete-one-strip jackknife sigmas (3, or None).

    ``with_tilt``: the flight-constant horizontal NED error is estimated (``heading_diversity`` of the strips at
    least ``HEADING_DIVERSITY_MIN``, two strips or more)."""

    attitude: StripMeans
    position: StripMeans
    heading_diversity: float
    with_tilt: bool
    attitude_fit: OffsetFit
    position_fit: OffsetFit
    attitude_jackknife: np.ndarray | None
    position_jackknife: np.ndarray | None


def _fit_strips(residuals: PhotoResiduals, strips: Strips) -> StripFits:
    """Average the residuals per strip and fit the boresight [rad, camera] and lever-arm [m, body] offsets."""
    attitude = _strip_means(residuals.rho, residuals.C_n_c, residuals.att_var_c, strips)
    position = _strip_means(residuals.p, residuals.C_n_b, residuals.pos_var_b, strips)
    diversity = heading_diversity(attitude.columns)
    with_tilt = diversity >= HEADING_DIVERSITY_MIN and strips.count >= 2
    return StripFits(attitude=attitude, position=position, heading_diversity=diversity, with_tilt=with_tilt,
                     attitude_fit=fit_offset(attitude, with_tilt), position_fit=fit_offset(position, with_tilt),
                     attitude_jackknife=jackknife(attitude, with_tilt),
                     position_jackknife=jackknife(position, with_tilt))


@dataclass(frozen=True)
class AttitudeFloor:
    """INS attitude errors no number of photos averages out, added to the boresight's covariance.

    ``cov_c`` (3, 3) their covariance [rad^2, camera frame]; ``yaw_var`` the flight-constant yaw variance [rad^2];
    ``body_tilt_deg`` (2) the body-fixed tilt sigma about body x and y [deg]; ``accel_sigma`` the filter's
    accelerometer-bias sigma [m/s^2, body x, y, z] it came from, None when it is the conservative bound."""

    cov_c: np.ndarray
    yaw_var: float
    body_tilt_deg: np.ndarray
    accel_sigma: np.ndarray | None


def _attitude_floor(residuals: PhotoResiduals, strips: Strips, fits: StripFits, accel_sigma: np.ndarray | None,
                    gravity_m_s2: float) -> AttitudeFloor:
    """The flight-constant attitude errors (docs/boresight.md, "sigma"); ``accel_sigma`` [m/s^2, body] from the
    process summary or None, ``gravity_m_s2`` the normal gravity at the photos [m/s^2].

    * the flight-constant yaw error adds onto b_z (and leaks into b_x, b_y through the camera's tilt): its
      variance is at most the EO's median yaw variance (the variance of a mean is at most the mean variance); the
      strips' yaw scatter tau_D is already in the GLS covariance, adding it again would count it twice;
    * a tilt error fixed in the *body* frame (the filter's accelerometer-bias error over g) adds onto b_x, b_y on
      every heading. With the process summary its variance is the filter's bias variance over g^2; without, the
      EO's tilt variance the between-strip scatter does not account for is a bound (it also holds the NED tilt,
      which the headings separate: pessimistic); with one heading the NED-constant tilt is not separated either."""
    used = strips.index >= 0
    eo_att_var = np.median(residuals.att_var_n[used], axis=0)
    tau2 = fits.attitude_fit.between_sigma**2
    yaw_var = float(eo_att_var[YAW])
    mean_C_n_c = residuals.C_n_c[used].mean(axis=0)
    if fits.with_tilt:
        floor_c = np.outer(mean_C_n_c[:, DOWN], mean_C_n_c[:, DOWN]) * yaw_var
    else:
        floor_c = mean_C_n_c @ np.diag([eo_att_var[ROLL], eo_att_var[PITCH], yaw_var]) @ mean_C_n_c.T
    C_c_b = residuals.C_c_b
    if accel_sigma is not None:
        body_tilt_c = accel_bias_tilt_covariance_camera(accel_sigma, gravity_m_s2, C_c_b)
        body_tilt_deg = np.degrees([accel_sigma[BODY_Y], accel_sigma[BODY_X]] / np.float64(gravity_m_s2))
    else:
        level_var = float(np.mean(eo_att_var[LEVEL])) - (float(np.mean(tau2[HORIZONTAL])) if fits.with_tilt else 0.0)
        level_var = max(0.0, level_var)
        body_tilt_c = C_c_b.T @ np.diag([level_var, level_var, 0.0]) @ C_c_b
        body_tilt_deg = np.degrees(np.sqrt([level_var, level_var]))
    return AttitudeFloor(cov_c=floor_c + body_tilt_c, yaw_var=yaw_var, body_tilt_deg=body_tilt_deg,
                         accel_sigma=accel_sigma)


def _boresight_components(boresight_rad: np.ndarray, fits: StripFits, floor: AttitudeFloor) -> list[Component]:
    """Roll, pitch, yaw corrections of the configured boresight ``boresight_rad`` [rad] and their sigmas [deg]:
    the camera-frame offset [rad] mapped to the angles by the Jacobian at the corrected boresight."""
    fit_att, jk_att = fits.attitude_fit, fits.attitude_jackknife
    cov_b = fit_att.cov + floor.cov_c
    new_angles = corrected_boresight(boresight_rad, fit_att.offset)
    J = boresight_angle_jacobian(new_angles)
    correction_deg = np.degrees(wrap_pi(new_angles - boresight_rad))
    sigma_deg = np.degrees(np.sqrt(np.diag(J @ cov_b @ J.T)))
    model_deg = np.degrees(np.sqrt(np.diag(J @ fit_att.cov @ J.T)))
    jk_deg = None if jk_att is None else np.degrees(np.sqrt(np.diag(J @ np.diag(jk_att**2) @ J.T)))
    boresight = [Component(name, "deg", float(np.degrees(boresight_rad[k])), float(correction_deg[k]),
                           float(sigma_deg[k]), float(model_deg[k]), None if jk_deg is None else float(jk_deg[k]),
                           True, "") for k, name in enumerate(("roll", "pitch", "yaw"))]
    _explain_boresight_sigma(boresight, floor, fits.with_tilt)
    return boresight


def _explain_boresight_sigma(boresight: list[Component], floor: AttitudeFloor, with_tilt: bool) -> None:
    """Say in each component's ``why`` which flight-constant INS error its sigma includes."""
    boresight[YAW].why = (f"includes the INS's flight-constant yaw error ({np.degrees(np.sqrt(floor.yaw_var)):.3f} "
                          "deg: the EO's median yaw sigma, which bounds it): it adds straight onto the boresight yaw")
    accel_sigma = floor.accel_sigma
    for k in (ROLL, PITCH):
        c = boresight[k]
        if accel_sigma is not None:
            c.why = (f"includes a body-fixed INS tilt of {floor.body_tilt_deg[k]:.4f} deg about body {'xy'[k]} (the "
                     f"filter's accelerometer-bias sigma {accel_sigma[1 - k]:.2g} m/s^2 along body {'yx'[k]} over g, "
                     "from the process summary): it adds onto roll and pitch on every heading")
        else:
            c.why = (f"CONSERVATIVE: includes a body-fixed INS tilt bound of {floor.body_tilt_deg[k]:.4f} deg (the "
                     "EO's tilt sigma not explained by the strips' scatter); pass --process-summary summary.json "
                     "(georef process --summary-json) to use the filter's accelerometer-bias sigma instead")
        if not with_tilt:
            c.why = ("all strips on one heading: the INS's flight-constant tilt is not separated; its sigma (the EO's "
                     "median tilt sigma) is included, " + c.why)


@dataclass(frozen=True)
class BodyShift:
    """A body-fixed position error in the lever-arm y sigma: its ``variance`` [m^2] and ``what`` bounds it."""

    variance: float
    what: str


def _body_shift(photos: MatchedPhotos, strips: Strips, fit_pos: OffsetFit, process: ProcessFigures | None
                ) -> BodyShift:
    """A position error fixed in the body frame (from the INS/GNSS solution) moves the camera like a lever arm on
    every heading: the EO's horizontal position variance [m^2] the strips' scatter does not account for bounds it.
    The filter knows one such error, its GNSS lever-arm estimate's (process summary; a configured GNSS lever arm
    is the same on every flight processed with it, so the calibration absorbs its error); the bound is kept even
    so: without it the simulated blocks' lever-y errors exceed the between-strip sigma (docs/boresight.md)."""
    used = strips.index >= 0
    pos_tau2 = fit_pos.between_sigma**2
    eo_pos_var = np.median(photos.sigma_position[used] ** 2, axis=0)
    variance = max(0.0, float(np.mean(eo_pos_var[HORIZONTAL]) - np.mean(pos_tau2[HORIZONTAL])))
    what = f"{np.sqrt(variance):.3f} m the EO's sigmas allow"
    gnss_lever = None if process is None else process.gnss_lever_arm_sigma_m
    if gnss_lever is not None and gnss_lever[BODY_Y] ** 2 > variance:
        variance = float(gnss_lever[BODY_Y] ** 2)
        what = f"{gnss_lever[BODY_Y]:.3f} m, the filter's GNSS lever-arm y sigma (process summary)"
    return BodyShift(variance=variance, what=what)


def _lever_arm_components(lever: np.ndarray, fits: StripFits, shift: BodyShift, speeds: list[float]
                          ) -> list[Component]:
    """Corrections of the configured camera lever arm ``lever`` [m, body x, y, z] and their sigmas [m]; only y is
    estimated (x goes with the trigger latency at the strips' ``speeds`` [m/s], z with a vertical datum shift)."""
    fit_pos, jk_pos = fits.position_fit, fits.position_jackknife
    lever_model = np.sqrt(np.diag(fit_pos.cov))
    lever_sigma = np.sqrt(lever_model**2 + shift.variance)
    lever_arm = [Component(name, "m", float(lever[k]), float(fit_pos.offset[k]), float(lever_sigma[k]),
                           float(lever_model[k]), None if jk_pos is None else float(jk_pos[k]), True)
                 for k, name in enumerate(("x", "y", "z"))]
    x, y, z = lever_arm[BODY_X], lever_arm[BODY_Y], lever_arm[BODY_Z]
    x.estimated = x.observed = False
    x.why = (f"combined with the trigger latency: both move the camera along track (dx = lever x + v dt, "
             f"v = {min(speeds, default=0):.1f}-{max(speeds, default=0):.1f} m/s); the value is lever x + "
             "v dt, not applied")
    z.estimated = z.observed = False
    z.why = ("combined with a vertical datum shift (heights of the block vs the EO's): both move the "
             "camera along body z on every heading; not applied")
    if not fits.with_tilt:
        y.estimated = y.observed = False
        y.why = ("combined with a horizontal datum shift: separable only with strips flown in opposite headings; not "
                 "applied")
    elif abs(y.value) <= SIGNIFICANT * y.sigma:
        y.estimated = False
        y.why = (f"not significant (|{y.value:+.3f}| <= {SIGNIFICANT:g} x {y.sigma:.3f} m; body-fixed position "
                 f"error in the sigma: {shift.what}): configured value kept")
    else:
        y.why = f"body-fixed position error in the sigma: {shift.what}"
    return lever_arm


@dataclass(frozen=True)
class Findings:
    """What weakens the calibration (``problems``: exit code 4) and what the user can do (``advice``)."""

    problems: list[str]
    advice: list[str]


def _findings(strips: Strips, fits: StripFits, boresight: list[Component], lever_arm: list[Component],
              process: ProcessFigures | None) -> Findings:
    """The checks, in report order: sigma source, strip count, heading diversity, then :func:`_consistency`."""
    problems: list[str] = []
    advice: list[str] = []
    if process is None or process.accel_bias_sigma_m_s2 is None:
        why = ("the process summary has no accelerometer-bias sigma (method " + process.method + ")"
               if process is not None else "no --process-summary")
        advice.append(f"the roll and pitch sigmas are CONSERVATIVE ({why}): they bound the body-fixed INS tilt by "
                      "the EO's tilt sigma, typically 2-3 x too large; process with --method rts or ekf and "
                      "--summary-json summary.json, then pass --process-summary summary.json")
    if strips.count < MIN_STRIPS_GOOD:
        problems.append(f"only {strips.count} strip(s) of {MIN_STRIP_PHOTOS}+ straight photos: the between-strip "
                        "variance is not measured (the sigma falls back to the EO's per-photo sigma)")
        advice.append("adjust a block with at least 3 strips, in opposite headings, ideally with cross strips")
    if not fits.with_tilt:
        problems.append(f"strip headings do not separate the INS's tilt from the boresight (diversity "
                        f"{fits.heading_diversity:.2f} < {HEADING_DIVERSITY_MIN})")
        advice.append("include strips flown in the opposite heading and cross strips")
    consistency = _consistency(strips, fits, boresight, lever_arm)
    return Findings(problems=problems + consistency.problems, advice=advice + consistency.advice)


def _consistency(strips: Strips, fits: StripFits, boresight: list[Component], lever_arm: list[Component]
                 ) -> Findings:
    """The strip residuals' chi-square against the EO's sigmas (level ``CHI2_LEVEL``), and estimated components
    whose jackknife sigma exceeds ``JACKKNIFE_RATIO_MAX`` times the model's (five strips or more)."""
    problems: list[str] = []
    advice: list[str] = []
    for label, fit in (("attitude", fits.attitude_fit), ("position", fits.position_fit)):
        if fit.dof > 0:
            limit = chi2_isf(1.0 - CHI2_LEVEL, fit.dof)
            if fit.chi2 > limit:
                problems.append(f"{label} residuals of the strips are inconsistent with the EO's sigmas: chi-square "
                                f"{fit.chi2:.1f} > {limit:.1f} ({fit.dof} dof)")
                advice.append(f"check the {label} inputs: the same CRS (--crs) and heights for both tables, the "
                              "image names' match, the configured mounting, and the block's own quality")
    for items, what in ((boresight, "boresight"), ([lever_arm[BODY_Y]], "lever arm")):
        for c in items:
            if c.estimated and c.jackknife_sigma is not None and c.jackknife_sigma > JACKKNIFE_RATIO_MAX * max(
                    c.model_sigma, 1e-12) and strips.count >= 5:
                problems.append(f"{what} {c.name}: the jackknife over strips gives sigma {c.jackknife_sigma:.4g} "
                                f"{c.unit}, {c.jackknife_sigma / c.model_sigma:.1f} x the model's {c.model_sigma:.4g}")
                advice.append("strips disagree more than their scatter says: look for a strip with a bad "
                              "adjustment or an INS problem (the strips table)")
    return Findings(problems=problems, advice=advice)


def _strip_rows(photos: MatchedPhotos, strips: Strips, fits: StripFits, speeds: list[float]) -> list[dict[str, Any]]:
    """The strips table: photos, first and last label, mean heading [deg], ground speed [m/s], and the fit's
    residuals of the strip mean (attitude [deg, camera frame], position [m, body frame])."""
    strip_rows = []
    for s in range(strips.count):
        members = np.flatnonzero(strips.index == s)
        strip_rows.append({"strip": s + 1, "photos": int(len(members)),
                           "first": str(photos.label[members[0]]), "last": str(photos.label[members[-1]]),
                           "heading_deg": float(np.degrees(np.angle(np.mean(np.exp(
                               1j * np.radians(photos.heading_deg[members])))))) % 360.0,
                           "speed_mps": float(speeds[s]) if speeds else None,
                           "attitude_residual_deg": [float(v) for v in np.degrees(fits.attitude_fit.residuals[s])],
                           "position_residual_m": [float(v) for v in fits.position_fit.residuals[s]]})
    return strip_rows


def calibrate(photos: MatchedPhotos, boresight_deg: Any, lever_arm_camera_m: Any, source: Any = "input",
              process: ProcessFigures | None = None) -> BoresightCalibration:
    """Estimate the boresight and camera lever-arm corrections from matched photos (module docstring).

    ``boresight_deg`` (roll_b, pitch_b, yaw_b) [deg] and ``lever_arm_camera_m`` [m, body] are the values the EO
    table was processed with. ``process``: the navigation filter's figures of the run that wrote the EO
    (``georef process --summary-json``): with its accelerometer-bias sigma the body-fixed INS tilt in the roll and
    pitch sigma is that sigma over g (without, a conservative bound from the EO's tilt sigma); its GNSS lever-arm
    sigma, when the filter estimated the lever arm, bounds the body-fixed position error in the lever-arm y sigma
    from below (``docs/boresight.md``).

    Raises :class:`CalibrationInputError` with fewer than ``MIN_PHOTOS`` photos or no
    strip; a calibration from fewer than ``MIN_STRIPS_GOOD`` strips or failing a check has ``problems``."""
    boresight_rad = np.radians(np.asarray(boresight_deg, float))
    lever = np.asarray(lever_arm_camera_m, float)
    _check_photos(photos, source, process)
    strips = _straight_strips(photos, source)
    residuals = _photo_residuals(photos, boresight_rad)
    fits = _fit_strips(residuals, strips)
    accel_sigma = None if process is None else process.accel_bias_sigma_m_s2
    floor = _attitude_floor(residuals, strips, fits, accel_sigma, photos.gravity_m_s2)
    boresight = _boresight_components(boresight_rad, fits, floor)
    speeds = _strip_speeds(photos, strips)
    lever_arm = _lever_arm_components(lever, fits, _body_shift(photos, strips, fits.position_fit, process), speeds)
    findings = _findings(strips, fits, boresight, lever_arm, process)
    fit_att, fit_pos = fits.attitude_fit, fits.position_fit
    return BoresightCalibration(
        boresight=boresight, lever_arm=lever_arm, photos_matched=len(photos),
        photos_used=int(np.count_nonzero(strips.index >= 0)), photos_in_turns=strips.in_turns,
        strips=_strip_rows(photos, strips, fits, speeds), tilt_estimated=fits.with_tilt,
        heading_diversity=fits.heading_diversity,
        ins_tilt_deg=None if fit_att.tilt is None else [float(v) for v in np.degrees(fit_att.tilt)],
        between_strip_attitude_deg=[float(v) for v in np.degrees(fit_att.between_sigma)],
        between_strip_position_m=[float(v) for v in fit_pos.between_sigma],
        chi2_attitude=fit_att.chi2, chi2_position=fit_pos.chi2, dof_attitude=fit_att.dof, dof_position=fit_pos.dof,
        unmatched_labels=photos.unmatched_labels, eo_rows_flagged=photos.eo_rows_flagged,
        eo_rows_without_camera=photos.eo_rows_without_camera, problems=findings.problems, advice=findings.advice,
        sigma_source=SIGMA_CONSERVATIVE if accel_sigma is None else SIGMA_FROM_FILTER)


def _strip_speeds(photos: MatchedPhotos, strips: Strips) -> list[float]:
    """Ground speed of each strip [m/s]: first to last photo's grid distance over the time."""
    speeds = []
    for s in range(strips.count):
        members = np.flatnonzero(strips.index == s)
        a, b = members[0], members[-1]
        span = photos.time[b] - photos.time[a]
        speeds.append(float(np.hypot(*(photos.grid[b] - photos.grid[a])) / span) if span > 0 else 0.0)
    return speeds


def calibration_toml(result: BoresightCalibration, eo_name: str, adjusted_name: str) -> str:
    """``calibration.toml``: a ``[mounting]`` section ``georef process --config`` reads (boresight and
    lever_arm_camera: configured plus the estimated corrections) with the sigmas and what was not estimated as
    comments (the loader reads no other keys; ``docs/boresight.md``)."""
    def triple(values: list[float]) -> str:
        return "[" + ", ".join(f"{v:.6f}" for v in values) + "]"

    lines = ["# Boresight / camera lever-arm calibration (georef calibrate-boresight)",
             f"# from {eo_name} and the adjusted cameras {adjusted_name}: {result.photos_used} photos in "
             f"{len(result.strips)} strips",
             "# use: georef process ... --config flight.toml --config calibration.toml", "#"]
    for c in result.boresight:
        jk = "-" if c.jackknife_sigma is None else f"{c.jackknife_sigma:.4f}"
        lines.append(f"# boresight {c.name}: {c.configured:.6f} {c.value:+.6f} = {c.calibrated:.6f} deg, sigma "
                     f"{c.sigma:.4f} deg (between strips {c.model_sigma:.4f}, jackknife {jk})")
        if c.why:
            lines.append(f"#   {c.why}")
    for c in result.lever_arm:
        jk = "-" if c.jackknife_sigma is None else f"{c.jackknife_sigma:.3f}"
        state = "applied" if c.estimated else "NOT applied"
        lines.append(f"# lever arm {c.name}: correction {c.value:+.3f} m, sigma {c.sigma:.3f} m (jackknife {jk}), "
                     f"{state}")
        if c.why:
            lines.append(f"#   {c.why}")
    for problem in result.problems:
        lines.append(f"# WEAK: {problem}")
    lines += ["", "[mounting]", f"boresight = {triple([c.calibrated for c in result.boresight])}",
              f"lever_arm_camera = {triple([c.calibrated for c in result.lever_arm])}", ""]
    return "\n".join(lines)
