"""Tail probabilities and quantiles of the chi-square and F distributions, for the quality checks and the
alignment's F-test.

These replace three functions of ``scipy.special`` (``chdtrc``, ``chdtri``, ``fdtri``) on the path of every
``georef process``, for values computed once each. The reason for own code in place of the library: importing
``scipy.special`` costs a run about as much as ``scipy.linalg``, most of it SciPy's array-API layer (which the two
share) and the wrappers it builds around every special function; ``georef.kernel_blas`` keeps ``scipy.linalg``
off the path, and with ``scipy.special`` on it that saving would be mostly lost (the figures:
``docs/performance.md``, "Imports"). ``tests/test_distributions.py`` checks these functions against
``scipy.special`` (still a dependency) to 1e-12 relative over the degrees of freedom and probabilities used and
beyond.

* :func:`chi2_sf` — ``P(X > x)`` for ``X ~ chi-square(k)``: the regularized upper incomplete gamma function
  ``Q(k/2, x/2)`` (:func:`chi2_cdf` its complement ``P(k/2, x/2)``: the report's share of good fixes a gate
  passes), by its power series below ``a + 1`` and its continued fraction above (modified Lentz), as in Press,
  Teukolsky, Vetterling & Flannery (2007), *Numerical Recipes*, 3rd ed., §6.2;
* :func:`chi2_isf` — the ``x`` with ``P(X > x) = p`` (``scipy.special.chdtri(k, p)``), by Newton's method from
  the Wilson–Hilferty approximation (Wilson & Hilferty 1931, PNAS 17:684), on whichever tail is the smaller;
* :func:`f_sf` — ``P(F > f)`` for ``F ~ F(d1, d2)`` with ``d1`` even: ``I_y(d2/2, d1/2)`` with
  ``y = d2 / (d2 + d1 f)``, which for a whole second parameter ``m = d1/2`` is the finite sum
  ``y^b Σ_{j<m} (b)_j / j! (1 - y)^j``, ``b = d2/2`` (Abramowitz & Stegun 1964, 26.5.6 and 6.6.2).
"""

from __future__ import annotations

import math

#: the chi-square(3) quantile at 99.9 % (``chi2_isf(1e-3, 3)`` = 16.266, to two decimals): a gate on a 3-D
#: innovation's ``zᵀS⁻¹z`` that refuses one good measurement in a thousand. The GNSS fixes' default gate
#: (flight.toml ``gate_chi2``, :class:`georef.config.GnssGateSection`) and the zero-velocity update's
#: (:data:`georef.fusion.ins_layout.ZUPT_GATE`)
CHI2_3DOF_99_9 = 16.27

_EPS = 1e-16
_TINY = 1e-300
_MAX_TERMS = 100_000


def _log_prefactor(a: float, x: float) -> float:
    """log(x^a e^-x / Γ(a)). Above a = 10 as ``½ log(a / 2π) - c(a) - a (t - log1p(t))`` with ``t = x/a - 1`` and
    Stirling's correction ``c(a) = lgamma(a) - ((a - ½) log a - a + ½ log 2π)``: the direct sum cancels terms of
    size ``a log x`` and loses their digits (1e-10 relative at a = 15000)."""
    if a < 10.0:
        return a * math.log(x) - x - math.lgamma(a)
    t = (x - a) / a
    r = 1.0 / (a * a)
    stirling = (1.0 / 12.0 - r * (1.0 / 360.0 - r * (1.0 / 1260.0 - r * (1.0 / 1680.0 - r / 1188.0)))) / a
    return 0.5 * math.log(a / (2.0 * math.pi)) - stirling + a * (math.log1p(t) - t)


def _gamma_p_series(a: float, x: float) -> float:
    """Regularized lower incomplete gamma P(a, x) by its series (x < a + 1)."""
    term = total = 1.0 / a
    ap = a
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(_log_prefactor(a, x))


def _gamma_q_fraction(a: float, x: float) -> float:
    """Regularized upper incomplete gamma Q(a, x) by its continued fraction (x >= a + 1), modified Lentz."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        if abs(d) < _TINY:
            d = _TINY
        c = b + an / c
        if abs(c) < _TINY:
            c = _TINY
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return math.exp(_log_prefactor(a, x)) * h


def _gamma_tails(a: float, x: float) -> tuple[float, float]:
    """(P(a, x), Q(a, x)); the smaller one is computed, the other is one minus it."""
    if x <= 0.0:
        return 0.0, 1.0
    if x < a + 1.0:
        p = _gamma_p_series(a, x)
        return p, 1.0 - p
    q = _gamma_q_fraction(a, x)
    return 1.0 - q, q


def chi2_sf(x: float, k: float) -> float:
    """P(X > x) for X ~ chi-square with ``k`` degrees of freedom (``scipy.special.chdtrc(k, x)``)."""
    if k <= 0:
        raise ValueError(f"degrees of freedom must be positive, got {k}")
    return _gamma_tails(0.5 * k, 0.5 * x)[1]


def chi2_cdf(x: float, k: float) -> float:
    """P(X <= x) for X ~ chi-square with ``k`` degrees of freedom (``scipy.special.chdtr(k, x)``)."""
    if k <= 0:
        raise ValueError(f"degrees of freedom must be positive, got {k}")
    return _gamma_tails(0.5 * k, 0.5 * x)[0]


def chi2_isf(p: float, k: float) -> float:
    """The x with P(X > x) = ``p`` for X ~ chi-square(k) (``scipy.special.chdtri(k, p)``), 0 < p < 1.

    Newton's method on the logarithm of the smaller tail against ``u = log(x/2)`` (nearly linear there, down to
    the smallest quantiles), kept inside a bracket; started from the Wilson-Hilferty approximation, or in the far
    lower tail of few degrees of freedom from ``P(a, y) ≈ y^a / Γ(a + 1)``."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"the probability must lie strictly between 0 and 1, got {p}")
    if k <= 0:
        raise ValueError(f"degrees of freedom must be positive, got {k}")
    from statistics import NormalDist  # its import costs 50 ms, and georef.config imports this module at start-up

    a = 0.5 * k
    upper = p < 0.5  # the tail solved for: Q(a, y) = p, or P(a, y) = 1 - p
    log_target = math.log(p) if upper else math.log1p(-p)
    # Wilson-Hilferty: (X/k)^(1/3) is nearly normal with mean 1 - 2/(9k) and variance 2/(9k)
    cube = 1.0 - 2.0 / (9.0 * k) + NormalDist().inv_cdf(1.0 - p) * math.sqrt(2.0 / (9.0 * k))
    series = (log_target + math.lgamma(a + 1.0)) / a  # log y where y^a / Γ(a + 1) equals the lower tail
    u = math.log(0.5 * k * cube**3) if cube > 0.0 else series
    if not upper:
        u = min(u, series) if series < math.log(a) - 1.0 else u
    lo, hi = -math.inf, math.inf
    for _ in range(400):
        y = math.exp(u)
        lower, upper_tail = _gamma_tails(a, y)
        tail = upper_tail if upper else lower
        if tail <= 0.0:
            g, slope = (-math.inf, 0.0)
        else:
            g = math.log(tail) - log_target
            slope = math.exp(_log_prefactor(a, y)) / tail * (-1.0 if upper else 1.0)  # d log(tail) / du
        # the upper tail falls with u, the lower tail rises: keep the root bracketed
        if (g > 0.0) == upper:
            lo = u
        else:
            hi = u
        new = u - g / slope if slope != 0.0 and math.isfinite(g) else math.nan
        if not lo < new < hi:
            if math.isfinite(lo) and math.isfinite(hi):
                new = 0.5 * (lo + hi)
            else:
                new = u + (2.0 if math.isinf(hi) else -2.0)
        if abs(new - u) <= 1e-15 * max(1.0, abs(new)):
            u = new
            break
        u = new
    return 2.0 * math.exp(u)


def f_sf(f: float, d1: int, d2: float) -> float:
    """P(F > f) for F ~ F(d1, d2) with ``d1`` a positive even integer."""
    if d1 <= 0 or d1 % 2:
        raise ValueError(f"the numerator's degrees of freedom must be a positive even integer, got {d1}")
    if d2 <= 0:
        raise ValueError(f"the denominator's degrees of freedom must be positive, got {d2}")
    if f <= 0.0:
        return 1.0
    y = d2 / (d2 + d1 * f)
    b = 0.5 * d2
    one_minus_y = d1 * f / (d2 + d1 * f)
    term = total = 1.0
    for j in range(1, d1 // 2):
        term *= (b + j - 1) / j * one_minus_y
        total += term
    return math.exp(b * math.log(y)) * total
