"""Ahead-of-time kernels (georef.kernels): same numbers as the JIT, never stale, arguments guarded."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from georef import kernels
from georef.config import load_config
from georef.pipeline import process

DATA = kernels.PACKAGE_DIR.parent / "data"


@pytest.fixture(scope="module")
def built() -> None:
    """The package's ahead-of-time modules for the current sources (``make`` builds them; else build here)."""
    for name in kernels.KERNELS:
        if importlib.util.find_spec(f"georef.{kernels.aot_module_name(name)}") is None:
            kernels.build(name)
    importlib.invalidate_caches()


@pytest.mark.slow  # the JIT compiles every kernel: about 50 s
@pytest.mark.parametrize("method", ["rts", "ekf", "axis"])
def test_aot_and_jit_give_identical_tables(built, monkeypatch, method):
    cfg = load_config(DATA / "flight.toml").updated(method=method)
    tables = {}
    for mode in ("aot", "jit"):
        monkeypatch.setenv("GEOREF_KERNELS", mode)
        tables[mode] = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg).table
        assert kernels.LOADED["axis" if method == "axis" else "ins"] == mode
    pd.testing.assert_frame_equal(tables["aot"], tables["jit"], check_exact=True)


def test_stale_build_is_never_run(built, monkeypatch):
    monkeypatch.setattr(kernels, "source_hash", lambda name: "000000000000")  # as if the sources had changed
    monkeypatch.setenv("GEOREF_KERNELS", "auto")
    kernels.load("ins")
    assert kernels.LOADED["ins"] == "jit"
    monkeypatch.setenv("GEOREF_KERNELS", "aot")
    with pytest.raises(ImportError, match="georef build-kernels"):
        kernels.load("ins")


def test_unknown_mode_is_refused(monkeypatch):
    monkeypatch.setenv("GEOREF_KERNELS", "fast")
    with pytest.raises(ValueError, match="auto, aot or jit"):
        kernels.load("ins")


@pytest.mark.parametrize("mode", ["aot", "jit"])
def test_arguments_are_converted_or_refused(built, monkeypatch, mode):
    """A strided float32 view must give what the contiguous float64 array gives; a wrong rank is refused."""
    monkeypatch.setenv("GEOREF_KERNELS", mode)
    axis_filter = kernels.load("axis").axis_filter
    rng = np.random.default_rng(3)
    t_imu = np.arange(0.0, 20.0, 0.02)
    acc = rng.normal(0.0, 0.1, (len(t_imu), 3))
    t_fix = np.arange(0.0, 20.0, 1.0)
    z_fix = rng.normal(0.0, 1.0, (len(t_fix), 3))
    r_fix = np.ones((len(t_fix), 3))
    args = (np.zeros(3), np.full(3, 1e-2), np.full(3, 1e-4), 16.0, 5)
    reference = axis_filter(t_imu, acc, t_fix, z_fix, r_fix, *args)
    wide = np.zeros((len(t_imu), 6), dtype=np.float32)
    wide[:, ::2] = acc
    converted = axis_filter(t_imu, wide[:, ::2], t_fix, z_fix, r_fix, *args)
    expected = axis_filter(t_imu, acc.astype(np.float32).astype(float), t_fix, z_fix, r_fix, *args)
    for got, want in zip(converted, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    assert not np.array_equal(reference[0], np.zeros_like(reference[0]))
    with pytest.raises(ValueError, match="dimensions"):
        axis_filter(t_imu, acc.ravel(), t_fix, z_fix, r_fix, *args)


def test_default_path_does_not_import_numba(built):
    """The point of the build: `georef process --method rts` loads no numba (0.55 s of start-up)."""
    code = ("import sys; from georef.config import load_config; from georef.pipeline import process; "
            "from georef import kernels; "
            f"process({str(DATA / 'POS.txt')!r}, {str(DATA / 'Kamera.txt')!r}, "
            f"load_config({str(DATA / 'flight.toml')!r})); "
            "print(kernels.LOADED['ins'], 'numba' in sys.modules)")
    env = {key: value for key, value in __import__("os").environ.items() if key != "GEOREF_KERNELS"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert result.stdout.split() == ["aot", "False"]
