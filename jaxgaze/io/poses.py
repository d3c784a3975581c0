"""Camera-pose files: COLMAP's ``images.txt`` and a pose CSV (Park et al. 2012, Sec. 3.2).

Both are read into :class:`~jaxgaze.poses.CameraPoses` in **our** camera convention
(+x forward, +y left, +z up; ``docs/conventions.md``, "Camera poses and COLMAP"):
the COLMAP reader and writer apply :data:`~jaxgaze.geometry.R_OURS_FROM_OPENCV`.
Quaternions are ``(w, x, y, z)``, scalar first. Errors raise :class:`PoseFileError`
whose message starts with ``path, line N:``.
"""

from __future__ import annotations

import csv
import io
import math
import re
from typing import Optional

import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.text import InputFileError, header_problem, parse_number, read_lines
from jaxgaze.poses import CameraPoses, as_camera_poses, camera_poses, matrices_to_quaternions, quaternions_to_matrices

__all__ = [
    "PoseFileError",
    "POSE_CSV_COLUMNS",
    "read_colmap_images",
    "write_colmap_images",
    "read_pose_csv",
    "write_pose_csv",
    "check_quaternion",
]

#: Required columns of :func:`read_pose_csv` (``timestamp`` is optional).
POSE_CSV_COLUMNS = ("frame", "qw", "qx", "qy", "qz", "cx", "cy", "cz")

#: Largest accepted ``|‖q‖ − 1|`` for a quaternion read from a file.
QUATERNION_NORM_TOLERANCE = 1e-3


class PoseFileError(InputFileError):
    """A pose file is malformed. The message starts with ``path, line N:``."""


def _read_text(path) -> list[str]:
    return read_lines(path, PoseFileError)


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
    POINTS2D line. Frame ids must be ≥ 0. Timestamps are not stored.
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
    with open(path, "w", encoding="utf-8", newline="\n") as handle:
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
    lines = _read_text(path)
    # Keep line numbers: feed csv only the non-comment lines, one at a time.
    content = [(n + 1, ln) for n, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not content:
        raise PoseFileError(
            "empty file: expected a header row with columns " + ", ".join(POSE_CSV_COLUMNS), path, 1
        )
    rows = []
    for n, ln in content:
        try:
            rows.append((n, next(csv.reader([ln], strict=True))))
        except csv.Error as error:
            raise PoseFileError(f"malformed CSV: {error}", path, n) from None
    header_line, header = rows[0]
    names = [cell.strip().lower() for cell in header]
    problem = header_problem(names, POSE_CSV_COLUMNS,
                             hint="need " + ", ".join(POSE_CSV_COLUMNS) + ", optionally timestamp")
    if problem:
        raise PoseFileError(problem, path, header_line)
    index = {c: names.index(c) for c in POSE_CSV_COLUMNS}
    ts_index = names.index("timestamp") if "timestamp" in names else None
    if len(rows) == 1:
        raise PoseFileError("no data rows after the header", path, header_line)

    frames, quats, centers, stamps, where = [], [], [], [], []
    for number, row in rows[1:]:
        if len(row) != len(header):
            raise PoseFileError(f"expected {len(header)} fields as in the header, got {len(row)}", path, number)

        def cell(column: str, col: int) -> str:
            text = row[col].strip()
            if not text:
                raise PoseFileError(f"empty cell in column '{column}'", path, number)
            return text

        frames.append(_integer(cell("frame", index["frame"]), "column 'frame'", path, number))
        q = [_number(cell(c, index[c]), f"column '{c}'", path, number) for c in ("qw", "qx", "qy", "qz")]
        check_quaternion(q, path, number)
        quats.append(q)
        centers.append([_number(cell(c, index[c]), f"column '{c}'", path, number) for c in ("cx", "cy", "cz")])
        if ts_index is not None:
            stamps.append(_number(cell("timestamp", ts_index), "column 'timestamp'", path, number))
        where.append(number)
    _check_duplicates(frames, where, path)
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return camera_poses(quaternions_to_matrices(q), centers, frames, stamps if ts_index is not None else None)


def write_pose_csv(path, poses: CameraPoses) -> None:
    """Write :class:`CameraPoses` in the format of :func:`read_pose_csv` (with
    ``timestamp`` when the poses have timestamps)."""
    poses = as_camera_poses(poses, "poses")
    q = matrices_to_quaternions(poses.R_camera_from_world)
    columns = list(POSE_CSV_COLUMNS) + (["timestamp"] if poses.timestamps is not None else [])
    with open(path, "w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for k in range(poses.num_frames):
            row = [int(poses.frame_ids[k]), *(repr(float(x)) for x in q[k]), *(repr(float(x)) for x in poses.centers[k])]
            if poses.timestamps is not None:
                row.append(repr(float(poses.timestamps[k])))
            writer.writerow(row)
