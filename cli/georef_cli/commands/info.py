"""``georef info``: what a log holds (an autopilot log, POS.txt, a ROS bag or an RTKLIB/Emlid .pos; the
descriptions are the readers')."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from georef.config import load_configs

from ..options import ConfigFile, ImuInstance
from ..running import console, out
from ..tables import print_rows


def info(
    pos: Annotated[Path, typer.Argument(help="The log: an autopilot log (ArduPilot .bin/.log, PX4 .ulg, gzip too), "
                                             "a POS unit's POS.txt, a ROS bag (.bag, a ROS 2 bag's folder) or an "
                                             "RTKLIB/Emlid .pos solution (gzip too).")],
    config: ConfigFile = None,
    gnss_rate: Annotated[float | None, typer.Option(help="GNSS fix rate in Hz, if known (default: the config's, "
                                                         "else 1).")] = None,
    imu_instance: ImuInstance = None,
) -> None:
    """Describe a log: for an autopilot log its vehicle, span, IMU streams, GNSS fixes and accuracy, clock, camera
    events and lever-arm parameters; for POS.txt its format, span, rates, GNSS epochs and gaps, quirks repaired,
    columns found; for an RTKLIB/Emlid .pos its layout, time system (GPST: the leap seconds), span, epochs, gaps
    and solution qualities."""
    from georef.io.logs import read_flight_log, sniff
    from georef.io.pos import read_pos
    from georef.io.rosbag import describe_bag, is_bag

    if is_bag(pos):  # a ROS bag: its topics, and which ones --bag reads
        print_rows(str(pos), describe_bag(pos))
        return
    from georef.io.rtklib import check_not_headerless, describe_pos, is_rtklib_pos

    if is_rtklib_pos(pos):  # an RTKLIB/Emlid .pos (gzip too): its time system, span, qualities
        print_rows(str(pos), describe_pos(pos))
        return
    check_not_headerless(pos)
    if sniff(pos) is not None:
        from georef.io.logs.flightlog import describe

        flight = read_flight_log(pos, imu_instance)
        print_rows(str(pos), describe(flight))
        for notice in flight.notices:
            console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)
        return
    cfg = load_configs(config)
    rate = gnss_rate if gnss_rate is not None else cfg.gnss.rate_hz
    log = read_pos(pos, column_names=cfg.pos_columns.names, gnss_rate_hz=rate)
    from rich.table import Table

    table = Table(title=escape(str(pos)), show_header=False, title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    if log.dialect is not None:
        table.add_row("format", escape(log.dialect.describe()))
    table.add_row("rows", f"{len(log)} at {log.sample_rate_hz:.2f} Hz")
    table.add_row("time span", f"{log.time[0]:.3f} - {log.time[-1]:.3f} s UTC of day "
                  f"({log.time[-1] - log.time[0]:.1f} s)")
    table.add_row("GNSS epochs", f"{len(log.gnss)}, {len(log.gnss.gaps())} gaps")
    for start, end in log.gnss.gaps()[:10]:
        table.add_row("GNSS gap", f"{start:.0f} - {end:.0f} s")
    table.add_row("time quirks repaired", str(log.time_repairs.n_quirks))
    table.add_row("columns found", escape(", ".join(f"{role}={name}" for role, name in log.column_names.items())))
    out.print(table)
    for notice in log.notices:
        console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)
