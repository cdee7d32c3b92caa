"""Photos matched to the EO table's frames by their capture times, and the camera clock's offset from UTC.

A camera stamps each photo with its own clock (EXIF ``DateTimeOriginal`` + ``SubSecTimeOriginal``, and
``OffsetTimeOriginal`` when it knows its time zone). The EO table's ``time`` is UTC seconds of the flight's day
(``docs/formats.md``): UTC from the GNSS receiver's GPS time minus the leap seconds
(:func:`georef.frames.gpstime.gps_week_to_utc`), or the POS unit's UTC. The camera clock's offset

    offset = camera clock - UTC of the exposure  [s]

is not known in advance (a clock set by hand, a local time zone, its drift), so it is searched: every pairing of
a few anchor photos with every frame proposes an offset, and each proposal is judged by how many photos then
have a frame within the tolerance (the capture time's resolution plus :data:`CLOCK_TOLERANCE_S`) once a
straight line (offset at mid-flight + drift in ppm, a camera's quartz runs 10-50 ppm off) is fitted to its pairs
(:func:`_refine`); the proposals are first scored coarsely on a sample of the photos, so that only those that
can rival the best are refined (:func:`_search`).

**Ambiguity.** A camera triggered at a regular interval T fits offsets T apart about equally well: shifted by
one interval every photo but one at each end still has a frame within the tolerance. Only irregular intervals
(turns, pauses, distance triggering at a changing speed) tell the offsets apart. When a second offset leaves
fewer than :data:`MIN_UNMATCHED_MARGIN` more photos without a frame than the best, the match is **not unique**:
:class:`ClockMatchError` lists the offsets and asks for ``--image-names`` or ``--camera-clock-offset``; georef
never picks one of them. A given offset is only good for choosing among them to within half an interval: its
drift is fitted too, the pairings one and two exposures either side are refined alike, and one that matches more
photos than the given offset means it is off by about an interval (:class:`ClockMatchError`).

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
#: a given offset is tried against the pairings this many exposures earlier and later
NEIGHBOUR_SHIFTS = (-2, -1, 1, 2)
#: pair-and-refit rounds of one offset at most (a drifting clock pairs from the middle outwards in two or three)
REFINE_ROUNDS = 8
#: the largest clock drift [ppm] the search is sure to find every rival offset under (a camera's quartz: 10-50)
MAX_DRIFT_PPM = 50.0
#: photos (spread over the flight) the search's proposals are first scored against
SAMPLE_PHOTOS = 200
#: of which this many are the first and this many the last in time
SAMPLE_END_PHOTOS = 50
HALF_DAY_S = SECONDS_PER_DAY / 2.0


#: what ``georef process`` offers when the capture times do not settle the match
PROCESS_ADVICE = ("Name the photos with --image-names, or give the offset with --camera-clock-offset SECONDS (camera "
                  "clock minus UTC)")


class ClockMatchError(GeorefError):
    """The capture times do not give a unique match (or none): ``finding`` says what was found, ``advice`` what the
    user can do (:data:`PROCESS_ADVICE` unless a caller with other options, ``georef batch``, replaces it)."""

    def __init__(self, finding: str, advice: str = PROCESS_ADVICE) -> None:
        super().__init__(f"{finding}. {advice}" if advice else finding)
        self.finding = finding
        self.advice = advice


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
    claimed = np.flatnonzero(ok)
    # per frame its claims closest first (lexsort is stable: equal distances keep the photos' order)
    ranked = claimed[np.lexsort((np.abs(diff[claimed]), frame[claimed]))]
    again = np.zeros(len(ranked), dtype=bool)
    again[1:] = frame[ranked[1:]] == frame[ranked[:-1]]
    frame[ranked[again]] = -1
    residual = np.where(frame >= 0, diff, np.nan)
    return frame, residual


def _cluster(offsets: np.ndarray, width: float) -> np.ndarray:
    """The distinct offsets among ``offsets`` [s], sorted: groups no wider than ``width``, each stood for by the
    middle of its range (within ``width`` / 2 of every member). Runs split at gaps wider than ``width``; a run
    wider than that is cut greedily (a group from its first member up to ``width`` past it). Regular triggering
    makes the anchors propose nearly the same offsets; each is then scored once."""
    ordered = np.sort(offsets)
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(ordered) > width) + 1, [len(ordered)]))
    low, high = ordered[bounds[:-1]], ordered[bounds[1:] - 1]
    wide = high - low > width
    middles = [((low + high) / 2.0)[~wide]]
    for first, end in zip(bounds[:-1][wide], bounds[1:][wide], strict=True):
        start = first
        while start < end:
            stop = int(np.searchsorted(ordered[:end], ordered[start] + width, side="right"))
            middles.append(np.array([(ordered[start] + ordered[stop - 1]) / 2.0]))
            start = stop
    return np.sort(np.concatenate(middles))


def _coarse_counts(eo_sorted: np.ndarray, camera_s: np.ndarray, wide: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per offset (no drift) how many of ``camera_s`` have a frame within ``wide`` [s]: all offsets at once, in
    blocks of about a million photo-offset pairs."""
    counts = np.empty(len(offsets), dtype=int)
    block = max(1, 1_000_000 // len(camera_s))
    for start in range(0, len(offsets), block):
        t = camera_s[None, :] - offsets[start:start + block, None]
        _, diff = _nearest(eo_sorted, t.ravel())
        counts[start:start + block] = np.sum(np.abs(diff.reshape(t.shape)) <= wide[None, :], axis=1)
    return counts


@dataclass(frozen=True)
class _Fit:
    """One offset refined with the photos it pairs: ``offset`` [s] at ``reference``, ``drift`` [s/s], per photo the
    EO row (-1: none) and residual [s]; ``proposal`` the offset it started from."""

    proposal: float
    offset: float
    drift: float
    frame: np.ndarray
    residual: np.ndarray

    @property
    def matched(self) -> int:
        return int(np.sum(self.frame >= 0))


def _refine(eo_sorted: np.ndarray, order: np.ndarray, camera_s: np.ndarray, tol: np.ndarray, proposal: float,
            reference: float) -> _Fit:
    """Pair the photos at ``proposal`` (no drift), then refit offset + drift to the pairs and pair again until the
    pairs stay. A drifting clock is matched from where the proposal holds outwards: the photos near it pair first,
    their line predicts the rest. Each refit moves the offset by no more than the tolerance (the residuals it fits
    are within it), so a proposal never slides to the pairing an interval away."""
    offset, drift = proposal, 0.0
    frame, residual = _assign(eo_sorted, order, camera_s, tol, offset, drift, reference)
    for _ in range(REFINE_ROUNDS):
        ok = frame >= 0
        if not ok.any():
            break
        x = camera_s[ok] - reference
        y = offset + drift * x + residual[ok]  # camera clock minus the frame's time
        if np.ptp(camera_s[ok]) >= DRIFT_MIN_SPAN_S and ok.sum() >= DRIFT_MIN_PHOTOS:
            drift, offset = (float(v) for v in np.polyfit(x, y, 1))
        else:
            drift, offset = 0.0, float(np.median(y))
        before = frame
        frame, residual = _assign(eo_sorted, order, camera_s, tol, offset, drift, reference)
        if np.array_equal(frame, before):
            break
    return _Fit(proposal, offset, drift, frame, residual)


def neighbour_fits(eo_sorted: np.ndarray, order: np.ndarray, camera_s: np.ndarray, tol: np.ndarray, fit: _Fit,
                   reference: float) -> list[_Fit]:
    """The pairings of the photos with the frames one and two exposures earlier or later than ``fit``'s, proposed
    as the search proposes them (an anchor photo's capture time minus a frame's time, the frames next to the
    anchor's own) and refined the same way (drift fitted): per shift the one that matches most photos."""
    anchors = _anchors(len(camera_s))
    own, _ = _nearest(eo_sorted, _model(camera_s[anchors], fit.offset, fit.drift, reference))
    fits = []
    for shift in NEIGHBOUR_SHIFTS:
        frame = own + shift
        inside = (frame >= 0) & (frame < len(eo_sorted))
        proposals = camera_s[anchors][inside] - eo_sorted[frame[inside]]
        refined = [_refine(eo_sorted, order, camera_s, tol, float(d), reference) for d in proposals]
        if refined:
            fits.append(max(refined, key=lambda f: f.matched))  # ties: the first anchor's
    return fits


def _check_given_offset(eo_sorted: np.ndarray, order: np.ndarray, camera_s: np.ndarray, tol: np.ndarray, fit: _Fit,
                        reference: float, given: float) -> list[OffsetFit]:
    """A given offset picks one of the offsets a trigger interval apart, and is only good for that to within half
    an interval: when an offset one or two exposures away matches more photos (both with their drift fitted), the
    given one is off by about an interval (every photo tagged with a neighbouring frame, ~ speed x interval away)
    and the match is refused. Returns the neighbours that match as many (the pairing then rests on the given
    offset alone), as proposed (camera clock minus the neighbouring frame's time at an anchor photo)."""
    fits = neighbour_fits(eo_sorted, order, camera_s, tol, fit, reference)
    interval = float(np.median(np.diff(eo_sorted))) if len(eo_sorted) > 1 else float("nan")

    def shown(other: _Fit) -> float:
        return other.proposal - fit.proposal + given

    better = [other for other in fits if other.matched > fit.matched]
    if better:
        other = max(better, key=lambda f: f.matched)
        raise ClockMatchError(
            f"capture times: the given camera clock offset {given:+.3f} s matches {fit.matched} of {len(camera_s)} "
            f"photos, and {shown(other):+.3f} s, {abs(shown(other) - given):.3f} s away, matches {other.matched}: "
            f"the given offset pairs the photos with frames about one trigger interval off (median interval "
            f"{interval:.3f} s). A given offset must be right to better than half the trigger interval "
            f"(+-{interval / 2.0:.3f} s) to pick the frames; check it (e.g. from a photo of a GPS clock)",
            "Or name the photos with --image-names")
    return [OffsetFit(shown(other), other.matched) for other in fits if other.matched == fit.matched]


def _anchors(count: int) -> np.ndarray:
    """Indices of the photos (spread over the flight) whose pairings with every frame propose offsets."""
    return np.unique(np.linspace(0, count - 1, min(ANCHORS, count)).round().astype(int))


def _search(eo_sorted: np.ndarray, order: np.ndarray, camera_s: np.ndarray, tol: np.ndarray,
            reference: float) -> list[_Fit]:
    """Every offset an anchor photo paired with a frame proposes, refined, best first (as many as can rival the
    best, at least four distinct ones when there are).

    Scoring each of the ~7 n proposals against all n photos costs n^2. Instead the proposals (clustered within the
    tolerance) are scored coarsely against :data:`SAMPLE_PHOTOS` photos (the first and last
    :data:`SAMPLE_END_PHOTOS` in time, where a pairing k intervals off loses k photos, and others spread over the
    flight), without drift but
    with a tolerance widened by what a drift up to :data:`MAX_DRIFT_PPM` and the clustering can move a photo
    (``wide``), and only the best are refined against every photo. A refined pairing that leaves u photos without
    a frame started from a proposal whose coarse count is at least m - u (m sampled): so once the coarse counts fall
    below m - (the best's unmatched + :data:`MIN_UNMATCHED_MARGIN`), nothing further down can rival the best."""
    anchors = _anchors(len(camera_s))
    proposals = _cluster((camera_s[anchors][:, None] - eo_sorted[None, :]).ravel(), float(np.min(tol)))
    # the first and last photos in time (where an offset an interval off loses its photos) and others spread between
    by_time = np.argsort(camera_s, kind="stable")
    spread = np.linspace(0, len(camera_s) - 1, max(0, min(SAMPLE_PHOTOS - 2 * SAMPLE_END_PHOTOS, len(camera_s))))
    ends = np.r_[0:SAMPLE_END_PHOTOS, len(camera_s) - SAMPLE_END_PHOTOS:len(camera_s)]
    sample = by_time[np.unique(np.clip(np.r_[spread.round().astype(int), ends], 0, len(camera_s) - 1))]
    wide = tol[sample] + 2.0 * float(np.max(tol)) + MAX_DRIFT_PPM * 1e-6 * float(np.ptp(camera_s))
    coarse = _coarse_counts(eo_sorted, camera_s[sample], wide, proposals)
    separate = 2.0 * float(np.max(tol))
    fits: list[_Fit] = []
    for k in np.argsort(-coarse, kind="stable"):
        if fits:
            unmatched = len(camera_s) - fits[0].matched
            if coarse[k] < len(sample) - unmatched - MIN_UNMATCHED_MARGIN and len(fits) > 3:
                break
        fit = _refine(eo_sorted, order, camera_s, tol, float(proposals[k]), reference)
        same = [j for j, other in enumerate(fits) if abs(other.offset - fit.offset) <= separate]
        if same:  # two proposals refined to one offset: keep the better
            if fit.matched <= fits[same[0]].matched:
                continue
            del fits[same[0]]
        fits.append(fit)
        fits.sort(key=lambda f: -f.matched)  # stable: among equals the first refined
    return fits


def match_capture_times(camera_posix: np.ndarray, resolution_s: np.ndarray, eo_time: np.ndarray,
                        fixed_offset_s: float | None = None) -> ClockMatch:
    """Match photos to EO rows by capture time.

    ``camera_posix``: each photo's capture time on the camera's clock as POSIX seconds (a time without a zone read
    as UTC); ``resolution_s``: its resolution (1 s without sub-seconds); ``eo_time``: the EO table's ``time``
    [UTC s of its day; NaN rows are never matched]; ``fixed_offset_s``: camera clock minus UTC [s] when the user
    knows it (``--camera-clock-offset``): then nothing is searched but the day and the clock's drift (the pairs
    start from the given offset; the reported offset is the given one, the residuals are taken from it with the
    drift fitted), and the offsets a trigger interval either side are tried. Raises :class:`ClockMatchError` when no
    offset matches most photos, several match about equally, or a given offset matches fewer photos than one an
    interval away (it is off by about an interval)."""
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
        fits = [_refine(eo_sorted, order, camera_s, tol, fixed_offset_s + k * SECONDS_PER_DAY, reference)
                for k in (-1.0, 0.0, 1.0)]
        fits.sort(key=lambda f: -f.matched)
    else:
        fits = _search(eo_sorted, order, camera_s, tol, reference)
    fit = fits[0]
    matched = fit.matched
    if matched < max(2, len(camera_s) // 2):
        shown = f"{fit.offset:+.3f} s" if fixed_offset_s is None else f"the given {fixed_offset_s:+.3f} s"
        raise ClockMatchError(f"capture times: at most {matched} of {len(camera_s)} photos have an exposure within "
                              f"{CLOCK_TOLERANCE_S:.2f} s at any camera clock offset (best {shown}); are these the "
                              "flight's photos?")
    alternatives: list[OffsetFit] = []
    residual = fit.residual
    if fixed_offset_s is not None:
        alternatives = _check_given_offset(eo_sorted, order, camera_s, tol, fit, reference, fixed_offset_s)
        # residuals from the given offset (the fit's own are ~0 at mid-flight): their median shows how far off it is
        residual = fit.residual + (fit.offset - fit.proposal)
    else:
        alternatives = [OffsetFit(other.offset, other.matched) for other in fits[1:4]]
        rivals = [a for a in alternatives if a.matched > matched - MIN_UNMATCHED_MARGIN]
        if rivals:
            listed = ", ".join(f"{a.offset_s:+.3f} s ({a.matched})" for a in rivals)
            raise ClockMatchError(
                f"capture times: the match to the exposures is not unique — several camera clock offsets fit about "
                f"equally (drift fitted to each, best first): {fit.offset:+.3f} s ({matched} of {len(camera_s)} "
                f"photos within the tolerance), {listed} (regular triggering: offsets a trigger interval apart fit "
                "alike; georef does not guess)")
    ok = fit.frame >= 0
    # split the day off: the EO table's day starts at day0 + (the offset's whole days)
    best = fit.offset if fixed_offset_s is None else fit.proposal
    clock = ((best + HALF_DAY_S) % SECONDS_PER_DAY) - HALF_DAY_S if fixed_offset_s is None else fixed_offset_s
    day_start = day0 + round((best - clock) / SECONDS_PER_DAY) * SECONDS_PER_DAY
    return ClockMatch(offset_s=float(clock), drift_ppm=fit.drift * 1e6, reference_posix=reference + day0,
                      spread_s=float(np.std(residual[ok])) if ok.sum() > 1 else 0.0, frame_index=fit.frame,
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
