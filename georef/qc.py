"""Quality checks of a finished run, with a verdict (``docs/qc.md``).

One job: judge a navigation solution (and the EO table made from it) after the fact, and say in words a user
can act on what looks wrong. Nothing here changes the solution.

>>> verdict = assess(result.nav, result.table, result.config)
>>> verdict.passed, [check.message for check in verdict.failures]

Every :class:`Check` has a status ``"pass"``, ``"warn"`` or ``"fail"``; the :class:`Verdict` has passed when no
check failed. ``georef process`` and ``georef fuse`` exit with code 4 when it did not (the outputs are written
all the same). Times in messages are the log's own time scale [s] (UTC second of day for POS.txt), with the
time since the start of the navigation where that helps to find the place.

Checks (thresholds are module constants, their reasons in ``docs/qc.md``):

* ``innovations``: the mean normalised innovation squared (NIS) of the GNSS fixes the filter used, against the
  chi-square distribution of the effective number of independent fixes (consecutive fixes are correlated); too
  high fails, too low (pessimistic) warns (full-state filters only);
* ``held-out fixes``: windows of fixes left out and predicted: worse than straight lines between the kept fixes,
  a filter that cannot bridge them, or sigmas too small there fail (full-state filters);
* ``innovation bursts``: the worst 60-s window of the NIS;
* ``rejected fixes``: the share of processed GNSS fixes the gate rejected;
* ``lever arm`` and ``latency``: what the data say about the GNSS lever arm and time tags, against the
  configuration (full-state filters, when the calibration pass ran);
* ``heading``: where the heading came from;
* ``restarts``, ``IMU gaps``: re-alignments after divergences, spans without IMU data;
* ``frames``: exposures outside the navigation span (a camera clock off by hours);
* ``GNSS at the ends``: exposures after the last GNSS fix or before the first (inertial only);
* ``graph vs rts``: the factor graph's solution against the smoother's (``--method graph``).

The advice names what the user holds (``kind``: POS.txt, an autopilot log, imu.csv).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from georef.config import GnssGateSection
from georef.distributions import chi2_isf, chi2_sf  # scipy.special's import would cost every run (its module says)
from georef.eo import FLAG_AFTER_LAST_FIX, FLAG_BEFORE_FIRST_FIX, FLAG_NO_SIGMA, FLAG_OUTSIDE, flag_mask

if TYPE_CHECKING:
    from collections.abc import Mapping

    from georef.config import ProcessingConfig
    from georef.fusion.solution import NavSolution

PASS, WARN, FAIL = "pass", "warn", "fail"
STATUSES = (PASS, WARN, FAIL)

#: the mean NIS must lie inside the two-sided band of this probability of chi-square(3 n) / n ...
NIS_BAND_PROBABILITY = 0.999
#: ... widened by this fraction on either side (the filter's linearisation, the fitted noise model, the gate's
#: truncation of the distribution: the model is an approximation)
NIS_BAND_WIDENING = 0.25
#: the worst window of this length [s] warns when its mean NIS exceeds NIS_WINDOW_LIMIT (with at least
#: NIS_WINDOW_MIN_FIXES fixes in it)
NIS_WINDOW_S = 60.0
NIS_WINDOW_LIMIT = 10.0
NIS_WINDOW_MIN_FIXES = 5
#: fewer used fixes than this: too few to judge the innovations' level
NIS_MIN_FIXES = 10
#: share of the processed GNSS fixes rejected by the gate that fails / warns
REJECTED_FAIL = 0.05
REJECTED_WARN = 0.01
#: rejected fix times listed at most
LIST_AT_MOST = 10
#: lever arm: a difference fails when it exceeds LEVER_SIGMAS * sqrt(sigma_est^2 + LEVER_FLOOR_M^2) and also the
#: estimates' resolution LEVER_RESOLUTION_M + LEVER_RESOLUTION_REL * |given| (on simulated cars the estimate
#: differs from the truth by up to about 1 m: it trades off against attitude and latency)
LEVER_SIGMAS = 3.0
#: a yaw sigma under this share of the only heading source's (magnetometer, autopilot) is spurious: with the
#: motion never showing the heading, nothing can know it better than that source (a two-minute hover's filter
#: claimed 11 deg from an autopilot's 15 deg and was 37 deg off)
SPURIOUS_HEADING_SHARE = 0.9
LEVER_FLOOR_M = 0.05
LEVER_RESOLUTION_M = 0.3
LEVER_RESOLUTION_REL = 0.2
#: latency: warns when the estimate exceeds LATENCY_SIGMAS sigma and LATENCY_MIN_S [s]
LATENCY_SIGMAS = 3.0
LATENCY_MIN_S = 0.02
#: frames: more than this share outside the navigation span fails
OUTSIDE_FAIL_SHARE = 0.5
#: held-out fixes: the solution fails when its error exceeds both the straight lines' and this many fix sigmas ...
HELD_FAIL_SIGMAS = 3.0
#: ... or its errors exceed their sigmas by more than this (RMS); over HELD_Z_NOTE they are noted as too small
#: inside gaps (a known limit of the outage sigmas, docs/method-ins.md section 9, so a note, not a failure), under
#: HELD_Z_WARN as pessimistic
HELD_Z_FAIL = 3.0
HELD_Z_NOTE = 2.0
HELD_Z_WARN = 0.5
#: the length of a held-out window [s], for messages (georef.fusion.ins.HELD_S)
HELD_WINDOW_S = 15.0
#: the attitude's sigma scale on the flight (rms of the forward-minus-smoothed separation over its sigma) above
#: which the attitude sigmas may be too small (a warning), or below which they are pessimistic (a note). It does
#: not fail a flight: a multicopter's hover start gave 5.0 in roll from the forward filter's start transient where
#: the smoothed roll, the one delivered, was 1.7 times its sigma (docs/qc.md)
ATTITUDE_SCALE_NOTE = 2.0
ATTITUDE_SCALE_LOW = 0.3
#: beyond this the forward filter and the smoother disagree by far more than any start transient measured (the
#: hover start's 5.0 above): an attitude that does not hold together at all (an IMU mounted or published upside
#: down read 587), so the check fails
ATTITUDE_SCALE_FAIL = 20.0

AXES = ("x", "y", "z")
AXIS_WORDS = {"x": "forward", "y": "right", "z": "down"}


@dataclass(frozen=True)
class Check:
    """One check: its ``name``, ``status`` (``"pass"``, ``"warn"`` or ``"fail"``) and a message saying what was
    found (figures with units) and, when it is not a pass, what to do."""

    name: str
    status: str
    message: str

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"check status must be one of {', '.join(STATUSES)}, got {self.status!r}")

    def line(self) -> str:
        """``"fail lever arm: ..."``: one line of text."""
        return f"{self.status} {self.name}: {self.message}"

    def to_dict(self) -> dict[str, str]:
        """Plain data (for a Dask worker's result, JSON, a CSV cell)."""
        return {"name": self.name, "status": self.status, "message": self.message}


@dataclass(frozen=True)
class Verdict:
    """The checks of one run; it has ``passed`` when none failed."""

    checks: tuple[Check, ...]

    @property
    def passed(self) -> bool:
        return not self.failures

    @property
    def failures(self) -> list[Check]:
        return [c for c in self.checks if c.status == FAIL]

    @property
    def warnings(self) -> list[Check]:
        return [c for c in self.checks if c.status == WARN]

    def short(self) -> str:
        """``"passed"``, ``"passed (warnings: restarts)"`` or ``"failed: lever arm, frames"``."""
        if not self.passed:
            return "failed: " + ", ".join(c.name for c in self.failures)
        if self.warnings:
            return "passed (warnings: " + ", ".join(c.name for c in self.warnings) + ")"
        return "passed"

    def details(self) -> str:
        """The failing and warning checks, one line each (empty when every check passed)."""
        return "\n".join(c.line() for c in self.checks if c.status != PASS)

    def __str__(self) -> str:
        return f"QC {self.short()}" + (f"\n{self.details()}" if self.details() else "")

    def to_dicts(self) -> list[dict[str, str]]:
        return [c.to_dict() for c in self.checks]

    @classmethod
    def from_dicts(cls, rows: Iterable[dict[str, Any]]) -> Verdict:
        return cls(tuple(Check(str(r["name"]), str(r["status"]), str(r["message"])) for r in rows))


# ---- helpers ---------------------------------------------------------------------------------------------------
def _times(values: Iterable[float], at_most: int = LIST_AT_MOST) -> str:
    """``"12.0 s, 14.5 s and 3 more"`` [s]."""
    values = list(values)
    text = ", ".join(f"{v:.1f} s" for v in values[:at_most])
    return text + (f" and {len(values) - at_most} more" if len(values) > at_most else "")


def _nav_start(nav: NavSolution) -> float:
    """Time [s] of the first row with a solution (the first row when none has)."""
    valid = np.flatnonzero(nav.valid)
    return float(nav.time[valid[0]] if len(valid) else nav.time[0])


def _gate(nav: NavSolution, cfg: ProcessingConfig | None) -> float:
    """The chi-square gate of the run (3 degrees of freedom)."""
    if nav.diagnostics is not None:
        return float(nav.diagnostics.gate_chi2)
    return float((cfg.gnss_gate if cfg is not None else GnssGateSection()).chi2)


# ---- the checks --------------------------------------------------------------------------------------------------
def nis_band(n: int) -> tuple[float, float]:
    """The accepted range of the mean NIS of ``n`` fixes: the central ``NIS_BAND_PROBABILITY`` band of
    chi-square(3 n) / n, widened by ``NIS_BAND_WIDENING`` on either side (lower edge times 0.75, upper times 1.25)."""
    tail = 0.5 * (1.0 - NIS_BAND_PROBABILITY)
    lo = chi2_isf(1.0 - tail, 3 * n) / n
    hi = chi2_isf(tail, 3 * n) / n
    return lo * (1.0 - NIS_BAND_WIDENING), hi * (1.0 + NIS_BAND_WIDENING)


def effective_count(time: np.ndarray, innovation: np.ndarray, variance: np.ndarray) -> int:
    """How many independent fixes ``n`` correlated innovations are worth: ``n (1 - r) / (1 + r)`` with ``r`` the
    lag-one autocorrelation of the normalised innovations of consecutive fixes (pooled over the three axes, floored
    at 0: an AR(1) sequence's mean has the variance of that many independent values)."""
    n = len(time)
    if n < 3:
        return n
    order = np.argsort(time)
    z = innovation[order] / np.sqrt(np.maximum(variance[order], 1e-300))
    z = z - np.nanmean(z, axis=0)
    numerator = float(np.nansum(z[1:] * z[:-1]))
    denominator = float(np.nansum(z * z))
    r = max(numerator / denominator, 0.0) if denominator > 0 else 0.0
    return max(int(round(n * (1.0 - r) / (1.0 + r))), min(n, NIS_MIN_FIXES))


def check_innovations(nav: NavSolution, kind: str = "POS.txt") -> list[Check]:
    """``innovations`` (mean NIS of the used fixes against chi-square(3 n)) and ``innovation bursts`` (the worst
    ``NIS_WINDOW_S`` window). Full-state filters only (their NIS uses the full innovation covariance). ``kind``:
    what the inputs were, for the advice."""
    if nav.diagnostics is None:
        return []
    nis = np.asarray(nav.diagnostics.nis, float)
    used = (nav.gnss.status == 1) & np.isfinite(nis)
    n = int(used.sum())
    if n == 0:
        return [Check("innovations", FAIL, "the filter used no GNSS fix: the solution is inertial only. Check "
                      "that the GNSS fixes lie inside the IMU's time span and their positions are sane "
                      "(georef info POS.txt).")]
    if n < NIS_MIN_FIXES:
        return [Check("innovations", WARN, f"only {n} GNSS fixes used: too few to judge the noise model")]
    value = float(np.mean(nis[used]))
    effective = effective_count(nav.gnss.time[used], nav.gnss.innovation[used], nav.gnss.innovation_var[used])
    lo, hi = nis_band(effective)
    figures = f"mean normalised innovation squared {value:.2f} over {n} used GNSS fixes (3 expected, accepted " \
              f"{lo:.2f} to {hi:.2f}" + (f" for the {effective} independent ones their correlation leaves)"
                                         if effective < n else ")")
    if value > hi:
        checks = [Check("innovations", FAIL, f"{figures}: the fixes disagree with the navigation more than the "
                        f"fitted model explains. {_time_scale_advice(kind)}Look for a wrong lever arm "
                        "(--gnss-lever-arm), GNSS time tags off (--gnss-latency), fixes of mixed quality "
                        "(float/DGPS), or a vehicle the model does not fit (--vehicle); the innovations plot of "
                        "--report shows where.")]
    elif value < lo:
        # a filter whose fixes agree better than their sigmas say is pessimistic, not wrong: noted; whether its
        # answer is good is for the held-out fixes to say
        checks = [Check("innovations", WARN, f"{figures}: the fixes agree with the navigation better than the "
                        "model says (consecutive fixes of one receiver wander together, and each new one is "
                        "predicted by the ones before): the sigmas may be pessimistic. The held-out check says "
                        "whether they are.")]
    else:
        checks = [Check("innovations", PASS, figures)]
    # the worst window
    t = nav.gnss.time[used]
    x = nis[used]
    order = np.argsort(t)
    t, x = t[order], x[order]
    cum = np.concatenate([[0.0], np.cumsum(x)])
    end = np.searchsorted(t, t + NIS_WINDOW_S, side="left")
    count = end - np.arange(len(t))
    # whole windows only (a window cut short by the end of the data is a few fixes, not a minute); a log shorter
    # than one window is one window
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    whole = t + NIS_WINDOW_S <= t[-1] + period
    if not whole.any():
        whole[0] = True
    ok = (count >= NIS_WINDOW_MIN_FIXES) & whole
    if ok.any():
        means = np.where(ok, (cum[end] - cum[:len(t)]) / np.maximum(count, 1), -np.inf)
        i = int(np.argmax(means))
        worst, j = float(means[i]), int(end[i]) - 1
        start = _nav_start(nav)
        span = (f"worst {NIS_WINDOW_S:.0f} s: mean normalised innovation squared {worst:.1f} over {count[i]} fixes "
                f"from {t[i]:.1f} to {t[j]:.1f} s ({t[i] - start:.0f} to {t[j] - start:.0f} s after the start)")
        if worst > NIS_WINDOW_LIMIT:
            checks.append(Check("innovation bursts", WARN, f"{span}, over {NIS_WINDOW_LIMIT:g}: the fixes or the "
                                "motion there do not fit the model (multipath, a float solution, a jump after an "
                                "outage, a hard manoeuvre); check the frames of that span."))
        else:
            checks.append(Check("innovation bursts", PASS, span))
    return checks


def check_held_out(nav: NavSolution, kind: str = "POS.txt") -> Check | None:
    """``held-out fixes``: does the solution predict GNSS fixes it was not given (windows of the flight left out
    and predicted, :func:`georef.fusion.ins.held_out_check`) better than straight lines between the fixes, and are
    its sigmas honest there? Fails when its error exceeds both the straight lines' and HELD_FAIL_SIGMAS times the
    fixes' sigma (a solution worse than the GNSS it was given), or when its errors exceed their sigmas by more than
    HELD_Z_FAIL (sigmas too small); sigmas too large only warn. ``kind``: what the inputs were, for the advice."""
    diagnostics = nav.diagnostics
    held = getattr(diagnostics, "held_out", None) if diagnostics is not None else None
    if diagnostics is None:
        return None
    if held is None:
        return Check("held-out fixes", WARN, "too few GNSS fixes to leave some out and predict them: the solution's "
                     "accuracy between fixes is not checked")
    if held.diverged:
        # a solution that cannot bridge a gap of the fixes is no better there than the fixes themselves
        return Check("held-out fixes", FAIL, f"with {held.held} fixes left out in windows of {HELD_WINDOW_S:.0f} s, "
                     "the filter diverged bridging them: between fixes the solution is no better than the GNSS it "
                     "was given, and frames in gaps of the GNSS of that length are lost. "
                     f"{_solution_advice(kind, nav.method)}")
    figures = (f"{held.held} fixes in {len(held.windows)} windows of {HELD_WINDOW_S:.0f} s left out and predicted: "
               f"horizontal error {held.error_rms_h:.2f} m RMS, straight lines between the kept fixes "
               f"{held.interpolation_rms_h:.2f} m, fixes' sigma {held.fix_sigma_h:.2f} m; errors "
               f"{held.z_rms:.2f} times their sigma (RMS)")
    if held.error_rms_h > max(held.interpolation_rms_h, HELD_FAIL_SIGMAS * held.fix_sigma_h):
        return Check("held-out fixes", FAIL, f"{figures}: the solution bridges gaps worse than straight lines "
                     "between the fixes, so it is worse than the GNSS it was given. "
                     f"{_solution_advice(kind, nav.method)}")
    if held.z_rms > HELD_Z_FAIL:
        return Check("held-out fixes", FAIL, f"{figures}: the sigmas are too small, so the EO table's sigmas "
                     f"claim an accuracy the solution does not have. {_solution_advice(kind, nav.method)}")
    if held.z_rms > HELD_Z_NOTE:
        return Check("held-out fixes", WARN, f"{figures}: across gaps of the GNSS the sigmas are too small; frames "
                     "inside GNSS outages carry sigmas about that many times too small")
    if held.z_rms < HELD_Z_WARN:
        return Check("held-out fixes", WARN, f"{figures}: the sigmas are larger than the errors (pessimistic, "
                     "safe to use)")
    return Check("held-out fixes", PASS, figures)


def check_attitude_scale(nav: NavSolution, kind: str = "POS.txt") -> Check | None:
    """``attitude sigmas``: the forward filter's attitude against the smoothed one, over the sigma their
    difference should have (:meth:`~georef.fusion.solution.ForwardSeparation.sigma_scale`). Warns when the RMS
    ratio of roll, pitch or yaw exceeds ATTITUDE_SCALE_NOTE, and notes sigmas too large; fails only beyond
    ATTITUDE_SCALE_FAIL (a start transient must not fail a usable flight, see ATTITUDE_SCALE_NOTE). What it
    cannot see: an error the forward filter and the smoother share (a bias the motion never separates), which the
    held-out fixes and the innovations do not see either."""
    if nav.forward is None or nav.diagnostics is None:
        return None
    _, scale = nav.forward.sigma_scale()
    if not np.any(np.isfinite(scale)):
        return None
    names = ("roll", "pitch", "yaw")
    figures = ("forward filter against the smoother, separation over its sigma (RMS): "
               + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, scale, strict=True) if np.isfinite(v)))
    worst = float(np.nanmax(scale))
    if worst > ATTITUDE_SCALE_FAIL:
        return Check("attitude sigmas", FAIL, f"{figures}: the forward filter and the smoother disagree by "
                     f"{worst:.0f} times the sigma expected, far beyond a start transient: the attitude is not "
                     "consistent with the IMU. Check the IMU's axes (forward-right-down in imu.csv; a bag's IMU "
                     "must publish REP 103 forward-left-up) and its units (rad/s, m/s^2).")
    if worst > ATTITUDE_SCALE_NOTE:
        return Check("attitude sigmas", WARN, f"{figures}: the forward filter strays from the smoothed attitude by "
                     f"up to {worst:.1f} times the sigma expected; the angle sigmas may be too small there. "
                     f"{_solution_advice(kind, nav.method, failing=False)}")
    if worst < ATTITUDE_SCALE_LOW:
        return Check("attitude sigmas", WARN, f"{figures}: the attitude sigmas are larger than the data show "
                     "(pessimistic, safe to use)")
    return Check("attitude sigmas", PASS, figures)


def _holds_solution_file(kind: str) -> bool:
    """Whether the inputs (``kind``) hold an RTKLIB/Emlid .pos, whose times were put on the IMU's scale."""
    return ".pos" in kind


def _time_scale_advice(kind: str) -> str:
    """For inputs holding a .pos: the time scale first. GPST and UTC differ by the leap seconds (18 s since 2017),
    and an IMU on the other one puts every fix that far along the track: most fixes rejected, no heading."""
    if not _holds_solution_file(kind):
        return ""
    return ("First check the time scale of the .pos against the IMU's clock: GPST and UTC differ by 18 s (the leap "
            "seconds), and a .pos read on the wrong one puts every fix 18 s along the track, so that the fixes are "
            "rejected or the heading is never found. The 'time scale' line says which scale was used; give the "
            "IMU's with --time-scale (utc-day: UTC seconds of the day, gps-week: GPS seconds of the week, unix; "
            "docs/rtklib.md). ")


def _solution_advice(kind: str, method: str = "rts", failing: bool = True) -> str:
    """What to look at when the solution is worse than the fixes, for the inputs the user holds and the method;
    the time scale of a .pos first when a check fails (``failing``), not in a warning of a run that may be right."""
    first = _time_scale_advice(kind) if failing else ""
    common = (f"{first}Look for a wrong GNSS lever arm (--gnss-lever-arm), GNSS time tags off "
              "(--gnss-latency), an IMU preset that does not fit the hardware (--imu-preset), and the frames flagged "
              "in the EO table; the report (--report) shows where the solution and the fixes part.")
    if method == "ekf":
        # the forward filter bridges a gap on the IMU alone; the smoother also uses the fixes after it
        common = ("The forward filter (--method ekf) bridges a gap of the fixes on the IMU alone: use --method rts, "
                  f"which also uses the fixes after the gap. {common}")
    if kind.startswith(("ArduPilot", "PX4")):
        return (f"{common} In an autopilot log, also check that the IMU was logged at its full rate (ArduPilot "
                "LOG_BITMASK IMU, PX4 SDLOG_PROFILE high rate): the IMU samples of a log at 10-50 Hz miss the "
                "motion between them.")
    return common


def check_rejected(nav: NavSolution, cfg: ProcessingConfig | None = None, kind: str = "POS.txt") -> Check | None:
    """``rejected fixes``: the share of processed fixes (status 0 or 1) the gate rejected. ``kind``: what the
    inputs were; with a .pos among them the advice names its time scale first."""
    status = nav.gnss.status
    processed = int((status >= 0).sum())
    if processed == 0:
        return None
    rejected = np.flatnonzero(status == 0)
    share = len(rejected) / processed
    gate = _gate(nav, cfg)
    alarm = chi2_sf(gate, 3)
    figures = (f"{len(rejected)} of {processed} processed GNSS fixes rejected ({100 * share:.1f} %; the gate "
               f"chi-square {gate:g} rejects {100 * alarm:.2f} % of good fixes)")
    if len(rejected):
        listed = [f"{nav.gnss.time[i]:.1f} s (line {int(nav.gnss.line[i])})" for i in rejected[:LIST_AT_MOST]]
        figures += ": " + ", ".join(listed) + (f" and {len(rejected) - LIST_AT_MOST} more"
                                               if len(rejected) > LIST_AT_MOST else "")
    advice = (". Check the GNSS quality at these times (multipath, float or autonomous fixes), --gnss-sigma, the "
              "lever arm (--gnss-lever-arm) and the time tags (--gnss-latency).")
    if share > REJECTED_WARN and _holds_solution_file(kind):
        advice = f". {_time_scale_advice(kind)}Then c{advice[3:]}"
    if share > REJECTED_FAIL:
        return Check("rejected fixes", FAIL, figures + advice)
    if share > REJECTED_WARN:
        return Check("rejected fixes", WARN, figures + advice)
    return Check("rejected fixes", PASS, figures)


def _lever_arm_differences(estimate: np.ndarray, sigma: np.ndarray, given: np.ndarray, given_sigma: np.ndarray,
                           axes: np.ndarray) -> list[int]:
    """Body axes (0, 1, 2) among ``axes`` where an estimated lever arm (``estimate`` +- ``sigma``, m) is off the
    given one (``given`` +- ``given_sigma``): by more than :data:`LEVER_SIGMAS` of both sigmas and the floor, and
    by more than the estimates' resolution."""
    off = []
    for k in np.flatnonzero(axes):
        difference = abs(estimate[k] - given[k])
        noise = LEVER_SIGMAS * float(np.sqrt(sigma[k] ** 2 + given_sigma[k] ** 2 + LEVER_FLOOR_M**2))
        resolution = LEVER_RESOLUTION_M + LEVER_RESOLUTION_REL * abs(given[k])
        if np.isfinite(difference) and difference > noise and difference > resolution:
            off.append(int(k))
    return off


def _lever_arm_text(estimate: np.ndarray, sigma: np.ndarray) -> str:
    return ", ".join(f"{e:.2f} +- {s:.2f}" for e, s in zip(estimate, sigma, strict=True))


LEVER_ADVICE = ("Check for a typo, the sign (body axes x forward, y right, z down; z negative when the antenna is "
                "above the IMU) and the axis order in --gnss-lever-arm / [mounting] lever_arm_gnss.")


def check_lever_arm(nav: NavSolution) -> Check | None:
    """``lever arm``: the calibration pass's lever arm against the configured one, per body axis
    (``--method graph``: :func:`check_graph_lever_arm`)."""
    graph = nav.graph_info
    if graph is not None and all(np.isfinite(np.asarray(value, float)).all()
                                 for value in vars(graph.calibration).values()):
        return check_graph_lever_arm(nav)
    # not a graph, or a graph whose calibration marginal could not be computed (an ill-conditioned graph: NaN)
    diagnostics = nav.diagnostics
    if diagnostics is None or diagnostics.calibration is None:
        return None
    calibration = diagnostics.calibration
    estimate = np.asarray(calibration.lever_arm, float)
    sigma = np.asarray(calibration.lever_arm_sigma, float)
    given = np.asarray(diagnostics.lever_arm_given, float)
    problems = [f"GNSS lever arm {AXES[k]} ({AXIS_WORDS[AXES[k]]}): the data put the antenna at {estimate[k]:.2f} "
                f"+- {sigma[k]:.2f} m, the configuration says {given[k]:.2f} m"
                for k in _lever_arm_differences(estimate, sigma, given, np.zeros(3), np.ones(3, bool))]
    both = _lever_arm_text(estimate, sigma)
    if problems:
        return Check("lever arm", FAIL, "; ".join(problems) + f" (estimate x, y, z: {both} m). " + LEVER_ADVICE)
    given_text = ", ".join(f"{g:.2f}" for g in given)
    return Check("lever arm", PASS, f"the GNSS lever arm the data show ({both} m) agrees with the configured "
                 f"{given_text} m")


#: the EKF's calibration pass contests the graph's lever-arm evidence on an axis only when its sigma there is at
#: most this many times the graph's (it resolves the axis about as well)
CONTEST_SIGMA_RATIO = 2.0


def check_graph_lever_arm(nav: NavSolution) -> Check | None:
    """``lever arm`` (``--method graph``): what the flight's data alone say about the GNSS lever arm (the graph's
    marginal on its calibration variable with the prior divided out, :class:`georef.campaign.FlightReduction`)
    against the lever arm it was given, per body axis; and the graph's estimate against the EKF's calibration pass.

    Axes given with a prior tighter than the free one (a configured lever arm, or a campaign's estimate) fail when
    the data put the antenna elsewhere (same thresholds as :func:`check_lever_arm`). A lever arm not given is
    estimated and applied by the graph: nothing to check it against but the EKF's calibration pass, which sees
    the same data; when the two disagree the check warns."""
    from georef.campaign import FlightReduction
    from georef.fusion.graph import LEVER_ARM_FREE_SIGMA

    reduction = FlightReduction.from_dict(vars(nav.graph_info.calibration))
    own, own_sigma = reduction.own_estimate()
    prior, prior_sigma = reduction.prior_mean[:3], np.sqrt(np.diag(reduction.prior_covariance))[:3]
    applied, applied_sigma = reduction.mean[:3], np.sqrt(np.diag(reduction.covariance))[:3]
    given = prior_sigma < LEVER_ARM_FREE_SIGMA
    diagnostics = nav.diagnostics
    calibration = None if diagnostics is None else diagnostics.calibration
    off = _lever_arm_differences(own, own_sigma, prior, prior_sigma, given)
    contested: list[int] = []
    doubt = ""
    if calibration is not None:
        ekf, ekf_sigma = np.asarray(calibration.lever_arm, float), np.asarray(calibration.lever_arm_sigma, float)
        # the EKF's calibration pass sees the same data: where it resolves the axis as well as the graph (sigma at
        # most CONTEST_SIGMA_RATIO times the graph's) and agrees with the configuration, the data do not single
        # out the configuration, and the graph's solution is as likely at fault (a multicopter with a consumer
        # IMU: the graph's data put the antenna 1.69 +- 0.54 m forward, the EKF -0.51 +- 0.52 m, the truth 0.02 m)
        ekf_off = _lever_arm_differences(ekf, ekf_sigma, prior, prior_sigma, np.ones(3, bool))
        contested = [k for k in off if k not in ekf_off and ekf_sigma[k] <= CONTEST_SIGMA_RATIO * own_sigma[k]]
        if contested:
            doubt = ("; ".join(f"on {AXES[k]} the graph's data put the antenna at {own[k]:.2f} +- "
                               f"{own_sigma[k]:.2f} m but the EKF's calibration pass, on the same data, at "
                               f"{ekf[k]:.2f} +- {ekf_sigma[k]:.2f} m, in agreement with the configured "
                               f"{prior[k]:.2f} m"
                               for k in contested)
                     + ": the graph's own solution is as likely at fault as the lever arm (see 'graph vs rts'); "
                     "compare the frames with --method rts")
    problems = [f"GNSS lever arm {AXES[k]} ({AXIS_WORDS[AXES[k]]}): the flight's data put the antenna at "
                f"{own[k]:.2f} +- {own_sigma[k]:.2f} m, the configuration says {prior[k]:.2f} +- {prior_sigma[k]:.2f} m"
                for k in off if k not in contested]
    graph_text = f"the graph applied {_lever_arm_text(applied, applied_sigma)} m (x, y, z)"
    if problems:
        return Check("lever arm", FAIL, "; ".join(problems) + f"; {graph_text}, held near the configuration by its "
                     "prior, so the frames carry the configured lever arm's error. " + LEVER_ADVICE
                     + (f" Also {doubt}." if doubt else ""))
    if doubt:
        return Check("lever arm", WARN, f"{graph_text}; {doubt}.")
    if given.all():
        text = f"the GNSS lever arm the data show agrees with the configured one; {graph_text}"
    elif given.any():
        text = f"{graph_text}, estimated on the axes not given, agreeing with the configuration on the others"
    else:
        text = f"no GNSS lever arm given: {graph_text.replace('applied', 'estimated and applied')}"
    if calibration is None:
        return Check("lever arm", PASS, text)
    ekf_text = f"the EKF's calibration pass puts it at {_lever_arm_text(ekf, ekf_sigma)} m"
    apart = _lever_arm_differences(ekf, ekf_sigma, applied, applied_sigma, np.ones(3, bool))
    if apart:
        return Check("lever arm", WARN, f"{text}; {ekf_text}: the two differ on {', '.join(AXES[k] for k in apart)} "
                     "although they see the same data, so one of them is wrong there. Compare the frames with "
                     "--method rts and check the lever arm on the installation.")
    return Check("lever arm", PASS, f"{text}; {ekf_text}, in agreement")


def unapplied_latency(nav: NavSolution, given: float | None) -> float:
    """The GNSS time-tag latency [s] the data show and the run did not apply: the calibration pass's estimate when
    the user gave none (``given``) and it is significant (LATENCY_SIGMAS sigma and LATENCY_MIN_S), else 0. The
    solution trails the truth by about that times the speed, which the EO sigmas then carry."""
    diagnostics = nav.diagnostics
    if given is not None or diagnostics is None or getattr(diagnostics, "calibration", None) is None:
        return 0.0
    value = float(diagnostics.calibration.latency)
    sigma = float(diagnostics.calibration.latency_sigma)
    return value if abs(value) > LATENCY_SIGMAS * sigma and abs(value) > LATENCY_MIN_S else 0.0


def check_latency(nav: NavSolution, cfg: ProcessingConfig | None = None) -> Check | None:
    """``latency``: the calibration pass's GNSS time-tag latency, when the user gave none (it is then not
    applied). Without ``cfg``, a latency applied as 0 counts as not given."""
    diagnostics = nav.diagnostics
    if diagnostics is None or diagnostics.calibration is None:
        return None
    given = cfg.gnss.latency if cfg is not None else (diagnostics.latency_applied or None)
    if given is not None:
        return None
    value = float(diagnostics.calibration.latency)
    sigma = float(diagnostics.calibration.latency_sigma)
    figures = f"the data show a GNSS time-tag latency of {value:.3f} +- {sigma:.3f} s"
    if unapplied_latency(nav, None):
        return Check("latency", WARN, f"{figures} (the fix measured that long before its time tag); it was not "
                     "applied, and the EO sigmas carry the position it moves (the speed times it). If the "
                     f"receiver's time tags are known to lag, apply it with --gnss-latency "
                     f"{value:.3f} ([gnss] gnss_latency) and check that the innovations improve; an estimate that "
                     "trades off against the lever arm's forward component is not worth applying.")
    return Check("latency", PASS, f"{figures}: not significant (not applied)")


def _heading_advice(kind: str) -> str:
    """Where else a heading can come from, for the inputs the user holds."""
    if kind.startswith("ArduPilot"):
        return ("Log the autopilot's attitude (ATT) or the magnetometer (MAG) in LOG_BITMASK, or fly turns or "
                "accelerations (a change of speed of a few m/s) in the log.")
    if kind.startswith("PX4"):
        return ("Log vehicle_attitude or the magnetometer (vehicle_magnetometer), or fly turns or accelerations (a "
                "change of speed of a few m/s) in the log.")
    if kind.startswith("imu.csv"):
        return ("Add the magnetometer (imu.csv mag_x..z, with --magnetic-declination) or the autopilot's yaw "
                "(imu.csv yaw), or include turns or accelerations in the log.")
    if kind.startswith("ROS"):
        return ("Include turns or accelerations (a change of speed of a few m/s) in the recording: georef reads "
                "no magnetometer or IMU orientation from a bag; or convert the bag to imu.csv with mag_x..z "
                "(docs/rosbags.md).")
    return ("Give the heading another way: the POS unit's own yaw with IACC (POS.txt), or include turns or "
            "accelerations in the log.")


def check_heading(nav: NavSolution, kind: str = "POS.txt") -> Check | None:
    """``heading``: never observable fails; a magnetometer's or an autopilot's heading warns. ``kind``: what the
    inputs were, for the advice."""
    diagnostics = nav.diagnostics
    if diagnostics is None:
        return None
    source = str(diagnostics.heading_source)
    sigma = float(np.degrees(diagnostics.alignment.heading_sigma))
    if source.startswith("none"):
        return Check("heading", FAIL, f"{source}. The yaw of every frame is undetermined. "
                     f"{_time_scale_advice(kind)}{_heading_advice(kind)}")
    if source.startswith(("magnetometer", "autopilot")):
        valid = np.asarray(nav.valid, bool)
        claimed = float(np.degrees(np.median(nav.att_sigma[valid, 2]))) if valid.any() else np.nan
        if claimed < SPURIOUS_HEADING_SHARE * sigma:
            # the motion never showed the heading (no window did), so no yaw can be better than the source's
            return Check("heading", FAIL, f"heading from the {source.split(' ')[0]} (sigma {sigma:.1f} deg), and the "
                         "motion never showed it, yet the solution claims a yaw sigma of "
                         f"{claimed:.1f} deg (median): information it cannot have, so neither the yaw nor its sigma "
                         "can be trusted. Fly turns or accelerations, or give a better heading source.")
        return Check("heading", WARN, f"heading from the {source.split(' ')[0]} (sigma {sigma:.1f} deg): the motion "
                     "never showed the heading, so the yaw is only as good as that source (declination, hard iron, "
                     "the autopilot's own errors). Check the yaw column of the EO table before using it.")
    return Check("heading", PASS, f"heading from the {source}")


def check_restarts(nav: NavSolution) -> Check | None:
    """``restarts``: re-alignments after a divergence (the smoother does not carry information across them)."""
    diagnostics = nav.diagnostics
    if diagnostics is None:
        return None
    restarts = list(diagnostics.restarts)
    if not restarts:
        return Check("restarts", PASS, "the filter ran without a restart")
    # a restart that gets no further (the same fixes rejected again after re-aligning) repeats at one place: listed
    # once with its count
    places = Counter(f"at {r.time:.1f} s: {r.reason}" for r in restarts)
    texts = [text if count == 1 else f"{text} ({count} times)" for text, count in places.items()]
    listed = "; ".join(texts[:LIST_AT_MOST])
    more = f"; and {len(texts) - LIST_AT_MOST} more" if len(texts) > LIST_AT_MOST else ""
    return Check("restarts", WARN, f"{len(restarts)} restart(s) after a divergence ({listed}{more}). Frames just "
                 "before and after them are less certain; look for bad GNSS fixes or IMU data there.")


#: graph against RTS: the share of keyframes whose horizontal positions, or attitudes on any axis, differ by more
#: than 3 of the graph's sigma that fails the check. Both smoothers use the same data, so a clean flight stays well
#: inside; flights where one of them went wrong (KITTI's positions, a simulated car's attitude) lie far beyond
#: (the figures: docs/qc.md, "graph vs rts").
GRAPH_SEPARATION_SIGMA = 3.0
GRAPH_SEPARATION_SHARE = 0.02


def check_graph_separation(nav: NavSolution) -> Check | None:
    """``graph vs rts`` (``--method graph``): the graph smoother against the EKF + RTS solution it started from,
    horizontal position and attitude, at its keyframes."""
    graph = nav.graph_info
    if graph is None:
        return None
    parts = [(what, np.asarray(values, float)) for what, values in
             (("horizontal positions", graph.rts_separation_sigma),
              ("attitudes", graph.rts_attitude_separation_sigma)) if values is not None and len(values)]
    if not parts:
        return None
    texts, failed = [], False
    for what, separation in parts:
        share = float(np.mean(separation > GRAPH_SEPARATION_SIGMA))
        failed |= share > GRAPH_SEPARATION_SHARE
        texts.append(f"{what} differ by a median {np.median(separation):.2f} and at most {separation.max():.2f} of "
                     f"the graph's sigma ({share:.1%} of {len(separation)} keyframes beyond "
                     f"{GRAPH_SEPARATION_SIGMA:g})")
    text = "graph and rts " + "; ".join(texts)
    if failed:
        return Check("graph vs rts", FAIL, text + ": the two smoothers of the same data disagree, so the graph's "
                     "answer and its sigma cannot be trusted. Compare with --method rts.")
    return Check("graph vs rts", PASS, text)


def check_imu_gaps(nav: NavSolution) -> Check | None:
    """``IMU gaps``: spans without real IMU data (time gaps or a logger's interpolated dropouts)."""
    diagnostics = nav.diagnostics
    if diagnostics is None:
        return None
    gaps = list(diagnostics.imu_gaps)
    if not gaps:
        return Check("IMU gaps", PASS, "no gap in the IMU data")
    lengths = np.array([b - a for a, b in gaps])
    k = int(np.argmax(lengths))
    return Check("IMU gaps", WARN, f"{len(gaps)} span(s) without IMU data, {lengths.sum():.2f} s in all (longest "
                 f"{lengths[k]:.2f} s from {gaps[k][0]:.1f} s; starts at {_times(a for a, _ in gaps)}): bridged "
                 "with the process noise of unknown motion, so frames there are less accurate. Check the logger "
                 "(dropped samples, a full disk, interpolated rows).")


def _frame_ids(table: Mapping[str, Any]) -> np.ndarray:
    """The ``frame`` column of an EO table (columns or a DataFrame) as text."""
    return np.asarray(table["frame"]).astype(str)


def _clock_advice(kind: str, frame_times: np.ndarray, t0: float, t1: float) -> str:
    """What to check when the exposures miss the navigation span, for the inputs the user holds (``kind``):
    a raw camera log's UTC offset for POS.txt; for events.csv the clock its times must be on (a bag's stamps,
    imu.csv's times, an autopilot log's clock), and the time scale of an _events.pos."""
    if kind.startswith("ROS"):
        advice = ("events.csv's times must be on the clock of the bag's header.stamp, which for a wall clock is "
                  "Unix seconds (UTC since 1970-01-01)")
        finite = frame_times[np.isfinite(frame_times)]
        if len(finite) and t0 > 1e9 and float(np.max(finite)) < 1e9:
            # seconds of a day or of a GPS week against Unix stamps: the day's (week's) start is missing
            import datetime as dt

            day = np.floor(t0 / 86400.0) * 86400.0
            date = dt.datetime.fromtimestamp(day, tz=dt.UTC).date().isoformat()
            advice += (": these exposure times are seconds of a day or a GPS week, not Unix time. For UTC seconds "
                       f"of the bag's day add its 00:00 UTC, {day:.0f} s ({date}), to every time in events.csv "
                       "(GPS seconds of the week: the week's start, less the 18 leap seconds), or give the "
                       "receiver's _events.pos, which --time-scale places")
        return (f"{advice}; also check --camera-time-offset (seconds) and that the files are of the same flight.")
    if kind.startswith("imu.csv"):
        return ("events.csv's times must be on imu.csv's clock (the same seconds as its time column); an "
                "_events.pos is placed on it with --time-scale (utc-day, gps-week, unix; GPST and UTC differ by 18 "
                "s). Also check --camera-time-offset (seconds) and that the files are of the same flight.")
    if kind.startswith(("ArduPilot", "PX4")):
        return ("the exposures must be on the log's own clock: events.csv (--events) in the log's UTC seconds of "
                "the day, as the EO table's time column. Also check --camera-time-offset (seconds) and that the "
                "files are of the same flight.")
    return ("The camera's clock does not match the POS log's: check --camera-utc-offset (hours, raw camera logs), "
            "--camera-time-offset (seconds) and that the two files are of the same flight.")


def check_frames(nav: NavSolution, table: Mapping[str, Any], kind: str = "POS.txt") -> Check:
    """``frames``: exposures outside the navigation span. More than half (or all) fails: the camera's clock does
    not match the POS log's (a wrong UTC offset, a different day). ``table``: the EO table, as columns
    (:func:`georef.eo.camera_eo_columns`) or a DataFrame; ``kind``: what the inputs were, for the advice."""
    n = len(table["flag"])
    if n == 0:
        return Check("frames", FAIL, "the exposure file holds no frame")
    outside = flag_mask(table, FLAG_OUTSIDE)
    count = int(outside.sum())
    valid = np.flatnonzero(nav.valid)
    if len(valid) == 0:
        return Check("frames", FAIL, f"no frame of {n} could be georeferenced: the filter produced no solution")
    t0, t1 = float(nav.time[valid[0]]), float(nav.time[valid[-1]])
    span = f"the navigation span {t0:.1f} to {t1:.1f} s"
    broken = flag_mask(table, FLAG_NO_SIGMA)
    if broken.any():
        frames = _frame_ids(table)[broken]
        listed = ", ".join(frames[:LIST_AT_MOST]) + (" ..." if broken.sum() > LIST_AT_MOST else "")
        return Check("frames", FAIL, f"{int(broken.sum())} of {n} frames have no valid sigma (frames {listed}): the "
                     "solution's covariance is numerically broken there, so their positions and attitudes cannot "
                     "be trusted either. Please report it with the data (a bug in georef, or data it does not "
                     "handle).")
    if count == 0:
        from georef.io.camera import FLAG_INCOMPLETE

        cut = flag_mask(table, FLAG_INCOMPLETE)
        if cut.any():
            frames = _frame_ids(table)[cut]
            listed = ", ".join(frames[:LIST_AT_MOST]) + (" ..." if cut.sum() > LIST_AT_MOST else "")
            return Check("frames", WARN, f"{int(cut.sum())} of {n} exposure lines were cut short in the exposure "
                         f"file and their rows are empty (frames {listed}); the other frames lie inside {span}. "
                         "Recover those lines from the camera's own log.")
        return Check("frames", PASS, f"all {n} frames inside {span}")
    frames = _frame_ids(table)[outside]
    listed = ", ".join(frames[:LIST_AT_MOST]) + (" ..." if count > LIST_AT_MOST else "")
    if count > OUTSIDE_FAIL_SHARE * n:
        # how far the exposures are off: their median time against the span's centre (a clock off by a UTC
        # offset shows as whole hours)
        times = np.asarray(table["time"], dtype=float)
        shift = float(np.nanmedian(times) - 0.5 * (t0 + t1))
        where = "later" if shift > 0 else "earlier"
        frame_span = f"{np.nanmin(times):.1f} to {np.nanmax(times):.1f} s" if np.isfinite(times).any() else "none"
        return Check("frames", FAIL, f"{count} of {n} frames lie outside {span} (frames {listed}; exposure times "
                     f"{frame_span}); the exposures lie {abs(shift):.0f} s ({abs(shift) / 3600:.2f} h) {where} than "
                     "the navigation (median frame time against the span's centre). "
                     f"{_clock_advice(kind, times, t0, t1)}")
    return Check("frames", WARN, f"{count} of {n} frames lie outside {span} (frames {listed}): their rows are "
                 "written with empty values and flagged. Exposures before the log started or after it ended "
                 "cannot be georeferenced.")


def check_gnss_ends(nav: NavSolution, table: Mapping[str, Any]) -> Check:
    """``GNSS at the ends``: frames after the last GNSS fix or before the first one (inertial only there);
    ``table`` as for :func:`check_frames`."""
    after = flag_mask(table, FLAG_AFTER_LAST_FIX)
    before = flag_mask(table, FLAG_BEFORE_FIRST_FIX)
    if not after.any() and not before.any():
        return Check("GNSS at the ends", PASS, "no frame before the first GNSS fix or after the last one")
    time = np.asarray(table["time"], dtype=float)
    frames = _frame_ids(table)
    first, last = float(np.min(nav.gnss.time)), float(np.max(nav.gnss.time))
    parts = []
    if after.any():
        longest = float(time[after].max() - last)
        parts.append(f"{int(after.sum())} frame(s) after the last GNSS fix at {last:.1f} s (frames "
                     f"{frames[after][0]} to {frames[after][-1]}, up to {longest:.0f} s of inertial-only navigation)")
    if before.any():
        longest = float(first - time[before].min())
        parts.append(f"{int(before.sum())} frame(s) before the first GNSS fix at {first:.1f} s (frames "
                     f"{frames[before][0]} to {frames[before][-1]}, up to {longest:.0f} s of inertial-only "
                     "navigation)")
    return Check("GNSS at the ends", WARN, "; ".join(parts) + ": they are flagged in the EO table and their "
                 "sigmas grow with the time since the fix. Check those frames, or log GNSS over the whole flight.")


def assess(nav: NavSolution, table: Mapping[str, Any] | None = None, cfg: ProcessingConfig | None = None,
           kind: str = "POS.txt") -> Verdict:
    """Every check that applies to ``nav`` (any method), the EO ``table`` (``georef process``; columns or a
    DataFrame) and ``cfg``; ``kind`` says what the inputs were (``PosLog.kind``), for the advice.

    The full-state filters get every check that applies: ``rts`` and ``ekf`` (``nav.diagnostics`` set), and
    ``graph``, which carries the diagnostics of the EKF + RTS it starts from and adds ``graph vs rts`` (it has no
    forward filter of its own, so no ``attitude sigmas``); ``axis`` gets the rejected fixes and, with a table, the
    frame checks.
    """
    checks: list[Check | None] = [*check_innovations(nav, kind), check_held_out(nav, kind),
                                  check_attitude_scale(nav, kind), check_rejected(nav, cfg, kind),
                                  check_lever_arm(nav), check_latency(nav, cfg), check_heading(nav, kind),
                                  check_restarts(nav), check_imu_gaps(nav), check_graph_separation(nav)]
    if table is not None:
        checks += [check_frames(nav, table, kind), check_gnss_ends(nav, table)]
    return Verdict(tuple(c for c in checks if c is not None))


def assess_result(result: Any) -> Verdict:
    """:func:`assess` of a :class:`georef.pipeline.ProcessResult` (its EO table as columns: no pandas)."""
    return assess(result.nav, result.columns, result.config, result.log.kind)
