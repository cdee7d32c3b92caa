"""Compiled walk over the messages of a binary DataFlash log (ArduPilot ``.bin``, :mod:`georef.io.logs.dataflash`).

A binary DataFlash log is a run of messages, each ``0xA3 0x95 <type>`` followed by a body whose length the log
itself defines: the ``FMT`` message (type 128, 89 bytes) gives each type's total length, and FMT messages may
come anywhere before the type's first use. The walk keeps that table as it goes and returns every message's
offset and type; bytes that do not start a known message are skipped one by one until the next header, and
counted with the offset where each skipped run began (a log cut by a power loss, a corrupt sector). FMT's own
length is fixed (89 bytes): a FMT message that would change it is damaged, and the walk does not follow it.

pymavlink's ``DFReader_binary`` walks the same way in Python, orders of magnitude slower
(``docs/performance.md``, "Autopilot logs"); the bodies are then read by numpy, a type at a time.
"""

from __future__ import annotations

import numpy as np
from numba import njit

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE, FMT_LENGTH = 128, 89


@njit(cache=True)
def _room(values: np.ndarray, size: int) -> np.ndarray:
    """``values`` with room for one more element after its first ``size``."""
    if size < values.shape[0]:
        return values
    grown = np.empty(2 * values.shape[0] + 1, values.dtype)
    grown[:size] = values[:size]
    return grown


@njit(cache=True)
def scan(data: np.ndarray, lengths: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Offsets and types of the messages of ``data`` (uint8), the message lengths per type as learned from the
    FMT messages (``lengths`` (256,) int64, updated in place; 0 = unknown), and the offsets and lengths of the
    skipped byte runs. A message must fit inside ``limit`` bytes."""
    n = min(limit, data.shape[0])
    offsets = np.empty(max(16, n // 32), np.int64)
    types = np.empty(max(16, n // 32), np.int64)
    skip_at = np.empty(16, np.int64)
    skip_len = np.empty(16, np.int64)
    count = 0
    skips = 0
    in_skip = False
    pos = 0
    while pos < n:
        if pos + 3 <= n and data[pos] == HEAD1 and data[pos + 1] == HEAD2:
            kind = data[pos + 2]
            length = lengths[kind]
            if length >= 3 and pos + length <= n:
                if kind == FMT_TYPE and length >= 5 and data[pos + 4] >= 3 and \
                        (data[pos + 3] != FMT_TYPE or data[pos + 4] == FMT_LENGTH):
                    lengths[data[pos + 3]] = data[pos + 4]
                offsets = _room(offsets, count)
                types = _room(types, count)
                offsets[count] = pos
                types[count] = kind
                count += 1
                pos += length
                in_skip = False
                continue
        if not in_skip:
            skip_at = _room(skip_at, skips)
            skip_len = _room(skip_len, skips)
            skip_at[skips] = pos
            skip_len[skips] = 0
            skips += 1
            in_skip = True
        skip_len[skips - 1] += 1
        pos += 1
    return offsets[:count].copy(), types[:count].copy(), skip_at[:skips].copy(), skip_len[:skips].copy()
