"""Options given as text (on the command line): their errors, which name the option, and the numbers they hold.

An :class:`OptionError` is a value refused or options that do not go together, found before any file is
processed; the command line prints it as it prints its own refusals (``Invalid value: ...``, or ``Invalid value
for OPTION: ...`` when :attr:`OptionError.option` names one) with exit code 2.
"""

from __future__ import annotations

from pathlib import Path

from georef.io.errors import GeorefError

#: ``-`` as a file name: standard output (``-o -``, ``--summary-json -``)
STDOUT = "-"


class OptionError(GeorefError):
    """An option's value refused, or options that do not go together: ``message``, and the ``option`` it is
    reported against when the message does not name it itself (None: the message names it)."""

    def __init__(self, message: str, option: str | None = None):
        super().__init__(message)
        self.message, self.option = message, option


def is_stdout(path: Path | str | None) -> bool:
    """``-``: standard output."""
    return path is not None and str(path) == STDOUT


def triple(text: str | None, what: str, unit: str) -> tuple[float, float, float] | None:
    """Three comma-separated numbers of the option ``what`` (``unit`` for the message); None when not given."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise OptionError(f"{what} needs three comma-separated numbers in {unit}, e.g. 0.5,0,-1.2; got {text!r}")
    return values  # type: ignore[return-value]


def pairs(values: list[str] | None, what: str) -> list[tuple[float, float]]:
    """Each of the repeated option ``what``'s values ``A,B`` as two numbers."""
    result = []
    for text in values or []:
        parts = text.split(",")
        if len(parts) != 2:
            raise OptionError(f"{what} takes two numbers A,B; got {text!r}")
        result.append((float(parts[0]), float(parts[1])))
    return result
