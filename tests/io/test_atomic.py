"""Safe output (georef.io.atomic; docs/report.md, "Safe output"): a crash, a signal or SIGKILL while writing
leaves the old file and no temporary file past the next run; targets that cannot be replaced are refused."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from georef.io import atomic
from georef.io.atomic import OutputError, atomic_group, atomic_write, remove_stale_temps, resolve_target


def test_atomic_write_leaves_the_old_file_on_a_crash(tmp_path):
    target = tmp_path / "eo.csv"
    target.write_text("old complete table\n")
    with pytest.raises(RuntimeError), atomic_write(target) as handle:
        handle.write("half a tab")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "old complete table\n"
    assert [p.name for p in tmp_path.iterdir()] == ["eo.csv"]


# ---- safe output (docs/report.md, "Safe output") --------------------------------------------------------------
def _device(tmp_path: Path, name: str, minor: int) -> Path:
    """A character device node with the numbers of /dev/null (1, 3) or /dev/full (1, 7), made in ``tmp_path`` so
    that a regression replaces our node, not the machine's. Needs root (CI runs as root)."""
    node = tmp_path / name
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    except PermissionError:
        pytest.skip("making a device node needs root (CI runs the suite as root)")
    return node


@pytest.mark.parametrize(("name", "minor"), [("null", 3), ("full", 7)])
def test_device_nodes_are_refused_and_kept(tmp_path, name, minor):
    node = _device(tmp_path, name, minor)
    with pytest.raises(OutputError, match=rf"{node}: is a character device, not a regular file"):
        with atomic_write(node) as handle:
            handle.write("table\n")
    assert stat.S_ISCHR(os.lstat(node).st_mode) and os.lstat(node).st_rdev == os.makedev(1, minor)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no temporary file either
    # the machine's own nodes are refused by the same check (resolve_target writes nothing)
    real = Path(f"/dev/{name}")
    if real.exists():
        with pytest.raises(OutputError, match=f"/dev/{name}: is a character device"):
            resolve_target(real)


def test_fifo_directory_and_socket_targets_are_refused(tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match=r"pipe.csv: is a FIFO \(named pipe\), not a regular file"):
        with atomic_write(fifo) as handle:  # refused before anything opens the FIFO (which would block)
            handle.write("x")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    folder = tmp_path / "out"
    folder.mkdir()
    with pytest.raises(OutputError, match=r"out: is a directory"):
        resolve_target(folder)
    import socket

    path = tmp_path / "s.sock"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(path))
        with pytest.raises(OutputError, match=r"s.sock: is a socket"):
            resolve_target(path)
    # a link to a device is refused as the device
    link = tmp_path / "link.csv"
    link.symlink_to(fifo)
    with pytest.raises(OutputError, match="is a FIFO"):
        resolve_target(link)


def test_write_protected_files_are_refused_and_writable_ones_keep_their_mode(tmp_path):
    protected = tmp_path / "eo.csv"
    protected.write_text("delivered\n")
    protected.chmod(0o444)
    with pytest.raises(OutputError, match=r"eo.csv: is write-protected \(mode 0444\); georef does not replace it"):
        with atomic_write(protected) as handle:
            handle.write("new\n")
    assert protected.read_text() == "delivered\n" and stat.S_IMODE(protected.stat().st_mode) == 0o444
    assert sorted(p.name for p in tmp_path.iterdir()) == ["eo.csv"]
    shared = tmp_path / "shared.csv"
    shared.write_text("old\n")
    shared.chmod(0o640)
    with atomic_write(shared) as handle:
        handle.write("new\n")
    assert shared.read_text() == "new\n" and stat.S_IMODE(shared.stat().st_mode) == 0o640
    for mask, expected in ((0o022, 0o644), (0o077, 0o600)):
        fresh = tmp_path / f"fresh{mask:o}.csv"
        umask = os.umask(mask)
        try:
            with atomic_write(fresh) as handle:
                handle.write("x\n")
        finally:
            os.umask(umask)
        assert stat.S_IMODE(fresh.stat().st_mode) == expected


def test_a_symbolic_link_is_followed_and_kept(tmp_path):
    real = tmp_path / "real.csv"
    real.write_text("old\n")
    link = tmp_path / "eo.csv"
    link.symlink_to(real)
    with atomic_write(link) as handle:
        handle.write("new\n")
    assert link.is_symlink() and real.read_text() == "new\n"


def test_a_full_disk_raises_an_error_naming_the_output_and_leaves_nothing(tmp_path):
    """A real ENOSPC on a 64 kB tmpfs when this process may mount one (root on CI), else the kernel's file-size
    limit (EFBIG) in a child process: both are write errors the kernel raises, not a patched function."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                             capture_output=True).returncode == 0
    try:
        if mounted:
            target = disk / "eo.csv"
            target.write_text("old complete table\n")
            with pytest.raises(OutputError, match=r"eo.csv: could not write it: No space left on device \(errno 28\)"):
                with atomic_write(target) as handle:
                    for _ in range(200):
                        handle.write("x" * 1024)
            assert target.read_text() == "old complete table\n"
            assert sorted(p.name for p in disk.iterdir()) == ["eo.csv"]
    finally:
        if mounted:
            subprocess.run(["umount", str(disk)], check=True)
    target = tmp_path / "big.csv"
    code = f"""
        import resource
        from georef.io.atomic import atomic_write, OutputError
        resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))
        try:
            with atomic_write({str(target)!r}) as handle:
                for _ in range(200):
                    handle.write("x" * 1024)
        except OutputError as exc:
            print(exc)
    """
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=60)
    assert "big.csv: could not write it: File too large (errno 27)" in out.stdout, out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["disk"]


def test_a_group_is_written_all_or_nothing(tmp_path):
    first, second = tmp_path / "eo.csv", tmp_path / "report.html"
    first.write_text("old table\n")
    with pytest.raises(RuntimeError, match="report failed"), atomic_group():
        with atomic_write(first) as handle:
            handle.write("new table\n")
        assert first.read_text() == "old table\n"  # not renamed before the group ends
        with atomic_write(second) as handle:
            handle.write("<html>half")
            raise RuntimeError("report failed")
    assert first.read_text() == "old table\n" and sorted(p.name for p in tmp_path.iterdir()) == ["eo.csv"]
    # a refused target inside the group: nothing is written either
    protected = tmp_path / "protected.html"
    protected.write_text("keep\n")
    protected.chmod(0o444)
    with pytest.raises(OutputError, match="write-protected"), atomic_group():
        with atomic_write(first) as handle:
            handle.write("new table\n")
        with atomic_write(protected) as handle:
            handle.write("x")
    assert first.read_text() == "old table\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["eo.csv", "protected.html"]
    with atomic_group():
        with atomic_write(first) as handle:
            handle.write("new table\n")
        with atomic_write(second) as handle:
            handle.write("<html></html>")
    assert first.read_text() == "new table\n" and second.read_text() == "<html></html>"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["eo.csv", "protected.html", "report.html"]


_WRITER = """
import sys, time
from georef.io.atomic import atomic_write
with atomic_write(sys.argv[1]) as handle:
    handle.write("half a tab")
    handle.flush()
    print("writing", flush=True)
    time.sleep(60)
"""


def _default_signals() -> None:
    """In the writer before it starts: SIGHUP and SIGINT at their default actions. A suite started under
    ``nohup`` or as a background job hands its children both ignored, and a writer that ignores a signal rightly
    keeps writing (the handler leaves an ignored signal ignored)."""
    for signum in (signal.SIGHUP, signal.SIGINT):
        signal.signal(signum, signal.SIG_DFL)


def _start_writer(target: Path) -> subprocess.Popen:
    writer = subprocess.Popen([sys.executable, "-c", _WRITER, str(target)], stdout=subprocess.PIPE, text=True,
                              preexec_fn=_default_signals)
    assert writer.stdout.readline().strip() == "writing"
    return writer


def _temps(folder: Path, name: str = "eo.csv") -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.name.startswith(f".{name}.") and p.name.endswith(".tmp"))


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_terminated_writer_removes_its_temporary_file(tmp_path, signum):
    target = tmp_path / "eo.csv"
    target.write_text("old complete table\n")
    writer = _start_writer(target)
    assert len(_temps(tmp_path)) == 1
    writer.send_signal(signum)
    writer.wait(timeout=30)
    # the process still ends by the signal (Python re-raises an uncaught KeyboardInterrupt as SIGINT)
    assert writer.returncode == -signum
    assert _temps(tmp_path) == [] and target.read_text() == "old complete table\n"


def test_a_killed_writers_temporary_file_is_removed_by_the_next_run(tmp_path):
    target = tmp_path / "eo.csv"
    target.write_text("old complete table\n")
    writer = _start_writer(target)
    writer.kill()  # SIGKILL: no handler runs
    writer.wait(timeout=30)
    left = _temps(tmp_path)
    assert len(left) == 1 and left[0].read_text() == "half a tab" and f".{writer.pid}." in left[0].name
    # young, but its writer's process is gone: the next run removes it
    with atomic_write(target) as handle:
        handle.write("second run\n")
    assert _temps(tmp_path) == [] and target.read_text() == "second run\n"
    # a file of the older naming (no process id): young, it might be a live writer's, so it stays until stale
    older = tmp_path / ".eo.csv.abcd_fgh.tmp"
    older.write_text("half a tab")
    with atomic_write(target) as handle:
        handle.write("third run\n")
    assert _temps(tmp_path) == [older]
    old = time.time() - atomic.STALE_AFTER_S - 60
    os.utime(older, (old, old))
    with atomic_write(target) as handle:
        handle.write("fourth run\n")
    assert _temps(tmp_path) == [] and target.read_text() == "fourth run\n"


def test_stale_files_of_live_writers_and_other_names_are_kept(tmp_path):
    target = tmp_path / "eo.csv"
    writer = _start_writer(target)  # holds an flock on its temporary file
    try:
        live = _temps(tmp_path)
        others = [tmp_path / name for name in (".eo.csv.tmp", ".eo.csv.abc.tmp", ".eo.csvX.abcdefgh.tmp",
                                               ".other.csv.abcdefgh.tmp", "eo.csv.abcdefgh.tmp")]
        for path in others:
            path.write_text("not ours\n")
        stale = tmp_path / ".eo.csv.abcd_fgh.tmp"
        stale.write_text("a killed writer's\n")
        old = time.time() - atomic.STALE_AFTER_S - 60
        for path in [*live, *others, stale]:
            os.utime(path, (old, old))
        assert remove_stale_temps(target) == [stale]
        assert len(live) == 1 and live[0].exists() and all(p.exists() for p in others) and not stale.exists()
    finally:
        writer.kill()
        writer.wait(timeout=30)
