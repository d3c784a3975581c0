"""Scoring who looks at whom and where (Siegfried et al. 2017, eq. 1; Park et al. 2012, Sec. 4.1): the pipeline's
target rule, the least-squares intersection of rays, and probability calibration.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float, Int

__all__ = ["nearest_target", "ray_intersection", "expected_calibration_error", "reliability_curve"]


def nearest_target(
    directions: Float[np.ndarray, "T P 3"],
    eye_positions: Float[np.ndarray, "T P 3"],
    present: Bool[np.ndarray, "T P"],
    points: Float[np.ndarray, "T M 3"],
    points_valid: Bool[np.ndarray, "T M"],
    threshold: float = np.deg2rad(10.0),
) -> Int[np.ndarray, "T P"]:
    """The pipeline's target: the candidate nearest the gaze if within ``threshold`` (Siegfried et al. 2017, eq. 1).

    Candidates are the other people present (ids ``0 … P−1``) and the frame's
    points (ids ``P … P+M−1``, e.g. mean-shift modes); beyond the threshold, or
    absent, the target is −1 (elsewhere). ``directions`` are unit world-frame gaze
    directions.
    """
    T, P = present.shape
    targets = np.concatenate([eye_positions, points], axis=1)  # (T, P+M, 3)
    ok = np.concatenate([present, points_valid], axis=1)[:, None, :] & ~np.eye(P, P + points.shape[1], dtype=bool)[None]
    u = targets[:, None] - eye_positions[:, :, None]
    u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    angle = np.arccos(np.clip(np.einsum("tik,tijk->tij", directions, u), -1.0, 1.0))
    angle = np.where(ok, angle, np.inf)
    best = np.argmin(angle, axis=-1)
    hit = np.take_along_axis(angle, best[..., None], axis=-1)[..., 0] < threshold
    return np.where(hit & present, best, -1)


def ray_intersection(
    origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"], widths: Float[np.ndarray, " N"]
) -> Float[np.ndarray, "3"]:
    """Weighted least-squares point nearest to ``N ≥ 2`` rays (Park et al. 2012, Sec. 4.1, the oracle).

    Minimises ``Σ_i ‖(I − v_i v_iᵀ)(x − p_i)‖² / (w_i t_i)²`` with ``t_i`` each ray's
    depth at a first unweighted solution, so each ray counts by its cone's
    cross-section there: ``x = (Σ A_i)⁻¹ Σ A_i p_i``, ``A_i = (I − v_i v_iᵀ) / (w_i t_i)²``.
    """
    v = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    proj = np.eye(3)[None] - v[:, :, None] * v[:, None, :]

    def solve(weights):
        A = proj * weights[:, None, None]
        return np.linalg.solve(A.sum(0), np.einsum("nij,nj->i", A, origins))

    x = solve(np.ones(len(v)))
    depth = np.maximum(np.einsum("nk,nk->n", v, x - origins), 0.1)
    return solve(1.0 / np.square(widths * depth))


def reliability_curve(
    confidence: Float[np.ndarray, " N"], correct: Bool[np.ndarray, " N"], bins: int = 10
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per equal-width confidence bin: ``(mean confidence, accuracy, count)`` (NaN for empty bins)."""
    confidence = np.asarray(confidence, float).ravel()
    correct = np.asarray(correct, float).ravel()
    which = np.clip((confidence * bins).astype(int), 0, bins - 1)
    count = np.bincount(which, minlength=bins)
    with np.errstate(invalid="ignore"):
        mean_conf = np.bincount(which, confidence, bins) / count
        accuracy = np.bincount(which, correct, bins) / count
    return mean_conf, accuracy, count


def expected_calibration_error(
    confidence: Float[np.ndarray, " N"], correct: Bool[np.ndarray, " N"], bins: int = 10
) -> float:
    """``ECE = Σ_b (n_b / N) |accuracy_b − confidence_b|`` over equal-width bins (top-label calibration)."""
    mean_conf, accuracy, count = reliability_curve(confidence, correct, bins)
    used = count > 0
    if not used.any():
        raise ValueError("expected_calibration_error: no predictions")
    return float(np.sum(count[used] * np.abs(accuracy[used] - mean_conf[used])) / count.sum())
