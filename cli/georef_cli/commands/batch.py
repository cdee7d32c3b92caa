"""``georef batch``: many flights, one Dask task each (:func:`georef.batch.run_batch`); the options checked by
:func:`georef.pipeline.preflight`, the summary table and the failures printed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from ..options import BatchMethod, Quiet, SummaryJson, output_option, plain
from ..output import write_json
from ..running import EXIT_INTERNAL_ERROR, EXIT_QC_FAILED, EXIT_USER_ERROR, console, messages
from ..tables import cell, print_campaign

if TYPE_CHECKING:
    import pandas as pd

    from georef.preflight import BatchPlan


def batch(
    source: Annotated[Path, typer.Argument(help="A folder of flight folders (POS.txt, Kamera.txt, flight.toml each) "
                                                "or a manifest CSV with columns flight, pos, camera[, config].")],
    output: Annotated[Path, output_option("Output folder: <flight>/eo.csv, <flight>/georef.log, batch_summary.csv.",
                                          stdout=False)] = Path("batch_out"),
    method: BatchMethod = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address, e.g. tcp://host:8786; default: a "
                                                       "LocalCluster on this machine.")] = None,
    workers: Annotated[int, typer.Option(help="LocalCluster worker processes (one thread each).")] = 2,
    export: Annotated[list[str] | None, typer.Option(
        "--export", help="Also write, in every flight's folder, FORMAT (metashape, pix4d, odm, parge, geojson, kml; "
                         "default file names metashape.csv, pix4d.csv, geo.txt, parge.txt, stations.geojson, "
                         "stations.kml) or FORMAT:NAME; repeatable. CRS, heights and image names come from each "
                         "flight's flight.toml. images[:NAME] writes geotagged copies of each flight's photos "
                         "(its folder images/, or the manifest's images column) into NAME (default images).")] = None,
    shared_calibration: Annotated[bool, typer.Option(
        "--shared-calibration", help="With --method graph: estimate one GNSS lever arm [m, body] and time offset "
                                     "[s] from all flights (one installation), re-solve every flight with it, and "
                                     "flag flights that disagree (chi-square); writes calibration.json and "
                                     "calibration.toml (give it to process or fuse as a second --config).")] = False,
    quiet: Quiet = False,
    summary_json: SummaryJson = None,
) -> None:
    """Process many flights, one Dask task each; a failed flight is reported and the others go on.

    Exit code 0 when every flight ran and passed its quality checks; else 3 when any flight failed with an internal
    error (a bug in georef, a worker that died), else 2 when any flight failed to run on its input, else 4 when
    any flight's quality checks failed (docs/qc.md). The other flights' outputs are written in every case.
    """
    from georef.batch import SUMMARY_COLUMNS, discover
    from georef.preflight import BatchRequest, preflight

    from ..summary import batch_document, batch_exit_code

    method = plain(method)
    plan = preflight(BatchRequest(output, export or [], method, shared_calibration))
    jobs = discover(source)
    settings = {"method": method, "scheduler": scheduler, "workers": workers,
                "exports": [f"{fmt}:{name}" for fmt, name in plan.exports], "shared_calibration": shared_calibration}
    rows, summary = _run_flights(jobs, output, plan, settings, quiet)
    code = batch_exit_code(rows, EXIT_USER_ERROR, EXIT_INTERNAL_ERROR, EXIT_QC_FAILED)
    outputs = [{"what": "summary", "format": "csv", "path": str(output / "batch_summary.csv")}]
    calibration_file = output / "calibration.json"
    if shared_calibration and calibration_file.exists():
        outputs += [{"what": "calibration", "format": "json", "path": str(calibration_file)},
                    {"what": "calibration config", "format": "toml", "path": str(output / "calibration.toml")}]
    if summary_json is not None:
        write_json(summary_json, batch_document(
            code, source=source, settings=settings, rows=rows, columns=SUMMARY_COLUMNS, outputs=outputs))
    if not quiet and len(outputs) > 1:
        print_campaign(json.loads(calibration_file.read_text(encoding="utf-8")), summary_json)
    if not quiet:
        _print_table(summary, output, summary_json)
    _print_failures(summary)
    if code:
        raise typer.Exit(code=code)


def _run_flights(jobs: list[Any], output: Path, plan: BatchPlan, settings: dict[str, Any],
                 quiet: bool) -> tuple[list[dict], pd.DataFrame]:
    """Run every flight (a progress bar of flights unless ``quiet``): each flight's summary row, in the order of
    ``jobs``, and the batch's summary table."""
    from georef.batch import run_batch

    rows: list[dict] = []

    def keep(row: dict) -> None:  # a campaign's earlier rounds are superseded by its last
        rows[:] = [r for r in rows if r["flight"] != row["flight"]] + [row]

    def run(on_done: Any) -> pd.DataFrame:
        return run_batch(jobs, output, method=settings["method"], scheduler=settings["scheduler"],
                         workers=settings["workers"], on_done=on_done, exports=plan.exports,
                         shared_calibration=settings["shared_calibration"])

    if quiet:
        summary = run(keep)
    else:
        from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                            TextColumn("{task.completed}/{task.total} flights"), TimeElapsedColumn(),
                            console=console, transient=True)
        with progress:
            task = progress.add_task("processing flights", total=len(jobs))

            current = {"round": 1}

            def done(row: dict) -> None:
                keep(row)
                step = f"round {row['round']}: " if "round" in row else ""
                if row.get("round", 1) != current["round"]:  # a campaign's next round
                    current["round"] = row["round"]
                    progress.reset(task, total=len(jobs))
                progress.advance(task)
                progress.update(task, description=f"{step}{escape(str(row['flight']))}: "
                                                  f"{escape(str(row['status']))}")

            summary = run(done)
    order = {job.flight: i for i, job in enumerate(jobs)}
    rows.sort(key=lambda row: order.get(row["flight"], len(order)))
    return rows, summary


def _print_table(summary: pd.DataFrame, output: Path, summary_json: Path | None) -> None:
    """The batch summary's main columns, one row a flight."""
    shown = ("flight", "status", "method", "frames", "rejected_fixes", "qc", "runtime_s", "message")
    from rich.table import Table

    table = Table(title=f"georef batch -> {escape(str(output))}/batch_summary.csv", title_justify="left")
    for column in shown:
        table.add_column(column)
    for row in summary.itertuples(index=False):
        table.add_row(*(escape(cell(getattr(row, c))) for c in shown))
    messages(summary_json).print(table)


def _print_failures(summary: pd.DataFrame) -> None:
    """Every flight that failed (an internal error, or its input) and every failed quality check, on stderr."""
    failed = summary[summary["status"] != "ok"]
    for row in failed.itertuples(index=False):
        if row.failure == "internal":
            console.print(f"[bold red]internal error:[/] {escape(str(row.flight))}: {escape(str(row.message))}. "
                          "This is a bug in georef; please report it with the flight's georef.log (it has the "
                          "traceback).", highlight=False)
        else:
            console.print(f"[bold red]failed:[/] {escape(str(row.flight))}: {escape(str(row.message))}",
                          highlight=False)
    qc_failed = summary[summary["qc"].fillna("").astype(str).str.startswith("failed")]
    for row in qc_failed.itertuples(index=False):
        console.print(f"[bold red]QC failed:[/] {escape(str(row.flight))}: {escape(str(row.qc_details))}",
                      highlight=False)
