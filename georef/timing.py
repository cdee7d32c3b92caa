"""Time alignment: one continuous UTC-seconds-of-day scale for the POS log, GNSS epochs and exposures.

* POS sample time = ``TRIG_TIME/100 + SAMPL_TIME/1e6`` [s of day], with the logger quirk repaired and
  a midnight roll-over unwrapped (times after midnight continue past 86400 s).
* GNSS fixes are extracted from the sample-and-hold columns and tagged with their own whole second.
* Exposure times are placed on the same continuous scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from georef.io.errors import InputError, InputNotice

SECONDS_PER_DAY = 86400.0
_CENTI_PER_DAY = 8_640_000


@dataclass
class TimeRepairReport:
    """What :func:`pos_sample_times` repaired: file lines of repaired TRIG_TIME blocks and of midnight."""

    quirk_lines: list[int] = field(default_factory=list)
    midnight_lines: list[int] = field(default_factory=list)

    @property
    def n_quirks(self) -> int:
        return len(self.quirk_lines)


def pos_sample_times(
    trig_time: np.ndarray, sampl_time: np.ndarray, lines: np.ndarray
) -> tuple[np.ndarray, TimeRepairReport]:
    """Sample times [UTC s of day, continuous] from TRIG_TIME [s x 100] and SAMPL_TIME [us].

    The logger sometimes raises TRIG_TIME by 1 instead of 100 at a new second. A block of rows with one
    TRIG_TIME value is accepted when it lies a whole number of seconds after the (repaired) previous
    block. If the raw value rose by anything else, it is the quirk: if SAMPL_TIME restarted, the block is
    the next second (or the number of seconds the raw jump implies, for a gap); if it did not, the block
    continues the current second. A raw value that falls is left alone, so that the time check names it.
    A drop of more than half a day is a midnight roll-over and adds 86400 s. Every repair is reported.
    """
    trig = np.asarray(trig_time, dtype=np.int64)
    sampl = np.asarray(sampl_time, dtype=np.float64)
    n = len(trig)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(trig) != 0) + 1])
    report = TimeRepairReport()
    repaired = np.empty(len(starts), dtype=np.int64)
    repaired[0] = trig[0]
    day_offset = 0
    previous_raw = int(trig[0])
    for b in range(1, len(starts)):
        row = starts[b]
        raw = int(trig[row]) + day_offset
        if raw - previous_raw < -_CENTI_PER_DAY // 2:
            day_offset += _CENTI_PER_DAY
            raw += _CENTI_PER_DAY
            report.midnight_lines.append(int(lines[row]))
        step = raw - int(repaired[b - 1])
        raw_step = raw - previous_raw
        sampl_restarted = sampl[row] < sampl[row - 1]
        if step > 0 and step % 100 == 0:
            repaired[b] = raw
        elif raw_step > 0:
            # the counter rose, but not by whole seconds from the repaired time: the logger quirk
            if sampl_restarted:
                repaired[b] = repaired[b - 1] + 100 * max(1, int(round(raw_step / 100.0)))
            else:
                repaired[b] = repaired[b - 1]
            report.quirk_lines.append(int(lines[row]))
        else:
            # TRIG_TIME went backwards: not a quirk; left as logged so the caller reports the line
            repaired[b] = raw
        previous_raw = raw
    block_of_row = np.repeat(np.arange(len(starts)), np.diff(np.concatenate([starts, [n]])))
    times = repaired[block_of_row] / 100.0 + sampl / 1e6
    return times, report


@dataclass
class GnssEpochs:
    """GNSS antenna fixes on whole UTC seconds [s], WGS84 latitude/longitude [deg], ellipsoidal height [m]."""

    time: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height: np.ndarray
    line: np.ndarray
    repeated: np.ndarray
    notices: list[InputNotice] = field(default_factory=list)
    #: per-fix 1-sigma north/east/up [m] when the source gives them (generic gnss.csv), else None
    sigma_neu: np.ndarray | None = None
    #: per-fix full position covariance (K, 3, 3) [m^2] in NED (north, east, down) when the source gives its cross
    #: terms (an RTKLIB .pos, a NavSatFix), else None; ``sigma_neu`` then holds the roots of its diagonal
    cov_ned: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time)

    def without(self, drop: np.ndarray) -> GnssEpochs:
        """A copy without the fixes where the boolean mask ``drop`` is True (notices kept)."""
        keep = ~np.asarray(drop, dtype=bool)
        sigma = None if self.sigma_neu is None else self.sigma_neu[keep]
        cov = None if self.cov_ned is None else self.cov_ned[keep]
        return GnssEpochs(self.time[keep], self.lat_deg[keep], self.lon_deg[keep], self.height[keep], self.line[keep],
                          self.repeated[keep], list(self.notices), sigma, cov)

    def gaps(self, nominal_period: float = 1.0) -> list[tuple[float, float]]:
        """Intervals [s] longer than 1.5 nominal periods between consecutive fixes (GNSS outages)."""
        if len(self.time) < 2:
            return []
        step = np.diff(self.time)
        idx = np.flatnonzero(step > 1.5 * nominal_period)
        return [(float(self.time[i]), float(self.time[i + 1])) for i in idx]


def extract_gnss_epochs(
    path: object,
    times: np.ndarray,
    lat_deg: np.ndarray,
    lon_deg: np.ndarray,
    height: np.ndarray,
    lines: np.ndarray,
    rate_hz: float | None = None,
    ground_speed: np.ndarray | None = None,
    equal_fix_distance: float = 2.0,
) -> GnssEpochs:
    """Fixes from the sample-and-hold GNSS columns of a POS log.

    A new fix starts on the row where latitude, longitude or height change (all zero = no fix yet).
    Fixes are taken on whole UTC seconds, so a fix is tagged with the whole second at or just before
    the row on which it appears.

    When the GNSS rate [Hz] is known, a whole second with no change is an *equal consecutive fix* if the
    logged ground speed [m/s] times the period is below ``equal_fix_distance`` [m] (a hovering aircraft);
    otherwise, or without a speed column, it is an outage. Both cases are reported.
    """
    valid = ~((lat_deg == 0.0) & (lon_deg == 0.0) & (height == 0.0))
    changed = np.ones(len(times), dtype=bool)
    changed[1:] = (lat_deg[1:] != lat_deg[:-1]) | (lon_deg[1:] != lon_deg[:-1]) | (height[1:] != height[:-1])
    new_fix = valid & changed
    rows = np.flatnonzero(new_fix)
    notices: list[InputNotice] = []
    if len(rows) == 0:
        return GnssEpochs(np.empty(0), np.empty(0), np.empty(0), np.empty(0), np.empty(0, int),
                          np.empty(0, bool), notices)
    tags = np.floor(times[rows] + 1e-6)
    # Two fixes tagged with the same second: the earlier one arrived late and belongs one second before.
    clash = np.flatnonzero(np.diff(tags) == 0)
    for i in clash[::-1]:
        if i == 0 or tags[i - 1] < tags[i] - 1:
            tags[i] -= 1
    if np.any(np.diff(tags) <= 0):
        dup = np.flatnonzero(np.diff(tags) <= 0) + 1
        notices.append(InputNotice(path, [int(lines[rows[i]]) for i in dup], None,
                                   "GNSS fix arrived in the same second as the previous one; kept the later"))
        keep = np.ones(len(rows), bool)
        keep[dup - 1] = False
        rows, tags = rows[keep], tags[keep]
    repeated = np.zeros(len(rows), dtype=bool)
    if rate_hz is not None and rate_hz > 0 and len(rows) > 1:
        period = 1.0 / rate_hz
        grid = np.arange(tags[0], tags[-1] + 0.5 * period, period)
        missing = grid[~np.isin(np.round(grid / period), np.round(tags / period))]
        if len(missing):
            held_row = np.searchsorted(times, missing + period * 0.999, side="right") - 1
            held_row = np.clip(held_row, 0, len(times) - 1)
            speed = ground_speed[held_row] if ground_speed is not None else np.full(len(missing), np.inf)
            equal = speed * period < equal_fix_distance
            if equal.any():
                notices.append(InputNotice(path, [int(lines[r]) for r in held_row[equal]], None,
                                           f"{int(equal.sum())} equal consecutive GNSS fixes kept (ground "
                                           f"speed below {equal_fix_distance / period:g} m/s)"))
                src = held_row[equal]
                order = np.argsort(np.concatenate([tags, missing[equal]]), kind="stable")
                rows = np.concatenate([rows, src])[order]
                tags = np.concatenate([tags, missing[equal]])[order]
                repeated = np.concatenate([repeated, np.ones(int(equal.sum()), bool)])[order]
    return GnssEpochs(time=tags, lat_deg=lat_deg[rows], lon_deg=lon_deg[rows], height=height[rows],
                      line=lines[rows], repeated=repeated, notices=notices)


def to_reference_day(times: np.ndarray, ref_start: float, ref_end: float) -> np.ndarray:
    """Place seconds-of-day [s] on the continuous scale of a reference span (the POS log).

    A flight that crosses midnight has POS times past 86400 s; exposure times taken from a clock that
    restarted at midnight are moved by whole days to the day that puts them nearest the reference span.
    """
    times = np.asarray(times, dtype=float)
    centre = 0.5 * (ref_start + ref_end)
    shift = np.round((centre - times) / SECONDS_PER_DAY) * SECONDS_PER_DAY
    return times + shift


def check_increasing(path: object, times: np.ndarray, lines: np.ndarray, column: str) -> None:
    """Raise :class:`InputError` at the first line where time [s] goes backwards.

    When the row before went *forward* by about as much (a time stamp spiked on one row), that row is named
    instead: its time is the wrong one.
    """
    step = np.diff(times)
    back = np.flatnonzero(step < 0)
    if len(back):
        i = back[0]
        if i > 0 and step[i - 1] > 1.0 and abs(step[i - 1] + step[i]) < 0.5 * step[i - 1]:
            raise InputError(path, int(lines[i]), column,
                             f"the time jumps forward by {step[i - 1]:.3f} s on this line and back on line "
                             f"{int(lines[i + 1])}: a wrong time stamp on one row")
        raise InputError(path, int(lines[i + 1]), column,
                         f"time goes backwards from {times[i]:.6f} s (line {int(lines[i])}) to "
                         f"{times[i + 1]:.6f} s")


#: a step between POS rows longer than this [s] (and than 20 sample periods) is a gap that is checked
GAP_SECONDS = 1.0


def check_time_jumps(path: object, times: np.ndarray, lines: np.ndarray, counter: np.ndarray | None,
                     time_column: str, counter_column: str | None) -> list[InputNotice]:
    """Gaps in the POS rows' time [s]: a located error when the record counter shows the rows are consecutive.

    A step longer than :data:`GAP_SECONDS` and 20 median sample periods is a gap. With a record counter, a gap
    whose counter advances by ``k`` records is real when its time is at most ``2 k`` periods + 1 s; a longer
    time over consecutive records is a wrong time stamp (e.g. TRIG_TIME raised by 100000 from one line on)
    and an error. A counter that wraps or restarts proves nothing. Real gaps are returned as notices
    (:func:`check_gnss_time_consistency` tests the rest against the GNSS positions).
    """
    if len(times) < 3:
        return []
    step = np.diff(times)
    period = float(np.median(step))
    gaps = np.flatnonzero(step > max(GAP_SECONDS, 20.0 * period))
    notices: list[InputNotice] = []
    real = []
    for i in gaps.tolist():
        if counter is not None:
            records = int(counter[i + 1]) - int(counter[i])
            if records > 0 and step[i] > 2.0 * records * period + 1.0:
                raise InputError(path, int(lines[i + 1]), time_column,
                                 f"the time jumps forward by {step[i]:.3f} s from line {int(lines[i])}, but the record "
                                 f"counter ({counter_column}) advances by {records}: the rows are consecutive, so "
                                 "this time stamp is wrong")
        real.append(i)
    if real:
        longest = max(step[i] for i in real)
        notices.append(InputNotice(path, [int(lines[i + 1]) for i in real], time_column,
                                   f"{len(real)} gap(s) in the IMU rows (longest {longest:.1f} s)"))
    return notices


def check_gnss_time_consistency(path: object, times: np.ndarray, lines: np.ndarray, gnss: GnssEpochs, time_column: str,
                                period: float | None) -> None:
    """Raise :class:`InputError` where the POS time jumps but the GNSS positions go on as if it had not.

    Across a real gap of ``dt`` seconds an aircraft moving at ``v`` covers about ``v dt``. When the first fix
    after a gap of more than 3 fix periods lies where the last fixes predict it one fix *period* later
    (within 25 % of a period's travel + 3 m) while moving at more than 5 m/s, the time stamps jumped and the
    aircraft did not: e.g. TRIG_TIME raised by 100000 from one line on. The error names the POS row (``times``
    [s], file ``lines``) with the longest step between the two fixes. ``period`` [s]: the GNSS fix period (the
    median fix spacing when None).
    """
    if len(gnss) < 3:
        return
    from georef.frames import geodetic_to_ecef

    t = gnss.time
    step = np.diff(t)
    nominal = float(period) if period else float(np.median(step))
    r = geodetic_to_ecef(np.radians(gnss.lat_deg), np.radians(gnss.lon_deg), gnss.height)
    for k in np.flatnonzero(step > max(3.0 * nominal, GAP_SECONDS + nominal)).tolist():
        if k == 0 or t[k] - t[k - 1] <= 0:
            continue
        velocity = (r[k] - r[k - 1]) / (t[k] - t[k - 1])
        speed = float(np.linalg.norm(velocity))
        if speed < 5.0:
            continue
        predicted = r[k] + velocity * nominal
        miss = float(np.linalg.norm(r[k + 1] - predicted))
        moved = float(np.linalg.norm(r[k + 1] - r[k]))
        if miss < 0.25 * speed * nominal + 3.0 and moved * 10.0 < speed * step[k]:
            first, last = np.searchsorted(lines, [gnss.line[k], gnss.line[k + 1]])
            row = int(first + np.argmax(np.diff(times[first:last + 1]))) + 1 if last > first else int(last)
            raise InputError(path, int(lines[min(row, len(lines) - 1)]), time_column,
                             f"the time jumps forward by {times[row] - times[row - 1]:.1f} s on this line, but the "
                             f"GNSS position moved on by {moved:.0f} m at {speed:.0f} m/s, as after one fix period "
                             f"({nominal:g} s): the time stamps are wrong from here on")
