"""Shared fixtures: simulated flights written to temporary folders (deterministic seeds)."""

from __future__ import annotations

from pathlib import Path

import pytest

from georef.sim.files import installation_config, processing_config_for, write_flight
from georef.sim.flight import SimConfig, SimulatedFlight, simulate


@pytest.fixture(scope="session")
def flight_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimulatedFlight, dict[str, Path]]:
    """A 3-minute flight like those of Bošnjak (2014) (50 Hz, MEMS with vibration, GNSS 1/1/2 m), written to disk."""
    flight = simulate(SimConfig(seed=1))
    paths = write_flight(flight, tmp_path_factory.mktemp("flight"))
    return flight, paths


@pytest.fixture(scope="session")
def flight_config(flight_dir):
    return processing_config_for(flight_dir[0])


@pytest.fixture(scope="session")
def flight_defaults(flight_dir):
    """The defaults with only the flight's installation (lever arms, boresight, GNSS rate): what a new user has."""
    return installation_config(flight_dir[0])
