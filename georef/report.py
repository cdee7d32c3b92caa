"""The quality-control report: one self-contained HTML file a client can file (``docs/report.md``).

Everything is in the one file: the plots are PNG images embedded as ``data:`` URIs, the styles inline; nothing is
fetched. Sections, in order (:data:`SECTIONS`): the QC verdict and its reasons (:mod:`georef.qc`); a summary of
the figures; provenance (georef and library versions, the date, the command, every input file with its size
and SHA-256, the mounting: lever arms, boresight, GNSS sigma, the innovation gate); the flagged frames; the
forward filter against the smoothed solution; the estimated accuracy over time; the ground track; GNSS status
(``STATUS[HEX]``) and IMU data gaps; the GNSS innovations against the gate; position and velocity; the camera
attitude; the estimated sensor biases; the recovered yaw origin of the POS unit; every processing setting.

Times are UTC time of day (POS.txt times are UTC seconds of day), shown as ``hh:mm:ss``. Units: metres,
degrees, seconds. ``georef process --report out.html`` writes it; the file is written atomically (complete or
not at all, :mod:`georef.io.atomic`).
"""

from __future__ import annotations

import base64
import dataclasses
import datetime as dt
import hashlib
import html
import io
import math
import platform
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import FuncFormatter, MaxNLocator, MultipleLocator  # noqa: E402

from georef.distributions import chi2_cdf  # noqa: E402
from georef.frames import STANDARD_GRAVITY, C_e_n, wrap_360, wrap_pi  # noqa: E402
from georef.io.atomic import atomic_write  # noqa: E402
from georef.run_summary import RunSummary, utc, utc_span  # noqa: E402

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from georef.config import ProcessingConfig
    from georef.pipeline import ProcessResult
    from georef.qc import Verdict

SECTIONS = [
    ("verdict", "Quality verdict"),
    ("summary", "Summary"),
    ("provenance", "Provenance"),
    ("flagged", "Flagged frames"),
    ("separation", "Forward against smoothed solution"),
    ("accuracy", "Estimated accuracy over time"),
    ("track", "Ground track"),
    ("gnss", "GNSS status and IMU data gaps"),
    ("innovations", "GNSS innovations and the χ² gate"),
    ("position", "Position and velocity"),
    ("attitude", "Camera attitude at the exposures"),
    ("biases", "Estimated sensor biases"),
    ("yaw-offset", "Recovered yaw origin of the POS unit"),
    ("settings", "Settings used"),
]

#: plotted points per line at most (longer series are decimated for drawing only)
MAX_PLOT_POINTS = 20_000
#: PNG resolution [dots per inch] of the embedded plots
DPI = 90
_COMPONENTS = ("north", "east", "down")
_ANGLES = ("roll", "pitch", "yaw")
_COLOURS = ("tab:blue", "tab:orange", "tab:green")
_STATUS_COLOURS = {"pass": "#1a7f37", "warn": "#9a6700", "fail": "#cf222e"}


# ---- formatting ---------------------------------------------------------------------------------------------
def _number(value: float, digits: int = 3) -> str:
    return f"{value:.{digits}f}".replace("-", "−") if math.isfinite(value) else "—"


def _triple(values: Sequence[float], labels: Sequence[str], unit: str, digits: int = 3) -> str:
    return ", ".join(f"{label} {_number(float(v), digits)}" for label, v in zip(labels, values, strict=True)) + \
        f" {unit}"


def _size(n_bytes: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.1f} {unit} ({n_bytes:,} bytes)"
    return f"{n_bytes} bytes"


def readable(value: object) -> str:
    """A value as a person reads it: no Python tuples, lists, dicts or ``None``."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.6g}".replace("-", "−")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, dict):
        return "; ".join(f"{k} = {readable(v)}" for k, v in value.items()) or "none"
    if isinstance(value, tuple | list | np.ndarray):
        items = list(value)
        if not items:
            return "none"
        shown = ", ".join(readable(v) for v in items[:12])
        return shown + (f", … ({len(items)} in all)" if len(items) > 12 else "")
    return str(value)


def _table(rows: Iterable[Sequence[object]], header: Sequence[str] | None = None, cls: str = "") -> str:
    """An HTML table; cells are escaped text (use :class:`_Raw` for markup)."""

    def cell(value: object, tag: str) -> str:
        text = value.html if isinstance(value, _Raw) else html.escape(readable(value))
        return f"<{tag}>{text}</{tag}>"

    head = "<thead><tr>" + "".join(cell(h, "th") for h in header) + "</tr></thead>" if header else ""
    body = "".join("<tr>" + "".join(cell(v, "th" if k == 0 and not header else "td") for k, v in enumerate(row))
                   + "</tr>" for row in rows)
    return f'<table class="{cls}">{head}<tbody>{body}</tbody></table>'


@dataclasses.dataclass
class _Raw:
    html: str


# ---- plots --------------------------------------------------------------------------------------------------
def _png(fig: Figure) -> str:
    """The figure as a ``data:image/png;base64,...`` URI (the figure is closed)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _tick_step(span: float) -> float:
    """A round tick interval [s] giving 4 to 8 ticks over ``span`` [s]."""
    for step in (1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600):
        if span / step <= 8:
            return float(step)
    return 43200.0


def _utc_axis(ax: Axes, t0: float, t1: float) -> None:
    """Ticks at round UTC times, labelled ``hh:mm:ss``."""
    ax.xaxis.set_major_locator(MultipleLocator(_tick_step(max(t1 - t0, 1.0))))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: utc(x, 0)))
    ax.set_xlim(t0, t1)


def _finish(fig: Figure, axes: Axes | np.ndarray, result: ProcessResult) -> None:
    """UTC ticks and a grid on every axes, the time label under the bottom row, a tight layout."""
    t0, t1 = float(result.log.time[0]), float(result.log.time[-1])
    grid = np.atleast_1d(axes)
    for ax in grid.ravel():
        _utc_axis(ax, t0, t1)
        ax.grid(True, lw=0.4, alpha=0.5)
    bottom = grid[-1] if grid.ndim == 2 else grid[-1:]
    for ax in np.atleast_1d(bottom):
        ax.set_xlabel("UTC (time of day)")
    fig.tight_layout()


def _stride(n: int) -> int:
    return max(1, int(math.ceil(n / MAX_PLOT_POINTS)))


def _shade_outages(ax: Axes, result: ProcessResult, label: bool = False) -> None:
    for k, (start, end) in enumerate(result.log.gnss.gaps()):
        ax.axvspan(start, end, color="0.85", lw=0, label="GNSS outage" if label and k == 0 else None)


def _track(result: ProcessResult) -> str:
    nav, table, gnss = result.nav, result.table, result.log.gnss
    valid = nav.valid
    s = _stride(int(valid.sum()))
    fig, ax = plt.subplots(figsize=(10, 8))
    ax.plot(np.degrees(nav.lon[valid][::s]), np.degrees(nav.lat[valid][::s]), color="0.4", lw=1,
            label="trajectory (IMU)")
    ax.scatter(gnss.lon_deg, gnss.lat_deg, s=6, color="tab:blue", label="GNSS fixes")
    stations = table[table["lat"].notna()]
    outage = stations["flag"].astype(str).str.contains("outage")
    ax.scatter(stations["lon"][~outage], stations["lat"][~outage], s=10, color="tab:green", label="exposures")
    if outage.any():
        ax.scatter(stations["lon"][outage], stations["lat"][outage], s=14, color="tab:red",
                   label="exposures in GNSS outage")
    rejected = nav.gnss.status == 0
    if rejected.any():
        ax.scatter(gnss.lon_deg[rejected], gnss.lat_deg[rejected], s=80, marker="x", color="black",
                   label="rejected fixes")
    ax.set_xlabel("longitude [deg]")
    ax.set_ylabel("latitude [deg]")
    ax.set_aspect(1.0 / np.cos(np.radians(np.nanmean(gnss.lat_deg))))
    ax.ticklabel_format(useOffset=False)
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, lw=0.4, alpha=0.5)
    return _png(fig)


def _accuracy(result: ProcessResult) -> str:
    """Position sigma N/E/U [m] and attitude sigma [deg] of the IMU solution, each on its own axes."""
    nav = result.nav
    v = np.flatnonzero(nav.valid)[:: _stride(int(nav.valid.sum()))]
    t = nav.time[v]
    sigma_pos = np.sqrt(nav.pos_var_n[v])
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, (name, colour) in enumerate(zip(("north", "east", "up"), _COLOURS, strict=True)):
        axes[0].plot(t, sigma_pos[:, k], color=colour, lw=1.2, label=f"σ {name}")
        axes[1].plot(t, np.degrees(nav.att_sigma[v, k]), color=colour, lw=1.2, label=f"σ {_ANGLES[k]}")
    for ax in axes:
        _shade_outages(ax, result, label=ax is axes[0])
        ax.set_ylim(bottom=0)
    axes[0].set_ylabel("position σ [m]")
    axes[1].set_ylabel("attitude σ [deg]")
    axes[0].legend(loc="upper left", fontsize=8, ncol=4)
    axes[1].legend(loc="upper left", fontsize=8, ncol=3)
    _finish(fig, axes, result)
    return _png(fig)


def _separation(result: ProcessResult) -> str | None:
    """Forward minus smoothed per component, with the +-2 sigma band the filter expects, each on its own axes."""
    sep = result.nav.forward
    if sep is None or len(sep.time) == 0:
        return None
    fig, axes = plt.subplots(3, 2, figsize=(11, 7.5), sharex=True)
    for k in range(3):
        for col, (value, sigma, unit, scale, name) in enumerate((
                (sep.position[:, k], sep.position_sigma[:, k], "m", 1.0, _COMPONENTS[k]),
                (sep.attitude[:, k], sep.attitude_sigma[:, k], "deg", np.degrees(1.0), _ANGLES[k]))):
            ax = axes[k, col]
            band = 2.0 * sigma * scale
            ax.fill_between(sep.time, -band, band, color="tab:orange", alpha=0.3, lw=0,
                            label="±2σ expected" if k == 0 else None)
            ax.plot(sep.time, value * scale, color="tab:blue", lw=0.9, label="forward − smoothed" if k == 0 else None)
            ax.set_ylabel(f"{name} [{unit}]")
            # the band is wide at the first epochs (the alignment's prior): scale to the bulk, not the start
            limit = max(float(np.nanpercentile(np.abs(value * scale), 99.5)), float(np.nanpercentile(band, 95)),
                        1e-6)
            ax.set_ylim(-1.15 * limit, 1.15 * limit)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    _finish(fig, axes, result)
    return _png(fig)


def _separation_table(result: ProcessResult) -> str:
    sep = result.nav.forward
    rows = []
    for label, values, sigma, scale, unit, digits in (
            *((c, sep.position[:, k], sep.position_sigma[:, k], 1.0, "m", 3) for k, c in enumerate(_COMPONENTS)),
            *((a, sep.attitude[:, k], sep.attitude_sigma[:, k], np.degrees(1.0), "deg", 4)
              for k, a in enumerate(_ANGLES))):
        worst = int(np.nanargmax(np.abs(values)))
        inside = float(np.mean(np.abs(values) <= 2.0 * sigma + 1e-12)) * 100.0
        rows.append((f"{label} [{unit}]", _number(float(np.sqrt(np.nanmean(values**2))) * scale, digits),
                     f"{_number(float(values[worst]) * scale, digits)} at {utc(float(sep.time[worst]))}",
                     _number(float(np.nanmedian(sigma)) * scale, digits), f"{inside:.1f} %"))
    return _table(rows, header=("component", "RMS", "largest", "median expected σ", "inside ±2σ"), cls="numbers")


def _position(result: ProcessResult) -> str:
    nav = result.nav
    v = np.flatnonzero(nav.valid)
    r0 = nav.r_e[v[0]]
    C = C_e_n(nav.lat[v[0]], nav.lon[v[0]])
    v = v[:: _stride(len(v))]
    t = nav.time[v]
    ned = (nav.r_e[v] - r0) @ C.T
    v_n = nav.v_n[v]
    fig, axes = plt.subplots(3, 2, figsize=(11, 7.5), sharex=True)
    for k, name in enumerate(_COMPONENTS):
        axes[k, 0].plot(t, ned[:, k], lw=1)
        axes[k, 0].set_ylabel(f"{name} [m]")
        axes[k, 1].plot(t, v_n[:, k], lw=1, color="tab:purple")
        axes[k, 1].set_ylabel(f"v {name} [m/s]")
    axes[0, 0].set_title("IMU position relative to the first solution, NED", fontsize=10)
    axes[0, 1].set_title("IMU velocity, NED", fontsize=10)
    _finish(fig, axes, result)
    return _png(fig)


def _attitude(result: ProcessResult) -> str | None:
    table = result.table[result.table["lat"].notna()]
    if table.empty:
        return None
    t = table["time"].to_numpy()
    fig, axes = plt.subplots(3, 1, figsize=(11, 6.5), sharex=True)
    for ax, name in zip(axes, _ANGLES, strict=True):
        value = table[name].to_numpy(float)
        if name == "yaw":
            value = np.degrees(np.unwrap(np.radians(value)))
        ax.plot(t, value, ".", ms=3, color="tab:blue")
        ax.set_ylabel(f"{name} [deg]")
    axes[-1].set_ylabel("yaw [deg] (unwrapped)")
    _finish(fig, axes, result)
    return _png(fig)


def _innovations(result: ProcessResult) -> str:
    gnss = result.nav.gnss
    statistic = gnss.normalised_innovation_sq
    used = gnss.status >= 1
    fig, ax = plt.subplots(figsize=(11, 3.8))
    ax.semilogy(gnss.time[used], statistic[used], ".", ms=4, label="used")
    rejected = gnss.status == 0
    if rejected.any():
        ax.semilogy(gnss.time[rejected], statistic[rejected], "x", color="tab:red", ms=9, label="rejected")
    gate = result.config.gnss_gate.chi2
    ax.axhline(gate, color="black", ls="--", label=f"χ² gate {gate:g}")
    ax.axhline(3.0, color="0.5", ls=":", label="expected mean 3")
    _shade_outages(ax, result, label=True)
    ax.set_ylabel("normalised innovation² [-]")
    ax.legend(fontsize=8, loc="upper right", ncol=4)
    _finish(fig, ax, result)
    return _png(fig)


def _status_values(result: ProcessResult) -> np.ndarray | None:
    status = result.log.data.get("status")
    if status is None or len(status) != len(result.log.time):
        return None
    return np.asarray(status)


def _gnss_status(result: ProcessResult, gaps: list[tuple[float, float]]) -> str:
    """STATUS[HEX] over time (one level per value), the GNSS fixes (used / rejected) and the IMU gaps."""
    status = _status_values(result)
    gnss = result.nav.gnss
    n_levels = len(np.unique(status)[:12]) if status is not None else 0
    rows = 2 if status is not None else 1
    heights = [0.5 + 0.35 * n_levels, 1.1] if rows == 2 else [1.1]
    fig, axes = plt.subplots(rows, 1, figsize=(11, 0.9 + sum(heights)), sharex=True, squeeze=False,
                             height_ratios=heights)
    axes = axes[:, 0]
    if status is not None:
        values, counts = np.unique(status, return_counts=True)
        order = values[np.argsort(-counts)][:12]
        level = {int(v): k for k, v in enumerate(sorted(int(x) for x in order))}
        y = np.array([level.get(int(v), -1) for v in status], float)
        y[y < 0] = np.nan
        s = _stride(len(y))
        axes[0].step(result.log.time[::s], y[::s], where="post", color="tab:blue", lw=1.2)
        axes[0].set_yticks(range(len(level)), [f"0x{v:X}" for v in sorted(level)])
        axes[0].set_ylim(-0.5, len(level) - 0.5)
        axes[0].set_ylabel("STATUS[HEX]")
    ax = axes[-1]
    used, rejected, unused = gnss.status >= 1, gnss.status == 0, gnss.status < 0
    ax.plot(gnss.time[used], np.ones(used.sum()), "|", color="tab:green", ms=10, label="fix used")
    if unused.any():
        ax.plot(gnss.time[unused], np.ones(unused.sum()), "|", color="0.6", ms=10, label="fix not processed")
    if rejected.any():
        ax.plot(gnss.time[rejected], np.ones(rejected.sum()), "x", color="tab:red", ms=9, label="fix rejected")
    for axis in axes:
        _shade_outages(axis, result, label=axis is ax)
        for k, (start, end) in enumerate(gaps):
            axis.axvspan(start, max(end, start + 0.5), color="tab:purple", alpha=0.35, lw=0,
                         label="IMU gap" if k == 0 and axis is ax else None)
    ax.set_yticks([])
    ax.set_ylim(0.5, 1.5)
    ax.set_ylabel("GNSS fixes")
    ax.legend(fontsize=8, loc="upper right", ncol=4)
    _finish(fig, axes, result)
    return _png(fig)


def _status_table(result: ProcessResult) -> str:
    status = _status_values(result)
    name = html.escape(result.log.column_names.get("status", "STATUS[HEX]"))
    if status is None:
        return f"<p>The POS log has no {name} column: no receiver status to show.</p>"
    t = result.log.time
    change = np.flatnonzero(np.diff(status.astype(np.int64)) != 0) + 1
    starts = np.r_[0, change]
    ends = np.r_[change, len(status)]
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    rows = []
    values, counts = np.unique(status, return_counts=True)
    for value, count in sorted(zip(values.tolist(), counts.tolist(), strict=True), key=lambda x: -x[1]):
        runs = [(s, e) for s, e in zip(starts, ends, strict=True) if int(status[s]) == value]
        spans = ", ".join(f"{utc(t[s], 0)}–{utc(t[e - 1] + period, 0)}" for s, e in runs[:4])
        if len(runs) > 4:
            spans += f", … ({len(runs)} stretches)"
        rows.append((f"0x{int(value):X}", f"{count:,}", f"{100.0 * count / len(status):.1f} %", spans))
    return (f"<p>The receiver's status word from column {name}, as logged (its bits are the receiver maker's; "
            "georef does not decode them).</p>"
            + _table(rows, header=("value", "rows", "share", "when (UTC)"), cls="numbers"))


def _imu_gaps(result: ProcessResult) -> list[tuple[float, float]]:
    diagnostics = result.nav.diagnostics
    if diagnostics is not None:
        return list(diagnostics.imu_gaps)
    log = result.log
    if not all(f"{p}_{a}" in log.data for p in ("gyro", "acc") for a in "xyz"):
        return []
    from georef.fusion.ins import imu_gaps

    return [(float(log.time[a]), float(log.time[b]))
            for a, b in imu_gaps(np.asarray(log.time, float), log.vector("gyro"), log.vector("acc"))]


def _gaps_table(gaps: list[tuple[float, float]]) -> str:
    if not gaps:
        return "<p>IMU data gaps: none (no missing or repeated IMU samples).</p>"
    rows = [(utc(a, 2), utc(b, 2), f"{b - a:.3f}") for a, b in gaps]
    return ("<p>IMU data gaps: spans without a real IMU measurement (time gaps and runs of interpolated samples); "
            "the filter bridges them with raised process noise.</p>"
            + _table(rows, header=("last sample before (UTC)", "first sample after (UTC)", "length [s]"),
                     cls="numbers"))


def _biases(result: ProcessResult) -> str | None:
    info = result.nav.ins_info
    if info is None:
        return None
    v = np.flatnonzero(result.nav.valid)
    v = v[:: _stride(len(v))]
    t = result.nav.time[v]
    fig, axes = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True)
    for k, axis in enumerate("xyz"):
        axes[0].plot(t, np.degrees(info.gyro_bias[v, k]) * 3600.0, color=_COLOURS[k], label=axis)
        axes[1].plot(t, info.accel_bias[v, k] / STANDARD_GRAVITY * 1000.0, color=_COLOURS[k], label=axis)
    axes[0].set_ylabel("gyro bias [deg/h]")
    axes[1].set_ylabel("accelerometer bias [mg]")
    axes[0].legend(fontsize=8, ncol=3, loc="upper right")
    _finish(fig, axes, result)
    return _png(fig)


def _yaw_offset(result: ProcessResult) -> str | None:
    """The POS unit's yaw origin: the axis method's followed offset, or the full-state filter's smoothed origin
    state with its sigma (and the windows recovered from IACC that gave its prior, when there were)."""
    nav = result.nav
    solution = nav.axis_info.yaw_offset if nav.axis_info is not None else None
    diagnostics = nav.diagnostics
    ins_info = nav.ins_info
    if solution is None and diagnostics is not None and ins_info is not None and diagnostics.unit_aiding:
        origin = ins_info.unit_yaw_origin
        solution = getattr(diagnostics.alignment, "yaw_offset", None)
        rows = np.flatnonzero(result.nav.valid & np.isfinite(origin))
        if len(rows) == 0:
            return None
        from georef.fusion.ins_layout import UNIT_YAW

        epoch_rows, epoch_sigma = ins_info.epoch_rows, ins_info.epoch_sigma
        value = np.unwrap(np.asarray(origin, float)[rows])
        t = result.nav.time[rows]
        fig, ax = plt.subplots(figsize=(11, 3.8))
        ax.plot(t, np.degrees(value), color="tab:red", label="smoothed origin (filter state)")
        if epoch_rows is not None and epoch_sigma is not None and len(epoch_rows):
            sigma = np.interp(t, result.nav.time[epoch_rows], epoch_sigma[:, UNIT_YAW])
            ax.fill_between(t, np.degrees(value - sigma), np.degrees(value + sigma), color="tab:red", alpha=0.2,
                            label="±1σ")
        if solution is not None:
            w = solution.windows
            ok = w.accepted
            offset = np.degrees(value[0] + wrap_pi(w.offset[ok] - value[0]))
            ax.errorbar(w.time[ok], offset, yerr=np.degrees(w.sigma[ok]), fmt="o", ms=3, color="tab:blue",
                        label="IACC windows (prior)")
        ax.set_ylabel("yaw origin [deg]")
        ax.legend(fontsize=8)
        ax.set_title("true yaw = unit yaw + origin", fontsize=10)
        _finish(fig, ax, result)
        return _png(fig)
    if solution is None:
        return None
    w = solution.windows
    value, sigma = solution.at(result.log.time)
    fig, ax = plt.subplots(figsize=(11, 3.8))
    ok = w.accepted
    ax.errorbar(w.time[ok], wrap_360(np.degrees(w.offset[ok])), yerr=np.degrees(w.sigma[ok]), fmt="o", ms=3,
                label="windows")
    ax.plot(result.log.time, wrap_360(np.degrees(value)), color="tab:red", label="followed offset")
    ax.fill_between(result.log.time, wrap_360(np.degrees(value)) - np.degrees(sigma),
                    wrap_360(np.degrees(value)) + np.degrees(sigma), color="tab:red", alpha=0.2, label="±1σ")
    ax.set_ylabel("yaw offset [deg]")
    ax.legend(fontsize=8)
    ax.set_title("true yaw = unit yaw + offset", fontsize=10)
    _finish(fig, ax, result)
    return _png(fig)


# ---- tables -------------------------------------------------------------------------------------------------
def _verdict(verdict: Verdict) -> str:
    colour = _STATUS_COLOURS["pass" if verdict.passed else "fail"]
    word = "passed" if verdict.passed else "failed"
    reasons = [c for c in verdict.checks if c.status != "pass"]
    lead = (f"{len(verdict.failures)} check(s) failed: do not use the outputs before you have understood them."
            if not verdict.passed else
            f"with {len(verdict.warnings)} warning(s): the outputs are usable; look at the warnings." if reasons
            else "every check passed.")
    rows = [(_Raw(f'<span class="status" style="color:{_STATUS_COLOURS[c.status]}">{html.escape(c.status)}</span>'),
             c.name, c.message) for c in sorted(verdict.checks, key=lambda c: ("fail", "warn", "pass").index(c.status))]
    return (f'<p class="verdict" style="border-color:{colour}"><span style="color:{colour}">QC {word}</span> — '
            f"{html.escape(lead)}</p>"
            + _table(rows, header=("status", "check", "what was found")))


def _summary(result: ProcessResult, accuracy: dict[str, float] | None, gaps: list[tuple[float, float]]) -> str:
    """The run's summary (:meth:`georef.run_summary.RunSummary.rows`), the figures against a reference, the input
    notices, and every figure of the JSON summary no row shows (figures added later are shown, readably)."""
    summary = RunSummary.of(result, imu_gaps=len(gaps))
    placed = summary.placed_rows("report")
    rows: list[tuple[object, object]] = [(row.label, row.text) for row in placed if row.text is not None]
    rows += _accuracy_rows(accuracy or {})
    rows += [("input notice", str(notice)) for notice in result.notices]
    shown = {key for row in placed for key in row.keys}
    rows += [(key.replace("_", " "), readable(value)) for key, value in summary.to_dict().items()
             if key not in shown and value is not None]
    return _table(rows)


def _accuracy_rows(accuracy: dict[str, float]) -> list[tuple[str, str]]:
    """The figures against a reference (``georef.evaluate.accuracy``), units from the keys' suffixes."""
    rows = []
    for key, value in accuracy.items():
        label, unit = key, ""
        for suffix, name in (("_m", "m"), ("_deg", "deg"), ("_s", "s")):
            if key.endswith(suffix):
                label, unit = key[: -len(suffix)], f" [{name}]"
        digits = 4 if unit == " [deg]" else 3
        shown = _number(float(value), digits) if isinstance(value, float | int) else readable(value)
        rows.append((f"against the reference: {label.replace('_', ' ').replace('rms', 'RMS')}{unit}", shown))
    return rows


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _inputs(result: ProcessResult, extra: dict[str, Path | str | None] | None) -> list[tuple[str, Path]]:
    files = [("POS log", Path(result.log.path)), ("exposures", Path(result.exposures.path))]
    files += [(label, Path(p)) for label, p in (extra or {}).items() if p is not None]
    return files


def _provenance(result: ProcessResult, inputs: dict[str, Path | str | None] | None, command: str | None,
                created: dt.datetime) -> str:
    """The software, the date and host, the command; every input file with its size and SHA-256; the mounting and
    the GNSS settings (with what the data showed of them)."""
    return (_table(_software_rows(command, created))
            + "<h3>Input files</h3>" + _table(_file_rows(result, inputs), header=("file", "path", "size", "SHA-256"))
            + "<h3>Mounting and GNSS</h3>" + _table(_mounting_rows(result)))


def _software_rows(command: str | None, created: dt.datetime) -> list[tuple[object, object]]:
    versions = [f"georef {_version('georef')}", f"Python {platform.python_version()}", f"NumPy {np.__version__}"]
    try:
        import pyproj

        versions.append(f"pyproj {pyproj.__version__} (PROJ {pyproj.proj_version_str})")
    except ImportError:  # pragma: no cover - a declared dependency
        pass
    rows: list[tuple[object, object]] = [
        ("software", ", ".join(versions)),
        ("report written", created.strftime("%Y-%m-%d %H:%M:%S UTC")),
        ("host", f"{platform.system()} {platform.machine()}"),
    ]
    if command:
        rows.append(("command", _Raw(f"<code>{html.escape(command)}</code>")))
    return rows


def _file_rows(result: ProcessResult, inputs: dict[str, Path | str | None] | None) -> list[tuple[object, ...]]:
    rows = []
    for label, path in _inputs(result, inputs):
        try:
            size, digest = _size(path.stat().st_size), _sha256(path)
        except OSError as exc:
            size, digest = "—", f"not readable now: {exc.strerror}"
        rows.append((label, _Raw(f"<code>{html.escape(str(path))}</code>"), size,
                     _Raw(f'<code class="hash">{digest}</code>')))
    return rows


def _mounting_rows(result: ProcessResult) -> list[tuple[object, object]]:
    """The lever arms and boresight given, what the data and the graph showed of them, the GNSS sigma, gate and
    latency, the camera's trigger latency and the projected CRS."""
    cfg = result.config
    calibration = getattr(result.nav.diagnostics, "calibration", None)
    mount, gate = cfg.mounting, cfg.gnss_gate.chi2
    rows: list[tuple[object, object]] = [
        ("GNSS lever arm (IMU → antenna)", _triple(mount.lever_arm_gnss, ("x", "y", "z"),
                                                   "m (body: x forward, y right, z down)")),
    ]
    if calibration is not None:
        rows.append(("GNSS lever arm the data show", ", ".join(
            f"{a} {_number(float(v))} ± {_number(float(s))}" for a, v, s in
            zip("xyz", calibration.lever_arm, calibration.lever_arm_sigma, strict=True)) + " m (not applied)"))
    rows += _graph_calibration_rows(result.nav.graph_info)
    rows += [
        ("camera lever arm (IMU → perspective centre)", _triple(mount.lever_arm_camera, ("x", "y", "z"), "m (body)")),
        ("boresight", _triple(mount.boresight, ("roll", "pitch", "yaw"), "deg (C_c_b = Rz(yaw) Ry(pitch) Rx(roll))")),
        ("GNSS σ given", _triple(cfg.gnss.sigma, ("N", "E", "U"), "m", 2)),
        ("innovation gate", f"χ² {gate:g} on the 3-D position innovation ({_gate_probability(gate)}"
                            " of good fixes pass)"),
        ("GNSS latency applied", f"{_number(float(cfg.gnss.latency or 0.0))} s"
         + (f"; the data show {_number(calibration.latency)} ± {_number(calibration.latency_sigma)} s (not applied)"
            if calibration is not None else "")),
        ("camera trigger latency", f"{_number(float(cfg.camera.time_offset))} s"),
        ("projected CRS", cfg.output.crs or "— (geographic coordinates only)"),
    ]
    return rows


def _graph_calibration_rows(graph: object | None) -> list[tuple[object, object]]:
    """``--method graph``: the calibration estimated with the trajectory (applied)."""
    if graph is None:
        return []
    rows: list[tuple[object, object]] = [
        ("GNSS lever arm the graph estimated", ", ".join(
            f"{a} {_number(float(v))} ± {_number(float(s))}" for a, v, s in
            zip("xyz", graph.lever_arm_m, graph.lever_arm_sigma_m, strict=True))
         + " m (applied: the trajectory was solved with it)"),
        ("GNSS time offset the graph estimated", f"{_number(1e3 * float(graph.time_offset_s))} ± "
         f"{_number(1e3 * float(graph.time_offset_sigma_s))} ms (applied)")]
    scale = graph.scale_factors
    if scale is not None:
        prior = float(scale.prior_sigma_ppm)
        for name, values, sigmas in (("gyro", scale.gyro_ppm, scale.gyro_sigma_ppm),
                                     ("accelerometer", scale.accel_ppm, scale.accel_sigma_ppm)):
            rows.append((f"{name} scale factors the graph estimated", ", ".join(
                f"{a} {v:.0f} ± {s:.0f}" + (" (not observed)" if s > 0.8 * prior else "") for a, v, s in
                zip("xyz", values, sigmas, strict=True))
                + f" ppm (prior ± {prior:.0f} ppm; applied)"))
    return rows


def _gate_probability(gate: float) -> str:
    """The share of good fixes a chi-square gate on a 3-D innovation passes, in per cent."""
    return f"{100.0 * chi2_cdf(gate, 3):.2f} %"


def _version(package: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown (not installed)"


_SETTING_UNITS = {
    "lever_arm_gnss": "m, body x/y/z", "lever_arm_camera": "m, body x/y/z", "boresight": "deg, roll/pitch/yaw",
    "gnss_sigma": "m, N/E/U", "gnss_rate_hz": "Hz", "camera_utc_offset": "h", "camera_time_offset": "s",
    "gnss_latency": "s", "magnetic_declination": "deg, east positive", "yaw_window": "s", "yaw_step": "s",
    "yaw_bandwidth": "s", "unit_level_sigma": "deg", "unit_yaw_sigma": "deg", "unit_level_time": "s",
    "unit_angle_noise": "deg", "unit_drift_change": "deg/min/√min", "axis_accel_sigma": "m/s²",
    "axis_bias_sigma": "m/s²", "axis_bias_time": "s", "gate_chi2": "χ², 3 d.o.f.", "covariance_rate": "Hz",
}


def _settings(cfg: ProcessingConfig) -> str:
    rows = []
    for name, value in cfg.settings().items():
        if value is None:
            shown = "— (not set)"
        elif isinstance(value, dict):
            shown = readable(value) if value else "none (defaults)"
        else:
            shown = readable(value)
        rows.append((_Raw(f"<code>{html.escape(name)}</code>"), shown, _SETTING_UNITS.get(name, "")))
    return ("<p>Every setting of the run (<code>flight.toml</code> and command-line options applied over the "
            "defaults).</p>" + _table(rows, header=("setting", "value", "unit")))


def _flagged(table: pd.DataFrame) -> str:
    flagged = table[table["flag"].astype(str) != ""]
    if flagged.empty:
        return "<p>No frame is flagged: every frame has a position, an attitude and their σ.</p>"
    rows = [(str(frame), utc(float(time), 2), flag)
            for frame, time, flag in zip(flagged["frame"], flagged["time"], flagged["flag"].astype(str), strict=True)]
    return (f"<p>{len(flagged)} of {len(table)} frames are flagged (their rows are in the EO table with the same "
            "flag).</p>" + _table(rows, header=("frame", "exposure (UTC)", "flag"), cls="flagged"))


# ---- the page -----------------------------------------------------------------------------------------------
_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1150px; color: #222; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.1em; } h2 { font-size: 1.25em; border-bottom: 1px solid #bbb;
padding-bottom: 0.2em; margin-top: 1.6em; } h3 { font-size: 1.05em; margin-bottom: 0.3em; }
.subtitle { color: #555; margin-top: 0; } nav { font-size: 0.9em; line-height: 1.7; }
nav a { margin-right: 0.9em; white-space: nowrap; } img { max-width: 100%; display: block; }
table { border-collapse: collapse; margin: 0.4em 0; font-size: 0.92em; }
th, td { text-align: left; padding: 0.25em 0.8em; border-bottom: 1px solid #e4e4e4; vertical-align: top; }
thead th { background: #f3f3f3; } tbody th { font-weight: 600; white-space: nowrap; }
table.numbers td { font-variant-numeric: tabular-nums; } .status { font-weight: bold; text-transform: uppercase; }
.verdict { font-size: 1.2em; font-weight: bold; border-left: 6px solid; padding: 0.4em 0.8em; background: #fafafa; }
code { font-size: 0.9em; } code.hash { font-size: 0.8em; word-break: break-all; }
.note { color: #555; font-size: 0.92em; }
"""


def flight_name(result: ProcessResult) -> str:
    """The flight's name: the folder of its POS log (flights are kept one per folder), else the file's stem."""
    path = Path(result.log.path).resolve()
    return path.parent.name or path.stem


def _separation_section(result: ProcessResult) -> str:
    """The forward filter against the smoother (plot and table), or why there is none for the method."""
    separation = _separation(result)
    method = result.nav.method
    if separation is not None:
        return ("<p>The forward filter's solution minus the smoothed one, at the filter's covariance epochs, with "
                "the ±2σ band the filter expects for it (σ² = forward variance − smoothed variance). Stretches "
                "outside the band are where the forward pass and the smoother disagree: a bad fix, an outage, a "
                "mis-modelled motion.</p>" + f'<img src="{separation}" alt="forward minus smoothed">'
                + _separation_table(result))
    if method == "ekf":
        return ("<p>Method ekf is the forward filter alone: there is no smoothed solution to compare with (run "
                "<code>--method rts</code> for it).</p>")
    return (f"<p>Method {html.escape(method)} has no forward filter pass: the separation is available with "
            "<code>--method rts</code>.</p>")


def _plots(result: ProcessResult) -> dict[str, tuple[str, str | None]]:
    """The plotted sections: section key -> (the note over the plot, the plot's data URI or None: not estimated)."""
    return {
        "accuracy": ("1-σ of the IMU position (north, east, up) and attitude, from the solution's covariance; GNSS "
                     "outages shaded.", _accuracy(result)),
        "track": ("Trajectory, GNSS fixes, exposures (red: in a GNSS outage) and rejected fixes.", _track(result)),
        "innovations": ("Each GNSS fix's normalised innovation squared (χ² with 3 degrees of freedom when the model "
                        "holds) against the gate.", _innovations(result)),
        "position": ("Smoothed IMU position and velocity (σ: see “Estimated accuracy over time”).", _position(result)),
        "attitude": ("Camera roll, pitch and yaw at each exposure (ZYX to NED; σ: see “Estimated accuracy over "
                     "time”).", _attitude(result)),
        "biases": ("Estimated gyro and accelerometer biases, body axes.", _biases(result)),
        "yaw-offset": ("The POS unit's yaw origin as the data show it.", _yaw_offset(result)),
    }


def _page(result: ProcessResult, flight: str, verdict: Verdict, body: str) -> str:
    """The whole HTML page around the sections' ``body``: title, subtitle, the units' note, the links."""
    t0, t1 = float(result.log.time[0]), float(result.log.time[-1])
    nav_links = " ".join(f'<a href="#{key}">{html.escape(title)}</a>' for key, title in SECTIONS)
    names = f"{Path(result.log.path).name} + {Path(result.exposures.path).name}"
    subtitle = (f"{names} · method {result.nav.method} · {utc_span(t0, t1, 0)} · {len(result.table)} frames · QC "
                f"{verdict.short()} · georef {_version('georef')}")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>georef quality report: flight {html.escape(flight)}</title>
<style>{_CSS}</style></head><body>
<h1>Quality report: flight {html.escape(flight)}</h1>
<p class="subtitle">{html.escape(subtitle)}</p>
<p class="note">Times are UTC (time of day); units metres, degrees, seconds; σ is one standard deviation.</p>
<nav>{nav_links}</nav>
{body}
</body></html>
"""


def write_report(result: ProcessResult, path: Path | str, accuracy: dict[str, float] | None = None,
                 verdict: Verdict | None = None, inputs: dict[str, Path | str | None] | None = None,
                 command: str | None = None, flight: str | None = None) -> Path:
    """Write the report as one self-contained HTML file (atomically); returns its path.

    ``verdict``: the run's :class:`georef.qc.Verdict` (computed here when not given); ``accuracy``: figures
    against a reference (``georef.evaluate.accuracy``); ``inputs``: further input files to list with their
    hashes, label -> path (e.g. ``{"configuration": "flight.toml"}``), None values skipped; ``command``: the
    command line that made the run; ``flight``: the name in the title (default :func:`flight_name`).
    """
    if verdict is None:
        from georef.qc import assess_result

        verdict = assess_result(result)
    created = dt.datetime.now(dt.UTC)
    flight = flight or flight_name(result)
    gaps = _imu_gaps(result)
    method = result.nav.method
    plots = _plots(result)
    body = []
    for key, title in SECTIONS:
        body.append(f'<section id="{key}"><h2>{html.escape(title)}</h2>')
        if key == "verdict":
            body.append(_verdict(verdict))
        elif key == "summary":
            body.append(_summary(result, accuracy, gaps))
        elif key == "provenance":
            body.append(_provenance(result, inputs, command, created))
        elif key == "flagged":
            body.append(_flagged(result.table))
        elif key == "separation":
            body.append(_separation_section(result))
        elif key == "gnss":
            body.append(f'<img src="{_gnss_status(result, gaps)}" alt="GNSS status and IMU gaps">')
            body.append(_status_table(result) + _gaps_table(gaps))
        elif key == "settings":
            body.append(_settings(result.config))
        else:
            note, image = plots[key]
            if image:
                body.append(f'<p class="note">{html.escape(note)}</p><img src="{image}" alt="{html.escape(title)}">')
            else:
                body.append(f"<p>Not estimated by method {html.escape(method)}.</p>")
        body.append("</section>")
    page = _page(result, flight, verdict, "".join(body))
    with atomic_write(path) as handle:
        handle.write(page)
    return Path(path)
