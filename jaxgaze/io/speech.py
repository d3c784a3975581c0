"""Speech segment files: NIST RTTM and a CSV of ``start,end,speaker`` (Siegfried et al. 2017, Sec. 3).

File errors raise :class:`SpeechFileError` whose message starts with ``path, line N:``.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Optional

import numpy as np

from jaxgaze.bias.speech import TIME_DECIMALS, SpeechSegments
from jaxgaze.io.text import InputFileError, first_few, parse_number, read_csv_table, read_lines

__all__ = ["SpeechFileError", "read_rttm", "read_segments_csv"]


class SpeechFileError(InputFileError):
    """An RTTM or segment CSV is malformed. The message starts with ``path, line N:``."""


def _segments(path, starts, ends, speakers, lines) -> SpeechSegments:
    """Merge overlapping segments of the same speaker (one short warning: the count and the first
    few cases), then sort."""
    merged, notes = [], []
    for name in sorted(set(speakers)):
        mine = sorted((s, e, n) for s, e, sp, n in zip(starts, ends, speakers, lines) if sp == name)
        current = list(mine[0])
        for s, e, n in mine[1:]:
            if s < current[1]:
                notes.append(f"'{name}' line {n} overlaps line {current[2]}")
                current[1] = max(current[1], e)
            else:
                merged.append((current[0], current[1], name))
                current = [s, e, n]
        merged.append((current[0], current[1], name))
    if notes:
        warnings.warn(
            f"{os.fspath(path)}: merged {len(notes)} overlapping segment(s) of the same speaker: "
            + first_few(notes, sep="; "),
            stacklevel=3,
        )
    merged.sort()
    return SpeechSegments(
        np.array([m[0] for m in merged], dtype=np.float64),
        np.array([m[1] for m in merged], dtype=np.float64),
        tuple(m[2] for m in merged),
    )


def read_rttm(path, *, file_id: Optional[str] = None) -> SpeechSegments:
    """Read speech segments from an RTTM file (NIST Rich Transcription Time Marked).

    Each ``SPEAKER <file> <channel> <onset> <duration> <NA> <NA> <speaker> <NA> <NA>``
    line (whitespace-separated, seconds) gives the segment
    ``[onset, onset + duration)`` (rounded to 1 ns). Other line types
    (``SPKR-INFO``, ``LEXEME``, ...) and ``;;`` comments are ignored. A file of
    several recordings (file ids, the 2nd field: AMI's or pyannote's RTTMs of a whole
    set) needs ``file_id`` to choose one: their times are on different clocks and
    their speaker names may repeat. Overlapping segments of one speaker are merged,
    with a warning.

    Raises :class:`SpeechFileError` (``path, line N:``) for an empty file, a
    SPEAKER line with fewer than 8 fields, a non-numeric or non-finite onset or
    duration, a negative duration, no SPEAKER lines, several recordings without
    ``file_id``, or no lines for ``file_id``.
    """
    lines = read_lines(path, SpeechFileError, "speech")
    if not any(ln.strip() for ln in lines):
        raise SpeechFileError(
            "empty file: expected RTTM lines "
            "'SPEAKER <file> <channel> <onset> <duration> <NA> <NA> <speaker> <NA> <NA>'",
            path,
            1,
        )
    starts, ends, names, where, files, first_line = [], [], [], [], [], {}
    for number, raw in enumerate(lines, start=1):
        fields = raw.split()
        if not fields or fields[0].startswith(";;") or fields[0] != "SPEAKER":
            continue
        if len(fields) < 8:
            raise SpeechFileError(
                "SPEAKER line needs at least 8 fields "
                f"'SPEAKER <file> <channel> <onset> <duration> <NA> <NA> <speaker>', got {len(fields)}",
                path,
                number,
            )
        files.append(fields[1])
        first_line.setdefault(fields[1], number)
        if file_id is not None and fields[1] != file_id:
            continue
        onset = parse_number(fields[3], "onset", path, number, SpeechFileError)
        duration = parse_number(fields[4], "duration", path, number, SpeechFileError)
        if duration < 0:
            raise SpeechFileError(f"negative duration {fields[4]}", path, number)
        if not math.isfinite(onset + duration):
            raise SpeechFileError(f"onset + duration is not finite: {fields[3]} + {fields[4]}", path, number)
        starts.append(onset)
        ends.append(round(onset + duration, TIME_DECIMALS))
        names.append(fields[7])
        where.append(number)
    if not files:
        raise SpeechFileError("no SPEAKER lines", path)
    ids = list(dict.fromkeys(files))
    if file_id is None and len(ids) > 1:
        raise SpeechFileError(f"a second recording '{ids[1]}' starts here: the RTTM holds {len(ids)} recordings "
                              f"(file ids {first_few(ids, 5)}) on separate clocks; choose one (file_id, --speech-file-id)", path,
                              first_line[ids[1]])
    if not starts:
        raise SpeechFileError(f"no SPEAKER lines for file '{file_id}' (files present: {first_few(sorted(ids), 5)})",
                              path)
    return _segments(path, starts, ends, names, where)


def read_segments_csv(path) -> SpeechSegments:
    """Read speech segments from a CSV file with a header row.

    Columns ``start, end, speaker`` (any order, case-insensitive; other columns
    ignored; blank lines and lines starting with ``#`` skipped): the segment
    ``[start, end)`` in seconds of ``speaker``. Overlapping segments of one speaker
    are merged, with a warning.

    Raises :class:`SpeechFileError` (``path, line N:``) for an empty file, a
    missing column, no data rows, a row with the wrong number of fields, a
    non-numeric or non-finite time, ``end < start`` or an empty speaker name.
    """
    table = read_csv_table(path, ("start", "end", "speaker"), error=SpeechFileError, what="speech", comments=True)
    starts, ends, speakers, where = [], [], [], []
    for row in table.rows:
        start, end, speaker = row.number("start"), row.number("end"), row.cell("speaker")
        if end < start:
            raise row.error(f"end {row.cell('end')} is before start {row.cell('start')}")
        if not speaker:
            raise row.error("empty speaker name")
        starts.append(start)
        ends.append(end)
        speakers.append(speaker)
        where.append(row.line)
    return _segments(path, starts, ends, speakers, where)
