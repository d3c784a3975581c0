"""Bayesian gaze-ray calibration: a posterior over the eye centre, direction and ``h``.

Park et al. (2012), Sec. 3.2 calibrate the primary gaze ray of a wearer from the
points of regard ``y_i`` expressed in the wearer's **camera frame** (metres):
while the pair looks at each other's camera, every ``y_i`` lies in the wearer's
gaze cone. Instead of RANSAC plus the convex apex programme, this module puts a
prior on the ray and samples its posterior with NUTS:

* eye centre ``p ~ N(0, prior_scale² I)`` in the camera frame;
* direction ``v = u / ‖u‖`` with ``u ~ N(e_x · direction_concentration, I)``,
  a projected normal centred on the camera's forward axis (+x);
* bandwidth ``h ~ LogNormal(log 0.03, 1)`` (radians);
* outlier share ``ε ~ Beta(1, 9)``.

Each point is a mixture: with probability ``1 − ε`` it follows the cone model
(:func:`jaxgaze.cone.cone_log_density`: its offset on the cross-section at depth
``t`` is ``N(0, (h t)² I₂)``), with probability ``ε`` a broad cone of
``outlier_bandwidth`` radians (the wearer looked elsewhere). The ``t``-dependent
normaliser of the cone density is what identifies the eye centre along the ray:
the scatter of the points grows linearly with their depth from the apex.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import warnings
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from jaxtyping import Array, Float, PRNGKeyArray
from numpyro.infer import MCMC, NUTS

from jaxgaze.cone import cone_log_density
from jaxgaze.geometry import unit
from jaxgaze.rays import GazeRays

if TYPE_CHECKING:  # arviz is imported when a posterior is summarised: it is slow to import
    import arviz as az

__all__ = [
    "calibration_model",
    "calibrate_cone_posterior",
    "CalibrationPosterior",
    "propagate_to_concurrences",
    "ConcurrenceEnsemble",
]


def _points(points) -> np.ndarray:
    y = np.asarray(points, dtype=float)
    if y.ndim != 2 or y.shape[1] != 3:
        raise ValueError(f"points must have shape (M, 3), got {y.shape}")
    if len(y) < 3:
        raise ValueError(f"calibration needs at least 3 points of regard, got {len(y)}")
    if not np.all(np.isfinite(y)):
        row = int(np.argwhere(~np.isfinite(y))[0, 0])
        raise ValueError(f"point of regard {row} is not finite (NaN or inf)")
    return y


def calibration_model(
    points: Float[Array, "M 3"],
    *,
    prior_scale: float = 0.2,
    direction_concentration: float = 3.0,
    outlier_bandwidth: float = 0.5,
):
    """numpyro model of the calibration points (camera frame) under the cone model."""
    dtype = points.dtype
    eye_center = numpyro.sample("eye_center", dist.Normal(jnp.zeros(3, dtype), prior_scale).to_event(1))
    forward = jnp.array([direction_concentration, 0.0, 0.0], dtype)
    raw = numpyro.sample("direction_raw", dist.Normal(forward, 1.0).to_event(1))
    direction = numpyro.deterministic("direction", unit(raw))
    bandwidth = numpyro.sample("bandwidth", dist.LogNormal(jnp.log(0.03), 1.0))
    outlier_share = numpyro.sample("outlier_share", dist.Beta(1.0, 9.0))

    def log_density(h):
        rays = GazeRays(eye_center[None], direction[None], h)
        return jax.vmap(lambda y: cone_log_density(rays, y)[0])(points)

    inlier = jnp.log1p(-outlier_share) + log_density(bandwidth)
    outlier = jnp.log(outlier_share) + log_density(jnp.asarray(outlier_bandwidth, dtype))
    per_point = jnp.logaddexp(inlier, outlier)
    numpyro.deterministic("inlier_probability", jnp.exp(inlier - per_point))
    numpyro.factor("points", jnp.sum(per_point))


class CalibrationPosterior(NamedTuple):
    """Posterior of one wearer's calibration.

    Attributes:
        idata: ``arviz.InferenceData`` (posterior, sample stats, observed points).
        summary: ``az.summary`` table (mean, sd, HDI, ESS, r-hat) of the main parameters.
        eye_center, direction: posterior means, camera frame (direction renormalised).
        bandwidth: posterior mean of ``h`` (radians).
        samples: dict of posterior draws (``eye_center (S,3)``, ``direction (S,3)``, ``bandwidth (S,)``, …).
        predictive_check: dict with the observed mean whitened distance ``‖d‖/h`` of
            the inliers and its posterior-predictive distribution (``observed``, ``replicated``,
            ``p_value``), a check that the cone spread fits the data.
    """

    idata: "az.InferenceData"
    summary: object
    eye_center: np.ndarray
    direction: np.ndarray
    bandwidth: float
    samples: dict
    predictive_check: dict


def calibrate_cone_posterior(
    points,
    *,
    key: PRNGKeyArray,
    num_warmup: int = 500,
    num_samples: int = 500,
    num_chains: int = 1,
    init_eye_center=None,
    init_direction=None,
    progress_bar: bool = False,
    **model_options,
) -> CalibrationPosterior:
    """Sample the calibration posterior with NUTS (numpyro) and summarise it with arviz.

    ``points (M, 3)`` are the points of regard in the wearer's camera frame
    (metres). ``init_*`` (e.g. from the RANSAC point estimate) start the chains
    near the mode; by default they start at the camera centre looking along +x.
    """
    y = jnp.asarray(_points(points))
    concentration = model_options.get("direction_concentration", 3.0)
    start_direction = jnp.array([1.0, 0.0, 0.0]) if init_direction is None else unit(jnp.asarray(init_direction))
    # Starting point in numpyro's unconstrained space (log h, logit ε).
    init_params = {
        "eye_center": jnp.zeros(3) if init_eye_center is None else jnp.asarray(init_eye_center),
        "direction_raw": start_direction * concentration,
        "bandwidth": jnp.log(0.05),
        "outlier_share": jax.scipy.special.logit(0.05),
    }
    init_params = jax.tree_util.tree_map(lambda a: jnp.asarray(a, y.dtype), init_params)
    mcmc = _sampler(num_warmup, num_samples, num_chains, progress_bar, tuple(sorted(model_options.items())))
    sample_key, check_key = jax.random.split(key)
    if num_chains > 1:
        init_params = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (num_chains,) + a.shape), init_params)
    mcmc.run(sample_key, y, init_params=init_params)
    import arviz as az

    samples = {k: np.asarray(v) for k, v in mcmc.get_samples().items()}
    with _single_chain_quiet(num_chains):
        idata = az.from_numpyro(mcmc)
        summary = az.summary(idata, var_names=["eye_center", "direction", "bandwidth", "outlier_share"])
    direction_mean = samples["direction"].mean(0)
    return CalibrationPosterior(
        idata=idata,
        summary=summary,
        eye_center=samples["eye_center"].mean(0),
        direction=direction_mean / np.linalg.norm(direction_mean),
        bandwidth=float(samples["bandwidth"].mean()),
        samples=samples,
        predictive_check=_predictive_check(check_key, y, samples),
    )


@contextlib.contextmanager
def _single_chain_quiet(num_chains: int):
    """With one chain arviz logs that r-hat cannot be computed (it is NaN in the summary); silence that."""
    if num_chains > 1:
        yield
        return
    import arviz

    # arviz logs through its own ``Logger("arviz")`` instance, not ``logging.getLogger``.
    loggers = [log for log in (getattr(arviz, "_log", None), logging.getLogger("arviz")) if log is not None]
    levels = [log.level for log in loggers]
    for log in loggers:
        log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            yield
    finally:
        for log, level in zip(loggers, levels):
            log.setLevel(level)


@functools.lru_cache(maxsize=8)
def _sampler(num_warmup, num_samples, num_chains, progress_bar, model_options):
    """One MCMC object per setting, so that wearers with the same number of points share a compilation."""
    model = functools.partial(calibration_model, **dict(model_options))
    kernel = NUTS(model, target_accept_prob=0.9)
    return MCMC(kernel, num_warmup=num_warmup, num_samples=num_samples, num_chains=num_chains,
                progress_bar=progress_bar, chain_method="sequential", jit_model_args=True)


def _whitened(points, eye_center, direction, bandwidth):
    diff = points - eye_center
    t = diff @ direction
    perp = diff - t[:, None] * direction
    return jnp.linalg.norm(perp, axis=-1) / (jnp.maximum(t, 1e-9) * bandwidth)


def _predictive_check(key, points, samples) -> dict:
    """Posterior-predictive check of the cone spread on the likely inliers.

    For every draw, the observed statistic is the mean ``‖d_i‖/h`` over points with
    inlier probability > 0.5; replicated points are drawn from the cone at the same
    depths. Under the model both are ≈ √(π/2) ≈ 1.25.
    """
    eye, direction, h = (jnp.asarray(samples[k]) for k in ("eye_center", "direction", "bandwidth"))
    inlier = jnp.asarray(samples["inlier_probability"]).mean(0) > 0.5
    observed = jax.vmap(lambda p, v, b: _whitened(points, p, v, b))(eye, direction, h)
    observed = jnp.sum(observed * inlier, axis=1) / jnp.maximum(jnp.sum(inlier), 1)
    offsets = jax.random.normal(key, (eye.shape[0], points.shape[0], 2))
    replicated = jnp.sum(jnp.linalg.norm(offsets, axis=-1) * inlier, axis=1) / jnp.maximum(jnp.sum(inlier), 1)
    return {
        "observed": np.asarray(observed),
        "replicated": np.asarray(replicated),
        "p_value": float(jnp.mean(replicated >= observed)),
    }


class ConcurrenceEnsemble(NamedTuple):
    """Concurrence locations under an ensemble of calibrations (one per posterior draw).

    Attributes:
        reference: the concurrences of the reference rays (e.g. the posterior means).
        locations: ``(S, K, 3)`` location of each reference mode under each draw
            (matched to the nearest mode of that draw; NaN where none is within reach).
        found: ``(S, K)`` whether draw ``s`` has a mode matched to reference mode ``k``.
        mean: ``(K, 3)`` ensemble mean location.
        covariance: ``(K, 3, 3)`` ensemble covariance: the calibration's share of the
            location uncertainty, to be added to the per-frame Laplace covariance.
    """

    reference: object
    locations: np.ndarray
    found: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray


def propagate_to_concurrences(
    eye_centers: Float[Array, "S N 3"],
    directions: Float[Array, "S N 3"],
    bandwidths: Float[Array, "S N"],
    R_world_from_camera: Float[Array, "N 3 3"],
    camera_centers: Float[Array, "N 3"],
    *,
    max_distance: float = 0.5,
    **options,
) -> ConcurrenceEnsemble:
    """Carry calibration uncertainty into the concurrences of one frame.

    Draw ``s`` gives person ``i`` the ray ``p = R_i e_s,i + C_i``, ``v = R_i d_s,i``
    (camera frame → world). All draws go through
    :func:`jaxgaze.find_concurrences_over_frames` at once, the draws playing the role
    of frames, and each reference mode (from the mean calibration) is matched to the
    nearest mode of every draw within ``max_distance`` metres.
    """
    from jaxgaze.concurrence import find_concurrences, find_concurrences_over_frames

    eye = jnp.asarray(eye_centers)
    d = jnp.asarray(directions)
    R = jnp.asarray(R_world_from_camera)
    C = jnp.asarray(camera_centers)
    if eye.ndim != 3 or eye.shape[-1] != 3 or d.shape != eye.shape:
        raise ValueError(f"eye_centers and directions must both be (S, N, 3), got {eye.shape} and {d.shape}")
    if R.shape != (eye.shape[1], 3, 3) or C.shape != (eye.shape[1], 3):
        raise ValueError(f"need one camera pose per person: R {R.shape}, centres {C.shape} for N = {eye.shape[1]}")
    origins = jnp.einsum("nij,snj->sni", R, eye) + C
    world_directions = jnp.einsum("nij,snj->sni", R, d)
    ensemble = find_concurrences_over_frames(GazeRays(origins, world_directions, bandwidths), **options)
    mean_direction = unit(world_directions.mean(0))
    reference = find_concurrences(GazeRays(origins.mean(0), mean_direction, jnp.asarray(bandwidths).mean(0)), **options)

    ref = np.asarray(reference.locations)  # (K, 3)
    locs = np.asarray(ensemble.locations)  # (S, K', 3)
    valid = np.asarray(ensemble.valid)
    dist = np.linalg.norm(locs[:, None, :, :] - ref[None, :, None, :], axis=-1)  # (S, K, K')
    dist = np.where(valid[:, None, :], dist, np.inf)
    nearest = np.argmin(dist, axis=-1) if dist.shape[-1] else np.zeros(dist.shape[:2], int)
    best = np.take_along_axis(dist, nearest[..., None], axis=-1)[..., 0] if dist.shape[-1] else np.full(
        dist.shape[:2], np.inf)
    found = best <= max_distance
    matched = np.where(found[..., None], np.take_along_axis(locs, nearest[..., None], axis=1), np.nan)
    mean = np.nanmean(matched, axis=0) if len(ref) else np.zeros((0, 3))
    centred = np.where(found[..., None], matched - mean, 0.0)
    counts = np.maximum(found.sum(0) - 1, 1)
    covariance = np.einsum("ski,skj->kij", centred, centred) / counts[:, None, None]
    return ConcurrenceEnsemble(reference, matched, found, mean, covariance)
