"""A seeded mutation corpus of POS.txt and Kamera.txt files through the readers ``process`` and ``info`` use.

Each case mutates a slice of the bundled flight (``data/``) with one to three of: cut lines, dropped fields,
stray quotes, a byte-order mark, undecodable or NUL bytes, ``inf``/``nan``, digits of other scripts, other
separators, huge cells, absurd values, header case and blanks, CR LF and lone CR line ends, blank, repeated,
swapped and deleted lines, files of a single (cut) line. Every case must end in either a clean result or an
:class:`InputError`, and:

* no other exception (no traceback);
* an error names the file and a line or a column, and stays short (a 100 000-character cell is quoted as an
  excerpt);
* Kamera.txt: every non-blank line is a row (flagged, time NaN, when it was cut short), and every line the
  mutation did not touch keeps its frame id and time: quotes never merge lines;
* POS.txt: every line that is neither blank nor in the result is named by a notice, and a value beyond the
  plausibility limits never passes.

The corpus is 1,200 cases and reads in about 15 s on one core.
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from georef.io.camera import read_exposures, read_kamera
from georef.io.errors import InputError
from georef.io.plausibility import LIMITS
from georef.io.pos import POS_ROLES, read_pos
from georef.io.table import peek_header

DATA = Path(__file__).resolve().parents[2] / "data"
N_POS = 600
N_KAMERA = 600
#: the longest message a case may produce [characters]
MAX_MESSAGE = 600

UNICODE_DIGITS = ("٠١٢٣٤٥٦٧٨٩", "０１２３４５６７８９", "०१२३४५६७८९")
NON_FINITE = ("inf", "-inf", "nan", "NaN", "Infinity", "1e999", "-1e400")
ABSURD = ("2147483648", "1e6", "-1e9", "99999999", "4.2e12")
BAD_BYTES = (b"\xae", b"\xff\xfe", b"\x00", b"\xc3", b"\xe2\x82", b"\x80abc")


@dataclass
class Case:
    """A mutated file: its lines (bytes, without line ends), how they are joined, and what was done."""

    header: list[bytes]
    lines: list[bytes]                      # data lines
    original: list[int | None]              # index of each data line in the unmutated file (None: inserted)
    touched: set[int] = field(default_factory=set)   # indices into ``lines`` that were changed
    prefix: bytes = b""
    newline: bytes = b"\n"
    cut_tail: int = 0                       # bytes cut off the end of the file
    absurd: list[tuple[int, int]] = field(default_factory=list)  # (line index, field index) of absurd values
    whole_file: bool = False                # a mutation of every line (separator, line ends)
    ops: list[str] = field(default_factory=list)

    def render(self) -> bytes:
        text = self.prefix + self.newline.join([b"\t".join(self.header), *self.lines]) + self.newline
        return text[: len(text) - self.cut_tail] if self.cut_tail else text


def _split(line: bytes) -> list[bytes]:
    return line.split(b"\t")


def _mark(case: Case, i: int, line: bytes) -> None:
    case.lines[i] = line
    case.touched.add(i)


def _mutate(case: Case, rng: random.Random, kind: str) -> None:
    n = len(case.lines)
    i = rng.randrange(n)
    cells = _split(case.lines[i])
    j = rng.randrange(len(cells))
    case.ops.append(kind)
    if kind == "truncate_file":
        case.cut_tail = rng.randint(1, max(1, len(case.lines[-1])))
        case.touched.add(n - 1)
    elif kind == "truncate_line":
        line = case.lines[i]
        _mark(case, i, line[: rng.randrange(1, max(2, len(line)))])
    elif kind == "drop_field":
        del cells[j]
        _mark(case, i, b"\t".join(cells))
    elif kind == "drop_last_field":
        _mark(case, i, b"\t".join(cells[:-1]))
    elif kind == "quote":
        line = case.lines[i]
        k = rng.randrange(len(line) + 1)
        _mark(case, i, line[:k] + b'"' + line[k:])
        # and a closing one a few lines later, as in a reported file's "9 -> "9 and 19 -> 19""
        if i + 10 < n and rng.random() < 0.7:
            other = case.lines[i + 10]
            _mark(case, i + 10, other + b'"')
    elif kind == "bom":
        case.prefix = b"\xef\xbb\xbf" + case.prefix
    elif kind == "bad_bytes":
        line = case.lines[i]
        k = rng.randrange(len(line) + 1)
        _mark(case, i, line[:k] + rng.choice(BAD_BYTES) + line[k:])
    elif kind == "non_finite":
        cells[j] = rng.choice(NON_FINITE).encode()
        _mark(case, i, b"\t".join(cells))
    elif kind == "unicode_digit":
        digits = rng.choice(UNICODE_DIGITS)
        text = cells[j].decode()
        text = "".join(digits[int(ch)] if ch.isdigit() and rng.random() < 0.5 else ch for ch in text) or digits[1]
        if text == cells[j].decode():
            text = digits[7] + text
        cells[j] = text.encode()
        _mark(case, i, b"\t".join(cells))
    elif kind == "separator_line":
        sep = rng.choice([b";", b",", b" ", b"  "])
        _mark(case, i, sep.join(cells))
    elif kind == "separator_file":
        sep = rng.choice([b";", b",", b" "])
        case.header = [sep.join(case.header)]
        case.lines = [sep.join(_split(line)) for line in case.lines]
        case.whole_file = True
    elif kind == "huge_cell":
        cells[j] = b"7" * 100_000
        _mark(case, i, b"\t".join(cells))
    elif kind == "absurd":
        cells[j] = rng.choice(ABSURD).encode()
        _mark(case, i, b"\t".join(cells))
        case.absurd.append((i, j))
    elif kind == "header_blank":
        k = rng.randrange(len(case.header))
        case.header[k] = rng.choice([b" ", b"  ", b""]) + case.header[k] + rng.choice([b" ", b"\t"[:0], b"  "])
    elif kind == "header_case":
        k = rng.randrange(len(case.header))
        case.header[k] = case.header[k].lower() if rng.random() < 0.5 else case.header[k].upper()
    elif kind == "crlf":
        case.newline = b"\r\n"
    elif kind == "lone_cr":
        line = case.lines[i]
        k = rng.randrange(len(line) + 1)
        _mark(case, i, line[:k] + b"\r" + line[k:])
    elif kind == "blank":
        case.lines.insert(i, rng.choice([b"", b"   ", b"\t"[:0]]))
        case.original.insert(i, None)
        case.touched = {t + 1 if t >= i else t for t in case.touched} | {i}
    elif kind == "duplicate":
        case.lines.insert(i + 1, case.lines[i])
        case.original.insert(i + 1, case.original[i])
        case.touched = {t + 1 if t > i else t for t in case.touched} | {i + 1}
    elif kind == "swap" and i + 1 < n:
        case.lines[i], case.lines[i + 1] = case.lines[i + 1], case.lines[i]
        case.original[i], case.original[i + 1] = case.original[i + 1], case.original[i]
        case.touched |= {i, i + 1}
    elif kind == "delete" and n > 3:
        del case.lines[i]
        del case.original[i]
        case.touched = {t - 1 if t > i else t for t in case.touched if t != i}
    elif kind == "empty_cell":
        cells[j] = b""
        _mark(case, i, b"\t".join(cells))
    elif kind == "extra_field":
        cells.insert(j, b"1")
        _mark(case, i, b"\t".join(cells))
    elif kind == "single_line":
        # a file of one data line, often cut short: no line is complete
        line = case.lines[i]
        case.lines, case.original, case.touched = [line[: rng.randrange(1, len(line) + 1)]], [case.original[i]], {0}


KINDS = ("truncate_file", "truncate_line", "drop_field", "drop_last_field", "quote", "bom", "bad_bytes", "non_finite",
         "unicode_digit", "separator_line", "separator_file", "huge_cell", "absurd", "header_blank", "header_case",
         "crlf", "lone_cr", "blank", "duplicate", "swap", "delete", "empty_cell", "extra_field", "single_line")


def _base(path: Path, first: int, count: int) -> tuple[list[bytes], list[bytes]]:
    raw = path.read_bytes().split(b"\n")
    return raw[0].split(b"\t"), raw[1 + first: 1 + first + count]


def _cases(path: Path, first: int, count: int, n: int, seed: int) -> list[Case]:
    header, lines = _base(path, first, count)
    rng = random.Random(seed)
    cases = []
    for k in range(n):
        case = Case(list(header), list(lines), list(range(len(lines))))
        for _ in range(1 if k % 3 else rng.randint(2, 3)):
            _mutate(case, rng, KINDS[k % len(KINDS)] if not case.ops else rng.choice(KINDS))
        cases.append(case)
    return cases


def _check_error(exc: InputError, path: Path) -> None:
    text = str(exc)
    assert path.name in text, text
    assert exc.line is not None or exc.column is not None, text
    assert len(text) < MAX_MESSAGE, f"{len(text)} characters: {text[:300]}"


def _data_line_numbers(data: bytes) -> list[int]:
    """1-based line numbers of the non-blank data lines of a file (LF or CR LF ends)."""
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines = lines[:-1]
    return [k + 1 for k, line in enumerate(lines) if k > 0 and line.strip(b" \t\r")]


def test_fuzz_kamera(tmp_path):
    truth = read_kamera(DATA / "Kamera.txt")
    truth_time = dict(zip(range(len(truth.frame)), truth.time, strict=True))
    outcome: Counter[str] = Counter()
    path = tmp_path / "Kamera.txt"
    for number, case in enumerate(_cases(DATA / "Kamera.txt", 100, 60, N_KAMERA, seed=12)):
        data = case.render()
        path.write_bytes(data)
        where = f"case {number} {case.ops}"
        try:
            exposures = read_exposures(path)
        except InputError as exc:
            _check_error(exc, path)
            outcome["error"] += 1
            continue
        outcome["read"] += 1
        # every non-blank line is a row: nothing lost, nothing merged
        assert sorted(exposures.lines.tolist()) == _data_line_numbers(data), where
        usable = exposures.problem == ""
        assert np.isfinite(exposures.time[usable]).all(), where
        assert np.isnan(exposures.time[~usable]).all(), where
        outcome["flagged rows"] += int((~usable).sum())
        if case.whole_file:
            continue
        first_line = 2
        for k, original in enumerate(case.original):
            if k in case.touched or original is None:
                continue
            row = np.flatnonzero(exposures.lines == first_line + k)
            assert len(row) == 1, where
            expected = truth_time[100 + original]
            assert exposures.frame[row[0]] == truth.frame[100 + original], where
            assert abs(exposures.time[row[0]] - expected) < 1e-9, where
    assert outcome["error"] > 50 and outcome["read"] > 50 and outcome["flagged rows"] > 20, outcome


def _named_by_notices(log, line: int) -> bool:
    return any(line in notice.lines for notice in log.notices)


def test_fuzz_pos(tmp_path):
    outcome: Counter[str] = Counter()
    path = tmp_path / "POS.txt"
    header, _ = _base(DATA / "POS.txt", 0, 0)
    # every column whose values have limits: the plausibility table, coordinates and the time columns
    limited = {POS_ROLES[role][0] for role in (*LIMITS, "lat", "lon", "trig_time", "sampl_time")}
    for number, case in enumerate(_cases(DATA / "POS.txt", 3000, 400, N_POS, seed=21)):
        data = case.render()
        path.write_bytes(data)
        where = f"case {number} {case.ops}"
        try:
            peek_header(path)
            log = read_pos(path, gnss_rate_hz=1.0)
        except InputError as exc:
            _check_error(exc, path)
            outcome["error"] += 1
            continue
        outcome["read"] += 1
        kept = set(log.lines.tolist())
        for line in _data_line_numbers(data):
            assert line in kept or _named_by_notices(log, line), f"{where}: line {line} silently dropped"
        if len(case.ops) == 1:
            for i, j in case.absurd:
                name = header[j].decode()
                if name in limited:
                    pytest.fail(f"{where}: absurd value in {name} on line {i + 2} passed")
    assert outcome["error"] > 50 and outcome["read"] > 50, outcome


def test_corpus_covers_every_mutation():
    """Each mutation appears in both corpora many times (the corpus is what the test claims)."""
    for path, first, n, seed in ((DATA / "Kamera.txt", 100, N_KAMERA, 12), (DATA / "POS.txt", 3000, N_POS, 21)):
        ops = Counter(op for case in _cases(path, first, 60, n, seed) for op in case.ops)
        assert set(ops) == set(KINDS) and min(ops.values()) >= 20, ops
    assert N_POS + N_KAMERA >= 1000
