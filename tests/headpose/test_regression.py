"""Head-pose regression on simulated table-top sessions, and the hyperparameter posterior.

Known truth: the simulator's gaze direction f1 and depth f2 per frame.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.gp import kernels
from jaxgaze.papers.yucel2013 import evaluate_regression, format_cogsci_table, format_table_i
from jaxgaze.gp import fit, predict, sample_hyperparameter_posterior
from jaxgaze.nuts import mixing_result
from jaxgaze.results import RESULTS, FitError, succeeded
from jaxgaze.headpose.regression import (
    RescaledRegression,
    fit_gaze_regression,
    fit_gaze_regression_nn,
    training_image_scale,
)
from jaxgaze.headpose.features import head_pose_features
from tests import helpers as zoo


@pytest.fixture(scope="module")
def sessions():
    # Two people, two sessions each: sessions 0, 1 are person 0; 2, 3 person 1.
    return zoo.tabletop_sessions(0, 2, 2, 60.0)


@pytest.fixture(scope="module")
def scores():
    """GPR and NN over every self- and cross-referencing split of 4 people x 2 one-minute sessions."""
    sessions = zoo.tabletop_sessions(0, 4, 2, 60.0)
    results = evaluate_regression(sessions, key=jax.random.key(1), max_train_frames=400)
    return {(r.split, r.method): r for r in results}


@pytest.mark.parametrize("split", ["self", "cross"])
def test_gpr_q2_beats_raw_head_pose(scores, split):
    gpr = scores[split, "gpr"]
    assert gpr.q2 > gpr.q2_head + 0.1
    assert gpr.q2_pooled >= gpr.q2 - 0.02  # pooling 4 frames does not hurt
    assert gpr.mean_angular_deviation < gpr.head_mean_angular_deviation


def test_gpr_90_percent_intervals_cover_85_to_95_percent_of_held_out_sessions(scores):
    # Self-referencing: every held-out session of a person the GP was trained on.
    assert 0.85 <= scores["self", "gpr"].coverage_90 <= 0.95
    # Cross-referencing: a person the GP never saw, trained on the three others.
    assert 0.85 <= scores["cross", "gpr"].coverage_90 <= 0.95


def test_nn_baseline_also_beats_head_pose_but_has_no_intervals(scores):
    for split in ("self", "cross"):
        nn = scores[split, "nn"]
        assert nn.q2 > nn.q2_head
        assert math.isnan(nn.coverage_90)


def test_tables_print_every_method_and_group(scores):
    table = format_table_i(list(scores.values()))
    assert table.count("| GPR |") == 2 and table.count("| NN |") == 2
    cogsci = format_cogsci_table(scores["self", "gpr"])
    for label in ("Q1 (rad)", "Q2(h)", "Q2(hg)", "Q2(hgd)", "near", "peripheral"):
        assert label in cogsci
    for row in scores["self", "gpr"].cogsci.values():
        assert 0 <= row[0] < math.pi and all(0 <= v <= 1 for v in row[1:])


def test_regression_predicts_training_truth_closely(sessions):
    s = sessions[0]
    X = head_pose_features(s.head_pose)[::3]
    model = fit_gaze_regression(X, s.gaze_direction_image[::3], s.target_depth_image[::3], key=jax.random.key(0))
    assert succeeded(model)
    pred = model.predict(X)
    # In-sample errors are far below the spread of the targets.
    assert np.sqrt(np.mean((np.asarray(pred.direction) - np.asarray(s.gaze_direction_image[::3])) ** 2)) < 0.5 * np.std(
        np.asarray(s.gaze_direction_image))
    assert np.all(np.asarray(pred.direction_variance) > 0) and np.all(np.asarray(pred.depth_variance) > 0)


def test_a_failed_gp_is_the_regressions_result_and_throw_carries_the_fit(sessions, monkeypatch):
    """The f2 GP stops at max_steps: the regression reports it (one result, read by ``succeeded``),
    and ``throw=True`` raises a FitError holding the regression, f1 fitted as without ``throw``."""
    import jaxgaze.headpose.regression as regression

    s = sessions[0]
    X, f1, f2 = head_pose_features(s.head_pose)[:60:3], s.gaze_direction_image[:60:3], s.target_depth_image[:60:3]
    calls = []

    def depth_fails(*args, **kwargs):
        gp = fit(*args, **kwargs)
        calls.append(gp)
        return gp._replace(result=RESULTS.max_steps_reached) if len(calls) % 2 == 0 else gp

    monkeypatch.setattr(regression, "fit", depth_fails)
    model = fit_gaze_regression(X, f1, f2, key=jax.random.key(0))  # throw=False by default
    assert model.result == RESULTS.max_steps_reached and succeeded(model) is False
    assert model.direction_gp.result == RESULTS.successful
    with pytest.raises(FitError, match="f2 .depth. GP") as error:
        fit_gaze_regression(X, f1, f2, key=jax.random.key(0), throw=True)
    assert isinstance(error.value.fit, regression.GazeRegression)
    assert error.value.result == RESULTS.max_steps_reached
    np.testing.assert_array_equal(error.value.fit.predict(X).direction, model.predict(X).direction)


@pytest.mark.parametrize(
    "bad, message",
    [
        (lambda X, a, b: (X[:, 0], a, b), "2-D"),
        (lambda X, a, b: (X, a[:-1], b), "direction must have shape"),
        (lambda X, a, b: (X, a, b.at[3].set(jnp.nan)), "depth contains NaN or inf .first at row 3"),
        (lambda X, a, b: (X.at[5, 1].set(jnp.inf), a, b), "features contains NaN"),
    ],
)
def test_regression_rejects_bad_training_data(sessions, bad, message):
    s = sessions[0]
    args = bad(head_pose_features(s.head_pose)[:50], s.gaze_direction_image[:50], s.target_depth_image[:50])
    with pytest.raises(ValueError, match=message):
        fit_gaze_regression(*args, key=jax.random.key(0))
    with pytest.raises(ValueError, match=message):
        fit_gaze_regression_nn(*args, key=jax.random.key(0))


def test_regression_predict_rejects_wrong_feature_count(sessions):
    s = sessions[0]
    X = head_pose_features(s.head_pose)[:60]
    model = fit_gaze_regression(X, s.gaze_direction_image[:60], s.target_depth_image[:60], key=jax.random.key(0),
                                image_size=(320, 240))
    with pytest.raises(ValueError, match=r"shape \(T, 3\)"):
        model.predict(np.zeros((4, 6)))
    # The model keeps its training images' size; on images twice as tall f2 (a row) doubles, its
    # variance quadruples, and f1 (an angle) stays.
    assert model.image_size == (320, 240)
    assert training_image_scale(model, (640, 480)) == 2.0 and training_image_scale(model, (320, 120)) == 0.5
    assert training_image_scale(model._replace(image_size=None), (640, 480)) == 1.0  # unknown: as it is
    twice = RescaledRegression(model, 2.0)
    assert twice.image_size == (640, 480) and RescaledRegression(model._replace(image_size=None)).image_size is None
    a, b = RescaledRegression(model, 1.0).predict(X[:7]), twice.predict(X[:7])  # one compilation (float64)
    np.testing.assert_allclose(b.depth, 2 * np.asarray(a.depth), rtol=1e-5)
    np.testing.assert_allclose(b.depth_variance, 4 * np.asarray(a.depth_variance), rtol=1e-4)
    np.testing.assert_allclose(b.direction, np.asarray(a.direction), rtol=1e-5)


@pytest.mark.parametrize("size", [(320,), (320.0, 240), (0, 240), (True, 240), "320x240", (320, -1)])
def test_regression_rejects_a_bad_image_size(sessions, size):
    s = sessions[0]
    args = (head_pose_features(s.head_pose)[:20], s.gaze_direction_image[:20], s.target_depth_image[:20])
    for fit_model in (fit_gaze_regression, fit_gaze_regression_nn):
        with pytest.raises(ValueError, match="image_size must be \\(width, height\\)"):
            fit_model(*args, key=jax.random.key(0), image_size=size)


# ---------------------------------------------------------------------------
# Hyperparameter posterior


@pytest.fixture(scope="module")
def posterior_case():
    """Data drawn from a known GP (RBF, lengthscale 0.8, noise variance 0.04), n = 80."""
    with jax.enable_x64(True):
        truth = kernels.RBF(variance=1.0, lengthscale=0.8) + kernels.White(variance=0.04)
        X = jnp.linspace(-3, 3, 80)[:, None]
        K = truth(X) + 1e-9 * jnp.eye(80)
        y = jnp.linalg.cholesky(K) @ jax.random.normal(jax.random.key(2), (80,), jnp.float64)
        prior = kernels.RBF(variance=1.0, lengthscale=1.0) + kernels.White(variance=0.1)
        ml = fit(prior, X, y, key=jax.random.key(3))
        post = sample_hyperparameter_posterior(prior, X, y, key=jax.random.key(4), start=ml, num_warmup=300,
                                               num_samples=400)
        X_new = jnp.linspace(-3.5, 3.5, 40)[:, None]
        return truth, X, y, ml, post, X_new, post.predict(X_new), ml.predict(X_new)


def test_posterior_covers_true_hyperparameters_and_reports_inference_data(posterior_case):
    import arviz as az

    _, _, _, _, post, _, _, _ = posterior_case
    assert set(post.samples) == {"0.RBF.variance", "0.RBF.lengthscale", "1.White.variance"}
    for name, true in (("0.RBF.lengthscale", 0.8), ("1.White.variance", 0.04)):
        lo, hi = np.quantile(post.samples[name], [0.025, 0.975])
        assert lo < true < hi, (name, lo, hi)
    summary = az.summary(post.sampler.idata)
    assert list(summary.index) == list(post.samples)
    assert post.sampler.diagnostics.divergences <= 5
    assert summary["ess_bulk"].min() > 30
    # the shared mixing checks: the result follows them, and a 400-draw run of 3 hyperparameters passes
    d = post.sampler.diagnostics
    assert d.divergences == int(np.sum(post.sampler.idata.sample_stats["diverging"].values)) and d.draws == 400 and d.chains == 1
    assert post.result == mixing_result(d) and succeeded(post)
    assert np.isfinite(d.max_rhat) and d.min_ess_tail >= 100
    table = post.sampler.summary  # mean, sd, 90% HDI, ESS and the split r-hat that a single chain has
    assert {"mean", "sd", "hdi_5%", "hdi_95%", "ess_bulk", "ess_tail", "r_hat"} <= set(table.columns)
    assert list(table.index) == list(post.samples) and np.all(table["r_hat"] < 1.05)
    assert np.all(table["hdi_5%"] < table["mean"]) and np.all(table["mean"] < table["hdi_95%"])


def test_a_hyperparameter_sampler_that_never_moved_is_a_failure(posterior_case, monkeypatch):
    """Every draw equal to the first (acceptance 0): ``not_mixed``, and ``throw=True`` raises."""
    import jaxgaze.gp.posterior as gp_posterior

    real = gp_posterior.sample_nuts

    def stuck(*args, num_samples, **options):
        values, stats = real(*args, num_samples=num_samples, **options)
        values = {k: np.repeat(np.asarray(v)[:, :1], num_samples, axis=1) for k, v in values.items()}
        return values, {**stats, "acceptance_rate": np.zeros((1, num_samples))}

    monkeypatch.setattr(gp_posterior, "sample_nuts", stuck)
    _, X, y, ml, _, _, _, _ = posterior_case
    prior = kernels.RBF(variance=1.0, lengthscale=1.0) + kernels.White(variance=0.1)
    with jax.enable_x64(True):
        post = sample_hyperparameter_posterior(prior, X, y, key=jax.random.key(4), start=ml, num_warmup=300,
                                               num_samples=400)
        assert post.result == RESULTS.not_mixed and not succeeded(post)
        assert post.sampler.diagnostics.min_ess_bulk == 0 and np.isnan(post.sampler.diagnostics.max_rhat)
        with pytest.raises(FitError, match="did not mix") as error:
            sample_hyperparameter_posterior(prior, X, y, key=jax.random.key(4), start=ml, num_warmup=300,
                                            num_samples=400, throw=True)
        # the FitError carries the posterior (new in issue 36): the draws are not thrown away
        assert error.value.fit.result == RESULTS.not_mixed and error.value.fit.sampler.diagnostics.min_ess_bulk == 0


def test_posterior_prediction_is_the_mixture_of_per_draw_predictions(posterior_case, x64):
    _, X, y, ml, post, X_new, (mean, var), (ml_mean, _) = posterior_case
    assert np.all(np.isfinite(np.asarray(mean))) and np.all(np.asarray(var) > 0)
    np.testing.assert_allclose(np.asarray(mean), np.asarray(ml_mean), atol=0.15)
    # Two hand-made draws: the mixture mean is their average, the variance adds the spread of the means.
    draws = [kernels.RBF(variance=1.0, lengthscale=0.5) + kernels.White(variance=0.05),
             kernels.RBF(variance=2.0, lengthscale=1.5) + kernels.White(variance=0.02)]
    stacked = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]) if eqx.is_array(a) else a, *draws)
    two = post._replace(kernels=stacked)
    m2, v2 = two.predict(X_new)
    parts = [predict(k, X, y, X_new) for k in draws]
    means = np.stack([np.asarray(p[0]) for p in parts])
    variances = np.stack([np.asarray(p[1]) for p in parts])
    np.testing.assert_allclose(np.asarray(m2), means.mean(0), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(v2), variances.mean(0) + means.var(0), rtol=1e-9, atol=1e-12)
    assert np.all(np.asarray(v2) >= variances.min(0))


def test_posterior_rejects_bad_arguments(posterior_case):
    _, X, y, _, _, _, _, _ = posterior_case
    k = kernels.RBF(variance=1.0, lengthscale=1.0) + kernels.White(variance=0.1)
    with pytest.raises(ValueError, match="prior_scale"):
        sample_hyperparameter_posterior(k, X, y, key=jax.random.key(0), prior_scale=0.0)
    with pytest.raises(ValueError, match="NaN|nan|finite"):
        sample_hyperparameter_posterior(k, X, y.at[0].set(jnp.nan), key=jax.random.key(0))
    with pytest.raises(ValueError, match="same kernel structure"):
        sample_hyperparameter_posterior(k, X, y, key=jax.random.key(0), start=kernels.RBF(variance=1.0, lengthscale=1.0))
