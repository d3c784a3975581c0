"""Inference for the joint model: NUTS on a window, SVI with frame subsampling for long recordings (Park et al. 2012, eq. 3; Siegfried et al. 2017, eq. 1).

:func:`fit_joint` starts from the pipeline (:func:`~jaxgaze.joint.joint_start`),
draws from the posterior and returns a :class:`JointPosterior`: the arviz
``InferenceData``, diagnostics and summary (its ``sampler``, a :class:`~jaxgaze.nuts.SamplerReport`),
the membership probabilities of every frame, who looks at whom, mutual gaze, the concurrences and a
posterior predictive check. A run whose diagnostics fail carries ``RESULTS.not_mixed`` (``throw=False``,
the default) or raises :class:`~jaxgaze.results.FitError` with the posterior as ``error.fit``
(``throw=True``).
"""

from __future__ import annotations

import functools
import math
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jax.sharding import NamedSharding, PartitionSpec
from numpyro.infer import SVI, Predictive, Trace_ELBO
from numpyro.infer.util import potential_energy

from jaxgaze._batching import frame_sharding
from jaxgaze.bias.looking import gaze_angles_to_direction, head_to_world
from jaxgaze.cone import sample_gaze_directions
from jaxgaze.geometry import angle_between, unit
from jaxgaze.joint.data import JointData
from jaxgaze.joint.init import JointStart, joint_start, model_arrays
from jaxgaze.joint import rivals
from jaxgaze.joint.model import (BLOCK_FRAMES, COUPLING_SHAPE_BASIS, POSITIVE_SITES, UNIT_SITES, JointPrior, ModelArrays, concurrence_locations, eye_positions,
                                 frame_log_likelihood, gaze_angles, joint_model, measurement_width, model_params,
                                 slot_mask, target_log_prior, target_marginals)
from jaxgaze.nuts import (MAX_DIVERGENT_SHARE, MAX_RHAT, MIN_ESS, SamplerReport, laplace_parts,
                          posterior_summary, sample_nuts, sampler_report)
from jaxgaze._progress import progress_bar
from jaxgaze.rays import GazeRays
from jaxgaze.results import RESULTS, throw_if_failed

__all__ = ["JointPosterior", "SVIDiagnostics", "fit_joint", "mean_field_guide", "MAX_RHAT", "MIN_ESS",
           "MAX_DIVERGENT_SHARE", "METHODS"]

#: Inference methods of :func:`fit_joint`.
METHODS = ("nuts", "svi")
_SUMMARY_SITES = ("bias", "cone_width", "alpha_person", "alpha_object", "speaker_effect", "stay",
                  "concurrence_locations", "eye_offset", "coupling", "head_lag", "tilt_width_ratio", "held_cone_share",
                  "coupling_shape")
#: Draws used for the membership probabilities and the predictive check.
_MAX_PROBABILITY_DRAWS = 200
#: Two free concurrences closer than this (metres) in every window after the start's refinement are one
#: target (:func:`_twin_concurrences`): gaze cannot tell them apart, as a cone of 4° is 10 cm wide at 1.5 m.
TWIN_DISTANCE = 0.15
#: BFGS steps of a descent (:func:`_descend`): the cap of one from the identity, which reaches it; in a Laplace
#: metric a 6-person scene's descents converged in 34–74 (RESULTS, 2026-12-07).
_REFINE_STEPS = 300
#: BFGS runs of a descent at most (:func:`_descend`): a run that stops as converged with the decrement still above
#: :data:`_NEWTON_DECREMENT` stalled (its line search shrank the step to nothing, which the Cauchy test reads as
#: convergence) and is run again from where it stopped, its inverse Hessian reset to the metric.
_DESCENT_RUNS = 3
#: Newton's steps to the chosen mode before sampling (:func:`_polish_mode`), and the decrement ``∇Uᵀ Σ ∇U`` (twice
#: the potential a full step is predicted to gain, nats) below which the mode counts as reached.
_NEWTON_STEPS = 4
_NEWTON_DECREMENT = 0.01
#: Steps with the search's inverse Hessian before the first Laplace of :func:`_polish_mode` (one gradient each).
_CHORD_STEPS = 12
#: The most (nats) that :func:`_predicted_evidence` adds for a mode's potential below a point's: beyond, the point is
#: no mode's neighbour, where the quadratic model need not hold.
_MAX_PREDICTED_GAIN = 50.0
#: The least curvature magnitude of the potential that NUTS's mass matrix takes (:func:`_laplace_evidence`);
#: the weakest prior curvature is about 0.1 (a logit of sd 3), so only a direction the start is no mode in
#: is raised to it.
_MIN_CURVATURE = 0.01
#: The least log Bayes factor of a fixation's spot that keeps it: "positive" evidence, a factor of 3 (Kass & Raftery
#: 1995, Sec. 3.2). On recordings without spots the factor's log was −2.4 to +0.6 (6 simulated scenes; +0.6 kept
#: the spot on one of ``bench_joint``'s), with ``c = 0.2`` 50–63 and with ``c = 0.5`` 190.
SPOT_MIN_LOG_FACTOR = math.log(3.0)
#: The least log Bayes factor of a Gaussian-process head–gaze map against the linear one that keeps it
#: (:func:`_choose_shape`; Kass & Raftery 1995's "positive" evidence, as for the spot).
SHAPE_MIN_LOG_FACTOR = math.log(3.0)
#: Points of the quadrature over the spot's ``s ≥ 0`` (:func:`_spot_log_bayes_factor`), squared-spaced.
_SPOT_POINTS = 48
#: Seconds over which a head's errors are taken as correlated when the couplings' intervals are widened
#: (:func:`_coupling_widening`): head sway and a tracker's drift last seconds, longer than a fixation's spot.
#: On 13 simulated conversations the 90% intervals of ``κ`` covered 0.83 unwidened, 0.86 with 1 s, 0.87 with 3 s
#: and 0.88 with 6 or 10 s (RESULTS, 2026-12-05).
COUPLING_ERROR_SPAN_S = 5.0


@functools.lru_cache(maxsize=None)
def _model(prior: JointPrior, blocks_per_step: int | None):
    return functools.partial(joint_model, prior=prior, blocks_per_step=blocks_per_step)


_arrays = model_arrays


def _start_values(start: JointStart, prior: JointPrior, num_people: int) -> dict:
    """Constrained starting values of every latent site."""
    K = start.num_concurrences
    W = start.concurrence_centres.shape[0]
    values = {"bias": np.asarray(start.bias, float), "cone_width": np.full(num_people, prior.cone_width_median),
              "alpha_person": np.zeros(()), "speaker_effect": np.asarray(prior.speaker_log_ratio),
              "stay": np.asarray(0.9)}
    if K:
        values["alpha_object"] = np.zeros(())
        values["concurrence_offset"] = np.zeros((K, 3))
        if W > 1:
            values["concurrence_drift"] = np.zeros((W, K, 3))
    if prior.held_scale is not None:
        values["held_spread"] = np.asarray(0.5)  # c = 0.16
    if start.coupling is not None:
        values["coupling"] = np.asarray(start.coupling, float)
        values["head_lag"] = np.asarray(start.head_lag, float)
        if prior.tilt_width_ratio_log_sd is not None:
            values["tilt_width_ratio"] = np.asarray(start.tilt_width_ratio or 1.0, float)
        if prior.coupling_shape_scale is not None:
            values["coupling_shape"] = np.zeros(np.shape(start.coupling) + (COUPLING_SHAPE_BASIS,))
    if start.eye_offset.shape[0]:
        values["eye_offset"] = np.asarray(start.eye_offset, float)
        values["calibration_outlier_share"] = np.full(start.eye_offset.shape[0], 0.1)
    return values


def _unconstrained(values: dict) -> dict:
    """numpyro's unconstrained values: log for the positive widths, logit for the probabilities."""
    out = dict(values)
    for site in POSITIVE_SITES:
        if site in values:
            out[site] = np.log(values[site])
    for site in UNIT_SITES:
        if site in values:
            out[site] = np.log(values[site]) - np.log1p(-values[site])
    return out


def _descend(model, params: dict, arrays: ModelArrays, frozen: dict, inverse=None) -> dict:
    """BFGS on ``model``'s potential from ``params`` (unconstrained), the entries where ``frozen`` is ``True`` held; a
    failed, non-finite or uphill search keeps ``params``.

    A held entry has no gradient, so BFGS's steps and its inverse Hessian leave it (from the identity, each update's
    ``s yᵀ`` is 0 in its row and column): the descent is that of the model conditioned on it, in the same program.

    ``inverse``: an inverse Hessian near the mode (a Laplace covariance, :func:`_laplace_evidence`; ``(d, d)`` over
    ``params`` flattened), to search in ``θ = θ₀ + L z`` with ``L Lᵀ`` that covariance (BFGS's first inverse Hessian
    becomes it, Nocedal & Wright 2006, eq. 6.20's scaling taken whole). From the identity the potential's scales
    differ by 10⁴ and BFGS ran every descent to its cap of :data:`_REFINE_STEPS` steps, 8–46 nats short of the mode;
    so preconditioned, rival trials of a 6-person scene converged in 34–74 steps, 90–300 nats lower (RESULTS,
    2026-12-07). A non-finite factor falls back to the identity.

    BFGS's Cauchy test (``y`` and ``f`` changed by less than ``rtol``) also stops a run whose line search stalled: a
    4-person head-only descent stopped "converged" 181 nats above the mode after a float32 rounding elsewhere in the
    program moved its path (RESULTS, 2026-12-07). A run that so stops with the decrement ``|∇_z U|²``
    (``∇Uᵀ Σ ∇U`` in the metric) above :data:`_NEWTON_DECREMENT` is run again from there, up to
    :data:`_DESCENT_RUNS` runs; one that reached its cap is not (from the identity every run reaches it)."""
    flat, unravel = ravel_pytree(params)
    held = ravel_pytree(frozen)[0].astype(bool)
    scale = jnp.eye(flat.shape[0], dtype=flat.dtype)
    if inverse is not None:
        jitter = 1e-6 * jnp.maximum(jnp.max(jnp.diag(inverse)), 1e-12)
        factor = jnp.linalg.cholesky(inverse + jitter * scale)
        scale = jnp.where(jnp.all(jnp.isfinite(factor)), factor, scale)

    def energy(z, _):
        return potential_energy(model, tuple(arrays), {}, unravel(jnp.where(held, flat, flat + scale @ z)))

    def run(carry):
        z, runs, _ = carry
        solution = optx.minimise(energy, optx.BFGS(rtol=1e-6, atol=1e-6), z, max_steps=_REFINE_STEPS, throw=False)
        gradient = solution.state.f_info.grad  # at the run's last point: no second gradient of the model to compile
        stalled = (solution.result == optx.RESULTS.successful) & (jnp.sum(jnp.square(gradient)) > _NEWTON_DECREMENT)
        return solution.value, runs + 1, stalled

    def again(carry):
        return (carry[1] < _DESCENT_RUNS) & carry[2]

    z, _, _ = jax.lax.while_loop(again, run, (jnp.zeros_like(flat), 0, jnp.asarray(True)))  # the first run always
    x = jnp.where(held, flat, flat + scale @ z)
    at = lambda x: potential_energy(model, tuple(arrays), {}, unravel(x))  # noqa: E731
    better = jnp.all(jnp.isfinite(x)) & (at(x) <= at(flat))
    return unravel(jnp.where(better, x, flat))


def _refine_start(start: dict, arrays: ModelArrays, prior: JointPrior, to_mode: bool, inverse=None) -> dict:
    """The pipeline's start moved to a mode of the model, in two descents (BFGS, numpyro's unconstrained space).

    1. The mode of the model with independent frames (``ρ = 10⁻⁶``). A start far from
       the truth (a pipeline bias tens of degrees off) puts the sticky chain in a local
       mode where a person's whole recording is a held glance elsewhere; with
       independent frames every gaze still pulls the bias towards its nearest
       candidate, so the mode of that model is in the right basin. Head pose only, the
       couplings and lags stay at the start's (:func:`~jaxgaze.joint.init.coupling_profile`'s
       choice, at :func:`~jaxgaze.joint.init.tilt_width_profile`'s ``r``): free here, a person's ``κ`` can climb into a rival mode (0.41 → 0.73 in one
       6-person scene, the bias 16° off, and NUTS stayed there).
    2. With ``to_mode``, from there, the mode of the model itself (``ρ`` free). Its Hessian is NUTS's
       mass matrix (:func:`_laplace_evidence`); the first mode can be a saddle of
       this model, with a strongly negative curvature along a concurrence, and no
       mass matrix taken there fits the posterior.

    Wearers' eye offsets stay at Park's calibration: the mode of the eye's depth
    along the primary ray is not where the truth is (see
    ``JointPrior.eye_offset_scale``), and NUTS explores it from Park's estimate.
    :func:`fit_joint` skips the second descent with wearers: from its point, with the
    eyes held, NUTS drifts to the eyes' far mode.

    With a fixation's spot (``JointPrior.held_scale``) the second descent first finds the mode without
    the spot, then the spot's from there (:func:`fit_joint` starts without the spot and weighs it
    afterwards: :func:`_choose_spot`). Straight from the first mode, the spot's share can grow
    while the biases are still far off, and the descent scattered them: on one adversarial 8-person
    scene, errors of 2, 2, 14, 7, 1, 45, 1, 3° became 18, 5, 35, 16, 7, 9, 2, 13°, a mode whose Laplace
    evidence the rival search could not raise to the truth's (one person ended 26° off at 40 posterior sd).
    Through the mode without the spot: 1, 1, 2, 1, 1, 19, 0, 3°, and the search mends the 19° (RESULTS,
    2026-12-05).

    Both descents are one compiled program (:func:`_descend_program`), shared with the pruning and the rival
    search: the first holds ``ρ``, the couplings and the wearers' eyes (:func:`_independent_mode`). The descents to
    the mode search in the metric of a Laplace covariance (:func:`_descend`): ``inverse``, the one of a mode near by
    (over ``start`` flattened: the rival search's current mode), else the one at the first descent's point.
    """
    spotless, spot = _without_spot(start, prior)
    plain = prior._replace(held_scale=None)
    values = _independent_mode(spotless, arrays, plain, None if inverse is None else _restricted(inverse, start,
                                                                                                 spotless))
    if to_mode:
        metric = _laplace_evidence(values, arrays, plain)[1] if inverse is None else _restricted(inverse, start,
                                                                                                 spotless)
        values = _to_mode(values, arrays, plain, metric)
    if not (to_mode and spot):
        return {**values, **spot}
    values = {**values, **spot}
    return _to_mode(values, arrays, prior, _laplace_evidence(values, arrays, prior)[1] if inverse is None else inverse)


def _restricted(inverse, values: dict, kept: dict):
    """The rows and columns of ``inverse`` (over ``values`` flattened) of the sites in ``kept``, in its order."""
    flat, unravel = ravel_pytree(values)
    index = unravel(jnp.arange(flat.shape[0], dtype=flat.dtype))
    rows = np.asarray(ravel_pytree({k: index[k] for k in kept})[0]).round().astype(int)
    return jnp.asarray(inverse)[np.ix_(rows, rows)]


def _without_spot(values: dict, prior: JointPrior) -> tuple[dict, dict]:
    """``values`` without the spot's site, and that site alone (empty without a spot)."""
    spot = {k: v for k, v in values.items() if k == "held_spread"} if prior.held_scale is not None else {}
    return {k: v for k, v in values.items() if k not in spot}, spot


def _coupling_widening(unconstrained: dict, inverse_hessian, arrays: ModelArrays, prior: JointPrior,
                       fps: float) -> np.ndarray:
    """``(P, 2)`` factors ``≥ 1`` that widen each coupling's posterior around its mean (``log κ``) to the sandwich
    variance (Chandler & Bate 2007, Sec. 3; Newey & West 1987).

    The model counts a head's errors as independent from frame to frame (beyond a fixation's spot), but sway and a
    tracker's drift last seconds. The mode's influence on ``κ`` of each frame, ``a_t = Σ s_t`` (``Σ`` the inverse
    Hessian, ``s_t`` the gradient of ``log p(h_t | h_{<t})``, :func:`~jaxgaze.joint.model.frame_log_likelihood`),
    gives the long-run variance ``Σ_{|l| ≤ L} (1 − |l|/(L + 1)) Σ_t a_t a_{t+l}`` with ``L`` the frames of
    :data:`COUPLING_ERROR_SPAN_S`; the factor is its square root over ``Σ``'s, never below 1.
    """
    scores = np.asarray(_frame_scores(unconstrained, arrays, prior), np.float64)  # (T, n)
    _, unravel = ravel_pytree(unconstrained)
    size = scores.shape[1]
    where = np.asarray(unravel(jnp.arange(size, dtype=jnp.float32))["coupling"]).round().astype(int)  # (P, 2)
    inverse = np.asarray(inverse_hessian, np.float64)
    influence = scores @ inverse[:, where.ravel()]  # (T, 2P)
    variance = _long_run_variance(influence, int(round(COUPLING_ERROR_SPAN_S * fps)))
    ratio = variance / np.diag(inverse)[where.ravel()]
    return np.sqrt(np.maximum(ratio, 1.0)).reshape(where.shape)


def _long_run_variance(series: np.ndarray, lags: int) -> np.ndarray:
    """The variance of the sum of each column of ``series (T, n)``, its autocovariances to ``lags`` weighed by
    Bartlett's ``1 − l/(L + 1)`` (Newey & West 1987, eq. 2; the columns centred)."""
    centred = series - series.mean(axis=0)
    lags = min(lags, centred.shape[0] - 1)
    variance = np.sum(centred * centred, axis=0)
    for lag in range(1, lags + 1):
        variance += 2.0 * (1.0 - lag / (lags + 1.0)) * np.sum(centred[lag:] * centred[:-lag], axis=0)
    return variance


@functools.partial(jax.jit, static_argnames=("prior",))
def _frame_scores(unconstrained: dict, arrays: ModelArrays, prior: JointPrior):
    """``(T, n)``: the gradient of every frame's ``log p(h_t | h_{<t})``, all people together, in numpyro's
    unconstrained values flattened (forward mode: ``n`` is a few dozen, ``T`` thousands)."""
    flat, unravel = ravel_pytree(unconstrained)

    def frames(x):
        params = model_params(rivals.constrained(unravel(x)), arrays.location_centres, prior)
        return jnp.sum(frame_log_likelihood(params, arrays, prior), axis=1)

    return jax.jacfwd(frames)(flat)


def _widen(draws: dict, factor: np.ndarray) -> dict:
    """The coupling draws ``(chains, S, P, 2)`` spread ``factor`` times further from their mean in ``log κ``, the
    sampled coordinate."""
    log_kappa = np.log(np.asarray(draws["coupling"], np.float64))
    centre = log_kappa.reshape((-1,) + log_kappa.shape[2:]).mean(axis=0)
    widened = centre + factor * (log_kappa - centre)
    return {**draws, "coupling": np.exp(widened).astype(np.asarray(draws["coupling"]).dtype)}


#: The stay probability ``ρ`` of the first descent's model with independent frames (:func:`_independent_mode`).
INDEPENDENT_STAY = 1e-6
#: What the first descent holds at the start's values: the wearers' eyes and the head–gaze profile's couplings.
_HELD_BY_THE_FIRST_DESCENT = ("eye_offset", "calibration_outlier_share", "coupling", "head_lag", "stay")


def _independent_mode(start: dict, arrays: ModelArrays, prior: JointPrior, inverse=None) -> dict:
    """The first descent of :func:`_refine_start`: the mode of the model with independent frames (``ρ`` held at
    :data:`INDEPENDENT_STAY`), the wearers' eyes and the profile's couplings and lags held too (``prior`` has no
    spot: :func:`_refine_start` takes it out, so that fits with and without one share this program).

    It is :func:`_to_mode`'s program with those entries held (:func:`_descend`): a program of its own, the model
    conditioned on them, took 8.7 s of a 113-s first fit to compile (RESULTS)."""
    stay = jnp.full_like(start["stay"], math.log(INDEPENDENT_STAY) - math.log1p(-INDEPENDENT_STAY))  # its logit
    frozen = {k: jnp.full(jnp.shape(v), k in _HELD_BY_THE_FIRST_DESCENT) for k, v in start.items()}
    metric = jnp.eye(ravel_pytree(start)[0].shape[0]) if inverse is None else inverse
    return {**_descend_program({**start, "stay": stay}, frozen, arrays, prior, metric), "stay": start["stay"]}


def _to_mode(values: dict, arrays: ModelArrays, prior: JointPrior, inverse=None) -> dict:
    """The nearest mode of the model (BFGS from ``values``; no wearers): the second descent of :func:`_refine_start`
    alone, which keeps every person in the basin the values are in; ``inverse``: a Laplace covariance to search in
    (:func:`_descend`), the identity's by default."""
    frozen = {k: jnp.zeros(jnp.shape(v), bool) for k, v in values.items()}
    size = ravel_pytree(values)[0].shape[0]
    return _descend_program(values, frozen, arrays, prior, jnp.eye(size) if inverse is None else inverse)


@functools.partial(jax.jit, static_argnames=("prior",))
def _descend_program(values: dict, frozen: dict, arrays: ModelArrays, prior: JointPrior, inverse=None) -> dict:
    """:func:`_descend` on the model, compiled once for both descents of :func:`_refine_start`, the pruning and the
    rival search (an identity ``inverse`` searches as none does, in the same program)."""
    dtype = ravel_pytree(values)[0].dtype
    return _descend(_model(prior, None), values, arrays, frozen, None if inverse is None else inverse.astype(dtype))


def _twin_concurrences(unconstrained: dict, centres, prior: JointPrior) -> list[int]:
    """Free concurrences that the refined start puts on top of an earlier one (within :data:`TWIN_DISTANCE` in
    every window): the same target, found twice by the pipeline. Two slots on one target share its gazes
    between them, and the posterior has no mode (NUTS takes ~150 leapfrog steps a draw); the later (less
    supported) one is dropped."""
    if "concurrence_offset" not in unconstrained:
        return []
    locations = np.asarray(concurrence_locations(unconstrained, jnp.asarray(centres, unconstrained["bias"].dtype),
                                                 prior))  # (W, K, 3)
    distance = np.linalg.norm(locations[:, :, None] - locations[:, None], axis=-1).max(axis=0)  # (K, K)
    return [k for k in range(distance.shape[0]) if np.any(distance[k, :k] < TWIN_DISTANCE)]


def _laplace_evidence(unconstrained: dict, arrays: ModelArrays, prior: JointPrior) -> tuple[float, jax.Array]:
    """The Laplace log evidence of the mode at ``unconstrained`` (:func:`~jaxgaze.joint.rivals.log_evidence`) and the
    inverse Hessian there, NUTS's inverse mass matrix, in one program (the potential evaluated op by op took longer
    than compiling it: 6 s a call on a 4-person scene).

    BFGS stops short of the mode along the tilt ridge, and the potential there is short of the mode's: it is taken at
    the mode by Newton's prediction, the potential lower by half the decrement, ``½ ∇Uᵀ Σ ∇U``
    (:func:`_predicted_evidence`), so that the pruning and the rival search compare modes, not where BFGS stopped.

    The posterior's scales differ by a factor of 100 (a bias of 0.1° against a
    logit); from the identity, NUTS's first warm-up windows take 150–180 leapfrog
    steps per draw, from this matrix 7–8, and no window is spent learning it.
    """
    evidence, inverse, _, gradient = _laplace_parts(unconstrained, arrays, prior)
    return _predicted_evidence(evidence, inverse, gradient), inverse


def _predicted_evidence(evidence, inverse, gradient) -> float:
    """The Laplace log evidence at the mode near ``θ`` from the one at ``θ``: plus the potential a Newton step is
    predicted to gain, ``½ ∇Uᵀ Σ ∇U`` (Nocedal & Wright 2006, eq. 2.14's quadratic model at its least), at most
    :data:`_MAX_PREDICTED_GAIN`. Head pose only, the BFGS points of the pruning and the rival search were 4–41 nats of
    evidence short of their modes on the 6-person bench scene, and the prediction 1.0–4.2 nats over; 2–44 short on a
    5-person one, and 0.3–19.6 over (``benchmarks/RESULTS.md``)."""
    gain = 0.5 * float(gradient @ inverse @ gradient)
    return float(evidence) + (min(gain, _MAX_PREDICTED_GAIN) if math.isfinite(gain) and gain > 0.0 else 0.0)


def _potential(arrays: ModelArrays, prior: JointPrior):
    """``U(θ)`` of the whole model (no subsampling) on numpyro's unconstrained values: the negative log joint density
    that BFGS, the Laplace and NUTS share."""
    return functools.partial(potential_energy, _model(prior, None), tuple(arrays), {})


@functools.partial(jax.jit, static_argnames=("prior",))
def _laplace_parts(unconstrained: dict, arrays: ModelArrays, prior: JointPrior):
    """The Laplace log evidence, the inverse Hessian, the potential and its gradient (flattened) at ``unconstrained``."""
    potential = _potential(arrays, prior)
    inverse, gradient = laplace_parts(potential, unconstrained, _MIN_CURVATURE)
    energy = potential(unconstrained)
    return rivals.log_evidence(energy, inverse), inverse, energy, gradient


def _without_concurrence(values: dict, arrays: ModelArrays, k: int):
    """``values`` and ``arrays`` with concurrence slot ``k`` masked (``ModelArrays.slot_active``), its offsets at
    their prior's centre. The shapes stay, and so do the compiled programs of :func:`_to_mode` and
    :func:`_laplace_parts`: removed, each count of slots compiled them again (15–20 s of a first fit, RESULTS). The
    masked slot's offsets (and ``α_object`` once every slot is masked) are then prior-only standard normals: their
    Laplace term is exactly 0, so the evidence is the smaller model's (:func:`_drop_masked_slots` removes them)."""
    out = dict(values)
    out["concurrence_offset"] = values["concurrence_offset"].at[k].set(0.0)
    if "concurrence_drift" in values:
        out["concurrence_drift"] = values["concurrence_drift"].at[:, k].set(0.0)
    return out, arrays._replace(slot_active=slot_mask(arrays).at[k].set(False))


def _drop_masked(values: dict, arrays: ModelArrays, inverse=None):
    """``values``, ``arrays`` and an inverse Hessian of them (or ``None``) without the slots masked by
    :func:`_without_concurrence`; ``α_object`` goes too when no slot is left."""
    active = np.asarray(slot_mask(arrays))
    if active.all():
        return values, arrays, inverse
    keep = np.flatnonzero(active)

    def drop(tree: dict) -> dict:
        out = {**tree, "concurrence_offset": tree["concurrence_offset"][keep]}
        if "concurrence_drift" in tree:
            out["concurrence_drift"] = tree["concurrence_drift"][:, keep]
        if not keep.size:
            out = {k: v for k, v in out.items() if not k.startswith(("concurrence_", "alpha_object"))}
        return out

    if inverse is not None:  # the rows and columns of what is kept, in jax.tree_util's order (the mass matrix's)
        flat, unravel = ravel_pytree(values)
        rows = np.asarray(ravel_pytree(drop(unravel(jnp.arange(flat.size, dtype=flat.dtype))))[0]).round().astype(int)
        inverse = jnp.asarray(inverse)[np.ix_(rows, rows)]
    smaller = arrays._replace(location_centres=arrays.location_centres[:, keep], slot_active=jnp.ones(keep.size, bool))
    return drop(values), smaller, inverse


def _drop_masked_slots(search, inverse, arrays: ModelArrays):
    """The search's modes (:func:`_search_modes`), the chosen mode's inverse Hessian and ``arrays`` without the slots
    the pruning masked: NUTS and SVI sample only the concurrences kept."""
    active = np.asarray(slot_mask(arrays))
    if active.all():
        return search, inverse, arrays
    P, K = arrays.present.shape[1], active.size
    columns = np.concatenate([np.arange(P), P + np.flatnonzero(active), [P + K]])
    start, smaller, inverse = _drop_masked(search.start, arrays, inverse)
    starts = tuple(_drop_masked(values, arrays, mass)[::2] for values, mass in search.alternative_starts)
    alternatives = tuple(a._replace(membership=a.membership[:, columns]) for a in search.alternatives)
    return search._replace(start=start, alternatives=alternatives, alternative_starts=starts), inverse, smaller


def _prune_concurrences(unconstrained: dict, arrays: ModelArrays, prior: JointPrior, progress: bool, scored=None):
    """The pipeline's concurrences the data do not need, dropped while the Laplace evidence rises (MacKay 2003, eq. 28.10).

    The start can place two slots on one target further apart than :data:`TWIN_DISTANCE`
    (a table object found at 0.3 m from itself in a window). They share its gazes, the
    posterior has a ridge along the split, and NUTS takes 140 leapfrog steps a draw
    with an ESS of 10 in 100 (against 7 steps and 113 with one slot). The
    evidence counts the extra slot's volume against the little it explains: one slot
    is dropped at a time, the one whose removal raises the evidence most, each removal
    refined from the current mode (:func:`_to_mode`, in its Laplace metric). Returns the values and the arrays (the
    dropped slots masked, :func:`_without_concurrence`) and the kept mode's ``(evidence, inverse Hessian)`` (for
    :func:`_search_modes`). ``scored``: the start's ``(evidence, inverse Hessian)`` when already computed.

    :func:`fit_joint` prunes with the model without a fixation's spot, whose choice follows
    (:func:`_choose_spot`): a BFGS program and a Hessian of the spot's model per concurrence count
    cost 26 s of a 106-s first fit (``bench_joint``), and a spot's offsets lie within the cone of
    a target, not between targets, so they do not bear on how many targets there are.
    """
    kept = [int(k) for k in np.flatnonzero(np.asarray(slot_mask(arrays)))]  # the twins are masked already
    scored = _laplace_evidence(unconstrained, arrays, prior) if scored is None else scored
    with progress_bar(progress, desc="joint concurrences") as bar:
        while kept:
            best = None
            bar.total = (bar.total or 0) + len(kept)
            for k in range(len(kept)):
                bar.update(1)
                values, smaller = _without_concurrence(unconstrained, arrays, kept[k])
                values = _to_mode(values, smaller, prior, scored[1])
                trial = _laplace_evidence(values, smaller, prior)
                if math.isfinite(trial[0]) and trial[0] > scored[0] and (best is None or trial[0] > best[0][0]):
                    best = (trial, k, values, smaller)
            if best is None:
                break
            scored, k, unconstrained, arrays = best
            del kept[k]
    return unconstrained, arrays, scored


def _prune_after_the_search(search, inverse_hessian, arrays: ModelArrays, prior: JointPrior, progress: bool):
    """The concurrences pruned again (:func:`_prune_concurrences`) from the search's mode where it moved someone and
    found no rival within the margin: a slot kept for a person's gazes at the wrong bias explains nothing at the right
    one. Such a slot is a prior on its own, free along the rays it once explained: on an adversarial scene two of them
    drifted in NUTS onto the one object, and NUTS took 63–160 leapfrog steps a draw (bulk ESS 3–32 of 150) where the
    scene's one slot takes 7 (RESULTS, 2026-12-08). Returns the search, the inverse Hessian and the arrays (the
    slots dropped masked)."""
    if not search.moved or search.alternatives:
        return search, inverse_hessian, arrays
    before = np.asarray(slot_mask(arrays))
    values, pruned, scored = _prune_concurrences(search.start, arrays, prior, progress,
                                                 (search.log_evidence, inverse_hessian))
    if np.array_equal(np.asarray(slot_mask(pruned)), before):
        return search, inverse_hessian, arrays
    return search._replace(start=values, log_evidence=float(scored[0])), scored[1], pruned


def _choose_shape(linear_mode: dict, shape_start: dict, arrays: ModelArrays, prior: JointPrior, scored):
    """A Gaussian-process head–gaze map (``JointPrior.coupling_shape_scale``) kept only where the data favour it over
    the linear map: the Laplace evidences of the two models, each at its own mode (MacKay 2003, eq. 28.10), their
    difference the log Bayes factor (Kass & Raftery 1995, eq. 1), kept above :data:`SHAPE_MIN_LOG_FACTOR`.

    ``linear_mode`` is the linear model's mode and ``scored`` its ``(evidence, inverse Hessian)``, both with the
    fixation's spot where :func:`_choose_spot` kept one. The process's mode is the better (by evidence) of two
    descents: :func:`_refine_start` from ``shape_start`` (the pipeline's start, the process's weights at 0), and
    :func:`_to_mode` from the linear mode with the weights at 0. From the linear mode alone, one saturating
    6-person scene ended in a mode that got 0.73 of the gazes at a person right, against 0.95 from the start.
    Yücel et al.'s map as a latent function is the right one for heads whose turn saturates, but where heads turn
    in proportion its weights only blur ``κ`` and cost 2–14× the linear fit (RESULTS). Returns the prior to go
    on with, its mode, the log Bayes factor and the chosen mode's ``(evidence, inverse Hessian)``.

    Weighed without the spot, a head's errors correlated over seconds count as evidence for any flexible map:
    on the issue-38 conversations (seed 38, 60 s) the process was favoured by ``e^260`` on a saturating scene and
    ``e^46`` on another, but lost (``e^−1.2``) on the scene it helped most (right 0.78 → 0.95); with the spot the
    factors were ``e^1.7``, ``e^6.9`` and ``e^108``, and ``e^−103`` where heads turn in proportion (RESULTS).
    """
    weights = jnp.zeros(linear_mode["coupling"].shape + (COUPLING_SHAPE_BASIS,), linear_mode["coupling"].dtype)
    modes = [_refine_start(shape_start, arrays, prior, True),
             _to_mode({**linear_mode, "coupling_shape": weights}, arrays, prior)]
    shape_scored, shape_mode = max(((_laplace_evidence(m, arrays, prior), m) for m in modes),
                                   key=lambda pair: pair[0][0] if math.isfinite(pair[0][0]) else -math.inf)
    log_factor = shape_scored[0] - scored[0]
    if math.isfinite(log_factor) and log_factor > SHAPE_MIN_LOG_FACTOR:
        return prior, shape_mode, log_factor, shape_scored
    return prior._replace(coupling_shape_scale=None), linear_mode, log_factor, scored


def _choose_spot(plain_mode: dict, arrays: ModelArrays, prior: JointPrior):
    """A fixation's spot kept only where the data need it: the Bayes factor of the spot (Kass & Raftery 1995, eq. 1),
    as :func:`_prune_concurrences` keeps a concurrence only where the evidence rises.

    ``plain_mode`` is the mode without the spot. The factor ``∫ p(g | θ*, s) p(s) ds / p(g | θ*)`` is taken
    with the other parameters there (:func:`_spot_log_bayes_factor`); only where it exceeds 3
    (:data:`SPOT_MIN_LOG_FACTOR`) is the spot kept, its mode found from there and sampled. With wearers of
    head-mounted cameras the start is no mode, and :func:`fit_joint` fits the model without a spot.

    Where a recording holds no spot, its share ``c = 0.8 s²/(1 + s²)`` has a posterior in ``s`` with two shallow wells at ``±s*`` and quartic
    walls: the Laplace mass matrix is 2.3× too narrow in ``s``, and NUTS took 15 leapfrog steps a draw
    instead of 7 (one of ``bench_joint``'s scenes) at 2.2× the gradient's cost, to learn ``c ≈ 0``.
    Returns the prior to sample with, its mode and the log Bayes factor.
    """
    log_factor, best = (float(x) for x in _spot_log_bayes_factor(plain_mode, arrays, prior))
    if not (math.isfinite(log_factor) and log_factor > SPOT_MIN_LOG_FACTOR):
        return prior._replace(held_scale=None), plain_mode, log_factor
    values = {**plain_mode, "held_spread": jnp.asarray(best, plain_mode["bias"].dtype)}
    return prior, _to_mode(values, arrays, prior, _laplace_evidence(values, arrays, prior)[1]), log_factor


@functools.partial(jax.jit, static_argnames=("prior",))
def _spot_log_bayes_factor(plain_mode: dict, arrays: ModelArrays, prior: JointPrior):
    """``log ∫ p(g | θ*, s) N(s; 0, σ²) ds − log p(g | θ*)`` and the ``s ≥ 0`` at the integrand's peak.

    The trapezoid rule over ``s = 4σu²``, ``u`` in ``[0, 1]`` (dense near ``s = 0``, where a recording
    without spots puts the likelihood's well); the integrand is even in ``s`` (``c`` depends on ``s²``),
    so the half line, doubled, is the whole. ``U(s) − U(0)`` of the spot model's potential is the log
    likelihood ratio plus the prior's, as the spot at ``c = 0`` is the model without it.
    """
    u = jnp.linspace(0.0, 1.0, _SPOT_POINTS, dtype=plain_mode["bias"].dtype)
    spread = 4.0 * prior.held_scale * jnp.square(u)
    potential = _potential(arrays, prior)
    energy = jax.lax.map(lambda s: potential({**plain_mode, "held_spread": s}), spread)  # U(s)
    log_integrand = energy[0] - energy  # log [p(g|s) p(s) / (p(g|0) p(s = 0))]
    peak = jnp.max(log_integrand)
    integral = jax.scipy.integrate.trapezoid(jnp.exp(log_integrand - peak) * 8.0 * prior.held_scale * u, u)
    log_prior_at_zero = -0.5 * math.log(2 * math.pi) - math.log(prior.held_scale)
    return peak + jnp.log(2.0 * integral) + log_prior_at_zero, spread[jnp.argmax(log_integrand)]


def _search_modes(unconstrained: dict, arrays: ModelArrays, prior: JointPrior, wearers, progress: bool,
                  scored=None):
    """Every person's rival bias modes, refined and compared by Laplace evidence (:mod:`jaxgaze.joint.rivals`).

    In rounds: the profiles around the current mode (the start first) give rivals; each is
    refined from the current mode, and one whose evidence beats the current mode's becomes
    it. A round that moves the current mode scans again around it (at most
    :data:`~jaxgaze.joint.rivals.MAX_ROUNDS` rounds), as a rival more than the scan's radius
    from the start can be within it from the first rival. Two refinements that end within the separation of each
    other are one mode, and the higher of the two points is kept: on one adversarial scene a first rival reached
    the truth's basin but stopped 150 nats of evidence short of its mode (below the wrong mode it was to replace),
    and the second, which reached it, was dropped as already known. A person whose current bias lies beyond the scan's
    radius from 0 (the prior's centre) is also scanned around 0: on one of 30 conversations with a fixation's
    spot, the start's descent sent a bias 88° off, out of reach of the scan around it. Returns the
    :class:`~jaxgaze.joint.rivals.ModeSearch` and the chosen mode's inverse Hessian. ``scored``: the start's
    ``(evidence, inverse Hessian)`` when already computed (by :func:`_prune_concurrences`).
    """
    P = arrays.present.shape[1]
    offsets, n = rivals.scan_offsets()
    people = np.ones(P, bool)
    people[list(wearers)] = False
    separation = math.radians(rivals.MIN_SEPARATION_DEG)
    radius = math.radians(rivals.SCAN_RADIUS_DEG)

    score = functools.partial(_laplace_evidence, arrays=arrays, prior=prior)
    trials = ([(axis, shift) for axis in (0, 1) for shift in rivals.COUPLING_SHIFTS]
              if "coupling" in unconstrained else [])  # head pose only: rivals in (κ, bias) too
    coarse, _ = rivals.scan_offsets(step_deg=rivals.COUPLING_SCAN_STEP_DEG)

    def twin(values) -> int | None:  # the found mode whose every bias (and coupling) is within the separation
        def close(mode) -> bool:
            near = np.all(np.linalg.norm(np.asarray(values["bias"]) - np.asarray(mode["bias"]), axis=-1) < separation)
            apart = jnp.exp(values["coupling"]) - jnp.exp(mode["coupling"]) if trials else 0.0
            return bool(near) and bool(np.all(np.abs(np.asarray(apart)) < rivals.COUPLING_SEPARATION))
        return next((m for m, mode in enumerate(modes) if close(mode[0])), None)

    def moved_to(base, person, delta, axis=None, shift=0.0) -> dict:  # the trial values of a rival
        bias = base["bias"]
        if axis is None:
            return {**base, "bias": bias.at[person].add(jnp.asarray(delta, bias.dtype))}
        # as rivals.coupling_trial, for one person in the unconstrained values (the coupling's log)
        moved, ratio = rivals.coupling_move(jnp.exp(base["coupling"][person, axis]), shift)
        bias = bias.at[person, axis].multiply(ratio).at[person].add(jnp.asarray(delta, bias.dtype))
        return {**base, "bias": bias, "coupling": base["coupling"].at[person, axis].set(jnp.log(moved))}

    evidence, inverse = score(unconstrained) if scored is None else scored
    modes = [(unconstrained, evidence, inverse)]  # (values, evidence, inverse Hessian)
    current, tried = 0, 0
    with progress_bar(progress, desc="joint rival modes") as bar:
        for _ in range(rivals.MAX_ROUNDS):
            base = modes[current][0]
            params = model_params(rivals.constrained(base), arrays.location_centres, prior)
            profile = np.asarray(rivals.bias_profile(params, arrays, prior, offsets))
            rivalled = [(i, delta) for i, delta, _ in rivals.profile_rivals(profile, offsets, n, people)]
            bias = np.asarray(base["bias"])
            far = people & (np.linalg.norm(bias, axis=-1) > radius)
            if far.any():  # a mode beyond the scan's reach of the prior's centre: scan around bias 0 as well
                around_zero = np.asarray(rivals.bias_profile({**params, "bias": jnp.zeros_like(params["bias"])},
                                                             arrays, prior, offsets))
                rivalled += [(i, delta - bias[i]) for i, delta, _ in rivals.profile_rivals(
                    around_zero, offsets, n, far, reference=profile[(n * n) // 2])]
            if trials:
                at_trials = np.stack([np.asarray(rivals.bias_profile(rivals.coupling_trial(params, axis, shift),
                                                                     arrays, prior, coarse)) for axis, shift in trials])
                rivalled += [(i, delta, axis, shift) for i, axis, shift, delta, _ in rivals.coupling_rivals(
                    at_trials, trials, coarse, profile[(n * n) // 2], people)]
            found = [moved_to(base, *rival) for rival in rivalled]
            found = [trial for trial in found if twin(trial) is None]
            if not found:
                break
            bar.total = (bar.total or 0) + len(found)
            changed = False
            for trial in found:
                bar.update(1)
                tried += 1
                theta = _refine_start(trial, arrays, prior, True, inverse=modes[current][2])
                if not np.all(np.isfinite(np.asarray(theta["bias"]))):
                    continue
                evidence, inverse = score(theta)
                if not math.isfinite(evidence):
                    continue
                m = twin(theta)  # a mode found before: keep the higher of the two points of its basin
                if m is None:
                    modes.append((theta, evidence, inverse))
                    m = len(modes) - 1
                elif evidence > modes[m][1]:
                    modes[m] = (theta, evidence, inverse)
                else:
                    continue
                if m == current or evidence > modes[current][1]:
                    current, changed = m, True
            if not changed:
                break
    best, best_evidence, best_inverse = modes[current]
    everything = np.array([m[1] for m in modes])
    weights = np.exp(everything - np.logaddexp.reduce(everything))
    alternatives, starts = [], []
    flat_index = _bias_index(best)
    for m, (theta, evidence, inverse) in enumerate(modes):
        if m == current or evidence < best_evidence - rivals.AMBIGUITY_MARGIN:
            continue
        apart = np.linalg.norm(np.asarray(theta["bias"]) - np.asarray(best["bias"]), axis=-1)
        who = int(np.argmax(apart))  # the person the two explanations differ on most
        sd = np.sqrt(np.diag(np.asarray(inverse))[flat_index + 2 * who: flat_index + 2 * who + 2])
        values = model_params(rivals.constrained(theta), arrays.location_centres, prior)
        membership = np.asarray(target_marginals(values, arrays, prior)[:, who])
        alternatives.append(rivals.Alternative(int(who), np.asarray(theta["bias"][who]), sd,
                                               float(evidence - best_evidence), float(weights[m]), membership))
        starts.append((theta, inverse))
    start_bias = np.asarray(unconstrained["bias"])
    moved = np.linalg.norm(np.asarray(best["bias"]) - start_bias, axis=-1) >= separation
    if trials:  # or whose couplings it moved to a rival's
        moved |= np.any(np.abs(np.asarray(jnp.exp(best["coupling"]) - jnp.exp(unconstrained["coupling"])))
                        >= rivals.COUPLING_SEPARATION, axis=-1)
    moved = tuple(int(i) for i in np.flatnonzero(moved))
    search = rivals.ModeSearch(best, tuple(alternatives), moved, tried, float(best_evidence), tuple(starts))
    return search, best_inverse


@functools.partial(jax.jit, static_argnames=("prior",))
def _potential_and_gradient(unconstrained: dict, arrays: ModelArrays, prior: JointPrior):
    """The potential and its gradient (flattened as :func:`_laplace_parts`'s) at ``unconstrained``: one gradient,
    where :func:`_laplace_parts` takes ``2d`` of them."""
    flat, unravel = ravel_pytree(unconstrained)
    potential = _potential(arrays, prior)
    return jax.value_and_grad(lambda x: potential(unravel(x)))(flat)


def _descent_steps(flat, unravel, inverse, energy, gradient, evaluate, steps: int):
    """At most ``steps`` steps ``θ ← θ − α Σ ∇U`` (``α`` halved from 1 to 1/4 until the potential falls) while the
    decrement ``∇Uᵀ Σ ∇U`` is at least :data:`_NEWTON_DECREMENT`; ``evaluate(values)`` gives ``(U, ∇U, …)``.
    Returns the last point and its evaluation (``None`` where no step was taken)."""
    last = None
    for _ in range(steps):
        step = -(inverse @ gradient)
        if not float(-(gradient @ step)) > _NEWTON_DECREMENT:  # also a non-finite one
            break
        for alpha in (1.0, 0.5, 0.25):
            trial = evaluate(unravel(flat + alpha * step))
            energy_trial, gradient_trial = trial[:2]
            if (bool(jnp.isfinite(energy_trial)) and float(energy_trial) < float(energy)
                    and bool(jnp.all(jnp.isfinite(gradient_trial)))):
                flat, last, energy, gradient = flat + alpha * step, trial, energy_trial, gradient_trial
                break
        else:
            break
    return flat, last


def _polish_mode(search, inverse_hessian, arrays: ModelArrays, prior: JointPrior):
    """Steps ``θ ← θ − α Σ ∇U`` from the chosen mode to the mode (``α`` halved until the potential falls, until the
    decrement ``∇Uᵀ Σ ∇U`` is below :data:`_NEWTON_DECREMENT`), and the mass matrix taken at the last point
    (Nocedal & Wright 2006, Sec. 3.3 and 11.1).

    The start's BFGS stops short of the mode along a flat, curved ridge: it used all of its 300 steps on every
    scene tried, and three more runs of it still lowered the potential by 1–13 nats each. Head pose only, such a
    ridge runs through every tilt coupling, the concurrences' heights and ``r``; on one 3-person scene the curvature
    taken short of the mode gave it a quarter of the draws' variance, and NUTS took an ESS of 37–53 of 500 draws.
    First up to :data:`_CHORD_STEPS` steps with the search's own inverse Hessian ``Σ`` (the chord method: each step
    one gradient, :func:`_potential_and_gradient`), then the Laplace at the point reached (:func:`_laplace_parts`,
    ``2d`` gradients: the mass matrix, and ``∇U`` from the same gradients) and, while its decrement is still above
    the bar, Newton's steps with it, at most :data:`_NEWTON_STEPS`. On the 6-person bench scene (head pose only) the
    chord steps took the decrement 10.5 → 0.003 and the polish 0.64 s, against 1.9 s for three Laplace calls
    (``benchmarks/RESULTS.md``)."""
    values = search.start
    flat, unravel = ravel_pytree(values)
    energy, gradient = _potential_and_gradient(values, arrays, prior)
    flat, last = _descent_steps(flat, unravel, inverse_hessian, energy, gradient,
                                lambda v: _potential_and_gradient(v, arrays, prior), _CHORD_STEPS)
    if last is None:
        return search, inverse_hessian
    evidence, inverse, energy, gradient = _laplace_parts(unravel(flat), arrays, prior)
    if not bool(jnp.isfinite(evidence)):
        return search, inverse_hessian
    newton_flat, newton_last = _descent_steps(flat, unravel, inverse, energy, gradient,
                                              lambda v: _reordered(_laplace_parts(v, arrays, prior)), _NEWTON_STEPS)
    if newton_last is not None and bool(jnp.isfinite(newton_last[2])):
        flat, (energy, gradient, evidence, inverse) = newton_flat, newton_last
    return search._replace(start=unravel(flat), log_evidence=_predicted_evidence(evidence, inverse, gradient)), inverse


def _reordered(parts):
    """:func:`_laplace_parts`'s ``(evidence, inverse, energy, gradient)`` as ``(energy, gradient, evidence, inverse)``."""
    evidence, inverse, energy, gradient = parts
    return energy, gradient, evidence, inverse


def _bias_index(values: dict) -> int:
    """Where ``bias`` starts in ``values`` flattened in ``jax.tree_util`` order (the inverse mass's order)."""
    index = 0
    for key in sorted(values):
        if key == "bias":
            return index
        index += int(np.size(values[key]))
    raise KeyError("bias")


#: A person whose gaze the fit sends elsewhere this much more often (share of frames) than the model predicts,
#: beyond the others' median excess, is flagged by the predictive check (:func:`_elsewhere_check`).
ELSEWHERE_EXCESS = 0.2


def _elsewhere_check(elsewhere: np.ndarray, predicted: np.ndarray) -> dict:
    """Per person, from ``(S, P)`` draws: the observed and predicted shares of glances elsewhere and the flag.

    A person in a wrong mode of their bias has their looks at people explained as glances elsewhere, far more
    than the prior predicts and than the others have: flagged when the excess ``observed − predicted``
    exceeds the median excess of everyone by :data:`ELSEWHERE_EXCESS`.
    """
    excess = (elsewhere - predicted).mean(axis=0)
    return {"elsewhere_observed": elsewhere.mean(axis=0), "elsewhere_predicted": predicted.mean(axis=0),
            "flagged": excess - np.median(excess) > ELSEWHERE_EXCESS}


@functools.partial(jax.jit, static_argnames=("prior",))
def _posterior_summaries(key, draws: dict, arrays: ModelArrays, prior: JointPrior):
    """One pass over the draws: mean membership ``P(z_ti = j)``, mutual ``E[p_ij p_ji]`` and the predictive check.

    The check, per person: for each draw a target is drawn for every gaze from its
    membership; the observed residual is the angle between the corrected gaze and
    the direction to that target, the replicated one the angle of a direction drawn
    from the cone around it (both over the width, then averaged). Glances elsewhere
    have no direction to compare and are left out. Also per person and draw: the share of
    the frames the fit sends elsewhere, ``mean_t P(z_t = elsewhere | g)``, and the share the
    model predicts, ``mean_t π_t(elsewhere)`` (the chain's share of a target over a stretch of
    constant prior).
    """
    T, P = arrays.present.shape
    frames = jnp.maximum(jnp.sum(arrays.present, axis=0), 1)

    def one(carry, key_and_draw):
        key, draw = key_and_draw
        params = model_params(draw, arrays.location_centres, prior)
        p = target_marginals(params, arrays, prior)
        predicted = jnp.exp(target_log_prior(params, arrays, prior)[..., -1])
        share = lambda x: jnp.sum(jnp.where(arrays.present, x, 0.0), axis=0) / frames  # noqa: E731
        lp = jnp.log(jnp.where(arrays.present[..., None], p, 1.0))
        people = p[..., :P]
        carry = (carry[0] + p, carry[1] + people * jnp.swapaxes(people, 1, 2))

        k1, k2 = jax.random.split(key)
        z = jax.random.categorical(k1, lp, axis=-1)  # (T, P)
        eyes = eye_positions(params, arrays)
        targets = jnp.concatenate([jnp.broadcast_to(eyes[:, None], (T, P, P, 3)),
                                   jnp.broadcast_to(params["locations"][arrays.window][:, None],
                                                    (T, P) + params["locations"].shape[1:])], axis=2)
        chosen = jnp.take_along_axis(targets, jnp.minimum(z, targets.shape[2] - 1)[..., None, None], axis=2)[:, :, 0]
        u = unit(chosen - eyes)
        d = head_to_world(gaze_angles_to_direction(gaze_angles(params, arrays) + params["bias"]),
                          arrays.R_world_from_head)
        width = measurement_width(params, arrays)
        replicated = sample_gaze_directions(k2, GazeRays(eyes.reshape(-1, 3), u.reshape(-1, 3), width.reshape(-1)))
        use = arrays.present & (z < targets.shape[2])
        count = jnp.maximum(jnp.sum(use, axis=0), 1)
        mean = lambda r: jnp.sum(jnp.where(use, r / width, 0.0), axis=0) / count  # noqa: E731
        return carry, (mean(angle_between(d, u)), mean(angle_between(replicated.reshape(T, P, 3), u)),
                       share(p[..., -1]), share(predicted))

    n = jax.tree_util.tree_leaves(draws)[0].shape[0]
    C = P + arrays.location_centres.shape[1] + 1
    dtype = arrays.gaze_angles.dtype
    zero = (jnp.zeros((T, P, C), dtype), jnp.zeros((T, P, P), dtype))
    (total, mutual), (observed, replicated, elsewhere, predicted) = jax.lax.scan(
        one, zero, (jax.random.split(key, n), draws))
    mask = arrays.present[..., None]
    return (jnp.where(mask, total / n, 0.0), jnp.where(mask, mutual / n, 0.0), observed, replicated, elsewhere,
            predicted)


class SVIDiagnostics(NamedTuple):
    """How an SVI fit of :func:`fit_joint` converged (the ``diagnostics`` of its ``sampler``).

    ``elbo_change``: the mean loss (negative ELBO) of the last tenth of the steps minus that of the
    tenth before; ``elbo_noise``: the standard error of that difference; ``final_loss``: the mean
    loss of the last tenth; ``draws``: the guide draws taken. A change below ``−3 × noise`` (still
    improving) is ``RESULTS.max_steps_reached``.
    """

    elbo_change: float
    elbo_noise: float
    final_loss: float
    draws: int


class JointPosterior(NamedTuple):
    """The joint posterior of a recording (Park et al. 2012, eq. 3; Siegfried et al. 2017, eq. 1).

    Candidate order in ``membership``: people ``0 … P−1``, concurrences ``P … P+K−1``,
    elsewhere ``P+K``.

    Attributes:
        sampler: a :class:`~jaxgaze.nuts.SamplerReport`. NUTS: its ``idata`` (posterior, sample_stats,
            observed_data), ``result`` (``not_mixed`` when the mixing checks fail), ``diagnostics``
            (:class:`~jaxgaze.nuts.MixingDiagnostics`: split r-hat, bulk and tail ESS, divergences,
            acceptance) and ``summary`` (:func:`jaxgaze.nuts.posterior_summary`). SVI has no chain to
            judge: ``idata`` holds the guide's independent draws (posterior, observed_data; no
            sample_stats), ``result`` the SVI convergence check (``successful``, ``max_steps_reached``
            for a run still improving, ``nonfinite``), ``diagnostics`` an :class:`SVIDiagnostics`
            and ``summary`` the table of those draws.
        result: the overall :class:`~jaxgaze.results.RESULTS` item: the sampler's, or ``nonfinite``
            when a draw is not finite. :func:`jaxgaze.succeeded` reads it.
        method: ``"nuts"`` or ``"svi"``.
        people: names; fps: frames per second.
        membership: ``(T, P, C)`` posterior ``P(z_ti = j)`` given the whole recording
            (forward–backward; 0 where absent).
        mutual: ``(T, P, P)`` ``P(i looks at j and j looks at i)``.
        samples: posterior draws (``bias (S, P, 2)``, ``cone_width (S, P)``, ``stay (S,)``
            (the probability that a target is held from one frame to the next),
            ``concurrence_locations (S, W, K, 3)``, …).
        window: ``(T,)`` window of each frame.
        start: the pipeline's answer the fit started from (a :class:`JointStart`; its concurrences those kept).
        predictive_check: per person, the observed mean ``angle / width`` of the
            gaze to its target and its replicated draws (``observed (P,)``,
            ``replicated (S, P)``, ``p_value (P,)``); the share of frames the fit sends elsewhere and
            the share the model predicts (``elsewhere_observed``, ``elsewhere_predicted (P,)``), and
            ``flagged (P,)``: people it explains much worse than the others (a wrong mode of their bias);
            a fit that mixed but flags someone is ``misfit``, not ``successful``.
        modes: the search for rival bias modes before sampling (:class:`~jaxgaze.joint.rivals.ModeSearch`;
            ``None`` with wearers of head-mounted cameras, whose start is no mode). ``result`` is
            ``ambiguous`` when it found an alternative the data cannot rule out (:attr:`alternatives`);
            NUTS then samples every such mode, and the draws (so the means, intervals and
            memberships) mix them in proportion to their weights; ``sampler`` reports the worst run.
        spot_log_bayes_factor: with a fixation's spot asked for (``JointPrior.held_scale``, the default),
            the log Bayes factor of the model with it against the model without (:func:`_choose_spot`); the
            spot was kept, and ``held_cone_share`` is among the draws, where it exceeds ``log 3``
            (:data:`SPOT_MIN_LOG_FACTOR`). ``None``: no spot asked for, or wearers of head-mounted cameras
            (their start is no mode to weigh it at; the fit is without one).
        shape_log_bayes_factor: head pose only with a Gaussian-process head–gaze map asked for
            (``JointPrior.coupling_shape_scale``): the log Bayes factor of that map against the linear one
            (:func:`_choose_shape`); the process was kept, and ``coupling_shape`` is among the draws, where it
            exceeds ``log 3`` (:data:`SHAPE_MIN_LOG_FACTOR`). ``None``: the linear map was asked for.
    """

    sampler: SamplerReport
    result: RESULTS
    method: str
    people: tuple[str, ...]
    fps: float
    membership: np.ndarray
    mutual: np.ndarray
    samples: dict
    window: np.ndarray
    start: JointStart
    predictive_check: dict
    modes: rivals.ModeSearch | None = None
    spot_log_bayes_factor: float | None = None
    shape_log_bayes_factor: float | None = None

    @property
    def alternatives(self) -> tuple:
        """The posterior's other modes that the data cannot rule out (:class:`~jaxgaze.joint.rivals.Alternative`);
        non-empty exactly when ``result`` is ``ambiguous`` or a failure hid it."""
        return () if self.modes is None else self.modes.alternatives

    @property
    def message(self) -> str:
        """One line on ``result``: its message, and for ``ambiguous`` who and which alternatives (degrees)."""
        if self.result != RESULTS.ambiguous or not self.alternatives:
            return RESULTS[self.result]
        parts = []
        for a in self.alternatives:
            here = np.degrees(np.asarray(self.modes.start["bias"][a.person]))
            there = np.degrees(a.bias)
            parts.append(f"{self.people[a.person]}'s bias is ({here[0]:+.1f}°, {here[1]:+.1f}°) or "
                         f"({there[0]:+.1f}°, {there[1]:+.1f}°) with weight {a.weight:.2f}")
        mixed = "" if self.sampler.result == RESULTS.successful else f"; and {RESULTS[self.sampler.result]}"
        return "the data cannot tell two explanations apart: " + "; ".join(parts) + mixed

    @property
    def num_people(self) -> int:
        return len(self.people)

    @property
    def num_concurrences(self) -> int:
        return self.membership.shape[-1] - self.num_people - 1

    @property
    def candidates(self) -> tuple[str, ...]:
        """Names of the candidate targets, in membership order."""
        return self.people + tuple(f"concurrence {k}" for k in range(self.num_concurrences)) + ("elsewhere",)

    @property
    def bias(self) -> np.ndarray:
        """``(P, 2)`` posterior mean bias (yaw, tilt), radians."""
        return self.samples["bias"].mean(axis=0)

    @property
    def cone_width(self) -> np.ndarray:
        """``(P,)`` posterior mean cone width, radians."""
        return self.samples["cone_width"].mean(axis=0)

    @property
    def looks_at(self) -> np.ndarray:
        """``(T, P, P)``: ``P(i looks at j)`` for every ordered pair (0 on the diagonal)."""
        return self.membership[..., : self.num_people]

    def map_targets(self) -> np.ndarray:
        """``(T, P)`` most probable target: a person ``j``, ``P + k`` for concurrence ``k``, −1 elsewhere or absent."""
        best = np.argmax(self.membership, axis=-1)
        absent = self.membership.sum(-1) == 0
        return np.where((best == self.membership.shape[-1] - 1) | absent, -1, best)

    def interval(self, site: str, level: float = 0.9) -> np.ndarray:
        """Equal-tailed ``level`` interval of a site: ``(..., 2)`` (lower, upper)."""
        if not 0 < level < 1:
            raise ValueError(f"level must lie in (0, 1), got {level!r}")
        draws = self.samples[site]
        return np.stack([np.quantile(draws, (1 - level) / 2, axis=0), np.quantile(draws, (1 + level) / 2, axis=0)],
                        axis=-1)

    def concurrence_locations(self, level: float = 0.9) -> dict:
        """Per frame, each free concurrence's posterior: ``mean (T, K, 3)``, ``covariance (T, K, 3, 3)``,
        ``hdi (T, K, 3, 2)`` (arviz HDI at ``level``), ``members (T, K)`` (expected number of gazers)
        and ``membership (T, P, K)``."""
        import arviz as az

        draws = self.samples.get("concurrence_locations")
        T, P = self.membership.shape[:2]
        K = self.num_concurrences
        if draws is None or K == 0:
            empty = np.zeros((T, 0, 3))
            return {"mean": empty, "covariance": np.zeros((T, 0, 3, 3)), "hdi": np.zeros((T, 0, 3, 2)),
                    "members": np.zeros((T, 0)), "membership": np.zeros((T, P, 0))}
        mean = draws.mean(axis=0)
        centred = draws - mean
        cov = np.einsum("swki,swkj->wkij", centred, centred) / max(draws.shape[0] - 1, 1)
        hdi = np.asarray(az.hdi(draws[None], hdi_prob=level))  # (W, K, 3, 2)
        membership = self.membership[..., P: P + K]
        return {"mean": mean[self.window], "covariance": cov[self.window], "hdi": hdi[self.window],
                "members": membership.sum(axis=1), "membership": membership}

    def concurrence_counts(self, min_members: int = 2) -> np.ndarray:
        """``(T,)`` gaze concurrences per frame: targets (people or free points) that at least
        ``min_members`` people look at (by their most probable target) — Park's concurrences."""
        targets = self.map_targets()
        C = self.num_people + self.num_concurrences
        counts = np.stack([(targets == c).sum(axis=1) for c in range(C)], axis=1)
        return (counts >= min_members).sum(axis=1)


def _inference_data(samples: dict, stats: dict | None, data: JointData, K: int):
    import arviz as az

    W = data.num_windows
    coords = {"person": list(data.people), "angle": ["yaw", "tilt"], "concurrence": list(range(K)),
              "wearer": [data.people[i] for i in data.wearers],
              "window": list(range(W)), "axis": ["x", "y", "z"], "frame": list(range(data.num_frames))}
    dims = {"bias": ["person", "angle"], "cone_width": ["person"], "concurrence_offset": ["concurrence", "axis"],
            "concurrence_drift": ["window", "concurrence", "axis"],
            "concurrence_locations": ["window", "concurrence", "axis"],
            "eye_offset": ["wearer", "axis"], "calibration_outlier_share": ["wearer"],
            "coupling": ["person", "angle"], "head_lag": ["person"], "coupling_shape": ["person", "angle", "basis"], "head_motion": ["frame", "person", "motion"],
            "gaze_angles": ["frame", "person", "angle"], "present": ["frame", "person"],
            "speaking": ["frame", "person"]}
    observed = {"gaze_angles": data.gaze_angles, "present": data.present.astype(np.int8),
                "speaking": data.speaking}
    if data.head_motion is not None:  # head pose only: what the gaze was inferred from, not a measured gaze
        observed = {**observed, "head_motion": data.head_motion}
        del observed["gaze_angles"]
        coords["motion"] = ["yaw", "tilt", "yaw_rate", "tilt_rate", "rate_fps"]
    return az.from_dict(posterior=samples, sample_stats=stats, observed_data=observed, coords=coords, dims=dims)


def fit_joint(
    data: JointData,
    *,
    key,
    method: str = "nuts",
    num_warmup: int = 500,
    num_samples: int = 500,
    num_chains: int = 1,
    num_steps: int = 3000,
    frames_per_step: int = 256,
    learning_rate: float = 0.02,
    prior: JointPrior = JointPrior(),
    start: JointStart | None = None,
    progress: bool = False,
    throw: bool = False,
) -> JointPosterior:
    """Infer biases, cone widths, who looks at whom and the concurrences of a recording together (Park et al. 2012, eq. 3; Siegfried et al. 2017, eq. 1).

    Args:
        data: the recording, from :func:`~jaxgaze.joint.joint_data`.
        key: a ``jax.random`` key (the start's frame draw, the sampler, the checks).
        method: ``"nuts"`` (exact; a window of a minute or two) or ``"svi"`` (a
            mean-field normal posterior, frames subsampled in whole blocks of
            :data:`~jaxgaze.joint.BLOCK_FRAMES`, ``frames_per_step`` at a time (rounded
            down, at least one block), for ``num_steps`` Adam steps at
            ``learning_rate``; long recordings). A
            mean-field posterior ignores correlations, so its intervals are narrower
            than NUTS's: use it for point estimates and memberships, NUTS on a window
            for intervals. SVI splits the frames over every local device (a
            ``NamedSharding`` of the frame axis), with the one-device answer up to
            float rounding (``docs/runtime.md``).
        num_warmup, num_samples, num_chains: NUTS settings (``num_samples`` draws are
            also taken from the SVI posterior).
        prior: a :class:`JointPrior`. A fixation's spot (``held_scale``) and, head pose only, a Gaussian-process
            head–gaze map (``coupling_shape_scale``) are each kept only where the data favour them by a Bayes
            factor over 3 (:func:`_choose_spot`, then :func:`_choose_shape`).
        start: the pipeline's answer to start from (default :func:`joint_start`). It is
            first moved to the mode of the model with independent frames, then to the
            mode of the model itself (BFGS in the metric of a Laplace covariance; the wearers' eye offsets are kept), and
            sampled or fitted from there. Without wearers, concurrences the data do not need are
            then dropped (Laplace evidence; :func:`_prune_concurrences`) and every person's rival
            bias modes compared (:mod:`~jaxgaze.joint.rivals`; head pose only, couplings too; where the search moves
            someone, the concurrences are pruned again from its mode, :func:`_prune_after_the_search`): NUTS samples each
            mode that carries weight, SVI only the best (its ``result`` is ``ambiguous`` all the same). The best is
            taken to the mode (:func:`_polish_mode`: steps with the search's inverse Hessian, then Newton's steps
            while needed). NUTS uses the inverse Hessian of the
            potential there as its mass matrix, fixed (only the step size adapts in
            the warm-up); with wearers of head-mounted cameras, whose eyes the start
            holds, it learns the mass matrix in the warm-up windows instead. For head pose only
            the couplings' draws are then widened for head errors correlated over seconds
            (:func:`_coupling_widening`).
        progress: progress bars on stderr.
        throw: ``False`` (the default, as in every jaxgaze fit): a failure is the posterior's
            ``result``; ``True``: raise :class:`~jaxgaze.results.FitError`, whose ``fit`` is that
            posterior.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if not isinstance(data, JointData):
        raise TypeError(f"data must be a JointData (see jaxgaze.joint.joint_data), got {type(data).__name__}")
    for label, value, least in (("num_warmup", num_warmup, 1), ("num_samples", num_samples, 4),
                                ("num_chains", num_chains, 1), ("num_steps", num_steps, 10),
                                ("frames_per_step", frames_per_step, 1)):
        if int(value) != value or value < least:
            raise ValueError(f"{label} must be an integer ≥ {least}, got {value!r}")
    k_start, k_fit, k_draws, k_check = jax.random.split(key, 4)
    start = joint_start(data, key=k_start, progress=progress) if start is None else start
    if start.concurrence_centres.shape[0] != data.num_windows:
        raise ValueError(f"start has {start.concurrence_centres.shape[0]} windows, the data {data.num_windows}")
    if start.eye_offset.shape[0] != len(data.wearers):
        raise ValueError(f"start has eye offsets of {start.eye_offset.shape[0]} wearers, the data "
                         f"{len(data.wearers)}; build it with joint_start")
    dtype = jnp.result_type(float)
    # With wearers the start holds their eyes at Park's calibration, where the potential curves down along
    # the eye's depth: no mode, so NUTS learns its mass matrix in the warm-up instead of the Laplace one.
    at_mode = not data.wearers

    # a fixation's spot and a GP head–gaze map are weighed after the pruning (_choose_shape, _choose_spot)
    plain = prior._replace(held_scale=None, coupling_shape_scale=None)

    arrays = _arrays(data, start.concurrence_centres, dtype)
    values = {k: jnp.asarray(v, dtype) for k, v in _unconstrained(_start_values(start, plain, data.num_people)).items()}
    unconstrained = _refine_start(values, arrays, plain, at_mode)
    twins = _twin_concurrences(unconstrained, start.concurrence_centres, prior)
    if twins:  # masked as the pruning masks (_without_concurrence), so that the second refinement shares the programs
        for k in twins:
            values, arrays = _without_concurrence(values, arrays, k)
        unconstrained = _refine_start(values, arrays, plain, at_mode)
    search, scored, spot_factor, shape_factor = None, None, None, None
    if at_mode:  # the slots dropped stay masked, so that what follows shares the pruning's programs
        unconstrained, arrays, scored = _prune_concurrences(unconstrained, arrays, plain, progress)
    shape_scale, prior = prior.coupling_shape_scale, prior._replace(coupling_shape_scale=None)
    if prior.held_scale is not None and at_mode:
        prior, unconstrained, spot_factor = _choose_spot(unconstrained, arrays, prior)
        scored = scored if prior.held_scale is None else None
    else:  # wearers: their start is no mode, where the spot's factor would weigh the start's misfit
        prior = plain
    if at_mode and shape_scale is not None and data.head_motion is not None:  # (head pose only has no wearers)
        scored = _laplace_evidence(unconstrained, arrays, prior) if scored is None else scored
        shaped = prior._replace(coupling_shape_scale=shape_scale)
        shape_start = {k: jnp.asarray(v, dtype) for k, v in
                       _unconstrained(_start_values(start, shaped, data.num_people)).items()}
        prior, unconstrained, shape_factor, scored = _choose_shape(unconstrained, shape_start, arrays, shaped, scored)
    if at_mode:
        search, inverse_hessian = _search_modes(unconstrained, arrays, prior, data.wearers, progress, scored)
        search, inverse_hessian, arrays = _prune_after_the_search(search, inverse_hessian, arrays, prior, progress)
        search, inverse_hessian = _polish_mode(search, inverse_hessian, arrays, prior)
        unconstrained = search.start
    widening = None  # head pose only: the couplings' intervals for errors correlated over seconds
    if at_mode and data.head_motion is not None:
        widening = _coupling_widening(unconstrained, inverse_hessian, arrays, prior, data.fps)
    kept = np.flatnonzero(np.asarray(slot_mask(arrays)))  # the twins and the pruning masked the others
    if search is not None:
        search, inverse_hessian, arrays = _drop_masked_slots(search, inverse_hessian, arrays)
        unconstrained = search.start
    else:
        unconstrained, arrays, _ = _drop_masked(unconstrained, arrays)
    start = start._replace(concurrence_centres=start.concurrence_centres[:, kept],
                           concurrence_support=start.concurrence_support[kept])
    K = start.num_concurrences
    if method == "nuts":
        modes = [(unconstrained, inverse_hessian if at_mode else None)] + list(search.alternative_starts if search else ())
        gaps = np.array([0.0] + [a.log_evidence_gap for a in (search.alternatives if search else ())])
        runs = [_sample_mode(values, mass, arrays, prior, key, num_chains, num_warmup, num_samples, progress)
                for (values, mass), key in zip(modes, jax.random.split(k_fit, len(modes)))]
        draws, stats = _mixture(runs, np.exp(gaps - np.logaddexp.reduce(gaps)), int(num_samples))
        draws = draws if widening is None else _widen(draws, widening)
        sampler = sampler_report(_inference_data(draws, stats, data, K), _SUMMARY_SITES)
        if len(runs) > 1:  # mixed draws have no r-hat: each mode's run is checked alone, the worst one reported
            reports = [sampler_report(_inference_data(d, st, data, K), _SUMMARY_SITES) for d, st in runs]
            worst = next((r for r in reports if r.result != RESULTS.successful), reports[0])
            sampler = sampler._replace(result=worst.result, diagnostics=worst.diagnostics)
    else:
        draws, svi_result, diagnostics = _svi(data, arrays, unconstrained, prior, k_fit, k_draws, int(num_steps),
                                              int(frames_per_step), float(learning_rate), int(num_samples), progress)
        draws = draws if widening is None else _widen(draws, widening)
        idata = _inference_data(draws, None, data, K)
        sampler = SamplerReport(idata, svi_result, diagnostics, posterior_summary(idata, _SUMMARY_SITES))
    result = sampler.result
    flat = {k: v.reshape((-1,) + v.shape[2:]) for k, v in draws.items()}
    if not all(np.all(np.isfinite(v)) for v in flat.values()):
        result = RESULTS.nonfinite
    elif search is not None and search.alternatives:
        result = RESULTS.ambiguous  # about the data, whatever the sampler did (the message says that too)
    pick = np.linspace(0, flat["bias"].shape[0] - 1, min(_MAX_PROBABILITY_DRAWS, flat["bias"].shape[0])).astype(int)
    latent = {k: jnp.asarray(v[pick], dtype) for k, v in flat.items() if k != "concurrence_locations"}
    membership, mutual, observed, replicated, elsewhere, predicted = (
        np.asarray(a) for a in _posterior_summaries(k_check, latent, arrays, prior))
    check = {"observed": observed.mean(axis=0), "replicated": replicated,
             "p_value": (replicated >= observed).mean(axis=0), **_elsewhere_check(elsewhere, predicted)}
    if result == RESULTS.successful and check["flagged"].any():
        result = RESULTS.misfit  # the sampler mixed, but in a mode that explains someone's gaze badly
    posterior = JointPosterior(sampler, result, method, data.people, data.fps, membership, mutual, flat,
                               data.window, start, check, search, spot_factor, shape_factor)
    return throw_if_failed(posterior, result, "fit_joint") if throw else posterior


def _sample_mode(values: dict, mass, arrays: ModelArrays, prior: JointPrior, key, num_chains: int, num_warmup: int,
                 num_samples: int, progress: bool):
    """NUTS from one mode (its inverse Hessian as the mass matrix, fixed; learnt in the warm-up when ``None``)."""
    batched = lambda a: jnp.broadcast_to(jnp.asarray(a), (num_chains,) + jnp.shape(a))  # noqa: E731
    draws, stats = sample_nuts(_model(prior, None), key, tuple(batched(a) for a in arrays),
                               {k: batched(v) for k, v in values.items()}, num_warmup=int(num_warmup),
                               num_samples=int(num_samples), dense_mass=True,
                               inverse_mass_matrix=None if mass is None else batched(mass), progress=progress,
                               description="joint NUTS")
    return {k: np.asarray(v) for k, v in draws.items()}, {k: np.asarray(v) for k, v in stats.items()}


def _mixture(runs: list, weights: np.ndarray, num_samples: int):
    """The draws of every mode's run in proportion to its weight (Laplace evidences normalised): each chain's
    first ``round(w_m S)`` draws of mode ``m`` in turn, ``S`` in all (the chosen mode takes the rounding)."""
    if len(runs) == 1:
        return runs[0]
    counts = np.floor(weights * num_samples + 0.5).astype(int)
    counts[0] += num_samples - counts.sum()
    join = lambda parts: {k: np.concatenate([p[k][:, :n] for p, n in zip(parts, counts)], axis=1)  # noqa: E731
                          for k in parts[0]}
    return join([r[0] for r in runs]), join([r[1] for r in runs])


def mean_field_guide(*model_args, start: dict, **model_kwargs):
    """Mean-field normal guide of the joint model in numpyro's unconstrained space, centred on ``start``.

    Each latent site ``s`` gets ``numpyro.param`` location and scale; positive sites are
    log-normal and shares logit-normal. (A plain numpyro guide function: unlike an
    autoguide it needs no eager trace of the model's gradient to start, which for
    this model costs a minute of op-by-op compilation.)
    """
    for site, value in start.items():
        value = jnp.asarray(value)
        loc = numpyro.param(f"{site}_loc", value)
        scale = numpyro.param(f"{site}_scale", jnp.full(value.shape, 0.01, value.dtype),
                              constraint=dist.constraints.softplus_positive)
        base = dist.Normal(loc, scale)
        if site in POSITIVE_SITES:
            fn = dist.TransformedDistribution(base, dist.transforms.ExpTransform())
        elif site in UNIT_SITES:
            fn = dist.TransformedDistribution(base, dist.transforms.SigmoidTransform())
        else:
            fn = base
        numpyro.sample(site, fn.to_event(value.ndim) if value.ndim else fn)


def _svi_arrays(arrays: ModelArrays) -> ModelArrays:
    """SVI's copy of the model's arrays: frames padded to whole blocks, the frame axis split over the local devices.

    The ``T`` frames are padded to ``B·L`` (``B = ⌈T / L⌉`` blocks of ``L`` =
    :data:`~jaxgaze.joint.BLOCK_FRAMES`) with copies of the last frame in which nobody
    is present. Such a frame only ends the last block, where the model already pads
    with unobserved frames: the chain moves on without an observation and adds
    ``log Σ_j p(z_t = j | g_<t) = log 1 = 0``, so the likelihood, the block count and
    the subsampling are unchanged (up to float rounding). With ``D > 1`` local devices
    the nine frame-axis leaves are split over a ``Mesh`` of ``gcd(D, B·L)`` of them
    (``NamedSharding(mesh, PartitionSpec("frames"))``; ``gcd(D, B·L) = D`` for ``D``
    a divisor of 64), the others replicated. A step then gathers its blocks from the
    devices that hold them (one all-reduce) and evaluates their ELBO on every device.
    The padding is the same for every ``D``, so one device and many run the same model
    on the same arrays.
    """
    T = arrays.present.shape[0]
    frames = -(-T // BLOCK_FRAMES) * BLOCK_FRAMES
    padded = ModelArrays(*(jnp.concatenate([a, jnp.repeat(a[-1:], frames - T, axis=0)]) for a in arrays[:9]),
                         *arrays[9:])
    padded = padded._replace(present=padded.present.at[T:].set(False))
    devices = jax.local_devices()[: math.gcd(jax.local_device_count(), frames)]
    if len(devices) == 1:
        return padded
    sharding = frame_sharding(devices)
    return ModelArrays(*jax.device_put(list(padded[:9]), sharding),
                       *jax.device_put(list(padded[9:]), NamedSharding(sharding.mesh, PartitionSpec())))


def _svi_run(svi: SVI, key, arrays: ModelArrays, num_steps: int, progress: bool):
    """``svi.run(key, num_steps, *arrays)``, compiled with the arrays as arguments: the last state and the losses.

    ``SVI.run`` closes over the arrays, and jit makes a closed-over array a replicated
    constant; as arguments they keep their sharding. The start and the steps are one
    program (one per step under a progress bar), so the start's trace of the model,
    which only looks for its parameters, is compiled away instead of run op by op.
    """
    def init(key, arrays):
        return svi.init(key, *arrays)

    def update(state, arrays):
        return svi.update(state, *arrays)

    if not progress:
        def run(key, arrays):
            return jax.lax.scan(lambda state, _: update(state, arrays), init(key, arrays), None, length=num_steps)

        return jax.jit(run)(key, arrays)
    from tqdm.auto import trange

    state, step, losses = jax.jit(init)(key, arrays), jax.jit(update), []
    if isinstance(arrays.present.sharding, NamedSharding):  # a step returns the state replicated on the mesh:
        state = jax.device_put(state, NamedSharding(arrays.present.sharding.mesh, PartitionSpec()))  # compile once
    for _ in trange(num_steps, desc="joint SVI", file=sys.stderr):
        state, loss = step(state, arrays)
        losses.append(loss)
    return state, jnp.stack(losses)


def _svi(data, arrays, start, prior, key, key_draws, num_steps, frames_per_step, learning_rate, num_samples,
         progress):
    num_blocks = -(-data.num_frames // BLOCK_FRAMES)
    batch = max(1, frames_per_step // BLOCK_FRAMES)
    model = _model(prior, batch if batch < num_blocks else None)
    guide = functools.partial(mean_field_guide, start=start)
    svi = SVI(model, guide, numpyro.optim.Adam(learning_rate), Trace_ELBO())
    state, losses = _svi_run(svi, key, _svi_arrays(arrays), num_steps, progress)
    params = svi.get_params(state)
    losses = np.asarray(losses)
    tail = max(10, num_steps // 10)
    last, before = losses[-tail:], losses[-2 * tail: -tail]
    change = float(np.mean(last) - np.mean(before))
    noise = float(np.std(last) / math.sqrt(tail) + np.std(before) / math.sqrt(tail))
    if not np.all(np.isfinite(losses[-tail:])):
        result = RESULTS.nonfinite
    elif change < -3.0 * noise:
        result = RESULTS.max_steps_reached
    else:
        result = RESULTS.successful
    draws = Predictive(guide, params=params, num_samples=num_samples)(key_draws, *arrays)
    latent = {k: np.asarray(v)[None] for k, v in draws.items() if k in start}
    if "concurrence_offset" in latent:
        centres = arrays.location_centres
        latent["concurrence_locations"] = np.asarray(
            jax.vmap(lambda d: concurrence_locations(d, centres, prior))(
                {k: jnp.asarray(v[0]) for k, v in latent.items()}))[None]
    return latent, result, SVIDiagnostics(change, noise, float(last.mean()), int(num_samples))
