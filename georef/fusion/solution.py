"""The navigation solution every fusion method returns, at the IMU rows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from georef.frames import C_e_n, C_n_e

if TYPE_CHECKING:
    from georef.fusion.yaw_offset import YawOffsetSolution


@dataclass
class GnssUse:
    """How each GNSS fix was used, one row per fix (M rows):

    * ``time`` [s] (M,); ``status`` (M,): 1 used, 0 rejected, -1 not processed (outside the IMU span or before
      the filter's start);
    * ``innovation`` [m] (M, 3): the predicted minus the measured position of the fix, resolved in the local
      NED frame at the fix (north, east, down), for every method (``axis`` filters along ECEF axes and turns
      its innovations into NED);
    * ``innovation_var`` [m^2] (M, 3): the innovation's variance along north, east and down;
    * ``line``: the fix's line in its file;
    * ``nis``: the normalised innovation squared (chi-square with 3 degrees of freedom when the model is right)
      with the filter's full innovation covariance, in the frame the filter works in;

    NaN where not processed."""

    time: np.ndarray
    status: np.ndarray
    innovation: np.ndarray
    innovation_var: np.ndarray
    line: np.ndarray
    nis: np.ndarray | None = None

    @property
    def rejected_lines(self) -> list[int]:
        return [int(x) for x in self.line[self.status == 0]]

    @property
    def normalised_innovation_sq(self) -> np.ndarray:
        """Per-fix chi-square statistic of the 3-D innovation: the filter's own (full covariance) when it gave one,
        else from the diagonal innovation variances."""
        if self.nis is not None:
            return self.nis
        return np.sum(self.innovation**2 / self.innovation_var, axis=1)


#: a separation's sigma below this share of the forward filter's own is taken as zero (the two agree there by
#: construction) and left out of :meth:`ForwardSeparation.sigma_scale`
SEPARATION_SIGMA_FLOOR = 0.05


@dataclass
class ForwardSeparation:
    """The forward filter's solution against the smoothed one, at the filter's covariance epochs.

    ``time`` [s] (E,); ``position`` forward minus smoothed IMU position, NED at the smoothed point [m] (E, 3);
    ``attitude`` forward minus smoothed ZYX roll, pitch, yaw [rad] (E, 3), yaw wrapped to (-pi, pi];
    ``position_sigma`` and ``attitude_sigma`` the 1-sigma of that difference the filter expects,
    ``sqrt(P_forward - P_smoothed)`` per component (for a Rauch-Tung-Striebel smoother the smoothed error is
    uncorrelated with the difference, so the difference's covariance is the difference of the covariances)
    [m], [rad]; ``forward_position_sigma`` and ``forward_attitude_sigma`` the forward filter's own 1-sigma.
    POSPac and Inertial Explorer users look at this first: a separation far outside its sigma marks a stretch
    where the forward filter and the smoother disagree (a bad fix, a mis-modelled outage).
    """

    time: np.ndarray
    position: np.ndarray
    attitude: np.ndarray
    position_sigma: np.ndarray
    attitude_sigma: np.ndarray
    forward_position_sigma: np.ndarray
    forward_attitude_sigma: np.ndarray

    def sigma_scale(self) -> tuple[np.ndarray, np.ndarray]:
        """How far the sigmas are borne out on this flight: rms(separation / its sigma) of the position (north,
        east, down) and the attitude (roll, pitch, yaw) (3,) each; 1 when the filter's model fits the data, above
        1 when its sigmas are too small. Epochs where the separation's sigma vanishes (the forward filter and the
        smoother agree by construction: the last epoch of each segment) do not count; NaN when none is left."""
        def scale(separation: np.ndarray, sigma: np.ndarray, forward_sigma: np.ndarray) -> np.ndarray:
            usable = sigma > SEPARATION_SIGMA_FLOOR * np.maximum(forward_sigma, 1e-12)
            z2 = np.where(usable, (separation / np.where(usable, sigma, 1.0)) ** 2, 0.0)
            count = usable.sum(axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                return np.where(count > 0, np.sqrt(z2.sum(axis=0) / np.maximum(count, 1)), np.nan)

        return (scale(self.position, self.position_sigma, self.forward_position_sigma),
                scale(self.attitude, self.attitude_sigma, self.forward_attitude_sigma))


@dataclass
class HeldOutCheck:
    """How the solution predicts GNSS fixes it was not given (:func:`georef.fusion.ins.held_out_check`): the fixes
    of ``windows`` [s] (``held`` of them) left out, the rest fused exactly as the delivered solution was, and the
    left-out fixes predicted. ``error_rms_h`` [m] the horizontal RMS of prediction minus fix; ``interpolation_rms_h``
    [m] the same for straight lines between the kept fixes on either side (what users did before); ``fix_sigma_h``
    [m] the fixes' median horizontal sigma (their own, else configured); ``z_rms`` the rms of the horizontal
    errors over their predicted sigma (the solution's and the fix's): 1 when the sigmas are honest;
    ``window_error_rms_h`` and ``window_interpolation_rms_h`` [m] per window."""

    windows: list[tuple[float, float]]
    held: int
    error_rms_h: float
    interpolation_rms_h: float
    fix_sigma_h: float
    z_rms: float
    window_error_rms_h: list[float]
    window_interpolation_rms_h: list[float]
    #: the filter diverged bridging the held-out windows (the figures are then NaN)
    diverged: bool = False


@dataclass
class InsInfo:
    """What the full-state filters (``rts``, ``ekf``, and the EKF + RTS the graph starts from) leave beside the
    trajectory, at the N IMU rows unless said otherwise:

    * ``vel_var_n`` NED velocity variances [m^2/s^2] (N, 3);
    * ``gyro_bias`` [rad/s] and ``accel_bias`` [m/s^2] (N, 3), the estimated sensor biases, body axes;
    * ``unit_yaw_origin`` [rad] (N,): the POS unit's yaw origin ``d`` (true yaw = unit yaw + d);
    * ``epoch_rows`` (E,): the rows of the covariance epochs, ``epoch_sigma`` (E, states): every state's 1-sigma
      there, in the units of :mod:`georef.fusion.ins_layout`;
    * ``start_row``: the first row the filter solved; ``smoothed``: an RTS pass ran; ``heading_source``: where the
      initial heading came from; ``unit_aiding``: the unit's own roll/pitch/yaw aided the filter.
    """

    vel_var_n: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    unit_yaw_origin: np.ndarray
    epoch_rows: np.ndarray
    epoch_sigma: np.ndarray
    start_row: int
    smoothed: bool
    heading_source: str
    unit_aiding: bool


@dataclass
class AxisInfo:
    """What the per-axis method leaves beside the trajectory: ``yaw_offset``, the POS unit's yaw offset and drift
    recovered from GNSS (:class:`georef.fusion.yaw_offset.YawOffsetSolution`), and ``accel_sigma_n`` [m/s^2] (3,),
    the white acceleration noise per sample the filters used, north, east, down."""

    yaw_offset: YawOffsetSolution
    accel_sigma_n: np.ndarray


@dataclass
class GraphCalibration:
    """The factor graph's solution reduced to its calibration variable (GNSS lever arm x, y, z [m, body], GNSS time
    offset [s]): the posterior ``mean`` (4,) and ``covariance`` (4, 4), and the prior it was given
    (``prior_mean``, ``prior_covariance``); what a campaign combines across flights (:mod:`georef.campaign`)."""

    mean: np.ndarray
    covariance: np.ndarray
    prior_mean: np.ndarray
    prior_covariance: np.ndarray

    def as_lists(self) -> dict[str, list]:
        """The four arrays as nested lists under their names (JSON; read back by ``FlightReduction.from_dict``)."""
        return {name: np.asarray(getattr(self, name), float).tolist()
                for name in ("mean", "covariance", "prior_mean", "prior_covariance")}


@dataclass
class ScaleFactors:
    """Scale-factor errors the graph estimated (``graph.graph_scale_factor_sigma`` > 0) [ppm, body x, y, z], with
    their marginal 1-sigma, and the 1-sigma of their prior [ppm]: an axis whose sigma stays near it was not
    observable in the flight's motion."""

    accel_ppm: np.ndarray
    accel_sigma_ppm: np.ndarray
    gyro_ppm: np.ndarray
    gyro_sigma_ppm: np.ndarray
    prior_sigma_ppm: float


@dataclass
class GraphInfo:
    """What the factor graph leaves beside the trajectory:

    * ``lever_arm_m``, ``lever_arm_sigma_m`` (3,): the GNSS lever arm [m, body x forward, y right, z down]
      estimated with the trajectory, and its marginal 1-sigma; ``time_offset_s``, ``time_offset_sigma_s`` the GNSS
      time offset [s] (each fix measured that long before its tag) and its 1-sigma; ``calibration`` both as one
      reduction with their prior;
    * ``rejected_fixes`` of ``fixes``: the fixes the robust pass dropped, of those at keyframes;
    * ``rts_separation_sigma`` (K,): the graph's horizontal position minus the RTS's it started from, in units of
      the graph's own horizontal sigma, at each of the ``keyframes`` K; ``rts_attitude_separation_sigma`` (K,) the
      same for the attitude, the largest axis;
    * ``nhc_factors``: the ground-vehicle factors; ``error_final``: the graph's final error (half the weighted sum of
      squared residuals);
    * ``scale_factors``: the scale-factor errors when estimated, else None;
    * ``noise_refit_lever_arm_m`` [m, body]: the lever arm the EKF + RTS were refitted with when the robust pass
      found it elsewhere than configured, else None.
    """

    lever_arm_m: np.ndarray
    lever_arm_sigma_m: np.ndarray
    time_offset_s: float
    time_offset_sigma_s: float
    calibration: GraphCalibration
    rejected_fixes: int
    fixes: int
    rts_separation_sigma: np.ndarray
    rts_attitude_separation_sigma: np.ndarray
    keyframes: int
    nhc_factors: int
    error_final: float
    scale_factors: ScaleFactors | None = None
    noise_refit_lever_arm_m: np.ndarray | None = None


@dataclass
class NavSolution:
    """IMU navigation at the POS rows, SI units.

    ``r_e`` ECEF position of the IMU [m], ``v_e`` ECEF velocity [m/s], ``lat``/``lon`` [rad] and
    ``height`` [m] of the IMU, body attitude ``roll, pitch, yaw`` [rad] (ZYX, body-to-NED),
    ``pos_var_n`` NED position variances [m^2] (N, 3), ``att_sigma`` roll/pitch/yaw 1-sigma [rad] (N, 3),
    ``valid`` rows that carry a solution, and, from the full-state filters, ``att_cov_n`` the covariance
    (N, 3, 3) [rad^2] of the small NED rotation ``phi`` with ``C_est = (I - [phi x]) C_true``.
    """

    method: str
    time: np.ndarray
    r_e: np.ndarray
    v_e: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    pos_var_n: np.ndarray
    att_sigma: np.ndarray
    valid: np.ndarray
    gnss: GnssUse
    #: the full-state filters' biases, velocity variances and epochs (``rts``, ``ekf``, ``graph``); else None
    ins_info: InsInfo | None = None
    #: the per-axis method's yaw offset and acceleration noise (``axis``); else None
    axis_info: AxisInfo | None = None
    #: the factor graph's calibration and separations (``graph``); else None
    graph_info: GraphInfo | None = None
    att_cov_n: np.ndarray | None = None
    #: how a full-state solution was reached (georef.fusion.ins.InsDiagnostics); None for other methods
    diagnostics: Any = None
    #: the forward filter against the smoothed solution (``--method rts``); None when nothing was smoothed
    forward: ForwardSeparation | None = None

    @property
    def v_n(self) -> np.ndarray:
        """NED velocity [m/s] (N, 3)."""
        return np.einsum("nij,nj->ni", C_e_n(self.lat, self.lon), self.v_e)


def ecef_variances_to_ned(lat: np.ndarray, lon: np.ndarray, var_e: np.ndarray) -> np.ndarray:
    """NED variances [m^2] (N, 3) of a position whose ECEF covariance is ``diag(var_e)``."""
    C = C_e_n(lat, lon)
    return np.einsum("nij,nj->ni", C**2, var_e)


def ned_variances_to_ecef(lat: np.ndarray, lon: np.ndarray, var_n: np.ndarray) -> np.ndarray:
    """Diagonal of the ECEF covariance [m^2] (N, 3) of a position with NED covariance ``diag(var_n)``."""
    C = C_n_e(lat, lon)
    return np.einsum("nij,nj->ni", C**2, var_n)
