"""Speaker-prior gaze bias (Siegfried, Odobez et al. 2017): looking-at decision, frame selection, estimators.

Every check is against a known truth, a plain-Python reference, or a property.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxgaze.bias.estimators import (
    contrast_log_density,
    BiasEstimate,
    estimate_bias,
    lmeds_bias,
    sample_bias_posterior,
    update_bias,
)
from jaxgaze.bias.looking import (
    angular_error,
    candidate_frames,
    direction_to_gaze_angles,
    gaze_angles_to_direction,
    gaze_offsets,
    head_target_angle,
    head_to_world,
    is_looking_at,
    looking_probability,
    select_frames,
    target_direction_head,
)
from jaxgaze.geometry import axis_angle_to_rotation_matrix, wrap_angle
from jaxgaze.results import RESULTS, FitError, succeeded

DEG = math.pi / 180
CHI2_2DOF_90 = -2 * math.log(0.1)  # 90% quantile of χ²(2)
TRUE_BIAS = np.radians([5.0, -8.0])


def synthetic_offsets(key, bias, n=60, looking=0.6, noise_deg=3.0, box_deg=40.0):
    """``looking·n`` offsets from N(b, noise²), the rest uniform over ±box (absolute angles)."""
    k_in, k_out = jax.random.split(key)
    m = int(round(looking * n))
    inliers = bias + noise_deg * DEG * np.asarray(jax.random.normal(k_in, (m, 2)))
    outliers = box_deg * DEG * np.asarray(jax.random.uniform(k_out, (n - m, 2), minval=-1.0, maxval=1.0))
    is_inlier = np.arange(n) < m
    return np.concatenate([inliers, outliers]).astype(np.float32), is_inlier


# ------------------------------------------------------------------ angle conversions


@pytest.mark.parametrize(
    "angles, direction",
    [
        ((0.0, 0.0), (1.0, 0.0, 0.0)),  # forward
        ((math.pi / 2, 0.0), (0.0, 1.0, 0.0)),  # yaw +90° → left (+y)
        ((-math.pi / 2, 0.0), (0.0, -1.0, 0.0)),  # right
        ((0.0, math.pi / 2), (0.0, 0.0, 1.0)),  # tilt +90° → up (+z)
        ((math.pi, 0.0), (-1.0, 0.0, 0.0)),  # backwards
        ((math.pi / 4, math.pi / 4), (0.5, 0.5, math.sqrt(0.5))),
    ],
)
def test_gaze_angles_known_values(angles, direction):
    np.testing.assert_allclose(gaze_angles_to_direction(jnp.array(angles)), direction, atol=1e-6)


def test_gaze_angles_round_trip():
    key_yaw, key_tilt = jax.random.split(jax.random.key(0))
    yaw = jax.random.uniform(key_yaw, (200,), minval=-3.1, maxval=3.1)
    tilt = jax.random.uniform(key_tilt, (200,), minval=-1.5, maxval=1.5)
    angles = jnp.stack([yaw, tilt], -1).reshape(10, 20, 2)
    direction = gaze_angles_to_direction(angles)
    assert direction.shape == (10, 20, 3)
    np.testing.assert_allclose(jnp.linalg.norm(direction, axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(direction_to_gaze_angles(direction), angles, atol=2e-5)
    # The inverse does not need unit vectors.
    np.testing.assert_allclose(direction_to_gaze_angles(3.0 * direction), angles, atol=2e-5)


def test_wrap_angle():
    x = jnp.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -3 * math.pi / 2, 2 * math.pi + 0.1, -6.0])
    expected = [0.0, math.pi, math.pi, -math.pi / 2, math.pi / 2, 0.1, 2 * math.pi - 6.0]
    np.testing.assert_allclose(wrap_angle(x), expected, atol=1e-6)


def test_target_direction_head_and_head_to_world():
    # The head looks along world +y (yaw 90° about world z): world +y is head +x, world −x is head +y.
    R = axis_angle_to_rotation_matrix(jnp.array([0.0, 0.0, math.pi / 2]))
    eye = jnp.array([1.0, 1.0, 1.6])
    np.testing.assert_allclose(target_direction_head(eye, eye + jnp.array([0.0, 2.0, 0.0]), R), [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(target_direction_head(eye, eye + jnp.array([-3.0, 0.0, 0.0]), R), [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(target_direction_head(eye, eye + jnp.array([0.0, 0.0, 0.5]), R), [0, 0, 1], atol=1e-6)
    # head_to_world undoes it, over a batch of frames.
    targets = eye + jax.random.normal(jax.random.key(1), (7, 3))
    u = target_direction_head(eye, targets, jnp.broadcast_to(R, (7, 3, 3)))
    expected = (targets - eye) / jnp.linalg.norm(targets - eye, axis=-1, keepdims=True)
    np.testing.assert_allclose(head_to_world(u, R), expected, atol=1e-6)


def test_gaze_offsets_recover_the_bias():
    """When the corrected gaze g + b points exactly at the target, the offset is b."""
    key_u, key_b = jax.random.split(jax.random.key(2))
    target_angles = jax.random.uniform(key_u, (50, 2), minval=-0.6, maxval=0.6)
    u = gaze_angles_to_direction(target_angles)
    bias = jnp.array([0.1, -0.15])
    gaze = target_angles - bias
    np.testing.assert_allclose(gaze_offsets(gaze, u), jnp.broadcast_to(bias, (50, 2)), atol=1e-5)
    np.testing.assert_allclose(angular_error(gaze, u, bias), 0.0, atol=1e-3)


def test_gaze_offsets_wrap_the_yaw():
    u = gaze_angles_to_direction(jnp.array([-3.0, 0.1]))  # yaw −3.0 rad
    offset = gaze_offsets(jnp.array([3.0, 0.0]), u)
    np.testing.assert_allclose(offset, [2 * math.pi - 6.0, 0.1], atol=1e-5)


def test_angular_error_against_hand_computation(x64):
    rng = np.random.default_rng(3)
    gaze = rng.uniform(-0.8, 0.8, (40, 2))
    bias = np.array([0.05, -0.02])
    u = rng.normal(size=(40, 3)) + [3.0, 0.0, 0.0]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    yaw, tilt = (gaze + bias).T
    v = np.stack([np.cos(tilt) * np.cos(yaw), np.cos(tilt) * np.sin(yaw), np.sin(tilt)], 1)
    expected = np.arccos(np.clip(np.sum(v * u, axis=1), -1, 1))
    np.testing.assert_allclose(angular_error(gaze, u, bias), expected, atol=1e-10)
    # A pure yaw offset α between gaze and target gives e = α.
    np.testing.assert_allclose(angular_error(np.zeros(2), [math.cos(0.3), math.sin(0.3), 0.0]), 0.3, atol=1e-12)


def test_is_looking_at_threshold_boundary(x64):
    tau = 10 * DEG
    for angle, expected in [(tau - 1e-9, True), (tau + 1e-9, False), (0.0, True), (math.pi, False)]:
        u = jnp.array([math.cos(angle), math.sin(angle), 0.0])
        assert bool(is_looking_at(jnp.zeros(2), u)) is expected
    # The bias moves the decision: with b = (τ, 0) a target at 2τ − ε is looked at.
    u = jnp.array([math.cos(2 * tau - 1e-6), math.sin(2 * tau - 1e-6), 0.0])
    assert not is_looking_at(jnp.zeros(2), u)
    assert is_looking_at(jnp.zeros(2), u, jnp.array([tau, 0.0]))
    # threshold_deg is in degrees
    assert is_looking_at(jnp.zeros(2), u, threshold_deg=21.0)


def test_is_looking_at_vmaps_and_jits():
    key_g, key_u = jax.random.split(jax.random.key(4))
    gaze = jax.random.uniform(key_g, (100, 2), minval=-0.4, maxval=0.4)
    u = gaze_angles_to_direction(jax.random.uniform(key_u, (100, 2), minval=-0.4, maxval=0.4))
    bias = jnp.array([0.02, -0.03])
    batched = is_looking_at(gaze, u, bias)
    assert batched.shape == (100,) and batched.dtype == bool
    assert 0 < int(batched.sum()) < 100
    np.testing.assert_array_equal(jax.vmap(is_looking_at, (0, 0, None))(gaze, u, bias), batched)
    np.testing.assert_array_equal(jax.jit(is_looking_at)(gaze, u, bias), batched)
    expected = np.asarray(angular_error(gaze, u, bias)) < 10 * DEG
    np.testing.assert_array_equal(batched, expected)


def test_looking_probability():
    key_g, key_u, key_b = jax.random.split(jax.random.key(5), 3)
    gaze = jax.random.uniform(key_g, (30, 2), minval=-0.3, maxval=0.3)
    u = gaze_angles_to_direction(jax.random.uniform(key_u, (30, 2), minval=-0.3, maxval=0.3))
    bias = jnp.array([0.05, -0.04])
    # All draws equal: the deterministic decision.
    p = looking_probability(gaze, u, jnp.tile(bias, (25, 1)))
    np.testing.assert_array_equal(p, is_looking_at(gaze, u, bias).astype(float))
    # Spread draws: the fraction of draws that decide "looking", in [0, 1].
    draws = bias + 0.05 * jax.random.normal(key_b, (64, 2))
    p = looking_probability(gaze, u, draws)
    assert p.shape == (30,) and np.all((p >= 0) & (p <= 1))
    expected = np.asarray(is_looking_at(gaze[None], u[None], draws[:, None, :])).mean(0)  # (S, frames) → frames
    np.testing.assert_allclose(p, expected, atol=1e-6)
    assert 0 < np.mean((p > 0) & (p < 1))  # some frames are uncertain


def test_head_target_angle():
    angles = jnp.array([[0.0, 0.0], [0.3, 0.0], [0.0, -0.5], [math.pi, 0.0]])
    angle = head_target_angle(gaze_angles_to_direction(angles))
    np.testing.assert_allclose(angle, [0.0, 0.3, 0.5, math.pi], atol=1e-5)


# --------------------------------------------------------------------- frame selection


def _recording(T=3000, seed=6):
    rng = np.random.default_rng(seed)
    speaking = rng.random(T) < 0.5
    angle = rng.uniform(0, 60, T) * DEG
    return speaking, angle


def test_select_frames_picks_only_candidates_in_the_window():
    speaking, angle = _recording()
    fps = 30.0
    sel = select_frames(jax.random.key(0), speaking, angle, num_frames=40, fps=fps)
    assert sel.num_selected == 40 == len(sel.indices) and not sel.partial
    assert len(np.unique(sel.indices)) == 40 and np.all(np.diff(sel.indices) > 0)
    assert np.all(speaking[sel.indices])
    assert np.all(angle[sel.indices] <= 30 * DEG)
    assert np.all(sel.indices / fps < 60.0)  # first minute = frames 0..1799
    expected = speaking & (angle <= 30 * DEG) & (np.arange(len(speaking)) < 1800)
    np.testing.assert_array_equal(sel.candidates, expected)
    assert sel.num_candidates == expected.sum()
    # Deterministic per key; another key draws another subset.
    again = select_frames(jax.random.key(0), speaking, angle, num_frames=40, fps=fps)
    np.testing.assert_array_equal(again.indices, sel.indices)
    other = select_frames(jax.random.key(1), speaking, angle, num_frames=40, fps=fps)
    assert not np.array_equal(other.indices, sel.indices)
    # The jittable mask agrees.
    np.testing.assert_array_equal(jax.jit(lambda s, a: candidate_frames(s, a, fps=fps))(speaking, angle), expected)


def test_select_frames_window_and_too_few_candidates():
    speaking = np.zeros(600, bool)
    speaking[[5, 50, 99, 100, 400]] = True
    angle = np.zeros(600)
    sel = select_frames(jax.random.key(0), speaking, angle, num_frames=10, fps=10.0, window_s=10.0)
    np.testing.assert_array_equal(sel.indices, [5, 50, 99])  # frame 100 is at t = 10 s: outside
    assert sel.partial and sel.num_selected == sel.num_candidates == 3
    sel = select_frames(jax.random.key(0), speaking, angle, num_frames=10, fps=10.0, window_s=10.0, start_s=5.0)
    np.testing.assert_array_equal(sel.indices, [50, 99, 100])


def test_select_frames_no_candidates_is_a_clear_error():
    speaking, angle = _recording()
    with pytest.raises(ValueError, match="no frames"):
        select_frames(jax.random.key(0), np.zeros_like(speaking), angle, num_frames=20, fps=30.0)
    with pytest.raises(ValueError, match="no frames"):  # head always turned away
        select_frames(jax.random.key(0), speaking, np.full(angle.shape, 40 * DEG), num_frames=20, fps=30.0)


def test_select_frames_bad_inputs():
    speaking, angle = _recording()
    bad = angle.copy()
    bad[17] = np.nan
    with pytest.raises(ValueError, match="head_target_angle.*frame 17"):
        select_frames(jax.random.key(0), speaking, bad, num_frames=20, fps=30.0)
    with pytest.raises(ValueError, match="shape"):
        select_frames(jax.random.key(0), speaking, angle[:-1], num_frames=20, fps=30.0)
    with pytest.raises(ValueError, match="num_frames"):
        select_frames(jax.random.key(0), speaking, angle, num_frames=0, fps=30.0)


# ------------------------------------------------------------------------ bad inputs


def test_looking_functions_reject_nan_and_bad_shapes():
    gaze = np.zeros((5, 2))
    gaze[3, 1] = np.nan
    u = np.tile([1.0, 0.0, 0.0], (5, 1))
    for fn in (angular_error, is_looking_at, gaze_offsets):
        with pytest.raises(ValueError, match="gaze_angles.*frame 3"):
            fn(gaze, u)
    bad_u = u.copy()
    bad_u[1, 0] = np.inf
    with pytest.raises(ValueError, match="target_dir_head.*frame 1"):
        angular_error(np.zeros((5, 2)), bad_u)
    with pytest.raises(ValueError, match=r"gaze_angles must have shape \(\.\.\., 2\)"):
        angular_error(np.zeros((5, 3)), u)
    with pytest.raises(ValueError, match="do not broadcast"):
        angular_error(np.zeros((4, 2)), u)
    with pytest.raises(ValueError, match="bias_samples"):
        looking_probability(np.zeros((5, 2)), u, np.zeros((3, 3)))


def test_estimate_bias_bad_inputs():
    good = np.zeros((10, 2))
    with pytest.raises(ValueError, match="no frames"):
        estimate_bias(np.zeros((0, 2)), "mean")
    for method in ("mean", "lmeds", "bayes"):
        with pytest.raises(ValueError, match="no frames"):
            estimate_bias(np.zeros((0, 2)), method)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        estimate_bias(np.zeros((10, 3)), "mean")
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        estimate_bias(np.zeros(10), "lmeds")
    bad = good.copy()
    bad[6, 0] = np.nan
    with pytest.raises(ValueError, match="row 6"):
        estimate_bias(bad, "lmeds")
    bad[6, 0] = np.inf
    with pytest.raises(ValueError, match="row 6"):
        estimate_bias(bad, "bayes")
    with pytest.raises(ValueError, match="unknown method"):
        estimate_bias(good, "median")
    with pytest.raises(ValueError, match="at least 3"):
        estimate_bias(np.zeros((2, 2)), "lmeds")
    with pytest.raises(TypeError, match="model options"):
        estimate_bias(good, "mean", looking_prior=(1, 1))


# ------------------------------------------------------------------------ mean, LMedS


def test_mean_is_exact():
    o = np.random.default_rng(7).normal(size=(20, 2)) * 0.1
    est = estimate_bias(o, "mean")
    assert isinstance(est, BiasEstimate) and est.method == "mean" and est.num_frames == 20
    np.testing.assert_allclose(est.bias, o.mean(0), atol=1e-7)
    np.testing.assert_allclose(est.covariance, np.cov(o, rowvar=False) / 20, rtol=1e-5)
    np.testing.assert_allclose(est.bias_deg, np.degrees(o.mean(0)), rtol=1e-5)
    assert est.inliers.all()
    assert estimate_bias(o[:1], "mean").covariance is None  # one frame: no spread


def lmeds_reference(offsets):
    """Plain-Python LMedS (eq. 2): every candidate o_i, median of squared residuals, ties → lowest index."""
    o = [(float(a), float(b)) for a, b in offsets]
    n = len(o)
    best, best_median = None, None
    for i in range(n):
        r2 = sorted((o[j][0] - o[i][0]) ** 2 + (o[j][1] - o[i][1]) ** 2 for j in range(n))
        median = (r2[(n - 1) // 2] + r2[n // 2]) / 2
        if best_median is None or median < best_median:
            best, best_median = i, median
    k = (n + 1) // 2  # ⌈N/2⌉
    residual = [((o[j][0] - o[best][0]) ** 2 + (o[j][1] - o[best][1]) ** 2, j) for j in range(n)]
    kept = [j for _, j in sorted(residual)[:k]]
    bias = (sum(o[j][0] for j in kept) / k, sum(o[j][1] for j in kept) / k)
    return best, bias, sorted(kept)


_angle = st.one_of(
    # no magnitude under 1e-100: its square would be subnormal, which XLA:CPU flushes to zero (the reference does not)
    st.floats(-0.7, 0.7, allow_nan=False, allow_subnormal=False).filter(lambda x: x == 0 or abs(x) >= 1e-100),
    st.integers(-3, 3).map(lambda i: 0.05 * i),  # coarse grid: exact ties in distances and medians
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(_angle, _angle), min_size=3, max_size=24))
def test_lmeds_matches_brute_force_exactly(x64, offsets):
    o = np.array(offsets, dtype=np.float64)
    best, bias, kept = lmeds_reference(o)
    est = estimate_bias(o, "lmeds")
    assert est.candidate == best
    np.testing.assert_allclose(est.bias, bias, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.flatnonzero(est.inliers), kept)
    assert est.bias.dtype == np.float64


def test_lmeds_rounding_follows_the_paper():
    # N = 40 → the mean of 20 offsets (the paper's Med); odd N rounds up.
    o = np.random.default_rng(8).normal(size=(41, 2))
    assert estimate_bias(o[:40], "lmeds").inliers.sum() == 20
    assert estimate_bias(o, "lmeds").inliers.sum() == 21


def test_lmeds_masked_padding_is_ignored():
    o = np.random.default_rng(9).normal(size=(13, 2)).astype(np.float32)
    padded = np.concatenate([o, np.full((7, 2), 100.0, np.float32)])
    mask = np.arange(20) < 13
    b, best, inliers = lmeds_bias(o)
    b_pad, best_pad, inliers_pad = lmeds_bias(padded, mask)
    np.testing.assert_allclose(b_pad, b, atol=1e-6)
    assert int(best_pad) == int(best)
    np.testing.assert_array_equal(inliers_pad[:13], inliers)
    assert not inliers_pad[13:].any()
    # vmappable over people
    stacked = jnp.stack([padded, padded[::-1]])
    masks = jnp.stack([mask, mask[::-1]])
    vb, _, _ = jax.vmap(lmeds_bias)(stacked, masks)
    np.testing.assert_allclose(vb, [b, b], atol=1e-6)


def test_lmeds_is_robust_to_40_percent_outliers():
    errors_lmeds, errors_mean = [], []
    for seed in range(10):
        bias = np.radians([6.0, -9.0]) + np.radians(5.0) * np.random.default_rng(seed).normal(size=2)
        o, is_inlier = synthetic_offsets(jax.random.key(100 + seed), bias, n=40, looking=0.6, noise_deg=2.0)
        est = estimate_bias(o, "lmeds")
        errors_lmeds.append(np.degrees(np.linalg.norm(est.bias - bias)))
        errors_mean.append(np.degrees(np.linalg.norm(estimate_bias(o, "mean").bias - bias)))
        assert est.inliers.sum() == 20 and is_inlier[est.inliers].mean() >= 0.9
    # Inlier noise 2° per axis: the mean of ~20 inliers is within ~0.6°; LMedS stays within noise.
    assert max(errors_lmeds) < 2.0, errors_lmeds
    assert np.median(errors_mean) > 3 * np.median(errors_lmeds)


def test_update_bias_mean_and_lmeds_refit_on_all_frames():
    o = np.random.default_rng(10).normal(size=(30, 2)).astype(np.float32) * 0.1
    for method in ("mean", "lmeds"):
        one_shot = estimate_bias(o, method)
        updated = update_bias(estimate_bias(o[:12], method), o[12:])
        assert updated.num_frames == 30 and updated.method == method
        np.testing.assert_array_equal(updated.bias, one_shot.bias)


# ------------------------------------------------------------------------------ bayes

DRAWS = 500  # NUTS warm-up and draws: the estimator's default, enough for 100 tail-effective draws.
# Every fit of this section has 33–64 frames (padded to 64), so all share one compiled program.


@pytest.fixture(scope="module")
def bayes_data():
    return synthetic_offsets(jax.random.key(11), TRUE_BIAS, n=60, looking=0.6, noise_deg=3.0, box_deg=40.0)


@pytest.fixture(scope="module")
def bayes_fit(bayes_data):
    offsets, _ = bayes_data
    return estimate_bias(offsets, "bayes", key=jax.random.key(12), num_warmup=DRAWS, num_samples=DRAWS)


def test_bayes_recovers_the_bias(bayes_fit):
    est = bayes_fit
    assert est.method == "bayes" and est.num_frames == 60
    error = est.bias - TRUE_BIAS
    assert np.degrees(np.linalg.norm(error)) < 1.5
    # The 90% credible region of b (Gaussian approximation of the draws) covers the truth.
    assert error @ np.linalg.solve(est.covariance, error) < CHI2_2DOF_90
    sd_deg = np.degrees(np.sqrt(np.diag(est.covariance)))
    assert np.all((sd_deg > 0.2) & (sd_deg < 1.5))  # ≈ 3°/√36 ≈ 0.5° per axis


def test_bayes_responsibilities(bayes_fit, bayes_data):
    offsets, is_inlier = bayes_data
    r = bayes_fit.responsibilities
    assert r.shape == (60,) and np.all((r >= 0) & (r <= 1))
    assert r[is_inlier].mean() > 0.8 and (r[is_inlier] > 0.5).mean() >= 0.9
    far = np.degrees(np.linalg.norm(offsets - TRUE_BIAS, axis=1)) > 15.0
    assert far.sum() > 10 and np.all(r[far] < 0.5)
    np.testing.assert_array_equal(bayes_fit.inliers, r > 0.5)
    share = bayes_fit.samples["looking_share"].mean()
    assert 0.45 < share < 0.75  # truth 0.6


def test_bayes_posterior_objects(bayes_fit):
    est = bayes_fit
    assert est.samples["bias"].shape == (DRAWS, 2)
    assert est.samples["responsibilities"].shape == (DRAWS, 60)
    np.testing.assert_allclose(est.bias, est.samples["bias"].mean(0), rtol=1e-6)
    assert est.sampler.idata.posterior["bias"].shape == (1, DRAWS, 2)
    assert {"ess_bulk", "r_hat", "mean", "sd"} <= set(est.sampler.summary.columns)
    assert est.sampler.summary.loc["bias[yaw]", "ess_bulk"] > 50
    assert int(est.sampler.idata.sample_stats["diverging"].sum()) <= 3
    # posterior draws feed looking_probability
    targets = gaze_angles_to_direction(jnp.array([[0.0, 0.0], [0.09, -0.14], [0.5, 0.5]]))
    p = looking_probability(jnp.zeros((3, 2)), targets, est.samples["bias"])
    assert p[1] > 0.99 and p[2] == 0.0


def test_bayes_fit_reports_its_mixing(bayes_fit, bayes_data):
    est = bayes_fit
    assert succeeded(est) and est.result == RESULTS.successful
    d = est.sampler.diagnostics
    assert d.chains == 1 and d.max_rhat < 1.05 and d.min_ess_bulk >= 100 and d.acceptance_rate > 0.5
    assert {"mean", "sd", "hdi_5%", "hdi_95%", "ess_bulk", "ess_tail", "r_hat"} <= set(est.sampler.summary.columns)
    assert np.all(np.isfinite(est.sampler.summary["r_hat"]))  # split r-hat: defined for one chain
    row = est.sampler.summary.loc["bias[yaw]"]
    assert row["hdi_5%"] <= TRUE_BIAS[0] <= row["hdi_95%"]
    assert succeeded(estimate_bias(bayes_data[0], "lmeds"))


def test_a_bias_sampler_that_never_moved_is_a_failure(bayes_data, monkeypatch):
    """A chain stuck at its start (acceptance 0, every draw the same) is ``not_mixed``; ``throw=True`` raises."""
    import jaxgaze.bias.estimators as estimators

    real = estimators.sample_nuts

    def stuck(model, key, model_args, init_params, *, num_warmup, num_samples, **options):
        values, _ = real(model, key, model_args, init_params, num_warmup=num_warmup, num_samples=num_samples,
                         **options)
        values = {k: np.repeat(np.asarray(v)[:, :1], num_samples, axis=1) for k, v in values.items()}
        stats = {"diverging": np.ones((1, num_samples), bool), "acceptance_rate": np.zeros((1, num_samples)),
                 "n_steps": np.ones((1, num_samples), int), "lp": np.zeros((1, num_samples))}
        return values, stats

    monkeypatch.setattr(estimators, "sample_nuts", stuck)
    offsets, _ = bayes_data
    est = estimate_bias(offsets, "bayes", num_warmup=DRAWS, num_samples=DRAWS)
    assert not succeeded(est) and est.result == RESULTS.not_mixed
    assert est.sampler.diagnostics.min_ess_bulk == 0 and np.isnan(est.sampler.diagnostics.max_rhat)
    assert est.sampler.diagnostics.divergences == DRAWS
    with pytest.raises(FitError, match="did not mix"):
        estimate_bias(offsets, "bayes", num_warmup=DRAWS, num_samples=DRAWS, throw=True)


def test_bayes_is_reproducible_and_update_matches_one_shot(bayes_fit, bayes_data):
    offsets, _ = bayes_data
    # The first 40 frames, then 20 more (N = 40 and 60 share one padded compilation).
    first = estimate_bias(offsets[:40], "bayes", key=jax.random.key(13), num_warmup=DRAWS, num_samples=DRAWS)
    assert first.num_frames == 40
    same = update_bias(first, offsets[40:], key=jax.random.key(12))
    np.testing.assert_array_equal(same.samples["bias"], bayes_fit.samples["bias"])  # same data, same key
    updated = update_bias(first, offsets[40:], key=jax.random.key(14))
    assert updated.num_frames == 60
    assert np.degrees(np.linalg.norm(updated.bias - bayes_fit.bias)) < 0.3
    np.testing.assert_allclose(np.sqrt(np.diag(updated.covariance)), np.sqrt(np.diag(bayes_fit.covariance)), rtol=0.3)
    # More looking frames narrow the posterior: 15 against 36 (the variance of b scales like
    # 1/N_looking). The last 15 looking frames and the 24 glances: 39 frames, the same program.
    # (The first 40 frames hold 36 looking ones too: too close to tell apart.)
    few = estimate_bias(offsets[21:], "bayes", key=jax.random.key(13), num_warmup=DRAWS, num_samples=DRAWS)
    assert few.num_frames == 39
    assert np.trace(bayes_fit.covariance) < 0.7 * np.trace(few.covariance)


def test_bayes_coverage_over_synthetic_people():
    """20 people (b ~ N(0, 10°)), all sampled in one compiled, batched run: error and 90% coverage."""
    people = 20
    keys = jax.random.split(jax.random.key(15), people)
    truths = np.radians(10.0) * np.asarray(jax.random.normal(jax.random.key(16), (people, 2)))
    offsets = np.stack([synthetic_offsets(k, b)[0] for k, b in zip(keys, truths)])
    values, stats = sample_bias_posterior(offsets, key=jax.random.key(17), num_warmup=DRAWS, num_samples=DRAWS)
    draws = np.asarray(values["bias"])[:, 0]  # (people, draws, 2)
    assert draws.shape == (people, DRAWS, 2)
    mean = draws.mean(1)
    errors_deg = np.degrees(np.linalg.norm(mean - truths, axis=1))
    covariance = np.stack([np.cov(d, rowvar=False) for d in draws])
    d = mean - truths
    mahalanobis2 = np.einsum("pi,pij,pj->p", d, np.linalg.inv(covariance), d)
    covered = np.mean(mahalanobis2 < CHI2_2DOF_90)
    print(f"bias error: median {np.median(errors_deg):.2f}°, max {errors_deg.max():.2f}°; 90% coverage {covered:.2f}")
    assert np.median(errors_deg) < 1.0 and errors_deg.max() < 2.5
    assert covered >= 0.75  # P(≤ 14 of 20 | 0.9) ≈ 0.04


# ----------------------------------------------------------- contrast with the silent partner


def test_contrast_log_density_matches_a_brute_force_kernel_sum(x64):
    rng = np.random.default_rng(3)
    o, silent = rng.normal(size=(5, 2)) * 0.1, rng.normal(size=(7, 2)) * 0.1
    mask = np.array([True] * 6 + [False])
    h = 0.05
    expected = [math.log(np.mean([math.exp(-np.sum((x - y) ** 2) / (2 * h * h)) / (2 * math.pi * h * h)
                                  for y in silent[mask]])) for x in o]
    got = contrast_log_density(jnp.asarray(o), jnp.asarray(silent), jnp.asarray(mask), h)
    np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-10)
