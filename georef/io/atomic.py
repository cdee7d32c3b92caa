"""Safe file output: write a temporary file beside the target, then rename it over the target.

Guarantees (``docs/report.md``, section "Safe output"):

* **Complete or absent.** The target is either the previous file or the complete new one, never part of it; a
  failure (an exception, a full disk, SIGINT, SIGTERM, SIGHUP) removes the temporary file and leaves the target
  as it was.
* **Only regular files are replaced.** A target that exists and is not a regular file (a device such as
  ``/dev/null`` or ``/dev/full``, a FIFO, a socket, a directory) is refused with :class:`OutputError` before
  anything is written: the rename would replace the device node itself. A symbolic link is followed: the file it
  points to is replaced and the link kept.
* **Write protection is kept.** A target without any write permission bit (e.g. mode 0444), or one this user
  may not write, is refused with :class:`OutputError`, also for root. An existing target keeps its permission
  bits; a new one gets ``0666 & ~umask``.
* **No litter.** Temporary files are named ``.NAME.PID.XXXXXXXX.tmp`` (``PID``: the writer's process id,
  ``XXXXXXXX``: 8 random characters) and are under an exclusive ``flock`` from before they get their name (Linux
  ``O_TMPFILE``, linked in locked; elsewhere locked right after creation) until they are renamed. SIGKILL cannot
  be caught, so every write first removes the temporary files of its own target that a killed writer left: those
  of our naming that are not locked (the kernel drops a dead process's locks) and whose writer process is gone,
  whatever their age, or that are older than :data:`STALE_AFTER_S` (a reused process id; the older
  ``.NAME.XXXXXXXX.tmp`` naming).
* **All or nothing for a set.** Inside ``with atomic_group():`` every :func:`atomic_write` keeps its finished
  temporary file until the group ends; only when every write succeeded are they renamed onto their targets, and
  on any failure all of them are removed and no target changes. Renames within one directory of one file
  system do not allocate data blocks, so a full disk fails the writes, before any rename.

>>> with atomic_group():
...     write_export(table, "eo.csv", "csv")   # uses atomic_write
...     write_report(result, "report.html")    # if this fails, eo.csv is not written either
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import re
import secrets
import signal
import stat
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from georef.io.errors import GeorefError

try:  # POSIX; elsewhere stale files are never removed (no way to tell a live writer's file from a dead one's)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

#: a temporary file of ours older than this [s] and not locked is stale (its writer was killed), even when a
#: process of the id in its name runs (the id reused)
STALE_AFTER_S = 300.0
#: signals whose default action ends the process: while a temporary file exists, they remove it first
CLEANUP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))

_KIND = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
         (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


@dataclass
class OutputError(GeorefError):
    """An output that cannot or must not be written: the path and why (the CLI prints it, exit code 2)."""

    path: Path | str
    message: str

    def __post_init__(self) -> None:
        super().__init__(str(self))

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


def _temp_pattern(name: str) -> re.Pattern[str]:
    """The names of our temporary files of target ``name``: ``.NAME.PID.XXXXXXXX.tmp`` (group ``pid``), or
    ``.NAME.XXXXXXXX.tmp`` as earlier versions named them."""
    return re.compile(rf"\.{re.escape(name)}\.(?:(?P<pid>[1-9][0-9]{{0,9}})\.)?[A-Za-z0-9_]{{8}}\.tmp")


def _writer_gone(pid: str | None) -> bool:
    """Whether no process of id ``pid`` (from a temporary file's name) runs here; False when unknown. POSIX only
    (on Windows, signal 0 is CTRL_C_EVENT): :func:`remove_stale_temps` does nothing where there is no ``fcntl``."""
    if pid is None:
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except (OSError, OverflowError):  # EPERM: another user's process, alive
        return False
    return False


def resolve_target(path: Path | str) -> Path:
    """The file an output to ``path`` replaces (a symbolic link followed), after checking that it may be replaced.

    Raises :class:`OutputError` for an existing target that is not a regular file, or that is write-protected.
    """
    path = Path(path)
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return path
    except OSError as exc:
        raise OutputError(path, f"cannot check the output: {exc.strerror}") from None
    for test, kind in _KIND:
        if test(st.st_mode):
            raise OutputError(path, f"is {kind}, not a regular file; georef writes an output as a new file renamed "
                                    "over the target, which would replace it. Give the path of a file.")
    if not stat.S_ISREG(st.st_mode):  # pragma: no cover - every other kind is listed above
        raise OutputError(path, "is not a regular file; give the path of a file")
    if not st.st_mode & 0o222 or not os.access(path, os.W_OK):
        raise OutputError(path, f"is write-protected (mode {stat.S_IMODE(st.st_mode):04o}); georef does not replace "
                                "it. Remove it, make it writable (chmod u+w) or write elsewhere.")
    return path


def remove_stale_temps(path: Path | str, older_than: float = STALE_AFTER_S) -> list[Path]:
    """Remove the temporary files of ours for target ``path`` left by killed writers; returns those removed.

    Only regular files of our naming (:func:`_temp_pattern`) that are not locked by a live writer are removed,
    and of those only the ones whose writer's process is gone or that are older than ``older_than`` [s]
    (nothing, where ``flock`` is unavailable or unsupported by the file system)."""
    path = Path(path)
    if fcntl is None:  # pragma: no cover - Windows
        return []
    pattern = _temp_pattern(path.name)
    removed = []
    now = time.time()
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    for name in names:
        match = pattern.fullmatch(name)
        if not match:
            continue
        candidate = path.parent / name
        try:
            fd = os.open(candidate, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
        except OSError:
            continue
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or (now - st.st_mtime < older_than and not _writer_gone(match["pid"])):
                continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                continue  # a live writer holds it (or the file system has no locks: keep it)
            with contextlib.suppress(FileNotFoundError):
                os.unlink(candidate)
                removed.append(candidate)
        finally:
            os.close(fd)
    return removed


# ---- temporary files alive in this process, removed by the signal handler ----------------------------------
_live: set[str] = set()
_live_lock = threading.Lock()
_previous_handlers: dict[int, object] = {}


def _on_signal(signum: int, frame: object) -> None:
    """Remove every live temporary file, then let the signal do what it did before we installed this."""
    with _live_lock:
        names = list(_live)
        _live.clear()
    for name in names:
        with contextlib.suppress(OSError):
            os.unlink(name)
    previous = _previous_handlers.get(signum, signal.SIG_DFL)
    if callable(previous):
        previous(signum, frame)
        return
    if previous == signal.SIG_IGN:
        return
    # the default action (terminate): restore it and send the signal again
    _restore_handlers()
    os.kill(os.getpid(), signum)


def _install_handlers() -> None:
    if threading.current_thread() is not threading.main_thread() or _previous_handlers:
        return
    for signum in CLEANUP_SIGNALS:
        with contextlib.suppress(ValueError, OSError):
            previous = signal.getsignal(signum)
            if previous is signal.SIG_IGN or previous is None:
                continue  # ignored, or set from C: leave it alone
            _previous_handlers[signum] = previous
            signal.signal(signum, _on_signal)


def _restore_handlers() -> None:
    if threading.current_thread() is not threading.main_thread():
        return
    for signum, previous in list(_previous_handlers.items()):
        with contextlib.suppress(ValueError, OSError, TypeError):
            signal.signal(signum, previous)  # type: ignore[arg-type]
        del _previous_handlers[signum]


def _register(name: str) -> None:
    with _live_lock:
        _live.add(name)
    _install_handlers()


def _unregister(name: str) -> None:
    with _live_lock:
        _live.discard(name)
        empty = not _live
    if empty:
        _restore_handlers()


def _locked(fd: int) -> None:
    """Take the exclusive lock that tells a live writer's temporary file from a dead one's (where there are
    locks: without them, :func:`remove_stale_temps` removes nothing)."""
    if fcntl is not None:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _link_unnamed(target: Path) -> tuple[int, str] | None:
    """A new file beside ``target`` made without a name (Linux ``O_TMPFILE``), locked, then given its name: it is
    never seen unlocked. None where the system or the file system cannot."""
    flag = getattr(os, "O_TMPFILE", 0)
    if not flag or fcntl is None:
        return None
    try:
        fd = os.open(target.parent, flag | os.O_RDWR | os.O_CLOEXEC, 0o600)
    except OSError:  # a kernel or file system without it
        return None
    name = None
    try:
        _locked(fd)
        name = _link_in(fd, target)
    finally:
        if name is None:
            os.close(fd)
    return None if name is None else (fd, name)


def _link_in(fd: int, target: Path) -> str | None:
    """Give the unnamed file ``fd`` a temporary name beside ``target``; None where it cannot be linked."""
    try:
        folder = os.open(target.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        for _ in range(100):
            name = _temp_name(target)
            # through /proc with linkat(AT_SYMLINK_FOLLOW), which os.link calls when given a dst_dir_fd
            with contextlib.suppress(FileExistsError):
                os.link(f"/proc/self/fd/{fd}", os.path.basename(name), dst_dir_fd=folder)
                return name
    except OSError:  # no /proc, or a file system that cannot: the caller creates a named file
        return None
    finally:
        os.close(folder)
    return None


def _temp_name(target: Path) -> str:
    """A fresh ``.NAME.PID.XXXXXXXX.tmp`` beside ``target`` (this process's id, 8 random hex digits)."""
    return str(target.parent / f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def _create_temp(target: Path) -> tuple[int, str]:
    """Our new temporary file beside ``target`` (``.NAME.PID.XXXXXXXX.tmp``), already locked: its descriptor and
    name. Linked in locked where the system can (:func:`_link_unnamed`), else created and locked at once."""
    made = _link_unnamed(target)
    if made is not None:
        return made
    for _ in range(100):
        name = _temp_name(target)
        try:
            fd = os.open(name, os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
                         | getattr(os, "O_CLOEXEC", 0), 0o600)
        except FileExistsError:
            continue
        _locked(fd)
        return fd, name
    raise FileExistsError(errno.EEXIST, "no free name for a temporary file", str(target.parent))


def _discard(name: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(name)
    _unregister(name)


# ---- groups -------------------------------------------------------------------------------------------------
@dataclass
class _Pending:
    tmp: str
    target: Path
    fd: int                       # kept open to hold the lock until the rename


@dataclass
class _Group:
    pending: list[_Pending] = field(default_factory=list)


_group: contextvars.ContextVar[_Group | None] = contextvars.ContextVar("georef_atomic_group", default=None)


def _commit(item: _Pending) -> None:
    try:
        os.replace(item.tmp, item.target)
    except OSError as exc:
        _discard(item.tmp)
        raise OutputError(item.target, f"could not write it: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            os.close(item.fd)
    _unregister(item.tmp)
    with contextlib.suppress(OSError):  # the rename itself durable
        dir_fd = os.open(item.target.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


@contextlib.contextmanager
def atomic_group() -> Iterator[None]:
    """Write several outputs all-or-nothing: :func:`atomic_write` calls inside defer their renames to the end.

    On leaving without an exception every target is checked again and then replaced; on an exception (or a
    refused target) every temporary file is removed and no target changes. A group inside a group joins it."""
    if _group.get() is not None:
        yield
        return
    group = _Group()
    token = _group.set(group)
    try:
        yield
        for item in group.pending:
            if resolve_target(item.target) != item.target:  # pragma: no cover - replaced by a link meanwhile
                raise OutputError(item.target, "changed while it was being written")
    except BaseException:
        for item in group.pending:
            with contextlib.suppress(OSError):
                os.close(item.fd)
            _discard(item.tmp)
        raise
    finally:
        _group.reset(token)
    for k, item in enumerate(group.pending):
        try:
            _commit(item)
        except BaseException:
            for rest in group.pending[k + 1:]:
                with contextlib.suppress(OSError):
                    os.close(rest.fd)
                _discard(rest.tmp)
            raise


def _umask() -> int:
    """The process's umask, read without changing it where the system tells it (Linux); else set and restored."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    umask = os.umask(0o077)  # briefly: another thread creating a file meanwhile gets the stricter mask
    os.umask(umask)
    return umask


def _mode_for(target: Path) -> int:
    """The permission bits the output gets: an existing target's own, else ``0666 & ~umask``."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode) & 0o777
    except FileNotFoundError:
        return 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_write(path: Path | str, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file in the target's folder; on success it replaces ``path`` in one rename.

    A failure inside the block (or while flushing) leaves any previous ``path`` untouched and no temporary file;
    an ``OSError`` while writing (a full disk) is raised as :class:`OutputError` naming ``path``. Refused
    targets: see :func:`resolve_target`. Inside :func:`atomic_group` the rename waits for the group's end.
    """
    target = resolve_target(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(target, f"cannot create its folder: {exc.strerror or exc}") from None
    remove_stale_temps(target)
    final_mode = _mode_for(target)
    try:
        fd, tmp_name = _create_temp(target)
    except OSError as exc:
        raise OutputError(target, f"cannot write in its folder: {exc.strerror or exc}") from None
    _register(tmp_name)
    lock_fd = -1
    try:
        lock_fd = os.dup(fd)  # the lock is the open file's: this copy holds it until the rename
        text = "b" not in mode
        try:
            with os.fdopen(fd, mode, encoding=encoding if text else None, newline="" if text else None) as handle:
                yield handle
                handle.flush()
                os.fsync(handle.fileno())
            os.chmod(tmp_name, final_mode)
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS):
                raise OutputError(target, f"could not write it: {exc.strerror} (errno {exc.errno}); nothing was "
                                          "written and any previous file is unchanged") from None
            raise
        group = _group.get()
        if group is not None:
            group.pending.append(_Pending(tmp=tmp_name, target=target, fd=lock_fd))
            lock_fd = -1
            return
        item = _Pending(tmp=tmp_name, target=target, fd=lock_fd)
        lock_fd = -1
        _commit(item)
    except BaseException:
        if lock_fd >= 0:
            with contextlib.suppress(OSError):
                os.close(lock_fd)
        _discard(tmp_name)
        raise
