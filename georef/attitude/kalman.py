"""Textbook Kalman filters of [A2] (``docs/attitude.md``, References): the scalar filter and a linear KF with a
control input."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ScalarKalman:
    """One-dimensional filter: ``K = E_est/(E_est + E_mea)``, ``x += K (z - x)``, ``E_est = (1 - K) E_est``.

    ``process_noise`` > 0 gives the Arduino variant's heuristic: after each update ``E_est += |Δx| q``,
    so a moving signal keeps the filter responsive. ``E`` values are variances in the measurement's unit².
    """

    estimate: float
    estimate_error: float
    measurement_error: float
    process_noise: float = 0.0

    def update(self, measurement: float) -> float:
        gain = self.estimate_error / (self.estimate_error + self.measurement_error)
        previous = self.estimate
        self.estimate = previous + gain * (measurement - previous)
        self.estimate_error = (1.0 - gain) * self.estimate_error + abs(previous - self.estimate) * self.process_noise
        return self.estimate

    def run(self, measurements: np.ndarray) -> np.ndarray:
        """Filter a whole series; returns the estimate after each measurement."""
        return np.array([self.update(float(z)) for z in np.asarray(measurements, dtype=float)])


@dataclass
class LinearKalman:
    """``x⁻ = A x + B u``, ``P⁻ = A P Aᵀ + Q``; update with ``z = H x + v``, ``v ~ N(0, R)``.

    ``diagonal_covariance`` zeroes the off-diagonal terms of ``P⁻`` after every prediction, as the worked
    aircraft example of [A2] does (a simplification the text makes by hand).
    """

    A: np.ndarray
    B: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    x: np.ndarray
    P: np.ndarray
    diagonal_covariance: bool = False
    last_gain: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def __post_init__(self) -> None:
        for name in ("A", "B", "H", "Q", "R", "x", "P"):
            setattr(self, name, np.atleast_1d(np.asarray(getattr(self, name), dtype=float)))

    def predict(self, u: np.ndarray | float | None = None) -> np.ndarray:
        control = np.zeros(self.B.shape[1] if self.B.ndim == 2 else 1) if u is None else np.atleast_1d(u)
        B = self.B.reshape(len(self.x), -1)
        self.x = self.A @ self.x + B @ control
        self.P = self.A @ self.P @ self.A.T + self.Q
        if self.diagonal_covariance:
            self.P = np.diag(np.diag(self.P))
        return self.x

    def update(self, z: np.ndarray | float) -> np.ndarray:
        z = np.atleast_1d(np.asarray(z, dtype=float))
        S = self.H @ self.P @ self.H.T + self.R
        K = self.P @ self.H.T @ np.linalg.inv(S)
        self.x = self.x + K @ (z - self.H @ self.x)
        identity = np.eye(len(self.x))
        self.P = (identity - K @ self.H) @ self.P
        self.last_gain = K
        return self.x
