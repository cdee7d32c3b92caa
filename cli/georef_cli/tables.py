"""Tables the commands print: (what, value) rows (``georef info``), a batch summary's cells, and a campaign's
calibration with each flight's own estimate (``georef batch --shared-calibration``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rich.markup import escape

from .running import console, messages, out


def print_rows(title: str, rows: list[tuple[str, str]]) -> None:
    """A two-column table of (what, value) rows on standard output."""
    from rich.table import Table

    table = Table(title=escape(title), show_header=False, title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    for what, value in rows:
        table.add_row(escape(what), escape(value))
    out.print(table)


def cell(value: Any) -> str:
    """A summary value as table text: empty for None/NaN/NA."""
    if value is None:
        return ""
    try:
        import pandas as pd

        if pd.isna(value):
            return ""
    except (TypeError, ValueError):
        pass
    return str(value)


def print_campaign(calibration: dict, summary_json: Path | None) -> None:
    """The campaign's calibration (lever arm [m, body], GNSS time offset [ms]) and each flight's own estimate, as
    a table; a notice where the flights' data removed little of the prior's variance."""
    def fmt(values, sigmas, scale: float = 1.0, digits: int = 3) -> str:
        values, sigmas = np.atleast_1d(values), np.atleast_1d(sigmas)
        return ", ".join("-" if v is None else f"{v * scale:.{digits}f} ± {s * scale:.{digits}f}"
                         for v, s in zip(values, sigmas, strict=True))

    from rich.table import Table

    table = Table(title=escape(f"campaign calibration ({calibration['rounds']} rounds): lever arm [m, body x y z], "
                               "GNSS time offset [ms]"), title_justify="left")
    for column in ("flight", "lever arm [m]", "time offset [ms]", "chi2 (dof)", "consistent"):
        table.add_column(escape(column))
    table.add_row("campaign", fmt(calibration["gnss_lever_arm_m"], calibration["gnss_lever_arm_sigma_m"]),
                  fmt(calibration["gnss_time_offset_s"], calibration["gnss_time_offset_sigma_s"], 1e3, 1), "", "")
    for name, flight in calibration["flights"].items():
        lever = [v if v is not None else np.nan for v in flight["gnss_lever_arm_m"]]
        lever_sigma = [v if v is not None else np.nan for v in flight["gnss_lever_arm_sigma_m"]]
        offset = flight["gnss_time_offset_s"] if flight["gnss_time_offset_s"] is not None else np.nan
        offset_sigma = flight["gnss_time_offset_sigma_s"] if flight["gnss_time_offset_sigma_s"] is not None else np.nan
        table.add_row(escape(name), fmt(lever, lever_sigma), fmt(offset, offset_sigma, 1e3, 1),
                      f"{flight['chi2']:.1f} ({flight['dof']})",
                      "yes" if flight["consistent"] else "[bold red]NO[/]")
    messages(summary_json).print(table)
    from georef.campaign import WEAK_DATA_SHARE

    names = ("lever arm x", "lever arm y", "lever arm z", "time offset")
    weak = [f"{name} ({100 * share:.0f} %)" for name, share in zip(names, calibration.get("data_share", [1.0] * 4),
                                                                     strict=True) if share < WEAK_DATA_SHARE]
    if weak:
        console.print(f"[yellow]notice:[/] the flights' data removed little of the configured prior's variance on "
                      f"{', '.join(weak)}: those campaign values are mostly the prior handed back, not a measured "
                      "calibration (longer flights, turns and speed changes observe them)", highlight=False)
