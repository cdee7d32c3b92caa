"""Property tests: ``--method graph`` never ends in an internal error (exit 3) on a valid simulated flight.

Hypothesis draws short flights (20-40 s) over seeds, POS rates (50-200 Hz), IMU classes, vehicles, GNSS
outages (at the start, at the end, in the middle, long) and outliers, and runs ``georef process --method graph``
on POS.txt/Kamera.txt or ``georef fuse --method graph`` on the generic imu.csv/gnss.csv through the CLI. Every
drawn flight keeps at least ``MIN_FIXES`` fixes outside its outages (the full-state filters need six), so the
input is valid and the exit code must be 0 (QC passed) or 4 (outputs written, QC failed); 2 (user error) and 3
(internal error) fail the test. Derandomised, so CI runs the same cases every time; many more cases:
``benchmarks/graph_property_sweep.py``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

IMUS = ("mems-ivru", "mems-consumer", "consumer-phone", "tactical-fog")
VEHICLES = ("helicopter", "multicopter", "car")
MIN_FIXES = 10
SETTINGS = settings(max_examples=6, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


@st.composite
def flights(draw) -> dict:
    """A valid random flight: simulate's options and the outages/outliers, in seconds from the start."""
    duration = draw(st.integers(200, 400)) / 10.0
    outages = []
    for kind in draw(st.lists(st.sampled_from(["start", "end", "middle", "long"]), max_size=2)):
        length = draw(st.integers(20, 100)) / 10.0
        if kind == "start":
            start = 0.0
        elif kind == "end":
            start = duration - length / 2.0
        elif kind == "long":
            length = duration / 2.0
            start = draw(st.integers(0, int(duration / 2.0))) * 1.0
        else:
            start = draw(st.integers(0, int(duration) - 1)) * 1.0
        outages.append((round(start, 1), round(length, 1)))
    fixes = np.arange(0.0, duration, 1.0)
    for start, length in outages:
        fixes = fixes[(fixes < start) | (fixes >= start + length)]
    assume(len(fixes) >= MIN_FIXES)  # too few fixes is an input error (exit 2), not what this test is about
    outliers = [(draw(st.integers(0, int(duration) - 1)) * 1.0, draw(st.integers(3, 60)) * 1.0)
                for _ in range(draw(st.integers(0, 2)))]
    return {"seed": draw(st.integers(1, 10**6)), "rate": draw(st.integers(50, 200)),
            "imu": draw(st.sampled_from(IMUS)), "vehicle": draw(st.sampled_from(VEHICLES)), "duration": duration,
            "outages": outages, "outliers": outliers}


def _simulate(runner, app, case: dict, folder: Path, generic: bool) -> None:
    args = ["simulate", str(folder), "--vehicle", case["vehicle"], "--duration", str(case["duration"]), "--rate",
            str(case["rate"]), "--seed", str(case["seed"]), "--imu", case["imu"], "-q"]
    for start, length in case["outages"]:
        args += ["--outage", f"{start},{length}"]
    for when, size in case["outliers"]:
        args += ["--outlier", f"{when},{size}"]
    result = runner.invoke(app, args + (["--generic"] if generic else []))
    assert result.exit_code == 0, (case, result.output)


def _check(result, case: dict) -> None:
    assert "internal error" not in result.output, (case, result.output)
    assert result.exit_code in (0, 4), (case, result.exit_code, result.output)


@SETTINGS
@given(case=flights())
def test_process_graph_never_exits_3(case):
    from georef_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "flight"
        _simulate(runner, app, case, folder, generic=False)
        result = runner.invoke(app, ["process", str(folder / "POS.txt"), str(folder / "Kamera.txt"), "--config",
                                     str(folder / "flight.toml"), "--method", "graph", "-o",
                                     str(folder / "eo.csv"), "-q"])
        _check(result, case)
        assert (folder / "eo.csv").exists()


@settings(SETTINGS, max_examples=3)
@given(case=flights())
def test_fuse_graph_never_exits_3(case):
    from georef_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "flight"
        _simulate(runner, app, case, folder, generic=True)
        result = runner.invoke(app, ["fuse", "--imu", str(folder / "imu.csv"), "--gnss", str(folder / "gnss.csv"),
                                     "--method", "graph", "-o", str(folder / "traj.csv"), "-q"])
        _check(result, case)
        assert (folder / "traj.csv").exists()
