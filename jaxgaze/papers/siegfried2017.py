"""Evaluation of speaker-prior gaze-bias adaptation (Siegfried, Odobez et al. 2017, Sec. 4, Table 1, Figs. 5–6).

For every person of a batch of simulated dyads (:func:`jaxgaze.simulate.dyadic.simulate_dyadic_sessions`)
:func:`evaluate_bias_methods` estimates the gaze bias ``b`` from the first minute
(the *adaptation window*) with the paper's methods and scores the corrected gaze
``g + b`` on the rest of the recording:

===============  =============================================================================
method           bias from
===============  =============================================================================
``baseline``     nothing, ``b = 0`` (the paper's *Baseline*)
``spk_mean``     the mean of the offsets of ``N = 20`` Spk frames (partner speaks, head–target
                 angle ≤ 30°, in the window; Sec. 3.2)
``spk_med``      LMedS (eq. 2) on ``N = 40`` Spk frames, then the mean of the 20 closest
``gt_mean``      the mean over 20 frames drawn from the ground-truth looking frames of the
                 window (the oracle *GT-Mean*)
``gt_med``       LMedS on 40 ground-truth looking frames (*GT-Med*)
``bayes``        ours: the posterior mean of the Bayesian mixture
                 (:func:`jaxgaze.bias.estimators.bias_model`) on the Spk candidates of the
                 window thinned to one frame per ``bayes_spacing_s`` (at most ``num_bayes``),
                 contrasted with the silent-partner frames of the window (same head
                 filter, thinned the same way, at most ``4 · num_bayes``)
===============  =============================================================================

Frames and metrics (Sec. 4.1, "Performance Measures"):

* **Evaluated frames** are all frames at or after the end of the adaptation window,
  ``t / fps ≥ window_start_s + window_s`` (the paper scores the annotated frames "after
  the first minute"; the simulator annotates every frame).
* **Mean angular error** of a person: the mean of ``e = ∠(Φ(g + b), u_t)`` (eq. 1) over
  the evaluated frames where the person truly looks at the partner (ground truth
  ``looking``), in degrees. A table entry is the mean of the per-person means.
* **Accuracy** of a person: the share of evaluated frames where the decision
  ``e < τ`` (``τ = 10°``) equals the ground truth (looking or not). A table entry is the
  mean of the per-person accuracies.
* For ``bayes`` also the decision ``P(e < τ | data) > 0.5`` with the probability from
  the posterior draws (:func:`jaxgaze.bias.looking.looking_probability`), and the
  coverage of the 90% credible region of ``b``: the true bias lies inside when its
  squared Mahalanobis distance from the posterior mean, under the covariance of the
  draws, is below the χ²₂ quantile ``−2 ln(1 − 0.9) = 4.61`` (the Gaussian
  approximation of the 90% highest-density region).
* Fig. 5: the per-person mean angular error in time bins of ``time_bin_s`` seconds
  after the window; Fig. 6: the per-person accuracy for thresholds ``τ`` of 2°…20°.

Frame draws use one ``jax.random`` key and are vectorised over people (a random
ranking of the allowed frames), not :func:`jaxgaze.bias.looking.select_frames`,
which draws one person at a time and compiles a permutation per candidate count.
The candidates are the same (:func:`candidate_frames`) and the
draw is the same distribution: ``N`` frames uniformly without replacement. The
Spk-Mean frames are the first 20 of the Spk-Med draw and the GT-Mean frames the
first 20 of the GT-Med draw (common random numbers: the comparison between methods
is less noisy than with independent draws).

Why the Bayes frames are thinned, not drawn at random: the estimator noise is
correlated over about 0.1 s (lag-1 autocorrelation ≈ 0.65 at 30 fps, ≈ 0.05 at 10
frames), and the mixture treats frames as independent. Random frames from the ~15–
25 s of candidates land close together often enough that the posterior is too
narrow. Taking every ``k``-th candidate, ``k ≥ bayes_spacing_s · fps`` (10 frames),
uses the whole minute with nearly independent frames: ``N ≈ 40–64`` per person,
about twice the 20 inliers that Spk-Med averages.

All angles are radians inside; names ending ``_deg`` hold degrees
(``docs/conventions.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray
from scipy.stats import chi2

from jaxgaze.bias.estimators import lmeds_bias, sample_bias_posterior
from jaxgaze.bias.looking import (
    angular_error,
    candidate_frames,
    gaze_offsets,
    head_target_angle,
    looking_probability,
    target_direction_head,
)
from jaxgaze.geometry import deg_to_rad

__all__ = [
    "METHODS",
    "METHOD_LABELS",
    "PAPER_TABLE1",
    "BAYES_MODEL_OPTIONS",
    "BiasEvaluation",
    "evaluate_bias_methods",
    "random_frames",
    "thinned_frames",
    "mean_angular_error_deg",
    "classification_accuracy",
    "error_by_time_deg",
    "accuracy_by_threshold",
    "credible_region_covers",
    "chi2_2dof_quantile",
    "format_table1",
    "format_figure_tables",
]

METHODS = ("baseline", "spk_mean", "spk_med", "gt_mean", "gt_med", "bayes")
METHOD_LABELS = {
    "baseline": "Baseline",
    "spk_mean": "Spk-Mean",
    "spk_med": "Spk-Med",
    "gt_mean": "GT-Mean",
    "gt_med": "GT-Med",
    "bayes": "Bayes (ours)",
}

#: The paper's Table 1 (mean angular error in degrees, accuracy), rows *Baseline* and
#: *Lm + …* (the bias corrections after landmark alignment, its best rows), by scenario.
PAPER_TABLE1 = {
    "interview": {"baseline": (21.04, 0.53), "spk_mean": (7.92, 0.73), "spk_med": (6.25, 0.82),
                  "gt_mean": (5.61, 0.85), "gt_med": (5.67, 0.84)},
    "desk": {"baseline": (26.19, 0.59), "spk_mean": (9.26, 0.80), "spk_med": (9.03, 0.81),
             "gt_mean": (8.85, 0.82), "gt_med": (8.94, 0.82)},
    "overall": {"baseline": (23.62, 0.56), "spk_mean": (8.59, 0.77), "spk_med": (7.64, 0.82),
                "gt_mean": (7.23, 0.84), "gt_med": (7.30, 0.83)},
}

#: Options of :func:`jaxgaze.bias.estimators.bias_model` used for ``bayes``: none, the
#: evaluation runs the model a user gets. (Its uniform "elsewhere" box exerts no pull on
#: ``b``, so the simulator's one-sided clusters of glances away, 25°–55° from ``b``, need
#: no wider component.)
BAYES_MODEL_OPTIONS: dict = {}


def chi2_2dof_quantile(level: float) -> float:
    """Quantile of χ² with 2 degrees of freedom (``scipy.stats.chi2.ppf``; ``−2 ln(1 − level)``, 4.605 for 0.9)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    return float(chi2.ppf(level, df=2))


# --------------------------------------------------------------------------- frames


def random_frames(
    key: PRNGKeyArray, allowed: Bool[Array, "n T"], num_frames: int
) -> tuple[Int[Array, "n K"], Bool[Array, "n K"]]:
    """Draw ``num_frames`` of each row's allowed frames uniformly without replacement (vectorised).

    Every frame gets a uniform random score, disallowed frames sort last, and the
    first ``K = num_frames`` frames of the ranking are taken. Returns
    ``(indices (n, K), valid (n, K))``; ``valid`` is ``False`` for the slots left
    when a row has fewer than ``K`` allowed frames (their indices point at disallowed
    frames and must be masked). The first ``k`` columns are themselves a uniform draw
    of ``k`` frames. Jittable.
    """
    allowed = jnp.asarray(allowed, bool)
    if allowed.ndim != 2:
        raise ValueError(f"allowed must have shape (n, T), got {allowed.shape}")
    k = int(num_frames)
    if k < 1 or k > allowed.shape[1]:
        raise ValueError(f"num_frames must be in 1 … {allowed.shape[1]}, got {num_frames}")
    score = jax.random.uniform(key, allowed.shape)
    score = jnp.where(allowed, score, 2.0)
    indices = jnp.argsort(score, axis=1)[:, :k]
    return indices, jnp.take_along_axis(allowed, indices, axis=1)


def thinned_frames(
    key: PRNGKeyArray, allowed: Bool[Array, "n T"], *, min_stride: int, max_frames: int
) -> tuple[Int[Array, "n K"], Bool[Array, "n K"]]:
    """Every ``s``-th allowed frame of each row, from a random start (vectorised).

    The allowed frames of a row are numbered ``r = 0, 1, …`` in time order; frame
    ``r`` is kept when ``(r + start) mod s == 0`` with ``s = max(min_stride,
    ⌈n_allowed / max_frames⌉)`` and ``start`` uniform in ``0 … s − 1``. Consecutive
    kept frames are at least ``min_stride`` frames apart, and at most ``max_frames``
    are kept. Returns ``(indices (n, max_frames), valid (n, max_frames))``, kept frames
    first, in time order. Jittable.
    """
    allowed = jnp.asarray(allowed, bool)
    if allowed.ndim != 2:
        raise ValueError(f"allowed must have shape (n, T), got {allowed.shape}")
    if int(min_stride) < 1 or int(max_frames) < 1:
        raise ValueError(f"min_stride and max_frames must be positive, got {min_stride}, {max_frames}")
    n, T = allowed.shape
    k = min(int(max_frames), T)
    count = jnp.sum(allowed, axis=1)
    stride = jnp.maximum(int(min_stride), -(-count // k))  # ⌈count / k⌉
    start = jnp.floor(jax.random.uniform(key, (n,)) * stride).astype(jnp.int32)
    rank = jnp.cumsum(allowed, axis=1) - 1
    keep = allowed & ((rank + start[:, None]) % stride[:, None] == 0)
    order = jnp.argsort(jnp.where(keep, jnp.arange(T)[None, :], T + jnp.arange(T)[None, :]), axis=1)[:, :k]
    return order, jnp.take_along_axis(keep, order, axis=1)


# -------------------------------------------------------------------------- metrics


def _masked_mean(values, mask, axis=-1):
    mask = jnp.asarray(mask, bool)
    total = jnp.sum(jnp.where(mask, values, 0.0), axis=axis)
    count = jnp.sum(mask, axis=axis)
    return jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan)


def mean_angular_error_deg(
    error: Float[Array, "... T"], looking: Bool[Array, "... T"], frames: Bool[Array, "... T"]
) -> Float[Array, "..."]:
    """Mean angular error (degrees) over the evaluated ``frames`` where the person truly looks.

    ``error`` is ``e`` of eq. 1 in radians (e.g. :func:`jaxgaze.bias.looking.angular_error`).
    NaN when no evaluated frame is a looking frame. Broadcasts over leading axes.
    """
    e = jnp.rad2deg(jnp.asarray(error))
    return _masked_mean(e, jnp.asarray(looking, bool) & jnp.asarray(frames, bool))


def classification_accuracy(
    predicted: Bool[Array, "... T"], looking: Bool[Array, "... T"], frames: Bool[Array, "... T"]
) -> Float[Array, "..."]:
    """Share of the evaluated ``frames`` where the looking-at decision equals the ground truth.

    ``predicted`` is e.g. ``error < τ`` (eq. 1). NaN when no frame is evaluated.
    """
    correct = jnp.asarray(predicted, bool) == jnp.asarray(looking, bool)
    frames = jnp.broadcast_to(jnp.asarray(frames, bool), correct.shape)
    return _masked_mean(correct.astype(jnp.float32), frames)


def error_by_time_deg(
    error: Float[Array, "... T"],
    looking: Bool[Array, "... T"],
    times_s: Float[Array, " T"],
    bin_edges_s: Float[Array, " B1"],
) -> Float[Array, "... B"]:
    """Fig. 5: the mean angular error (degrees) of the looking frames in each time bin.

    Bin ``j`` holds the frames with ``bin_edges_s[j] ≤ t < bin_edges_s[j + 1]``; NaN
    for a bin without looking frames.
    """
    t = jnp.asarray(times_s)
    edges = jnp.asarray(bin_edges_s)
    in_bin = (t[None, :] >= edges[:-1, None]) & (t[None, :] < edges[1:, None])  # (B, T)
    e = jnp.asarray(error)[..., None, :]
    lk = jnp.asarray(looking, bool)[..., None, :]
    return mean_angular_error_deg(e, lk, in_bin)


def accuracy_by_threshold(
    error: Float[Array, "... T"],
    looking: Bool[Array, "... T"],
    frames: Bool[Array, "... T"],
    thresholds_deg: Float[Array, " K"],
) -> Float[Array, "... K"]:
    """Fig. 6: the accuracy of the decision ``e < τ`` for each threshold ``τ`` (degrees)."""
    tau = deg_to_rad(jnp.asarray(thresholds_deg, jnp.float32))
    e = jnp.asarray(error)[..., None, :]
    predicted = e < tau[:, None]
    return classification_accuracy(predicted, jnp.asarray(looking, bool)[..., None, :],
                                   jnp.asarray(frames, bool)[..., None, :])


def credible_region_covers(
    draws: Float[Array, "... S 2"], truth: Float[Array, "... 2"], level: float = 0.9
) -> tuple[Bool[np.ndarray, "..."], Float[np.ndarray, "..."]]:
    """Does the ``level`` credible region of the draws contain ``truth``?

    The region is the Gaussian approximation of the highest-density region:
    ``d² = (x − m)ᵀ C⁻¹ (x − m) ≤ χ²₂(level)``, with ``m`` and ``C`` the mean and
    covariance (``ddof = 1``) of the draws. Returns ``(covered, d²)``.
    """
    d = np.asarray(draws, np.float64)
    x = np.asarray(truth, np.float64)
    if d.ndim < 2 or d.shape[-1] != 2 or x.shape[-1] != 2 or d.shape[:-2] != x.shape[:-1]:
        raise ValueError(f"draws must be (..., S, 2) and truth (..., 2) with the same leading axes, "
                         f"got {d.shape} and {x.shape}")
    mean = d.mean(axis=-2)
    centred = d - mean[..., None, :]
    cov = np.einsum("...si,...sj->...ij", centred, centred) / (d.shape[-2] - 1)
    diff = x - mean
    m2 = np.einsum("...i,...i->...", diff, np.linalg.solve(cov, diff[..., None])[..., 0])
    return m2 <= chi2_2dof_quantile(level), m2


# ----------------------------------------------------------------------- evaluation


class BiasEvaluation(NamedTuple):
    """Per-person results of :func:`evaluate_bias_methods` (``n`` people, ``M`` methods).

    Angles in radians unless named ``_deg``. Aggregates: :meth:`aggregate`, :meth:`figure5`,
    :meth:`figure6`; printed with :func:`format_table1` and :func:`format_figure_tables`.

    Attributes:
        methods: the ``M`` method names, :data:`METHODS`.
        scenario: ``(n,)`` the preset of each person's recording.
        session: ``(n,)`` session index in its batch; ``person``: ``(n,)`` person (0 or 1).
        true_bias: ``(n, 2)`` the simulated bias.
        bias: ``(n, M, 2)`` the estimates (0 for ``baseline``, and for a method that
            had no frame).
        error_deg: ``(n, M)`` mean angular error on the evaluated looking frames.
        accuracy: ``(n, M)`` accuracy at ``threshold_deg`` on the evaluated frames.
        bayes_prob_accuracy: ``(n,)`` accuracy of ``P(e < τ | data) > 0.5``.
        bias_draws: ``(n, S, 2)`` posterior draws of ``b`` (chains flattened).
        mahalanobis2: ``(n,)`` ``d²`` of the true bias under the posterior (Gaussian approx.).
        covered: ``(n,)`` the true bias is inside the ``credible_level`` region.
        num_candidates: ``(n,)`` Spk candidate frames in the window.
        spk_precision: ``(n,)`` share of the Spk candidates truly looking at the partner.
        num_bayes_frames: ``(n,)`` frames the mixture saw.
        num_gt_frames: ``(n,)`` ground-truth looking frames in the window.
        divergences: ``(n,)`` divergent NUTS transitions after warm-up.
        time_bin_edges_s: ``(B + 1,)`` Fig. 5 bin edges (seconds from the recording start).
        error_by_time_deg: ``(n, M, B)``.
        thresholds_deg: ``(K,)`` Fig. 6 thresholds.
        accuracy_by_threshold: ``(n, M, K)``.
        settings: the options of the run.
    """

    methods: tuple[str, ...]
    scenario: np.ndarray
    session: np.ndarray
    person: np.ndarray
    true_bias: np.ndarray
    bias: np.ndarray
    error_deg: np.ndarray
    accuracy: np.ndarray
    bayes_prob_accuracy: np.ndarray
    bias_draws: np.ndarray
    mahalanobis2: np.ndarray
    covered: np.ndarray
    num_candidates: np.ndarray
    spk_precision: np.ndarray
    num_bayes_frames: np.ndarray
    num_gt_frames: np.ndarray
    divergences: np.ndarray
    time_bin_edges_s: np.ndarray
    error_by_time_deg: np.ndarray
    thresholds_deg: np.ndarray
    accuracy_by_threshold: np.ndarray
    settings: dict

    @property
    def num_people(self) -> int:
        return int(self.scenario.shape[0])

    @property
    def scenarios(self) -> list[str]:
        """The scenarios in order of first appearance."""
        return list(dict.fromkeys(self.scenario.tolist()))

    def groups(self) -> dict[str, np.ndarray]:
        """Boolean person masks per scenario, plus ``"overall"`` (all people)."""
        out = {s: self.scenario == s for s in self.scenarios}
        out["overall"] = np.ones(self.num_people, bool)
        return out

    def method_index(self, method: str) -> int:
        return self.methods.index(method)

    def aggregate(self) -> dict[str, dict]:
        """Table 1 per scenario and overall: means over people of the per-person metrics.

        Returns ``{group: {"people", "error_deg" (M,), "accuracy" (M,),
        "bayes_prob_accuracy", "coverage", "bias_error_deg" (M,)}}``; like the paper, every
        person counts once (``overall`` is the mean over all people). People without
        evaluated looking frames are left out of the error (NaN-mean).
        """
        bias_err = np.degrees(np.linalg.norm(self.bias - self.true_bias[:, None, :], axis=-1))
        out = {}
        for name, m in self.groups().items():
            out[name] = {
                "people": int(m.sum()),
                "error_deg": np.nanmean(self.error_deg[m], axis=0),
                "accuracy": np.nanmean(self.accuracy[m], axis=0),
                "bayes_prob_accuracy": float(np.nanmean(self.bayes_prob_accuracy[m])),
                "coverage": float(np.nanmean(self.covered[m])),
                "bias_error_deg": np.nanmean(bias_err[m], axis=0),
            }
        return out

    def figure5(self) -> dict[str, np.ndarray]:
        """Fig. 5: ``{group: (M, B)}`` mean over people of the per-bin error (degrees)."""
        return {name: np.nanmean(self.error_by_time_deg[m], axis=0) for name, m in self.groups().items()}

    def figure6(self) -> dict[str, np.ndarray]:
        """Fig. 6: ``{group: (M, K)}`` mean over people of the accuracy per threshold."""
        return {name: np.nanmean(self.accuracy_by_threshold[m], axis=0) for name, m in self.groups().items()}


def _as_batches(recordings) -> list:
    if hasattr(recordings, "speaking"):
        recordings = [recordings]
    batches = []
    for rec in recordings:
        if not hasattr(rec, "speaking"):
            raise TypeError(f"expected DyadicRecording(s), got {type(rec).__name__}")
        if rec.speaking.ndim == 2:  # one session: add the session axis
            rec = rec._replace(**{f: jnp.asarray(getattr(rec, f))[None] for f in rec._fields
                                  if isinstance(getattr(rec, f), jax.Array | np.ndarray)})
        batches.append(rec)
    if not batches:
        raise ValueError("no recordings to evaluate")
    return batches


@jax.jit
def _geometry(eye, target, R, gaze):
    u = target_direction_head(eye, target, R)
    return u, gaze_offsets(gaze, u), head_target_angle(u)


def _flat(a):
    a = jnp.asarray(a)
    return a.reshape((-1,) + a.shape[2:])


def _take(offsets, indices):
    return jnp.take_along_axis(offsets, indices[..., None], axis=1)


def _mean_or_zero(o, valid):
    n = jnp.sum(valid, axis=1)
    total = jnp.sum(jnp.where(valid[..., None], o, 0.0), axis=1)
    return jnp.where(n[:, None] > 0, total / jnp.maximum(n, 1)[:, None], 0.0)


def _lmeds_or_zero(o, valid):
    bias = jax.vmap(lmeds_bias)(o, valid)[0]
    return jnp.where(jnp.sum(valid, axis=1)[:, None] > 0, bias, 0.0)


def evaluate_bias_methods(
    recordings,
    key: PRNGKeyArray,
    *,
    num_mean: int = 20,
    num_med: int = 40,
    num_bayes: int = 64,
    bayes_spacing_s: float = 1.0 / 3.0,
    window_s: float = 60.0,
    window_start_s: float = 0.0,
    max_head_angle_deg: float = 30.0,
    threshold_deg: float = 10.0,
    thresholds_deg: Sequence[float] = tuple(range(2, 21)),
    time_bin_s: float = 20.0,
    credible_level: float = 0.9,
    num_warmup: int = 300,
    num_samples: int = 300,
    bayes_options: dict | None = None,
) -> BiasEvaluation:
    """Table 1, Fig. 5 and Fig. 6 of Siegfried et al. (2017) on simulated dyads, plus the Bayes fit.

    Args:
        recordings: a :class:`~jaxgaze.simulate.dyadic.DyadicRecording` (one session or a
            batch from ``simulate_dyadic_sessions``) or a sequence of them (e.g. one batch
            per preset). Each person of each session is evaluated; ``scenario`` is the
            recording's preset.
        key: one ``jax.random`` key for the frame draws and the sampler.
        num_mean, num_med: ``N`` of the Mean (20) and Med (40) estimators.
        num_bayes, bayes_spacing_s: the Bayes frames are the Spk candidates of the
            window thinned to one every ``≥ bayes_spacing_s · fps`` frames, at most
            ``num_bayes`` (see the module docstring).
        window_s, window_start_s: the adaptation window (the first minute).
        max_head_angle_deg: the Spk head–target filter (30°).
        threshold_deg: ``τ`` of the looking decision (10°).
        thresholds_deg: the ``τ`` values of Fig. 6.
        time_bin_s: width of the Fig. 5 time bins after the window.
        credible_level: level of the credible region whose coverage is reported (0.9).
        num_warmup, num_samples: NUTS settings (one chain per person, all people through
            one compiled program, :func:`~jaxgaze.bias.estimators.sample_bias_posterior`).
        bayes_options: :func:`~jaxgaze.bias.estimators.bias_model` options; default
            :data:`BAYES_MODEL_OPTIONS`.

    Returns:
        :class:`BiasEvaluation`.

    Raises:
        ValueError: for recordings without evaluated frames after the window, or bad sizes.
    """
    batches = _as_batches(recordings)
    for name, v in (("num_mean", num_mean), ("num_med", num_med), ("num_bayes", num_bayes)):
        if int(v) != v or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v}")
    if not (window_s > 0 and bayes_spacing_s > 0 and time_bin_s > 0):
        raise ValueError("window_s, bayes_spacing_s and time_bin_s must be positive")
    options = dict(BAYES_MODEL_OPTIONS if bayes_options is None else bayes_options)
    thresholds = np.asarray(thresholds_deg, np.float32)
    num_draw = max(int(num_mean), int(num_med))
    key_spk, key_gt, key_bayes, key_nuts = jax.random.split(key, 4)
    window_end = window_start_s + window_s

    per_batch = []
    for b, rec in enumerate(batches):
        fps = float(rec.fps)
        T = rec.speaking.shape[-1]
        times = np.arange(T) / fps
        evaluated = times >= window_end
        if not evaluated.any():
            raise ValueError(f"recording {b} ({T / fps:.1f} s) has no frame after the {window_end:.1f} s window")
        gaze = _flat(rec.gaze_angles)
        u, offsets, head_angle = _geometry(_flat(rec.eye_positions), _flat(rec.target_positions),
                                           _flat(rec.R_world_from_head), gaze)
        looking = _flat(rec.looking).astype(bool)
        spk = jax.vmap(lambda s, a: candidate_frames(s, a, fps=fps, max_head_angle_deg=max_head_angle_deg,
                                                     window_s=window_s, start_s=window_start_s))(
            _flat(rec.partner_speaking), head_angle)
        in_window = jnp.asarray((times >= window_start_s) & (times < window_end))
        gt = looking & in_window[None, :]
        k_spk, k_gt, k_bayes = (jax.random.fold_in(k, b) for k in (key_spk, key_gt, key_bayes))
        spk_idx, spk_ok = random_frames(k_spk, spk, min(num_draw, T))
        gt_idx, gt_ok = random_frames(k_gt, gt, min(num_draw, T))
        stride = max(1, int(math.ceil(bayes_spacing_s * fps - 1e-9)))
        bay_idx, bay_ok = thinned_frames(k_bayes, spk, min_stride=stride, max_frames=int(num_bayes))
        # The contrast: the same window and head filter while the partner is silent.
        quiet = jax.vmap(lambda s, a: candidate_frames(s, a, fps=fps, max_head_angle_deg=max_head_angle_deg,
                                                       window_s=window_s, start_s=window_start_s))(
            ~_flat(rec.partner_speaking), head_angle)
        quiet_idx, quiet_ok = thinned_frames(jax.random.fold_in(k_bayes, 1), quiet, min_stride=stride,
                                             max_frames=4 * int(num_bayes))
        spk_o, gt_o = _take(offsets, spk_idx), _take(offsets, gt_idx)
        n = gaze.shape[0]
        estimates = [
            jnp.zeros((n, 2), gaze.dtype),
            _mean_or_zero(spk_o[:, :num_mean], spk_ok[:, :num_mean]),
            _lmeds_or_zero(spk_o[:, :num_med], spk_ok[:, :num_med]),
            _mean_or_zero(gt_o[:, :num_mean], gt_ok[:, :num_mean]),
            _lmeds_or_zero(gt_o[:, :num_med], gt_ok[:, :num_med]),
        ]
        n_spk = jnp.sum(spk, axis=1)
        per_batch.append(dict(
            rec=rec, fps=fps, times=times, evaluated=evaluated, gaze=gaze, u=u, looking=looking,
            estimates=jnp.stack(estimates, axis=1), bayes_offsets=_take(offsets, bay_idx), bayes_valid=bay_ok,
            silent_offsets=_take(offsets, quiet_idx), silent_valid=quiet_ok,
            num_candidates=np.asarray(n_spk),
            spk_precision=np.asarray(jnp.sum(spk & looking, axis=1) / jnp.maximum(n_spk, 1)),
            num_gt=np.asarray(jnp.sum(gt, axis=1)),
        ))

    # Bayes: every person of every batch through one compiled NUTS program.
    width = max(d["bayes_offsets"].shape[1] for d in per_batch)
    pad = lambda a, v: jnp.pad(a, [(0, 0), (0, width - a.shape[1])] + [(0, 0)] * (a.ndim - 2), constant_values=v)
    bay_o = jnp.concatenate([pad(d["bayes_offsets"], 0.0) for d in per_batch])
    bay_ok = jnp.concatenate([pad(d["bayes_valid"], False) for d in per_batch])
    num_bay = np.asarray(jnp.sum(bay_ok, axis=1))
    empty = num_bay == 0
    if empty.any():  # no frame: fit a dummy frame (discarded below) so that the sampler stays finite
        bay_ok = bay_ok.at[:, 0].set(bay_ok[:, 0] | jnp.asarray(empty))
    silent_width = max(d["silent_offsets"].shape[1] for d in per_batch)
    pad_silent = lambda a, v: jnp.pad(a, [(0, 0), (0, silent_width - a.shape[1])] + [(0, 0)] * (a.ndim - 2),  # noqa: E731
                                      constant_values=v)
    quiet_o = jnp.concatenate([pad_silent(d["silent_offsets"], 0.0) for d in per_batch])
    quiet_ok = jnp.concatenate([pad_silent(d["silent_valid"], False) for d in per_batch])
    values, stats = sample_bias_posterior(bay_o, bay_ok, quiet_o, quiet_ok, key=key_nuts, num_warmup=num_warmup,
                                          num_samples=num_samples, **options)
    draws = np.asarray(values["bias"]).reshape(bay_o.shape[0], -1, 2)
    bayes_mean = np.where(empty[:, None], 0.0, draws.mean(axis=1))
    divergences = np.asarray(stats["diverging"]).reshape(bay_o.shape[0], -1).sum(axis=1)
    truth_all = np.concatenate([np.asarray(_flat(d["rec"].bias)) for d in per_batch])
    covered, m2 = credible_region_covers(draws, truth_all, credible_level)
    covered = np.where(empty, np.nan, covered.astype(float))
    m2 = np.where(empty, np.nan, m2)

    # Metrics, batch by batch (the frame counts may differ between batches).
    tau = float(threshold_deg)
    start = 0
    rows = {k: [] for k in ("bias", "error", "accuracy", "prob_acc", "by_time", "by_tau", "scenario", "session",
                            "person")}
    longest = max(d["times"][-1] + 1 / d["fps"] for d in per_batch)
    edges = np.arange(window_end, longest + time_bin_s - 1e-9, time_bin_s)
    for d in per_batch:
        n = d["gaze"].shape[0]
        stop = start + n
        est = np.concatenate([np.asarray(d["estimates"]), bayes_mean[start:stop, None, :]], axis=1)  # (n, M, 2)
        est_j = jnp.asarray(est, d["gaze"].dtype)
        error = angular_error(d["gaze"][:, None], d["u"][:, None], est_j[:, :, None, :])  # (n, M, T)
        lk = d["looking"][:, None, :]
        ev = jnp.asarray(d["evaluated"])[None, None, :]
        rows["bias"].append(est)
        rows["error"].append(np.asarray(mean_angular_error_deg(error, lk, ev)))
        rows["accuracy"].append(np.asarray(classification_accuracy(error < deg_to_rad(tau), lk, ev)))
        rows["by_time"].append(np.asarray(error_by_time_deg(error, lk, jnp.asarray(d["times"]), jnp.asarray(edges))))
        rows["by_tau"].append(np.asarray(accuracy_by_threshold(error, lk, ev, thresholds)))
        person_draws = jnp.asarray(draws[start:stop], d["gaze"].dtype)
        prob = jax.vmap(lambda g, u, s: looking_probability(g, u, s, tau))(d["gaze"], d["u"], person_draws)
        prob_acc = np.asarray(classification_accuracy(prob > 0.5, d["looking"], jnp.asarray(d["evaluated"])[None]))
        rows["prob_acc"].append(np.where(empty[start:stop], np.nan, prob_acc))
        sessions, people = d["rec"].speaking.shape[:2]
        rows["scenario"].append(np.full(n, d["rec"].preset, dtype=object))
        rows["session"].append(np.repeat(np.arange(sessions), people))
        rows["person"].append(np.tile(np.arange(people), sessions))
        start = stop
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    settings = dict(num_mean=int(num_mean), num_med=int(num_med), num_bayes=int(num_bayes),
                    bayes_spacing_s=float(bayes_spacing_s), window_s=float(window_s),
                    window_start_s=float(window_start_s), max_head_angle_deg=float(max_head_angle_deg),
                    threshold_deg=tau, time_bin_s=float(time_bin_s), credible_level=float(credible_level),
                    num_warmup=int(num_warmup), num_samples=int(num_samples), bayes_options=options)
    return BiasEvaluation(
        methods=METHODS,
        scenario=cat["scenario"].astype(str),
        session=cat["session"],
        person=cat["person"],
        true_bias=truth_all,
        bias=cat["bias"],
        error_deg=cat["error"],
        accuracy=cat["accuracy"],
        bayes_prob_accuracy=cat["prob_acc"],
        bias_draws=draws,
        mahalanobis2=m2,
        covered=covered,
        num_candidates=np.concatenate([d["num_candidates"] for d in per_batch]),
        spk_precision=np.concatenate([d["spk_precision"] for d in per_batch]),
        num_bayes_frames=num_bay,
        num_gt_frames=np.concatenate([d["num_gt"] for d in per_batch]),
        divergences=divergences,
        time_bin_edges_s=edges,
        error_by_time_deg=cat["by_time"],
        thresholds_deg=thresholds.astype(float),
        accuracy_by_threshold=cat["by_tau"],
        settings=settings,
    )


# ------------------------------------------------------------------------- printing


def format_table1(evaluation: BiasEvaluation, *, paper: bool = True) -> str:
    """Table 1's layout: rows = methods; per scenario and overall, mean error (°) and accuracy at τ.

    With ``paper=True`` the paper's figures (rows *Baseline* and *Lm + …*) follow in brackets.
    """
    agg = evaluation.aggregate()
    groups = list(agg)
    tau = evaluation.settings.get("threshold_deg", 10.0)
    titles = [f"{g} (n={agg[g]['people']})" for g in groups]
    head = f"{'method':14s}" + "".join(f" | {t:>26s}" for t in titles)
    sub = f"{'':14s}" + "".join(f" | {'error (°)':>12s} {f'acc τ={tau:g}°':>13s}" for _ in groups)
    lines = [head, sub, "-" * len(sub)]
    for i, m in enumerate(evaluation.methods):
        cells = []
        for g in groups:
            e, a = agg[g]["error_deg"][i], agg[g]["accuracy"][i]
            ref = PAPER_TABLE1.get(g, {}).get(m) if paper else None
            cells.append(f" | {e:5.2f}{f' [{ref[0]:5.2f}]' if ref else ' ' * 8:8s} {a:5.2f}{f' [{ref[1]:.2f}]' if ref else ' ' * 7:7s}")
        lines.append(f"{METHOD_LABELS.get(m, m):14s}" + "".join(cells))
    lines.append(f"{'Bayes P>0.5':14s}" + "".join(
        f" | {'':12s} {agg[g]['bayes_prob_accuracy']:5.2f}{'':8s}" for g in groups))
    level = evaluation.settings.get("credible_level", 0.9)
    lines.append(f"{f'Bayes {level:.0%} cov.':14s}" + "".join(
        f" | {agg[g]['coverage']:12.2f} {'':13s}" for g in groups))
    if paper:
        lines.append("[paper, Table 1: Baseline and Lm + Spk/GT rows]; the simulator has no landmark stage.")
    return "\n".join(lines)


def format_figure_tables(evaluation: BiasEvaluation, *, group: str = "overall",
                         thresholds_deg: Sequence[float] = (2, 4, 6, 8, 10, 12, 14, 16, 18, 20)) -> str:
    """Fig. 5 (error by time bin after the window) and Fig. 6 (accuracy against τ) as text tables."""
    f5, f6 = evaluation.figure5()[group], evaluation.figure6()[group]
    edges = evaluation.time_bin_edges_s
    labels = [METHOD_LABELS.get(m, m) for m in evaluation.methods]
    lines = [f"Fig. 5 ({group}): mean angular error (°) on looking frames, by time after the start (s)"]
    lines.append(f"{'bin (s)':>11s}" + "".join(f" {lab:>13s}" for lab in labels))
    for j in range(len(edges) - 1):
        lines.append(f"{f'{edges[j]:.0f}-{edges[j + 1]:.0f}':>11s}" + "".join(f" {f5[i, j]:13.2f}" for i in range(len(labels))))
    lines.append("")
    lines.append(f"Fig. 6 ({group}): accuracy of e < τ against τ (°)")
    lines.append(f"{'τ (°)':>11s}" + "".join(f" {lab:>13s}" for lab in labels))
    taus = evaluation.thresholds_deg
    for t in thresholds_deg:
        j = int(np.argmin(np.abs(taus - t)))
        if abs(taus[j] - t) > 1e-6:
            continue
        lines.append(f"{taus[j]:11g}" + "".join(f" {f6[i, j]:13.2f}" for i in range(len(labels))))
    return "\n".join(lines)
