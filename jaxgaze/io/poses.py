"""Camera-pose files: COLMAP's ``images.txt``, a pose CSV, and a CSV of several wearers'
camera poses (Park et al. 2012, Sec. 3.2).

All are read into :class:`~jaxgaze.poses.CameraPoses` in **our** camera convention
(+x forward, +y left, +z up; ``docs/conventions.md``, "Camera poses and COLMAP"):
the COLMAP reader and writer apply :data:`~jaxgaze.geometry.R_OURS_FROM_OPENCV`.
Quaternions are ``(w, x, y, z)``, scalar first. Errors raise :class:`PoseFileError`
whose message starts with ``path, line N:``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from typing import NamedTuple, Optional

import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.text import InputFileError, atomic_path, parse_number, read_csv_table, read_lines
from jaxgaze.poses import CameraPoses, as_camera_poses, camera_poses, matrices_to_quaternions, quaternions_to_matrices

__all__ = [
    "PoseFileError",
    "POSE_CSV_COLUMNS",
    "read_colmap_images",
    "write_colmap_images",
    "read_pose_csv",
    "write_pose_csv",
    "read_poses",
    "check_quaternion",
    "CAMERA_POSE_COLUMNS",
    "WearerPoses",
    "read_camera_poses_csv",
    "write_camera_poses_csv",
]

#: Required columns of :func:`read_pose_csv` (``timestamp`` is optional).
POSE_CSV_COLUMNS = ("frame", "qw", "qx", "qy", "qz", "cx", "cy", "cz")

#: Columns of a camera-pose CSV of several wearers, one row per (frame, person): ``q`` the unit
#: quaternion (w, x, y, z) of R_camera_from_world in our camera convention, ``c`` the centre (m).
CAMERA_POSE_COLUMNS = ("frame", "person", "qw", "qx", "qy", "qz", "cx", "cy", "cz")

#: Largest accepted ``|‖q‖ − 1|`` for a quaternion read from a file.
QUATERNION_NORM_TOLERANCE = 1e-3


class PoseFileError(InputFileError):
    """A pose file is malformed. The message starts with ``path, line N:``."""


def _read_text(path) -> list[str]:
    return read_lines(path, PoseFileError, "pose")


def _number(text: str, what: str, path, line: int) -> float:
    return parse_number(text, what, path, line, PoseFileError)


def _integer(text: str, what: str, path, line: int) -> int:
    value = _number(text, what, path, line)
    if not value.is_integer():
        raise PoseFileError(f"{what} must be an integer, got {text!r}", path, line)
    return int(value)


def check_quaternion(q, path, line: int) -> None:
    """Raise :class:`PoseFileError` at ``path, line`` unless ``|‖q‖ − 1| ≤ QUATERNION_NORM_TOLERANCE``."""
    norm = math.sqrt(sum(x * x for x in q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise PoseFileError(
            f"quaternion (qw, qx, qy, qz) = {tuple(q)} is not unit: norm {norm:.6g} "
            f"(allowed |norm − 1| ≤ {QUATERNION_NORM_TOLERANCE:g})",
            path,
            line,
        )


def _check_duplicates(frames: list[int], lines: list[int], path) -> None:
    first: dict[int, int] = {}
    for frame, line in zip(frames, lines):
        seen = first.setdefault(frame, line)
        if seen != line:
            raise PoseFileError(f"duplicate frame {frame} (first on line {seen})", path, line)


_TRAILING_DIGITS = re.compile(r"(\d+)$")


def _frame_from_name(name: str) -> Optional[int]:
    """Trailing digits of the file name's stem: ``dir/frame_000123.jpg`` → 123."""
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    stem = base.rsplit(".", 1)[0] if "." in base else base
    match = _TRAILING_DIGITS.search(stem)
    return int(match.group(1)) if match else None


# ---------------------------------------------------------------------------
# COLMAP


def read_colmap_images(path) -> CameraPoses:
    """Read COLMAP's text ``images.txt`` into :class:`CameraPoses` (our convention).

    Format: lines starting with ``#`` are comments. Each image takes two lines:
    ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and then its POINTS2D line
    (``X Y POINT3D_ID`` triples; it may be empty). COLMAP's pose is world to
    camera in the OpenCV camera frame, ``x_cam = R(q) x_world + t``, so the
    centre is ``C = −R(q)ᵀ t`` and ``R_camera_from_world = R_OURS_FROM_OPENCV @ R(q)``.

    The frame index is the trailing digits of NAME's stem (``frame_000123.jpg``
    → 123), or IMAGE_ID if the stem does not end in digits. Poses are sorted by
    frame; ``timestamps`` is ``None``.

    Raises :class:`PoseFileError` (a ``ValueError``) naming file and line for a
    missing or non-numeric field, a NaN/inf, a non-unit quaternion
    (``|‖q‖ − 1| > 1e-3``), a missing POINTS2D line, a duplicate frame, or a
    file with no images.
    """
    lines = _read_text(path)
    quats, ts, frames, where = [], [], [], []
    i = 0
    while i < len(lines):
        raw = lines[i]
        number = i + 1
        i += 1
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split()
        if len(fields) < 10:
            raise PoseFileError(
                f"expected 10 fields 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {len(fields)}",
                path,
                number,
            )
        image_id = _integer(fields[0], "IMAGE_ID", path, number)
        q = [_number(fields[1 + k], name, path, number) for k, name in enumerate(("QW", "QX", "QY", "QZ"))]
        t = [_number(fields[5 + k], name, path, number) for k, name in enumerate(("TX", "TY", "TZ"))]
        _integer(fields[8], "CAMERA_ID", path, number)
        name = " ".join(fields[9:])
        check_quaternion(q, path, number)
        # The next line, whatever it holds, is this image's POINTS2D line (as in COLMAP).
        if i < len(lines):
            points = lines[i].split()
            if len(points) % 3 != 0:
                raise PoseFileError(
                    f"expected the POINTS2D line of image {image_id} (X Y POINT3D_ID triples, "
                    f"possibly empty), got {len(points)} fields",
                    path,
                    i + 1,
                )
            i += 1
        frame = _frame_from_name(name)
        quats.append(q)
        ts.append(t)
        frames.append(image_id if frame is None else frame)
        where.append(number)
    if not frames:
        raise PoseFileError("no images: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME' lines", path)
    _check_duplicates(frames, where, path)
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    R_cv = quaternions_to_matrices(q)
    t = np.asarray(ts, dtype=np.float64)
    centers = -np.einsum("tji,tj->ti", R_cv, t)
    R = np.einsum("ij,tjk->tik", R_OURS_FROM_OPENCV, R_cv)
    return camera_poses(R, centers, frames)


def write_colmap_images(path, poses: CameraPoses, *, camera_id: int = 1) -> None:
    """Write :class:`CameraPoses` as COLMAP text ``images.txt``.

    The inverse of :func:`read_colmap_images`: image ``k`` (1-based) is named
    ``frame_%06d.jpg`` after its frame id, with ``camera_id`` and an empty
    POINTS2D line. Frame ids must be ≥ 0. Timestamps are not stored. The file is
    written atomically.
    """
    poses = as_camera_poses(poses, "poses")
    frames = np.asarray(poses.frame_ids)
    if np.any(frames < 0):
        raise ValueError("write_colmap_images: frame ids must be non-negative")
    if len(np.unique(frames)) != len(frames):
        raise ValueError("write_colmap_images: duplicate frame ids")
    R_cv = np.einsum("ji,tjk->tik", R_OURS_FROM_OPENCV, poses.R_camera_from_world)
    q = matrices_to_quaternions(R_cv)
    t = -np.einsum("tij,tj->ti", R_cv, poses.centers)
    out = io.StringIO()
    out.write("# Image list with two lines of data per image:\n")
    out.write("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n")
    out.write("#   POINTS2D[] as (X, Y, POINT3D_ID)\n")
    out.write(f"# Number of images: {len(frames)}, written by jaxgaze.poses (no 2D points)\n")
    for k in range(len(frames)):
        values = " ".join(repr(float(x)) for x in (*q[k], *t[k]))
        out.write(f"{k + 1} {values} {camera_id} frame_{int(frames[k]):06d}.jpg\n\n")
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as handle:
        handle.write(out.getvalue())


# ---------------------------------------------------------------------------
# CSV


def read_pose_csv(path) -> CameraPoses:
    """Read camera poses from a CSV file with a header row.

    Columns (any order, case-insensitive): ``frame, qw, qx, qy, qz, cx, cy, cz``
    and optionally ``timestamp`` (seconds). ``(qw, qx, qy, qz)`` is the unit
    quaternion of ``R_camera_from_world`` in **our** camera convention (+x
    forward, +y left, +z up), not OpenCV's; ``(cx, cy, cz)`` is the camera
    centre in the world, metres. Other columns are ignored; blank lines and
    lines starting with ``#`` are skipped. Poses are sorted by frame.

    Raises :class:`PoseFileError` (a ``ValueError``) naming file and line for a
    missing column, an empty or non-numeric cell, NaN/inf, a non-integer frame,
    a non-unit quaternion (``|‖q‖ − 1| > 1e-3``), a duplicate frame or an empty
    file.
    """
    table = read_csv_table(path, POSE_CSV_COLUMNS, ("timestamp",), error=PoseFileError, what="pose", comments=True)
    frames, quats, centers, stamps, where = [], [], [], [], []
    for row in table.rows:
        frames.append(row.integer("frame"))
        quats.append(_row_quaternion(row))
        centers.append([row.number(c) for c in ("cx", "cy", "cz")])
        if table.has("timestamp"):
            stamps.append(row.number("timestamp"))
        where.append(row.line)
    _check_duplicates(frames, where, table.path)
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return camera_poses(quaternions_to_matrices(q), centers, frames, stamps if table.has("timestamp") else None)


def _row_quaternion(row) -> list:
    q = [row.number(c) for c in ("qw", "qx", "qy", "qz")]
    check_quaternion(q, row.table.path, row.line)
    return q


def write_pose_csv(path, poses: CameraPoses) -> None:
    """Write :class:`CameraPoses` in the format of :func:`read_pose_csv` (with
    ``timestamp`` when the poses have timestamps), atomically."""
    poses = as_camera_poses(poses, "poses")
    q = matrices_to_quaternions(poses.R_camera_from_world)
    columns = list(POSE_CSV_COLUMNS) + (["timestamp"] if poses.timestamps is not None else [])
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for k in range(poses.num_frames):
            row = [int(poses.frame_ids[k]), *(repr(float(x)) for x in q[k]), *(repr(float(x)) for x in poses.centers[k])]
            if poses.timestamps is not None:
                row.append(repr(float(poses.timestamps[k])))
            writer.writerow(row)


def read_poses(path) -> CameraPoses:
    """One wearer's camera poses from a COLMAP ``images.txt`` (``.txt``, :func:`read_colmap_images`)
    or a pose CSV (``.csv``, :func:`read_pose_csv`); :class:`PoseFileError` for another extension."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in (".txt", ".csv"):
        raise PoseFileError(f"unknown pose file type '{ext}': expected a COLMAP images.txt (.txt) or a pose CSV "
                            "(.csv)", path)
    return read_colmap_images(path) if ext == ".txt" else read_pose_csv(path)


# ---------------------------------------------------------------------------
# Several wearers in one CSV


class WearerPoses(NamedTuple):
    """The camera poses of several wearers from one camera-pose CSV.

    ``poses`` maps each person (in the order of their first row) to their
    :class:`CameraPoses` (sorted by frame); ``lines`` maps each person to the file
    line of each of those poses; ``path`` is the file.
    """

    poses: dict
    lines: dict
    path: str


def read_camera_poses_csv(path) -> WearerPoses:
    """Read a CSV of camera poses, one row per (frame, person), columns :data:`CAMERA_POSE_COLUMNS`.

    Columns are in any order (case-insensitive); other columns are ignored, blank lines
    skipped. ``(qw, qx, qy, qz)`` is the unit quaternion of ``R_camera_from_world`` in
    our camera convention (+x forward, +y left, +z up), checked as by
    :func:`read_pose_csv`; ``(cx, cy, cz)`` is the camera centre in the world (metres).
    Raises :class:`PoseFileError` naming the file and line for a header problem, an
    empty or non-numeric cell, NaN/inf, a non-integer frame, a non-unit quaternion or
    a duplicate (frame, person).
    """
    table = read_csv_table(path, CAMERA_POSE_COLUMNS, error=PoseFileError)
    rows: dict[str, list] = {}
    seen: dict[tuple[int, str], int] = {}
    for row in table.rows:
        frame = row.integer("frame")
        person = row.text("person")
        q = _row_quaternion(row)
        centre = [row.number(c) for c in ("cx", "cy", "cz")]
        first = seen.setdefault((frame, person), row.line)
        if first != row.line:
            raise row.error(f"duplicate pose for frame {frame}, person '{person}' (first on line {first})")
        rows.setdefault(person, []).append((frame, q, centre, row.line))
    poses, lines = {}, {}
    for person, mine in rows.items():
        q = np.asarray([r[1] for r in mine], dtype=np.float64)
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        frames = np.asarray([r[0] for r in mine], dtype=np.int64)
        poses[person] = camera_poses(quaternions_to_matrices(q), [r[2] for r in mine], frames)
        lines[person] = np.asarray([r[3] for r in mine], dtype=np.int64)[np.argsort(frames, kind="stable")]
    return WearerPoses(poses, lines, table.path)


def write_camera_poses_csv(path, poses: dict) -> None:
    """Write ``{person: CameraPoses}`` as a camera-pose CSV (:data:`CAMERA_POSE_COLUMNS`),
    rows sorted by frame, then in the order of ``poses``; atomically."""
    rows = []
    for k, (person, p) in enumerate(poses.items()):
        p = as_camera_poses(p, f"poses[{person!r}]")
        q = matrices_to_quaternions(p.R_camera_from_world)
        for t in range(p.num_frames):
            rows.append((int(p.frame_ids[t]), k, [int(p.frame_ids[t]), person, *(repr(float(x)) for x in q[t]),
                                                 *(repr(float(x)) for x in p.centers[t])]))
    rows.sort(key=lambda r: r[:2])
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(CAMERA_POSE_COLUMNS)
        writer.writerows(r[2] for r in rows)
