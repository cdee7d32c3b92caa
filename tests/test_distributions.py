"""georef.distributions against scipy.special (the functions it replaces on the path of every run)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import chdtr, chdtrc, chdtri, fdtr, fdtri

from georef.distributions import CHI2_3DOF_99_9, chi2_cdf, chi2_isf, chi2_sf, f_sf

#: degrees of freedom: the quality checks use 3 and 3 n (n used GNSS fixes, tens to tens of thousands)
DOFS = [1, 2, 3, 4, 5, 7, 10, 15, 30, 31, 60, 99, 300, 1000, 2601, 3000, 10001, 30000, 90000]
PROBABILITIES = [1e-12, 1e-8, 1e-4, 5e-4, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 0.9995, 0.9999, 1 - 1e-8]


@pytest.mark.parametrize("k", DOFS)
def test_chi2_quantiles_match_scipy(k):
    for p in PROBABILITIES:
        expected = chdtri(k, p)
        assert chi2_isf(p, k) == pytest.approx(expected, rel=1e-12, abs=1e-300), (k, p)


@pytest.mark.parametrize("k", DOFS)
def test_chi2_tails_match_scipy(k):
    for x in np.concatenate([k * np.array([1e-4, 0.01, 0.3, 0.8, 0.95, 1.0, 1.05, 1.2, 2.0, 5.0]),
                             [1e-3, 0.5, 7.8, 16.27, 97.0]]):
        expected = chdtrc(k, x)
        if expected < 1e-290:
            continue
        assert chi2_sf(x, k) == pytest.approx(expected, rel=1e-12), (k, x)
        lower = chdtr(k, x)
        if lower > 1e-290:
            assert chi2_cdf(x, k) == pytest.approx(lower, rel=1e-12), (k, x)


def test_the_gates_own_false_alarm_rate():
    """The gate of the rejected-fixes check: chi-square(3) at 16.27 rejects 0.1 % of good fixes."""
    assert chi2_sf(16.27, 3) == pytest.approx(chdtrc(3, 16.27), rel=1e-13)
    assert chi2_sf(16.27, 3) == pytest.approx(0.001, rel=2e-3)


def test_the_gates_are_the_quantiles_they_name():
    """The 3-D gate of 99.9 % (GNSS fixes' default, zero-velocity update), the estimation passes' 1 - 1e-8 and the
    non-holonomic update's chi-square(2) 1 - 1e-20 (its quantile is -2 ln p), each to the digits written."""
    from georef.config import GnssGateSection
    from georef.fusion.ins import ESTIMATION_GATE
    from georef.fusion.ins_layout import NHC_GATE, ZUPT_GATE

    assert CHI2_3DOF_99_9 == round(chi2_isf(1e-3, 3), 2) == GnssGateSection().chi2 == ZUPT_GATE
    assert ESTIMATION_GATE == round(chi2_isf(1e-8, 3), 1)
    assert NHC_GATE == round(-2.0 * np.log(1e-20), 1)


@pytest.mark.parametrize("d1", [2, 4, 6, 8])
@pytest.mark.parametrize("d2", [1, 2, 5, 17, 60, 285, 1000, 12345.5])
def test_f_tails_match_scipy(d1, d2):
    for p in [0.001, 0.05, 0.5, 0.9, 0.999, 0.999999]:
        f = fdtri(d1, d2, p)  # the F-test's critical value: P(F > f) = 1 - p
        assert f_sf(f, d1, d2) == pytest.approx(1.0 - fdtr(d1, d2, f), rel=1e-11, abs=1e-15), (d1, d2, p)
        assert f_sf(f, d1, d2) == pytest.approx(1.0 - p, rel=1e-9), (d1, d2, p)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError):
        chi2_isf(0.0, 3)
    with pytest.raises(ValueError):
        chi2_isf(0.5, 0)
    with pytest.raises(ValueError):
        chi2_cdf(1.0, 0)
    with pytest.raises(ValueError):
        f_sf(1.0, 3, 10)  # odd numerator degrees of freedom: no finite sum
