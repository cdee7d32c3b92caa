"""Ellipsoidal heights of fixes a receiver reported above mean sea level.

Receivers report height above their geoid model (u-blox: ``hMSL``); autopilots log that (ArduPilot's ``GPS.Alt``,
PX4's ``alt``), and some also log what the receiver gave as the separation of the two (ArduPilot's ``GPA``). The
ellipsoidal height is ``h = H + N``: with the receiver's separation ``N`` where the log has it, else EGM96 through
PROJ (:meth:`georef.frames.heights.OutputFrames.egm96`), which is the model u-blox receivers use.
"""

from __future__ import annotations

import numpy as np


def egm96_undulation(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """EGM96 geoid undulation N [m] (ellipsoidal minus EGM96 height) at WGS 84 points, from PROJ's grid."""
    from georef.frames.heights import OutputFrames

    frames = OutputFrames(None, "orthometric")
    zeros = np.zeros(np.shape(lat_deg))
    return -frames.egm96(lat_deg, lon_deg, zeros)


def ellipsoidal_heights(lat_deg: np.ndarray, lon_deg: np.ndarray, msl: np.ndarray, undulation: np.ndarray | None,
                        field: str) -> tuple[np.ndarray, str]:
    """(ellipsoidal heights [m], how they were made) of heights ``msl`` [m] above mean sea level; ``undulation``
    [m] the receiver's ellipsoidal minus mean-sea-level height per fix (NaN where unknown) or None."""
    lat, lon, msl = (np.asarray(a, dtype=float) for a in (lat_deg, lon_deg, msl))
    given = np.zeros(len(msl), bool) if undulation is None else np.isfinite(undulation)
    n = np.where(given, 0.0 if undulation is None else np.nan_to_num(undulation), 0.0)
    if (~given).any():
        n[~given] = egm96_undulation(lat[~given], lon[~given])
    if given.all():
        text = f"{field} (mean sea level) + the receiver's undulation"
    elif given.any():
        text = f"{field} (mean sea level) + the receiver's undulation, else EGM96 (PROJ)"
    else:
        text = f"{field} (mean sea level) + EGM96 undulation (PROJ): the log has none of the receiver's"
    return msl + n, text
