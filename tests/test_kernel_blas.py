"""The compiled kernels' BLAS and LAPACK without importing scipy.linalg (georef.kernel_blas): the same results as
with the normal import, scipy.linalg not imported, and importable afterwards."""

from __future__ import annotations

import subprocess
import sys

import pytest

#: a kernel call whose products and solves go through BLAS and LAPACK (the smoother: matrix products and
#: np.linalg.solve), on random but well-posed inputs; prints a digest of the results and whether scipy.linalg was
#: imported
SCRIPT = """
import hashlib, sys
import numpy as np
if {import_first}:
    import scipy.linalg  # the normal lookup: numba finds the modules through the package
from georef import aot
from georef.fusion import ins_layout as layout
kernel = aot.load("ins")
rng = np.random.default_rng(3)
n_ep, nx = 40, layout.NX_NAV
Phi = np.eye(nx) + 0.01 * rng.standard_normal((n_ep, nx, nx))
B = rng.standard_normal((n_ep, nx, nx))
Pp = np.einsum("eij,ekj->eik", B, B) + nx * np.eye(nx)
Pm = np.einsum("eij,ejk,elk->eil", Phi, Pp, Phi) + np.eye(nx)
seg = np.zeros(n_ep, dtype=bool)
seg[0] = True
out = kernel.rts_backward(np.full(n_ep, 0.5), Pm, Pp, Phi, 0.01 * rng.standard_normal((n_ep, nx)), seg,
                          np.zeros(n_ep, dtype=bool), np.ones(layout.N_NOISE), np.zeros(0, dtype=np.int64),
                          np.zeros((0, 3)), np.zeros((0, 3, nx)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64),
                          np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3)),
                          np.zeros((0, 3, nx)), np.zeros(0, dtype=np.int64), np.zeros((0, 3)), True,
                          np.zeros((n_ep, nx)))
digest = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in out)).hexdigest()
print(digest, "scipy.linalg" in sys.modules, aot.LOADED["ins"])
import scipy.linalg
print(bool(np.allclose(scipy.linalg.solve(Pp[1], np.ones(nx)) @ Pp[1], 1.0)))
"""


def _run(import_first: bool) -> list[str]:
    run = subprocess.run([sys.executable, "-c", SCRIPT.format(import_first=import_first)], capture_output=True,
                         text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr
    return run.stdout.split()


@pytest.mark.parametrize("mode", ["aot", "jit"])
def test_kernels_use_scipys_blas_without_importing_scipy_linalg(monkeypatch, mode):
    monkeypatch.setenv("GEOREF_KERNELS", mode) if mode == "jit" else monkeypatch.delenv("GEOREF_KERNELS", raising=False)
    registered = _run(import_first=False)
    normal = _run(import_first=True)
    assert registered[0] == normal[0], "the results differ from those of the normal BLAS lookup"
    assert registered[1] == "False", "scipy.linalg was imported"
    assert normal[1] == "True"
    assert registered[3] == "True", "scipy.linalg does not work after the registration"


def test_registration_falls_back_to_the_normal_import_when_the_layout_differs():
    """A scipy whose extension files are not where register() looks (here: no file has an extension suffix it
    tries, for the whole run): it registers nothing and says so, and the kernels then find BLAS and LAPACK
    through the normal import of scipy.linalg, with the same results."""
    script = ("import importlib.machinery, sys\n"
              "importlib.machinery.EXTENSION_SUFFIXES[:] = ['.no-such-suffix']\n"
              "from georef import kernel_blas\n"
              "print(kernel_blas.register(), any(m in sys.modules for m in kernel_blas.MODULES))\n")
    run = subprocess.run([sys.executable, "-c", script + SCRIPT.format(import_first=False)], capture_output=True,
                         text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr
    refused, loaded, digest, imported, *_ = run.stdout.split()
    assert (refused, loaded) == ("False", "False")
    assert digest == _run(import_first=True)[0], "the fallback's results differ from those of the normal lookup"
    assert imported == "True", "the fallback did not go through scipy.linalg"
