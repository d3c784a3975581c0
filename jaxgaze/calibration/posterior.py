"""Bayesian gaze-ray calibration: a posterior over the eye centre, direction and ``h``.

Park et al. (2012), Sec. 3.2 calibrate the primary gaze ray of a wearer from the
points of regard ``y_i`` expressed in the wearer's **camera frame** (metres):
while the pair looks at each other's camera, every ``y_i`` lies in the wearer's
gaze cone. Instead of RANSAC plus the convex apex programme, this module puts a
prior on the ray and samples its posterior with NUTS:

* eye centre ``p ~ N(0, prior_scale² I)`` in the camera frame;
* direction ``v ~ ProjectedNormal(e_x · direction_concentration)`` (the direction of
  ``N(e_x · direction_concentration, I)``), centred on the camera's forward axis (+x);
  it is sampled as ``v = u / ‖u‖`` with a free 3-vector ``u`` whose length, which the
  likelihood does not see, is held near 1 (:data:`DIRECTION_RADIUS_SCALE`);
* bandwidth ``h ~ LogNormal(log 0.03, 1)`` (radians);
* outlier share ``ε ~ Beta(1, 9)``.

Each point is a mixture: with probability ``1 − ε`` it follows the cone model
(:func:`jaxgaze.cone.cone_log_density`: its offset on the cross-section at depth
``t`` is ``N(0, (h t)² I₂)``), with probability ``ε`` a broad background cone
of ``outlier_bandwidth`` radians from the camera centre along the camera's +x
(the wearer looked elsewhere). The background does not depend on the ray, so
outliers cannot pull the eye centre (a broad cone around the gaze ray itself
would). The ``t``-dependent normaliser of the cone density is what identifies
the eye centre along the ray: the scatter of the points grows linearly with their depth from the apex.

Why the length of ``u`` is held: drawn as ``u ~ N(c e_x, I)`` (the usual way to sample a
projected normal) its length ranges over ``c ± 2``, and the posterior of ``u`` across the ray is
``‖u‖`` times the angular spread, a funnel. A mass matrix and step size adapted where
``‖u‖ ≈ 3`` are several times too coarse where ``‖u‖ < 1``: a chain that strayed there at the
end of warm-up rejected every proposal for all its draws (acceptance 0, split r-hat NaN),
and whether it did hung on the last bit of a float32 start point. Here
``u`` has the density ``PN(u/‖u‖) · N(‖u‖; 1, s²) / ‖u‖²``: the same projected normal prior on
the direction (the radial factor integrates out against the ``‖u‖²`` of the volume element),
with ``‖u‖`` within ``1 ± 4s``, so the scales across the ray change by at most that much.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from jaxgaze.calibration.cone_fit import ConeCalibration
from jaxgaze.cone import cone_log_density
from jaxgaze.geometry import angle_between
from jaxgaze._checks import bucket_size
from jaxgaze.nuts import SamplerReport, quiet_single_chain, sample_nuts, sampler_report, set_units, split_chains
from jaxgaze.rays import GazeRays
from jaxgaze.results import RESULTS, succeeded, throw_if_failed

__all__ = [
    "calibration_model",
    "calibration_log_likelihood",
    "calibrate_cone_posterior",
    "calibrate_cone_posterior_batch",
    "CalibrationPosterior",
    "CalibrationChoice",
    "needs_posterior",
    "choose_calibration",
    "MAX_EYE_OFFSET",
    "DIRECTION_RADIUS_SCALE",
    "UNITS",
]

#: The farthest a wearer's eye centre can plausibly be from the head-mounted camera (metres); a
#: posterior mean beyond it is ``RESULTS.implausible``.
MAX_EYE_OFFSET = 0.3
#: Standard deviation ``s`` of the length of the latent direction vector ``u`` about 1 (the
#: direction is ``u / ‖u‖``; see the module's docstring). The length is a nuisance that the data
#: do not see; holding it near 1 keeps the posterior's scales across the ray nearly constant.
DIRECTION_RADIUS_SCALE = 0.1
_SUMMARY_VARS = ["eye_center", "direction", "bandwidth", "outlier_share"]
#: Units of the posterior's variables, in their attributes (and so in the netCDF); "1": no unit.
UNITS = {"eye_center": "m", "direction": "1", "bandwidth": "rad", "outlier_share": "1", "inlier_probability": "1",
         "points": "m", "diverging": "1", "acceptance_rate": "1", "n_steps": "1", "lp": "1"}


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
    mask: Bool[Array, " M"] | None = None,
    *,
    prior_scale: float = 0.2,
    direction_concentration: float = 3.0,
    outlier_bandwidth: float = 0.5,
):
    """numpyro model of the calibration points (camera frame) under the cone model (Park et al. 2012, Sec. 3.2).

    ``mask`` marks the real points (``False`` for padding, which adds nothing).
    """
    dtype = points.dtype
    eye_center = numpyro.sample("eye_center", dist.Normal(jnp.zeros(3, dtype), prior_scale).to_event(1))
    forward = jnp.array([direction_concentration, 0.0, 0.0], dtype)
    # v ~ ProjectedNormal(forward), through u with density PN(u/‖u‖) N(‖u‖; 1, s²) / ‖u‖² (module docstring).
    raw = numpyro.sample("direction_raw", dist.ImproperUniform(dist.constraints.real_vector, (), (3,)))
    radius = jnp.linalg.norm(raw)
    direction = numpyro.deterministic("direction", raw / radius)
    numpyro.factor("direction_prior", dist.ProjectedNormal(forward).log_prob(direction)
                   - 0.5 * jnp.square((radius - 1.0) / DIRECTION_RADIUS_SCALE) - 2.0 * jnp.log(radius))
    bandwidth = numpyro.sample("bandwidth", dist.LogNormal(jnp.log(0.03), 1.0))
    outlier_share = numpyro.sample("outlier_share", dist.Beta(1.0, 9.0))

    per_point, inlier_probability = calibration_log_likelihood(points, eye_center, direction, bandwidth,
                                                               outlier_share, outlier_bandwidth)
    numpyro.deterministic("inlier_probability", inlier_probability)
    if mask is not None:
        per_point = jnp.where(mask, per_point, 0.0)
    numpyro.factor("points", jnp.sum(per_point))


def calibration_log_likelihood(
    points: Float[Array, "M 3"],
    eye_center: Float[Array, "3"],
    direction: Float[Array, "3"],
    bandwidth,
    outlier_share,
    outlier_bandwidth: float = 0.5,
) -> tuple[Float[Array, " M"], Float[Array, " M"]]:
    """Per-point log likelihood of calibration points of regard, and each point's inlier probability (Park et al. 2012, Sec. 3.2).

    A point is on the wearer's cone around the primary ray ``(eye_center,
    direction)`` with bandwidth ``h`` (share ``1 − outlier_share``), or, looking
    elsewhere, on a broad cone of ``outlier_bandwidth`` around the camera's +x
    axis. The background does not move with the ray: looking elsewhere says
    nothing about where the eyes are, and a ray-centred one lets outliers drag the
    apex. Camera frame (+x forward), metres.
    """
    dtype = points.dtype

    def log_density(origin, axis, h):
        rays = GazeRays(origin[None], axis[None], h)
        return jax.vmap(lambda y: cone_log_density(rays, y)[0])(points)

    inlier = jnp.log1p(-outlier_share) + log_density(eye_center, direction, bandwidth)
    camera_forward = log_density(jnp.zeros(3, dtype), jnp.array([1.0, 0.0, 0.0], dtype),
                                 jnp.asarray(outlier_bandwidth, dtype))
    outlier = jnp.log(outlier_share) + camera_forward
    per_point = jnp.logaddexp(inlier, outlier)
    return per_point, jnp.exp(inlier - per_point)


class CalibrationPosterior(NamedTuple):
    """Posterior of one wearer's calibration.

    Attributes:
        sampler: the :class:`~jaxgaze.nuts.SamplerReport` of the NUTS run: ``idata`` (posterior, sample
            stats, observed points; each chain as its two halves, :func:`jaxgaze.nuts.split_chains`, so
            that arviz's own r-hat and ESS are those reported; each variable with its ``units`` attribute,
            :data:`UNITS`), the sampler's ``result`` (mixing only), its ``diagnostics`` and the ``summary``
            table (mean, sd, 90% HDI, bulk and tail ESS, split r-hat) of the main parameters.
        eye_center, direction: posterior means, camera frame (direction renormalised).
        bandwidth: posterior mean of ``h`` (radians).
        samples: dict of posterior draws (``eye_center (S,3)``, ``direction (S,3)``, ``bandwidth (S,)``, …).
        predictive_check: dict with the observed mean whitened distance ``‖d‖/h`` of
            the inliers and its posterior-predictive distribution (``observed``, ``replicated``,
            ``p_value``), a check that the cone spread fits the data.
        result: the overall result: ``RESULTS.successful``; ``implausible`` when the mean eye centre
            is more than :data:`MAX_EYE_OFFSET` from the camera, else the sampler's (``not_mixed`` when
            it failed its checks, :func:`jaxgaze.nuts.mixing_result`). :func:`jaxgaze.succeeded` reads it.
    """

    sampler: SamplerReport
    eye_center: np.ndarray
    direction: np.ndarray
    bandwidth: float
    samples: dict
    predictive_check: dict
    result: RESULTS = RESULTS.successful

    def credible_radii(self, level: float = 0.9) -> tuple[float, float]:
        """Radii of the ``level`` credible regions, centred on the posterior means.

        Direction: the ``level`` quantile of the draws' angles to the mean direction
        (radians). Eye centre: the ``level`` quantile of the draws' distances from the
        mean eye centre *perpendicular to the mean direction* (metres); along the axis
        the eye centre is weakly identified, and that offset hardly moves the ray.
        """
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must lie in (0, 1), got {level!r}")
        angles = _angles_to(self.samples["direction"], self.direction)
        offsets = _perpendicular(self.samples["eye_center"] - self.eye_center, self.direction)
        return float(np.quantile(angles, level)), float(np.quantile(np.linalg.norm(offsets, axis=-1), level))

    def contains(self, eye_center, direction, level: float = 0.9) -> tuple[bool, bool]:
        """Whether a (true) direction and eye centre lie in the ``level`` credible regions.

        The regions of :meth:`credible_radii`. Used for coverage checks on
        simulations with known truth.
        """
        direction_radius, eye_radius = self.credible_radii(level)
        direction = np.asarray(direction, dtype=float)
        angle = float(_angles_to(direction[None], self.direction)[0])
        offset = _perpendicular(np.asarray(eye_center, dtype=float) - self.eye_center, self.direction)
        return angle <= direction_radius, float(np.linalg.norm(offset)) <= eye_radius


    def region_level(self, eye_center) -> float:
        """The smallest credible level whose eye-centre region holds ``eye_center``: the share of draws
        nearer the posterior mean than it, in the Mahalanobis metric of the draws' covariance (all three
        axes, the one along the ray included). A point outside the 90% region has a level above 0.9."""
        draws = np.asarray(self.samples["eye_center"], float)
        centred = draws - draws.mean(0)
        precision = np.linalg.pinv(np.cov(centred.T))
        offset = np.asarray(eye_center, float) - draws.mean(0)
        return float(np.mean(np.einsum("si,ij,sj->s", centred, precision, centred) < offset @ precision @ offset))

    def to_cone(self) -> ConeCalibration:
        """The posterior means as a :class:`ConeCalibration` (α and ξ NaN: eq. 2 is not solved; inliers: the
        points with a mean inlier probability above 0.5; ``result`` the posterior's)."""
        inliers = np.asarray(self.samples["inlier_probability"]).mean(0) > 0.5
        return ConeCalibration(eye_center=np.asarray(self.eye_center, float), direction=np.asarray(self.direction, float),
                               bandwidth=np.float64(self.bandwidth), alpha=np.float64(np.nan), xi=np.float64(np.nan),
                               inliers=inliers, result=self.result)


class CalibrationChoice(NamedTuple):
    """The calibration to use, and how the point estimate compared with the posterior (:func:`choose_calibration`).

    Attributes:
        cone: the :class:`ConeCalibration` to use: the point estimate, or the posterior means.
        method: ``"ransac+cone"`` or ``"posterior mean"``.
        disagrees: the point estimate's eye centre lies outside the posterior's ``level`` region, or
            more than :data:`MAX_EYE_OFFSET` from the camera.
        region_level: :meth:`CalibrationPosterior.region_level` of the point estimate's eye centre.
        distance: metres between the point estimate's eye centre and the posterior mean.
        eye_distance: the point estimate's eye centre's distance from the camera (m).
        message: when it disagrees, one line naming both eye centres, their distance, why, and which is used.
    """

    cone: ConeCalibration
    method: str
    disagrees: bool
    region_level: float
    distance: float
    eye_distance: float
    message: str = ""


def needs_posterior(fit: ConeCalibration) -> bool:
    """Whether a point estimate (RANSAC + eq. 2) needs the posterior to place its eye centre: the apex is more
    than :data:`MAX_EYE_OFFSET` from the camera, where no eye of a head-mounted camera's wearer is (the apex of
    Park et al. 2012, eq. 2 is loose along the ray)."""
    return float(np.linalg.norm(np.asarray(fit.eye_center, float))) > MAX_EYE_OFFSET


def choose_calibration(fit: ConeCalibration, posterior: CalibrationPosterior, level: float = 0.9
                       ) -> CalibrationChoice:
    """The better of a point estimate ``fit`` (Park et al. 2012, Sec. 3.2) and the posterior's means.

    The point estimate *disagrees* with the posterior when its eye centre lies outside the
    posterior's ``level`` region (:meth:`CalibrationPosterior.region_level` ``> level``) or when it
    is more than :data:`MAX_EYE_OFFSET` from the camera (:func:`needs_posterior`). Then the
    posterior means are used, if the posterior succeeded; otherwise the point estimate is kept.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    eye = np.asarray(fit.eye_center, float)
    region, distance, eye_distance = posterior.region_level(eye), float(np.linalg.norm(eye - posterior.eye_center)), \
        float(np.linalg.norm(eye))
    why = ([f"outside the posterior's {100 * level:g}% region (its {100 * region:.0f}% region)"] if region > level
           else []) + ([f"{eye_distance:.2f} m from the camera (more than {MAX_EYE_OFFSET:g} m)"]
                       if needs_posterior(fit) else [])
    use_posterior = bool(why) and succeeded(posterior)
    then = "using the posterior mean" if use_posterior else "the posterior failed, so the point estimate is kept"
    vector = lambda v: "(" + ", ".join(f"{x:.3f}" for x in v) + ") m"  # noqa: E731
    message = (f"the RANSAC eye centre {vector(eye)} is {distance:.2f} m from the posterior mean "
               f"{vector(posterior.eye_center)}, {' and '.join(why)}: the apex is loose along the gaze ray; {then}"
               if why else "")
    return CalibrationChoice(cone=posterior.to_cone() if use_posterior else fit,
                             method="posterior mean" if use_posterior else "ransac+cone", disagrees=bool(why),
                             region_level=region, distance=distance, eye_distance=eye_distance, message=message)


def _angles_to(directions: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.asarray(angle_between(jnp.asarray(directions), jnp.asarray(reference)))


def _perpendicular(offsets: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return offsets - (offsets @ axis)[..., None] * axis


def calibrate_cone_posterior(
    points,
    *,
    key: PRNGKeyArray,
    num_warmup: int = 500,
    num_samples: int = 500,
    num_chains: int = 1,
    init_eye_center=None,
    init_direction=None,
    progress: bool = False,
    throw: bool = False,
    **model_options,
) -> CalibrationPosterior:
    """Sample one wearer's calibration posterior with NUTS, summarised by arviz (Park et al. 2012, Sec. 3.2).

    ``points (M, 3)`` are the points of regard in the wearer's camera frame
    (metres). ``init_*`` (e.g. from the RANSAC point estimate) start the chains
    near the mode; by default they start at the camera centre looking along +x.
    ``model_options`` go to :func:`calibration_model`. For many wearers at once use
    :func:`calibrate_cone_posterior_batch` (one compiled, vectorised run). A run that
    did not mix, or an implausible eye centre, is the posterior's ``result``
    (``throw=False``, the default) or a :class:`~jaxgaze.results.FitError` carrying the posterior as
    ``error.fit`` (``throw=True``).
    """
    y = _points(points)
    init_eye = None if init_eye_center is None else np.asarray(init_eye_center, float)[None]
    init_dir = None if init_direction is None else np.asarray(init_direction, float)[None]
    posterior = _fit([y], key, num_warmup, num_samples, num_chains, init_eye, init_dir, progress, model_options)[0]
    return throw_if_failed(posterior, posterior.result, "calibrate_cone_posterior") if throw else posterior


def calibrate_cone_posterior_batch(
    points,
    *,
    key: PRNGKeyArray,
    num_warmup: int = 500,
    num_samples: int = 500,
    num_chains: int = 1,
    init_eye_centers=None,
    init_directions=None,
    progress: bool = False,
    throw: bool = False,
    **model_options,
) -> list[CalibrationPosterior]:
    """:func:`calibrate_cone_posterior` for ``W`` wearers in one vectorised NUTS run (Park et al. 2012, Sec. 3.2).

    ``points`` is ``(W, M, 3)`` or a list of ``W`` arrays ``(M_w, 3)`` (padded and
    masked internally). ``init_eye_centers``/``init_directions`` are ``(W, 3)`` or
    ``None``. Wearer ``w``'s chains use keys split from ``key``; the result is one
    :class:`CalibrationPosterior` per wearer, in order, each with its own ``result``;
    ``throw=True`` raises on the first that failed, with the whole list as ``error.fit``.
    """
    ys = [_points(y) for y in (points if isinstance(points, (list, tuple)) else np.asarray(points, float))]
    if not ys:
        raise ValueError("points holds no wearers")
    for name, init in (("init_eye_centers", init_eye_centers), ("init_directions", init_directions)):
        if init is not None and np.shape(init) != (len(ys), 3):
            raise ValueError(f"{name} must have shape ({len(ys)}, 3), got {np.shape(init)}")
    posteriors = _fit(ys, key, num_warmup, num_samples, num_chains,
                      None if init_eye_centers is None else np.asarray(init_eye_centers, float),
                      None if init_directions is None else np.asarray(init_directions, float),
                      progress, model_options)
    for w, posterior in enumerate(posteriors if throw else ()):
        throw_if_failed(posterior, posterior.result, f"calibrate_cone_posterior_batch (wearer {w})", fit=posteriors)
    return posteriors


@functools.lru_cache(maxsize=8)
def _model(model_options: tuple):
    """One model object per option set: it keys the compilation in :func:`jaxgaze.nuts.sample_nuts`."""
    return functools.partial(calibration_model, **dict(model_options))


def _fit(ys, key, num_warmup, num_samples, num_chains, init_eye, init_dir, progress, model_options):
    """Fit ``W`` wearers × ``num_chains`` chains in one batch; padded to a common length."""
    import arviz as az

    if num_chains < 1:
        raise ValueError(f"num_chains must be at least 1, got {num_chains}")
    num_wearers = len(ys)
    length = bucket_size(max(len(y) for y in ys), minimum=64, multiple=64)
    dtype = jnp.zeros(()).dtype
    padded = np.zeros((num_wearers, length, 3))
    padded[..., 0] = 1.0  # padding sits on the +x axis, in front of the camera (masked out)
    mask = np.zeros((num_wearers, length), bool)
    for w, y in enumerate(ys):
        padded[w, : len(y)], mask[w, : len(y)] = y, True
    start_eye = np.zeros((num_wearers, 3)) if init_eye is None else init_eye
    start_dir = np.tile([1.0, 0.0, 0.0], (num_wearers, 1)) if init_dir is None else init_dir
    start_dir = start_dir / np.linalg.norm(start_dir, axis=-1, keepdims=True)
    # Starting point in numpyro's unconstrained space (log h, logit ε); chains of a wearer are adjacent.
    init = {
        "eye_center": start_eye,
        "direction_raw": start_dir,  # ‖u‖ = 1, where its prior holds it
        "bandwidth": np.full(num_wearers, np.log(0.05)),
        "outlier_share": np.full(num_wearers, float(jax.scipy.special.logit(0.05))),
    }
    repeat = lambda a: jnp.asarray(np.repeat(a, num_chains, axis=0), dtype)  # noqa: E731
    sample_key, check_key = jax.random.split(key)
    values, stats = sample_nuts(
        _model(tuple(sorted(model_options.items()))), sample_key,
        (repeat(padded), jnp.asarray(np.repeat(mask, num_chains, axis=0))),
        {k: repeat(v) for k, v in init.items()},
        num_warmup=num_warmup, num_samples=num_samples, dense_mass=True, target_accept_prob=0.9,
        progress=progress, description=f"calibration posterior ({num_wearers} wearer(s))",
    )
    values = {k: np.asarray(v).reshape((num_wearers, num_chains) + v.shape[1:]) for k, v in values.items()}
    stats = {k: np.asarray(v).reshape((num_wearers, num_chains) + v.shape[1:]) for k, v in stats.items()}
    check_keys = jax.random.split(check_key, num_wearers)
    posteriors = []
    for w, y in enumerate(ys):
        m = len(y)
        draws = {k: v[w] for k, v in values.items() if k != "direction_raw"}
        draws["inlier_probability"] = draws["inlier_probability"][..., :m]
        with quiet_single_chain(num_chains):
            idata = split_chains(az.from_dict(
                posterior=draws,
                sample_stats={k: v[w] for k, v in stats.items()},
                observed_data={"points": y},
                dims={"eye_center": ["axis"], "direction": ["axis"], "inlier_probability": ["point"],
                      "points": ["point", "axis"]},
                coords={"axis": ["x", "y", "z"], "point": np.arange(m)},
            ))
        set_units(idata, UNITS)
        sampler = sampler_report(idata, _SUMMARY_VARS)
        samples = {k: v.reshape((-1,) + v.shape[2:]) for k, v in draws.items()}
        direction_mean = samples["direction"].mean(0)
        eye_center = samples["eye_center"].mean(0)
        plausible = np.linalg.norm(eye_center) <= MAX_EYE_OFFSET
        result = sampler.result if plausible else RESULTS.implausible
        posteriors.append(CalibrationPosterior(
            sampler=sampler,
            eye_center=eye_center,
            direction=direction_mean / np.linalg.norm(direction_mean),
            bandwidth=float(samples["bandwidth"].mean()),
            samples=samples,
            predictive_check=_predictive_check(check_keys[w], jnp.asarray(y, dtype), samples),
            result=result,
        ))
    return posteriors


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
