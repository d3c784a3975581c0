"""Simulated calibration sessions (jaxgaze.simulate.calibration, Park et al. 2012 Sec. 3.2, 4).

Every single session here uses ``num_frames = T`` and ``fps = 10`` so that all of
them share one compiled program (noise levels and mountings are traced).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.geometry import orthonormal_basis, perspective_distance
from jaxgaze.simulate.calibration import (
    CalibrationSession,
    Mounting,
    random_mounting,
    simulate_calibration_session,
    simulate_wearers,
)

T = 300
NO_POSE_NOISE = dict(pose_noise_rotation=0.0, pose_noise_position=0.0)


def _offsets(eye, direction, points):
    """Perspective distances ``d`` (T, 3) of the points from the ray, and in-front flags."""
    d, in_front = jax.vmap(perspective_distance, in_axes=(None, None, 0))(eye, direction, points)
    return np.asarray(d), np.asarray(in_front)


def _both(session):
    """``(eye, direction, y, outlier)`` of wearers A and B."""
    return [
        (session.eye_center_a, session.direction_a, session.points_of_regard_a(), session.outlier_a),
        (session.eye_center_b, session.direction_b, session.points_of_regard_b(), session.outlier_b),
    ]


@pytest.fixture(scope="module")
def noiseless():
    return simulate_calibration_session(jax.random.key(0), T, eye_in_head=0.0, **NO_POSE_NOISE)


@pytest.fixture(scope="module")
def default():
    return simulate_calibration_session(jax.random.key(1), T)


def test_deterministic_for_a_key():
    a = simulate_calibration_session(jax.random.key(7), T)
    b = simulate_calibration_session(jax.random.key(7), T)
    c = simulate_calibration_session(jax.random.key(8), T)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert not np.allclose(a.centers_a, c.centers_a)
    assert not np.allclose(a.eye_center_a, c.eye_center_a)


def test_shapes_and_types(default):
    s = default
    assert isinstance(s, CalibrationSession)
    for name in ("R_camera_from_world_a", "R_camera_from_world_b", "true_R_camera_from_world_a"):
        assert getattr(s, name).shape == (T, 3, 3)
    for name in ("centers_a", "centers_b", "true_centers_a", "true_centers_b"):
        assert getattr(s, name).shape == (T, 3)
    for name in ("eye_center_a", "direction_a", "eye_center_b", "direction_b"):
        assert getattr(s, name).shape == (3,)
    assert s.outlier_a.shape == s.outlier_b.shape == (T,)
    assert s.outlier_a.dtype == jnp.bool_
    np.testing.assert_array_equal(s.frame_ids, np.arange(T))
    assert s.points_of_regard_a().shape == s.points_of_regard_b().shape == (T, 3)
    assert s.num_frames == T
    assert s.eye_in_head == 0.03 and s.fps == 10.0
    assert not bool(jnp.any(s.outlier_a)) and not bool(jnp.any(s.outlier_b))
    for x in s:
        if isinstance(x, jax.Array):
            assert bool(jnp.all(jnp.isfinite(x)))


def test_points_of_regard_formula(default):
    s = default
    y = np.einsum("tij,tj->ti", s.R_camera_from_world_a, s.centers_b - s.centers_a)
    np.testing.assert_allclose(s.points_of_regard_a(), y, atol=1e-6)
    y = np.einsum("tij,tj->ti", s.R_camera_from_world_b, s.centers_a - s.centers_b)
    np.testing.assert_allclose(s.points_of_regard_b(), y, atol=1e-6)


def test_mounting_is_plausible(default):
    for eye, direction in ((default.eye_center_a, default.direction_a), (default.eye_center_b, default.direction_b)):
        eye, direction = np.asarray(eye), np.asarray(direction)
        assert -0.10 <= eye[2] <= -0.05 and -0.04 <= eye[0] <= -0.01 and abs(eye[1]) <= 0.02
        assert abs(np.linalg.norm(direction) - 1) < 1e-6
        assert 0 < math.degrees(math.acos(min(1.0, direction[0]))) < 7.5


def test_noiseless_points_lie_on_the_primary_ray(noiseless):
    for eye, direction, y, _ in _both(noiseless):
        d, in_front = _offsets(eye, direction, y)
        assert in_front.all()
        assert np.abs(d).max() < 1e-5
        depth = np.asarray(y - eye) @ np.asarray(direction)
        assert depth.min() > 0.7  # the partner is about 1–4 m away


def test_eye_in_head_spread_matches_h():
    h = 0.03
    s = simulate_calibration_session(jax.random.key(2), T, eye_in_head=h, **NO_POSE_NOISE)
    per_axis = []
    for eye, direction, y, _ in _both(s):
        d, in_front = _offsets(eye, direction, y)
        assert in_front.all()
        u1, u2 = orthonormal_basis(direction)
        per_axis.append(np.stack([d @ np.asarray(u1), d @ np.asarray(u2)], axis=-1))
        np.testing.assert_allclose(d @ np.asarray(direction), 0.0, atol=1e-6)  # d ⊥ v
    per_axis = np.concatenate(per_axis)  # (2T, 2)
    assert abs(per_axis.std() / h - 1) < 0.15
    assert np.all(np.abs(per_axis.mean(axis=0)) < 4 * h / math.sqrt(len(per_axis)))
    # E‖d‖² = 2h² (docs/conventions.md, "Bandwidth h").
    rms = math.sqrt(np.mean(np.sum(per_axis**2, axis=-1)) / 2)
    assert abs(rms / h - 1) < 0.15


def test_motion_back_and_forth_and_side_to_side():
    for seed in range(3):
        s = simulate_calibration_session(jax.random.key(10 + seed), T, **NO_POSE_NOISE)
        a, b = np.asarray(s.true_centers_a), np.asarray(s.true_centers_b)
        pair = (b - a).mean(axis=0)
        axis = np.array([pair[0], pair[1], 0.0]) / np.hypot(pair[0], pair[1])
        across = np.array([-axis[1], axis[0], 0.0])
        for c in (a, b):
            v = np.diff(c, axis=0)
            for direction in (axis, across):
                speed = v @ direction
                sign_changes = np.count_nonzero(np.diff(np.sign(speed)) != 0)
                assert sign_changes >= 6, sign_changes  # ≥ 3 cycles (Park et al. Sec. 4)
        distance = np.linalg.norm(b - a, axis=-1)
        assert distance.min() >= 0.8 and distance.max() <= 4.2  # about 1–4 m apart
        assert 1.55 <= a[:, 2].min() and a[:, 2].max() <= 1.85
        step = np.linalg.norm(np.diff(a, axis=0), axis=-1) * s.fps
        assert step.max() < 2.0  # walking speed, m/s: smooth paths


def test_cameras_face_each_other_and_stay_upright(default):
    s = default
    for R, c, other in (
        (s.true_R_camera_from_world_a, s.true_centers_a, s.true_centers_b),
        (s.true_R_camera_from_world_b, s.true_centers_b, s.true_centers_a),
    ):
        R = np.asarray(R)
        w = np.array(other - c)
        w /= np.linalg.norm(w, axis=-1, keepdims=True)
        forward, up = R[:, 0, :], R[:, 2, :]  # camera axes in world = rows of R_camera_from_world
        assert np.einsum("ti,ti->t", forward, w).min() > math.cos(math.radians(30))
        assert up[:, 2].min() > math.cos(math.radians(25))


@pytest.mark.parametrize("which", ["reported", "true"])
def test_rotations_orthonormal(default, which):
    prefix = "" if which == "reported" else "true_"
    for R in (getattr(default, prefix + "R_camera_from_world_a"), getattr(default, prefix + "R_camera_from_world_b")):
        R = np.asarray(R, np.float64)
        np.testing.assert_allclose(np.einsum("tji,tjk->tik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-5)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-5)


def test_pose_noise_levels():
    rot, pos = 0.02, 0.05
    s = simulate_calibration_session(jax.random.key(3), T, pose_noise_rotation=rot, pose_noise_position=pos)
    dc = np.asarray(s.centers_a - s.true_centers_a)
    assert abs(dc.std() / pos - 1) < 0.15
    dR = np.einsum("tij,tkj->tik", np.asarray(s.R_camera_from_world_a), np.asarray(s.true_R_camera_from_world_a))
    angle = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1))
    # ‖ω‖² has mean 3σ² for ω ~ N(0, σ² I₃).
    assert abs(math.sqrt(np.mean(angle**2) / 3) / rot - 1) < 0.15


def test_outliers():
    s = simulate_calibration_session(jax.random.key(4), T, eye_in_head=0.0, outlier_fraction=0.2, **NO_POSE_NOISE)
    for eye, direction, y, outlier in _both(s):
        outlier = np.asarray(outlier)
        assert outlier.sum() == round(0.2 * T)
        d, in_front = _offsets(eye, direction, y)
        assert in_front.all()
        norm = np.linalg.norm(d, axis=-1)
        angle = np.degrees(np.arctan(norm))
        assert angle[outlier].min() > 9.9 and angle[outlier].max() < 30.1
        assert norm[~outlier].max() < 1e-5
    assert not np.array_equal(np.asarray(s.outlier_a), np.asarray(s.outlier_b))


def test_given_mounting():
    m_a = Mounting(jnp.array([-0.02, 0.01, -0.07]), jnp.array([1.0, 0.05, -0.08]))
    m_b = random_mounting(jax.random.key(99))
    key = jax.random.key(5)
    s = simulate_calibration_session(key, T, mounting=(m_a, m_b), eye_in_head=0.0, **NO_POSE_NOISE)
    np.testing.assert_allclose(s.eye_center_a, m_a.eye_center_in_camera, atol=1e-7)
    np.testing.assert_allclose(s.direction_a, m_a.direction_in_camera / jnp.linalg.norm(m_a.direction_in_camera))
    np.testing.assert_allclose(s.eye_center_b, m_b.eye_center_in_camera, atol=1e-7)
    for eye, direction, y, _ in _both(s):
        d, in_front = _offsets(eye, direction, y)
        assert in_front.all() and np.abs(d).max() < 1e-5
    # The motion does not depend on whether the mounting is drawn or given.
    drawn = simulate_calibration_session(key, T, eye_in_head=0.0, **NO_POSE_NOISE)
    np.testing.assert_array_equal(s.true_centers_a, drawn.true_centers_a)
    # One Mounting with (3,) fields is shared by both wearers.
    shared = simulate_calibration_session(key, T, mounting=m_a)
    np.testing.assert_allclose(shared.eye_center_b, m_a.eye_center_in_camera, atol=1e-7)


def test_simulate_wearers_batch():
    n = 50
    key = jax.random.key(6)
    batch = simulate_wearers(key, n, T, outlier_fraction=0.1)
    assert batch.R_camera_from_world_a.shape == (n, T, 3, 3)
    assert batch.centers_b.shape == (n, T, 3)
    assert batch.eye_center_a.shape == batch.direction_b.shape == (n, 3)
    assert batch.frame_ids.shape == (n, T)
    assert batch.points_of_regard_a().shape == (n, T, 3)
    assert batch.outlier_a.shape == (n, T)
    # Wearers differ from one another.
    assert np.unique(np.round(np.asarray(batch.eye_center_a), 6), axis=0).shape[0] == n
    # Session i is the single session simulated from split(key, n)[i].
    i = 3
    single = simulate_calibration_session(jax.random.split(key, n)[i], T, outlier_fraction=0.1)
    one = batch.take(i)
    assert one.eye_in_head == single.eye_in_head
    np.testing.assert_allclose(one.points_of_regard_a(), single.points_of_regard_a(), atol=1e-4)
    np.testing.assert_array_equal(one.outlier_b, single.outlier_b)
    np.testing.assert_allclose(one.eye_center_b, single.eye_center_b, atol=1e-7)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(num_frames=1),
        dict(num_frames=10.0),
        dict(eye_in_head=-0.1),
        dict(pose_noise_rotation=float("nan")),
        dict(outlier_fraction=1.5),
        dict(fps=0.0),
        dict(mounting=Mounting(jnp.zeros(4), jnp.array([1.0, 0.0, 0.0]))),
        dict(mounting=Mounting(jnp.zeros(3), jnp.zeros(3))),
        dict(mounting="forehead"),
    ],
)
def test_invalid_arguments(kwargs):
    with pytest.raises(ValueError):
        simulate_calibration_session(jax.random.key(0), **kwargs)


def test_invalid_key_and_count():
    with pytest.raises(ValueError, match="key"):
        simulate_calibration_session(0)
    with pytest.raises(ValueError, match="num_wearers"):
        simulate_wearers(jax.random.key(0), 0)
