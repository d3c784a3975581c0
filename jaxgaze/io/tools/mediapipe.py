"""MediaPipe Face Landmarker head poses → world-frame rays: the head's direction as the primary gaze
ray, as for a head-pose-only tracker (Yücel et al. 2013, head pose for gaze direction).

``FaceLandmarkerResult.facial_transformation_matrixes`` holds one 4 × 4 matrix ``M`` per face that maps
MediaPipe's canonical face model into its metric camera space (MediaPipe docs, Face Mesh, "Face
Transform Module"; ``geometry_pipeline.cc``). From MediaPipe's docs and code:

* **camera space**: right-handed, **centimetres** (the canonical model's unit), the virtual camera at
  the origin looking along **−z**, x right, y up (``TOP_LEFT_CORNER`` origin, y flipped in
  ``ProjectXY``, z negated in ``ChangeHandedness``). Its vertical field of view is **63°**
  (``FaceGeometryFromLandmarksGraph``), whatever the real camera's: x and y come out right, depth
  scales as ``1 / tan(fov / 2)``, so ``vertical_fov_deg`` (the real camera's) rescales z by
  ``tan(31.5°) / tan(vertical_fov_deg / 2)`` (63: unchanged);
* **canonical face model** (``canonical_face_model.obj``): +x the person's left, +y up, +z out of the
  face (the nose tip has the largest z). So the head's forward direction is ``M``'s third column
  (normalised: ``M`` is a Procrustes similarity, with a scale near 1);
* ``M`` is a NumPy array in the Python API (``_build_landmarker_result`` turns MediaPipe's
  column-major ``MatrixData`` into the true matrix): ``x_camera = M @ (x_model, 1)``.

One ray per face: origin ``M`` applied to the canonical centre of the eyes :data:`CANONICAL_EYE_CENTER_CM`
(the mean of the eye corners, landmarks 33, 133, 362, 263), direction the face's +z, both turned into
our axes (:data:`R_OURS_FROM_MEDIAPIPE`) and metres, and placed by ``camera=`` (else the world is our
camera frame). The faces of a frame are people ``"0", "1", …`` in MediaPipe's order, which is **not** an
identity across frames (like OpenFace's ``face_id``). The bandwidth is :data:`DEFAULT_BANDWIDTH_MEDIAPIPE`.
The images must not be mirrored (a selfie preview swaps the person's left and right).

**Iris landmarks** (478 landmarks: 468–477 the irises, with ``refine_landmarks``) are checked when
present but not used: they are normalised image coordinates with a relative depth, and MediaPipe
has no eyeball model to turn them into an eye-in-head rotation (its head pose also uses the first
468 landmarks only). The eyes' deviation from the head stays in the bandwidth.

**File**: the Python API returns objects, so the file is a JSON Lines dump, one JSON object a line
(blank lines skipped)::

    {"frame": 0, "timestamp_ms": 0, "facial_transformation_matrixes": [[m00, m01, …, m33], …],
     "face_landmarks": [[[x, y, z], …], …]}

``frame`` (integer, required, unique), ``timestamp_ms`` (optional number, not used),
``facial_transformation_matrixes`` (required, one matrix per face: 16 numbers row-major, or four rows
of four, i.e. ``m.tolist()``; ``[]`` for a frame without a face), ``face_landmarks`` (optional, one
list of 468 or 478 ``[x, y, z]`` per face).
"""

from __future__ import annotations

import json
import math
import os
from typing import Optional

import numpy as np

from jaxgaze.io.tools.common import rays_from_camera, world_rays_to_camera, tool_bandwidth
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import InputFileError, atomic_path, first_few, read_lines
from jaxgaze.poses import CameraPoses

__all__ = [
    "DEFAULT_BANDWIDTH_MEDIAPIPE",
    "R_OURS_FROM_MEDIAPIPE",
    "CANONICAL_EYE_CENTER_CM",
    "MEDIAPIPE_VERTICAL_FOV_DEG",
    "mediapipe_head_rays",
    "mediapipe_to_rays",
    "read_mediapipe",
    "write_mediapipe",
]

#: Bandwidth ``h`` (radians, 11.5°) of a head-pose-only ray: the eyes are not the head. In meetings the
#: head carries about 70% of a gaze shift (Stiefelhagen & Zhu 2002), leaving eye-in-head offsets of
#: 10–15°; 0.2 rad is the low end of the 0.2–0.3 head-pose spread this library assumes elsewhere
#: (``jaxgaze.rays.PLAUSIBLE_BANDWIDTH``), a mean angle of ``h √(π/2)`` = 14°. MediaPipe's own head-pose
#: error (a few degrees) adds in quadrature and changes it little.
DEFAULT_BANDWIDTH_MEDIAPIPE = 0.2

#: ``v_ours = R_OURS_FROM_MEDIAPIPE @ v_mediapipe``: MediaPipe's camera space is x right, y up, z toward
#: the viewer (the camera looks along −z); ours is x forward, y left, z up. det = +1.
R_OURS_FROM_MEDIAPIPE = np.array([
    [0.0, 0.0, -1.0],
    [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
])
R_OURS_FROM_MEDIAPIPE.setflags(write=False)

#: The centre of the eyes in the canonical face model (centimetres): the mean of the eye corners,
#: landmarks 33 (−4.445859, 2.663991, 3.173422), 133 (−1.856432, 2.585245, 3.757904) and their
#: mirror images 263 and 362 (``canonical_face_model.obj``).
CANONICAL_EYE_CENTER_CM = np.array([0.0, 2.624618, 3.465663])
CANONICAL_EYE_CENTER_CM.setflags(write=False)

#: The vertical field of view of MediaPipe's virtual camera (degrees, ``FaceGeometryFromLandmarksGraph``).
MEDIAPIPE_VERTICAL_FOV_DEG = 63.0

_MATRIX_KEY = "facial_transformation_matrixes"
_LANDMARK_COUNTS = (468, 478)
#: A transformation whose 3 × 3 part is further than this from a scaled rotation, or whose last row is
#: further from (0, 0, 0, 1), is no face pose.
_MATRIX_TOLERANCE = 1e-3


def _depth_scale(vertical_fov_deg: float) -> float:
    fov = float(vertical_fov_deg)
    if not 0.0 < fov < 180.0:
        raise ValueError(f"vertical_fov_deg must be in (0, 180) degrees, got {fov:g}")
    return math.tan(math.radians(MEDIAPIPE_VERTICAL_FOV_DEG) / 2) / math.tan(math.radians(fov) / 2)


def _matrix_problem(M: np.ndarray) -> Optional[str]:
    """What makes a 4 × 4 ``M`` no face pose in front of the camera, or ``None``."""
    if not np.isfinite(M).all():
        return "a facial transformation matrix is not finite"
    if np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max() > _MATRIX_TOLERANCE:
        return "a facial transformation matrix's last row is not (0, 0, 0, 1)"
    A = M[:3, :3]
    det = np.linalg.det(A)
    if det <= 0:
        return "a facial transformation matrix is not a rotation (determinant ≤ 0)"
    R = A / np.cbrt(det)
    if np.abs(R @ R.T - np.eye(3)).max() > _MATRIX_TOLERANCE:
        return "a facial transformation matrix is not a scaled rotation (row-major? 16 numbers or 4 rows of 4)"
    if M[2, 3] >= 0:
        return (f"a face at z = {M[2, 3]:g} cm is not in front of the camera (MediaPipe's camera looks along −z; "
                "transposed?)")
    return None


def mediapipe_head_rays(matrices, *, vertical_fov_deg: float = MEDIAPIPE_VERTICAL_FOV_DEG):
    """``(K, 4, 4)`` facial transformation matrices → eye centres ``(K, 3)`` (metres) and unit head
    directions ``(K, 3)`` in **our** camera frame: ``M @ (CANONICAL_EYE_CENTER_CM, 1)`` with its depth
    rescaled to the real field of view, and ``M``'s third column; then :data:`R_OURS_FROM_MEDIAPIPE`."""
    M = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    for m in M:
        problem = _matrix_problem(m)
        if problem:
            raise ValueError(problem)
    eyes = np.einsum("kij,j->ki", M[:, :3, :3], CANONICAL_EYE_CENTER_CM) + M[:, :3, 3]
    eyes[:, 2] *= _depth_scale(vertical_fov_deg)
    forward = M[:, :3, 2] / np.linalg.norm(M[:, :3, 2], axis=-1, keepdims=True)
    return eyes / 100.0 @ R_OURS_FROM_MEDIAPIPE.T, forward @ R_OURS_FROM_MEDIAPIPE.T


def mediapipe_to_rays(results, frames=None, *, camera: Optional[CameraPoses] = None,
                      bandwidth: float = DEFAULT_BANDWIDTH_MEDIAPIPE,
                      vertical_fov_deg: float = MEDIAPIPE_VERTICAL_FOV_DEG) -> RayRecording:
    """Rays from Face Landmarker results: a sequence of objects with ``.facial_transformation_matrixes``
    (``FaceLandmarkerResult``, or anything alike; one object is one frame), one per frame of ``frames``
    (default ``0 … T−1``). Face ``k`` of a frame is person ``str(k)``; a frame without faces has no
    rays. Origins, directions and ``vertical_fov_deg`` as :func:`mediapipe_head_rays`; every ray gets
    ``bandwidth``. Raises ``ValueError`` for an object without the attribute or a bad matrix.
    """
    if hasattr(results, _MATRIX_KEY):
        results = [results]
    results = list(results)
    frames = list(range(len(results))) if frames is None else [int(f) for f in np.asarray(frames).reshape(-1)]
    if len(frames) != len(results):
        raise ValueError(f"mediapipe_to_rays: {len(results)} results but {len(frames)} frames")
    if len(set(frames)) != len(frames):
        raise ValueError("mediapipe_to_rays: a frame appears twice in frames")
    rows, persons, matrices = [], [], []
    for i, (frame, result) in enumerate(zip(frames, results)):
        if not hasattr(result, _MATRIX_KEY):
            raise ValueError(f"mediapipe_to_rays: result {i} has no .{_MATRIX_KEY} (FaceLandmarker needs "
                             "output_facial_transformation_matrixes=True)")
        faces = getattr(result, _MATRIX_KEY)
        for k, matrix in enumerate([] if faces is None else faces):
            matrix = np.asarray(matrix, dtype=np.float64)
            if matrix.size != 16:
                raise ValueError(f"mediapipe_to_rays: result {i}, face {k}: a 4 × 4 matrix, got shape {matrix.shape}")
            rows.append(frame)
            persons.append(str(k))
            matrices.append(matrix.reshape(4, 4))
    if not matrices:
        raise ValueError("mediapipe_to_rays: no faces (no facial transformation matrices: FaceLandmarker needs "
                         "output_facial_transformation_matrixes=True)")
    h = tool_bandwidth(bandwidth, "mediapipe_to_rays")
    eyes, forward = mediapipe_head_rays(matrices, vertical_fov_deg=vertical_fov_deg)
    return rays_from_camera(rows, persons, eyes, forward, np.full(len(rows), h), camera=camera)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _parse_matrix(value) -> Optional[np.ndarray]:
    """16 numbers, or 4 rows of 4 → ``(4, 4)``; ``None`` if it is neither."""
    if isinstance(value, list) and len(value) == 4 and all(isinstance(r, list) and len(r) == 4 for r in value):
        value = [x for r in value for x in r]
    if not (isinstance(value, list) and len(value) == 16 and all(_number(x) for x in value)):
        return None
    return np.array(value, dtype=np.float64).reshape(4, 4)


def _check_landmarks(value, faces: int, fail) -> None:
    if not (isinstance(value, list) and len(value) == faces):
        fail(f"face_landmarks must list one face per facial transformation matrix ({faces})")
    for k, face in enumerate(value):
        if not (isinstance(face, list) and len(face) in _LANDMARK_COUNTS):
            count = len(face) if isinstance(face, list) else type(face).__name__
            fail(f"face_landmarks of face {k}: need 468 or 478 (with the irises) landmarks, got {count}")
        if not all(isinstance(p, list) and len(p) == 3 and all(_number(x) for x in p) for p in face):
            fail(f"face_landmarks of face {k}: every landmark must be [x, y, z], three finite numbers")


def _read_dump(path, seen: dict, first_person: int):
    """One JSON Lines dump → (frames, persons, matrices ``(4, 4)``, faces in its fullest frame)."""
    frames, persons, matrices, most = [], [], [], 0
    lines = read_lines(path)
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue

        def fail(message, number=number):
            raise InputFileError(message, path, number)

        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            fail(f"not JSON: {error.msg} at column {error.colno}")
        if not isinstance(record, dict):
            fail("each line must be one JSON object {\"frame\": …, \"facial_transformation_matrixes\": […]}")
        frame = record.get("frame")
        if not (_number(frame) and float(frame).is_integer()):
            fail(f"'frame' must be an integer, got {json.dumps(frame)}" if "frame" in record else "no 'frame'")
        frame = int(frame)
        if "timestamp_ms" in record and not _number(record["timestamp_ms"]):
            fail(f"'timestamp_ms' must be a number, got {json.dumps(record['timestamp_ms'])}")
        faces = record.get(_MATRIX_KEY)
        if not isinstance(faces, list):
            fail(f"no '{_MATRIX_KEY}' list" if faces is None else f"'{_MATRIX_KEY}' must be a list of matrices")
        if "face_landmarks" in record:
            _check_landmarks(record["face_landmarks"], len(faces), fail)
        first = seen.setdefault((os.fspath(path), frame), number)
        if first != number:
            fail(f"frame {frame} again (first on line {first})")
        for k, value in enumerate(faces):
            matrix = _parse_matrix(value)
            if matrix is None:
                fail(f"face {k}: a facial transformation matrix is 16 finite numbers (row-major) or 4 rows of 4")
            problem = _matrix_problem(matrix)
            if problem:
                fail(f"face {k}: {problem}")
            frames.append(frame)
            persons.append(str(first_person + k))
            matrices.append(matrix)
        most = max(most, len(faces))
    if not any(line.strip() for line in lines):
        raise InputFileError("empty file: expected JSON Lines with 'frame' and 'facial_transformation_matrixes'",
                             path, max(len(lines), 1))
    return frames, persons, matrices, most


def read_mediapipe(paths, *, camera: Optional[CameraPoses] = None, bandwidth: float = DEFAULT_BANDWIDTH_MEDIAPIPE,
                   vertical_fov_deg: float = MEDIAPIPE_VERTICAL_FOV_DEG) -> RayRecording:
    """Rays from MediaPipe Face Landmarker JSON Lines dumps (format in the module docstring).

    ``paths`` is one dump or several of the same camera (e.g. one per cropped person): a file's faces
    are numbered on after the previous files' (person ``str(k)``, not an identity across frames).
    Rays as :func:`mediapipe_head_rays` (``vertical_fov_deg``: the real camera's), placed by ``camera``,
    with ``bandwidth`` each. Raises :class:`~jaxgaze.io.text.InputFileError` (``path, line N:``) for a
    line that is not a JSON object, a missing or non-integer or repeated ``frame``, a bad
    ``timestamp_ms``, a matrix that is not 16 numbers, not a scaled rotation, or puts the face behind
    the camera, ``face_landmarks`` of the wrong shape, or no face at all.
    """
    h = tool_bandwidth(bandwidth, "read_mediapipe")
    _depth_scale(vertical_fov_deg)  # a bad field of view fails before the files are read
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise ValueError("read_mediapipe: no files given")
    frames, persons, matrices, seen, offset = [], [], [], {}, 0
    for path in paths:
        f, p, m, most = _read_dump(path, seen, offset)
        frames += f
        persons += p
        matrices += m
        offset += most
    where = os.fspath(paths[0]) if len(paths) == 1 else first_few([os.fspath(p) for p in paths])
    if not matrices:
        raise InputFileError("no faces: every frame's facial_transformation_matrixes is empty", where)
    eyes, forward = mediapipe_head_rays(matrices, vertical_fov_deg=vertical_fov_deg)
    return rays_from_camera(frames, persons, eyes, forward, np.full(len(frames), h), camera=camera, path=where)


def write_mediapipe(path, recording: RayRecording, *, camera: Optional[CameraPoses] = None,
                    vertical_fov_deg: float = MEDIAPIPE_VERTICAL_FOV_DEG) -> int:
    """Write a :class:`~jaxgaze.io.rays.RayRecording` as a JSON Lines dump (the inverse of
    :func:`read_mediapipe`), atomically; returns the number of faces written.

    World → camera frame (``camera``, as read) → MediaPipe's axes and centimetres (depth un-rescaled by
    ``vertical_fov_deg``); each ray becomes a rigid ``M`` whose +z is the ray's direction, whose +x is
    horizontal (an upright head) and which puts the canonical centre of the eyes at the ray's origin.
    A frame's rays become its faces in order (persons read back as ``"0", "1", …``). The bandwidth is
    not written.
    """
    mask = np.asarray(recording.rays.mask)
    t, n = np.nonzero(mask)
    frames = np.asarray(recording.frame_ids, dtype=np.int64)[t]
    eyes, gaze = world_rays_to_camera(frames, recording.world_origins()[t, n],
                                      np.asarray(recording.rays.directions, float)[t, n], camera)
    eyes = eyes @ R_OURS_FROM_MEDIAPIPE * 100.0
    eyes[:, 2] /= _depth_scale(vertical_fov_deg)
    if not (eyes[:, 2] < 0).all():
        raise ValueError("write_mediapipe: a ray starts behind the camera")
    z = gaze @ R_OURS_FROM_MEDIAPIPE
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross([0.0, 1.0, 0.0], z)
    x[np.linalg.norm(x, axis=-1) < 1e-9] = [1.0, 0.0, 0.0]
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    R = np.stack([x, np.cross(z, x), z], axis=-1)
    M = np.zeros((len(frames), 4, 4))
    M[:, :3, :3] = R
    M[:, :3, 3] = eyes - R @ CANONICAL_EYE_CENTER_CM
    M[:, 3, 3] = 1.0
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as handle:
        for frame in recording.frame_ids:
            faces = [M[i].reshape(-1).tolist() for i in np.flatnonzero(frames == frame)]
            handle.write(json.dumps({"frame": int(frame), _MATRIX_KEY: faces}) + "\n")
    return len(frames)
