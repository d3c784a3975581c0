"""The fused (Pallas) mean-shift kernel against the XLA path it replaces on GPUs.

On CPU the kernel runs in Pallas' interpreter; on a GPU these tests also run the
compiled kernel (``jaxgaze.meanshift`` dispatches to it there).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgaze as jg
from jaxgaze.concurrence.field import xla_meanshift, field_value, ray_projector
from jaxgaze.concurrence.meanshift_pallas import fused_meanshift

ON_GPU = jax.default_backend() == "gpu"


def scene(num_rays, num_seeds, seed=0, dtype=np.float64):
    """Six people per target, seeds along the rays, a few rays masked out."""
    rng = np.random.default_rng(seed)
    targets = rng.uniform(-3, 3, (max(1, num_rays // 6), 3))
    member = rng.integers(0, len(targets), num_rays)
    angle = rng.uniform(0, 2 * np.pi, num_rays)
    origins = targets[member] + np.column_stack([3 * np.cos(angle), 3 * np.sin(angle), rng.uniform(0.3, 0.8, num_rays)])
    directions = targets[member] - origins + rng.normal(0, 0.05, (num_rays, 3))
    mask = np.ones(num_rays, bool)
    mask[::7] = False
    rays = jg.GazeRays(origins.astype(dtype), directions.astype(dtype), np.full(num_rays, 0.05, dtype), mask)
    ray = rng.integers(0, num_rays, num_seeds)
    depth = rng.uniform(0.5, 8.0, num_seeds)
    seeds = origins[ray] + depth[:, None] * directions[ray] / np.linalg.norm(directions[ray], axis=1, keepdims=True)
    return rays, jnp.asarray(seeds.astype(dtype))


# Sizes that are not multiples of the tiles, so padding of rays and seeds is exercised.
@pytest.mark.parametrize("max_stretch", [1, 8])
def test_fused_kernel_equals_xla_path_in_float64(x64, max_stretch):
    rays, seeds = scene(37, 150)
    proj = ray_projector(rays)
    want = xla_meanshift(proj, seeds, 1e-5, 60, max_stretch)
    got = fused_meanshift(proj, seeds, 1e-5, max_iter=60, max_stretch=max_stretch, block_seeds=64, block_rays=16,
                          interpret=not ON_GPU)
    np.testing.assert_allclose(np.asarray(got[0]), np.asarray(want[0]), atol=1e-8)
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(want[1]))
    np.testing.assert_array_equal(np.asarray(got[2]), np.asarray(want[2]))
    assert 0 < int(np.sum(np.asarray(want[2]))) < len(seeds)  # some converge within 60 iterations, some not


def test_fused_kernel_float32_plain_steps_agree_and_climb():
    rays, seeds = scene(37, 150, seed=1, dtype=np.float32)
    proj = ray_projector(rays)
    with jax.default_matmul_precision("highest"):  # no TF32 in the reference on GPUs
        want = xla_meanshift(proj, seeds, 0.0, 12, 1)
    got = fused_meanshift(proj, seeds, 0.0, max_iter=12, max_stretch=1, block_seeds=64, block_rays=16,
                          interpret=not ON_GPU)
    assert got[0].dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(got[1]), 12)  # tol = 0: every seed runs max_iter steps
    # float32 rounding moves seeds along flat ridges (single rays); the field value is what matters.
    f = jax.vmap(lambda x: field_value(proj, x))
    np.testing.assert_allclose(np.asarray(f(got[0])), np.asarray(f(want[0])), rtol=2e-3, atol=1e-6)
    assert np.all(np.asarray(f(got[0])) >= np.asarray(f(seeds)) * (1 - 1e-5))  # Theorem 1


def test_seed_behind_every_ray_stays_put_and_is_not_converged(x64):
    rays, seeds = scene(13, 4)
    rays = jg.GazeRays(rays.origins, jnp.tile(jnp.array([1.0, 0.0, 0.0]), (13, 1)) + 0.01 * rays.directions,
                       rays.bandwidth, rays.mask)
    seeds = seeds.at[0].set(jnp.array([-50.0, 1.0, 2.0]))  # every ray points along +x, away from it
    proj = ray_projector(rays)
    got = fused_meanshift(proj, seeds, 1e-4, max_iter=30, max_stretch=1, block_seeds=64, block_rays=16,
                          interpret=not ON_GPU)
    want = xla_meanshift(proj, seeds, 1e-4, 30, 1)
    np.testing.assert_array_equal(np.asarray(got[0][0]), [-50.0, 1.0, 2.0])
    assert not bool(got[2][0]) and not bool(want[2][0])
    np.testing.assert_allclose(np.asarray(got[0]), np.asarray(want[0]), atol=1e-8)
