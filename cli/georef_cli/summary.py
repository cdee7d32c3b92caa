"""The machine-readable run summary of ``--summary-json`` (``process``, ``fuse``, ``batch``); keys in ``docs/qc.md``.

The documents are plain dictionaries; :func:`georef_cli.output.write_json` turns numpy values, tuples and paths into
JSON and NaN into ``null``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from georef.qc import Verdict

from .options import georef_version

#: the version of the summary's layout: raised when a key changes meaning or goes away (new keys may appear)
SCHEMA_VERSION = 1


def qc_block(verdict: Verdict) -> dict[str, Any]:
    """``{"passed", "verdict", "checks": [{"name", "status", "message"}, ...]}``."""
    return {"passed": verdict.passed, "verdict": verdict.short(), "checks": verdict.to_dicts()}


def _settings(settings: Any) -> dict[str, Any] | None:
    if settings is None:
        return None
    if dataclasses.is_dataclass(settings) and not isinstance(settings, type):
        return dataclasses.asdict(settings)
    return dict(settings)


def _paths(value: Path | str | list | None) -> str | list[str] | None:
    """An input as JSON: its path, a list for a repeated option given more than once (``--config``), or null."""
    if isinstance(value, list):
        return None if not value else str(value[0]) if len(value) == 1 else [str(p) for p in value]
    return None if value is None else str(value)


def run_document(command: str, exit_code: int, *, inputs: Mapping[str, Path | str | None], settings: Any,
                 outputs: list[dict[str, str]], summary: Mapping[str, Any], verdict: Verdict) -> dict[str, Any]:
    """The summary of one ``process`` or ``fuse`` run."""
    return {
        "schema": SCHEMA_VERSION,
        "georef_version": georef_version(),
        "command": command,
        "exit_code": exit_code,
        "inputs": {k: _paths(v) for k, v in inputs.items()},
        "settings": _settings(settings),
        "outputs": outputs,
        "summary": dict(summary),
        "qc": qc_block(verdict),
    }


def batch_exit_code(rows: Iterable[Mapping[str, Any]], user_error: int, internal_error: int, qc_failed: int) -> int:
    """The exit code of a batch: ``internal_error`` when any flight failed with an internal error (a bug, a worker
    that died), else ``user_error`` when any flight failed to run on its input, else ``qc_failed`` when any
    flight's quality checks failed, else 0."""
    rows = list(rows)
    if any(r.get("status") != "ok" and r.get("failure") == "internal" for r in rows):
        return internal_error
    if any(r.get("status") != "ok" for r in rows):
        return user_error
    if any(str(r.get("qc") or "").startswith("failed") for r in rows):
        return qc_failed
    return 0


def batch_document(exit_code: int, *, source: Path, settings: Mapping[str, Any], outputs: list[dict[str, str]],
                   rows: list[Mapping[str, Any]], columns: list[str]) -> dict[str, Any]:
    """The summary of a ``batch`` run: one entry per flight (``rows`` as :func:`georef.batch.process_flight`
    returns them, in the batch's order)."""
    flights = []
    for row in rows:
        entry: dict[str, Any] = {c: row.get(c) for c in columns if c not in ("qc", "qc_details")}
        checks = row.get("checks")
        entry["qc"] = qc_block(Verdict.from_dicts(checks)) if checks is not None else None
        entry["summary"] = row.get("summary")
        entry["outputs"] = list(row.get("outputs") or [])
        flights.append(entry)
    ran = [f for f in flights if f["status"] == "ok"]
    return {
        "schema": SCHEMA_VERSION,
        "georef_version": georef_version(),
        "command": "batch",
        "exit_code": exit_code,
        "inputs": {"source": str(source)},
        "settings": dict(settings),
        "outputs": outputs,
        "counts": {
            "flights": len(flights),
            "ok": len(ran),
            "failed_input": sum(f["status"] != "ok" and f.get("failure") != "internal" for f in flights),
            "failed_internal": sum(f["status"] != "ok" and f.get("failure") == "internal" for f in flights),
            "qc_failed": sum(f["qc"] is not None and not f["qc"]["passed"] for f in ran),
        },
        "flights": flights,
    }
