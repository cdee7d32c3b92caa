"""Where the commands' outputs go: a file (written atomically by the library) or standard output for ``-``.

With ``-o -`` the table goes to standard output and nothing else does: every message, the progress bar and the
run summary go to standard error, so ``georef process ... -o - > eo.csv`` gives a clean file. Standard output
receives the table only once it is complete: the library's writer fills a private temporary file first (so a
failure half way prints nothing on standard output), which is then copied out and removed.

``--summary-json FILE`` (:func:`write_json`): a JSON document, atomically written or on standard output for ``-``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Mapping
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from georef.io.atomic import atomic_write
from georef.option_values import is_stdout


def write_target(path: Path, writer: Callable[[Path], Any]) -> None:
    """Run ``writer(file)`` on ``path``, or, for ``-``, on a private temporary file copied to standard output."""
    if not is_stdout(path):
        writer(path)
        return
    with tempfile.TemporaryDirectory(prefix="georef-stdout-") as folder:
        staged = Path(folder) / "stdout"
        writer(staged)
        with staged.open("rb") as handle:
            _copy_to_stdout(handle)


def _copy_to_stdout(handle: Any) -> None:
    """Copy a binary file object to standard output. A reader that closes the pipe early (``| head``) ends the
    copy quietly, as other Unix tools do, instead of a "Broken pipe" error and a traceback at exit."""
    sink = getattr(sys.stdout, "buffer", None)
    try:
        if sink is not None:
            sys.stdout.flush()
            shutil.copyfileobj(handle, sink)
            sink.flush()
        else:  # a text-only stream (an embedding application's)
            sys.stdout.write(handle.read().decode("utf-8"))
            sys.stdout.flush()
    except BrokenPipeError:
        # Python's recipe (docs: signal, "Note on SIGPIPE"): point stdout at devnull so the flush at exit is quiet
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON data: numpy scalars and arrays to numbers and lists, tuples to lists, paths and
    enums to strings, NaN and infinities to ``null`` (JSON has no NaN)."""
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, list | tuple | set | frozenset):
        return [jsonable(v) for v in value]
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating | float):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, int | str):
        return value
    try:
        import pandas as pd

        if pd.isna(value):
            return None
    except (TypeError, ValueError):
        pass
    return str(value)


def write_json(path: Path, document: Mapping[str, Any]) -> None:
    """Write ``document`` as indented JSON (UTF-8, ``\\n`` line ends) to ``path``, atomically, or to standard
    output for ``-``."""
    text = json.dumps(jsonable(document), indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    if is_stdout(path):
        sys.stdout.flush()
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    with atomic_write(path) as handle:
        handle.write(text)
