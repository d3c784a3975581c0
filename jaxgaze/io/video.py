"""Reading and writing videos and frame folders (RGB ``uint8``, see ``docs/conventions.md``).

* :func:`read_frames` / :func:`iter_frames` read **RGB** ``uint8`` frames
  ``(H, W, 3)`` (``docs/conventions.md``; not OpenCV's BGR) from a video file
  (anything ``cv2.VideoCapture`` opens) or from a folder of images (``.png``,
  ``.jpg``, ``.jpeg``, ``.bmp``, ``.tif``, ``.tiff``) taken in *natural* order
  (``frame2.png`` before ``frame10.png``); :func:`video_fps` gives the frame rate
  a video file declares.
* :func:`write_video` writes frames atomically (a temporary file next to the
  target, renamed on success): ``.mp4`` with the ``mp4v`` codec, ``.avi`` with
  ``MJPG`` (both lossy: a few grey levels off), ``.mkv`` with ``FFV1``
  (lossless); :func:`write_frames` writes a video or, for a path without an
  extension, a folder of PNG images (atomically too), and
  :func:`check_frames_output` checks such a path before any work.

FFmpeg's own log lines (e.g. ``moov atom not found`` for a corrupt ``.mp4``) are
silenced: importing this module sets ``OPENCV_FFMPEG_LOGLEVEL=-8`` (quiet) unless it is
already set, since OpenCV reads it when it first uses FFmpeg. A file that cannot be
read raises :class:`VideoFileError` instead.

Errors in the input are :class:`VideoFileError` (a ``ValueError`` whose message
starts with ``path:``), naming the file: a missing path, a file OpenCV cannot
open, a video or folder without frames, an unreadable image, images of
differing sizes.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from collections.abc import Iterator

os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # before OpenCV first opens FFmpeg (see the docstring)

import cv2  # noqa: E402
import numpy as np

from jaxgaze.io.text import InputFileError, atomic_path, replace_with_the_others
from jaxgaze.vision.images import check_image

__all__ = [
    "IMAGE_EXTENSIONS",
    "VIDEO_CODECS",
    "VideoFileError",
    "VideoFrames",
    "check_frames_output",
    "frame_count",
    "iter_frames",
    "read_frames",
    "video_fps",
    "write_frames",
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


class VideoFrames:
    """The frames of a video or frame folder, read again each time it is iterated (so a long
    video is never held in memory); ``len()`` is ``count`` when it is known."""

    def __init__(self, path, *, max_frames: int | None = None, count: int | None = None):
        self.path, self.max_frames, self.count = path, max_frames, count

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter_frames(self.path, max_frames=self.max_frames)

    def __len__(self) -> int:
        if self.count is None:
            raise TypeError("VideoFrames: the number of frames is not known")
        return self.count


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


def check_frames_output(path) -> None:
    """Check, before any work, that :func:`write_frames` can write ``path``: a video extension
    (:data:`VIDEO_CODECS`) or none (a folder of PNG images that does not exist or is empty), in an
    existing directory. Raises ``ValueError`` naming what is wrong."""
    path = os.fspath(path)
    ext = os.path.splitext(path.rstrip(os.sep))[1].lower()
    if ext and ext not in VIDEO_CODECS:
        raise ValueError(f"cannot write frames to {path}: {ext!r} is not a video extension ("
                         + ", ".join(VIDEO_CODECS) + "), and a folder of PNG images has no extension")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise ValueError(f"cannot write frames to {path}: directory {directory} does not exist")
    if not ext and os.path.exists(path) and not (os.path.isdir(path) and not os.listdir(path)):
        raise ValueError(f"cannot write frames to {path}: it exists and is not an empty folder")


def write_frames(path, frames, fps: float) -> int:
    """Write ``frames`` (as :func:`write_video`) to a video file, or to a folder of PNG images
    ``frame_000000.png``, ``frame_000001.png``, ... for a path without an extension; returns
    the number written. ``fps`` is the video's frame rate (unused for a folder).

    Atomic: the frames go to a temporary file or folder next to ``path``, renamed onto it
    only when all are written (a folder replaces only an empty folder). Raises as
    :func:`check_frames_output` and :func:`write_video`.
    """
    check_frames_output(path)
    path = os.fspath(path).rstrip(os.sep) or os.sep
    if os.path.splitext(path)[1]:
        return write_video(path, frames, fps)
    target = os.path.abspath(path)
    tmp = tempfile.mkdtemp(dir=os.path.dirname(target), prefix=f".{os.path.basename(target)}.", suffix=".tmp")
    try:
        count, size = 0, None
        for index, frame in enumerate(frames):
            image = check_image(frame, f"frames[{index}]")
            if image.dtype != np.uint8:
                image = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
            if size is None:
                size = image.shape[:2]
            elif image.shape[:2] != size:
                raise ValueError(f"frames[{index}] is {image.shape[1]}x{image.shape[0]} px but frames[0] is "
                                 f"{size[1]}x{size[0]} px")
            bgr = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            file = os.path.join(tmp, f"frame_{index:06d}.png")
            if not cv2.imwrite(file, bgr):
                raise OSError(f"cannot write {file}")
            count += 1
        if count == 0:
            raise ValueError(f"cannot write frames to {path}: no frames")
        if not replace_with_the_others(tmp, path):  # with the command's other outputs, else now
            if os.path.isdir(target):
                os.rmdir(target)  # empty (checked above); os.replace needs it gone on some systems
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return count
