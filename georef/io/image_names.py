"""Image file names for the frames (``--image-names``): a pattern or a two-column CSV.

Metashape, Pix4D and OpenDroneMap match the rows of a reference file to the images by **file name**; a bare
frame number links to nothing. ``--image-names`` gives the names:

* a pattern with ``{frame}``, Python format syntax: ``IMG_{frame:04d}.JPG`` gives ``IMG_0012.JPG`` for frame
  ``12``. ``{frame}`` is the frame id as an integer when it is one (so ``:04d`` works), else its text; ``{id}``
  is always the text as written in the exposure file;
* a CSV file with two columns, frame id and file name (comma, semicolon or tab separated; a first row
  ``frame,name`` or ``frame,image`` is a header). Every frame must have a name: a missing one is an error that
  names the frame; a frame listed twice, or one name given to two frames, is an error naming both lines.
"""

from __future__ import annotations

import csv
import string
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from georef.io.errors import GeorefError, InputError

_HEADERS = {"frame", "number", "id"}
_NAME_HEADERS = {"name", "image", "file", "filename", "image_name", "imagename"}


def _frame_value(frame: str) -> int | str:
    text = frame.strip()
    return int(text) if text.isdecimal() and text.isascii() else text


@dataclass
class ImageNames:
    """A frame-id -> image-file-name mapping, from a pattern or a table."""

    pattern: str | None = None
    table: dict[str, str] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        # "0012" in Kamera.txt and "12" in the table are the same frame
        self._numeric = {value: name for key, name in self.table.items()
                         if isinstance(value := _frame_value(key), int)}

    @classmethod
    def parse(cls, option: str) -> ImageNames:
        """``option`` is a pattern when it contains ``{``, otherwise the path of a two-column CSV."""
        if "{" in option:
            return cls.from_pattern(option)
        return cls.from_csv(Path(option))

    @classmethod
    def from_pattern(cls, pattern: str) -> ImageNames:
        try:
            fields = [name for _, name, _, _ in string.Formatter().parse(pattern) if name is not None]
        except ValueError as exc:
            raise GeorefError(f"--image-names {pattern!r}: not a valid pattern ({exc})") from None
        unknown = sorted({f for f in fields if f not in ("frame", "id")})
        if unknown or not fields:
            raise GeorefError(f"--image-names {pattern!r}: a pattern takes {{frame}} (e.g. IMG_{{frame:04d}}.JPG) "
                              f"or {{id}}; found {', '.join('{' + u + '}' for u in unknown) or 'neither'}")
        names = cls(pattern=pattern, source=f"pattern {pattern!r}")
        names.name("1")  # a format spec that cannot take an integer frame fails here, before any processing
        return names

    @classmethod
    def from_csv(cls, path: Path) -> ImageNames:
        if not path.is_file():
            raise InputError(path, None, None, "image-name file not found (--image-names takes a pattern with "
                             "{frame}, e.g. IMG_{frame:04d}.JPG, or a CSV of frame,name)")
        try:
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError as exc:
            raise InputError(path, None, None, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
        lines = text.splitlines()
        sample = next((line for line in lines if line.strip()), "")
        delimiter = "\t" if "\t" in sample else (";" if ";" in sample and "," not in sample else ",")
        table: dict[str, str] = {}
        line_of: dict[str, int] = {}
        owner: dict[str, tuple[str, int]] = {}
        reader = csv.reader(lines, delimiter=delimiter, quoting=csv.QUOTE_NONE)
        for number, row in enumerate(reader, start=1):
            cells = [c.strip() for c in row]
            if not any(cells) or cells[0].startswith("#"):
                continue
            if len(cells) != 2 or not all(cells):
                raise InputError(path, number, None, f"expected two fields, frame and image name; got {len(cells)}"
                                 f" ({delimiter!r} separated): {';'.join(cells)[:80]!r}")
            frame, name = cells
            if not table and frame.lower() in _HEADERS and name.lower() in _NAME_HEADERS:
                continue  # header row
            if frame in table:
                raise InputError(path, number, None, f"frame {frame!r} is listed twice (first on line "
                                 f"{line_of[frame]})")
            if name in owner:
                raise InputError(path, number, None, f"image name {name!r} is given to frame {frame!r} and to frame "
                                 f"{owner[name][0]!r} (line {owner[name][1]})")
            table[frame], line_of[frame], owner[name] = name, number, (frame, number)
        if not table:
            raise InputError(path, None, None, "no frame,name rows found")
        return cls(table=table, source=str(path))

    def name(self, frame: str) -> str:
        """The image name of one frame id (text as in the exposure file)."""
        if self.pattern is not None:
            try:
                return self.pattern.format(frame=_frame_value(frame), id=frame)
            except (ValueError, KeyError, IndexError) as exc:
                raise GeorefError(f"--image-names {self.pattern!r} cannot name frame {frame!r}: {exc}") from None
        key = frame.strip()
        if key in self.table:
            return self.table[key]
        value = _frame_value(key)
        if isinstance(value, int) and value in self._numeric:
            return self._numeric[value]
        raise KeyError(frame)

    def names(self, frames: Sequence[str]) -> list[str]:
        """Image names of every frame, in order; a frame without a name is an error naming it."""
        out, missing = [], []
        for frame in frames:
            try:
                out.append(self.name(str(frame)))
            except KeyError:
                missing.append(str(frame))
        if missing:
            shown = ", ".join(missing[:10]) + (f" and {len(missing) - 10} more" if len(missing) > 10 else "")
            raise GeorefError(f"{self.source}: no image name for frame(s) {shown} ({len(missing)} of {len(frames)})")
        return out
