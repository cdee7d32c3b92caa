"""``--method graph`` (GTSAM) against the RTS smoother and against outliers."""

from __future__ import annotations

import numpy as np
import pytest

from georef.evaluate import accuracy, frame_errors
from georef.pipeline import process
from georef.sim.files import processing_config_for, write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.sensors import GnssModel

OUTLIERS = [(30.0, 25.0), (55.0, 40.0), (140.0, 20.0)]
PAIRS = [("north", "sigma_n"), ("east", "sigma_e"), ("up", "sigma_u"), ("roll", "sigma_roll"),
         ("pitch", "sigma_pitch"), ("yaw", "sigma_yaw")]


def _run(tmp_path, sim, **changes):
    flight = simulate(sim)
    paths = write_flight(flight, tmp_path)
    cfg = processing_config_for(flight)
    return flight, {name: process(paths["POS.txt"], paths["Kamera.txt"], cfg.updated(**change))
                    for name, change in changes.items()}


@pytest.mark.parametrize("seed", [1, 2])
def test_graph_and_rts_agree_within_their_sigmas(tmp_path, seed):
    flight, results = _run(tmp_path, SimConfig(seed=seed), rts={"method": "rts"}, graph={"method": "graph"})
    rts, graph = results["rts"].table, results["graph"].table
    difference = frame_errors(graph, rts)
    for component, sigma in PAIRS:
        combined = np.hypot(rts[sigma], graph[sigma])
        assert np.mean(np.abs(difference[component]) <= 2.0 * combined) >= 0.95, component
    figures = accuracy(frame_errors(graph, flight.truth_frames))
    assert figures["horizontal_rms_m"] <= 0.4 and figures["vertical_rms_m"] <= 0.7


def test_robust_kernel_resists_outliers(tmp_path):
    sim = SimConfig(seed=2, gnss=GnssModel(outliers=OUTLIERS))
    flight, results = _run(tmp_path, sim, robust={"method": "graph"},
                           plain={"method": "graph", "graph_robust": False}, rts={"method": "rts"})
    robust = accuracy(frame_errors(results["robust"].table, flight.truth_frames))
    plain = accuracy(frame_errors(results["plain"].table, flight.truth_frames))
    rts = accuracy(frame_errors(results["rts"].table, flight.truth_frames))
    assert robust["horizontal_rms_m"] < plain["horizontal_rms_m"]
    assert robust["horizontal_rms_m"] <= rts["horizontal_rms_m"]  # this flight; see the xfail below


SHORTFALL = pytest.mark.xfail(strict=True, reason=(
    "known shortfall: with the unit's attitude fused (Gauss-Markov level errors, yaw origin and drift) the robust "
    "graph beats RTS-with-gating on seed 2 (0.240 vs 0.265 m) but not on 1 (0.276 vs 0.260 m), 3 (0.295 vs 0.277 m; "
    "it did before the RTS's noise model was fitted to the data) and 4 (0.308 vs 0.271 m); the two smoothers carry "
    "the same information but their estimates differ by a few centimetres, and the Cauchy kernel down-weights good "
    "fixes (docs/method-graph.md)"))


@pytest.mark.parametrize("seed", [pytest.param(1, marks=SHORTFALL), 2, pytest.param(3, marks=SHORTFALL),
                                  pytest.param(4, marks=SHORTFALL)])
def test_graph_at_least_as_accurate_as_rts_with_outliers(tmp_path, seed):
    sim = SimConfig(seed=seed, gnss=GnssModel(outliers=OUTLIERS))
    flight, results = _run(tmp_path, sim, graph={"method": "graph"}, rts={"method": "rts"})
    graph = accuracy(frame_errors(results["graph"].table, flight.truth_frames))
    rts = accuracy(frame_errors(results["rts"].table, flight.truth_frames))
    assert graph["horizontal_rms_m"] <= rts["horizontal_rms_m"]


def test_isam2_matches_batch(tmp_path):
    flight, results = _run(tmp_path, SimConfig(seed=5), lm={"method": "graph"},
                           isam2={"method": "graph", "graph_solver": "isam2"})
    difference = frame_errors(results["isam2"].table, results["lm"].table)
    lm = results["lm"].table
    for component, sigma in PAIRS[:3]:
        assert np.mean(np.abs(difference[component]) <= lm[sigma]) >= 0.95
