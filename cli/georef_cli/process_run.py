"""``georef process`` once its options are checked (:func:`georef.pipeline.preflight`): the run with its stage
progress, the outputs written together (the EO table, the exports, SBETs, image copies, the report: all or none),
the summary JSON, the lines printed and the exit code (0, or 4 when the quality checks failed)."""

from __future__ import annotations

import contextlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer
from rich.markup import escape

from .handoffs import export_images, process_sbet_clock, with_image_checks
from .output import is_stdout, write_json, write_target
from .running import console, exit_code, messages, print_verdict, stage_progress
from .terminal import print_summary

if TYPE_CHECKING:
    from georef.pipeline import ProcessResult
    from georef.preflight import ProcessPlan, ProcessRequest


@dataclass(frozen=True)
class Written:
    """What a run wrote besides its EO table and exports: the SBETs and image copies (their hand-off results),
    and the quality checks' verdict with the image checks."""

    verdict: Any
    sbets: list[Any]
    images: list[Any]


def run_process(plan: ProcessPlan, request: ProcessRequest, quiet: bool, verbose: bool) -> None:
    """Run ``plan``, write its outputs, the summary JSON and the run's summary; exit 4 when QC failed."""
    progress, step = stage_progress(quiet, total=5 if request.report is not None else 4)
    with progress if progress is not None else contextlib.nullcontext():
        result = plan.run(step)
        written = write_outputs(plan, request, result, step)
    code = exit_code(written.verdict)
    if request.summary_json is not None:
        write_json(request.summary_json, _document(plan, request, result, written, code))
    if not quiet:
        _print_outputs(plan, request.summary_json, result, written, verbose)
    print_verdict(written.verdict, quiet)
    if code:
        raise typer.Exit(code=code)


def write_outputs(plan: ProcessPlan, request: ProcessRequest, result: ProcessResult, step: Any) -> Written:
    """The files and the report together, or none of them (a full disk, a refused target); standard output last,
    once the files are in place."""
    from georef.io.atomic import atomic_group
    from georef.io.exports import write_export
    from georef.qc import assess_result

    files, time_scale = plan.source.files, plan.source.inputs.time_scale
    sbet_day = process_sbet_clock(result, request.utc_date, files, time_scale) if plan.sbet_specs else None
    sbets: list[Any] = []

    def write(spec: Any) -> None:
        if spec.fmt == "sbet":
            from georef.io.sbet import imu_rows_of_log, write_sbet

            sbets.append(write_sbet(result.nav, imu_rows_of_log(result.log), spec.path, sbet_day, request.sbet_rate))
            return
        write_target(spec.path, lambda path: write_export(result.columns, path, spec.fmt, frames=result.frames,
                                                          odm_angles=plan.cfg.output.odm_angles))

    with atomic_group():
        step("writing table" if len(plan.specs) == 1 else f"writing {len(plan.specs)} outputs")
        for spec in plan.specs:
            if not is_stdout(spec.path):
                write(spec)
        images = [export_images(result, request.images, target, request.camera_clock_offset, request.utc_date,
                                files, time_scale) for target in plan.image_targets]
        verdict = with_image_checks(assess_result(result), images)
        if request.report is not None:
            _write_report(result, request, verdict, step)
    for spec in plan.specs:
        if is_stdout(spec.path):
            write(spec)
    return Written(verdict, sbets, images)


def _write_report(result: ProcessResult, request: ProcessRequest, verdict: Any, step: Any) -> None:
    """The HTML quality report, with the configuration files and the command as typed (when run as georef)."""
    import shlex

    from georef.report import write_report

    step("writing report")
    command = shlex.join(["georef", *sys.argv[1:]]) if Path(sys.argv[0]).name == "georef" else None
    configs = request.configs or []
    inputs = {f"configuration {i + 1}" if len(configs) > 1 else "configuration": path
              for i, path in enumerate(configs)}
    write_report(result, request.report, verdict=verdict, inputs=inputs, command=command)


def _document(plan: ProcessPlan, request: ProcessRequest, result: ProcessResult, written: Written,
              code: int) -> dict[str, Any]:
    """The ``--summary-json`` document (docs/qc.md)."""
    from georef.io.pos_time_scale import time_scale_summaries

    from .summary import run_document

    outputs = [{"what": "table" if index == 0 else "export", "format": spec.fmt, "path": str(spec.path)}
               for index, spec in enumerate(plan.specs)]
    if request.report is not None:
        outputs.append({"what": "report", "format": "html", "path": str(request.report)})
    outputs += [{"what": "export", "format": "smrmsg", "path": str(done.smrmsg_path)} for done in written.sbets]
    outputs += [{"what": "export", "format": "images", "path": str(done.target_dir)} for done in written.images]
    summary = result.summary()
    summary["time_scale"] = time_scale_summaries(result.notices)  # the .pos files' scale, [] for none
    if written.images:
        summary["images"] = [done.to_dict() for done in written.images]
    if written.sbets:
        summary["sbet"] = [{**done.summary(), "notes": done.notes} for done in written.sbets]
    return run_document("process", code, inputs={**plan.source.files, "config": request.configs},
                        settings=result.config.settings(), outputs=outputs, summary=summary, verdict=written.verdict)


def _print_outputs(plan: ProcessPlan, summary_json: Path | None, result: ProcessResult, written: Written,
                   verbose: bool) -> None:
    """The run's summary table, then every other file written, and the warnings."""
    output = plan.specs[0].path
    to = messages(output, summary_json, *(spec.path for spec in plan.specs[1:]))
    print_summary(result, output, verbose, to)
    for spec in plan.specs[1:]:
        to.print(f"also wrote {escape(spec.fmt)} -> {escape(str(spec.path))}", highlight=False)
    for done in written.sbets:
        to.print(f"also wrote smrmsg -> {escape(str(done.smrmsg_path))}; SBET times: GPS week "
                 f"{done.records.gps_week}, from {escape(done.records.time_basis)}", highlight=False)
        for note in done.notes:
            console.print(f"[yellow]warning:[/] {escape(note)}", highlight=False)
    for done in written.images:
        for line in done.lines():
            to.print(escape(line), highlight=False)
    for warning in result.summary()["geodesy_warnings"]:
        console.print(f"[yellow]warning:[/] {escape(str(warning))}", highlight=False)
