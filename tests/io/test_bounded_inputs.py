"""Every input reader is bounded, and a killed writer leaves no temporary file past the next run.

Defects found by mutating the bundled flight (``data/``):

* a named pipe (FIFO) that nobody writes to kept ``georef process`` waiting for ever;
* a 5,000,000-character line in Kamera.txt took 15 GB and 38 s (its frame id copied at numpy's fixed width, the
  widest id's, for every row);
* ``georef process`` killed by SIGKILL while writing left its ``.eo.csv.*.tmp`` until a run at least 5 minutes
  later.

Whatever could hang or exhaust memory runs in a child process, with a timeout and an address-space cap.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from unittest import mock

import pytest

import georef.io.table as table_module
from georef.io import atomic
from georef.io.atomic import atomic_write
from georef.io.errors import MAX_FIELD_CHARS, InputError
from georef.io.table import PIPE_WAIT_S, InMemory, read_table

DATA = Path(__file__).resolve().parents[2] / "data"
CLI = "from georef_cli.main import main; main()"
#: the address space a child may take: a regression fails fast instead of taking the machine's memory
ADDRESS_CAP = 4 << 30
#: the peak resident memory a run may reach on a 5 MB line [MB]
PEAK_LIMIT_MB = 1024


def _cli(*args: str, timeout: float = 60.0) -> tuple[subprocess.CompletedProcess, float]:
    """``georef ARGS`` in a child process: the finished process and its wall time [s]."""
    start = time.perf_counter()
    try:
        run = subprocess.run([sys.executable, "-c", CLI, *args], capture_output=True, text=True, timeout=timeout,
                             check=False, cwd=DATA.parent)
    except subprocess.TimeoutExpired:
        pytest.fail(f"georef {' '.join(args)} still ran after {timeout:.0f} s")
    return run, time.perf_counter() - start


def _write_generic(folder: Path) -> dict[str, Path]:
    """A small imu.csv (100 Hz, at rest, level) and gnss.csv (1 Hz) of 20 s."""
    imu = ["time,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z"]
    imu += [f"{k * 0.01:.2f},0.001,-0.002,0.0005,0.01,-0.02,-9.81" for k in range(2000)]
    gnss = ["time,lat,lon,height"] + [f"{k:.1f},{45.0 + k * 1e-7:.8f},15.0,300.0" for k in range(20)]
    paths = {"imu.csv": folder / "imu.csv", "gnss.csv": folder / "gnss.csv"}
    paths["imu.csv"].write_text("\n".join(imu) + "\n")
    paths["gnss.csv"].write_text("\n".join(gnss) + "\n")
    return paths


def _with_long_field(source: Path, target: Path, line: int, column: int, text: str) -> None:
    """``source`` with field ``column`` (0-based) of file line ``line`` (1-based) replaced by ``text``."""
    lines = source.read_text().splitlines(keepends=True)
    sep = "\t" if "\t" in lines[0] else ","
    cells = lines[line - 1].rstrip("\n").split(sep)
    cells[column] = text
    lines[line - 1] = sep.join(cells) + "\n"
    target.write_text("".join(lines))


# ---- 1. a named pipe without a writer ------------------------------------------------------------------------
def _process_args(pos: Path, kamera: Path, out: Path) -> list[str]:
    return ["process", str(pos), str(kamera), "--config", str(DATA / "flight.toml"), "-o", str(out), "-q"]


@pytest.mark.parametrize("which", ["POS.txt", "Kamera.txt", "imu.csv", "gnss.csv"])
def test_a_pipe_without_a_writer_is_refused_within_a_bounded_wait(tmp_path, which):
    """``georef process FIFO data/Kamera.txt`` waited for ever; it now exits 2 naming the pipe."""
    fifo = tmp_path / which
    os.mkfifo(fifo)
    if which in ("POS.txt", "Kamera.txt"):
        pos = fifo if which == "POS.txt" else DATA / "POS.txt"
        kamera = fifo if which == "Kamera.txt" else DATA / "Kamera.txt"
        args = _process_args(pos, kamera, tmp_path / "eo.csv")
    else:
        folder = tmp_path / "files"
        folder.mkdir()
        generic = {**_write_generic(folder), which: fifo}
        args = ["fuse", "--imu", str(generic["imu.csv"]), "--gnss", str(generic["gnss.csv"]), "-o",
                str(tmp_path / "traj.csv"), "-q"]
    run, elapsed = _cli(*args, timeout=60)
    text = run.stdout + run.stderr
    assert run.returncode == 2, text
    assert f"{fifo}: a named pipe (FIFO) and no writer appeared within {PIPE_WAIT_S:g} s" in text, text
    assert "Traceback" not in text
    assert PIPE_WAIT_S <= elapsed < 10.0, elapsed
    assert not (tmp_path / "eo.csv").exists() and not (tmp_path / "traj.csv").exists()


def _late_writer(fifo: Path, data: bytes, delay: float, deadline: float = 60.0) -> threading.Thread:
    """A thread that opens ``fifo`` for writing ``delay`` s from now and writes ``data``. It opens non-blocking
    (refused while no reader is there) and retries, so that it never waits for ever itself."""

    def write() -> None:
        time.sleep(delay)
        end = time.monotonic() + deadline
        while True:
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
                break
            except OSError:  # ENXIO: no reader yet
                if time.monotonic() > end:
                    return
                time.sleep(0.01)
        os.set_blocking(fd, True)
        with open(fd, "wb") as handle:
            handle.write(data)

    thread = threading.Thread(target=write, daemon=True)
    thread.start()
    return thread


def test_a_pipe_whose_writer_comes_late_is_read(tmp_path):
    """A writer that connects a second after georef opened the pipe is waited for, and its data read whole."""
    fifo = tmp_path / "Kamera.fifo"
    os.mkfifo(fifo)
    writer = _late_writer(fifo, (DATA / "Kamera.txt").read_bytes(), delay=1.0)
    run, _ = _cli(*_process_args(DATA / "POS.txt", fifo, tmp_path / "piped.csv"), timeout=120)
    writer.join(timeout=30)
    assert run.returncode == 0, run.stdout + run.stderr
    reference, _ = _cli(*_process_args(DATA / "POS.txt", DATA / "Kamera.txt", tmp_path / "file.csv"), timeout=120)
    assert reference.returncode == 0, reference.stdout + reference.stderr
    assert (tmp_path / "piped.csv").read_bytes() == (tmp_path / "file.csv").read_bytes()


def test_a_pipe_whose_writer_writes_nothing_is_refused_at_once(tmp_path):
    fifo = tmp_path / "POS.txt"
    os.mkfifo(fifo)
    _late_writer(fifo, b"", delay=0.0)
    run, elapsed = _cli(*_process_args(fifo, DATA / "Kamera.txt", tmp_path / "eo.csv"), timeout=60)
    assert run.returncode == 2 and "POS.txt, line 1: the pipe gave no data" in run.stdout + run.stderr, run
    assert elapsed < PIPE_WAIT_S + 5.0


# ---- 2. one over-long line ------------------------------------------------------------------------------------
# The child's own peak is its VmHWM: getrusage(RUSAGE_SELF) in a child counts the parent's peak too (Linux keeps
# the high-water mark of the image replaced by exec), and a pytest worker may have grown to hundreds of MB.
_MEASURED = """
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))
def peak_mb():
    with open("/proc/self/status") as status:
        return int(status.read().split("VmHWM:")[1].split()[0]) / 1024
{body}
print(json.dumps({{"message": message, "peak_mb": peak_mb()}}))
"""


def _read_in_child(body: str) -> tuple[str, float]:
    """Run ``body`` (which sets ``message`` and may call ``peak_mb()``) in a child under the address-space cap:
    ``message`` and the child's peak resident memory [MB]."""
    code = _MEASURED.format(cap=ADDRESS_CAP, body=textwrap.dedent(body))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout.strip().splitlines()[-1])
    return result["message"], result["peak_mb"]


def test_a_5_mb_frame_id_is_refused_in_bounded_memory(tmp_path):
    """``georef process`` on a Kamera.txt whose line 6 holds a 5,000,000-character frame id: 15 GB and 38 s, exit
    0; now an error naming line and column, in bounded memory."""
    kamera = tmp_path / "Kamera.txt"
    _with_long_field(DATA / "Kamera.txt", kamera, 6, 0, "7" * 5_000_000)
    # the CLI's peak as getrusage(RUSAGE_CHILDREN) of a fresh, small wrapper: a child of the pytest worker itself
    # would count the worker's peak too (see _MEASURED)
    wrapper = (f"import resource, subprocess, sys, json\n"
               f"cap = lambda: resource.setrlimit(resource.RLIMIT_AS, ({ADDRESS_CAP}, {ADDRESS_CAP}))\n"
               "run = subprocess.run(sys.argv[1:], capture_output=True, text=True, preexec_fn=cap, timeout=240)\n"
               "print(json.dumps({'rc': run.returncode, 'text': run.stdout + run.stderr,\n"
               "                  'peak_mb': resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))\n")
    args = [sys.executable, "-c", CLI, *_process_args(DATA / "POS.txt", kamera, tmp_path / "eo.csv")]
    run = subprocess.run([sys.executable, "-c", wrapper, *args], capture_output=True, text=True, timeout=300,
                         check=False)
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["rc"] == 2, result["text"][-3000:]
    assert (f"Kamera.txt, line 6, column 'Number': field of 5000000 characters, at most {MAX_FIELD_CHARS}: "
            f"{'7' * 40!r}… (5000000 characters)") in result["text"]
    assert result["peak_mb"] < PEAK_LIMIT_MB, result["peak_mb"]
    assert not (tmp_path / "eo.csv").exists()


@pytest.mark.parametrize("name, line, column, spelled, text", [
    ("POS.txt", 501, 1, "ACCS_X", "0" * 5_000_000),      # a valid number (zero) the compiled reader took
    ("POS.txt", 501, 16, "VELX", "1" * 5_000_000),       # a column that is not read
    ("POS.txt", 501, 0, "CNT[HEX]", "A" * 5_000_000),
    ("imu.csv", 51, 0, "time", "1" * 5_000_000),
    ("gnss.csv", 11, 1, "lat", "4" * 5_000_000),
    ("Kamera.txt", 6, 0, "Number", "é" * 2_500_000),      # characters, not bytes, are counted
])
def test_an_over_long_field_in_any_table_is_located_in_bounded_memory(tmp_path, name, line, column, spelled, text):
    sources = {"POS.txt": DATA / "POS.txt", "Kamera.txt": DATA / "Kamera.txt", **_write_generic(tmp_path)}
    path = tmp_path / f"long-{name}"
    _with_long_field(sources[name], path, line, column, text)
    reader = {"POS.txt": "from georef.io.pos import read_pos as read",
              "Kamera.txt": "from georef.io.camera import read_exposures as read",
              "imu.csv": "from georef.io.generic import read_imu_csv as read",
              "gnss.csv": "from georef.io.generic import read_gnss_csv as read"}[name]
    message, peak_mb = _read_in_child(f"""
        {reader}
        from georef.io.errors import InputError
        try:
            read({str(path)!r})
            message = "read without an error"
        except InputError as exc:
            message = str(exc)
        """)
    assert message.startswith(f"{path}, line {line}, column {spelled!r}: field of {len(text)} characters, at most "
                              f"{MAX_FIELD_CHARS}: {text[:40]!r}… ({len(text)} characters)"), message
    assert peak_mb < PEAK_LIMIT_MB, peak_mb


def test_a_line_far_longer_than_any_block_is_refused_without_holding_it(tmp_path):
    """A 64 MB field in a column that is not read: refused while the file streams past, not after the line was
    gathered into memory (the compiled reader gathered it, 275 MB, and took the file). Measured as the growth of
    the peak over reading the same file with a 1 MB field first (which imports and warms up the same code)."""
    size = 64 << 20
    short, long = tmp_path / "short.txt", tmp_path / "POS.txt"
    _with_long_field(DATA / "POS.txt", short, 501, 17, "9" * (1 << 20))
    _with_long_field(DATA / "POS.txt", long, 501, 17, "9" * size)
    message, peak_mb = _read_in_child(f"""
        from georef.io.pos import read_pos
        from georef.io.errors import InputError
        messages, peaks = [], []
        for path in ({str(short)!r}, {str(long)!r}):
            try:
                read_pos(path)
                messages.append("read without an error")
            except InputError as exc:
                messages.append(str(exc))
            peaks.append(peak_mb())
        message = messages[1] + f" | {{peaks[1] - peaks[0]:.1f}}"
        """)
    assert f"POS.txt, line 501, column 'ODO_TICKS': field of {size} characters" in message, message
    growth_mb = float(message.rsplit("| ", 1)[1])
    assert growth_mb < size / 2**20 / 2, (growth_mb, peak_mb)


@pytest.mark.parametrize("sep", ["\t", ",", " "])
def test_the_field_limit_is_the_same_for_the_three_readers(sep):
    """A field of :data:`MAX_FIELD_CHARS` characters is read; one more is an error, with the same message whichever
    reader takes the file (compiled, numpy's ``loadtxt``, pandas)."""
    def table(frame_id: str, number: str = "1.5") -> bytes:
        rows = [sep.join(["Number", "Time", "Extra"])]
        rows += [sep.join([f"f{k}", f"{k}.25", "x"]) for k in range(1, 6)]
        rows.insert(3, sep.join([frame_id, number, "x"]))
        return ("\n".join(rows) + "\n").encode()

    wanted = {"Number": "str", "Time": "float"}

    def read_all_ways(data: bytes) -> list[object]:
        results = []
        for patch in (None, "_parse_compiled", "_parse_clean"):
            with mock.patch.object(table_module, patch, lambda *_args: None) if patch else contextlib.nullcontext():
                try:
                    got = read_table(InMemory(Path("t.txt"), data), wanted, required=list(wanted))
                    results.append(got.columns["Number"].tolist() + got.columns["Time"].tolist())
                except InputError as exc:
                    results.append(str(exc))
        return results

    longest = "a" * MAX_FIELD_CHARS
    ways = read_all_ways(table(longest))
    assert ways[0] == ways[1] == ways[2] and longest in ways[0], ways
    wide = "é" * MAX_FIELD_CHARS  # twice as many bytes: still within the limit
    ways = read_all_ways(table(wide))
    assert ways[0] == ways[1] == ways[2] and wide in ways[0], ways
    for frame_id, number, column in (("a" * (MAX_FIELD_CHARS + 1), "1.5", "Number"),
                                     ("f9", "0" * (MAX_FIELD_CHARS + 1), "Time")):
        ways = read_all_ways(table(frame_id, number))
        length = MAX_FIELD_CHARS + 1
        assert ways[0] == ways[1] == ways[2], ways
        assert ways[0].startswith(f"t.txt, line 4, column {column!r}: field of {length} characters, at most "
                                  f"{MAX_FIELD_CHARS}"), ways[0]


# ---- 3. SIGKILL while writing -----------------------------------------------------------------------------------
_WRITER = """
import sys, time
from georef.io.atomic import atomic_write
print("start", flush=True)
with atomic_write(sys.argv[1]) as handle:
    for k in range(200):
        handle.write(f"row {k} " + "x" * 3000 + "\\n")
        handle.flush()
        time.sleep(0.001)
print("done", flush=True)
time.sleep(60)
"""


def _temps(folder: Path, name: str) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.name.startswith(f".{name}.") and p.name.endswith(".tmp"))


def test_no_temporary_file_of_a_killed_writer_survives_the_next_run(tmp_path):
    """SIGKILL at random points of a write (before, during and after it): the next write to the same target
    removes what the killed one left, whatever its age."""
    target = tmp_path / "eo.csv"
    target.write_text("old complete table\n")
    rng = random.Random(3)
    left_by_kills = 0
    for run in range(8):
        writer = subprocess.Popen([sys.executable, "-c", _WRITER, str(target)], stdout=subprocess.PIPE, text=True)
        assert writer.stdout.readline().strip() == "start"
        time.sleep(rng.uniform(0.0, 0.35))
        writer.send_signal(signal.SIGKILL)
        writer.wait(timeout=30)
        writer.stdout.close()
        left = _temps(tmp_path, "eo.csv")
        left_by_kills += bool(left)
        assert all(f".{writer.pid}." in p.name for p in left), left
        with atomic_write(target) as handle:
            handle.write(f"run {run}\n")
        assert _temps(tmp_path, "eo.csv") == [], run
        assert target.read_text() == f"run {run}\n"
    assert left_by_kills >= 2  # the kills did hit writes: otherwise this test would prove nothing


def test_a_killed_georef_process_leaves_nothing_after_the_next_run(tmp_path):
    """``georef process ... -o eo.csv`` killed as soon as its temporary file appears (or a few ms later)."""
    out = tmp_path / "out"
    out.mkdir()
    args = _process_args(DATA / "POS.txt", DATA / "Kamera.txt", out / "eo.csv")
    rng = random.Random(5)
    hit = 0
    for _ in range(3):
        process = subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL, cwd=DATA.parent)
        end = time.monotonic() + 120
        while process.poll() is None and not _temps(out, "eo.csv") and time.monotonic() < end:
            time.sleep(0.0002)
        time.sleep(rng.uniform(0.0, 0.003))
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=30)
        hit += bool(_temps(out, "eo.csv"))
        run, _ = _cli(*args, timeout=120)
        assert run.returncode == 0, run.stdout + run.stderr
        assert _temps(out, "eo.csv") == []
    assert hit >= 1  # at least one kill landed inside the write


@pytest.mark.parametrize("unnamed", [True, False], ids=["O_TMPFILE", "named"])
def test_a_temporary_file_is_locked_and_named_with_its_writer(tmp_path, unnamed):
    """Both ways of making the temporary file (linked in from an unnamed file; created by name where the system
    cannot) give a file named with the writer's process id and locked against removal."""
    import fcntl

    if unnamed and not getattr(os, "O_TMPFILE", 0):
        pytest.skip("no O_TMPFILE here")
    target = tmp_path / "eo.csv"
    with mock.patch.object(atomic, "_link_unnamed", atomic._link_unnamed if unnamed else lambda _target: None):
        with atomic_write(target) as handle:
            handle.write("table\n")
            (temp,) = _temps(tmp_path, "eo.csv")
            assert temp.name.startswith(f".eo.csv.{os.getpid()}.")
            fd = os.open(temp, os.O_RDONLY)
            try:
                with pytest.raises(OSError):
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            finally:
                os.close(fd)
            assert atomic.remove_stale_temps(target, older_than=0.0) == []  # a live writer's: kept
    assert target.read_text() == "table\n" and _temps(tmp_path, "eo.csv") == []
