"""Start-up cost of the compiled kernels in a new process, for each way of getting compiled code.

    python benchmarks/kernel_startup.py [--runs 5]

Every figure is measured in a fresh Python process (the cost a `georef` command pays), after numpy and
georef.aot are imported, and is the median (and best) of ``--runs`` processes:

(a) ahead of time (numba.pycc, ``georef build-kernels``): hashing the kernel's inputs, loading the extension
    module and the first call of the ``axis`` kernel; and loading the larger ``ins`` kernel;
(b) numba's on-disk cache (``cache=True``, warm): importing numba and the kernel's module, then the first call,
    which loads the cached machine code (numba initialises its code generator then);
(b0) the same with an empty cache: the JIT compiles (what a fresh checkout, e.g. CI, pays once);
(c) a minimal C extension built here with the system compiler: the floor for any compiled extension module
    (C, Cython, Rust) that would replace pycc, whatever its body;
(d) ``georef build-kernels`` with every kernel up to date (run by every ``make``).

Needs the builds (``georef build-kernels``) for (a); (b) uses a temporary NUMBA_CACHE_DIR.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_AXIS_ARGS = """
import numpy as np
t_imu = np.arange(0.0, 20.0, 0.02)
acc = np.zeros((len(t_imu), 3))
t_fix = np.arange(0.0, 20.0, 1.0)
z_fix = np.zeros((len(t_fix), 3))
r_fix = np.ones((len(t_fix), 3))
args = (t_imu, acc, t_fix, z_fix, r_fix, np.zeros(3), np.full(3, 1e-2), np.full(3, 1e-4), 16.0, 5)
"""

_KERNEL_SCRIPT = _AXIS_ARGS + """
import json, sys, time
from georef import aot
t0 = time.perf_counter()
aot.build_hash("axis")
t1 = time.perf_counter()
axis = aot.load("axis")
t2 = time.perf_counter()
axis.axis_filter(*args)
t3 = time.perf_counter()
aot.load("ins")
t4 = time.perf_counter()
assert aot.LOADED["axis"] == aot.LOADED["ins"] == sys.argv[1], aot.LOADED
print(json.dumps({"hash": t1 - t0, "load": t2 - t1, "first call": t3 - t2, "axis total": t3 - t0,
                  "ins load": t4 - t3, "numba imported": "numba" in sys.modules}))
"""

_JIT_SCRIPT = _AXIS_ARGS + """
import json, time
t0 = time.perf_counter()
import numba
t1 = time.perf_counter()
from georef.fusion import axis_kernel
t2 = time.perf_counter()
axis_kernel.axis_filter(*args)
t3 = time.perf_counter()
print(json.dumps({"import numba": t1 - t0, "import module": t2 - t1, "first call": t3 - t2,
                  "axis total": t3 - t0}))
"""

_C_SOURCE = """
#include <Python.h>
static PyObject *nothing(PyObject *self, PyObject *args) { Py_RETURN_NONE; }
static PyMethodDef methods[] = {{"nothing", nothing, METH_NOARGS, NULL}, {NULL, NULL, 0, NULL}};
static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_startup_probe", NULL, -1, methods};
PyMODINIT_FUNC PyInit__startup_probe(void) { return PyModule_Create(&module); }
"""

_C_SCRIPT = """
import json, time
import numpy
t0 = time.perf_counter()
import _startup_probe
_startup_probe.nothing()
print(json.dumps({"axis total": time.perf_counter() - t0}))
"""


def _runs(script: str, runs: int, env: dict[str, str], *args: str) -> list[dict]:
    results = []
    for _ in range(runs):
        done = subprocess.run([sys.executable, "-c", script, *args], env=env, capture_output=True, text=True,
                              cwd=ROOT)
        if done.returncode != 0:
            raise SystemExit(f"measurement failed:\n{done.stderr}")
        results.append(json.loads(done.stdout))
    return results


def _summary(label: str, results: list[dict]) -> None:
    parts = []
    for key in results[0]:
        values = [result[key] for result in results]
        if isinstance(values[0], bool):
            parts.append(f"{key} {values[0]}")
        else:
            parts.append(f"{key} {1e3 * statistics.median(values):.1f} ms (best {1e3 * min(values):.1f})")
    print(f"{label}: " + "; ".join(parts))


def _compile_probe(directory: Path) -> bool:
    compiler = sysconfig.get_config_var("CC") or "cc"
    source = directory / "probe.c"
    source.write_text(_C_SOURCE)
    target = directory / f"_startup_probe{sysconfig.get_config_var('EXT_SUFFIX')}"
    command = [*compiler.split(), "-shared", "-fPIC", "-O2", f"-I{sysconfig.get_paths()['include']}",
               str(source), "-o", str(target)]
    return subprocess.run(command, capture_output=True).returncode == 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    runs = parser.parse_args().runs
    base = {key: value for key, value in os.environ.items() if key not in ("GEOREF_KERNELS", "NUMBA_DISABLE_JIT")}
    base["OPENBLAS_NUM_THREADS"] = "1"
    print(f"{runs} fresh processes each; median (best)")
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        try:
            _summary("(a) ahead of time", _runs(_KERNEL_SCRIPT, runs, {**base, "GEOREF_KERNELS": "aot"}, "aot"))
        except SystemExit as exc:
            print(f"(a) ahead of time: not measured, run 'georef build-kernels' first ({exc})")
        cache = {**base, "NUMBA_CACHE_DIR": str(scratch / "numba-cache")}
        _summary("(b0) numba JIT, empty cache", _runs(_JIT_SCRIPT, 1, cache))
        _summary("(b) numba JIT from its on-disk cache", _runs(_JIT_SCRIPT, runs, cache))
        _summary("(b) through georef.aot (GEOREF_KERNELS=jit)",
                 _runs(_KERNEL_SCRIPT, runs, {**cache, "GEOREF_KERNELS": "jit"}, "jit"))
        if _compile_probe(scratch):
            _summary("(c) minimal C extension", _runs(_C_SCRIPT, runs, {**base, "PYTHONPATH": str(scratch)}))
        else:
            print("(c) minimal C extension: not measured, no C compiler")
        sys.path.insert(0, str(ROOT))
        from georef import aot

        stale = [name for name in aot.KERNELS if aot.stale_builds(name) or not any(
            aot.kernel_dir().glob(f"{aot.aot_module_name(name)}.*"))]
        if stale:
            print(f"(d) georef build-kernels: not measured, {', '.join(stale)} would be compiled")
            return
        georef = shutil.which("georef", path=str(Path(sys.executable).parent)) or "georef"
        times = []
        for _ in range(runs):
            done = subprocess.run([sys.executable, "-c", "import subprocess, sys, time; t = time.perf_counter(); "
                                   "subprocess.run(sys.argv[1:], check=True, capture_output=True); "
                                   "print(time.perf_counter() - t)", georef, "build-kernels"],
                                  env=base, capture_output=True, text=True, cwd=ROOT)
            if done.returncode != 0:
                print(f"(d) georef build-kernels: failed\n{done.stderr}")
                break
            times.append(float(done.stdout))
        if times:
            print(f"(d) georef build-kernels, nothing to compile: {statistics.median(times):.2f} s "
                  f"(best {min(times):.2f}; whole command with Python start-up)")


if __name__ == "__main__":
    main()
