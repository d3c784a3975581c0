"""Primary gaze rays as CSV, one row per (frame, person) (Park et al. 2012, Sec. 3.1).

Rays are in the world frame: origin ``(ox, oy, oz)`` the centre of the eyes (metres),
direction ``(dx, dy, dz)`` (any length, normalised on reading), and optionally the
bandwidth ``h`` (radians) and the ``depth`` of the point of regard (metres from the origin along
the unit direction, ``origin + depth · direction``; an empty cell where the tool gave none, as
Aria's ``depth_m``) with its sd ``depth_sd`` (metres; only beside ``depth``). Errors raise :class:`~jaxgaze.io.text.InputFileError`
(``path, line N: what``); writers are atomic.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Sequence

import numpy as np

from jaxgaze.io.text import InputFileError, atomic_path, csv_writer, format_float, read_csv_table
from jaxgaze.rays import GazeRays, check_bandwidth

__all__ = ["CSV_COLUMNS", "DEFAULT_BANDWIDTH", "Sampling", "RayRecording", "read_rays_csv", "write_rays_csv",
           "stack_rays"]

#: Required columns of a rays CSV (``bandwidth``, ``depth`` and ``depth_sd`` columns are optional).
CSV_COLUMNS = ("frame", "person", "ox", "oy", "oz", "dx", "dy", "dz")
#: Bandwidth ``h`` (radians) of every ray of a rays CSV without a ``bandwidth`` column.
DEFAULT_BANDWIDTH = 0.05

_MIN_DIRECTION_NORM = 1e-9
_RECENTRE_DISTANCE = 1024.0  # metres, as jaxgaze.concurrence.recentre.RECENTRE_DISTANCE
_FLOAT32_MAX = 3.4028234e38


class Sampling(NamedTuple):
    """How a reader of timestamped samples put them on frames: ``frame = round((t − start_ns) · fps / 1e9)``
    (``t`` on the shared clock, ns). Of the ``read`` samples, ``kept`` became rays; the others were
    ``filtered`` by the reader's own rules (Pupil's confidence below ``min_confidence`` or no 3D gaze,
    Neon's not worn or in a blink), had no pose (``outside`` the trajectory or in a gap of it) or were
    ``merged``: another sample of the same person lay nearer their frame's time."""

    fps: float
    start_ns: int
    read: int
    kept: int
    outside: int = 0
    merged: int = 0
    filtered: int = 0

    @property
    def dropped(self) -> int:
        """Samples read but not kept: ``read − kept``."""
        return self.read - self.kept


class RayRecording(NamedTuple):
    """A recording of gaze rays: sorted ``frame_ids`` ``(T,)``, the ``persons`` of each frame
    (lists, in file order) and :class:`~jaxgaze.rays.GazeRays` ``(T, N)`` padded and masked
    as by :meth:`GazeRays.stack` (``N`` the most people in a frame).

    ``reference`` (float64 ``(3,)`` metres, or ``None`` for the world origin) is the world point
    the rays' origins are measured from: the eyes in the world are ``rays.origins + reference``
    (:meth:`world_origins`). :func:`stack_rays` sets it for recordings far from the world origin
    (docs/conventions.md, "Far from the origin"), and locations found from ``rays`` are relative to it.

    ``depth`` (float64 ``(T, N)`` metres, or ``None``): the distance of each ray's point of regard from
    its origin along its unit direction (:meth:`points_of_regard`), NaN where unknown and in padding;
    ``depth_sd`` (same shape, or ``None``): its sd along the ray (metres), NaN where the tool gives none.
    ``sampling``: for readers of timestamped samples, the time grid and the count of samples kept
    and dropped (:class:`Sampling`). ``up``: the axis of the input's world that was up and was turned
    onto our +z (``"z"``: as read), for readers that know it.
    """

    frame_ids: list
    persons: list
    rays: GazeRays
    reference: Optional[np.ndarray] = None
    depth: Optional[np.ndarray] = None
    sampling: Optional[Sampling] = None
    up: Optional[str] = None
    depth_sd: Optional[np.ndarray] = None

    def world_origins(self) -> np.ndarray:
        """``(T, N, 3)`` float64 eyes in the world frame: ``rays.origins + reference``."""
        origins = np.asarray(self.rays.origins, dtype=np.float64)
        return origins if self.reference is None else origins + self.reference

    def points_of_regard(self) -> np.ndarray:
        """``(T, N, 3)`` float64 points of regard in the world frame: ``world_origins + depth · d / |d|``
        (NaN where the depth is unknown; all NaN without ``depth``)."""
        directions = np.asarray(self.rays.directions, dtype=np.float64)
        directions = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        depth = np.full(directions.shape[:-1], np.nan) if self.depth is None else np.asarray(self.depth, np.float64)
        return self.world_origins() + depth[..., None] * directions


def stack_rays(frames: Sequence[int], persons: Sequence[str], origins, directions, bandwidth, *,
               path, depth=None, depth_sd=None) -> RayRecording:
    """One ray per row (frame, person, origin (3,), direction (3,), bandwidth, optional depth and its sd) → a
    :class:`RayRecording`.

    Rows keep their order within a frame; frames are sorted; :meth:`GazeRays.from_rows`
    pads them (``depth``, ``depth_sd`` with NaN). Its ``ValueError`` becomes an :class:`InputFileError` naming ``path``.
    """
    if len(frames) == 0:
        raise InputFileError("no gaze rays", path)
    rows_of: dict[int, list[int]] = {}
    for i, frame in enumerate(frames):
        rows_of.setdefault(int(frame), []).append(i)
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    reference = None
    if np.all(np.isfinite(origins)) and np.abs(origins).max() > _RECENTRE_DISTANCE:
        # Far from the world origin (UTM, ECEF): measure the eyes from their mean, in float64,
        # before float32 rounds them (0.5 m at 5,000 km).
        reference = np.round(origins.mean(axis=0))
        origins = origins - reference
    try:
        frame_array, rays = GazeRays.from_rows(np.asarray(frames, dtype=np.int64), origins, directions, bandwidth)
    except ValueError as error:
        raise InputFileError(str(error), path) from None
    frame_ids = [int(f) for f in frame_array]

    def on_grid(values, what):  # one value per row → (T, N), NaN in padding
        if values is None:
            return None
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if values.shape[0] != len(frames):
            raise ValueError(f"stack_rays: {values.shape[0]} {what} for {len(frames)} rays")
        grid = np.full(np.asarray(rays.mask).shape, np.nan)
        for t, f in enumerate(frame_ids):
            grid[t, :len(rows_of[f])] = values[rows_of[f]]
        return grid

    return RayRecording(frame_ids, [[persons[i] for i in rows_of[f]] for f in frame_ids], rays, reference,
                        on_grid(depth, "depths"), depth_sd=on_grid(depth_sd, "depth sds"))


def _float32(row, column: str) -> float:
    value = row.number(column)
    if abs(value) > _FLOAT32_MAX:
        raise row.error(f"column '{column}' is out of range (beyond float32): {row.cell(column)!r}")
    return value


def _depth(row, column: str = "depth") -> float:
    """A ``depth`` or ``depth_sd`` cell: metres ≥ 0, NaN when empty."""
    if not row.cell(column):
        return math.nan
    value = _float32(row, column)
    if value < 0:
        raise row.error(f"{column} must be zero or more (metres along the ray), got {row.cell(column)}")
    return value


def read_rays_csv(path, default_bandwidth: float = DEFAULT_BANDWIDTH) -> RayRecording:
    """Read a CSV of primary gaze rays (columns :data:`CSV_COLUMNS`, optionally ``bandwidth`` and
    ``depth``: metres to the point of regard along the ray, an empty cell where unknown).

    Columns are in any order (case-insensitive); other columns are ignored, blank lines
    skipped. Rays without a ``bandwidth`` column get ``default_bandwidth``. Raises
    :class:`InputFileError` naming the file and line for a header problem, an empty or
    non-numeric cell, NaN/inf or a value beyond float32, a non-integer frame, a
    non-positive bandwidth or one of a radian or more (degrees?, :func:`~jaxgaze.rays.check_bandwidth`),
    a zero direction or a duplicate (frame, person).
    """
    table = read_csv_table(path, CSV_COLUMNS, ("bandwidth", "depth", "depth_sd"), empty="input is empty: expected a "
                           "header row with columns " + ", ".join(CSV_COLUMNS), empty_at_end=True)
    if table.has("depth_sd") and not table.has("depth"):
        raise table.fail("a depth_sd column without a depth column")
    frames, persons, origins, directions, bandwidth, depth, depth_sd = [], [], [], [], [], [], []
    seen: dict[tuple[int, str], int] = {}
    for row in table.rows:
        frame = row.integer("frame")
        person = row.text("person")
        origin = [_float32(row, c) for c in ("ox", "oy", "oz")]
        direction = [_float32(row, c) for c in ("dx", "dy", "dz")]
        h = default_bandwidth
        if table.has("bandwidth"):
            h = _float32(row, "bandwidth")
            if h <= 0:
                raise row.error(f"bandwidth must be positive (radians), got {row.cell('bandwidth')}")
            try:
                check_bandwidth(h)
            except ValueError as error:
                raise row.error(str(error)) from None
        if math.sqrt(sum(x * x for x in direction)) < _MIN_DIRECTION_NORM:
            raise row.error("direction (dx, dy, dz) has zero length")
        first = seen.setdefault((frame, person), row.line)
        if first != row.line:
            raise row.error(f"duplicate ray for frame {frame}, person '{person}' (first on line {first})")
        frames.append(frame)
        persons.append(person)
        origins.append(origin)
        directions.append(direction)
        bandwidth.append(h)
        if table.has("depth"):
            depth.append(_depth(row))
        if table.has("depth_sd"):
            depth_sd.append(_depth(row, "depth_sd"))
    return stack_rays(frames, persons, origins, directions, bandwidth, path=table.path,
                      depth=depth if table.has("depth") else None,
                      depth_sd=depth_sd if table.has("depth_sd") else None)


def write_rays_csv(path, recording: RayRecording) -> int:
    """Write a :class:`RayRecording` as a rays CSV with a ``bandwidth`` column, and a ``depth`` column
    when the recording has depths (empty where NaN), atomically; returns the number of rows. Padded
    slots are not written."""
    mask = np.asarray(recording.rays.mask)
    origins, directions = np.asarray(recording.rays.origins), np.asarray(recording.rays.directions)
    if recording.reference is not None:  # float64 world coordinates; otherwise the float32 values as read
        origins = recording.world_origins()
    bandwidth = np.asarray(recording.rays.bandwidth)
    extra = {name: np.asarray(values, dtype=np.float64) for name, values in
             (("depth", recording.depth), ("depth_sd", recording.depth_sd)) if values is not None}
    if "depth" not in extra:
        extra = {}
    rows = 0
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv_writer(handle)
        writer.writerow(CSV_COLUMNS + ("bandwidth",) + tuple(extra))
        for t, (frame, persons) in enumerate(zip(recording.frame_ids, recording.persons)):
            for n in np.flatnonzero(mask[t]):
                cells = [int(frame), persons[n], *map(format_float, origins[t, n]), *map(format_float, directions[t, n]),
                         format_float(bandwidth[t, n])]
                cells += [format_float(v[t, n]) if np.isfinite(v[t, n]) else "" for v in extra.values()]
                writer.writerow(cells)
                rows += 1
    return rows
