"""Tests of jaxgaze.cone: the cone model (density, sampling) and the social saliency
field of Park et al. (2012), eq. 3, against quadrature, moments, a NumPy reference
and invariances."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxgaze import (
    GazeRays,
    cone_log_density,
    max_intensity_projection,
    ray_kernels,
    sample_gaze_directions,
    sample_points_of_regard,
    saliency_field,
    saliency_field_grid,
)

log_density = jax.jit(jax.vmap(cone_log_density, in_axes=(None, 0)))  # (M, 3) points → (M, N)
kernels = jax.jit(jax.vmap(ray_kernels, in_axes=(None, 0)))
field = jax.jit(saliency_field)
points_of_regard = jax.jit(jax.vmap(sample_points_of_regard, in_axes=(0, None, None)))  # keys → (K, N, 3)
one_point_of_regard = jax.jit(sample_points_of_regard)
gaze_directions = jax.jit(jax.vmap(sample_gaze_directions, in_axes=(0, None)))

# three rays, one near +z and one near −z (both branches of the tangent basis)
ORIGINS = np.array([[0.0, 0.0, 1.6], [1.0, -0.5, 1.7], [-0.4, 0.8, 1.5]])
DIRECTIONS = np.array([[1.0, 0.3, -0.1], [0.05, -0.02, 1.0], [-0.03, 0.04, -1.0]])
BANDWIDTH = np.array([0.05, 0.1, 0.03])
DEPTHS = np.array([2.0, 0.5, 4.0])


def _rays(**kw):
    return GazeRays(ORIGINS, DIRECTIONS, BANDWIDTH, **kw)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perp_basis(v):
    """An orthonormal basis (e1, e2) of v⊥, built independently of the library."""
    a = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(a - np.dot(a, v) * v)
    return e1, np.cross(v, e1)


def _field_np(origins, directions, bandwidth, mask, points):
    """Brute-force eq. 3 in float64: f(x) = (1/N) Σ_i exp(−‖d_i‖²/2h_i²) / (h_i √2π)."""
    directions = _unit(directions)
    out = np.zeros(len(points))
    n_real = max(int(mask.sum()), 1)
    for m, x in enumerate(points):
        total = 0.0
        for p, v, h, real in zip(origins, directions, bandwidth, mask):
            if not real:
                continue
            t = np.dot(v, x - p)
            if t <= 0:  # d = ∞ behind the eye
                continue
            d = (x - p - t * v) / t
            total += math.exp(-np.dot(d, d) / (2 * h * h)) / (h * math.sqrt(2 * math.pi))
        out[m] = total / n_real
    return out


# ---------------------------------------------------------------- cone density


@pytest.mark.parametrize("i", [0, 1, 2])
def test_cone_log_density_integrates_to_one(i):
    """∫ p(x) dA over the cross-section plane at depth t is 1 (trapezoid quadrature)."""
    rays = _rays()
    v = _unit(DIRECTIONS[i])
    h, t = BANDWIDTH[i], DEPTHS[i]
    e1, e2 = _perp_basis(v)
    s = np.linspace(-8 * h * t, 8 * h * t, 161)
    a, b = np.meshgrid(s, s, indexing="ij")
    pts = ORIGINS[i] + t * v + a[..., None] * e1 + b[..., None] * e2
    dens = np.exp(np.asarray(log_density(rays, jnp.asarray(pts.reshape(-1, 3), jnp.float32)), float))[:, i]
    integral = np.trapezoid(np.trapezoid(dens.reshape(a.shape), s, axis=1), s)
    assert integral == pytest.approx(1.0, abs=2e-3)
    # peak value −log(2π h² t²) at the centre of the cross-section
    centre = log_density(rays, jnp.asarray((ORIGINS[i] + t * v)[None], jnp.float32))[0, i]
    assert float(centre) == pytest.approx(-math.log(2 * math.pi * h**2 * t**2), abs=1e-4)


def test_cone_log_density_behind_eye_and_masked():
    rays = _rays(mask=np.array([True, True, False]))
    v0 = _unit(DIRECTIONS[0])
    pts = jnp.asarray(
        np.stack([ORIGINS[0] - 1.0 * v0, ORIGINS[0], ORIGINS[0] + 2.0 * v0]), jnp.float32
    )  # behind, at the eye (t = 0), in front
    lp = np.asarray(log_density(rays, pts))
    assert not np.any(np.isnan(lp))
    assert lp[0, 0] == -np.inf and lp[1, 0] == -np.inf
    assert np.isfinite(lp[2, 0])
    np.testing.assert_array_equal(lp[:, 2], -np.inf)  # padded ray
    # gradient of an in-front ray's density is finite even where others are −inf
    grad = jax.jit(jax.grad(lambda r, x: cone_log_density(r, x)[0], argnums=1))(rays, pts[2] + jnp.array([0.0, 0.05, 0.0]))
    assert np.all(np.isfinite(grad))


def test_cone_log_density_matches_kernel():
    """p(x) = K(x) / (h t² √(2π)): the cross-section density vs the eq. 3 kernel."""
    rays = _rays()
    rng = np.random.default_rng(0)
    pts = ORIGINS[0] + 1.5 * _unit(DIRECTIONS[0]) + 0.1 * rng.normal(size=(20, 3))
    pts32 = jnp.asarray(pts, jnp.float32)
    lp = np.asarray(log_density(rays, pts32), float)
    k = np.asarray(kernels(rays, pts32), float)
    t = np.einsum("nk,mnk->mn", _unit(DIRECTIONS), pts[:, None, :] - ORIGINS[None])
    front = (t > 0) & (k > 1e-30)
    np.testing.assert_allclose(np.exp(lp[front]), (k / (BANDWIDTH * t**2 * math.sqrt(2 * math.pi)))[front], rtol=1e-4)


# ---------------------------------------------------------------- sampling


def _to_ray_frame(offsets, v):
    """Coordinates of (K, 3) offsets in the frame (v, e1, e2)."""
    e1, e2 = _perp_basis(v)
    return offsets @ np.stack([v, e1, e2]).T


def test_sample_points_of_regard_covariance():
    """Offsets at depth t have covariance (h t)² on the two axes ⊥ v and 0 along v."""
    rays = _rays()
    K = 20000
    keys = jax.random.split(jax.random.key(0), K)
    x = np.asarray(points_of_regard(keys, rays, jnp.asarray(DEPTHS, jnp.float32)), float)
    assert x.shape == (K, 3, 3)
    for i in range(3):
        v = _unit(DIRECTIONS[i])
        ht = BANDWIDTH[i] * DEPTHS[i]
        c = _to_ray_frame(x[:, i] - (ORIGINS[i] + DEPTHS[i] * v), v)
        cov = c.T @ c / K  # the mean is known to be 0
        assert np.sqrt(cov[0, 0]) < 1e-3 * ht  # exactly at depth t: no spread along the ray
        np.testing.assert_allclose([cov[1, 1], cov[2, 2]], ht**2, rtol=0.05)
        assert abs(cov[1, 2]) < 0.05 * ht**2
        np.testing.assert_allclose(c[:, 1:].mean(axis=0), 0.0, atol=5 * ht / np.sqrt(K))


def test_sample_points_scalar_depth_and_keys():
    rays = _rays()
    keys = jax.random.split(jax.random.key(1), 4)
    x = np.asarray(points_of_regard(keys, rays, 3.0))
    assert x.shape == (4, 3, 3)
    # depth exactly 3 along each ray
    t = np.einsum("nk,mnk->mn", _unit(DIRECTIONS), x - ORIGINS[None])
    np.testing.assert_allclose(t, 3.0, rtol=1e-5)
    # vmap over keys matches a loop, different keys give different draws
    for j in range(4):
        np.testing.assert_allclose(x[j], one_point_of_regard(keys[j], rays, 3.0), rtol=1e-6)
    assert not np.allclose(x[0], x[1])


def test_sample_gaze_directions_spread():
    """tan α = h ‖δ‖ with δ ~ N(0, I₂): E[tan² α] = 2h², isotropic on the unit plane."""
    rays = _rays()
    K = 20000
    keys = jax.random.split(jax.random.key(2), K)
    s = np.asarray(gaze_directions(keys, rays), float)
    assert s.shape == (K, 3, 3)
    np.testing.assert_allclose(np.linalg.norm(s, axis=-1), 1.0, rtol=1e-5)
    for i in range(3):
        v = _unit(DIRECTIONS[i])
        h = BANDWIDTH[i]
        c = _to_ray_frame(s[:, i], v)
        assert np.all(c[:, 0] > 0)  # always forward
        plane = c[:, 1:] / c[:, :1]  # where the sampled direction meets Π: (d1, d2)
        cov = plane.T @ plane / K
        np.testing.assert_allclose(np.diag(cov), h**2, rtol=0.05)
        assert abs(cov[0, 1]) < 0.05 * h**2
        alpha = np.arctan(np.linalg.norm(plane, axis=1))
        assert np.mean(alpha) == pytest.approx(h * math.sqrt(math.pi / 2), rel=0.03)  # Rayleigh mean
        np.testing.assert_allclose(np.mean(np.tan(alpha) ** 2), 2 * h**2, rtol=0.05)
    # vmap over keys matches a loop
    np.testing.assert_allclose(s[5], jax.jit(sample_gaze_directions)(keys[5], rays), rtol=1e-6)


# ---------------------------------------------------------------- saliency field


def _scene(rng, n=6):
    origins = rng.uniform([-2, -2, 1.4], [2, 2, 1.8], size=(n, 3))
    target = np.array([0.2, -0.1, 1.0])
    directions = _unit(target - origins + 0.2 * rng.normal(size=(n, 3)))
    bandwidth = rng.uniform(0.03, 0.15, n)
    return origins, directions, bandwidth


def test_saliency_field_against_numpy(x64):
    rng = np.random.default_rng(3)
    origins, directions, bandwidth = _scene(rng)
    mask = np.array([True, True, True, False, True, True])
    rays = GazeRays(origins, directions, bandwidth, mask)
    assert rays.origins.dtype == jnp.float64
    near = origins[rng.integers(0, 6, 100)] + rng.uniform(0.5, 4, (100, 1)) * directions[rng.integers(0, 6, 100)]
    pts = np.concatenate([rng.uniform(-3, 3, (100, 3)), near + 0.05 * rng.normal(size=(100, 3))])
    got = np.asarray(field(rays, jnp.asarray(pts)))
    ref = _field_np(origins, directions, bandwidth, mask, pts)
    assert got.dtype == np.float64
    assert np.count_nonzero(ref > 1e-3) > 20  # the comparison is not all zeros
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-300)
    # shape of points is kept
    np.testing.assert_allclose(field(rays, jnp.asarray(pts.reshape(4, 50, 3))), ref.reshape(4, 50), rtol=1e-10)


def test_saliency_field_float32_and_counts():
    rng = np.random.default_rng(4)
    origins, directions, bandwidth = _scene(rng, n=3)
    rays = GazeRays(origins, directions, bandwidth)
    pts = origins[0] + np.linspace(0.5, 3, 7)[:, None] * directions[0]
    got = np.asarray(field(rays, jnp.asarray(pts, jnp.float32)))
    np.testing.assert_allclose(got, _field_np(origins, directions, bandwidth, np.ones(3, bool), pts), rtol=1e-4)
    # N counts real rays only: an extra padded ray changes nothing
    padded = GazeRays(
        np.vstack([origins, np.full((1, 3), np.nan)]),
        np.vstack([directions, np.zeros((1, 3))]),
        np.r_[bandwidth, -1.0],
        np.array([True, True, True, False]),
    )
    np.testing.assert_allclose(field(padded, jnp.asarray(pts, jnp.float32)), got, rtol=1e-6)
    # no real rays: 0 everywhere
    empty = GazeRays(origins, directions, bandwidth, np.zeros(3, bool))
    np.testing.assert_array_equal(field(empty, jnp.asarray(pts, jnp.float32)), 0.0)


def test_ray_kernels_peak_behind_and_masked():
    rays = _rays(mask=np.array([True, True, False]))
    v0 = _unit(DIRECTIONS[0])
    pts = jnp.asarray(np.stack([ORIGINS[0] + 1.0 * v0, ORIGINS[0] + 7.0 * v0, ORIGINS[0] - v0]), jnp.float32)
    k = np.asarray(kernels(rays, pts))
    peak = 1.0 / (BANDWIDTH[0] * math.sqrt(2 * math.pi))
    np.testing.assert_allclose(k[:2, 0], peak, rtol=1e-5)  # on the ray: flat along it
    assert k[2, 0] == 0.0  # behind the eye
    np.testing.assert_array_equal(k[:, 2], 0.0)  # padded


@settings(max_examples=30, deadline=None)
@given(
    st.tuples(*[st.floats(-1, 1) for _ in range(4)]).filter(lambda q: np.linalg.norm(q) > 0.1),
    st.tuples(*[st.floats(-10, 10) for _ in range(3)]),
    st.integers(0, 2**31 - 1),
)
def test_saliency_field_rigid_invariance(q, shift, seed):
    """f(R x + s) under rays (R p + s, R v) equals f(x) under (p, v)."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(seed)
        origins, directions, bandwidth = _scene(rng, n=4)
        R = Rotation.from_quat(np.array(q), scalar_first=True).as_matrix()
        s = np.array(shift)
        pts = origins[rng.integers(0, 4, 16)] + rng.uniform(0.3, 4, (16, 1)) * directions[rng.integers(0, 4, 16)]
        pts = np.concatenate([pts + 0.1 * rng.normal(size=pts.shape), rng.uniform(-3, 3, (8, 3))])
        f0 = np.asarray(field(GazeRays(origins, directions, bandwidth), jnp.asarray(pts)))
        f1 = np.asarray(
            field(GazeRays(origins @ R.T + s, directions @ R.T, bandwidth), jnp.asarray(pts @ R.T + s))
        )
        assert f0.dtype == np.float64
        assert f0.max() > 0.1  # a meaningful comparison
        np.testing.assert_allclose(f1, f0, rtol=1e-8, atol=1e-10 * f0.max())


# ---------------------------------------------------------------- grid and projection


def test_grid_and_max_intensity_projection():
    rng = np.random.default_rng(5)
    rays = GazeRays(*_scene(rng, n=3))
    lower, upper, shape = np.array([-1.0, -1.0, 0.5]), np.array([1.5, 1.0, 2.0]), (5, 4, 3)
    values, (xs, ys, zs) = saliency_field_grid(rays, lower, upper, shape)
    assert values.shape == shape
    for ax, lo, hi, n in zip((xs, ys, zs), lower, upper, shape):
        np.testing.assert_allclose(ax, np.linspace(lo, hi, n), rtol=1e-6, atol=1e-7)
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1)
    direct = np.asarray(field(rays, jnp.asarray(grid.reshape(-1, 3)))).reshape(shape)
    np.testing.assert_allclose(values, direct, rtol=1e-5, atol=1e-7)
    assert np.asarray(values).max() > 1e-3  # a meaningful comparison
    top = max_intensity_projection(values)
    assert top.shape == (5, 4)
    np.testing.assert_array_equal(top, np.asarray(values).max(axis=2))
    np.testing.assert_allclose(top, direct.max(axis=2), rtol=1e-5, atol=1e-7)
    side = max_intensity_projection(values, axis=0)
    assert side.shape == (4, 3)
    np.testing.assert_array_equal(side, np.asarray(values).max(axis=0))


# ---------------------------------------------------------------- bad inputs


def test_bad_inputs_raise():
    rays = _rays()
    batched = GazeRays.stack([rays, rays])
    with pytest.raises(ValueError, match="batch"):
        saliency_field(batched, jnp.zeros(3))
    with pytest.raises(ValueError, match="points"):
        saliency_field(rays, jnp.zeros((5, 2)))
    with pytest.raises(ValueError, match="points"):
        saliency_field(rays, jnp.float32(1.0))
    with pytest.raises(ValueError):
        saliency_field_grid(batched, [0, 0, 0], [1, 1, 1], (2, 2, 2))
    with pytest.raises(ValueError, match="upper"):
        saliency_field_grid(rays, [0, 0, 0], [1, 0, 1], (2, 2, 2))  # upper == lower on y
    with pytest.raises(ValueError, match="upper"):
        saliency_field_grid(rays, [0, 0, 0], [1, 1, -1], (2, 2, 2))  # upper < lower on z
    with pytest.raises(ValueError):
        saliency_field_grid(rays, [0, 0], [1, 1], (2, 2, 2))  # not 3-vectors
    with pytest.raises(ValueError):
        saliency_field_grid(rays, [0, 0, 0], [1, 1, 1], (2, 2))  # shape not a 3-tuple
