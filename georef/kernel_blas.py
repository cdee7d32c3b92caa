"""scipy's BLAS and LAPACK for the compiled kernels, without importing ``scipy.linalg``.

A kernel compiled by numba (ahead of time or by the JIT) finds BLAS and LAPACK as numba does: at its first matrix
product or solve it imports the modules ``scipy.linalg.cython_blas`` and ``scipy.linalg.cython_lapack`` by name and
reads the function pointers from their ``__pyx_capi__``. Importing them by name first runs the ``scipy.linalg``
package, which imports most of scipy.linalg and scipy's array-API layer, a large share of every ``georef
process``'s CPU, for two extension modules that load in a small fraction of it on their own
(``docs/performance.md``, "Imports").

:func:`register` loads the two extension modules from scipy's own files and registers them under their names in
``sys.modules``, so that the kernels' lookup finds them there. They are the same modules, with the same library and
functions, so the results are bit for bit those of the normal import. ``scipy.linalg`` can still be imported
afterwards (it finds the two modules already loaded). Nothing is done when ``scipy.linalg`` is already imported or
when anything differs from this layout (a module missing, an error while loading): the kernels' lookup then
imports ``scipy.linalg`` as before.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path

#: the modules numba's helper library imports for BLAS and LAPACK (numba/_helperlib.c, import_cython_function)
MODULES = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")


def register() -> bool:
    """Load and register :data:`MODULES` without their package; True when they are (now or already) registered."""
    if all(name in sys.modules for name in MODULES):
        return True
    if "scipy.linalg" in sys.modules:
        return False  # the package is imported: numba's import finds its modules the usual way
    try:
        import scipy  # noqa: F401  (the top-level package only: cheap, docs/performance.md "Imports")

        directory = Path(sys.modules["scipy"].__file__).parent / "linalg"
        loaded = []
        for name in MODULES:
            if name in sys.modules:
                continue
            stem = name.rsplit(".", 1)[1]
            files = [directory / (stem + suffix) for suffix in importlib.machinery.EXTENSION_SUFFIXES]
            path = next((f for f in files if f.is_file()), None)
            if path is None:
                return False
            loader = importlib.machinery.ExtensionFileLoader(name, str(path))
            spec = importlib.util.spec_from_file_location(name, path, loader=loader)
            if spec is None:
                return False
            module = importlib.util.module_from_spec(spec)
            loader.exec_module(module)
            if not isinstance(getattr(module, "__pyx_capi__", None), dict):
                return False
            loaded.append((name, module))
        for name, module in loaded:
            sys.modules[name] = module
        return True
    except Exception:  # noqa: BLE001 - any surprise: leave the lookup to the normal import
        return False
