"""Evaluation of estimated gaze concurrences against ground truth.

Park et al. (2012), Sec. 4.1, report the distance between each estimated gaze
concurrence and its motion-capture marker (10.1 ± 5.73 cm). Here estimates
and truths of a frame are paired by the Hungarian algorithm (minimum total
Euclidean distance, :func:`scipy.optimize.linear_sum_assignment`), then:

* localisation error: ``‖x̂_k − x_m‖`` over all matched pairs (metres);
* count accuracy: fraction of frames whose number of concurrences is right;
* coverage: fraction of matched pairs whose truth lies inside the estimate's
  ``level`` credible ellipsoid, ``(x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤ q``: ``q = χ²₃(level)``
  for a Gaussian, ``q = 3 (ν − 2)/ν · F⁻¹(level; 3, ν)`` for the Student-t with
  ``ν`` degrees of freedom and covariance ``Σ`` that
  :func:`~jaxgaze.concurrence.find_concurrences` reports.

Inputs are host arrays or JAX arrays; results are NumPy. The per-frame
Hungarian step runs on the host (it is a few small assignment problems).
Estimates are any object with ``locations (T, K, 3)``, ``valid (T, K)`` and,
for coverage, ``covariances (T, K, 3, 3)`` and optionally ``degrees_of_freedom
(T, K)`` (Gaussian without it) — e.g. the padded
:class:`~jaxgaze.concurrence.Concurrences` of ``find_concurrences_over_frames``.
A single frame (``(K, 3)``, no ``valid``) is accepted too.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2, f

__all__ = [
    "Matching",
    "FrameMatches",
    "Evaluation",
    "match_concurrences",
    "match_over_frames",
    "localisation_errors",
    "count_accuracy",
    "mahalanobis_squared",
    "region_threshold",
    "coverage",
    "region_coverage",
    "evaluate",
]


class Matching(NamedTuple):
    """Pairs ``(estimated[i], truth[i])`` and their distances (m) for one frame."""

    estimated: np.ndarray
    truth: np.ndarray
    distances: np.ndarray


class FrameMatches(NamedTuple):
    """Matched pairs over a recording: frame, estimate slot, truth slot, distance (m)."""

    frames: np.ndarray
    estimated: np.ndarray
    truth: np.ndarray
    distances: np.ndarray


class Evaluation(NamedTuple):
    """Summary of :func:`evaluate` (distances in metres)."""

    mean_error: float
    std_error: float
    median_error: float
    count_accuracy: float
    coverage: float
    level: float
    num_matched: int
    num_frames: int


def _points(name: str, a, ndim_extra: int = 0) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 + ndim_extra or a.shape[-1] != 3:
        want = "(K, 3)" if ndim_extra == 0 else "(T, K, 3)"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    return a


def match_concurrences(estimated, truth, *, max_distance: float | None = None) -> Matching:
    """Hungarian matching of estimated ``(K, 3)`` to true ``(M, 3)`` concurrences.

    Minimises ``Σ ‖x̂_i − x_j‖`` over one-to-one assignments; ``min(K, M)``
    pairs are returned (ordered by estimate index). With ``max_distance``
    (metres), pairs farther apart are dropped afterwards (counted as a miss
    and a false alarm).
    """
    est = _points("estimated", estimated)
    tru = _points("truth", truth)
    if max_distance is not None and not max_distance > 0:
        raise ValueError(f"max_distance must be positive, got {max_distance}")
    if len(est) == 0 or len(tru) == 0:
        empty = np.zeros(0, dtype=int)
        return Matching(empty, empty.copy(), np.zeros(0))
    cost = np.linalg.norm(est[:, None, :] - tru[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(cost)
    dist = cost[rows, cols]
    if max_distance is not None:
        keep = dist <= max_distance
        rows, cols, dist = rows[keep], cols[keep], dist[keep]
    return Matching(rows.astype(int), cols.astype(int), dist)


def _estimates(concurrences, need_covariances: bool = False):
    """``(locations (T,K,3), valid (T,K), covariances (T,K,3,3) | None)`` from an estimate object."""
    for field in ("locations",) + (("covariances",) if need_covariances else ()):
        if not hasattr(concurrences, field):
            raise ValueError(f"concurrences must have a '{field}' field (e.g. jaxgaze.Concurrences)")
    loc = np.asarray(concurrences.locations, dtype=float)
    single = loc.ndim == 2
    if single:
        loc = loc[None]
    if loc.ndim != 3 or loc.shape[-1] != 3:
        raise ValueError(
            f"concurrences.locations must have shape (T, K, 3) or (K, 3), got {np.shape(concurrences.locations)}"
        )
    valid = getattr(concurrences, "valid", None)
    valid = np.ones(loc.shape[:2], bool) if valid is None else np.asarray(valid, dtype=bool)
    if single and valid.ndim == 1:
        valid = valid[None]
    if valid.shape != loc.shape[:2]:
        raise ValueError(f"concurrences.valid shape {valid.shape} does not match locations {loc.shape[:2]}")
    cov = None
    if need_covariances:
        cov = np.asarray(concurrences.covariances, dtype=float)
        if single:
            cov = cov[None]
        if cov.shape != loc.shape[:2] + (3, 3):
            raise ValueError(f"concurrences.covariances must have shape {loc.shape[:2] + (3, 3)}, got {cov.shape}")
    return loc, valid, cov


def _truth(truth, truth_valid, num_frames: int):
    """``(locations (T,M,3), valid (T,M))`` from a Scene or arrays."""
    if hasattr(truth, "concurrence_valid") and hasattr(truth, "concurrences"):
        if truth_valid is not None:
            raise ValueError("truth_valid must be omitted when truth is a Scene (it carries concurrence_valid)")
        truth, truth_valid = truth.concurrences, truth.concurrence_valid
    loc = np.asarray(truth, dtype=float)
    if loc.ndim == 2:
        loc = loc[None]
        if truth_valid is not None and np.ndim(truth_valid) == 1:
            truth_valid = np.asarray(truth_valid)[None]
    if loc.ndim != 3 or loc.shape[-1] != 3:
        raise ValueError(f"truth must have shape (T, M, 3) or (M, 3), got {np.shape(truth)}")
    if loc.shape[0] != num_frames:
        raise ValueError(f"truth has {loc.shape[0]} frames but the estimates have {num_frames}")
    valid = np.ones(loc.shape[:2], bool) if truth_valid is None else np.asarray(truth_valid, dtype=bool)
    if valid.shape != loc.shape[:2]:
        raise ValueError(f"truth_valid shape {valid.shape} does not match truth {loc.shape[:2]}")
    return loc, valid


def match_over_frames(concurrences, truth, truth_valid=None, *, max_distance: float | None = None) -> FrameMatches:
    """Hungarian matching in every frame between valid estimates and valid truths.

    Args:
        concurrences: estimates with ``locations (T, K, 3)`` and ``valid (T, K)``.
        truth: true locations ``(T, M, 3)``, or a :class:`~jaxgaze.simulate.Scene`.
        truth_valid: ``(T, M)`` mask of real concurrences (all if omitted).
        max_distance: optional gate (m), see :func:`match_concurrences`.
    """
    loc, valid, _ = _estimates(concurrences)
    tloc, tvalid = _truth(truth, truth_valid, loc.shape[0])
    frames, est, tru, dist = [], [], [], []
    for t in range(loc.shape[0]):
        ei, ti = np.flatnonzero(valid[t]), np.flatnonzero(tvalid[t])
        m = match_concurrences(loc[t, ei], tloc[t, ti], max_distance=max_distance)
        frames.append(np.full(len(m.distances), t))
        est.append(ei[m.estimated])
        tru.append(ti[m.truth])
        dist.append(m.distances)
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    return FrameMatches(cat(frames, int), cat(est, int), cat(tru, int), cat(dist, float))


def localisation_errors(concurrences, truth, truth_valid=None, *, max_distance: float | None = None) -> np.ndarray:
    """Distances (m) between matched estimated and true concurrences, all frames pooled.

    ``concurrences`` is the padded result of ``find_concurrences_over_frames``
    (or one frame); ``truth`` is ``(T, M, 3)`` with ``truth_valid (T, M)``, or a
    :class:`~jaxgaze.simulate.Scene`. Missed and spurious concurrences do not
    contribute (see :func:`count_accuracy` for those).
    """
    return match_over_frames(concurrences, truth, truth_valid, max_distance=max_distance).distances


def count_accuracy(estimated_count, true_count) -> float:
    """Fraction of frames in which the number of concurrences is right."""
    est = np.asarray(estimated_count)
    tru = np.asarray(true_count)
    if est.ndim != 1 or tru.ndim != 1:
        raise ValueError(f"counts must be 1-D (T,), got {est.shape} and {tru.shape}")
    if est.shape != tru.shape:
        raise ValueError(f"estimated_count has {est.shape[0]} frames but true_count has {tru.shape[0]}")
    if est.size == 0:
        raise ValueError("count_accuracy needs at least one frame")
    return float(np.mean(est == tru))


def _matched_mahalanobis(concurrences, truth, truth_valid, max_distance):
    """``(x − x̂)ᵀ Σ⁻¹ (x − x̂)`` and the degrees of freedom (``inf``: Gaussian) of every matched pair."""
    loc, _, cov = _estimates(concurrences, need_covariances=True)
    dof = getattr(concurrences, "degrees_of_freedom", None)
    dof = np.full(loc.shape[:2], np.inf) if dof is None else np.asarray(dof, dtype=float).reshape(loc.shape[:2])
    matches = match_over_frames(concurrences, truth, truth_valid, max_distance=max_distance)
    tloc, _ = _truth(truth, truth_valid, loc.shape[0])
    diff = tloc[matches.frames, matches.truth] - loc[matches.frames, matches.estimated]
    sigma = cov[matches.frames, matches.estimated]
    if len(diff) == 0:
        return np.zeros(0), np.zeros(0)
    m2 = np.einsum("pi,pi->p", diff, np.linalg.solve(sigma, diff[..., None])[..., 0])
    return m2, dof[matches.frames, matches.estimated]


def mahalanobis_squared(concurrences, truth, truth_valid=None, *, max_distance: float | None = None) -> np.ndarray:
    """``(x − x̂)ᵀ Σ⁻¹ (x − x̂)`` for every matched pair, ``Σ`` = ``concurrences.covariances``.

    χ²₃ if the covariance is right and Gaussian; for a Student-t location
    (``degrees_of_freedom`` ``ν``) it is ``3 (ν − 2)/ν`` times an ``F(3, ν)`` variable.
    Compare it with :func:`region_threshold`.
    """
    return _matched_mahalanobis(concurrences, truth, truth_valid, max_distance)[0]


def region_threshold(level: float, degrees_of_freedom=np.inf) -> np.ndarray:
    """Bound ``q`` of the ``level`` region ``(x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤ q``, ``Σ`` the location's covariance.

    ``χ²₃⁻¹(level)`` for a Gaussian (``degrees_of_freedom = inf``); for a 3-D
    Student-t with ``ν > 2`` degrees of freedom and covariance ``Σ`` (scale matrix
    ``(ν − 2)/ν · Σ``) it is ``3 (ν − 2)/ν · F⁻¹(level; 3, ν)``, which tends to
    ``χ²₃⁻¹(level)`` as ``ν → ∞``. Broadcasts over ``degrees_of_freedom``.
    """
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    nu = np.asarray(degrees_of_freedom, dtype=float)
    if np.any(~(nu > 2)):
        raise ValueError("degrees_of_freedom must exceed 2 (the covariance of a t with ν ≤ 2 is infinite)")
    finite = np.isfinite(nu)
    safe = np.where(finite, nu, 3.0)
    t_bound = 3.0 * (safe - 2.0) / safe * f.ppf(level, 3, safe)
    return np.where(finite, t_bound, chi2.ppf(level, df=3))


def coverage(concurrences, truth, truth_valid=None, level: float = 0.9, *, max_distance: float | None = None) -> float:
    """Fraction of matched pairs whose truth lies in the estimate's ``level`` ellipsoid.

    The region is ``{x : (x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤ q}`` with ``Σ`` the estimate's
    covariance (``concurrences.covariances``) and ``q`` from
    :func:`region_threshold`: the Student-t bound for the estimate's
    ``degrees_of_freedom``, or ``χ²₃⁻¹(level)`` when it has none (Gaussian). A
    calibrated estimate gives coverage ≈ ``level``. Returns NaN when nothing matched.
    """
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    m2, dof = _matched_mahalanobis(concurrences, truth, truth_valid, max_distance)
    if m2.size == 0:
        return float("nan")
    return float(np.mean(m2 <= region_threshold(level, dof)))


def region_coverage(concurrences, truth, truth_valid=None, *, max_distance: float | None = None) -> float:
    """Fraction of matched truths inside the confidence region of their estimate (Park et al. 2012, Sec. 4.1).

    Park et al. (Sec. 4.1) draw the region ``{x : f(x) ≥ 0.8 f(mode)}`` and
    report that the markers are always inside it. It is a level set of the
    saliency field (how sharply the gaze agrees, about ``0.7 h`` times the viewing
    distance across the rays, whatever the number of viewers), not a confidence
    region for the location: on the simulated mocap scene it holds the marker in
    43.5 % of the frames. :func:`coverage` checks the location's uncertainty. With the region's principal
    axes ``A`` (columns) and semi-axes ``s`` (``concurrences.region_axes``,
    ``region_semi_axes``; ``inf`` along a flat direction) the test is
    ``Σ_i (a_iᵀ(x − x̂) / s_i)² ≤ 1``. Returns NaN when nothing matched.
    """
    loc, _, _ = _estimates(concurrences)
    for field in ("region_axes", "region_semi_axes"):
        if not hasattr(concurrences, field):
            raise ValueError(f"concurrences must have a '{field}' field (e.g. jaxgaze.Concurrences)")
    axes = np.asarray(concurrences.region_axes, dtype=float).reshape(loc.shape[:2] + (3, 3))
    semi = np.asarray(concurrences.region_semi_axes, dtype=float).reshape(loc.shape[:2] + (3,))
    matches = match_over_frames(concurrences, truth, truth_valid, max_distance=max_distance)
    if matches.distances.size == 0:
        return float("nan")
    tloc, _ = _truth(truth, truth_valid, loc.shape[0])
    diff = tloc[matches.frames, matches.truth] - loc[matches.frames, matches.estimated]
    y = np.einsum("pij,pi->pj", axes[matches.frames, matches.estimated], diff)
    return float(np.mean(np.sum((y / semi[matches.frames, matches.estimated]) ** 2, axis=-1) <= 1.0))


def evaluate(concurrences, scene, level: float = 0.9, *, max_distance: float | None = None) -> Evaluation:
    """Errors, count accuracy and coverage of a recording's estimates against a Scene."""
    errors = localisation_errors(concurrences, scene, max_distance=max_distance)
    valid = np.asarray(concurrences.valid, bool)
    count = valid.sum(axis=-1) if valid.ndim == 2 else valid.sum()[None]
    true_count = np.asarray(scene.concurrence_valid).sum(axis=-1)
    return Evaluation(
        mean_error=float(np.mean(errors)) if errors.size else float("nan"),
        std_error=float(np.std(errors)) if errors.size else float("nan"),
        median_error=float(np.median(errors)) if errors.size else float("nan"),
        count_accuracy=count_accuracy(count, true_count),
        coverage=coverage(concurrences, scene, level=level, max_distance=max_distance),
        level=float(level),
        num_matched=int(errors.size),
        num_frames=int(true_count.shape[0]),
    )
