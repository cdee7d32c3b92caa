"""Geotagged copies of a flight's photos (``georef process ... --images SRC --export images:DIR``).

Every photo in ``SRC`` (``.jpg``, ``.jpeg``, ``.tif``, ``.tiff``, any case) is matched to a frame of the EO table
— by the ``image`` column of ``--image-names``, or by its capture time (:mod:`georef.io.image_match`) — and a
copy with the frame's geotags (:mod:`georef.io.image_tags`) is written to ``DIR``, each atomically
(:func:`georef.io.atomic.atomic_write`, inside the run's all-or-nothing group). The photos are only read.

Which photos get a copy (``docs/images.md``):

* a photo matched to a frame with a position and finite sigmas: a copy, also when the frame is **flagged** for
  a GNSS outage, inertial-only navigation at the ends, or an IMU gap — those flags mean a larger uncertainty,
  and the frame's sigmas already carry it (``georef.eo``), so the copy's accuracies tell Pix4D and ODM to weigh it
  less; its flag is in the table;
* no copy for a frame whose **position or time is in doubt beyond its sigmas**: outside the navigation span (no
  values), no valid sigma, a duplicate frame number (which exposure is this photo?), a time earlier than the
  previous frame's (the exposure time is suspect); and none for a photo without a frame. A copy without
  georef's tags would carry the drone's own position, a second source of another accuracy, into the project.

Every photo, copied or not, is a row of ``DIR/georef_images.csv`` with its status and reason, and the counts are
in the run's output; frames named for a photo that is not in ``SRC`` are counted and listed there too.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import re
import string
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from georef.eo import FLAG_DUPLICATE, FLAG_NO_SIGMA, FLAG_ORDER
from georef.frames.heights import EGM96_HEIGHT
from georef.frames.pix4d import Pix4dAngles, per_axis_sigma, pix4d_angles
from georef.io.atomic import atomic_write
from georef.io.errors import GeorefError, InputError
from georef.io.image_match import ClockMatch, ClockMatchError, match_capture_times, offset_from_pairs
from georef.io.image_tags import IMAGE_SUFFIXES, Geotag, SourceImage, read_source, tagged_copy

if TYPE_CHECKING:
    from georef.eo import EoColumns
    from georef.frames.heights import OutputFrames
    from georef.qc import Check

#: the table of every photo, written into DIR
REPORT_NAME = "georef_images.csv"
#: flags after which a frame's photo gets no tags (its position or time is in doubt beyond its sigmas)
UNTAGGED_FLAGS = (FLAG_DUPLICATE, FLAG_ORDER, FLAG_NO_SIGMA)
TAGGED = "tagged"
TAGGED_FLAGGED = "tagged, flagged"
NOT_TAGGED = "not tagged"
BY_NAME = "image names"
#: a named photo whose capture time is this far [s] from its frame's (after the median offset) is reported
NAMED_DISAGREES_S = 1.0
#: the largest camera clock offset [s] a time zone explains: UTC-12 to UTC+14, and an hour for a clock set by
#: hand or a summer time not switched; beyond it the flight's date is wrong (``--utc-date``) or the camera's
MAX_ZONE_OFFSET_S = 15 * 3600.0
#: fewer photos than this share of the folder's matched by name fails the images check (a wrong pattern or CSV);
#: fewer than all of them is a warning
NAMED_FAIL_SHARE = 0.5
BY_CAPTURE_TIME = "capture time"


class ImageExportError(GeorefError):
    """The image export cannot be done as asked (checked before processing where possible)."""


@dataclass(frozen=True)
class ImageRow:
    """One photo of ``SRC``: its frame (``""`` without one), status (:data:`TAGGED`, :data:`TAGGED_FLAGGED`,
    :data:`NOT_TAGGED`), the reason or flag, the copy written (``""`` without), the exposure's UTC time of day [s]
    and the capture time's residual after the clock offset [s] (NaN without)."""

    image: str
    frame: str
    status: str
    reason: str
    copy: str
    time_utc_s: float
    capture_residual_s: float


@dataclass
class ImageExport:
    """What ``--export images:DIR`` did: a row per photo, how photos were matched, the camera clock (``None``
    without capture times), the heights written, whether the date is known, frames named for missing photos."""

    source_dir: Path
    target_dir: Path
    method: str
    rows: list[ImageRow] = field(default_factory=list)
    clock: ClockMatch | None = None
    vertical_datum: str = f"EGM96 height ({EGM96_HEIGHT})"
    date_source: str | None = None
    frames_without_photo: list[str] = field(default_factory=list)

    def count(self, status: str) -> int:
        return sum(row.status == status for row in self.rows)

    def lines(self) -> list[str]:
        """The run's output about the copies."""
        not_tagged = [row for row in self.rows if row.status == NOT_TAGGED]
        reasons: dict[str, int] = {}
        for row in not_tagged:
            reasons[row.reason] = reasons.get(row.reason, 0) + 1
        flagged = [row for row in self.rows if row.status == TAGGED_FLAGGED]
        out = [f"images: {self.count(TAGGED) + len(flagged)} of {len(self.rows)} photos in {self.source_dir} copied "
               f"with geotags to {self.target_dir} (matched by {self.method}); altitude: {self.vertical_datum}, "
               f"WGS 84 latitude/longitude"]
        if flagged:
            out.append(f"images: {len(flagged)} copies are of flagged frames (their sigmas carry the flag; see "
                       f"{REPORT_NAME}): " + "; ".join(sorted({row.reason for row in flagged}))[:300])
        if not_tagged:
            out.append(f"images: {len(not_tagged)} photos not copied: "
                       + "; ".join(f"{n} {reason}" for reason, n in sorted(reasons.items(), key=lambda kv: -kv[1])))
        if self.frames_without_photo:
            shown = ", ".join(self.frames_without_photo[:8]) + (" ..." if len(self.frames_without_photo) > 8 else "")
            out.append(f"images: {len(self.frames_without_photo)} frames have no photo in {self.source_dir}: {shown}")
        off = [row.image for row in self.rows if abs(row.capture_residual_s) > NAMED_DISAGREES_S]
        if off and self.method == BY_NAME:
            out.append(f"images: warning: {len(off)} photos' capture times disagree with their named frame by more "
                       f"than {NAMED_DISAGREES_S:.0f} s after the camera clock offset ({', '.join(off[:5])}): check "
                       "--image-names")
        if self.clock is not None:
            drift = f", drift {self.clock.drift_ppm:+.1f} ppm" if self.clock.drift_ppm else ""
            given = " (given)" if self.clock.fixed else ""
            bias = ""
            if self.clock.fixed and self.clock.matched:
                bias = f", median residual {float(np.nanmedian(self.clock.residual_s)) * 1e3:+.1f} ms"
            out.append(f"images: camera clock minus UTC {self.clock.offset_s:+.3f} s{given}{drift}, spread "
                       f"{self.clock.spread_s:.3f} s{bias} over {self.clock.matched} photos")
            if self.clock.fixed and self.clock.alternatives:
                shown = ", ".join(f"{fit.offset_s:+.3f} s" for fit in self.clock.alternatives)
                out.append(f"images: warning: the offsets {shown} pair the photos with frames one or two exposures "
                           f"away and match as many photos ({self.clock.matched}): the pairing rests on the given "
                           "offset being right to within half the trigger interval")
        out.append("images: GPSDateStamp " + (f"from {self.date_source}" if self.date_source else
                                               "not written (the flight's UTC date is unknown: give --utc-date)"))
        return out

    def check(self) -> Check | None:
        """The QC check of a match by name (``None`` by capture time, whose match is refused below half): a fail
        when fewer than :data:`NAMED_FAIL_SHARE` of the folder's photos have a named frame, a warning when some
        photo has none or some named photo is missing."""
        from georef.qc import FAIL, PASS, WARN, Check

        if self.method != BY_NAME:
            return None
        unnamed = [row.image for row in self.rows if not row.frame]
        matched = len(self.rows) - len(unnamed)
        missing = self.frames_without_photo
        found = (f"{matched} of {len(self.rows)} photos in {self.source_dir} have a frame named by --image-names"
                 + (f"; {len(unnamed)} have none ({', '.join(unnamed[:3])}{' ...' if len(unnamed) > 3 else ''})"
                    if unnamed else "")
                 + (f"; {len(missing)} frames' named photos are not in the folder (frames {', '.join(missing[:3])}"
                    f"{' ...' if len(missing) > 3 else ''})" if missing else ""))
        if matched < NAMED_FAIL_SHARE * len(self.rows):
            return Check("images", FAIL, f"{found}. Most photos were left without geotags: check --image-names "
                         "(or image_names in flight.toml) against the folder's file names and the frame numbers")
        if unnamed or missing:
            return Check("images", WARN, f"{found}. See {REPORT_NAME}; if photos should have a frame, check "
                         "--image-names against the folder's file names")
        return Check("images", PASS, found)

    def to_dict(self) -> dict:
        """For the run's JSON summary."""
        clock = None if self.clock is None else {
            "offset_s": self.clock.offset_s, "drift_ppm": self.clock.drift_ppm, "spread_s": self.clock.spread_s,
            "matched": self.clock.matched, "given": self.clock.fixed,
            # a given offset's neighbours an interval away that match as many photos (the pairing rests on it)
            "equal_offsets_s": [fit.offset_s for fit in self.clock.alternatives] if self.clock.fixed else []}
        return {"source": str(self.source_dir), "target": str(self.target_dir), "matched_by": self.method,
                "photos": len(self.rows), "tagged": self.count(TAGGED), "tagged_flagged": self.count(TAGGED_FLAGGED),
                "not_tagged": self.count(NOT_TAGGED), "vertical_datum": self.vertical_datum,
                "date_source": self.date_source, "camera_clock": clock,
                "frames_without_photo": self.frames_without_photo}


def source_photos(source_dir: Path) -> list[Path]:
    """The photos of ``source_dir`` georef tags, by name."""
    return sorted(p for p in Path(source_dir).iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _name_matcher(image_names: str) -> tuple[str, Callable[[str, bool], bool]]:
    """What ``--image-names`` names (its text for messages) and a test of a file name against it, exact or
    ignoring case: a pattern's fields stand for any text, a CSV's names are taken as listed."""
    from georef.io.image_names import ImageNames

    names = ImageNames.parse(image_names)
    if names.pattern is not None:
        parts = [re.escape(literal) + (".+?" if field is not None else "")
                 for literal, field, _, _ in string.Formatter().parse(names.pattern)]
        exact, folded = re.compile("".join(parts)), re.compile("".join(parts), re.IGNORECASE)
        return names.source, lambda name, fold: bool((folded if fold else exact).fullmatch(name))
    listed = set(names.table.values())
    lowered = {name.lower() for name in listed}
    return names.source, lambda name, fold: (name.lower() in lowered) if fold else (name in listed)


def _no_photo_named(source_dir: Path, what: str, named: list[str], present: list[str], case_only: list[str]) -> str:
    """The message when no photo of the folder has a name that ``what`` gives."""
    hint = (f"; {len(case_only)} names differ only in case (e.g. {case_only[0]}): file names are matched exactly, "
            "so write the pattern's or the CSV's names as the files are named") if case_only else ""
    shown = f" (e.g. {', '.join(named[:3])})" if named else ""
    return (f"--images {source_dir}: none of its {len(present)} photos ({', '.join(present[:3])}"
            f"{' ...' if len(present) > 3 else ''}) has a name that --image-names {what} gives{shown}{hint}; "
            "no copy could be matched to a frame")


def check_image_export(source_dir: Path | None, target_dir: Path, frames: OutputFrames | None,
                       image_names: str | None = None) -> None:
    """Before processing: ``--images`` is a folder with photos, ``DIR`` is another folder (never the photos' own:
    the originals are never written), PROJ has the EGM96 grid for the altitudes, and with ``image_names`` (the
    ``--image-names`` pattern or CSV) at least one photo has a name it can give."""
    from georef.frames.heights import OutputFrames

    if source_dir is None:
        raise ImageExportError(f"--export images:{target_dir} copies the flight's photos: give their folder with "
                               "--images SRC_DIR")
    if not Path(source_dir).is_dir():
        raise InputError(source_dir, None, None, "--images: not a folder of photos")
    if not source_photos(source_dir):
        raise InputError(source_dir, None, None, f"--images: no photos ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    if target_dir.exists() and not target_dir.is_dir():
        raise ImageExportError(f"--export images:{target_dir}: exists and is not a folder")
    if target_dir.resolve() == Path(source_dir).resolve():
        raise ImageExportError(f"--export images:{target_dir} is the photos' own folder: georef never writes over the "
                               "originals; name another folder")
    (frames or OutputFrames()).egm96([45.0], [15.0], [0.0])  # the EGM96 grid is there, or GeoidGridError now
    if image_names:
        what, named = _name_matcher(image_names)
        present = [path.name for path in source_photos(source_dir)]
        if not any(named(name, False) for name in present):
            raise ImageExportError(_no_photo_named(Path(source_dir), what, [], present,
                                                   [name for name in present if named(name, True)]))


def _untagged_reason(flag: str, values: list[float]) -> str | None:
    for bad in UNTAGGED_FLAGS:
        if bad in flag:
            return f"frame flagged: {flag}"
    if not np.all(np.isfinite(values)):
        return f"frame not georeferenced: {flag}" if flag else "frame not georeferenced"
    return None


@dataclass(frozen=True)
class _PhotoMatch:
    """Per photo of ``SRC`` (in :func:`source_photos` order) the EO row it is matched to (-1: none) and the reason
    when none; the camera clock (``None`` without capture times)."""

    rows: np.ndarray
    reasons: list[str]
    clock: ClockMatch | None


def _match(photos: list[SourceImage], columns: EoColumns, fixed_offset_s: float | None,
           by_name: bool) -> _PhotoMatch:
    """Per photo the EO row (-1: none) and the reason when none, and the clock (when capture times exist)."""
    n = len(photos)
    rows = np.full(n, -1)
    reasons = [""] * n
    times = np.asarray(columns["time"], float)
    timed = [i for i, p in enumerate(photos) if p.capture is not None]
    posix = np.array([photos[i].capture.posix_s for i in timed])  # type: ignore[union-attr]
    resolution = np.array([photos[i].capture.resolution_s for i in timed])  # type: ignore[union-attr]
    clock = None
    if by_name:
        index: dict[str, int] = {}
        for row, name in enumerate(np.asarray(columns["image"], dtype=object)):
            index.setdefault(str(name), row)
        for i, photo in enumerate(photos):
            rows[i] = index.get(photo.path.name, -1)
            if rows[i] < 0:
                reasons[i] = "no frame is named for this photo (--image-names)"
        paired = [i for i in timed if rows[i] >= 0]
        if paired:
            pick = np.array([timed.index(i) for i in paired])
            clock = offset_from_pairs(posix[pick], resolution[pick], times[rows[paired]])
        return _PhotoMatch(rows, reasons, clock)
    if not timed:
        raise ClockMatchError(f"{photos[0].path.parent}: no photo has a capture time (EXIF DateTimeOriginal) to "
                              "match it to its frame", "Name the photos with --image-names")
    clock = match_capture_times(posix, resolution, times, fixed_offset_s)
    for k, i in enumerate(timed):
        rows[i] = clock.frame_index[k]
        if rows[i] < 0:
            reasons[i] = (f"no exposure within {clock.tolerance_s[k]:.3f} s of its capture time (camera clock minus "
                          f"UTC {clock.offset_s:+.3f} s)")
    for i, photo in enumerate(photos):
        if photo.capture is None:
            reasons[i] = f"{photo.capture_problem}: cannot be matched by capture time"
    return _PhotoMatch(rows, reasons, clock)


@dataclass(frozen=True)
class _FlightDay:
    """The flight's UTC day as settled between the log (or ``--utc-date``) and the photos: the camera clock (its
    offset [s] moved by whole days when the photos' day and the log's differ by a time zone; ``None`` without
    capture times), 00:00 UTC of the day [POSIX s] (``None``: unknown, no ``GPSDateStamp``) and what gave it."""

    clock: ClockMatch | None
    day_start_posix: float | None
    date_source: str | None


@dataclass(frozen=True)
class _FrameTags:
    """What the EO table gives each frame's copy: WGS 84 latitude, longitude [deg], altitude above EGM96 [m] (NaN
    without a position), horizontal 1-sigma per axis [m], Pix4D's yaw, pitch, roll [deg] and the frame's flags."""

    lat: np.ndarray
    lon: np.ndarray
    altitude: np.ndarray
    xy_sigma: np.ndarray
    angles: Pix4dAngles
    flags: np.ndarray


def _refuse_unnamed(photos: list[SourceImage], columns: EoColumns, source_dir: Path) -> None:
    """Refuse a match by name that gave no photo a frame (a wrong pattern or CSV), naming names that differ only
    in case."""
    present = [photo.path.name for photo in photos]
    named = [str(name) for name in np.asarray(columns["image"], dtype=object)]
    folded = {name.lower() for name in named}
    what = "(the EO table's image column) or flight.toml's image_names"
    raise ImageExportError(_no_photo_named(Path(source_dir), what, named, present,
                                           [name for name in present if name.lower() in folded]))


def _flight_day(photos: list[SourceImage], clock: ClockMatch | None, day_start_posix: float | None,
                date_source: str | None) -> _FlightDay:
    """The flight's day: the given one (checked against the photos' capture times, and the camera clock's
    offset counted from it), else the photos' own, else unknown."""
    if day_start_posix is None and clock is not None:
        return _FlightDay(clock, clock.day_start_posix, "the photos' capture times (camera clock within 12 h of UTC)")
    if day_start_posix is not None and clock is not None:
        _check_day(photos, clock, day_start_posix, date_source or "the flight's date")
        if not clock.fixed:
            # the photos' day and the log's agree but for the camera's time zone: the offset from the known day
            shift = clock.day_start_posix - day_start_posix
            clock = replace(clock, offset_s=clock.offset_s + shift, day_start_posix=day_start_posix)
    return _FlightDay(clock, day_start_posix, date_source)


def _frames_without_photo(photos: list[SourceImage], columns: EoColumns, rows: np.ndarray, by_name: bool
                          ) -> list[str]:
    """The frames no photo was matched to: by name, those whose named photo is not in the folder; by capture
    time, those with a time that no photo claimed."""
    if by_name:
        present = {p.path.name for p in photos}
        return [str(f) for f, name in zip(columns["frame"], columns["image"], strict=True) if str(name) not in present]
    claimed = set(rows[rows >= 0].tolist())
    return [str(columns["frame"][j]) for j in range(len(columns["time"]))
            if j not in claimed and np.isfinite(columns["time"][j])]


def _frame_tags(columns: EoColumns, frames: OutputFrames | None) -> _FrameTags:
    """The tags of every frame of the EO table, altitudes converted to EGM96 with ``frames`` where there is a
    position."""
    from georef.frames.heights import OutputFrames

    lat, lon, h = (np.asarray(columns[name], float) for name in ("lat", "lon", "height"))
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
    altitude = np.full(len(lat), np.nan)
    if ok.any():
        altitude[ok] = (frames or OutputFrames()).egm96(lat[ok], lon[ok], h[ok])
    return _FrameTags(lat=lat, lon=lon, altitude=altitude, xy_sigma=per_axis_sigma(columns["sigma_n"],
                      columns["sigma_e"]), angles=pix4d_angles(columns["roll"], columns["pitch"], columns["yaw"]),
                      flags=np.asarray(columns["flag"], dtype=object))


def _capture_residuals(photos: list[SourceImage], clock: ClockMatch | None, rows: np.ndarray, by_name: bool
                       ) -> np.ndarray:
    """Per photo its capture time's residual after the camera clock offset [s] (NaN without a capture time, or
    by name without a frame)."""
    residual = np.full(len(photos), np.nan)
    if clock is not None:
        timed = [i for i, p in enumerate(photos) if p.capture is not None and (not by_name or rows[i] >= 0)]
        residual[timed] = clock.residual_s[: len(timed)]
    return residual


def _copy_photo(photo: SourceImage, j: int, residual_s: float, columns: EoColumns, tags: _FrameTags,
                day_start_posix: float | None, target_dir: Path) -> ImageRow:
    """The photo's row for EO row ``j``: a tagged copy written into ``target_dir`` (atomically), or none when the
    frame's flag or missing values put its position or time in doubt (:func:`_untagged_reason`)."""
    frame, flag, time_s = str(columns["frame"][j]), str(tags.flags[j] or ""), float(columns["time"][j])
    values = [tags.lat[j], tags.lon[j], tags.altitude[j], tags.xy_sigma[j], columns["sigma_u"][j], columns["roll"][j],
              columns["pitch"][j], columns["yaw"][j], columns["sigma_roll"][j], columns["sigma_pitch"][j],
              columns["sigma_yaw"][j]]
    why = _untagged_reason(flag, values)
    if why is not None:
        return ImageRow(photo.path.name, frame, NOT_TAGGED, why, "", time_s, residual_s)
    angles = tags.angles
    tag = Geotag(lat=float(tags.lat[j]), lon=float(tags.lon[j]), altitude_m=float(tags.altitude[j]),
                 utc_posix=None if day_start_posix is None else day_start_posix + time_s,
                 utc_seconds_of_day=time_s,
                 angles=type(angles)(angles.yaw[j], angles.pitch[j], angles.roll[j]),
                 xy_accuracy_m=float(tags.xy_sigma[j]), z_accuracy_m=float(columns["sigma_u"][j]),
                 yaw_accuracy_deg=float(columns["sigma_yaw"][j]),
                 pitch_accuracy_deg=float(columns["sigma_pitch"][j]),
                 roll_accuracy_deg=float(columns["sigma_roll"][j]))
    copy = Path(target_dir) / photo.path.name
    data = tagged_copy(photo.path.read_bytes(), tag, photo.make, photo.path)
    with atomic_write(copy, "wb") as handle:
        handle.write(data)
    return ImageRow(photo.path.name, frame, TAGGED_FLAGGED if flag else TAGGED, flag, str(copy), time_s, residual_s)


def export_images(columns: EoColumns, source_dir: Path, target_dir: Path, frames: OutputFrames | None = None,
                  fixed_offset_s: float | None = None, day_start_posix: float | None = None,
                  date_source: str | None = None) -> ImageExport:
    """Match the photos of ``source_dir`` to the EO table ``columns`` and write their tagged copies and
    ``georef_images.csv`` into ``target_dir`` (created). ``fixed_offset_s``: camera clock minus UTC [s] when known;
    ``day_start_posix``: 00:00 UTC [POSIX s] of the EO table's day when the log or ``--utc-date`` gives it
    (``date_source`` says which); otherwise the photos' capture times give it, or no ``GPSDateStamp`` is written.
    Raises :class:`~georef.io.image_match.ClockMatchError` for an ambiguous capture-time match."""
    photos = [read_source(path) for path in source_photos(source_dir)]
    by_name = "image" in columns
    match = _match(photos, columns, fixed_offset_s, by_name)
    if by_name and not (match.rows >= 0).any():
        _refuse_unnamed(photos, columns, source_dir)
    day = _flight_day(photos, match.clock, day_start_posix, date_source)
    result = ImageExport(Path(source_dir), Path(target_dir), BY_NAME if by_name else BY_CAPTURE_TIME, clock=day.clock,
                         date_source=day.date_source,
                         frames_without_photo=_frames_without_photo(photos, columns, match.rows, by_name))
    tags = _frame_tags(columns, frames)
    residual = _capture_residuals(photos, day.clock, match.rows, by_name)
    Path(target_dir).mkdir(parents=True, exist_ok=True)
    for i, photo in enumerate(photos):
        j = int(match.rows[i])
        if j < 0:
            result.rows.append(ImageRow(photo.path.name, "", NOT_TAGGED, match.reasons[i], "", np.nan, residual[i]))
            continue
        result.rows.append(_copy_photo(photo, j, residual[i], columns, tags, day.day_start_posix, Path(target_dir)))
    _write_report(result)
    return result


def _utc_date(posix_s: float) -> str:
    return dt.datetime.fromtimestamp(posix_s, dt.UTC).date().isoformat()


def _check_day(photos: list[SourceImage], clock: ClockMatch, day_start_posix: float, date_source: str) -> None:
    """The flight's UTC date (the log's, or ``--utc-date``) and the photos' capture times agree to within a time
    zone: a camera clock more than :data:`MAX_ZONE_OFFSET_S` off UTC, or a given offset that puts the exposures
    on another day, means a wrong date, and every copy's GPSDateStamp would be wrong."""
    dates = sorted({_utc_date(p.capture.posix_s) for p in photos if p.capture is not None})
    taken = f"the photos were taken {' to '.join(dict.fromkeys([dates[0], dates[-1]]))} (camera clock)"
    flight = _utc_date(day_start_posix)
    if clock.fixed:
        if abs(clock.day_start_posix - day_start_posix) > 1.0:
            raise ImageExportError(
                f"{taken}: with the given camera clock offset {clock.offset_s:+.3f} s they were exposed on "
                f"{_utc_date(clock.day_start_posix)} UTC, and {date_source} says {flight}; check the date and "
                "--camera-clock-offset")
        return
    offset = clock.offset_s + clock.day_start_posix - day_start_posix
    if abs(offset) > MAX_ZONE_OFFSET_S:
        raise ImageExportError(
            f"{taken}, and {date_source} puts the flight on {flight} UTC: the camera clock would be "
            f"{offset:+.3f} s ({offset / 3600.0:+.1f} h) off UTC, beyond any time zone (at most "
            f"{MAX_ZONE_OFFSET_S / 3600.0:.0f} h); the date is wrong: check --utc-date (or the camera's date)")


def _write_report(result: ImageExport) -> None:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["image", "frame", "status", "reason", "time_utc_s", "capture_residual_s", "copy"])
    for row in result.rows:
        writer.writerow([row.image, row.frame, row.status, row.reason,
                         "" if not np.isfinite(row.time_utc_s) else f"{row.time_utc_s:.6f}",
                         "" if not np.isfinite(row.capture_residual_s) else f"{row.capture_residual_s:.4f}", row.copy])
    with atomic_write(result.target_dir / REPORT_NAME) as handle:
        handle.write(buffer.getvalue())
