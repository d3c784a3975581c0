"""Facial-feature localisation metrics (ROVIS gaze following, eq. 3–5).

``τ(m) = 1 / ‖(m_le + m_re)/2 − m_m‖`` (the eye-midpoint-to-mouth distance; the paper
prints it without the /2), the mean normalised deviation ``τ(m) (1/k) Σ ‖m_i − m̂_i‖``
and the maximal one ``τ(m) max ‖m_i − m̂_i‖``, over the ``k`` features present.
Features in the order of :data:`~jaxgaze.facial.face_model.FEATURES`
(right eye, left eye, nose, mouth).
"""

from __future__ import annotations

import numpy as np

__all__ = ["tau", "normalized_deviation", "cumulative_histogram"]


def _arr(name, x, shape_tail):
    x = np.asarray(x, float)
    if x.shape[-len(shape_tail):] != shape_tail:
        raise ValueError(f"{name} must have shape (..., {', '.join(map(str, shape_tail))}), got {x.shape}")
    return x


def tau(true_features) -> np.ndarray:
    """``τ = 1 / ‖(m_le + m_re)/2 − m_m‖`` for true feature centres ``(..., 4, 2)`` (ROVIS gaze following, eq. 3–5).

    Raises ValueError on NaN or a degenerate face (eye midpoint on the mouth)."""
    m = _arr("true_features", true_features, (4, 2))
    if not np.all(np.isfinite(m)):
        raise ValueError("true_features contains NaN or inf")
    d = np.linalg.norm(0.5 * (m[..., 0, :] + m[..., 1, :]) - m[..., 3, :], axis=-1)
    if np.any(d <= 0):
        raise ValueError("degenerate face: the eye midpoint coincides with the mouth")
    return 1.0 / d


def normalized_deviation(true_features, estimated, present=None):
    """Mean and max normalised deviation (ROVIS gaze following, eq. 3, 5), each ``(...,)``.

    ``estimated (..., 4, 2)`` may hold NaN for features it did not estimate;
    ``present (..., 4)`` (default: the finite estimates) picks the features compared.
    A face with no feature present gets NaN.

    Raises:
        ValueError: shapes, NaN truth, or a present feature with a NaN estimate.
    """
    t = tau(true_features)
    m = np.asarray(true_features, float)
    e = _arr("estimated", estimated, (4, 2))
    finite = np.all(np.isfinite(e), -1)
    present = finite if present is None else np.asarray(present, bool)
    if present.shape != e.shape[:-1]:
        raise ValueError(f"present must have shape {e.shape[:-1]}, got {present.shape}")
    if np.any(present & ~finite):
        raise ValueError("a present feature has a NaN/inf estimate")
    dist = np.linalg.norm(np.where(present[..., None], e - m, 0.0), axis=-1)
    k = present.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(k > 0, t * dist.sum(-1) / k, np.nan)
        mx = np.where(k > 0, t * np.where(present, dist, -np.inf).max(-1), np.nan)
    return mean, mx


def cumulative_histogram(deviations, thresholds) -> np.ndarray:
    """Fraction of faces with deviation ≤ each threshold; NaN deviations (no estimate) count as failures."""
    d = np.asarray(deviations, float).ravel()
    th = np.asarray(thresholds, float)
    if d.size == 0:
        raise ValueError("no deviations")
    if not np.all(np.isfinite(th)):
        raise ValueError("thresholds contain NaN or inf")
    ok = np.where(np.isnan(d), np.inf, d)
    return (ok[None, :] <= th.reshape(-1, 1)).mean(1).reshape(th.shape)
