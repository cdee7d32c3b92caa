"""``georef fuse`` once its trajectory is written: the quality checks, the summary JSON, the lines printed and the
exit code (0, or 4 when the quality checks failed)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import typer
from rich.markup import escape

from .output import write_json
from .running import exit_code, messages, print_verdict
from .terminal import filter_rows, target_text

if TYPE_CHECKING:
    from georef.fusion.solution import NavSolution
    from georef.generic_fusion import FuseInputs
    from georef.preflight import FuseRequest


def finish_fuse(request: FuseRequest, cfg: Any, method: str, inputs: FuseInputs, nav: NavSolution, sbets: list[Any],
            quiet: bool) -> None:
    """The quality checks, the summary JSON, the lines printed; exit 4 when QC failed."""
    from georef.pipeline import solution_figures
    from georef.qc import assess

    verdict = assess(nav, cfg=cfg, kind=inputs.kind)
    code = exit_code(verdict)
    figures = solution_figures(nav, cfg.gnss, inputs.ins.gnss.sigma_neu)
    if request.summary_json is not None:
        write_json(request.summary_json, _document(request, cfg, method, inputs, nav, sbets, figures, code, verdict))
    if not quiet:
        _print_run(request, inputs, nav, sbets, figures)
    print_verdict(verdict, quiet)
    if code:
        raise typer.Exit(code=code)


def _document(request: FuseRequest, cfg: Any, method: str, inputs: FuseInputs, nav: NavSolution, sbets: list[Any],
              figures: dict[str, Any], code: int, verdict: Any) -> dict[str, Any]:
    """The ``--summary-json`` document (docs/qc.md)."""
    from georef.io.pos_time_scale import time_scale_summaries

    from .summary import run_document

    fixes = inputs.ins.gnss
    summary = {"method": method, "trajectory_rows": int(nav.valid.sum()), "gnss_fixes": len(fixes),
               "gnss_used": int((nav.gnss.status >= 1).sum()), "gnss_rejected_lines": nav.gnss.rejected_lines,
               **figures, "time_scale": time_scale_summaries(fixes.notices)}
    outputs = [{"what": "trajectory", "format": "csv", "path": str(request.output)}]
    for done in sbets:
        outputs += [{"what": "export", "format": "sbet", "path": str(done.sbet_path)},
                    {"what": "export", "format": "smrmsg", "path": str(done.smrmsg_path)}]
        summary.setdefault("sbet", []).append({**done.summary(), "notes": done.notes})
    return run_document("fuse", code, inputs={**inputs.files, "config": request.configs}, settings=cfg.settings(),
                        outputs=outputs, summary=summary, verdict=verdict)


def _print_run(request: FuseRequest, inputs: FuseInputs, nav: NavSolution, sbets: list[Any],
               figures: dict[str, Any]) -> None:
    """The rows and fixes used, the .pos's time scale, the filter's figures, the SBETs, the readers' notices."""
    from georef.io.pos_time_scale import time_scale_lines

    to, fixes, rejected = messages(request.output, request.summary_json), inputs.ins.gnss, nav.gnss.rejected_lines
    named = f" (lines {', '.join(map(str, rejected[:10]))})" if rejected else ""
    to.print(f"{int(nav.valid.sum())} trajectory rows -> {target_text(request.output)}; GNSS {len(fixes)} fixes, "
             f"{int((nav.gnss.status >= 1).sum())} used, {len(rejected)} rejected{named}", highlight=False,
             soft_wrap=True)
    for line in time_scale_lines(fixes.notices):  # which scale the .pos was put on: GPST and UTC are 18 s apart
        to.print(f"time scale: {escape(line)}", highlight=False, soft_wrap=True)
    for what, text in filter_rows(figures):
        to.print(f"{what}: {text}", highlight=False, soft_wrap=True)
    for done in sbets:
        to.print(f"also wrote sbet -> {escape(str(done.sbet_path))}, smrmsg -> {escape(str(done.smrmsg_path))}; "
                 f"SBET times: GPS week {done.records.gps_week}, from {escape(done.records.time_basis)}",
                 highlight=False, soft_wrap=True)
        for note in done.notes:
            to.print(f"[yellow]warning:[/] {escape(note)}", highlight=False, soft_wrap=True)
    for notice in inputs.reader_notices():  # what the bag or .pos reader converted or skipped: never silent
        to.print(f"[yellow]notice:[/] {escape(str(notice))}", highlight=False, soft_wrap=True)
