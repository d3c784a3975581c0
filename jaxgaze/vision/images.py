"""Checking and converting images, shared by everything in :mod:`jaxgaze.vision`.

Conventions (``docs/conventions.md``): images are NumPy arrays in the *image*
frame, ``(H, W)`` grey or ``(H, W, 3)`` colour in **RGB** order (as scikit-image
and matplotlib give them; OpenCV's ``imread`` gives BGR, convert with
``cv2.cvtColor(..., cv2.COLOR_BGR2RGB)``). Pixel ``(row, col)`` = ``(y, x)``;
``x`` grows to the right and ``y`` downwards; as in ``docs/conventions.md``
the origin is the top-left pixel's outer corner, so pixel ``(i, j)`` covers
``[j, j+1] × [i, i+1]`` and its centre is ``(j + ½, i + ½)``. ``uint8`` images hold 0…255, floating images 0…1.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_image", "iterate_frames", "rotation_about", "to_float", "to_gray_float", "to_gray_uint8", "to_rgb_float", "warp_affine"]

_ALLOWED_DTYPES = (np.uint8, np.float32, np.float64)


def check_image(image, name: str = "image", *, min_size: int = 1) -> np.ndarray:
    """Return ``image`` as a NumPy array after checking it is a usable picture.

    Raises ``TypeError`` for a dtype other than uint8/float32/float64 (bool, int16,
    ...), ``ValueError`` for the wrong number of dimensions or channels, an empty
    image, a side shorter than ``min_size``, NaN/inf, or float values outside
    ``[0, 1]``. Every message names ``name``.
    """
    if image is None:
        raise TypeError(f"{name} is None (an unreadable file? cv2.imread returns None)")
    array = np.asarray(image)
    if array.dtype == object:
        raise TypeError(f"{name} must be a numeric array, got dtype object")
    if array.dtype not in _ALLOWED_DTYPES:
        raise TypeError(f"{name} must have dtype uint8 (0..255) or float32/float64 (0..1), got {array.dtype}")
    if array.ndim == 3 and array.shape[-1] == 1:
        array = array[..., 0]
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[-1] != 3):
        raise ValueError(f"{name} must have shape (H, W) or (H, W, 3), got {array.shape}")
    if array.size == 0:
        raise ValueError(f"{name} is empty: shape {array.shape}")
    if min(array.shape[:2]) < min_size:
        raise ValueError(f"{name} is {array.shape[1]}x{array.shape[0]} px; need at least {min_size} px on each side")
    if array.dtype != np.uint8:
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} contains NaN or inf")
        lo, hi = float(array.min()), float(array.max())
        if lo < 0.0 or hi > 1.0:
            raise ValueError(f"{name} is floating with values in [{lo:g}, {hi:g}]; expected [0, 1] (or pass uint8)")
    return array


def to_float(image, name: str = "image", *, min_size: int = 1) -> np.ndarray:
    """``image`` checked and scaled to float32 in ``[0, 1]``, channels kept."""
    array = check_image(image, name, min_size=min_size)
    if array.dtype == np.uint8:
        return array.astype(np.float32) / 255.0
    return array.astype(np.float32)


def to_rgb_float(image, name: str = "image", *, min_size: int = 1) -> np.ndarray:
    """``(H, W, 3)`` float32 RGB in ``[0, 1]``; a grey image is repeated on three channels."""
    array = to_float(image, name, min_size=min_size)
    if array.ndim == 2:
        array = np.repeat(array[..., None], 3, axis=-1)
    return array


def to_gray_float(image, name: str = "image", *, min_size: int = 1) -> np.ndarray:
    """``(H, W)`` float32 luminance in ``[0, 1]`` (ITU-R 601 weights, as OpenCV's RGB2GRAY)."""
    array = to_float(image, name, min_size=min_size)
    if array.ndim == 3:
        array = array @ np.asarray([0.299, 0.587, 0.114], dtype=np.float32)
    return array


def to_gray_uint8(image, name: str = "image", *, min_size: int = 1) -> np.ndarray:
    """``(H, W)`` uint8 luminance, what OpenCV's detectors take."""
    array = check_image(image, name, min_size=min_size)
    if array.dtype == np.uint8:
        if array.ndim == 3:
            import cv2

            return cv2.cvtColor(np.ascontiguousarray(array), cv2.COLOR_RGB2GRAY)
        return array
    return np.clip(np.rint(to_gray_float(array, name) * 255.0), 0, 255).astype(np.uint8)


def warp_affine(image: np.ndarray, affine, size: tuple[int, int]) -> np.ndarray:
    """``cv2.warpAffine`` for a 2×3 map ``affine`` from ``image``'s coordinates to the
    output's, both in our frame (pixel centres at ``+½``); output ``size = (width, height)``,
    bilinear, border replicated.

    OpenCV puts pixel centres at integers, so ``q = A p + b`` in our coordinates is
    ``A p' + (b + A·(½, ½) − ½)`` in OpenCV's; without that shift a warp and its
    mirror image disagree by half a pixel.
    """
    import cv2

    M = np.asarray(affine, float)
    if M.shape != (2, 3) or not np.all(np.isfinite(M)):
        raise ValueError(f"affine must be a finite 2x3 matrix, got shape {M.shape}")
    shifted = np.hstack([M[:, :2], (M[:, 2] + M[:, :2] @ [0.5, 0.5] - 0.5)[:, None]])
    return cv2.warpAffine(image, shifted, (int(size[0]), int(size[1])), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def rotation_about(centre, angle: float, new_centre=None) -> tuple[np.ndarray, np.ndarray]:
    """2×3 maps ``(forward, backward)``: ``forward`` turns the image by ``−angle``
    (radians, measured from +x towards +y) about ``centre`` and moves ``centre`` to
    ``new_centre`` (default: it stays); ``backward`` undoes it. A feature turned by
    ``+angle`` in the image stands upright after ``forward``."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, s], [-s, c]])
    centre = np.asarray(centre, float)
    new_centre = centre if new_centre is None else np.asarray(new_centre, float)
    forward = np.hstack([R, (new_centre - R @ centre)[:, None]])
    backward = np.hstack([R.T, (centre - R.T @ new_centre)[:, None]])
    return forward, backward


def iterate_frames(frames):
    """An iterator over a video's frames: a sequence or iterable of images, or one ``(T, H, W[, 3])`` array.

    Raises ``TypeError`` for ``None`` or a non-iterable, ``ValueError`` for a single image.
    """
    if frames is None:
        raise TypeError("frames must be a sequence of images, got None")
    if isinstance(frames, np.ndarray):
        if frames.ndim < 3 or (frames.ndim == 3 and frames.shape[-1] == 3 and frames.shape[0] > 3):
            raise ValueError(
                f"frames must be a sequence of images (T, H, W) or (T, H, W, 3); got one array of shape {frames.shape}"
            )
    try:
        return iter(frames)
    except TypeError:
        raise TypeError(f"frames must be a sequence or iterable of images, got {type(frames).__name__}") from None
