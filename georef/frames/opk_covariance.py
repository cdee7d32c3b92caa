"""Covariances in the photogrammetric frame: ω, φ, κ from the attitude covariance, and grid-axis positions.

Attitude errors are small rotations ``δ`` of the NED frame (``C' = exp([δ×]) C``, the convention of
``NavSolution.att_cov_n`` and :func:`georef.frames.rotations.euler_error_jacobian`), with covariance ``P``
[rad²]. The camera attitude is ``C_c_n = C_b_n C_c_b`` (boresight ``C_c_b``), so a NED-frame error of the body
is the same NED-frame error of the camera; and ``R_i_m = M C_c_n C_i_c`` with ``M`` the rotation from NED to the
grid frame (``enu_to_grid(γ) C_n_enu``, :mod:`georef.frames.photogrammetry`). Hence

    R_i_m' = exp([(M δ)×]) R_i_m,

a small rotation ``ε = M δ`` of the mapping frame. For ``R = Rx(ω) Ry(φ) Rz(κ)``,
``dR Rᵀ = [ε×]`` with ``ε = E (dω, dφ, dκ)``, where the columns of ``E`` are the three rotation axes expressed
in the mapping frame: ``x``, ``Rx(ω) y`` and ``Rx(ω) Ry(φ) z``:

    E = [[1, 0, sin φ], [0, cos ω, -sin ω cos φ], [0, sin ω, cos ω cos φ]],

so ``d(ω, φ, κ) = E⁻¹ M δ`` and ``Cov(ω, φ, κ) = J P Jᵀ`` with ``J = E⁻¹ M`` (first order; singular only at
φ = ±90°, a camera looking at the horizon). The roll and pitch sigmas are **not** the ω and φ sigmas: on a
north–south line ω is about the pitch axis, and on an east–west line about the roll axis.

Positions: the grid axes (easting, northing) are the local east and north turned by the meridian convergence γ
and scaled by the projection's point scale factor ``k``, so ``Cov_grid = k² G Cov_EN Gᵀ``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from georef.frames.photogrammetry import C_n_enu, enu_to_grid

Array = NDArray[np.float64]


def opk_axes(omega: ArrayLike, phi: ArrayLike) -> Array:
    """``E`` (..., 3, 3): mapping-frame small rotation per unit change of (ω, φ, κ) [rad]."""
    omega, phi = np.broadcast_arrays(np.asarray(omega, float), np.asarray(phi, float))
    so, co, sp, cp = np.sin(omega), np.cos(omega), np.sin(phi), np.cos(phi)
    zero, one = np.zeros_like(omega), np.ones_like(omega)
    return np.stack([np.stack([one, zero, sp], -1), np.stack([zero, co, -so * cp], -1),
                     np.stack([zero, so, co * cp], -1)], -2)


def opk_jacobian(omega: ArrayLike, phi: ArrayLike, convergence_deg: ArrayLike) -> Array:
    """``J = E⁻¹ M`` (..., 3, 3): d(ω, φ, κ) / dδ for a small NED rotation δ [rad/rad]."""
    M = enu_to_grid(convergence_deg) @ C_n_enu
    return np.linalg.solve(opk_axes(omega, phi), M)


def opk_covariance(omega: ArrayLike, phi: ArrayLike, convergence_deg: ArrayLike, att_cov_n: ArrayLike) -> Array:
    """Covariance (..., 3, 3) of (ω, φ, κ) [rad²] from the NED attitude covariance ``att_cov_n`` [rad²] at the
    camera's ω, φ [rad] and the grid convergence γ [deg]."""
    J = opk_jacobian(omega, phi, convergence_deg)
    return J @ np.asarray(att_cov_n, float) @ np.swapaxes(J, -1, -2)


def grid_position_covariance(var_n: ArrayLike, var_e: ArrayLike, convergence_deg: ArrayLike,
                             scale: ArrayLike) -> tuple[Array, Array, Array]:
    """Variances of easting and northing and their covariance [m² of the grid] from the north and east
    variances [m²] (uncorrelated, as the filters report them), the convergence γ [deg] and scale factor k."""
    G = enu_to_grid(convergence_deg)[..., :2, :2]
    var_n, var_e = np.broadcast_arrays(np.asarray(var_n, float), np.asarray(var_e, float))
    cov_en = np.zeros((*var_n.shape, 2, 2))
    cov_en[..., 0, 0], cov_en[..., 1, 1] = var_e, var_n
    k2 = np.asarray(scale, float) ** 2
    cov = k2[..., None, None] * (G @ cov_en @ np.swapaxes(G, -1, -2))
    return cov[..., 0, 0], cov[..., 1, 1], cov[..., 0, 1]
