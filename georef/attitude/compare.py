"""Evaluating attitude series: RMS against a reference and a constant yaw offset between two series.

[A1] (``docs/attitude.md``, References) could not evaluate yaw because the filter's yaw and the Vicon reference
differ by an unknown constant. :func:`yaw_offset` estimates it in closed form: the rotation ``Rz(ψ)`` about the
NED down axis that best maps one attitude series onto the other, ``ψ = atan2(M₁₀ − M₀₁, M₀₀ + M₁₁)`` with
``M = Σ C_ref C_estᵀ`` (the least-squares fit of ``Rz(ψ) C_est ≈ C_ref`` in the Frobenius norm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.frames import dcm_to_euler, euler_to_dcm, wrap_pi


@dataclass
class YawOffset:
    offset: float          # rad, add to the estimate's yaw
    sigma: float           # rad, 1-sigma of the offset from the scatter (independent samples assumed)
    residual_rms: float    # rad, yaw RMS after removing the offset


def attitude_rms(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """RMS of roll, pitch, yaw differences [rad] between two (N, 3) Euler series [rad]; yaw wrapped."""
    diff = wrap_pi(np.asarray(estimate, float) - np.asarray(reference, float))
    return np.sqrt(np.nanmean(diff**2, axis=0))


def yaw_offset(estimate: np.ndarray, reference: np.ndarray) -> YawOffset:
    """Constant yaw offset between two (N, 3) ZYX Euler series [rad]: ``reference ≈ Rz(offset) estimate``."""
    C_est = euler_to_dcm(estimate[:, 0], estimate[:, 1], estimate[:, 2])
    C_ref = euler_to_dcm(reference[:, 0], reference[:, 1], reference[:, 2])
    M = np.einsum("nij,nkj->ik", C_ref, C_est)
    offset = float(np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1]))
    corrected = np.einsum("ij,njk->nik", euler_to_dcm(0.0, 0.0, offset), C_est)
    _, _, yaw = dcm_to_euler(corrected)
    residual = wrap_pi(yaw - reference[:, 2])
    return YawOffset(offset=offset, sigma=float(np.std(residual) / np.sqrt(len(residual))),
                     residual_rms=float(np.sqrt(np.mean(residual**2))))
