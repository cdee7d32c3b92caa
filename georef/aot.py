"""The compiled recursions, ahead of time when built, numba's JIT otherwise.

The filters' inner loops are numba functions (:mod:`georef.fusion.ins_kernel`, :mod:`georef.fusion.axis_kernel`,
:mod:`georef.attitude.mekf`, ...). Run through the JIT, even from numba's on-disk cache, they cost every new
process about 0.55 s before the first epoch is filtered: 0.25 s to import numba and 0.3 s for numba to initialise
its code generator when it loads the first cached function. ``georef build-kernels`` (run by ``make``) compiles
the same Python source ahead of time with ``numba.pycc`` into ordinary extension modules; loading one takes
milliseconds and imports no numba.

A built module's name carries a hash of everything the compiled code depends on (``_aot_ins_<hash>``): the bytes
of every ``georef`` source file that importing the kernel's module executes, directly or through other modules
(found by reading their ``import`` statements, :func:`import_closure`), the exported signatures, and the Python,
numba, llvmlite and numpy versions and the platform. A kernel whose sources or toolchain changed after the build
is therefore never run from a stale binary: its module is not found and the JIT serves until ``georef
build-kernels`` runs again. A JSON record of the inputs next to each build lets the loader say what changed.

The builds live in the package directory, or in ``$GEOREF_KERNEL_DIR`` when that is set (a read-only install,
tests). ``GEOREF_KERNELS=jit`` forces the JIT (tests compare the two), ``GEOREF_KERNELS=aot`` makes a missing or
stale build an error that names it.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import importlib.machinery
import importlib.util
import json
import os
import platform
import re
import sys
import sysconfig
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType, SimpleNamespace

import numpy as np

from georef import kernel_blas

PACKAGE = "georef"
PACKAGE_DIR = Path(__file__).resolve().parent
#: the environment variable naming the directory builds are written to and loaded from (default PACKAGE_DIR)
DIR_VARIABLE = "GEOREF_KERNEL_DIR"
#: version of the build procedure and of the record written next to each build; part of every build's hash
BUILD_FORMAT = 2


#: an argument or result: (dtype, number of dimensions); 0 dimensions is a scalar. Arrays are C-ordered.
Slot = tuple[str, int]
_NUMBA_TYPE = {"float64": "float64", "int64": "int64", "bool": "bool_", "uint8": "uint8"}


def _numba_type(slot: Slot) -> str:
    dtype, ndim = slot
    if ndim == 0:
        return _NUMBA_TYPE[dtype]
    return f"{_NUMBA_TYPE[dtype]}[{', '.join([':'] * (ndim - 1) + ['::1'])}]"


@dataclass(frozen=True)
class KernelFunction:
    """An exported function's interface: argument and result slots, in order."""

    args: tuple[Slot, ...]
    returns: tuple[Slot, ...]

    def numba_signature(self) -> str:
        """The numba signature text ``Tuple((...))(...)``, or ``type(...)`` for one return value, that
        ``numba.pycc`` compiles."""
        arguments = ", ".join(_numba_type(slot) for slot in self.args)
        if len(self.returns) == 1:
            return f"{_numba_type(self.returns[0])}({arguments})"
        returns = ", ".join(_numba_type(slot) for slot in self.returns)
        return f"Tuple(({returns}))({arguments})"


@dataclass(frozen=True)
class KernelSpec:
    """One compiled module: the numba module it comes from and its exported functions.

    The files it is built from are not listed: :func:`import_closure` reads them off the module's imports.
    """

    jit_module: str
    functions: dict[str, KernelFunction]


F1, F2, F3, I1, I2, B1 = ("float64", 1), ("float64", 2), ("float64", 3), ("int64", 1), ("int64", 2), ("bool", 1)
U1 = ("uint8", 1)
FLOAT, INT, BOOL = ("float64", 0), ("int64", 0), ("bool", 0)

KERNELS: dict[str, KernelSpec] = {
    "ins": KernelSpec(
        "georef.fusion.ins_kernel",
        {"ekf_forward": KernelFunction(
            args=(F1, F2, F2, F2, B1, F2, INT, F1, F2, I1, F1, F2, F2, F2, F1, F1, F2),
            returns=(I1, F1, F3, F3, F3, F2, I1, F2, F3, F3, F1, I1, I1, I1, F2, F3, I1, F2, I1, F2)),
         "rts_backward": KernelFunction(
            args=(F1, F3, F3, F3, F2, B1, B1, F1, I1, F2, F3, F2, I1, I1, I1, F2, F3, I1, F2, BOOL, F2),
            returns=(F2, F2, F2)),
         "prior_shift": KernelFunction(args=(F3, F3, F3, B1, F1), returns=(F2, F2)),
         "corrected": KernelFunction(args=(F1, F1), returns=(F1,)),
         "two_sample_corrections": KernelFunction(args=(F2, F2), returns=(F2, F2)),
         "finish_rows": KernelFunction(
            args=(F1, F2, I1, F2, F2, F3, F3),
            returns=(B1, F2, F2, F3, F2, F2, F2))}),
    "align": KernelSpec(
        "georef.fusion.alignment_kernel",
        {"preintegrate": KernelFunction(
            args=(F1, F2, F2, INT, F1, F1, F1, F1),
            returns=(F3, F2, F2, F2, F2, F3, F3, F3, F3, F3, F3))}),
    "yaw": KernelSpec(
        "georef.fusion.yaw_offset_kernel",
        {"window_solve": KernelFunction(args=(F2, F1, F2, F3, F1, FLOAT), returns=(F1,)),
         "huber_lstsq": KernelFunction(args=(F2, F1, FLOAT), returns=(F1, F2))}),
    "axis": KernelSpec(
        "georef.fusion.axis_kernel",
        {"axis_filter": KernelFunction(args=(F1, F2, F1, F2, F2, F1, F1, F1, FLOAT, INT),
                                       returns=(F2, F2, F2, F2, F2, F2, F2, I1))}),
    # the attitude filters: t, gyro, accel, mag, mag_reference, q0, b0, P0, gyro_noise, bias_walk, accel_sigma,
    # mag_sigma, accel_gate, use_mag[, alpha, beta, kappa], rate_gate -> quaternions, biases, sigmas
    "mekf": KernelSpec(
        "georef.attitude.mekf",
        {"mekf": KernelFunction(
            args=(F1, F2, F2, F2, F1, F1, F1, F2, FLOAT, FLOAT, FLOAT, FLOAT, FLOAT, BOOL, FLOAT),
            returns=(F2, F2, F2))}),
    "ukf": KernelSpec(
        "georef.attitude.ukf",
        {"ukf": KernelFunction(
            args=(F1, F2, F2, F2, F1, F1, F1, F2, FLOAT, FLOAT, FLOAT, FLOAT, FLOAT, BOOL, FLOAT, FLOAT, FLOAT,
                  FLOAT),
            returns=(F2, F2, F2))}),
    # a clean block of a text table: bytes, length, separator, fields, output column per field, kind per output,
    # lines -> numbers, text cell starts and ends, status
    "table": KernelSpec(
        "georef.io.table_kernel",
        {"parse_block": KernelFunction(args=(U1, INT, INT, INT, I1, I1, INT), returns=(F2, I2, I2, I1))}),
    # the message walk of a binary DataFlash log: bytes, message length per type (updated), bytes to walk ->
    # message offsets and types, skipped runs' offsets and lengths
    "dataflash": KernelSpec(
        "georef.io.logs.dataflash_kernel",
        {"scan": KernelFunction(args=(U1, I1, INT), returns=(I1, I1, I1, I1))}),
    "tilt": KernelSpec(
        "georef.attitude.tilt",
        {"complementary": KernelFunction(args=(F1, F2, F1, F1, FLOAT), returns=(F2,)),
         "angle_bias_kalman": KernelFunction(args=(F1, F2, F1, F1, FLOAT, FLOAT, FLOAT), returns=(F2, F2))}),
}

#: which implementation each kernel was loaded from in this process ("aot" or "jit")
LOADED: dict[str, str] = {}
#: why the last load of a kernel in "auto" mode did not use an ahead-of-time build (absent when it did)
FALLBACK: dict[str, str] = {}


# --------------------------------------------------------------------------------------------------------------
# what a build depends on


def _module_file(module: str, root: Path) -> Path | None:
    """The source file of ``georef`` module ``module`` under ``root`` (the package directory), or None when the
    name is no module there (a name imported from a module, or a namespace package without ``__init__.py``)."""
    parts = module.split(".")
    if parts[0] != PACKAGE:
        return None
    base = root.joinpath(*parts[1:])
    if len(parts) > 1 and base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    return None


_STATEMENT_START = re.compile(r"[ \t]*(?:import[ \t]|from[ \t.])")


def import_statements(source: str) -> list[ast.Import | ast.ImportFrom]:
    """Every ``import`` and ``from ... import`` statement of a Python source, at any depth (inside functions and
    ``if`` blocks too: a superset of what one run imports).

    Only the lines that begin such a statement (and their bracketed or backslashed continuation) are parsed,
    1 ms against 67 ms for parsing the eight files of the "ins" kernel whole, which every run would pay. A
    docstring line that happens to read like an import is parsed too; it can only add a file to the closure.
    Statements that do not begin a line (``if x: import y``) are not seen: tests/test_aot.py checks that
    the package has none, against a full :func:`ast.parse` of every file.
    """
    lines = source.splitlines()
    statements: list[ast.Import | ast.ImportFrom] = []
    for number, line in enumerate(lines):
        if not _STATEMENT_START.match(line):
            continue
        text = code = line.partition("#")[0]
        end = number
        while (code.count("(") > code.count(")") or code.rstrip().endswith("\\")) and end + 1 < len(lines):
            end += 1
            more = lines[end].partition("#")[0]
            text, code = f"{text}\n{more}", f"{code}\n{more}"
        try:
            tree = ast.parse(text.strip())
        except SyntaxError:
            continue  # prose in a docstring
        statements.extend(node for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom))
    return statements


def imported_modules(statements: list[ast.Import | ast.ImportFrom], module: str, is_package: bool) -> list[str]:
    """The absolute module names ``statements`` (in module ``module``) may import: ``from a import b`` gives
    ``a`` and ``a.b`` (b may be a submodule); relative imports are resolved against ``module``."""
    names = []
    for node in statements:
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
            continue
        if node.level:
            package = module if is_package else module.rpartition(".")[0]
            for _ in range(node.level - 1):
                package = package.rpartition(".")[0]
            base = f"{package}.{node.module}" if node.module else package
        else:
            base = node.module or ""
        names.append(base)
        names.extend(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
    return names


def import_closure(module: str, root: Path = PACKAGE_DIR) -> tuple[str, ...]:
    """The ``georef`` source files that importing ``module`` may execute, as paths relative to ``root``.

    Follows ``import`` and ``from ... import`` statements (:func:`import_statements`) recursively through the
    package, including the ``__init__.py`` of every package on the way, which Python runs before a
    submodule. Modules outside ``georef`` are not followed (numba's and numpy's versions are hashed instead);
    nor are imports by computed name (``importlib.import_module(f"...")``), which the kernels do not use.
    """
    seen: set[str] = set()
    files: set[Path] = set()
    pending = [module]
    while pending:
        name = pending.pop()
        if name in seen or not (name == PACKAGE or name.startswith(PACKAGE + ".")):
            continue
        seen.add(name)
        parts = name.split(".")
        pending.extend(".".join(parts[:i]) for i in range(1, len(parts)))  # parent packages run first
        path = _module_file(name, root)
        if path is None:
            continue
        files.add(path)
        statements = import_statements(path.read_text(encoding="utf-8"))
        pending.extend(imported_modules(statements, name, path.name == "__init__.py"))
    return tuple(sorted(path.relative_to(root).as_posix() for path in files))


def _distribution_version(name: str) -> str:
    """The installed version of distribution ``name`` without importing it: from its ``.dist-info`` folder
    name next to the package (standard for wheels), else from :mod:`importlib.metadata` (40 ms to import)."""
    spec = importlib.util.find_spec(name)
    if spec is not None and spec.origin:
        found = list(Path(spec.origin).parent.parent.glob(f"{name}-*.dist-info"))
        if len(found) == 1:
            return found[0].name[len(name) + 1:-len(".dist-info")]
    from importlib.metadata import version

    return version(name)


@functools.cache
def toolchain() -> dict[str, str]:
    """What besides the sources a compiled module depends on: interpreter, platform, numba, llvmlite, numpy."""
    return {"python": f"{sys.implementation.name} {platform.python_version()}",
            "platform": sysconfig.get_platform(),
            "extension": importlib.machinery.EXTENSION_SUFFIXES[0],
            "numba": _distribution_version("numba"),
            "llvmlite": _distribution_version("llvmlite"),
            "numpy": np.__version__}


@functools.cache
def build_inputs(name: str) -> dict:
    """Everything kernel ``name``'s compiled module depends on, as recorded next to a build: the build format,
    the exported signatures, SHA-256 of each source file in :func:`import_closure` and the :func:`toolchain`.
    Computed once per process (the JIT module is not reloaded within a process either)."""
    spec = KERNELS[name]
    return {"format": BUILD_FORMAT,
            "kernel": name,
            "module": spec.jit_module,
            "functions": {function: interface.numba_signature() for function, interface in spec.functions.items()},
            "files": {relative: hashlib.sha256((PACKAGE_DIR / relative).read_bytes()).hexdigest()
                      for relative in import_closure(spec.jit_module)},
            **toolchain()}


def build_hash(name: str) -> str:
    """Twelve hex digits of SHA-256 over :func:`build_inputs` (canonical JSON)."""
    text = json.dumps(build_inputs(name), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def aot_module_name(name: str) -> str:
    """The extension module's name for the current inputs of kernel ``name``."""
    return f"_aot_{name}_{build_hash(name)}"


def kernel_dir() -> Path:
    """The directory builds are written to and loaded from: ``$GEOREF_KERNEL_DIR``, else the package."""
    value = os.environ.get(DIR_VARIABLE, "").strip()
    return Path(value).expanduser().resolve() if value else PACKAGE_DIR


def _build_file(module_name: str, directory: Path) -> Path | None:
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        if (directory / f"{module_name}{suffix}").is_file():
            return directory / f"{module_name}{suffix}"
    return None


def _builds(name: str, directory: Path, records: bool = False) -> list[Path]:
    """Every compiled module of kernel ``name`` in ``directory``, whatever its hash (and their records)."""
    pattern = re.compile(rf"_aot_{re.escape(name)}_[0-9a-f]{{12}}\.")
    return sorted(path for path in directory.glob(f"_aot_{name}_*")
                  if pattern.match(path.name) and (records or not path.name.endswith(".json")))


def _differences(recorded: dict, current: dict) -> list[str]:
    """What changed between a build's recorded inputs and the current ones, in words."""
    changes = []
    old_files, new_files = recorded.get("files", {}), current["files"]
    changes += [f"{PACKAGE}/{path} changed" for path in sorted(old_files.keys() & new_files.keys())
                if old_files[path] != new_files[path]]
    changes += [f"{PACKAGE}/{path} is now imported" for path in sorted(new_files.keys() - old_files.keys())]
    changes += [f"{PACKAGE}/{path} is no longer imported" for path in sorted(old_files.keys() - new_files.keys())]
    for key in sorted(current.keys() - {"files"}):
        if recorded.get(key) != current[key]:
            changes.append(f"{key}: {recorded.get(key)!r} then, {current[key]!r} now")
    return changes


def stale_builds(name: str, directory: Path | None = None) -> list[str]:
    """A sentence for each build of kernel ``name`` in ``directory`` that does not match the current inputs,
    naming the file and what changed since it was built (from the record next to it, when there is one)."""
    directory = kernel_dir() if directory is None else directory
    current = build_inputs(name)
    wanted = aot_module_name(name)
    found = []
    for path in _builds(name, directory):
        module_name = path.name.split(".")[0]
        if module_name == wanted:
            continue
        record = path.with_name(f"{module_name}.json")
        try:
            changes = _differences(json.loads(record.read_text()), current)
        except (OSError, ValueError):
            changes = ["it has no readable record of its inputs (an older georef built it)"]
        found.append(f"{path} is stale: {'; '.join(changes) or 'its record matches, but not its name'}")
    return found


# --------------------------------------------------------------------------------------------------------------
# loading


def _mode() -> str:
    mode = os.environ.get("GEOREF_KERNELS", "auto").strip().lower() or "auto"
    if mode not in ("auto", "aot", "jit"):
        raise ValueError(f"GEOREF_KERNELS must be auto, aot or jit, got {mode!r}")
    return mode


def _guarded(function: Callable, interface: KernelFunction) -> Callable:
    """``function`` with every argument converted to its slot's dtype, C order and checked dimensions.

    A compiled-ahead function reads an array's buffer as the declared dtype in C order whatever it is handed,
    so a strided view or a float32 array would be misread rather than refused; the JIT would instead compile
    another specialisation. Both get exactly the declared types.
    """

    def call(*args):
        if len(args) != len(interface.args):
            raise TypeError(f"{function.__name__} takes {len(interface.args)} arguments, got {len(args)}")
        converted = []
        for position, (value, (dtype, ndim)) in enumerate(zip(args, interface.args, strict=True)):
            if ndim == 0:
                converted.append({"float64": float, "int64": int, "bool": bool}[dtype](value))
                continue
            array = np.ascontiguousarray(value, dtype=np.bool_ if dtype == "bool" else dtype)
            if array.ndim != ndim:
                raise ValueError(f"{function.__name__}: argument {position} must have {ndim} dimensions, "
                                 f"got shape {array.shape}")
            converted.append(array)
        return function(*converted)

    call.__name__ = function.__name__
    call.__doc__ = function.__doc__
    return call


def _import_build(module_name: str, path: Path) -> ModuleType:
    """Import the extension module at ``path`` as ``georef.<module_name>`` (once per process)."""
    qualified = f"{PACKAGE}.{module_name}"
    if qualified in sys.modules:
        return sys.modules[qualified]
    spec = importlib.util.spec_from_file_location(qualified, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path} is not an extension module this Python can load")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules[qualified] = module
    return module


def load(name: str) -> SimpleNamespace:
    """Kernel ``name``'s functions: from the ahead-of-time build when one matches the current sources and
    toolchain, else from the numba JIT module (unless ``GEOREF_KERNELS=aot``, which raises ImportError naming
    the stale build and what changed). Records the choice in :data:`LOADED`, a fallback's reason in
    :data:`FALLBACK`."""
    spec = KERNELS[name]
    mode = _mode()
    module = None
    FALLBACK.pop(name, None)
    if mode != "jit":
        directory = kernel_dir()
        module_name = aot_module_name(name)
        path = _build_file(module_name, directory)
        if path is not None:
            module = _import_build(module_name, path)
        else:
            stale = stale_builds(name, directory)
            reason = (f"no ahead-of-time build of the {name!r} kernel matches the current sources and toolchain "
                      f"({module_name} in {directory}): "
                      + (" ".join(stale) if stale else "there is no build of it there"))
            if mode == "aot":
                raise ImportError(f"{reason}; run 'georef build-kernels'")
            FALLBACK[name] = reason
    LOADED[name] = "jit" if module is None else "aot"
    if module is None:
        module = importlib.import_module(spec.jit_module)
    kernel_blas.register()  # BLAS and LAPACK without importing scipy.linalg (0.2 s per run)
    return SimpleNamespace(**{function: _guarded(getattr(module, function), interface)
                              for function, interface in spec.functions.items()})


# --------------------------------------------------------------------------------------------------------------
# building


@dataclass(frozen=True)
class Build:
    """The result of :func:`build`: the module file, whether it was compiled now (False: it was up to date) and
    the warnings numba issued when ``numba.pycc`` was imported (its pending deprecation)."""

    path: Path
    compiled: bool
    notices: tuple[str, ...]


class BuildUnavailableError(RuntimeError):
    """The installed numba cannot compile ahead of time (``numba.pycc`` is missing or fails to import)."""


@functools.cache
def _pycc() -> tuple[type, tuple[str, ...]]:
    """numba.pycc's ``CC`` class and numba's deprecation warnings from importing it, as text.

    numba issues its ``NumbaPendingDeprecationWarning`` for pycc once, on import; Python's default filters
    hide pending deprecations, so they are recorded here and shown by ``georef build-kernels`` instead.
    """
    from numba.core.errors import NumbaDeprecationWarning, NumbaPendingDeprecationWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NumbaPendingDeprecationWarning)
        warnings.simplefilter("always", NumbaDeprecationWarning)
        try:
            from numba.pycc import CC
        except ImportError as exc:
            raise BuildUnavailableError(f"numba {toolchain()['numba']} cannot compile ahead of time ({exc}); install "
                                   "the numba range pyproject.toml names (docs/aot.md). georef runs its "
                                   "kernels through numba's JIT meanwhile.") from exc
    notices = []
    for warning in caught:
        if issubclass(warning.category, NumbaPendingDeprecationWarning | NumbaDeprecationWarning):
            notices.append(str(warning.message))
        else:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    return CC, tuple(notices)


def build(name: str, output_dir: Path | str | None = None, *, force: bool = False) -> Build:
    """Compile kernel ``name`` ahead of time into ``output_dir`` (default :func:`kernel_dir`, where
    :func:`load` looks), with the record of its inputs next to it; older builds of the kernel there are
    removed. Nothing is compiled when an up-to-date build is there, unless ``force``.

    The module and its record are compiled in a scratch folder and renamed into place, so a reader never sees
    half a file. Takes about 10 s per kernel.
    """
    directory = kernel_dir() if output_dir is None else Path(output_dir).resolve()
    module_name = aot_module_name(name)
    existing = _build_file(module_name, directory)
    if existing is not None and not force:
        return Build(existing, False, ())
    CC, notices = _pycc()
    spec = KERNELS[name]
    jit_module = importlib.import_module(spec.jit_module)
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{module_name}-", dir=directory) as scratch:
        compiler = CC(module_name)
        compiler.output_dir = scratch
        compiler.verbose = False
        for function, interface in spec.functions.items():
            compiler.export(function, interface.numba_signature())(getattr(jit_module, function).py_func)
        compiler.compile()
        produced = Path(scratch) / compiler.output_file
        if not produced.is_file():
            raise RuntimeError(f"numba.pycc produced no module {compiler.output_file} in {scratch}")
        record = Path(scratch) / f"{module_name}.json"
        record.write_text(json.dumps(build_inputs(name), indent=1, sort_keys=True) + "\n")
        os.replace(record, directory / record.name)
        os.replace(produced, directory / produced.name)
    built = directory / produced.name
    for old in _builds(name, directory, records=True):
        if not old.name.startswith(module_name + "."):
            old.unlink(missing_ok=True)
    return Build(built, True, notices)
