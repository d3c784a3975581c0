"""Who speaks when: speech segments and per-frame speaking flags (Siegfried et al. 2017, Sec. 3).

Segments are ``[start, end)`` in seconds; a frame speaks for a speaker when its time
(rounded to 1 ns) lies in one of the speaker's segments. The file readers (RTTM, CSV)
are in :mod:`jaxgaze.io.speech`.
"""

from __future__ import annotations

import math
import operator
import warnings
from typing import NamedTuple, Sequence

import numpy as np

__all__ = ["SpeechSegments", "choose_partner", "speaking_flags", "speaking_at"]

#: Frame and segment times are rounded to 1 ns before they are compared.
TIME_DECIMALS = 9


class SpeechSegments(NamedTuple):
    """Speech segments ``[start, end)`` in seconds: ``start`` and ``end`` ``(K,)``
    float64 and ``speaker`` (a tuple of ``K`` names). The readers merge
    overlapping segments of one speaker and sort by ``(start, end, speaker)``."""

    start: np.ndarray
    end: np.ndarray
    speaker: tuple

    @property
    def speakers(self) -> tuple:
        """The speaker names, sorted and unique."""
        return tuple(sorted(set(self.speaker)))


def choose_partner(segments: SpeechSegments, partner: str | None, *, option: str = "partner=") -> str:
    """The partner's speaker name in ``segments``: ``partner``, or the only speaker when it is ``None``.

    Raises ``ValueError`` for an unknown name, or for ``None`` with several speakers (the
    message says to pass ``option``, e.g. a command-line flag).
    """
    listed = ", ".join(repr(s) for s in segments.speakers)
    if partner is None:
        if len(segments.speakers) != 1:
            raise ValueError(f"several speakers ({listed}): name the partner (the person looked at) with {option}")
        return segments.speakers[0]
    if partner not in segments.speakers:
        raise ValueError(f"unknown partner speaker {partner!r} (speakers: {listed})")
    return partner


def speaking_flags(
    segments: SpeechSegments, speakers: Sequence[str], num_frames: int, fps: float, start_time: float = 0.0
) -> np.ndarray:
    """``(len(speakers), num_frames)`` bool: whether each speaker speaks at each frame.

    Frame ``t`` is at time ``start_time + t / fps`` seconds (rounded to 1 ns) and
    is speaking for a speaker if that time lies in one of the speaker's segments
    ``[start, end)``. Segments of speakers not in ``speakers`` are ignored. Warns
    (i) naming requested speakers that have no segment at all ("unknown speaker";
    their rows are all False), and (ii) with the number of frames where two or
    more of ``speakers`` speak at once (overlapping speech: all of them are True).

    Raises ``ValueError`` for a negative ``num_frames``, ``fps ≤ 0`` or non-finite,
    a non-finite ``start_time``, duplicate ``speakers``, or segments whose arrays
    disagree in length, are not finite or have ``end < start``; ``TypeError`` if
    ``speakers`` is a single string.
    """
    if isinstance(speakers, str):
        raise TypeError(f"speaking_flags: speakers must be a sequence of names, not the string {speakers!r}")
    speakers = [str(s) for s in speakers]
    if len(set(speakers)) != len(speakers):
        raise ValueError(f"speaking_flags: duplicate names in speakers {speakers}")
    num_frames = operator.index(num_frames)
    fps, start_time = float(fps), float(start_time)
    if num_frames < 0:
        raise ValueError(f"speaking_flags: num_frames must be ≥ 0, got {num_frames}")
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"speaking_flags: fps must be finite and > 0, got {fps}")
    if not math.isfinite(start_time):
        raise ValueError(f"speaking_flags: start_time must be finite, got {start_time}")
    start = np.asarray(segments.start, dtype=np.float64).reshape(-1)
    end = np.asarray(segments.end, dtype=np.float64).reshape(-1)
    names = tuple(segments.speaker)
    if not (start.shape == end.shape == (len(names),)):
        raise ValueError(
            f"speaking_flags: segments have {start.shape[0]} starts, {end.shape[0]} ends and {len(names)} speakers"
        )
    if not (np.all(np.isfinite(start)) and np.all(np.isfinite(end)) and np.all(end >= start)):
        raise ValueError("speaking_flags: segment times must be finite with end ≥ start")

    times = start_time + np.arange(num_frames) / fps
    return _flags_at(start, end, names, speakers, times, "speaking_flags")


def speaking_at(segments: SpeechSegments, speakers: Sequence[str], times) -> np.ndarray:
    """:func:`speaking_flags` at given frame times ``(T,)`` (seconds, increasing), e.g. when frames were dropped.

    Same rule (``start ≤ time < end``, times rounded to 1 ns) and the same warnings.
    """
    if isinstance(speakers, str):
        raise TypeError(f"speaking_at: speakers must be a sequence of names, not the string {speakers!r}")
    speakers = [str(s) for s in speakers]
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ValueError("speaking_at: times must be a finite, non-decreasing (T,) array of seconds")
    start = np.asarray(segments.start, dtype=np.float64).reshape(-1)
    end = np.asarray(segments.end, dtype=np.float64).reshape(-1)
    if not (np.all(np.isfinite(start)) and np.all(np.isfinite(end)) and np.all(end >= start)):
        raise ValueError("speaking_at: segment times must be finite with end ≥ start")
    return _flags_at(start, end, tuple(segments.speaker), speakers, t, "speaking_at")


def _flags_at(start, end, names, speakers, times, caller: str) -> np.ndarray:
    """Flags ``(len(speakers), T)`` at the given times, with the unknown-speaker and overlap warnings."""
    num_frames = times.shape[0]
    unknown = [s for s in speakers if s not in set(names)]
    if unknown:
        warnings.warn(
            f"{caller}: unknown speaker(s) {', '.join(repr(s) for s in unknown)} have no segments "
            f"(known: {', '.join(repr(s) for s in sorted(set(names)))}); their flags are all False",
            stacklevel=3,
        )
    times = np.round(times, TIME_DECIMALS)
    flags = np.zeros((len(speakers), num_frames), dtype=bool)
    for row, name in enumerate(speakers):
        mine = np.array([n == name for n in names], dtype=bool)
        # Frames lo..hi-1 satisfy start ≤ time < end; a difference array marks them.
        lo = np.searchsorted(times, start[mine], side="left")
        hi = np.searchsorted(times, end[mine], side="left")
        marks = np.zeros(num_frames + 1, dtype=np.int64)
        np.add.at(marks, lo, 1)
        np.add.at(marks, hi, -1)
        flags[row] = np.cumsum(marks[:-1]) > 0
    overlapping = int(np.count_nonzero(flags.sum(axis=0) >= 2))
    if overlapping:
        warnings.warn(
            f"{caller}: {overlapping} of {num_frames} frames have two or more of the speakers speaking at once "
            "(overlapping speech); they are flagged for each of them",
            stacklevel=3,
        )
    return flags
