"""The compiled recursions, ahead of time when built, numba's JIT otherwise.

The filters' inner loops are numba functions (:mod:`georef.fusion.ins_kernel`, :mod:`georef.fusion.axis_kernel`).
Run through the JIT, even from numba's on-disk cache, they cost every new process about 0.55 s before the
first epoch is filtered: 0.25 s to import numba and 0.3 s for numba to initialise its code generator when it
loads the first cached function. ``georef build-kernels`` (run by ``make``) compiles the same Python source
ahead of time with ``numba.pycc`` into ordinary extension modules next to this package; loading one takes
milliseconds and imports no numba.

A built module's name carries a hash of the kernel's source files (``_aot_ins_<hash>``), so a kernel
edited after the build is never run from a stale binary: its module is simply not found and the JIT
serves until ``georef build-kernels`` runs again. ``GEOREF_KERNELS=jit`` forces the JIT (tests compare
the two), ``GEOREF_KERNELS=aot`` makes a missing build an error.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

PACKAGE_DIR = Path(__file__).resolve().parent


#: an argument or result: (dtype, number of dimensions); 0 dimensions is a scalar. Arrays are C-ordered.
Slot = tuple[str, int]
_NUMBA_TYPE = {"float64": "float64", "int64": "int64", "bool": "bool_"}


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
    """One compiled module: the numba module it comes from, its exported functions, the files it is built from.

    ``sources`` are paths relative to the ``georef`` package: the kernel module and every module whose
    numba functions it calls.
    """

    jit_module: str
    functions: dict[str, KernelFunction]
    sources: tuple[str, ...]


F1, F2, F3, I1, B1 = ("float64", 1), ("float64", 2), ("float64", 3), ("int64", 1), ("bool", 1)
FLOAT, INT, BOOL = ("float64", 0), ("int64", 0), ("bool", 0)

KERNELS: dict[str, KernelSpec] = {
    "ins": KernelSpec(
        "georef.fusion.ins_kernel",
        {"ekf_forward": KernelFunction(
            args=(F1, F2, F2, INT, F1, F2, I1, F1, F2, F2, F1, F2, INT, FLOAT, INT, FLOAT, FLOAT, F2, BOOL, BOOL, F2),
            returns=(I1, F1, F3, F3, F3, F2, I1, F2, F3, F3, F1, I1, I1, I1, F2, F3, I1, F2, I1, F2)),
         "rts_backward": KernelFunction(
            args=(F1, F3, F3, F3, F2, B1, B1, F1, I1, F2, F3, F2, I1, I1, I1, F2, F3, I1, F2, BOOL),
            returns=(F2, F2, F2)),
         "corrected": KernelFunction(args=(F1, F1), returns=(F1,)),
         "two_sample_corrections": KernelFunction(args=(F2, F2), returns=(F2, F2)),
         "finish_rows": KernelFunction(
            args=(F1, F2, I1, F2, F2, F3, F3),
            returns=(B1, F2, F2, F3, F2, F2, F2))},
        ("fusion/ins_kernel.py", "fusion/ins_layout.py", "fusion/strapdown.py", "frames/kernels.py",
         "frames/earth.py")),
    "align": KernelSpec(
        "georef.fusion.alignment_kernel",
        {"preintegrate": KernelFunction(
            args=(F1, F2, F2, INT, F1, F1, F1, F1),
            returns=(F3, F2, F2, F2, F2, F3, F3, F3, F3, F3, F3))},
        ("fusion/alignment_kernel.py", "frames/kernels.py", "frames/earth.py")),
    "axis": KernelSpec(
        "georef.fusion.axis_kernel",
        {"axis_filter": KernelFunction(args=(F1, F2, F1, F2, F2, F1, F1, F1, FLOAT, INT),
                                       returns=(F2, F2, F2, F2, F2, F2, F2, I1))},
        ("fusion/axis_kernel.py",)),
}

#: which implementation each kernel was loaded from in this process ("aot" or "jit")
LOADED: dict[str, str] = {}


@functools.cache
def source_hash(name: str) -> str:
    """Twelve hex digits of SHA-256 over the kernel's source files (their bytes, in the listed order), computed
    once per process (the JIT module is not reloaded within a process either)."""
    digest = hashlib.sha256()
    for relative in KERNELS[name].sources:
        digest.update(relative.encode())
        digest.update((PACKAGE_DIR / relative).read_bytes())
    return digest.hexdigest()[:12]


def aot_module_name(name: str) -> str:
    """The extension module's name for the current sources of kernel ``name``."""
    return f"_aot_{name}_{source_hash(name)}"


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


def load(name: str) -> SimpleNamespace:
    """Kernel ``name``'s functions: from the ahead-of-time build when one matches the current sources, else
    from the numba JIT module (unless ``GEOREF_KERNELS=aot``). Records the choice in :data:`LOADED`."""
    spec = KERNELS[name]
    mode = _mode()
    module = None
    if mode != "jit":
        module_name = f"georef.{aot_module_name(name)}"
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            if mode == "aot":
                raise ImportError(f"no ahead-of-time build of the {name!r} kernel for the current sources "
                                  f"({module_name}); run 'georef build-kernels'") from exc
    LOADED[name] = "jit" if module is None else "aot"
    if module is None:
        module = importlib.import_module(spec.jit_module)
    return SimpleNamespace(**{function: _guarded(getattr(module, function), interface)
                              for function, interface in spec.functions.items()})


def build(name: str) -> Path:
    """Compile kernel ``name`` ahead of time into this package, where :func:`load` finds it; returns the file.

    Older builds of the same kernel are removed. Takes about 10 s per kernel.
    """
    import warnings

    from numba.core.errors import NumbaPendingDeprecationWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
        from numba.pycc import CC

        spec = KERNELS[name]
        jit_module = importlib.import_module(spec.jit_module)
        module_name = aot_module_name(name)
        compiler = CC(module_name)
        compiler.output_dir = str(PACKAGE_DIR)
        compiler.verbose = False
        for function, interface in spec.functions.items():
            compiler.export(function, interface.numba_signature())(getattr(jit_module, function).py_func)
        for old in PACKAGE_DIR.glob(f"_aot_{name}_*"):
            old.unlink()
        compiler.compile()
    built = sorted(PACKAGE_DIR.glob(f"{module_name}.*"))
    if not built:
        raise RuntimeError(f"numba.pycc produced no module {module_name} in {PACKAGE_DIR}")
    return built[0]
