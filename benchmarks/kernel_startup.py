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

With ``--process`` it also times whole ``georef process`` runs in fresh processes, on the bundled flight and on
every ``--flight DIR`` (holding POS.txt, Kamera.txt, flight.toml), alternating between: the ahead-of-time builds
(``GEOREF_KERNELS=aot``); numba's on-disk cache warm (``GEOREF_KERNELS=jit``, a NUMBA_CACHE_DIR the first cold
run filled); and the cache cold (an empty NUMBA_CACHE_DIR each run: the compile a new install pays once).
With ``--build-runs N`` it times, alternating, ``georef build-kernels`` into an empty GEOREF_KERNEL_DIR (what
``make test`` pays on a fresh clone) and filling an empty numba cache with every kernel function the build
exports, one after the other in one process. Each is wall time and CPU time (user + sys of the process and its
children); CPU time is the steadier figure on a shared machine.

    python benchmarks/kernel_startup.py --process --flight DIR --runs 5 --cold-runs 5 --build-runs 5
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
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


_POPULATE_SCRIPT = """
from numba.core.sigutils import normalize_signature
import importlib
from georef import aot
for spec in aot.KERNELS.values():
    module = importlib.import_module(spec.jit_module)
    for function, interface in spec.functions.items():
        arguments, _ = normalize_signature(interface.numba_signature())
        getattr(module, function).compile(tuple(arguments))  # the key a call with these types looks up
"""


def _timed(command: list[str], env: dict[str, str], label: str) -> tuple[float, float]:
    """Wall time and CPU time (user + sys, with every child it waited for) of ``command``, in seconds; each run
    is printed as it ends (the compile-bound ones take minutes on a loaded machine)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stdout}\n{done.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    print(f"  {label}: wall {wall:.2f} s, CPU {cpu:.2f} s, load average {os.getloadavg()[0]:.1f}", flush=True)
    return wall, cpu


def _report(label: str, times: list[tuple[float, float]]) -> None:
    walls, cpus = [wall for wall, _ in times], [cpu for _, cpu in times]
    print(f"{label}: wall {statistics.median(walls):.2f} s (best {min(walls):.2f}), "
          f"CPU {statistics.median(cpus):.2f} s (best {min(cpus):.2f}), {len(times)} runs", flush=True)


def _tree_env(base: dict[str, str]) -> dict[str, str]:
    """``base`` running the georef of this checkout (ROOT), whatever is installed."""
    return {**base, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "cli")])}


def _process_runs(flights: list[Path], runs: int, cold_runs: int, base: dict[str, str], scratch: Path) -> None:
    """``georef process`` per flight, fresh processes, alternating: builds, warm cache, cold cache."""
    env = _tree_env(base)
    for flight in flights:
        output = scratch / f"{flight.name}-eo.csv"
        command = [sys.executable, "-m", "georef_cli.main", "process", str(flight / "POS.txt"),
                   str(flight / "Kamera.txt"), "--config", str(flight / "flight.toml"), "-o", str(output), "-q"]
        warm = {**env, "GEOREF_KERNELS": "jit", "NUMBA_CACHE_DIR": str(scratch / f"warm-cache-{flight.name}")}
        first = _timed(command, warm, f"{flight.name} cold")  # fills the warm cache: the first cold run
        times: dict[str, list[tuple[float, float]]] = {"aot": [], "warm": [], "cold": [first]}
        for run in range(1, max(runs + 1, cold_runs)):
            if run <= runs:
                times["aot"].append(_timed(command, {**env, "GEOREF_KERNELS": "aot"}, f"{flight.name} aot"))
                times["warm"].append(_timed(command, warm, f"{flight.name} warm"))
            if run < cold_runs:
                cold = scratch / f"cold-cache-{flight.name}-{run}"
                cold_env = {**env, "GEOREF_KERNELS": "jit", "NUMBA_CACHE_DIR": str(cold)}
                times["cold"].append(_timed(command, cold_env, f"{flight.name} cold"))
                shutil.rmtree(cold, ignore_errors=True)
        label = f"georef process, {flight.name}"
        _report(f"{label}, ahead-of-time builds", times["aot"])
        _report(f"{label}, numba cache warm", times["warm"])
        if times["cold"]:
            _report(f"{label}, numba cache cold (compiles)", times["cold"])


def _build_runs(runs: int, base: dict[str, str], scratch: Path) -> None:
    """``georef build-kernels`` from nothing against filling an empty numba cache with the same functions."""
    env = _tree_env(base)
    builds, fills = [], []
    for run in range(runs):
        directory, cache = scratch / f"build-{run}", scratch / f"fill-cache-{run}"
        builds.append(_timed([sys.executable, "-m", "georef_cli.main", "build-kernels", "-q"],
                             {**env, "GEOREF_KERNEL_DIR": str(directory)}, "build-kernels"))
        fills.append(_timed([sys.executable, "-c", _POPULATE_SCRIPT], {**env, "NUMBA_CACHE_DIR": str(cache)},
                            "cache fill"))
        shutil.rmtree(directory, ignore_errors=True)
        shutil.rmtree(cache, ignore_errors=True)
    _report("georef build-kernels, every kernel from nothing", builds)
    _report("numba cache filled with every exported function, one process", fills)


def _startup(runs: int, base: dict[str, str]) -> None:
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
        times = []
        for _ in range(runs):  # this checkout's CLI, as `georef build-kernels` runs it
            done = subprocess.run([sys.executable, "-c", "import subprocess, sys, time; t = time.perf_counter(); "
                                   "subprocess.run(sys.argv[1:], check=True, capture_output=True); "
                                   "print(time.perf_counter() - t)", sys.executable, "-m", "georef_cli.main",
                                   "build-kernels"],
                                  env=_tree_env(base), capture_output=True, text=True, cwd=ROOT)
            if done.returncode != 0:
                print(f"(d) georef build-kernels: failed\n{done.stderr}")
                break
            times.append(float(done.stdout))
        if times:
            print(f"(d) georef build-kernels, nothing to compile: {statistics.median(times):.2f} s "
                  f"(best {min(times):.2f}; whole command with Python start-up)")




def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--process", action="store_true", help="time whole georef process runs")
    parser.add_argument("--flight", type=Path, action="append", default=[],
                        help="a folder with POS.txt, Kamera.txt, flight.toml (besides the bundled flight)")
    parser.add_argument("--cold-runs", type=int, default=None, help="cold-cache runs per flight (default --runs)")
    parser.add_argument("--build-runs", type=int, default=0, help="time build-kernels and cache filling N times")
    parser.add_argument("--no-startup", action="store_true", help="skip the start-up figures (a)-(d)")
    options = parser.parse_args()
    base = {key: value for key, value in os.environ.items()
            if key not in ("GEOREF_KERNELS", "GEOREF_KERNEL_DIR", "NUMBA_DISABLE_JIT", "NUMBA_CACHE_DIR")}
    base["OPENBLAS_NUM_THREADS"] = "1"
    if not options.no_startup:
        _startup(options.runs, base)
    with tempfile.TemporaryDirectory() as scratch:
        if options.process:
            cold_runs = options.runs if options.cold_runs is None else options.cold_runs
            _process_runs([ROOT / "data", *options.flight], options.runs, cold_runs, base, Path(scratch))
        if options.build_runs:
            _build_runs(options.build_runs, base, Path(scratch))


if __name__ == "__main__":
    main()
