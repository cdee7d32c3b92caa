"""DataFlash logs written: message types defined by FMT messages, encoded binary (``.bin``) or as text (``.log``).

A binary DataFlash log is a run of packed little-endian messages ``A3 95 <type> <body>``; the FMT message
(type 128, 89 bytes, format ``BBnNZ``) defines every other type's name, length, format characters and column
names, and the log starts with the FMT of FMT itself. The text form, as pymavlink and Mission Planner write it,
holds one ``NAME, v1, v2, ...`` line per message with the values scaled to their units.

The format characters and their scales are ArduPilot's (``libraries/AP_Logger/LogStructure.h``): ``c``/``C``/
``e``/``E`` hold hundredths, ``L`` a latitude or longitude in 1e-7 degrees. The table is this writer's own and not
the reader's (:data:`georef.io.logs.dataflash.FORMAT_TYPES`): ``tests/sim/test_autopilot_logs.py`` checks both
against pymavlink, which a shared table would not do for the reader.

A :class:`MessageBlock` holds the messages of one type as stored (integers for the scaled characters) with each
message's boot time, which orders the log; values that do not fit their field raise ``ValueError`` naming the
message and field, nothing is clipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HEAD = (0xA3, 0x95)
FMT_TYPE, FMT_NAME = 128, "FMT"
#: format character -> (numpy type of the stored value, scale from stored to physical; None: text)
FORMAT_CHARS: dict[str, tuple[str, float | None]] = {
    "b": ("i1", 1.0), "B": ("u1", 1.0), "h": ("<i2", 1.0), "H": ("<u2", 1.0), "i": ("<i4", 1.0),
    "I": ("<u4", 1.0), "q": ("<i8", 1.0), "Q": ("<u8", 1.0), "M": ("u1", 1.0), "f": ("<f4", 1.0),
    "d": ("<f8", 1.0), "n": ("S4", None), "N": ("S16", None), "Z": ("S64", None), "c": ("<i2", 0.01),
    "C": ("<u2", 0.01), "e": ("<i4", 0.01), "E": ("<u4", 0.01), "L": ("<i4", 1e-7),
}
#: decimals of the scaled characters in the text form: the stored integer written exactly
_DECIMALS = {"c": 2, "C": 2, "e": 2, "E": 2, "L": 7}


@dataclass(frozen=True)
class MessageType:
    """One message type as its FMT message defines it."""

    name: str
    type_id: int
    format: str
    columns: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.format) != len(self.columns) or not set(self.format) <= set(FORMAT_CHARS):
            raise ValueError(f"{self.name}: format {self.format!r} does not match columns {self.columns}")

    @property
    def dtype(self) -> np.dtype:
        """The packed message, header included."""
        fields = [("head1", "u1"), ("head2", "u1"), ("msgid", "u1")]
        return np.dtype(fields + [(c, FORMAT_CHARS[f][0]) for c, f in zip(self.columns, self.format, strict=True)])

    @property
    def length(self) -> int:
        return self.dtype.itemsize


FMT = MessageType(FMT_NAME, FMT_TYPE, "BBnNZ", ("Type", "Length", "Name", "Format", "Columns"))


@dataclass
class MessageBlock:
    """The messages of one type: ``stored[column]`` as the binary form holds them and ``time`` [s] each message's
    boot time (the order in the log; messages of one time keep the order of the blocks)."""

    kind: MessageType
    stored: dict[str, np.ndarray]
    time: np.ndarray

    def __len__(self) -> int:
        return len(self.time)


def _stored(kind: MessageType, column: str, char: str, values: object, n: int) -> np.ndarray:
    """Physical ``values`` of one column as stored: scaled and rounded, range-checked."""
    numpy_type, scale = FORMAT_CHARS[char]
    if scale is None:
        size = np.dtype(numpy_type).itemsize
        texts = np.broadcast_to(np.asarray(values, dtype=object), (n,))
        encoded = [str(t).encode("ascii") for t in texts]
        comma = b", " if kind.name == FMT_NAME else b","  # FMT's column list is comma-separated itself
        if any(len(e) > size or comma in e or b"\n" in e for e in encoded):
            raise ValueError(f"{kind.name}.{column}: text longer than {size} characters or holding "
                             f"{comma.decode()!r} or a newline (the text form could not be read back)")
        return np.array(encoded, dtype=numpy_type)
    physical = np.broadcast_to(np.asarray(values, dtype=float), (n,))
    if not np.all(np.isfinite(physical)) and char not in "fd":
        raise ValueError(f"{kind.name}.{column}: a value that is not finite")
    if char in "fd":
        return physical.astype(numpy_type)
    raw = np.round(physical / scale) if scale != 1.0 else np.round(physical)
    info = np.iinfo(np.dtype(numpy_type))
    if raw.size and (raw.min() < info.min or raw.max() > info.max):
        raise ValueError(f"{kind.name}.{column}: values {raw.min() * scale:g}..{raw.max() * scale:g} do not fit "
                         f"format '{char}' ({info.min * scale:g}..{info.max * scale:g})")
    return raw.astype(numpy_type)


def block(kind: MessageType, time: np.ndarray, **values: object) -> MessageBlock:
    """The messages of ``kind`` at boot times ``time`` [s] with every column's physical values (arrays of the
    messages' count, or one value for all)."""
    time = np.asarray(time, dtype=float)
    missing = set(kind.columns) - set(values)
    if missing or set(values) - set(kind.columns):
        raise ValueError(f"{kind.name}: columns {sorted(missing)} missing or {sorted(set(values) - set(kind.columns))}"
                         " unknown")
    stored = {column: _stored(kind, column, char, values[column], len(time))
              for column, char in zip(kind.columns, kind.format, strict=True)}
    return MessageBlock(kind, stored, time)


def format_block(kinds: list[MessageType]) -> MessageBlock:
    """The FMT messages defining ``kinds`` (FMT itself first)."""
    kinds = [FMT] + [k for k in kinds if k.type_id != FMT_TYPE]
    ids = [k.type_id for k in kinds]
    if len(set(ids)) != len(ids) or len({k.name for k in kinds}) != len(kinds):
        raise ValueError("message types need distinct numbers and names")
    return block(FMT, np.full(len(kinds), -np.inf), Type=ids, Length=[k.length for k in kinds],
                 Name=[k.name for k in kinds], Format=[k.format for k in kinds],
                 Columns=[",".join(k.columns) for k in kinds])


def _order(blocks: list[MessageBlock]) -> tuple[np.ndarray, np.ndarray]:
    """(block index, row) of every message in log order: by time, FMT messages first."""
    which = np.concatenate([np.full(len(b), k) for k, b in enumerate(blocks)])
    rows = np.concatenate([np.arange(len(b)) for b in blocks])
    time = np.concatenate([b.time for b in blocks])
    order = np.lexsort((rows, which, time))
    return which[order], rows[order]


def encode_binary(blocks: list[MessageBlock]) -> bytes:
    """The binary log of ``blocks`` (the first being :func:`format_block`'s)."""
    packed = []
    for b in blocks:
        records = np.zeros(len(b), dtype=b.kind.dtype)
        records["head1"], records["head2"], records["msgid"] = HEAD[0], HEAD[1], b.kind.type_id
        for column in b.kind.columns:
            records[column] = b.stored[column]
        packed.append(records.view(np.dtype((np.void, b.kind.length))))
    which, rows = _order(blocks)
    return b"".join(packed[k][r].tobytes() for k, r in zip(which.tolist(), rows.tolist(), strict=True))


def _text_cells(b: MessageBlock) -> list[list[str]]:
    """Each column's values as text: integers exact, scaled integers with their decimals, floats as the double
    that holds them exactly (a reader gets the stored float back)."""
    cells = []
    for column, char in zip(b.kind.columns, b.kind.format, strict=True):
        stored = b.stored[column]
        if FORMAT_CHARS[char][1] is None:
            cells.append([s.decode("ascii") for s in stored])
        elif char in _DECIMALS:
            digits = _DECIMALS[char]
            cells.append([f"{'-' if v < 0 else ''}{abs(v) // 10**digits}.{abs(v) % 10**digits:0{digits}d}"
                          for v in stored.astype(np.int64).tolist()])
        elif char in "fd":
            cells.append([repr(v) for v in stored.astype(float).tolist()])
        else:
            cells.append([str(v) for v in stored.tolist()])
    return cells


def encode_text(blocks: list[MessageBlock]) -> str:
    """The text log of ``blocks``: ``NAME, v1, v2, ...`` lines."""
    lines = []
    for b in blocks:
        cells = _text_cells(b)
        lines.append([", ".join([b.kind.name, *row]) for row in zip(*cells, strict=True)])
    which, rows = _order(blocks)
    return "".join(lines[k][r] + "\n" for k, r in zip(which.tolist(), rows.tolist(), strict=True))
