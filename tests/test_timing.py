"""POS time construction: the TRIG_TIME quirk in its forms, midnight, and GNSS epoch extraction."""

from __future__ import annotations

import numpy as np
import pytest

from georef.timing import extract_gnss_epochs, pos_sample_times, to_reference_day

RATE = 50


def _clock(start_s: int, seconds: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    k = np.arange(seconds * RATE)
    whole = start_s + k // RATE
    trig = (whole % 86400) * 100
    sampl = (k % RATE) * (1_000_000 // RATE) + 3000
    true = whole + sampl / 1e6
    return trig.astype(np.int64), sampl.astype(np.int64), true.astype(float)


def test_clean_clock():
    trig, sampl, true = _clock(24513, 10)
    times, report = pos_sample_times(trig, sampl, np.arange(len(trig)) + 2)
    np.testing.assert_allclose(times, true)
    assert report.n_quirks == 0


def test_one_off_quirk_as_in_the_thesis_logs():
    """One second logged as previous+1 instead of previous+100; the next second is right again (the logs of
    Bošnjak 2014, docs/method-axis.md)."""
    trig, sampl, true = _clock(24513, 10)
    block = (trig == 2451800)
    trig[block] = 2451701
    times, report = pos_sample_times(trig, sampl, np.arange(len(trig)) + 2)
    np.testing.assert_allclose(times, true)
    assert report.n_quirks == 1 and report.quirk_lines == [int(np.flatnonzero(block)[0]) + 2]


def test_persistent_quirk_continues_from_wrong_value():
    trig, sampl, true = _clock(24513, 10)
    later = trig >= 2451800
    trig[later] -= 99  # from then on the counter runs 99 centiseconds low
    times, report = pos_sample_times(trig, sampl, np.arange(len(trig)) + 2)
    np.testing.assert_allclose(times, true)
    assert report.n_quirks >= 1


def test_quirk_without_sampl_restart_stays_in_the_second():
    trig, sampl, true = _clock(24513, 4)
    rows = np.flatnonzero(trig == 2451400)
    trig[rows[20:]] = 2451401  # changed mid-second
    times, report = pos_sample_times(trig, sampl, np.arange(len(trig)) + 2)
    np.testing.assert_allclose(times, true)
    assert report.n_quirks == 1  # the glitch; the next second is consistent again


def test_data_gap_of_whole_seconds_is_kept():
    trig, sampl, true = _clock(24513, 10)
    keep = ~((true >= 24516) & (true < 24519))
    times, report = pos_sample_times(trig[keep], sampl[keep], np.arange(keep.sum()) + 2)
    np.testing.assert_allclose(times, true[keep])
    assert report.n_quirks == 0


def test_midnight_rollover_is_unwrapped():
    trig, sampl, true = _clock(86400 - 3, 6)
    times, report = pos_sample_times(trig, sampl, np.arange(len(trig)) + 2)
    np.testing.assert_allclose(times, true)
    assert np.all(np.diff(times) > 0) and times[-1] > 86400
    assert len(report.midnight_lines) == 1


def test_exposures_placed_on_the_same_day_scale():
    assert to_reference_day(np.array([30.0]), 86390.0, 86460.0)[0] == pytest.approx(86430.0)
    assert to_reference_day(np.array([86395.0]), 86390.0, 86460.0)[0] == pytest.approx(86395.0)
    assert to_reference_day(np.array([24600.0]), 24513.0, 24700.0)[0] == pytest.approx(24600.0)


def _held_gnss(values_per_second: list[float], latency: float = 0.14):
    """Sample-and-hold columns at 50 Hz for fixes on whole seconds 100, 101, ..."""
    t = 100.0 + np.arange(len(values_per_second) * RATE) / RATE + 0.01
    fix_t = 100.0 + np.arange(len(values_per_second))
    held = np.searchsorted(fix_t + latency, t, side="right") - 1
    lat = np.where(held >= 0, np.asarray(values_per_second)[np.maximum(held, 0)], 0.0)
    lon = np.where(held >= 0, 15.6, 0.0)
    h = np.where(held >= 0, 700.0, 0.0)
    return t, lat, lon, h


def test_fixes_tagged_with_their_own_whole_second():
    t, lat, lon, h = _held_gnss([44.0, 44.0001, 44.0002, 44.0003])
    epochs = extract_gnss_epochs("POS.txt", t, lat, lon, h, np.arange(len(t)) + 2)
    np.testing.assert_allclose(epochs.time, [100, 101, 102, 103])
    np.testing.assert_allclose(epochs.lat_deg, [44.0, 44.0001, 44.0002, 44.0003])


def test_equal_consecutive_fix_kept_when_rate_known_and_hovering():
    t, lat, lon, h = _held_gnss([44.0, 44.0001, 44.0001, 44.0002])
    lines = np.arange(len(t)) + 2
    unknown = extract_gnss_epochs("POS.txt", t, lat, lon, h, lines)
    assert len(unknown) == 3  # change detection alone cannot see the repeat
    speed = np.zeros(len(t))
    known = extract_gnss_epochs("POS.txt", t, lat, lon, h, lines, rate_hz=1.0, ground_speed=speed)
    np.testing.assert_allclose(known.time, [100, 101, 102, 103])
    assert known.repeated.tolist() == [False, False, True, False]
    assert any("equal consecutive" in str(n) for n in known.notices)


def test_unchanged_values_while_moving_are_an_outage_not_a_fix():
    t, lat, lon, h = _held_gnss([44.0, 44.0001, 44.0001, 44.0001, 44.0004])
    speed = np.full(len(t), 30.0)
    epochs = extract_gnss_epochs("POS.txt", t, lat, lon, h, np.arange(len(t)) + 2, rate_hz=1.0,
                                 ground_speed=speed)
    np.testing.assert_allclose(epochs.time, [100, 101, 104])
    assert epochs.gaps() == [(101.0, 104.0)]
