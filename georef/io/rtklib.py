"""RTKLIB / Emlid Studio position solutions (``.pos``) as GNSS fixes, and ``_events.pos`` as exposures.

The format is RTKLIB's solution text (``outsolheads``/``outsols`` in its ``src/solution.c``), which rnx2rtkp, RTKPOST,
the demo5 fork and Emlid Studio write: ``%`` header lines, then one line per epoch::

    % ref pos   : 35.132066140  139.624302130    75.8027
    % (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)
    %  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m) ...
    2005/04/02 00:00:00.000   35.160875058  139.613838572    70.2698   1   5   0.0143   0.0052   0.0160   0.0045 ...

What the header says, and what georef does with it (``docs/rtklib.md``):

* time system ``GPST``, ``UTC`` or ``JST`` (the column header's first name) and format (``yyyy/mm/dd hh:mm:ss.s``
  or GPS week + seconds; both two fields): converted to UTC with the leap seconds of
  :mod:`georef.frames.gpstime`, then to the scale asked for (:data:`georef.frames.gpstime.TIME_SCALES`);
* positions ``lat/lon/height`` (degrees, or ``d m s`` with ``-g``), ``x/y/z-ecef`` or ``e/n/u-baseline`` from the
  ``% ref pos`` base; heights ``ellipsoidal`` or ``geodetic`` (above a geoid: converted with PROJ's grid for
  ``geoid``, EGM96 by default; the geoid RTKLIB used is not in the file);
* the six ``sd`` columns: three standard deviations and three *signed* roots of covariances, in the frame of the
  positions (ENU at the base for baselines, ECEF for x/y/z): the NED covariance of each fix
  (:mod:`georef.frames.position_covariance`), with a floor per solution quality ``Q`` (:data:`SIGMA_FLOORS`).
"""

from __future__ import annotations

import datetime as dt
import gzip
import re
import stat
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from georef.frames.earth import ecef_to_geodetic
from georef.frames.gpstime import (
    GPS_EPOCH,
    JST_MINUS_UTC,
    SECONDS_PER_DAY,
    SECONDS_PER_WEEK,
    gps_minus_utc,
    gps_week_to_utc,
    leap_seconds_note,
    solution_times,
    utc_to_gps_seconds,
)
from georef.frames.heights import EGM96_HEIGHT, ellipsoidal_from_orthometric
from georef.frames.position_covariance import (
    covariance_from_signed_roots,
    ecef_to_ned_covariance,
    enu_at_base_to_ned_covariance,
    enu_baseline_to_ecef,
    neu_to_ned_covariance,
    with_sigma_floor,
)
from georef.io.errors import InputError, InputNotice, excerpt
from georef.timing import GnssEpochs, check_increasing

if TYPE_CHECKING:
    from georef.io.camera import Exposures

#: the time scales a solution's times can be put on (the IMU's scale must be the same):
#: ``utc-day`` UTC seconds from 00:00 UTC of the first solution's day (going on past 86400 s), georef's scale for
#: POS.txt, Kamera.txt and autopilot logs; ``gps-week`` GPS seconds from the start of the first solution's GPS week
#: (going on past 604800 s); ``utc-posix`` UTC seconds since 1970-01-01

#: RTKLIB's solution qualities (``SOLQ_*`` of rtklib.h; 7, dead reckoning, is the demo5 fork's)
QUALITY_NAMES: dict[int, str] = {1: "fix", 2: "float", 3: "SBAS", 4: "DGPS", 5: "single", 6: "PPP",
                                 7: "dead reckoning"}
#: carrier-phase solutions: relative fix and float, and PPP
CARRIER_QUALITIES = (1, 2, 6)
#: code-only solutions
CODE_QUALITIES = (3, 4, 5)

#: smallest 1-sigma north, east, up [m] a fix of each quality is given. RTKLIB's sd columns are the filter's
#: formal covariance, which leaves out multipath, antenna phase centre and base coordinate errors and is
#: optimistic (millimetres for a fix). The floors are typical achieved accuracies: an RTK fix 1 cm + 1 ppm
#: horizontal, twice that vertical (receiver data sheets, e.g. u-blox ZED-F9P, Emlid Reach RS2), taken at 10 km;
#: a float solution decimetres; DGPS and SBAS sub-metre to metre (SBAS: WAAS performance standard, ICAO Annex 10);
#: a single-point solution the GPS SPS performance standard's few metres; converged kinematic PPP a decimetre.
SIGMA_FLOORS: dict[int, tuple[float, float, float]] = {
    1: (0.02, 0.02, 0.04), 2: (0.30, 0.30, 0.60), 3: (1.0, 1.0, 1.5), 4: (0.5, 0.5, 1.0), 5: (2.5, 2.5, 5.0),
    6: (0.10, 0.10, 0.20), 7: (10.0, 10.0, 15.0),
}

#: column name (lower case) -> how many whitespace-separated fields it spans in a data line
_DMS_LAT, _DMS_LON = "latitude(d'\")", "longitude(d'\")"
_FIELDS = {_DMS_LAT: 3, _DMS_LON: 3}
_TIME_SYSTEMS = ("GPST", "UTC", "JST")
#: the columns every layout has after its three position columns
_COMMON = ("q", "ns")
#: layout -> its position columns and its six sd columns, as RTKLIB 2.4.3's outsolheads names them
_LAYOUTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "llh-deg": (("latitude(deg)", "longitude(deg)", "height(m)"),
                ("sdn(m)", "sde(m)", "sdu(m)", "sdne(m)", "sdeu(m)", "sdun(m)")),
    # RTKLIB labels the sixth sd column of the d m s layout "sdue(m)"; outpos writes the north-up term there too
    "llh-dms": ((_DMS_LAT, _DMS_LON, "height(m)"), ("sdn(m)", "sde(m)", "sdu(m)", "sdne(m)", "sdeu(m)", "sdue(m)")),
    "xyz": (("x-ecef(m)", "y-ecef(m)", "z-ecef(m)"), ("sdx(m)", "sdy(m)", "sdz(m)", "sdxy(m)", "sdyz(m)", "sdzx(m)")),
    "enu": (("e-baseline(m)", "n-baseline(m)", "u-baseline(m)"),
            ("sde(m)", "sdn(m)", "sdu(m)", "sden(m)", "sdnu(m)", "sdue(m)")),
}
#: columns after the sd columns that georef knows and reads
_KNOWN_TAIL = ("age(s)", "ratio")
_FORMAT_LINE = re.compile(r"\((?:lat/lon/height=(?P<datum>[^/,]+)/(?P<height>[^,]+)|x/y/z-ecef=(?P<xyz>[^,]+)|"
                          r"e/n/u-baseline=(?P<enu>[^,]+)),Q=")
#: separators rnx2rtkp's ``-s`` may set that georef splits on besides blanks
_SEPARATORS = (",", ";", "\t", "|")
#: what marks demo5's line for a camera event without a solution (lower case)
_INVALID_MARK = "time mark is not valid"
#: how much of a file :func:`is_rtklib_pos` looks at [bytes]
_SNIFF_BYTES = 16384
#: the first two bytes of a gzip file (RFC 1952)
_GZIP_MAGIC = b"\x1f\x8b"
#: a solution line's start: ``yyyy/mm/dd hh:mm:ss`` or GPS week and seconds of week (RTKLIB's two time formats)
_SOLUTION_LINE = re.compile(r"^\s*(?:\d{4}/\d{1,2}/\d{1,2}\s+\d{1,2}:\d{2}:\d{2}(?:\.\d*)?|\d{3,4}\s+\d+\.\d+)\s+"
                            r"[-+]?\d")


@dataclass
class PosHeader:
    """What a .pos header says. ``layout``: a key of the layouts (llh-deg, llh-dms, xyz, enu); ``height``:
    ``ellipsoidal`` or ``geodetic``; ``base``: the ``% ref pos`` (lat, lon [rad], ellipsoidal height [m]) or None;
    ``columns``: the column header's names (lower case) after the time; lines are 1-based file lines."""

    time_system: str
    layout: str
    height: str
    columns: list[str]
    column_line: int
    separator: str | None
    program: str | None = None
    base: tuple[float, float, float] | None = None
    base_line: int | None = None
    format_line: int | None = None


@dataclass
class PosSolution:
    """The epochs of a .pos file: UTC [POSIX s], WGS 84 latitude, longitude [deg], ellipsoidal height [m], quality
    ``Q``, satellites, NED covariance (K, 3, 3) [m^2] as the file gives it (no floor), age [s], ratio, file line."""

    path: Path
    header: PosHeader
    utc: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height: np.ndarray
    quality: np.ndarray
    n_sat: np.ndarray
    cov_ned: np.ndarray
    age: np.ndarray
    ratio: np.ndarray
    line: np.ndarray
    notices: list[InputNotice] = field(default_factory=list)
    #: an event file's time marks without a solution (demo5's "Q=0, Time mark is not valid" lines): UTC [POSIX s]
    #: and file lines
    invalid_mark_utc: np.ndarray = field(default_factory=lambda: np.empty(0))
    invalid_mark_line: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))

    def __len__(self) -> int:
        return len(self.utc)


def _read_bytes(path: Path | str, limit: int | None = None) -> bytes:
    """The file's bytes (the first ``limit`` of them), decompressed when it is gzip (an archived ``.pos.gz``:
    recognised by gzip's magic bytes, not by the name)."""
    with open(path, "rb") as handle:
        magic = handle.read(2)
        handle.seek(0)
        if magic != _GZIP_MAGIC:
            return handle.read() if limit is None else handle.read(limit)
        with gzip.GzipFile(fileobj=handle) as unzipped:
            return unzipped.read() if limit is None else unzipped.read(limit)


def is_rtklib_pos(path: Path | str) -> bool:
    """Whether ``path`` is an RTKLIB solution file (gzip too), by its content: a ``% program :`` line naming
    RTKLIB (or rnx2rtkp, RTKPOST, Emlid), or a ``%`` column header naming a time system and RTKLIB's position
    columns. A pipe or a missing file is not looked into (False)."""
    try:
        if not stat.S_ISREG(Path(path).stat().st_mode):
            return False
        head = _read_bytes(path, _SNIFF_BYTES).decode("utf-8", errors="replace")
    except (OSError, EOFError, zlib.error):
        return False
    for raw in head.splitlines():
        text = raw.strip()
        if not text:
            continue
        if not text.startswith("%"):
            return False
        lowered = text.lower()
        if lowered.startswith("% program") and any(name in lowered for name in ("rtklib", "rnx2rtkp", "rtkpost",
                                                                                  "emlid")):
            return True
        if _column_header(text) is not None:
            return True
    return False


def _column_header(text: str) -> tuple[str, list[str], str | None] | None:
    """(time system, names after it in lower case, separator) of a column header line, else None."""
    body = text.lstrip("%")
    separator = next((s for s in _SEPARATORS if s in body), None)
    names = (body.replace(separator, " ") if separator else body).split()
    if len(names) < 4 or names[0].upper() not in _TIME_SYSTEMS:
        return None
    lowered = [name.lower() for name in names[1:]]
    if not any(lowered[:3] == list(positions) for positions, _ in _LAYOUTS.values()):
        return None
    return names[0].upper(), lowered, separator


@dataclass(frozen=True)
class _HeaderLines:
    """The ``%`` lines of a header that georef reads, each with its 1-based file line: ``program`` (the text after
    ``% program :``), ``ref`` (the ``% ref pos`` values, not yet numbers), ``format_match`` (the ``(lat/lon/height=
    ...,Q=`` line), ``column`` (time system, lower-case names, separator of the column header); ``first_data``: the
    0-based index of the first line that is not a header line (the number of lines when there is none)."""

    program: str | None
    ref: tuple[int, list[str]] | None
    format_match: tuple[int, re.Match[str]] | None
    column: tuple[int, tuple[str, list[str], str | None]] | None
    first_data: int


def _scan_header(lines: list[str]) -> _HeaderLines:
    """The header lines georef reads, from the ``%`` lines before the first solution line (blank lines skipped)."""
    program = None
    ref: tuple[int, list[str]] | None = None
    format_match: tuple[int, re.Match[str]] | None = None
    column: tuple[int, tuple[str, list[str], str | None]] | None = None
    first_data = len(lines)
    for index, raw in enumerate(lines):
        text = raw.strip()
        if not text:
            continue
        if not text.startswith("%"):
            first_data = index
            break
        body = text.lstrip("%").strip()
        if body.lower().startswith("program") and ":" in body:
            program = body.split(":", 1)[1].strip()
        elif body.lower().startswith("ref pos") and ":" in body:
            ref = (index + 1, body.split(":", 1)[1].replace(",", " ").split())
        elif (found := _FORMAT_LINE.search(body)) is not None:
            format_match = (index + 1, found)
        elif (parsed := _column_header(text)) is not None:
            column = (index + 1, parsed)
    return _HeaderLines(program=program, ref=ref, format_match=format_match, column=column, first_data=first_data)


def _check_columns(path: Path, layout: str, names: list[str], column_line: int) -> None:
    """Refuse a column header whose names after the time differ from RTKLIB's for ``layout``: positions, Q, ns,
    then the six sd columns (the llh-deg layout's sixth may be called ``sdue(m)``, as the d m s layout's is)."""
    expected = [*_LAYOUTS[layout][0], *_COMMON, *_LAYOUTS[layout][1]]
    for k, want in enumerate(expected):
        got = names[k] if k < len(names) else None
        alias = layout == "llh-deg" and want == "sdun(m)" and got == "sdue(m)"
        if got != want and not alias:
            raise InputError(path, column_line, got if got is not None else want,
                             f"RTKLIB's {layout} layout has {want!r} as column {k + 2} (after the time), "
                             f"found {got!r}")


def _height_type(path: Path, format_match: tuple[int, re.Match[str]] | None, layout: str, column_line: int) -> str:
    """``ellipsoidal`` or ``geodetic`` (above a geoid), as the ``(lat/lon/height=WGS84/...`` line says; x/y/z and
    e/n/u positions are ellipsoidal. Refuses a line naming other positions than the columns, a datum other than
    WGS84, and latitude/longitude columns without the line."""
    if format_match is None:
        if layout.startswith("llh"):
            raise InputError(path, column_line, "height(m)", "the header does not say whether the heights are "
                             "ellipsoidal or geodetic (its '% (lat/lon/height=WGS84/...' line is missing): write the "
                             "solution with its header (out-outhead=on)")
        return "ellipsoidal"
    line, found = format_match
    kind = "xyz" if found.group("xyz") else "enu" if found.group("enu") else "llh"
    if kind != layout[:3]:
        raise InputError(path, line, None, f"the header line says {kind} positions but the column header "
                         f"(line {column_line}) has the {layout} columns")
    datum = (found.group("datum") or found.group("xyz") or found.group("enu")).strip()
    if datum.upper() != "WGS84":
        raise InputError(path, line, None, f"datum {excerpt(datum)}: georef reads WGS84 solutions only (write "
                         "the solution with out-datum=wgs84)")
    if kind != "llh":
        return "ellipsoidal"
    height = found.group("height").strip().lower()
    if height not in ("ellipsoidal", "geodetic"):
        raise InputError(path, line, None, f"height type {excerpt(height)}: RTKLIB writes ellipsoidal or "
                         "geodetic")
    return height


def _parse_header(path: Path, lines: list[str]) -> tuple[PosHeader, int]:
    """The header, and the 0-based index of the first data line."""
    scanned = _scan_header(lines)
    if scanned.column is None:
        where = scanned.first_data + 1 if scanned.first_data < len(lines) else None
        raise InputError(path, where, None, "no RTKLIB column header line (a '%' line such as '%  GPST  "
                         "latitude(deg) longitude(deg) height(m) Q ns sdn(m) ...') before the solutions: write the "
                         "solution with its header (RTKLIB option out-outhead=on)")
    column_line, (time_system, names, separator) = scanned.column
    layout = next(key for key, (positions, _) in _LAYOUTS.items() if names[:3] == list(positions))
    _check_columns(path, layout, names, column_line)
    height = _height_type(path, scanned.format_match, layout, column_line)
    base = None
    base_line = None
    if scanned.ref is not None:
        base_line, values = scanned.ref
        base = _parse_base(path, base_line, values)
    header = PosHeader(time_system=time_system, layout=layout, height=height, columns=names, column_line=column_line,
                       separator=separator, program=scanned.program, base=base, base_line=base_line,
                       format_line=scanned.format_match[0] if scanned.format_match else None)
    return header, scanned.first_data


def _parse_base(path: Path, line: int, values: list[str]) -> tuple[float, float, float]:
    """``% ref pos``: latitude, longitude [deg] and height [m, ellipsoidal], or d m s twice and height, or ECEF
    x y z [m] -> (lat, lon [rad], ellipsoidal height [m])."""
    try:
        numbers = [float(v) for v in values]
    except ValueError:
        raise InputError(path, line, "ref pos", f"not a number in {excerpt(' '.join(values))}") from None
    if len(numbers) == 3 and max(abs(v) for v in numbers) > 1000.0:
        lat, lon, h = ecef_to_geodetic(np.array(numbers))
        return float(lat), float(lon), float(h)
    if len(numbers) == 3:
        return float(np.radians(numbers[0])), float(np.radians(numbers[1])), numbers[2]
    if len(numbers) == 7:
        lat = _dms(path, line, "ref pos", values[0:3])
        lon = _dms(path, line, "ref pos", values[3:6])
        return float(np.radians(lat)), float(np.radians(lon)), numbers[6]
    raise InputError(path, line, "ref pos", f"expected latitude, longitude, height (3 or 7 numbers) or ECEF x y z, "
                     f"found {len(numbers)} numbers")


def _dms(path: Path, line: int, column: str, parts: list[str]) -> float:
    """Degrees of RTKLIB's ``ddd mm ss.sssss`` (the sign on the degrees, ``-0`` for -1 < value < 0)."""
    try:
        d, m, s = (float(p) for p in parts)
    except ValueError:
        raise InputError(path, line, column, f"not a number in {excerpt(' '.join(parts))}") from None
    if not (0.0 <= m < 60.0 and 0.0 <= s < 60.0 and d == int(d)):
        raise InputError(path, line, column, f"{excerpt(' '.join(parts))} is not degrees, minutes (0-59) and "
                         "seconds (0-60)")
    sign = -1.0 if parts[0].strip().startswith("-") else 1.0
    return sign * (abs(d) + m / 60.0 + s / 3600.0)


_EPOCH_ORDINAL = dt.date(1970, 1, 1).toordinal()


def _clock_reading(path: Path, line: int, column: str, first: str, second: str) -> float:
    """The time of a line as read on its own time system's calendar [s since 1970-01-01 of that calendar]:
    ``yyyy/mm/dd hh:mm:ss.sss`` or GPS week and seconds of week (RTKLIB counts a UTC or JST time in weeks too)."""
    try:
        if "/" in first:
            year, month, day = (int(v) for v in first.split("/"))
            hour, minute, second_s = second.split(":")
            h, m, s = int(hour), int(minute), float(second_s)
            if not (0 <= h <= 23 and 0 <= m <= 59 and 0.0 <= s < 61.0):
                raise ValueError
            days = dt.date(year, month, day).toordinal() - _EPOCH_ORDINAL
            return days * SECONDS_PER_DAY + h * 3600.0 + m * 60.0 + s
        week, seconds = int(first), float(second)
        if week < 0 or not 0.0 <= seconds < SECONDS_PER_WEEK + 1.0:
            raise ValueError
        return GPS_EPOCH.timestamp() + week * SECONDS_PER_WEEK + seconds
    except ValueError:
        raise InputError(path, line, column, f"{excerpt(first + ' ' + second)} is neither yyyy/mm/dd hh:mm:ss.s nor "
                         "a GPS week and seconds of week") from None


#: where each quantity sits in a row of the columns :func:`read_pos_solution` reads (:attr:`_ColumnPlan.wanted`):
#: the three positions, solution quality Q, satellites, the three standard deviations, the three signed roots of
#: the covariances (all in the order and frame of the layout's columns), then the known tail columns present
_POSITION, _Q, _NS, _SD, _CROSS, _TAIL = slice(0, 3), 3, 4, slice(5, 8), slice(8, 11), 11


@dataclass(frozen=True)
class _ColumnPlan:
    """Where the columns georef reads sit in a solution line split into fields: ``width`` the fields of a line
    (the time's two included), ``column_of`` column name -> (its first field, how many fields it spans),
    ``sd_names`` the header's own names of the six sd columns, ``wanted`` the columns read into a row, in the
    row's order (:data:`_POSITION` ...), ``unknown`` the tail columns georef does not use."""

    width: int
    column_of: dict[str, tuple[int, int]]
    sd_names: list[str]
    wanted: list[str]
    unknown: list[str]


def _plan_columns(header: PosHeader) -> _ColumnPlan:
    """Which fields of a solution line hold which column, from the column header's names."""
    positions, sds = _LAYOUTS[header.layout]
    names = header.columns
    spans = [_FIELDS.get(name, 1) for name in names]
    offsets = np.concatenate([[2], 2 + np.cumsum(spans)])  # the time spans the first two fields
    column_of = {name: (int(offsets[k]), spans[k]) for k, name in enumerate(names)}
    n_fixed = len(positions) + len(_COMMON)
    unknown = [name for name in names[n_fixed + len(sds):] if name not in _KNOWN_TAIL]
    # the header's own names (RTKLIB's d m s layout calls the north-up term sdue), then the known tail
    sd_names = names[n_fixed:n_fixed + len(sds)]
    wanted = [*names[:n_fixed], *sd_names, *[n for n in _KNOWN_TAIL if n in column_of]]
    return _ColumnPlan(width=int(offsets[-1]), column_of=column_of, sd_names=sd_names, wanted=wanted,
                       unknown=unknown)


@dataclass
class _DataLines:
    """The solution lines as read: ``rows`` the wanted columns (:attr:`_ColumnPlan.wanted`) as numbers (degrees,
    metres, seconds as the file gives them), ``readings`` their times on the file's time system's calendar [s since
    1970-01-01 of that calendar], ``lines`` their 1-based file lines; ``mark_readings`` and ``mark_lines`` the same
    for demo5's time marks without a solution."""

    rows: list[list[float]] = field(default_factory=list)
    readings: list[float] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    mark_readings: list[float] = field(default_factory=list)
    mark_lines: list[int] = field(default_factory=list)


def _decode_lines(path: Path) -> list[str]:
    """The file's lines as text (gzip unpacked, ``\\r`` of CRLF ends dropped); an :class:`InputError` for a file
    that cannot be read, a damaged gzip file or a byte that is not UTF-8 (naming its line)."""
    try:
        raw_lines = _read_bytes(path).split(b"\n")
    except OSError as exc:
        raise InputError(path, None, None, f"cannot read: {exc.strerror or exc}") from None
    except (EOFError, zlib.error) as exc:
        raise InputError(path, None, None, f"a damaged gzip file ({exc}): unpack it with gunzip to see what is "
                         "left, or copy it again") from None
    lines: list[str] = []
    for index, raw in enumerate(raw_lines):
        try:
            lines.append(raw.decode("utf-8").rstrip("\r"))
        except UnicodeDecodeError:
            raise InputError(path, index + 1, None, "not text (a byte that is not UTF-8): an RTKLIB .pos file is "
                             "text") from None
    return lines


def _parse_row(path: Path, number: int, fields: list[str], plan: _ColumnPlan) -> list[float]:
    """The wanted columns of the solution line ``number`` (split into ``fields``) as numbers: d m s as degrees,
    anything else as the finite float it must be."""
    row: list[float] = []
    for name in plan.wanted:
        start, span = plan.column_of[name]
        if span == 3:
            row.append(_dms(path, number, name, fields[start:start + 3]))
            continue
        try:
            value = float(fields[start])
        except ValueError:
            raise InputError(path, number, name, f"not a number: {excerpt(fields[start])}") from None
        if not np.isfinite(value):
            raise InputError(path, number, name, f"not a finite number: {excerpt(fields[start])}")
        row.append(value)
    return row


def _read_data_lines(path: Path, lines: list[str], first: int, header: PosHeader, plan: _ColumnPlan,
                     notices: list[InputNotice]) -> _DataLines:
    """The lines from index ``first`` on (``%`` and blank lines skipped): solutions, and demo5's time marks
    without one. A last line cut short (a file copied while RTKLIB wrote it) is dropped with a notice; any other
    line with more or fewer fields than the column header gives is an :class:`InputError`."""
    read = _DataLines()
    last_line = max((k + 1 for k in range(first, len(lines)) if lines[k].strip()), default=0)
    for index in range(first, len(lines)):
        text = lines[index].strip()
        if not text or text.startswith("%"):
            continue
        number = index + 1
        fields = (text.replace(header.separator, " ") if header.separator else text).split()
        if _INVALID_MARK in text.lower() and len(fields) >= 2:
            # demo5 writes a time mark it has no solution for as "<time>   Q=0, Time mark is not valid"
            read.mark_readings.append(_clock_reading(path, number, header.time_system, fields[0], fields[1]))
            read.mark_lines.append(number)
            continue
        if len(fields) != plan.width:
            if len(fields) < plan.width and number == last_line:
                # a file copied while RTKLIB was still writing it: its last line cut short
                notices.append(InputNotice(path, [number], None, f"last line cut short ({len(fields)} of "
                                           f"{plan.width} fields): dropped"))
                continue
            raise InputError(path, number, None, f"{len(fields)} fields, the column header (line "
                             f"{header.column_line}) gives {plan.width}")
        read.readings.append(_clock_reading(path, number, header.time_system, fields[0], fields[1]))
        read.rows.append(_parse_row(path, number, fields, plan))
        read.lines.append(number)
    return read


def _marks_only(path: Path, header: PosHeader, notices: list[InputNotice], mark_utc: np.ndarray,
                mark_line: np.ndarray) -> PosSolution:
    """A solution without epochs, holding only an event file's time marks (UTC [POSIX s] and file lines)."""
    empty = np.empty(0)
    return PosSolution(path=path, header=header, utc=empty, lat_deg=empty, lon_deg=empty, height=empty,
                       quality=np.empty(0, np.int64), n_sat=np.empty(0, np.int64), cov_ned=np.empty((0, 3, 3)),
                       age=empty, ratio=empty, line=np.empty(0, np.int64), notices=notices,
                       invalid_mark_utc=mark_utc, invalid_mark_line=mark_line)


def _check_quality_and_sigmas(path: Path, data: np.ndarray, line: np.ndarray, sd_names: list[str]) -> None:
    """Refuse a solution quality that is not RTKLIB's (an integer 1-7) and a negative standard deviation."""
    quality = data[:, _Q]
    bad_q = np.flatnonzero((quality != np.round(quality)) | (quality < 1) | (quality > 7))
    if len(bad_q):
        raise InputError(path, int(line[bad_q[0]]), "q", f"solution quality {quality[bad_q[0]]:g}: RTKLIB writes "
                         "1 fix, 2 float, 3 SBAS, 4 DGPS, 5 single, 6 PPP (7 dead reckoning, demo5)")
    sd = data[:, _SD]
    negative = np.flatnonzero(np.any(sd < 0, axis=1))
    if len(negative):
        k = int(negative[0])
        axis = int(np.argmax(sd[k] < 0))
        raise InputError(path, int(line[k]), sd_names[axis], "a standard deviation must not be negative")


def _ellipsoidal_height(path: Path, header: PosHeader, where: _Positions, geoid: str,
                        notices: list[InputNotice]) -> np.ndarray:
    """The WGS 84 ellipsoidal heights [m] of the positions: the file's, or its heights above the geoid
    (``geodetic``) converted with ``geoid`` (a PROJ vertical CRS), with a notice saying so."""
    if header.height != "geodetic":
        return where.height
    height, used = ellipsoidal_from_orthometric(where.lat_deg, where.lon_deg, where.height, geoid)
    notices.append(InputNotice(path, [header.format_line or header.column_line], "height(m)",
                               f"heights above the geoid converted to WGS 84 ellipsoidal with {used}; RTKLIB's own "
                               "geoid (by default its embedded 1-degree EGM96) may differ from this grid by "
                               "decimetres: write ellipsoidal heights (out-height=ellipsoidal) to avoid both"))
    return height


def _tail_columns(data: np.ndarray, plan: _ColumnPlan) -> dict[str, np.ndarray]:
    """The known tail columns the file has (age [s], ratio), by name."""
    present = [name for name in _KNOWN_TAIL if name in plan.column_of]
    return {name: data[:, _TAIL + k] for k, name in enumerate(present)} if data.shape[1] > _TAIL else {}


def read_pos_solution(path: Path | str, geoid: str = EGM96_HEIGHT) -> PosSolution:
    """Every epoch of an RTKLIB/Emlid ``.pos`` file, in UTC and WGS 84 with NED covariances.

    ``geoid``: the vertical CRS (PROJ name) of the heights when the header says ``geodetic`` (RTKLIB's own
    default is its embedded EGM96; the file does not say which model it used). Errors name the file, line and
    column.
    """
    path = Path(path)
    lines = _decode_lines(path)
    header, first = _parse_header(path, lines)
    plan = _plan_columns(header)
    notices: list[InputNotice] = []
    if plan.unknown:
        notices.append(InputNotice(path, [header.column_line], None, f"column(s) {', '.join(plan.unknown)} not used"))
    positions = _LAYOUTS[header.layout][0]
    if header.layout == "enu" and header.base is None:
        raise InputError(path, header.column_line, positions[0], "east/north/up baselines need the base position, "
                         "and the header has no '% ref pos' line")
    read = _read_data_lines(path, lines, first, header, plan, notices)
    mark_utc = _to_utc(np.array(read.mark_readings), header.time_system)
    mark_line = np.array(read.mark_lines, np.int64)
    if not read.rows:
        if read.mark_lines:
            return _marks_only(path, header, notices, mark_utc, mark_line)
        raise InputError(path, None, None, "no solution lines after the header")
    data = np.array(read.rows)
    line = np.array(read.lines, dtype=np.int64)
    _check_quality_and_sigmas(path, data, line, plan.sd_names)
    utc = _to_utc(np.array(read.readings), header.time_system)
    _check_times(path, utc, line, header.time_system)
    where = _positions(path, header, data, notices)
    height = _ellipsoidal_height(path, header, where, geoid, notices)
    bad_lat = np.flatnonzero((np.abs(where.lat_deg) > 90.0) | (np.abs(where.lon_deg) > 180.0))
    if len(bad_lat):
        raise InputError(path, int(line[bad_lat[0]]), positions[0], "coordinate outside the valid range")
    tail = _tail_columns(data, plan)
    return PosSolution(path=path, header=header, utc=utc, lat_deg=where.lat_deg, lon_deg=where.lon_deg,
                       height=height, quality=data[:, _Q].astype(np.int64), n_sat=data[:, _NS].astype(np.int64),
                       cov_ned=where.cov_ned, age=tail.get("age(s)", np.full(len(line), np.nan)),
                       ratio=tail.get("ratio", np.full(len(line), np.nan)), line=line, notices=notices,
                       invalid_mark_utc=mark_utc, invalid_mark_line=mark_line)


def _to_utc(readings: np.ndarray, time_system: str) -> np.ndarray:
    """UTC [POSIX s] of clock readings on GPST, UTC or JST [s since 1970-01-01 of that calendar]."""
    if time_system == "GPST":
        return gps_week_to_utc(0, readings - GPS_EPOCH.timestamp())
    if time_system == "JST":
        return readings - JST_MINUS_UTC
    return readings


def _check_times(path: Path, utc: np.ndarray, line: np.ndarray, column: str) -> None:
    check_increasing(path, utc, line, column)
    same = np.flatnonzero(np.diff(utc) == 0)
    if len(same):
        raise InputError(path, int(line[same[0] + 1]), column, f"the same time as line {int(line[same[0]])}")


@dataclass(frozen=True)
class _Positions:
    """The positions of the solution lines: WGS 84 latitude, longitude [deg], height [m, ellipsoidal or above the
    geoid, as the file's] and NED covariance (K, 3, 3) [m^2] at each position."""

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height: np.ndarray
    cov_ned: np.ndarray


def _positions(path: Path, header: PosHeader, data: np.ndarray, notices: list[InputNotice]) -> _Positions:
    """Latitude, longitude [deg], height [m, as the file's], NED covariance (K, 3, 3) [m^2] of the rows."""
    position, sd, cross = data[:, _POSITION], data[:, _SD], data[:, _CROSS]
    if header.layout.startswith("llh"):
        cov_neu = covariance_from_signed_roots(sd, cross)  # sdn sde sdu, then ne, eu, un
        return _Positions(position[:, 0], position[:, 1], position[:, 2], neu_to_ned_covariance(cov_neu))
    if header.layout == "xyz":
        lat, lon, h = ecef_to_geodetic(position)
        cov_e = covariance_from_signed_roots(sd, cross)  # sdx sdy sdz, then xy, yz, zx
        return _Positions(np.degrees(lat), np.degrees(lon), h, ecef_to_ned_covariance(cov_e, lat, lon))
    assert header.base is not None
    base_lat, base_lon, base_h = header.base
    lat, lon, h = ecef_to_geodetic(enu_baseline_to_ecef(position, base_lat, base_lon, base_h))
    cov_enu = covariance_from_signed_roots(sd, cross)  # sde sdn sdu, then en, nu, ue
    cov = enu_at_base_to_ned_covariance(cov_enu, base_lat, base_lon, lat, lon)
    return _Positions(np.degrees(lat), np.degrees(lon), h, cov)


def _time_notice(solution: PosSolution, scale: str, first_utc: float | None = None) -> InputNotice:
    system = solution.header.time_system
    first = float(solution.utc[0]) if first_utc is None else first_utc
    gps = utc_to_gps_seconds(np.array([first]))
    leap = int(gps_minus_utc(gps)[0])
    how = {"GPST": f"GPS time, UTC = GPST - {leap} s (leap seconds)", "UTC": "UTC",
           "JST": "JST, UTC = JST - 9 h"}[system]
    day = dt.datetime.fromtimestamp(first, tz=dt.UTC)
    start = {"utc-day": f"UTC seconds of {day.date().isoformat()}",
             "gps-week": f"GPS seconds of week {int(np.floor(float(gps[0]) / SECONDS_PER_WEEK))}",
             "utc-posix": "UTC seconds since 1970-01-01"}[scale]
    return InputNotice(solution.path, [solution.header.column_line], system,
                       f"times in {how}; taken as {start} (the IMU's times must be on the same scale)")


def _quality_notices(solution: PosSolution) -> list[InputNotice]:
    counts = {q: int((solution.quality == q).sum()) for q in QUALITY_NAMES}
    summary = ", ".join(f"{n} {QUALITY_NAMES[q]} (Q={q})" for q, n in counts.items() if n)
    return [InputNotice(solution.path, [], "Q", f"{len(solution)} solutions: {summary}")]


def _reading_notices(solution: PosSolution, time_scale: str, reference_utc: float | None) -> list[InputNotice]:
    """The notices of reading the file as fixes: the file's own, its time system and scale, its solution
    qualities, the time marks without a solution skipped and the leap seconds' validity."""
    notices = [*solution.notices, _time_notice(solution, time_scale, reference_utc), *_quality_notices(solution)]
    if len(solution.invalid_mark_line):
        notices.append(InputNotice(solution.path, solution.invalid_mark_line.tolist(), None, "time-mark lines "
                                   "without a solution ('Time mark is not valid') skipped: not GNSS fixes"))
    note = leap_seconds_note(float(solution.utc[-1]))
    if note:
        notices.append(InputNotice(solution.path, [], solution.header.time_system, note))
    return notices


def _dropped(solution: PosSolution, drop_code_solutions: bool, notices: list[InputNotice]) -> np.ndarray:
    """Which epochs are not used as fixes (bool (K,)): dead reckoning (Q 7) always, code-only solutions (Q 3, 4,
    5) when ``drop_code_solutions`` and the file has carrier-phase ones; a notice for each kind dropped. An
    :class:`InputError` when nothing is left."""
    drop = solution.quality == 7
    if drop.any():
        notices.append(InputNotice(solution.path, solution.line[drop].tolist(), "Q", f"{int(drop.sum())} "
                                   "dead-reckoning solution(s) (Q=7) dropped: not a GNSS fix"))
    carrier = np.isin(solution.quality, CARRIER_QUALITIES)
    code = np.isin(solution.quality, CODE_QUALITIES)
    if drop_code_solutions and carrier.any() and code.any():
        drop |= code
        notices.append(InputNotice(solution.path, solution.line[code].tolist(), "Q", f"{int(code.sum())} code-only "
                                   "solution(s) (Q=3 SBAS, 4 DGPS, 5 single) dropped: the file has carrier-phase "
                                   "solutions (fix, float, PPP), which they would pull metres off"))
    if drop.all():
        raise InputError(solution.path, None, "Q", "no usable solution: every line was dropped (see the notices)")
    return drop


def _floored_covariance(solution: PosSolution, floors: Mapping[int, tuple[float, float, float]],
                        notices: list[InputNotice]) -> np.ndarray:
    """The NED covariances (K, 3, 3) [m^2] of every epoch with its north, east, up standard deviations raised to
    ``floors[Q]`` [m] (correlations kept) and made positive semi-definite, with notices naming what changed."""
    floor = np.array([floors[int(q)] for q in solution.quality], dtype=float)
    raised = floor > np.sqrt(np.diagonal(solution.cov_ned, axis1=-2, axis2=-1))
    cov = with_sigma_floor(solution.cov_ned, floor)
    cov = _positive_semidefinite(solution, cov, notices)
    if raised.any():
        per_q = ", ".join(f"Q={q}: {floors[q][0]:g}/{floors[q][1]:g}/{floors[q][2]:g} m"
                          for q in sorted(set(solution.quality[raised.any(axis=1)].tolist())))
        notices.append(InputNotice(solution.path, [], "sdn/sde/sdu", f"{int(raised.any(axis=1).sum())} solution(s) "
                                   f"with standard deviations below the floor (north/east/up {per_q}) raised to it, "
                                   "the correlations kept"))
    return cov


def read_rtklib_gnss(path: Path | str, time_scale: str = "utc-day", sigma_floors: Mapping[int, tuple[float, float,
                     float]] | None = None, drop_code_solutions: bool = True, geoid: str = EGM96_HEIGHT,
                     reference_utc: float | None = None, solution: PosSolution | None = None) -> GnssEpochs:
    """An RTKLIB/Emlid ``.pos`` solution as GNSS antenna fixes with full NED covariances.

    * times on ``time_scale`` (:data:`TIME_SCALES`; the IMU's must be the same), from ``reference_utc``'s day
      (default the first solution's);
    * each fix's covariance is the file's, its standard deviations raised to ``sigma_floors[Q]`` (north, east,
      up [m]; default :data:`SIGMA_FLOORS`) with the correlations kept; ``sigma_neu`` holds its diagonal's roots;
    * when the file has carrier-phase solutions (Q 1, 2, 6) and ``drop_code_solutions``, its code-only ones (Q 3,
      4, 5: metres off, and biased against the carrier-phase track) are dropped; dead-reckoning (Q 7) solutions
      are always dropped; every drop is a notice naming the lines.

    ``solution``: the file already read by :func:`read_pos_solution` (with ``geoid``), so it is not parsed twice.
    """
    solution = read_pos_solution(path, geoid=geoid) if solution is None else solution
    if not len(solution):
        raise InputError(solution.path, None, None, "no solution lines, only camera time marks: this is an events "
                         "file (give it to --events)")
    floors = dict(SIGMA_FLOORS)
    floors.update(sigma_floors or {})
    notices = _reading_notices(solution, time_scale, reference_utc)
    drop = _dropped(solution, drop_code_solutions, notices)
    cov = _floored_covariance(solution, floors, notices)
    keep = ~drop
    times = solution_times(solution.utc, time_scale, reference_utc)
    sigma = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    fixes = GnssEpochs(time=times[keep], lat_deg=solution.lat_deg[keep], lon_deg=solution.lon_deg[keep],
                       height=solution.height[keep], line=solution.line[keep], repeated=np.zeros(int(keep.sum()), bool),
                       notices=notices, sigma_neu=sigma[keep], cov_ned=cov[keep])
    from georef.io.plausibility import check_gnss_jumps

    fixes, jumps = check_gnss_jumps(solution.path, fixes, _LAYOUTS[solution.header.layout][0][0])
    fixes.notices.extend(jumps)
    return fixes


def _positive_semidefinite(solution: PosSolution, cov: np.ndarray, notices: list[InputNotice]) -> np.ndarray:
    """The covariances with negative eigenvalues (the file's 0.1 mm rounding of near-perfect correlations) clipped
    to 0, with a notice naming the lines."""
    values, vectors = np.linalg.eigh(cov)
    scale = np.maximum(np.abs(values).max(axis=-1, keepdims=True), 1e-30)
    bad = np.any(values < -1e-9 * scale, axis=-1)
    if not bad.any():
        return cov
    clipped = vectors @ (np.clip(values, 0.0, None)[..., None] * np.swapaxes(vectors, -1, -2))
    notices.append(InputNotice(solution.path, solution.line[bad].tolist(), "sdne/sdeu/sdun", f"{int(bad.sum())} "
                               "covariance(s) not positive semi-definite (correlations beyond 1 after rounding): "
                               "negative eigenvalues set to 0"))
    return np.where(bad[:, None, None], clipped, cov)


def read_rtklib_events(path: Path | str, time_scale: str = "utc-day", reference_utc: float | None = None,
                       geoid: str = EGM96_HEIGHT, solution: PosSolution | None = None) -> tuple[Exposures, None]:
    """The camera events of an Emlid Studio / RTKLIB demo5 ``_events.pos`` as exposures.

    The file is a solution file (``outsol`` of demo5's ``postpos.c``): one line per time mark of the receiver's
    event input, with the solution interpolated to it, and ``<time>   Q=0, Time mark is not valid`` for a mark the
    receiver had no solution for. Every mark is an exposure (its time is the receiver's either way): frame ids
    1, 2, ... in line order, times on ``time_scale`` (:func:`solution_times`), each known as well as a hot-shoe
    feedback's (:data:`~georef.io.camera.FEEDBACK_TIME_SIGMA`). The event positions are not used: georef places
    every exposure on its own trajectory. Returns (exposures, None): the file names no images. ``solution``: the
    file already read by :func:`read_pos_solution`, so it is not parsed twice."""
    from georef.io.camera import FEEDBACK_TIME_SIGMA, Exposures

    solution = read_pos_solution(path, geoid=geoid) if solution is None else solution
    check_events_file(solution)
    utc = np.concatenate([solution.utc, solution.invalid_mark_utc])
    line = np.concatenate([solution.line, solution.invalid_mark_line]).astype(np.int64)
    order = np.argsort(line, kind="stable")
    utc, line = utc[order], line[order]
    back = np.flatnonzero(np.diff(utc) < 0)
    if len(back):
        raise InputError(solution.path, int(line[back[0] + 1]), solution.header.time_system, "event times go "
                         f"backwards from line {int(line[back[0]])}")
    times = solution_times(utc, time_scale, reference_utc)
    # the notice names the day (or week) the times count from: reference_utc's when given
    notices = [*solution.notices, _time_notice(solution, time_scale, float(utc[0]) if reference_utc is None
                                               else reference_utc),
               InputNotice(solution.path, [], None, f"{len(utc)} camera events; their positions in the file are not "
                           "used (each exposure is placed on the fused trajectory)")]
    if len(solution.invalid_mark_line):
        notices.append(InputNotice(solution.path, solution.invalid_mark_line.tolist(), None, "camera event(s) "
                                   "without a GNSS solution ('Time mark is not valid'): kept, the time is the "
                                   "receiver's"))
    frames = np.array([str(k + 1) for k in range(len(utc))], dtype=object)
    exposures = Exposures(path=solution.path, frame=frames, time=times, lines=line, notices=notices,
                          problem=np.array([""] * len(utc)), time_sigma=np.full(len(utc), FEEDBACK_TIME_SIGMA))
    return exposures, None


def check_not_headerless(path: Path | str) -> None:
    """Refuse RTKLIB solution lines without their ``%`` header (written with out-outhead=off, or the header cut
    off), which would otherwise be read as a csv without its column names: an :class:`InputError` naming the
    first line. Anything else (a csv, a missing file) is left to its reader."""
    try:
        if not stat.S_ISREG(Path(path).stat().st_mode):
            return
        head = _read_bytes(path, _SNIFF_BYTES).decode("utf-8", errors="replace")
    except (OSError, EOFError, zlib.error):
        return
    for number, raw in enumerate(head.splitlines(), start=1):
        if not raw.strip():
            continue
        if _SOLUTION_LINE.match(raw) and "," not in raw:
            raise InputError(path, number, None, "RTKLIB solution lines without RTKLIB's header: the '%' lines "
                             "that name the time system (GPST, UTC) and the columns are missing, so the times and "
                             "positions cannot be read safely. Write the solution with its header (RTKLIB option "
                             "out-outhead=on; Emlid Studio writes it), or copy the header lines back from the same "
                             "program's output")
        return


#: a solution file given as camera events: most steps between its epochs equal to the median step to this share
#: of it (a receiver's output rate; a simulated receiver's time tags jitter by a few ms at 5 Hz) ...
_REGULAR_STEP_TOLERANCE = 0.05
#: ... in this share of the steps, with at least this many epochs
_REGULAR_SHARE, _REGULAR_MIN_EPOCHS = 0.9, 20


def check_events_file(solution: PosSolution) -> None:
    """Refuse a position solution given as camera events (``--events rover.pos``): its epochs follow the
    receiver's output rate (nearly all steps equal), while an Emlid/RTKLIB demo5 event file (named
    ``*_events.pos``, or holding 'Time mark is not valid' lines) has one line per shutter. An
    :class:`InputError` (exit 2) says to give it as --gnss."""
    if len(solution.invalid_mark_line) or solution.path.name.lower().removesuffix(".gz").endswith("_events.pos"):
        return
    if len(solution) < _REGULAR_MIN_EPOCHS:
        return
    step = np.diff(solution.utc)
    median = float(np.median(step))
    regular = float(np.mean(np.abs(step - median) <= _REGULAR_STEP_TOLERANCE * median))
    if regular < _REGULAR_SHARE:
        return
    raise InputError(solution.path, None, None, f"this is a position solution, not camera events: {len(solution)} "
                     f"epochs, {100 * regular:.0f} % of them {median:g} s apart (the receiver's output rate, not "
                     "shutter events). Give it as --gnss; the camera events are the *_events.pos that Emlid Studio "
                     "or RTKLIB demo5 writes from the receiver's event input (or an events.csv). An event file "
                     "renamed: name it *_events.pos")


def describe_pos(path: Path | str) -> list[tuple[str, str]]:
    """``georef info`` of an RTKLIB/Emlid .pos: (what, value) rows: program, layout, time system, epochs, span
    (UTC and, for GPST, GPS time), output interval, solution qualities, median sigmas, camera time marks."""
    solution = read_pos_solution(path)
    header = solution.header
    rows = [("format", f"RTKLIB solution (.pos), {header.program or 'program not named'}"),
            ("layout", f"{header.layout}, heights {header.height}"
             + (f", base {np.degrees(header.base[0]):.8f}, {np.degrees(header.base[1]):.8f}, "
                f"{header.base[2]:.3f} m" if header.base is not None else "")),
            ("time system", _time_system_text(solution))]
    marks = len(solution.invalid_mark_line)
    if not len(solution):
        first, last = float(solution.invalid_mark_utc[0]), float(solution.invalid_mark_utc[-1])
        rows += [("epochs", f"none with a solution; {marks} camera time mark(s) without one: an events file"),
                 ("time span", _utc_span(first, last))]
        return rows
    first, last = float(solution.utc[0]), float(solution.utc[-1])
    step = np.diff(solution.utc)
    events = bool(marks) or solution.path.name.lower().removesuffix(".gz").endswith("_events.pos")
    if events:  # one line per shutter: no output rate, no gaps
        rows += [("camera events", f"{len(solution) + marks} ({marks} without a solution): an events file, for "
                  "--events"), ("time span", _utc_span(min(first, *solution.invalid_mark_utc),
                                                       max(last, *solution.invalid_mark_utc)))]
        step = np.empty(0)
    else:
        rate = f", every {float(np.median(step)):g} s" if len(step) else ""
        rows += [("epochs", f"{len(solution)}{rate}: a position solution, for --gnss"),
                 ("time span", _utc_span(first, last))]
    if header.time_system == "GPST":
        gps = utc_to_gps_seconds(np.array([first, last]))
        week = int(np.floor(gps[0] / SECONDS_PER_WEEK))
        rows.append(("GPS time", f"week {week}, {gps[0] - week * SECONDS_PER_WEEK:.3f} - "
                     f"{gps[1] - week * SECONDS_PER_WEEK:.3f} s of the week"))
    gaps = np.flatnonzero(step > 1.5 * float(np.median(step))) if len(step) else np.empty(0, int)
    if len(gaps):
        rows.append(("gaps", f"{len(gaps)}, longest {float(step.max()):.1f} s (after line "
                     f"{int(solution.line[int(np.argmax(step))])})"))
    counts = ", ".join(f"{int((solution.quality == q).sum())} {name} (Q={q})" for q, name in QUALITY_NAMES.items()
                       if (solution.quality == q).any())
    rows.append(("solution quality", counts))
    sigma = np.sqrt(np.diagonal(solution.cov_ned, axis1=-2, axis2=-1))
    rows.append(("median sigma (file)", f"north {np.median(sigma[:, 0]):.3f}, east {np.median(sigma[:, 1]):.3f}, "
                 f"up {np.median(sigma[:, 2]):.3f} m (before georef's floors per Q)"))
    rows += [("notice", str(notice)) for notice in solution.notices]
    return rows


def _time_system_text(solution: PosSolution) -> str:
    system = solution.header.time_system
    if system == "GPST":
        first = float(solution.utc[0]) if len(solution) else float(solution.invalid_mark_utc[0])
        leap = int(gps_minus_utc(utc_to_gps_seconds(np.array([first])))[0])
        return f"GPST (GPS time): UTC = GPST - {leap} s (leap seconds)"
    return {"UTC": "UTC", "JST": "JST: UTC = JST - 9 h"}[system]


def _utc_span(first: float, last: float) -> str:
    def text(posix: float) -> str:
        return dt.datetime.fromtimestamp(posix, tz=dt.UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]

    return f"{text(first)} - {text(last)} UTC ({last - first:.1f} s)"
