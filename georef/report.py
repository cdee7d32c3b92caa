"""A quality-control report: one self-contained HTML page with PNG plots beside it.

Sections: the quality checks and their verdict (:mod:`georef.qc`), ground track (stations, GNSS outages,
rejected fixes), position and velocity per axis, attitude with ±σ bands, innovations against the χ² gate,
estimated sensor biases, the recovered yaw offset, and a summary table of the figures.
``georef process --report out.html`` writes it.
"""

from __future__ import annotations

import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from georef.frames import C_e_n, wrap_360, wrap_pi  # noqa: E402
from georef.io.atomic import atomic_write  # noqa: E402

SECTIONS = [
    ("qc", "Quality checks"),
    ("track", "Ground track"),
    ("position", "Position and velocity"),
    ("attitude", "Attitude with ±σ"),
    ("innovations", "GNSS innovations and the χ² gate"),
    ("biases", "Estimated sensor biases"),
    ("yaw-offset", "Recovered yaw offset of the POS unit"),
    ("summary", "Summary"),
]


def _save(fig, folder: Path, name: str) -> str:
    path = folder / name
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return name


def _relative_time(result, t: np.ndarray) -> np.ndarray:
    return t - result.log.time[0]


def _track(result, folder: Path, stem: str) -> str:
    nav, table, gnss = result.nav, result.table, result.log.gnss
    valid = nav.valid
    fig, ax = plt.subplots(figsize=(8, 6))
    ax.plot(np.degrees(nav.lon[valid]), np.degrees(nav.lat[valid]), color="0.4", lw=1, label="trajectory (IMU)")
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
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Ground track")
    return _save(fig, folder, f"{stem}_track.png")


def _position(result, folder: Path, stem: str) -> str:
    nav = result.nav
    v = nav.valid
    t = _relative_time(result, nav.time)
    r0 = nav.r_e[v][0]
    C = C_e_n(nav.lat[v][0], nav.lon[v][0])
    ned = (nav.r_e[v] - r0) @ C.T
    sigma = np.sqrt(nav.pos_var_n[v])
    v_n = nav.v_n[v]
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    for k, name in enumerate(("north", "east", "down")):
        axes[k, 0].plot(t[v], ned[:, k], lw=1)
        axes[k, 0].set_ylabel(f"{name} [m]")
        ax2 = axes[k, 0].twinx()
        ax2.plot(t[v], sigma[:, k], color="tab:orange", lw=0.8)
        ax2.set_ylabel("σ [m]", color="tab:orange")
        axes[k, 1].plot(t[v], v_n[:, k], lw=1)
        axes[k, 1].set_ylabel(f"v {name} [m/s]")
    axes[2, 0].set_xlabel("time since start [s]")
    axes[2, 1].set_xlabel("time since start [s]")
    fig.suptitle("IMU position relative to the start (σ in orange) and velocity, NED")
    return _save(fig, folder, f"{stem}_position.png")


def _attitude(result, folder: Path, stem: str) -> str:
    table = result.table[result.table["lat"].notna()]
    t = _relative_time(result, table["time"].to_numpy())
    fig, axes = plt.subplots(3, 1, figsize=(11, 7), sharex=True)
    for ax, name in zip(axes, ("roll", "pitch", "yaw"), strict=True):
        value = table[name].to_numpy()
        if name == "yaw":
            value = np.unwrap(np.radians(value))
            value = np.degrees(value)
        sigma = table[f"sigma_{name}"].to_numpy()
        ax.plot(t, value, lw=1)
        ax.fill_between(t, value - sigma, value + sigma, alpha=0.4, color="tab:orange", label="±σ")
        ax.set_ylabel(f"{name} [deg]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time since start [s]")
    fig.suptitle("Camera attitude at the exposures (ZYX to NED) with ±σ")
    return _save(fig, folder, f"{stem}_attitude.png")


def _innovations(result, folder: Path, stem: str) -> str:
    gnss = result.nav.gnss
    used = gnss.status >= 0
    t = _relative_time(result, gnss.time)
    statistic = gnss.normalised_innovation_sq
    fig, ax = plt.subplots(figsize=(11, 4))
    ax.semilogy(t[used & (gnss.status >= 1)], statistic[used & (gnss.status >= 1)], ".", label="used")
    rejected = gnss.status == 0
    if rejected.any():
        ax.semilogy(t[rejected], statistic[rejected], "x", color="tab:red", ms=9, label="rejected")
    ax.axhline(result.config.gate_chi2, color="black", ls="--", label=f"χ² gate {result.config.gate_chi2:g}")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("normalised innovation² [-]")
    ax.legend(fontsize=8)
    ax.set_title("GNSS position innovations")
    return _save(fig, folder, f"{stem}_innovations.png")


def _biases(result, folder: Path, stem: str) -> str | None:
    info = result.nav.info
    if "gyro_bias" not in info:
        return None
    v = result.nav.valid
    t = _relative_time(result, result.nav.time[v])
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for k, axis in enumerate("xyz"):
        axes[0].plot(t, np.degrees(info["gyro_bias"][v, k]) * 3600.0, label=axis)
        axes[1].plot(t, info["accel_bias"][v, k] / 9.80665 * 1000.0, label=axis)
    axes[0].set_ylabel("gyro bias [deg/h]")
    axes[1].set_ylabel("accelerometer bias [mg]")
    axes[1].set_xlabel("time since start [s]")
    axes[0].legend(fontsize=8)
    fig.suptitle("Estimated IMU biases (smoothed)")
    return _save(fig, folder, f"{stem}_biases.png")


def _yaw_offset(result, folder: Path, stem: str) -> str | None:
    """The POS unit's yaw origin: the axis method's followed offset, or the full-state filter's smoothed origin
    state with its sigma (and the windows recovered from IACC that gave its prior, when there were)."""
    info = result.nav.info
    solution = info.get("yaw_offset")
    diagnostics = result.nav.diagnostics
    origin = info.get("unit_yaw_origin")
    if solution is None and diagnostics is not None and origin is not None and diagnostics.unit_aiding:
        solution = getattr(diagnostics.alignment, "yaw_offset", None)
        rows = np.flatnonzero(result.nav.valid & np.isfinite(origin))
        if len(rows) == 0:
            return None
        from georef.fusion.ins_layout import UNIT_YAW

        epoch_rows, epoch_sigma = info.get("epoch_rows"), info.get("epoch_sigma")
        value = np.unwrap(np.asarray(origin, float)[rows])
        t = _relative_time(result, result.nav.time[rows])
        fig, ax = plt.subplots(figsize=(11, 4))
        ax.plot(t, np.degrees(value), color="tab:red", label="smoothed origin (filter state)")
        if epoch_rows is not None and epoch_sigma is not None and len(epoch_rows):
            sigma = np.interp(result.nav.time[rows], result.nav.time[epoch_rows], epoch_sigma[:, UNIT_YAW])
            ax.fill_between(t, np.degrees(value - sigma), np.degrees(value + sigma), color="tab:red", alpha=0.2,
                            label="1 sigma")
        if solution is not None:
            w = solution.windows
            ok = w.accepted
            offset = np.degrees(value[0] + wrap_pi(w.offset[ok] - value[0]))
            ax.errorbar(_relative_time(result, w.time[ok]), offset, yerr=np.degrees(w.sigma[ok]), fmt="o", ms=3,
                        color="tab:blue", label="IACC windows (prior)")
        ax.set_xlabel("time since start [s]")
        ax.set_ylabel("yaw origin [deg]")
        ax.legend(fontsize=8)
        ax.set_title("Yaw origin of the POS unit: true yaw = unit yaw + origin")
        return _save(fig, folder, f"{stem}_yaw_offset.png")
    if solution is None:
        return None
    w = solution.windows
    t = _relative_time(result, result.log.time)
    value, sigma = solution.at(result.log.time)
    fig, ax = plt.subplots(figsize=(11, 4))
    ok = w.accepted
    tw = _relative_time(result, w.time)
    ax.errorbar(tw[ok], wrap_360(np.degrees(w.offset[ok])), yerr=np.degrees(w.sigma[ok]), fmt="o", ms=3,
                label="windows")
    ax.plot(t, wrap_360(np.degrees(value)), color="tab:red", label="followed offset")
    ax.fill_between(t, wrap_360(np.degrees(value)) - np.degrees(sigma), wrap_360(np.degrees(value)) + np.degrees(sigma),
                    color="tab:red", alpha=0.2)
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("yaw offset [deg]")
    ax.legend(fontsize=8)
    ax.set_title("Yaw origin of the POS unit: true yaw = unit yaw + offset")
    return _save(fig, folder, f"{stem}_yaw_offset.png")


_STATUS_COLOURS = {"pass": "#1a7f37", "warn": "#9a6700", "fail": "#cf222e"}


def _quality_checks(verdict) -> str:
    """The verdict and one row per check (status, name, message) as HTML."""
    colour = _STATUS_COLOURS["pass" if verdict.passed else "fail"]
    rows = "".join(f'<tr><td style="color:{_STATUS_COLOURS[c.status]};font-weight:bold">{html.escape(c.status)}</td>'
                   f"<th>{html.escape(c.name)}</th><td>{html.escape(c.message)}</td></tr>" for c in verdict.checks)
    return (f'<p class="verdict" style="color:{colour};font-weight:bold">QC {html.escape(verdict.short())}</p>'
            f"<table>{rows}</table>")


def write_report(result, path: Path | str, accuracy: dict[str, float] | None = None, verdict=None) -> Path:
    """Write the HTML report and its PNG plots (``<stem>_*.png`` beside it); returns the HTML path.

    ``verdict``: the run's :class:`georef.qc.Verdict` (computed here when not given)."""
    if verdict is None:
        from georef.qc import assess_result

        verdict = assess_result(result)
    path = Path(path)
    folder = path.parent
    folder.mkdir(parents=True, exist_ok=True)
    stem = path.stem
    images = {"track": _track(result, folder, stem), "position": _position(result, folder, stem),
              "attitude": _attitude(result, folder, stem), "innovations": _innovations(result, folder, stem),
              "biases": _biases(result, folder, stem), "yaw-offset": _yaw_offset(result, folder, stem)}
    summary = result.summary()
    rows = [(key.replace("_", " "), value) for key, value in summary.items()]
    table = result.table
    valid = table[table["sigma_n"].notna()]
    if len(valid):
        rows += [("median σ north/east/up [m]", f"{valid['sigma_n'].median():.3f} / {valid['sigma_e'].median():.3f} / "
                                                 f"{valid['sigma_u'].median():.3f}"),
                 ("median σ roll/pitch/yaw [deg]", f"{valid['sigma_roll'].median():.4f} / "
                                                    f"{valid['sigma_pitch'].median():.4f} / "
                                                    f"{valid['sigma_yaw'].median():.4f}")]
    for key, value in (accuracy or {}).items():
        rows.append((f"against reference: {key}", f"{value:.4f}"))

    def fmt(value: object) -> str:
        if isinstance(value, float):
            return f"{value:.4f}"
        if isinstance(value, tuple | list) and len(value) > 12:
            return f"{len(value)} items: " + ", ".join(map(str, value[:12])) + " ..."
        return str(value)

    body = []
    for key, title in SECTIONS:
        body.append(f'<section id="{key}"><h2>{html.escape(title)}</h2>')
        if key == "qc":
            body.append(_quality_checks(verdict))
        elif key == "summary":
            body.append("<table>" + "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(fmt(v))}</td></tr>"
                                            for k, v in rows) + "</table>")
        elif images.get(key):
            body.append(f'<img src="{html.escape(images[key])}" alt="{html.escape(title)}">')
        else:
            body.append("<p>Not estimated by this method.</p>")
        body.append("</section>")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>georef report: {html.escape(path.stem)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 1100px; color: #222; }}
h1 {{ font-size: 1.6em; }} h2 {{ font-size: 1.2em; border-bottom: 1px solid #ccc; padding-bottom: 0.2em; }}
img {{ max-width: 100%; }} table {{ border-collapse: collapse; }}
th, td {{ text-align: left; padding: 0.2em 0.8em; border-bottom: 1px solid #eee; vertical-align: top; }}
</style></head><body>
<h1>georef quality report — {html.escape(str(result.log.path.name))}, method {html.escape(result.nav.method)}</h1>
<p>{len(table)} frames, {int((table['flag'].astype(str) != '').sum())} flagged; units: metres, degrees, seconds.</p>
{''.join(body)}
</body></html>
"""
    with atomic_write(path) as handle:
        handle.write(page)
    return path
