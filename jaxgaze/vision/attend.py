"""The attended object: regression estimates refined by saliency (Yücel et al. T-CYB 2013, Sec. VI–VII).

The gaze regressors of :mod:`jaxgaze.gp` give, per frame, the image angle ``f1`` of
the gaze line from the head centre and the image row ``f2`` of the target, with
predictive variances; :func:`~jaxgaze.headpose.target.target_point` turns them into a
target point. T-CYB pools 4 consecutive estimates (10 fps), puts a Gaussian mask
(σ = 10 px) around each, computes bottom-up saliency and lets a winner-take-all with
inhibition of return pick the attended location; the object there is segmented by
region growing. Here the choice is a **posterior over candidate locations**:

* **Target-point covariance** (:func:`target_point_covariance`, delta method): with
  ``p(f1, f2)`` the target point, ``Σ_t = var(f1) J₁J₁ᵀ + var(f2) J₂J₂ᵀ``, ``J_i = ∂p/∂f_i``
  (the derivatives of :func:`~jaxgaze.headpose.target.target_point`'s closed form, the same
  as JAX's forward mode; ``f1`` and ``f2`` are independent GPs). Where the ray misses the row (the point is the head
  centre) the Jacobian is 0; where it is capped at ``max_length`` only ``J₁`` is left.
  The NN baseline has no variances: ``Σ_t = 0``, and the posterior below is the
  paper's mask alone.
* **Candidates**: the winner-take-all fixations of the saliency map ``S`` times the
  mask ``max_p exp(−‖x − x_p‖² / 2σ²)`` around the window's ``P`` estimates ``x_p``
  (:func:`~jaxgaze.vision.saliency_maps.winner_take_all`, at most ``num_candidates``, no
  two within ``ior_radius_px``).
* **Weights**: ``w(c) ∝ S(c) · (1/P) Σ_p N(c; x_p, Σ_p + σ² I)``: the saliency as the
  evidence that an object is at ``c``, times the regression's predictive density of
  the target point, widened by the mask's σ (an object is not a point). Normalised
  over the candidates they are the probabilities; for one estimate this is
  ``S(c) · N(c; x̄, Σ + σ² I)``. Computed in log space.
* **Objects**: with known boxes (simulation), ``P(object k)`` is the sum over the
  candidates inside box ``k`` (closed box; a candidate inside several boxes goes to
  the box whose centre is nearest) and the rest is ``none_probability``.
* **Choice**: the top candidate; its region is
  :func:`~jaxgaze.vision.saliency_maps.salient_region` on the masked map ``S · mask``; its object is the box it is in.

Functions: :func:`attend_window` (one window) and :func:`attend_frames` (a video:
head tracking → regression → pooling → attention; the regression's ``f2`` rows are
scaled to the frames' size); :func:`draw_attention` and :func:`attention_overlay` draw
the result on the frames. The paper's Tables I–II on simulated sessions are in
:mod:`jaxgaze.papers.yucel2013_attention`.

Coordinates are image coordinates (``docs/conventions.md``): x right, y down, origin at
the top-left pixel's outer corner, so pixel ``(row i, col j)`` is centred at
``(j + ½, i + ½)``; fixations are pixel centres, boxes ``(x_min, y_min, x_max, y_max)``.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import cv2
import numpy as np

from jaxgaze.geometry import head_pose_to_rotation
from jaxgaze.headpose import target as tg
from jaxgaze.headpose.regression import RescaledRegression, training_image_scale
from jaxgaze.vision.head_model import CylinderHead
from jaxgaze.vision.images import check_image, iterate_frames
from jaxgaze.vision.saliency_maps import SALIENCY_METHODS, gaussian_mask, salient_region, saliency, winner_take_all

__all__ = [
    "Attention",
    "AttentionWindows",
    "attend_frames",
    "attend_window",
    "attention_overlay",
    "draw_attention",
    "OVERLAY_COLOURS",
    "target_points_and_covariances",
    "NO_LOCATION",
    "target_point_covariance",
]

SIGMA_PX = 10.0
"""T-CYB's Gaussian mask σ (px) around each pooled estimate."""
NO_LOCATION = "no location stands out"


# ---------------------------------------------------------------------------
# Target-point covariance


def target_point_covariance(
    head_centre, direction, depth_y, direction_variance, depth_variance, *, max_length: float = tg.MAX_LENGTH_PX
) -> np.ndarray:
    """Delta-method covariance ``(T, 2, 2)`` (px²) of the target points (Yücel et al. 2013, Sec. VI).

    The points ``p`` are those of :func:`~jaxgaze.headpose.target.target_point`.
    ``Σ_t = var(f1_t) J₁J₁ᵀ + var(f2_t) J₂J₂ᵀ`` with ``J₁ = ∂p/∂f1``, ``J₂ = ∂p/∂f2`` at
    the predicted means: for a ray that reaches the row, ``p = (h_x + (f2 − h_y) cot f1, f2)``,
    so ``J₁ = (−(f2 − h_y) / sin² f1, 0)`` and ``J₂ = (cot f1, 1)``; a ray capped at
    ``max_length`` L has ``p = h + L (cos f1, sin f1)``, ``J₁ = L (−sin f1, cos f1)``,
    ``J₂ = 0``; a ray that misses the row gives ``p = h`` and ``J = 0``. Inputs as
    ``target_point`` (``(T, 2)``, ``(T,)`` × 4; variances ≥ 0, radians² and px²).
    Linearisation: near-horizontal rays (small ``sin f1``) have large, asymmetric
    errors that this makes Gaussian.
    """
    h = _finite("head_centre", head_centre)
    d, y = _finite("direction", direction), _finite("depth_y", depth_y)
    vd, vy = _finite("direction_variance", direction_variance), _finite("depth_variance", depth_variance)
    if h.ndim != 2 or h.shape[1] != 2:
        raise ValueError(f"head_centre must have shape (T, 2), got {h.shape}")
    for name, a in (("direction", d), ("depth_y", y), ("direction_variance", vd), ("depth_variance", vy)):
        if a.shape != (h.shape[0],):
            raise ValueError(f"{name} must have shape ({h.shape[0]},), got {a.shape}")
    if np.any(vd < 0) or np.any(vy < 0):
        raise ValueError("direction_variance and depth_variance must be >= 0")
    tg.target_point(h, d, y, max_length=max_length)  # the same checks as the point itself
    # the branches of target_point: the ray reaches the row, is capped at max_length, or misses it
    c, s = np.cos(d), np.sin(d)
    dy = y - h[:, 1]
    ahead = dy * s > 0
    length = np.where(ahead, dy / np.where(ahead, s, 1.0), 0.0)
    capped = ahead & (length > max_length)
    reached = ((ahead & ~capped) | (dy == 0)) & (s != 0)
    s_safe = np.where(s != 0, s, 1.0)
    zero = np.zeros_like(d)
    j1 = np.where(reached[:, None], np.stack([-dy / s_safe**2, zero], -1),
                  np.where(capped[:, None], max_length * np.stack([-s, c], -1), 0.0))
    j2 = np.where(reached[:, None], np.stack([c / s_safe, np.ones_like(d)], -1), 0.0)
    return vd[:, None, None] * j1[:, :, None] * j1[:, None, :] + vy[:, None, None] * j2[:, :, None] * j2[:, None, :]


# ---------------------------------------------------------------------------
# One window


class Attention(NamedTuple):
    """The attended location of one window (image coordinates, px).

    Attributes:
        xy: ``(2,)`` the chosen location (the most probable candidate, a pixel centre).
        probability: its posterior probability.
        candidates_xy: ``(C, 2)`` candidate locations (winner-take-all order).
        candidate_probabilities: ``(C,)``, summing to 1.
        candidate_saliency: ``(C,)`` the (unmasked) saliency at each candidate.
        region_box: ``(4,)`` ``(x_min, y_min, x_max, y_max)`` of the salient region at ``xy``.
        candidate_objects: ``(C,)`` the box each candidate is in, or −1 (−1 without boxes).
        object_probabilities: ``(K,)`` ``P(object k)``, or None without boxes.
        none_probability: the probability of no object (NaN without boxes).
        chosen_object: the box the chosen location is in, or −1.
    """

    xy: np.ndarray
    probability: float
    candidates_xy: np.ndarray
    candidate_probabilities: np.ndarray
    candidate_saliency: np.ndarray
    region_box: np.ndarray
    candidate_objects: np.ndarray
    object_probabilities: np.ndarray | None
    none_probability: float
    chosen_object: int


def _finite(name, x, dtype=np.float64) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {type(x).__name__}") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    return a


def _check_covariance(cov, num_points: int) -> np.ndarray:
    c = _finite("target_cov", cov)
    if c.shape == (2, 2):
        c = np.broadcast_to(c, (num_points, 2, 2))
    if c.shape != (num_points, 2, 2):
        raise ValueError(f"target_cov must have shape (2, 2) or ({num_points}, 2, 2), got {np.shape(cov)}")
    scale = max(1.0, float(np.abs(c).max()))
    if np.any(np.abs(c - np.swapaxes(c, -1, -2)) > 1e-6 * scale):
        raise ValueError("target_cov must be symmetric")
    if np.any(np.linalg.eigvalsh(c)[:, 0] < -1e-6 * scale):
        raise ValueError("target_cov must be positive semi-definite")
    return c


def _objects_of(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The closed box each point is in (nearest box centre among several), or −1."""
    p = points[:, None, :]
    inside = ((p[..., 0] >= boxes[:, 0]) & (p[..., 0] <= boxes[:, 2])
              & (p[..., 1] >= boxes[:, 1]) & (p[..., 1] <= boxes[:, 3]))
    centres = np.stack([(boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2], -1)
    d2 = np.where(inside, np.sum((p - centres[None]) ** 2, -1), np.inf)
    return np.where(inside.any(1), np.argmin(d2, 1), -1) if len(points) else np.zeros(0, np.int64)


def _log_mixture(points, means, covs):
    """``log (1/P) Σ_p N(c; means_p, covs_p)`` for each row ``c`` of ``points`` (2-D Gaussians)."""
    inv = np.linalg.inv(covs)  # (P, 2, 2)
    r = points[:, None, :] - means[None]  # (C, P, 2)
    maha = np.einsum("cpi,pij,cpj->cp", r, inv, r)
    logn = -math.log(2 * math.pi) - 0.5 * np.linalg.slogdet(covs)[1][None] - 0.5 * maha
    top = logn.max(1, keepdims=True)
    return (top + np.log(np.mean(np.exp(logn - top), axis=1, keepdims=True)))[:, 0]


def attend_window(
    image,
    target_xy,
    target_cov,
    *,
    method: str = "itti",
    sigma_px: float = SIGMA_PX,
    num_candidates: int = 5,
    ior_radius_px: float = 20.0,
    object_boxes=None,
    saliency_map=None,
) -> Attention:
    """Attended location of one pooling window: saliency × regression posterior (Yücel et al. 2013, Sec. VI–VII).

    The posterior is described in the module docstring.

    Args:
        image: the frame (``(H, W[, 3])``, uint8 or float in [0, 1]); may be None when
            ``saliency_map`` is given.
        target_xy: ``(P, 2)`` (or ``(2,)``) the window's target-point estimates (px).
        target_cov: ``(2, 2)`` or ``(P, 2, 2)`` their covariance (px², e.g.
            :func:`target_point_covariance`; zeros for a regression without variances).
        method: saliency method (:data:`~jaxgaze.vision.saliency_maps.SALIENCY_METHODS`).
        sigma_px: the mask's σ (T-CYB: 10 px), also added to the covariance.
        num_candidates: most winner-take-all candidates.
        ior_radius_px: inhibition-of-return radius between candidates.
        object_boxes: ``(K, 4)`` known boxes (simulation), or None.
        saliency_map: a precomputed ``(H, W)`` map of ``image`` (e.g. a static scene's).

    Raises:
        ValueError: ``"no location stands out"`` when the saliency inside the mask is
            flat, NaN/inf estimates or covariance, a covariance that is not symmetric
            positive semi-definite, bad shapes, ``sigma_px ≤ 0``, ``num_candidates < 1``,
            an unknown method.
    """
    xy = _finite("target_xy", target_xy)
    if xy.ndim == 1:
        xy = xy[None]
    if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] < 1:
        raise ValueError(f"target_xy must have shape (P, 2) with P >= 1 as (x, y), got {np.shape(target_xy)}")
    cov = _check_covariance(target_cov, xy.shape[0])
    sigma = float(sigma_px)
    if not math.isfinite(sigma) or sigma <= 0:
        raise ValueError(f"sigma_px must be finite and > 0, got {sigma_px!r}")
    if isinstance(num_candidates, bool) or int(num_candidates) != num_candidates or num_candidates < 1:
        raise ValueError(f"num_candidates must be an integer >= 1, got {num_candidates!r}")
    if saliency_map is None:
        if image is None:
            raise ValueError("attend_window needs an image or a saliency_map")
        smap = saliency(image, method)
    else:
        smap = np.asarray(saliency_map)
        if image is not None and check_image(image).shape[:2] != smap.shape:
            raise ValueError(f"saliency_map has shape {smap.shape}, the image {np.shape(image)[:2]}")
    boxes = None
    if object_boxes is not None:
        boxes = tg._boxes("object_boxes", object_boxes)

    mask = gaussian_mask(smap.shape, xy, sigma_px=sigma)
    try:
        fix = winner_take_all(smap, int(num_candidates), ior_radius_px=ior_radius_px, mask=mask)
    except ValueError as err:
        if NO_LOCATION in str(err):
            raise ValueError(f"{NO_LOCATION}: the saliency map is flat inside the mask (σ = {sigma:g} px) "
                             f"around the estimates {xy.round(1).tolist()}") from None
        raise
    cands = fix.xy
    s = np.asarray(smap, np.float64)[np.floor(cands[:, 1]).astype(int), np.floor(cands[:, 0]).astype(int)]
    with np.errstate(divide="ignore"):
        logw = np.log(s) + _log_mixture(cands, xy, cov + sigma**2 * np.eye(2))
    if not np.any(np.isfinite(logw)):
        raise ValueError(f"{NO_LOCATION}: no candidate has positive saliency")
    w = np.exp(logw - logw[np.isfinite(logw)].max())
    prob = w / w.sum()
    best = int(np.argmax(prob))
    # Segment in the masked map: Itti's map can stay high along a whole table edge, and a
    # region grown on S alone then spans the table (measured: 320 px wide for a 38 px cube).
    region = np.asarray(salient_region(np.asarray(smap, np.float64) * mask, cands[best]), np.float64)
    if boxes is None:
        objects, obj_prob, none, chosen = np.full(len(cands), -1), None, math.nan, -1
    else:
        objects = _objects_of(cands, boxes)
        obj_prob = np.bincount(objects[objects >= 0], weights=prob[objects >= 0], minlength=len(boxes))
        none, chosen = float(prob[objects < 0].sum()), int(objects[best])
    return Attention(cands[best].copy(), float(prob[best]), cands, prob, s, region, objects, obj_prob, none, chosen)


def target_points_and_covariances(regression, features, head_xy):
    """Predicted target points and their delta-method covariances (Yücel et al. 2013, Sec. VI).

    Returns ``(f1, f2, points (T, 2), covariances (T, 2, 2))``; the covariances are 0
    for a regression without predictive variances (the NN baseline).
    """
    pred = regression.predict(features)
    d, y = np.asarray(pred.direction, np.float64), np.asarray(pred.depth, np.float64)
    points = np.asarray(tg.target_point(head_xy, d, y), np.float64)
    if pred.direction_variance is None:
        cov = np.zeros((len(d), 2, 2))
    else:
        cov = target_point_covariance(head_xy, d, y, pred.direction_variance, pred.depth_variance)
    return d, y, points, cov



# ---------------------------------------------------------------------------
# Video


class AttentionWindows(NamedTuple):
    """Per non-overlapping window of ``window`` frames of a video (:func:`attend_frames`).

    Attributes:
        start_frame: ``(W,)`` first frame of the window.
        pose: ``(W, 3)`` pooled head pose (pitch, yaw, roll), radians (mean over tracked frames).
        direction: ``(W,)`` pooled ``f1``, radians (circular mean).
        depth_y: ``(W,)`` pooled ``f2``, px.
        target_xy: ``(W, 2)`` pooled target point (mean of the frames' points), px.
        attended_xy: ``(W, 2)`` the attended location, px.
        region_box: ``(W, 4)`` the salient region there, ``(x_min, y_min, x_max, y_max)`` px.
        probability: ``(W,)`` the attended location's posterior probability.
        valid: ``(W,)`` True where a location was attended.
        head_xy: ``(W, 2)`` pooled head centre in the image, px.
        reason: ``(W,)`` why a window is not valid: ``""``, ``"tracker lost"`` (pose,
            direction, depth, target and attention NaN) or ``"no location stands out"``
            (the regression fields are kept; attention NaN). Probability 0 in both.
        window: frames per window.
        image_scale: the factor applied to the regression's ``f2`` rows (and variances):
            frame height / training image height (1 when equal or unknown).
    """

    start_frame: np.ndarray
    pose: np.ndarray
    direction: np.ndarray
    depth_y: np.ndarray
    target_xy: np.ndarray
    attended_xy: np.ndarray
    region_box: np.ndarray
    probability: np.ndarray
    valid: np.ndarray
    head_xy: np.ndarray
    reason: tuple
    window: int
    image_scale: float


def _head_centre_image(track, focal: float, size, head: CylinderHead) -> np.ndarray:
    """Project the front of the face on the cylinder's mid-height, ``t + R (b, 0, 0)``: the
    tracker's stand-in for the eye midpoint the regression was trained on."""
    width, height = size
    pose = np.nan_to_num(track.pose)  # (pitch, yaw, roll)
    R_frontal = head_pose_to_rotation(yaw=pose[:, 1], pitch=pose[:, 0], roll=pose[:, 2])
    R = track.R_optical_from_frontal @ np.asarray(R_frontal, np.float64)
    front = track.translation + R[:, :, 0] * head.half_depth_m
    return np.stack([focal * front[:, 0] / front[:, 2] + width / 2, focal * front[:, 1] / front[:, 2] + height / 2], -1)


def _regression_for_frames(regression, width: int, height: int):
    """The regression with ``f2`` in rows of ``width × height`` frames, and the factor ``h / h_train``
    (:func:`~jaxgaze.headpose.regression.training_image_scale`); warns when the training size is
    unknown or of another aspect ratio."""
    trained = getattr(regression, "image_size", None)
    if trained is None:
        warnings.warn(f"the gaze regression does not know the size of its training images: its depth rows f2 are "
                      f"taken as rows of these {width}x{height} px frames (fit it with image_size=(width, height) or "
                      f"use regression._replace(image_size=(width, height)))", stacklevel=3)
        return regression, 1.0
    scale = training_image_scale(regression, (width, height))
    if abs(width / trained[0] - scale) > 0.01 * scale:
        warnings.warn(f"the frames are {width}x{height} px but the gaze regression was trained on {trained[0]}x"
                      f"{trained[1]} px images (another aspect ratio): its depth rows are scaled by the heights, "
                      f"x {scale:.4g}", stacklevel=3)
    return (regression if scale == 1 else RescaledRegression(regression, scale)), scale


def attend_frames(
    frames,
    regression,
    *,
    focal_px: float,
    window: int = 4,
    method: str = "itti",
    initial_box=None,
    progress: bool = False,
    sigma_px: float = SIGMA_PX,
    num_candidates: int = 5,
    head: CylinderHead = CylinderHead(),
    **track_options,
) -> AttentionWindows:
    """The video pipeline (Yücel et al. 2013, Sec. IV–VI): head tracking → regression → pooling → attention.

    :func:`~jaxgaze.vision.tracker.track_head` (frame 0 frontal, eye contact; ``initial_box``
    or face detection; ``track_options`` passed on) gives the pose and the head position;
    the head centre in the image is the projected front of the face (the cylinder's
    centre plus ``half_depth`` along the facing direction). The regression (trained on
    ``(pitch, yaw, roll)``, or with the position appended if it has 6 features) predicts
    ``f1``, ``f2`` per frame (``f2`` scaled to the frames' size, below), :func:`~jaxgaze.headpose.target.target_point` and
    :func:`target_point_covariance` give the target points, and each non-overlapping
    window of ``window`` frames (a trailing incomplete one is dropped) is attended by
    :func:`attend_window` on its **last** frame, from the points of its tracked frames.
    ``frames`` may be an iterator (only each window's last frame is kept).

    ``focal_px`` is the focal length (px) of the camera that took ``frames``. The
    regression's ``f2`` is a row of its training images (``regression.image_size``): on
    frames ``s = h / h_train`` times as tall it is scaled by ``s`` (variance ``s²``), as
    :class:`~jaxgaze.headpose.regression.RescaledRegression` does, assuming the same camera
    at another resolution (so ``focal_px`` is then ``s`` times the training focal length);
    the factor is ``AttentionWindows.image_scale``. A ``UserWarning`` says when the
    frames' aspect ratio differs (rows still scale by the heights) and when the training
    size is unknown (``image_size`` ``None``: ``f2`` is taken as rows of these frames).

    Raises:
        ValueError: ``window < 1``, fewer frames than one window, a bad ``focal_px``, and
            the tracker's errors (no face in frame 0, frames of differing sizes, ...).
    """
    from tqdm.auto import tqdm

    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ValueError(f"window must be an integer >= 1 frame, got {window!r}")
    focal = float(focal_px)
    if not math.isfinite(focal) or focal <= 0:
        raise ValueError(f"focal_px must be a positive finite number, got {focal_px!r}")
    if method not in SALIENCY_METHODS:
        raise ValueError(f"unknown saliency method {method!r}; choose one of {', '.join(SALIENCY_METHODS)}")
    if frames is None:
        raise TypeError("frames must be a sequence or iterable of images, got None")
    from jaxgaze.vision.tracker import track_head

    last: list = []  # each window's last frame

    def keep(it):
        for t, frame in enumerate(it):
            if (t + 1) % window == 0:
                last.append(frame)
            yield frame

    try:
        total = len(frames)
    except TypeError:  # a generator, or a lazy sequence of unknown length
        total = None
    if total is not None and total < window:
        raise ValueError(f"frames has {total} frames, fewer than one window of {window}")
    stream = tqdm(keep(iterate_frames(frames)), total=total, desc="tracking", unit="frame", disable=not progress)
    track = track_head(stream, focal_px=focal, initial_box=initial_box, head=head, **track_options)
    T = len(track.pose)
    n = T // window
    if n < 1:
        raise ValueError(f"frames has {T} frames, fewer than one window of {window}")
    height, width = check_image(last[0], "frames").shape[:2]
    regression, image_scale = _regression_for_frames(regression, width, height)
    tracked = np.all(np.isfinite(track.pose), 1) & np.all(np.isfinite(track.translation), 1)
    head_xy = np.full((T, 2), np.nan)
    head_xy[tracked] = _head_centre_image(track, focal, (width, height), head)[tracked]
    d, y, points, cov = np.full(T, np.nan), np.full(T, np.nan), np.full((T, 2), np.nan), np.full((T, 2, 2), np.nan)
    if tracked.any():
        width_features = getattr(getattr(regression, "features", None), "mean", np.zeros(3)).shape[0]
        feats = track.pose if width_features != 6 else np.concatenate([track.pose, track.translation], 1)
        # predict every frame (one array shape per video: one compilation), lost ones on zeros, then drop them
        fill = tracked[:, None]
        d, y, points, cov = target_points_and_covariances(regression, np.where(fill, feats, 0.0),
                                                    np.where(fill, head_xy, 0.0))
        d, y = np.where(tracked, d, np.nan), np.where(tracked, y, np.nan)
        points, cov = np.where(fill, points, np.nan), np.where(fill[:, :, None], cov, np.nan)

    nan2, nan3, nan4 = np.full(2, np.nan), np.full(3, np.nan), np.full(4, np.nan)
    rows = []
    for b in tqdm(range(n), desc="attending", unit="window", disable=not progress):
        sel = np.arange(b * window, (b + 1) * window)
        sel = sel[tracked[sel]]
        if sel.size == 0:
            rows.append((nan3, math.nan, math.nan, nan2, nan2, nan4, 0.0, False, nan2, "tracker lost"))
            continue
        pooled = (track.pose[sel].mean(0), float(np.arctan2(np.sin(d[sel]).sum(), np.cos(d[sel]).sum())),
                  float(y[sel].mean()), points[sel].mean(0))
        try:
            a = attend_window(last[b], points[sel], cov[sel], method=method, sigma_px=sigma_px,
                              num_candidates=num_candidates)
        except ValueError as err:
            if NO_LOCATION not in str(err):
                raise
            rows.append((*pooled, nan2, nan4, 0.0, False, head_xy[sel].mean(0), NO_LOCATION))
            continue
        rows.append((*pooled, a.xy, a.region_box, a.probability, True, head_xy[sel].mean(0), ""))
    pose, direction, depth, target, attended, region, prob, valid, hxy, reason = zip(*rows)
    return AttentionWindows(
        start_frame=np.arange(n) * window, pose=np.stack(pose), direction=np.asarray(direction),
        depth_y=np.asarray(depth), target_xy=np.stack(target), attended_xy=np.stack(attended),
        region_box=np.stack(region), probability=np.asarray(prob), valid=np.asarray(valid, bool),
        head_xy=np.stack(hxy), reason=tuple(reason), window=int(window), image_scale=float(image_scale),
    )


# ---------------------------------------------------------------------------
# Drawing

#: The overlay's colours (RGB): the attended point, its salient region, the head centre and
#: the regression's target point (a cross, on the gaze line from the head centre).
OVERLAY_COLOURS = {"attended": (255, 0, 0), "region": (0, 255, 0), "head": (0, 160, 255), "target": (255, 255, 0)}
_SHIFT = 4  # OpenCV's fractional bits: points drawn to 1/16 px


def _cv_point(xy, limit: float):
    """Image coordinates (corner origin) → OpenCV's fixed-point pixel indices (pixel centres at integers)."""
    x, y = (float(np.clip(v - 0.5, -limit, limit)) for v in xy)
    return round(x * 2**_SHIFT), round(y * 2**_SHIFT)


def _disc(img: np.ndarray, xy, radius: float, colour) -> None:
    """Fill the pixels whose centres are within ``radius`` of ``xy`` (image coordinates)."""
    x, y = xy
    rows = np.arange(max(0, math.floor(y - radius)), min(img.shape[0], math.ceil(y + radius) + 1))
    cols = np.arange(max(0, math.floor(x - radius)), min(img.shape[1], math.ceil(x + radius) + 1))
    inside = (cols[None, :] + 0.5 - x) ** 2 + (rows[:, None] + 0.5 - y) ** 2 <= radius**2
    img[rows[:, None], cols[None, :]] = np.where(inside[..., None], colour, img[rows[:, None], cols[None, :]])


def draw_attention(image, windows: AttentionWindows, index: int) -> np.ndarray:
    """A copy of ``image`` (as RGB ``uint8``) with window ``index`` of ``windows`` drawn on it.

    The salient region box (green, 1 px), the gaze line from the head centre to the
    regression's pooled target point (yellow, with a cross at the target), the head
    centre (blue disc, radius 3 px) and the attended location (red disc, radius 4 px,
    drawn last): :data:`OVERLAY_COLOURS`. A disc fills the pixels whose centres are within
    its radius, so it is centred on the point to sub-pixel accuracy. What a window does not have (NaN: a lost
    tracker, no location) is not drawn.
    """
    img = check_image(image)
    if img.dtype != np.uint8:
        img = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    img = np.ascontiguousarray(np.repeat(img[..., None], 3, -1) if img.ndim == 2 else img).copy()
    limit = 4.0 * max(img.shape)
    colour = {k: tuple(int(c) for c in v) for k, v in OVERLAY_COLOURS.items()}
    box, head = np.asarray(windows.region_box[index], float), np.asarray(windows.head_xy[index], float)
    target, attended = np.asarray(windows.target_xy[index], float), np.asarray(windows.attended_xy[index], float)
    if np.all(np.isfinite(box)):  # pixel columns x_min … x_max − 1, rows y_min … y_max − 1
        cv2.rectangle(img, _cv_point(box[:2] + 0.5, limit), _cv_point(box[2:] - 0.5, limit), colour["region"], 1,
                      cv2.LINE_8, _SHIFT)
    if np.all(np.isfinite(target)):
        if np.all(np.isfinite(head)):
            cv2.line(img, _cv_point(head, limit), _cv_point(target, limit), colour["target"], 1, cv2.LINE_8, _SHIFT)
        x, y = (round(v / 2**_SHIFT) for v in _cv_point(target, limit))
        cv2.drawMarker(img, (x, y), colour["target"], cv2.MARKER_CROSS, 11, 1, cv2.LINE_8)
    if np.all(np.isfinite(head)):
        _disc(img, head, 3.0, colour["head"])
    if np.all(np.isfinite(attended)):
        _disc(img, attended, 4.0, colour["attended"])
    return img


def attention_overlay(frames, windows: AttentionWindows):
    """The frames of ``windows``' windows, each with its window drawn (:func:`draw_attention`),
    one at a time; frames after the last complete window are not yielded."""
    total = len(windows.start_frame) * windows.window
    for t, frame in enumerate(iterate_frames(frames)):
        if t >= total:
            return
        yield draw_attention(frame, windows, t // windows.window)
