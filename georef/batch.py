"""Batch processing of many flights on Dask distributed (``georef batch``).

Input: a folder of flight folders (each with ``POS.txt``, ``Kamera.txt`` or a raw camera log, and optionally
``flight.toml``), or a manifest CSV with columns ``flight, pos, camera[, config]`` (paths relative to the
manifest). Each flight is one task: by default on a ``LocalCluster`` of worker processes on this machine, or
on an existing cluster given by its scheduler address. A failed flight is reported with its reason and the
others go on. Every flight gets ``<out>/<flight>/eo.csv``, the exports asked for (``exports``: formats and file
names, :func:`georef.io.exports.parse_folder_export`, written with the table all-or-nothing) and
``<out>/<flight>/georef.log``; the batch writes ``<out>/batch_summary.csv``. A flight's CRS, heights and image
names come from its own ``flight.toml``.

Each flight's quality checks (:mod:`georef.qc`) run on the worker and come back as plain text in the row:
``qc`` is ``"passed"`` or ``"failed: <check names>"`` (empty when the flight did not run), ``qc_details`` the
failing and warning checks' messages, one ``"<status> <name>: <message>"`` each, joined by ``" | "``.

A flight that did not run has ``status`` ``"failed"`` and ``failure`` ``"input"`` (its input or configuration is
wrong: a :class:`~georef.io.errors.GeorefError`, ``ValueError``, ``KeyError`` or ``OSError``, the errors the CLI
reports as exit code 2) or ``"internal"`` (anything else, a bug in georef, or a worker that died: exit code 3).
The row dictionaries that :func:`process_flight` returns (and ``on_done`` of :func:`run_batch` receives) carry
three more entries that the CSV summary leaves out: ``checks`` (the verdict's checks as dictionaries, ``None``
when the flight did not run), ``summary`` (:meth:`georef.pipeline.ProcessResult.summary`, ``None`` likewise) and
``outputs`` (the files written for the flight: ``what``, ``format``, ``path``).
"""

from __future__ import annotations

import json
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from georef.io.atomic import atomic_write
from georef.io.errors import GeorefError, InputError

if TYPE_CHECKING:
    from georef.config import ProcessingConfig
    from georef.frames.heights import OutputFrames
    from georef.io.exports import ExportSpec
    from georef.pipeline import ProcessResult

SUMMARY_COLUMNS = ["flight", "status", "method", "frames", "frames_flagged", "gnss_epochs", "rejected_fixes",
                   "innovation_mean_nis", "innovation_share_over_gate", "qc", "qc_details", "runtime_s", "message",
                   "failure"]
#: the errors that mean the flight's input or configuration is wrong (the CLI's exit code 2); any other
#: exception is a bug in georef (exit code 3)
USER_ERRORS = (GeorefError, ValueError, KeyError, OSError)
#: a flight folder's photos, for the ``images`` export (geotagged copies, georef.io.image_export)
IMAGES_FOLDER = "images"
#: what a batch user can do when the photos' capture times do not settle their frames
BATCH_CLOCK_ADVICE = ("Name the photos with image_names in the flight's flight.toml ([output] image_names = "
                      "\"IMG_{frame:04d}.JPG\", or a CSV of frame,name); batch takes no camera clock offset: for a "
                      "known offset run georef process on this flight with --camera-clock-offset SECONDS")


@dataclass(frozen=True)
class FlightJob:
    """One flight to process: its name and input files."""

    flight: str
    pos: str
    camera: str
    config: str | None = None
    #: the flight's photos for the ``images`` export (``<flight>/images/``, or the manifest's ``images`` column)
    images: str | None = None


def discover(source: Path | str) -> list[FlightJob]:
    """Flights in a folder of flight folders, or listed in a manifest CSV."""
    source = Path(source)
    if source.is_file():
        manifest = pd.read_csv(source, dtype=str, keep_default_na=False)
        missing = [c for c in ("flight", "pos", "camera") if c not in manifest.columns]
        if missing:
            raise InputError(source, 1, missing[0], "manifest needs columns flight, pos, camera[, config]")
        base = source.parent

        def resolve(value: str) -> str:
            return str(value if Path(value).is_absolute() else base / value)

        return [FlightJob(row.flight, resolve(row.pos), resolve(row.camera),
                          resolve(row.config) if getattr(row, "config", "") else None,
                          resolve(row.images) if getattr(row, "images", "") else None)
                for row in manifest.itertuples(index=False)]
    if not source.is_dir():
        raise InputError(source, None, None, "neither a folder of flights nor a manifest CSV")
    jobs = []
    for folder in sorted(p for p in source.iterdir() if p.is_dir()):
        camera = next((folder / name for name in ("Kamera.txt", "camera.txt") if (folder / name).exists()), None)
        config = folder / "flight.toml"
        jobs.append(FlightJob(folder.name, str(folder / "POS.txt"), str(camera or folder / "Kamera.txt"),
                              str(config) if config.exists() else None,
                              str(folder / IMAGES_FOLDER) if (folder / IMAGES_FOLDER).is_dir() else None))
    if not jobs:
        raise InputError(source, None, None, "no flight folders found (each needs POS.txt and Kamera.txt)")
    return jobs


def process_flight(job: FlightJob, output_root: str, method: str | None = None,
                   exports: tuple[tuple[str, str], ...] = (),
                   calibration_prior: tuple[list, list] | None = None) -> dict:
    """Process one flight (runs on a worker); never raises: failures come back as a status row. ``exports``:
    (format, file name) pairs written beside ``eo.csv`` in the flight's folder. ``calibration_prior``: the graph's
    prior on (lever arm [m], GNSS time offset [s]) as (mean, covariance), replacing the flight's own (campaign
    calibration); the row then carries ``calibration``, the graph's reduction to those variables."""
    from georef.pipeline import process

    start = time.perf_counter()
    out = Path(output_root) / job.flight
    out.mkdir(parents=True, exist_ok=True)
    row: dict = dict.fromkeys(SUMMARY_COLUMNS)
    row.update(flight=job.flight, status="failed", method=method or "", checks=None, summary=None, outputs=[],
               calibration=None)
    log_lines = [f"flight {job.flight}", f"POS {job.pos}", f"camera {job.camera}", f"config {job.config}"]
    try:
        plan = _flight_plan(job, out, method, exports)
        result = process(job.pos, job.camera, plan.cfg, calibration_prior=calibration_prior)
        image_checks = _write_flight_outputs(job, plan, result, row, log_lines)
        _record_result(row, plan.cfg, result, image_checks, log_lines)
    except Exception as exc:  # noqa: BLE001 - a failed flight is reported, the batch goes on
        row["message"] = f"{type(exc).__name__}: {exc}"
        row["status"] = "failed"
        row["failure"] = "input" if isinstance(exc, USER_ERRORS) else "internal"
        log_lines.append(f"FAILED ({row['failure']}): {row['message']}")
        if row["failure"] == "internal":
            log_lines.append(traceback.format_exc())
    row["runtime_s"] = round(time.perf_counter() - start, 3)
    log_lines.append(f"status {row['status']} in {row['runtime_s']} s")
    with atomic_write(out / "georef.log") as handle:
        handle.write("\n".join(log_lines) + "\n")
    row["outputs"].append({"what": "log", "format": "text", "path": str(out / "georef.log")})
    return row


@dataclass(frozen=True)
class _FlightPlan:
    """What one flight's run uses and writes: its configuration ``cfg``, the table's and exports' ``specs`` (the
    table first), its output ``frames`` (None: WGS 84 ellipsoidal) and the folders its geotagged photos go to
    (``image_targets``)."""

    cfg: ProcessingConfig
    specs: list[ExportSpec]
    frames: OutputFrames | None
    image_targets: list[Path]


def _flight_plan(job: FlightJob, out: Path, method: str | None, exports: tuple[tuple[str, str], ...]) -> _FlightPlan:
    """The flight's configuration and outputs, checked before processing: a format that needs the flight's CRS, or
    photos the flight lacks, fails here."""
    from georef.config import ProcessingConfig, load_config
    from georef.frames.heights import OutputFrames
    from georef.io.exports import ExportSpec, check_exports

    cfg = load_config(job.config) if job.config else ProcessingConfig()
    if method:
        cfg = cfg.updated(method=method)
    specs = [ExportSpec("csv", out / "eo.csv"), *(ExportSpec(fmt, out / name) for fmt, name in exports
                                                  if fmt != "images")]
    frames = (OutputFrames(cfg.output.crs, cfg.output.height, cfg.output.vertical_crs)
              if cfg.output.crs or cfg.output.height != "ellipsoidal" else None)
    check_exports(specs, frames)  # a format that needs this flight's CRS fails before processing
    image_targets = [out / name for fmt, name in exports if fmt == "images"]
    if image_targets:
        from georef.io.image_export import check_image_export

        if job.images is None:
            raise InputError(job.flight, None, None, f"--export images: this flight has no photos (a folder "
                             f"{IMAGES_FOLDER}/ beside its POS.txt, or an images column in the manifest)")
        for target in image_targets:
            check_image_export(Path(job.images), target, frames, cfg.output.image_names)
    return _FlightPlan(cfg=cfg, specs=specs, frames=frames, image_targets=image_targets)


def _write_flight_outputs(job: FlightJob, plan: _FlightPlan, result: ProcessResult, row: dict,
                          log_lines: list[str]) -> list:
    """The table, the exports and the geotagged photos, all or nothing; each listed in ``row["outputs"]``.
    Returns the photo exports' quality checks (None where there is none)."""
    from georef.io.atomic import atomic_group
    from georef.io.exports import write_export

    image_checks = []
    with atomic_group():
        for spec in plan.specs:
            write_export(result.columns, spec.path, spec.fmt, frames=result.frames,
                         odm_angles=plan.cfg.output.odm_angles)
        if plan.image_targets:
            from georef.io.image_export import export_images
            from georef.io.image_match import ClockMatchError

            flight_day = None if result.flight is None else float(result.flight.day_start_utc)
            for target in plan.image_targets:
                try:
                    done = export_images(result.columns, Path(job.images), target, frames=result.frames,
                                         day_start_posix=flight_day,
                                         date_source=None if flight_day is None else "the log's own date")
                except ClockMatchError as exc:  # batch has neither option the message names: its own advice
                    raise ClockMatchError(exc.finding, BATCH_CLOCK_ADVICE) from None
                log_lines.extend(done.lines())
                image_checks.append(done.check())
                row["outputs"].append({"what": "export", "format": "images", "path": str(target)})
    row["outputs"] += [{"what": "table" if k == 0 else "export", "format": spec.fmt, "path": str(spec.path)}
                       for k, spec in enumerate(plan.specs)]
    return image_checks


def _record_result(row: dict, cfg: ProcessingConfig, result: ProcessResult, image_checks: list,
                   log_lines: list[str]) -> None:
    """The run's figures, its calibration (graph) and its quality verdict (judged here, on the worker, and sent
    back as plain text) into ``row``; the summary, checks and notices into the log."""
    from georef.qc import assess_result

    summary = result.summary()
    if result.nav.graph_info is not None:
        row["calibration"] = result.nav.graph_info.calibration.as_lists()
    gnss = result.nav.gnss
    used = gnss.status >= 1
    nis = gnss.normalised_innovation_sq[used]
    row.update(status="ok", method=cfg.processing.method, frames=summary["frames_written"],
               frames_flagged=summary["frames_flagged"], gnss_epochs=summary["gnss_epochs"],
               rejected_fixes=len(summary["gnss_rejected_lines"]),
               innovation_mean_nis=float(np.mean(nis)) if len(nis) else float("nan"),
               innovation_share_over_gate=float(np.mean(gnss.normalised_innovation_sq[gnss.status >= 0]
                                                        > cfg.gnss_gate.chi2)) if len(nis) else float("nan"),
               message="")
    # the verdict is judged here, on the worker, and travels back as plain text
    verdict = assess_result(result)
    verdict = type(verdict)((*verdict.checks, *(check for check in image_checks if check is not None)))
    row.update(qc="passed" if verdict.passed else "failed: " + ", ".join(c.name for c in verdict.failures),
               qc_details=" | ".join(c.line() for c in verdict.checks if c.status != "pass"),
               checks=verdict.to_dicts(), summary=summary)
    log_lines += [f"{key}: {value}" for key, value in summary.items()]
    log_lines += [f"QC {check.line()}" for check in verdict.checks]
    log_lines += [f"notice: {notice}" for notice in result.notices]


#: Dask settings for the LocalCluster that georef starts, where a flight is one CPU-bound, single-threaded task.
#: * The nanny's default environment sets ``MALLOC_TRIM_THRESHOLD_=65536`` (to hand memory back to the OS).
#:   Setting it switches off glibc's dynamic mmap threshold, so every large numpy array of the pipeline is a
#:   fresh mmap, page-faulted in and unmapped again: tasks ran slower than in a plain process and two workers
#:   gained far less than twice (benchmarks/bench_batch.py; docs/method-graph.md, "`georef batch`").
#:   BLAS/OpenMP stay at one thread per worker, as in Dask's default.
#: * The statistical profiler samples every thread's stack every 10 ms (holding the GIL); the memory and system
#:   monitors poll 10 and 2 times a second. None of it is of use to a batch of flights.
LOCAL_CLUSTER_CONFIG = {
    "distributed.nanny.pre-spawn-environ": {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1},
    "distributed.worker.profile.enabled": False,
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
}


def start_local_cluster(workers: int = 2, tuned: bool = True):
    """A ``LocalCluster`` of ``workers`` single-threaded worker processes on this machine, no dashboard.

    With ``tuned``, the workers run with :data:`LOCAL_CLUSTER_CONFIG` (the nanny hands the configuration to
    the worker processes it spawns); without it, with Dask's defaults.
    """
    import dask
    from dask.distributed import LocalCluster

    settings = LOCAL_CLUSTER_CONFIG if tuned else {}
    with dask.config.set(settings):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)


def run_batch(jobs: list[FlightJob], output_root: Path | str, method: str | None = None,
              scheduler: str | None = None, workers: int = 2,
              on_done: Callable[[dict], None] | None = None,
              exports: tuple[tuple[str, str], ...] = (), shared_calibration: bool = False) -> pd.DataFrame:
    """Process every job on Dask distributed; returns (and writes) the summary table. ``exports``: (format, file
    name) pairs every flight writes beside its ``eo.csv``.

    ``scheduler`` is an address such as ``tcp://host:8786``; without it a ``LocalCluster`` of ``workers``
    single-threaded processes is started (:func:`start_local_cluster`) and closed here.

    ``shared_calibration`` (``method`` must be ``graph``): one GNSS lever arm and time offset for all flights
    (:mod:`georef.campaign`): every flight is solved, reduced to those variables on its worker, the driver
    combines them and re-solves each flight with the campaign's estimate from the other flights as its prior,
    until the estimate settles; writes ``calibration.json`` and ``calibration.toml`` (a ``--config`` fragment).
    ``on_done`` then sees every round's rows (``row["round"]``, from 1); the summary is the last round's.
    """
    from dask.distributed import Client

    output_root = Path(output_root)
    output_root.mkdir(parents=True, exist_ok=True)
    if shared_calibration and method != "graph":
        raise ValueError("--shared-calibration needs --method graph: the calibration is a variable of the graph")
    cluster = None
    if scheduler is None:
        cluster = start_local_cluster(workers)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        if shared_calibration:
            rows, campaign = _campaign(client, jobs, output_root, method, exports, on_done)
        else:
            rows, campaign = _round(client, jobs, output_root, method, exports, {}, on_done, 0), None
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    if campaign is not None:
        with atomic_write(output_root / "calibration.json") as handle:
            json.dump(campaign.to_json(), handle, indent=2)
            handle.write("\n")
        with atomic_write(output_root / "calibration.toml") as handle:
            handle.write(campaign.config_toml())
    order = {job.flight: i for i, job in enumerate(jobs)}
    summary = pd.DataFrame(rows, columns=SUMMARY_COLUMNS).sort_values("flight", key=lambda s: s.map(order))
    for column in ("frames", "frames_flagged", "gnss_epochs", "rejected_fixes"):
        summary[column] = summary[column].astype("Int64")
    with atomic_write(output_root / "batch_summary.csv") as handle:
        summary.to_csv(handle, index=False, lineterminator="\n")
    return summary.reset_index(drop=True)


def _round(client, jobs: list[FlightJob], output_root: Path, method: str | None, exports, priors: dict,
           on_done: Callable[[dict], None] | None, round_number: int) -> list[dict]:
    """One task per flight (``priors``: the calibration prior per flight name, absent = the flight's own)."""
    from dask.distributed import as_completed

    futures = [client.submit(process_flight, job, str(output_root), method, tuple(exports), priors.get(job.flight),
                             key=f"flight-{job.flight}-{round_number}", pure=False) for job in jobs]
    rows = []
    for future in as_completed(futures):
        try:
            row = future.result()
        except Exception as exc:  # noqa: BLE001 - a worker that died
            flight = future.key.removeprefix("flight-").rsplit("-", 1)[0] if isinstance(future.key, str) \
                else str(future.key)
            row = dict.fromkeys(SUMMARY_COLUMNS)
            row.update(flight=flight, status="failed", message=f"worker error: {exc}", failure="internal",
                       checks=None, summary=None, outputs=[], calibration=None)
        if round_number:
            row["round"] = round_number
        rows.append(row)
        if on_done is not None:
            on_done(row)
    return rows


def _campaign(client, jobs: list[FlightJob], output_root: Path, method: str | None, exports,
              on_done: Callable[[dict], None] | None):
    """Rounds of per-flight solves until the campaign's calibration settles (:mod:`georef.campaign`)."""
    from georef.campaign import MAX_ROUNDS, FlightReduction, combine, leave_one_out, settled

    def reductions_of(rows: list[dict]) -> dict[str, FlightReduction]:
        return {row["flight"]: FlightReduction.from_dict(row["calibration"]) for row in rows
                if row["status"] == "ok" and row.get("calibration")}

    rows = _round(client, jobs, output_root, method, exports, {}, on_done, 1)
    reductions = reductions_of(rows)
    if not reductions:
        return rows, None
    configured = {name: (r.prior_mean, r.prior_covariance) for name, r in reductions.items()}
    estimate = combine(reductions, configured, rounds=1)
    for round_number in range(2, MAX_ROUNDS + 1):
        priors = {}
        for name in reductions:
            prior = leave_one_out(estimate, reductions, name)
            priors[name] = None if prior is None else (prior[0].tolist(), prior[1].tolist())
        rows = _round(client, jobs, output_root, method, exports,
                      {name: prior for name, prior in priors.items() if prior is not None}, on_done, round_number)
        # a flight solved with the campaign's prior: its data part is taken against that prior
        reductions.update(reductions_of(rows))
        previous, estimate = estimate, combine(reductions, configured, rounds=round_number)
        if settled(estimate, previous):
            break
    for row in rows:
        flight = estimate.flights.get(row["flight"])
        if flight is not None and not flight["consistent"]:
            row["qc"] = "failed: campaign calibration" if row.get("qc") in (None, "passed") else \
                f"{row['qc']}, campaign calibration"
            detail = (f"fail campaign calibration: this flight's lever arm/time offset disagree with the other "
                      f"flights' (chi2 {flight['chi2']:.1f}, {flight['dof']} dof, p {flight['p_value']:.2g}): a moved "
                      f"antenna or a changed receiver? It keeps its own estimate")
            row["qc_details"] = f"{row['qc_details']} | {detail}" if row.get("qc_details") else detail
    return rows, estimate
