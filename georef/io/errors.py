"""Errors and warnings about input files that name the file, the line and the column."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: the longest piece of a cell an error message quotes [characters]
EXCERPT_CHARS = 40
#: the longest field a text table may hold [characters]: a longer one is an error naming its line and column, so
#: no reader holds an unbounded line, and a text column (frame ids) held at numpy's fixed width costs at most
#: 4 bytes x this per row. A frame id, an image name or a number is far shorter.
MAX_FIELD_CHARS = 256


def excerpt(text: object, limit: int = EXCERPT_CHARS) -> str:
    """``repr`` of at most ``limit`` characters of ``text``, with the full length when it was cut.

    A 5 MB cell gives a message of a line, not of 5 MB: ``'3.14159265358979323846…' (5242880 characters)``.
    """
    text = str(text)
    if len(text) <= limit:
        return repr(text)
    more = "over " if text.endswith("…") else ""
    return f"{text[:limit]!r}… ({more}{len(text.rstrip('…'))} characters)"


class GeorefError(Exception):
    """Base class of the errors georef reports to a user without a traceback."""


@dataclass
class InputError(GeorefError):
    """A problem with an input file, located by 1-based line number (the header is line 1) and column."""

    path: Path | str
    line: int | None
    column: str | None
    message: str

    def __post_init__(self) -> None:
        super().__init__(str(self))

    def __str__(self) -> str:
        where = f"{self.path}"
        if self.line is not None:
            where += f", line {self.line}"
        if self.column is not None:
            where += f", column {excerpt(self.column)}"
        return f"{where}: {self.message}"


@dataclass
class InputNotice:
    """Something repaired or skipped in an input file: never silent, always in the summary."""

    path: Path | str
    lines: list[int]
    column: str | None
    message: str

    def __str__(self) -> str:
        shown = ", ".join(str(n) for n in self.lines[:8])
        if len(self.lines) > 8:
            shown += f", ... ({len(self.lines)} lines)"
        where = f"{self.path}"
        if self.lines:
            where += f", line{'s' if len(self.lines) > 1 else ''} {shown}"
        if self.column is not None:
            where += f", column {excerpt(self.column)}"
        return f"{where}: {self.message}"
