"""Tests of jaxgaze.geometry: every conversion, against known values, a reference
implementation (SciPy / NumPy) or a property; key tests also in float64."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxgaze import geometry as g

SETTINGS = settings(max_examples=40, deadline=None)

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)
quat = st.tuples(finite, finite, finite, finite).map(np.array).filter(lambda q: np.linalg.norm(q) > 0.1)


def _unit_np(v):
    return v / np.linalg.norm(v)


@st.composite
def unit_dirs_incl_poles(draw):
    """Unit directions, half of them within ~1e-3 of ±z (the Duff branch switch)."""
    if draw(st.booleans()):
        eps = draw(st.tuples(st.floats(-1e-3, 1e-3), st.floats(-1e-3, 1e-3)))
        sign = draw(st.sampled_from([-1.0, 1.0]))
        return _unit_np(np.array([eps[0], eps[1], sign]))
    return _unit_np(draw(vec3))


# jitted once per shape/dtype: keeps hypothesis examples fast
yp_to_dir = jax.jit(g.yaw_pitch_to_direction)
dir_to_yp = jax.jit(g.direction_to_yaw_pitch)
q_to_R = jax.jit(g.quaternion_to_rotation_matrix)
R_to_q = jax.jit(g.rotation_matrix_to_quaternion)
aa_to_R = jax.jit(g.axis_angle_to_rotation_matrix)
basis = jax.jit(g.orthonormal_basis)
angle = jax.jit(g.angle_between)
persp = jax.jit(g.perspective_distance)
unit = jax.jit(g.unit)
depth = jax.jit(g.ray_depth)
vmap_R_to_q = jax.jit(jax.vmap(g.rotation_matrix_to_quaternion))
vmap_basis = jax.jit(jax.vmap(g.orthonormal_basis))
jac_unit = jax.jit(jax.jacobian(g.unit))
jac_aa = jax.jit(jax.jacobian(g.axis_angle_to_rotation_matrix))
grad_angle = jax.jit(jax.grad(g.angle_between))
jac_persp = jax.jit(jax.jacobian(lambda p, v, x: g.perspective_distance(p, v, x)[0], argnums=2))


# ---------------------------------------------------------------- unit


def test_unit_normalises_and_keeps_zero():
    v = jnp.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [0.0, -2.0, 0.0]])
    u = unit(v)
    np.testing.assert_allclose(u, [[0.6, 0.8, 0.0], [0.0, 0.0, 0.0], [0.0, -1.0, 0.0]], atol=1e-7)
    assert not np.any(np.isnan(u))


def test_unit_gradient_finite_at_zero():
    jac = jac_unit(jnp.zeros(3))
    assert np.all(np.isfinite(jac))
    # away from zero the Jacobian is (I − u uᵀ)/‖v‖
    v = jnp.array([1.0, 2.0, 2.0])
    u = np.asarray(v) / 3.0
    np.testing.assert_allclose(jac_unit(v), (np.eye(3) - np.outer(u, u)) / 3.0, atol=1e-6)


# ---------------------------------------------------------------- yaw / pitch


@pytest.mark.parametrize(
    "yaw, pitch, expected",
    [
        (0.0, 0.0, [1.0, 0.0, 0.0]),
        (np.pi / 2, 0.0, [0.0, 1.0, 0.0]),  # yaw left → +y
        (-np.pi / 2, 0.0, [0.0, -1.0, 0.0]),
        (np.pi, 0.0, [-1.0, 0.0, 0.0]),
        (0.0, np.pi / 2, [0.0, 0.0, 1.0]),  # pitch up → +z
        (0.0, -np.pi / 2, [0.0, 0.0, -1.0]),
        (np.pi / 4, 0.0, [np.sqrt(0.5), np.sqrt(0.5), 0.0]),
    ],
)
def test_yaw_pitch_known_values(yaw, pitch, expected):
    np.testing.assert_allclose(yp_to_dir(yaw, pitch), expected, atol=1e-6)


def test_yaw_pitch_inverse_known_values():
    yaw, pitch = dir_to_yp(jnp.array([[0.0, 1.0, 0.0], [0.0, 0.0, 2.0], [-1.0, 0.0, 0.0], [1.0, 0.0, -1.0]]))
    np.testing.assert_allclose(yaw, [np.pi / 2, 0.0, np.pi, 0.0], atol=1e-6)  # yaw ∈ (−π, π]: −x is +π
    np.testing.assert_allclose(pitch, [0.0, np.pi / 2, 0.0, -np.pi / 4], atol=1e-6)


def test_yaw_pitch_matches_rotations():
    """d = R_z(yaw) R_y(−pitch) e_x, as docs/conventions.md states."""
    yaw, pitch = 0.7, -0.3
    Rz = aa_to_R(jnp.array([0.0, 0.0, yaw]))
    Ry = aa_to_R(jnp.array([0.0, -pitch, 0.0]))
    np.testing.assert_allclose(Rz @ Ry @ jnp.array([1.0, 0.0, 0.0]), yp_to_dir(yaw, pitch), atol=1e-6)


def test_yaw_pitch_broadcasts():
    d = yp_to_dir(jnp.linspace(-1, 1, 4), 0.2)
    assert d.shape == (4, 3)
    np.testing.assert_allclose(d[:, 2], np.sin(0.2), rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, rtol=1e-6)


@SETTINGS
@given(st.floats(-np.pi + 1e-3, np.pi), st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3), st.floats(0.1, 10.0))
def test_yaw_pitch_round_trip(yaw, pitch, scale):
    d = yp_to_dir(jnp.float32(yaw), jnp.float32(pitch))
    np.testing.assert_allclose(np.linalg.norm(d), 1.0, rtol=1e-6)
    y2, p2 = dir_to_yp(scale * d)  # the inverse does not need a unit direction
    np.testing.assert_allclose(p2, pitch, atol=2e-6)
    wrapped = (float(y2) - yaw + np.pi) % (2 * np.pi) - np.pi
    assert abs(wrapped) < 2e-6 / max(np.cos(pitch), 1e-3)
    np.testing.assert_allclose(yp_to_dir(y2, p2), d, atol=2e-6)


@SETTINGS
@given(unit_dirs_incl_poles())
def test_yaw_pitch_round_trip_from_direction(v):
    d = yp_to_dir(*dir_to_yp(jnp.asarray(v, jnp.float32)))
    np.testing.assert_allclose(d, v, atol=2e-6)


def test_yaw_pitch_round_trip_x64(x64):
    rng = np.random.default_rng(0)
    yaw = rng.uniform(-np.pi + 1e-6, np.pi, 100)
    pitch = rng.uniform(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6, 100)
    d = yp_to_dir(jnp.asarray(yaw), jnp.asarray(pitch))
    assert d.dtype == jnp.float64
    y2, p2 = dir_to_yp(d)
    np.testing.assert_allclose(y2, yaw, atol=1e-12)
    np.testing.assert_allclose(p2, pitch, atol=1e-12)


def test_float32_arctan2_matches_float64_reference():
    """The float32 ``atan2`` written out (``geometry._arctan2``, a polynomial: XLA's does not vectorise) against NumPy's
    float64 one, as accurate as XLA's float32 one, on random pairs and on every branch boundary."""
    rng = np.random.default_rng(0)
    y, x = rng.normal(size=(2, 100_000)) * 10.0 ** rng.uniform(-6, 6, size=(2, 100_000))
    t = np.tan(np.pi / 8)
    edges = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0], [t, 1.0], [-t, -1.0], [1.0, t], [1.0, 1.0],
                      [-1.0, -1.0], [1e-30, -1.0], [-1e-30, -1.0], [3.0, -1e-30], [0.0, 0.0]])
    y32, x32 = (np.concatenate([a, edges[:, i]]).astype(np.float32) for i, a in enumerate((y, x)))
    ours = np.asarray(jax.jit(g._arctan2)(y32, x32))
    assert ours.dtype == np.float32
    truth = np.arctan2(y32.astype(np.float64), x32.astype(np.float64))
    xla = np.asarray(jnp.arctan2(y32, x32), np.float64)
    assert np.max(np.abs(ours - truth)) < 3.5e-7  # XLA's own float32 error is 2.5e-7
    assert np.max(np.abs(xla - truth)) < 3.5e-7
    rounded = np.float32(np.arctan2(edges[:, 0], edges[:, 1]))  # where the branches meet: within an ulp …
    assert np.all(np.abs(ours[-13:] - rounded) <= np.spacing(np.abs(rounded)))
    on_axes = [0, 1, 2, 3, 7, 8, 12]  # … and on the axes, the diagonals and at 0 exact (0, ±π/2, π, π/4, −3π/4)
    np.testing.assert_array_equal(ours[-13:][on_axes], rounded[on_axes])
    assert np.all(np.abs(ours) <= np.float32(np.pi))


def test_float32_arctan2_derivative_is_the_exact_one():
    rng = np.random.default_rng(1)
    y, x = rng.normal(size=(2, 50)).astype(np.float32)
    dy, dx = jax.vmap(jax.grad(g._arctan2, argnums=(0, 1)))(y, x)
    r2 = x.astype(np.float64) ** 2 + y.astype(np.float64) ** 2
    np.testing.assert_allclose(dy, x / r2, rtol=1e-6)
    np.testing.assert_allclose(dx, -y / r2, rtol=1e-6)


def test_arctan2_in_float64_is_xlas(x64):
    y, x = jnp.asarray(np.random.default_rng(2).normal(size=(2, 100)))
    assert g._arctan2(y, x).dtype == jnp.float64
    np.testing.assert_array_equal(g._arctan2(y, x), jnp.arctan2(y, x))


# ---------------------------------------------------------------- degrees


def test_deg_rad_known_values():
    np.testing.assert_allclose(g.deg_to_rad(jnp.array([0.0, 90.0, 180.0, -45.0])), [0, np.pi / 2, np.pi, -np.pi / 4], rtol=1e-6)
    np.testing.assert_allclose(g.rad_to_deg(jnp.array([np.pi, np.pi / 6])), [180.0, 30.0], rtol=1e-6)


@SETTINGS
@given(st.floats(-720.0, 720.0))
def test_deg_rad_round_trip(angle_deg):
    np.testing.assert_allclose(g.rad_to_deg(g.deg_to_rad(jnp.float32(angle_deg))), angle_deg, atol=1e-4)


# ---------------------------------------------------------------- quaternions


def test_quaternion_known_values():
    np.testing.assert_allclose(q_to_R(jnp.array([1.0, 0, 0, 0])), np.eye(3), atol=1e-7)
    # 90° about +z: (cos 45°, 0, 0, sin 45°) maps +x → +y
    c = np.sqrt(0.5)
    R = q_to_R(jnp.array([c, 0, 0, c]))
    np.testing.assert_allclose(R @ jnp.array([1.0, 0, 0]), [0, 1, 0], atol=1e-6)
    # not unit: normalised first
    np.testing.assert_allclose(q_to_R(jnp.array([3 * c, 0, 0, 3 * c])), R, atol=1e-6)


def _assert_same_rotation_quaternion(q1, q2, atol):
    q1, q2 = _unit_np(np.asarray(q1, float)), _unit_np(np.asarray(q2, float))
    s = 1.0 if np.dot(q1, q2) >= 0 else -1.0  # q and −q are the same rotation
    np.testing.assert_allclose(q1, s * q2, atol=atol)


@SETTINGS
@given(quat)
def test_quaternion_matrix_round_trip(q):
    R = q_to_R(jnp.asarray(q, jnp.float32))
    # orthonormal, det +1
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(np.asarray(R, float)), 1.0, atol=1e-5)
    # reference: SciPy (scalar-first)
    np.testing.assert_allclose(R, Rotation.from_quat(q, scalar_first=True).as_matrix(), atol=1e-5)
    q2 = R_to_q(R)
    assert q2[0] >= 0.0
    np.testing.assert_allclose(np.linalg.norm(q2), 1.0, atol=1e-6)
    _assert_same_rotation_quaternion(q2, q, atol=1e-4)
    np.testing.assert_allclose(q_to_R(q2), R, atol=1e-5)


@pytest.mark.parametrize("axis", [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, -1.0, 0.5]])
def test_quaternion_half_turns(axis):
    """θ = π has w = 0: exercises the x/y/z pivots of Shepperd's method."""
    a = _unit_np(np.array(axis))
    R = Rotation.from_rotvec(np.pi * a).as_matrix()
    q = R_to_q(jnp.asarray(R, jnp.float32))
    _assert_same_rotation_quaternion(q, np.r_[0.0, a], atol=1e-6)


def test_quaternion_vmap():
    rots = Rotation.random(16, random_state=1)
    q = vmap_R_to_q(jnp.asarray(rots.as_matrix(), jnp.float32))
    for qi, ref in zip(np.asarray(q), rots.as_quat(scalar_first=True)):
        _assert_same_rotation_quaternion(qi, ref, atol=1e-5)
    np.testing.assert_allclose(q_to_R(q), rots.as_matrix(), atol=1e-5)


def test_quaternion_round_trip_x64(x64):
    rots = Rotation.random(200, random_state=2)
    q_ref = rots.as_quat(scalar_first=True)
    R = q_to_R(jnp.asarray(q_ref))
    assert R.dtype == jnp.float64
    np.testing.assert_allclose(R, rots.as_matrix(), atol=1e-13)
    q = vmap_R_to_q(R)
    for qi, ref in zip(np.asarray(q), q_ref):
        _assert_same_rotation_quaternion(qi, ref, atol=1e-13)


# ---------------------------------------------------------------- axis-angle


@pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-9, 1e-7, 1e-4, 1e-2, 0.5, 2.0, np.pi, 5.0])
def test_axis_angle_against_scipy(theta):
    axis = _unit_np(np.array([0.3, -0.5, 0.8]))
    rv = theta * axis
    R = aa_to_R(jnp.asarray(rv, jnp.float32))
    ref = Rotation.from_rotvec(rv).as_matrix()
    np.testing.assert_allclose(R, ref, atol=2e-6)
    # the tiny angles must still rotate: R − I ≈ [rv]ₓ
    skew = np.array([[0, -rv[2], rv[1]], [rv[2], 0, -rv[0]], [-rv[1], rv[0], 0]])
    if 0 < theta <= 1e-4:
        np.testing.assert_allclose(np.asarray(R) - np.eye(3), skew, atol=1e-7 + 1e-2 * theta)


@SETTINGS
@given(vec3, st.floats(0.0, 2 * np.pi))
def test_axis_angle_property(axis, theta):
    rv = theta * _unit_np(axis)
    R = aa_to_R(jnp.asarray(rv, jnp.float32))
    np.testing.assert_allclose(R, Rotation.from_rotvec(rv).as_matrix(), atol=5e-6)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(np.asarray(R, float)), 1.0, atol=1e-5)
    np.testing.assert_allclose(R @ jnp.asarray(rv, jnp.float32), rv, atol=1e-5)  # the axis is fixed


def test_axis_angle_batched():
    rv = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi / 2], [1e-9, 0.0, 0.0], [0.4, 0.1, -0.2]])
    R = aa_to_R(jnp.asarray(rv, jnp.float32))
    assert R.shape == (4, 3, 3)
    np.testing.assert_allclose(R, Rotation.from_rotvec(rv).as_matrix(), atol=1e-6)


def test_axis_angle_x64_tiny_angles(x64):
    axis = _unit_np(np.array([-0.2, 0.9, 0.4]))
    for theta in [0.0, 1e-15, 1e-10, 1e-8, 1.0000001e-8, 1e-6, 1e-3, 1.0, 3.0]:
        rv = theta * axis
        R = aa_to_R(jnp.asarray(rv))
        assert R.dtype == jnp.float64
        np.testing.assert_allclose(R, Rotation.from_rotvec(rv).as_matrix(), atol=1e-15, rtol=0)


def test_axis_angle_gradient_finite_at_zero():
    jac = jac_aa(jnp.zeros(3))
    assert np.all(np.isfinite(jac))
    # dR/drv_k at 0 is the generator [e_k]ₓ
    np.testing.assert_allclose(jac[..., 2], [[0, -1, 0], [1, 0, 0], [0, 0, 0]], atol=1e-6)
    np.testing.assert_allclose(jac[..., 0], [[0, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-6)
    # and near zero it is continuous with the value at zero
    jac_small = jac_aa(jnp.array([1e-6, -2e-6, 1e-6]))
    np.testing.assert_allclose(jac_small, jac, atol=1e-5)


# ---------------------------------------------------------------- orthonormal basis


def _check_basis(v, u1, u2, atol):
    M = np.stack([v, np.asarray(u1), np.asarray(u2)])  # rows v, u1, u2
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=atol)
    np.testing.assert_allclose(np.linalg.det(M.astype(float)), 1.0, atol=atol)  # right-handed
    np.testing.assert_allclose(np.cross(v, u1), u2, atol=atol)


@SETTINGS
@given(unit_dirs_incl_poles())
def test_orthonormal_basis_property(v):
    u1, u2 = basis(jnp.asarray(v, jnp.float32))
    _check_basis(v, u1, u2, atol=2e-6)


@pytest.mark.parametrize("v", [[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0], [0, 0.6, -0.8]])
def test_orthonormal_basis_special_directions(v):
    v = np.array(v)
    u1, u2 = basis(jnp.asarray(v, jnp.float32))
    _check_basis(v, u1, u2, atol=1e-6)


def test_orthonormal_basis_vmap_x64(x64):
    rng = np.random.default_rng(3)
    v = rng.normal(size=(200, 3))
    v[:50, :2] *= 1e-9  # near the poles
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    u1, u2 = vmap_basis(jnp.asarray(v))
    assert u1.dtype == jnp.float64
    for i in range(len(v)):
        _check_basis(v[i], u1[i], u2[i], atol=1e-14)


# ---------------------------------------------------------------- angle between


@SETTINGS
@given(vec3, vec3)
def test_angle_between_against_arccos(a, b):
    ref = np.arccos(np.clip(np.dot(_unit_np(a), _unit_np(b)), -1.0, 1.0))
    got = float(angle(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)))
    assert 0.0 <= got <= float(np.float32(np.pi))  # float32 π rounds up to 3.1415927 > np.pi
    if 0.05 < ref < np.pi - 0.05:  # where arccos (float64) is a good reference
        assert abs(got - ref) < 1e-5
    assert abs(got - float(angle(jnp.asarray(b, jnp.float32), jnp.asarray(a, jnp.float32)))) < 1e-6


@pytest.mark.parametrize("eps", [1e-7, 1e-6, 1e-5, 1e-4])
def test_angle_between_tiny_angles(eps):
    """float32 arccos(a·b) returns 0 (or ~3e-4) here; atan2 stays relatively accurate."""
    a = jnp.array([1.0, 0.0, 0.0])
    b = jnp.array([np.cos(eps), np.sin(eps), 0.0], jnp.float32)
    np.testing.assert_allclose(angle(a, b), eps, rtol=1e-5)
    np.testing.assert_allclose(angle(a, 7.0 * b), eps, rtol=1e-5)  # scale free
    near_pi = angle(a, jnp.array([-np.cos(eps), np.sin(eps), 0.0], jnp.float32))
    np.testing.assert_allclose(np.pi - float(near_pi), eps, atol=5e-7)


def test_angle_between_tiny_angles_x64(x64):
    a = jnp.array([1.0, 0.0, 0.0])
    for eps in [1e-14, 1e-10, 1e-6]:
        b = jnp.array([np.cos(eps), np.sin(eps), 0.0])
        got = angle(a, b)
        assert got.dtype == jnp.float64
        np.testing.assert_allclose(got, eps, rtol=1e-12)


def test_angle_between_gradient_finite_when_parallel():
    a = jnp.array([0.0, 1.0, 0.0])
    for b in [a, 2.0 * a, -a]:
        grad = grad_angle(a, b)
        assert np.all(np.isfinite(grad))
    # away from the edge it is the usual −(b⊥)/‖b⊥‖ for unit a
    grad = grad_angle(jnp.array([1.0, 0, 0]), jnp.array([0.0, 1.0, 0]))
    np.testing.assert_allclose(grad, [0.0, -1.0, 0.0], atol=1e-6)


# ---------------------------------------------------------------- perspective distance


def _perspective_np(p, v, x):
    """Brute force: line of sight p → x meets the unit plane Π at p + v + d."""
    v = _unit_np(v)
    w = x - p
    t = float(np.dot(v, w))
    if t <= 0:
        return None, t
    hit = w / t  # on the plane {y : vᵀ y = 1} relative to p
    return hit - v, t


def test_ray_depth():
    p, v, x = jnp.array([1.0, 2.0, 0.5]), jnp.array([0.0, 1.0, 0.0]), jnp.array([4.0, 5.0, -1.0])
    assert float(depth(p, v, x)) == pytest.approx(3.0)
    assert float(depth(p, v, jnp.array([9.0, 0.0, 9.0]))) == pytest.approx(-2.0)


def test_perspective_distance_known_value():
    p, v = jnp.zeros(3), jnp.array([1.0, 0.0, 0.0])
    d, in_front = persp(p, v, jnp.array([2.0, 0.5, -1.0]))
    np.testing.assert_allclose(d, [0.0, 0.25, -0.5], atol=1e-7)
    assert bool(in_front)


@SETTINGS
@given(vec3, vec3, vec3, st.floats(-5.0, 5.0))
def test_perspective_distance_against_brute_force(p, v, offset, depth):
    v = _unit_np(v)
    x = p + depth * v + offset
    ref, t = _perspective_np(p, v, x)
    d, in_front = persp(*(jnp.asarray(a, jnp.float32) for a in (p, v, x)))
    assert np.all(np.isfinite(d))
    if t > 1e-2:
        assert bool(in_front)
        np.testing.assert_allclose(d, ref, atol=1e-4 * (1 + np.linalg.norm(ref)) / t)
        assert abs(float(jnp.dot(d, jnp.asarray(v, jnp.float32)))) < 1e-4 * (1 + np.linalg.norm(ref))
        # ‖d‖ is tan of the angle at the eye
        ang = np.arccos(np.clip(np.dot(v, _unit_np(x - p)), -1, 1))
        if ang < 1.4:
            np.testing.assert_allclose(np.linalg.norm(d), np.tan(ang), rtol=1e-3, atol=1e-4)
    elif t < -1e-2:
        assert not bool(in_front)
        np.testing.assert_array_equal(d, 0.0)


def test_perspective_distance_x64(x64):
    rng = np.random.default_rng(4)
    for _ in range(50):
        p, v, x = rng.normal(size=(3, 3))
        v = _unit_np(v)
        ref, t = _perspective_np(p, v, x)
        d, in_front = persp(jnp.asarray(p), jnp.asarray(v), jnp.asarray(x))
        assert d.dtype == jnp.float64
        assert bool(in_front) == (t > 0)
        if t > 0:
            np.testing.assert_allclose(d, ref, rtol=1e-10, atol=1e-12)
        else:
            np.testing.assert_array_equal(d, 0.0)


def test_perspective_distance_behind_eye_and_at_eye():
    p, v = jnp.array([1.0, 1.0, 1.0]), jnp.array([0.0, 0.0, 1.0])
    for x in [p - 2.0 * v + jnp.array([0.3, 0.0, 0.0]), p + jnp.array([0.5, 0.0, 0.0]), p]:  # t < 0, t = 0, x = p
        d, in_front = persp(p, v, x)
        assert not bool(in_front)
        np.testing.assert_array_equal(d, 0.0)
        jac = jac_persp(p, v, x)
        assert np.all(np.isfinite(jac))
        np.testing.assert_array_equal(jac, 0.0)


def test_perspective_distance_gradient_matches_finite_differences():
    p, v = jnp.zeros(3), unit(jnp.array([1.0, 0.2, -0.1]))
    x = jnp.array([2.0, 0.7, 0.3])
    jac = jac_persp(p, v, x)
    assert np.all(np.isfinite(jac))
    # dd/dx = (I − v vᵀ)/t − (x − x̂) vᵀ / t²
    t = float(v @ x)
    off = np.asarray(x - t * v)
    vv = np.asarray(v)
    ref = (np.eye(3) - np.outer(vv, vv)) / t - np.outer(off, vv) / t**2
    np.testing.assert_allclose(jac, ref, atol=1e-5)


def test_x64_is_restored_after_x64_tests():
    """Runs after the x64 tests above (file order): float32 is the default again."""
    assert not jax.config.jax_enable_x64
    assert jnp.zeros(1).dtype == jnp.float32
    assert unit(jnp.ones(3)).dtype == jnp.float32


def test_yaw_pitch_of_a_pole_with_subnormal_components_is_finite():
    # Hypothesis found this: XLA's atan2 gave 0/0 = NaN for subnormal x, y.
    v = jnp.asarray([1.40129846e-45, 1.40129846e-45, -1.0], jnp.float32)
    yaw, pitch = dir_to_yp(v)
    assert float(yaw) == 0.0 and float(pitch) == pytest.approx(-np.pi / 2)
    np.testing.assert_allclose(yp_to_dir(yaw, pitch), [0.0, 0.0, -1.0], atol=2e-6)


def test_head_pose_rotation_signs_and_round_trip(x64):
    # Yaw turns the forward axis (+x) towards the person's left (+y); pitch raises it (+z);
    # roll raises the left ear: the left axis (+y) gains +z.
    R = g.head_pose_to_rotation(yaw=0.3, pitch=0.0, roll=0.0)
    np.testing.assert_allclose(R[:, 0], [np.cos(0.3), np.sin(0.3), 0.0], atol=1e-12)
    R = g.head_pose_to_rotation(yaw=0.0, pitch=0.2, roll=0.0)
    np.testing.assert_allclose(R[:, 0], [np.cos(0.2), 0.0, np.sin(0.2)], atol=1e-12)
    R = g.head_pose_to_rotation(yaw=0.0, pitch=0.0, roll=0.1)
    np.testing.assert_allclose(R[:, 1], [0.0, np.cos(0.1), np.sin(0.1)], atol=1e-12)
    poses = jax.random.uniform(jax.random.key(3), (50, 3), minval=-1.2, maxval=1.2)
    Rs = g.head_pose_to_rotation(*poses.T)  # columns (yaw, pitch, roll)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", Rs, Rs), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(jnp.stack(g.rotation_to_head_pose(Rs), axis=-1), poses, atol=1e-10)


def test_wrap_angle_numpy_keeps_float64_and_jax_matches():
    x = np.array([0.0, np.pi, -np.pi, 3 * np.pi / 2, 2 * np.pi + 1e-9, -6.0, 1e-12])
    w = g.wrap_angle(x)
    assert isinstance(w, np.ndarray) and w.dtype == np.float64
    np.testing.assert_allclose(w, [0.0, np.pi, np.pi, -np.pi / 2, 1e-9, 2 * np.pi - 6.0, 1e-12], atol=1e-15)
    assert np.all((w > -np.pi) & (w <= np.pi))
    np.testing.assert_allclose(np.asarray(g.wrap_angle(jnp.asarray(x[3:6], jnp.float32))), w[3:6], atol=1e-6)
