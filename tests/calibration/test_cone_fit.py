"""Gaze-ray calibration (Park et al. 2012, Sec. 3.2) against synthetic wearers with known cones."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxgaze as jg
from jaxgaze.calibration import (
    MAX_APEX_DISTANCE,
    ConeCalibration,
    calibrate_cone,
    points_in_camera_frame,
)
from jaxgaze.calibration.cone_fit import solve_cone_apex
from jaxgaze.geometry import angle_between, axis_angle_to_rotation_matrix, yaw_pitch_to_direction
from jaxgaze.results import RESULTS, FitError, succeeded

M = 60  # points of regard per wearer
WEARERS = 20
EYE = np.array([-0.08, 0.0, -0.10])  # centre of the eyes in the camera frame (m)


def synthetic_wearer(key, num_points=M):
    """Points of regard of one wearer in the camera frame, and the true ``(p*, v*, h*)``.

    ``p*`` is a few cm from ``EYE``; ``v*`` within 6° of +x; ``h*`` in [0.02, 0.05];
    depths uniform in 1–4 m; the points follow the cone model exactly.
    """
    k = jax.random.split(key, 5)
    p = jnp.asarray(EYE) + 0.02 * jax.random.uniform(k[0], (3,), minval=-1.0, maxval=1.0)
    yaw, pitch = jnp.deg2rad(jax.random.uniform(k[1], (2,), minval=-6.0, maxval=6.0))
    v = yaw_pitch_to_direction(yaw, pitch)
    h = jax.random.uniform(k[2], (), minval=0.02, maxval=0.05)
    depth = jax.random.uniform(k[3], (num_points,), minval=1.0, maxval=4.0)
    rays = jg.GazeRays(jnp.broadcast_to(p, (num_points, 3)), jnp.broadcast_to(v, (num_points, 3)), h)
    return jg.sample_points_of_regard(k[4], rays, depth), p, v, h


def errors(cal, p, v):
    """Direction error (deg), eye-centre error perpendicular to and along ``v*`` (m)."""
    e = cal.eye_center - p
    along = jnp.sum(e * v, axis=-1)
    perp = jnp.linalg.norm(e - along[..., None] * v, axis=-1)
    return np.rad2deg(np.asarray(angle_between(cal.direction, v))), np.asarray(perp), np.asarray(along)


def with_outliers(key, y, fraction=0.2):
    """Replace ``fraction`` of the points by points uniform in a box in front of the camera."""
    n = int(round(fraction * y.shape[0]))
    box = jax.random.uniform(key, (n, 3), minval=jnp.array([0.5, -2.5, -2.5]), maxval=jnp.array([5.0, 2.5, 2.5]))
    return y.at[:n].set(box), n


@pytest.fixture(scope="module")
def wearers():
    keys = jax.random.split(jax.random.PRNGKey(0), WEARERS)
    y, p, v, h = jax.jit(jax.vmap(synthetic_wearer))(keys)
    return keys, y, p, v, h


@pytest.fixture(scope="module")
def calibrated(wearers):
    keys, y, *_ = wearers
    return calibrate_many(y, keys)


@jax.jit
def calibrate_many(points, keys):
    return jax.vmap(lambda pts, k: calibrate_cone(pts, key=k, throw=False))(points, keys)


@pytest.fixture(scope="module")
def one_wearer(wearers):
    _, y, p, v, h = wearers
    return np.asarray(y[0]), p[0], v[0], h[0]


# --- recovery ------------------------------------------------------------------------------------


def test_calibration_recovers_direction_and_eye_center(wearers, calibrated):
    _, _, p, v, _ = wearers
    assert np.all(np.asarray(calibrated.result == RESULTS.successful))
    ang, perp, along = errors(calibrated, p, v)
    assert np.median(ang) < 2.0, ang
    assert np.median(perp) < 0.04, perp
    # Along the axis the apex depends on λ; with the default it is unbiased to ~10 cm here.
    assert abs(np.median(along)) < 0.15, along
    assert np.all(np.linalg.norm(calibrated.direction, axis=-1) == pytest.approx(1.0, abs=1e-5))
    assert np.all(np.asarray(calibrated.alpha) > 0)


def test_calibration_recovers_bandwidth(wearers, calibrated):
    *_, h = wearers
    ratio = np.asarray(calibrated.bandwidth / h)
    assert abs(np.median(ratio) - 1.0) < 0.2, ratio
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio


def test_calibration_constraint_holds_at_the_apex(calibrated, wearers):
    """Every inlier lies inside the fitted cone: ``a_i/(b_i + α) ≤ ξ``."""
    _, y, *_ = wearers
    rel = y - calibrated.eye_center[:, None, :]
    t = jnp.einsum("wmk,wk->wm", rel, calibrated.direction)
    off = jnp.linalg.norm(rel - t[..., None] * calibrated.direction[:, None, :], axis=-1)
    tangent = jnp.where(calibrated.inliers, off / t, 0.0)
    assert np.all(np.asarray(t)[np.asarray(calibrated.inliers)] > 0)
    assert np.all(np.asarray(tangent) <= np.asarray(calibrated.xi)[:, None] * (1 + 1e-4) + 1e-6)


def test_ransac_rejects_outliers(wearers):
    keys, y, p, v, _ = wearers
    out_keys = jax.random.split(jax.random.PRNGKey(7), WEARERS)
    y_out, n = jax.vmap(with_outliers, in_axes=(0, 0))(out_keys, y)[0], int(round(0.2 * M))
    cal = calibrate_many(y_out, keys)
    assert np.all(np.asarray(cal.result == RESULTS.successful))
    ang, perp, _ = errors(cal, p, v)
    assert np.median(ang) < 2.0, ang
    assert np.median(perp) < 0.04, perp
    inl = np.asarray(cal.inliers)
    assert inl[:, :n].mean() < 0.15  # most outliers rejected
    assert inl[:, n:].mean() > 0.95  # nearly all cone points kept


def test_ransac_is_deterministic_for_a_fixed_key(one_wearer):
    y, *_ = one_wearer
    y_out, _ = with_outliers(jax.random.PRNGKey(3), jnp.asarray(y))
    a = calibrate_cone(y_out, key=jax.random.PRNGKey(11))
    b = calibrate_cone(y_out, key=jax.random.PRNGKey(11))
    for x, z in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(z))


def test_sign_puts_points_in_front_of_the_camera(one_wearer):
    y, _, v, _ = one_wearer
    cal = calibrate_cone(y, key=jax.random.PRNGKey(1))
    assert float(jnp.dot(cal.direction, v)) > 0.99
    # Reversing the order of the points cannot flip the sign.
    cal_rev = calibrate_cone(y[::-1], key=jax.random.PRNGKey(1))
    assert float(jnp.dot(cal_rev.direction, v)) > 0.99


# --- the 1-D convex apex problem -------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_apex_solve_matches_brute_force_grid(seed):
    with jax.enable_x64(True):
        rng = np.random.default_rng(seed)
        n = 40
        b = np.concatenate([[0.0], rng.uniform(0.0, 3.0, n - 1)])
        a = rng.uniform(0.0, 0.15, n) * (b + 1.0)
        lam = [0.05, 0.02, 0.2][seed]
        alpha, xi = solve_cone_apex(jnp.asarray(a), jnp.asarray(b), lam)
        alpha, xi = float(alpha), float(xi)

        def g(al):
            al = np.asarray(al)[..., None]
            return np.max(a / (b + al), axis=-1) + lam * al[..., 0]

        grid = np.geomspace(1e-4, 100.0, 400_001)
        values = np.concatenate([g(grid[i : i + 50_000]) for i in range(0, grid.size, 50_000)])
        k = int(np.argmin(values))
        assert g(alpha) <= values[k] + 1e-12  # at least as good as the grid
        assert alpha == pytest.approx(grid[k], rel=1e-3)
        assert xi == pytest.approx(np.max(a / (b + alpha)), rel=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 5.0)), min_size=12, max_size=12),
    st.floats(1e-3, 1.0),
)
def test_apex_solve_is_a_global_minimum(pairs, lam):
    """``g`` is convex, so a point no worse than its neighbours on both sides is the minimum."""
    with jax.enable_x64(True):
        a, b = np.array(pairs).T
        b[0] = 0.0  # p0 is the nearest point
        a[0] = max(a[0], 1e-3)
        alpha, xi = solve_cone_apex(jnp.asarray(a), jnp.asarray(b), lam)
        alpha = float(alpha)
        g = lambda al: np.max(a / (b + al)) + lam * al  # noqa: E731
        assert alpha > 0
        for step in (1e-6, 1e-3, 1e-1):
            assert g(alpha) <= g(alpha * (1 + step)) + 1e-12
            assert g(alpha) <= g(alpha * (1 - step)) + 1e-12
        assert float(xi) == pytest.approx(np.max(a / (b + alpha)), rel=1e-12)


def test_apex_solve_respects_mask_and_regularization():
    a = jnp.array([0.1, 0.2, 5.0])
    b = jnp.array([0.0, 1.0, 0.5])
    masked, _ = solve_cone_apex(a, b, 0.05, mask=jnp.array([True, True, False]))
    alone, _ = solve_cone_apex(a[:2], b[:2], 0.05)
    assert float(masked) == pytest.approx(float(alone), rel=1e-6)
    # A larger λ pulls the apex toward p0.
    far, _ = solve_cone_apex(a[:2], b[:2], 0.01)
    near, _ = solve_cone_apex(a[:2], b[:2], 0.5)
    assert float(near) < float(alone) < float(far)
    # One point, a/α + λα: the minimiser is √(a/λ).
    single, xi = solve_cone_apex(jnp.array([0.2]), jnp.array([0.0]), 0.05)
    assert float(single) == pytest.approx(2.0, rel=1e-5)
    assert float(xi) == pytest.approx(0.1, rel=1e-5)


# --- world frame ----------------------------------------------------------------------------------


def test_to_gaze_rays_matches_hand_computation():
    cal = ConeCalibration(
        eye_center=jnp.array([-0.08, 0.01, -0.1]),
        direction=jnp.array([1.0, 0.0, 0.0]),
        bandwidth=jnp.array(0.03),
        alpha=jnp.array(0.5),
        xi=jnp.array(0.1),
        inliers=jnp.ones(5, bool),
        result=RESULTS.successful,
    )
    # Frame 0: identity at C = (1, 2, 3). Frame 1: yaw 90° (x → y, y → −x) at C = (0, 0, 1.7).
    R = jnp.stack([jnp.eye(3), jnp.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])])
    C = jnp.array([[1.0, 2.0, 3.0], [0.0, 0.0, 1.7]])
    rays = cal.to_gaze_rays(R, C)
    assert rays.batch_shape == (2,) and rays.num_rays == 1
    np.testing.assert_allclose(rays.origins[:, 0], [[0.92, 2.01, 2.9], [-0.01, -0.08, 1.6]], atol=1e-6)
    np.testing.assert_allclose(rays.directions[:, 0], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(rays.bandwidth, 0.03, rtol=1e-6)
    single = cal.to_gaze_rays(R[1], C[1])
    assert single.origins.shape == (1, 3)
    with pytest.raises(ValueError, match="camera_centers"):
        cal.to_gaze_rays(R, C[:1])
    with pytest.raises(ValueError, match="failed"):
        cal._replace(result=RESULTS.degenerate).to_gaze_rays(R, C)


def test_calibration_round_trip_through_world_frame(one_wearer):
    """Points of regard made in the world, mapped to the camera, give back the world gaze rays."""
    y, p, v, _ = one_wearer
    R = axis_angle_to_rotation_matrix(jnp.array([0.1, -0.2, 1.0]))
    C = jnp.array([2.0, -1.0, 1.6])
    world = jnp.asarray(y) @ R.T + C
    back = points_in_camera_frame(jnp.broadcast_to(R, (M, 3, 3)), jnp.broadcast_to(C, (M, 3)), world)
    np.testing.assert_allclose(back, y, atol=1e-5)
    cal = calibrate_cone(back, key=jax.random.PRNGKey(2))
    rays = cal.to_gaze_rays(R, C)
    assert float(angle_between(rays.directions[0], R @ v)) < math.radians(2.0)


# --- validation -----------------------------------------------------------------------------------


def test_rejects_too_few_points():
    with pytest.raises(ValueError, match="at least 3 points"):
        calibrate_cone(np.array([[1.0, 0.0, 0.0], [2.0, 0.1, 0.0]]), key=jax.random.PRNGKey(0))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_rejects_nonfinite_points(one_wearer, bad):
    y = one_wearer[0].copy()
    y[7, 1] = bad
    with pytest.raises(ValueError, match="point 7 is not finite"):
        calibrate_cone(y, key=jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="not finite"):
        calibrate_cone(y, key=jax.random.PRNGKey(0), throw=False)


@pytest.mark.parametrize("shape", [(10,), (10, 2), (2, 10, 3), (10, 4)])
def test_rejects_wrong_shape(shape):
    with pytest.raises(ValueError, match=r"shape \(M, 3\)"):
        calibrate_cone(np.ones(shape), key=jax.random.PRNGKey(0))


def test_rejects_bad_parameters(one_wearer):
    y = one_wearer[0]
    with pytest.raises(ValueError, match="regularization"):
        calibrate_cone(y, key=jax.random.PRNGKey(0), regularization=0.0)
    with pytest.raises(ValueError, match="inlier_threshold"):
        calibrate_cone(y, key=jax.random.PRNGKey(0), inlier_threshold=-1.0)


@pytest.fixture(scope="module")
def collinear_through_origin():
    t = np.linspace(1.0, 4.0, M)
    return np.outer(t, [0.99, 0.1, -0.05]).astype(np.float32)


def test_rejects_points_collinear_through_the_camera_centre(collinear_through_origin):
    with pytest.raises(ValueError, match="collinear through the camera centre"):
        calibrate_cone(collinear_through_origin, key=jax.random.PRNGKey(0), throw=True)


def test_rejects_points_behind_the_camera(one_wearer):
    y = one_wearer[0] * np.array([-1.0, 1.0, 1.0])  # mirrored: +x is backward
    with pytest.raises(ValueError, match="behind the camera"):
        calibrate_cone(y, key=jax.random.PRNGKey(0), throw=True)


def test_throw_false_returns_failure_codes(one_wearer, collinear_through_origin):
    y = one_wearer[0]
    key = jax.random.PRNGKey(0)
    cases = {  # RESULTS items are not hashable: keyed by name
        "collinear_through_camera": collinear_through_origin,
        "behind_camera": y * np.array([-1.0, 1.0, 1.0]),
        "too_few_inliers": np.asarray(
            jax.random.uniform(key, (M, 3), minval=jnp.array([1.0, -2.0, -2.0]), maxval=jnp.array([4.0, 2.0, 2.0]))
        ),
    }
    for code, pts in cases.items():
        cal = calibrate_cone(pts, key=key, throw=False)
        assert bool(cal.result == getattr(RESULTS, code)), (code, cal.message)
        assert not bool(succeeded(cal))
        for field in (cal.eye_center, cal.direction, cal.bandwidth, cal.alpha, cal.xi):
            assert np.all(np.isfinite(np.asarray(field)))
        np.testing.assert_array_equal(cal.direction, [1.0, 0.0, 0.0])
        assert float(cal.bandwidth) > 0
    with pytest.raises(ValueError, match="too few RANSAC inliers"):
        calibrate_cone(cases["too_few_inliers"], key=key, throw=True)


def test_exactly_collinear_points_off_the_origin_are_degenerate():
    t = np.linspace(1.0, 4.0, M)
    y = (np.outer(t, [0.99, 0.1, -0.05]) + [0.0, 0.1, -0.12]).astype(np.float32)
    cal = calibrate_cone(y, key=jax.random.PRNGKey(0), throw=False)
    assert bool(cal.result == RESULTS.degenerate)
    with pytest.raises(ValueError, match="lie exactly on one line"):
        calibrate_cone(y, key=jax.random.PRNGKey(0), throw=True)


def test_works_under_vmap_and_reports_codes(wearers):
    """Traced input cannot raise; a NaN wearer is reported by its code and the others are unaffected."""
    keys, y, *_ = wearers
    cal = calibrate_many(y.at[3, 5, 0].set(jnp.nan), keys)
    assert np.asarray(cal.result == RESULTS.nonfinite)[3]
    assert np.all(np.delete(np.asarray(cal.result == RESULTS.successful), 3))
    assert np.all(np.isfinite(np.asarray(cal.eye_center)))


def test_an_eye_centre_metres_from_the_camera_is_implausible(one_wearer):
    """Positions in millimetres put the eye centre ~100 m away: ``implausible``, with the estimate kept."""
    y = one_wearer[0]
    key = jax.random.PRNGKey(0)
    good = calibrate_cone(y, key=key)
    assert bool(succeeded(good)) and float(good.eye_distance) < MAX_APEX_DISTANCE
    far = calibrate_cone(1000.0 * y, key=key, throw=False)
    assert bool(far.result == RESULTS.implausible) and not bool(succeeded(far))
    assert float(far.eye_distance) > 100.0  # the estimate is kept (λ of eq. 2 is not scale-free: not 1000×)
    with pytest.raises(ValueError, match="physically implausible"):
        calibrate_cone(1000.0 * y, key=key, throw=True)


def test_a_failed_fit_raises_with_what_throw_false_returns(one_wearer):
    """``calibrate_cone`` defaults to ``throw=False``, like every fit; ``throw=True`` raises a FitError whose
    ``fit`` is the calibration ``throw=False`` returns (nothing computed is thrown away)."""
    y = 1000.0 * one_wearer[0]  # millimetres: an implausible eye centre
    key = jax.random.PRNGKey(0)
    quiet = calibrate_cone(y, key=key)
    assert bool(quiet.result == RESULTS.implausible)
    with pytest.raises(FitError, match="physically implausible") as raised:
        calibrate_cone(y, key=key, throw=True)
    assert isinstance(raised.value.fit, ConeCalibration) and bool(raised.value.result == RESULTS.implausible)
    for got, want in zip(raised.value.fit, quiet):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
