"""Throughput of the hand-offs: geotagged image copies, RTKLIB .pos input, SBET + smrmsg output, ROS bag input.

Every figure is the median of ``--repeats`` timed runs after one untimed warm-up run (files in the page cache,
numba kernels compiled), on data built here in a temporary folder:

1. image copies (``--export images:DIR``): :func:`georef.io.image_export.export_images` end to end, per photo, for
   small (64x48) and realistic (4000x3000, about 5 MB of noisy JPEG) photos, with its parts (EXIF read, tagging
   in memory, atomic write) and a plain file copy as the floor; capture-time matching
   (:func:`georef.io.image_match.match_capture_times`) for 300 and 3000 photos, triggered regularly (the
   search ends in the "not unique" error, as it must) and irregularly, and with a given camera clock offset;
2. RTKLIB .pos: :func:`georef.io.rtklib.read_pos_solution` and :func:`~georef.io.rtklib.read_rtklib_gnss` per
   epoch on a 1 h 5 Hz file made from the fixtures' lines (tests/data/rtklib, times advanced consistently), in four
   layouts, and on every fixture as it is (20 epochs: the header and set-up dominate);
3. SBET + smrmsg: :func:`georef.io.sbet.write_sbet` per record at the IMU's 200 Hz for a simulated 15 min flight
   (processed with ``--method rts``), and its two parts (records, writing);
4. ROS bags: :func:`georef.io.rosbag.read_bag` per IMU message for a 10 min 200 Hz IMU + 5 Hz NavSatFix bag written
   with rosbags as ROS 1, ROS 2 sqlite3 and ROS 2 mcap, beside rosbags' own iteration of the raw messages.

Usage: GEOREF_KERNELS=jit python benchmarks/handoffs.py [--quick] [--repeats 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import datetime as dt
import io
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from georef.config import load_config
from georef.io.atomic import atomic_write
from georef.io.image_export import TAGGED, export_images
from georef.io.image_match import ClockMatchError, match_capture_times
from georef.io.image_tags import Geotag, read_source, tagged_copy
from georef.io.rosbag import read_bag
from georef.io.rtklib import read_pos_solution, read_rtklib_gnss
from georef.io.sbet import imu_rows_of_log, sbet_records, write_sbet
from georef.pipeline import process
from georef.sim.files import write_flight
from georef.sim.flight import SimConfig, simulate
from georef.sim.trajectory import FlightPlan

RTKLIB_FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "data" / "rtklib"
#: the fixtures made long: one per position layout, and the geoid-height one (a PROJ grid conversion)
LONG_POS_FIXTURES = ("llh_deg_gpst_ell.pos", "llh_dms_gpst_ell.pos", "xyz_gpst.pos", "llh_deg_gpst_geo.pos")
#: the flight's UTC date (the EO table's and the SBET's times count from its 00:00)
DAY = dt.datetime(2025, 6, 14, tzinfo=dt.UTC).timestamp()
#: the ROS bags' clock: Unix seconds (a wall clock) at the bag's start
BAG_START_UNIX = 1_795_996_800.0
G = 9.80665


@dataclass
class Figure:
    """One line of the summary table: what was timed, the figure, its unit, and what it means."""

    section: str
    name: str
    value: float
    unit: str
    meaning: str
    #: the timed runs' (slowest - fastest) / median, None for a figure derived from several timings
    spread: float | None = None


@dataclass
class Sizes:
    """How much data each section builds (``--quick`` shrinks it)."""

    flight_minutes: float
    small_photos: int
    large_photos: int
    match_sizes: tuple[int, ...]
    pos_hours: float
    bag_minutes: float


FULL = Sizes(flight_minutes=15.0, small_photos=100, large_photos=6, match_sizes=(300, 3000), pos_hours=1.0,
             bag_minutes=10.0)
QUICK = Sizes(flight_minutes=3.0, small_photos=20, large_photos=2, match_sizes=(300, 1000), pos_hours=0.1,
              bag_minutes=1.0)


class Timing(float):
    """A median wall time [s] that also carries ``spread``: (slowest - fastest run) / median, the run-to-run
    scatter (large on a shared, loaded machine)."""

    spread: float

    def __new__(cls, times: list[float]) -> Timing:
        middle = statistics.median(times)
        timing = super().__new__(cls, middle)
        timing.spread = (max(times) - min(times)) / middle if middle > 0 else 0.0
        return timing


def median_time(run: Callable[[], object], repeats: int, warm_up: bool = True,
                before: Callable[[], object] | None = None) -> Timing:
    """Median wall time [s] of ``repeats`` calls of ``run`` (``before`` runs untimed ahead of each call)."""
    if warm_up:
        if before is not None:
            before()
        run()
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return Timing(times)


def _version(package: str) -> str:
    try:
        return version(package)
    except PackageNotFoundError:
        return "not installed"


def machine_lines() -> list[str]:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return [f"machine: {cpu}, nproc {usable} (cpu_count {os.cpu_count()}), load average {load}",
            f"python {platform.python_version()} ({platform.python_implementation()}), numpy {np.__version__}, "
            f"Pillow {_version('pillow')}, pyexiv2 {_version('pyexiv2')}, rosbags {_version('rosbags')}, "
            f"numba {_version('numba')}",
            f"GEOREF_KERNELS={os.environ.get('GEOREF_KERNELS', '(unset)')}"]


# --- the flight: an EO table for the image copies, a navigation solution for the SBET ---------------------------
@dataclass
class Flight:
    result: object
    seconds: float
    rows: int


def simulated_flight(folder: Path, minutes: float) -> Flight:
    """A simulated fixed-wing flight of ``minutes`` at 200 Hz, processed with ``--method rts``."""
    start = time.perf_counter()
    flight = simulate(SimConfig(plan=FlightPlan(duration_s=minutes * 60.0), pos_rate_hz=200.0))
    write_flight(flight, folder)
    rows = len(flight.pos)
    del flight
    cfg = load_config(folder / "flight.toml").updated(method="rts")
    result = process(folder / "POS.txt", folder / "Kamera.txt", cfg)
    return Flight(result=result, seconds=time.perf_counter() - start, rows=rows)


# --- 1. image copies ---------------------------------------------------------------------------------------------
def _exif_time(posix: float) -> tuple[str, str]:
    moment = dt.datetime.fromtimestamp(posix, tz=dt.UTC)
    return moment.strftime("%Y:%m:%d %H:%M:%S"), f"{moment.microsecond // 1000:03d}"


def small_jpeg(path: Path, capture_posix: float, rng: np.random.Generator) -> None:
    """A 64x48 noise JPEG with EXIF Make and capture time (camera clock on UTC, no zone)."""
    from PIL import Image

    exif = Image.Exif()
    exif[0x010F] = "SONY"
    sub = exif.get_ifd(0x8769)
    sub[0x9003], sub[0x9291] = _exif_time(capture_posix)  # DateTimeOriginal, SubSecTimeOriginal
    pixels = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "JPEG", quality=90, exif=exif.tobytes())
    path.write_bytes(buffer.getvalue())


def large_jpeg(capture_posix: float, rng: np.random.Generator) -> bytes:
    """A 4000x3000 JPEG of about 5 MB: colour gradients under Gaussian noise (sigma 24 grey levels), quality 85,
    so that it does not compress to almost nothing as a flat image would; EXIF Make and capture time."""
    from PIL import Image

    exif = Image.Exif()
    exif[0x010F] = "SONY"
    sub = exif.get_ifd(0x8769)
    sub[0x9003], sub[0x9291] = _exif_time(capture_posix)
    y, x = np.mgrid[0:3000, 0:4000].astype(np.float32)
    base = np.stack([x / 4000 * 200 + 30, y / 3000 * 200 + 30, (x + y) / 7000 * 200 + 30], axis=-1)
    pixels = np.clip(base + rng.normal(0.0, 24.0, base.shape).astype(np.float32), 0, 255).astype(np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "JPEG", quality=85, exif=exif.tobytes())
    return buffer.getvalue()


def with_capture_time(data: bytes, capture_posix: float) -> bytes:
    """``data`` (a JPEG) with another EXIF capture time (the pixels untouched)."""
    import pyexiv2

    stamp, subsec = _exif_time(capture_posix)
    with pyexiv2.ImageData(data) as image:
        image.modify_exif({"Exif.Photo.DateTimeOriginal": stamp, "Exif.Photo.SubSecTimeOriginal": subsec})
        return image.get_bytes()


def eo_subset(columns: dict[str, np.ndarray], count: int) -> dict[str, np.ndarray]:
    """The first ``count`` unflagged, georeferenced frames of the EO table, each named for a photo."""
    flags = np.asarray(columns["flag"], dtype=str)
    ok = np.flatnonzero((flags == "") & np.isfinite(np.asarray(columns["lat"], float)))
    if len(ok) < count:
        raise SystemExit(f"the simulated flight has {len(ok)} clean frames, fewer than the {count} photos asked for")
    rows = ok[:count]
    subset = {name: np.asarray(values)[rows] for name, values in columns.items() if name != "image"}
    subset["image"] = np.array([f"IMG_{k:05d}.JPG" for k in range(count)], dtype=object)
    return subset


def bench_image_copies(kind: str, src: Path, out_root: Path, columns: dict[str, np.ndarray], frames: object,
                       repeats: int, figures: list[Figure]) -> None:
    """export_images end to end on the photos of ``src`` (named for the EO rows), and its parts on one photo."""
    photos = sorted(src.iterdir())
    target = out_root / f"copies_{kind}"

    def clean() -> None:
        shutil.rmtree(target, ignore_errors=True)

    result = None

    def run() -> None:
        nonlocal result
        result = export_images(columns, src, target, frames=frames, day_start_posix=DAY, date_source="benchmark")

    total = median_time(run, repeats, before=clean)
    assert result is not None and result.count(TAGGED) == len(photos), "every photo must be copied with geotags"
    size_mb = photos[0].stat().st_size / 1e6
    size_text = f"{size_mb:.2f} MB" if size_mb >= 1 else f"{1e3 * size_mb:.1f} kB"
    per_photo_ms = 1e3 * total / len(photos)
    print(f"  {kind}: {len(photos)} photos of {size_text}: export {total:.3f} s, {per_photo_ms:.2f} ms/photo "
          f"({len(photos) / total:.1f} photos/s, {len(photos) * size_mb / total:.0f} MB/s)")
    figures.append(Figure("images", f"copy + tag, {kind} photo", per_photo_ms, "ms/photo",
                          f"export_images end to end per photo ({size_text} JPEG): EXIF read, tags written in "
                          "memory, atomic write (fsync), georef_images.csv", total.spread))

    # its parts, on the first photo
    one = photos[0]
    data = one.read_bytes()
    source = read_source(one)
    j = 0
    tag = Geotag(lat=float(columns["lat"][j]), lon=float(columns["lon"][j]), altitude_m=float(columns["height"][j]),
                 utc_posix=DAY + float(columns["time"][j]), utc_seconds_of_day=float(columns["time"][j]),
                 angles=_angles(columns, j), xy_accuracy_m=float(columns["sigma_n"][j]),
                 z_accuracy_m=float(columns["sigma_u"][j]), yaw_accuracy_deg=float(columns["sigma_yaw"][j]),
                 pitch_accuracy_deg=float(columns["sigma_pitch"][j]), roll_accuracy_deg=float(columns["sigma_roll"][j]))
    tagged = tagged_copy(data, tag, source.make, one)
    scratch = out_root / f"part_{kind}"
    scratch.mkdir(exist_ok=True)

    def write_atomic() -> None:
        with atomic_write(scratch / one.name, "wb") as handle:
            handle.write(tagged)

    parts = {
        "read capture time (read_source)": median_time(lambda: read_source(one), repeats * 3),
        "tag in memory (tagged_copy)": median_time(lambda: tagged_copy(data, tag, source.make, one), repeats * 3),
        "atomic write of the copy": median_time(write_atomic, repeats * 3),
        "plain file copy (shutil.copyfile), the floor": median_time(
            lambda: shutil.copyfile(one, scratch / "plain.jpg"), repeats * 3),
    }
    for name, seconds in parts.items():
        print(f"    {name:<46} {1e3 * seconds:8.3f} ms")
    figures.append(Figure("images", f"  of which tagging in memory, {kind}",
                          1e3 * parts["tag in memory (tagged_copy)"], "ms/photo",
                          "pyexiv2 reads the photo's bytes, replaces the GPS IFD and XMP, returns the copy",
                          parts["tag in memory (tagged_copy)"].spread))
    figures.append(Figure("images", f"  of which the atomic write, {kind}", 1e3 * parts["atomic write of the copy"],
                          "ms/photo", "atomic_write of the tagged copy: temporary file, fsync, rename, fsync of the "
                          "folder", parts["atomic write of the copy"].spread))
    figures.append(Figure("images", f"  plain file copy, {kind}",
                          1e3 * parts["plain file copy (shutil.copyfile), the floor"], "ms/photo",
                          "shutil.copyfile of the same photo (no fsync): what any copy costs on this disk",
                          parts["plain file copy (shutil.copyfile), the floor"].spread))


def _angles(columns: dict[str, np.ndarray], j: int):
    from georef.frames.pix4d import pix4d_angles

    angles = pix4d_angles(columns["roll"][j:j + 1], columns["pitch"][j:j + 1], columns["yaw"][j:j + 1])
    return type(angles)(angles.yaw[0], angles.pitch[0], angles.roll[0])


def trigger_times(count: int, regular: bool, rng: np.random.Generator) -> np.ndarray:
    """Exposure times [UTC s of day]: every 2.0 s (regular, as an intervalometer; 2 ms jitter), or distance
    triggering at a changing speed (1.2 .. 3.0 s) with a 20 .. 60 s pause in each turn (every 40 .. 80 photos)."""
    start = 36000.0
    if regular:
        return start + 2.0 * np.arange(count) + rng.normal(0.0, 0.002, count)
    steps = rng.uniform(1.2, 3.0, count)
    turns = np.cumsum(rng.integers(40, 81, count))
    steps[turns[turns < count]] += rng.uniform(20.0, 60.0, int(np.sum(turns < count)))
    steps[0] = 0.0
    return start + np.cumsum(steps)


@dataclass
class MatchOutcome:
    """What one matching call gave: ``text`` for the detail line, ``short`` for the table."""

    text: str
    short: str


def _match_outcome(match_call: Callable[[], object], count: int) -> MatchOutcome:
    """The offset, drift and how many photos are on their own frame, or the error (its finding, cut short)."""
    try:
        match = match_call()
    except ClockMatchError as exc:
        finding = str(getattr(exc, "finding", exc))
        short = ("ClockMatchError, not unique" if "not unique" in finding else
                 "ClockMatchError, given offset refused" if "given camera clock offset" in finding else
                 "ClockMatchError")
        return MatchOutcome("ClockMatchError: " + (finding[:237] + "..." if len(finding) > 240 else finding), short)
    on_frame = int(np.sum(match.frame_index == np.arange(count)))
    return MatchOutcome(f"offset {match.offset_s:+.3f} s, drift {match.drift_ppm:+.1f} ppm, {on_frame} of {count} "
                        "photos on their own frame", f"{on_frame}/{count} photos on their own frame")


def bench_matching(sizes: tuple[int, ...], repeats: int, figures: list[Figure]) -> None:
    """match_capture_times on a camera on UTC+2 (no zone tag), 0.317 s fast and running 25 ppm fast: searched, and
    (regular triggering) with the offset given as --camera-clock-offset. Each call's outcome is printed as it is."""
    rng = np.random.default_rng(25)
    offset, drift = 7200.0 + 0.317, 25e-6
    for count in sizes:
        for regular in (False, True):
            eo_time = trigger_times(count, regular, rng)
            camera = DAY + eo_time + offset + drift * (eo_time - eo_time.mean()) + rng.normal(0.0, 0.002, count)
            camera = np.floor(camera * 1000.0) / 1000.0  # SubSecTimeOriginal in ms, truncated
            resolution = np.full(count, 1e-3)
            label = "regular" if regular else "irregular"
            calls = {"search": lambda eo_time=eo_time, camera=camera, resolution=resolution: match_capture_times(
                camera, resolution, eo_time)}
            if regular:
                calls["given offset"] = (lambda eo_time=eo_time, camera=camera, resolution=resolution:
                                         match_capture_times(camera, resolution, eo_time, fixed_offset_s=offset))
            for how, call in calls.items():
                outcome: list[MatchOutcome] = []

                def run(call=call, outcome=outcome, count=count) -> None:
                    outcome[:] = [_match_outcome(call, count)]

                seconds = median_time(run, repeats, warm_up=how != "search")
                print(f"  {count:5d} photos, {label:9s} triggering, {how:<12}: {1e3 * seconds:9.1f} ms "
                      f"({1e6 * seconds / count:7.1f} us/photo): {outcome[0].text}")
                meaning = ("match_capture_times without a known offset: 7 anchor photos x every frame proposed, "
                           "clustered, scored on 200 sampled photos, refined (drift fitted) while they can rival "
                           "the best" if how == "search" else
                           "match_capture_times with --camera-clock-offset: drift fitted, and the neighbouring "
                           "offsets refined alike")
                figures.append(Figure("matching", f"{how}, {count} photos, {label}", 1e3 * seconds, "ms",
                                      f"{meaning}; outcome: {outcome[0].short}", seconds.spread))


# --- 2. RTKLIB .pos ----------------------------------------------------------------------------------------------
def long_pos(fixture: Path, target: Path, hours: float, rate_hz: float = 5.0) -> int:
    """``fixture`` made ``hours`` long at ``rate_hz``: its header, then its data lines repeated in turn with the
    time advanced by 1/rate_hz each line, written in the fixture's own time format. Returns the epochs written."""
    lines = fixture.read_text().splitlines()
    header = [line for line in lines if line.startswith("%")]
    data = [line for line in lines if line.strip() and not line.startswith("%")]
    first = data[0].split()
    count = int(round(hours * 3600.0 * rate_hz))
    body = []
    if "/" in first[0]:  # yyyy/mm/dd hh:mm:ss.sss
        width = len(first[0]) + 1 + len(first[1])
        t0 = dt.datetime.strptime(f"{first[0]} {first[1]}", "%Y/%m/%d %H:%M:%S.%f")
        for k in range(count):
            moment = t0 + dt.timedelta(microseconds=round(k * 1e6 / rate_hz))
            body.append(moment.strftime("%Y/%m/%d %H:%M:%S.%f")[:-3] + data[k % len(data)].lstrip()[width:])
    else:  # GPS week and seconds of week
        week, sow = int(first[0]), float(first[1])
        for k in range(count):
            line = data[k % len(data)].lstrip()
            rest = line[len(line.split()[0]):].lstrip()
            rest = rest[len(rest.split()[0]):]
            body.append(f"{week} {sow + k / rate_hz:.3f}{rest}")
    target.write_text("\n".join(header + body) + "\n")
    return count


def bench_rtklib(folder: Path, hours: float, repeats: int, figures: list[Figure]) -> None:
    for name in LONG_POS_FIXTURES:
        target = folder / f"long_{name}"
        epochs = long_pos(RTKLIB_FIXTURES / name, target, hours)
        solution = read_pos_solution(target)
        assert len(solution) == epochs, f"{target}: {len(solution)} epochs read of {epochs}"
        parse = median_time(lambda target=target: read_pos_solution(target), repeats)
        gnss = median_time(lambda target=target: read_rtklib_gnss(target), repeats)
        size_mb = target.stat().st_size / 1e6
        print(f"  {name:<24} {epochs} epochs ({size_mb:.1f} MB): read_pos_solution {1e6 * parse / epochs:6.2f} "
              f"us/epoch, read_rtklib_gnss {1e6 * gnss / epochs:6.2f} us/epoch ({gnss:.2f} s)")
        figures.append(Figure("rtklib", f"long {name} ({hours:g} h, 5 Hz)", 1e6 * gnss / epochs, "us/epoch",
                              "read_rtklib_gnss per epoch: parse, times to UTC, NED covariances, floors, jump check",
                              gnss.spread))
        figures.append(Figure("rtklib", "  of which parsing (read_pos_solution)", 1e6 * parse / epochs, "us/epoch",
                              "read_pos_solution per epoch: the text, times to UTC, positions and NED covariances",
                              parse.spread))
    per_file = []
    for path in sorted(RTKLIB_FIXTURES.glob("*.pos")):
        epochs = len(read_pos_solution(path)) + len(read_pos_solution(path).invalid_mark_line)
        seconds = median_time(lambda path=path: read_pos_solution(path), repeats * 3)
        per_file.append((path.name, epochs, seconds))
        print(f"  fixture {path.name:<28} {epochs:3d} epochs: {1e3 * seconds:6.2f} ms, "
              f"{1e6 * seconds / epochs:7.1f} us/epoch")
    median_file = statistics.median(s for _, _, s in per_file)
    median_epoch = statistics.median(s / n for _, n, s in per_file)
    figures.append(Figure("rtklib", f"fixtures ({len(per_file)} files, 10-20 epochs)", 1e6 * median_epoch, "us/epoch",
                          f"read_pos_solution on the fixtures as they are (median; {1e3 * median_file:.2f} ms a file): "
                          "the header and set-up dominate"))


# --- 3. SBET + smrmsg --------------------------------------------------------------------------------------------
def bench_sbet(flight: Flight, folder: Path, minutes: float, repeats: int, figures: list[Figure]) -> None:
    result = flight.result
    imu = imu_rows_of_log(result.log)
    nav = result.nav
    target = folder / "sbet_flight.out"
    export = write_sbet(nav, imu, target, DAY)
    records = len(export.records.sbet)
    total = median_time(lambda: write_sbet(nav, imu, target, DAY), repeats)
    build = median_time(lambda: sbet_records(nav, imu, DAY), repeats)
    sizes = target.stat().st_size + export.smrmsg_path.stat().st_size
    rate = 1.0 / float(np.median(np.diff(nav.time)))
    print(f"  {minutes:g} min flight at {rate:.0f} Hz, method {nav.method}: {records} records "
          f"({sizes / 1e6:.1f} MB SBET + smrmsg)")
    print(f"    write_sbet {total:.3f} s = {1e6 * total / records:.2f} us/record; of which the records "
          f"(GPS time, wander frame, body accelerations, RMS) {1e6 * build / records:.2f} us/record, writing both "
          f"files {1e6 * (total - build) / records:.2f} us/record")
    figures.append(Figure("sbet", f"SBET + smrmsg, {minutes:g} min at {rate:.0f} Hz", 1e6 * total / records,
                          "us/record", f"write_sbet per record ({records} records): both files, atomically",
                          total.spread))
    figures.append(Figure("sbet", "  of which building the records", 1e6 * build / records, "us/record",
                          "sbet_records: GPS time, wander-frame velocity, body accelerations, smrmsg RMS",
                          build.spread))


# --- 4. ROS bags -------------------------------------------------------------------------------------------------
def _imu_signals(times: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Angular rate [rad/s] and specific force [m/s^2] on REP 103 axes (forward-left-up) of a level vehicle
    swaying gently: +g on the up axis, noise as a MEMS IMU's."""
    n = len(times)
    rate = np.column_stack([0.05 * np.sin(0.7 * times), 0.04 * np.sin(0.5 * times), 0.02 * np.cos(0.1 * times)])
    rate += rng.normal(0.0, 0.003, (n, 3))
    force = np.column_stack([0.3 * np.sin(0.2 * times), 0.2 * np.cos(0.3 * times), np.full(n, G)])
    force += rng.normal(0.0, 0.05, (n, 3))
    return rate, force


def write_bags(folder: Path, minutes: float) -> tuple[dict[str, Path], int, float]:
    """The same 200 Hz IMU + 5 Hz NavSatFix recording as a ROS 1 bag and ROS 2 bags (sqlite3, mcap). Returns the
    bags, the IMU message count and the seconds the writing took."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    start = time.perf_counter()
    rng = np.random.default_rng(7)
    imu_t = BAG_START_UNIX + np.arange(int(round(minutes * 60 * 200))) / 200.0
    rate, force = _imu_signals(imu_t - BAG_START_UNIX, rng)
    gnss_t = BAG_START_UNIX + np.arange(int(round(minutes * 60 * 5))) / 5.0
    # a straight drive north at 15 m/s
    lat = 45.8 + 15.0 * (gnss_t - BAG_START_UNIX) / 111_320.0
    cov_enu = np.diag([0.02**2, 0.02**2, 0.05**2]).ravel()
    bags = {"ROS 1": folder / "flight.bag", "ROS 2 sqlite3": folder / "flight_db3",
            "ROS 2 mcap": folder / "flight_mcap"}
    for ros1 in (True, False):
        store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        t = store.types
        serialize = store.serialize_ros1 if ros1 else store.serialize_cdr

        def header(seconds: float, frame_id: str, ros1=ros1, t=t):
            whole = int(np.floor(seconds))
            stamp = t["builtin_interfaces/msg/Time"](sec=whole, nanosec=int(round((seconds - whole) * 1e9)) % 10**9)
            return (t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id) if ros1 else
                    t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id))

        vector, quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
        absent = np.zeros(9)
        absent[0] = -1.0
        records: list[tuple[int, str, bytes]] = []
        for k, seconds in enumerate(imu_t):
            message = t["sensor_msgs/msg/Imu"](
                header=header(float(seconds), "imu_link"), orientation=quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=absent, angular_velocity=vector(x=rate[k, 0], y=rate[k, 1], z=rate[k, 2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vector(x=force[k, 0], y=force[k, 1], z=force[k, 2]),
                linear_acceleration_covariance=np.zeros(9))
            records.append((int(round((seconds + 0.004) * 1e9)), "/imu/data", serialize(message, message.__msgtype__)))
        for k, seconds in enumerate(gnss_t):
            message = t["sensor_msgs/msg/NavSatFix"](
                header=header(float(seconds), "gps"), status=t["sensor_msgs/msg/NavSatStatus"](status=2, service=1),
                latitude=float(lat[k]), longitude=15.97, altitude=120.0, position_covariance=cov_enu,
                position_covariance_type=2)
            records.append((int(round((seconds + 0.030) * 1e9)), "/gps/fix", serialize(message, message.__msgtype__)))
        records.sort(key=lambda r: r[0])
        plugins = [None] if ros1 else [StoragePlugin.SQLITE3, StoragePlugin.MCAP]
        for plugin in plugins:
            if ros1:
                writer = Writer1(bags["ROS 1"])
            else:
                path = bags["ROS 2 mcap" if plugin == StoragePlugin.MCAP else "ROS 2 sqlite3"]
                writer = Writer2(path, version=9, storage_plugin=plugin)
            with writer:
                connections = {"/imu/data": writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store),
                               "/gps/fix": writer.add_connection("/gps/fix", "sensor_msgs/msg/NavSatFix",
                                                                 typestore=store)}
                for stamp_ns, topic, raw in records:
                    writer.write(connections[topic], stamp_ns, raw)
    return bags, len(imu_t), time.perf_counter() - start


def _raw_iteration(bag: Path) -> int:
    """rosbags' own iteration of every message's bytes, without deserialising (the floor of any reader)."""
    from rosbags.highlevel import AnyReader

    count = 0
    with AnyReader([bag]) as reader:
        for _connection, _stamp, raw in reader.messages():
            count += len(raw) > 0
    return count


def bench_bags(folder: Path, minutes: float, repeats: int, figures: list[Figure]) -> None:
    bags, imu_messages, seconds = write_bags(folder, minutes)
    print(f"  {minutes:g} min, {imu_messages} IMU messages at 200 Hz + {int(minutes * 60 * 5)} fixes at 5 Hz, "
          f"written as 3 bags in {seconds:.1f} s (set-up, not timed below)")
    for kind, bag in bags.items():
        inputs = read_bag(bag)
        assert len(inputs.time) == imu_messages and len(inputs.gnss.time) == int(round(minutes * 60 * 5)), kind
        read = median_time(lambda bag=bag: read_bag(bag), repeats)
        raw = median_time(lambda bag=bag: _raw_iteration(bag), repeats)
        size = sum(p.stat().st_size for p in bag.iterdir()) if bag.is_dir() else bag.stat().st_size
        print(f"  {kind:<14} ({size / 1e6:5.1f} MB, read as {inputs.kind!r}): read_bag {read:.3f} s = "
              f"{1e6 * read / imu_messages:5.2f} us/IMU message; rosbags' raw iteration "
              f"{1e6 * raw / imu_messages:5.2f} us/message")
        figures.append(Figure("bags", f"read_bag, {kind}", 1e6 * read / imu_messages, "us/IMU msg",
                              f"read_bag per IMU message ({imu_messages} IMU + 5 Hz fixes): both topics decoded, "
                              "FLU to FRD, stamps, range and jump checks", read.spread))
        figures.append(Figure("bags", f"  rosbags raw iteration, {kind}", 1e6 * raw / imu_messages, "us/IMU msg",
                              "AnyReader.messages() over every message's bytes, nothing decoded: the floor",
                              raw.spread))


# --- the run -----------------------------------------------------------------------------------------------------
def print_table(figures: list[Figure]) -> None:
    name_width = max(len(f.name) for f in figures)
    print()
    print(f"{'section':<9} {'figure':<{name_width}} {'median':>10} {'unit':<11} {'range':>6}  meaning")
    print("-" * (name_width + 48))
    for f in figures:
        spread = "" if f.spread is None else f"{100 * f.spread:5.0f}%"
        print(f"{f.section:<9} {f.name:<{name_width}} {f.value:>10.2f} {f.unit:<11} {spread:>6}  {f.meaning}")
    print("range: (slowest - fastest timed run) / median; the machine is shared, so compare figures within a run")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smaller data everywhere (a smoke run, under a minute)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per figure (median reported)")
    parser.add_argument("--keep", type=Path, default=None, help="build the data in this folder and keep it")
    args = parser.parse_args()
    sizes = QUICK if args.quick else FULL
    wall = time.perf_counter()
    for line in machine_lines():
        print(line)
    print(f"sizes: {'quick' if args.quick else 'full'}; median of {args.repeats} timed runs after one warm-up")
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        folder = args.keep
    else:
        folder = Path(tempfile.mkdtemp(prefix="georef-handoffs-"))
    figures: list[Figure] = []
    try:
        flight = simulated_flight(folder / "flight", sizes.flight_minutes)
        columns = flight.result.columns
        print(f"\nset-up: simulated {sizes.flight_minutes:g} min at 200 Hz ({flight.rows} rows, "
              f"{len(columns['time'])} frames), processed with rts, in {flight.seconds:.1f} s")

        print("\n1. geotagged image copies (export_images, matched by --image-names)")
        rng = np.random.default_rng(11)
        small = eo_subset(columns, sizes.small_photos)
        src = folder / "photos_small"
        src.mkdir(exist_ok=True)
        for k in range(sizes.small_photos):
            small_jpeg(src / small["image"][k], DAY + float(small["time"][k]), rng)
        bench_image_copies("64x48", src, folder, small, flight.result.frames, args.repeats, figures)
        start = time.perf_counter()
        large = eo_subset(columns, sizes.large_photos)
        data = large_jpeg(DAY + float(large["time"][0]), rng)
        src = folder / "photos_large"
        src.mkdir(exist_ok=True)
        for k in range(sizes.large_photos):
            (src / large["image"][k]).write_bytes(with_capture_time(data, DAY + float(large["time"][k])))
        print(f"  (made {sizes.large_photos} 4000x3000 photos of {len(data) / 1e6:.2f} MB in "
              f"{time.perf_counter() - start:.1f} s)")
        bench_image_copies("4000x3000", src, folder, large, flight.result.frames, args.repeats, figures)
        print("  capture-time matching (match_capture_times; 1 ms sub-seconds, 2 ms jitter, 25 ppm drift)")
        bench_matching(sizes.match_sizes, args.repeats, figures)

        print("\n2. RTKLIB .pos input")
        bench_rtklib(folder, sizes.pos_hours, args.repeats, figures)

        print("\n3. SBET + smrmsg export")
        bench_sbet(flight, folder, sizes.flight_minutes, args.repeats, figures)

        print("\n4. ROS bags (read_bag)")
        bench_bags(folder, sizes.bag_minutes, args.repeats, figures)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    print_table(figures)
    print()
    for line in machine_lines()[:1]:
        print(line.replace("machine:", "at the end:"))
    print(f"benchmark wall time {time.perf_counter() - wall:.0f} s (set-up included); {sys.executable}")


if __name__ == "__main__":
    main()
