"""Face and eye detection with OpenCV's Viola–Jones Haar cascades.

Yücel et al. (T-CYB 2013, Sec. IV) start their cylindrical head tracker from the
face region found by the Viola–Jones detector (AdaBoost over Haar-like features,
Viola & Jones, CVPR 2001) on a frontal view of the experimenter, and report that it
still finds the face in low-resolution robot images (their Fig. 6). This module runs
the cascades that ship with OpenCV (``cv2.data.haarcascades``):

- frontal faces: ``haarcascade_frontalface_alt2.xml`` (it found more of
  ``skimage.data.lfw_subset``'s faces than ``..._default.xml``);
- profiles: ``haarcascade_profileface.xml``, which only finds faces turned towards
  the image's left (checked on ``lfw_subset``), so it is also run on the mirrored
  image for faces turned to the right;
- eyes: ``haarcascade_eye.xml`` inside the upper part of a face box.

Small images (such as 25 × 25 crops) are upsampled so their short side is at least
``100`` px and every image is padded by replicating its border, so that a face that
fills the picture still fits inside the detector's window; boxes are mapped back to
the original pixels. Boxes follow ``docs/conventions.md``'s image frame: ``x`` right,
``y`` down, in pixels from the top-left corner; a box covers
``image[y:y + height, x:x + width]`` like OpenCV's ``Rect`` (after rescaling the
numbers are floats).
"""

from __future__ import annotations

import math
import numbers
import os
from typing import NamedTuple

import numpy as np

from jaxgaze.vision.images import rotation_about, to_gray_uint8, warp_affine

__all__ = ["EyeBox", "FaceBox", "detect_eyes", "detect_faces", "haar_cascade"]

FACE_KINDS = ("frontal", "profile_left", "profile_right")

_CASCADE_FILES = {
    "frontal": "haarcascade_frontalface_alt2.xml",
    "profile": "haarcascade_profileface.xml",
    "eye": "haarcascade_eye.xml",
    # facial-feature cascades (jaxgaze.facial.image_features)
    "eye_glasses": "haarcascade_eye_tree_eyeglasses.xml",
    "lefteye_2splits": "haarcascade_lefteye_2splits.xml",
    "righteye_2splits": "haarcascade_righteye_2splits.xml",
    "smile": "haarcascade_smile.xml",
}
_CASCADES: dict = {}  # name -> cv2.CascadeClassifier, loaded once

_MIN_SHORT_SIDE_PX = 100  # automatic upsampling target for small images
_PAD_FRACTION = 0.25  # border replicated on each side, as a fraction of the short side ...
_PAD_MAX_PX = 50  # ... but at most this many (resized) pixels, to keep large frames fast
_MIN_NEIGHBORS = 5  # raw windows needed to keep a box (3, OpenCV's default, let a false face through)
_SCALE_FACTOR = 1.1
_EYE_MIN_NEIGHBORS = 3  # eyes are small and similar: 5 loses many on 25 px faces
_EYE_FACE_WIDTH_PX = 200  # faces are resized to about this width before looking for eyes
_NMS_IOU = 0.3  # boxes overlapping more than this (intersection over union) ...
_NMS_COVER = 0.6  # ... or covering more than this of the smaller box are duplicates


class FaceBox(NamedTuple):
    """A detected face: the box in pixels of the input image and what found it.

    ``x, y`` is the top-left corner and ``width, height`` the size (image frame:
    ``x`` right, ``y`` down, origin at the top-left corner of the image). ``kind`` is
    ``"frontal"``, ``"profile_left"`` (face turned towards the image's left, nose
    pointing to −x) or ``"profile_right"`` (towards +x). ``score`` is the cascade's
    neighbour count: how many raw detection windows (over positions and scales)
    OpenCV merged into this box; more is more confident (at least 5).

    ``rotation`` (radians) is non-zero for a face found in a rotated copy of the image
    (``detect_faces(..., rotations_deg=...)``): the face's box is the axis-aligned box
    ``x, y, width, height`` turned about its centre by ``rotation``, measured from the
    image's +x axis towards +y (clockwise on screen, as ``y`` points down). The face
    is upright in the image turned the other way about that centre.
    """

    x: float
    y: float
    width: float
    height: float
    kind: str
    score: float
    rotation: float = 0.0  # radians; the box turned by this about its centre (see above)

    @property
    def centre(self) -> tuple[float, float]:
        return (self.x + 0.5 * self.width, self.y + 0.5 * self.height)


class EyeBox(NamedTuple):
    """A detected eye, in pixels of the full image (same frame as :class:`FaceBox`).

    ``score`` is the neighbour count of ``haarcascade_eye.xml``. Eyes are returned
    from the image's left to its right; for an unmirrored camera facing the person,
    the first is the person's right eye.
    """

    x: float
    y: float
    width: float
    height: float
    score: float


def _haarcascade_dir() -> str:
    import cv2

    data = getattr(cv2, "data", None)
    return getattr(data, "haarcascades", "") if data is not None else ""


def haar_cascade(name: str):
    """OpenCV's Haar cascade ``name`` (``"frontal"``, ``"profile"``, ``"eye"`` or a facial-feature one
    such as ``"mouth"``: a key of ``_CASCADE_FILES``), loaded once per process."""
    if name not in _CASCADES:
        import cv2

        directory = _haarcascade_dir()
        path = os.path.join(directory, _CASCADE_FILES[name])
        if not directory or not os.path.isfile(path):
            raise FileNotFoundError(
                f"OpenCV's Haar cascade {_CASCADE_FILES[name]!r} was not found "
                f"(looked in cv2.data.haarcascades = {directory!r}); "
                "install it with `pip install 'opencv-python-headless<5'`"
            )
        classifier = cv2.CascadeClassifier(path)
        if classifier.empty():
            raise RuntimeError(f"OpenCV could not load the Haar cascade {path!r}")
        _CASCADES[name] = classifier
    return _CASCADES[name]


def _prepare(gray: np.ndarray, upsample: float | None) -> tuple[np.ndarray, float, float, int]:
    """Resize and pad ``gray``; return it with the x/y scales and the pad in new pixels."""
    import cv2

    h, w = gray.shape
    if upsample is None:
        upsample = max(1.0, _MIN_SHORT_SIDE_PX / min(h, w))
    elif not (isinstance(upsample, numbers.Real) and math.isfinite(upsample) and upsample > 0):
        raise ValueError(f"upsample must be a positive number or None, got {upsample!r}")
    new_w, new_h = max(1, round(w * upsample)), max(1, round(h * upsample))
    if (new_w, new_h) != (w, h):
        interpolation = cv2.INTER_CUBIC if upsample > 1 else cv2.INTER_AREA
        gray = cv2.resize(gray, (new_w, new_h), interpolation=interpolation)
    pad = min(round(_PAD_FRACTION * min(new_h, new_w)), _PAD_MAX_PX)
    if pad:
        gray = cv2.copyMakeBorder(gray, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    return gray, new_w / w, new_h / h, pad


def _run(classifier, gray: np.ndarray, min_size: int, mirrored: bool = False):
    """Boxes ``(x, y, w, h, neighbours)`` of ``classifier`` on ``gray`` (or its mirror)."""
    source = np.ascontiguousarray(gray[:, ::-1]) if mirrored else gray
    rects, neighbours = classifier.detectMultiScale2(
        source, scaleFactor=_SCALE_FACTOR, minNeighbors=_MIN_NEIGHBORS, minSize=(min_size, min_size)
    )
    out = []
    for (x, y, w, h), n in zip(np.reshape(rects, (-1, 4)), np.ravel(neighbours)):
        if mirrored:
            x = gray.shape[1] - x - w
        out.append((float(x), float(y), float(w), float(h), float(n)))
    return out


def _overlaps(a, b) -> tuple[float, float]:
    """Intersection over union, and intersection over the smaller area, of two boxes."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    area_a, area_b = a[2] * a[3], b[2] * b[3]
    union = area_a + area_b - inter
    smaller = min(area_a, area_b)
    return (inter / union if union > 0 else 0.0), (inter / smaller if smaller > 0 else 0.0)


def _nms(boxes: list, iou: float = _NMS_IOU, cover: float = _NMS_COVER) -> list:
    """Greedy non-maximum suppression; ``boxes`` must already be sorted best first.

    A box is dropped when it overlaps a kept one by IoU > ``iou`` or when the kept
    box covers more than ``cover`` of it (or it covers that much of the kept box):
    a profile box inside a frontal one is the same face.
    """
    kept = []
    for box in boxes:
        if all(o[0] <= iou and o[1] <= cover for o in (_overlaps(box, k) for k in kept)):
            kept.append(box)
    return kept


def _parse_kinds(kinds) -> tuple[str, ...]:
    if isinstance(kinds, str):
        kinds = (kinds,)
    wanted = []
    for kind in kinds:
        expanded = ("profile_left", "profile_right") if kind == "profile" else (kind,)
        for k in expanded:
            if k not in FACE_KINDS:
                raise ValueError(
                    f"unknown face kind {kind!r}; use 'frontal', 'profile', 'profile_left' or 'profile_right'"
                )
            if k not in wanted:
                wanted.append(k)
    if not wanted:
        raise ValueError("kinds is empty; use e.g. ('frontal', 'profile')")
    return tuple(wanted)


def detect_faces(
    image,
    *,
    kinds=("frontal", "profile"),
    min_size_px: float = 12,
    upsample: float | None = None,
    rotations_deg=(0.0,),
) -> list[FaceBox]:
    """Faces in ``image`` found by OpenCV's Viola–Jones Haar cascades, best first (Viola & Jones 2001).

    ``image``: RGB ``(H, W, 3)`` or grey ``(H, W)``, uint8 0…255 or float 0…1 (checked
    by :func:`jaxgaze.vision.images.check_image`). ``kinds``: any of ``"frontal"``,
    ``"profile"`` (both sides), ``"profile_left"``, ``"profile_right"``.
    ``min_size_px``: the smallest face side, in pixels of ``image``, to report.
    ``upsample``: resize factor before detection; ``None`` enlarges images whose short
    side is under 100 px to 100 px and leaves larger ones alone. A face is only found
    if it is at least the cascade's window (20 px) after resizing, so pass e.g.
    ``upsample=2`` for faces under 20 px in a large frame. The image is also padded by
    replicating its border (a quarter of the short side, at most 50 resized px), so
    faces that fill the picture or touch its edge are found.

    Duplicates between cascades (and between the two profile sides) are merged by
    greedy non-maximum suppression (IoU > 0.3, or > 60 % of the smaller box covered).
    The profile cascade is about four times slower than the frontal one: pass
    ``kinds=("frontal",)`` when speed matters (the paper starts from a frontal face).

    ``rotations_deg``: in-plane angles to search. The cascades only find faces within
    about ±10° of upright; e.g. ``(0, -15, 15)`` also runs them on the image turned
    by ∓15° about its centre (on a canvas large enough to keep every pixel), and a face
    found there gets ``rotation = ±15°`` (in radians). Boxes from different angles are
    merged by the same suppression, on their unrotated boxes; upright wins ties.

    Returns a list of :class:`FaceBox` sorted by ``score`` (neighbour count)
    descending, frontal before profile on ties; ``[]`` when there is no face,
    including for a blank image.
    """
    wanted = _parse_kinds(kinds)
    gray = to_gray_uint8(image, "image")
    if not (isinstance(min_size_px, numbers.Real) and math.isfinite(min_size_px) and min_size_px >= 0):
        raise ValueError(f"min_size_px must be a non-negative number, got {min_size_px!r}")
    angles = _parse_rotations(rotations_deg)
    found = []  # (x, y, w, h, score, kind, rotation) in the input image's pixels
    for angle in angles:
        rotated, to_image = _rotated(gray, angle)
        big, sx, sy, pad = _prepare(rotated, upsample)
        min_size = max(1, math.ceil(min_size_px * min(sx, sy)))
        boxes = []
        if "frontal" in wanted:
            boxes += [(*b, "frontal") for b in _run(haar_cascade("frontal"), big, min_size)]
        if "profile_left" in wanted:
            boxes += [(*b, "profile_left") for b in _run(haar_cascade("profile"), big, min_size)]
        if "profile_right" in wanted:
            boxes += [(*b, "profile_right") for b in _run(haar_cascade("profile"), big, min_size, mirrored=True)]
        for x, y, w, h, score, kind in boxes:
            x, y, w, h = (x - pad) / sx, (y - pad) / sy, w / sx, h / sy
            cx, cy = to_image @ (x + 0.5 * w, y + 0.5 * h, 1.0)
            found.append((cx - 0.5 * w, cy - 0.5 * h, w, h, score, kind, math.radians(angle)))
    found.sort(key=lambda b: (-b[4], abs(b[6]), FACE_KINDS.index(b[5]), b[1], b[0]))
    return [FaceBox(x, y, w, h, kind, score, rotation) for x, y, w, h, score, kind, rotation in _nms(found)]


def _parse_rotations(rotations_deg) -> tuple[float, ...]:
    try:
        angles = tuple(float(a) for a in np.atleast_1d(np.asarray(rotations_deg, float)))
    except (TypeError, ValueError):
        raise ValueError(f"rotations_deg must be a sequence of angles in degrees, got {rotations_deg!r}") from None
    if not angles or not all(math.isfinite(a) and -90.0 <= a <= 90.0 for a in angles):
        raise ValueError(f"rotations_deg must be a non-empty sequence of finite angles in [-90, 90], got {rotations_deg!r}")
    return tuple(dict.fromkeys(angles))


def _rotated(gray: np.ndarray, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """``gray`` turned by ``-angle_deg`` (so a face turned by ``+angle_deg`` stands upright)
    on a canvas that keeps every pixel, and the 2×3 map from its coordinates back to ``gray``'s."""
    if angle_deg == 0.0:
        return gray, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    h, w = gray.shape
    t = math.radians(angle_deg)
    new_w = math.ceil(w * abs(math.cos(t)) + h * abs(math.sin(t)))
    new_h = math.ceil(w * abs(math.sin(t)) + h * abs(math.cos(t)))
    forward, backward = rotation_about((w / 2, h / 2), t, (new_w / 2, new_h / 2))
    return warp_affine(gray, forward, (new_w, new_h)), backward


def detect_eyes(image, face: FaceBox, *, upsample: float | None = None) -> list[EyeBox]:
    """Eyes inside ``face`` (a :class:`FaceBox` of ``image``), at most two, left to right (Viola & Jones 2001).

    Runs ``haarcascade_eye.xml`` (Viola–Jones) on the upper part of the face box
    (from 15 % to 65 % of its height), resized so the face is about 200 px wide
    (or by ``upsample``), keeps eyes of 1/8 to 1/2 of the face width, merges
    overlapping boxes and returns the two best in full-image pixels, sorted by ``x``.
    ``[]`` when none is found.
    """
    import cv2

    gray = to_gray_uint8(image, "image")
    fx, fy, fw, fh = (float(v) for v in face[:4])
    if not (fw > 0 and fh > 0 and all(math.isfinite(v) for v in (fx, fy, fw, fh))):
        raise ValueError(f"face must have a positive finite width and height, got {face!r}")
    h, w = gray.shape
    x0, x1 = max(0, math.floor(fx)), min(w, math.ceil(fx + fw))
    y0, y1 = max(0, math.floor(fy + 0.15 * fh)), min(h, math.ceil(fy + 0.65 * fh))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return []
    scale = upsample if upsample is not None else max(1.0, _EYE_FACE_WIDTH_PX / fw)
    if not (isinstance(scale, numbers.Real) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"upsample must be a positive number or None, got {upsample!r}")
    region = gray[y0:y1, x0:x1]
    new_w, new_h = max(1, round(region.shape[1] * scale)), max(1, round(region.shape[0] * scale))
    if (new_w, new_h) != region.shape[::-1]:
        region = cv2.resize(region, (new_w, new_h), interpolation=cv2.INTER_CUBIC if scale > 1 else cv2.INTER_AREA)
    sx, sy = new_w / (x1 - x0), new_h / (y1 - y0)
    min_size = max(1, round(fw * sx / 8))
    max_size = max(min_size, round(fw * sx / 2))
    rects, neighbours = haar_cascade("eye").detectMultiScale2(
        region, scaleFactor=_SCALE_FACTOR, minNeighbors=_EYE_MIN_NEIGHBORS,
        minSize=(min_size, min_size), maxSize=(max_size, max_size),
    )
    found = [
        (float(x), float(y), float(bw), float(bh), float(n))
        for (x, y, bw, bh), n in zip(np.reshape(rects, (-1, 4)), np.ravel(neighbours))
    ]
    found.sort(key=lambda b: -b[4])
    eyes = [EyeBox(x0 + x / sx, y0 + y / sy, bw / sx, bh / sy, n) for x, y, bw, bh, n in _nms(found, 0.1, 0.3)[:2]]
    return sorted(eyes, key=lambda e: e.x)
