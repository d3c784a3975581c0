"""Other gaze tools' outputs → world-frame :class:`~jaxgaze.rays.GazeRays`: the pieces every adapter shares.

Each adapter (``jaxgaze.io.tools.gaze360``, ``l2cs``, ``xgaze``, ``mediapipe``, ``pupil``, ``aria``,
``openface``) turns one tool's output into a :class:`~jaxgaze.io.rays.RayRecording`: one ray per
(frame, person), origin at the centre of the eyes, world frame, metres, with a per-ray bandwidth
``h`` (radians) taken from the tool's own uncertainty where it reports one.

A camera-based tool (a webcam looking at people) sees the rays in its camera frame. They reach the
world through the camera's pose: ``x_world = R_world_from_camera @ x_camera + center``. Without a
pose the world **is** our camera frame (+x along the optical axis, +y left, +z up in the image),
which is what one static camera needs.
"""

from __future__ import annotations

import importlib
import math
from typing import Optional, Sequence

import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.rays import RayRecording, stack_rays
from jaxgaze.io.text import InputFileError
from jaxgaze.poses import CameraPoses, as_camera_poses
from jaxgaze.rays import GazeRays, check_bandwidth, check_distance

__all__ = [
    "check_camera_distances",
    "MissingExtraError",
    "require_extra",
    "bandwidth_from_mean_angular_error",
    "tool_bandwidth",
    "with_bandwidth",
    "eye_axes_problem",
    "MAX_EYE_OFF_AXIS",
    "MAX_EYE_ELEVATION",
    "camera_rays_to_world",
    "world_rays_to_camera",
    "rays_from_camera",
]


class MissingExtraError(ImportError):
    """An optional package is not installed; the message names the extra that installs it."""


def require_extra(module: str, extra: str):
    """Import ``module`` of an optional extra, or raise :class:`MissingExtraError` with one line:
    ``reading X needs the optional package P: pip install 'jaxgaze[extra]'``."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(f"this needs the optional package {module.split('.')[0]}: "
                                f"pip install 'jaxgaze[{extra}]'") from None


def bandwidth_from_mean_angular_error(mean_error) -> float:
    """The bandwidth ``h`` whose cone has the mean angular error ``mean_error`` (radians).

    The offset on the plane at unit depth is ``h δ`` with ``δ ~ N(0, I₂)``, so the angle is Rayleigh
    with scale ``h`` for small ``h`` and its mean is ``h √(π/2)``: ``h = error / √(π/2)``.
    """
    return float(mean_error) / math.sqrt(math.pi / 2)


def tool_bandwidth(value, who: str) -> float:
    """A reader's ``bandwidth=`` argument as ``h`` (radians): positive and under a radian
    (:func:`~jaxgaze.rays.check_bandwidth`), else a ``ValueError`` naming ``who``."""
    h = float(value)
    if not h > 0:
        raise ValueError(f"{who}: bandwidth must be positive (radians), got {h:g}")
    check_bandwidth(h, f"{who}: bandwidth")
    return h


#: An eye more than this far from the camera's optical axis (radians, 80°) is outside any real camera's view.
MAX_EYE_OFF_AXIS = math.radians(80.0)
#: An eye more than this far above or below the optical axis (radians, 60°) is outside any real camera's view.
MAX_EYE_ELEVATION = math.radians(60.0)
_EYE_AXES = {
    "ours": ("our camera axes (+x forward along the optical axis, +y left, +z up)",
             "they look like OpenCV axes (x right, y down, z forward), as in a dump CSV or Gaze360's person_eyes3d: "
             "turn them into ours with eyes_opencv @ R_OURS_FROM_OPENCV.T"),
    "opencv": ("OpenCV camera axes (x right, y down, z forward along the optical axis)",
               "they look like our axes (+x forward, +y left, +z up): write them in OpenCV's, "
               "eyes_ours @ R_OURS_FROM_OPENCV (z the depth)"),
}


def eye_axes_problem(eyes_camera, axes: str) -> Optional[tuple[int, str]]:
    """The frame check at the door of the camera-based readers: ``eyes_camera (M, 3)`` in our camera axes,
    read from input given in ``axes`` (``"ours"`` or ``"opencv"``). A real eye lies in front of the camera
    (positive depth along its optical axis) and within its view; input in the other convention puts the
    eyes behind the camera, or most of them beyond :data:`MAX_EYE_OFF_AXIS` from the axis or
    :data:`MAX_EYE_ELEVATION` above or below it (a swap of the two conventions gave 60–74° errors).
    Returns ``(row, message)`` of the first offending eye, naming the convention expected and the likely
    swap, or None when the eyes are plausible: an eye behind the camera, or more than half the eyes out of
    view."""
    if axes not in _EYE_AXES:
        raise ValueError(f"axes must be 'ours' or 'opencv', got {axes!r}")
    eyes = np.asarray(eyes_camera, dtype=np.float64).reshape(-1, 3)
    depth = eyes[:, 0]
    off_axis = np.arctan2(np.linalg.norm(eyes[:, 1:], axis=1), depth)
    elevation = np.arctan2(np.abs(eyes[:, 2]), np.abs(depth))
    behind = ~(depth > 0)
    out_of_view = (off_axis > MAX_EYE_OFF_AXIS) | (elevation > MAX_EYE_ELEVATION)
    if behind.any():
        i, what = int(np.argmax(behind)), "is not in front of the camera (its depth along the optical axis is not positive)"
    elif len(eyes) and out_of_view.mean() > 0.5:
        i = int(np.argmax(out_of_view))
        what = (f"lies {math.degrees(off_axis[i]):.0f}° from the camera's optical axis and "
                f"{math.degrees(elevation[i]):.0f}° above or below it, out of any camera's view, as "
                f"{int(out_of_view.sum())} of the {len(eyes)} eyes do")
    else:
        return None
    shown = eyes[i] if axes == "ours" else eyes[i] @ R_OURS_FROM_OPENCV
    expected, swap = _EYE_AXES[axes]
    return i, (f"the eye centre ({', '.join(f'{v:.3g}' for v in shown)}) {what}: eye positions are taken in "
               f"{expected}; {swap}")


def with_bandwidth(recording: RayRecording, bandwidth: float) -> RayRecording:
    """``recording`` with every ray's bandwidth ``h`` set to ``bandwidth`` (radians; padding too)."""
    rays = recording.rays
    h = np.full_like(np.asarray(rays.bandwidth), float(bandwidth))
    return recording._replace(rays=GazeRays(rays.origins, rays.directions, h, rays.mask))


def _poses_of_frames(camera: CameraPoses, frames: np.ndarray, path) -> tuple[np.ndarray, np.ndarray]:
    """``R_world_from_camera (M, 3, 3)`` and ``centers (M, 3)`` for each row's frame: one pose serves
    every frame; several are matched by frame id (a frame without a pose is an error naming it)."""
    camera = as_camera_poses(camera, "camera")
    R = camera.R_world_from_camera
    if camera.num_frames == 1:
        return np.broadcast_to(R[0], (len(frames), 3, 3)), np.broadcast_to(camera.centers[0], (len(frames), 3))
    index = np.searchsorted(camera.frame_ids, frames)
    index = np.clip(index, 0, camera.num_frames - 1)
    missing = camera.frame_ids[index] != frames
    if missing.any():
        raise InputFileError(f"no camera pose for frame {int(frames[np.argmax(missing)])} "
                             f"({int(missing.sum())} rows without one)", "<arrays>" if path is None else path)
    return R[index], camera.centers[index]


def camera_rays_to_world(frames, eyes_camera, directions_camera, camera: Optional[CameraPoses] = None, *, path=None):
    """Eye centres and gaze directions in our camera frame → world frame, row by row.

    ``x_world = R_world_from_camera @ x_camera + center`` and ``v_world = R_world_from_camera @ v_camera``,
    with the pose of each row's frame (``camera=None``: the world is the camera frame).
    """
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    eyes = np.asarray(eyes_camera, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions_camera, dtype=np.float64).reshape(-1, 3)
    if camera is None:
        return eyes, directions
    R, centers = _poses_of_frames(camera, frames, path)
    return np.einsum("mij,mj->mi", R, eyes) + centers, np.einsum("mij,mj->mi", R, directions)


def world_rays_to_camera(frames, eyes_world, directions_world, camera: Optional[CameraPoses] = None, *, path=None):
    """The inverse of :func:`camera_rays_to_world` (the writers of the round trips use it)."""
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    eyes = np.asarray(eyes_world, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions_world, dtype=np.float64).reshape(-1, 3)
    if camera is None:
        return eyes, directions
    R, centers = _poses_of_frames(camera, frames, path)
    return np.einsum("mji,mj->mi", R, eyes - centers), np.einsum("mji,mj->mi", R, directions)


def rays_from_camera(frames: Sequence[int], persons: Sequence[str], eyes_camera, directions_camera, bandwidth, *,
                     camera: Optional[CameraPoses] = None, path=None) -> RayRecording:
    """Rows of (frame, person, eye centre, gaze direction, bandwidth) in our camera frame → a world
    :class:`RayRecording` (:func:`camera_rays_to_world`, then :func:`~jaxgaze.io.rays.stack_rays`)."""
    path = "<arrays>" if path is None else path
    origins, directions = camera_rays_to_world(frames, eyes_camera, directions_camera, camera, path=path)
    return stack_rays(list(frames), list(persons), origins, directions, bandwidth, path=path)


def check_camera_distances(recording) -> None:
    """A :class:`~jaxgaze.rays.UnitWarning` when an eye of a camera-frame recording lies more than 100 m from
    the camera (millimetres?): with one face per frame, the spread rule of ``check_units`` cannot see it.
    The message names the frame by its row, as ``check_units`` does."""
    distance = np.linalg.norm(recording.world_origins(), axis=-1)
    check_distance(np.where(recording.rays.mask, distance, 0.0).max(axis=1),
                   "an eye's distance from the camera", np.arange(len(recording.frame_ids)))
