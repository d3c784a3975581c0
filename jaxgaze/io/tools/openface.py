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

Several faces (``FaceLandmarkVidMulti``): :func:`read_openface_rays` gives every face's gaze ray (eye
centre, mean eye vector, :data:`DEFAULT_BANDWIDTH_OPENFACE`) and re-links the faces into people by
position, since ``face_id`` is a tracker slot, not a person (:func:`link_openface_faces`);
:func:`write_openface_rays` / :func:`write_openface_faces` write the format back.

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

import numpy as np
from scipy.optimize import linear_sum_assignment

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.common import bandwidth_from_mean_angular_error, rays_from_camera, world_rays_to_camera
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import (InputFileError, first_few, format_float, parse_integer, parse_number, read_csv_table,
                             write_csv_rows)
from jaxgaze.poses import CameraPoses

__all__ = [
    "OPENFACE_COLUMNS",
    "OPENFACE_OUTPUT_FLAGS",
    "looks_like_openface",
    "R_OPENFACE_MODEL_FROM_HEAD",
    "OpenFaceFileError",
    "OpenFaceTrack",
    "read_openface",
    "OpenFacePeople",
    "read_openface_people",
    "openface_pose_and_gaze",
    "OPENFACE_MEAN_GAZE_ERROR",
    "DEFAULT_BANDWIDTH_OPENFACE",
    "OPENFACE_LINK_GATE_M",
    "OPENFACE_RAYS_COLUMNS",
    "link_openface_faces",
    "read_openface_rays",
    "write_openface_faces",
    "write_openface_rays",
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
        # direction_to_yaw_pitch on the host in float64 (yaw 0 at a pole)
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        r2 = x * x + y * y
        off_pole = r2 > 0
        yaw = np.arctan2(np.where(off_pole, y, 0.0), np.where(off_pole, x, 1.0))
        angles = np.stack([yaw, np.arctan2(z, np.sqrt(r2))], axis=-1)
        return np.where(np.isfinite(d).all(axis=-1, keepdims=True), angles, np.nan)  # NaN: head pose only


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


def _parse_columns(table, columns) -> tuple[np.ndarray, np.ndarray]:
    """The source lines ``(M,)`` and the numbers ``(M, len(columns))`` of a table's rows (NaN/inf
    allowed here), after checking the bookkeeping columns: finite, ``frame``/``face_id`` 64-bit
    integers, ``success`` 0 or 1 (errors name the file and line)."""
    where = np.array([row.line for row in table.rows], dtype=np.int64)
    values = np.array(
        [[parse_number(row.cell(c), f"column '{c}'", table.path, row.line, OpenFaceFileError, finite=False)
          for c in columns] for row in table.rows],
        dtype=np.float64,
    ).reshape(len(where), len(columns))
    col = {c: values[:, j] for j, c in enumerate(columns)}

    def fail_at(mask, message):
        _fail_at(mask, message, table.path, where)

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
    return where, values


def _exact_ids(table, column: str) -> np.ndarray:
    """``(M,)`` int64 of an integer column (frame, face_id) of every row, parsed exactly (not through float64,
    which rounds ids above 2^53); the float checks of :func:`_parse_columns` came first."""
    return np.array([parse_integer(row.cell(column), f"column '{column}'", table.path, row.line, OpenFaceFileError)
                     for row in table.rows], dtype=np.int64)


def _fail_at(mask, message, path, where) -> None:
    """Raise :class:`OpenFaceFileError` ``message(i)`` at the line of the first row ``i`` where ``mask`` holds."""
    bad = np.nonzero(mask)[0]
    if bad.size:
        raise OpenFaceFileError(message(bad[0]), path, int(where[bad[0]]))


def _check_gaze_angles(col, fail_at) -> None:
    """``gaze_angle_x`` and ``gaze_angle_y`` must lie in (−π/2, π/2) (a gaze toward the camera)."""
    for c in ("gaze_angle_x", "gaze_angle_y"):
        fail_at(
            np.abs(col[c]) >= np.pi / 2,
            lambda i, c=c: f"column '{c}' = {float(col[c][i])!r} is outside (−π/2, π/2): "
            "not atan2(g, −g_z) of a gaze toward the camera",
        )


def _gaze_from_angles(ax: np.ndarray, ay: np.ndarray) -> np.ndarray:
    """The inverse of OpenFace's ``GetGazeAngle``: ``(T,)`` angles → ``(T, 3)`` unit gaze in OpenCV
    camera axes, ``unit(tan x, tan y, −1)`` (angles in (−π/2, π/2))."""
    # (tan x, tan y, −1) scaled by cos x cos y > 0: no division, same direction.
    g_cv = np.stack([np.sin(ax) * np.cos(ay), np.cos(ax) * np.sin(ay), -np.cos(ax) * np.cos(ay)], axis=-1)
    return g_cv / np.linalg.norm(g_cv, axis=-1, keepdims=True)


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
    return _read_tracks(path, min_confidence, face_id, with_gaze=True)[0]


def _read_tracks(path, min_confidence: float, face_id: Optional[int], *, with_gaze: bool,
                 link_gate_m: Optional[float] = None):
    """:func:`read_openface` (``link_gate_m`` None: one face, ``face_id`` or the only one) and
    :func:`read_openface_people` (every face, re-linked): the file parsed, checked and converted once."""
    min_confidence = float(min_confidence)
    if not math.isfinite(min_confidence):
        raise ValueError(f"read_openface: min_confidence must be finite, got {min_confidence}")
    table = read_csv_table(
        path, OPENFACE_COLUMNS if with_gaze else OPENFACE_COLUMNS[:4] + _GAZE_POSE[2:], ("face_id",),
        error=OpenFaceFileError, what="OpenFace", lower=False, hint=_missing_columns_hint,
        empty="empty file: expected an OpenFace CSV header (frame, face_id, timestamp, ...)",
    )
    gaze = _GAZE_POSE[:2] if with_gaze else ()
    pose = _GAZE_POSE[2:]
    columns = [c for c in _BOOKKEEPING if table.has(c)] + list(gaze) + list(pose)
    where, values = _parse_columns(table, columns)

    faces = _exact_ids(table, "face_id") if "face_id" in columns else np.zeros(len(where), dtype=np.int64)
    present = sorted(set(faces.tolist()))
    everyone = link_gate_m is not None
    if everyone:
        mine = np.ones(len(where), dtype=bool)
    else:
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
    where, values, faces = where[mine], values[mine], faces[mine]
    col = {c: values[:, j] for j, c in enumerate(columns)}
    frames = _exact_ids(table, "frame")[mine]

    def fail_at(mask, message):
        _fail_at(mask, message, path, where)

    first: dict[tuple[int, int], int] = {}
    for key, line in zip(zip(frames.tolist(), faces.tolist()), where.tolist()):
        seen = first.setdefault(key, line)
        if seen != line:
            raise OpenFaceFileError(f"duplicate frame {key[0]} of face_id {key[1]} (first on line {seen})", path, line)

    failed = col["success"] == 0
    unsure = ~failed & (col["confidence"] < min_confidence)
    dropped = {"success == 0": int(failed.sum()), f"confidence < {min_confidence:g}": int(unsure.sum())}
    keep = ~(failed | unsure)
    total = int(mine.sum())
    summary = ", ".join(f"{reason}: {count}" for reason, count in dropped.items())
    which = "rows" if everyone else f"frames of face_id {face_id}"
    if not keep.any():
        raise OpenFaceFileError(f"no frames left: all {total} {which} dropped ({summary})", path)
    if not keep.all():
        warnings.warn(f"{os.fspath(path)}: dropped {total - int(keep.sum())} of {total} {which} ({summary})",
                      stacklevel=3)
    where, values, frames, faces = where[keep], values[keep], frames[keep], faces[keep]
    col = {c: values[:, j] for j, c in enumerate(columns)}
    for c in (*gaze, *pose):
        fail_at(
            ~np.isfinite(col[c]), lambda i, c=c: f"column '{c}' is not finite in a kept frame: {float(col[c][i])!r}"
        )
    if gaze:
        _check_gaze_angles(col, fail_at)
        g_cv = _gaze_from_angles(col["gaze_angle_x"], col["gaze_angle_y"])
    else:
        g_cv = np.full((len(where), 3), np.nan)
    R_cv = _openface_euler_to_matrix(col["pose_Rx"], col["pose_Ry"], col["pose_Rz"])
    position = np.stack([col["pose_Tx"], col["pose_Ty"], col["pose_Tz"]], axis=-1) / 1000.0 @ R_OURS_FROM_OPENCV.T
    person, relinks = (link_openface_faces(frames, faces, position, gate_m=link_gate_m) if everyone and len(present) > 1
                       else (np.zeros(len(where), dtype=np.int64), 0))

    def track(rows):
        rows = rows[np.argsort(frames[rows], kind="stable")]
        return OpenFaceTrack(
            frame=frames[rows], timestamp=col["timestamp"][rows], confidence=col["confidence"][rows],
            gaze_direction_camera=g_cv[rows] @ R_OURS_FROM_OPENCV.T,
            R_camera_from_head=R_OURS_FROM_OPENCV @ R_cv[rows] @ R_OPENFACE_MODEL_FROM_HEAD,
            head_position_camera=position[rows], dropped=dropped,
        )

    tracks = tuple(track(np.flatnonzero(person == k)) for k in range(int(person.max()) + 1))
    if not everyone:
        return tracks
    ids = tuple(tuple(sorted(set(faces[person == k].tolist()))) for k in range(len(tracks)))
    return OpenFacePeople(tracks, ids, relinks, dropped)


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


# ---------------------------------------------------------------------------
# Several faces (FaceLandmarkVidMulti) → gaze rays

#: OpenFace 2.0's mean gaze error, 9.1° on MPIIGaze cross-dataset (Baltrušaitis et al., FG 2018,
#: "OpenFace 2.0: Facial behavior analysis toolkit", gaze estimation results), in radians.
OPENFACE_MEAN_GAZE_ERROR = math.radians(9.1)
#: The bandwidth ``h`` (radians, ≈ 0.127, 7.3°) of OpenFace's rays: the cone whose mean angular error is
#: :data:`OPENFACE_MEAN_GAZE_ERROR` (``bandwidth_from_mean_angular_error``; OpenFace reports no per-frame
#: uncertainty). A cross-dataset figure: people far from the camera or turned away do worse.
DEFAULT_BANDWIDTH_OPENFACE = bandwidth_from_mean_angular_error(OPENFACE_MEAN_GAZE_ERROR)
#: Largest step (metres) of an eye centre between two sightings of one person when
#: :func:`read_openface_rays` re-links faces into people (``link_gate_m``): below the ~0.6 m between
#: the heads of two people side by side, above OpenFace's jumps in depth when a face is re-detected.
OPENFACE_LINK_GATE_M = 0.5

_GAZE_VECTORS = tuple(f"gaze_{e}_{a}" for e in (0, 1) for a in "xyz")
_GAZE_ANGLES = ("gaze_angle_x", "gaze_angle_y")
_POSE_T = ("pose_Tx", "pose_Ty", "pose_Tz")
_POSE_R = ("pose_Rx", "pose_Ry", "pose_Rz")
_NUM_EYE_LANDMARKS = 56
_EYE_LANDMARKS = tuple(f"eye_lmk_{a}_{k}" for a in "XYZ" for k in range(_NUM_EYE_LANDMARKS))
_RAYS_BOOKKEEPING = ("frame", "timestamp", "confidence", "success")
#: Columns :func:`write_openface_rays` writes (OpenFace 2's names and order).
OPENFACE_RAYS_COLUMNS = ("frame", "face_id", "timestamp", "confidence", "success", *_GAZE_VECTORS, *_GAZE_ANGLES,
                         *_POSE_T, *_POSE_R)


class _Faces(NamedTuple):
    """The kept rows of one OpenFace CSV: frame, face_id, eye centre and gaze (our camera frame)."""

    path: str
    frame: np.ndarray
    face_id: np.ndarray
    eyes_camera: np.ndarray
    gaze_camera: np.ndarray


def _read_faces(path, min_confidence: float) -> _Faces:
    """One OpenFace CSV → :class:`_Faces` (see :func:`read_openface_rays` for the columns and checks)."""
    table = read_csv_table(
        path, _RAYS_BOOKKEEPING, ("face_id", *_GAZE_VECTORS, *_GAZE_ANGLES, *_POSE_T, *_EYE_LANDMARKS),
        error=OpenFaceFileError, what="OpenFace", lower=False, hint=_missing_columns_hint,
        empty="empty file: expected an OpenFace CSV header (frame, face_id, timestamp, ...)",
    )
    path = table.path
    landmarks = [c for c in _EYE_LANDMARKS if table.has(c)]
    if landmarks and len(landmarks) < len(_EYE_LANDMARKS):
        missing = [c for c in _EYE_LANDMARKS if not table.has(c)]
        raise table.fail(f"incomplete 3D eye landmarks: missing {first_few(missing)} (need eye_lmk_X_0 … eye_lmk_Z_55)")
    if all(table.has(c) for c in _GAZE_VECTORS):
        gaze = _GAZE_VECTORS
    elif all(table.has(c) for c in _GAZE_ANGLES):
        gaze = _GAZE_ANGLES
    else:
        raise table.fail("no gaze in the header (need gaze_0_x … gaze_1_z, or gaze_angle_x and gaze_angle_y): "
                         "run OpenFace with -gaze, or with no output flag at all for every column")
    if landmarks:
        position = _EYE_LANDMARKS
    elif all(table.has(c) for c in _POSE_T):
        position = _POSE_T
    else:
        raise table.fail("no head position in the header (need pose_Tx, pose_Ty, pose_Tz, or the 3D eye landmarks "
                         "eye_lmk_X_0 … eye_lmk_Z_55): run OpenFace with -pose, or with no output flag at all")
    columns = [c for c in _BOOKKEEPING if table.has(c)] + list(gaze) + list(position)
    where, values = _parse_columns(table, columns)
    col = {c: values[:, j] for j, c in enumerate(columns)}
    frames = _exact_ids(table, "frame")
    faces = _exact_ids(table, "face_id") if "face_id" in col else np.zeros(len(where), dtype=np.int64)

    first: dict[tuple[int, int], int] = {}
    for key, line in zip(zip(frames.tolist(), faces.tolist()), where.tolist()):
        seen = first.setdefault(key, line)
        if seen != line:
            raise OpenFaceFileError(f"duplicate face_id {key[1]} in frame {key[0]} (first on line {seen})", path, line)

    failed = col["success"] == 0
    unsure = ~failed & (col["confidence"] < min_confidence)
    keep = ~(failed | unsure)
    summary = f"success == 0: {int(failed.sum())}, confidence < {min_confidence:g}: {int(unsure.sum())}"
    if not keep.any():
        raise OpenFaceFileError(f"no faces left: all {len(where)} rows dropped ({summary})", path)
    if not keep.all():
        warnings.warn(f"{path}: dropped {len(where) - int(keep.sum())} of {len(where)} rows ({summary})", stacklevel=3)
    where, values, frames, faces = where[keep], values[keep], frames[keep], faces[keep]
    col = {c: values[:, j] for j, c in enumerate(columns)}

    def fail_at(mask, message):
        _fail_at(mask, message, path, where)

    for c in (*gaze, *position):
        fail_at(~np.isfinite(col[c]), lambda i, c=c: f"column '{c}' is not finite in a kept row: {float(col[c][i])!r}")
    if gaze == _GAZE_ANGLES:
        _check_gaze_angles(col, fail_at)
        g_cv = _gaze_from_angles(col["gaze_angle_x"], col["gaze_angle_y"])
    else:
        # GetGazeAngle's mean of the two eyes, kept as a vector: it may point away from the camera.
        g_cv = 0.5 * np.stack([col[f"gaze_0_{a}"] + col[f"gaze_1_{a}"] for a in "xyz"], axis=-1)
        norm = np.linalg.norm(g_cv, axis=-1, keepdims=True)
        fail_at(norm[:, 0] < 1e-9, lambda i: "gaze_0 and gaze_1 average to a zero vector")
        g_cv = g_cv / norm
    if position == _EYE_LANDMARKS:
        eyes_cv = np.stack([np.mean([col[f"eye_lmk_{a}_{k}"] for k in range(_NUM_EYE_LANDMARKS)], axis=0)
                            for a in "XYZ"], axis=-1) / 1000.0
    else:
        eyes_cv = np.stack([col[c] for c in _POSE_T], axis=-1) / 1000.0
    return _Faces(path, frames, faces, eyes_cv @ R_OURS_FROM_OPENCV.T, g_cv @ R_OURS_FROM_OPENCV.T)


def link_openface_faces(frames, face_ids, positions, *, gate_m: float = OPENFACE_LINK_GATE_M) -> tuple[np.ndarray, int]:
    """Re-link OpenFace's faces into people by position: ``(M,)`` rows → ``(track (M,), relinks)``.

    OpenFace's ``face_id`` is the slot of a tracker, not a person: a face lost and detected again
    takes the first free slot, so ids swap or pass to someone else (OpenFace issues #804, #900).
    Frame by frame, in increasing order, each face is assigned to a person seen before by the
    minimum total distance between its ``position`` (metres) and that person's last position
    (``scipy.optimize.linear_sum_assignment``); a pair farther apart than ``gate_m`` is not
    linked, and a face linked to nobody starts a new person. People are numbered ``0, 1, …`` in
    order of first appearance (then of ``face_id``). ``relinks`` counts the rows whose person
    was last seen under another ``face_id``. People who cross within ``gate_m`` of each other
    while both unseen can be confused: no appearance model is used.
    """
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    face_ids = np.asarray(face_ids, dtype=np.int64).reshape(-1)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    gate_m = float(gate_m)
    if not (math.isfinite(gate_m) and gate_m > 0):
        raise ValueError(f"link_openface_faces: gate_m must be a positive number of metres, got {gate_m}")
    if not (len(frames) == len(face_ids) == len(positions)):
        raise ValueError("link_openface_faces: frames, face_ids and positions need the same number of rows")
    order = np.lexsort((face_ids, frames))
    track = np.full(len(frames), -1, dtype=np.int64)
    last_position: list[np.ndarray] = []
    last_id: list[int] = []
    relinks = 0
    starts = np.flatnonzero(np.r_[True, np.diff(frames[order]) != 0])
    for rows in np.split(order, starts[1:]):
        linked = np.zeros(len(rows), dtype=bool)
        if last_position:
            cost = np.linalg.norm(positions[rows][:, None] - np.asarray(last_position)[None], axis=-1)
            r, k = linear_sum_assignment(np.where(cost <= gate_m, cost, 1e9))
            for ri, ki in zip(r, k):
                if cost[ri, ki] <= gate_m:
                    row = rows[ri]
                    track[row], linked[ri] = ki, True
                    relinks += int(last_id[ki] != face_ids[row])
                    last_position[ki], last_id[ki] = positions[row], int(face_ids[row])
        for row in rows[~linked]:
            track[row] = len(last_position)
            last_position.append(positions[row])
            last_id.append(int(face_ids[row]))
    return track, relinks


class OpenFacePeople(NamedTuple):
    """Every face of an OpenFace CSV as people (:func:`read_openface_people`).

    ``tracks``: one :class:`OpenFaceTrack` per person, in order of first appearance (NaN gaze when the
    file has no gaze columns); ``face_ids``: the OpenFace ``face_id`` values each person was seen under;
    ``relinks``: rows whose person was last seen under another ``face_id``; ``dropped``: rows removed per
    reason, over the whole file."""

    tracks: tuple
    face_ids: tuple
    relinks: int
    dropped: dict


def read_openface_people(path, *, min_confidence: float = 0.75, link_gate_m: float = OPENFACE_LINK_GATE_M,
                         with_gaze: bool = True) -> OpenFacePeople:
    """The head pose of every face of an OpenFace 2 CSV (``FaceLandmarkVidMulti``: a group filmed by one camera),
    one :class:`OpenFaceTrack` per person, in our camera frame.

    Conversions and checks are :func:`read_openface`'s, except that every face is kept and, without
    ``with_gaze`` (head pose only), the gaze columns are neither needed nor read (the gaze is NaN: a face
    turned away from the camera has a head pose, not OpenFace's gaze angles). ``face_id`` is a
    tracker slot, not a person: the kept rows are re-linked into people by their head position ``pose_T``
    (:func:`link_openface_faces`, gate ``link_gate_m``). A file with one ``face_id`` is one person (as
    :func:`read_openface`), however far its face jumps. One warning counts the dropped rows.
    """
    return _read_tracks(path, min_confidence, None, with_gaze=with_gaze, link_gate_m=link_gate_m)


def read_openface_rays(paths, *, camera: Optional[CameraPoses] = None, min_confidence: float = 0.75,
                       link_gate_m: float = OPENFACE_LINK_GATE_M) -> RayRecording:
    """Gaze rays of every face in OpenFace 2 CSVs (``FaceLandmarkVidMulti``, or ``FeatureExtraction``).

    ``paths`` is one CSV or several of the same camera (e.g. one per person); each file's faces are
    linked into people separately and numbered on after the previous files' people. Per kept row:

    * **direction**: the mean of the two eyes' gaze vectors ``(gaze_0 + gaze_1) / 2``, unit (OpenCV
      camera axes; the vector whose ``atan2`` is ``gaze_angle_*``, OpenFace ``GazeAnalysis::GetGazeAngle``;
      it may point away from the camera). Without ``gaze_0/1`` columns, the inverse of
      ``gaze_angle_x/y`` (toward the camera only, as :func:`read_openface`);
    * **origin**: the centre of the eyes, the mean of the 56 3D eye landmarks ``eye_lmk_X/Y/Z_*``
      (millimetres, camera frame; ~1 cm in front of the eyeball centres OpenFace's gaze starts
      from). Without them, ``pose_T``: the origin of OpenFace's head model (``GetPose``'s
      ``solvePnP`` translation), a few centimetres below and in front of the eyes; that offset is
      ignored (< 2° to a target 1.5 m away);
    * **bandwidth**: :data:`DEFAULT_BANDWIDTH_OPENFACE` (OpenFace reports no gaze uncertainty).

    OpenCV axes and millimetres become our camera frame and metres (``R_OURS_FROM_OPENCV``, / 1000);
    ``camera`` (:class:`~jaxgaze.poses.CameraPoses`) places them in a world, else the world is the
    camera frame. Rows with ``success == 0`` or ``confidence < min_confidence`` are dropped (one
    warning counts them). ``face_id`` is not a person (:func:`link_openface_faces`): faces are
    re-linked into people ``person_0, person_1, …`` by eye position with the gate ``link_gate_m``,
    and one warning counts the re-links. Within a frame, rays are in person order.

    Raises :class:`OpenFaceFileError` (``path, line N:``) for a malformed file, a header without gaze
    or position columns or with some of the 3D eye landmarks only, a bad bookkeeping cell (as
    :func:`read_openface`), a duplicate (frame, face_id), NaN/inf in a used column of a kept row,
    a gaze angle outside (−π/2, π/2), eye vectors averaging to zero, or every row dropped.
    """
    min_confidence = float(min_confidence)
    if not math.isfinite(min_confidence):
        raise ValueError(f"read_openface_rays: min_confidence must be finite, got {min_confidence}")
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise ValueError("read_openface_rays: no files given")
    frames, people, eyes, gaze = [], [], [], []
    num_people = 0
    for path in paths:
        faces = _read_faces(path, min_confidence)
        track, relinks = link_openface_faces(faces.frame, faces.face_id, faces.eyes_camera, gate_m=link_gate_m)
        if relinks:
            warnings.warn(f"{faces.path}: face_id is not stable: re-linked {relinks} rows to the person last seen "
                          f"there; {int(track.max()) + 1} people from face_id {first_few(sorted(set(faces.face_id.tolist())), 5)}",
                          stacklevel=2)
        frames.append(faces.frame)
        people.append(track + num_people)
        eyes.append(faces.eyes_camera)
        gaze.append(faces.gaze_camera)
        num_people += int(track.max()) + 1
    frames, people = np.concatenate(frames), np.concatenate(people)
    order = np.lexsort((people, frames))
    where = os.fspath(paths[0]) if len(paths) == 1 else first_few([os.fspath(p) for p in paths])
    return rays_from_camera(frames[order], [f"person_{k}" for k in people[order]], np.concatenate(eyes)[order],
                            np.concatenate(gaze)[order], np.full(len(order), DEFAULT_BANDWIDTH_OPENFACE),
                            camera=camera, path=where)


def _facing(directions: np.ndarray) -> np.ndarray:
    """``(M, 3)`` unit directions → ``(M, 3, 3)`` rotations whose forward axis is the direction, left axis
    horizontal (our camera's +z is up; a vertical direction takes +y as its left)."""
    up = np.array([0.0, 0.0, 1.0])
    left = np.cross(up, directions)
    flat = np.linalg.norm(left, axis=-1) < 1e-9
    left[flat] = [0.0, 1.0, 0.0]
    left /= np.linalg.norm(left, axis=-1, keepdims=True)
    return np.stack([directions, left, np.cross(directions, left)], axis=-1)


def write_openface_faces(path, frames, face_ids, eyes_camera, gaze_camera, *, R_camera_from_head=None,
                         confidence=None, fps: float = 30.0) -> int:
    """Write rows (frame, face_id, eye centre, gaze, in our camera frame, metres) as an OpenFace 2 CSV
    with the columns :data:`OPENFACE_RAYS_COLUMNS`, atomically; returns the number of rows.

    ``gaze_0 = gaze_1 =`` the gaze in OpenCV axes; ``gaze_angle_*``, ``pose_T`` (millimetres) and
    ``pose_R`` by :func:`openface_pose_and_gaze` with ``pose_T`` at the eye centre (read back by
    :func:`read_openface_rays`, which finds no eye landmarks). ``R_camera_from_head`` ``(M, 3, 3)``
    defaults to a head facing along the gaze, upright. ``timestamp = (frame − 1) / fps`` (OpenFace
    counts frames from 1), ``success = 1``, ``confidence`` default 1.
    """
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    face_ids = np.asarray(face_ids, dtype=np.int64).reshape(-1)
    eyes = np.asarray(eyes_camera, dtype=np.float64).reshape(-1, 3)
    gaze = np.asarray(gaze_camera, dtype=np.float64).reshape(-1, 3)
    gaze = gaze / np.linalg.norm(gaze, axis=-1, keepdims=True)
    R = _facing(gaze) if R_camera_from_head is None else np.asarray(R_camera_from_head, float).reshape(-1, 3, 3)
    confidence = np.ones(len(frames)) if confidence is None else np.broadcast_to(confidence, frames.shape)
    fps = float(fps)
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"write_openface_faces: fps must be positive, got {fps}")
    if not (len(face_ids) == len(eyes) == len(gaze) == len(R) == len(frames)):
        raise ValueError("write_openface_faces: every input needs one row per face")
    if not (np.isfinite(eyes).all() and np.isfinite(gaze).all() and np.isfinite(R).all()):
        raise ValueError("write_openface_faces: eye centres, gaze and head rotations must be finite and non-zero")
    columns = openface_pose_and_gaze(R, eyes, gaze)
    g_cv = gaze @ R_OURS_FROM_OPENCV
    order = np.lexsort((face_ids, frames))
    rows = ([int(frames[i]), int(face_ids[i]), format_float((frames[i] - 1) / fps), format_float(confidence[i]), 1,
             *map(format_float, g_cv[i]), *map(format_float, g_cv[i]),
             *(format_float(columns[c][i]) for c in (*_GAZE_ANGLES, *_POSE_T, *_POSE_R))] for i in order)
    return write_csv_rows(path, OPENFACE_RAYS_COLUMNS, rows)


def write_openface_rays(path, recording: RayRecording, *, camera: Optional[CameraPoses] = None,
                        fps: float = 30.0) -> int:
    """Write a :class:`~jaxgaze.io.rays.RayRecording` as an OpenFace 2 multi-face CSV (the inverse of
    :func:`read_openface_rays`): world → camera frame (``camera``, as read), ``face_id`` = the index
    of the person in order of first appearance, and :func:`write_openface_faces`. OpenFace has no
    bandwidth column: the rays read back with :data:`DEFAULT_BANDWIDTH_OPENFACE`."""
    mask = np.asarray(recording.rays.mask)
    t, n = np.nonzero(mask)
    frames = np.asarray(recording.frame_ids, dtype=np.int64)[t]
    names = [recording.persons[a][b] for a, b in zip(t, n)]
    face_id = {name: k for k, name in enumerate(dict.fromkeys(names))}
    eyes, gaze = world_rays_to_camera(frames, recording.world_origins()[t, n],
                                      np.asarray(recording.rays.directions, float)[t, n], camera)
    return write_openface_faces(path, frames, [face_id[name] for name in names], eyes, gaze, fps=fps)
