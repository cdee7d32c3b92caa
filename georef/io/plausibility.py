"""Plausibility of the POS log's physical quantities: impossible values are errors, short spikes are repaired.

Three tests, each stated with its values in ``docs/formats.md`` ("Plausibility limits"):

* **Range** (:data:`LIMITS`): a value no sensor of the kind can produce (beyond the full-scale range of any
  navigation IMU, an angle outside its definition, a height no aircraft reaches) is an error naming line
  and column: it is not a measurement, and nothing else in the file can be trusted to be right around it.
* **Spikes** (:func:`repair_spikes`): a value on one row, or a run of up to :data:`SPIKE_RUN` rows, that departs
  from *both* neighbours, in the same direction, by more than :data:`SPIKE_FACTOR` times the local sample-to-sample
  scatter (and at least the quantity's floor in :data:`SPIKE_FLOOR`), while the neighbours agree with each other,
  is replaced by the straight line between its neighbours and reported with its lines. The filter would otherwise
  integrate it (ten rows of 500 deg/s turned the bundled flight's yaw 99 deg).
* **GNSS jumps** (:func:`check_gnss_jumps`): consecutive fixes implying more than :data:`MAX_GNSS_SPEED`. A
  single such fix between two consistent ones is dropped with a notice; a lasting jump is an error.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from georef.io.errors import InputError, InputNotice
from georef.timing import GnssEpochs


@dataclass(frozen=True)
class Limit:
    """The plausible interval ``[low, high]`` of a quantity, its unit and why."""

    low: float
    high: float
    unit: str
    why: str


_FORCE = Limit(-490.0, 490.0, "m/s^2", "50 g, beyond the full-scale range of any navigation IMU's accelerometers")
_RATE = Limit(-2000.0, 2000.0, "deg/s", "beyond the full-scale range of any navigation IMU's gyros, 2000 deg/s for "
              "the widest MEMS ones")
_TEMPERATURE = Limit(-80.0, 150.0, "degC", "beyond the operating range of any electronics")

#: role -> plausible interval. Roles as in :data:`georef.io.pos.POS_ROLES`; units the file's.
LIMITS: dict[str, Limit] = {
    **{f"{p}_{a}": _FORCE for p in ("acc", "iacc") for a in "xyz"},
    **{f"{p}_{a}": _RATE for p in ("gyro", "igyro") for a in "xyz"},
    "roll": Limit(-180.0, 180.0, "deg", "roll is defined on -180..180"),
    "pitch": Limit(-90.0, 90.0, "deg", "pitch is defined on -90..90"),
    "yaw": Limit(-360.0, 360.0, "deg", "a heading is -180..180 or 0..360"),
    "imu_temp": _TEMPERATURE,
    "sens_temp": _TEMPERATURE,
    "alt": Limit(-1000.0, 50000.0, "m", "below the lowest ground (Dead Sea, about -450 m ellipsoidal) or above "
                 "the highest balloon flights"),
    "gnss_speed": Limit(-600.0, 600.0, "m/s", "faster than any aircraft that takes survey images"),
}

#: a spike departs from both neighbours by more than this many times the local scatter ...
SPIKE_FACTOR = 25.0
#: ... and by at least this much (file units): smaller one-row excursions are left to the filter
SPIKE_FLOOR: dict[str, float] = {
    **{f"{p}_{a}": 5.0 for p in ("acc", "iacc") for a in "xyz"},    # m/s^2
    **{f"{p}_{a}": 20.0 for p in ("gyro", "igyro") for a in "xyz"},  # deg/s
    "roll": 5.0, "pitch": 5.0, "yaw": 5.0,                             # deg
}
#: the steps either side of a row over which its local scatter (median absolute step) is taken
SPIKE_BLOCK = 250
#: the longest run of rows taken as one spike: a logger's corrupted burst, not motion (no vehicle turns at hundreds of
#: deg/s and back to the rate it had within a few hundredths of a second)
SPIKE_RUN = 10
#: fastest plausible motion between consecutive GNSS fixes [m/s]
MAX_GNSS_SPEED = 600.0

_UNITS = {**{role: limit.unit for role, limit in LIMITS.items()}}
_ANGLES = {"roll", "yaw"}


#: the same limits for the generic ``imu.csv`` and ``gnss.csv`` (their units: rad/s, m/s^2, deg, m)
GENERIC_LIMITS: dict[str, Limit] = {
    **{f"gyro_{a}": Limit(-np.radians(2000.0), np.radians(2000.0), "rad/s", _RATE.why) for a in "xyz"},
    **{f"acc_{a}": _FORCE for a in "xyz"},
    "yaw": LIMITS["yaw"], "roll": LIMITS["roll"], "pitch": LIMITS["pitch"],
    "height": LIMITS["alt"],
}


def check_ranges(path: Path, data: Mapping[str, np.ndarray], lines: np.ndarray, names: Mapping[str, str],
                 limits: Mapping[str, Limit] = LIMITS) -> None:
    """Raise :class:`InputError` at the first value outside its interval in ``limits`` (earliest line)."""
    first: tuple[int, str] | None = None
    for role, limit in limits.items():
        values = data.get(role)
        if values is None or not len(values):
            continue
        bad = (values < limit.low) | (values > limit.high)
        if bad.any():
            row = int(np.argmax(bad))
            if first is None or row < first[0]:
                first = (row, role)
    if first is not None:
        row, role = first
        limit = limits[role]
        value = float(data[role][row])
        raise InputError(path, int(lines[row]), names.get(role, role),
                         f"{value:.6g} {limit.unit} is outside the plausible range {limit.low:g}..{limit.high:g} "
                         f"{limit.unit} ({limit.why})")


def find_spikes(values: np.ndarray, floor: float, wrap: float | None = None) -> list[tuple[int, int]]:
    """Spikes in ``values`` as (first, last) rows, inclusive (see the module docstring); ``wrap`` [deg] for angles.

    Rows ``i..j-1`` (at most :data:`SPIKE_RUN` of them, not touching either end) are a spike when the step into
    them, ``x[i] - x[i-1]``, and the step out, ``x[j-1] - x[j]``, have the same sign and both exceed
    ``max(floor, SPIKE_FACTOR * s)``, where ``s`` is the median absolute step over the :data:`SPIKE_BLOCK` steps
    either side; when the rows either side agree, ``|x[j] - x[i-1]|`` less than half the smaller step; and when
    every row of the run lies beyond half the smaller step from the straight line between them, on the step's
    side. The shortest such run wins. Only rows whose step in exceeds ``floor`` are examined further, so a clean
    channel costs a few array passes.
    """
    n = len(values)
    if n < 5:
        return []
    step = np.diff(values)
    if wrap is not None:
        step = (step + wrap / 2) % wrap - wrap / 2
    size = np.abs(step)
    runs: list[tuple[int, int]] = []
    covered = -1
    for i in (np.flatnonzero(size[:-1] > floor) + 1).tolist():
        if i <= covered:
            continue
        run = _spike_run(values, step, size, i, floor, wrap)
        if run is not None:
            runs.append(run)
            covered = run[1]
    return runs


def _spike_run(values: np.ndarray, step: np.ndarray, size: np.ndarray, i: int, floor: float,
               wrap: float | None) -> tuple[int, int] | None:
    """The shortest spike starting at row ``i`` (:func:`find_spikes`), or None."""
    n = len(values)
    left = step[i - 1]
    threshold = max(floor, SPIKE_FACTOR * float(np.median(size[max(0, i - SPIKE_BLOCK): i + SPIKE_BLOCK])))
    for j in range(i + 1, min(i + SPIKE_RUN, n - 1) + 1):
        right = -step[j - 1]
        smaller = min(abs(left), abs(right))
        if (left > 0) != (right > 0) or smaller <= threshold:
            continue
        across = values[j] - values[i - 1]
        if wrap is not None:
            across = (across + wrap / 2) % wrap - wrap / 2
        if abs(across) >= 0.5 * smaller:
            continue
        offset = values[i:j] - (values[i - 1] + across * np.arange(1, j - i + 1) / (j - i + 1))
        if wrap is not None:
            offset = (offset + wrap / 2) % wrap - wrap / 2
        if np.all(np.sign(left) * offset > 0.5 * smaller):
            return i, j - 1
    return None


def repair_spikes(path: Path, data: dict[str, np.ndarray], lines: np.ndarray,
                  names: Mapping[str, str]) -> list[InputNotice]:
    """Replace spikes of the IMU and attitude columns (one row or runs of up to :data:`SPIKE_RUN` rows,
    :func:`find_spikes`) by the straight line between their neighbours, in place.

    One notice per column names every repaired line and the largest excursion.
    """
    notices = []
    for role, floor in SPIKE_FLOOR.items():
        values = data.get(role)
        if values is None:
            continue
        wrap = 360.0 if role in _ANGLES else None
        runs = find_spikes(values, floor, wrap)
        if not runs:
            continue
        repaired = values.copy()
        excursion = 0.0
        rows: list[int] = []
        for first, last in runs:
            span = values[last + 1] - values[first - 1]
            if wrap is not None:
                span = (span + 180.0) % 360.0 - 180.0
            line = values[first - 1] + span * np.arange(1, last - first + 2) / (last - first + 2)
            excursion = max(excursion, float(np.max(np.abs(values[first:last + 1] - line))))
            repaired[first:last + 1] = line
            rows.extend(range(first, last + 1))
        data[role] = repaired
        longest = max(last - first + 1 for first, last in runs)
        notices.append(InputNotice(path, lines[np.asarray(rows)].tolist(), names.get(role, role),
                                   f"{len(runs)} spike(s) of up to {longest} row(s) repaired (up to {excursion:.4g} "
                                   f"{_UNITS[role]} away from the rows either side; replaced by the straight line "
                                   "between them)"))
    return notices


def check_gnss_jumps(path: Path, gnss: GnssEpochs, columns: str) -> tuple[GnssEpochs, list[InputNotice]]:
    """Fixes that imply a speed above :data:`MAX_GNSS_SPEED` from the fix before.

    A single fix away from two neighbours that agree with each other is dropped with a notice; any other such
    jump (the positions stay away) raises :class:`InputError` naming the fix's line.
    """
    if len(gnss) < 2:
        return gnss, []
    from georef.frames import geodetic_to_ecef

    r = geodetic_to_ecef(np.radians(gnss.lat_deg), np.radians(gnss.lon_deg), gnss.height)
    t = gnss.time

    def too_fast(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        dt = np.maximum(np.abs(t[j] - t[i]), 1e-3)
        return np.linalg.norm(r[j] - r[i], axis=-1) / dt > MAX_GNSS_SPEED

    n = len(t)
    jump = too_fast(np.arange(n - 1), np.arange(1, n))
    if not jump.any():
        return gnss, []
    drop = np.zeros(n, dtype=bool)
    inner = np.arange(1, n - 1)
    lone = jump[:-1] & jump[1:] & ~too_fast(inner - 1, inner + 1)
    drop[inner[lone]] = True
    # at the ends: the first (last) fix away from the next (previous) two, which agree
    if n >= 3 and jump[0] and not jump[1]:
        drop[0] = True
    if n >= 3 and jump[-1] and not jump[-2]:
        drop[-1] = True
    kept = np.flatnonzero(~drop)
    still = too_fast(kept[:-1], kept[1:])
    if still.any():
        k = int(kept[1:][np.argmax(still)])
        p = int(kept[:-1][np.argmax(still)])
        distance = float(np.linalg.norm(r[k] - r[p]))
        raise InputError(path, int(gnss.line[k]), columns,
                         f"the GNSS position jumps by {distance / 1000:.3g} km in {abs(t[k] - t[p]):.3g} s from the "
                         f"fix on line {int(gnss.line[p])} (faster than {MAX_GNSS_SPEED:g} m/s) and stays there")
    notice = InputNotice(path, gnss.line[drop].tolist(), columns,
                         f"{int(drop.sum())} GNSS fix(es) dropped: each lies away from both neighbouring fixes by more "
                         f"than {MAX_GNSS_SPEED:g} m/s allows")
    return gnss.without(drop), [notice]
