"""The POS.txt reader (georef.io.pos): columns found by name and remapped by the configuration, times and the
counter against the simulation."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from georef.io.pos import read_pos


def test_remapped_columns_and_ignored_extras(flight_dir, tmp_path):
    _, paths = flight_dir
    frame = pd.read_csv(paths["POS.txt"], sep="\t", dtype=str)
    frame = frame.rename(columns={"LATITUDE": "Lat_deg", "IACC_X": "acc_level_x"})
    frame.insert(3, "EXTRA", "x")
    frame = frame[list(reversed(frame.columns))]  # columns found by name, not position
    remapped = tmp_path / "POS.txt"
    frame.to_csv(remapped, sep="\t", index=False)
    log = read_pos(remapped, required_roles=["iacc_x"], column_names={"lat": "Lat_deg", "iacc_x": "acc_level_x"})
    reference = read_pos(paths["POS.txt"], required_roles=["iacc_x"])
    np.testing.assert_array_equal(log.time, reference.time)
    np.testing.assert_array_equal(log.data["iacc_x"], reference.data["iacc_x"])
    np.testing.assert_array_equal(log.gnss.lat_deg, reference.gnss.lat_deg)
    with pytest.raises(ValueError, match="unknown POS column role"):
        read_pos(remapped, column_names={"latitude": "Lat_deg"})


def test_pos_times_and_counter_match_the_simulation(flight_dir):
    flight, paths = flight_dir
    log = read_pos(paths["POS.txt"], gnss_rate_hz=1.0)
    np.testing.assert_allclose(log.time, flight.truth_nav.time, atol=1e-9)
    np.testing.assert_allclose(log.gnss.time, flight.gnss_fixes["time"])
    assert log.time_repairs.n_quirks == len(flight.config.trig_quirk_seconds)
    assert log.data["counter"][0] == 0xA4
