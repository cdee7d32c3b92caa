"""The navigation filter's figures ``georef calibrate-boresight --process-summary`` reads from a ``georef process
--summary-json`` document (``docs/qc.md``, "Machine-readable summary"; ``docs/boresight.md``, "sigma").

Only what the calibration needs: the filter's accelerometer-bias 1-sigma [m/s^2, body x, y, z] (its x, y over g
are the sigma of the INS tilt error fixed in the body frame), the GNSS lever arm's 1-sigma [m, body] when the
filter or the graph estimated it, the method and the POS time span [s UTC of day] (to check the EO belongs to the
same flight).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from georef.io.errors import InputError


@dataclass
class ProcessFigures:
    """``accel_bias_sigma_m_s2`` (3,) or None (the method has no bias covariance: ``axis``, ``graph``);
    ``gnss_lever_arm_sigma_m`` (3,) or None (the GNSS lever arm was configured, not estimated);
    ``time_span_s`` [first, last] POS time [s UTC of day]; ``method``; ``path`` the summary read."""

    accel_bias_sigma_m_s2: np.ndarray | None
    gnss_lever_arm_sigma_m: np.ndarray | None
    time_span_s: tuple[float, float]
    method: str
    path: str


def _triple(value: object, path: Path, key: str) -> np.ndarray | None:
    if value is None:
        return None
    try:
        values = np.asarray(value, float)
    except (TypeError, ValueError):
        values = np.array([])
    if values.shape != (3,) or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise InputError(path, None, f"summary.{key}", f"expected three non-negative numbers, got {value!r}")
    return values


def read_process_summary(path: Path | str) -> ProcessFigures:
    """Read the figures of a ``georef process --summary-json`` document; :class:`InputError` naming the key when
    the file is not JSON, not a ``process`` summary, or a figure is malformed. A summary of a run without bias
    covariances (``--method axis`` or ``graph``, or a georef that did not write the key) gives None figures."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, None, None, "process summary not found") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        line = getattr(exc, "lineno", None)
        raise InputError(path, line, None, f"not a JSON summary of georef process: {exc}") from None
    if not isinstance(document, dict) or document.get("command") != "process" or not isinstance(
            document.get("summary"), dict):
        what = document.get("command") if isinstance(document, dict) else type(document).__name__
        raise InputError(path, None, "command", f"not a summary of georef process (command {what!r}): write one "
                                                "with georef process ... --summary-json summary.json")
    return figures_of_summary(document["summary"], path)


def figures_of_summary(summary: dict, path: Path | str = "summary") -> ProcessFigures:
    """The figures of a process run's ``summary`` (``ProcessResult.summary()``, the ``summary`` object of the
    JSON document); ``path`` names it in errors."""
    path = Path(path)
    span = summary.get("time_span_s")
    try:
        first, last = (float(v) for v in span)
    except (TypeError, ValueError):
        raise InputError(path, None, "summary.time_span_s", f"expected [first, last] seconds, got {span!r}") from None
    lever = summary.get("gnss_lever_arm_sigma_m")
    if lever is None:
        lever = summary.get("graph_lever_arm_sigma_m")
    return ProcessFigures(accel_bias_sigma_m_s2=_triple(summary.get("accel_bias_sigma_m_s2"), path,
                                                        "accel_bias_sigma_m_s2"),
                          gnss_lever_arm_sigma_m=_triple(lever, path, "gnss_lever_arm_sigma_m"),
                          time_span_s=(first, last), method=str(summary.get("method")), path=str(path))
