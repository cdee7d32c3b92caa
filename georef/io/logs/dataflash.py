"""DataFlash logs, binary (``.bin``) and text (``.log``): the messages of the wanted types as numpy columns.

Both forms define their message types in the log itself with ``FMT`` messages: a name (``IMU``, ``GPS``), a
format string of one character per field and the field names. In the binary form the characters give each
field's C type and scale (ArduPilot ``libraries/AP_Logger/LogStructure.h``): ``c``/``C``/``e``/``E`` are
hundredths, ``L`` is a latitude or longitude in 1e-7 degrees. The text form holds the same messages as comma
separated lines, already scaled. :func:`read_dataflash` returns, for each wanted type, a
:class:`MessageTable` of float columns (text fields as str) with each message's position in the log, for
located errors: the byte offset (binary) or line (text).

The binary walk is compiled (:mod:`georef.io.logs.dataflash_kernel`); the bodies are read by numpy per type.
pymavlink's DFReader reads the same logs and is the reference of ``tests/sim/test_autopilot_logs.py``; it is not used
here because it is slow, reading in Python (``docs/performance.md``, "Autopilot logs").
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from georef.io.errors import InputError, excerpt

#: format character -> (numpy type, scale applied to the stored value); strings have scale None
FORMAT_TYPES: dict[str, tuple[str, float | None]] = {
    "a": ("(32,)<i2", 1.0), "b": ("i1", 1.0), "B": ("u1", 1.0), "h": ("<i2", 1.0), "H": ("<u2", 1.0),
    "i": ("<i4", 1.0), "I": ("<u4", 1.0), "f": ("<f4", 1.0), "d": ("<f8", 1.0), "n": ("S4", None),
    "N": ("S16", None), "Z": ("S64", None), "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01),
    "E": ("<u4", 0.01), "L": ("<i4", 1e-7), "M": ("u1", 1.0), "q": ("<i8", 1.0), "Q": ("<u8", 1.0),
    "g": ("<f2", 1.0),
}
#: whole-number format character -> (lowest, highest) value its field can hold, scaled
WHOLE_NUMBER_RANGES: dict[str, tuple[float, float]] = {
    char: (float(np.iinfo(np.dtype(kind).base).min) * scale, float(np.iinfo(np.dtype(kind).base).max) * scale)
    for char, (kind, scale) in FORMAT_TYPES.items() if scale is not None and np.dtype(kind).base.kind in "iu"}
#: the whole-number format characters stored unscaled: their text holds no fraction
UNSCALED_WHOLE_NUMBERS = frozenset(char for char in WHOLE_NUMBER_RANGES if FORMAT_TYPES[char][1] == 1.0)
HEADER_BYTES = 3
FMT_TYPE = 128


@dataclass
class MessageFormat:
    """One message type as its FMT message defines it."""

    type_id: int
    length: int
    name: str
    format: str
    columns: tuple[str, ...]


@dataclass
class MessageTable:
    """All messages of one type: ``columns[name]`` (float64, or object for text fields) and ``where`` each
    message's byte offset (binary) or 1-based line (text)."""

    name: str
    columns: dict[str, np.ndarray]
    where: np.ndarray

    def __len__(self) -> int:
        return len(self.where)

    def has(self, *names: str) -> bool:
        return all(name in self.columns for name in names)


@dataclass
class DataFlashLog:
    """The wanted message types of a DataFlash log, the formats of all, and what was skipped."""

    path: Path
    binary: bool
    formats: dict[str, MessageFormat]
    messages: dict[str, MessageTable]
    #: (byte offset or line, how many bytes or lines) of each run that was not a message
    skipped: list[tuple[int, int]] = field(default_factory=list)

    def location(self, where: int) -> str:
        """``"byte 1234"`` or ``"line 56"``."""
        return f"byte {where}" if self.binary else f"line {where}"


def is_binary_dataflash(head: bytes) -> bool:
    """A binary DataFlash log holds the FMT message of FMT, ``A3 95 80 80 59``, at its start or, after bytes a
    log cut or an SD card's garbage left, within ``head`` (its first kilobytes)."""
    return bytes([0xA3, 0x95, FMT_TYPE, FMT_TYPE, 89]) in head


def is_text_dataflash(head: bytes) -> bool:
    """A text DataFlash log has a ``FMT, 128, 89, FMT,`` line among its first lines."""
    text = head[:4096].decode("latin-1")
    return any(line.replace(" ", "").startswith("FMT,128,89,FMT,") for line in text.splitlines()[:20])


def _format_dtype(fmt: MessageFormat) -> np.dtype:
    """The packed little-endian body of a message type; ValueError saying what its FMT message gets wrong (an
    unknown type character, a field name empty or repeated, fields that do not add up to the declared length)."""
    unknown = "".join(sorted(set(fmt.format) - set(FORMAT_TYPES)))
    if unknown:
        raise ValueError(f"format {fmt.format!r} has type characters DataFlash does not define: {unknown!r}")
    names = fmt.columns[:len(fmt.format)]
    if len(set(names)) < len(names) or not all(names):
        raise ValueError(f"field names {excerpt(','.join(fmt.columns), 80)} hold an empty or repeated one")
    dtype = np.dtype([(name, FORMAT_TYPES[char][0]) for name, char in zip(names, fmt.format, strict=False)])
    if dtype.itemsize != fmt.length - HEADER_BYTES:
        raise ValueError(f"format {fmt.format!r} of {len(names)} fields does not add up to the declared "
                         f"{fmt.length} bytes")
    return dtype


def _parse_formats(data: np.ndarray, offsets: np.ndarray) -> dict[int, MessageFormat]:
    formats: dict[int, MessageFormat] = {}
    body = np.dtype([("type", "u1"), ("length", "u1"), ("name", "S4"), ("format", "S16"), ("columns", "S64")])
    for offset in offsets:
        raw = data[offset + HEADER_BYTES:offset + HEADER_BYTES + body.itemsize].view(body)[0]
        name = raw["name"].decode("latin-1").strip("\x00 ")
        columns = tuple(c.strip() for c in raw["columns"].decode("latin-1").strip("\x00").split(","))
        formats[int(raw["type"])] = MessageFormat(int(raw["type"]), int(raw["length"]), name,
                                                  raw["format"].decode("latin-1").strip("\x00"), columns)
    return formats


def _binary_table(data: np.ndarray, fmt: MessageFormat, offsets: np.ndarray) -> MessageTable:
    dtype = _format_dtype(fmt)
    index = offsets[:, None] + HEADER_BYTES + np.arange(dtype.itemsize)
    records = np.ascontiguousarray(data[index]).view(dtype).reshape(-1)
    columns: dict[str, np.ndarray] = {}
    for name, char in zip(fmt.columns, fmt.format, strict=False):
        scale = FORMAT_TYPES[char][1]
        values = records[name]
        if scale is None:
            columns[name] = np.array([v.decode("latin-1").strip("\x00") for v in values], dtype=object)
        elif values.ndim == 1:
            with np.errstate(invalid="ignore"):  # a signalling NaN (any bit pattern may be one) is NaN all the same
                columns[name] = values.astype(float) * scale if scale != 1.0 else values.astype(float)
    return MessageTable(fmt.name, columns, offsets.copy())


def read_binary(path: Path, data: bytes, wanted: Iterable[str]) -> DataFlashLog:
    """The wanted message types of a binary DataFlash log held in ``data``."""
    from georef.aot import load as load_kernel

    buffer = np.frombuffer(data, dtype=np.uint8)
    lengths = np.zeros(256, dtype=np.int64)
    lengths[FMT_TYPE] = 89
    offsets, types, skip_at, skip_len = load_kernel("dataflash").scan(buffer, lengths, len(buffer))
    formats = _parse_formats(buffer, offsets[types == FMT_TYPE])
    by_name = {fmt.name: fmt for fmt in formats.values()}
    messages = {}
    for name in wanted:
        fmt = by_name.get(name)
        if fmt is None:
            continue
        try:
            messages[name] = _binary_table(buffer, fmt, offsets[types == fmt.type_id])
        except ValueError as exc:
            raise InputError(path, None, f"FMT {name}", str(exc)) from None
    return DataFlashLog(path, True, by_name, messages, list(zip(skip_at.tolist(), skip_len.tolist(), strict=True)))


def _text_value(text: str, char: str) -> object:
    """A field of a text line, scaled; ValueError when it is no number, or one the field's binary type could not
    hold (a whole-number field's NaN, inf, out-of-range or fractional value): the line is damaged."""
    if FORMAT_TYPES.get(char, ("", 1.0))[1] is None:
        return text
    value = float(text)
    bounds = WHOLE_NUMBER_RANGES.get(char)
    if bounds is not None and not bounds[0] <= value <= bounds[1]:
        raise ValueError(f"{text!r} is out of the range of format character {char!r}")
    if char in UNSCALED_WHOLE_NUMBERS and not value.is_integer():
        raise ValueError(f"{text!r} is not a whole number, as format character {char!r} holds")
    return value


def read_text(path: Path, text: str, wanted: Iterable[str]) -> DataFlashLog:
    """The wanted message types of a text DataFlash log (``NAME, v1, v2, ...`` lines, values scaled)."""
    wanted = set(wanted)
    formats: dict[str, MessageFormat] = {}
    rows: dict[str, list[list[object]]] = {name: [] for name in wanted}
    lines: dict[str, list[int]] = {name: [] for name in wanted}
    skipped: list[tuple[int, int]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        name, _, rest = line.partition(",")
        name = name.strip()
        if name == "FMT":
            parts = [p.strip() for p in rest.split(",")]
            if len(parts) < 4:
                skipped.append((number, 1))
                continue
            try:
                fmt = MessageFormat(int(parts[0]), int(parts[1]), parts[2], parts[3], tuple(parts[4:]))
            except ValueError:
                skipped.append((number, 1))
                continue
            formats[fmt.name] = fmt
            continue
        if name not in wanted:
            continue
        fmt = formats.get(name)
        parts = [p.strip() for p in rest.split(",")]
        if fmt is None or len(parts) != len(fmt.columns):
            skipped.append((number, 1))
            continue
        try:
            rows[name].append([_text_value(p, c) for p, c in zip(parts, fmt.format, strict=False)])
        except ValueError:
            skipped.append((number, 1))
            continue
        lines[name].append(number)
    messages = {}
    for name in wanted:
        if name not in formats or not rows[name]:
            continue
        fmt = formats[name]
        columns = {}
        for k, (column, char) in enumerate(zip(fmt.columns, fmt.format, strict=False)):
            values = [row[k] for row in rows[name]]
            text_field = FORMAT_TYPES.get(char, ("", 1.0))[1] is None
            columns[column] = np.array(values, dtype=object if text_field else float)
        messages[name] = MessageTable(name, columns, np.array(lines[name], dtype=np.int64))
    return DataFlashLog(path, False, formats, messages, skipped)
