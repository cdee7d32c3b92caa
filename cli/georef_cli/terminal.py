"""The run summary on the terminal: the table ``georef process`` prints after a run."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape

from .output import is_stdout

if TYPE_CHECKING:
    from georef.pipeline import ProcessResult
    from georef.run_summary import FilterFigures

#: notices go to standard error, as every other message of the commands
console = Console(stderr=True, soft_wrap=True, emoji=False)


def target_text(path: Path) -> str:
    """Where an output went, as rich markup: the escaped path, or "standard output" for ``-``."""
    return "standard output" if is_stdout(path) else escape(str(path))


def filter_rows(figures: FilterFigures | Mapping[str, Any] | None) -> list[tuple[str, str]]:
    """The terminal's rows of the full-state filters (:func:`georef.run_summary.filter_rows`): heading source, the
    unit's yaw origin, the fitted noise, the ground-vehicle constraints, what the graph estimated; empty for the
    other methods. ``figures``: :class:`georef.run_summary.FilterFigures`, or their JSON keys
    (``georef.pipeline.solution_figures``)."""
    from georef.run_summary import FilterFigures
    from georef.run_summary import filter_rows as run_summary_filter_rows

    if figures is not None and not isinstance(figures, FilterFigures):
        figures = FilterFigures.from_dict(figures)
    return [(row.label, escape(row.text)) for row in run_summary_filter_rows(figures, "terminal")]


def print_summary(result: ProcessResult, output: Path, verbose: bool, to: Console) -> None:
    """The run's summary table (:meth:`georef.run_summary.RunSummary.rows`) on ``to``, then the input notices
    (the first five, every one with ``verbose``) on standard error."""
    from rich.table import Table

    from georef.io.pos_time_scale import time_scale_lines
    from georef.run_summary import RunSummary

    # a .pos's scale, GPST vs UTC: a row of its own, never only a notice cut off
    summary = RunSummary.of(result, time_scale_lines=time_scale_lines(result.notices))
    table = Table(title=f"georef process ({escape(str(summary.method))}) -> {target_text(output)}",
                  show_header=False, title_justify="left")
    table.add_column("what", style="bold")
    table.add_column("value")
    for row in summary.rows("terminal"):
        table.add_row(row.label, escape(row.text))
    to.print(table)
    notices = result.notices
    if notices:
        shown = notices if verbose else notices[:5]
        for notice in shown:
            console.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False)
        if len(notices) > len(shown):
            console.print(f"[yellow]notice:[/] ... {len(notices) - len(shown)} more (use --verbose)")
