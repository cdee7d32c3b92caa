"""Column remapping, hex parsing, atomic output and configuration files."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from georef.config import ProcessingConfig, config_to_toml, load_config
from georef.io.atomic import atomic_write
from georef.io.eo_table import read_eo_csv, write_eo_csv
from georef.io.errors import InputError
from georef.io.pos import read_pos
from georef.io.table import parse_hex


def test_hex_parsing():
    values, bad = parse_hex(np.array(["A4", "ff", "0x1F", " 10 ", "DEADBEEF", "G1", ""]))
    assert values[:5].tolist() == [0xA4, 0xFF, 0x1F, 0x10, 0xDEADBEEF]
    assert bad.tolist() == [False, False, False, False, False, True, True]


def test_remapped_columns_and_ignored_extras(flight_dir, tmp_path):
    flight, paths = flight_dir
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


def test_atomic_write_leaves_the_old_file_on_a_crash(tmp_path):
    target = tmp_path / "eo.csv"
    target.write_text("old complete table\n")
    with pytest.raises(RuntimeError), atomic_write(target) as handle:
        handle.write("half a tab")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "old complete table\n"
    assert [p.name for p in tmp_path.iterdir()] == ["eo.csv"]


def test_eo_table_round_trip(tmp_path):
    table = pd.DataFrame({"frame": ["001", "002"], "time": [1.0, 2.0], "lat": [44.1, np.nan],
                          "lon": [15.6, np.nan], "height": [700.0, np.nan], "flag": ["", "outside navigation span"]})
    write_eo_csv(table, tmp_path / "eo.csv")
    back = read_eo_csv(tmp_path / "eo.csv")
    assert back["frame"].tolist() == ["001", "002"]
    assert np.isnan(back["lat"][1]) and back["flag"][1] == "outside navigation span"


def test_config_round_trip_and_unknown_keys(tmp_path):
    cfg = ProcessingConfig(lever_arm_gnss=(0.5, 0.1, -1.6), boresight=(0.1, 0.2, 0.3), crs="EPSG:3765",
                           pos_columns={"lat": "Lat"})
    path = tmp_path / "flight.toml"
    path.write_text(config_to_toml(cfg))
    assert load_config(path) == cfg
    path.write_text("[mounting]\nlever_arm = [1, 2, 3]\n")
    with pytest.raises(InputError, match="mounting.lever_arm"):
        load_config(path)
    path.write_text("[mounting\n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_config(path)
