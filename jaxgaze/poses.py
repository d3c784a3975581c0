"""Camera poses of head-mounted cameras: COLMAP and CSV readers, frame matching,
and the points of regard used for calibration (Park et al. 2012, Sec. 3.2).

Conventions (see ``docs/conventions.md``, "Camera poses and COLMAP"):

* Our camera frame is +x forward (the optical axis), +y left, +z up, like the
  head frame. COLMAP / OpenCV cameras are x right, y down, z forward. The fixed
  rotation between the two is :data:`R_OURS_FROM_OPENCV`; the COLMAP reader and
  writer apply it, so every :class:`CameraPoses` is in **our** convention.
* ``R_camera_from_world`` maps world vectors into the camera frame:
  ``x_camera = R_camera_from_world @ (x_world − center)``. Its rows are the
  camera axes written in world coordinates, so the optical axis in the world is
  ``R_camera_from_world[0]``.
* Quaternions are ``(w, x, y, z)``, scalar first (COLMAP's order too).

Everything here is host-side NumPy in float64 (file I/O and bookkeeping); the
arrays go straight into JAX code. Errors in files raise :class:`PoseFileError`
(a ``ValueError``) whose message names the file and the line.
"""

from __future__ import annotations

import csv
import io
import math
import re
from typing import NamedTuple, Optional

import jax
import numpy as np

from jaxgaze.geometry import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from jaxgaze.textfiles import InputFileError, header_problem, parse_number, read_lines

__all__ = [
    "R_OURS_FROM_OPENCV",
    "CameraPoses",
    "PoseFileError",
    "POSE_CSV_COLUMNS",
    "read_colmap_images",
    "write_colmap_images",
    "read_pose_csv",
    "write_pose_csv",
    "match_frames",
    "points_of_regard",
    "transform_poses",
    "check_quaternion",
    "quaternions_to_matrices",
]

#: ``v_ours = R_OURS_FROM_OPENCV @ v_opencv``. OpenCV/COLMAP camera axes are
#: x right, y down, z forward; ours are x forward, y left, z up. So
#: our x = OpenCV z, our y = −(OpenCV x), our z = −(OpenCV y). det = +1.
#: A COLMAP world-to-camera rotation converts as
#: ``R_camera_from_world = R_OURS_FROM_OPENCV @ R_opencv_camera_from_world``.
R_OURS_FROM_OPENCV = np.array(
    [
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ]
)
R_OURS_FROM_OPENCV.setflags(write=False)

#: Required columns of :func:`read_pose_csv` (``timestamp`` is optional).
POSE_CSV_COLUMNS = ("frame", "qw", "qx", "qy", "qz", "cx", "cy", "cz")

#: Largest accepted ``|‖q‖ − 1|`` for a quaternion read from a file.
QUATERNION_NORM_TOLERANCE = 1e-3


class PoseFileError(InputFileError):
    """A pose file is malformed. The message starts with ``path, line N:``."""


class CameraPoses(NamedTuple):
    """Poses of one camera over ``T`` frames, in our camera convention.

    Fields (NumPy arrays, float64; a NamedTuple, hence also a JAX pytree):

    * ``R_camera_from_world`` ``(T, 3, 3)``: world → camera rotation
      (camera +x forward, +y left, +z up).
    * ``centers`` ``(T, 3)``: the camera's optical centre in the world, metres.
    * ``frame_ids`` ``(T,)`` int64: frame index of each pose.
    * ``timestamps`` ``(T,)`` float64 seconds, or ``None``.

    A point maps as ``x_camera = R_camera_from_world @ (x_world − center)``.
    """

    R_camera_from_world: np.ndarray
    centers: np.ndarray
    frame_ids: np.ndarray
    timestamps: Optional[np.ndarray] = None

    @property
    def num_frames(self) -> int:
        return int(np.shape(self.frame_ids)[0])

    @property
    def R_world_from_camera(self) -> np.ndarray:
        """``(T, 3, 3)``: the transpose of ``R_camera_from_world``."""
        return np.swapaxes(np.asarray(self.R_camera_from_world), -1, -2)

    @property
    def forward(self) -> np.ndarray:
        """``(T, 3)``: the optical axis (camera +x) in world coordinates."""
        return np.asarray(self.R_camera_from_world)[:, 0, :]

    def select(self, index) -> "CameraPoses":
        """The poses at ``index`` (an integer array, slice or boolean mask)."""
        index = np.asarray(index) if not isinstance(index, slice) else index
        return CameraPoses(
            np.asarray(self.R_camera_from_world)[index],
            np.asarray(self.centers)[index],
            np.asarray(self.frame_ids)[index],
            None if self.timestamps is None else np.asarray(self.timestamps)[index],
        )


def _make_poses(R, centers, frame_ids, timestamps=None) -> CameraPoses:
    """Build :class:`CameraPoses` with checked shapes and dtypes, sorted by frame."""
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    frame_ids = np.asarray(frame_ids, dtype=np.int64).reshape(-1)
    if timestamps is not None:
        timestamps = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    n = frame_ids.shape[0]
    if R.shape[0] != n or centers.shape[0] != n or (timestamps is not None and timestamps.shape[0] != n):
        raise ValueError("CameraPoses fields must all have the same number of frames")
    order = np.argsort(frame_ids, kind="stable")
    return CameraPoses(R[order], centers[order], frame_ids[order], None if timestamps is None else timestamps[order])


def _as_poses(poses: CameraPoses, name: str) -> CameraPoses:
    """Check a user-supplied :class:`CameraPoses` (shapes only) and cast to NumPy."""
    if not isinstance(poses, CameraPoses):
        raise TypeError(f"{name} must be CameraPoses, got {type(poses).__name__}")
    R = np.asarray(poses.R_camera_from_world, dtype=np.float64)
    C = np.asarray(poses.centers, dtype=np.float64)
    f = np.asarray(poses.frame_ids)
    ts = None if poses.timestamps is None else np.asarray(poses.timestamps, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise ValueError(f"{name}.R_camera_from_world must be (T, 3, 3), got {R.shape}")
    if C.shape != (R.shape[0], 3):
        raise ValueError(f"{name}.centers must be ({R.shape[0]}, 3), got {C.shape}")
    if f.shape != (R.shape[0],):
        raise ValueError(f"{name}.frame_ids must be ({R.shape[0]},), got {f.shape}")
    if ts is not None and ts.shape != (R.shape[0],):
        raise ValueError(f"{name}.timestamps must be ({R.shape[0]},), got {ts.shape}")
    return CameraPoses(R, C, f, ts)


# One compiled call per padded size (powers of two), instead of one eager op
# at a time for every new number of frames.
_quat_to_matrix_jit = jax.jit(quaternion_to_rotation_matrix)
_matrix_to_quat_jit = jax.jit(jax.vmap(rotation_matrix_to_quaternion))


def _padded_size(n: int) -> int:
    return max(16, 1 << (n - 1).bit_length())


def quaternions_to_matrices(q: np.ndarray) -> np.ndarray:
    """``(T, 4)`` unit quaternions (w, x, y, z) → ``(T, 3, 3)`` float64 rotation matrices.

    :func:`jaxgaze.geometry.quaternion_to_rotation_matrix` in float64, compiled once
    per padded length (powers of two) rather than once per file length.
    """
    n = q.shape[0]
    padded = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (_padded_size(n), 1))
    padded[:n] = q
    with jax.enable_x64(True):
        return np.asarray(_quat_to_matrix_jit(padded), dtype=np.float64)[:n]


def _matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """``(T, 3, 3)`` → ``(T, 4)`` (w, x, y, z) with ``w ≥ 0``, float64."""
    n = R.shape[0]
    padded = np.tile(np.eye(3), (_padded_size(n), 1, 1))
    padded[:n] = R
    with jax.enable_x64(True):
        return np.asarray(_matrix_to_quat_jit(padded), dtype=np.float64)[:n]


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
    return _make_poses(R, centers, frames)


def write_colmap_images(path, poses: CameraPoses, *, camera_id: int = 1) -> None:
    """Write :class:`CameraPoses` as COLMAP text ``images.txt``.

    The inverse of :func:`read_colmap_images`: image ``k`` (1-based) is named
    ``frame_%06d.jpg`` after its frame id, with ``camera_id`` and an empty
    POINTS2D line. Frame ids must be ≥ 0. Timestamps are not stored.
    """
    poses = _as_poses(poses, "poses")
    frames = np.asarray(poses.frame_ids)
    if np.any(frames < 0):
        raise ValueError("write_colmap_images: frame ids must be non-negative")
    if len(np.unique(frames)) != len(frames):
        raise ValueError("write_colmap_images: duplicate frame ids")
    R_cv = np.einsum("ji,tjk->tik", R_OURS_FROM_OPENCV, poses.R_camera_from_world)
    q = _matrix_to_quat(R_cv)
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
    return _make_poses(quaternions_to_matrices(q), centers, frames, stamps if ts_index is not None else None)


def write_pose_csv(path, poses: CameraPoses) -> None:
    """Write :class:`CameraPoses` in the format of :func:`read_pose_csv` (with
    ``timestamp`` when the poses have timestamps)."""
    poses = _as_poses(poses, "poses")
    q = _matrix_to_quat(poses.R_camera_from_world)
    columns = list(POSE_CSV_COLUMNS) + (["timestamp"] if poses.timestamps is not None else [])
    with open(path, "w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for k in range(poses.num_frames):
            row = [int(poses.frame_ids[k]), *(repr(float(x)) for x in q[k]), *(repr(float(x)) for x in poses.centers[k])]
            if poses.timestamps is not None:
                row.append(repr(float(poses.timestamps[k])))
            writer.writerow(row)


# ---------------------------------------------------------------------------
# Matching and points of regard


def _match_keys(keys_a: np.ndarray, keys_b: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one nearest-key pairs within ``tolerance``; indices sorted by ``keys_a``."""
    if len(keys_a) == 0 or len(keys_b) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order_b = np.argsort(keys_b, kind="stable")
    sorted_b = keys_b[order_b]
    pos = np.searchsorted(sorted_b, keys_a)
    left = np.clip(pos - 1, 0, len(sorted_b) - 1)
    right = np.clip(pos, 0, len(sorted_b) - 1)
    d_left = np.abs(keys_a - sorted_b[left])
    d_right = np.abs(sorted_b[right] - keys_a)
    take_right = d_right < d_left
    nearest = np.where(take_right, right, left)
    dist = np.where(take_right, d_right, d_left)
    candidates = np.nonzero(dist <= tolerance)[0]
    # When several of A share a nearest B, the closest keeps it (ties: earlier in A).
    used: set[int] = set()
    keep = []
    for ia in candidates[np.lexsort((candidates, dist[candidates]))]:
        ib = int(order_b[nearest[ia]])
        if ib not in used:
            used.add(ib)
            keep.append((int(ia), ib))
    keep.sort(key=lambda pair: (keys_a[pair[0]], pair[0]))
    ia = np.array([p[0] for p in keep], dtype=np.int64)
    ib = np.array([p[1] for p in keep], dtype=np.int64)
    return ia, ib


def match_frames(
    poses_a: CameraPoses,
    poses_b: CameraPoses,
    *,
    by: str = "frame",
    tolerance: Optional[float] = None,
) -> tuple[CameraPoses, CameraPoses]:
    """Restrict two pose sequences to their common frames, aligned row by row.

    * ``by="frame"``: pair equal ``frame_ids`` (``tolerance``, default 0, allows
      ``|frame_a − frame_b| ≤ tolerance``, nearest first).
    * ``by="timestamp"``: pair each pose of A with the pose of B nearest in
      time, if within ``tolerance`` seconds (required). Both need timestamps.

    Pairs are one-to-one: when several poses of A have the same nearest pose of
    B, the closest one keeps it. The result is sorted by A's key; row ``i`` of
    both outputs belongs to the same moment. Raises ``ValueError`` if nothing
    matches, for an unknown ``by``, a negative or missing tolerance, or missing
    timestamps.
    """
    poses_a = _as_poses(poses_a, "poses_a")
    poses_b = _as_poses(poses_b, "poses_b")
    if by == "frame":
        tol = 0.0 if tolerance is None else float(tolerance)
        keys_a = poses_a.frame_ids.astype(np.float64)
        keys_b = poses_b.frame_ids.astype(np.float64)
    elif by == "timestamp":
        if tolerance is None:
            raise ValueError("match_frames: by='timestamp' needs a tolerance in seconds")
        tol = float(tolerance)
        if poses_a.timestamps is None or poses_b.timestamps is None:
            which = "poses_a" if poses_a.timestamps is None else "poses_b"
            raise ValueError(f"match_frames: by='timestamp' but {which} has no timestamps")
        keys_a, keys_b = poses_a.timestamps, poses_b.timestamps
        if not (np.all(np.isfinite(keys_a)) and np.all(np.isfinite(keys_b))):
            raise ValueError("match_frames: timestamps must be finite")
    else:
        raise ValueError(f"match_frames: by must be 'frame' or 'timestamp', got {by!r}")
    if not (tol >= 0.0 and math.isfinite(tol)):
        raise ValueError(f"match_frames: tolerance must be finite and ≥ 0, got {tolerance!r}")
    ia, ib = _match_keys(keys_a, keys_b, tol)
    if len(ia) == 0:
        raise ValueError(
            f"match_frames: no common frames (by={by!r}, tolerance={tol:g}; "
            f"{poses_a.num_frames} and {poses_b.num_frames} poses)"
        )
    return poses_a.select(ia), poses_b.select(ib)


def points_of_regard(poses_a: CameraPoses, poses_b: CameraPoses) -> np.ndarray:
    """Where wearer A looks when looking at B's camera, in A's camera frame.

    ``y_i = R_A,i (C_B,i − C_A,i)`` (Park et al. 2012, Sec. 3.2), ``(T, 3)`` in
    metres, with +x A's optical axis. The two sequences must already be
    matched (same length, row ``i`` the same moment): use :func:`match_frames`.
    Raises ``ValueError`` if their lengths differ.
    """
    poses_a = _as_poses(poses_a, "poses_a")
    poses_b = _as_poses(poses_b, "poses_b")
    if poses_a.num_frames != poses_b.num_frames:
        raise ValueError(
            f"points_of_regard: poses_a has {poses_a.num_frames} frames and poses_b "
            f"{poses_b.num_frames}; match them first with match_frames"
        )
    return np.einsum("tij,tj->ti", poses_a.R_camera_from_world, poses_b.centers - poses_a.centers)


def transform_poses(poses: CameraPoses, scale, R, t) -> CameraPoses:
    """Move poses into another world frame ``x' = scale · R @ x + t``.

    Use it with :func:`jaxgaze.geometry.similarity_alignment` (e.g. SfM → mocap):
    centres map as points and ``R_camera_from_world' = R_camera_from_world @ Rᵀ``.
    Lengths in the new world are ``scale`` times the old ones.
    """
    poses = _as_poses(poses, "poses")
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    scale = float(scale)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"transform_poses: R must be (3, 3) and t (3,), got {R.shape} and {t.shape}")
    if not scale > 0:
        raise ValueError(f"transform_poses: scale must be positive, got {scale}")
    return CameraPoses(
        poses.R_camera_from_world @ R.T,
        scale * poses.centers @ R.T + t,
        poses.frame_ids,
        poses.timestamps,
    )
