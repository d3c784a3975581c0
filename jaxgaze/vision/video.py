"""Reading and writing videos, and rendering a simulated table-top session as a video.

* :func:`read_frames` / :func:`iter_frames` read **RGB** ``uint8`` frames
  ``(H, W, 3)`` (``docs/conventions.md``; not OpenCV's BGR) from a video file
  (anything ``cv2.VideoCapture`` opens) or from a folder of images (``.png``,
  ``.jpg``, ``.jpeg``, ``.bmp``, ``.tif``, ``.tiff``) taken in *natural* order
  (``frame2.png`` before ``frame10.png``); :func:`video_fps` gives the frame rate
  a video file declares.
* :func:`write_video` writes frames atomically (a temporary file next to the
  target, renamed on success): ``.mp4`` with the ``mp4v`` codec, ``.avi`` with
  ``MJPG`` (both lossy: a few grey levels off), ``.mkv`` with ``FFV1``
  (lossless).
* :func:`render_tabletop_video` renders a
  :class:`~jaxgaze.simulate_tabletop.TabletopSession`: the table-top scene of
  :func:`~jaxgaze.vision.render.render_tabletop_scene` with the textured
  cylinder head of :func:`~jaxgaze.vision.head_model.render_head` at the
  session's head position and pose in every frame, plus the ground truth, so
  that the whole attention pipeline runs on a synthetic video.

Errors in the input are :class:`VideoFileError` (a ``ValueError`` whose message
starts with ``path:``), naming the file: a missing path, a file OpenCV cannot
open, a video or folder without frames, an unreadable image, images of
differing sizes.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator
from typing import NamedTuple

import cv2
import numpy as np

from jaxgaze.textfiles import InputFileError, atomic_path
from jaxgaze.vision.images import check_image

__all__ = [
    "IMAGE_EXTENSIONS",
    "VIDEO_CODECS",
    "VideoFileError",
    "VideoTruth",
    "frame_count",
    "iter_frames",
    "read_frames",
    "render_tabletop_video",
    "video_fps",
    "write_video",
]

#: Image files a frame folder may hold (case-insensitive); other files are ignored.
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: The codec :func:`write_video` uses for each extension (all write and read back with this OpenCV).
VIDEO_CODECS = {".mp4": "mp4v", ".avi": "MJPG", ".mkv": "FFV1"}


class VideoFileError(InputFileError):
    """A video or frame folder that cannot be read. The message starts with ``path:``."""


# ---------------------------------------------------------------------------
# Reading


def _natural_key(name: str):
    """Sort key that orders the digit runs of ``name`` by value: ``f2.png`` < ``f10.png``."""
    return [(0, int(part), part) if part.isdigit() else (1, 0, part.lower())
            for part in re.split(r"(\d+)", name) if part] + [(2, 0, name)]


def _folder_images(path: str) -> list[str]:
    try:
        names = os.listdir(path)
    except OSError as error:
        raise VideoFileError(f"cannot list the frame folder: {error.strerror or error}", path) from None
    files = [n for n in names if os.path.splitext(n)[1].lower() in IMAGE_EXTENSIONS
             and os.path.isfile(os.path.join(path, n))]
    if not files:
        raise VideoFileError("the folder holds no frames (no " + ", ".join(IMAGE_EXTENSIONS) + " files)", path)
    return [os.path.join(path, n) for n in sorted(files, key=_natural_key)]


def _check_max_frames(max_frames) -> int | None:
    if max_frames is None:
        return None
    if isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer)) or max_frames < 1:
        raise ValueError(f"max_frames must be None or a positive integer, got {max_frames!r}")
    return int(max_frames)


def _open_capture(path: str):
    capture = cv2.VideoCapture(path)
    if not capture.isOpened():
        capture.release()
        raise VideoFileError("cannot open video: not a video OpenCV can read", path)
    return capture


def _check_path(path) -> str:
    path = os.fspath(path)
    if not os.path.exists(path):
        raise VideoFileError("no such video file or frame folder", path)
    return path


def iter_frames(path, *, max_frames: int | None = None) -> Iterator[np.ndarray]:
    """Frames of a video file or image folder, one ``(H, W, 3)`` RGB ``uint8`` array at a time.

    The path is checked (and a video opened) before this returns; the frames are
    read lazily. At most ``max_frames`` frames. Raises :class:`VideoFileError`
    (see the module docstring), while iterating too (an unreadable image, a size
    that differs from the first frame's, a video without frames).
    """
    path = _check_path(path)
    limit = _check_max_frames(max_frames)
    if os.path.isdir(path):
        return _iter_folder(path, _folder_images(path), limit)
    return _iter_video(path, _open_capture(path), limit)


def _iter_folder(folder: str, files: list[str], limit):
    shape = None
    first = None
    for count, file in enumerate(files):
        if limit is not None and count >= limit:
            return
        image = cv2.imread(file, cv2.IMREAD_COLOR)
        if image is None:
            raise VideoFileError("cannot read the image (not an image OpenCV can decode)", file)
        if shape is None:
            shape, first = image.shape, os.path.basename(file)
        elif image.shape != shape:
            raise VideoFileError(f"the image is {image.shape[1]}x{image.shape[0]} px but the folder's first frame "
                                 f"{first} is {shape[1]}x{shape[0]} px", file)
        yield cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _iter_video(path: str, capture, limit):
    count = 0
    try:
        while limit is None or count < limit:
            ok, image = capture.read()
            if not ok or image is None:
                break
            if image.ndim == 2:
                image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
            count += 1
            yield cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()
    if count == 0:
        raise VideoFileError("the video has no frames OpenCV can decode", path)


def read_frames(path, *, max_frames: int | None = None) -> list[np.ndarray]:
    """All frames (at most ``max_frames``) of a video file or image folder, as a list of
    ``(H, W, 3)`` RGB ``uint8`` arrays; see :func:`iter_frames`."""
    return list(iter_frames(path, max_frames=max_frames))


def frame_count(path) -> int | None:
    """Number of frames of a frame folder, or the count a video file declares (``None`` when it
    declares none; OpenCV's count can be off for some containers). Raises :class:`VideoFileError`."""
    path = _check_path(path)
    if os.path.isdir(path):
        return len(_folder_images(path))
    capture = _open_capture(path)
    try:
        count = float(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        capture.release()
    return int(count) if math.isfinite(count) and count > 0 else None


def video_fps(path) -> float | None:
    """Frames per second a video file declares, or ``None`` for a frame folder or a video
    that declares none (OpenCV reports 0). Raises :class:`VideoFileError` as :func:`iter_frames`."""
    path = _check_path(path)
    if os.path.isdir(path):
        _folder_images(path)
        return None
    capture = _open_capture(path)
    try:
        fps = float(capture.get(cv2.CAP_PROP_FPS))
    finally:
        capture.release()
    return fps if math.isfinite(fps) and fps > 0 else None


# ---------------------------------------------------------------------------
# Writing


def write_video(path, frames, fps: float) -> int:
    """Write ``frames`` (images ``(H, W, 3)`` RGB or ``(H, W)`` grey, uint8 or float in [0, 1],
    all the same size) to a video file at ``fps`` frames per second; returns the number written.

    The codec follows the extension (:data:`VIDEO_CODECS`: ``.mp4`` mp4v, ``.avi`` MJPG,
    ``.mkv`` FFV1 lossless). The file is written to a temporary file next to ``path`` and
    renamed onto it only when every frame is written, so a failure never leaves a
    partial video (an existing ``path`` is kept). Raises ``ValueError`` for an unknown
    extension, a bad ``fps``, no frames, bad or differently sized frames, and
    ``OSError`` when the file cannot be written.
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in VIDEO_CODECS:
        raise ValueError(f"cannot write video {path}: unknown extension {ext or '(none)'!r}; use one of "
                         + ", ".join(VIDEO_CODECS))
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) or not (
            math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive finite number, got {fps!r}")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise OSError(f"cannot write video {path}: directory {directory} does not exist")
    count = 0
    with atomic_path(path) as tmp:
        writer = None
        try:
            for index, frame in enumerate(frames):
                image = check_image(frame, f"frames[{index}]")
                if image.dtype != np.uint8:
                    image = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
                image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR if image.ndim == 2 else cv2.COLOR_RGB2BGR)
                if writer is None:
                    size = (image.shape[1], image.shape[0])
                    writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*VIDEO_CODECS[ext]), float(fps), size)
                    if not writer.isOpened():
                        raise OSError(f"cannot write video {path}: OpenCV has no {VIDEO_CODECS[ext]} encoder "
                                      f"for {ext} files")
                elif (image.shape[1], image.shape[0]) != size:
                    raise ValueError(f"frames[{index}] is {image.shape[1]}x{image.shape[0]} px but frames[0] is "
                                     f"{size[0]}x{size[1]} px")
                writer.write(np.ascontiguousarray(image))
                count += 1
        finally:
            if writer is not None:
                writer.release()
        if count == 0:
            raise ValueError(f"cannot write video {path}: no frames")
    return count


# ---------------------------------------------------------------------------
# A simulated session as a video


class VideoTruth(NamedTuple):
    """Ground truth of :func:`render_tabletop_video`, one row per frame (NumPy arrays).

    Pixel quantities are in the rendered (scaled) image: ``scale`` times those of the
    session (the image frame's origin is the top-left pixel corner, so scaling is exact).

    Attributes:
        head_pose: ``(T, 3)`` the rendered (pitch, yaw, roll), radians, relative to
            ``R_optical_from_frontal``.
        head_position_optical: ``(T, 3)`` the session's head position, the eye midpoint, optical
            frame, metres: the front of the rendered face at the cylinder's mid-height.
        head_centre_image: ``(T, 2)`` its projection, px (what the regression's ``f1`` starts from).
        cylinder_centre_optical: ``(T, 3)`` the rendered cylinder's centre (axis, mid-height),
            ``head.half_depth_m`` behind the eye midpoint along the facing direction.
        target: ``(T,)`` the attended object, or ``-1`` in the lead-in frames.
        gaze_direction_image: ``(T,)`` f1, radians (NaN in the lead-in).
        target_depth_image: ``(T,)`` f2, image row of the attended object's centre, px (NaN in the lead-in).
        object_centres_image: ``(K, 2)`` px.
        object_boxes_image: ``(K, 4)`` ``(x_min, y_min, x_max, y_max)`` px.
        object_labels: ``(H, W)`` int16 object seen at each pixel or ``-1`` (the scene without the head).
        head_masks: ``(T, H, W)`` bool, where the head was drawn.
        R_optical_from_frontal: ``(3, 3)`` the frontal frame the poses are relative to.
        focal_px: the focal length of the rendered images (``scale × session.focal_px``).
        image_size: ``(W, H)`` px.
        scale: the image scale relative to the simulator's 320 × 240.
        fps: the session's frame rate.
        lead_in: number of frames before the session's first (eye contact, then turning).
        session_frame: ``(T,)`` the session frame each video frame shows (``-1`` in the lead-in).
    """

    head_pose: np.ndarray
    head_position_optical: np.ndarray
    head_centre_image: np.ndarray
    cylinder_centre_optical: np.ndarray
    target: np.ndarray
    gaze_direction_image: np.ndarray
    target_depth_image: np.ndarray
    object_centres_image: np.ndarray
    object_boxes_image: np.ndarray
    object_labels: np.ndarray
    head_masks: np.ndarray
    R_optical_from_frontal: np.ndarray
    focal_px: float
    image_size: tuple[int, int]
    scale: int
    fps: float
    lead_in: int
    session_frame: np.ndarray


def render_tabletop_video(
    session,
    *,
    key,
    condition: str = "natural",
    scale: int = 2,
    pose: str = "true",
    lead_in: int = 10,
    num_frames: int | None = None,
    head=None,
) -> tuple[list[np.ndarray], VideoTruth]:
    """Render a simulated table-top session as video frames, with its ground truth.

    Every frame is the session's scene (:func:`~jaxgaze.vision.render.render_tabletop_scene`
    with ``key`` and ``condition``: the same background in every frame) with the textured
    cylinder head (:func:`~jaxgaze.vision.head_model.render_head`) in the session's pose
    (relative to its ``R_optical_from_frontal``) with the front of the face at mid-height on
    the session's ``head_position_optical`` (the eye midpoint; the cylinder's centre is
    ``head.half_depth_m`` behind it), which is the point
    :func:`jaxgaze.vision.attend.attend_frames` projects as the head centre. The cubes are
    nearer to the camera than the head, so their pixels stay in front of it. The ``condition``
    (colour cast, dimming and noise, motion blur) is applied to the scene, not to the head.

    **Scale.** At the simulator's 320 × 240 (``scale=1``) the head is about
    ``0.15 m · 316 px / 1.5 m ≈ 32 px`` wide, too small for
    :func:`~jaxgaze.vision.tracker.track_head`: on 6 s sessions (3 seeds, 16 lead-in frames)
    its rotation error was 3–11° (median per session). At ``scale=2`` (640 × 480, a head of
    about 60–64 px) it was 0.5–3° with 8 lead-in frames (max 3.7°), and the OpenCV face
    detector finds the face in the first frame; hence the defaults.

    Args:
        session: a :class:`~jaxgaze.simulate_tabletop.TabletopSession`.
        key: ``jax.random`` key of the scene's layout, clutter and condition.
        condition: one of :data:`jaxgaze.vision.render.CONDITIONS`.
        scale: integer 1 to 16; the images are ``320·scale × 240·scale`` px with focal
            length ``scale · session.focal_px`` (the scene is resized with ``cv2.INTER_CUBIC``,
            the head is ray-cast at full resolution); see above.
        pose: ``"true"`` renders ``head_pose_true``, ``"reported"`` the noisy ``head_pose``.
        lead_in: frames shown before the session's first: the head at the first frame's
            position in eye contact (looking at the camera), then turning smoothly (cosine
            ramp) to the first frame's pose over the remaining lead-in frames. The head
            tracker needs a frontal first frame; the session's own first frame looks at an
            object (without a lead-in the tracked pose is off by that first pose, ~20°).
        num_frames: render only the session's first ``num_frames`` frames (default all).
        head: a :class:`~jaxgaze.vision.head_model.CylinderHead` (default the standard one).

    Returns:
        ``(frames, truth)``: a list of ``(H, W, 3)`` RGB uint8 images and a :class:`VideoTruth`.
    """
    from jaxgaze.simulate_tabletop import IMAGE_HEIGHT, IMAGE_WIDTH, TabletopSession
    from jaxgaze.vision.head_model import (
        CylinderHead,
        frontal_rotation,
        pose_to_rotation,
        render_head,
        rotation_to_pose,
    )
    from jaxgaze.vision.render import render_tabletop_scene

    if not isinstance(session, TabletopSession):
        raise TypeError(f"session must be a TabletopSession, got {type(session).__name__}")
    if isinstance(scale, bool) or not isinstance(scale, (int, np.integer)) or not 1 <= scale <= 16:
        raise ValueError(f"scale must be an integer from 1 to 16, got {scale!r}")
    scale = int(scale)
    if pose not in ("true", "reported"):
        raise ValueError(f"pose must be 'true' or 'reported', got {pose!r}")
    if isinstance(lead_in, bool) or not isinstance(lead_in, (int, np.integer)) or lead_in < 0:
        raise ValueError(f"lead_in must be a non-negative integer, got {lead_in!r}")
    lead_in = int(lead_in)
    total = session.num_frames
    if num_frames is not None:
        if isinstance(num_frames, bool) or not isinstance(num_frames, (int, np.integer)) or num_frames < 1:
            raise ValueError(f"num_frames must be None or a positive integer, got {num_frames!r}")
        total = min(total, int(num_frames))
    head = CylinderHead() if head is None else head

    scene = render_tabletop_scene(session, key=key, condition=condition)
    width, height = IMAGE_WIDTH * scale, IMAGE_HEIGHT * scale
    background = scene.image
    labels = np.asarray(scene.object_labels)
    if scale != 1:
        background = cv2.resize(background, (width, height), interpolation=cv2.INTER_CUBIC)
        labels = cv2.resize(labels, (width, height), interpolation=cv2.INTER_NEAREST)
    focal = float(session.focal_px) * scale
    Rf = np.asarray(session.R_optical_from_frontal, dtype=np.float64)

    poses = np.asarray(session.head_pose_true if pose == "true" else session.head_pose, dtype=np.float64)[:total]
    eyes = np.asarray(session.head_position_optical, dtype=np.float64)[:total]
    if lead_in:
        # Eye contact at the first frame's position: pose 0 relative to the frontal frame there.
        eye_contact = np.asarray(rotation_to_pose(Rf.T @ frontal_rotation(eyes[0])), dtype=np.float64)
        ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(lead_in) / lead_in)  # 0 ... < 1
        poses = np.concatenate([eye_contact + ramp[:, None] * (poses[0] - eye_contact), poses])
        eyes = np.concatenate([np.repeat(eyes[:1], lead_in, axis=0), eyes])
    # The session's head position is the eye midpoint: the front of the face at mid-height, half a head
    # depth in front of the cylinder's centre along the facing direction.
    R_optical_from_head = Rf @ np.asarray(pose_to_rotation(poses), dtype=np.float64)
    centres = eyes - head.half_depth_m * R_optical_from_head[:, :, 0]

    in_front = labels >= 0
    frames, masks = [], []
    for p, t in zip(poses, centres):
        image, mask = render_head(p, head=head, focal_px=focal, image_size=(width, height), position_optical=t,
                                  background=background, R_optical_from_frontal=Rf)
        mask &= ~in_front
        image[in_front] = background[in_front]
        frames.append(image)
        masks.append(mask)

    nan = np.full(lead_in, np.nan)
    session_frame = np.concatenate([np.full(lead_in, -1), np.arange(total)])
    eyes_image = np.stack([focal * eyes[:, 0] / eyes[:, 2] + width / 2.0,
                           focal * eyes[:, 1] / eyes[:, 2] + height / 2.0], axis=-1)
    truth = VideoTruth(
        head_pose=poses,
        head_position_optical=eyes,
        head_centre_image=eyes_image,
        cylinder_centre_optical=centres,
        target=np.concatenate([np.full(lead_in, -1), np.asarray(session.target)[:total]]).astype(np.int64),
        gaze_direction_image=np.concatenate([nan, np.asarray(session.gaze_direction_image, np.float64)[:total]]),
        target_depth_image=np.concatenate([nan, scale * np.asarray(session.target_depth_image, np.float64)[:total]]),
        object_centres_image=scale * np.asarray(scene.object_centres, np.float64),
        object_boxes_image=scale * np.asarray(scene.object_boxes, np.float64),
        object_labels=labels.astype(np.int16),
        head_masks=np.stack(masks),
        R_optical_from_frontal=Rf,
        focal_px=focal,
        image_size=(width, height),
        scale=scale,
        fps=float(session.fps),
        lead_in=lead_in,
        session_frame=session_frame.astype(np.int64),
    )
    return frames, truth
