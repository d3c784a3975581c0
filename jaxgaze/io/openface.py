"""Head pose and gaze from OpenFace 2, an input of the speaker-prior gaze bias (Siegfried, Yu &
Odobez, ICMI 2017, "Towards the use of social interaction conventions as prior for gaze model
adaptation", Sec. 3; who speaks when is :mod:`jaxgaze.io.speech`).

Conventions (see ``docs/conventions.md``, "OpenFace and speaking status"):

* Our camera and head frames are +x forward, +y left, +z up, metres, radians.
  OpenFace works in OpenCV camera coordinates (x right, y down, z forward) and
  millimetres; :func:`read_openface` converts everything.
* OpenFace's ``pose_R*`` is ``R = Rx(pose_Rx) · Ry(pose_Ry) · Rz(pose_Rz)``, the
  rotation from OpenFace's head model to the OpenCV camera
  (``RotationHelpers.h: Euler2RotationMatrix``; ``GetPose`` runs ``solvePnP`` on
  the model's 3D landmarks). The model's axes are those of the camera when the
  face is upright and frontal: x = the person's left, y = down, z = backwards
  into the head. Hence, in the method's head frame, forward = −z_model,
  left = +x_model, up = −y_model (:data:`R_OPENFACE_MODEL_FROM_HEAD`).
* ``gaze_angle_x = atan2(g_x, −g_z)`` and ``gaze_angle_y = atan2(g_y, −g_z)``,
  where ``g`` is the mean of the two eyes' gaze vectors in OpenCV camera
  coordinates (``GazeEstimation.cpp: GetGazeAngle``). So ``g ∝ (tan x, tan y, −1)``.

Everything here is host-side NumPy in float64 (file reading, not jitted). The CSV is read
by :func:`~jaxgaze.io.text.read_csv_table`; file errors raise :class:`OpenFaceFileError`
(an :class:`~jaxgaze.io.text.InputFileError`) whose message starts with ``path, line N:``.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.geometry import direction_to_yaw_pitch, unit
from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.text import InputFileError, first_few, parse_number, read_csv_table

__all__ = [
    "OPENFACE_COLUMNS",
    "OPENFACE_OUTPUT_FLAGS",
    "looks_like_openface",
    "R_OPENFACE_MODEL_FROM_HEAD",
    "OpenFaceFileError",
    "OpenFaceTrack",
    "read_openface",
    "openface_pose_and_gaze",
]

#: Columns :func:`read_openface` needs (``face_id`` is used when present).
OPENFACE_COLUMNS = (
    "frame",
    "timestamp",
    "confidence",
    "success",
    "gaze_angle_x",
    "gaze_angle_y",
    "pose_Tx",
    "pose_Ty",
    "pose_Tz",
    "pose_Rx",
    "pose_Ry",
    "pose_Rz",
)
_BOOKKEEPING = ("frame", "face_id", "timestamp", "confidence", "success")
_GAZE_POSE = OPENFACE_COLUMNS[4:]

#: OpenFace 2 ``FeatureExtraction``'s output flags and the columns each writes (a run without any of
#: them writes every column; ``frame, face_id, timestamp, confidence, success`` are always written).
OPENFACE_OUTPUT_FLAGS = {
    "-gaze": ("gaze_0_x … gaze_angle_y", r"gaze_(\d_[xyz]|angle_[xy])$|eye_lmk_"),
    "-pose": ("pose_Tx … pose_Rz", r"pose_[TR][xyz]$"),
    "-2Dfp": ("x_0 … y_67", r"[xy]_\d+$"),
    "-3Dfp": ("X_0 … Z_67", r"[XYZ]_\d+$"),
    "-pdmparams": ("p_scale … p_33", r"p_(scale|r[xyz]|t[xy]|\d+)$"),
    "-aus": ("AU01_r … AU45_c", r"AU\d+_[rc]$"),
}


def looks_like_openface(names) -> bool:
    """Whether the column ``names`` of a header are OpenFace's: its bookkeeping columns, or a column
    one of its output flags writes."""
    if {"frame", "timestamp", "confidence", "success"} <= set(names):
        return True
    return any(re.match(pattern, name) for _, pattern in OPENFACE_OUTPUT_FLAGS.values() for name in names)


def _missing_columns_hint(names) -> str:
    """What to do about missing columns: the FeatureExtraction flag that writes them, for a header that is
    OpenFace's; else ask whether the file is OpenFace's at all."""
    flags = [flag for flag in ("-gaze", "-pose")
             if any(c not in names and re.match(OPENFACE_OUTPUT_FLAGS[flag][1], c) for c in OPENFACE_COLUMNS)]
    if not (flags and looks_like_openface(names)):
        return "is this an OpenFace 2 FeatureExtraction CSV?"
    return ("this OpenFace output was written without them: run FeatureExtraction with "
            + " and ".join(f"{flag} (it writes {OPENFACE_OUTPUT_FLAGS[flag][0]})" for flag in flags)
            + ", or with no output flag at all for every column")


#: ``v_model = R_OPENFACE_MODEL_FROM_HEAD @ v_head``: our head axes (forward,
#: left, up) written in OpenFace's head-model axes (x = the person's left,
#: y = down, z = into the head): forward = −z, left = +x, up = −y. det = +1.
R_OPENFACE_MODEL_FROM_HEAD = np.array(
    [
        [0.0, 1.0, 0.0],
        [0.0, 0.0, -1.0],
        [-1.0, 0.0, 0.0],
    ]
)
R_OPENFACE_MODEL_FROM_HEAD.setflags(write=False)

class OpenFaceFileError(InputFileError):
    """An OpenFace CSV is malformed. The message starts with ``path, line N:``."""


# ---------------------------------------------------------------------------
# OpenFace


class OpenFaceTrack(NamedTuple):
    """One face tracked by OpenFace over ``T`` kept frames, in **our** frames.

    * ``frame`` ``(T,)`` int64 and ``timestamp`` ``(T,)`` float64 seconds, sorted by frame.
    * ``confidence`` ``(T,)``: OpenFace's landmark-detection confidence.
    * ``gaze_direction_camera`` ``(T, 3)``: unit gaze (mean of both eyes), our camera frame.
    * ``R_camera_from_head`` ``(T, 3, 3)``: ``v_camera = R_camera_from_head @ v_head``.
    * ``head_position_camera`` ``(T, 3)``: origin of OpenFace's head model (``pose_T``,
      near the middle of the face, not exactly the eye centre), metres, our camera frame.
    * ``dropped``: frames removed, per reason, e.g. ``{"success == 0": 3, "confidence < 0.75": 2}``.
    """

    frame: np.ndarray
    timestamp: np.ndarray
    confidence: np.ndarray
    gaze_direction_camera: np.ndarray
    R_camera_from_head: np.ndarray
    head_position_camera: np.ndarray
    dropped: dict

    @property
    def head_direction_camera(self) -> np.ndarray:
        """``(T, 3)``: the head's forward axis (+x_head) in our camera frame."""
        return np.asarray(self.R_camera_from_head)[:, :, 0]

    @property
    def gaze_angles_head(self) -> np.ndarray:
        """``(T, 2)`` (yaw, tilt) in radians of the gaze in the head frame (the
        paper's ``g = (φ, θ)``): ``direction_to_yaw_pitch(R_camera_from_headᵀ @ gaze)``.
        Yaw is positive to the person's left, tilt positive up."""
        d = np.einsum("tji,tj->ti", self.R_camera_from_head, self.gaze_direction_camera)
        with jax.enable_x64(True):
            yaw, tilt = direction_to_yaw_pitch(jnp.asarray(d))
            return np.stack([np.asarray(yaw), np.asarray(tilt)], axis=-1)


def _openface_euler_to_matrix(rx: np.ndarray, ry: np.ndarray, rz: np.ndarray) -> np.ndarray:
    """OpenFace's ``Euler2RotationMatrix``: ``Rx(rx) · Ry(ry) · Rz(rz)`` (right-handed,
    active), ``(T,) → (T, 3, 3)``: head model → OpenCV camera."""
    c1, s1, c2, s2, c3, s3 = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    return np.stack(
        [
            np.stack([c2 * c3, -c2 * s3, s2], axis=-1),
            np.stack([c1 * s3 + c3 * s1 * s2, c1 * c3 - s1 * s2 * s3, -c2 * s1], axis=-1),
            np.stack([s1 * s3 - c1 * c3 * s2, c3 * s1 + c1 * s2 * s3, c1 * c2], axis=-1),
        ],
        axis=-2,
    )


def read_openface(path, *, min_confidence: float = 0.75, face_id: Optional[int] = None) -> OpenFaceTrack:
    """Read an OpenFace 2 ``FeatureExtraction`` (or ``FaceLandmarkVidMulti``) CSV.

    Uses the columns :data:`OPENFACE_COLUMNS` and ``face_id`` if present (names are
    stripped: older files write ``" confidence"``); others are ignored. Frames with
    ``success == 0``, else with ``confidence < min_confidence``, are dropped; the
    counts go to ``OpenFaceTrack.dropped`` and one warning states them. If the file
    has several faces, pass ``face_id`` (an error lists the ids present).

    Conversions (OpenFace: OpenCV camera axes, millimetres; see the module notes):

    * gaze: ``g_cv = unit(tan gaze_angle_x, tan gaze_angle_y, −1)`` (inverse of
      ``GetGazeAngle``; both angles must lie in (−π/2, π/2), i.e. the gaze points
      toward the camera's side, as it does for any eye the camera sees), then
      ``gaze_direction_camera = R_OURS_FROM_OPENCV @ g_cv``;
    * pose: ``R_camera_from_head = R_OURS_FROM_OPENCV @ Rx·Ry·Rz @ R_OPENFACE_MODEL_FROM_HEAD``,
      so pose_R = 0 faces the camera (forward = −x_camera); ``pose_Rx > 0`` pitches
      the head down, ``pose_Ry > 0`` turns it to the person's right, ``pose_Rz > 0``
      rolls its top toward the person's left;
    * position: ``head_position_camera = R_OURS_FROM_OPENCV @ pose_T / 1000``.

    Raises :class:`OpenFaceFileError` (a ``ValueError``, ``path, line N:``) for an
    empty file, a missing column, no data rows, a row with the wrong number of
    fields, a non-numeric cell in a used column, NaN/inf in frame, face_id,
    timestamp, confidence or success (any row) or in a gaze/pose column of a kept
    frame, a non-integer frame or face_id, success not 0/1, a gaze angle outside
    (−π/2, π/2), a duplicate frame of the chosen face, several faces without
    ``face_id``, an absent ``face_id``, or every frame dropped.
    """
    min_confidence = float(min_confidence)
    if not math.isfinite(min_confidence):
        raise ValueError(f"read_openface: min_confidence must be finite, got {min_confidence}")
    table = read_csv_table(
        path, OPENFACE_COLUMNS, ("face_id",), error=OpenFaceFileError, what="OpenFace", lower=False,
        hint=_missing_columns_hint,
        empty="empty file: expected an OpenFace CSV header (frame, face_id, timestamp, ...)",
    )
    columns = [c for c in _BOOKKEEPING if table.has(c)] + list(_GAZE_POSE)
    where = np.array([row.line for row in table.rows], dtype=np.int64)
    values = np.array(
        [[parse_number(row.cell(c), f"column '{c}'", table.path, row.line, OpenFaceFileError, finite=False)
          for c in columns] for row in table.rows],
        dtype=np.float64,
    ).reshape(len(where), len(columns))
    col = {c: values[:, j] for j, c in enumerate(columns)}

    def fail_at(mask, message):
        bad = np.nonzero(mask)[0]
        if bad.size:
            raise OpenFaceFileError(message(bad[0]), path, int(where[bad[0]]))

    for c in _BOOKKEEPING:
        if c in col:
            fail_at(~np.isfinite(col[c]), lambda i, c=c: f"column '{c}' is not finite: {float(col[c][i])!r}")
    for c in ("frame", "face_id"):
        if c in col:
            fail_at(
                (col[c] != np.round(col[c])) | (np.abs(col[c]) >= 2.0 ** 63),
                lambda i, c=c: f"column '{c}' must be a 64-bit integer, got {float(col[c][i])!r}",
            )
    fail_at(
        (col["success"] != 0) & (col["success"] != 1),
        lambda i: f"success must be 0 or 1, got {float(col['success'][i])!r}",
    )

    faces = col["face_id"].astype(np.int64) if "face_id" in col else np.zeros(len(where), dtype=np.int64)
    present = sorted(set(faces.tolist()))
    if face_id is None:
        if len(present) > 1:
            raise OpenFaceFileError(
                f"several faces (face_id {first_few(present, 5)}); pass face_id= to choose one", path
            )
        face_id = present[0]
    elif int(face_id) not in present:
        raise OpenFaceFileError(
            f"no rows with face_id {face_id} (face_id present: {first_few(present, 5)})", path
        )
    mine = faces == int(face_id)
    where, values = where[mine], values[mine]
    col = {c: values[:, j] for j, c in enumerate(columns)}
    frames = col["frame"].astype(np.int64)

    first: dict[int, int] = {}
    for frame, line in zip(frames.tolist(), where.tolist()):
        seen = first.setdefault(frame, line)
        if seen != line:
            raise OpenFaceFileError(f"duplicate frame {frame} of face_id {face_id} (first on line {seen})", path, line)

    failed = col["success"] == 0
    unsure = ~failed & (col["confidence"] < min_confidence)
    dropped = {"success == 0": int(failed.sum()), f"confidence < {min_confidence:g}": int(unsure.sum())}
    keep = ~(failed | unsure)
    total = int(mine.sum())
    summary = ", ".join(f"{reason}: {count}" for reason, count in dropped.items())
    if not keep.any():
        raise OpenFaceFileError(f"no frames left: all {total} frames of face_id {face_id} dropped ({summary})", path)
    if not keep.all():
        warnings.warn(
            f"{os.fspath(path)}: dropped {total - int(keep.sum())} of {total} frames of face_id {face_id} ({summary})",
            stacklevel=2,
        )
    where, values, frames = where[keep], values[keep], frames[keep]
    col = {c: values[:, j] for j, c in enumerate(columns)}
    for c in _GAZE_POSE:
        fail_at(
            ~np.isfinite(col[c]), lambda i, c=c: f"column '{c}' is not finite in a kept frame: {float(col[c][i])!r}"
        )
    for c in ("gaze_angle_x", "gaze_angle_y"):
        fail_at(
            np.abs(col[c]) >= np.pi / 2,
            lambda i, c=c: f"column '{c}' = {float(col[c][i])!r} is outside (−π/2, π/2): "
            "not atan2(g, −g_z) of a gaze toward the camera",
        )

    order = np.argsort(frames, kind="stable")
    ax, ay = col["gaze_angle_x"][order], col["gaze_angle_y"][order]
    # (tan x, tan y, −1) scaled by cos x cos y > 0: no division, same direction.
    g_cv = np.stack([np.sin(ax) * np.cos(ay), np.cos(ax) * np.sin(ay), -np.cos(ax) * np.cos(ay)], axis=-1)
    with jax.enable_x64(True):
        g_cv = np.asarray(unit(jnp.asarray(g_cv)), dtype=np.float64)
    R_cv = _openface_euler_to_matrix(col["pose_Rx"][order], col["pose_Ry"][order], col["pose_Rz"][order])
    T_cv = np.stack([col["pose_Tx"], col["pose_Ty"], col["pose_Tz"]], axis=-1)[order] / 1000.0
    return OpenFaceTrack(
        frame=frames[order],
        timestamp=col["timestamp"][order],
        confidence=col["confidence"][order],
        gaze_direction_camera=g_cv @ R_OURS_FROM_OPENCV.T,
        R_camera_from_head=R_OURS_FROM_OPENCV @ R_cv @ R_OPENFACE_MODEL_FROM_HEAD,
        head_position_camera=T_cv @ R_OURS_FROM_OPENCV.T,
        dropped=dropped,
    )


def openface_pose_and_gaze(R_camera_from_head, head_position_camera, gaze_direction_camera) -> dict:
    """The columns OpenFace 2 writes for a head pose and a gaze given in our camera frame: the
    inverse of :func:`read_openface`'s conversions, ``{column: (T,) array}`` for
    ``gaze_angle_x, gaze_angle_y`` (radians), ``pose_Tx, pose_Ty, pose_Tz`` (millimetres) and
    ``pose_Rx, pose_Ry, pose_Rz`` (radians).

    With ``R = R_OURS_FROM_OPENCVᵀ R_camera_from_head R_OPENFACE_MODEL_FROM_HEADᵀ = Rx Ry Rz``:
    ``pose_Rx = atan2(−R₁₂, R₂₂)``, ``pose_Ry = asin R₀₂``, ``pose_Rz = atan2(−R₀₁, R₀₀)``;
    ``g_cv = R_OURS_FROM_OPENCVᵀ g``, ``gaze_angle_x = atan2(g_x, −g_z)``, ``gaze_angle_y = atan2(g_y, −g_z)``
    (OpenFace's ``GetGazeAngle``); ``pose_T = 1000 R_OURS_FROM_OPENCVᵀ p``.
    """
    R_cv = R_OURS_FROM_OPENCV.T @ np.asarray(R_camera_from_head, float) @ R_OPENFACE_MODEL_FROM_HEAD.T
    g_cv = np.asarray(gaze_direction_camera, float) @ R_OURS_FROM_OPENCV
    t_cv = np.asarray(head_position_camera, float) @ R_OURS_FROM_OPENCV * 1000.0
    return {
        "gaze_angle_x": np.arctan2(g_cv[..., 0], -g_cv[..., 2]),
        "gaze_angle_y": np.arctan2(g_cv[..., 1], -g_cv[..., 2]),
        "pose_Tx": t_cv[..., 0], "pose_Ty": t_cv[..., 1], "pose_Tz": t_cv[..., 2],
        "pose_Rx": np.arctan2(-R_cv[..., 1, 2], R_cv[..., 2, 2]),
        "pose_Ry": np.arcsin(np.clip(R_cv[..., 0, 2], -1.0, 1.0)),
        "pose_Rz": np.arctan2(-R_cv[..., 0, 1], R_cv[..., 0, 0]),
    }
