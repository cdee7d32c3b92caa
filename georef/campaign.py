"""Campaign calibration: one GNSS lever arm and time offset for many flights of one installation
(``georef batch --method graph --shared-calibration``).

The calibration variable ``c = (lever arm x, y, z [m, body], GNSS time offset [s])`` is one quantity for a
campaign flown with one installation. Each flight's factor graph (:mod:`georef.fusion.graph`) runs in its own
Dask task and comes back reduced to ``c``: the Gaussian marginal of its posterior (mean, covariance) and the prior
it was solved with. Dividing the prior out gives what the flight's *data* say about ``c`` in information form,
``L_i = P_post^-1 - P_prior^-1`` and ``e_i = P_post^-1 x_post - P_prior^-1 x_prior`` (exact for a linear
Gaussian problem, the Schur complement of the flight's graph on ``c``).

The campaign estimate is the information-weighted sum of every consistent flight's data and each *distinct*
configured prior once (flights sharing one ``flight.toml`` lever arm share one tape measurement, which must not be
counted once per flight): ``L = sum L_i + sum L_prior``, ``x = L^-1 (sum e_i + sum e_prior)``.

Each flight is then re-solved with the campaign's estimate from all the *other* flights (and the priors) as its
prior, so its own data enter once and its solution is consistent with the one campaign estimate; its data part is
re-derived at the new linearisation point and the estimate recombined, until it moves by less than
:data:`SETTLED` of its sigma. A flight whose data disagree with the other flights' estimate is flagged by a
chi-square test of ``r = e_i - L_i x_loo`` with covariance ``S = L_i + L_i P_loo L_i`` (degrees of freedom: the
rank of ``L_i``) at :data:`CONSISTENCY_P`; flagged flights (a moved antenna, a re-cabled receiver) are left out
of the campaign estimate one at a time, worst first, and keep their own estimate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from georef.distributions import chi2_sf

#: below this share of the prior's variance removed by the data (:meth:`CampaignEstimate.data_share`), a component is
#: reported as barely observed: its campaign value is mostly the configured prior
WEAK_DATA_SHARE = 0.5
#: a flight is consistent with the others unless its chi-square exceeds this tail probability (one false alarm in
#: a thousand flights)
CONSISTENCY_P = 1e-3
#: the campaign estimate has settled when no component moves by more than this fraction of its sigma
SETTLED = 0.1
#: at most this many rounds of per-flight solves (the first with the flights' own priors)
MAX_ROUNDS = 4
#: eigenvalues of an information matrix below this fraction of its largest are unobserved directions
RANK_TOLERANCE = 1e-9


@dataclass(frozen=True)
class FlightReduction:
    """One flight's graph reduced to the calibration variable: the posterior marginal (``mean`` (4,),
    ``covariance`` (4, 4)) and the prior it was solved with (``prior_mean``, ``prior_covariance``). Units: m, s."""

    mean: np.ndarray
    covariance: np.ndarray
    prior_mean: np.ndarray
    prior_covariance: np.ndarray

    @classmethod
    def from_dict(cls, value: dict) -> FlightReduction:
        """From the ``graph_calibration`` entry of a graph solution's info (lists or arrays)."""
        return cls(*(np.asarray(value[key], float) for key in ("mean", "covariance", "prior_mean",
                                                               "prior_covariance")))

    def data(self) -> tuple[np.ndarray, np.ndarray]:
        """What the flight's data alone say about the calibration: information matrix (4, 4) and vector (4,)."""
        info_post = _inverse(self.covariance)
        info_prior = _inverse(self.prior_covariance)
        information = _clip(info_post - info_prior)
        vector = info_post @ self.mean - info_prior @ self.prior_mean
        return information, vector

    def own_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The flight's data-only estimate of the calibration and its sigma (4,) each: NaN where the data do not
        observe a component (its information is below :data:`RANK_TOLERANCE` of the largest)."""
        return _own_estimate(*self.data())


@dataclass
class CampaignEstimate:
    """The campaign's calibration (``mean`` (4,), ``covariance`` (4, 4); m, s), each flight's own data estimate
    and sigma (NaN where its data do not observe a component), its chi-square against the others, and whether it
    was found consistent (and so used)."""

    mean: np.ndarray
    covariance: np.ndarray
    flights: dict[str, dict]
    rounds: int = 0
    configured_priors: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def data_share(self) -> np.ndarray:
        """Per component (lever arm x, y, z, time offset) the share of the campaign estimate's variance that the
        flights' data removed from the configured priors' (distinct priors combined): 1 - var / var_prior, in
        [0, 1]. Near 0 the data did not observe the component and the campaign value is the prior handed back
        (three 75-s simulated flights with 1-m fixes: 0.005-0.016)."""
        variance = np.diag(self.covariance)
        if not self.configured_priors:
            return np.ones(4)
        prior_variance = np.diag(_inverse(_distinct_priors(self.configured_priors)[0]))
        return np.clip(1.0 - variance / prior_variance, 0.0, 1.0)

    def to_json(self) -> dict:
        """``calibration.json``: the campaign estimate with sigma and, per flight, its own estimate and verdict."""
        sigma = np.sqrt(np.diag(self.covariance))
        return {"gnss_lever_arm_m": [float(v) for v in self.mean[:3]],
                "gnss_lever_arm_sigma_m": [float(v) for v in sigma[:3]],
                "gnss_time_offset_s": float(self.mean[3]), "gnss_time_offset_sigma_s": float(sigma[3]),
                "covariance": [[float(v) for v in row] for row in self.covariance],
                "data_share": [float(v) for v in self.data_share()],
                "rounds": self.rounds, "consistency_p": CONSISTENCY_P,
                "flights": {name: {key: (_plain(value)) for key, value in flight.items()}
                            for name, flight in self.flights.items()}}

    def config_toml(self) -> str:
        """A ``flight.toml`` fragment that feeds the campaign estimate back in (``--config``): the lever arm and
        time offset with their sigmas (the lever arm's per axis)."""
        sigma = np.sqrt(np.diag(self.covariance))
        numbers = ", ".join(f"{v:.4f}" for v in self.mean[:3])
        sigmas = ", ".join(f"{max(v, 1e-4):.4f}" for v in sigma[:3])
        share = self.data_share()
        names = ("lever arm x", "lever arm y", "lever arm z", "time offset")
        weak = [name for name, value in zip(names, share, strict=True) if value < WEAK_DATA_SHARE]
        note = (f"# the flights' data barely observed: {', '.join(weak)} "
                "(their values are mostly the configured prior)\n" if weak else "")
        return ("# campaign calibration (georef batch --shared-calibration)\n" + note +
                f"[mounting]\nlever_arm_gnss = [{numbers}]\nlever_arm_gnss_sigma = [{sigmas}]\n\n"
                f"[gnss]\ngnss_latency = {self.mean[3]:.5f}\ngnss_latency_sigma = {max(sigma[3], 1e-5):.5f}\n")


def combine(reductions: dict[str, FlightReduction], configured_priors: dict[str, tuple[np.ndarray, np.ndarray]],
            rounds: int = 0) -> CampaignEstimate:
    """The campaign estimate from the flights' reductions and their configured priors (mean, covariance; the
    priors of the first round's solves), flagging inconsistent flights (see the module)."""
    if not reductions:
        raise ValueError("no flight came back with a calibration to combine")
    data = {name: reduction.data() for name, reduction in reductions.items()}
    prior_info, prior_vec = _distinct_priors(configured_priors)
    used = set(data)
    while True:
        total_info = sum((data[name][0] for name in used), np.zeros((4, 4))) + prior_info
        total_vec = sum((data[name][1] for name in used), np.zeros(4)) + prior_vec
        tests = {name: _consistency(data[name], total_info, total_vec, name in used) for name in data}
        failing = [name for name in used if tests[name]["p_value"] < CONSISTENCY_P]
        if not failing or len(used) <= 2:  # two flights that disagree cannot say which of them moved
            break
        used.discard(max(failing, key=lambda name: tests[name]["chi2"]))
    covariance = _inverse(total_info)
    mean = covariance @ total_vec
    flights = {}
    for name, (information, vector) in data.items():
        own_mean, own_sigma = _own_estimate(information, vector)
        flights[name] = {"gnss_lever_arm_m": own_mean[:3], "gnss_lever_arm_sigma_m": own_sigma[:3],
                         "gnss_time_offset_s": own_mean[3], "gnss_time_offset_sigma_s": own_sigma[3],
                         "chi2": tests[name]["chi2"], "dof": tests[name]["dof"], "p_value": tests[name]["p_value"],
                         "consistent": name in used}
    return CampaignEstimate(mean=mean, covariance=covariance, flights=flights, rounds=rounds,
                            configured_priors=dict(configured_priors))


def leave_one_out(estimate: CampaignEstimate, reductions: dict[str, FlightReduction],
                  flight: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The prior for re-solving ``flight``: the campaign estimate without that flight's own data (mean (4,),
    covariance (4, 4)); ``None`` for a flight found inconsistent (it keeps its own configured prior)."""
    if not estimate.flights[flight]["consistent"]:
        return None
    information = _inverse(estimate.covariance)
    vector = information @ estimate.mean
    own_info, own_vec = reductions[flight].data()
    covariance = _inverse(information - own_info)
    return covariance @ (vector - own_vec), covariance


def settled(new: CampaignEstimate, old: CampaignEstimate) -> bool:
    """True when no component of the campaign estimate moved by more than :data:`SETTLED` of its sigma."""
    sigma = np.sqrt(np.diag(new.covariance))
    return bool(np.all(np.abs(new.mean - old.mean) <= SETTLED * sigma))


def _consistency(flight_data: tuple[np.ndarray, np.ndarray], total_info: np.ndarray, total_vec: np.ndarray,
                 included: bool) -> dict:
    """Chi-square of a flight's data against the estimate from everything else (see the module)."""
    information, vector = flight_data
    other_info = total_info - information if included else total_info
    other_vec = total_vec - vector if included else total_vec
    other_cov = _inverse(other_info)
    other_mean = other_cov @ other_vec
    residual = vector - information @ other_mean
    S = information + information @ other_cov @ information
    dof = int(np.linalg.matrix_rank(information, tol=RANK_TOLERANCE * max(np.max(np.abs(information)), 1e-300)))
    value = float(residual @ np.linalg.pinv(S, rcond=RANK_TOLERANCE, hermitian=True) @ residual)
    return {"chi2": value, "dof": dof, "p_value": chi2_sf(value, dof) if dof else 1.0}


def _own_estimate(information: np.ndarray, vector: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and sigma from information form (pseudo-inverse), NaN on the components the information leaves
    unobserved."""
    own_cov = np.linalg.pinv(information, rcond=RANK_TOLERANCE, hermitian=True)
    observed = np.diag(information) > RANK_TOLERANCE * max(np.max(np.diag(information)), 1e-300)
    own_sigma = np.where(observed, np.sqrt(np.clip(np.diag(own_cov), 0.0, None)), np.nan)
    return np.where(observed, own_cov @ vector, np.nan), own_sigma


def _distinct_priors(priors: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Information matrix and vector of the distinct configured priors, each counted once."""
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    for mean, covariance in priors.values():
        if not any(np.allclose(mean, m) and np.allclose(covariance, c) for m, c in seen):
            seen.append((np.asarray(mean, float), np.asarray(covariance, float)))
    information = sum((_inverse(c) for _, c in seen), np.zeros((4, 4)))
    vector = sum((_inverse(c) @ m for m, c in seen), np.zeros(4))
    return information, vector


def _inverse(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive-definite matrix, symmetrised."""
    inverse = np.linalg.inv(np.asarray(matrix, float))
    return 0.5 * (inverse + inverse.T)


def _clip(information: np.ndarray) -> np.ndarray:
    """A symmetric information matrix with the small negative eigenvalues that rounding leaves set to zero."""
    information = 0.5 * (information + information.T)
    values, vectors = np.linalg.eigh(information)
    return (vectors * np.clip(values, 0.0, None)) @ vectors.T


def _plain(value):
    """JSON-ready: arrays to lists, NaN to None."""
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return None if not np.isfinite(value) else float(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
