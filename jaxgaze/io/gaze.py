"""Per-frame gaze and head pose of one person, and target positions, for the bias adaptation
(Siegfried et al. 2017): our gaze CSV, an OpenFace 2 CSV, and a targets CSV.

Readers raise :class:`GazeFileError` (an :class:`~jaxgaze.io.text.InputFileError`,
``path, line N: what``); the OpenFace reader's own errors are
:class:`~jaxgaze.io.tools.openface.OpenFaceFileError` and its warnings (dropped frames) pass through.
"""

from __future__ import annotations

import math
import os
from typing import NamedTuple, Optional

import numpy as np

from jaxgaze.io.tools.openface import OpenFaceTrack, looks_like_openface, read_openface
from jaxgaze.io.poses import check_quaternion
from jaxgaze.io.text import InputFileError, read_csv_table, read_text
from jaxgaze.poses import quaternions_to_matrices

__all__ = ["GAZE_COLUMNS", "ANGLE_SD_COLUMN", "TARGET_COLUMNS", "GazeFileError", "GazeTrack", "is_openface_csv",
           "read_gaze", "read_gaze_csv", "read_openface_gaze", "openface_gaze_track", "read_targets_csv", "parse_point", "REFERENCE_AXES"]

#: Required columns of our gaze CSV, one row per frame: ``yaw, tilt`` the estimated gaze in the head
#: frame (radians, uncorrected), ``q`` the unit quaternion (w, x, y, z) of R_world_from_head, ``e`` the
#: eye midpoint (world, metres). Optional: ``timestamp`` (seconds) and :data:`TARGET_COLUMNS`.
GAZE_COLUMNS = ("frame", "yaw", "tilt", "qw", "qx", "qy", "qz", "ex", "ey", "ez")
#: Optional column of our gaze CSV: the per-frame sd of the angles (radians, in [0, 0.5]): the gaze estimator's, or
#: for head pose only the head tracker's, where the tool reports one (the joint model's ``measurement_scale``).
ANGLE_SD_COLUMN = "angle_sd"
#: Target position columns (metres): the partner's eye midpoint, in a gaze CSV or, with ``frame``, a targets CSV.
TARGET_COLUMNS = ("tx", "ty", "tz")
#: The frames of reference of a :class:`GazeTrack` (and of its targets), with their axes.
REFERENCE_AXES = {"camera": "camera frame (+x forward along the optical axis, +y left, +z up; not OpenCV's)",
                  "world": "world frame (that of the eye positions ex, ey, ez)"}
_FLOAT32_MAX = 3.4028234e38

class GazeFileError(InputFileError):
    """A malformed gaze or targets file. The message is ``path, line N: what``."""


class GazeTrack(NamedTuple):
    """One person's gaze over ``T`` frames, sorted by frame, in one frame of reference.

    ``format`` ``"csv"`` or ``"openface"``; ``frame (T,)`` int64; ``time (T,)`` float64
    seconds or ``None``; ``gaze_angles (T, 2)`` (yaw, tilt) in the head frame, radians;
    ``R_world_from_head (T, 3, 3)`` (``R_camera_from_head`` for OpenFace); ``eye (T, 3)``
    metres; ``target (T, 3)`` or ``None``; ``lines (T,)`` each frame's line in the file
    (``None`` for OpenFace); ``dropped`` OpenFace's dropped frames per reason;
    ``reference`` ``"world"`` or ``"camera"``; ``angle_sd (T,)`` the per-frame sd of the gaze angles (of the
    head's, for head pose only; radians) where the file gives one (:data:`ANGLE_SD_COLUMN`), else ``None``.
    """

    format: str
    frame: np.ndarray
    time: Optional[np.ndarray]
    gaze_angles: np.ndarray
    R_world_from_head: np.ndarray
    eye: np.ndarray
    target: Optional[np.ndarray]
    lines: Optional[np.ndarray]
    dropped: dict
    reference: str
    angle_sd: Optional[np.ndarray] = None

    @property
    def timestamp_rate(self) -> Optional[float]:
        """Frames per second from the timestamps, ``1 / median(Δtime / Δframe)`` to 6 decimals (``None``
        without timestamps or with one frame)."""
        if self.time is None or len(self.frame) < 2:
            return None
        return round(float(1.0 / np.median(np.diff(self.time) / np.diff(self.frame))), 6)

    def line_of(self, index: Optional[int]) -> Optional[int]:
        """The file line of frame ``index`` (``None`` when unknown)."""
        return None if self.lines is None or index is None else int(self.lines[index])


def is_openface_csv(text: str) -> bool:
    """Whether the first non-blank line names OpenFace's ``gaze_angle_x`` or ``pose_Rx`` column, or is
    otherwise OpenFace's (:func:`~jaxgaze.io.tools.openface.looks_like_openface`; then
    :func:`~jaxgaze.io.tools.openface.read_openface` names the missing columns and the flag that writes them)."""
    for line in text.splitlines():
        if line.strip():
            names = [cell.strip() for cell in line.split(",")]
            return bool({"gaze_angle_x", "pose_rx"} & {n.lower() for n in names}) or looks_like_openface(names)
    return False


def read_gaze(path, *, face_id: Optional[int] = None, min_confidence: float = 0.75) -> GazeTrack:
    """An OpenFace 2 CSV (:func:`read_openface_gaze`, by its header) or our gaze CSV (:func:`read_gaze_csv`)."""
    if is_openface_csv(read_text(path, GazeFileError, "gaze")):
        return read_openface_gaze(path, face_id=face_id, min_confidence=min_confidence)
    if face_id is not None:
        raise GazeFileError("a face id is only for OpenFace input (no gaze_angle_x and pose_Rx columns here)", path)
    return read_gaze_csv(path)


def _number(row, column: str) -> float:
    value = row.number(column)
    if abs(value) > _FLOAT32_MAX:
        raise row.error(f"column '{column}' is out of range (beyond float32): {row.cell(column)!r}")
    return value


def _check_increasing(time, frame, path, lines=None) -> None:
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise GazeFileError(f"timestamps must increase with the frame: frame {frame[i]} at {time[i]:g} s is not "
                            f"after frame {frame[i - 1]} at {time[i - 1]:g} s", path,
                            None if lines is None else int(lines[i]))


def read_gaze_csv(path, *, with_gaze: bool = True) -> GazeTrack:
    """Read our per-frame gaze CSV (columns :data:`GAZE_COLUMNS`, optional ``timestamp`` and
    :data:`TARGET_COLUMNS`), sorted by frame. Without ``with_gaze`` (head pose only), ``yaw, tilt`` are neither needed nor
    read: the gaze is NaN.

    ``yaw`` must lie in [−π, π] and ``tilt`` in [−π/2, π/2] (radians: degrees are caught
    here), the quaternion must be unit as for the pose readers (normalised here), frames
    unique, and timestamps must increase with the frame. Raises :class:`GazeFileError`
    (or the pose readers' error for a quaternion) naming the file and line.
    """
    required = GAZE_COLUMNS if with_gaze else tuple(c for c in GAZE_COLUMNS if c not in ("yaw", "tilt"))
    table = read_csv_table(path, required, ("timestamp", ANGLE_SD_COLUMN) + TARGET_COLUMNS, error=GazeFileError,
                           what="gaze")
    present = [c for c in TARGET_COLUMNS if table.has(c)]
    if present and len(present) < len(TARGET_COLUMNS):
        missing = [c for c in TARGET_COLUMNS if c not in present]
        raise table.fail("missing column" + ("s " if len(missing) > 1 else " ") + ", ".join(f"'{c}'" for c in missing)
                         + " in the header (the target columns " + ", ".join(TARGET_COLUMNS) + " go together)")
    timed = table.has("timestamp")
    rows, seen = [], {}
    for row in table.rows:
        frame = row.integer("frame")
        yaw, tilt = (_number(row, "yaw"), _number(row, "tilt")) if with_gaze else (math.nan, math.nan)
        if abs(yaw) > math.pi + 1e-9:
            raise row.error(f"column 'yaw' must be an angle in radians within [-pi, pi], got {row.cell('yaw')} "
                            "(degrees?)")
        if abs(tilt) > math.pi / 2 + 1e-9:
            raise row.error(f"column 'tilt' must be an angle in radians within [-pi/2, pi/2], got "
                            f"{row.cell('tilt')} (degrees?)")
        q = [_number(row, c) for c in ("qw", "qx", "qy", "qz")]
        check_quaternion(q, table.path, row.line)
        eye = [_number(row, c) for c in ("ex", "ey", "ez")]
        target = [_number(row, c) for c in present]
        time_s = _number(row, "timestamp") if timed else None
        sd = _number(row, ANGLE_SD_COLUMN) if table.has(ANGLE_SD_COLUMN) else math.nan
        if table.has(ANGLE_SD_COLUMN) and not 0.0 <= sd <= 0.5:
            raise row.error(f"column '{ANGLE_SD_COLUMN}' must be an sd in radians within [0, 0.5], got "
                            f"{row.cell(ANGLE_SD_COLUMN)} (degrees?)")
        first = seen.setdefault(frame, row.line)
        if first != row.line:
            raise row.error(f"duplicate frame {frame} (first on line {first})")
        rows.append((frame, time_s, (yaw, tilt), q, eye, target, row.line, sd))
    rows.sort(key=lambda r: r[0])
    frame = np.array([r[0] for r in rows], dtype=np.int64)
    lines = np.array([r[6] for r in rows], dtype=np.int64)
    time = np.array([r[1] for r in rows], dtype=np.float64) if timed else None
    if timed:
        _check_increasing(time, frame, table.path, lines)
    q = np.array([r[3] for r in rows], dtype=np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return GazeTrack(format="csv", frame=frame, time=time, gaze_angles=np.array([r[2] for r in rows], dtype=np.float64),
                     R_world_from_head=np.asarray(quaternions_to_matrices(q), dtype=np.float64),
                     eye=np.array([r[4] for r in rows], dtype=np.float64),
                     target=np.array([r[5] for r in rows], dtype=np.float64) if present else None,
                     lines=lines, dropped={}, reference="world",
                     angle_sd=np.array([r[7] for r in rows]) if table.has(ANGLE_SD_COLUMN) else None)


def read_openface_gaze(path, *, face_id: Optional[int] = None, min_confidence: float = 0.75) -> GazeTrack:
    """An OpenFace 2 CSV (:func:`~jaxgaze.io.tools.openface.read_openface`) as a :class:`GazeTrack` in our camera
    frame: the gaze angles in the head frame, ``R_camera_from_head``, the eyes at OpenFace's head position
    ``pose_T`` (metres) and no targets. Timestamps must increase with the frame."""
    return openface_gaze_track(read_openface(path, min_confidence=min_confidence, face_id=face_id), path)


def openface_gaze_track(track: OpenFaceTrack, path) -> GazeTrack:
    """An :class:`~jaxgaze.io.tools.openface.OpenFaceTrack` of ``path`` as a :class:`GazeTrack` (see
    :func:`read_openface_gaze`)."""
    frame = np.asarray(track.frame, dtype=np.int64)
    time = np.asarray(track.timestamp, dtype=np.float64)
    _check_increasing(time, frame, path)
    return GazeTrack(format="openface", frame=frame, time=time,
                     gaze_angles=np.asarray(track.gaze_angles_head, dtype=np.float64),
                     R_world_from_head=np.asarray(track.R_camera_from_head, dtype=np.float64),
                     eye=np.asarray(track.head_position_camera, dtype=np.float64), target=None, lines=None,
                     dropped=dict(track.dropped), reference="camera")


def read_targets_csv(path, frames=None):
    """Read a targets CSV: columns ``frame, tx, ty, tz`` (metres, the partner's eye midpoint), one row per frame.

    Returns ``(frame ids (N,), targets (N, 3))`` in file order, or, given ``frames (T,)``,
    the ``(T, 3)`` targets of those frames (:class:`GazeFileError` when one is missing).
    """
    table = read_csv_table(path, ("frame",) + TARGET_COLUMNS, error=GazeFileError, what="targets")
    targets, seen = {}, {}
    for row in table.rows:
        frame = row.integer("frame")
        point = np.array([_number(row, c) for c in TARGET_COLUMNS])
        first = seen.setdefault(frame, row.line)
        if first != row.line:
            raise row.error(f"duplicate frame {frame} (first on line {first})")
        targets[frame] = point
    if frames is None:
        return np.array(list(targets), dtype=np.int64), np.stack(list(targets.values()))
    missing = [int(f) for f in frames if int(f) not in targets]
    if missing:
        raise GazeFileError(f"frames of the gaze file and the targets do not match: no target for frame {missing[0]} "
                            f"({len(missing)} of {len(frames)} frames missing)", table.path)
    return np.stack([targets[int(f)] for f in frames])


def parse_point(text: str) -> Optional[np.ndarray]:
    """``"x,y,z"`` → ``(3,)`` float64, or ``None`` for a file name. ``ValueError`` for numbers that are
    not three or not finite, and for comma-separated text that names no file."""
    parts = text.split(",")
    try:
        point = np.array([float(p) for p in parts])
    except ValueError:
        if len(parts) > 1 and not os.path.exists(text):
            raise ValueError(f"expected X,Y,Z (3 numbers) or a CSV file, got {text!r}") from None
        return None
    if len(point) != 3:
        raise ValueError(f"expected X,Y,Z (3 numbers) or a CSV file, got {len(point)} number(s): {text!r}")
    if not np.all(np.isfinite(point)):
        raise ValueError(f"the point must be finite, got {text!r}")
    return point
