"""Target point, pooling, evaluation metrics and train/test splits (Yücel et al.).

From the two regressed image quantities of T-CYB 2013 (Sec. V–VI, Fig. 9) —
``f1``, the image-plane angle of the gaze line from the head centre, and
``f2``, the image row (y, px) of the attended object — the *target point* is
where the gaze line meets that row. Estimates are *pooled* over bins of
consecutive frames (4 at 10 fps in T-CYB Sec. VI, 5 at 25 fps in CogSci) and
scored:

* T-CYB eq. 14, ``Q1(i) = |{q ∈ B_i}| / |q|``: the fraction of frames labelled
  with object ``i`` whose estimated point lies in ``i``'s bounding box;
* T-CYB eq. 15, ``Q2(i) = |{q : d(q, c_i) < d(q, c_j) ∀ j ≠ i}| / |q|``: the
  fraction whose nearest object centre is ``i``'s (strictly: ties count as
  misses). T-CYB Table I reports the mean over objects of these per-object
  rates (:attr:`TargetRates.mean`);
* CogSci Q1: the mean absolute wrapped angular deviation (radians);
* CogSci Q2(h), Q2(hg): the rate at which the image-plane cone of half-angle
  ``tolerance`` (3π/64) around the head direction (h) or the regressed gaze
  direction (hg), with its apex at the head centre, intersects the attended
  box; Q2(hgd): the rate at which the disk of radius ``mask_radius`` (10 px,
  the σ of the T-CYB Gaussian mask) around the target point intersects it;
* the CMC curve (CogSci Fig. 5): accuracy ``P(|error| ≤ τ)`` per threshold τ.

Image coordinates are pixels, origin top-left, x right, y down; image angles
are ``atan2(dy, dx)`` in those coordinates (pointing down the image is +π/2).
:func:`target_point` is written in ``jax.numpy`` (jit-able, differentiable);
the pooling, metric and split helpers run on the host and return NumPy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.geometry import wrap_angle

__all__ = [
    "TOLERANCE",
    "MASK_RADIUS_PX",
    "MAX_LENGTH_PX",
    "Pooled",
    "PooledLabels",
    "TargetRates",
    "target_point",
    "reaches_row",
    "pool",
    "pool_labels",
    "q1",
    "q2",
    "angular_errors",
    "mean_angular_deviation",
    "cone_hits_box",
    "disk_hits_box",
    "cone_rates",
    "disk_rates",
    "cmc_curve",
    "self_referencing_splits",
    "cross_referencing_splits",
]

TOLERANCE = 3 * math.pi / 64
"""CogSci tolerance: half-angle of the gaze cone (radians)."""
MASK_RADIUS_PX = 10.0
"""T-CYB Gaussian mask σ (px), the radius of the target point's tolerance disk."""
MAX_LENGTH_PX = 400.0
"""Default longest gaze segment in :func:`target_point`: the diagonal of a 320 × 240 image."""


# ---------------------------------------------------------------------------
# Validation helpers


def _is_tracer(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _host(name: str, x, *, dtype=np.float64) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a numeric array: {e}") from None
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    return a


def _labels(name: str, x, n: int | None = None) -> np.ndarray:
    a = np.asarray(x)
    if a.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {a.shape}")
    if a.size and a.dtype.kind not in "iu":
        if a.dtype.kind == "f" and np.all(np.isfinite(a)) and np.all(a == np.round(a)):
            a = a.astype(np.int64)
        else:
            raise ValueError(f"{name} must hold integer labels, got dtype {a.dtype}")
    a = a.astype(np.int64)
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} has {a.shape[0]} entries, expected {n} (one per frame)")
    return a


def _valid_mask(valid, n: int) -> np.ndarray:
    if valid is None:
        return np.ones(n, dtype=bool)
    v = np.asarray(valid)
    if v.dtype != bool:
        raise ValueError(f"valid must be a boolean mask, got dtype {v.dtype}")
    if v.shape != (n,):
        raise ValueError(f"valid must have shape ({n},), got {v.shape}")
    return v


def _boxes(name: str, boxes) -> np.ndarray:
    b = _host(name, boxes)
    if b.ndim != 2 or b.shape[1] != 4 or b.shape[0] < 1:
        raise ValueError(f"{name} must have shape (K, 4) with K ≥ 1 as (x_min, y_min, x_max, y_max), got {b.shape}")
    if np.any(b[:, 2] < b[:, 0]) or np.any(b[:, 3] < b[:, 1]):
        raise ValueError(f"{name} must have x_min ≤ x_max and y_min ≤ y_max")
    return b


def _points(name: str, points, n: int | None = None) -> np.ndarray:
    p = _host(name, points)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) image points, got {p.shape}")
    if n is not None and p.shape[0] != n:
        raise ValueError(f"{name} has {p.shape[0]} rows, expected {n}")
    return p


def _positive(name: str, value, *, open_hi: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be finite and ≥ 0, got {value!r}")
    if open_hi is not None and value >= open_hi:
        raise ValueError(f"{name} must be < {open_hi}, got {value!r}")
    return value


# ---------------------------------------------------------------------------
# Target point (T-CYB Fig. 9)


def _check_target_inputs(head_centre, direction, depth_y, max_length):
    if not isinstance(max_length, (int, float, np.integer, np.floating)) or isinstance(max_length, bool):
        raise ValueError(f"max_length must be a positive number, got {max_length!r}")
    if not (math.isfinite(float(max_length)) and max_length > 0):
        raise ValueError(f"max_length must be finite and > 0, got {max_length!r}")
    h, d, y = (jnp.asarray(a) for a in (head_centre, direction, depth_y))
    if h.ndim < 1 or h.shape[-1] != 2:
        raise ValueError(f"head_centre must have shape (..., 2), got {h.shape}")
    if d.shape != h.shape[:-1]:
        raise ValueError(f"direction must have shape {h.shape[:-1]} (one angle per head centre), got {d.shape}")
    if y.shape != h.shape[:-1]:
        raise ValueError(f"depth_y must have shape {h.shape[:-1]} (one row per head centre), got {y.shape}")
    for name, a in (("head_centre", head_centre), ("direction", direction), ("depth_y", depth_y)):
        if not _is_tracer(a) and not np.all(np.isfinite(np.asarray(a))):
            raise ValueError(f"{name} contains NaN or inf")
    dtype = jnp.result_type(h, d, y, float)
    return h.astype(dtype), d.astype(dtype), y.astype(dtype)


def _ray_to_row(h, d, y, max_length):
    c, s = jnp.cos(d), jnp.sin(d)
    dy = y - h[..., 1]
    ahead = dy * s > 0  # the row lies on the side the ray points to
    length = jnp.where(ahead, dy / jnp.where(ahead, s, 1.0), 0.0)
    clipped = length > max_length
    length = jnp.minimum(length, max_length)
    reached = (ahead & ~clipped) | (dy == 0)
    return c, s, length, reached


def target_point(
    head_centre: Float[Array, "T 2"],
    direction: Float[Array, " T"],
    depth_y: Float[Array, " T"],
    *,
    max_length: float = MAX_LENGTH_PX,
) -> Float[Array, "T 2"]:
    """Where the gaze line meets the estimated object row (Yücel et al. 2013, Sec. VI, Fig. 9).

    The ray ``h + s (cos d, sin d)``, ``s ≥ 0``, from the head centre ``h`` at image
    angle ``d`` (``f1``) meets the row ``y = depth_y`` (``f2``) at
    ``s = (depth_y − h_y) / sin d``; the point is ``(h_x + s cos d, depth_y)`` — with
    the true ``f1``, ``f2`` it is the object centre. Robust cases (never NaN):

    * near-horizontal rays: ``s`` is capped at ``max_length`` px (default the
      image diagonal); the point then lies on the ray, short of the row;
    * the row lies *behind* the ray (the ray points away from it) or the ray is
      exactly parallel to it: the ray never reaches the row and the point is
      the head centre ``h`` (``s = 0``); a row through ``h`` gives ``h`` too.

    :func:`reaches_row` tells which points lie on the row. Leading shapes may
    be any ``(...)``; the result is ``(..., 2)``.

    Raises:
        ValueError: mismatched shapes, NaN or inf input, ``max_length ≤ 0``.
    """
    h, d, y = _check_target_inputs(head_centre, direction, depth_y, max_length)
    c, s, length, reached = _ray_to_row(h, d, y, max_length)
    x = h[..., 0] + length * c
    row = jnp.where(reached, y, h[..., 1] + length * s)
    return jnp.stack([x, row], axis=-1)


def reaches_row(
    head_centre: Float[Array, "T 2"],
    direction: Float[Array, " T"],
    depth_y: Float[Array, " T"],
    *,
    max_length: float = MAX_LENGTH_PX,
) -> Bool[Array, " T"]:
    """True where :func:`target_point` lies on the row ``depth_y`` (Yücel et al. 2013, Sec. VI, Fig. 9).

    That is, where the ray reaches the row within ``max_length``.
    """
    h, d, y = _check_target_inputs(head_centre, direction, depth_y, max_length)
    return _ray_to_row(h, d, y, max_length)[3]


# ---------------------------------------------------------------------------
# Pooling (T-CYB Sec. VI)


class PooledLabels(NamedTuple):
    """Labels pooled over bins: the bin's label if all its frames share it, else −1 (and not valid)."""

    labels: Int[np.ndarray, " B"]
    valid: Bool[np.ndarray, " B"]


class Pooled(NamedTuple):
    """Pooled values ``(B, ...)``, which bins are valid, and the pooled labels (or None)."""

    values: Float[np.ndarray, "B ..."]
    valid: Bool[np.ndarray, " B"]
    labels: Int[np.ndarray, " B"] | None


def _check_window(window) -> int:
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)):
        raise ValueError(f"window must be an integer number of frames, got {window!r}")
    if window < 1:
        raise ValueError(f"window must be ≥ 1 frame, got {window}")
    return int(window)


def pool_labels(labels: Int[Array, " T"], window: int) -> PooledLabels:
    """Pool per-frame labels into ``B = T // window`` bins of ``window`` frames (Yücel et al. 2013, Sec. VI).

    A bin is valid when all its frames carry one label (the experimenter looked
    at one object throughout); otherwise its label is −1. Trailing ``T % window``
    frames (an incomplete bin) are dropped.

    Raises:
        ValueError: ``window < 1``, non-integer or non-1-D labels, or ``T < window``.
    """
    window = _check_window(window)
    lab = _labels("labels", labels)
    B = lab.shape[0] // window
    if B < 1:
        raise ValueError(f"labels has {lab.shape[0]} frames, fewer than one window of {window}")
    bins = lab[: B * window].reshape(B, window)
    valid = np.all(bins == bins[:, :1], axis=1)
    return PooledLabels(labels=np.where(valid, bins[:, 0], -1), valid=valid)


def pool(
    values: Float[Array, "T ..."],
    window: int,
    *,
    labels: Int[Array, " T"] | None = None,
    circular: bool = False,
) -> Pooled:
    """Average ``values`` over bins of ``window`` consecutive frames (Yücel et al. 2013, Sec. VI).

    T-CYB pools 4 frames at 10 fps, CogSci 5 at 25 fps.
    Points (``(T, 2)``) and other values are averaged component-wise; with
    ``circular=True`` each column is an angle and the bin value is the circular
    mean ``atan2(Σ sin, Σ cos)`` (0 when the sines and cosines cancel exactly).
    Bins are ``[b·window, (b+1)·window)``; trailing ``T % window`` frames are
    dropped. With ``labels`` (the attended object per frame) a bin is valid only
    if all its frames share one label (:func:`pool_labels`); without, every bin
    is valid. Invalid bins are flagged, not dropped, so outputs stay aligned.

    Raises:
        ValueError: ``window < 1``, NaN/inf values, ``T < window``, labels of another length.
    """
    window = _check_window(window)
    v = _host("values", values)
    if v.ndim < 1:
        raise ValueError("values must have a leading frame axis (T, ...)")
    T = v.shape[0]
    B = T // window
    if B < 1:
        raise ValueError(f"values has {T} frames, fewer than one window of {window}")
    bins = v[: B * window].reshape((B, window) + v.shape[1:])
    if circular:
        out = np.arctan2(np.sin(bins).sum(axis=1), np.cos(bins).sum(axis=1))
    else:
        out = bins.mean(axis=1)
    if labels is None:
        return Pooled(values=out, valid=np.ones(B, dtype=bool), labels=None)
    pl = pool_labels(_labels("labels", labels, T), window)
    return Pooled(values=out, valid=pl.valid, labels=pl.labels)


# ---------------------------------------------------------------------------
# Per-object rates (T-CYB eq. 14–15, CogSci Q2)


class TargetRates(NamedTuple):
    """Per-object true-positive rates.

    Attributes:
        per_object: ``(K,)`` ``hits / counts``; 0 for objects never attended
            (``counts == 0``), which the summaries below leave out.
        hits: ``(K,)`` frames (or bins) of object ``i`` that score.
        counts: ``(K,)`` frames (or bins) labelled with object ``i``.
        mean: mean of ``per_object`` over attended objects (T-CYB Table I).
        overall: ``Σ hits / Σ counts`` over all frames.
    """

    per_object: Float[np.ndarray, " K"]
    hits: Int[np.ndarray, " K"]
    counts: Int[np.ndarray, " K"]
    mean: float
    overall: float

    def group(self, objects: Bool[Array, " K"]) -> float:
        """``Σ hits / Σ counts`` over the objects in the mask (e.g. the CogSci near/far groups)."""
        m = np.asarray(objects)
        if m.dtype != bool or m.shape != self.counts.shape:
            raise ValueError(f"objects must be a boolean mask of shape {self.counts.shape}, got {m.dtype} {m.shape}")
        n = int(self.counts[m].sum())
        if n == 0:
            raise ValueError("no frames are labelled with any object of this group")
        return float(self.hits[m].sum() / n)


def _rates(hit: np.ndarray, target: np.ndarray, valid: np.ndarray, K: int) -> TargetRates:
    use = valid
    if not np.any(use):
        raise ValueError("no valid frames to score")
    t = target[use]
    counts = np.bincount(t, minlength=K)
    hits = np.bincount(t, weights=hit[use].astype(np.float64), minlength=K).astype(np.int64)
    present = counts > 0
    per = np.where(present, hits / np.maximum(counts, 1), 0.0)
    return TargetRates(
        per_object=per,
        hits=hits,
        counts=counts,
        mean=float(per[present].mean()),
        overall=float(hits.sum() / counts.sum()),
    )


def _targets(target, n: int, K: int, valid) -> tuple[np.ndarray, np.ndarray]:
    t = _labels("target", target, n)
    v = _valid_mask(valid, n)
    bad = v & ((t < 0) | (t >= K))
    if np.any(bad):
        raise ValueError(f"target must index the {K} objects (0 … {K - 1}) on valid frames, got {t[bad][0]}")
    return np.clip(t, 0, K - 1), v


def q1(points: Float[Array, "N 2"], boxes: Float[Array, "K 4"], target: Int[Array, " N"], *, valid=None) -> TargetRates:
    """``Q1`` (Yücel et al. 2013, eq. 14): per object, the fraction of its frames whose point lies in its box.

    The box edges count as inside.

    Args:
        points: estimated target points (px).
        boxes: ``(x_min, y_min, x_max, y_max)`` per object (px).
        target: attended object per point.
        valid: optional mask of points to score (e.g. :attr:`Pooled.valid`).
    """
    b = _boxes("boxes", boxes)
    p = _points("points", points)
    t, v = _targets(target, p.shape[0], b.shape[0], valid)
    bt = b[t]
    hit = (p[:, 0] >= bt[:, 0]) & (p[:, 0] <= bt[:, 2]) & (p[:, 1] >= bt[:, 1]) & (p[:, 1] <= bt[:, 3])
    return _rates(hit, t, v, b.shape[0])


def q2(points: Float[Array, "N 2"], centres: Float[Array, "K 2"], target: Int[Array, " N"], *, valid=None) -> TargetRates:
    """``Q2`` (Yücel et al. 2013, eq. 15): per object, the fraction of its frames whose nearest centre is its own.

    Strict: a point equally near another centre is a miss. Arguments as in :func:`q1`.
    """
    c = _points("centres", centres)
    if c.shape[0] < 1:
        raise ValueError("centres must hold at least one object")
    p = _points("points", points)
    t, v = _targets(target, p.shape[0], c.shape[0], valid)
    d2 = np.sum((p[:, None, :] - c[None, :, :]) ** 2, axis=-1)  # (N, K)
    own = d2[np.arange(p.shape[0]), t]
    others = np.where(np.arange(c.shape[0])[None, :] == t[:, None], np.inf, d2)
    hit = own < others.min(axis=1)
    return _rates(hit, t, v, c.shape[0])


# ---------------------------------------------------------------------------
# Angular metrics (CogSci)


def angular_errors(estimated: Float[Array, " N"], true: Float[Array, " N"]) -> Float[np.ndarray, " N"]:
    """Wrapped differences ``estimated − true`` in [−π, π] (radians)."""
    e = _host("estimated", estimated)
    t = _host("true", true)
    if e.shape != t.shape:
        raise ValueError(f"estimated and true must have the same shape, got {e.shape} and {t.shape}")
    return wrap_angle(e - t)


def mean_angular_deviation(estimated: Float[Array, " N"], true: Float[Array, " N"], *, valid=None) -> float:
    """Mean of ``|wrap(estimated − true)|`` (radians) over the (valid) frames: Q1 (Yücel et al. 2009, CogSci)."""
    err = angular_errors(estimated, true).reshape(-1)
    v = _valid_mask(valid, err.shape[0])
    if not np.any(v):
        raise ValueError("no valid frames to average over")
    return float(np.abs(err[v]).mean())


def cone_hits_box(
    head_centre: Float[Array, "... 2"],
    direction: Float[Array, "..."],
    box: Float[Array, "... 4"],
    tolerance: float = TOLERANCE,
) -> Bool[np.ndarray, "..."]:
    """Does the image-plane cone ``{p : |wrap(angle(p − a) − direction)| ≤ tolerance}`` with
    apex ``a = head_centre`` meet the closed ``box``? Exact, broadcasting over leading axes.

    If the apex is in the box, yes. Otherwise the box is convex and misses the
    apex, so the directions from the apex to its points form an arc shorter
    than π whose ends are directions to corners: measured from the direction
    of the box centre, the corner angles lie in (−π, π) and their min and max
    bound the arc. The cone meets the box iff its arc ``[d − tol, d + tol]``
    overlaps that arc: the wrapped gap between the arc centres is at most the
    sum of their half-widths.

    Raises:
        ValueError: NaN input, bad shapes, boxes with max < min, tolerance outside [0, π/2).
    """
    tol = _positive("tolerance", tolerance, open_hi=math.pi / 2)
    a = _host("head_centre", head_centre)
    d = _host("direction", direction)
    b = _host("box", box)
    if a.shape[-1:] != (2,):
        raise ValueError(f"head_centre must have shape (..., 2), got {a.shape}")
    if b.shape[-1:] != (4,):
        raise ValueError(f"box must have shape (..., 4), got {b.shape}")
    if np.any(b[..., 2] < b[..., 0]) or np.any(b[..., 3] < b[..., 1]):
        raise ValueError("box must have x_min ≤ x_max and y_min ≤ y_max")
    try:
        shape = np.broadcast_shapes(a.shape[:-1], d.shape, b.shape[:-1])
    except ValueError:
        raise ValueError(
            f"head_centre {a.shape}, direction {d.shape} and box {b.shape} do not broadcast together"
        ) from None
    ax, ay = a[..., 0], a[..., 1]
    x0, y0, x1, y1 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    inside = (ax >= x0) & (ax <= x1) & (ay >= y0) & (ay <= y1)
    phi_c = np.arctan2((y0 + y1) / 2 - ay, (x0 + x1) / 2 - ax)
    corner_x = np.stack([x0, x1, x1, x0], axis=-1)
    corner_y = np.stack([y0, y0, y1, y1], axis=-1)
    rel = wrap_angle(np.arctan2(corner_y - ay[..., None], corner_x - ax[..., None]) - phi_c[..., None])
    lo, hi = rel.min(axis=-1), rel.max(axis=-1)
    mid = phi_c + (lo + hi) / 2
    half = (hi - lo) / 2
    hit = np.abs(wrap_angle(d - mid)) <= half + tol
    return np.broadcast_to(inside | hit, shape).copy()


def disk_hits_box(
    centre: Float[Array, "... 2"], box: Float[Array, "... 4"], radius: float = MASK_RADIUS_PX
) -> Bool[np.ndarray, "..."]:
    """Does the closed disk of ``radius`` px around ``centre`` meet the closed ``box``?
    (Distance from the centre to the box ≤ radius.) Broadcasts over leading axes."""
    r = _positive("radius", radius)
    c = _host("centre", centre)
    b = _host("box", box)
    if c.shape[-1:] != (2,):
        raise ValueError(f"centre must have shape (..., 2), got {c.shape}")
    if b.shape[-1:] != (4,):
        raise ValueError(f"box must have shape (..., 4), got {b.shape}")
    if np.any(b[..., 2] < b[..., 0]) or np.any(b[..., 3] < b[..., 1]):
        raise ValueError("box must have x_min ≤ x_max and y_min ≤ y_max")
    dx = np.maximum(np.maximum(b[..., 0] - c[..., 0], c[..., 0] - b[..., 2]), 0.0)
    dy = np.maximum(np.maximum(b[..., 1] - c[..., 1], c[..., 1] - b[..., 3]), 0.0)
    return dx * dx + dy * dy <= r * r


def cone_rates(
    head_centre: Float[Array, "N 2"],
    direction: Float[Array, " N"],
    boxes: Float[Array, "K 4"],
    target: Int[Array, " N"],
    *,
    tolerance: float = TOLERANCE,
    valid=None,
) -> TargetRates:
    """Q2(h) (``direction`` = head direction) or Q2(hg) (regressed gaze direction) (Yücel et al. 2009, CogSci):
    per object, the fraction of its frames whose cone meets its box (:func:`cone_hits_box`)."""
    b = _boxes("boxes", boxes)
    a = _points("head_centre", head_centre)
    d = _host("direction", direction)
    if d.shape != (a.shape[0],):
        raise ValueError(f"direction must have shape ({a.shape[0]},), got {d.shape}")
    t, v = _targets(target, a.shape[0], b.shape[0], valid)
    return _rates(cone_hits_box(a, d, b[t], tolerance), t, v, b.shape[0])


def disk_rates(
    points: Float[Array, "N 2"],
    boxes: Float[Array, "K 4"],
    target: Int[Array, " N"],
    *,
    mask_radius: float = MASK_RADIUS_PX,
    valid=None,
) -> TargetRates:
    """Q2(hgd) (Yücel et al. 2009, CogSci): per object, the fraction of its target points whose disk of
    ``mask_radius`` px (the T-CYB mask σ) meets its box (:func:`disk_hits_box`)."""
    b = _boxes("boxes", boxes)
    p = _points("points", points)
    t, v = _targets(target, p.shape[0], b.shape[0], valid)
    return _rates(disk_hits_box(p, b[t], mask_radius), t, v, b.shape[0])


def cmc_curve(angular_errors: Float[Array, " N"], thresholds: Float[Array, " M"]) -> Float[np.ndarray, " M"]:
    """CMC curve (Yücel et al. 2009, CogSci, Fig. 5): accuracy ``mean(|wrap(error)| ≤ τ)`` per threshold ``τ ≥ 0``.

    Thresholds and errors in radians.
    Non-decreasing in τ and 1 for ``τ ≥ π``. Raises on NaN, empty errors or negative thresholds.
    """
    e = _host("angular_errors", angular_errors).reshape(-1)
    if e.size == 0:
        raise ValueError("angular_errors is empty")
    tau = _host("thresholds", thresholds)
    if tau.ndim != 1 or tau.size == 0:
        raise ValueError(f"thresholds must be a non-empty 1-D array, got shape {tau.shape}")
    if np.any(tau < 0):
        raise ValueError("thresholds must be ≥ 0")
    err = np.sort(np.abs(wrap_angle(e)))
    return np.searchsorted(err, tau, side="right") / err.size


# ---------------------------------------------------------------------------
# Train/test splits (T-CYB Sec. VII-D)


def _persons(sessions) -> np.ndarray:
    if isinstance(sessions, (str, bytes)) or not isinstance(sessions, Sequence):
        raise ValueError(f"sessions must be a sequence of sessions (or person ids), got {type(sessions).__name__}")
    if len(sessions) == 0:
        raise ValueError("sessions is empty")
    ids = []
    for i, s in enumerate(sessions):
        p = getattr(s, "person", s)
        if isinstance(p, bool) or not isinstance(p, (int, np.integer)):
            raise ValueError(f"sessions[{i}] has no integer person id (got {p!r})")
        ids.append(int(p))
    return np.asarray(ids)


def self_referencing_splits(sessions) -> list[tuple[list[int], list[int]]]:
    """Intraclass splits: train on one session of a person, test on another of the same person.

    ``sessions`` holds objects with a ``person`` attribute (e.g.
    :class:`~jaxgaze.simulate.tabletop.TabletopSession`) or plain person ids. One
    split ``([i], [j])`` per ordered pair ``i ≠ j`` of sessions of one person, in
    order of person then ``i`` then ``j``. People with a single session give none.

    Raises:
        ValueError: empty input, missing person ids, or no person with ≥ 2 sessions.
    """
    persons = _persons(sessions)
    splits = []
    for p in np.unique(persons):
        idx = np.flatnonzero(persons == p).tolist()
        splits += [([i], [j]) for i in idx for j in idx if i != j]
    if not splits:
        raise ValueError("self-referencing splits need a person with at least 2 sessions")
    return splits


def cross_referencing_splits(sessions) -> list[tuple[list[int], list[int]]]:
    """Interclass splits (leave one person out): train on all sessions of the other
    people, test on all sessions of one person.

    One split per held-out person (in increasing person id). T-CYB's
    cross-referencing trains and tests on different experimenters; training on
    every other experimenter (rather than on a single one) puts the spread
    *between* people into the training data, so the GP's noise level includes
    it and its intervals stay better calibrated for a new person. Input as in
    :func:`self_referencing_splits`.

    Raises:
        ValueError: empty input, missing person ids, or fewer than 2 people.
    """
    persons = _persons(sessions)
    people = np.unique(persons)
    if people.size < 2:
        raise ValueError(f"cross-referencing splits need at least 2 people, got {people.size}")
    return [
        (np.flatnonzero(persons != p).tolist(), np.flatnonzero(persons == p).tolist()) for p in people
    ]
