"""``georef evaluate``: an EO table's accuracy against a reference (:mod:`georef.evaluate`; the tables read and
checked by :mod:`georef_cli.evaluate_inputs`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from ..running import out


def evaluate(
    eo: Annotated[Path, typer.Argument(help="EO table written by georef process ('-': read it from standard "
                                            "input, e.g. piped from georef process -o -).")],
    truth: Annotated[Path, typer.Argument(help="Reference EO table (e.g. truth.csv of georef simulate): frame, "
                                               "time, lat, lon, height, roll, pitch, yaw; same frames, same order.")],
) -> None:
    """Accuracy of an EO table against a reference: RMS and the share of errors inside 2 sigma.

    Both tables are checked first: a missing or non-numeric column, a different number of frames or different
    times are reported with the file, line and column (and arguments given the wrong way round are named so).
    """
    from georef.evaluate import accuracy, frame_errors, sigma_coverage

    from ..evaluate_inputs import read_inputs

    estimate, reference = read_inputs(eo, truth)
    errors = frame_errors(estimate, reference)
    from rich.table import Table

    table = Table(title=escape(f"{eo} against {truth}"), title_justify="left")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for name, value in accuracy(errors).items():
        table.add_row(name, f"{value:.3f}")
    for name, value in sigma_coverage(estimate, errors).items():
        table.add_row(f"inside 2 sigma: {name}", f"{100 * value:.1f} %")
    out.print(table)
