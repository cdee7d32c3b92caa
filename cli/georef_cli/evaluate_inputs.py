"""The inputs of ``georef evaluate``, checked before any figure is computed.

``georef evaluate EO REFERENCE`` compares an EO table (``georef process``: frame, time, position, attitude and
their sigmas) with a reference (``truth.csv`` of ``georef simulate``: frame, time, position, attitude) row by row.
Everything that would otherwise end in a bare ``KeyError`` or a silent NaN is an :class:`InputError` naming the
file, the line (header = line 1) and the column:

* a file that cannot be read as a CSV table, or holds no rows;
* a required column missing (with the columns found; when the EO table lacks its sigma columns and the
  reference has them, the arguments were given the wrong way round, and the message says so);
* a cell that is not a number (in the EO table, empty cells are allowed except in ``time``: frames without a
  solution keep their row with empty values; in the reference every cell must be a number);
* a different number of frames, or a frame at another time (the first such line).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from georef.io.errors import InputError

from .output import is_stdout

#: what the EO table needs (beside ``frame``): the time [s], the position [deg, deg, m], the attitude [deg]
EO_COLUMNS = ("time", "lat", "lon", "height", "roll", "pitch", "yaw")
#: the EO table's sigmas [m, deg]; the reference has none
SIGMA_COLUMNS = ("sigma_n", "sigma_e", "sigma_u", "sigma_roll", "sigma_pitch", "sigma_yaw")
#: what the reference needs
REFERENCE_COLUMNS = EO_COLUMNS
#: frames are matched by row order; their times must agree to this [s] (as in ``georef.evaluate.frame_errors``)
TIME_TOLERANCE_S = 1e-6
#: at most this many column names and characters of a cell are quoted in a message
_SHOWN_COLUMNS = 15
_SHOWN_CHARS = 40

STDIN_NAME = "<standard input>"


def _excerpt(text: str) -> str:
    return text if len(text) <= _SHOWN_CHARS else text[:_SHOWN_CHARS] + "…"


def _found(columns: pd.Index) -> str:
    names = [str(c) for c in columns]
    shown = ", ".join(_excerpt(n) for n in names[:_SHOWN_COLUMNS])
    return shown + (f", … ({len(names)} columns)" if len(names) > _SHOWN_COLUMNS else "")


def _read(path: Path, what: str) -> tuple[pd.DataFrame, str]:
    """The table at ``path`` (standard input for ``-``) with every cell as text, and the name used in messages."""
    name = STDIN_NAME if is_stdout(path) else str(path)
    source = getattr(sys.stdin, "buffer", sys.stdin) if is_stdout(path) else path
    try:
        table = pd.read_csv(source, dtype=str, keep_default_na=False)
    except FileNotFoundError:
        raise InputError(name, None, None, f"{what}: file not found") from None
    except IsADirectoryError:
        raise InputError(name, None, None, f"{what}: a folder, not a CSV file") from None
    except pd.errors.EmptyDataError:
        raise InputError(name, None, None, f"{what}: the file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(name, None, None, f"{what}: not a readable CSV table ({_excerpt(str(exc))})") from None
    if table.empty:
        raise InputError(name, None, None, f"{what}: a header but no rows")
    return table, name


def _numbers(table: pd.DataFrame, name: str, column: str, allow_empty: bool) -> np.ndarray:
    """``table[column]`` as floats; the first cell that is not a number (or empty where that is not allowed)
    is an error naming its line."""
    text = table[column].str.strip()
    values = pd.to_numeric(text.where(text != "", None), errors="coerce")
    bad = values.isna() & ((text != "") | (not allow_empty))
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        cell = text.iloc[row]
        found = f"not a number: {_excerpt(cell)!r}" if cell else "empty: a number is needed here"
        raise InputError(name, row + 2, column, found)
    return values.to_numpy(dtype=float)


def read_inputs(eo_path: Path, reference_path: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The EO table and the reference, checked (module docstring); numeric columns as floats, ``frame`` as text."""
    if is_stdout(eo_path) and is_stdout(reference_path):
        raise InputError(STDIN_NAME, None, None, "only one of the two tables can be read from standard input")
    eo, eo_name = _read(eo_path, "EO table")
    reference, reference_name = _read(reference_path, "reference")
    usage = "georef evaluate EO_TABLE REFERENCE: the table written by georef process first, the reference second"
    missing_eo = [c for c in ("frame", *EO_COLUMNS, *SIGMA_COLUMNS) if c not in eo.columns]
    if missing_eo:
        swapped = (all(c not in eo.columns for c in SIGMA_COLUMNS)
                   and all(c in reference.columns for c in ("frame", *EO_COLUMNS, *SIGMA_COLUMNS)))
        hint = (f"; {reference_name} has them: the arguments look swapped ({usage})" if swapped else
                f" ({usage})")
        raise InputError(eo_name, 1, missing_eo[0], f"the EO table lacks column(s) {', '.join(missing_eo)}; "
                         f"columns found: {_found(eo.columns)}{hint}")
    missing_reference = [c for c in REFERENCE_COLUMNS if c not in reference.columns]
    if missing_reference:
        raise InputError(reference_name, 1, missing_reference[0],
                         f"the reference lacks column(s) {', '.join(missing_reference)}; columns found: "
                         f"{_found(reference.columns)} ({usage})")
    for column in (*EO_COLUMNS, *SIGMA_COLUMNS):
        eo[column] = _numbers(eo, eo_name, column, allow_empty=column != "time")
    for column in REFERENCE_COLUMNS:
        reference[column] = _numbers(reference, reference_name, column, allow_empty=False)
    if len(eo) != len(reference):
        raise InputError(eo_name, None, None, f"{len(eo)} frames, but the reference {reference_name} has "
                         f"{len(reference)}: evaluate compares the same frames, row by row")
    apart = np.abs(eo["time"].to_numpy() - reference["time"].to_numpy()) > TIME_TOLERANCE_S
    if apart.any():
        row = int(np.flatnonzero(apart)[0])
        raise InputError(eo_name, row + 2, "time", f"frame {_excerpt(str(eo['frame'].iloc[row]))!r} at "
                         f"{eo['time'].iloc[row]:.6f} s, but line {row + 2} of the reference {reference_name} is at "
                         f"{reference['time'].iloc[row]:.6f} s: evaluate compares the same frames, row by row")
    return eo, reference
