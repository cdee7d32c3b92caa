"""A tab/comma separated table reader that locates every problem by file, line and column.

The fast path is pandas' C parser on the wanted columns only. When it refuses a cell, a slower
diagnostic pass finds the exact line and column so the user can fix the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from georef.io.errors import InputError, InputNotice

Kind = Literal["float", "int", "hex", "str"]


@dataclass
class Table:
    """Columns read from a file, by name, with the 1-based file line of every row (header = line 1)."""

    path: Path
    header: list[str]
    columns: dict[str, np.ndarray]
    lines: np.ndarray
    notices: list[InputNotice] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.lines)

    def take(self, keep: np.ndarray) -> None:
        """Keep only the rows selected by the boolean mask or index array ``keep``."""
        self.columns = {name: values[keep] for name, values in self.columns.items()}
        self.lines = self.lines[keep]


def _hex_or_none(text: object) -> int | None:
    try:
        value = int(str(text), 16)
    except ValueError:
        return None
    return value if 0 <= value < 2**64 and "_" not in str(text) else None


def parse_hex(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hex-string parsing: the integers (uint64) and a mask of cells that are not hex.

    Surrounding blanks and a ``0x`` prefix are accepted. The common all-valid case is one pass of
    Python's ``int(text, 16)`` (about 0.1 s per million cells); the mask is built only on failure.
    """
    values = np.asarray(values, dtype=object)
    try:
        parsed = np.fromiter((int(text, 16) for text in values), dtype=np.uint64, count=len(values))
        if not any("_" in text for text in values if isinstance(text, str) and len(text) > 2):
            return parsed, np.zeros(len(values), dtype=bool)
    except (ValueError, TypeError, OverflowError):
        pass
    checked = [_hex_or_none(text) for text in values]
    bad = np.array([value is None for value in checked], dtype=bool)
    return np.array([value or 0 for value in checked], dtype=np.uint64), bad


def _read_header(path: Path, sep: str) -> list[str]:
    if not path.exists():
        raise InputError(path, None, None, "file not found")
    if path.is_dir():
        raise InputError(path, None, None, "is a folder, not a file")
    if os.path.getsize(path) == 0:
        raise InputError(path, 1, None, "the file is empty (no header line)")
    with open(path, encoding="utf-8", errors="replace") as handle:
        header_line = handle.readline()
        has_data = any(line.strip() for line in handle)
    header = [name.strip() for name in header_line.rstrip("\r\n").split(sep)]
    if not any(header):
        raise InputError(path, 1, None, "the header line is blank")
    if not has_data:
        raise InputError(path, 2, None, "no data rows after the header")
    return header


def _last_line_field_count(path: Path, sep: str) -> tuple[int, bool]:
    """Number of fields on the last non-blank line, and whether the file ends without a newline."""
    with open(path, "rb") as handle:
        handle.seek(0, os.SEEK_END)
        size = handle.tell()
        handle.seek(max(0, size - 65536))
        tail = handle.read()
    ends_with_newline = tail.endswith(b"\n")
    lines = [line for line in tail.split(b"\n") if line.strip()]
    last = lines[-1].decode("utf-8", errors="replace").rstrip("\r") if lines else ""
    return len(last.split(sep)), not ends_with_newline


def _locate_bad_cell(path: Path, sep: str, name: str, kind: Kind) -> InputError | None:
    """Diagnostic pass: the first cell of column ``name`` that is not a valid ``kind``."""
    text = pd.read_csv(path, sep=sep, usecols=[name], dtype=str, skip_blank_lines=False,
                       keep_default_na=False, engine="c")[name].str.strip()
    if kind == "hex":
        _, bad = parse_hex(text.to_numpy())
        bad &= text.to_numpy() != ""
    else:
        numbers = pd.to_numeric(text, errors="coerce")
        bad = (numbers.isna() & (text != "")).to_numpy()
        if kind == "int" and not bad.any():
            finite = numbers.notna().to_numpy()
            bad = finite & (numbers.fillna(0).to_numpy() % 1 != 0)
    if bad.any():
        index = int(np.argmax(bad))
        what = {"float": "a number", "int": "a whole number", "hex": "a hexadecimal number"}.get(kind, kind)
        return InputError(path, index + 2, name, f"cannot read {text.iloc[index]!r} as {what}")
    return None


def read_table(
    path: Path | str,
    wanted: dict[str, Kind],
    required: set[str],
    sep: str = "\t",
) -> Table:
    """Read the ``wanted`` columns (name -> kind) of a header-led table.

    * A missing required column, a cell that is not of its kind, an empty cell in any column that is read,
      or a row with too many fields raises :class:`InputError` naming file, line and column.
    * A truncated last line (fewer fields than the header, as when a logger loses power) is dropped
      with a notice; blank lines are dropped with a notice.
    * Optional columns that are absent are simply not in ``Table.columns``.
    """
    path = Path(path)
    header = _read_header(path, sep)
    missing = [name for name in required if name not in header]
    if missing:
        raise InputError(
            path, 1, missing[0],
            f"required column {missing[0]!r} is missing (columns found: {', '.join(h for h in header if h)})",
        )
    present = [name for name in wanted if name in header]
    dtypes = {name: (np.float64 if wanted[name] in ("float", "int") else str) for name in present}
    notices: list[InputNotice] = []
    try:
        frame = pd.read_csv(path, sep=sep, usecols=present, dtype=dtypes, skip_blank_lines=False,
                            skipinitialspace=True, engine="c", keep_default_na=False,
                            na_values={n: [""] for n in present})
    except (ValueError, pd.errors.ParserError) as exc:
        message = str(exc)
        for name in present:
            located = _locate_bad_cell(path, sep, name, wanted[name])
            if located is not None:
                raise located from None
        raise InputError(path, None, None, f"cannot parse the table: {message}") from None

    lines = np.arange(2, len(frame) + 2)
    blank = frame.isna().all(axis=1).to_numpy() if present else np.zeros(len(frame), bool)
    n_fields, _ = _last_line_field_count(path, sep)
    keep = ~blank
    if blank.any():
        interior = lines[blank][lines[blank] < lines[~blank].max(initial=0)]
        if len(interior):
            notices.append(InputNotice(path, interior.tolist(), None, "blank lines skipped"))
    if n_fields < len(header) and keep.any():
        last = int(np.flatnonzero(keep)[-1])
        keep[last] = False
        notices.append(InputNotice(path, [int(lines[last])], None,
                                   f"truncated last line ({n_fields} of {len(header)} fields) dropped"))
    frame = frame[keep]
    lines = lines[keep]
    if len(frame) == 0:
        raise InputError(path, 2, None, "no complete data rows after the header")

    columns: dict[str, np.ndarray] = {}
    for name in present:
        values = frame[name].to_numpy()
        kind = wanted[name]
        # every column that is read is used: an empty cell is never silently a NaN
        empty = pd.isna(values) if kind in ("float", "int") else (pd.isna(values) | (values == ""))
        if np.any(empty):
            index = int(np.argmax(empty))
            raise InputError(path, int(lines[index]), name, "empty cell")
        if kind == "hex":
            parsed, bad = parse_hex(np.where(pd.isna(values), "0", values))
            if bad.any():
                index = int(np.argmax(bad))
                raise InputError(path, int(lines[index]), name, f"cannot read {values[index]!r} as hexadecimal")
            columns[name] = parsed
        elif kind == "int":
            if np.any(np.isfinite(values) & (values % 1 != 0)):
                index = int(np.argmax(np.isfinite(values) & (values % 1 != 0)))
                raise InputError(path, int(lines[index]), name, f"{values[index]!r} is not a whole number")
            columns[name] = values.astype(np.float64)
        elif kind == "float":
            columns[name] = values.astype(np.float64)
        else:
            columns[name] = np.asarray(values, dtype=str)
    return Table(path=path, header=header, columns=columns, lines=lines, notices=notices)
