"""``georef build-kernels``: the filters' inner loops compiled ahead of time (:mod:`georef.aot`)."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.markup import escape

from ..options import Quiet
from ..running import EXIT_USER_ERROR, console


def build_kernels(
    force: Annotated[bool, typer.Option("--force", help="Compile even the kernels whose build is up to date.")] = False,
    quiet: Quiet = False,
) -> None:
    """Compile the filters' inner loops ahead of time (10-45 s each; nothing to do when up to date).

    The modules are written inside the installed georef package, or into $GEOREF_KERNEL_DIR when set (the
    runs then load them from there). Without this step georef runs the same loops through numba's JIT, which
    costs every run about 0.5 s of start-up. A build whose sources, numba, numpy or Python have changed since
    is never run; this command replaces it.
    """
    import os
    from concurrent.futures import ProcessPoolExecutor

    from georef.aot import KERNELS, BuildUnavailableError, build

    # one process per kernel, as many at once as there are cores: each compile is single-threaded (numba.pycc),
    # and on a 2-core machine the six kernels took 2 min one after the other
    notices: list[str] = []
    workers = max(1, min(len(KERNELS), os.cpu_count() or 1))
    try:
        with ProcessPoolExecutor(workers) as pool:
            futures = [pool.submit(build, name, force=force) for name in KERNELS]
            for name, future in zip(KERNELS, futures, strict=True):
                if quiet:
                    result = future.result()
                else:
                    with console.status(f"compiling the {name} kernel ({workers} at a time)"):
                        result = future.result()
                    console.print(f"{'built' if result.compiled else 'up to date'} {escape(str(result.path))}",
                                  highlight=False)
                notices += [notice for notice in result.notices if notice not in notices]
    except BuildUnavailableError as exc:  # a numba without pycc: the user can install the tested range
        console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=EXIT_USER_ERROR) from None
    if not quiet:
        for notice in notices:  # numba.pycc's pending deprecation, shown rather than filtered (docs/aot.md)
            console.print(f"[yellow]notice from numba:[/] {escape(notice)}", highlight=False)
