"""L2CS-Net (Abdelrahman et al. 2022) → world-frame rays, with a published-error bandwidth.

**What L2CS-Net gives.** ``Pipeline.step`` (l2cs/pipeline.py) returns a ``GazeResultContainer``
(l2cs/results.py) with ``pitch``, ``yaw`` (radians, each in ``[−π, π]`` from its 90 bins of 4°),
``bboxes``, ``landmarks`` and ``scores``, one entry per detected face.

**The swap** (L2CS-Net issue #32). ``L2CS.forward`` returns ``(yaw head, pitch head)`` but
``Pipeline.predict_gaze`` unpacks them as ``gaze_pitch, gaze_yaw``, and ``train.py`` does the same
with the labels: the first output is trained on ``label[0]``, which is the **horizontal** angle
(GazeHub's ``gaze2d = (yaw, pitch)``, which ``datasets.py`` calls "pitch"). So the container's
``pitch`` holds the horizontal angle and its ``yaw`` the vertical one. L2CS-Net itself is
consistent with that: ``gazeto3d([pitch, yaw])`` (l2cs/utils.py) and ``draw_gaze(…, (pitch, yaw))``
(l2cs/vis.py, ``dx = −sin(pitchyaw[0]) cos(pitchyaw[1])``, ``dy = −sin(pitchyaw[1])``) both take the
first as horizontal. ``order=("pitch", "yaw")`` (the default) names the container fields in that
order, horizontal first; pass ``order=("yaw", "pitch")`` if your code swapped them back so that
``yaw`` is horizontal.

**Frame and vector.** With ``h`` the horizontal and ``v`` the vertical angle, ``gazeto3d`` gives
``(−cos v sin h, −sin v, −cos v cos h)`` in axes right, down, away from the camera. The shipped
``L2CSNet_gaze360.pkl`` is trained on GazeHub's Gaze360 labels, i.e. in Gaze360's eye coordinate
system (z from the camera to the face), so the direction is Gaze360's with ``yaw = h``,
``pitch = v`` (:func:`jaxgaze.io.tools.gaze360.gaze360_directions`): ``h = v = 0`` looks into the camera
wherever the face is, ``h > 0`` to the camera's left (the person's right), ``v > 0`` up.

**Bandwidth.** L2CS-Net reports no uncertainty: every ray gets :data:`DEFAULT_BANDWIDTH_L2CS`, from
its published mean angular error on Gaze360 (10.41°, "Front 180"), the dataset of the weights its
pipeline ships and the closest to unconstrained video (3.92° on MPIIFaceGaze is for laptop users
a half metre from the camera): ``h = 10.41° / √(π/2)`` (:func:`bandwidth_from_mean_angular_error`).

**The dump CSV** (:func:`read_l2cs` / :func:`write_l2cs`): one row per face and frame,
:data:`L2CS_COLUMNS` = ``frame, face, pitch, yaw, eye_x, eye_y, eye_z``. ``face`` is any text (L2CS
does not track faces: give one person the same ``face`` in every frame); ``pitch`` and ``yaw`` are
the container's fields, as they come; L2CS-Net gives face boxes, not 3-D positions, so ``eye_*`` is
the mid-eye point in the **OpenCV camera frame** (x right, y down, z forward), metres, e.g. the
back-projection of the eyes' pixel at a depth from the face size. Several files are rows of one
recording.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.gaze360 import (
    check_rows,
    check_unique,
    default_rows,
    gaze360_angles,
    gaze360_directions,
    read_dump,
    recording_rows,
    validate_by_file,
)
from jaxgaze.io.tools.common import bandwidth_from_mean_angular_error, rays_from_camera, tool_bandwidth
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import format_float, write_csv_rows
from jaxgaze.poses import CameraPoses

__all__ = [
    "L2CS_COLUMNS",
    "L2CS_MEAN_ERROR_DEG",
    "DEFAULT_BANDWIDTH_L2CS",
    "l2cs_to_rays",
    "read_l2cs",
    "write_l2cs",
]

#: Columns of an L2CS-Net dump CSV (see the module docstring).
L2CS_COLUMNS = ("frame", "face", "pitch", "yaw", "eye_x", "eye_y", "eye_z")
#: L2CS-Net's published mean angular error on Gaze360 (README, "Front 180", β = 1), degrees.
L2CS_MEAN_ERROR_DEG = 10.41
#: The bandwidth of every L2CS-Net ray: ``radians(10.41°) / √(π/2)`` ≈ 0.145 rad (8.3°).
DEFAULT_BANDWIDTH_L2CS = bandwidth_from_mean_angular_error(math.radians(L2CS_MEAN_ERROR_DEG))

_ORDERS = (("pitch", "yaw"), ("yaw", "pitch"))
_ARRAYS = "<arrays>"


def _check_order(order) -> tuple:
    order = tuple(order)
    if order not in _ORDERS:
        raise ValueError(f"order must be ('pitch', 'yaw') or ('yaw', 'pitch') (horizontal angle first), got {order}")
    return order


def _horizontal_vertical(pitch, yaw, order) -> tuple[np.ndarray, np.ndarray]:
    """The container's fields → (horizontal, vertical) angles, by ``order`` (horizontal first)."""
    return (pitch, yaw) if _check_order(order) == ("pitch", "yaw") else (yaw, pitch)


_LIMITS = {"pitch": math.pi, "yaw": math.pi}


def l2cs_to_rays(pitch, yaw, eyes_camera, *, order: Sequence[str] = ("pitch", "yaw"),
                 frames: Optional[Sequence[int]] = None, persons: Optional[Sequence[str]] = None,
                 camera: Optional[CameraPoses] = None, bandwidth: float = DEFAULT_BANDWIDTH_L2CS) -> RayRecording:
    """L2CS-Net outputs as arrays → a world :class:`~jaxgaze.io.rays.RayRecording` (Abdelrahman et al. 2022).

    ``pitch``, ``yaw`` ``(M,)``: the ``GazeResultContainer`` fields (radians); ``order`` says which
    is horizontal (first, default ``pitch``, see the module docstring); ``eyes_camera`` ``(M, 3)``
    the mid-eye points in **our** camera axes (origin the camera centre, +x along the optical axis,
    +y left, +z up), metres, not the OpenCV axes (x right, y down, z forward) of the dump CSV's
    ``eye_*`` columns: turn those into ours with ``eyes_opencv @ R_OURS_FROM_OPENCV.T``
    (:data:`jaxgaze.geometry.R_OURS_FROM_OPENCV`), as :func:`read_l2cs` does; ``frames``
    (default ``0 … M−1``) and ``persons`` (default ``"0"``) per ray; ``camera`` places the camera in
    a world; ``bandwidth`` (radians) for every ray. Bad values raise
    :class:`~jaxgaze.io.text.InputFileError` naming the row.
    """
    pitch = np.asarray(pitch, dtype=np.float64).reshape(-1)
    yaw = np.asarray(yaw, dtype=np.float64).reshape(-1)
    if len(pitch) != len(yaw):
        raise ValueError(f"pitch and yaw must have one value per ray, got lengths {len(pitch)} and {len(yaw)}")
    eyes = np.asarray(eyes_camera, dtype=np.float64)
    if eyes.shape != (len(pitch), 3):
        raise ValueError(f"eyes_camera must be ({len(pitch)}, 3) (one eye centre per ray), got {eyes.shape}")
    horizontal, vertical = _horizontal_vertical(pitch, yaw, order)
    bandwidth = tool_bandwidth(bandwidth, "l2cs")
    frames, persons = default_rows(len(pitch), frames, persons)
    check_rows({"pitch": pitch, "yaw": yaw}, eyes, _ARRAYS, None, limits=_LIMITS, axes="ours")
    check_unique(frames, persons, [(_ARRAYS, None)] * len(frames))
    return rays_from_camera(frames, persons, eyes, gaze360_directions(horizontal, vertical, eyes), bandwidth,
                            camera=camera, path=_ARRAYS)


def read_l2cs(paths, *, camera: Optional[CameraPoses] = None, order: Sequence[str] = ("pitch", "yaw"),
              bandwidth: float = DEFAULT_BANDWIDTH_L2CS) -> RayRecording:
    """Read L2CS-Net dump CSVs (:data:`L2CS_COLUMNS`, see the module docstring) into world rays.

    One path or several (rows of one recording). Raises
    :class:`~jaxgaze.io.text.InputFileError` naming the file and line for a missing column, an
    empty or non-numeric cell, NaN, an angle beyond ±π (degrees?), eyes not in front of the
    camera, or a duplicate (frame, face).
    """
    bandwidth = tool_bandwidth(bandwidth, "l2cs")
    _check_order(order)
    frames, persons, numbers, eyes, places = read_dump(paths, L2CS_COLUMNS, "face", ("pitch", "yaw"),
                                                       L2CS_COLUMNS[4:])
    pitch, yaw = numbers["pitch"], numbers["yaw"]
    validate_by_file(places, lambda path, lines, rows: check_rows(
        {"pitch": pitch[rows], "yaw": yaw[rows]}, eyes[rows], path, lines, limits=_LIMITS, axes="opencv"))
    check_unique(frames, persons, places)
    horizontal, vertical = _horizontal_vertical(pitch, yaw, order)
    return rays_from_camera(frames, persons, eyes, gaze360_directions(horizontal, vertical, eyes), bandwidth,
                            camera=camera, path=places[0][0])


def write_l2cs(path, recording: RayRecording, *, camera: Optional[CameraPoses] = None,
               order: Sequence[str] = ("pitch", "yaw")) -> int:
    """Write rays as an L2CS-Net dump CSV (atomically); returns the number of rows.

    The inverse of :func:`read_l2cs` with the same ``order`` (the bandwidth is not written:
    L2CS-Net has none).
    """
    frames, persons, eyes, directions, _ = recording_rows(recording, camera)
    horizontal, vertical = gaze360_angles(directions, eyes)
    pitch, yaw = _horizontal_vertical(horizontal, vertical, order)  # the swap is its own inverse
    eyes_opencv = eyes @ R_OURS_FROM_OPENCV  # rows: R_OURS_FROM_OPENCV.T @ e
    rows = ([int(frames[i]), persons[i], format_float(pitch[i]), format_float(yaw[i]), *map(format_float, eyes_opencv[i])]
            for i in range(len(frames)))
    return write_csv_rows(path, L2CS_COLUMNS, rows)
