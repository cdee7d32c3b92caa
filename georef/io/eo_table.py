"""Writing and reading the EO table (CSV), atomically."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from georef.io.atomic import atomic_write

#: decimals per column: ~0.1 mm in angles-of-latitude, 1 mm in heights, 1e-6 deg in angles
_FORMATS = {"time": 3, "lat": 10, "lon": 10, "height": 4, "roll": 6, "pitch": 6, "yaw": 6,
            "sigma_n": 4, "sigma_e": 4, "sigma_u": 4, "sigma_roll": 5, "sigma_pitch": 5, "sigma_yaw": 5,
            "track": 5, "yaw_minus_track": 5, "easting": 4, "northing": 4, "omega": 6, "phi": 6,
            "kappa": 6, "height_orthometric": 4, "sigma_x": 4, "sigma_y": 4, "sigma_omega": 5, "sigma_phi": 5,
            "sigma_kappa": 5}


def write_eo_csv(table: pd.DataFrame, path: Path | str) -> Path:
    """Write the EO table as CSV; the file appears complete or not at all."""
    rounded = table.copy()
    for column, decimals in _FORMATS.items():
        if column in rounded:
            rounded[column] = rounded[column].round(decimals)
    with atomic_write(path) as handle:
        rounded.to_csv(handle, index=False, lineterminator="\n")
    return Path(path)


def read_eo_csv(path: Path | str) -> pd.DataFrame:
    """Read an EO table written by :func:`write_eo_csv` (frame ids kept as text)."""
    return pd.read_csv(path, dtype={"frame": str, "image": str, "flag": str}, keep_default_na=False,
                       na_values={c: [""] for c in _FORMATS})
