"""The navigation solution every fusion method returns, at the IMU rows."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from georef.frames import C_e_n, C_n_e


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
    info: dict = field(default_factory=dict)
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
