"""RTKLIB / Emlid ``.pos`` solutions and ``_events.pos`` camera events (georef/io/rtklib.py, docs/rtklib.md).

The fixtures are rnx2rtkp's own output for every layout and time system it writes (tests/data/rtklib/README.md):
each must read to the positions, times and covariances of the llh/GPST/ellipsoidal reference to the digits the
layout carries.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from georef_cli.main import app
from pyproj import CRS, Transformer
from pyproj.crs import CompoundCRS
from typer.testing import CliRunner

from georef.frames import C_e_n, geodetic_to_ecef, lat_lon_to_ned
from georef.frames.gpstime import solution_times
from georef.io.errors import InputError
from georef.io.events import read_events
from georef.io.generic import read_gnss_csv
from georef.io.rtklib import (
    SIGMA_FLOORS,
    is_rtklib_pos,
    read_pos_solution,
    read_rtklib_events,
    read_rtklib_gnss,
)

DATA = Path(__file__).parents[1] / "data" / "rtklib"
REFERENCE = DATA / "llh_deg_gpst_ell.pos"
RUNNER = CliRunner()

#: 2005-04-02 00:00:00 GPST, the first epoch, is 23:59:47 UTC on 2005-04-01 (GPS - UTC = 13 s from 1999 to 2005,
#: IERS Bulletin C): UTC seconds of 2005-04-01, every 30 s for 20 epochs
EXPECTED_UTC_DAY = 86400.0 - 13.0 + 30.0 * np.arange(20)
#: the UTC day of the first epoch, POSIX seconds
DAY_START = dt.datetime(2005, 4, 1, tzinfo=dt.UTC).timestamp()
#: half a unit of the last digit a layout writes, as a position error [m]: 1e-9 deg is 0.11 mm, 1e-5 arc second
#: 0.3 mm, 1e-4 m of x/y/z or e/n/u 0.05 mm each; 1 mm bounds them all
POSITION_DIGITS_M = 1e-3
#: the sd columns carry 0.1 mm: a covariance from roots of up to 0.02 m rounded by 0.05 mm is off by at most
#: 2 * 0.02 * 0.00005 = 2e-6 m^2, and a rotation mixes three such terms
COVARIANCE_DIGITS_M2 = 6e-6

ELLIPSOIDAL = ["llh_dms_gpst_ell.pos", "xyz_gpst.pos", "enu_gpst.pos", "llh_deg_utc_ell.pos", "llh_deg_gpst_week.pos",
               "llh_dms_utc_week.pos", "xyz_utc_week.pos", "enu_utc.pos", "llh_deg_gpst_ell_comma.pos",
               "llh_deg_jst_week.pos"]
GEODETIC = ["llh_deg_gpst_geo.pos", "llh_dms_jst_geo.pos"]


def _ecef(lat_deg, lon_deg, height):
    return geodetic_to_ecef(np.radians(lat_deg), np.radians(lon_deg), height)


def test_the_reference_reads_value_by_value():
    """The first line of the reference, by hand: the times in UTC, the NEU sd columns into a NED covariance with
    the signed roots squared (sdne 0.0045 -> +2.025e-5; sdeu -0.0053 -> cov(e, u) -2.809e-5, cov(e, d) +2.809e-5;
    sdun -0.0118 -> cov(n, d) +1.3924e-4)."""
    solution = read_pos_solution(REFERENCE)
    assert len(solution) == 20
    np.testing.assert_allclose(solution.utc - DAY_START, EXPECTED_UTC_DAY, rtol=0, atol=1e-6)
    assert solution.lat_deg[0] == 35.160875058 and solution.lon_deg[0] == 139.613838572
    assert solution.height[0] == 70.2698
    assert solution.quality.tolist() == [1] * 20 and solution.n_sat[0] == 5
    assert solution.ratio[0] == 7.2 and solution.age[0] == 0.0
    expected = np.array([[0.0143**2, 0.0045**2, 0.0118**2],
                         [0.0045**2, 0.0052**2, 0.0053**2],
                         [0.0118**2, 0.0053**2, 0.0160**2]])
    np.testing.assert_allclose(solution.cov_ned[0], expected, rtol=1e-12, atol=0)
    base_lat, base_lon, base_h = solution.header.base
    assert np.degrees(base_lat) == pytest.approx(35.132066140, abs=1e-12)
    assert np.degrees(base_lon) == pytest.approx(139.624302130, abs=1e-12) and base_h == 75.8027


@pytest.mark.parametrize("name", ELLIPSOIDAL)
def test_every_layout_and_time_system_reads_to_the_same_fixes(name):
    reference = read_pos_solution(REFERENCE)
    solution = read_pos_solution(DATA / name)
    np.testing.assert_allclose(solution.utc - DAY_START, EXPECTED_UTC_DAY, rtol=0, atol=1e-6)
    error = np.linalg.norm(_ecef(solution.lat_deg, solution.lon_deg, solution.height)
                           - _ecef(reference.lat_deg, reference.lon_deg, reference.height), axis=-1)
    assert error.max() < POSITION_DIGITS_M, name
    np.testing.assert_allclose(solution.cov_ned, reference.cov_ned, rtol=0, atol=COVARIANCE_DIGITS_M2)
    assert solution.quality.tolist() == reference.quality.tolist()
    fixes = read_rtklib_gnss(DATA / name)
    np.testing.assert_allclose(fixes.time, EXPECTED_UTC_DAY, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", GEODETIC)
def test_geodetic_heights_become_ellipsoidal_through_the_egm96_grid(name):
    """h = H + N with PROJ's EGM96 grid; the file's own H is the reference's h less RTKLIB's embedded geoid, which
    differs from PROJ's 15' grid by 0.30 m here (measured): the heights agree to that, no better."""
    reference = read_pos_solution(REFERENCE)
    solution = read_pos_solution(DATA / name)
    raw = pd.read_csv(DATA / "llh_deg_gpst_geo.pos", comment="%", sep=r"\s+", header=None)
    geoid_heights = raw[4].to_numpy()  # date, time, latitude, longitude, height
    egm96 = CompoundCRS(name="WGS 84 + EGM96", components=[CRS.from_epsg(4326), CRS.from_epsg(5773)])
    to_h = Transformer.from_crs(egm96, CRS.from_epsg(4979), always_xy=True, allow_ballpark=False, only_best=True)
    _, _, expected = to_h.transform(reference.lon_deg, reference.lat_deg, geoid_heights)
    np.testing.assert_allclose(solution.height, expected, rtol=0, atol=2e-4)
    grid_difference = solution.height - reference.height
    assert np.ptp(grid_difference) < 2e-4
    assert 0.25 < -grid_difference.mean() < 0.35
    assert any("EGM96 height -> WGS 84 ellipsoidal" in str(n) for n in solution.notices)
    np.testing.assert_allclose(solution.utc - DAY_START, EXPECTED_UTC_DAY, rtol=0, atol=1e-6)


def test_ecef_and_baseline_covariances_are_rotated_into_ned():
    """xyz: the file's ECEF covariance rotated by C_e_n gives back the NED one of the llh file; enu: the
    ENU-at-base covariance, rotated to the rover (3.3 km away, a 0.03 deg turn), too."""
    reference = read_pos_solution(REFERENCE)
    xyz = read_pos_solution(DATA / "xyz_gpst.pos")
    raw = pd.read_csv(DATA / "xyz_gpst.pos", comment="%", sep=r"\s+", header=None)
    sd = raw[[7, 8, 9]].to_numpy()
    cross = raw[[10, 11, 12]].to_numpy()
    cov_e = np.zeros((len(raw), 3, 3))
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        cov_e[:, i, j] = cov_e[:, j, i] = np.sign(cross[:, k]) * cross[:, k] ** 2
    for i in range(3):
        cov_e[:, i, i] = sd[:, i] ** 2
    C = C_e_n(np.radians(reference.lat_deg), np.radians(reference.lon_deg))
    np.testing.assert_allclose(xyz.cov_ned, C @ cov_e @ np.swapaxes(C, 1, 2), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(xyz.cov_ned, reference.cov_ned, rtol=0, atol=COVARIANCE_DIGITS_M2)
    enu = read_pos_solution(DATA / "enu_gpst.pos")
    # the rover's north-down covariance is +1.39e-4 m^2 in the llh file: a sign error on up/down would flip it
    assert enu.cov_ned[0, 0, 2] == pytest.approx(0.0118**2, abs=COVARIANCE_DIGITS_M2)


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


HEADER_LLH = [
    "% program   : RTKLIB ver.2.4.3 b34",
    "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
    "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  "
    "sdeu(m)  sdun(m) age(s)  ratio",
]


def _line(time: str, q: int = 1, sdn: float = 0.5, sde: float = 0.4, sdu: float = 0.9, sdne: float = 0.0,
          sdeu: float = 0.0, sdun: float = 0.0, lat: float = 45.0, lon: float = 16.0, h: float = 120.0) -> str:
    return (f"{time}   {lat:12.9f}  {lon:13.9f}  {h:9.4f}  {q:2d}  9  {sdn:7.4f}  {sde:7.4f}  {sdu:7.4f}  {sdne:7.4f}  "
            f"{sdeu:7.4f}  {sdun:7.4f}   0.00    0.0")


def test_a_negative_cross_term_gives_a_negative_covariance(tmp_path):
    path = _write(tmp_path / "hand.pos", [*HEADER_LLH, _line("2024/06/01 10:00:00.000", sdne=-0.3, sdeu=0.2,
                                                                  sdun=-0.6)])
    solution = read_pos_solution(path)
    cov = solution.cov_ned[0]
    assert cov[0, 1] == pytest.approx(-0.09) and cov[1, 0] == pytest.approx(-0.09)
    # north-up -0.36 is north-down +0.36; east-up +0.04 is east-down -0.04
    assert cov[0, 2] == pytest.approx(0.36) and cov[1, 2] == pytest.approx(-0.04)
    assert np.diag(cov) == pytest.approx([0.25, 0.16, 0.81])


def test_quality_floors_and_gating(tmp_path):
    """Fixes keep their correlations when their sigmas are raised to the Q floor; code-only solutions are dropped
    beside carrier-phase ones (with a notice naming them) and kept when asked to or when alone."""
    lines = [_line(f"2024/06/01 10:00:{s:02d}.000", q=q, sdn=sdn, sde=sdn, sdu=2 * sdn, sdne=0.7 * sdn,
                   lat=45.0 + s * 1e-6)
             for s, q, sdn in ((0, 1, 0.005), (1, 1, 0.006), (2, 5, 3.0), (3, 2, 0.1), (4, 4, 0.6), (5, 1, 0.005))]
    path = _write(tmp_path / "mixed.pos", [*HEADER_LLH, *lines])
    fixes = read_rtklib_gnss(path)
    assert fixes.line.tolist() == [4, 5, 7, 9]
    dropped = [n for n in fixes.notices if "code-only" in str(n)]
    assert len(dropped) == 1 and dropped[0].lines == [6, 8]
    # Q=1 raised to 0.02/0.02/0.04 m, Q=2 to 0.30/0.30/0.60 m, the north-east correlation (0.49) kept
    np.testing.assert_allclose(fixes.sigma_neu[0], SIGMA_FLOORS[1], rtol=1e-12)
    np.testing.assert_allclose(fixes.sigma_neu[2], SIGMA_FLOORS[2], rtol=1e-12)
    rho = fixes.cov_ned[:, 0, 1] / (fixes.sigma_neu[:, 0] * fixes.sigma_neu[:, 1])
    np.testing.assert_allclose(rho, 0.49, rtol=1e-9)
    everything = read_rtklib_gnss(path, drop_code_solutions=False, sigma_floors={5: (1.0, 1.0, 2.0)})
    assert everything.line.tolist() == [4, 5, 6, 7, 8, 9]
    # a single-point sigma above its floor stays the file's
    np.testing.assert_allclose(everything.sigma_neu[2], [3.0, 3.0, 6.0], rtol=1e-12)
    single = read_rtklib_gnss(DATA / "single_gpst.pos")
    assert len(single) == 20 and not any("code-only" in str(n) for n in single.notices)
    assert single.sigma_neu[0] == pytest.approx([9.5492, 4.8764, 14.1223])


def test_time_scales(tmp_path):
    utc = read_pos_solution(REFERENCE).utc
    gps_week = solution_times(utc, "gps-week")
    # week 1316, seconds 518400 + 30 k: the file's own GPS week and seconds
    np.testing.assert_allclose(gps_week, 518400.0 + 30.0 * np.arange(20), rtol=0, atol=1e-6)
    np.testing.assert_allclose(solution_times(utc, "utc-posix"), utc)
    with pytest.raises(ValueError, match="time scale"):
        solution_times(utc, "tai")


@pytest.mark.parametrize(("change", "line", "column", "words"), [
    (lambda lines: lines[:3] + [lines[3].replace("   1  9", "   9  9")], 4, "q", "solution quality 9"),
    (lambda lines: lines[:3] + [lines[3].replace("120.0000", "12O.0000")], 4, "height(m)", "not a number"),
    (lambda lines: lines[:3] + [lines[3] + "  7.0"], 4, None, "16 fields, the column header (line 3) gives 15"),
    (lambda lines: lines[:3] + [lines[3].replace("2024/06/01", "2024/13/01")], 4, "GPST", "neither"),
    (lambda lines: lines[:3] + [lines[3].replace(" 0.5000", "-0.5000")], 4, "sdn(m)", "must not be negative"),
    (lambda lines: lines[:3] + [lines[4], lines[3]], 5, "GPST", "time goes backwards"),
    (lambda lines: [lines[0], lines[1].replace("WGS84/", "Tokyo/"), *lines[2:]], 2, None, "datum 'Tokyo'"),
    (lambda lines: [lines[0], lines[2], *lines[3:]], 2, "height(m)", "ellipsoidal or geodetic"),
    (lambda lines: [lines[0], lines[1], *lines[3:]], 3, None, "no RTKLIB column header"),
    (lambda lines: [lines[0], lines[1], lines[2].replace("sdne(m)", "sdnx(m)"), *lines[3:]], 3, "sdnx(m)",
     "'sdne(m)' as column"),
])
def test_bad_lines_name_file_line_and_column(tmp_path, change, line, column, words):
    good = [*HEADER_LLH, _line("2024/06/01 10:00:00.000"), _line("2024/06/01 10:00:01.000")]
    path = _write(tmp_path / "bad.pos", change(good))
    with pytest.raises(InputError) as info:
        read_rtklib_gnss(path)
    assert info.value.line == line and info.value.column == column, str(info.value)
    assert words in info.value.message and "bad.pos" in str(info.value)


def test_a_last_line_cut_short_is_dropped_with_a_notice(tmp_path):
    lines = REFERENCE.read_text().splitlines()
    cut = _write(tmp_path / "cut.pos", [*lines[:-1], lines[-1][:60]])
    fixes = read_rtklib_gnss(cut)
    assert len(fixes) == 19 and fixes.line[-1] == len(lines) - 1
    assert any(n.lines == [len(lines)] and "cut short" in str(n) for n in fixes.notices)
    # the same line anywhere else is an error
    with pytest.raises(InputError, match="fields, the column header") as info:
        read_rtklib_gnss(_write(tmp_path / "mid.pos", [*lines[:-2], lines[-2][:60], lines[-1]]))
    assert info.value.line == len(lines) - 1


def test_a_baseline_file_needs_its_base(tmp_path):
    lines = [line for line in (DATA / "enu_gpst.pos").read_text().splitlines() if "ref pos" not in line]
    with pytest.raises(InputError, match="need the base position") as info:
        read_pos_solution(_write(tmp_path / "enu.pos", lines))
    assert info.value.line == 9 and info.value.column == "e-baseline(m)"


def test_recognised_by_content_not_name(tmp_path):
    renamed = tmp_path / "solution.txt"
    renamed.write_bytes(REFERENCE.read_bytes())
    assert is_rtklib_pos(renamed)
    # no program line: the column header alone
    headless = _write(tmp_path / "emlid.pos", [*HEADER_LLH[1:], _line("2024/06/01 10:00:00.000"),
                                               _line("2024/06/01 10:00:01.000")])
    assert is_rtklib_pos(headless)
    csv = _write(tmp_path / "gnss.pos", ["time,lat,lon,height", "1,45,16,100", "2,45,16,100"])
    assert not is_rtklib_pos(csv)
    fixes = read_gnss_csv(renamed)
    assert fixes.cov_ned is not None and len(fixes) == 20
    np.testing.assert_allclose(fixes.time, EXPECTED_UTC_DAY, rtol=0, atol=1e-6)


def test_camera_events_file(tmp_path):
    """The hand-written _events.pos: six time marks (one without a solution), frames 1-6 in line order, UTC
    seconds (GPS - 13 s) of their own first day, 2005-04-02, or of the GNSS solution's, 2005-04-01 (past 86400 s),
    hot-shoe time sigmas."""
    exposures, names = read_rtklib_events(DATA / "camera_events.pos")
    assert names is None
    gpst = np.array([67.412, 133.085, 171.730, 210.500, 359.999, 541.250])
    np.testing.assert_allclose(exposures.time, gpst - 13.0, rtol=0, atol=1e-6)
    on_gnss_day, _ = read_rtklib_events(DATA / "camera_events.pos", reference_utc=read_pos_solution(REFERENCE).utc[0])
    np.testing.assert_allclose(on_gnss_day.time, 86400.0 - 13.0 + gpst, rtol=0, atol=1e-6)
    assert exposures.frame.tolist() == ["1", "2", "3", "4", "5", "6"]
    assert exposures.lines.tolist() == [5, 6, 7, 8, 9, 10]
    assert exposures.time_sigma.tolist() == [0.002] * 6
    assert any(n.lines == [7] and "Time mark is not valid" in str(n) for n in exposures.notices)
    # read_events recognises it by its content
    again, _ = read_events(DATA / "camera_events.pos")
    np.testing.assert_array_equal(again.time, exposures.time)
    with pytest.raises(InputError, match="events file"):
        read_rtklib_gnss(_write_invalid_only(DATA / "camera_events.pos", tmp_path))


def _write_invalid_only(source: Path, folder: Path) -> Path:
    lines = [line for line in source.read_text().splitlines() if line.startswith("%") or "not valid" in line]
    return _write(folder / "marks.pos", lines)


# -- end to end: the CLI, and the filter with correlated fixes -------------------------------------------------


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A 2-minute simulated helicopter flight with its generic files (imu.csv, gnss.csv; UTC seconds of day)."""
    folder = tmp_path_factory.mktemp("rtklib") / "sim"
    result = RUNNER.invoke(app, ["simulate", str(folder), "--duration", "120", "--seed", "4", "--generic", "-q",
                                 "--gnss-sigma", "0.01,0.01,0.02"])
    assert result.exit_code == 0, result.output
    return folder


#: the simulated flight's UTC date, written as GPS time (GPS - UTC = 18 s in 2024)
SIM_DAY = dt.datetime(2024, 6, 1, tzinfo=dt.UTC)


def _gps_calendar(utc_seconds_of_day: float) -> str:
    t = SIM_DAY + dt.timedelta(seconds=float(utc_seconds_of_day) + 18.0)
    return f"{t:%Y/%m/%d %H:%M:%S}.{round(t.microsecond / 1000):03d}"


def _as_pos(gnss_csv: Path, out: Path) -> Path:
    """gnss.csv as an RTKLIB llh/GPST file, DGPS quality (floor 0.5/0.5/1.0 m) and the csv's sigmas."""
    g = pd.read_csv(gnss_csv)
    lines = [*HEADER_LLH]
    for r in g.itertuples():
        lines.append(_line(_gps_calendar(r.time), q=4, sdn=max(r.sigma_n, 0.5), sde=max(r.sigma_e, 0.5),
                           sdu=max(r.sigma_u, 1.0), lat=r.lat, lon=r.lon, h=r.height))
    return _write(out, lines)


def test_fuse_reads_a_pos_file_as_it_reads_gnss_csv(sim, tmp_path):
    """The same fixes as gnss.csv (at the 0.1 mm the .pos carries) written in GPS time: the trajectory is the
    csv one. One leap second wrong would move it by the flight's ~30 m/s."""
    g = pd.read_csv(sim / "gnss.csv")
    g[["sigma_n", "sigma_e", "sigma_u"]] = [0.5, 0.5, 1.0]
    csv = tmp_path / "gnss.csv"
    g.to_csv(csv, index=False, float_format="%.10f")
    pos = _as_pos(csv, tmp_path / "solution.pos")
    common = ["fuse", "--imu", str(sim / "imu.csv"), "--config", str(sim / "flight.toml"), "-q"]
    a = RUNNER.invoke(app, [*common, "--gnss", str(csv), "-o", str(tmp_path / "a.csv")])
    b = RUNNER.invoke(app, [*common, "--gnss", str(pos), "-o", str(tmp_path / "b.csv")])
    assert a.exit_code in (0, 4) and b.exit_code == a.exit_code, b.output
    ta, tb = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert len(ta) == len(tb) and (ta.time == tb.time).all()
    north, east = lat_lon_to_ned(np.radians(tb.lat - ta.lat), np.radians(tb.lon - ta.lon), np.radians(ta.lat),
                                 ta.height)
    assert np.abs(north).max() < 0.005 and np.abs(east).max() < 0.005
    assert np.abs(tb.height - ta.height).max() < 0.005
    assert np.abs(tb.sigma_n - ta.sigma_n).max() < 1e-3


def test_a_bad_pos_file_is_exit_2_naming_the_line(sim, tmp_path):
    bad = _write(tmp_path / "bad.pos", [*HEADER_LLH, _line("2024/06/01 10:00:00.000"),
                                        _line("2024/06/01 10:00:01.000").replace("   1  9", "   8  9")])
    result = RUNNER.invoke(app, ["fuse", "--imu", str(sim / "imu.csv"), "--gnss", str(bad), "-o",
                                 str(tmp_path / "t.csv"), "-q"])
    assert result.exit_code == 2
    assert "bad.pos, line 5, column 'q'" in " ".join(result.output.split())


def test_correlated_fixes_constrain_the_direction_they_are_precise_in(sim):
    """Fixes whose north and east errors are correlated (rho 0.9, 1 m each): their error along north-minus-east has
    a sigma of sqrt(1 - 0.9) m = 0.32 m, along north-plus-east 1.38 m. A filter told the covariance follows the
    fixes in the precise direction; one given only the diagonal (1 m each way) smooths it as much as the other.
    The smoothed trajectory's error along north-minus-east is then smaller with the full covariance (measured:
    0.070 m against 0.096 m for this draw) and much larger with the correlation's sign flipped (0.36 m)."""
    from georef.config import InsSettings, load_configs
    from georef.fusion.ins import InsInputs, solve_ins
    from georef.io.generic import read_imu_csv

    cfg = InsSettings.of(load_configs(sim / "flight.toml"))
    t, gyro, accel, _ = read_imu_csv(sim / "imu.csv")
    clean = read_gnss_csv(sim / "gnss.csv")
    truth = pd.read_csv(sim / "truth_traj.csv")
    rho, sigma = 0.9, np.array([1.0, 1.0, 2.0])
    cov = np.array([[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]]) * np.outer(sigma, sigma)
    error = np.random.default_rng(7).multivariate_normal(np.zeros(3), cov, size=len(clean))
    d_lat, d_lon = _ned_to_degrees(error[:, 0], error[:, 1], clean.lat_deg, clean.height)

    def run(declared: np.ndarray | None) -> float:
        fixes = dataclasses.replace(clean, lat_deg=clean.lat_deg + d_lat, lon_deg=clean.lon_deg + d_lon,
                                    height=clean.height - error[:, 2], sigma_neu=np.tile(sigma, (len(clean), 1)),
                                    cov_ned=None if declared is None else np.tile(declared, (len(clean), 1, 1)),
                                    notices=[])
        nav = solve_ins(InsInputs(time=t, gyro=gyro, accel=accel, gnss=fixes, source="sim"), cfg, smooth=True)
        rows = np.flatnonzero(nav.valid)
        k = np.searchsorted(truth.time.to_numpy(), nav.time[rows])
        assert np.abs(truth.time.to_numpy()[k] - nav.time[rows]).max() < 1e-6
        north, east = lat_lon_to_ned(nav.lat[rows] - np.radians(truth.lat.to_numpy()[k]),
                                     nav.lon[rows] - np.radians(truth.lon.to_numpy()[k]), nav.lat[rows],
                                     nav.height[rows])
        return float(np.sqrt(np.mean(((north - east) / np.sqrt(2.0)) ** 2)))

    diagonal = run(None)
    full = run(cov)
    flipped = cov.copy()
    flipped[0, 1] = flipped[1, 0] = -cov[0, 1]
    wrong = run(flipped)
    assert full < 0.85 * diagonal, (full, diagonal)
    assert wrong > 2.0 * diagonal, (wrong, diagonal)


def _ned_to_degrees(north, east, lat_deg, height):
    from georef.frames import ned_to_lat_lon

    d_lat, d_lon = ned_to_lat_lon(north, east, np.radians(lat_deg), height)
    return np.degrees(d_lat), np.degrees(d_lon)


def test_process_reads_a_pos_file_and_its_events_across_midnight(sim, tmp_path):
    """``process --imu --gnss solution.pos --events flight_events.pos`` gives the EO of the same fixes and exposure
    times as gnss.csv and events.csv. The flight is moved to cross 00:00 UTC: the solution's times go on past
    86400 s from its first day, and the events, which start after midnight, are placed on that day too."""
    shift = 86400.0 - 60.0 - 24513.0  # the IMU's first row 60 s before midnight
    imu = pd.read_csv(sim / "imu.csv")
    imu["time"] += shift
    imu.to_csv(tmp_path / "imu.csv", index=False, float_format="%.12g")
    g = pd.read_csv(sim / "gnss.csv")
    g["time"] += shift
    g[["sigma_n", "sigma_e", "sigma_u"]] = [0.5, 0.5, 1.0]
    g.to_csv(tmp_path / "gnss.csv", index=False, float_format="%.10f")
    pos = _as_pos(tmp_path / "gnss.csv", tmp_path / "solution.pos")
    camera = pd.read_csv(sim / "Kamera.txt", sep="\t")
    times = camera["Time"] + camera["Milliseconds"] / 1000.0 + shift
    after = times[times > 86400.0]
    assert len(after) > 10 and times.iloc[0] > g["time"].iloc[0]
    # every event after midnight, so the file's own first day is the next one
    marks = [*HEADER_LLH, *[_line(_gps_calendar(t), lat=45.0, lon=16.0) for t in after]]
    events_pos = _write(tmp_path / "flight_events.pos", marks)
    pd.DataFrame({"frame": np.arange(1, len(after) + 1), "time": after.to_numpy(), "time_sigma": 0.002}).to_csv(
        tmp_path / "events_after.csv", index=False, float_format="%.6f")
    common = ["process", "--imu", str(tmp_path / "imu.csv"), "--config", str(sim / "flight.toml"), "-q"]
    a = RUNNER.invoke(app, [*common, "--gnss", str(tmp_path / "gnss.csv"), "--events",
                            str(tmp_path / "events_after.csv"), "-o", str(tmp_path / "a.csv")])
    b = RUNNER.invoke(app, [*common, "--gnss", str(pos), "--events", str(events_pos), "-o", str(tmp_path / "b.csv")])
    assert a.exit_code in (0, 4) and b.exit_code == a.exit_code, b.output
    ea, eb = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert len(ea) == len(eb) == len(after)
    # the exposure times: UTC seconds of the solution's first day, past 86400 s
    np.testing.assert_allclose(eb.time, after.to_numpy(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(ea.time, eb.time, rtol=0, atol=1e-6)
    north, east = lat_lon_to_ned(np.radians(eb.lat - ea.lat), np.radians(eb.lon - ea.lon), np.radians(ea.lat),
                                 ea.height)
    assert np.abs(north).max() < 0.005 and np.abs(east).max() < 0.005
    assert np.abs(eb.height - ea.height).max() < 0.005
    for column in ("roll", "pitch", "yaw"):
        difference = (eb[column] - ea[column] + 180.0) % 360.0 - 180.0
        assert np.abs(difference).max() < 1e-3, column


# -- the IMU's time scale (--time-scale; georef.io.pos_time_scale) -----------------------------------------------

#: 2024-06-01 is a Saturday, six days into GPS week 2316 (weeks count from 1980-01-06); GPS time was 18 s ahead of
#: UTC (IERS Bulletin C): GPS seconds of the week at 00:00 UTC of SIM_DAY. Written out with datetime here, not
#: with georef.frames.gpstime, so that a slip there cannot cancel against itself.
SOW_AT_SIM_DAY = (SIM_DAY - dt.datetime(1980, 1, 6, tzinfo=dt.UTC)).total_seconds() % 604800.0 + 18.0
#: Unix seconds at 00:00 UTC of SIM_DAY
UNIX_AT_SIM_DAY = SIM_DAY.timestamp()
#: how far the trajectory and EO on another time scale may be from the UTC-of-day ones. Horizontal [m]: traj.csv
#: writes latitude and longitude to 10 significant digits, 1e-8 deg or 1.1 mm, so two rows of equal solutions can
#: differ by one such step; height [m] and angles [deg]: the IMU intervals differ in their last bits when the times
#: are larger (measured: one step of 1e-8 deg on 1 % of the rows for both; gps-week 1e-5 m, 4e-5 deg; unix, whose
#: 1.7e9 s keep 0.24 us, 6e-5 m, 8e-5 deg)
TIME_SCALE_POSITION_M = 2e-3
TIME_SCALE_HEIGHT_M = 1e-4
TIME_SCALE_ANGLE_DEG = 2e-4
#: eo.csv writes heights to 0.1 mm: one step of that on top of TIME_SCALE_HEIGHT_M [m]
EO_HEIGHT_M = TIME_SCALE_HEIGHT_M + 1e-4


@pytest.fixture(scope="module")
def utc_pair(sim, tmp_path_factory) -> Path:
    """gnss.csv as solution.pos (GPST, DGPS sigmas), and the trajectory fuse makes of it with the UTC-of-day
    imu.csv: the reference the other time scales must reproduce."""
    folder = tmp_path_factory.mktemp("utc_pair")
    g = pd.read_csv(sim / "gnss.csv")
    g[["sigma_n", "sigma_e", "sigma_u"]] = [0.5, 0.5, 1.0]
    g.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")
    _as_pos(folder / "gnss.csv", folder / "solution.pos")
    result = RUNNER.invoke(app, ["fuse", "--imu", str(sim / "imu.csv"), "--gnss", str(folder / "solution.pos"),
                                 "--config", str(sim / "flight.toml"), "-o", str(folder / "traj.csv"), "-q"])
    assert result.exit_code in (0, 4), result.output
    return folder


def _imu_on(sim: Path, offset: float, out: Path) -> Path:
    """The simulated imu.csv with ``offset`` [s] added to its UTC seconds of day."""
    imu = pd.read_csv(sim / "imu.csv")
    imu["time"] += offset
    imu.to_csv(out, index=False, float_format="%.6f")
    return out


@pytest.mark.parametrize(("scale", "offset", "words"), [
    ("gps-week", SOW_AT_SIM_DAY, "GNSS fixes taken as GPS seconds of week 2316"),
    ("unix", UNIX_AT_SIM_DAY, "GNSS fixes taken as Unix seconds"),
])
def test_an_imu_in_gps_seconds_of_week_or_unix_time_gives_the_utc_trajectory(sim, utc_pair, tmp_path, scale, offset,
                                                                              words):
    """imu.csv logged in GPS seconds of the week (or Unix seconds) with the same .pos: the scale is detected from
    imu.csv's span, and the trajectory is the UTC pair's, its times moved by the offset. A leap second dropped or
    counted twice would shift the fixes by 18 s against the IMU, metres at the flight's speed."""
    imu = _imu_on(sim, offset, tmp_path / "imu.csv")
    out = tmp_path / "traj.csv"
    result = RUNNER.invoke(app, ["fuse", "--imu", str(imu), "--gnss", str(utc_pair / "solution.pos"), "--config",
                                 str(sim / "flight.toml"), "-o", str(out)])
    assert result.exit_code in (0, 4), result.output
    assert words in " ".join(result.output.split())
    a, b = pd.read_csv(utc_pair / "traj.csv"), pd.read_csv(out)
    assert len(a) == len(b) > 5000
    np.testing.assert_allclose(b.time - offset, a.time, rtol=0, atol=1e-6)
    north, east = lat_lon_to_ned(np.radians(b.lat - a.lat), np.radians(b.lon - a.lon), np.radians(a.lat), a.height)
    assert np.abs(north).max() < TIME_SCALE_POSITION_M and np.abs(east).max() < TIME_SCALE_POSITION_M
    assert np.abs(b.height - a.height).max() < TIME_SCALE_HEIGHT_M
    for column in ("roll", "pitch", "yaw"):
        assert np.abs((b[column] - a[column] + 180.0) % 360.0 - 180.0).max() < TIME_SCALE_ANGLE_DEG, column
    np.testing.assert_allclose(b.sigma_n, a.sigma_n, rtol=1e-3)


def test_process_with_an_imu_in_gps_seconds_of_week_and_an_events_pos(sim, utc_pair, tmp_path):
    """``process --imu imu.csv (GPS seconds of week) --gnss solution.pos --events flight_events.pos``: the EO
    table of the UTC-of-day imu.csv with the same files, every exposure time moved by the same offset."""
    camera = pd.read_csv(sim / "Kamera.txt", sep="\t")
    times = (camera["Time"] + camera["Milliseconds"] / 1000.0).to_numpy()
    events = _write(tmp_path / "flight_events.pos", [*HEADER_LLH, *[_line(_gps_calendar(t)) for t in times]])
    common = ["process", "--gnss", str(utc_pair / "solution.pos"), "--events", str(events), "--config",
              str(sim / "flight.toml"), "-q"]
    a = RUNNER.invoke(app, [*common, "--imu", str(sim / "imu.csv"), "-o", str(tmp_path / "utc.csv")])
    imu = _imu_on(sim, SOW_AT_SIM_DAY, tmp_path / "imu_gps_week.csv")
    b = RUNNER.invoke(app, [*common, "--imu", str(imu), "--time-scale", "gps-week", "-o", str(tmp_path / "gps.csv")])
    assert a.exit_code in (0, 4) and b.exit_code == a.exit_code, b.output
    ea, eb = pd.read_csv(tmp_path / "utc.csv"), pd.read_csv(tmp_path / "gps.csv")
    assert len(ea) == len(eb) == len(times)
    np.testing.assert_allclose(ea.time, times, rtol=0, atol=1e-6)
    np.testing.assert_allclose(eb.time, times + SOW_AT_SIM_DAY, rtol=0, atol=1e-6)
    north, east = lat_lon_to_ned(np.radians(eb.lat - ea.lat), np.radians(eb.lon - ea.lon), np.radians(ea.lat),
                                 ea.height)
    assert np.abs(north).max() < TIME_SCALE_POSITION_M and np.abs(east).max() < TIME_SCALE_POSITION_M
    assert np.abs(eb.height - ea.height).max() < EO_HEIGHT_M
    for column in ("roll", "pitch", "yaw"):
        assert np.abs((eb[column] - ea[column] + 180.0) % 360.0 - 180.0).max() < TIME_SCALE_ANGLE_DEG, column


def test_the_spans_are_named_when_the_clocks_do_not_overlap(sim, utc_pair, tmp_path):
    """An IMU on a clock no scale matches (seconds since power-on), a scale asked for that is not the IMU's, and a
    gnss.csv on another clock than imu.csv: exit 2, the IMU's span and the fixes' named, the option suggested."""
    g = pd.read_csv(utc_pair / "gnss.csv")
    g0, g1 = float(g.time.iloc[0]), float(g.time.iloc[-1])
    boot = _imu_on(sim, -20000.0, tmp_path / "imu.csv")
    t = pd.read_csv(boot).time
    common = ["fuse", "--imu", str(boot), "--config", str(sim / "flight.toml"), "-o", str(tmp_path / "t.csv"), "-q"]
    result = RUNNER.invoke(app, [*common, "--gnss", str(utc_pair / "solution.pos")])
    text = " ".join(result.output.split())
    assert result.exit_code == 2, result.output
    assert f"imu.csv's times span {t.iloc[0]:.3f} - {t.iloc[-1]:.3f} s" in text
    assert f"as UTC seconds of 2024-06-01 {g0:.3f} - {g1:.3f} s" in text
    assert f"as GPS seconds of week 2316 {g0 + SOW_AT_SIM_DAY:.3f} - {g1 + SOW_AT_SIM_DAY:.3f} s" in text
    assert f"as Unix seconds (UTC since 1970-01-01) {g0 + UNIX_AT_SIM_DAY:.3f} - {g1 + UNIX_AT_SIM_DAY:.3f} s" in text
    assert "--time-scale" in text
    # the IMU in GPS seconds of week, told it is UTC of day: the scale that fits is named
    gps = _imu_on(sim, SOW_AT_SIM_DAY, tmp_path / "imu_gps.csv")
    wrong = RUNNER.invoke(app, ["fuse", "--imu", str(gps), "--gnss", str(utc_pair / "solution.pos"), "--time-scale",
                                "utc-day", "-o", str(tmp_path / "t.csv"), "-q"])
    assert wrong.exit_code == 2
    assert "they overlap it as gps-week: give --time-scale gps-week" in " ".join(wrong.output.split())
    # gnss.csv has no scale to choose: the filter's own check names both spans
    csv = RUNNER.invoke(app, [*common, "--gnss", str(utc_pair / "gnss.csv")])
    text = " ".join(csv.output.split())
    assert csv.exit_code == 2, csv.output
    assert f"inside the IMU span ({t.iloc[0]:.3f} - {t.iloc[-1]:.3f} s); {len(g)} GNSS fixes span {g0:.3f} - " \
           f"{g1:.3f} s, 0 of them inside" in text
    # --time-scale with no .pos to act on is refused, not ignored
    idle = RUNNER.invoke(app, [*common, "--gnss", str(utc_pair / "gnss.csv"), "--time-scale", "gps-week"])
    assert idle.exit_code == 2 and "--gnss hold none" in " ".join(idle.output.split())


def test_choose_time_scale_on_a_sunday_and_across_the_gps_week(tmp_path):
    """On a Sunday GPS seconds of the week are UTC seconds of the day + 18 s: both overlap an IMU's span, so auto
    asks and each explicit scale is taken as said. Across the GPS week's start (Saturday 23:59:42 UTC in 2024) a
    .pos whose first fix is after it is counted on from the IMU's week, past 604800 s."""
    from georef.io.pos_time_scale import choose_time_scale

    sunday = dt.datetime(2024, 6, 2, 10, 0, 0, tzinfo=dt.UTC).timestamp()
    utc = sunday + np.arange(0.0, 100.0)
    imu_utc_day = 36000.0 - 10.0 + np.arange(0.0, 120.0, 0.01)
    with pytest.raises(InputError, match=r"overlap it on 2 scales: as UTC seconds of 2024-06-02 36000\.000 - "
                                         r"36099\.000 s; as GPS seconds of week 2317 36018\.000 - 36117\.000 s"):
        choose_time_scale(tmp_path / "a.pos", utc, imu_utc_day)
    np.testing.assert_allclose(choose_time_scale(tmp_path / "a.pos", utc, imu_utc_day, "utc-day").times,
                               36000.0 + np.arange(100.0), rtol=0, atol=1e-6)
    np.testing.assert_allclose(choose_time_scale(tmp_path / "a.pos", utc, imu_utc_day + 18.0, "gps-week").times,
                               36018.0 + np.arange(100.0), rtol=0, atol=1e-6)
    # the week starts at 2024-06-01 23:59:42 UTC; the fixes from 5 s later, the IMU's rows from 10 s before it
    week_start = dt.datetime(2024, 6, 1, 23, 59, 42, tzinfo=dt.UTC).timestamp()
    choice = choose_time_scale(tmp_path / "a.pos", week_start + 5.0 + np.arange(60.0),
                               604790.0 + np.arange(0.0, 100.0, 0.01))
    assert choice.scale == "gps-week" and "GPS seconds of week 2316" in choice.notice.message
    np.testing.assert_allclose(choice.times, 604805.0 + np.arange(60.0), rtol=0, atol=1e-6)


def test_the_command_line_offers_the_scales_the_module_takes():
    """options.py writes the --time-scale choices out (importing the module costs pyproj): the two must agree."""
    from georef_cli.options import TIME_SCALES

    from georef.frames.gpstime import TIME_SCALES as RTKLIB_TIME_SCALES
    from georef.io.pos_time_scale import CHOICES, SCALES

    assert TIME_SCALES == CHOICES
    assert set(SCALES.values()) == set(RTKLIB_TIME_SCALES)


def test_the_inputs_kind_names_the_pos(utc_pair, sim):
    """The QC advice names what the user holds: a .pos is not gnss.csv."""
    from georef.io.generic import read_generic_log

    assert read_generic_log(sim / "imu.csv", utc_pair / "solution.pos").kind == "imu.csv + RTKLIB .pos"
    assert read_generic_log(sim / "imu.csv", utc_pair / "gnss.csv").kind == "imu.csv + gnss.csv"


# -- the new-user trial (issue 25): a .pos misread, misplaced or missing its header ------------------------------


def test_an_imu_in_gps_time_read_as_utc_names_the_time_scale(sim, utc_pair, tmp_path):
    """imu.csv in GPS seconds of the day (UTC + 18 s) with a GPST .pos taken as UTC seconds of the day
    (--time-scale utc-day): every fix 18 s along the track, most rejected, exit 4. The advice must name the time
    scale and the 18 leap seconds, and fuse must say which scale it used in its output and in the summary."""
    imu = _imu_on(sim, 18.0, tmp_path / "imu_gps_seconds_of_day.csv")
    summary = tmp_path / "s.json"
    result = RUNNER.invoke(app, ["fuse", "--imu", str(imu), "--gnss", str(utc_pair / "solution.pos"), "--time-scale",
                                 "utc-day", "--config", str(sim / "flight.toml"), "-o", str(tmp_path / "t.csv"),
                                 "--summary-json", str(summary)])
    text = " ".join(result.output.split())
    assert result.exit_code == 4, result.output
    # the fixes 18 s along a straight survey line: the heading is never found (the trial's drone, turning, also
    # had 70 % of its fixes rejected); every failing check that can come of it names the time scale first
    failures = {check.split(":", 1)[0]: check for check in text.split("QC fail ")[1:]}
    assert "heading" in failures, text
    for name in ("heading", "rejected fixes", "innovations", "held-out fixes"):
        if name in failures:
            assert "GPST and UTC differ by 18 s" in failures[name] and "--time-scale" in failures[name], name
    assert "time scale: " in text and "GNSS fixes taken as UTC seconds of 2024-06-01" in text
    assert "GPST: UTC = GPST - 18 s" in text
    import json

    scales = json.loads(summary.read_text())["summary"]["time_scale"]
    assert scales == [{"file": str(utc_pair / "solution.pos"), "what": "GNSS fixes", "scale": "utc-day",
                       "counted_from": "UTC seconds of 2024-06-01", "time_system": "GPST", "gps_minus_utc_s": 18,
                       "requested": "utc-day"}]


def test_process_summary_names_the_time_scale_of_each_pos(sim, utc_pair, tmp_path):
    """process --gnss solution.pos --events flight_events.pos on the UTC-of-day imu.csv: both files' scales (auto:
    UTC seconds of 2024-06-01, GPST with 18 leap seconds) in the summary JSON and in the summary table."""
    camera = pd.read_csv(sim / "Kamera.txt", sep="\t")
    times = (camera["Time"] + camera["Milliseconds"] / 1000.0).to_numpy()
    events = _write(tmp_path / "flight_events.pos", [*HEADER_LLH, *[_line(_gps_calendar(t)) for t in times]])
    summary = tmp_path / "s.json"
    result = RUNNER.invoke(app, ["process", "--imu", str(sim / "imu.csv"), "--gnss", str(utc_pair / "solution.pos"),
                                 "--events", str(events), "--config", str(sim / "flight.toml"), "-o",
                                 str(tmp_path / "eo.csv"), "--summary-json", str(summary)])
    assert result.exit_code in (0, 4), result.output
    import json

    scales = json.loads(summary.read_text())["summary"]["time_scale"]
    assert [(s["file"], s["what"], s["scale"], s["time_system"], s["gps_minus_utc_s"], s["requested"])
            for s in scales] == [(str(utc_pair / "solution.pos"), "GNSS fixes", "utc-day", "GPST", 18, "auto"),
                                 (str(events), "camera events", "utc-day", "GPST", 18, "auto")]
    text = " ".join(result.output.split())
    assert text.count("UTC = GPST - 18 s") >= 2
    # the scales are right here: no warning may send the user after them
    assert all("GPST and UTC differ by 18 s" not in line for line in text.split("QC warning")[1:])


def test_a_solution_given_as_events_is_refused(sim, utc_pair, tmp_path):
    """--events solution.pos (the receiver's 1 Hz positions, not shutter events) is exit 2 saying to give it as
    --gnss, not 120 exposures; the same file named *_events.pos, and an events file with irregular marks, are
    events."""
    result = RUNNER.invoke(app, ["process", "--imu", str(sim / "imu.csv"), "--gnss", str(utc_pair / "solution.pos"),
                                 "--events", str(utc_pair / "solution.pos"), "-o", str(tmp_path / "eo.csv"), "-q"])
    text = " ".join(result.output.split())
    assert result.exit_code == 2, result.output
    assert "this is a position solution, not camera events" in text and "Give it as --gnss" in text
    assert not (tmp_path / "eo.csv").exists()
    renamed = tmp_path / "flight_events.pos"
    renamed.write_bytes((utc_pair / "solution.pos").read_bytes())
    exposures, _ = read_rtklib_events(renamed)
    assert len(exposures) == len(read_pos_solution(utc_pair / "solution.pos"))
    g = pd.read_csv(utc_pair / "gnss.csv")
    irregular = g.time.iloc[0] + np.cumsum(np.random.default_rng(5).uniform(1.5, 3.5, 30))
    marks = _write(tmp_path / "marks.pos", [*HEADER_LLH, *[_line(_gps_calendar(t)) for t in irregular]])
    exposures, _ = read_rtklib_events(marks)
    np.testing.assert_allclose(exposures.time, irregular, rtol=0, atol=1e-3)


def test_info_describes_a_pos(tmp_path):
    """georef info on the reference .pos: its program, layout, GPST with 2005's 13 leap seconds, 20 epochs every
    30 s, the span in UTC (GPST 2005-04-02 00:00:00 is 2005-04-01 23:59:47 UTC) and in GPS time, the qualities."""
    result = RUNNER.invoke(app, ["info", str(REFERENCE)])
    text = " ".join(result.output.replace("│", " ").split())
    assert result.exit_code == 0, result.output
    solution = read_pos_solution(REFERENCE)
    assert f"format RTKLIB solution (.pos), {solution.header.program}" in text
    assert "layout llh-deg, heights ellipsoidal" in text
    assert "time system GPST (GPS time): UTC = GPST - 13 s (leap seconds)" in text
    assert "epochs 20, every 30 s: a position solution, for --gnss" in text
    assert "2005-04-01 23:59:47.000 - 2005-04-02 00:09:17.000 UTC (570.0 s)" in text
    # 2005-04-02 is a Saturday: 6 days into GPS week 1316
    assert "GPS time week 1316, 518400.000 - 518970.000 s of the week" in text
    assert "solution quality 20 fix (Q=1)" in text
    events = RUNNER.invoke(app, ["info", str(DATA / "camera_events.pos")])
    assert events.exit_code == 0, events.output
    assert "camera events 6 (1 without a solution): an events file, for --events" in " ".join(
        events.output.replace("│", " ").split())


def test_a_gzipped_pos_reads_as_the_pos(tmp_path):
    """An archived .pos.gz is the same solution, value by value (recognised by gzip's magic bytes)."""
    import gzip

    packed = tmp_path / "solution.pos.gz"
    packed.write_bytes(gzip.compress(REFERENCE.read_bytes()))
    assert is_rtklib_pos(packed)
    a, b = read_pos_solution(REFERENCE), read_pos_solution(packed)
    for name in ("utc", "lat_deg", "lon_deg", "height", "quality", "cov_ned", "line"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)
    fixes = read_gnss_csv(packed)
    np.testing.assert_allclose(fixes.time, EXPECTED_UTC_DAY, rtol=0, atol=1e-6)
    broken = tmp_path / "cut.pos.gz"
    broken.write_bytes(gzip.compress(REFERENCE.read_bytes())[:200])
    with pytest.raises(InputError, match="damaged gzip"):
        read_pos_solution(broken)


def test_a_pos_without_its_header_is_refused_naming_it(sim, utc_pair, tmp_path):
    """Solution lines with the '%' header cut off are not a csv missing its 'time' column: exit 2 naming line 1
    and the missing RTKLIB header, as --gnss, as --events and for georef info."""
    lines = [line for line in (utc_pair / "solution.pos").read_text().splitlines() if not line.startswith("%")]
    bare = _write(tmp_path / "rover.pos", lines)
    assert not is_rtklib_pos(bare)
    common = ["--imu", str(sim / "imu.csv"), "-o", str(tmp_path / "t.csv"), "-q"]
    for args in (["fuse", *common, "--gnss", str(bare)],
                 ["process", *common, "--gnss", str(utc_pair / "solution.pos"), "--events", str(bare)],
                 ["info", str(bare)]):
        result = RUNNER.invoke(app, args)
        text = " ".join(result.output.split())
        assert result.exit_code == 2, (args, result.output)
        assert "rover.pos, line 1: RTKLIB solution lines without RTKLIB's header" in text, args
        assert "required column" not in text
    assert not (tmp_path / "t.csv").exists()


def test_fuse_lists_only_sbet_as_an_export(sim, tmp_path):
    """fuse --export images:x (or any EO-table format) is exit 2 naming sbet:FILE only, not the EO formats."""
    for export in ("images:x", "metashape:m.csv", "eo.kml"):
        result = RUNNER.invoke(app, ["fuse", "--imu", str(sim / "imu.csv"), "--gnss", str(sim / "gnss.csv"),
                                     "--export", export, "-o", str(tmp_path / "t.csv"), "-q"])
        text = " ".join(result.output.split())
        assert result.exit_code == 2, result.output
        assert "sbet:FILE only" in text and "metashape, pix4d" not in text and "choose one of" not in text
        assert not (tmp_path / "t.csv").exists()
