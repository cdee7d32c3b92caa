"""Header-led text tables (POS.txt, Kamera.txt, imu.csv, gnss.csv), read with every problem located.

The rules (``docs/formats.md``, "Reading text tables"):

* **Encoding**: UTF-8 (ASCII is UTF-8). A UTF-8 byte-order mark is removed; UTF-16 with a byte-order mark
  (Excel's "Unicode text") is converted. A NUL byte (a binary or damaged file), an undecodable byte or a
  carriage return inside a line is an error naming its line and column. A file with a NUL byte in its first
  64 KiB is refused before anything else is read.
* **Separator**: tab, semicolon, comma or runs of blanks, detected from the header line and checked against
  the first data lines. When two separators fit, or the data lines use another one than the header, it is an
  error that names the line and says what was seen.
* **Header names** are matched ignoring case and surrounding blanks; two columns matching one wanted name
  are an error.
* **Quotes** are ordinary characters: they never join fields or lines. A quote in a number is an error in
  its own cell; a quote in a text cell (a frame id) is an error too, since no format here has one.
* **Fields**: a line with more fields than the header is an error. A line with fewer is an error, except the
  last line (a logger that lost power), which is dropped with a notice, or kept and marked when the caller
  asks (``short_rows="keep"``: Kamera.txt, where every frame gets a row). Blank lines are skipped with a notice.
* **Numbers** are ASCII decimals (``-1.5``, ``2e-3``). ``inf``, ``nan``, overflowing exponents, hexadecimal,
  digits of other scripts, decimal commas and quoted numbers are errors naming line and column. Messages
  quote at most :data:`~georef.io.errors.EXCERPT_CHARS` characters of a cell.
* **Length**: a field (wanted or not) of more than :data:`~georef.io.errors.MAX_FIELD_CHARS` characters is an
  error naming its line and column, found as the bytes stream past: no reader holds more of such a line than a
  block, and a text column at numpy's fixed width stays small.
* **Pipes** (FIFOs) are read into memory once; a writer has :data:`PIPE_WAIT_S` to send its first byte (or to
  close the pipe), after which the pipe is an error rather than a wait for ever.

Three readers, which must give the same numbers to the bit (``tests/io/test_table.py``):

* a **clean** file (every line with the header's number of fields, printable ASCII, no quote, every number
  finite and within the exact fast path of at most 15 significant digits) is read by the compiled reader
  (:mod:`georef.io.table_kernel`) in 8 MiB blocks of whole lines;
* a clean file it declines (a number of 16 digits or more, say), up to 16 MiB, by numpy's ``loadtxt``,
  streamed in 256 KiB blocks through a checker (:class:`_Scanner`);
* anything else by pandas' C parser behind the same checker, whose results and messages define the rules;
  when pandas refuses a cell, a second, chunked pass finds its line and column.

All three round correctly (Clinger's fast path; numpy through ``PyOS_string_to_double``; pandas 3 through
fast_float). The first two exist for speed: importing pandas is slow, and ``georef process`` needs it for
nothing else (``docs/formats.md``, "Reading text tables"; ``docs/method-ins.md``, section 10;
``docs/performance.md``, "Tables").
"""

from __future__ import annotations

import codecs
import csv
import functools
import io
import os
import re
import select
import stat
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Literal

import numpy as np

from georef.io.errors import EXCERPT_CHARS, MAX_FIELD_CHARS, InputError, InputNotice, excerpt

if TYPE_CHECKING:
    import pandas as pd

Kind = Literal["float", "int", "hex", "str"]

#: separators tried, in order; None stands for runs of blanks (spaces or tabs)
SEPARATORS: tuple[str, ...] = ("\t", ";", ",")
SEPARATOR_NAMES = {"\t": "tab", ";": "semicolon", ",": "comma", None: "whitespace"}

_BLOCK = 1 << 18          # bytes handed to pandas per read
_SNIFF = 1 << 16          # bytes looked at before parsing (header, separator, binary check)
_MAX_ANOMALIES = 10_000   # short or blank lines recorded before the file is called unreadable
_LINE_PEEK = 4096         # bytes of a line read back to explain it
#: how long a named pipe may keep a reader waiting for its writer's first byte [s]
PIPE_WAIT_S = 5.0

_UTF8_BOM = b"\xef\xbb\xbf"
_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")
# unambiguous (no nested or overlapping repeats), so a 5 MB cell is matched in linear time
_FLOAT_TEXT = r"\s*[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*"
_HEX_TEXT = r"\s*(?:0[xX])?[0-9a-fA-F]{1,16}\s*"
_BAD_TEXT = re.compile(r'["\x00-\x08\x0a-\x1f\x7f]')
_KIND_WORDS = {"float": "a number", "int": "a whole number", "hex": "a hexadecimal number"}


@dataclass(frozen=True)
class Dialect:
    """How a table file was written: its separator (None: runs of blanks) and its encoding."""

    separator: str | None
    encoding: str

    def describe(self) -> str:
        """E.g. ``"tab-separated, UTF-8 (byte-order mark removed)"``."""
        return f"{SEPARATOR_NAMES[self.separator]}-separated, {self.encoding}"


@dataclass
class Table:
    """Columns read from a file, by the caller's name, with the 1-based file line of every row (header = 1).

    ``names`` maps each wanted name found to the file's own spelling of it. ``incomplete`` marks rows whose
    line was cut short (``short_rows="keep"`` only; their missing cells are NaN or empty text) and
    ``fields`` holds the number of fields of each such row (0 elsewhere).
    """

    path: Path
    header: list[str]
    columns: dict[str, np.ndarray]
    lines: np.ndarray
    notices: list[InputNotice] = field(default_factory=list)
    dialect: Dialect = Dialect("\t", "UTF-8")
    names: dict[str, str] = field(default_factory=dict)
    incomplete: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    fields: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    def __len__(self) -> int:
        return len(self.lines)


# --------------------------------------------------------------------------------------------------- hex


_HEX_LUT = np.full(256, 255, dtype=np.uint8)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX_LUT[_c] = _i
for _i, _c in enumerate(b"ABCDEF"):
    _HEX_LUT[_c] = 10 + _i


def _hex_or_none(text: object) -> int | None:
    if not isinstance(text, str) or not re.fullmatch(_HEX_TEXT, text):
        return None
    return int(text, 16)


def _parse_bare_hex(values: np.ndarray) -> np.ndarray | None:
    """Cells of 1-16 bare ASCII hex digits, vectorised over the joined text; None when any cell is not."""
    n = len(values)
    try:
        joined = "\n".join(values)
    except TypeError:
        return None
    if not joined.isascii():
        return None
    buf = np.frombuffer(joined.encode("ascii"), dtype=np.uint8)
    breaks = np.flatnonzero(buf == 10)
    if len(breaks) != n - 1:  # a cell holding a line break
        return None
    ends = np.empty(n, dtype=np.intp)
    ends[:-1] = breaks
    ends[-1] = len(buf)
    lengths = np.diff(ends, prepend=-1) - 1
    if lengths.min() < 1 or lengths.max() > 16:
        return None
    digits = _HEX_LUT[buf]
    digits[breaks] = 0
    if digits.max() > 15:
        return None
    # the last digit of every cell, then each earlier digit of the cells that have one, 4 bits further up
    out = digits[ends - 1].astype(np.uint64)
    for p in range(1, int(lengths.max())):
        live = np.flatnonzero(lengths > p)
        out[live] |= digits[ends[live] - 1 - p].astype(np.uint64) << np.uint64(4 * p)
    return out


def parse_hex(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hex-string parsing: the integers (uint64) and a mask of cells that are not hex.

    Accepted: 1 to 16 ASCII hex digits, a ``0x`` prefix, surrounding blanks. The common case (bare digits) is
    vectorised (``docs/performance.md``, "Tables"); anything else goes cell by cell.
    """
    values = np.asarray(values, dtype=object)
    if len(values) == 0:
        return np.zeros(0, np.uint64), np.zeros(0, bool)
    fast = _parse_bare_hex(values)
    if fast is not None:
        return fast, np.zeros(len(values), bool)
    checked = [_hex_or_none(text) for text in values]
    bad = np.array([value is None for value in checked], dtype=bool)
    return np.array([value or 0 for value in checked], dtype=np.uint64), bad


# ------------------------------------------------------------------------------------------------ opening


def _nul_error(path: Path, data: bytes, index: int, sep: str | None = None,
               header: list[str] | None = None) -> InputError:
    """A NUL byte at ``index`` of ``data`` (which starts at line 1)."""
    line = data.count(b"\n", 0, index) + 1
    column = None
    if header is not None and line > 1:
        start = data.rfind(b"\n", 0, index) + 1
        column = _column_at(data[start:index], sep, header)
    return InputError(path, line, column, f"a NUL byte (byte {index} of the file): this is not a text table "
                      "(a binary file, a damaged copy, or UTF-16 without a byte-order mark?)")


def _open_pipe(path: Path, wait_s: float = PIPE_WAIT_S) -> int:
    """A blocking descriptor on named pipe ``path`` once its writer has sent something or closed it.

    A plain ``open`` of a FIFO waits for a writer for ever; it is opened non-blocking instead (which never waits)
    and polled for at most ``wait_s`` [s]. Raises :class:`InputError` when nothing came in that time."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputError(path, None, None, f"cannot read the pipe: {exc.strerror or exc}") from None
    try:
        poller = select.poll()
        poller.register(fd, select.POLLIN)  # a writer that came and went shows as POLLHUP (always reported)
        if not poller.poll(max(wait_s, 0.0) * 1000.0):
            raise InputError(path, None, None, f"a named pipe (FIFO) and no writer appeared within {wait_s:g} s "
                             "(nothing was written to it): start the program that writes it, or give a file")
        os.set_blocking(fd, True)  # a writer is there: wait for the rest of its output as long as it takes
    except BaseException:
        os.close(fd)
        raise
    return fd


def _read_pipe(path: Path) -> bytes:
    """All bytes of a pipe (FIFO), refused at once when its first block is binary; :func:`_open_pipe` bounds the
    wait for a writer."""
    parts = []
    with open(_open_pipe(path), "rb") as handle:
        first = handle.read(_SNIFF)
        if b"\0" in first:
            raise _nul_error(path, first, first.index(b"\0"))
        parts.append(first)
        while block := handle.read(1 << 20):
            parts.append(block)
    return b"".join(parts)


@dataclass(frozen=True)
class InMemory:
    """The bytes of an input that can be read only once (a pipe), with the path they came from (for messages)."""

    path: Path
    data: bytes = field(repr=False)

    def __str__(self) -> str:
        return str(self.path)


Source = Path | str | InMemory


def source_path(source: Source) -> Path:
    """The path of a source, for messages."""
    return source.path if isinstance(source, InMemory) else Path(source)


def snapshot(source: Source) -> Path | InMemory:
    """A source that can be read more than once: a named pipe (FIFO) read into memory, any other path as it is.

    Use it before reading one input twice (e.g. its header to tell its format, then its table).
    """
    if isinstance(source, InMemory):
        return source
    path = Path(source)
    try:
        is_pipe = stat.S_ISFIFO(os.stat(path).st_mode)
    except OSError:
        return path
    if not is_pipe:
        return path
    data = _read_pipe(path)
    if not data:
        raise InputError(path, 1, None, "the pipe gave no data (no header line)")
    return InMemory(path, data)


#: the first bytes of a gzip stream
GZIP_MAGIC = b"\x1f\x8b"
#: a gunzipped input is held in memory up to this size, then spills to a temporary file [bytes]
_GUNZIP_IN_MEMORY = 64 << 20


def _gunzipped(path: Path, handle: BinaryIO) -> BinaryIO:
    """A seekable handle on the decompressed content of the gzip stream ``handle`` (closed here): in memory up to
    _GUNZIP_IN_MEMORY, in an unnamed temporary file beyond, so memory stays bounded whatever the size."""
    import gzip
    import shutil
    import tempfile
    import zlib

    out = tempfile.SpooledTemporaryFile(max_size=_GUNZIP_IN_MEMORY)  # noqa: SIM115 - returned open
    try:
        with handle, gzip.GzipFile(fileobj=handle) as stream:
            shutil.copyfileobj(stream, out, 1 << 20)
    except (OSError, EOFError, zlib.error) as exc:
        out.close()
        raise InputError(path, None, None, f"a gzip file that cannot be decompressed: {exc}") from None
    if out.tell() == 0:
        out.close()
        raise InputError(path, 1, None, "the gzip file holds nothing (no header line)")
    out.seek(0)
    return out  # type: ignore[return-value]


def _open_source(source: Source) -> BinaryIO:
    """A seekable binary handle on ``source`` (a gzip file's decompressed content); folders, devices, sockets and
    empty files are refused.

    A named pipe (FIFO, e.g. ``<(zcat POS.txt.gz)``) can be read only once, so it is read into memory.
    """
    handle = _open_raw(source)
    head = handle.read(2)
    handle.seek(0)
    if head == GZIP_MAGIC:
        return _gunzipped(source_path(source), handle)
    return handle


def read_bytes(source: Source) -> bytes:
    """All the bytes of ``source`` (decompressed when it is gzip), with :func:`_open_source`'s refusals."""
    with _open_source(source) as handle:
        return handle.read()


def _open_raw(source: Source) -> BinaryIO:
    """A seekable binary handle on ``source`` as it is (see :func:`_open_source`)."""
    if isinstance(source, InMemory):
        if not source.data:
            raise InputError(source.path, 1, None, "the file is empty (no header line)")
        return io.BytesIO(source.data)
    path = Path(source)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(path, None, None, "file not found") from None
    except OSError as exc:
        raise InputError(path, None, None, f"cannot read the file: {exc.strerror}") from None
    mode = st.st_mode
    if stat.S_ISDIR(mode):
        raise InputError(path, None, None, "is a folder, not a file")
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        raise InputError(path, None, None, "is a device, not a file")
    try:
        if stat.S_ISFIFO(mode):
            data = _read_pipe(path)
            if not data:
                raise InputError(path, 1, None, "the pipe gave no data (no header line)")
            return io.BytesIO(data)
        if not stat.S_ISREG(mode):
            raise InputError(path, None, None, "is not a regular file (a socket?)")
        if st.st_size == 0:
            raise InputError(path, 1, None, "the file is empty (no header line)")
        return open(path, "rb", buffering=0)  # noqa: SIM115 - closed by read_table
    except PermissionError:
        raise InputError(path, None, None, "cannot read the file: permission denied") from None
    except IsADirectoryError:
        raise InputError(path, None, None, "is a folder, not a file") from None


def _utf16_to_utf8(path: Path, handle: BinaryIO) -> BinaryIO:
    """A UTF-16 file (with its byte-order mark) converted to UTF-8 in memory."""
    handle.seek(0)
    data = handle.read()
    handle.close()
    try:
        text = data.decode("utf-16")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].decode("utf-16", errors="replace").count("\n") + 1
        raise InputError(path, line, None, f"byte {exc.start} is not valid UTF-16 (the file starts with a "
                         "UTF-16 byte-order mark)") from None
    encoded = text.encode("utf-8")
    if b"\0" in encoded:
        raise _nul_error(path, encoded, encoded.index(b"\0"))
    return io.BytesIO(encoded)


# ---------------------------------------------------------------------------------------------- separator


_BLANKS = re.compile(r"[ \t]+")


def _split(text: str, sep: str | None) -> list[str]:
    """Fields of a line: split at ``sep``, or (None) at runs of spaces and tabs, as pandas' C parser does."""
    if sep is not None:
        return text.split(sep)
    stripped = text.strip(" \t")
    return _BLANKS.split(stripped) if stripped else []


def _column_at(line_prefix: bytes, sep: str | None, header: list[str], marks: int = 0, in_word: bool = False) -> str:
    """The header name of the field in which a line's bytes ``line_prefix`` end.

    ``marks`` and ``in_word`` carry the state of the part of the line before ``line_prefix`` (separators or
    word starts seen, and whether it ended inside a word) when the line began in an earlier block.
    """
    if sep is None:
        words = re.findall(rb"[^ \t\r]+", line_prefix)
        continues = bool(line_prefix[:1]) and line_prefix[:1] not in b" \t\r" and in_word
        total = marks + len(words) - (1 if continues else 0)
        ends_in_word = (bool(line_prefix) and line_prefix[-1:] not in b" \t\r") or (not line_prefix and in_word)
        index = total - 1 if ends_in_word else total
    else:
        index = marks + line_prefix.count(sep.encode())
    return _field_name(header, max(index, 0))


def _field_name(header: list[str], index: int) -> str:
    if index < len(header):
        return header[index] or f"field {index + 1} (no name)"
    return f"field {index + 1} (the header has {len(header)})"


def _describe_counts(text: str) -> str:
    parts = [f"{text.count(sep)} {SEPARATOR_NAMES[sep]}{'s' if text.count(sep) != 1 else ''}"
             for sep in SEPARATORS if sep in text]
    return ", ".join(parts) if parts else "no tab, semicolon or comma"


def _detect_separator(path: Path, header_text: str, samples: list[tuple[int, str]]) -> str | None:
    """The separator of a table from its header line and a few data lines ``(line number, text)``."""
    candidates = [sep for sep in SEPARATORS if sep in header_text]
    if not candidates:
        chosen: str | None = None if len(_split(header_text, None)) > 1 else "\t"
    elif len(candidates) == 1:
        chosen = candidates[0]
    else:
        fitting = [sep for sep in candidates
                   if samples and all(len(_split(text, sep)) == len(_split(header_text, sep)) for _, text in samples)]
        if len(fitting) != 1:
            seen = " and ".join(SEPARATOR_NAMES[sep] for sep in fitting) if fitting else "none of them"
            last = samples[-1][0] if samples else 1
            raise InputError(path, 1, None, "cannot tell the separator: the header has "
                             f"{_describe_counts(header_text)}, and lines 2-{last} fit {seen}; use one separator "
                             "(tab, semicolon or comma)")
        chosen = fitting[0]
    # the data must be split the same way: a header with tabs over lines with semicolons is not guessed at
    n_fields = len(_split(header_text, chosen))
    for line, text in samples:
        if len(_split(text, chosen)) == n_fields:
            return chosen
        others = [sep for sep in (*SEPARATORS, None) if sep != chosen and len(_split(text, sep)) == n_fields
                  and len(_split(header_text, sep)) != n_fields]
        if others:
            raise InputError(path, line, None, f"the header (line 1) is {SEPARATOR_NAMES[chosen]}-separated into "
                             f"{n_fields} fields, but this line splits into {n_fields} fields only with "
                             f"{' or '.join(SEPARATOR_NAMES[s] for s in others)}; use one separator throughout")
        return chosen
    return chosen


# ------------------------------------------------------------------------------------------------ scanner


class _AbortError(Exception):
    """Raised inside pandas' read to stop it; ``problem`` (set by :func:`_parse`) says why."""

    problem: InputError


class _Scanner(io.RawIOBase):
    """A pass-through reader that checks every block pandas reads.

    It stops at a NUL byte, an undecodable byte, a carriage return inside a line or a line with more fields
    than the header, and records blank lines and lines with fewer fields (with their byte offsets). Field
    counts are vectorised with numpy (separator positions, or word starts for blank-separated files).
    """

    def __init__(self, handle: BinaryIO, path: Path, sep: str | None, header: list[str], offset: int,
                 check_clean: bool = False) -> None:
        super().__init__()
        #: whether every byte so far is one of ``_CLEAN_BYTES`` (looked at with ``check_clean`` only)
        self.clean = True
        self._check_clean = check_clean
        self._handle = handle
        self.path = path
        self.sep = sep
        self.header = header
        self.n_fields = len(header)
        self._sep_byte = None if sep is None else ord(sep)
        self.line = 2                  # number of the line being read
        self.line_start = offset       # its first byte
        self.offset = offset           # next byte to read
        self._marks = 0                # separators (or word starts) so far in the current line
        self._in_word = False          # whitespace mode: the previous byte was part of a word
        self._nonblank = False         # the current line has a non-blank byte so far
        self._pending_cr = False
        #: the bytes that end a field: the separator (blanks, for runs of blanks) and line ends
        self._break_bytes = (b" ", b"\t", b"\n", b"\r") if sep is None else (sep.encode(), b"\n", b"\r")
        self._field_chars = 0          # characters of the field the previous block ended in
        self._field_head = b""         # and its first bytes (for a message)
        self._decoder = codecs.getincrementaldecoder("utf-8")()
        self.short: list[tuple[int, int, int]] = []   # (line, fields, offset of its first byte)
        self.blank: list[int] = []
        self.problem: InputError | None = None
        self.n_lines = 0
        self.finished = False

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:  # type: ignore[override]
        n = self._handle.readinto(buffer)
        if not n:
            self._finish()
            return 0
        self._check(bytes(memoryview(buffer)[:n]))
        self.offset += n
        return n

    # -- locating
    def _fail(self, chunk: bytes, index: int, message: str) -> None:
        """Stop at byte ``index`` of ``chunk`` (negative: the end of the previous block)."""
        index = max(index, 0)
        before = chunk[:index]
        newlines = before.count(b"\n")
        if newlines:
            prefix = before[before.rfind(b"\n") + 1:]
            column = _column_at(prefix, self.sep, self.header)
        else:
            column = _column_at(before, self.sep, self.header, self._marks, self._in_word)
        self.problem = InputError(self.path, self.line + newlines, column, message)
        raise _AbortError(message)

    # -- checks of one block
    def _check(self, chunk: bytes) -> None:
        if self._check_clean and self.clean and chunk.translate(None, _CLEAN_BYTES):
            self.clean = False
        nul = chunk.find(b"\0")
        if nul >= 0:
            self._fail(chunk, nul, f"a NUL byte (byte {self.offset + nul} of the file): not text (a damaged copy, "
                                   "or binary data?)")
        pending = self._decoder.getstate()[0]
        if pending or not chunk.isascii():
            try:
                self._decoder.decode(chunk)
            except UnicodeDecodeError as exc:
                index = exc.start - len(pending)
                bad = chunk[max(index, 0)]
                self._fail(chunk, index, f"byte 0x{bad:02x} (byte {self.offset + max(index, 0)} of the file) is not "
                                         "UTF-8 text; save the file as UTF-8")
        a = np.frombuffer(chunk, dtype=np.uint8)
        if self._pending_cr and a[0] != 10:
            self._fail(chunk, -1, "a carriage return (CR) inside a line; lines must end in LF or CR LF")
        if b"\r" in chunk:
            cr = np.flatnonzero(a == 13)
            follows = cr + 1 < len(a)
            lone = cr[follows][a[cr[follows] + 1] != 10]
            if len(lone):
                self._fail(chunk, int(lone[0]), "a carriage return (CR) inside a line; lines must end in LF or CR LF")
            self._pending_cr = bool(a[-1] == 13)
        else:
            self._pending_cr = False
        newlines = np.flatnonzero(a == 10)
        self._check_field_lengths(chunk, a, newlines)
        self._count_fields(chunk, a, newlines)

    def _breaks(self, a: np.ndarray) -> np.ndarray:
        """Mask of the bytes that end a field (:attr:`_break_bytes`)."""
        if self.sep is None:
            return (a == 32) | (a == 9) | (a == 10) | (a == 13)
        return (a == self._sep_byte) | (a == 10) | (a == 13)

    def _check_field_lengths(self, chunk: bytes, a: np.ndarray, newlines: np.ndarray) -> None:
        """Stop at the first field of more than :data:`MAX_FIELD_CHARS` characters (UTF-8 continuation bytes not
        counted) before it is handed on, so that no reader holds more of it than a block. Only where a line is
        longer than that in bytes (never fewer than its characters) are its fields looked at."""
        before = self.offset - self.line_start  # bytes of the current line in earlier blocks
        if len(newlines):
            longest = max(before + int(newlines[0]), int(np.diff(newlines).max(initial=1)) - 1,
                          len(a) - 1 - int(newlines[-1]))
        else:
            longest = before + len(a)
        if longest > MAX_FIELD_CHARS:
            self._check_fields(chunk, a)
        tail = max(chunk.rfind(byte) for byte in self._break_bytes) + 1
        self._field_chars = _chars(a[tail:]) + (self._field_chars if tail == 0 else 0)
        self._field_head = ((self._field_head if tail == 0 else b"") + chunk[tail:tail + 4 * EXCERPT_CHARS])[
            :4 * EXCERPT_CHARS]

    def _check_fields(self, chunk: bytes, a: np.ndarray) -> None:
        """:meth:`_check_field_lengths` field by field: in bytes first, in characters where that is too many."""
        ends = np.flatnonzero(self._breaks(a))
        bounds = np.concatenate(([-1], ends, [len(a)]))
        spans = np.diff(bounds) - 1
        spans[0] += self._field_chars
        for k in np.flatnonzero(spans > MAX_FIELD_CHARS).tolist():
            begin = int(bounds[k]) + 1
            chars = _chars(a[begin:int(bounds[k + 1])]) + (self._field_chars if k == 0 else 0)
            if chars > MAX_FIELD_CHARS:
                self._long_field(chunk, begin, chars + (self._count_rest() if k == len(ends) else 0),
                                 self._field_head if k == 0 else b"")

    def _long_field(self, chunk: bytes, begin: int, total: int, earlier: bytes) -> None:
        """Stop at a field of ``total`` characters that starts at byte ``begin`` of ``chunk`` (or, with
        ``earlier``, its first bytes, in an earlier block)."""
        head = (earlier + chunk[begin:begin + 4 * EXCERPT_CHARS]).decode("utf-8", errors="replace")[:EXCERPT_CHARS]
        self._fail(chunk, begin, f"field of {total} characters, at most {MAX_FIELD_CHARS}: {head!r}… ({total} "
                                 "characters)")

    def _count_rest(self) -> int:
        """Characters of the field the current block ends in that follow the block (read on, 1 MiB at a time, up
        to its end); the scanner stops after this, so what it reads is not handed on."""
        total = 0
        while block := self._handle.read(1 << 20):
            a = np.frombuffer(block, dtype=np.uint8)
            brk = np.flatnonzero(self._breaks(a))
            total += _chars(a[: brk[0]] if len(brk) else a)
            if len(brk):
                break
        return total

    def _count_fields(self, chunk: bytes, a: np.ndarray, newlines: np.ndarray) -> None:
        if self.sep is None:
            brk = (a == 32) | (a == 9) | (a == 13) | (a == 10)
            before = np.empty(len(a), dtype=bool)
            before[0] = not self._in_word
            before[1:] = brk[:-1]
            marks = ~brk & before
            extra = 0
        else:
            marks = a == self._sep_byte
            extra = 1
        if len(newlines) == 0:
            self._marks += int(np.count_nonzero(marks))
            self._nonblank = self._nonblank or bool(chunk.strip())
            self._in_word = bool(a[-1] not in (32, 9, 13, 10))
            return
        last = int(newlines[-1])
        starts = np.empty(len(newlines), dtype=np.intp)
        starts[0] = 0
        starts[1:] = newlines[:-1] + 1
        counts = np.add.reduceat(marks[: last + 1], starts, dtype=np.int64)
        counts[0] += self._marks
        fields = counts + extra
        odd = np.flatnonzero(fields != self.n_fields)
        for k in odd.tolist():
            start = self.line_start if k == 0 else self.offset + int(starts[k])
            self._anomaly(chunk, k, int(fields[k]), start, newlines)
        self.n_lines += len(newlines)
        self.line += len(newlines)
        self.line_start = self.offset + last + 1
        self._marks = int(np.count_nonzero(marks[last + 1:]))
        tail = chunk[last + 1:]
        self._nonblank = bool(tail.strip())
        self._in_word = bool(tail) and a[-1] not in (32, 9, 13, 10)

    def _anomaly(self, chunk: bytes, k: int, fields: int, start: int, newlines: np.ndarray) -> None:
        line = self.line + k
        if fields > self.n_fields:
            begin = 0 if k == 0 else int(newlines[k - 1]) + 1
            text = chunk[begin:int(newlines[k])]
            cut = _nth_separator(text, self.sep, self.n_fields)
            offset = begin + cut if cut is not None else begin
            self._fail(chunk, offset, f"{fields} fields, but the header has {self.n_fields}: a separator too many "
                                      "(or two lines run together?)")
        if fields <= 1:
            begin = 0 if k == 0 else int(newlines[k - 1]) + 1
            content = bool(chunk[begin:int(newlines[k])].strip()) or (k == 0 and self._nonblank)
            if not content:
                self.blank.append(line)
                self._check_count()
                return
        self.short.append((line, fields, start))
        self._check_count()

    def _check_count(self) -> None:
        if len(self.short) + len(self.blank) > _MAX_ANOMALIES:
            line = self.short[0][0] if self.short else self.blank[0]
            self.problem = InputError(self.path, line, None, f"more than {_MAX_ANOMALIES} lines are blank or have "
                                      f"fewer fields than the header ({self.n_fields}), from this line on: is the "
                                      f"separator right ({SEPARATOR_NAMES[self.sep]})?")
            raise _AbortError("too many short lines")

    def _finish(self) -> None:
        if self.finished:
            return
        self.finished = True
        try:
            self._decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            self.problem = InputError(self.path, self.line, None, "the file ends inside a UTF-8 character "
                                      "(cut short?)")
            raise _AbortError("incomplete UTF-8") from None
        if self.offset > self.line_start:
            # an unterminated last line (a trailing lone CR is its line end)
            fields = self._marks + (1 if self.sep is not None else 0)
            if fields > self.n_fields:
                self.problem = InputError(self.path, self.line, _field_name(self.header, self.n_fields),
                                          f"{fields} fields, but the header has {self.n_fields}")
                raise _AbortError("too many fields")
            if not self._nonblank:
                self.blank.append(self.line)
            elif fields < self.n_fields:
                self.short.append((self.line, fields, self.line_start))
            self.n_lines += 1


def _chars(a: np.ndarray) -> int:
    """Characters in UTF-8 bytes ``a``: the bytes that are not continuation bytes (0b10xxxxxx)."""
    return int(np.count_nonzero((a & 0xC0) != 0x80))


def _nth_separator(text: bytes, sep: str | None, n: int) -> int | None:
    """Byte index of the start of field ``n`` (0-based) of a line, or None."""
    decoded = text.decode("utf-8", errors="replace")
    if sep is None:
        matches = list(re.finditer(r"[^ \t]+", decoded))
        return len(decoded[: matches[n].start()].encode()) if len(matches) > n else None
    parts = decoded.split(sep)
    return len(sep.join(parts[:n]).encode()) + 1 if len(parts) > n else None


def _line_at(handle: BinaryIO, offset: int, limit: int = _LINE_PEEK) -> tuple[str, bool]:
    """The text of the line starting at byte ``offset`` (at most ``limit`` bytes) and whether it is whole."""
    handle.seek(offset)
    data = handle.read(limit + 1)
    end = data.find(b"\n")
    whole = end >= 0 or len(data) <= limit
    data = data[:end] if end >= 0 else data[:limit]
    return data.rstrip(b"\r").decode("utf-8", errors="replace"), whole


def _line_offset(handle: BinaryIO, start: int, first_line: int, wanted: int) -> int | None:
    """Byte offset of file line ``wanted``, counting from byte ``start`` (which begins line ``first_line``)."""
    handle.seek(start)
    line, position = first_line, start
    if line == wanted:
        return start
    while block := handle.read(1 << 20):
        if line + block.count(b"\n") >= wanted:
            k = 0
            while (found := block.find(b"\n", k)) >= 0:
                line += 1
                if line == wanted:
                    return position + found + 1
                k = found + 1
        line += block.count(b"\n")
        position += len(block)
    return None


# --------------------------------------------------------------------------------------------------- cells


def _cell_problem(text: str, kind: Kind, sep: str | None) -> str:
    """Why ``text`` is not a valid cell of ``kind``, for a message (with the cell's excerpt)."""
    message = f"cannot read {excerpt(text)} as {_KIND_WORDS.get(kind, kind)}"
    stripped = text.strip()
    hints = []
    if '"' in text or "'" in text:
        hints.append("quotes are not part of this format")
    if stripped.lower().lstrip("+-") in ("inf", "infinity", "nan"):
        hints.append("not a finite number")
    elif kind != "hex" and re.fullmatch(_FLOAT_TEXT, text) and not np.isfinite(float(stripped)):
        hints.append("too large: not a finite number")
    if any(ch.isdigit() and not ch.isascii() for ch in text):
        hints.append("digits must be ASCII 0-9")
    elif not text.isascii():
        hints.append("it holds non-ASCII characters")
    if kind == "float" and "," in stripped and sep != "," and re.fullmatch(_FLOAT_TEXT, stripped.replace(",", ".")):
        hints.append("a decimal comma? use a decimal point")
    if any(ord(ch) < 32 or ord(ch) == 127 for ch in text):
        hints.append("it holds a control character")
    return message + (f" ({'; '.join(hints)})" if hints else "")


def _bad_cells(text: pd.Series, kind: Kind) -> np.ndarray:
    """Mask of non-empty cells of ``text`` (strings, NaN = empty) that are not valid ``kind``."""
    import pandas as pd

    present = text.notna().to_numpy()
    if kind == "str":
        return present & text.str.contains(_BAD_TEXT, regex=True, na=False).to_numpy()
    pattern = _HEX_TEXT if kind == "hex" else _FLOAT_TEXT
    fits = text.str.fullmatch(pattern, na=True).to_numpy(dtype=bool)
    bad = present & ~fits
    if kind in ("float", "int"):
        numbers = pd.to_numeric(text.where(fits & present), errors="coerce").to_numpy(dtype=float)
        with np.errstate(invalid="ignore"):
            bad |= present & fits & ~np.isfinite(numbers)
            if kind == "int":
                bad |= present & fits & np.isfinite(numbers) & (numbers % 1 != 0)
    return bad


def _str_problem(text: str) -> str:
    if '"' in text:
        return (f"{excerpt(text)} holds a double quote; quotes are not special in this format and are not part "
                "of a value: remove it")
    return f"{excerpt(text)} holds a control character"


# ----------------------------------------------------------------------------------------------- the reader


@dataclass
class _Layout:
    path: Path
    handle: BinaryIO
    header: list[str]
    dialect: Dialect
    data_start: int
    index: dict[str, int]


def _layout(source: Source, wanted: dict[str, Kind], required: list[str],
            sep: str | None | Literal["auto"]) -> _Layout:
    """Open the file, check it is text, read its header, find the separator and the wanted columns."""
    path = source_path(source)
    handle = _open_source(source)
    try:
        return _read_layout(path, handle, wanted, required, sep)
    except BaseException:
        handle.close()
        raise


def _read_layout(path: Path, handle: BinaryIO, wanted: dict[str, Kind], required: list[str],
                 sep: str | None | Literal["auto"]) -> _Layout:
    """:func:`_layout` on an open ``handle``: the head decoded, the header line read, the separator found (or
    ``sep``), the wanted columns located and the required ones checked."""
    head = _Head.read(path, handle)
    handle = head.handle
    end = head.data.find(b"\n", head.start)
    if end < 0:
        if b"\r" in head.data:
            raise InputError(path, 1, None, "lines end in a lone carriage return (CR, classic Mac OS); save the file "
                             "with LF or CR LF line ends")
        if len(head.data) == _SNIFF:
            raise InputError(path, 1, None, f"no line end in the first {_SNIFF // 1024} KiB: not a table with a "
                             "header line")
        raise InputError(path, 2, None, "no data rows after the header")
    header_text = _header_text(path, head.data[head.start:end])
    data_start = end + 1
    samples = _sample_lines(head.data, data_start, whole=len(head.data) < _SNIFF)
    if not samples and not _has_data(handle, data_start):
        raise InputError(path, 2, None, "no data rows after the header")
    chosen = _detect_separator(path, header_text, samples) if sep == "auto" else sep
    header = [name.strip().strip("\ufeff").strip() for name in _split(header_text, chosen)]
    index = _column_index(path, header, wanted)
    missing = [name for name in required if name not in index]
    if missing:
        found = ", ".join(name for name in header if name)
        if len(found) > 300:
            found = found[:300] + f"… ({len(header)} columns)"
        raise InputError(path, 1, missing[0], f"required column {missing[0]!r} is missing (columns found, "
                         f"{SEPARATOR_NAMES[chosen]}-separated: {found})")
    dialect = Dialect(chosen, head.encoding)
    return _Layout(path, handle, header, dialect, data_start, index)


@dataclass(frozen=True)
class _Head:
    """The first :data:`_SNIFF` bytes of a table (``data``, UTF-8), the ``handle`` to read on (UTF-16 converted),
    where the header starts (``start``: after a byte-order mark) and the encoding as told to the user."""

    handle: BinaryIO
    data: bytes
    start: int
    encoding: str

    @staticmethod
    def read(path: Path, handle: BinaryIO) -> _Head:
        """The head of ``handle``: a UTF-8 byte-order mark passed over, UTF-16 converted; a NUL byte is an error."""
        head = handle.read(_SNIFF)
        encoding = "UTF-8"
        start = 0
        if head.startswith(_UTF8_BOM):
            start, encoding = len(_UTF8_BOM), "UTF-8 (byte-order mark removed)"
        elif head[:2] in _UTF16_BOMS:
            handle = _utf16_to_utf8(path, handle)
            head = handle.read(_SNIFF)
            if head.startswith(_UTF8_BOM):
                start = len(_UTF8_BOM)
            encoding = "UTF-16 (converted to UTF-8)"
        if b"\0" in head:
            raise _nul_error(path, head, head.index(b"\0"))
        return _Head(handle=handle, data=head, start=start, encoding=encoding)


def _header_text(path: Path, header_bytes: bytes) -> str:
    """The header line (without its line end) as text; a carriage return inside it, a byte that is not UTF-8 or a
    blank header is an error."""
    if header_bytes.endswith(b"\r"):
        header_bytes = header_bytes[:-1]
    if b"\r" in header_bytes:
        raise InputError(path, 1, None, "a carriage return (CR) inside the header line; lines must end in LF or "
                         "CR LF (classic Mac OS line ends?)")
    try:
        header_text = header_bytes.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, 1, None, f"byte 0x{header_bytes[exc.start]:02x} of the header is not UTF-8 text; "
                         "save the file as UTF-8") from None
    if not header_text.strip():
        raise InputError(path, 1, None, "the header line is blank")
    return header_text


def _column_index(path: Path, header: list[str], wanted: dict[str, Kind]) -> dict[str, int]:
    """The field of each wanted name found in ``header`` (names matched ignoring case); two fields matching one
    name are an error."""
    folded: dict[str, list[int]] = {}
    for i, name in enumerate(header):
        folded.setdefault(name.casefold(), []).append(i)
    index: dict[str, int] = {}
    for name in wanted:
        hits = folded.get(name.strip().casefold(), [])
        if len(hits) > 1:
            spelled = ", ".join(f"{header[i]!r} (field {i + 1})" for i in hits)
            raise InputError(path, 1, name, f"{len(hits)} columns match this name: {spelled}; names are matched "
                             "ignoring case, so rename or remove one")
        if hits:
            index[name] = hits[0]
    return index


def _sample_lines(head: bytes, start: int, whole: bool, count: int = 5) -> list[tuple[int, str]]:
    """Up to ``count`` non-blank data lines of the sniffed head (``whole``: the head is the whole file)."""
    samples = []
    lines = head[start:].split(b"\n")
    if not whole:
        lines = lines[:-1]  # the last piece may be cut
    for k, raw in enumerate(lines):
        text = raw.rstrip(b"\r").decode("utf-8", errors="replace")
        if text.strip():
            samples.append((k + 2, text))
            if len(samples) == count:
                break
    return samples


def _has_data(handle: BinaryIO, start: int) -> bool:
    """Whether anything but blanks follows byte ``start``."""
    handle.seek(start)
    while block := handle.read(1 << 20):
        if block.strip():
            return True
    return False


def peek_header(source: Source) -> list[str]:
    """The header names of a table file (BOM removed, separator detected, blanks stripped), nothing else read.

    A pipe is consumed: pass a :func:`snapshot` of it when the table is to be read afterwards.
    """
    layout = _layout(source, {}, [], "auto")
    layout.handle.close()
    return layout.header


def read_table(
    path: Source,
    wanted: dict[str, Kind],
    required: Iterable[str],
    sep: str | None | Literal["auto"] = "auto",
    short_rows: Literal["error", "keep"] = "error",
) -> Table:
    """Read the ``wanted`` columns (name -> kind; names matched ignoring case) of a header-led text table.

    * A missing required column, a cell that is not of its kind, an empty cell in a column that is read, a
      non-finite number, or a line with more fields than the header raises :class:`InputError` naming file,
      line and column.
    * A line with fewer fields than the header: the last line is dropped with a notice; any other is an
      error. With ``short_rows="keep"`` every such line is kept and marked in ``Table.incomplete``.
    * Blank lines are dropped (with a notice when they are not at the end).
    * Optional columns that are absent are simply not in ``Table.columns``.
    """
    ordered_required = [name for name in wanted if name in set(required)]
    layout = _layout(path, wanted, ordered_required, sep)
    try:
        return _read_body(layout, wanted, short_rows)
    finally:
        layout.handle.close()


def _read_csv(source: BinaryIO, layout: _Layout, usecols: list[int] | None, dtypes: dict[int, type],
              **options: object) -> pd.DataFrame:
    import pandas as pd

    sep = layout.dialect.separator
    return pd.read_csv(source, sep=r"\s+" if sep is None else sep, header=None, names=list(range(len(layout.header))),
                       usecols=usecols, dtype=dtypes, quoting=csv.QUOTE_NONE, skip_blank_lines=False,
                       skipinitialspace=True, keep_default_na=False, na_values=[""], engine="c", index_col=False,
                       encoding="utf-8", **options)


def _parse(layout: _Layout, usecols: list[int], dtypes: dict[int, type]) -> tuple[pd.DataFrame, _Scanner]:
    """pandas' C parser on the wanted columns, through a :class:`_Scanner`.

    When no line has as many fields as the header, the C parser refuses ``usecols`` ("Too many columns
    specified"); then every column is read (as text where not wanted), which only such a file pays for.
    """
    import pandas as pd

    for attempt in ("wanted", "all"):
        layout.handle.seek(layout.data_start)
        scanner = _Scanner(layout.handle, layout.path, layout.dialect.separator, layout.header, layout.data_start)
        columns = usecols if attempt == "wanted" else None
        types = dtypes if attempt == "wanted" else {i: dtypes.get(i, str) for i in range(len(layout.header))}
        try:
            frame = _read_csv(scanner, layout, columns, types)
        except _AbortError as stop:
            stop.problem = scanner.problem  # type: ignore[assignment]
            raise
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError, OverflowError) as exc:
            if scanner.problem is not None:
                stop = _AbortError(str(exc))
                stop.problem = scanner.problem
                raise stop from None
            if attempt == "wanted" and str(exc).startswith("Too many columns specified"):
                continue
            raise
        return frame, scanner
    raise AssertionError("unreachable")


#: bytes of a clean file (:func:`_parse_clean`): printable ASCII but the double quote, tab, line ends
_CLEAN_BYTES = bytes(range(32, 127)).replace(b'"', b"") + b"\t\n\r"
#: text widths [characters] numpy reads a hex and a text cell into; a cell that fills one goes to pandas
_HEX_WIDTH, _STR_WIDTH = 24, 64


#: numpy's ``loadtxt`` is slower per MB than pandas, whose import costs a fixed time, and its peak memory is higher:
#: larger files go to pandas (docs/performance.md, "Tables")
_LOADTXT_MAX_BYTES = 16 << 20
#: bytes handed to the compiled reader at a time (whole lines)
_KERNEL_BLOCK = 1 << 23
_KERNEL_KINDS = {"float": 0, "int": 0, "hex": 1, "str": 2}  # georef.io.table_kernel's FLOAT, HEX, TEXT


@functools.cache
def _table_kernel() -> Callable:
    from georef import aot

    return aot.load("table").parse_block


def _parse_clean(layout: _Layout, kinds: dict[int, Kind]) -> tuple[dict[int, np.ndarray], int] | None:
    """The wanted columns (file column -> kind) of a clean file and its number of rows: by the compiled reader
    (:mod:`georef.io.table_kernel`), else by numpy's ``loadtxt``; None when the file is not clean, and the caller
    reads it with pandas, which gives every message. Hex columns come converted (uint64)."""
    if not kinds:
        return None
    return _parse_compiled(layout, kinds) or _parse_loadtxt(layout, kinds)


def _parse_compiled(layout: _Layout, kinds: dict[int, Kind]) -> tuple[dict[int, np.ndarray], int] | None:
    """:func:`_parse_clean` by the compiled reader, in blocks of whole lines; None when a block holds a byte
    outside printable ASCII (tab and line ends aside) or a double quote, or the kernel stops at anything (see
    :mod:`georef.io.table_kernel`: a line with another number of fields, a blank line, a number outside its exact
    fast path, ...)."""
    wanted = sorted(kinds)
    slot = np.full(len(layout.header), -1, dtype=np.int64)
    slot[wanted] = np.arange(len(wanted))
    kind = np.array([_KERNEL_KINDS[kinds[i]] for i in wanted], dtype=np.int64)
    sep = -1 if layout.dialect.separator is None else ord(layout.dialect.separator)
    parse = _table_kernel()
    layout.handle.seek(layout.data_start)
    numbers, texts = [], {i: [] for i in wanted if kinds[i] == "str"}
    # the longest line of the header's fields, none longer than the limit (and a CR): a longer one is not clean
    longest = len(layout.header) * (MAX_FIELD_CHARS + 1) + 1
    carry = b""
    while True:
        block = layout.handle.read(_KERNEL_BLOCK)
        data = carry + block
        if block:
            cut = data.rfind(b"\n") + 1
            if len(data) - cut > longest:
                return None
            if cut == 0:
                carry = data
                continue
            data, carry = data[:cut], data[cut:]
        elif not data:
            break
        if data.translate(None, _CLEAN_BYTES):
            return None
        lines = data.count(b"\n") + (0 if data.endswith(b"\n") else 1)
        values, starts, ends, status = parse(np.frombuffer(bytearray(data), dtype=np.uint8), len(data), sep,
                                             len(layout.header), slot, kind, lines)
        if status[0] != 0:
            return None
        numbers.append(values)
        for i, cells in texts.items():
            k = int(slot[i])
            cells += [data[a:b].decode("ascii") for a, b in zip(starts[:, k].tolist(), ends[:, k].tolist(),
                                                                    strict=True)]
        if not block:
            break
    if not numbers:
        return None
    frame: dict[int, np.ndarray] = {}
    for k, i in enumerate(wanted):  # column by column from the blocks: one copy of the numbers at a time
        if kinds[i] == "str":
            frame[i] = np.asarray(texts[i], dtype=str)
        else:
            column = np.concatenate([block[:, k] for block in numbers])
            frame[i] = column.astype(np.uint64) if kinds[i] == "hex" else column
    return frame, sum(len(block) for block in numbers)


def _parse_loadtxt(layout: _Layout, kinds: dict[int, Kind]) -> tuple[dict[int, np.ndarray], int] | None:
    """:func:`_parse_clean` by numpy's ``loadtxt`` through a :class:`_Scanner`; None when a line has another
    number of fields than the header or is blank, a byte is outside printable ASCII (tab and line ends aside)
    or a double quote, numpy refuses a cell, a number is not finite, or a text cell has leading blanks (pandas
    drops them) or fills its width; None also for a file of more than :data:`_LOADTXT_MAX_BYTES`, which pandas
    reads faster."""
    if layout.handle.seek(0, io.SEEK_END) - layout.data_start > _LOADTXT_MAX_BYTES:
        return None
    usecols = sorted(kinds)
    width = {"hex": _HEX_WIDTH, "str": _STR_WIDTH}
    dtype = [(str(i), np.float64 if kinds[i] in ("float", "int") else f"U{width[kinds[i]]}") for i in usecols]
    layout.handle.seek(layout.data_start)
    scanner = _Scanner(layout.handle, layout.path, layout.dialect.separator, layout.header, layout.data_start,
                       check_clean=True)
    text = io.TextIOWrapper(io.BufferedReader(scanner, _BLOCK), encoding="utf-8", newline=None)
    try:
        data = np.loadtxt(text, dtype=dtype, delimiter=layout.dialect.separator, comments=None, usecols=usecols,
                          ndmin=1, quotechar=None)
    except (ValueError, _AbortError, UnicodeDecodeError, OverflowError):
        return None
    if (not scanner.finished or scanner.problem is not None or scanner.short or scanner.blank
            or not scanner.clean or len(data) != scanner.n_lines):
        return None
    frame = {}
    for i in usecols:
        column = np.array(data[str(i)])
        if kinds[i] in ("float", "int"):
            if not np.all(np.isfinite(column)):
                return None
        elif len(column) and (np.char.str_len(column).max() >= width[kinds[i]]
                              or np.any(np.char.startswith(column, " ") | np.char.startswith(column, "\t"))):
            return None
        frame[i] = column
    return frame, scanner.n_lines


def _is_missing(values: np.ndarray) -> np.ndarray:
    """Missing cells of a text column: none in numpy's text (``"U"``), None or NaN in pandas' objects."""
    if values.dtype.kind == "U":
        return np.zeros(len(values), dtype=bool)
    import pandas as pd  # an object column comes from pandas: already imported

    return np.asarray(pd.isna(values), dtype=bool)


def _read_body(layout: _Layout, wanted: dict[str, Kind], short_rows: str) -> Table:
    """The data rows of ``layout``'s file: the wanted columns checked and converted, blank and cut-short lines
    handled (:func:`_kept_rows`)."""
    header, index = layout.header, layout.index
    present = [name for name in wanted if name in index]
    usecols = sorted(index[name] for name in present)
    clean = _parse_clean(layout, {index[name]: wanted[name] for name in present})
    if clean is not None:
        frame, n_rows = clean  # no blank or short line, by definition
        kept = _kept_rows(layout, n_rows, [], [], short_rows)
    else:
        frame, scanner = _parse_with_pandas(layout, wanted, present, usecols)
        n_rows = len(frame)
        if n_rows != scanner.n_lines:
            raise RuntimeError(f"{layout.path}: pandas read {n_rows} rows, the line scan found {scanner.n_lines}")
        kept = _kept_rows(layout, n_rows, scanner.blank, scanner.short, short_rows)
    columns: dict[str, np.ndarray] = {}
    rows = kept.rows
    every_row = len(rows) == n_rows
    for name in present:
        values = np.asarray(frame[index[name]])
        if not every_row:
            values = values[rows]
        columns[name] = _checked_column(layout, name, wanted[name], values, kept)
    return Table(path=layout.path, header=header, columns=columns, lines=kept.lines[rows], notices=kept.notices,
                 dialect=layout.dialect, names={name: header[index[name]] for name in present},
                 incomplete=kept.incomplete[rows], fields=kept.n_fields[rows])


@dataclass(frozen=True)
class _KeptRows:
    """Which parsed rows a table keeps: ``lines`` the file line of every parsed row (header = 1), ``rows`` the
    kept ones (indices), ``incomplete`` and ``n_fields`` the cut-short rows kept (``short_rows="keep"``) with their
    number of fields, ``notices`` about the lines skipped or dropped."""

    lines: np.ndarray
    rows: np.ndarray
    incomplete: np.ndarray
    n_fields: np.ndarray
    notices: list[InputNotice]


def _kept_rows(layout: _Layout, n_rows: int, blank_lines: list[int], short_lines: list[tuple[int, int, int]],
               short_rows: str) -> _KeptRows:
    """Blank lines dropped (a notice for those before the last data line); lines with fewer fields than the header
    (``short_lines``: line, fields, byte offset) kept and marked (``short_rows="keep"``), dropped with a notice when
    last, else an error."""
    path, header = layout.path, layout.header
    sep = layout.dialect.separator
    lines = np.arange(2, n_rows + 2)
    keep = np.ones(n_rows, dtype=bool)
    notices: list[InputNotice] = []
    blank = np.asarray(blank_lines, dtype=int)
    if len(blank):
        keep[blank - 2] = False
    if not keep.any():
        raise InputError(path, 2, None, "no data rows after the header")
    last_line = int(lines[keep][-1])
    if len(blank):
        interior = blank[blank < last_line]
        if len(interior):
            notices.append(InputNotice(path, interior.tolist(), None, "blank lines skipped"))

    incomplete = np.zeros(n_rows, dtype=bool)
    n_fields = np.zeros(n_rows, dtype=int)
    for line, fields, start in short_lines:
        text, _ = _line_at(layout.handle, start)
        other = [s for s in (*SEPARATORS, None) if s != sep and len(_split(text, s)) == len(header)]
        missing_column = _field_name(header, fields)
        if other:
            raise InputError(path, line, missing_column, f"{fields} of {len(header)} fields with the header's "
                             f"{SEPARATOR_NAMES[sep]} separator, but {len(header)} with "
                             f"{' or '.join(SEPARATOR_NAMES[s] for s in other)}: use one separator throughout")
        if short_rows == "keep":
            incomplete[line - 2] = True
            n_fields[line - 2] = fields
        elif line == last_line:
            keep[line - 2] = False
            notices.append(InputNotice(path, [line], None, f"truncated last line ({fields} of {len(header)} "
                                       "fields) dropped"))
        else:
            raise InputError(path, line, missing_column, f"the line is cut short: {fields} of {len(header)} fields "
                             f"(from column {missing_column!r} on nothing is there)")
    if not keep.any():
        raise InputError(path, 2, None, "no complete data rows after the header")
    return _KeptRows(lines=lines, rows=np.flatnonzero(keep), incomplete=incomplete, n_fields=n_fields,
                     notices=notices)


def _checked_column(layout: _Layout, name: str, kind: Kind, values: np.ndarray, kept: _KeptRows) -> np.ndarray:
    """Column ``name``'s ``values`` at the kept rows, checked (no empty cell but in cut-short rows, every cell of
    its kind) and converted: float64 numbers, uint64 hex, text."""
    path, sep = layout.path, layout.dialect.separator
    spelled = layout.header[layout.index[name]]
    rows, lines = kept.rows, kept.lines
    complete = ~kept.incomplete[rows]
    # every column that is read is used: an empty cell is never silently a NaN (cut-short rows excepted)
    if kind in ("float", "int"):
        values = np.asarray(values, dtype=np.float64)
        empty = np.isnan(values)
    elif values.dtype == np.uint64:  # hex, converted by the compiled reader
        empty = np.zeros(len(values), dtype=bool)
    else:
        empty = _is_missing(values) | (values == "")
    if not complete.all():
        empty &= complete
    if np.any(empty):
        row = int(np.argmax(empty))
        raise InputError(path, int(lines[rows[row]]), spelled, "empty cell")
    if kind == "hex" and values.dtype == np.uint64:
        return values
    if kind == "hex":
        parsed, bad = parse_hex(np.where(_is_missing(values), "0", values))
        if bad.any():
            row = int(np.argmax(bad))
            raise InputError(path, int(lines[rows[row]]), spelled, _cell_problem(str(values[row]), kind, sep))
        return parsed
    if kind in ("float", "int"):
        _check_numbers(layout, name, kind, values, kept)
        return values
    cells = np.where(_is_missing(values), "", values).tolist()
    bad = [row for row, cell in enumerate(cells) if _BAD_TEXT.search(cell)]
    if bad:
        raise InputError(path, int(lines[rows[bad[0]]]), spelled, _str_problem(str(values[bad[0]])))
    return np.asarray(cells, dtype=str)


def _check_numbers(layout: _Layout, name: str, kind: Kind, values: np.ndarray, kept: _KeptRows) -> None:
    """An infinite number (quoted from its line in the file) or, in a whole-number column, a fraction is an
    error naming its line and column."""
    path, sep, column = layout.path, layout.dialect.separator, layout.index[name]
    spelled = layout.header[column]
    rows, lines = kept.rows, kept.lines
    infinite = np.isinf(values)
    if infinite.any():
        row = int(np.argmax(infinite))
        line = int(lines[rows[row]])
        offset = _line_offset(layout.handle, layout.data_start, 2, line)
        text, whole = _line_at(layout.handle, offset, 1 << 20) if offset is not None else ("", True)
        fields = _split(text, sep)
        cell = fields[column] if column < len(fields) else str(values[row])
        if not whole and column >= len(fields) - 1:
            cell += "…"  # cut at 1 MiB: the excerpt says "more than"
        raise InputError(path, line, spelled, _cell_problem(cell, kind, sep))
    if kind == "int":
        with np.errstate(invalid="ignore"):
            fractional = np.isfinite(values) & (values % 1 != 0)
        if fractional.any():
            row = int(np.argmax(fractional))
            raise InputError(path, int(lines[rows[row]]), spelled, f"{values[row]!r} is not a whole number")


def _parse_with_pandas(layout: _Layout, wanted: dict[str, Kind], present: list[str],
                       usecols: list[int]) -> tuple[pd.DataFrame, _Scanner]:
    """The wanted columns by pandas' C parser (:func:`_parse`), every problem raised as an :class:`InputError`
    naming its line and column."""
    import pandas as pd

    dtypes = {layout.index[name]: (np.float64 if wanted[name] in ("float", "int") else str) for name in present}
    try:
        frame, scanner = _parse(layout, usecols, dtypes)
    except _AbortError as stop:
        raise stop.problem from None
    except (ValueError, pd.errors.ParserError, UnicodeDecodeError, OverflowError) as exc:
        try:
            located = _locate_bad_cell(layout, wanted, present)
        except (ValueError, pd.errors.ParserError):
            located = None
        if located is not None:
            raise located from None
        raise InputError(layout.path, None, None, f"cannot parse the table: {excerpt(str(exc), 200)}") from None
    if not scanner.finished:  # pandas stopped before the end (cannot happen with the C parser; be sure)
        while scanner.read(_BLOCK):
            pass
    return frame, scanner


def _text_chunks(layout: _Layout, usecols: list[int]) -> Iterator[pd.DataFrame]:
    """The wanted columns as text, 100,000 rows at a time (every column when no line is complete)."""
    import pandas as pd

    layout.handle.seek(layout.data_start)
    yielded = False
    try:
        for chunk in _read_csv(layout.handle, layout, usecols, dict.fromkeys(usecols, str), encoding_errors="replace",
                               chunksize=100_000):
            yielded = True
            yield chunk
        return
    except pd.errors.ParserError as exc:
        if yielded or not str(exc).startswith("Too many columns specified"):
            raise
    layout.handle.seek(layout.data_start)
    yield from _read_csv(layout.handle, layout, None, dict.fromkeys(range(len(layout.header)), str),
                         encoding_errors="replace", chunksize=100_000)


def _locate_bad_cell(layout: _Layout, wanted: dict[str, Kind], present: list[str]) -> InputError | None:
    """Diagnostic pass (pandas refused a cell): the earliest cell of a wanted column that is not its kind."""
    path, header, index = layout.path, layout.header, layout.index
    sep = layout.dialect.separator
    layout.handle.seek(layout.data_start)
    usecols = sorted(index[name] for name in present)
    chunks = _text_chunks(layout, usecols)
    first_row = 0
    for chunk in chunks:
        best: tuple[int, int, str] | None = None
        for name in sorted(present, key=lambda n: index[n]):
            bad = _bad_cells(chunk[index[name]], wanted[name])
            if bad.any():
                row = int(np.argmax(bad))
                if best is None or row < best[0]:
                    best = (row, index[name], name)
        if best is not None:
            row, column, name = best
            text = str(chunk[column].iloc[row])
            kind = wanted[name]
            message = _str_problem(text) if kind == "str" else _cell_problem(text, kind, sep)
            return InputError(path, first_row + row + 2, header[column], message)
        first_row += len(chunk)
    return None
