"""ETH-XGaze, MPIIFaceGaze and ptgaze gaze angles → world-frame rays (Zhang et al. 2020, "ETH-XGaze",
Sec. 4.1, data normalisation; Zhang, Sugano & Bulling 2018, "Revisiting data normalization", Sec. 4.2).

These networks see a *normalised* face image: a virtual camera rotated by ``R`` (the normalising
rotation) so that it looks straight at the face centre, with the head's x axis kept horizontal. They
output ``(pitch, yaw)`` in radians in that normalised camera frame. The conventions, from the tools'
own code:

* **angles → vector** (ptgaze ``FaceParts.angle_to_vector``; ETH-XGaze's labels in
  ``normalization_example.py``: ``pitch = arcsin(−g_y)``, ``yaw = arctan2(−g_x, −g_z)``), OpenCV axes
  (x right, y down, z forward)::

      g_norm = −(cos(pitch) sin(yaw), sin(pitch), cos(pitch) cos(yaw))

  so ``(0, 0)`` looks back into the camera, ``pitch > 0`` looks up and ``yaw > 0`` toward the
  camera's left (image left: the person's **right**);
* **normalising rotation** (ETH-XGaze ``normalizeData_face``; ptgaze
  ``HeadPoseNormalizer._compute_normalizing_rotation``): rows ``x, y, z`` with ``z = unit(c)``
  (``c`` the face centre in the camera), ``y = unit(z × h_x)`` (``h_x`` the head rotation's first
  column) and ``x = unit(y × z)``; ETH-XGaze normalises a gaze vector as ``g_norm = R g``;
* **de-normalisation** (ptgaze ``FaceParts.denormalize_gaze_vector``: ``g_norm @ R``):
  ``g_camera = Rᵀ g_norm``. The scaling of the normalised camera does not touch directions.

The face centre (ETH-XGaze ``normalizeData_face``) is the mean of the eye centre (four eye corners)
and the nose centre (two nose wings), a few centimetres below the eyes; it is the ray's origin here
(that offset is under 2° to a target 1 m away). Our rays are in our camera frame
(``R_OURS_FROM_OPENCV``), or a world with ``camera=`` (:func:`~jaxgaze.io.tools.common.rays_from_camera`).

The networks return arrays, not files, so the file is a CSV dump (:data:`XGAZE_COLUMNS`) named after
ptgaze's attributes: ``frame, person, pitch, yaw`` (``face.normalized_gaze_angles``), ``center_x,
center_y, center_z`` (``face.center``: OpenCV camera frame, **metres**, as ptgaze), and the
normalising rotation either as nine columns ``normalizing_rot_00 … normalizing_rot_22`` (row-major,
``face.normalizing_rot.as_matrix()``; ETH-XGaze's ``face_mat_norm``) or as the head rotation vector
``head_pose_rot_x, head_pose_rot_y, head_pose_rot_z`` (``face.head_pose_rot.as_rotvec()``, the
``solvePnP`` ``rvec``), from which ``R`` is computed as the tool does. With both, the matrix is used.
"""

from __future__ import annotations

import math
import os
from typing import Optional

import cv2
import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.common import (
    bandwidth_from_mean_angular_error,
    eye_axes_problem,
    rays_from_camera,
    tool_bandwidth,
    world_rays_to_camera,
)
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import first_few, format_float, read_csv_table, write_csv_rows
from jaxgaze.poses import CameraPoses

__all__ = [
    "XGAZE_MEAN_GAZE_ERROR",
    "DEFAULT_BANDWIDTH_XGAZE",
    "XGAZE_COLUMNS",
    "NORMALIZING_ROT_COLUMNS",
    "HEAD_POSE_ROT_COLUMNS",
    "ETH_XGAZE_FACE_MODEL",
    "ETH_XGAZE_DLIB_INDICES",
    "xgaze_pitchyaw_to_vector",
    "normalizing_rotation",
    "denormalize_gaze",
    "xgaze_head_pose",
    "xgaze_to_rays",
    "read_xgaze",
    "write_xgaze",
]

#: Mean angular error of the ETH-XGaze ResNet-50 baseline on its within-dataset test set, 4.49°
#: (ETH-XGaze repository, ``evaluation_test_set_within_dataset_setting/output/scores.txt``; the
#: paper's 4.5°). A lower bound off the dataset: cross-dataset errors are larger.
XGAZE_MEAN_GAZE_ERROR = math.radians(4.4929)
#: Bandwidth ``h`` (radians, 0.063) of an ETH-XGaze/ptgaze ray: the tools report no uncertainty, so
#: ``h = XGAZE_MEAN_GAZE_ERROR / √(π/2)`` (:func:`~jaxgaze.io.tools.common.bandwidth_from_mean_angular_error`).
DEFAULT_BANDWIDTH_XGAZE = bandwidth_from_mean_angular_error(XGAZE_MEAN_GAZE_ERROR)

NORMALIZING_ROT_COLUMNS = tuple(f"normalizing_rot_{i}{j}" for i in range(3) for j in range(3))
HEAD_POSE_ROT_COLUMNS = ("head_pose_rot_x", "head_pose_rot_y", "head_pose_rot_z")
#: Required columns of the dump; add :data:`NORMALIZING_ROT_COLUMNS` or :data:`HEAD_POSE_ROT_COLUMNS`.
XGAZE_COLUMNS = ("frame", "person", "pitch", "yaw", "center_x", "center_y", "center_z")

#: The six points of ETH-XGaze's ``face_model.txt`` its demo fits (rows 20, 23, 26, 29, 15, 19: the
#: corners of the eye on the image's left, then of the other eye, then the two nose wings), in metres.
#: Axes as OpenCV for an upright frontal face: x right in the image, y down, z away from the camera.
ETH_XGAZE_FACE_MODEL = np.array([
    [-46.50949859619140625, -38.32709503173828125, 36.41600418090820312],
    [-17.76072120666503906, -32.58519744873046875, 29.07615661621093750],
    [18.04391098022460938, -30.95682334899902344, 29.06296730041503906],
    [44.73758697509765625, -34.10787200927734375, 36.73243713378906250],
    [-10.61166477203369141, 12.95834922790527344, 21.62276458740234375],
    [11.28962993621826172, 13.86424446105957031, 21.83790016174316406],
]) / 1000.0
ETH_XGAZE_FACE_MODEL.setflags(write=False)
#: The dlib 68-point landmarks matching :data:`ETH_XGAZE_FACE_MODEL` (ETH-XGaze ``demo.py``).
ETH_XGAZE_DLIB_INDICES = (36, 39, 42, 45, 31, 35)

#: A normalising rotation further than this from orthonormal (max |RRᵀ − I|) is no rotation.
_ROTATION_TOLERANCE = 1e-3
#: A face centre further than this from the camera (metres) is in millimetres (ETH-XGaze's own unit).
_MAX_FACE_DISTANCE = 20.0


def xgaze_pitchyaw_to_vector(pitch, yaw) -> np.ndarray:
    """Normalised ``(pitch, yaw)`` → unit gaze vectors ``(..., 3)`` in the normalised camera frame, OpenCV
    axes (ptgaze ``FaceParts.angle_to_vector``): ``−(cos p sin y, sin p, cos p cos y)``."""
    pitch, yaw = np.broadcast_arrays(np.asarray(pitch, dtype=np.float64), np.asarray(yaw, dtype=np.float64))
    return -np.stack([np.cos(pitch) * np.sin(yaw), np.sin(pitch), np.cos(pitch) * np.cos(yaw)], axis=-1)


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    if not (norm > 1e-12).all():
        raise ValueError(f"normalizing_rotation: {what}")
    return v / norm


def normalizing_rotation(face_center_camera, R_head_camera) -> np.ndarray:
    """The normalising rotation ``R (..., 3, 3)`` (Zhang et al. 2018, Sec. 4.2; ETH-XGaze
    ``normalizeData_face``): rows ``x, y, z`` with ``z = unit(c)``, ``y = unit(z × h_x)``,
    ``x = unit(y × z)``, where ``c (..., 3)`` is the face centre and ``h_x`` the first column of the
    head rotation ``R_head_camera (..., 3, 3)``, both in the OpenCV camera frame."""
    c = np.asarray(face_center_camera, dtype=np.float64)
    h_x = np.asarray(R_head_camera, dtype=np.float64)[..., :, 0]
    z = _unit(c, "the face centre is at the camera")
    y = _unit(np.cross(z, h_x), "the head's x axis points at the camera")
    x = _unit(np.cross(y, z), "degenerate rotation")
    return np.stack([x, y, z], axis=-2)


def denormalize_gaze(pitch, yaw, R_normalizing) -> np.ndarray:
    """Unit gaze ``(..., 3)`` in the OpenCV camera frame: ``Rᵀ g_norm`` (ptgaze
    ``FaceParts.denormalize_gaze_vector``), ``g_norm`` by :func:`xgaze_pitchyaw_to_vector`."""
    g_norm = xgaze_pitchyaw_to_vector(pitch, yaw)
    return np.einsum("...ji,...j->...i", np.asarray(R_normalizing, dtype=np.float64), g_norm)


def xgaze_head_pose(landmarks_image, camera_matrix, distortion=None) -> tuple[np.ndarray, np.ndarray]:
    """Face centre ``(3,)`` (metres) and head rotation ``(3, 3)``, OpenCV camera frame, from image landmarks
    as ETH-XGaze's demo does (``estimateHeadPose``: ``cv2.solvePnP`` EPnP, then refined iteratively, on
    :data:`ETH_XGAZE_FACE_MODEL`; the face centre as in ``normalizeData_face``).

    ``landmarks_image`` is ``(6, 2)`` pixels in the order of :data:`ETH_XGAZE_FACE_MODEL`, or all 68
    dlib landmarks (those of :data:`ETH_XGAZE_DLIB_INDICES` are used); ``camera_matrix`` the 3 × 3
    intrinsics, ``distortion`` OpenCV's coefficients (default none).
    """
    points = np.asarray(landmarks_image, dtype=np.float64)
    if points.shape == (68, 2):
        points = points[list(ETH_XGAZE_DLIB_INDICES)]
    if points.shape != (6, 2) or not np.isfinite(points).all():
        raise ValueError(f"xgaze_head_pose: need (6, 2) or (68, 2) finite landmarks, got shape {points.shape}")
    K = np.asarray(camera_matrix, dtype=np.float64)
    dist = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=np.float64)
    model = np.ascontiguousarray(ETH_XGAZE_FACE_MODEL).reshape(6, 1, 3)
    image = np.ascontiguousarray(points).reshape(6, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(model, image, K, dist, flags=cv2.SOLVEPNP_EPNP)
    if ok:
        ok, rvec, tvec = cv2.solvePnP(model, image, K, dist, rvec, tvec, True)
    if not ok:
        raise ValueError("xgaze_head_pose: cv2.solvePnP failed")
    R_head = cv2.Rodrigues(rvec)[0]
    face = ETH_XGAZE_FACE_MODEL @ R_head.T + tvec.reshape(3)
    center = 0.5 * (face[:4].mean(axis=0) + face[4:].mean(axis=0))
    return center, R_head


def _rows(values, count: int, shape: tuple, what: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    try:
        return np.broadcast_to(array, (count, *shape))
    except ValueError:
        raise ValueError(f"xgaze_to_rays: {what} must have shape {(count, *shape)}, got {array.shape}") from None


def xgaze_to_rays(pitch, yaw, face_centers_opencv, *, R_normalizing=None, R_head=None, frames=None, persons=None,
                  bandwidth: float = DEFAULT_BANDWIDTH_XGAZE, camera: Optional[CameraPoses] = None,
                  path=None) -> RayRecording:
    """Rays from ``M`` network outputs ``pitch, yaw (M,)`` (radians, normalised frame) and face centres
    ``face_centers_opencv (M, 3)`` in the **OpenCV** camera axes (origin the camera centre, x right,
    y down, z forward; ptgaze's ``face.center``), metres (unlike :func:`~jaxgaze.io.tools.gaze360.gaze360_to_rays`
    and :func:`~jaxgaze.io.tools.l2cs.l2cs_to_rays`, which take our axes), with either the normalising rotations ``R_normalizing
    (M, 3, 3)`` or the head rotations ``R_head (M, 3, 3)`` (camera from head model, OpenCV) from which
    :func:`normalizing_rotation` computes them. Direction ``Rᵀ g_norm`` (:func:`denormalize_gaze`),
    origin the face centre, both turned into our axes (``R_OURS_FROM_OPENCV``) and placed by ``camera``.
    ``frames`` default ``0 … M−1``, ``persons`` default ``"0"``; ``bandwidth`` is ``h`` for every ray.
    """
    pitch = np.asarray(pitch, dtype=np.float64).reshape(-1)
    count = len(pitch)
    yaw = _rows(yaw, count, (), "yaw").reshape(-1)
    centers = _rows(face_centers_opencv, count, (3,), "face_centers_opencv")
    problem = eye_axes_problem(centers @ R_OURS_FROM_OPENCV.T, "opencv")
    if problem is not None:
        raise ValueError(f"xgaze_to_rays: face_centers_opencv row {problem[0]}: {problem[1]}")
    if (R_normalizing is None) == (R_head is None):
        raise ValueError("xgaze_to_rays: pass exactly one of R_normalizing and R_head")
    if R_normalizing is None:
        R_normalizing = normalizing_rotation(centers, _rows(R_head, count, (3, 3), "R_head"))
    R_normalizing = _rows(R_normalizing, count, (3, 3), "R_normalizing")
    frames = np.arange(count) if frames is None else np.asarray(frames, dtype=np.int64).reshape(-1)
    persons = ["0"] * count if persons is None else [str(p) for p in persons]
    if not (len(frames) == len(persons) == count):
        raise ValueError(f"xgaze_to_rays: frames and persons need {count} entries")
    gaze = denormalize_gaze(pitch, yaw, R_normalizing)
    return rays_from_camera(frames, persons, centers @ R_OURS_FROM_OPENCV.T, gaze @ R_OURS_FROM_OPENCV.T,
                            np.full(count, tool_bandwidth(bandwidth, "xgaze_to_rays")), camera=camera, path=path)


def _read_dump(path, seen: dict) -> tuple[list, list, list, list]:
    """One dump → (frames, persons, centres, de-normalised gaze, both OpenCV, metres)."""
    table = read_csv_table(path, XGAZE_COLUMNS, NORMALIZING_ROT_COLUMNS + HEAD_POSE_ROT_COLUMNS,
                           hint="need " + ", ".join(XGAZE_COLUMNS) + " and normalizing_rot_00 … normalizing_rot_22 "
                                "or head_pose_rot_x, head_pose_rot_y, head_pose_rot_z")
    use_matrix = all(table.has(c) for c in NORMALIZING_ROT_COLUMNS)
    if not use_matrix and not all(table.has(c) for c in HEAD_POSE_ROT_COLUMNS):
        partial = [c for c in NORMALIZING_ROT_COLUMNS + HEAD_POSE_ROT_COLUMNS if table.has(c)]
        raise table.fail("the normalising rotation is missing: need the nine columns normalizing_rot_00 … "
                         "normalizing_rot_22 or the three head_pose_rot_x, _y, _z"
                         + (f" (found only {first_few(partial)})" if partial else ""))
    frames, persons, centers, gaze = [], [], [], []
    for row in table.rows:
        frame, person = row.integer("frame"), row.text("person")
        pitch, yaw = row.number("pitch"), row.number("yaw")
        if abs(pitch) > math.pi / 2 or abs(yaw) > math.pi:
            raise row.error(f"pitch {pitch:g}, yaw {yaw:g} outside |pitch| ≤ π/2, |yaw| ≤ π: they are radians "
                            "(degrees?)")
        center = np.array([row.number(c) for c in XGAZE_COLUMNS[4:]])
        distance = float(np.linalg.norm(center))
        if center[2] <= 0:  # behind the camera: the frame check's message (eye_axes_problem)
            raise row.error(eye_axes_problem([center @ R_OURS_FROM_OPENCV.T], "opencv")[1])
        if distance > _MAX_FACE_DISTANCE:
            raise row.error(f"face centre {first_few(center.tolist())} is not a face in front of the camera within "
                            f"{_MAX_FACE_DISTANCE:g} m: center_z must be positive, in metres (millimetres?)")
        if use_matrix:
            R = np.array([row.number(c) for c in NORMALIZING_ROT_COLUMNS]).reshape(3, 3)
            if np.abs(R @ R.T - np.eye(3)).max() > _ROTATION_TOLERANCE or np.linalg.det(R) < 0:
                raise row.error("normalizing_rot_00 … normalizing_rot_22 is not a rotation matrix (row-major)")
        else:
            rvec = np.array([row.number(c) for c in HEAD_POSE_ROT_COLUMNS])
            try:
                R = normalizing_rotation(center, cv2.Rodrigues(rvec)[0])
            except ValueError as error:
                raise row.error(str(error)) from None
        first = seen.setdefault((frame, person), (table.path, row.line))
        if first != (table.path, row.line):
            raise row.error(f"duplicate face for frame {frame}, person '{person}' (first at {first[0]}, "
                            f"line {first[1]})")
        frames.append(frame)
        persons.append(person)
        centers.append(center)
        gaze.append(denormalize_gaze(pitch, yaw, R))
    problem = eye_axes_problem(np.asarray(centers).reshape(-1, 3) @ R_OURS_FROM_OPENCV.T, "opencv")
    if problem is not None:
        raise table.rows[problem[0]].error(problem[1])
    return frames, persons, centers, gaze


def read_xgaze(paths, *, camera: Optional[CameraPoses] = None,
               bandwidth: float = DEFAULT_BANDWIDTH_XGAZE) -> RayRecording:
    """Rays from ETH-XGaze / MPIIFaceGaze / ptgaze CSV dumps (module docstring: columns, frames, units).

    ``paths`` is one dump or several (their rows are pooled; a (frame, person) twice is an error).
    Each row's gaze is de-normalised (:func:`denormalize_gaze`) with its normalising rotation (or the
    one :func:`normalizing_rotation` makes from ``head_pose_rot``), starts at the face centre, turns into
    our axes and, with ``camera``, into the world. Every ray gets ``bandwidth`` (default
    :data:`DEFAULT_BANDWIDTH_XGAZE`). Raises :class:`~jaxgaze.io.text.InputFileError` (``path, line N:``)
    for a malformed file, a header without the rotation columns, a bad cell, angles beyond
    ``|pitch| ≤ π/2, |yaw| ≤ π`` (degrees?), a face centre behind the camera or over 20 m away
    (millimetres?), a normalising matrix that is no rotation, or a duplicate (frame, person).
    """
    h = tool_bandwidth(bandwidth, "read_xgaze")
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise ValueError("read_xgaze: no files given")
    frames, persons, centers, gaze, seen = [], [], [], [], {}
    for path in paths:
        f, p, c, g = _read_dump(path, seen)
        frames += f
        persons += p
        centers += c
        gaze += g
    where = os.fspath(paths[0]) if len(paths) == 1 else first_few([os.fspath(p) for p in paths])
    return rays_from_camera(frames, persons, np.asarray(centers) @ R_OURS_FROM_OPENCV.T,
                            np.asarray(gaze) @ R_OURS_FROM_OPENCV.T, np.full(len(frames), h),
                            camera=camera, path=where)


def write_xgaze(path, recording: RayRecording, *, camera: Optional[CameraPoses] = None) -> int:
    """Write a :class:`~jaxgaze.io.rays.RayRecording` as a dump with the nine ``normalizing_rot`` columns
    (the inverse of :func:`read_xgaze`), atomically; returns the number of rows.

    World → camera frame (``camera``, as read) → OpenCV axes; the face centre is the ray's origin and
    ``R`` the normalising rotation of an upright head (head x axis = camera x axis), so
    ``g_norm = R g`` gives ``pitch = arcsin(−g_y)``, ``yaw = arctan2(−g_x, −g_z)`` (ETH-XGaze's labels).
    The bandwidth is not written: rays read back with :data:`DEFAULT_BANDWIDTH_XGAZE`.
    """
    mask = np.asarray(recording.rays.mask)
    t, n = np.nonzero(mask)
    frames = np.asarray(recording.frame_ids, dtype=np.int64)[t]
    eyes, gaze = world_rays_to_camera(frames, recording.world_origins()[t, n],
                                      np.asarray(recording.rays.directions, float)[t, n], camera)
    centers, gaze = eyes @ R_OURS_FROM_OPENCV, gaze @ R_OURS_FROM_OPENCV
    if not (centers[:, 2] > 0).all():
        raise ValueError("write_xgaze: a ray starts behind the camera (the dump needs center_z > 0)")
    R = normalizing_rotation(centers, np.broadcast_to(np.eye(3), (len(frames), 3, 3)))
    g = np.einsum("mij,mj->mi", R, gaze / np.linalg.norm(gaze, axis=-1, keepdims=True))
    pitch, yaw = np.arcsin(np.clip(-g[:, 1], -1.0, 1.0)), np.arctan2(-g[:, 0], -g[:, 2])
    rows = ([int(frames[i]), recording.persons[t[i]][n[i]], format_float(pitch[i]), format_float(yaw[i]),
             *map(format_float, centers[i]), *map(format_float, R[i].reshape(-1))] for i in range(len(frames)))
    return write_csv_rows(path, XGAZE_COLUMNS + NORMALIZING_ROT_COLUMNS, rows)
