"""Position covariances of GNSS solutions: signed square roots, and the change from ENU or ECEF to NED.

* RTKLIB writes a covariance ``c`` as the *signed* square root ``s = sign(c) sqrt(|c|)`` (``sqvar`` in its
  ``solution.c``), so ``c = sign(s) s^2``; the variances are plain square roots.
* NED from ENU: north = E's second axis, east = its first, down = minus up. ``P_ned = T P_enu T^T`` with the
  permutation-and-sign matrix :data:`C_ENU_TO_NED`; the north-down and east-down covariances change sign.
* NED from ECEF: ``P_ned = C_e_n P_e C_e_n^T`` with :func:`georef.frames.earth.C_e_n` at the point.
* An ENU baseline from a base ``b``: ``r_e = r_b + C_n_e(b) T enu`` (the local level frame *at the base*, as
  RTKLIB's ``ecef2enu``); its covariance is in the base's frame too and is carried to the rover's NED through
  ECEF, which is exact however long the baseline.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from georef.frames.earth import C_e_n, C_n_e, geodetic_to_ecef

Array = NDArray[np.float64]

#: ENU -> NED: north = +E[1], east = +E[0], down = -E[2]
C_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: the three covariance pairs a solution file lists after its three standard deviations, as (row, column) of a 3x3
PAIR_01_12_20 = ((0, 1), (1, 2), (2, 0))


def covariance_from_signed_roots(sd: ArrayLike, cross: ArrayLike,
                                 pairs: tuple[tuple[int, int], ...] = PAIR_01_12_20) -> Array:
    """(K, 3, 3) covariances [m^2] from standard deviations ``sd`` (K, 3) [m] and signed roots ``cross`` (K, 3) [m]
    of the off-diagonal terms, ``cov = sign(s) s^2``, the k-th root being the (i, j) of ``pairs[k]``."""
    sd = np.asarray(sd, dtype=float)
    cross = np.asarray(cross, dtype=float)
    cov = np.zeros((*sd.shape[:-1], 3, 3))
    for axis in range(3):
        cov[..., axis, axis] = sd[..., axis] ** 2
    for k, (i, j) in enumerate(pairs):
        value = np.sign(cross[..., k]) * cross[..., k] ** 2
        cov[..., i, j] = value
        cov[..., j, i] = value
    return cov


def enu_to_ned_covariance(cov_enu: ArrayLike) -> Array:
    """(..., 3, 3) covariances [m^2] from east-north-up to north-east-down axes."""
    return C_ENU_TO_NED @ np.asarray(cov_enu, dtype=float) @ C_ENU_TO_NED.T


def neu_to_ned_covariance(cov_neu: ArrayLike) -> Array:
    """(..., 3, 3) covariances [m^2] from north-east-up to north-east-down axes (the up row and column negated)."""
    flip = np.diag([1.0, 1.0, -1.0])
    return flip @ np.asarray(cov_neu, dtype=float) @ flip


def ecef_to_ned_covariance(cov_e: ArrayLike, lat: ArrayLike, lon: ArrayLike) -> Array:
    """(..., 3, 3) ECEF covariances [m^2] in the NED frame at latitude, longitude [rad]."""
    C = C_e_n(lat, lon)
    return C @ np.asarray(cov_e, dtype=float) @ np.swapaxes(C, -1, -2)


def enu_baseline_to_ecef(enu: ArrayLike, base_lat: float, base_lon: float, base_height: float) -> Array:
    """ECEF positions [m] (K, 3) of east-north-up baselines [m] (K, 3) from a base at latitude, longitude [rad] and
    ellipsoidal height [m]."""
    r_b = geodetic_to_ecef(base_lat, base_lon, base_height)
    ned = np.asarray(enu, dtype=float) @ C_ENU_TO_NED.T
    return r_b + ned @ C_n_e(base_lat, base_lon).T


def enu_at_base_to_ned_covariance(cov_enu: ArrayLike, base_lat: float, base_lon: float, lat: ArrayLike,
                                  lon: ArrayLike) -> Array:
    """(K, 3, 3) covariances [m^2] given in the ENU frame at the base, in the NED frame at each point
    (latitude, longitude [rad])."""
    ned_base = enu_to_ned_covariance(cov_enu)
    C_b = C_n_e(base_lat, base_lon)
    cov_e = C_b @ ned_base @ C_b.T
    return ecef_to_ned_covariance(cov_e, lat, lon)


def correlations(cov: ArrayLike) -> Array:
    """(..., 3) correlation coefficients (0-1, 0-2, 1-2) of (..., 3, 3) covariances; 0 where a variance is 0."""
    cov = np.asarray(cov, dtype=float)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1), 0.0, None))
    out = np.zeros((*cov.shape[:-2], 3))
    for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
        denominator = sd[..., i] * sd[..., j]
        out[..., k] = np.divide(cov[..., i, j], denominator, out=np.zeros_like(denominator), where=denominator > 0)
    return out


def with_sigma_floor(cov: ArrayLike, floor: ArrayLike) -> Array:
    """(..., 3, 3) covariances whose standard deviations are raised to at least ``floor`` (..., 3) [m], the
    correlation coefficients kept: ``P' = D' R D'``. Still positive semi-definite when ``P`` was."""
    cov = np.asarray(cov, dtype=float)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1), 0.0, None))
    raised = np.maximum(sd, np.asarray(floor, dtype=float))
    scale = np.divide(raised, sd, out=np.ones_like(sd), where=sd > 0)
    out = cov * scale[..., :, None] * scale[..., None, :]
    # a zero variance has no correlation to keep: the floor alone
    zero = sd <= 0
    if np.any(zero):
        idx = np.nonzero(zero)
        out[(*idx[:-1], idx[-1], idx[-1])] = raised[zero] ** 2
    return out
