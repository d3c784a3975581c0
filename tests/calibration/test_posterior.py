"""Bayesian calibration (numpyro NUTS) on simulated wearers with known truth."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgaze as jg
import numpyro.distributions as dist

from jaxgaze.calibration.posterior import (DIRECTION_RADIUS_SCALE, MAX_EYE_OFFSET, calibrate_cone_posterior,
                                            calibration_model)
from jaxgaze.nuts import sample_nuts
from jaxgaze.results import RESULTS, FitError, succeeded
from jaxgaze.cone import sample_points_of_regard

TRUE_EYE = np.array([-0.08, 0.01, -0.10])
TRUE_DIRECTION = np.asarray(jg.geometry.unit(jnp.array([1.0, 0.12, -0.05])))
TRUE_H = 0.03


def wearer_points(key, n=120, outlier_fraction=0.0, eye=TRUE_EYE):
    """Points of regard in the camera frame drawn from the true cone, plus outliers."""
    k_depth, k_cone, k_out = jax.random.split(key, 3)
    rays = jg.GazeRays(np.tile(eye, (n, 1)), np.tile(TRUE_DIRECTION, (n, 1)), TRUE_H)
    depth = jax.random.uniform(k_depth, (n,), minval=1.0, maxval=4.0)
    y = np.array(sample_points_of_regard(k_cone, rays, depth))
    m = int(outlier_fraction * n)
    y[:m] = eye + np.asarray(jax.random.uniform(k_out, (m, 3), minval=-2.0, maxval=2.0)) + [2.5, 0, 0]
    return y


def errors(post):
    direction_deg = np.degrees(np.arccos(np.clip(post.direction @ TRUE_DIRECTION, -1, 1)))
    offset = post.eye_center - TRUE_EYE
    perpendicular = offset - (offset @ TRUE_DIRECTION) * TRUE_DIRECTION
    return direction_deg, np.linalg.norm(perpendicular)


@pytest.fixture(scope="module")
def posterior():
    # 800 draws: at 300 (and 400) two of five keys end below the tail ESS of 100 that counts as mixed
    # (tail ESS 50–73), so the success asserted below hung on the key; at 800 the lowest of keys 1–3 is 121.
    return calibrate_cone_posterior(wearer_points(jax.random.key(0)), key=jax.random.key(1),
                                    num_warmup=300, num_samples=800)


def test_posterior_recovers_the_true_ray(posterior):
    direction_deg, perpendicular = errors(posterior)
    assert direction_deg < 2.0
    assert perpendicular < 0.04
    assert abs(posterior.bandwidth - TRUE_H) < 0.3 * TRUE_H


def test_credible_intervals_contain_truth(posterior):
    s = posterior.samples
    lo, hi = np.percentile(s["direction"], [0.5, 99.5], axis=0)
    assert np.all((lo <= TRUE_DIRECTION) & (TRUE_DIRECTION <= hi))
    lo, hi = np.percentile(s["bandwidth"], [0.5, 99.5])
    assert lo <= TRUE_H <= hi


def test_diagnostics_and_predictive_check(posterior):
    summary = posterior.sampler.summary
    assert {"mean", "sd", "hdi_5%", "hdi_95%", "ess_bulk", "ess_tail", "r_hat"} <= set(summary.columns)
    assert summary["ess_bulk"].min() > 50
    assert np.all(summary["r_hat"] < 1.05)  # split r-hat: defined for the one chain
    assert succeeded(posterior) and posterior.result == RESULTS.successful
    assert posterior.sampler.diagnostics.chains == 1 and posterior.sampler.diagnostics.max_rhat < 1.05
    assert "posterior" in posterior.sampler.idata.groups()
    assert 0.05 < posterior.predictive_check["p_value"] < 0.95


def test_the_direction_prior_is_the_projected_normal_with_its_latent_length_held_near_one():
    """With no points, the direction's draws follow ProjectedNormal(3 e_x), the documented prior, and the
    latent vector ``u`` behind it (direction ``u / ‖u‖``) keeps a length of 1 ± 0.1. Drawn as
    ``u ~ N(3 e_x, I)`` its length ranged over 1–5, the scales across the ray with it, and a chain of the
    CLI's calibration session that strayed to 0.64 at the end of warm-up rejected every proposal."""
    points = jnp.zeros((1, 64, 3)).at[..., 0].set(1.0)
    init = {"eye_center": jnp.zeros((1, 3)), "direction_raw": jnp.array([[1.0, 0.0, 0.0]]),
            "bandwidth": jnp.full(1, jnp.log(0.05)), "outlier_share": jnp.full(1, -3.0)}
    values, stats = sample_nuts(calibration_model, jax.random.key(0), (points, jnp.zeros((1, 64), bool)), init,
                                num_warmup=500, num_samples=2000, dense_mass=True, target_accept_prob=0.9)
    assert not np.any(stats["diverging"]) and float(stats["acceptance_rate"].mean()) > 0.8
    direction = np.asarray(values["direction"][0])
    reference = np.asarray(dist.ProjectedNormal(jnp.array([3.0, 0.0, 0.0])).sample(jax.random.key(1), (100_000,)))
    assert abs(direction[:, 0].mean() - reference[:, 0].mean()) < 0.02  # 0.89
    np.testing.assert_allclose(np.quantile(direction[:, 0], [0.05, 0.25, 0.5]),
                               np.quantile(reference[:, 0], [0.05, 0.25, 0.5]), atol=0.04)
    radius = np.linalg.norm(np.asarray(values["direction_raw"][0]), axis=-1)
    assert abs(radius.mean() - 1.0) < 0.02 and abs(radius.std() - DIRECTION_RADIUS_SCALE) < 0.02
    assert radius.min() > 0.5


FAR_EYE = np.array([-1.0, 0.02, -0.05])  # a metre behind the camera: no head-mounted camera sits there


def test_a_sampler_that_never_moved_is_a_failure():
    """Started at the camera centre, a metre from the cone's apex, NUTS never accepts a step."""
    y = wearer_points(jax.random.key(0), eye=FAR_EYE)
    post = calibrate_cone_posterior(y, key=jax.random.key(1), num_warmup=300, num_samples=300)
    assert post.result == RESULTS.not_mixed and not succeeded(post)
    d = post.sampler.diagnostics
    assert d.acceptance_rate < 0.5 and d.min_ess_bulk == 0 and np.isnan(d.max_rhat)
    assert np.all(post.sampler.summary["ess_bulk"] == 0)  # arviz alone gives a constant chain the full ESS
    with pytest.raises(FitError, match="did not mix"):
        calibrate_cone_posterior(y, key=jax.random.key(1), num_warmup=300, num_samples=300, throw=True)


def test_an_eye_centre_far_from_the_camera_is_implausible():
    y = wearer_points(jax.random.key(0), eye=FAR_EYE)
    post = calibrate_cone_posterior(y, key=jax.random.key(1), num_warmup=300, num_samples=300,
                                    init_eye_center=FAR_EYE, init_direction=TRUE_DIRECTION)
    assert np.linalg.norm(post.eye_center) > MAX_EYE_OFFSET
    assert post.result == RESULTS.implausible


def test_outliers_are_absorbed():
    post = calibrate_cone_posterior(wearer_points(jax.random.key(2), outlier_fraction=0.2),
                                    key=jax.random.key(3), num_warmup=300, num_samples=300)
    direction_deg, perpendicular = errors(post)
    assert direction_deg < 2.0 and perpendicular < 0.06
    share = post.samples["outlier_share"].mean()
    assert 0.1 < share < 0.3


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((2, 3)), "at least 3"),
        (np.zeros((5, 2)), "shape"),
        (np.array([[1.0, 0, 0], [2, 0, np.nan], [3, 0, 0]]), "point of regard 1"),
    ],
)
def test_bad_points(points, message):
    with pytest.raises(ValueError, match=message):
        calibrate_cone_posterior(points, key=jax.random.key(0))


def test_calibration_spread_propagates_to_concurrence_locations():
    """Direction draws of spread σ move the concurrence like the Laplace covariance with h = σ."""
    from jaxgaze.concurrence import propagate_to_concurrences
    from jaxgaze.geometry import orthonormal_basis

    target = np.array([0.0, 0.0, 1.2])
    eyes = np.array([[2.0, 0.5, 1.7], [-1.5, 2.0, 1.6], [-0.5, -3.0, 1.75], [3.0, -2.0, 1.65]])
    eye_in_camera = np.array([-0.03, 0.0, -0.10])
    rotations, centres = [], []
    for p in eyes:
        v = (target - p) / np.linalg.norm(target - p)
        u1, u2 = (np.asarray(u) for u in orthonormal_basis(jnp.asarray(v)))
        R = np.stack([v, u1, u2], axis=1)  # camera +x along the gaze: direction (1, 0, 0) in camera frame
        rotations.append(R)
        centres.append(p - R @ eye_in_camera)
    draws, sigma = 400, 0.02
    exact = jg.GazeRays(np.tile(eye_in_camera, (4, 1)), np.tile([1.0, 0, 0], (4, 1)), sigma)
    keys = jax.random.split(jax.random.key(9), draws)
    directions = jax.vmap(jg.sample_gaze_directions, in_axes=(0, None))(keys, exact)
    eye = np.broadcast_to(eye_in_camera, (draws, 4, 3))
    ensemble = propagate_to_concurrences(eye, directions, np.full((draws, 4), sigma), np.stack(rotations),
                                         np.stack(centres))
    assert ensemble.found.mean() > 0.95
    np.testing.assert_allclose(ensemble.mean[0], target, atol=0.02)
    # The cone model's Laplace covariance at h = σ, at the target that every exact ray passes
    # through: (Σ_i (I − v_i v_iᵀ)/(σ t_i)²)⁻¹. (find_concurrences would scale it by the noise
    # that exact rays show, none.)
    depth = np.linalg.norm(target - eyes, axis=1)
    v = (target - eyes) / depth[:, None]
    laplace = np.linalg.inv(np.sum((np.eye(3) - v[:, :, None] * v[:, None, :]) / (sigma * depth[:, None, None]) ** 2, 0))
    ratio = np.trace(ensemble.covariance[0]) / np.trace(laplace)
    assert 0.7 < ratio < 1.4, ratio
