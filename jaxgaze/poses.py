"""Camera poses of head-mounted cameras: frame matching and the points of regard used for calibration (Park et al. 2012, Sec. 3.2).

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

import math
import warnings
from typing import NamedTuple, Optional

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgaze.rays import UnitWarning

__all__ = [
    "CameraPoses",
    "camera_poses",
    "as_camera_poses",
    "match_frames",
    "points_of_regard",
    "transform_poses",
    "quaternions_to_matrices",
    "matrices_to_quaternions",
    "REGARD_DISTANCE_RANGE",
    "MAX_CAMERA_SPEED",
]

#: Plausible range (metres) of the median distance between the two cameras of a calibration
#: session, people looking at each other's camera: outside it, positions are not in metres.
REGARD_DISTANCE_RANGE = (0.2, 50.0)
#: The fastest plausible median speed (m/s) of a head-mounted camera between frames.
MAX_CAMERA_SPEED = 10.0
#: Two cameras closer than this (metres) are at the same place: no two heads are.
_COINCIDENT = 0.01

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


def camera_poses(R, centers, frame_ids, timestamps=None) -> CameraPoses:
    """Build :class:`CameraPoses` from arrays, with checked shapes and dtypes, sorted by frame."""
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


def as_camera_poses(poses: CameraPoses, name: str) -> CameraPoses:
    """Check a given :class:`CameraPoses` (shapes only) and cast to NumPy."""
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


def quaternions_to_matrices(q: np.ndarray) -> np.ndarray:
    """``(T, 4)`` unit quaternions (w, x, y, z) → ``(T, 3, 3)`` float64 rotation matrices
    (``scipy.spatial.transform.Rotation``, which normalises ``q`` first)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    return Rotation.from_quat(q, scalar_first=True).as_matrix()


def matrices_to_quaternions(R: np.ndarray) -> np.ndarray:
    """``(T, 3, 3)`` rotation matrices → ``(T, 4)`` quaternions (w, x, y, z) with ``w ≥ 0``, float64
    (``scipy.spatial.transform.Rotation``)."""
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    q = Rotation.from_matrix(R).as_quat(scalar_first=True)
    return np.where(q[:, :1] < 0, -q, q)


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
    poses_a = as_camera_poses(poses_a, "poses_a")
    poses_b = as_camera_poses(poses_b, "poses_b")
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

    Units are checked at the door. Raises ``ValueError`` if the lengths differ; or if
    the two cameras are less than 1 cm apart in half the frames or more (the same
    pose track twice: every point of regard would be zero). A
    :class:`~jaxgaze.rays.UnitWarning` (implausible, not impossible: the library's unit
    rule) when the median distance ``‖y_i‖`` is outside :data:`REGARD_DISTANCE_RANGE`,
    naming the likely unit (millimetres, centimetres), or when a track with timestamps
    moves faster than :data:`MAX_CAMERA_SPEED` (median over frames). A plain warning
    when a few frames have the cameras at the same place.
    """
    poses_a = as_camera_poses(poses_a, "poses_a")
    poses_b = as_camera_poses(poses_b, "poses_b")
    if poses_a.num_frames != poses_b.num_frames:
        raise ValueError(
            f"points_of_regard: poses_a has {poses_a.num_frames} frames and poses_b "
            f"{poses_b.num_frames}; match them first with match_frames"
        )
    y = np.einsum("tij,tj->ti", poses_a.R_camera_from_world, poses_b.centers - poses_a.centers)
    _check_session_units(poses_a, poses_b, np.linalg.norm(y, axis=-1))
    return y


def _check_session_units(poses_a: CameraPoses, poses_b: CameraPoses, distances: np.ndarray) -> None:
    """The door checks of :func:`points_of_regard` on the distances ``‖C_B − C_A‖`` (metres)."""
    num_frames = distances.shape[0]
    if num_frames == 0 or not np.all(np.isfinite(distances)):
        return  # calibrate_cone names NaN/inf frames
    coincident = distances < _COINCIDENT
    if 2 * np.count_nonzero(coincident) >= num_frames:
        if np.array_equal(poses_a.centers, poses_b.centers) and np.array_equal(poses_a.R_camera_from_world,
                                                                               poses_b.R_camera_from_world):
            raise ValueError(f"the two pose tracks are identical in all {num_frames} matched frame(s) (the same "
                             "file twice?), so every point of regard is zero: the second must be the partner's "
                             "camera poses")
        raise ValueError(f"the two cameras are less than {100 * _COINCIDENT:g} cm apart in "
                         f"{np.count_nonzero(coincident)} of {num_frames} matched frame(s) (first: frame "
                         f"{int(poses_a.frame_ids[np.argmax(coincident)])}), so those points of regard are zero: "
                         "poses of the same wearer twice?")
    if coincident.any():
        warnings.warn(f"the two cameras are less than {100 * _COINCIDENT:g} cm apart in "
                      f"{np.count_nonzero(coincident)} of {num_frames} matched frame(s) (first: frame "
                      f"{int(poses_a.frame_ids[np.argmax(coincident)])}); those points of regard are ≈ 0",
                      stacklevel=3)
    median = float(np.median(distances[~coincident]))
    low, high = REGARD_DISTANCE_RANGE
    where = f"points of regard up to {float(distances.max()):.3g} m away, median {median:.3g} m"
    if median > high:
        unit = "millimetres" if median > 300.0 else "centimetres"
        warnings.warn(f"positions look like {unit} ({where}; two people looking at each other's camera are "
                      f"{low:g}–{high:g} m apart): poses must be in metres", UnitWarning, stacklevel=3)
    if median < low:
        warnings.warn(f"positions look too small for metres ({where}; two people looking at each other's camera "
                      f"are {low:g}–{high:g} m apart): poses must be in metres (an SfM reconstruction "
                      "without metric scale?)", UnitWarning, stacklevel=3)
    for name, poses in (("A", poses_a), ("B", poses_b)):
        speed = _median_speed(poses)
        if speed > MAX_CAMERA_SPEED:
            unit = "millimetres" if speed > 300 else "centimetres" if speed > 30 else "decimetres"
            warnings.warn(f"camera {name} moves at a median {speed:.3g} m/s between frames (a head-mounted camera "
                          f"moves at most {MAX_CAMERA_SPEED:g} m/s): positions look like {unit}, or timestamps "
                          "are not in seconds; poses must be in metres and timestamps in seconds", UnitWarning,
                          stacklevel=3)


def _median_speed(poses: CameraPoses) -> float:
    """Median ``‖ΔC‖ / Δt`` over consecutive frames with ``Δt > 0`` (m/s); 0 without timestamps."""
    if poses.timestamps is None or poses.num_frames < 2:
        return 0.0
    order = np.argsort(poses.timestamps, kind="stable")
    dt = np.diff(poses.timestamps[order])
    step = np.linalg.norm(np.diff(poses.centers[order], axis=0), axis=-1)
    moving = dt > 0
    return float(np.median(step[moving] / dt[moving])) if moving.any() else 0.0


def transform_poses(poses: CameraPoses, scale, R, t) -> CameraPoses:
    """Move poses into another world frame ``x' = scale · R @ x + t``.

    Use it with :func:`jaxgaze.geometry.similarity_alignment` (e.g. SfM → mocap):
    centres map as points and ``R_camera_from_world' = R_camera_from_world @ Rᵀ``.
    Lengths in the new world are ``scale`` times the old ones.
    """
    poses = as_camera_poses(poses, "poses")
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
