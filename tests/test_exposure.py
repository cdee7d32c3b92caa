"""An exposure time known only to sigma_t (a trigger command's time, events.csv's ``time_sigma``) widens each
camera's position and attitude sigmas: checked against the spread of the EO itself over exposure times drawn from
that distribution (Monte-Carlo through the same interpolation), on the bundled-like simulated flight."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from georef.eo import camera_eo_columns
from georef.exposure import interpolate_to_exposures
from georef.frames import C_e_n, geodetic_to_ecef
from georef.pipeline import process

TIME_SIGMA_S = 0.05
DRAWS = 400


@pytest.fixture(scope="module")
def run(flight_dir, flight_defaults):
    _, paths = flight_dir
    return process(paths["POS.txt"], paths["Kamera.txt"], flight_defaults)


def _columns(run, times: np.ndarray, frames: np.ndarray, time_sigma: np.ndarray | None):
    exposures = dataclasses.replace(run.exposures, frame=frames, time=times, lines=np.zeros(len(times), int),
                                    problem=None, time_sigma=time_sigma)
    states = interpolate_to_exposures(run.nav, times)
    return camera_eo_columns(exposures, states, run.log.gnss, run.config.mounting, run.config.output)


def _ned(columns, reference: np.ndarray) -> np.ndarray:
    """Camera positions (K, 3) [m] NED from ``reference`` (lat, lon [deg], h) (K, 3), resolved there."""
    lat, lon = np.radians(reference[:, 0]), np.radians(reference[:, 1])
    r = geodetic_to_ecef(np.radians(columns["lat"]), np.radians(columns["lon"]), columns["height"])
    r0 = geodetic_to_ecef(lat, lon, reference[:, 2])
    return np.einsum("nij,nj->ni", C_e_n(lat, lon), r - r0)


def test_the_time_sigma_adds_the_spread_of_the_exposure_itself(run):
    times = run.exposures.time
    ok = np.isfinite(times) & (run.columns["flag"] == "")
    times, frames = times[ok], run.exposures.frame[ok]
    n = len(times)
    plain = _columns(run, times, frames, None)
    widened = _columns(run, times, frames, np.full(n, TIME_SIGMA_S))
    rng = np.random.default_rng(7)
    shifted = (times[None, :] + rng.normal(0.0, TIME_SIGMA_S, (DRAWS, n))).ravel()
    drawn = _columns(run, shifted, np.tile(frames, DRAWS), None)
    reference = np.tile(np.column_stack([plain["lat"], plain["lon"], plain["height"]]), (DRAWS, 1))
    spread = _ned(drawn, reference).reshape(DRAWS, n, 3).std(axis=0)
    for k, column in enumerate(("sigma_n", "sigma_e", "sigma_u")):
        added = np.sqrt(widened[column] ** 2 - plain[column] ** 2)
        moving = spread[:, k] > 0.2          # the axis the camera moves along (a level flight: not up)
        assert moving.sum() > n // 4 or column == "sigma_u", column
        ratio = added[moving] / spread[moving, k]
        print(column, np.percentile(ratio, [5, 50, 95]) if len(ratio) else None)
        if len(ratio):
            assert abs(np.median(ratio) - 1.0) < 0.05 and np.all(np.abs(ratio - 1.0) < 0.25), column
    for angle in ("roll", "pitch", "yaw"):
        values = np.radians(drawn[angle]).reshape(DRAWS, n)
        spread_deg = np.degrees(np.angle(np.exp(1j * (values - np.radians(plain[angle])))).std(axis=0))
        added = np.sqrt(widened[f"sigma_{angle}"] ** 2 - plain[f"sigma_{angle}"] ** 2)
        turning = spread_deg > 0.05
        print(angle, turning.sum(), np.percentile(added[turning] / spread_deg[turning], [5, 50, 95])
              if turning.any() else None)
        if turning.sum() >= 5:
            assert abs(np.median(added[turning] / spread_deg[turning]) - 1.0) < 0.1, angle
