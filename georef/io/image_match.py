"""Photos matched to the EO table's frames by their capture times, and the camera clock's offset from UTC.

A camera stamps each photo with its own clock (EXIF ``DateTimeOriginal`` + ``SubSecTimeOriginal``, and
``OffsetTimeOriginal`` when it knows its time zone). The EO table's ``time`` is UTC seconds of the flight's day
(``docs/formats.md``): UTC from the GNSS receiver's GPS time minus the leap seconds
(:func:`georef.frames.gpstime.gps_week_to_utc`), or the POS unit's UTC. The camera clock's offset

    offset = camera clock - UTC of the exposure  [s]

is not known in advance (a clock set by hand, a local time zone, its drift), so it is searched: every pairing of
a few anchor photos with every frame proposes an offset, and each proposal is scored by how many photos then
have a frame within the tolerance (the capture time's resolution plus :data:`CLOCK_TOLERANCE_S`). The best is
refined by a straight-line fit (offset at mid-flight + drift in ppm, a camera's quartz runs 10-50 ppm off).

**Ambiguity.** A camera triggered at a regular interval T fits offsets T apart about equally well: shifted by
one interval every photo but one at each end still has a frame within the tolerance. Only irregular intervals
(turns, pauses, distance triggering at a changing speed) tell the offsets apart. When a second offset leaves
fewer than :data:`MIN_UNMATCHED_MARGIN` more photos without a frame than the best, the match is **not unique**:
:class:`ClockMatchError` lists the offsets and asks for ``--image-names`` or ``--camera-clock-offset``; georef
never picks one of them.

Without a time zone (no ``OffsetTimeOriginal``) the camera's clock is read as if it were UTC, and the offset
then holds the time zone; offsets are taken within +-12 h of UTC, which also gives the flight's UTC date (the
EO table has none) for the ``GPSDateStamp`` of the copies.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from georef.frames.gpstime import SECONDS_PER_DAY, utc_day_start
from georef.io.errors import GeorefError

#: how far [s] a photo's capture time (less the offset) may be from its frame's time, beyond half the capture
#: time's resolution: a camera's stamping jitter and what a straight line leaves of its clock's drift
CLOCK_TOLERANCE_S = 0.05
#: a second offset must leave at least this many more photos without a frame than the best one, else the match
#: is ambiguous (regular triggering leaves one more per end of each regular run)
MIN_UNMATCHED_MARGIN = 3
#: photos whose pairings with every frame propose offsets (spread over the flight)
ANCHORS = 7
#: the drift is fitted only over at least this span of matched photos [s] and this many photos
DRIFT_MIN_SPAN_S = 60.0
DRIFT_MIN_PHOTOS = 10
HALF_DAY_S = SECONDS_PER_DAY / 2.0


class ClockMatchError(GeorefError):
    """The capture times do not give a unique match (or none): the message says what the user can do."""


@dataclass(frozen=True)
class OffsetFit:
    """One candidate camera clock offset and how many photos it matches."""

    offset_s: float
    matched: int


@dataclass(frozen=True)
class ClockMatch:
    """The photos matched to frames by capture time.

    ``offset_s``: camera clock minus UTC [s] at ``reference_posix`` (the mean capture time of the matched photos,
    camera clock as POSIX seconds); ``drift_ppm``: how fast the offset grows [1e-6 s/s] (0 when not fitted);
    ``spread_s``: standard deviation of the matched photos' residuals [s]; ``frame_index``: per photo the EO row
    (-1: none within ``tolerance_s``); ``residual_s``: per photo, capture time minus offset minus the frame's time
    [s] (NaN without a frame); ``day_start_posix``: POSIX seconds of 00:00 UTC of the EO table's day (its ``time``
    0); ``alternatives``: the next best offsets, for the report."""

    offset_s: float
    drift_ppm: float
    reference_posix: float
    spread_s: float
    frame_index: np.ndarray
    residual_s: np.ndarray
    tolerance_s: np.ndarray
    day_start_posix: float
    fixed: bool
    alternatives: list[OffsetFit] = field(default_factory=list)

    @property
    def matched(self) -> int:
        return int(np.sum(self.frame_index >= 0))


def _nearest(sorted_times: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index into ``sorted_times`` of the nearest value to each ``t``, and the signed difference t - nearest."""
    right = np.clip(np.searchsorted(sorted_times, t), 1, len(sorted_times) - 1)
    left = right - 1
    use_right = np.abs(sorted_times[right] - t) < np.abs(t - sorted_times[left])
    idx = np.where(use_right, right, left)
    return idx, t - sorted_times[idx]


def _model(camera_s: np.ndarray, offset: float, drift: float, reference: float) -> np.ndarray:
    """UTC [s, the EO table's scale] the camera times stand for under ``offset`` + ``drift`` (s/s)."""
    return camera_s - offset - drift * (camera_s - reference)


def _count(eo_sorted: np.ndarray, camera_s: np.ndarray, tol: np.ndarray, offset: float, drift: float,
           reference: float) -> int:
    _, diff = _nearest(eo_sorted, _model(camera_s, offset, drift, reference))
    return int(np.sum(np.abs(diff) <= tol))


def _assign(eo_sorted: np.ndarray, order: np.ndarray, camera_s: np.ndarray, tol: np.ndarray, offset: float,
            drift: float, reference: float) -> tuple[np.ndarray, np.ndarray]:
    """Per photo the EO row (or -1) and residual; a frame claimed by two photos goes to the closer one."""
    idx, diff = _nearest(eo_sorted, _model(camera_s, offset, drift, reference))
    ok = np.abs(diff) <= tol
    frame = np.where(ok, order[idx], -1)
    for row in np.unique(frame[frame >= 0]):
        claim = np.flatnonzero(frame == row)
        if len(claim) > 1:
            keep = claim[np.argmin(np.abs(diff[claim]))]
            frame[claim[claim != keep]] = -1
    residual = np.where(frame >= 0, diff, np.nan)
    return frame, residual


def match_capture_times(camera_posix: np.ndarray, resolution_s: np.ndarray, eo_time: np.ndarray,
                        fixed_offset_s: float | None = None) -> ClockMatch:
    """Match photos to EO rows by capture time.

    ``camera_posix``: each photo's capture time on the camera's clock as POSIX seconds (a time without a zone read
    as UTC); ``resolution_s``: its resolution (1 s without sub-seconds); ``eo_time``: the EO table's ``time``
    [UTC s of its day; NaN rows are never matched]; ``fixed_offset_s``: camera clock minus UTC [s] when the user
    knows it (``--camera-clock-offset``): then nothing is searched but the day. Raises :class:`ClockMatchError`
    when no offset matches most photos or several match about equally.
    """
    camera_posix = np.asarray(camera_posix, float)
    resolution = np.asarray(resolution_s, float)
    eo_time = np.asarray(eo_time, float)
    valid = np.flatnonzero(np.isfinite(eo_time))
    if len(valid) < 2 or len(camera_posix) == 0:
        raise ClockMatchError("matching by capture time needs at least two exposures with a time and one photo")
    order = valid[np.argsort(eo_time[valid], kind="stable")]
    eo_sorted = eo_time[order]
    day0 = utc_day_start(float(np.min(camera_posix)))
    # a time truncated to its resolution stands for the middle of that interval
    camera_s = camera_posix - day0 + resolution / 2.0
    tol = CLOCK_TOLERANCE_S + resolution / 2.0
    reference = float(np.mean(camera_s))
    if fixed_offset_s is not None:
        candidates = np.array([fixed_offset_s + k * SECONDS_PER_DAY for k in (-1.0, 0.0, 1.0)])
    else:
        anchors = np.unique(np.linspace(0, len(camera_s) - 1, min(ANCHORS, len(camera_s))).round().astype(int))
        candidates = (camera_s[anchors][:, None] - eo_sorted[None, :]).ravel()
    counts = np.array([_count(eo_sorted, camera_s, tol, d, 0.0, reference) for d in candidates])
    best = float(candidates[int(np.argmax(counts))])
    drift = 0.0
    frame, residual = _assign(eo_sorted, order, camera_s, tol, best, drift, reference)
    for _ in range(3):  # refine: the offset at mid-flight and, over a long enough flight, the clock's drift
        ok = frame >= 0
        if not ok.any():
            break
        x = camera_s[ok] - reference
        y = (camera_s[ok] - eo_time[frame[ok]])
        if fixed_offset_s is None and np.ptp(camera_s[ok]) >= DRIFT_MIN_SPAN_S and ok.sum() >= DRIFT_MIN_PHOTOS:
            slope, intercept = np.polyfit(x, y, 1)
        else:
            slope, intercept = 0.0, float(np.median(y)) if fixed_offset_s is None else best
        best, drift = float(intercept), float(slope)
        frame, residual = _assign(eo_sorted, order, camera_s, tol, best, drift, reference)
    matched = int(np.sum(frame >= 0))
    if matched < max(2, len(camera_s) // 2):
        shown = f"{best:+.3f} s" if fixed_offset_s is None else f"the given {fixed_offset_s:+.3f} s"
        raise ClockMatchError(f"capture times: at most {matched} of {len(camera_s)} photos have an exposure within "
                              f"{CLOCK_TOLERANCE_S:.2f} s at any camera clock offset (best {shown}); are these the "
                              "flight's photos? Name them with --image-names, or give --camera-clock-offset SECONDS "
                              "(camera clock minus UTC)")
    alternatives: list[OffsetFit] = []
    if fixed_offset_s is None:
        # every other proposal, with the fitted drift, told apart from the best by more than the tolerance
        rescored = sorted(((_count(eo_sorted, camera_s, tol, float(d), drift, reference), float(d))
                           for d in np.unique(candidates.round(3)) if abs(d - best) > 2.0 * float(np.max(tol))),
                          reverse=True)
        for count, d in rescored:
            if all(abs(d - a.offset_s) > 2.0 * float(np.max(tol)) for a in alternatives):
                alternatives.append(OffsetFit(d, count))
            if len(alternatives) == 3:
                break
        rivals = [a for a in alternatives if a.matched > matched - MIN_UNMATCHED_MARGIN]
        if rivals:
            listed = ", ".join(f"{a.offset_s:+.3f} s ({a.matched})" for a in rivals)
            raise ClockMatchError(
                f"capture times: the match to the exposures is not unique — several camera clock offsets fit about "
                f"equally: {best:+.3f} s ({matched} of {len(camera_s)} photos within the tolerance), {listed} "
                "(regular triggering: offsets a trigger interval apart fit alike; georef does not guess). Name the "
                "photos with --image-names, or give the offset with --camera-clock-offset SECONDS (camera clock "
                "minus UTC)")
    ok = frame >= 0
    # split the day off: the EO table's day starts at day0 + (the offset's whole days)
    clock = ((best + HALF_DAY_S) % SECONDS_PER_DAY) - HALF_DAY_S if fixed_offset_s is None else fixed_offset_s
    day_start = day0 + round((best - clock) / SECONDS_PER_DAY) * SECONDS_PER_DAY
    return ClockMatch(offset_s=float(clock), drift_ppm=drift * 1e6, reference_posix=reference + day0,
                      spread_s=float(np.std(residual[ok])) if ok.sum() > 1 else 0.0, frame_index=frame,
                      residual_s=residual, tolerance_s=tol, day_start_posix=float(day_start),
                      fixed=fixed_offset_s is not None, alternatives=alternatives)


def offset_from_pairs(camera_posix: np.ndarray, resolution_s: np.ndarray, eo_time: np.ndarray) -> ClockMatch:
    """The camera clock offset of photos already paired with their frames (``--image-names``): ``eo_time[i]`` is
    photo i's frame time [UTC s of day]. Nothing is searched; the residuals show photos whose capture time
    disagrees with the named frame."""
    camera_posix = np.asarray(camera_posix, float)
    resolution = np.asarray(resolution_s, float)
    eo_time = np.asarray(eo_time, float)
    day0 = utc_day_start(float(np.min(camera_posix)))
    camera_s = camera_posix - day0 + resolution / 2.0
    ok = np.isfinite(eo_time)
    raw = camera_s[ok] - eo_time[ok]
    middle = float(np.median(raw))
    clock = ((middle + HALF_DAY_S) % SECONDS_PER_DAY) - HALF_DAY_S
    residual = np.full(len(camera_s), np.nan)
    residual[ok] = raw - middle
    frame = np.where(ok, np.arange(len(camera_s)), -1)
    return ClockMatch(offset_s=float(clock), drift_ppm=0.0, reference_posix=float(np.mean(camera_posix)),
                      spread_s=float(np.std(residual[ok])) if ok.sum() > 1 else 0.0, frame_index=frame,
                      residual_s=residual, tolerance_s=CLOCK_TOLERANCE_S + resolution / 2.0,
                      day_start_posix=day0 + round((middle - clock) / SECONDS_PER_DAY) * SECONDS_PER_DAY,
                      fixed=False)
