"""Compiled reading of a clean block of a text table (:mod:`georef.io.table`): fields split, numbers converted.

One pass over the bytes of whole lines: each line must hold exactly the header's number of fields (split at the
separator byte, or at runs of blanks, ``sep = -1``) of at most :data:`~georef.io.errors.MAX_FIELD_CHARS` bytes
each, end in LF or CR LF and not be blank; each wanted field is converted by its kind. Anything else stops the
block with a status other than :data:`CLEAN`, and the caller reads the file with numpy or pandas instead, which
then give the messages. So this path never decides what is an error; it only takes the files where nothing is.

Numbers are converted only where one IEEE operation gives the correctly rounded result, as a strtod does
(Clinger 1990, "How to read floating point numbers accurately", the fast path): at most 15 significant digits,
so the digits form an integer ``w < 2^53`` exactly, and a decimal exponent ``e`` with ``|e| <= 22``, so ``10^|e|``
is exact; then ``w * 10^e`` or ``w / 10^-e`` is one correctly rounded operation. Any other number (16 or more
significant digits, a larger exponent, ``nan``, ``inf``) stops the block: the file goes to a reader that rounds
correctly everywhere. pandas 3 (fast_float) and numpy (Python's ``PyOS_string_to_double``) round correctly, so
the three readers give the same bits (``tests/io/test_table.py``). Hex cells of 1 to 13 digits (below 2^52,
exact in a float64) are converted; text cells are returned as byte ranges.

It exists for speed: it reads a clean table several times faster than numpy's ``loadtxt`` or pandas' C parser
(which also needs pandas imported); the figures are in ``docs/performance.md``, "Tables".
"""

from __future__ import annotations

import numpy as np
from numba import njit

from georef.io.errors import MAX_FIELD_CHARS

#: statuses of a block: read, or the first thing that stopped it
CLEAN, FIELD_COUNT, BLANK_LINE, LONE_CR, BAD_NUMBER, BAD_HEX, BAD_TEXT, FIELD_TOO_LONG = 0, 1, 2, 3, 4, 5, 6, 7
#: kinds of a wanted field
FLOAT, HEX, TEXT = 0, 1, 2
#: the exact powers of ten of a float64
POWERS = np.array([10.0**k for k in range(23)])
MAX_DIGITS = 15
MAX_HEX_DIGITS = 13

_SPACE, _TAB, _LF, _CR, _PLUS, _MINUS, _DOT = 32, 9, 10, 13, 43, 45, 46


@njit(cache=True)
def _digits(buf: np.ndarray, i: int, n: int, mantissa: int, digits: int) -> tuple[int, int, int, int]:
    """The decimal digits from ``buf[i]`` on, appended to ``mantissa``: the index after them, the mantissa, its
    significant digits (leading zeros not counted) and how many digits were read; ``digits`` is -1 once there
    are more than :data:`MAX_DIGITS` (the mantissa is then no longer exact)."""
    start = i
    while i < n and 48 <= buf[i] <= 57:
        if digits >= 0 and (mantissa or buf[i] != 48):
            digits += 1
            if digits > MAX_DIGITS:
                digits = -1
            else:
                mantissa = mantissa * 10 + (buf[i] - 48)
        i += 1
    return i, mantissa, digits, i - start


@njit(cache=True)
def _number(buf: np.ndarray, i: int, n: int) -> tuple[float, int, bool]:
    """The decimal number starting at ``buf[i]`` (``[+-]digits[.digits][(e|E)[+-]digits]``, or ``.digits``), read
    as far as that form goes: its value, the index after it, and whether it was converted (False: no digit, an
    exponent without digits, or outside the exact fast path)."""
    negative = False
    if i < n and (buf[i] == _PLUS or buf[i] == _MINUS):
        negative = buf[i] == _MINUS
        i += 1
    i, mantissa, digits, whole = _digits(buf, i, n, 0, 0)
    fraction = 0
    if i < n and buf[i] == _DOT:
        i, mantissa, digits, fraction = _digits(buf, i + 1, n, mantissa, digits)
    exponent = -fraction
    if digits < 0 or whole + fraction == 0:  # beyond the exact range, or no digit at all
        return 0.0, i, False
    if i < n and (buf[i] == 101 or buf[i] == 69):  # e, E
        i += 1
        sign = 1
        if i < n and (buf[i] == _PLUS or buf[i] == _MINUS):
            sign = -1 if buf[i] == _MINUS else 1
            i += 1
        start = i
        value = 0
        while i < n and 48 <= buf[i] <= 57:
            if i - start >= 4:
                return 0.0, i, False
            value = value * 10 + (buf[i] - 48)
            i += 1
        if i == start:
            return 0.0, i, False
        exponent += sign * value
    if mantissa == 0:
        return -0.0 if negative else 0.0, i, True
    if exponent < -22 or exponent > 22:
        return 0.0, i, False
    result = float(mantissa) * POWERS[exponent] if exponent >= 0 else float(mantissa) / POWERS[-exponent]
    return -result if negative else result, i, True


@njit(cache=True)
def _hex(buf: np.ndarray, i: int, n: int) -> tuple[float, int, bool]:
    """The hex digits starting at ``buf[i]`` as an exact float64, the index after them, and whether there were 1
    to 13 of them."""
    value = 0
    start = i
    while i < n:
        c = buf[i]
        if 48 <= c <= 57:
            digit = c - 48
        elif 97 <= c <= 102:
            digit = c - 87
        elif 65 <= c <= 70:
            digit = c - 55
        else:
            break
        if i - start >= MAX_HEX_DIGITS:
            return 0.0, i, False
        value = value * 16 + digit
        i += 1
    return float(value), i, i > start


@njit(cache=True)
def _text_field(buf: np.ndarray, i: int, n: int, sep: int, wanted: bool) -> tuple[int, int]:
    """Pass over a text field, or a field that is not wanted, from ``buf[i]``: the index after it, and CLEAN or
    BAD_TEXT (a ``wanted`` cell that is empty or holds a blank, which pandas would strip)."""
    a = i
    while i < n:
        c = buf[i]
        if c == _LF or c == _CR or c == sep or (sep < 0 and (c == _SPACE or c == _TAB)):
            break
        if wanted and (c == _SPACE or c == _TAB):  # pandas would strip a text cell's blanks
            return i, BAD_TEXT
        i += 1
    if wanted and i == a:
        return i, BAD_TEXT
    return i, CLEAN


@njit(cache=True)
def _parse_fields(buf: np.ndarray, i: int, n: int, sep: int, n_fields: int, slot: np.ndarray, kind: np.ndarray,
                  values: np.ndarray, starts: np.ndarray, ends: np.ndarray, row: int) -> tuple[int, int, int]:
    """The fields of the line from ``buf[i]``, the wanted ones into row ``row`` of ``values`` (numbers) or
    ``starts``/``ends`` (text): the index of the line's end (LF, CR or ``n``), the fields read, and CLEAN or the
    code of what stopped the line."""
    field = 0
    while True:
        if sep < 0:  # runs of blanks separate; none at the start or the end of a line counts
            while i < n and (buf[i] == _SPACE or buf[i] == _TAB):
                i += 1
            if i >= n or buf[i] == _LF or buf[i] == _CR:
                return i, field, CLEAN
        if field >= n_fields:
            return i, field, FIELD_COUNT
        out = slot[field]
        field_start = i
        if out >= 0 and kind[out] != TEXT:
            value, i, ok = _number(buf, i, n) if kind[out] == FLOAT else _hex(buf, i, n)
            if not ok:
                return i, field, BAD_NUMBER if kind[out] == FLOAT else BAD_HEX
            values[row, out] = value
        else:
            i, code = _text_field(buf, i, n, sep, out >= 0)
            if code != CLEAN:
                return i, field, code
            if out >= 0:
                starts[row, out] = field_start
                ends[row, out] = i
        if i - field_start > MAX_FIELD_CHARS:  # the other readers name it; none holds such a line
            return i, field, FIELD_TOO_LONG
        field += 1
        if i >= n:
            return i, field, CLEAN
        c = buf[i]
        if c == _LF or c == _CR:
            return i, field, CLEAN
        if sep >= 0 and c == sep:
            i += 1
        elif not (sep < 0 and (c == _SPACE or c == _TAB)):
            # a number ran into a letter
            return i, field, BAD_NUMBER if out >= 0 and kind[out] == FLOAT else BAD_HEX


@njit(cache=True)
def _line_end(buf: np.ndarray, i: int, n: int, sep: int, n_fields: int, line_start: int,
              field: int) -> tuple[int, int]:
    """After a line's fields were read cleanly (``field`` of them; ``buf[i]`` its end): the index of its LF (a CR LF
    passed over), and CLEAN, or LONE_CR, BLANK_LINE or FIELD_COUNT."""
    if i < n and buf[i] == _CR:
        if i + 1 < n and buf[i + 1] == _LF:
            i += 1
        elif i + 1 < n:
            return i, LONE_CR
    empty = line_start >= n or buf[line_start] == _LF or buf[line_start] == _CR
    if field == 0 or (sep >= 0 and field == 1 and empty):
        return i, BLANK_LINE
    if field != n_fields:
        return i, FIELD_COUNT
    return i, CLEAN


@njit(cache=True)
def parse_block(buf: np.ndarray, n: int, sep: int, n_fields: int, slot: np.ndarray, kind: np.ndarray,
                n_lines: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The wanted fields of the ``n_lines`` lines in ``buf[:n]`` (whole lines; the last may lack its LF).

    ``sep``: the separator byte, -1 for runs of blanks (space, tab); ``n_fields``: fields per line; ``slot``
    (``n_fields``,): the output column of each field, -1 where it is not wanted; ``kind`` (outputs,): FLOAT,
    HEX or TEXT per output column. Returns ``values`` (lines, outputs) [the numbers; hex as float64], ``starts``
    and ``ends`` (lines, outputs; no lines when no column is TEXT) [byte ranges of the text cells in ``buf``],
    ``status`` (2,): CLEAN or why the
    block stopped, and the line it stopped at (0-based). One pass: a wanted number is converted as its bytes are
    read, and must then end at a field's end."""
    n_out = len(kind)
    values = np.zeros((n_lines, n_out))
    text_lines = n_lines if np.any(kind == TEXT) else 0  # no text column: no byte ranges to hold
    starts = np.zeros((text_lines, n_out), dtype=np.int64)
    ends = np.zeros((text_lines, n_out), dtype=np.int64)
    status = np.zeros(2, dtype=np.int64)
    i = 0
    row = 0
    while i < n and row < n_lines:
        line_start = i
        i, field, code = _parse_fields(buf, i, n, sep, n_fields, slot, kind, values, starts, ends, row)
        if code == CLEAN:
            i, code = _line_end(buf, i, n, sep, n_fields, line_start, field)
        if code != CLEAN:
            status[0] = code
            status[1] = row
            return values, starts, ends, status
        row += 1
        i += 1  # past the line feed
    if row != n_lines:
        status[0] = FIELD_COUNT
        status[1] = row
    return values, starts, ends, status
