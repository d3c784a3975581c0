"""Evaluate the head-pose regressors on table-top sessions: T-CYB Table I and the CogSci table.

For one train/test split (:func:`~jaxgaze.headpose.target.self_referencing_splits`,
:func:`~jaxgaze.headpose.target.cross_referencing_splits`) the regressors of
:mod:`jaxgaze.headpose.regression` (GPR or the NN baseline) are fitted on the
training sessions' head poses and scored on each test session:

* **T-CYB** (eq. 14–15): the target point (direction ``f1`` meets row ``f2``,
  :func:`~jaxgaze.headpose.target.target_point`) per frame; Q1 = inside the attended
  box, Q2 = the attended centre is the nearest; mean over objects, as in Table I.
  ``pooled`` scores average the points over ``window`` frames first. The
  head-pose baseline replaces ``f1`` by the raw head direction in the image and
  keeps the regressed depth, so it differs from GPR in the direction only.
* **CogSci** (Table 1): Q1 = mean angular deviation of ``f1`` (radians); Q2(h)
  and Q2(hg) = the 3π/64 cone around the head / regressed direction meets the
  attended box; Q2(hgd) = the 10 px disk around the target point meets it;
  each for the near, far, central and peripheral objects.
* **Calibration** (GPR): the fraction of true ``f1`` inside the 90 % predictive interval.

Scores of several test sessions are pooled by summing hits and counts per object
group (CogSci) or averaging the per-session means (T-CYB).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxgaze.headpose import target as tg
from jaxgaze.headpose.regression import fit_gaze_regression, fit_gaze_regression_nn
from jaxgaze.simulate.tabletop import TabletopSession, session_features

__all__ = ["GROUPS", "RegressionScores", "evaluate_split", "evaluate_regression", "format_table_i",
           "format_cogsci_table"]

GROUPS = ("near", "far", "central", "peripheral")
_Z90 = 1.6448536269514722  # the 95th percentile of N(0, 1): a central 90 % interval


class RegressionScores(NamedTuple):
    """Scores of one method on one split (or the mean over splits).

    Attributes:
        method: ``"gpr"`` or ``"nn"``; split: ``"self"`` or ``"cross"``.
        q1, q2: T-CYB eq. 14–15 per frame; q1_pooled, q2_pooled: after pooling.
        q2_head: eq. 15 with the raw head direction (and the regressed depth).
        mean_angular_deviation, head_mean_angular_deviation: of ``f1`` (radians).
        coverage_90: fraction of true ``f1`` inside the 90 % predictive interval (NaN for the NN).
        cogsci: ``{group: (Q1 deviation, Q2(h), Q2(hg), Q2(hgd))}`` for :data:`GROUPS`.
        angular_errors: ``|wrap(f1 − f1_true)|`` of every test frame (for the CMC curve).
        head_angular_errors: the same for the raw head direction.
    """

    method: str
    split: str
    q1: float
    q2: float
    q1_pooled: float
    q2_pooled: float
    q2_head: float
    mean_angular_deviation: float
    head_mean_angular_deviation: float
    coverage_90: float
    cogsci: dict
    angular_errors: np.ndarray
    head_angular_errors: np.ndarray


def training_data(sessions, indices, max_frames):
    """Head poses ``X (T, 3)`` and targets ``f1``, ``f2`` of the sessions ``indices``, thinned
    evenly to at most ``max_frames`` frames (``None``: all)."""
    X = np.concatenate([np.asarray(session_features(sessions[i])) for i in indices])
    f1 = np.concatenate([np.asarray(sessions[i].gaze_direction_image) for i in indices])
    f2 = np.concatenate([np.asarray(sessions[i].target_depth_image) for i in indices])
    if max_frames is not None and len(X) > max_frames:
        keep = np.linspace(0, len(X) - 1, max_frames).round().astype(int)  # even thinning: frames are correlated
        X, f1, f2 = X[keep], f1[keep], f2[keep]
    return X, f1, f2


def fit_regressor(method, X, f1, f2, key):
    """``fit_gaze_regression`` (``method="gpr"``) or ``fit_gaze_regression_nn`` (``"nn"``)."""
    if method == "gpr":
        return fit_gaze_regression(X, f1, f2, key=key)
    if method == "nn":
        return fit_gaze_regression_nn(X, f1, f2, key=key)
    raise ValueError(f"method must be 'gpr' or 'nn', got {method!r}")


def _group_masks(session: TabletopSession) -> dict:
    near, central = np.asarray(session.object_is_near), np.asarray(session.object_is_central)
    return {"near": near, "far": ~near, "central": central, "peripheral": ~central}


def evaluate_split(
    sessions: Sequence[TabletopSession],
    train: Sequence[int],
    test: Sequence[int],
    *,
    method: str,
    key,
    split: str = "",
    window: int = 4,
    max_train_frames: int | None = 600,
) -> RegressionScores:
    """Fit ``method`` on the ``train`` sessions and score it on the ``test`` sessions.

    ``max_train_frames`` thins the training frames evenly (consecutive frames at
    10 fps are strongly correlated; exact GPR costs O(n³)). ``window`` is the
    pooling bin (4 frames at 10 fps in T-CYB).
    """
    if not train or not test:
        raise ValueError("train and test must each name at least one session")
    model = fit_regressor(method, *training_data(sessions, train, max_train_frames), key)
    per_session = {name: [] for name in ("q1", "q2", "q1p", "q2p", "q2h")}
    errors, head_errors, inside = [], [], []
    group_hits = {g: np.zeros(3) for g in GROUPS}
    group_counts = {g: 0 for g in GROUPS}
    group_dev = {g: [] for g in GROUPS}
    for i in test:
        s = sessions[i]
        pred = model.predict(session_features(s))
        direction, depth = np.asarray(pred.direction), np.asarray(pred.depth)
        truth = np.asarray(s.gaze_direction_image)
        points = np.asarray(tg.target_point(s.head_centre_image, direction, depth))
        head_points = np.asarray(tg.target_point(s.head_centre_image, s.head_direction_image, depth))
        per_session["q1"].append(tg.q1(points, s.object_boxes_image, s.target).mean)
        per_session["q2"].append(tg.q2(points, s.object_centres_image, s.target).mean)
        per_session["q2h"].append(tg.q2(head_points, s.object_centres_image, s.target).mean)
        pooled = tg.pool(points, window, labels=s.target)
        per_session["q1p"].append(tg.q1(pooled.values, s.object_boxes_image, pooled.labels, valid=pooled.valid).mean)
        per_session["q2p"].append(tg.q2(pooled.values, s.object_centres_image, pooled.labels, valid=pooled.valid).mean)
        err = np.abs(tg.angular_errors(direction, truth))
        errors.append(err)
        head_err = np.abs(tg.angular_errors(s.head_direction_image, truth))
        head_errors.append(head_err)
        if pred.direction_variance is not None:
            inside.append(err <= _Z90 * np.sqrt(np.asarray(pred.direction_variance)))
        rates = (
            tg.cone_rates(s.head_centre_image, s.head_direction_image, s.object_boxes_image, s.target),
            tg.cone_rates(s.head_centre_image, direction, s.object_boxes_image, s.target),
            tg.disk_rates(points, s.object_boxes_image, s.target),
        )
        target = np.asarray(s.target)
        for g, mask in _group_masks(s).items():
            in_group = mask[target]
            group_dev[g].append(err[in_group])
            group_counts[g] += int(rates[0].counts[mask].sum())
            group_hits[g] += [int(r.hits[mask].sum()) for r in rates]
    cogsci = {}
    for g in GROUPS:
        dev = np.concatenate(group_dev[g])
        n = group_counts[g]
        cogsci[g] = (float(dev.mean()) if dev.size else math.nan, *(group_hits[g] / n if n else [math.nan] * 3))
    errors, head_errors = np.concatenate(errors), np.concatenate(head_errors)
    return RegressionScores(
        method, split,
        *(float(np.mean(per_session[k])) for k in ("q1", "q2", "q1p", "q2p", "q2h")),
        float(errors.mean()), float(head_errors.mean()),
        float(np.mean(np.concatenate(inside))) if inside else math.nan,
        cogsci, errors, head_errors,
    )


def _mean_scores(scores: list[RegressionScores]) -> RegressionScores:
    first = scores[0]
    def average(values):
        values = np.asarray(values, dtype=float)
        return float(values[~np.isnan(values)].mean()) if np.any(~np.isnan(values)) else math.nan

    numbers = {f: average([getattr(s, f) for s in scores]) for f in RegressionScores._fields[2:10]}
    cogsci = {g: tuple(average(column) for column in zip(*(s.cogsci[g] for s in scores))) for g in GROUPS}
    return first._replace(
        **numbers, cogsci=cogsci,
        angular_errors=np.concatenate([s.angular_errors for s in scores]),
        head_angular_errors=np.concatenate([s.head_angular_errors for s in scores]),
    )


def evaluate_regression(
    sessions: Sequence[TabletopSession],
    *,
    key,
    methods: Sequence[str] = ("gpr", "nn"),
    window: int = 4,
    max_splits: int | None = None,
    max_train_frames: int | None = 600,
    progress: bool = False,
) -> list[RegressionScores]:
    """Scores of each method on the self- and cross-referencing splits, averaged over splits.

    ``max_splits`` keeps the first few splits of each kind (full runs use all).
    Returns one :class:`RegressionScores` per (split kind, method).
    """
    from tqdm.auto import tqdm

    kinds = {"self": tg.self_referencing_splits(sessions), "cross": tg.cross_referencing_splits(sessions)}
    jobs = [(kind, m, tr, te) for kind, splits in kinds.items() for m in methods
            for tr, te in splits[: max_splits or len(splits)]]
    keys = jax.random.split(key, len(jobs))
    results = {}
    for (kind, m, tr, te), k in zip(tqdm(jobs, desc="splits", disable=not progress), keys):
        results.setdefault((kind, m), []).append(
            evaluate_split(sessions, tr, te, method=m, key=k, split=kind, window=window,
                           max_train_frames=max_train_frames))
    return [_mean_scores(v) for v in results.values()]


def format_table_i(scores: Sequence[RegressionScores]) -> str:
    """T-CYB Table I, regression-only columns: Q1 and Q2 per method and split (and the head-pose baseline)."""
    lines = ["| method | split | Q1 | Q2 | Q1 pooled | Q2 pooled | Q2 head pose | f1 dev (rad) | 90% coverage |",
             "|---|---|---|---|---|---|---|---|---|"]
    for s in scores:
        cov = "–" if math.isnan(s.coverage_90) else f"{s.coverage_90:.2f}"
        lines.append(f"| {s.method.upper()} | {s.split} | {s.q1:.2f} | {s.q2:.2f} | {s.q1_pooled:.2f} | "
                     f"{s.q2_pooled:.2f} | {s.q2_head:.2f} | {s.mean_angular_deviation:.3f} | {cov} |")
    return "\n".join(lines)


def format_cogsci_table(score: RegressionScores) -> str:
    """The CogSci table: Q1 deviation (rad) and Q2(h / hg / hgd) for near, far, central, peripheral."""
    rows = [("Q1 (rad)", 0), ("Q2(h)", 1), ("Q2(hg)", 2), ("Q2(hgd)", 3)]
    lines = [f"{score.method.upper()}, {score.split}-referencing", "| quality | " + " | ".join(GROUPS) + " |",
             "|---|" + "---|" * len(GROUPS)]
    for label, j in rows:
        lines.append(f"| {label} | " + " | ".join(f"{score.cogsci[g][j]:.2f}" for g in GROUPS) + " |")
    return "\n".join(lines)
