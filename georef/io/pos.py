"""Reader of the POS unit's log (iMAR iVRU-style ``POS.txt``), see ``docs/formats.md``.

Columns are found by header name. Each column has a *role*; the default preset maps roles to the iMAR
names and a user can remap any role in the flight configuration (``[pos_columns]`` in flight.toml).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from georef.io.errors import InputError, InputNotice
from georef.io.plausibility import check_gnss_jumps, check_ranges, repair_spikes
from georef.io.table import Dialect, Kind, read_table
from georef.timing import (
    GnssEpochs,
    TimeRepairReport,
    check_gnss_time_consistency,
    check_increasing,
    check_time_jumps,
    extract_gnss_epochs,
    pos_sample_times,
)

#: Role -> (default header name, kind). Units: ACCS/IACC m/s^2, OMGS/IOMG deg/s, angles deg,
#: TRIG_TIME s x 100, SAMPL_TIME us, LAT/LON deg, ALTITUDE m (ellipsoidal), VELOCITY m/s.
POS_ROLES: dict[str, tuple[str, Kind]] = {
    "counter": ("CNT[HEX]", "hex"),
    "acc_x": ("ACCS_X", "float"), "acc_y": ("ACCS_Y", "float"), "acc_z": ("ACCS_Z", "float"),
    "iacc_x": ("IACC_X", "float"), "iacc_y": ("IACC_Y", "float"), "iacc_z": ("IACC_Z", "float"),
    "gyro_x": ("OMGS_X", "float"), "gyro_y": ("OMGS_Y", "float"), "gyro_z": ("OMGS_Z", "float"),
    "igyro_x": ("IOMG_X", "float"), "igyro_y": ("IOMG_Y", "float"), "igyro_z": ("IOMG_Z", "float"),
    "roll": ("ROLL", "float"), "pitch": ("PITCH", "float"), "yaw": ("YAW", "float"),
    "trig_time": ("TRIG_TIME", "int"), "sampl_time": ("SAMPL_TIME", "int"),
    "imu_temp": ("IMU_TEMP", "float"), "sens_temp": ("SENS_TEMP", "float"),
    "lon": ("LONGITUDE", "float"), "lat": ("LATITUDE", "float"), "alt": ("ALTITUDE", "float"),
    "gnss_speed": ("VELOCITY", "float"),
    "status": ("STATUS[HEX]", "hex"),
}

#: TRIG_TIME [s x 100] of a UTC day: 0 up to 86400 s (86401 s with a leap second)
TRIG_TIME_RANGE = (0, 8_640_100)

#: Roles every reading needs.
BASE_ROLES = ("trig_time", "sampl_time", "lat", "lon", "alt")


def _one_edit_apart(a: str, b: str) -> bool:
    """Whether ``a`` becomes ``b`` by one inserted, deleted or replaced character (case ignored)."""
    a, b = a.upper(), b.upper()
    if a == b or abs(len(a) - len(b)) > 1:
        return False
    if len(a) > len(b):
        a, b = b, a
    i = 0
    while i < len(a) and a[i] == b[i]:
        i += 1
    return a[i + (len(a) == len(b)):] == b[i + 1:]


def _check_near_misses(path: Path, header: list[str], wanted: Mapping[str, Kind]) -> None:
    """A header name one edit away from a column georef reads, where that column is absent, is a damaged header
    (a flipped byte turned ``IACC_X`` into ``IACC\x1f_X``): an error naming both, never a column silently dropped."""
    present = {name.upper() for name in header}
    for name in wanted:
        if name.upper() in present:
            continue
        for index, found in enumerate(header):
            if found.upper() not in {w.upper() for w in wanted} and _one_edit_apart(found, name):
                raise InputError(path, 1, name, f"header field {index + 1} is {found!r}, one character away from "
                                 f"the column {name!r}, which the file lacks: a damaged header? Correct the name "
                                 f"(or map the column in [pos_columns] of the flight configuration)")


@dataclass
class PosLog:
    """A POS log on the continuous time scale (or an autopilot log's IMU and GNSS handed over in the same form,
    :func:`georef.io.logs.flightlog.to_pos_log`).

    ``time`` [UTC s of day, continuous across midnight]; ``data[role]`` in the file's units (see
    :data:`POS_ROLES`); ``lines`` the 1-based file line of every row; ``gnss`` the extracted fixes.
    """

    path: Path
    time: np.ndarray
    data: dict[str, np.ndarray]
    lines: np.ndarray
    gnss: GnssEpochs
    time_repairs: TimeRepairReport
    notices: list[InputNotice] = field(default_factory=list)
    column_names: dict[str, str] = field(default_factory=dict)
    #: separator and encoding the file was read with
    dialect: Dialect | None = None
    #: what the rows came from, for messages and the report: "POS.txt", "ArduPilot DataFlash log (binary)", ...
    kind: str = "POS.txt"
    #: a magnetometer on the rows (N, 3) [any unit, body axes], when the log has one
    mag: np.ndarray | None = None
    #: the autopilot's own roll, pitch, yaw on the rows (N, 3) [rad, ZYX to NED, yaw from true north], when logged:
    #: a heading source of its own and a comparison, not the POS unit's attitude (whose yaw origin is unknown)
    autopilot_rpy: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time)

    @property
    def sample_rate_hz(self) -> float:
        """Median IMU row rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.time))) if len(self.time) > 1 else float("nan")

    def vector(self, prefix: str) -> np.ndarray:
        """Stack the roles ``prefix_x, prefix_y, prefix_z`` into an (N, 3) array."""
        return np.stack([self.data[f"{prefix}_{axis}"] for axis in "xyz"], axis=-1)


def resolve_columns(overrides: Mapping[str, str] | None = None) -> dict[str, str]:
    """Role -> header name, the default preset with the user's remapping applied."""
    names = {role: spec[0] for role, spec in POS_ROLES.items()}
    for role, name in (overrides or {}).items():
        if role not in POS_ROLES:
            raise ValueError(f"unknown POS column role {role!r}; known roles: {', '.join(POS_ROLES)}")
        names[role] = name
    return names


def read_pos(
    path: Path | str,
    required_roles: Iterable[str] = (),
    column_names: Mapping[str, str] | None = None,
    gnss_rate_hz: float | None = None,
) -> PosLog:
    """Read a POS.txt log: times repaired and unwrapped, GNSS fixes extracted, every problem located.

    ``required_roles`` are the roles (beyond time and GNSS) the chosen method needs; a missing one is an
    :class:`InputError` on line 1. Header names are matched ignoring case. Exact duplicate rows are dropped
    with a notice; a time that goes backwards (other than across midnight), a repeated time with different
    values or a time jump over consecutive records is an error. Values outside the plausibility limits are
    errors and short spikes are repaired with a notice (:mod:`georef.io.plausibility`); GNSS fixes that jump
    faster than any aircraft are dropped (one) or an error (lasting).
    """
    path = Path(path)
    names = resolve_columns(column_names)
    required = set(BASE_ROLES) | set(required_roles)
    wanted = {names[role]: POS_ROLES[role][1] for role in POS_ROLES}
    table = read_table(path, wanted, required={names[role] for role in required})
    _check_near_misses(path, table.header, wanted)
    notices = list(table.notices)
    data = {role: table.columns[names[role]] for role in POS_ROLES if names[role] in table.columns}
    # the file's own spelling of each column, for messages
    spelled = {role: table.names.get(names[role], names[role]) for role in POS_ROLES}
    lines = table.lines

    _check_time_fields(path, data, lines, spelled)
    times, repairs = pos_sample_times(data["trig_time"], data["sampl_time"], lines)
    notices += _repair_notices(path, repairs, spelled)
    time_column = f"{spelled['trig_time']}/{spelled['sampl_time']}"
    rows = _without_duplicates(path, _Rows(times, lines, data), time_column, notices)
    times, lines, data = rows.times, rows.lines, rows.data
    check_increasing(path, times, lines, time_column)
    counter = data.get("counter")
    notices += check_time_jumps(path, times, lines, counter, time_column, spelled["counter"])
    notices += _counter_notices(path, counter, lines, spelled)
    _check_coordinates(path, data, lines, spelled)
    check_ranges(path, data, lines, spelled)
    notices += repair_spikes(path, data, lines, spelled)
    gnss = extract_gnss_epochs(path, times, data["lat"], data["lon"], data["alt"], lines, rate_hz=gnss_rate_hz,
                               ground_speed=data.get("gnss_speed"))
    gnss_columns = f"{spelled['lat']}/{spelled['lon']}/{spelled['alt']}"
    gnss, jump_notices = check_gnss_jumps(path, gnss, gnss_columns)
    check_gnss_time_consistency(path, times, lines, gnss, time_column, 1.0 / gnss_rate_hz if gnss_rate_hz else None)
    notices.extend(gnss.notices)
    notices.extend(jump_notices)
    return PosLog(path=path, time=times, data=data, lines=lines, gnss=gnss, time_repairs=repairs,
                  notices=notices, column_names={role: spelled[role] for role in data}, dialect=table.dialect)


def _check_time_fields(path: Path, data: dict[str, np.ndarray], lines: np.ndarray, spelled: dict[str, str]) -> None:
    """SAMPL_TIME [us] within a second and TRIG_TIME [s x 100] within a day (:data:`TRIG_TIME_RANGE`), else an error
    naming the first line outside."""
    sampl = data["sampl_time"]
    bad_sampl = np.flatnonzero((sampl < 0) | (sampl >= 1_000_000))
    if len(bad_sampl):
        i = bad_sampl[0]
        raise InputError(path, int(lines[i]), spelled["sampl_time"],
                         f"SAMPL_TIME {sampl[i]:.0f} us is outside 0..999999")
    trig = data["trig_time"]
    bad_trig = np.flatnonzero((trig < TRIG_TIME_RANGE[0]) | (trig >= TRIG_TIME_RANGE[1]))
    if len(bad_trig):
        i = bad_trig[0]
        raise InputError(path, int(lines[i]), spelled["trig_time"],
                         f"TRIG_TIME {trig[i]:.10g} is outside a day (0..{TRIG_TIME_RANGE[1] - 1} hundredths of a "
                         "second)")


def _repair_notices(path: Path, repairs: TimeRepairReport, spelled: dict[str, str]) -> list[InputNotice]:
    """Notices of the time repairs: the logger's TRIG_TIME quirk, a midnight roll-over."""
    notices = []
    if repairs.n_quirks:
        notices.append(InputNotice(path, repairs.quirk_lines, spelled["trig_time"],
                                   f"TRIG_TIME logger quirk repaired {repairs.n_quirks} time(s) "
                                   "(rose by other than a whole second)"))
    if repairs.midnight_lines:
        notices.append(InputNotice(path, repairs.midnight_lines, spelled["trig_time"],
                                   "midnight roll-over: later times continue past 86400 s"))
    return notices


@dataclass(frozen=True)
class _Rows:
    """A POS log's rows: ``times`` [s], 1-based file ``lines`` and ``data`` by role."""

    times: np.ndarray
    lines: np.ndarray
    data: dict[str, np.ndarray]


def _without_duplicates(path: Path, rows: _Rows, time_column: str, notices: list[InputNotice]) -> _Rows:
    """The rows without exact duplicates (same time and same values), each dropped one reported in a notice added to
    ``notices``; the same time with different values is an error."""
    times, lines, data = rows.times, rows.lines, rows.data
    same_time = np.flatnonzero(np.diff(times) == 0) + 1
    if not len(same_time):
        return rows
    identical = np.ones(len(same_time), dtype=bool)
    for values in data.values():
        identical &= values[same_time] == values[same_time - 1]
    if not identical.all():
        i = same_time[~identical][0]
        raise InputError(path, int(lines[i]), time_column,
                         f"same time stamp as line {int(lines[i - 1])} but different values")
    notices.append(InputNotice(path, lines[same_time].tolist(), None,
                               f"{len(same_time)} duplicate row(s) dropped (identical to the row before)"))
    keep = np.ones(len(times), dtype=bool)
    keep[same_time] = False
    return _Rows(times[keep], lines[keep], {role: values[keep] for role, values in data.items()})


def _counter_notices(path: Path, counter: np.ndarray | None, lines: np.ndarray,
                     spelled: dict[str, str]) -> list[InputNotice]:
    """A notice when the record counter skips records (rows missing from the log)."""
    if counter is None or len(counter) <= 1:
        return []
    step = np.diff(counter.astype(np.int64))
    jumps = np.flatnonzero(step > 1)
    if not len(jumps):
        return []
    return [InputNotice(path, lines[jumps + 1].tolist(), spelled["counter"],
                        f"record counter skips {int((step[jumps] - 1).sum())} record(s): rows missing from the log")]


def _check_coordinates(path: Path, data: dict[str, np.ndarray], lines: np.ndarray, spelled: dict[str, str]) -> None:
    """Latitude within +-90 deg and longitude within +-180 deg, else an error naming the first line outside."""
    lat, lon = data["lat"], data["lon"]
    out_of_range = np.flatnonzero((np.abs(lat) > 90) | (np.abs(lon) > 180))
    if len(out_of_range):
        i = out_of_range[0]
        column = spelled["lat"] if abs(lat[i]) > 90 else spelled["lon"]
        raise InputError(path, int(lines[i]), column, f"coordinate {lat[i] if abs(lat[i]) > 90 else lon[i]:.10g} "
                         "is outside the valid range (degrees expected)")
