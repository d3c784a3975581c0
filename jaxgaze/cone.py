"""The cone gaze model and the 3D social saliency field (Park et al. 2012, Sec. 3.1, eq. 3–4).

Each primary gaze ray ``(p, v)`` with bandwidth ``h`` spreads the point of
regard over a cone: the gaze direction is ``v + d1 u1 + d2 u2`` with
``d1, d2 ~ N(0, h²)`` on the plane at unit depth, so the cross-section at depth
``t`` is an isotropic Gaussian of standard deviation ``h t``.
All positions are in the world frame (metres); ``h`` is in radians.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from jaxgaze.geometry import orthonormal_basis, perspective_distance, unit
from jaxgaze.rays import GazeRays

__all__ = [
    "cone_log_density",
    "cone_direction_log_density",
    "sample_gaze_directions",
    "sample_points_of_regard",
    "ray_kernels",
    "saliency_field",
    "saliency_field_grid",
    "max_intensity_projection",
]

_LOG_2PI = math.log(2.0 * math.pi)


def cone_log_density(rays: GazeRays, point: Float[Array, "3"]) -> Float[Array, " N"]:
    """Log density of a point of regard under each ray's cone, ``(N,)`` for one point (Park et al. 2012, Sec. 3.1).

    Given the depth ``t = vᵀ(x − p)`` the offset ``x − x̂`` on the cross-section is
    ``N(0, (h t)² I₂)``, so ``log p = −log(2π h² t²) − ‖d‖² / (2 h²)`` with ``d``
    the perspective distance of eq. 4. The depth itself is left unmodelled (a
    flat prior along the ray). Behind the eye the density is 0 (``−inf``); padded
    rays give ``−inf`` too. ``vmap`` over points for many.
    """
    d, in_front = jax.vmap(perspective_distance, in_axes=(0, 0, None))(rays.origins, rays.directions, point)
    t = jnp.einsum("nk,nk->n", rays.directions, point - rays.origins)
    h = rays.bandwidth
    safe_t = jnp.where(in_front, t, 1.0)
    log_p = -_LOG_2PI - 2.0 * jnp.log(h * safe_t) - jnp.sum(d * d, axis=-1) / (2.0 * h**2)
    return jnp.where(in_front & rays.mask, log_p, -jnp.inf)


def cone_direction_log_density(cosine: Float[Array, "..."], bandwidth: Float[Array, "..."]) -> Float[Array, "..."]:
    """Log density of a unit gaze direction around a cone axis, per steradian (Park et al. 2012, eq. 3, for directions).

    Park's cone puts the direction's offset on the plane at unit depth at
    ``N(0, h² I₂)``. Written on the sphere, where it stays proper at any angle,
    that is the Fisher density with concentration ``κ = 1/h²``:
    ``log p(v | u) = log κ − log 2π − log(1 − e^{−2κ}) + κ (uᵀv − 1)``, which for
    small angles equals the plane Gaussian (``κ(uᵀv − 1) ≈ −θ²/2h²``). Takes the
    cosine ``uᵀv`` of the direction and the axis; shapes broadcast, and the
    normaliser is evaluated at the bandwidth's shape only.
    """
    kappa = 1.0 / jnp.square(bandwidth)
    log_normaliser = jnp.log(kappa) - math.log(2.0 * math.pi) - jnp.log(-jnp.expm1(-2.0 * kappa))
    return log_normaliser + kappa * (cosine - 1.0)


def sample_gaze_directions(key: PRNGKeyArray, rays: GazeRays) -> Float[Array, "N 3"]:
    """Draw one gaze direction per ray from its cone (Park et al. 2012, Sec. 3.1).

    The direction is ``unit(v + d1 u1 + d2 u2)`` with ``d ~ N(0, h²)``.
    """
    offsets = jax.random.normal(key, rays.directions.shape[:-1] + (2,), rays.directions.dtype)
    u1, u2 = jax.vmap(orthonormal_basis)(rays.directions)
    h = rays.bandwidth[..., None]
    return unit(rays.directions + h * (offsets[..., :1] * u1 + offsets[..., 1:] * u2))


def sample_points_of_regard(key: PRNGKeyArray, rays: GazeRays, depth: Float[Array, "..."]) -> Float[Array, "N 3"]:
    """Draw points of regard at depth ``t`` along each ray: ``p + t (v + d1 u1 + d2 u2)`` (Park et al. 2012, Sec. 3.1).

    ``depth`` is a scalar or ``(N,)``; the point's depth along ``v`` is exactly ``t``
    and its offset is ``N(0, (h t)² I₂)``, the cone's cross-section.
    """
    offsets = jax.random.normal(key, rays.directions.shape[:-1] + (2,), rays.directions.dtype)
    u1, u2 = jax.vmap(orthonormal_basis)(rays.directions)
    h = rays.bandwidth[..., None]
    t = jnp.broadcast_to(jnp.asarray(depth, rays.directions.dtype), rays.bandwidth.shape)[..., None]
    return rays.origins + t * (rays.directions + h * (offsets[..., :1] * u1 + offsets[..., 1:] * u2))


def ray_kernels(rays: GazeRays, point: Float[Array, "3"]) -> Float[Array, " N"]:
    """Per-ray kernel ``K_i(x) = exp(−‖d_i‖² / 2h_i²) / (h_i √(2π))`` (Park et al. 2012, eq. 3; 0 behind the eye)."""
    d, in_front = jax.vmap(perspective_distance, in_axes=(0, 0, None))(rays.origins, rays.directions, point)
    h = rays.bandwidth
    k = jnp.exp(-jnp.sum(d * d, axis=-1) / (2.0 * h**2)) / (h * math.sqrt(2.0 * math.pi))
    return jnp.where(in_front & rays.mask, k, 0.0)


def saliency_field(rays: GazeRays, points: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """The 3D social saliency field ``f(x) = (1/N) Σ_i K_i(x)`` (Park et al. 2012, eq. 3).

    ``N`` counts real (unmasked) rays. ``points`` may have any leading shape;
    the result has that shape. With no rays the field is 0 everywhere.
    """
    if rays.batch_shape:
        raise ValueError(
            f"saliency_field: rays must be one frame (N, 3), got batch shape {rays.batch_shape}; use rays[t]"
        )
    points = jnp.asarray(points, rays.origins.dtype)
    if points.shape[-1:] != (3,):
        raise ValueError(f"saliency_field: points must have shape (..., 3), got {points.shape}")
    return _field_at(rays, points.reshape(-1, 3)).reshape(points.shape[:-1])


@jax.jit
def _field_at(rays: GazeRays, points: Float[Array, "P 3"]) -> Float[Array, " P"]:
    n = jnp.maximum(jnp.sum(rays.mask), 1)
    return jax.vmap(lambda x: jnp.sum(ray_kernels(rays, x)))(points) / n


def saliency_field_grid(
    rays: GazeRays,
    lower: Float[Array, "3"],
    upper: Float[Array, "3"],
    shape: tuple[int, int, int] = (64, 64, 32),
) -> tuple[Float[Array, "nx ny nz"], tuple[Array, Array, Array]]:
    """Evaluate ``f`` (Park et al. 2012, eq. 3) on a regular world-frame grid spanning the box ``[lower, upper]``.

    Returns ``(values, (xs, ys, zs))`` with ``values[i, j, k] = f(xs[i], ys[j], zs[k])``.
    """
    lower = jnp.asarray(lower, rays.origins.dtype)
    upper = jnp.asarray(upper, rays.origins.dtype)
    if lower.shape != (3,) or upper.shape != (3,) or len(shape) != 3:
        raise ValueError("saliency_field_grid: lower and upper must be 3-vectors and shape a 3-tuple")
    if not bool(jnp.all(upper > lower)):
        raise ValueError(f"saliency_field_grid: upper {upper} must exceed lower {lower} on every axis")
    axes = tuple(jnp.linspace(lower[i], upper[i], shape[i]) for i in range(3))
    grid = jnp.stack(jnp.meshgrid(*axes, indexing="ij"), axis=-1)
    return saliency_field(rays, grid), axes


def max_intensity_projection(values: Float[Array, "nx ny nz"], axis: int = 2) -> Float[Array, "a b"]:
    """Maximum-intensity projection of a field grid along ``axis`` (2 = top view, looking down z)."""
    return jnp.max(values, axis=axis)
