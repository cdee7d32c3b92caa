"""``georef``: direct georeferencing from the command line.

Exit codes: 0 done and the quality checks passed; 2 an error in the user's input, printed as one actionable
line (file, line, column), never a traceback; 3 an internal error (a bug in georef); 4 the outputs are written
but the quality checks failed (``docs/qc.md``). Text from the user's files and options is escaped before rich
prints it (a path such as ``flight[red]/POS.txt`` prints as it is).

Conventions: ``georef --version``; ``-o -`` writes the table to standard output and every message to standard
error; ``--summary-json FILE`` writes a machine-readable summary (``docs/qc.md``); options shared by several
commands are defined once, in :mod:`georef_cli.options`.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Annotated, Any

import typer
from rich.markup import escape

from georef.io.errors import GeorefError
from georef.option_values import OptionError

from .coercion import PlainCoercionCommand, PlainCoercionGroup
from .commands.attitude import attitude
from .commands.batch import batch
from .commands.build_kernels import build_kernels
from .commands.calibrate_boresight import calibrate_boresight
from .commands.evaluate import evaluate
from .commands.fuse import fuse
from .commands.info import info
from .commands.process import process
from .commands.simulate import simulate
from .options import georef_version
from .running import EXIT_INTERNAL_ERROR, EXIT_QC_FAILED, EXIT_USER_ERROR, console, out

__all__ = ["EXIT_INTERNAL_ERROR", "EXIT_QC_FAILED", "EXIT_USER_ERROR", "app", "console", "main", "out"]

app = typer.Typer(
    cls=PlainCoercionGroup, add_completion=False, no_args_is_help=True, rich_markup_mode=None,
    pretty_exceptions_enable=False,
    help="georef: GPS/INS direct georeferencing of aerial imagery. Units: metres, degrees, seconds; "
         "body axes x forward, y right, z down.",
)


def _version_callback(show: bool) -> None:
    if show:
        out.print(f"georef {escape(georef_version())}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", callback=_version_callback, is_eager=True,
                                          help="Print georef's version and exit.")] = False,
) -> None:
    """The options before the command (``georef --version``); the help text is the app's."""


def _user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn georef's user-facing errors into one red line and exit code 2 (a refused option as the command line
    words it: ``Invalid value[ for OPTION]: ...``)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except OptionError as exc:
            message = typer.BadParameter(exc.message, param_hint=exc.option).format_message()
            console.print(f"[bold red]error:[/] {escape(message)}", highlight=False)
            raise typer.Exit(code=EXIT_USER_ERROR) from None
        except (GeorefError, ValueError, KeyError, OSError) as exc:  # CRSChoiceError is a ValueError
            console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
            raise typer.Exit(code=EXIT_USER_ERROR) from None
        except typer.BadParameter as exc:
            console.print(f"[bold red]error:[/] {escape(exc.format_message())}", highlight=False)
            raise typer.Exit(code=EXIT_USER_ERROR) from None
        except (typer.Exit, typer.Abort, SystemExit, KeyboardInterrupt):
            raise
        except Exception as exc:  # a bug in georef, not in the user's input
            if os.environ.get("GEOREF_DEBUG"):
                raise
            console.print(f"[bold red]internal error:[/] {type(exc).__name__}: {escape(str(exc))}. This is a bug in "
                          "georef; please report it with the command you ran (GEOREF_DEBUG=1 shows the traceback).",
                          highlight=False)
            raise typer.Exit(code=EXIT_INTERNAL_ERROR) from None

    return wrapper


# the commands in the order --help lists them (commands/<name>.py each)
for _command in (process, simulate, fuse, attitude, batch):
    app.command(cls=PlainCoercionCommand)(_user_errors(_command))
app.command("calibrate-boresight", cls=PlainCoercionCommand)(_user_errors(calibrate_boresight))
app.command(cls=PlainCoercionCommand)(_user_errors(info))
app.command("build-kernels", cls=PlainCoercionCommand)(_user_errors(build_kernels))
app.command(cls=PlainCoercionCommand)(_user_errors(evaluate))


def _exit_now(code: object) -> None:
    """End the process with ``code`` as ``sys.exit`` would, without the interpreter's teardown.

    The command is done: its files are written atomically and closed. What remains of a normal exit is the
    ``atexit`` handlers, flushing the standard streams and then tearing down every module the run imported
    (numpy, pandas, scipy, pyproj...; about 900 of them), which gives the user nothing and cost 0.25 s of CPU
    in a 2.5-s ``georef process`` (measured: the same imports, then exiting normally or with ``os._exit``).
    The handlers run and the streams are flushed here, then ``os._exit``. With another thread still alive, or
    when a stream cannot be flushed (a closed pipe), the normal exit runs instead, with its usual messages."""
    import atexit
    import threading

    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:
        sys.exit(code)  # a message: printed by the interpreter, status 1
    if threading.active_count() > 1:
        sys.exit(status)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        sys.exit(status)
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        sys.exit(status)
    os._exit(status & 0xFF)


def main() -> None:  # pragma: no cover - console entry point (tests/cli/test_commands.py runs it as a process)
    """The ``georef`` command: :data:`app`, then :func:`_exit_now` with its exit code. Tests call :data:`app`
    in-process (typer's runner), which never ends the process."""
    try:
        app()
    except SystemExit as exc:
        _exit_now(exc.code)
    _exit_now(0)


if __name__ == "__main__":  # pragma: no cover
    main()
