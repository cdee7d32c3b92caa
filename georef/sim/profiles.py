"""Smooth control profiles for the vehicle simulators, with exact first and second time derivatives.

Vehicles other than the helicopter survey are described by piecewise profiles (speed, velocity vector,
height, heading) that hold a level and move to the next one along a *smootherstep*
``S(x) = 10 x^3 - 15 x^4 + 6 x^5``: value, first and second derivative are continuous and the first two
derivatives vanish at both ends of every transition, so accelerations (and the attitudes derived from them)
are continuous and the body rates of the ideal IMU have no jumps. The peak slope of ``S`` is
:data:`SMOOTHERSTEP_PEAK_SLOPE` (15/8): a change ``delta`` over ``T`` seconds has a peak rate of
``1.875 delta / T``, so ``T = 1.875 |delta| / rate_limit`` honours a rate limit.
"""

from __future__ import annotations

import numpy as np

#: Peak of dS/dx of the smootherstep (at x = 1/2).
SMOOTHERSTEP_PEAK_SLOPE = 1.875


def smootherstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``S(x)``, ``dS/dx`` and ``d2S/dx2`` of the smootherstep, ``x`` clipped to [0, 1]."""
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    s = x**3 * (10.0 - 15.0 * x + 6.0 * x**2)
    ds = 30.0 * x**2 * (1.0 - x) ** 2
    d2s = 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x)
    return s, ds, d2s


def transition_time(delta: float | np.ndarray, rate_limit: float, minimum: float = 1.0) -> float:
    """Duration [s] of a smootherstep change of size ``|delta|`` whose peak rate stays at ``rate_limit``."""
    return max(minimum, SMOOTHERSTEP_PEAK_SLOPE * float(np.linalg.norm(delta)) / rate_limit)


def piecewise_smooth(t: np.ndarray, initial: float | np.ndarray, starts: np.ndarray, durations: np.ndarray,
                     levels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A signal that holds ``initial``, moves to ``levels[k]`` during ``[starts[k], starts[k] + durations[k]]``.

    ``t`` (N,) [s]; ``initial`` a scalar or (D,) vector; ``starts``, ``durations`` (K,) [s], sorted and
    non-overlapping; ``levels`` (K,) or (K, D). Returns value, first and second time derivative with
    shapes (N,) or (N, D). Between transitions the value is the level itself (bit-exact, so a profile that
    returns to 0 is exactly 0 there).
    """
    t = np.asarray(t, dtype=float)
    starts = np.asarray(starts, dtype=float)
    durations = np.asarray(durations, dtype=float)
    initial = np.asarray(initial, dtype=float)
    levels = np.asarray(levels, dtype=float).reshape((len(starts), *initial.shape))
    if len(starts) and (np.any(np.diff(starts) < 0) or np.any(starts[1:] < (starts + durations)[:-1] - 1e-9)):
        raise ValueError("profile transitions must be sorted and must not overlap")
    shape = (len(t), *initial.shape)
    if len(starts) == 0:
        return np.broadcast_to(initial, shape).copy(), np.zeros(shape), np.zeros(shape)
    all_levels = np.concatenate([initial[None], levels], axis=0)  # transition k: all_levels[k] -> [k + 1]
    k = np.searchsorted(starts, t, side="right") - 1               # -1: before the first transition
    kk = np.maximum(k, 0)
    before, after = all_levels[kk], all_levels[k + 1]
    x = (t - starts[kk]) / durations[kk]
    s, ds, d2s = smootherstep(x)
    moving = _expand((k >= 0) & (x < 1.0), initial)
    delta = after - before
    value = np.where(moving, before + delta * _expand(s, initial), after)
    rate = np.where(moving, delta * _expand(ds / durations[kk], initial), 0.0)
    accel = np.where(moving, delta * _expand(d2s / durations[kk] ** 2, initial), 0.0)
    return value, rate, accel


def _expand(column: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Give an (N,) array the trailing axes of ``like`` so it broadcasts against (N, D) values."""
    return column.reshape(column.shape + (1,) * like.ndim)


def sinusoids(t: np.ndarray, amplitudes: np.ndarray, freqs_hz: np.ndarray,
              phases: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``sum_j A_j sin(2 pi f_j t + phi_j)`` and its first and second time derivatives, each (N,).

    ``amplitudes``, ``freqs_hz``, ``phases`` [rad] are (J,) arrays of the components.
    """
    w = 2.0 * np.pi * np.asarray(freqs_hz, dtype=float)
    arg = np.outer(t, w) + np.asarray(phases, dtype=float)
    a = np.asarray(amplitudes, dtype=float)
    return np.sin(arg) @ a, np.cos(arg) @ (a * w), -(np.sin(arg) @ (a * w**2))
