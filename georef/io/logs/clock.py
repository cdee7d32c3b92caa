"""An autopilot's boot clock mapped to UTC: an offset and a rate, fitted to the GNSS fixes.

Every message of an autopilot log carries the time since boot of the flight controller's clock. The GNSS
receiver tells the true time of each fix (GPS week and time of week, or UTC). Fitting ``utc = offset + rate *
boot`` through the fixes carries every other message (IMU samples, camera events) onto UTC. The rate is fitted
too: a crystal is off by tens of ppm (tens of ms over an hour), and one Linux flight controller of 2014 ran its
boot clock at 12/13 of real time, which an offset alone would turn into a drift of 8 s per 100 s.

A fix's message is logged when it arrives, some tens of milliseconds after the fix (the receiver's computing
and the serial link): ``lag`` [s] is subtracted from the arrival times before the fit, so the mapping is of the
fix's own instant. What the lag was, and where it came from, is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef.io.errors import InputError

#: fixes whose residual exceeds this many robust sigmas (and CLOCK_OUTLIER_MIN_S) are left out of the fit
CLOCK_OUTLIER_SIGMAS = 5.0
CLOCK_OUTLIER_MIN_S = 0.05
#: a rate further than this from 1 is reported (a clock that is not a crystal's)
RATE_NOTICE = 1e-3
#: the rates a boot clock can have against UTC: 12/13 is the slowest met (see above); beyond, the fixes' times or
#: the boot times are damaged
RATE_RANGE = (0.5, 2.0)


@dataclass(frozen=True)
class ClockFit:
    """``utc = offset + rate * (boot - boot_ref)`` [s]; fitted on ``fixes`` fixes, of which ``outliers`` were
    left out, with an rms residual ``residual_s`` [s] (the arrival jitter). ``lag_s`` was subtracted from the
    arrival times first; ``lag_source`` says where it came from."""

    offset: float
    rate: float
    boot_ref: float
    residual_s: float
    fixes: int
    outliers: int
    lag_s: float
    lag_source: str
    #: the earliest UTC [POSIX s] of the fixes the fit kept (not of an outlier)
    first_utc: float = float("nan")

    def utc(self, boot: np.ndarray | float) -> np.ndarray:
        """UTC [POSIX s] of boot-clock times [s]."""
        return self.offset + self.rate * (np.asarray(boot, dtype=float) - self.boot_ref)

    def describe(self) -> str:
        ppm = (self.rate - 1.0) * 1e6
        text = (f"boot clock to UTC over {self.fixes} fixes: rate {ppm:+.0f} ppm, arrival jitter "
                f"{self.residual_s * 1e3:.0f} ms rms, {self.outliers} fix(es) left out; fix messages taken as "
                f"{self.lag_s * 1e3:.0f} ms after their fix ({self.lag_source})")
        if abs(self.rate - 1.0) > RATE_NOTICE:
            text += (f". The boot clock runs at {self.rate:.6f} times real time, not a crystal's rate: every IMU "
                     "sample and camera event is rescaled by it")
        return text


def fit_clock(path: object, boot_arrival: np.ndarray, utc: np.ndarray, lag_s: float, lag_source: str,
              field: str) -> ClockFit:
    """The boot clock -> UTC mapping from fixes logged at boot times ``boot_arrival`` [s] whose receiver time is
    ``utc`` [POSIX s]. Robust: fixes far off the line (a stale time of week, a receiver restart) are left out.
    Raises :class:`InputError` naming ``field`` when fewer than two usable fixes remain, or when the fit makes the
    boot clock run at a rate outside :data:`RATE_RANGE` (damaged times)."""
    boot = np.asarray(boot_arrival, dtype=float) - lag_s
    utc = np.asarray(utc, dtype=float)
    ok = np.isfinite(boot) & np.isfinite(utc)
    if ok.sum() < 2:
        raise InputError(path, None, field, "fewer than two GNSS fixes with a time: the log's clock cannot be "
                         "tied to UTC")
    boot_ref = float(np.median(boot[ok]))
    keep = ok.copy()
    for _ in range(5):
        A = np.stack([np.ones(keep.sum()), boot[keep] - boot_ref], -1)
        (offset, rate), *_ = np.linalg.lstsq(A, utc[keep], rcond=None)
        residual = utc - (offset + rate * (boot - boot_ref))
        spread = 1.4826 * float(np.median(np.abs(residual[keep] - np.median(residual[keep]))))
        limit = max(CLOCK_OUTLIER_SIGMAS * spread, CLOCK_OUTLIER_MIN_S)
        new_keep = ok & (np.abs(residual) <= limit)
        if new_keep.sum() < 2 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        raise InputError(path, None, field, f"over the {int(keep.sum())} fixes fitted, the boot clock would run at "
                         f"{rate:.3g} times UTC: the fixes' times or their boot times are damaged")
    rms = float(np.sqrt(np.mean(residual[keep] ** 2)))
    return ClockFit(offset=float(offset), rate=float(rate), boot_ref=boot_ref, residual_s=rms, fixes=int(keep.sum()),
                    outliers=int(ok.sum() - keep.sum()), lag_s=float(lag_s), lag_source=lag_source,
                    first_utc=float(utc[keep].min()))
