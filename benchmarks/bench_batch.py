"""Batch speed-up: N simulated flights processed sequentially vs on a 2-worker Dask LocalCluster.

The cluster's start-up and each worker's first task (imports, kernel load) are reported separately; the
speed-up compares steady-state batch time. For reference, the same flights on two plain processes without Dask
(the machine's own ceiling for two concurrent flights).
Usage: python benchmarks/bench_batch.py [--flights 6] [--minutes 10] [--dask-defaults]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from georef.batch import discover, process_flight, start_local_cluster
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--flights", type=int, default=6)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--method", default="rts")
    parser.add_argument("--dask-defaults", action="store_true",
                        help="run the workers with Dask's default settings instead of georef's")
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="georef-batch-"))
    for seed in range(1, args.flights + 1):
        write_flight(simulate(SimConfig(seed=seed, plan=FlightPlan(duration_s=args.minutes * 60, seed=seed))),
                     root / "in" / f"flight{seed:02d}")
    jobs = discover(root / "in")
    process_flight(jobs[0], str(root / "warm"), args.method)  # warm this process's numba cache
    start = time.perf_counter()
    for job in jobs:
        process_flight(job, str(root / "sequential"), args.method)
    sequential = time.perf_counter() - start

    from dask.distributed import Client, wait

    start = time.perf_counter()
    cluster = start_local_cluster(2, tuned=not args.dask_defaults)
    client = Client(cluster)
    startup = time.perf_counter() - start
    workers = list(client.scheduler_info()["workers"])
    start = time.perf_counter()
    warm = [client.submit(process_flight, jobs[0], str(root / "warm"), args.method, workers=[w], pure=False,
                          key=f"warm-{i}") for i, w in enumerate(workers)]
    wait(warm)
    warmup = time.perf_counter() - start
    start = time.perf_counter()
    futures = [client.submit(process_flight, job, str(root / "parallel"), args.method, pure=False) for job in jobs]
    rows = client.gather(futures)
    parallel = time.perf_counter() - start
    client.close()
    cluster.close()
    assert all(row["status"] == "ok" for row in rows)

    # the machine's own ceiling: the same flights on two plain processes, no Dask
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2) as pool:
        list(pool.map(process_flight, jobs[:2], [str(root / "warm")] * 2, [args.method] * 2))  # warm both
        start = time.perf_counter()
        plain_rows = list(pool.map(process_flight, jobs, [str(root / "plain")] * len(jobs),
                                   [args.method] * len(jobs)))
        plain = time.perf_counter() - start
    assert all(row["status"] == "ok" for row in plain_rows)
    busy = sum(row["runtime_s"] for row in rows)
    from georef import aot

    settings = "Dask defaults" if args.dask_defaults else "georef's worker settings"
    print(f"{args.flights} flights of {args.minutes:g} min at 50 Hz, method {args.method}, kernels {aot.LOADED}, "
          f"{settings}:")
    print(f"  sequential (one process, warm):      {sequential:6.2f} s")
    print(f"  LocalCluster 2 workers (warm):       {parallel:6.2f} s   speed-up {sequential / parallel:.2f}x")
    print(f"  two plain processes, no Dask (warm): {plain:6.2f} s   speed-up {sequential / plain:.2f}x   "
          f"(summed task time {sum(row['runtime_s'] for row in plain_rows):.2f} s)")
    print(f"  cluster start-up {startup:.2f} s, first task per worker (imports, kernel load) {warmup:.2f} s")
    print(f"  summed task time on the workers {busy:.2f} s (sequential {sequential:.2f} s): contention "
          f"{busy / sequential:.2f}x, scheduling overhead {parallel - busy / 2:.2f} s")


if __name__ == "__main__":
    main()
