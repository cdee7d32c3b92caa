"""A seeded mutation corpus of autopilot logs through :func:`georef.io.logs.read_flight_log` and ``georef info``.

The seeds are a simulated drone flight of 60 s written as ArduCopter DataFlash logs (4.x and 3.x, binary and text,
the text ones cut to their first quarter) and PX4 ULogs (v1.14 and v1.10), and the real trimmed logs of
``tests/data/logs/``. Each case mutates one seed with one to three of:

* bytes, any format: a cut at any offset, within the definitions or inside a message; flipped bytes; inserted,
  deleted, duplicated and erased (0x00/0xFF) runs;
* DataFlash binary: FMT messages with another length, format character, name, field names or type id, FMT's own
  FMT damaged, a FMT or every message of a type removed; NaN/inf in float fields, absurd integers (latitude beyond
  90 deg, status 255, instance 7); TimeUS/TimeMS going backwards or jumping; GPS week 0 or absurd; every fix
  invalid (status < 3); repeated and swapped messages;
* DataFlash text: the same on lines, plus cut lines, missing and extra fields, non-numeric, non-finite and
  100,000-character fields, undecodable bytes and NUL, damaged FMT lines, CR LF, blank, repeated, swapped and
  deleted lines;
* ULog: the file header, message sizes (0 to 65535) and types, format definitions (``F``: field and type names,
  array sizes, the topic's name), info (``I``/``M``) and parameter (``P``) messages, every parameter removed,
  subscriptions (``A``: ids, names), a topic's data removed; NaN/inf and absurd values, timestamps backwards or
  jumping, ``time_utc_usec`` 0 or absurd, every fix invalid (``fix_type`` < 3), dropout and sync messages
  inserted, the flag bits (incompatible flags, appended-data offsets);
* gzip: the stream cut, its CRC or length damaged, a byte of the deflate data flipped, the header damaged, bytes
  after the stream, two members, a gzip of a mutated log, of garbage, of nothing, of a gzip.

Every case must end within :data:`CASE_LIMIT_S`, and in either

* a :class:`~georef.io.logs.flightlog.FlightLog` whose IMU times are finite and strictly increasing, IMU
  values, GNSS fixes (time, position, height) and camera events finite, GNSS sigmas positive where given, and
  which :func:`~georef.io.logs.flightlog.to_pos_log` and :func:`~georef.io.logs.flightlog.describe` take; or
* an :class:`~georef.io.errors.InputError` that names the file, stays short (< :data:`MAX_MESSAGE` characters) and
  is located: it names a message or topic of the log (``GPS.Status``, ``FMT IMU``, ``vehicle_gps_position.lat``)
  or a line or byte, or is about the file as a whole (:data:`WHOLE_FILE`: not a log at all, a gzip stream that
  cannot be decompressed);

with no other exception and no RuntimeWarning (numpy's invalid casts and divisions). ``georef info`` on 3 more
cases of each seed exits 0 or 2, never 3 (an internal error), and an error names the file.

Defects the corpus found in the readers (all fixed):

* a FMT or F message that lost or renamed a field, or made a number field text, raised KeyError, TypeError or
  ValueError (``could not convert string to float``) instead of naming the message and field; a FMT with a field
  name twice or empty raised numpy's ValueError;
* IMU samples whose time stamp went back (or a lone one far ahead) left the IMU times out of order: only a repeat of
  the previous stamp was dropped; NaN IMU values went through to the filter;
* a clock fitted to damaged fix times could run at rate 0 or backwards (every IMU sample at one time), and the day's
  start came from an outlier fix;
* a type with a FMT and no message (or no usable fix) raised IndexError; a NaN height was kept as a fix; a GPA.HAcc
  of 0 (no accuracy) became a sigma of 0 m;
* a FMT redefining FMT's own length made the walk read past the end (numpy ValueError);
* a text log's NaN or out-of-range integer field (``Status, 1e300``) gave RuntimeWarnings and garbage instances;
* a float32 signalling NaN raised ``invalid value encountered in cast``;
* pyulog reads some ULogs with damaged message headers for ever (it seeks back before the broken message and meets
  it again): the reader now stops it with an error naming the byte;
* a non-numeric or NaN parameter value raised ValueError.

The corpus is 790 cases (and 39 through ``georef info``); the file runs in about 40 s on one core (45 s on a loaded
one), 2-3 s of them making the seeds; no test takes 20 s.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gzip
import random
import re
import signal
import struct
import time
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from georef_cli.main import app
from typer.testing import CliRunner

from georef.io.errors import InputError
from georef.io.logs import read_flight_log
from georef.io.logs.ardupilot import WANTED
from georef.io.logs.flightlog import FlightLog, describe, to_pos_log
from georef.io.logs.px4 import TOPICS
from georef.sim.autopilot_logs import write_dataflash, write_ulog
from georef.sim.flight import SimConfig, simulate

REAL = Path(__file__).resolve().parents[2] / "data" / "logs"
#: a case that takes longer than this fails [s]; one that hangs is interrupted after HANG_S [s]
CASE_LIMIT_S = 5.0
HANG_S = 20.0
#: the longest message an error may have [characters]
MAX_MESSAGE = 600
#: what an error about a file as a whole starts with (after the path): it has no place to point at
WHOLE_FILE = ("not an autopilot log", "a gzip file that cannot be decompressed", "the gzip file holds nothing",
              "the file is empty")
#: the names an error's column may start with: the messages and topics the readers read, and FMT
LOCATIONS = frozenset({*WANTED, *TOPICS, "FMT"})
#: cases per seed: (group, seed name, number of cases, random seed)
PLAN = (("dataflash-bin", "4x.bin", 120, 11), ("dataflash-bin", "3x.bin", 100, 12),
        ("dataflash-bin", "log171.bin", 50, 13),
        ("dataflash-text", "4x.log", 80, 21), ("dataflash-text", "3x.log", 70, 22),
        ("ulog", "new.ulg", 100, 31), ("ulog", "old.ulg", 90, 32), ("ulog", "hover.ulg", 60, 33),
        ("ulog", "ground.ulg", 20, 34),
        ("gzip", "3x.bin", 30, 41), ("gzip", "3x.log", 25, 42), ("gzip", "hover.ulg", 25, 43),
        ("gzip", "new.ulg", 20, 44))
GROUPS = ("dataflash-bin", "dataflash-text", "ulog", "gzip")
#: cases of each seed that go through ``georef info``
CLI_CASES = 3

#: what a float field is set to: not numbers, and the largest float32
FLOAT_EXTREMES = (float("nan"), float("inf"), float("-inf"), 3.4e38)
RUNNER = CliRunner()


# --- byte-level mutations, any format ------------------------------------------------------------------------------

def _byte_op(data: bytes, rng: random.Random, kind: str, head_end: int) -> bytes:
    """``data`` after the byte-level mutation ``kind``; ``head_end``: where the definitions end [byte]."""
    n = len(data)
    head = max(2, min(head_end, n))
    if kind == "truncate":
        return data[:rng.randrange(n)]
    if kind == "truncate_head":
        return data[:rng.randrange(head)]
    if kind == "flip":
        out = bytearray(data)
        for _ in range(rng.randint(1, 16)):
            out[rng.randrange(n)] ^= rng.randrange(1, 256)
        return bytes(out)
    if kind == "flip_head":
        out = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(head)] ^= rng.randrange(1, 256)
        return bytes(out)
    if kind == "insert_run":
        at = rng.randrange(n + 1)
        return data[:at] + rng.randbytes(rng.choice((1, 2, 7, 64, 300, 5000))) + data[at:]
    if kind == "delete_run":
        at = rng.randrange(n)
        return data[:at] + data[at + rng.choice((1, 2, 3, 50, 700, 20_000)):]
    if kind == "duplicate_chunk":
        start, at = rng.randrange(n), rng.randrange(n)
        return data[:at] + data[start:start + rng.choice((10, 200, 4000, 60_000))] + data[at:]
    if kind == "erased_run":
        at, size = rng.randrange(n), rng.choice((16, 512, 4096))
        return data[:at] + rng.choice((b"\x00", b"\xff")) * size + data[at + size:]
    raise AssertionError(kind)


BYTE_KINDS = ("truncate", "truncate_head", "flip", "flip_head", "insert_run", "delete_run", "duplicate_chunk",
              "erased_run")


# --- DataFlash binary -----------------------------------------------------------------------------------------------

#: DataFlash format character -> bytes (ArduPilot's LogStructure.h)
DF_SIZES = {"a": 64, "b": 1, "B": 1, "h": 2, "H": 2, "i": 4, "I": 4, "f": 4, "d": 8, "n": 4, "N": 16, "Z": 64,
            "c": 2, "C": 2, "e": 4, "E": 4, "L": 4, "M": 1, "q": 8, "Q": 8, "g": 2}
DF_STRUCT = {"b": "<b", "B": "<B", "h": "<h", "H": "<H", "i": "<i", "I": "<I", "f": "<f", "d": "<d", "c": "<h",
             "C": "<H", "e": "<i", "E": "<I", "L": "<i", "M": "<B", "q": "<q", "Q": "<Q", "g": "<e"}
FMT_ID = 128


@dataclass(frozen=True)
class DfFormat:
    """A message type of a DataFlash log as its FMT message (chunk ``index``) defines it."""

    index: int
    type_id: int
    length: int
    name: str
    format: str
    columns: tuple[str, ...]

    def field(self, name: str) -> tuple[int, str] | None:
        """(offset in the message [byte], format character) of a field, or None."""
        offset = 3
        for column, char in zip(self.columns, self.format, strict=False):
            if column == name:
                return offset, char
            offset += DF_SIZES.get(char, 0)
        return None


@dataclass
class DfLog:
    """A binary DataFlash log as its messages (garbage runs are chunks of type -1), to mutate message by message."""

    chunks: list[bytes]
    types: list[int]
    formats: dict[str, DfFormat]            # by name
    head_end: int                           # the end of the leading FMT, PARM and MSG messages [byte]
    by_type: dict[int, list[int]]            # type id -> its messages (the seed's; shared by the copies)

    def indices(self, name: str) -> list[int]:
        """The messages of type ``name`` that no mutation removed."""
        fmt = self.formats.get(name)
        return [] if fmt is None else [k for k in self.by_type.get(fmt.type_id, []) if self.chunks[k]]

    def copy(self) -> DfLog:
        return dataclasses.replace(self, chunks=list(self.chunks))

    def render(self) -> bytes:
        return b"".join(self.chunks)


def _parse_dataflash(data: bytes) -> DfLog:
    """The messages of a binary DataFlash log, walked as pymavlink's DFReader walks them."""
    lengths = {FMT_ID: 89}
    chunks: list[bytes] = []
    types: list[int] = []
    formats: dict[str, DfFormat] = {}
    pos = garbage = 0
    while pos + 3 <= len(data):
        kind = data[pos + 2]
        if data[pos] == 0xA3 and data[pos + 1] == 0x95 and kind in lengths and pos + lengths[kind] <= len(data):
            if garbage < pos:
                chunks.append(data[garbage:pos])
                types.append(-1)
            body = data[pos:pos + lengths[kind]]
            if kind == FMT_ID:
                name = body[5:9].rstrip(b"\x00").decode("latin-1")
                columns = tuple(body[25:89].rstrip(b"\x00").decode("latin-1").split(","))
                formats[name] = DfFormat(len(chunks), body[3], body[4], name,
                                         body[9:25].rstrip(b"\x00").decode("latin-1"), columns)
                lengths[body[3]] = body[4]
            chunks.append(body)
            types.append(kind)
            pos += len(body)
            garbage = pos
        else:
            pos += 1
    chunks.append(data[garbage:])
    types.append(-1)
    first_data = next(k for k, t in enumerate(types) if t not in (FMT_ID, formats["PARM"].type_id,
                                                                  formats["MSG"].type_id))
    by_type: dict[int, list[int]] = {}
    for k, t in enumerate(types):
        by_type.setdefault(t, []).append(k)
    return DfLog(chunks, types, formats, sum(len(c) for c in chunks[:first_data]), by_type)


def _df_set(log: DfLog, index: int, name: str, column: str, value: float) -> bool:
    """Write ``value`` into field ``column`` of message ``index`` (type ``name``); False when it has no such field."""
    where = log.formats[name].field(column)
    if where is None or where[1] not in DF_STRUCT:
        return False
    offset, char = where
    code = DF_STRUCT[char]
    if char == "g" and abs(value) > 65504.0:                # beyond float16: its infinity
        value = float("inf") if value > 0 else float("-inf")
    elif char not in "fdg":
        bits = 8 * struct.calcsize(code)
        low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code[1].islower() else (0, (1 << bits) - 1)
        value = int(min(max(value, low), high))
    body = bytearray(log.chunks[index])
    if len(body) < offset + struct.calcsize(code):
        return False
    struct.pack_into(code, body, offset, value)
    log.chunks[index] = bytes(body)
    return True


def _df_get(log: DfLog, index: int, name: str, column: str) -> float | None:
    """Field ``column`` of message ``index`` (type ``name``), or None when it has none (or was cut)."""
    where = log.formats[name].field(column)
    if where is None or where[1] not in DF_STRUCT:
        return None
    code = DF_STRUCT[where[1]]
    if len(log.chunks[index]) < where[0] + struct.calcsize(code):
        return None
    return float(struct.unpack_from(code, log.chunks[index], where[0])[0])


def _some(rng: random.Random, items: list[int]) -> list[int]:
    """One, a run of, or every one of ``items``."""
    if not items:
        return []
    choice = rng.random()
    if choice < 0.35:
        return [rng.choice(items)]
    if choice < 0.7:
        start = rng.randrange(len(items))
        return items[start:start + rng.randint(2, 40)]
    return list(items)


def _df_time_field(log: DfLog, name: str) -> str:
    """The boot-time field of messages ``name``: TimeUS (4.x) or TimeMS (3.x)."""
    return "TimeUS" if log.formats[name].field("TimeUS") else "TimeMS"


def _df_op(log: DfLog, rng: random.Random, kind: str) -> None:
    """Apply the message-level mutation ``kind`` to ``log``."""
    present = [name for name in ("IMU", "GPS", "GPA", "ATT", "MAG", "PARM", "CAM", "TRIG", "UBX3", "AHR2", "MSG")
               if name in log.formats and log.indices(name)]
    if not present:                                         # an earlier mutation removed every message
        return
    name = rng.choice(present[:2] if rng.random() < 0.5 else present)
    fmt = log.formats[name]
    if kind.startswith("fmt_"):
        body = bytearray(log.chunks[fmt.index])
        if not body:                                        # removed by an earlier mutation
            return
        if kind == "fmt_length":
            body[4] = rng.choice((0, 1, 3, 4, fmt.length - 1, fmt.length + 1, 255, rng.randrange(256))) % 256
        elif kind == "fmt_format":
            k = rng.randrange(len(fmt.format))
            text = bytearray(fmt.format.encode())
            text[k] = ord(rng.choice("fdQBIhLZNnax?\x00"))
            body[9:25] = bytes(text).ljust(16, b"\x00")[:16]
        elif kind == "fmt_name":
            new = rng.choice((b"GPS", b"IMU", b"PARM", b"GP\xd3", b"", b"\xff\xff\xff\xff", name.lower().encode()))
            body[5:9] = new.ljust(4, b"\x00")
        elif kind == "fmt_columns":
            columns = list(fmt.columns)
            k = rng.randrange(len(columns))
            how = rng.randrange(5)
            if how == 0:
                columns[k] = columns[k][:-1] + "x"          # a field renamed: Lat -> Lax
            elif how == 1:
                columns[k] = columns[(k + 1) % len(columns)]  # a name twice
            elif how == 2:
                del columns[k]                               # one name short
            elif how == 3:
                columns[k] = ""
            else:
                columns = ["\xe9\x00\x01"]
            body[25:89] = ",".join(columns).encode("latin-1").ljust(64, b"\x00")[:64]
        elif kind == "fmt_type":
            others = [f.type_id for f in log.formats.values()]
            body[3] = rng.choice((*others, FMT_ID, 0, 255))
        elif kind == "fmt_of_fmt" and rng.random() < 0.5:
            # FMT's own FMT damaged
            body = bytearray(log.chunks[log.formats["FMT"].index] or bytes(89))
            body[rng.choice((3, 4))] = rng.choice((0, 3, 50, 88, 90, 255))
            log.chunks[log.formats["FMT"].index] = bytes(body)
            return
        elif kind == "fmt_of_fmt":
            # another FMT redefines FMT's length, and the log ends among the definitions after it
            body[3] = FMT_ID
            cut = min(fmt.index + rng.randint(1, 3), len(log.chunks) - 1)
            log.chunks[cut] = log.chunks[cut][:rng.randrange(1, 89)]
            log.chunks[cut + 1:] = [b""] * (len(log.chunks) - cut - 1)
        log.chunks[fmt.index] = bytes(body)
    elif kind == "drop_type":
        for k in log.indices(rng.choice(("IMU", "GPS", "PARM", name))):
            log.chunks[k] = b""
    elif kind == "drop_fmt":
        log.chunks[fmt.index] = b""
    elif kind == "nonfinite":
        floats = [c for c, ch in zip(fmt.columns, fmt.format, strict=False) if ch in "fdg"]
        floats = floats or [c for n in ("IMU", "GPS") for c, ch in zip(log.formats[n].columns, log.formats[n].format,
                                                                         strict=False) if ch in "fdg"]
        column = rng.choice(floats)
        owner = name if column in fmt.columns else ("IMU" if column in log.formats["IMU"].columns else "GPS")
        value = rng.choice(FLOAT_EXTREMES)
        for k in _some(rng, log.indices(owner)):
            _df_set(log, k, owner, column, value)
    elif kind == "absurd":
        column, value = rng.choice((("Lat", 1e9), ("Lng", -2e9), ("Lat", 0), ("Alt", 2e9), ("Status", 255),
                                    ("I", 7), ("HAcc", 0), ("Img", 65535), ("GWk", 65535), ("NSats", 0)))
        owners = [n for n in ("GPS", "IMU", "GPA", "CAM", "TRIG") if n in log.formats
                  and log.formats[n].field(column)]
        if owners:
            owner = rng.choice(owners)
            for k in _some(rng, log.indices(owner)):
                _df_set(log, k, owner, column, value)
    elif kind in ("time_backwards", "time_jump"):
        owner = rng.choice(("IMU", "GPS", name))
        column = _df_time_field(log, owner)
        rows = log.indices(owner)
        if len(rows) > 3:
            at = rng.randrange(1, len(rows))
            if kind == "time_backwards":
                back = rows[max(0, at - rng.choice((1, 2, 50, 10_000)))]
                for k in rows[at:at + rng.choice((1, 3, 100))]:
                    _df_set(log, k, owner, column, rng.choice((_df_get(log, back, owner, column) or 0.0, 0.0)))
            else:
                jump = rng.choice((3.6e9, 1e15, 2.0**63, -1e6)) / (1.0 if column == "TimeUS" else 1e3)
                for k in rows[at:]:
                    _df_set(log, k, owner, column, (_df_get(log, k, owner, column) or 0.0) + jump)
    elif kind == "gps_week":
        column = "GWk" if log.formats["GPS"].field("GWk") else "Week"
        value = rng.choice((0, 1, 65535, rng.randrange(65536)))
        for k in _some(rng, log.indices("GPS")):
            _df_set(log, k, "GPS", column, value)
    elif kind == "fixes_invalid":
        rows = log.indices("GPS")
        keep = rng.choice((0, 1, 2))
        for k in rows[:len(rows) - keep] if rng.random() < 0.5 else rows[keep:]:
            _df_set(log, k, "GPS", "Status", rng.choice((0, 1, 2)))
    elif kind == "duplicate_messages":
        at = rng.randrange(len(log.chunks))
        run = rng.choice((1, 5, 200))
        log.chunks[at] = b"".join(log.chunks[at:at + run]) + log.chunks[at]
    elif kind == "swap_messages":
        for _ in range(rng.choice((1, 10, 100))):
            k = rng.randrange(len(log.chunks) - 1)
            log.chunks[k], log.chunks[k + 1] = log.chunks[k + 1], log.chunks[k]
    else:
        raise AssertionError(kind)


DF_KINDS = ("fmt_length", "fmt_format", "fmt_name", "fmt_columns", "fmt_type", "fmt_of_fmt", "drop_type", "drop_fmt",
            "nonfinite", "absurd", "time_backwards", "time_jump", "gps_week", "fixes_invalid", "duplicate_messages",
            "swap_messages")


# --- DataFlash text ------------------------------------------------------------------------------------------------

@dataclass
class TextLog:
    """A text DataFlash log as its lines (bytes, None: deleted), to mutate line by line."""

    lines: list[bytes | None]
    formats: dict[str, tuple[int, list[str]]]    # name -> (FMT line index, field names)
    head_end: int
    newline: bytes = b"\n"

    def indices(self, name: str) -> list[int]:
        prefix = name.encode() + b","
        return [k for k, line in enumerate(self.lines) if line is not None and line.startswith(prefix)]

    def copy(self) -> TextLog:
        return dataclasses.replace(self, lines=list(self.lines))

    def render(self) -> bytes:
        return self.newline.join(line for line in self.lines if line is not None) + self.newline


def _parse_text(data: bytes, keep: float) -> TextLog:
    """A text DataFlash log cut to the first ``keep`` of its lines."""
    lines: list[bytes | None] = list(data.split(b"\n"))
    lines = lines[:int(len(lines) * keep)]
    formats = {}
    for k, line in enumerate(lines):
        if line is not None and line.startswith(b"FMT,"):
            parts = [p.strip().decode() for p in line.split(b",")]
            formats[parts[3]] = (k, parts[5:])
    first_data = next(k for k, line in enumerate(lines) if line is not None and not line.startswith((b"FMT", b"PARM",
                                                                                                    b"MSG")))
    return TextLog(lines, formats, sum(len(line or b"") + 1 for line in lines[:first_data]))


def _text_cells(log: TextLog, k: int) -> list[bytes]:
    """The comma-separated fields of line ``k`` (the first is the message's name)."""
    return (log.lines[k] or b"").split(b",")


def _text_set(log: TextLog, rows: list[int], name: str, column: str, value: Callable[[bytes], bytes]) -> None:
    """Replace field ``column`` of lines ``rows`` (messages ``name``) by ``value(old)``."""
    fields = log.formats.get(name, (0, []))[1]
    if column not in fields:
        return
    j = 1 + fields.index(column)
    for k in rows:
        cells = _text_cells(log, k)
        if j < len(cells):
            cells[j] = b" " + value(cells[j].strip())
            log.lines[k] = b",".join(cells)


def _shifted(text: bytes, jump: float) -> bytes:
    """A text field plus ``jump`` (itself when an earlier mutation made it no number)."""
    try:
        return repr(float(text) + jump).encode()
    except ValueError:
        return text


def _text_op(log: TextLog, rng: random.Random, kind: str) -> None:
    """Apply the line-level mutation ``kind`` to ``log``."""
    live = [k for k, line in enumerate(log.lines) if line]
    k = rng.choice(live)
    cells = _text_cells(log, k)
    j = rng.randrange(1, max(2, len(cells)))
    name = rng.choice(("IMU", "GPS", "GPS", "PARM", "ATT", "MAG", "CAM", "GPA"))
    if kind == "cut_line":
        log.lines[k] = log.lines[k][:rng.randrange(len(log.lines[k]))]
    elif kind == "drop_field":
        del cells[j]
        log.lines[k] = b",".join(cells)
    elif kind == "extra_field":
        cells.insert(j, b" 1")
        log.lines[k] = b",".join(cells)
    elif kind in ("non_numeric", "nonfinite", "huge_field"):
        pool = {"non_numeric": (b"abc", b"", b"0x1F", b"1.2.3", b"--5", b"\xd9\xa3"),
                "nonfinite": (b"nan", b"inf", b"-inf", b"1e999", b"NaN"),
                "huge_field": (b"7" * 100_000, b"x" * 100_000, b"1" + b"0" * 400)}[kind]
        rows = _some(rng, log.indices(name)) if rng.random() < 0.6 else [k]
        rows = rows[:3] if kind == "huge_field" else rows     # a few 100 kB lines, not hundreds of MB
        column = rng.choice(log.formats.get(name, (0, ["TimeUS"]))[1])
        if rows == [k]:
            cells[j] = b" " + rng.choice(pool)
            log.lines[k] = b",".join(cells)
        else:
            value = rng.choice(pool)
            _text_set(log, rows, name, column, lambda _: value)
    elif kind == "bad_bytes":
        line = log.lines[k]
        at = rng.randrange(len(line) + 1)
        log.lines[k] = line[:at] + rng.choice((b"\xff\xfe", b"\x00", b"\xc3", b"\xe2\x82", b"\x1b[2J")) + line[at:]
    elif kind == "fmt_line":
        index, _ = log.formats[rng.choice(("IMU", "GPS", "PARM", name if name in log.formats else "GPS"))]
        parts = (log.lines[index] or b"").split(b",")
        parts += [b""] * (5 - len(parts))
        how = rng.randrange(5)
        if how == 0:
            del parts[-1]                                   # one field name short
        elif how == 1:
            parts[1] = b" x"                                # the type is not a number
        elif how == 2:
            parts[4] = parts[4][:-1] + b"?"                 # an unknown format character
        elif how == 3:
            parts = parts[:3]                               # cut
        else:
            parts.append(b"Extra")                          # a field name too many
        log.lines[index] = b",".join(parts)
    elif kind == "drop_type":
        for row in log.indices(rng.choice(("IMU", "GPS", "PARM", name))):
            log.lines[row] = None
    elif kind in ("time_backwards", "time_jump"):
        owner = rng.choice(("IMU", "GPS"))
        column = "TimeUS" if "TimeUS" in log.formats[owner][1] else "TimeMS"
        rows = log.indices(owner)
        if len(rows) < 3:
            return
        at = rng.randrange(1, len(rows))
        if kind == "time_backwards":
            back = (_text_cells(log, rows[max(0, at - rng.choice((1, 2, 50, 2000)))]) + [b""])[1].strip()
            _text_set(log, rows[at:at + rng.choice((1, 3, 100))], owner, column, lambda _: back)
        else:
            jump = rng.choice((3.6e9, 1e15, 2.0**63, -1e6, 1e300))
            _text_set(log, rows[at:], owner, column, lambda old: _shifted(old, jump))
    elif kind == "gps_week":
        column = "GWk" if "GWk" in log.formats["GPS"][1] else "Week"
        value = rng.choice((b"0", b"65535", b"70000", b"-1", b"1.5"))
        _text_set(log, _some(rng, log.indices("GPS")), "GPS", column, lambda _: value)
    elif kind == "fixes_invalid":
        rows = log.indices("GPS")
        _text_set(log, rows[rng.choice((0, 1, 2)):], "GPS", "Status", lambda _: rng.choice((b"0", b"1", b"2")))
    elif kind == "absurd":
        column, value = rng.choice((("Lat", b"91.5"), ("Lng", b"-400"), ("Lat", b"0"), ("Alt", b"1e9"),
                                    ("Status", b"255"), ("Status", b"3.5"), ("I", b"7"), ("I", b"-1"),
                                    ("Img", b"1e12")))
        for owner in ("GPS", "IMU", "CAM"):
            _text_set(log, _some(rng, log.indices(owner)), owner, column, lambda _: value)
    elif kind == "crlf":
        log.newline = b"\r\n"
    elif kind == "blank_lines":
        log.lines[k] = log.lines[k] + b"\n" + rng.choice((b"", b"   ", b",,,"))
    elif kind == "duplicate_lines":
        log.lines[k] = b"\n".join([log.lines[k]] * rng.choice((2, 3)))
    elif kind == "swap_lines" and k + 1 < len(log.lines):
        log.lines[k], log.lines[k + 1] = log.lines[k + 1], log.lines[k]
    elif kind == "delete_lines":
        for row in range(k, min(len(log.lines), k + rng.choice((1, 10, 500)))):
            log.lines[row] = None


TEXT_KINDS = ("cut_line", "drop_field", "extra_field", "non_numeric", "nonfinite", "huge_field", "bad_bytes",
              "fmt_line", "drop_type", "time_backwards", "time_jump", "gps_week", "fixes_invalid", "absurd", "crlf",
              "blank_lines", "duplicate_lines", "swap_lines", "delete_lines")


# --- ULog ----------------------------------------------------------------------------------------------------------

#: ULog type name -> (struct code, bytes)
ULOG_TYPES = {"int8_t": ("<b", 1), "uint8_t": ("<B", 1), "bool": ("<B", 1), "char": ("<c", 1), "int16_t": ("<h", 2),
              "uint16_t": ("<H", 2), "int32_t": ("<i", 4), "uint32_t": ("<I", 4), "int64_t": ("<q", 8),
              "uint64_t": ("<Q", 8), "float": ("<f", 4), "double": ("<d", 8)}
#: the topics the mutations aim at
ULOG_AIMS = ("sensor_combined", "vehicle_gps_position", "vehicle_imu", "vehicle_attitude", "sensor_gps")


@dataclass
class ULogFile:
    """A ULog as its 16-byte header and messages (each with its 3-byte header), to mutate message by message."""

    header: bytes
    chunks: list[bytes]
    kinds: list[str]                                      # message type: "F", "A", "D", ...
    topics: list[str | None]                              # the topic of a D or A message
    fields: dict[str, dict[str, tuple[int, str]]]         # topic -> field -> (offset in a D message, type)
    head_end: int
    by_kind: dict[tuple[str, str | None], list[int]]    # (type, topic or None) -> its messages (the seed's)

    def indices(self, kind: str, topic: str | None = None) -> list[int]:
        """The messages of type ``kind`` (of ``topic``) that no mutation removed or cut below a header."""
        return [k for k in self.by_kind.get((kind, topic), []) if len(self.chunks[k]) >= 3]

    def copy(self) -> ULogFile:
        return dataclasses.replace(self, chunks=list(self.chunks))

    def render(self) -> bytes:
        return self.header + b"".join(self.chunks)


def _ulog_fields(definitions: dict[str, str]) -> dict[str, dict[str, tuple[int, str]]]:
    """Topic -> field name -> (offset in a D message [byte], type) of the formats whose types are all simple
    (nested formats are left out)."""
    out: dict[str, dict[str, tuple[int, str]]] = {}
    for topic, text in definitions.items():
        offset, fields = 3 + 2, {}
        for item in filter(None, text.split(";")):
            kind, _, name = item.partition(" ")
            base, _, count = kind.partition("[")
            if base not in ULOG_TYPES:
                break
            n = int(count.rstrip("]")) if count else 1
            for k in range(n):
                fields[f"{name}[{k}]" if count else name] = (offset + k * ULOG_TYPES[base][1], base)
            offset += n * ULOG_TYPES[base][1]
        else:
            out[topic] = fields
    return out


def _parse_ulog(data: bytes) -> ULogFile:
    """The messages of a ULog, with the field offsets of the topics whose formats are simple."""
    chunks, kinds, topics = [], [], []
    definitions: dict[str, str] = {}
    ids: dict[int, str] = {}
    pos, head_end = 16, 0
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        body = data[pos:pos + 3 + size]
        letter = chr(kind)
        topic = None
        if letter == "F":
            name, _, text = body[3:].decode("latin-1").partition(":")
            definitions[name] = text
        elif letter == "A":
            topic = body[6:].decode("latin-1")
            ids[struct.unpack_from("<H", body, 4)[0]] = topic
        elif letter == "D":
            topic = ids.get(struct.unpack_from("<H", body, 3)[0])
            head_end = head_end or pos
        chunks.append(body)
        kinds.append(letter)
        topics.append(topic)
        pos += len(body)
    by_kind: dict[tuple[str, str | None], list[int]] = {}
    for k, (letter, topic) in enumerate(zip(kinds, topics, strict=True)):
        by_kind.setdefault((letter, None), []).append(k)
        if topic is not None:
            by_kind.setdefault((letter, topic), []).append(k)
    return ULogFile(data[:16], chunks, kinds, topics, _ulog_fields(definitions), head_end, by_kind)


def _ulog_set(log: ULogFile, rows: list[int], topic: str, name: str, value: Callable[[float], float]) -> None:
    """Replace field ``name`` of the D messages ``rows`` of ``topic`` by ``value(old)``."""
    where = log.fields.get(topic, {}).get(name)
    if where is None or where[1] == "char":
        return
    offset, kind = where
    code, size = ULOG_TYPES[kind]
    for k in rows:
        body = bytearray(log.chunks[k])
        if len(body) < offset + size:
            continue
        new = value(float(struct.unpack_from(code, body, offset)[0]))
        if kind not in ("float", "double"):
            bits = 8 * size
            low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code[1].islower() else (0, (1 << bits) - 1)
            new = int(min(max(new, low), high)) if np.isfinite(new) else 0
        struct.pack_into(code, body, offset, new)
        log.chunks[k] = bytes(body)


def _with_payload(chunk: bytes, payload: bytes) -> bytes:
    """A message with ``payload`` in place of its own, its size field to match."""
    return struct.pack("<HB", len(payload) & 0xFFFF, chunk[2]) + payload


def _ulog_gps(log: ULogFile) -> str:
    """The GNSS topic of the log."""
    return "vehicle_gps_position" if log.indices("D", "vehicle_gps_position") else "sensor_gps"


def _ulog_imu(log: ULogFile) -> str:
    """The IMU topic of the log."""
    return "sensor_combined" if log.indices("D", "sensor_combined") else "vehicle_imu"


def _ulog_op(log: ULogFile, rng: random.Random, kind: str) -> None:
    """Apply the message-level mutation ``kind`` to ``log``."""
    gps, imu = _ulog_gps(log), _ulog_imu(log)
    topic = rng.choice((gps, imu, gps, "vehicle_attitude"))
    chunks = [k for k, chunk in enumerate(log.chunks) if len(chunk) >= 3]
    if kind == "header":
        body = bytearray(log.header)
        body[rng.choice((rng.randrange(7), 7, rng.randrange(8, 16)))] ^= rng.randrange(1, 256)
        log.header = bytes(body)
    elif kind == "msg_size":
        k = rng.choice(chunks if rng.random() < 0.5 else log.indices("F") + log.indices("A") or chunks)
        size = struct.unpack_from("<H", log.chunks[k])[0]
        new = rng.choice((0, 1, 2, size - 1, size + 1, 0xFFFF, rng.randrange(0x10000))) & 0xFFFF
        log.chunks[k] = struct.pack("<H", new) + log.chunks[k][2:]
    elif kind == "msg_type":
        k = rng.choice(chunks if rng.random() < 0.5 else log.indices("F") + log.indices("A") or chunks)
        letter = rng.choice((b"F", b"A", b"D", b"I", b"P", b"B", b"Q", b"\x00", b"z"))
        log.chunks[k] = log.chunks[k][:2] + letter + log.chunks[k][3:]
    elif kind == "format":
        defs = [k for k in log.indices("F") if log.chunks[k][3:].split(b":")[0].decode("latin-1") in ULOG_AIMS]
        if not log.indices("F"):
            return
        k = rng.choice(defs if defs and rng.random() < 0.8 else log.indices("F"))
        name, _, text = log.chunks[k][3:].partition(b":")
        items = text.split(b";")
        j = rng.randrange(max(1, len(items) - 1))
        how = rng.randrange(8)
        if how == 0:
            items[j] = items[j][:-1] + b"x"                                   # a field renamed
        elif how == 1:
            items[j] = re.sub(rb"^\w+", rng.choice((b"double", b"char", b"uint8_t", b"floatx", b"")), items[j])
        elif how == 2:
            items[j] = re.sub(rb"\[\d+\]|(?= )", b"[" + rng.choice((b"0", b"2", b"300", b"-1", b"x")) + b"]",
                              items[j], count=1)
        elif how == 3:
            del items[j]
        elif how == 4:
            items.insert(j, items[j])
        elif how == 5:
            name = rng.choice((b"sensor_combined", b"vehicle_gps_position", name[:-1], b""))
        elif how == 6:
            items = items[:rng.randrange(len(items))]
        else:
            items[j] = items[j].replace(b" ", b"")
        log.chunks[k] = _with_payload(log.chunks[k], name + b":" + b";".join(items))
    elif kind == "info":
        rows = log.indices("I") + log.indices("M")
        if rows:
            k = rng.choice(rows)
            body = bytearray(log.chunks[k])
            key_at = 3 if log.kinds[k] == "I" else 4
            how = rng.randrange(3)
            if how == 0:
                body[key_at] = rng.choice((0, 255, (body[key_at] + 1) % 256))
            elif how == 1:
                body[key_at + 1:key_at + 1 + body[key_at]] = re.sub(rb"\[\d+\]", b"[9999]",
                                                                    bytes(body[key_at + 1:key_at + 1 + body[key_at]]))
            else:
                body = body[:rng.randrange(3, len(body) + 1)]
            log.chunks[k] = _with_payload(bytes(body[:3]), bytes(body[3:]))
    elif kind == "drop_params":
        for k in log.indices("P") + log.indices("Q"):
            log.chunks[k] = b""
    elif kind == "param":
        rows = log.indices("P")
        if rows:
            k = rng.choice(rows)
            body = bytearray(log.chunks[k])
            key = bytes(body[4:4 + body[3]])
            how = rng.randrange(4)
            if how == 0:
                key = key.replace(b"float", b"char[4]").replace(b"int32_t", b"char[4]")
            elif how == 1:
                key = key.replace(b"float", b"int32_t") if b"float" in key else key.replace(b"int32_t", b"float")
            elif how == 2:
                key = key.split(b" ")[0] + b" " + rng.randbytes(6)
            value = bytes(body[4 + body[3]:])
            if how == 3:
                value = struct.pack("<f", rng.choice(FLOAT_EXTREMES))
            log.chunks[k] = _with_payload(log.chunks[k], bytes([len(key) & 0xFF]) + key + value)
    elif kind == "subscription" and log.indices("A"):
        k = rng.choice(log.indices("A"))
        body = bytearray(log.chunks[k])
        how = rng.randrange(4)
        if how == 0:
            body[4:6] = struct.pack("<H", rng.choice((0, 1, 2, 0xFFFF)))
        elif how == 1:
            body[3] = rng.choice((1, 5, 255))
        elif how == 2:
            body = body[:6] + rng.choice((b"sensor_combined", b"vehicle_gps_position", b"nothing", b"\xff"))
        else:
            body = b""
        log.chunks[k] = _with_payload(bytes(body[:3]), bytes(body[3:])) if body else b""
    elif kind == "drop_topic":
        for k in log.indices("D", rng.choice((gps, imu, topic))):
            log.chunks[k] = b""
    elif kind == "nonfinite":
        floats = [n for n, (_, t) in log.fields.get(topic, {}).items() if t in ("float", "double")]
        if floats:
            value = rng.choice(FLOAT_EXTREMES)
            _ulog_set(log, _some(rng, log.indices("D", topic)), topic, rng.choice(floats), lambda _: value)
    elif kind == "absurd":
        name, value = rng.choice((("lat", 2.0**31 - 1), ("lon", -(2.0**31)), ("latitude_deg", 91.0),
                                  ("longitude_deg", 0.0), ("alt_ellipsoid", 2.0**31 - 1), ("eph", 0.0),
                                  ("eph", -1.0), ("fix_type", 255.0), ("altitude_ellipsoid_m", 1e12),
                                  ("gyro_integral_dt", 2.0**32 - 1), ("delta_angle_dt", 0.0)))
        for owner in (gps, imu):
            _ulog_set(log, _some(rng, log.indices("D", owner)), owner, name, lambda _: value)
    elif kind in ("time_backwards", "time_jump"):
        owner = rng.choice((gps, imu))
        rows = log.indices("D", owner)
        if len(rows) > 3:
            at = rng.randrange(1, len(rows))
            if kind == "time_backwards":
                back = log.chunks[rows[max(0, at - rng.choice((1, 2, 50, 5000)))]]
                new = rng.choice((float(struct.unpack_from("<Q", back, 5)[0]) if len(back) >= 13 else 0.0, 0.0))
                _ulog_set(log, rows[at:at + rng.choice((1, 3, 100))], owner, "timestamp", lambda _: new)
            else:
                jump = rng.choice((3.6e9, 1e15, 2.0**63, -1e6))
                _ulog_set(log, rows[at:], owner, "timestamp", lambda old: old + jump)
    elif kind == "gps_time":
        change = rng.choice((lambda _: 0.0, lambda _: 2.0**63, lambda _: 2.0**64 - 1, lambda old: old + 86400e6,
                             lambda old: old - 1e6 * rng.randrange(1, 100), lambda _: 1e6))
        _ulog_set(log, _some(rng, log.indices("D", gps)), gps, "time_utc_usec", change)
        _ulog_set(log, _some(rng, log.indices("D", gps)), gps, "timestamp_sample", rng.choice((change, lambda x: x)))
    elif kind == "fixes_invalid":
        rows = log.indices("D", gps)
        value = float(rng.choice((0, 1, 2)))
        _ulog_set(log, rows[rng.choice((0, 1, 2)):], gps, "fix_type", lambda _: value)
    elif kind == "dropout":
        for _ in range(rng.choice((1, 5, 50))):
            k = rng.randrange(len(log.chunks))
            log.chunks[k] = struct.pack("<HBH", 2, ord("O"), rng.choice((0, 10, 0xFFFF))) + log.chunks[k]
    elif kind == "sync":
        sync = bytes([0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12])
        for _ in range(rng.choice((1, 5))):
            k = rng.randrange(len(log.chunks))
            piece = rng.choice((struct.pack("<HB", 8, ord("S")) + sync, sync))
            log.chunks[k] = piece + log.chunks[k]
    elif kind == "subscription":
        return
    elif kind == "flag_bits":
        rows = log.indices("B")
        if rows:
            body = bytearray(log.chunks[rows[0]])
            how = rng.randrange(3)
            if how == 0:
                body[3 + 8 + rng.randrange(8)] = rng.choice((1, 2, 0x80))             # an incompatible flag
            elif how == 1:
                body[3 + 8] = 1                                                       # "data appended" ...
                offset = rng.choice((0, 17, len(log.render()) // 2, 2**40, 2**64 - 1))
                body[3 + 16:3 + 24] = struct.pack("<Q", offset)                       # ... at this offset
            else:
                body = body[:rng.randrange(3, len(body))]
                body = bytearray(_with_payload(bytes(body[:3]), bytes(body[3:])))
            log.chunks[rows[0]] = bytes(body)
    else:
        raise AssertionError(kind)


ULOG_KINDS = ("header", "msg_size", "msg_type", "format", "info", "drop_params", "param", "subscription",
              "drop_topic", "nonfinite", "absurd", "time_backwards", "time_jump", "gps_time", "fixes_invalid",
              "dropout", "sync", "flag_bits")


# --- gzip ----------------------------------------------------------------------------------------------------------

def _gzip(data: bytes) -> bytes:
    """``data`` gzipped, fast and reproducibly (no time stamp)."""
    return gzip.compress(data, compresslevel=1, mtime=0)


def _gzip_op(data: bytes, mutated: Callable[[], bytes], rng: random.Random, kind: str) -> bytes:
    """A gzip file of ``data`` (``mutated()``: the log after one of its own format's mutations) damaged by
    ``kind``."""
    packed = _gzip(data)
    if kind == "gz_truncated":
        return packed[:rng.randrange(2, len(packed))]
    if kind in ("gz_crc", "gz_isize"):
        out = bytearray(packed)
        out[-8 + rng.randrange(4) + (4 if kind == "gz_isize" else 0)] ^= rng.randrange(1, 256)
        return bytes(out)
    if kind == "gz_flip":
        out = bytearray(packed)
        out[rng.randrange(10, len(out) - 8)] ^= 1 << rng.randrange(8)
        return bytes(out)
    if kind == "gz_header":
        out = bytearray(packed)
        out[rng.choice((2, 3, 3, 8, 9))] = rng.choice((0, 0x04, 0x08, 0x1F, 0xFF))
        return bytes(out)
    if kind == "gz_trailing":
        return packed + rng.choice((b"\x00" * 512, rng.randbytes(100), packed[:30]))
    if kind == "gz_concat":
        cut = rng.randrange(len(data))
        return _gzip(data[:cut]) + _gzip(data[cut:])
    if kind == "gz_of_mutated":
        return _gzip(mutated())
    if kind == "gz_garbage":
        return _gzip(rng.choice((rng.randbytes(rng.choice((1, 100, 50_000))), b"time\tlat\tlon\n1\t2\t3\n",
                                 data[:rng.randrange(1, 200)])))
    if kind == "gz_empty":
        return _gzip(b"")
    if kind == "gz_double":
        return _gzip(rng.choice((packed, _gzip(mutated()))))
    raise AssertionError(kind)


GZIP_KINDS = ("gz_truncated", "gz_crc", "gz_isize", "gz_flip", "gz_header", "gz_trailing", "gz_concat",
              "gz_of_mutated", "gz_garbage", "gz_empty", "gz_double")


# --- the corpus ----------------------------------------------------------------------------------------------------

@dataclass
class Case:
    """One mutated log: its group, seed, bytes, the file name it is read under and what was done."""

    group: str
    seed: str
    number: int
    data: bytes
    name: str
    ops: list[str] = field(default_factory=list)

    def __str__(self) -> str:
        return f"{self.group} {self.seed} case {self.number} {self.ops}"


Parsed = DfLog | TextLog | ULogFile


def _structured_kinds(parsed: Parsed) -> tuple[str, ...]:
    """The message- or line-level mutations of a seed's format."""
    return DF_KINDS if isinstance(parsed, DfLog) else TEXT_KINDS if isinstance(parsed, TextLog) else ULOG_KINDS


def _apply(parsed: Parsed, ops: list[str], rng: random.Random) -> bytes:
    """The bytes of ``parsed`` after ``ops``: the message- and line-level ones first, then the byte-level ones."""
    log = parsed.copy()
    for op in ops:
        if op not in BYTE_KINDS:
            if isinstance(log, DfLog):
                _df_op(log, rng, op)
            elif isinstance(log, TextLog):
                _text_op(log, rng, op)
            else:
                _ulog_op(log, rng, op)
    data = log.render()
    for op in ops:
        if op in BYTE_KINDS and data:
            data = _byte_op(data, rng, op, parsed.head_end)
    return data


def _op_lists(group: str, kinds: tuple[str, ...], n: int, random_seed: int, start: int = 0) -> list[list[str]]:
    """The mutations of ``n`` cases of a seed whose own mutations are ``kinds``: the first of case k is the
    (start + k)-th kind of the group in turn, every third case has one or two more; a gzip case's second names the
    mutation of the log inside (when it has one)."""
    rng = random.Random(random_seed)
    first = GZIP_KINDS if group == "gzip" else kinds
    out = []
    for k in range(n):
        ops = [first[(start + k) % len(first)]]
        if group == "gzip":
            inner = rng.choice(kinds)
            ops += [inner] if ops[0] in ("gz_of_mutated", "gz_double") else []
        elif k % 3 == 0:
            ops += [rng.choice(kinds) for _ in range(rng.randint(1, 2))]
        out.append(ops)
    return out


def _cases(group: str, seed: str, parsed: Parsed, n: int, random_seed: int, start: int = 0) -> list[Case]:
    """``n`` deterministic cases of one seed, with the mutations of :func:`_op_lists`."""
    rng = random.Random(random_seed + 1_000_003)      # the mutations' own draws
    suffix = Path(seed).suffix + (".gz" if group == "gzip" else "")
    out = []
    for k, ops in enumerate(_op_lists(group, _structured_kinds(parsed) + BYTE_KINDS, n, random_seed, start)):
        if group == "gzip":
            data = _gzip_op(parsed.render(), lambda ops=ops: _apply(parsed, ops[1:2], rng), rng, ops[0])
        else:
            data = _apply(parsed, ops, rng)
        out.append(Case(group, seed, k, data, f"case{suffix}", ops))
    return out


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Parsed]:
    """Every seed log, parsed for mutation: simulated (60 s of a drone flight) and real."""
    flight = simulate(SimConfig.for_vehicle("drone", duration_s=60, seed=4, with_magnetometer=True,
                                            with_autopilot=True))
    folder = tmp_path_factory.mktemp("seeds")
    out: dict[str, Parsed] = {}
    path = folder / "seed"
    write_dataflash(flight, path, generation="4.x", second_imu=True)
    out["4x.bin"] = _parse_dataflash(path.read_bytes())
    write_dataflash(flight, path, generation="3.x")
    out["3x.bin"] = _parse_dataflash(path.read_bytes())
    for generation in ("4.x", "3.x"):
        write_dataflash(flight, path, text=True, generation=generation)
        out[f"{generation[0]}x.log"] = _parse_text(path.read_bytes(), keep=0.25)
    for generation in ("new", "old"):
        write_ulog(flight, path, generation=generation)
        out[f"{generation}.ulg"] = _parse_ulog(path.read_bytes())
    out["log171.bin"] = _parse_dataflash(gzip.decompress((REAL / "ardupilot_copter_log171.bin.gz").read_bytes()))
    out["hover.ulg"] = _parse_ulog((REAL / "px4_quad_hover_start.ulg").read_bytes())
    out["ground.ulg"] = _parse_ulog((REAL / "px4_quad_ground_start.ulg").read_bytes())
    # every seed reads as it is (and the readers' compiled walk is loaded before any case is timed)
    for name, parsed in out.items():
        path = folder / name
        path.write_bytes(parsed.render())
        _check_log(read_flight_log(path), Case("seed", name, 0, b"", name))
    return out


def _corpus(seeds: dict[str, Parsed], group: str) -> list[Case]:
    """Every case of ``group``, as PLAN says."""
    return [case for g, seed, n, random_seed in PLAN if g == group
            for case in _cases(g, seed, seeds[seed], n, random_seed)]


# --- the checks ----------------------------------------------------------------------------------------------------

class Hang(BaseException):
    """A case ran past HANG_S (a BaseException: no reader's ``except Exception`` takes it for a bad file)."""


@contextlib.contextmanager
def _bounded(where: object) -> Iterator[None]:
    """Interrupt the block after HANG_S and fail it when it took longer than CASE_LIMIT_S."""

    def hang(_signum: int, _frame: object) -> None:
        raise Hang(f"{where}: still running after {HANG_S:.0f} s")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    start = time.perf_counter()
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        elapsed = time.perf_counter() - start
        if elapsed >= CASE_LIMIT_S:
            pytest.fail(f"{where}: took {elapsed:.1f} s")


def _located(exc: InputError) -> bool:
    """Whether an error points at a place in the log: a message, topic or field it names, a line or a byte; or is
    about the file as a whole."""
    if exc.line is not None:
        return True
    if exc.column is not None:
        return re.split(r"[ .\[/]", exc.column)[0] in LOCATIONS
    return bool(re.search(r"\b(byte|line|message) \d+", exc.message)) or exc.message.startswith(WHOLE_FILE)


def _check_error(exc: InputError, path: Path, case: Case) -> None:
    """An error names the file, is short and located."""
    text = str(exc)
    assert path.name in text, f"{case}: {text}"
    assert len(text) < MAX_MESSAGE, f"{case}: {len(text)} characters: {text[:300]}"
    assert _located(exc), f"{case}: not located: {text}"


def _check_log(log: FlightLog, case: Case) -> None:
    """A log read has what the pipeline needs, in order and finite, and goes through to_pos_log and describe."""
    imu = log.imu
    assert len(imu.time) > 0, case
    assert np.isfinite(imu.time).all() and (np.diff(imu.time) > 0).all(), f"{case}: IMU times"
    assert np.isfinite(imu.gyro).all() and np.isfinite(imu.accel).all(), f"{case}: IMU values"
    gnss = log.gnss
    for values in (gnss.time, gnss.lat_deg, gnss.lon_deg, gnss.height):
        assert np.isfinite(values).all(), f"{case}: GNSS fixes"
    assert (np.abs(gnss.lat_deg) <= 90).all() and (np.abs(gnss.lon_deg) <= 180).all(), f"{case}: GNSS positions"
    assert (np.diff(gnss.time) > 0).all(), f"{case}: GNSS times"
    if gnss.sigma_neu is not None:
        given = gnss.sigma_neu[~np.isnan(gnss.sigma_neu)]
        assert np.isfinite(given).all() and (given > 0).all(), f"{case}: GNSS sigmas {given.min()}"
    if log.events is not None:
        assert np.isfinite(log.events.time).all(), f"{case}: event times"
    assert len(to_pos_log(log).time) == len(imu.time), case
    assert describe(log), case


def _read(case: Case, path: Path, outcome: Counter[str]) -> None:
    """Read one case: a checked log or a checked error, within the time bound, without a RuntimeWarning."""
    path.write_bytes(case.data)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with _bounded(case):
                log = read_flight_log(path)
                _check_log(log, case)
        except InputError as exc:
            _check_error(exc, path, case)
            outcome["error"] += 1
        except Exception as exc:
            exc.add_note(f"in {case}")
            raise
        else:
            outcome["read"] += 1
    runtime = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not runtime, f"{case}: {runtime[0].category.__name__} at {runtime[0].filename}:{runtime[0].lineno}: " \
                        f"{runtime[0].message}"


@pytest.mark.parametrize("group", GROUPS)
def test_fuzz_logs(seeds, tmp_path, group):
    """Every case of the group ends in a checked log or a checked error, in time, without a RuntimeWarning."""
    outcome: Counter[str] = Counter()
    for case in _corpus(seeds, group):
        _read(case, tmp_path / case.name, outcome)
    # the corpus reaches both ends: logs still read after a mutation, and refusals
    assert outcome["read"] >= 10 and outcome["error"] >= 10, outcome


def test_fuzz_info_command(seeds, tmp_path):
    """``georef info`` on CLI_CASES cases of each seed (other mutations first than the reader's corpus): exit 0 or
    2, no traceback, an error naming the file."""
    codes: Counter[int] = Counter()
    cases = [case for group, seed, _, random_seed in PLAN
             for case in _cases(group, seed, seeds[seed], CLI_CASES, random_seed + 7, start=random_seed)]
    for case in cases:
        path = tmp_path / case.name
        path.write_bytes(case.data)
        with _bounded(case):
            result = RUNNER.invoke(app, ["info", str(path)])
        codes[result.exit_code] += 1
        assert result.exit_code in (0, 2), f"{case}: exit {result.exit_code}: {result.output[-600:]}"
        assert result.exception is None or isinstance(result.exception, SystemExit), case
        assert "Traceback" not in result.output and "internal error" not in result.output, case
        if result.exit_code == 2:
            assert "error:" in result.output and path.name in result.output, f"{case}: {result.output[-600:]}"
    assert codes[0] >= 5 and codes[2] >= 5, codes


def test_corpus_covers_every_mutation(seeds):
    """Each mutation appears in its group many times, and the corpus is deterministic (the corpus is what the test
    claims)."""
    for group in GROUPS:
        ops: Counter[str] = Counter()
        for g, seed, n, random_seed in PLAN:
            if g == group:
                ops.update(op for case in _op_lists(g, _structured_kinds(seeds[seed]) + BYTE_KINDS, n, random_seed)
                           for op in case)
        expected = set(GZIP_KINDS) if group == "gzip" else set(BYTE_KINDS) | {
            "dataflash-bin": set(DF_KINDS), "dataflash-text": set(TEXT_KINDS), "ulog": set(ULOG_KINDS)}[group]
        assert expected <= set(ops) and min(ops[kind] for kind in expected) >= 5, (group, ops)
    for group, seed, _, random_seed in PLAN[::3]:
        once, twice = (_cases(group, seed, seeds[seed], 12, random_seed) for _ in range(2))
        assert [case.data for case in once] == [case.data for case in twice], seed
    assert sum(n for *_, n, _ in PLAN) == 790 and len(PLAN) * CLI_CASES == 39     # as the docstring says
