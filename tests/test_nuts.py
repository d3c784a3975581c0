"""The shared NUTS runner: a fixed Laplace mass matrix against closed forms and a known Gaussian."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest

from jaxgaze.nuts import laplace_inverse_mass, laplace_parts, sample_nuts

# A badly scaled posterior: 'a' has sd 1e-3, 'b' is 2-D with sd 50 and 0.2 and correlation 0.9.
A_SD = 1e-3
B_COV = np.array([[50.0**2, 0.9 * 50.0 * 0.2], [0.9 * 50.0 * 0.2, 0.2**2]])


def _model(a_mean, b_mean):
    numpyro.sample("b", dist.MultivariateNormal(b_mean, covariance_matrix=jnp.asarray(B_COV)))
    numpyro.sample("a", dist.Normal(a_mean, A_SD))


def _potential(params):
    a, b = params["a"], params["b"]
    return 0.5 * (a / A_SD) ** 2 + 0.5 * b @ jnp.linalg.solve(jnp.asarray(B_COV), b)


def _true_covariance():
    """Flattened in jax.tree_util order: 'a' (sorted first), then 'b'."""
    cov = np.zeros((3, 3))
    cov[0, 0] = A_SD**2
    cov[1:, 1:] = B_COV
    return cov


def test_laplace_inverse_mass_of_a_gaussian_is_its_covariance():
    params = {"b": jnp.zeros(2), "a": jnp.zeros(())}
    mass = laplace_inverse_mass(_potential, params, 1e-6)
    np.testing.assert_allclose(np.asarray(mass), _true_covariance(), rtol=1e-4, atol=1e-9)


def test_laplace_parts_newton_step_lands_on_the_mode_of_a_gaussian(x64):
    """The gradient from the Hessian's own ``2d`` gradients is the exact one (a quadratic potential), so one Newton
    step ``θ − Σ ∇U`` from anywhere lands on the mode (0). In float64: the scales differ by 5·10⁴."""
    params = {"b": jnp.array([0.7, -1.2]), "a": jnp.array(0.4)}
    inverse, gradient = laplace_parts(_potential, params, 1e-6)
    flat = np.array([0.4, 0.7, -1.2])  # 'a', then 'b'
    np.testing.assert_allclose(np.asarray(gradient), np.linalg.solve(_true_covariance(), flat), rtol=1e-8)
    np.testing.assert_allclose(flat - np.asarray(inverse) @ np.asarray(gradient), 0.0, atol=1e-6)


def test_laplace_inverse_mass_floors_curvature_and_refuses_nonfinite():
    # a saddle: curvature +4 along x, −2 along y (its magnitude kept), 0.1 along z (raised to 0.5)
    saddle = lambda p: 2.0 * p["x"] ** 2 - p["y"] ** 2 + 0.05 * p["z"] ** 2  # noqa: E731
    mass = laplace_inverse_mass(saddle, {"x": jnp.zeros(()), "y": jnp.zeros(()), "z": jnp.zeros(())}, 0.5)
    np.testing.assert_allclose(np.asarray(mass), np.diag([0.25, 0.5, 2.0]), rtol=1e-6)
    nonfinite = lambda p: jnp.sum(p["x"] ** 2) + jnp.sqrt(p["x"][0])  # noqa: E731
    mass = laplace_inverse_mass(nonfinite, {"x": jnp.array([0.0, 1.0])}, 0.5)
    np.testing.assert_array_equal(np.asarray(mass), np.eye(2))


def test_fixed_mass_matrix_samples_a_badly_scaled_gaussian():
    """With the exact covariance as its fixed mass, 100 warm-up steps (step size only) suffice."""
    means = (jnp.array([[0.01]]), jnp.array([[3.0, -1.0]]))
    init = {"a": means[0][:, 0], "b": means[1]}
    mass = jnp.asarray(_true_covariance())[None]
    values, stats = sample_nuts(_model, jax.random.key(1), (means[0][:, 0], means[1]), init, num_warmup=100,
                                num_samples=1500, dense_mass=True, inverse_mass_matrix=mass)
    a, b = np.asarray(values["a"][0]), np.asarray(values["b"][0])
    assert abs(a.std() / A_SD - 1) < 0.1
    np.testing.assert_allclose(b.std(axis=0), np.sqrt(np.diag(B_COV)), rtol=0.1)
    assert abs(np.corrcoef(b.T)[0, 1] - 0.9) < 0.03
    assert abs(a.mean() - 0.01) < 4 * A_SD / np.sqrt(1500) * 3  # within a few Monte Carlo errors (ESS ≥ N/9)
    # whitened by its exact covariance, the target is a standard normal: short trajectories
    assert np.mean(stats["n_steps"]) < 8
    assert not np.any(stats["diverging"])


def test_inverse_mass_matrix_shape_is_checked():
    means = (jnp.zeros((1,)), jnp.zeros((1, 2)))
    init = {"a": means[0], "b": means[1]}
    with pytest.raises(ValueError, match=r"inverse_mass_matrix must have shape \(1, 3, 3\)"):
        sample_nuts(_model, jax.random.key(0), means, init, num_warmup=5, num_samples=5, dense_mass=True,
                    inverse_mass_matrix=jnp.eye(3))
    with pytest.raises(ValueError, match=r"inverse_mass_matrix must have shape \(1, 3\)"):
        sample_nuts(_model, jax.random.key(0), means, init, num_warmup=5, num_samples=5,
                    inverse_mass_matrix=jnp.ones((1, 3, 3)))


def _idata(draws, diverging=None, acceptance=None):
    import arviz as az

    chains, n = draws.shape[:2]
    stats = {"diverging": np.zeros((chains, n), bool) if diverging is None else diverging,
             "acceptance_rate": np.full((chains, n), 0.85) if acceptance is None else acceptance}
    return az.from_dict(posterior={"x": draws}, sample_stats=stats)


def test_mixing_checks_pass_independent_draws_and_fail_each_failure():
    from jaxgaze.nuts import mixing_diagnostics, mixing_result, posterior_summary
    from jaxgaze.results import RESULTS

    rng = np.random.default_rng(0)
    good = rng.normal(size=(1, 1000, 2))
    d = mixing_diagnostics(_idata(good), ["x"])
    assert mixing_result(d) == RESULTS.successful
    assert d.max_rhat < 1.01 and d.min_ess_bulk > 500 and d.chains == 1 and d.draws == 1000
    # a single chain whose halves disagree: split r-hat exists for one chain, and it is large
    drifted = good + np.concatenate([np.zeros(500), np.full(500, 3.0)])[None, :, None]
    assert mixing_diagnostics(_idata(drifted), ["x"]).max_rhat > 1.5
    assert mixing_result(mixing_diagnostics(_idata(drifted), ["x"])) == RESULTS.not_mixed
    # a chain that never moved: no ESS, NaN r-hat, acceptance 0 (as a sampler stuck at its start)
    stuck = mixing_diagnostics(_idata(np.ones((1, 1000, 2)), acceptance=np.zeros((1, 1000))), ["x"])
    assert stuck.min_ess_bulk == 0 and np.isnan(stuck.max_rhat) and stuck.acceptance_rate == 0
    assert mixing_result(stuck) == RESULTS.not_mixed
    # too many divergences; too low an acceptance; too few effective draws
    diverging = np.zeros((1, 1000), bool)
    diverging[0, :20] = True
    assert mixing_result(mixing_diagnostics(_idata(good, diverging=diverging), ["x"])) == RESULTS.not_mixed
    assert mixing_result(mixing_diagnostics(_idata(good, acceptance=np.full((1, 1000), 0.3)), ["x"])) \
        == RESULTS.not_mixed
    sticky = np.repeat(rng.normal(size=(1, 50, 2)), 20, axis=1)  # 50 distinct values, each held 20 draws
    assert mixing_result(mixing_diagnostics(_idata(sticky), ["x"])) == RESULTS.not_mixed
    # the summary: mean, sd, 90% HDI, ESS and a split r-hat for one chain
    table = posterior_summary(_idata(good), ["x"])
    assert {"mean", "sd", "hdi_5%", "hdi_95%", "ess_bulk", "ess_tail", "r_hat"} <= set(table.columns)
    assert np.all(np.isfinite(table["r_hat"])) and np.all(table["hdi_5%"] < table["hdi_95%"])
    np.testing.assert_allclose(table["hdi_95%"] - table["hdi_5%"], 2 * 1.645, atol=0.25)
