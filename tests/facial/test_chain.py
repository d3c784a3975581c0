"""GMM point localisation, the facial-feature cascade and its extremum-seeking
threshold tuning (ROVIS, seed 003 Sec. 3–4, eq. 2; METHODS.md §4)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.facial.chain import run_chain, sweep_threshold, tune_threshold
from jaxgaze.facial.gmm import localize_point, pixel_coordinates
from jaxgaze.facial.metrics import normalized_deviation
from jaxgaze.facial.spatial import best_configuration, fit_spatial_model
from tests import helpers as zoo

SHAPE = (24, 30)  # one map shape for all GMM tests: one compilation
_localize = jax.jit(localize_point)
H = 3  # hypotheses per feature (keeps the exact search small: 189 configurations)


def _blobs(shape, centres, amps, sd=2.0):
    h, w = shape
    yy, xx = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    return sum(a * np.exp(-0.5 * ((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / sd**2) for c, a in zip(centres, amps))


@pytest.fixture(scope="module")
def model():
    train = zoo.faces(1, 1000)
    return fit_spatial_model(train.features_image, train.visible)


@pytest.fixture(scope="module")
def pool():
    return zoo.faces(2, 600, num_hypotheses=H)


# ---------------------------------------------------------------- GMM


def test_gmm_single_blob_recovers_centre():
    L = _blobs(SHAPE, [(10.3, 7.6)], [1.0])
    est = _localize(L, jnp.array([100.0, 50.0]))
    assert np.linalg.norm(np.asarray(est.point) - [110.3, 57.6]) < 0.5
    assert np.all(np.linalg.eigvalsh(np.asarray(est.covariance)) > 0)


def test_gmm_two_blobs_heaviest_is_strongest():
    L = _blobs(SHAPE, [(8.2, 12.4), (21.7, 9.1)], [1.0, 0.6])
    est = _localize(L, jnp.zeros(2))
    assert np.linalg.norm(np.asarray(est.point) - [8.2, 12.4]) < 0.5
    means = np.asarray(est.fit.means)
    assert np.min(np.linalg.norm(means - [21.7, 9.1], axis=1)) < 0.5
    assert 0.5 < float(est.weight) < 0.8  # 1 / (1 + 0.6) of the mass
    assert np.all(np.diff(np.asarray(est.fit.log_likelihood)) > -1e-4)  # EM never decreases it


def test_gmm_matches_sklearn_on_sampled_points():
    from sklearn.mixture import GaussianMixture

    L = _blobs(SHAPE, [(8.2, 12.4), (21.7, 9.1)], [1.0, 0.6])
    xy = np.asarray(pixel_coordinates(L.shape))
    rng = np.random.default_rng(0)
    p = L.ravel() / L.sum()
    idx = rng.choice(len(p), 6000, p=p)
    pts = xy[idx] + rng.uniform(-0.5, 0.5, (6000, 2))  # uniform within the pixel
    sk = GaussianMixture(2, random_state=0).fit(pts)
    ours = _localize(L, jnp.zeros(2)).fit  # = fit_gmm(xy, L.ravel(), 2)
    a = np.asarray(ours.means)[np.argsort(np.asarray(ours.means)[:, 0])]
    b = sk.means_[np.argsort(sk.means_[:, 0])]
    np.testing.assert_allclose(a, b, atol=0.3)
    np.testing.assert_allclose(np.sort(np.asarray(ours.weights)), np.sort(sk.weights_), atol=0.03)


def test_gmm_empty_map_is_flagged():
    est = _localize(np.zeros(SHAPE), jnp.zeros(2))
    assert np.all(np.isnan(np.asarray(est.point))) and float(est.weight) == 0.0


# ---------------------------------------------------------------- chain


def test_search_agrees_with_spatial(model, pool):
    r = run_chain(pool.hypotheses, model, 0.3, features_image=pool.features_image, visible=pool.visible)
    ref = best_configuration(pool.hypotheses, model, 0.3)
    np.testing.assert_array_equal(np.asarray(r.chosen), np.asarray(ref.chosen))
    np.testing.assert_allclose(np.asarray(r.posterior), np.asarray(ref.posterior), atol=1e-5)
    y = np.asarray(r.y_f)
    assert np.all((y >= 0) & (y <= 1)) and np.all(y[~np.asarray(r.found)] == 0)


def test_no_face_and_missing_features_are_flagged(model, pool):
    h = pool.hypotheses
    # no face: nothing above threshold
    r = run_chain(h, model, 0.999, features_image=pool.features_image, visible=pool.visible)
    assert not np.any(r.found) and np.all(np.asarray(r.num_kept) == 0)
    assert np.all(np.asarray(r.y_f) == 0) and np.all(np.isnan(np.asarray(r.points)))
    # two features missing (no usable hypothesis) → no configuration
    conf = np.array(h.confidences)
    conf[:, 2:] = 0.0
    r = run_chain((h.positions, conf), model, 0.1, features_image=pool.features_image)
    assert not np.any(r.found) and np.all(np.asarray(r.y_f) == 0) and np.all(np.isnan(np.asarray(r.points)))
    # one feature missing → a 3-feature configuration, that feature's point NaN, y_f finite
    conf = np.array(h.confidences)
    conf[:, 3] = 0.0
    r = run_chain((h.positions, conf), model, 0.1, features_image=pool.features_image)
    f = np.asarray(r.found)
    assert f.mean() > 0.9
    assert np.all(np.isnan(np.asarray(r.points)[f, 3])) and np.all(np.isfinite(np.asarray(r.points)[f, :3]))
    assert np.all(np.isfinite(np.asarray(r.y_f))) and np.all(np.asarray(r.y_f)[f] > 0)
    with pytest.raises(ValueError):
        run_chain(h, model, float("nan"), features_image=pool.features_image)


def test_esc_converges_to_sweep_best_and_beats_baseline(model, pool):
    grid = np.round(np.arange(0.0, 0.901, 0.05), 3)
    sweep = sweep_threshold(pool, model, grid)
    best = grid[np.argmax(sweep)]
    traj = tune_threshold(pool, model, key=jax.random.key(3), theta0=0.2, batch_size=256, num_steps=150,
                          amplitude=0.08, gain=2.0)
    final = float(traj.final)
    late = float(np.mean(np.asarray(traj.theta_hat)[-60:]))
    print(f"\nsweep best T_h = {best:.2f} (mean y_f {sweep.max():.3f}); ESC final T_h = {final:.3f}, "
          f"mean of last 60 = {late:.3f}, start 0.20")
    assert abs(final - best) <= 0.1 and abs(late - best) <= 0.1
    # the tuned threshold is nearly as good as the best fixed one
    assert sweep_threshold(pool, model, [final])[0] >= 0.9 * sweep.max()

    # spatial model vs independent detectors at the tuned threshold, same GMM localisation
    kw = dict(features_image=pool.features_image, visible=pool.visible)
    sp = run_chain(pool.hypotheses, model, final, **kw)
    ind = run_chain(pool.hypotheses, model, final, method="independent", **kw)
    both = np.asarray(sp.found) & np.any(np.isfinite(np.asarray(ind.points)[..., 0]), -1)
    d_sp = normalized_deviation(pool.features_image[both], np.asarray(sp.points)[both])[0]
    d_ind = normalized_deviation(pool.features_image[both], np.asarray(ind.points)[both])[0]
    print(f"mean normalised deviation at T_h={final:.3f} over {both.sum()} faces: "
          f"spatial {d_sp.mean():.4f}, independent {d_ind.mean():.4f}")
    assert both.sum() > 300 and d_sp.mean() < 0.8 * d_ind.mean()
