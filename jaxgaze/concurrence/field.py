"""The social saliency field through per-ray projections, and its mean-shift (Park et al. 2012, eq. 3, 5–6).

:class:`RayProjector` holds each ray's constants so that a point's ray coordinates
are one matmul; :func:`field_value` is eq. 3, :func:`meanshift_step` eq. 6 and
:func:`meanshift` the full ascent from a set of seeds (on GPU the fused kernel of
:mod:`jaxgaze.concurrence.meanshift_pallas`).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxgaze.concurrence.meanshift_pallas import fused_meanshift
from jaxgaze.concurrence.types import MeanShiftResult
from jaxgaze.geometry import orthonormal_basis
from jaxgaze.rays import GazeRays

__all__ = [
    "RayProjector", "ray_projector", "ray_coordinates", "meanshift_step", "field_value", "xla_meanshift", "meanshift",
]

class RayProjector(NamedTuple):
    """Per-ray constants that turn a point into its ray coordinates with one matmul.

    For ray ``i`` with orthonormal ``(v_i, u1_i, u2_i)``, ``basis @ x − offsets``
    gives ``(t_i, a_i, b_i)``: the depth of ``x`` and its offset on the
    cross-section, so ``r_i² = a_i² + b_i²`` has no cancellation and, vmapped
    over seeds, the work is an ``(S,3)×(3,3N)`` product with no ``(S,N,3)`` temporary.
    """

    basis: Float[Array, "3N 3"]
    offsets: Float[Array, "3N"]
    origins: Float[Array, "N 3"]
    directions: Float[Array, "N 3"]
    bandwidth: Float[Array, " N"]
    mask: Bool[Array, " N"]
    exponent_scale: Float[Array, " N"]  # −1 / (2 h²)
    weight_scale: Float[Array, " N"]  # 1 / h³, 0 for padded rays


def ray_projector(rays: GazeRays) -> RayProjector:
    """Precompute the :class:`RayProjector` of one frame of rays (Park et al. 2012, eq. 5–6)."""
    u1, u2 = jax.vmap(orthonormal_basis)(rays.directions)
    basis = jnp.stack([rays.directions, u1, u2], axis=1)  # (N, 3, 3)
    offsets = jnp.einsum("nij,nj->ni", basis, rays.origins, precision=jax.lax.Precision.HIGHEST)
    h = rays.bandwidth
    return RayProjector(
        basis.reshape(-1, 3), offsets.reshape(-1), rays.origins, rays.directions, h, rays.mask,
        -0.5 / (h * h), jnp.where(rays.mask, 1.0 / (h * h * h), 0.0),
    )


def ray_coordinates(proj: RayProjector, x: Float[Array, "3"]):
    """``(t, r², in front)`` of ``x`` for every ray, and ``1/t`` (0 where not in front)."""
    # HIGHEST: GPUs would otherwise round this float32 product through TF32 (10-bit mantissa).
    tab = (jnp.matmul(proj.basis, x, precision=jax.lax.Precision.HIGHEST) - proj.offsets).reshape(-1, 3)
    t, r2 = tab[:, 0], tab[:, 1] ** 2 + tab[:, 2] ** 2
    ok = (t > 0) & proj.mask
    inv_t = jnp.where(ok, 1.0 / jnp.where(ok, t, 1.0), 0.0)
    return t, r2, ok, inv_t


def meanshift_step(proj: RayProjector, x: Float[Array, "3"]) -> tuple[Array, Array]:
    """One closed-form update ``x ← Σ w_i x̄_i / Σ w_i`` (eq. 6) and ``Σ w_i``.

    With ``t_i = v_iᵀ(x − p_i)`` and ``r_i² = ‖x − x̂_i‖²``:
    ``w_i = exp(−r_i² / 2h_i²t_i²) / (h_i³ t_i²)`` (Gaussian profile, ``g ∝ e^{−s/2}``)
    and ``x̄_i = x̂_i + (r_i²/t_i) v_i = p_i + (r_i²/t_i + t_i) v_i``.
    Rays with ``t_i ≤ 0`` (behind the eye) or masked get zero weight.
    """
    t, r2, _, inv_t = ray_coordinates(proj, x)
    inv_t2 = inv_t * inv_t  # 0 behind the eye and for padded rays, so w = 0 there
    w = jnp.exp(proj.exponent_scale * r2 * inv_t2) * (inv_t2 * proj.weight_scale)
    total = jnp.sum(w)
    exact = jax.lax.Precision.HIGHEST
    target = jnp.matmul(w, proj.origins, precision=exact) + jnp.matmul(w * (r2 * inv_t + t), proj.directions, precision=exact)
    x_new = jnp.where(total > 0, target / jnp.where(total > 0, total, 1.0), x)
    return x_new, total


def field_value(proj: RayProjector, x: Float[Array, "3"]) -> Array:
    """``f(x)`` of eq. 3 through the projector (same values as :func:`jaxgaze.saliency_field`)."""
    _, r2, ok, inv_t = ray_coordinates(proj, x)
    h = proj.bandwidth
    k = jnp.where(ok, jnp.exp(proj.exponent_scale * r2 * inv_t * inv_t), 0.0) / (h * math.sqrt(2.0 * math.pi))
    return jnp.sum(k) / jnp.maximum(jnp.sum(proj.mask), 1)


def xla_meanshift(proj: RayProjector, seeds, tol, max_iter: int, max_stretch: int):
    """:func:`meanshift`'s loop in plain XLA: each seed runs its own ``while_loop`` (vmapped)."""
    stretches = 2.0 ** jnp.arange(int(math.log2(max_stretch)) + 1, dtype=proj.origins.dtype)

    def run_one(x0):
        def cond(state):
            _, it, done, _ = state
            return (~done) & (it < max_iter)

        def body(state):
            x, it, _, _ = state
            m, total = meanshift_step(proj, x)
            if max_stretch == 1:
                x_new = m
            else:
                candidates = x + stretches[:, None] * (m - x)
                values = jax.vmap(lambda c: field_value(proj, c))(candidates)
                x_new = candidates[jnp.argmax(values)]
            step = jnp.linalg.norm(m - x)
            return x_new, it + 1, step < tol, total > 0

        x, it, done, alive = jax.lax.while_loop(cond, body, (x0, jnp.int32(0), jnp.bool_(False), jnp.bool_(True)))
        return x, it, done & alive

    return jax.vmap(run_one)(seeds)


@functools.partial(jax.jit, static_argnames=("max_stretch",))
def meanshift(
    rays: GazeRays,
    seeds: Float[Array, "S 3"],
    *,
    tol: float = 1e-4,
    max_iter: int = 500,
    max_stretch: int = 32,
) -> MeanShiftResult:
    """Run the mean-shift (Park et al. 2012, eq. 6) from each seed until a step is below ``tol`` metres.

    Jit-compatible and vmapped over seeds; each seed runs its own
    ``lax.while_loop``. Each iteration computes the closed-form update
    ``m(x)`` and then tries the stretched steps ``x + s (m(x) − x)`` for
    ``s = 1, 2, 4, …, max_stretch``, keeping the one with the largest ``f``.
    ``s = 1`` is the paper's update, so ``f`` still never decreases (Theorem 1),
    while long flat ridges (near-parallel rays) are climbed in far fewer
    iterations. ``max_stretch=1`` gives the plain eq. 6 iteration.
    A seed where every weight underflows (far from all rays) does not move and
    is reported as not converged.
    """
    if not isinstance(max_stretch, int) or max_stretch < 1 or max_stretch & (max_stretch - 1):
        raise ValueError(f"max_stretch must be a power of two ≥ 1, got {max_stretch}")
    proj = ray_projector(rays)
    if jax.default_backend() == "gpu":
        points, iterations, converged = fused_meanshift(proj, seeds, tol, max_iter=max_iter, max_stretch=max_stretch)
    else:
        points, iterations, converged = xla_meanshift(proj, seeds, tol, max_iter, max_stretch)
    values = jax.vmap(lambda p: field_value(proj, p))(points)
    return MeanShiftResult(points, values, iterations, converged)
