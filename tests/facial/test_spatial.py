"""Facial-feature simulator, spatial model and metrics (ROVIS, seed 003; METHODS.md §4)."""

import itertools

import jax
import numpy as np
import pytest

from jaxgaze.facial.metrics import cumulative_histogram, normalized_deviation, tau
from jaxgaze.simulate.faces import Hypotheses, simulate_faces
from jaxgaze.facial.spatial import (
    best_configuration,
    enumerate_combinations,
    fit_spatial_model,
    independent_detectors,
    selected_positions,
)
from tests import helpers as zoo


@pytest.fixture(scope="module")
def model():
    train = zoo.faces(1, 2000)
    return fit_spatial_model(train.features_image, train.visible)


# ---------------------------------------------------------------- simulator


def test_simulator_truth():
    s = zoo.faces(0, 400)
    yaw = np.rad2deg(s.yaw)
    assert np.all(np.abs(yaw[~s.profile]) < 20) and np.all((np.abs(yaw[s.profile]) >= 50) & (np.abs(yaw[s.profile]) <= 80))
    # profile faces hide the far eye: the left eye when turned to the person's left (yaw > 0)
    assert not s.visible[s.profile & (s.yaw > 0), 1].any() and not s.visible[s.profile & (s.yaw < 0), 0].any()
    # frontal faces: the person's right eye is on the image's left, the mouth below the eyes
    fr = ~s.profile
    assert np.all(s.features_image[fr, 0, 0] < s.features_image[fr, 1, 0])
    assert np.all(s.features_image[fr, 3, 1] > s.features_image[fr, :2, 1].mean(-1))
    assert np.all((s.points_image >= 0) & (s.points_image <= [320, 240]))
    h = s.hypotheses
    assert h.positions.shape == (400, 4, 4, 2) and h.confidences.shape == (400, 4, 4)
    # exactly one true hypothesis per visible feature, none for hidden ones, near the truth
    np.testing.assert_array_equal(h.is_true.sum(-1), s.visible.astype(int))
    tp = np.where(h.is_true[..., None], h.positions, 0).sum(2)
    err = np.linalg.norm(tp - s.features_image, axis=-1)[s.visible] / np.repeat(s.face_size_px[:, None], 4, 1)[s.visible]
    assert err.mean() < 0.06
    # a distractor sometimes outscores the true ROI
    best_is_true = np.take_along_axis(h.is_true, h.confidences.argmax(-1)[..., None], -1)[..., 0]
    frac = best_is_true[s.visible].mean()
    assert 0.4 < frac < 0.9
    # same key, same faces
    np.testing.assert_array_equal(simulate_faces(jax.random.key(0), 400).hypotheses.positions, h.positions)


def test_simulator_bad_args():
    with pytest.raises(ValueError):
        simulate_faces(0, 3)
    with pytest.raises(ValueError):
        simulate_faces(jax.random.key(0), 0)
    with pytest.raises(ValueError):
        simulate_faces(jax.random.key(0), 3, view="side")
    with pytest.raises(ValueError, match="point_sd"):
        simulate_faces(jax.random.key(0), 3, point_sd=-0.001)
    with pytest.raises(ValueError, match="shape_sd"):
        simulate_faces(jax.random.key(0), 3, shape_sd=float("nan"))


def test_simulator_generic_shape_is_the_generic_face():
    """shape_sd = point_sd = 0: every face is the generic face, so PnP recovers the pose exactly."""
    from jaxgaze.facial import orientation_pnp
    from jaxgaze.simulate.faces import FOCAL_PX, IMAGE_HEIGHT, IMAGE_WIDTH

    faces = simulate_faces(jax.random.key(4), 5, view="frontal", shape_sd=0.0, point_sd=0.0)
    for i in range(5):
        o = orientation_pnp(faces.points_image[i], focal_px=FOCAL_PX, principal_point=(IMAGE_WIDTH / 2, IMAGE_HEIGHT / 2))
        np.testing.assert_allclose([o.yaw, o.pitch, o.roll], [faces.yaw[i], faces.pitch[i], faces.roll[i]], atol=1e-4)
    varied = simulate_faces(jax.random.key(4), 5, view="frontal")
    assert np.max(np.abs(varied.points_image - faces.points_image)) > 0.1  # the default varies the shape


# ---------------------------------------------------------------- must-show


def _evaluate(faces, chosen):
    chosen = np.asarray(chosen)
    est = selected_positions(faces.hypotheses, chosen)
    present = faces.visible & (chosen >= 0)
    mean, mx = normalized_deviation(faces.features_image, est, present)
    missed = (faces.visible & (chosen < 0)).sum() / faces.visible.sum()
    return np.nanmean(mean), np.nanmean(mx), missed


@pytest.mark.parametrize("view", ["frontal", "profile"])
def test_spatial_model_beats_independent_detectors(model, view):
    faces = zoo.faces(2, 300, view=view)
    cfg = best_configuration(faces.hypotheses, model, threshold=0.0)
    base = _evaluate(faces, independent_detectors(faces.hypotheses))
    spat = _evaluate(faces, cfg.chosen)
    print(f"\n{view}: mean/max normalised deviation, missed visible features")
    print(f"  independent detectors {base[0]:.3f} / {base[1]:.3f}  missed {base[2]:.3f}")
    print(f"  spatial model         {spat[0]:.3f} / {spat[1]:.3f}  missed {spat[2]:.3f}")
    assert spat[0] < 0.5 * base[0] and spat[1] < 0.5 * base[1]
    assert spat[2] < 0.1  # it does not win by dropping features
    assert np.all(cfg.found) and np.all((cfg.posterior > 0) & (cfg.posterior <= 1))
    # the posterior is a usable chain confidence: higher when the whole configuration is right
    ch, it = np.asarray(cfg.chosen), faces.hypotheses.is_true
    right = np.all(np.where(ch >= 0, np.take_along_axis(it, np.maximum(ch, 0)[..., None], -1)[..., 0], ~faces.visible), -1)
    post = np.asarray(cfg.posterior)
    print(f"  exact configurations {right.mean():.2f}; mean posterior right {post[right].mean():.2f}, wrong {post[~right].mean():.2f}")
    assert post[right].mean() > post[~right].mean()
    if view == "profile":  # mostly the 3-feature configuration without the hidden eye
        assert ((np.asarray(cfg.chosen) >= 0) == faces.visible).all(-1).mean() > 0.8


# ---------------------------------------------------------------- exact search


def _np_log_density(pos, present, model):
    """Independent NumPy re-implementation of the configuration density."""
    m = np.asarray(present)
    if m.sum() < 3:
        return -np.inf
    s = 0 if m.all() else 1 + int(np.argmin(m))
    p = pos[m]
    d = p - p.mean(0)
    d = d / np.sqrt((d**2).sum() / m.sum())
    x = np.zeros((4, 2))
    x[m] = d
    z = (x.ravel() - np.asarray(model.mean[s])) @ np.asarray(model.whiten[s])
    return float(model.log_prior[s] + model.log_norm[s] - 0.5 * z @ z)


def test_vmapped_search_equals_brute_force(model):
    rng = np.random.default_rng(0)
    H, thr = 2, 0.2
    faces = simulate_faces(jax.random.key(5), 6, num_hypotheses=H)
    pos = faces.hypotheses.positions + rng.normal(0, 3, faces.hypotheses.positions.shape)
    conf = rng.uniform(0, 1, (6, 4, H))
    conf[0, 2] = 0.0  # the nose has no hypothesis at all
    cfg = best_configuration((pos, conf), model, threshold=thr)
    assert enumerate_combinations(H).shape == (3**4 - 1 - 8 - 24, 4)
    for n in range(6):
        scores = {}
        for combo in itertools.product(range(-1, H), repeat=4):
            c = np.array(combo)
            if (c >= 0).sum() < 3 or any(conf[n, f, c[f]] <= thr for f in range(4) if c[f] >= 0):
                continue
            idx = np.maximum(c, 0)
            ll = _np_log_density(pos[n, np.arange(4), idx], c >= 0, model)
            scores[combo] = ll + sum(np.log(conf[n, f, c[f]]) for f in range(4) if c[f] >= 0)
        best = max(scores, key=scores.get)
        vals = np.array(list(scores.values()))
        np.testing.assert_array_equal(np.asarray(cfg.chosen[n]), best)
        np.testing.assert_allclose(float(cfg.score[n]), scores[best], rtol=1e-4, atol=1e-4)
        post = 1.0 / np.exp(vals - scores[best]).sum()
        np.testing.assert_allclose(float(cfg.posterior[n]), post, rtol=1e-3)
    assert (np.asarray(cfg.chosen[0, 2]) == -1)


def test_too_few_features_is_flagged(model):
    faces = simulate_faces(jax.random.key(6), 3)
    pos, conf = faces.hypotheses.positions, faces.hypotheses.confidences.copy()
    conf[0, 1:3] = 0.0  # two features without hypotheses
    conf[1] = np.where(conf[1] > 0, 0.3, 0.0)  # all below the threshold
    cfg = best_configuration(Hypotheses(pos, conf, faces.hypotheses.is_true), model, threshold=0.5)
    assert not cfg.found[0] and not cfg.found[1] and cfg.found[2] in (True, False)
    np.testing.assert_array_equal(np.asarray(cfg.chosen[:2]), -1)
    assert np.all(np.isneginf(np.asarray(cfg.score[:2]))) and np.all(np.asarray(cfg.posterior[:2]) == 0)
    base = np.asarray(independent_detectors((pos, conf), threshold=0.5))
    assert np.all(base[1] == -1)


def test_nan_and_bad_inputs_raise(model):
    faces = simulate_faces(jax.random.key(7), 2)
    pos, conf = faces.hypotheses.positions.copy(), faces.hypotheses.confidences.copy()
    bad = pos.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        best_configuration((bad, conf), model)
    badc = conf.copy()
    badc[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        independent_detectors((pos, badc))
    with pytest.raises(ValueError):
        best_configuration((pos, conf * 2), model)
    with pytest.raises(ValueError):
        best_configuration((pos[..., 0], conf), model)
    with pytest.raises(ValueError):
        best_configuration((pos, conf), model, threshold=float("nan"))
    F = faces.features_image.copy()
    F[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fit_spatial_model(F, faces.visible)


# ---------------------------------------------------------------- metrics


def test_metrics_hand_computed():
    # right eye, left eye, nose, mouth; eye midpoint (10, 0), mouth (10, 20): τ = 1/20
    m = np.array([[0.0, 0.0], [20.0, 0.0], [10.0, 10.0], [10.0, 20.0]])
    assert tau(m) == pytest.approx(1 / 20)
    # the paper's literal (m_le + m_re) − m_m would give 1/‖(10, -20)‖, not 1/20
    assert tau(m) != pytest.approx(1 / np.hypot(10, 20))
    est = m + np.array([[3.0, 4.0], [0.0, 0.0], [0.0, 2.0], [np.nan, np.nan]])
    mean, mx = normalized_deviation(m, est)  # mouth missing: k = 3
    assert mean == pytest.approx((5 + 0 + 2) / 3 / 20) and mx == pytest.approx(5 / 20)
    mean2, mx2 = normalized_deviation(m, est, present=[False, True, True, False])
    assert mean2 == pytest.approx(1 / 20) and mx2 == pytest.approx(2 / 20)
    # τ scales with face size, not position: shift and double the face
    mean3, _ = normalized_deviation(2 * m + 100, 2 * est + 100)
    assert mean3 == pytest.approx(mean)
    nothing, _ = normalized_deviation(m, np.full((4, 2), np.nan))
    assert np.isnan(nothing)
    with pytest.raises(ValueError):
        normalized_deviation(m, est, present=[True, True, True, True])  # NaN estimate marked present
    with pytest.raises(ValueError, match="NaN"):
        tau(np.where(np.eye(4, 2, dtype=bool), np.nan, m))
    frac = cumulative_histogram([0.05, 0.1, 0.3, np.nan], [0.0, 0.1, 0.25, 1.0])
    np.testing.assert_allclose(frac, [0.0, 0.5, 0.5, 0.75])
