"""Ahead-of-time kernels (georef.aot): same numbers as the JIT, never stale, arguments guarded.

No test writes into the source package: builds go to temporary directories (``GEOREF_KERNEL_DIR``), or into a
copy of the package.
"""

from __future__ import annotations

import ast
import importlib.machinery
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from georef import aot
from georef.config import load_config
from georef.pipeline import process

DATA = aot.PACKAGE_DIR.parent / "data"


def _environment(**changes: str | None) -> dict[str, str]:
    env = {key: value for key, value in os.environ.items()
           if key not in ("GEOREF_KERNELS", aot.DIR_VARIABLE, "NUMBA_DISABLE_JIT")}
    env["OPENBLAS_NUM_THREADS"] = "1"
    env.update({key: value for key, value in changes.items() if value is not None})
    return env


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """A directory holding current builds of every kernel, which the tests load through ``GEOREF_KERNEL_DIR``.

    A current build in the package (``make`` writes them) is copied; a missing one is compiled there.
    """
    directory = tmp_path_factory.mktemp("kernels")
    for name in aot.KERNELS:
        module_name = aot.aot_module_name(name)
        found = list(aot.PACKAGE_DIR.glob(f"{module_name}.*"))
        if any(path.suffix != ".json" for path in found):
            for path in found:
                shutil.copy2(path, directory / path.name)
        else:
            aot.build(name, directory)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(aot.DIR_VARIABLE, str(directory))
        yield directory


@pytest.mark.slow  # the JIT compiles every kernel: about 50 s
@pytest.mark.parametrize("method", ["rts", "ekf", "axis"])
def test_aot_and_jit_give_identical_tables(built, monkeypatch, method):
    cfg = load_config(DATA / "flight.toml").updated(method=method)
    tables = {}
    for mode in ("aot", "jit"):
        monkeypatch.setenv("GEOREF_KERNELS", mode)
        tables[mode] = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg).table
        assert aot.LOADED["axis" if method == "axis" else "ins"] == mode
    pd.testing.assert_frame_equal(tables["aot"], tables["jit"], check_exact=True)


_ATTITUDE_SCRIPT = """
import sys
import numpy as np
from georef.attitude.run import estimate_attitude
rng = np.random.default_rng(7)
n = 300
t = np.arange(n) * 0.01
rate = np.column_stack([0.3 * np.sin(t), 0.2 * np.cos(2 * t), 0.1 + 0.05 * t])
gyro = rate + rng.normal(0.0, 0.002, (n, 3)) + [0.01, -0.02, 0.005]
accel = np.array([0.3, -0.2, -9.81]) + rng.normal(0.0, 0.05, (n, 3))
mag = np.array([0.5, 0.1, 0.85]) + rng.normal(0.0, 0.01, (n, 3))
tables = {method: estimate_attitude(method, t, gyro, accel, mag) for method in sys.argv[2:]}
np.savez(sys.argv[1], **{f"{method}.{column}": table[column].to_numpy()
                         for method, table in tables.items() for column in table.columns})
"""


def test_attitude_kernels_match_interpreted_python(built, tmp_path):
    """The attitude filters' builds against the same source run as plain Python (``NUMBA_DISABLE_JIT=1``),
    300 samples with a magnetometer: an independent check that costs no JIT compilation (which takes
    25-40 s for the MEKF and the UKF).

    The complementary filter, the angle-bias KF and the MEKF must agree to the bit. The UKF's sigma points use
    ``np.linalg.cholesky`` and matrix products, which the interpreted run takes from numpy (its BLAS and LAPACK)
    and the compiled one from numba's loops and SciPy's LAPACK: rounding, grown over 300 steps. Measured
    2026-11-23: at most 3.8e-11 of a column's largest value (bias_z); allowed 1e-9.
    """
    methods = ["complementary", "kf", "mekf", "ukf"]
    script = tmp_path / "attitude.py"
    script.write_text(_ATTITUDE_SCRIPT)
    outputs = {}
    for mode, extra in (("aot", {aot.DIR_VARIABLE: str(built)}), ("python", {"NUMBA_DISABLE_JIT": "1"})):
        env = _environment(GEOREF_KERNELS="aot" if mode == "aot" else "jit", **extra)
        subprocess.run([sys.executable, str(script), str(tmp_path / f"{mode}.npz"), *methods], env=env,
                       check=True, capture_output=True, text=True)
        outputs[mode] = np.load(tmp_path / f"{mode}.npz")
    assert sorted(outputs["aot"].files) == sorted(outputs["python"].files)
    assert {name.split(".")[0] for name in outputs["aot"].files} == set(methods)
    for name in outputs["aot"].files:
        compiled, interpreted = outputs["aot"][name], outputs["python"][name]
        if name.startswith("ukf."):
            scale = np.abs(interpreted).max()
            np.testing.assert_allclose(compiled, interpreted, rtol=0.0, atol=1e-9 * scale, err_msg=name)
        else:
            np.testing.assert_array_equal(compiled, interpreted, err_msg=name)


def test_unknown_mode_is_refused(monkeypatch):
    monkeypatch.setenv("GEOREF_KERNELS", "fast")
    with pytest.raises(ValueError, match="auto, aot or jit"):
        aot.load("ins")


@pytest.mark.parametrize("mode", ["aot", "jit"])
def test_arguments_are_converted_or_refused(built, monkeypatch, mode):
    """A strided float32 view must give what the contiguous float64 array gives; a wrong rank is refused."""
    monkeypatch.setenv("GEOREF_KERNELS", mode)
    axis_filter = aot.load("axis").axis_filter
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
            "from georef import aot; "
            f"process({str(DATA / 'POS.txt')!r}, {str(DATA / 'Kamera.txt')!r}, "
            f"load_config({str(DATA / 'flight.toml')!r})); "
            "print(aot.LOADED['ins'], 'numba' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                            env=_environment(**{aot.DIR_VARIABLE: str(built)}))
    assert result.stdout.split() == ["aot", "False"]


# --------------------------------------------------------------------------------------------------------------
# what a build's hash covers


def _statement_keys(statements) -> set[tuple]:
    return {(type(node).__name__, getattr(node, "module", None), getattr(node, "level", 0),
             tuple((alias.name, alias.asname) for alias in node.names)) for node in statements}


def test_import_scan_sees_every_import_statement_of_the_package():
    """The loader reads only the lines that start an import; a full parse of every georef file must find no
    import statement it missed (one after ``:`` or ``;`` on a line would be)."""
    files = sorted(aot.PACKAGE_DIR.rglob("*.py"))
    assert len(files) > 40
    for path in files:
        source = path.read_text(encoding="utf-8")
        full = _statement_keys(node for node in ast.walk(ast.parse(source))
                               if isinstance(node, ast.Import | ast.ImportFrom))
        missed = full - _statement_keys(aot.import_statements(source))
        assert not missed, f"{path}: import statements not seen by aot.import_statements: {sorted(missed)}"


def test_import_closure_resolves_relative_nested_and_continued_imports(tmp_path):
    """A made-up package: relative imports at two levels, a submodule imported by ``from package import name``,
    an import inside a function, a bracketed import with a comment holding brackets, a backslash continuation,
    a docstring line that reads like prose, and a module outside the package, which is not followed."""
    root = tmp_path / "georef"
    files = {
        "kern/__init__.py": "",
        "kern/main.py": ('"""Kernel.\n\nfrom the body rates, roll is integrated\n"""\n'
                         "import numpy as np\n"
                         "from . import helper\n"
                         "from .sub.deep import (  # noqa: F401 (public names)\n    value,\n)\n"
                         "from georef.consts \\\n    import G\n\n"
                         "def late():\n    from ..lazy import thing\n    return thing\n"),
        "kern/helper.py": "from georef.kern.sub import leaf\n",
        "kern/sub/__init__.py": "",
        "kern/sub/deep.py": "value = 1\n",
        "kern/sub/leaf.py": "import math\n",
        "consts.py": "G = 9.8\n",
        "lazy.py": "thing = 2\n",
        "unrelated.py": "x = 1\n",
    }
    for relative, text in files.items():
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / relative).write_text(text)
    assert aot.import_closure("georef.kern.main", root) == (
        "consts.py", "kern/__init__.py", "kern/helper.py", "kern/main.py", "kern/sub/__init__.py",
        "kern/sub/deep.py", "kern/sub/leaf.py", "lazy.py")


def test_import_closure_covers_what_python_imports():
    """Python's own import system as the reference: every georef file loaded by importing a kernel's numba
    module is in its closure (the closure may hold more: imports inside functions)."""
    code = ("import sys, importlib; importlib.import_module(sys.argv[1]); "
            "print('\\n'.join(m.__file__ for n, m in list(sys.modules.items()) "
            "if (n == 'georef' or n.startswith('georef.')) and getattr(m, '__file__', None)))")
    runs = {name: subprocess.Popen([sys.executable, "-c", code, spec.jit_module], stdout=subprocess.PIPE,
                                   text=True, env=_environment())
            for name, spec in aot.KERNELS.items()}
    for name, run in runs.items():
        stdout, _ = run.communicate(timeout=300)
        assert run.returncode == 0, name
        imported = {Path(line).resolve().relative_to(aot.PACKAGE_DIR).as_posix() for line in stdout.split()}
        closure = set(aot.import_closure(aot.KERNELS[name].jit_module))
        assert imported, name
        assert imported <= closure, f"{name}: imported but not hashed: {sorted(imported - closure)}"
    assert "frames/earth.py" in aot.import_closure("georef.fusion.ins_kernel")


def test_hash_covers_toolchain(monkeypatch):
    """Another numba, numpy or Python gives another module name, so a build made with the old one is unused."""
    before = aot.aot_module_name("axis")
    installed = aot.toolchain()
    for key, value in (("numba", "0.0.1"), ("numpy", "0.0.1"), ("python", "cpython 3.0.0"), ("platform", "x")):
        assert installed[key] != value
        aot.build_inputs.cache_clear()
        monkeypatch.setattr(aot, "toolchain", lambda key=key, value=value: {**installed, key: value})
        assert aot.aot_module_name("axis") != before, key
    monkeypatch.undo()
    aot.build_inputs.cache_clear()
    assert aot.aot_module_name("axis") == before


# --------------------------------------------------------------------------------------------------------------
# a stale build in a copy of the package


_LOAD_SCRIPT = """
import json, os, sys
from georef import aot
assert str(aot.PACKAGE_DIR) == sys.argv[1], aot.PACKAGE_DIR
result = {"module": aot.aot_module_name("align")}
os.environ["GEOREF_KERNELS"] = "auto"
aot.load("align")
result["auto"] = aot.LOADED["align"]
result["fallback"] = aot.FALLBACK.get("align")
result["numba imported"] = "numba" in sys.modules
os.environ["GEOREF_KERNELS"] = "aot"
try:
    aot.load("align")
    result["aot"] = aot.LOADED["align"]
except ImportError as exc:
    result["aot"] = "ImportError: " + str(exc)
print(json.dumps(result))
"""


def test_build_made_stale_by_an_indirect_import_is_refused(tmp_path):
    """Copy the package, build the ``align`` kernel in the copy (the smallest that reaches frames/earth.py:
    alignment_kernel -> frames.kernels -> frames.earth), check the unchanged copy loads it, change GAMMA_E in
    frames/earth.py and check the build is refused: the JIT serves, and ``GEOREF_KERNELS=aot`` names the
    stale file and the edited one. A leftover build of an older georef (no record) is named, then removed."""
    started = time.perf_counter()
    package = tmp_path / "georef"
    shutil.copytree(aot.PACKAGE_DIR, package, ignore=shutil.ignore_patterns("_aot_*", "__pycache__"))
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    leftover = package / f"_aot_align_0123456789ab{suffix}"
    leftover.write_bytes(b"not a module")
    env = _environment(PYTHONPATH=str(tmp_path), NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, *args], cwd=tmp_path, env=env, capture_output=True, text=True,
                              check=True)

    def load() -> dict:
        (tmp_path / "load.py").write_text(_LOAD_SCRIPT)
        return json.loads(run(str(tmp_path / "load.py"), str(package)).stdout)

    before = load()
    assert before["auto"] == "jit"
    assert leftover.name in before["aot"] and "no readable record" in before["aot"]

    build = json.loads(run("-c", "import json; from georef import aot; "
                               "print(json.dumps(aot.build('align').notices))").stdout)
    assert any("'pycc' module is pending deprecation" in notice for notice in build)  # shown, not filtered
    built = sorted(path.name for path in package.iterdir() if path.name.startswith(("_aot_", ".")))
    assert built == sorted([f"{before['module']}.json", f"{before['module']}{suffix}"])  # leftover, scratch gone
    unchanged = load()
    assert (unchanged["auto"], unchanged["aot"], unchanged["fallback"]) == ("aot", "aot", None)
    assert not unchanged["numba imported"]

    earth = package / "frames" / "earth.py"
    text, count = re.subn(r"^GAMMA_E = 9\.7803253359$", "GAMMA_E = 9.7803253360", earth.read_text(), flags=re.M)
    assert count == 1, "GAMMA_E = 9.7803253359 not found in georef/frames/earth.py"
    earth.write_text(text)
    edited = load()
    assert edited["module"] != before["module"]
    assert edited["auto"] == "jit"
    for message in (edited["fallback"], edited["aot"]):
        assert f"{before['module']}{suffix} is stale: georef/frames/earth.py changed" in message
    assert edited["aot"].startswith("ImportError") and "georef build-kernels" in edited["aot"]
    print(f"stale-build test: {time.perf_counter() - started:.1f} s")


def test_build_kernels_without_pycc_is_a_user_error(tmp_path, monkeypatch):
    """A numba without numba.pycc: `georef build-kernels` says so and exits 2 (the JIT still serves)."""
    from georef_cli.main import app
    from typer.testing import CliRunner

    monkeypatch.setenv(aot.DIR_VARIABLE, str(tmp_path))  # nothing built there: every kernel needs pycc
    monkeypatch.setitem(sys.modules, "numba.pycc", None)  # makes `from numba.pycc import CC` raise ImportError
    aot._pycc.cache_clear()
    try:
        result = CliRunner().invoke(app, ["build-kernels"])
    finally:
        aot._pycc.cache_clear()
    assert result.exit_code == 2, result.output
    assert "cannot compile ahead of time" in result.output and "numba range" in result.output
    assert not list(tmp_path.iterdir())


_NO_PYCC_SCRIPT = """
import json, sys
sys.modules["numba.pycc"] = None  # a numba without pycc: `from numba.pycc import CC` raises ImportError
import numpy as np
from georef import aot
try:
    import numba.pycc
    pycc = "importable"
except ImportError:
    pycc = "missing"
t_imu = np.arange(0.0, 20.0, 0.02)
t_fix = np.arange(0.0, 20.0, 1.0)
axis = aot.load("axis")
states = axis.axis_filter(t_imu, np.zeros((len(t_imu), 3)), t_fix, np.zeros((len(t_fix), 3)),
                          np.ones((len(t_fix), 3)), np.zeros(3), np.full(3, 1e-2), np.full(3, 1e-4), 16.0, 5)
try:
    aot.build("axis")
    build = "built"
except aot.BuildUnavailableError as exc:
    build = str(exc)
print(json.dumps({"pycc": pycc, "loaded": aot.LOADED["axis"], "fallback": aot.FALLBACK.get("axis"),
                  "finite": bool(np.isfinite(states[0][-1]).all()), "fixes used": int((states[-1] == 1).sum()),
                  "build": build}))
"""


def test_runs_without_pycc_fall_back_to_the_jit(tmp_path):
    """A numba without numba.pycc and no build (what numba's removal of pycc leaves): the kernels load from the
    JIT and run, the reason is kept in ``aot.FALLBACK``, and a build attempt says pycc is missing and that the
    JIT serves meanwhile, without writing anything."""
    result = subprocess.run([sys.executable, "-c", _NO_PYCC_SCRIPT], capture_output=True, text=True, check=True,
                            env=_environment(**{aot.DIR_VARIABLE: str(tmp_path)}))
    found = json.loads(result.stdout)
    assert (found["pycc"], found["loaded"], found["finite"]) == ("missing", "jit", True)
    assert "no ahead-of-time build of the 'axis' kernel" in found["fallback"]
    assert "there is no build of it there" in found["fallback"]
    assert found["fixes used"] == 20
    assert "cannot compile ahead of time" in found["build"] and "JIT meanwhile" in found["build"]
    assert not list(tmp_path.iterdir())
