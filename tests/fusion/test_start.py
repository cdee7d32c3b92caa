"""The start of the filter from any start (georef.fusion.start) and the effective count of correlated fixes
(georef.qc): each against an independent reference (the physics simulated, a sampled process, the simulator's
truth)."""

from __future__ import annotations

import numpy as np
import pytest

from georef.frames import euler_to_dcm
from georef.frames.earth import STANDARD_GRAVITY
from georef.fusion.start import (
    BANK_HEADINGS,
    LEVEL_NOISE,
    Level,
    bank_choice,
    first_motion,
    heading_prior,
    level_covariance,
    still_rows,
)
from georef.qc import effective_count
from georef.sim.flight import SimConfig, simulate


def _level_from(f_b: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] of a body whose accelerometers read ``f_b`` at rest (bias taken as zero)."""
    return float(np.arctan2(-f_b[1], -f_b[2])), float(np.arcsin(np.clip(f_b[0] / np.linalg.norm(f_b), -1, 1)))


def test_the_level_covariance_is_that_of_levels_made_from_biased_accelerometers():
    """Draw biases, make the level from each biased gravity reading as a still start does, and compare the sample
    covariance of (tilt error about N, E; bias error) with level_covariance's."""
    rng = np.random.default_rng(3)
    roll, pitch, yaw = np.radians([2.0, -1.5, 130.0])
    C_b_n = euler_to_dcm(roll, pitch, yaw)
    sigma_b = 0.3
    f_true = C_b_n.T @ np.array([0.0, 0.0, -STANDARD_GRAVITY])
    tilt, bias_error = [], []
    for b in rng.normal(0.0, sigma_b, (4000, 3)):
        r, p = _level_from(f_true + b)
        C_est = euler_to_dcm(r, p, yaw)
        # the filter's attitude error: C_est = (I - [phi x]) C_b_n
        E = np.eye(3) - C_est @ C_b_n.T
        tilt.append([0.5 * (E[2, 1] - E[1, 2]), 0.5 * (E[0, 2] - E[2, 0])])
        bias_error.append(-b)   # the bias left at zero: estimate minus truth
    tilt, bias_error = np.array(tilt), np.array(bias_error)
    level = Level(roll=roll, pitch=pitch, f_mean=f_true, window=(0.0, 10.0), still=True, gyro_bias=None,
                  gyro_bias_sigma=0.0)
    level_cov, bias_cov, cross = level_covariance(level, C_b_n, sigma_b)
    sample = np.cov(np.column_stack([tilt, bias_error]).T)
    np.testing.assert_allclose(sample[:2, :2] + LEVEL_NOISE**2 * np.eye(2), level_cov, rtol=0.08, atol=1e-7)
    np.testing.assert_allclose(sample[:2, 2:], cross, rtol=0, atol=0.08 * sigma_b**2 / STANDARD_GRAVITY)
    np.testing.assert_allclose(sample[2:, 2:], bias_cov, rtol=0.08, atol=0.08 * sigma_b**2)


def test_the_effective_count_of_an_autoregressive_sequence():
    """An AR(1) sequence with lag-one correlation r: n (1 - r) / (1 + r) independent values' worth, which is the
    variance of its mean (sampled)."""
    rng = np.random.default_rng(5)
    n, r = 1500, 0.6
    means, counts = [], []
    for _ in range(300):
        e = rng.normal(size=(n, 3))
        x = np.empty_like(e)
        x[0] = e[0]
        for k in range(1, n):
            x[k] = r * x[k - 1] + np.sqrt(1 - r**2) * e[k]
        counts.append(effective_count(np.arange(n, dtype=float), x, np.ones((n, 3))))
        means.append(x.mean(axis=0))
    expected = n * (1 - r) / (1 + r)
    assert abs(np.median(counts) - expected) < 0.08 * expected
    # the variance of the mean is that of the effective count of independent values (within sampling error)
    assert abs(np.var(np.concatenate(means)) * expected - 1.0) < 0.2
    # independent fixes count as themselves
    white = rng.normal(size=(n, 3))
    assert effective_count(np.arange(n, dtype=float), white, np.ones((n, 3))) > 0.9 * n


def _bank(headings: np.ndarray, true: float, spread: float, sharpness: float, epochs: int = 50):
    """Synthetic bank outputs: each filter's log-likelihood falls with its start heading's distance from ``true``
    from epoch 10 on, its yaw converges to ``true`` within ``spread`` [rad]."""
    d = np.abs(np.angle(np.exp(1j * (headings - true))))
    growth = np.clip(np.arange(epochs) - 10, 0, None)[:, None]
    cum = -sharpness * growth * d[None, :] ** 2
    yaw = np.tile(true + spread * np.sin(headings)[None, :], (epochs, 1))
    return np.arange(epochs, dtype=float), cum, yaw, np.full((epochs, len(headings)), np.radians(2.0))


def test_the_bank_decides_only_after_motion_and_when_the_headings_agree():
    prior = heading_prior(BANK_HEADINGS, None, None)
    t, cum, yaw, sigma = _bank(BANK_HEADINGS, np.radians(100.0), np.radians(2.0), 5.0)
    choice = bank_choice(BANK_HEADINGS, t, cum, yaw, sigma, prior, motion_from=20.0)
    assert choice.heading is not None and choice.decided_at >= 20.0
    assert abs(np.degrees(np.angle(np.exp(1j * (choice.heading - np.radians(100.0)))))) <= 30.0
    # no motion shown: undecided, whatever the filters claim
    assert bank_choice(BANK_HEADINGS, t, cum, yaw, sigma, prior, motion_from=np.inf).heading is None
    # filters that end at headings spread over the circle with equal likelihood: undecided
    flat = np.zeros_like(cum)
    spread_yaw = np.tile(BANK_HEADINGS, (len(t), 1))
    assert bank_choice(BANK_HEADINGS, t, flat, spread_yaw, sigma, prior, motion_from=0.0).heading is None


@pytest.fixture(scope="module")
def drone():
    return simulate(SimConfig.for_vehicle("drone", duration_s=150.0, seed=2, start="ground"))


def test_still_rows_are_the_ground_phase_and_never_flight(drone):
    """Against the simulator's truth: rows found still have true speed under 0.05 m/s and no rotation, and they
    cover most of the time the drone stands with its motors off (idling rotors shake the IMU: not still)."""
    truth = drone.truth_nav
    pos = drone.pos
    gyro = np.radians(pos[["OMGS_X", "OMGS_Y", "OMGS_Z"]].to_numpy(float))
    accel = pos[["ACCS_X", "ACCS_Y", "ACCS_Z"]].to_numpy(float)
    fixes = drone.gnss_fixes
    lat0, lon0 = np.radians(fixes["lat"].iloc[0]), np.radians(fixes["lon"].iloc[0])
    ned = np.column_stack([(np.radians(fixes["lat"]) - lat0) * 6378137.0,
                           (np.radians(fixes["lon"]) - lon0) * 6378137.0 * np.cos(lat0),
                           -(fixes["height"] - fixes["height"].iloc[0])])
    still = still_rows(truth.time, gyro, accel, fixes["time"].to_numpy(), ned)
    speed = np.linalg.norm(truth.v_n, axis=1)
    rate = np.linalg.norm(truth.omega_ib_b, axis=1)
    assert still.any()
    assert np.all(speed[still] < 0.05) and np.all(rate[still] < np.radians(1.0))
    standing = (speed < 1e-3) & (np.asarray(drone.motor_thrust_ratio) == 0.0)
    print("standing", standing.sum(), "found still", still[standing].mean())
    assert standing.sum() > 0 and still[standing].mean() > 0.8
    # the drone flies: motion shown by the fixes, after the still rows
    assert np.isfinite(first_motion(fixes["time"].to_numpy(), ned))
