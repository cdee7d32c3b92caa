"""What every command prints around its work: the consoles, the stage progress on standard error, the quality
checks' verdict, and the exit codes (``docs/qc.md``).

Text from the user's files and options is escaped before rich prints it; emoji are off, so user text such as
``images:x:...`` prints as it is, never as ``:x:`` -> an emoji.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape

from .output import is_stdout

if TYPE_CHECKING:
    from rich.progress import Progress

#: exit codes (docs/qc.md)
EXIT_USER_ERROR = 2
EXIT_INTERNAL_ERROR = 3
EXIT_QC_FAILED = 4

#: standard error: errors, warnings, notices, the progress
console = Console(stderr=True, soft_wrap=True, emoji=False)
#: standard output: the run's summary, unless an output goes there (:func:`messages`)
out = Console(emoji=False)


def messages(*stdout_outputs: Path | None) -> Console:
    """The console for the run's summary: standard output, unless one of ``stdout_outputs`` is ``-`` (then standard
    output carries that data and nothing else, and the summary goes to standard error)."""
    return console if any(is_stdout(p) for p in stdout_outputs) else out


def stage_progress(quiet: bool, total: int) -> tuple[Progress | None, Callable[[str], None]]:
    """A transient progress bar of ``total`` stages on standard error (None when ``quiet``) and the function that
    starts the next stage by its description."""
    if quiet:
        return None, lambda _step: None
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                        console=console, transient=True)
    task = progress.add_task("starting", total=total)
    state = {"first": True}

    def step(description: str) -> None:
        if not state["first"]:
            progress.advance(task)
        state["first"] = False
        progress.update(task, description=escape(description))

    return progress, step


def print_verdict(verdict: Any, quiet: bool) -> None:
    """The quality checks on stderr: one line per failing (and, unless ``quiet``, warning) check, then the
    verdict; a green "QC passed" when nothing is wrong."""
    for check in verdict.checks:
        if check.status == "fail":
            console.print(f"[bold red]QC fail[/] {escape(check.name)}: {escape(check.message)}", highlight=False)
        elif check.status == "warn" and not quiet:
            console.print(f"[yellow]QC warning[/] {escape(check.name)}: {escape(check.message)}", highlight=False)
    if not verdict.passed:
        console.print(f"[bold red]QC failed[/] ({len(verdict.failures)} check(s)): the outputs are written; exit "
                      f"code {EXIT_QC_FAILED} (docs/qc.md)", highlight=False)
    elif not quiet:
        extra = f" with {len(verdict.warnings)} warning(s)" if verdict.warnings else ""
        console.print(f"[bold green]QC passed[/]{extra}", highlight=False)


def exit_code(verdict: Any) -> int:
    """0 when the quality checks passed, else :data:`EXIT_QC_FAILED`."""
    return 0 if verdict.passed else EXIT_QC_FAILED
