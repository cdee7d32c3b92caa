"""Expensive test inputs computed once per test session, shared by pytest-xdist's workers.

A module-scoped fixture runs once in *every* worker that executes one of its tests: with ``-n auto`` the
Monte-Carlo fixtures of ``tests/fusion/test_ins.py`` were computed in full by each worker. :func:`computed_once` splits
the work instead: each item is claimed by the first worker to reach it (an exclusive file creation), computed
there and pickled into the session's temporary folder, which every worker of the session shares; the others
wait for the items they did not claim and load them. Without xdist the folder is the session's own.

Nothing outlives the session (pytest's temporary folders are per session), so a result never comes from older
code.
"""

from __future__ import annotations

import os
import pickle
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")

#: how long a worker waits for an item another worker claimed [s] (a claimed item that never arrives means that
#: worker died; its error names the item)
WAIT_S = 1800.0
POLL_S = 0.2


def session_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The temporary folder shared by every worker of this session (the session's own without xdist)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def computed_once(tmp_path_factory: pytest.TempPathFactory, name: str, keys: Sequence[str],
                  compute: Callable[[str], T]) -> dict[str, T]:
    """``{key: compute(key)}`` for every key, each computed by exactly one worker of the session.

    ``keys`` are file-name-safe strings, the same in every worker; ``compute``'s results must pickle.
    An item whose computation raised is reported as failed to the workers waiting for it.
    """
    folder = session_folder(tmp_path_factory) / f"shared-{name}"
    folder.mkdir(exist_ok=True)
    for key in keys:
        try:
            os.close(os.open(folder / f"{key}.claimed", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            continue  # another worker has it
        try:
            value = compute(key)
        except BaseException as exc:
            (folder / f"{key}.failed").write_text(f"{type(exc).__name__}: {exc}")
            raise
        part = folder / f"{key}.{os.getpid()}.part"
        part.write_bytes(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        os.replace(part, folder / f"{key}.pickle")  # atomic: a reader sees the whole result or none
    results = {}
    deadline = time.monotonic() + WAIT_S
    for key in keys:
        done, failed = folder / f"{key}.pickle", folder / f"{key}.failed"
        while not done.exists():
            if failed.exists():
                raise RuntimeError(f"{name} {key}: the worker computing it failed: {failed.read_text()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"{name} {key}: claimed by another worker but not delivered in {WAIT_S:.0f} s "
                                   f"(did it die?); see {folder}")
            time.sleep(POLL_S)
        results[key] = pickle.loads(done.read_bytes())
    return results
