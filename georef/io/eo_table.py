"""Writing and reading the EO table (CSV), atomically.

The table is written with the standard library's ``csv`` module, cell by cell as pandas' ``DataFrame.to_csv``
writes it (a float as numpy's shortest repr after rounding to the column's decimals, a missing value as an empty
cell, the same quoting), so the file is the same byte for byte (``tests/io/test_exports.py`` compares the two) and
a run that writes only the table never imports pandas (its import is slow: ``docs/performance.md``, "Imports").
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from georef.io.atomic import atomic_write

if TYPE_CHECKING:
    import pandas as pd

#: decimals per column: ~0.1 mm in angles-of-latitude, 1 mm in heights, 1e-6 deg in angles
_FORMATS = {"time": 3, "lat": 10, "lon": 10, "height": 4, "roll": 6, "pitch": 6, "yaw": 6,
            "sigma_n": 4, "sigma_e": 4, "sigma_u": 4, "sigma_roll": 5, "sigma_pitch": 5, "sigma_yaw": 5,
            "track": 5, "yaw_minus_track": 5, "easting": 4, "northing": 4, "omega": 6, "phi": 6,
            "kappa": 6, "height_orthometric": 4, "sigma_x": 4, "sigma_y": 4, "sigma_omega": 5, "sigma_phi": 5,
            "sigma_kappa": 5}


def _cells(values: Any, decimals: int | None) -> Any:
    """The CSV cells of one column: floats rounded to ``decimals`` and written as numpy's shortest repr, a
    missing value (NaN, None) empty, anything else as its text."""
    values = np.asarray(values)
    if values.dtype.kind == "f":
        if decimals is not None:
            values = np.round(values, decimals)
        text = values.astype(str).astype(object)
        text[np.isnan(values)] = ""
        return text
    if values.dtype.kind in "iub":
        return values.astype(str)
    return ["" if value is None or (isinstance(value, float) and value != value) else value
            for value in values.tolist()]


def write_eo_csv(table: Mapping[str, Any] | pd.DataFrame, path: Path | str) -> Path:
    """Write the EO table (columns, :func:`georef.eo.camera_eo_columns`, or a DataFrame) as CSV; the file
    appears complete or not at all."""
    names = list(table)
    columns = [_cells(table[name], _FORMATS.get(str(name))) for name in names]
    with atomic_write(path) as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(names)
        writer.writerows(zip(*columns, strict=True))
    return Path(path)


def read_eo_csv(path: Path | str) -> pd.DataFrame:
    """Read an EO table written by :func:`write_eo_csv` (frame ids kept as text)."""
    import pandas as pd

    return pd.read_csv(path, dtype={"frame": str, "image": str, "flag": str}, keep_default_na=False,
                       na_values={c: [""] for c in _FORMATS})
