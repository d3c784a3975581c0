"""The cone gaze model and the 3D social saliency field (Park et al. 2012, Sec. 3.1, eq. 3–4).

Each primary gaze ray ``(p, v)`` with bandwidth ``h`` spreads the point of
regard over a cone: the gaze direction is ``v + d1 u1 + d2 u2`` with
``d1, d2 ~ N(0, h²)`` on the plane at unit depth, so the cross-section at depth
``t`` is an isotropic Gaussian of standard deviation ``h t``.
All positions are in the world frame (metres); ``h`` is in radians.
Who looks at whom under these cones (Siegfried et al. 2017, eq. 1, made
probabilistic) is :func:`looking_at_each_other`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import i0e
from jaxtyping import Array, Float, PRNGKeyArray

from jaxgaze.geometry import angle_between, orthonormal_basis, perspective_distance, unit
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
    "disc_probability",
    "LookingAtEachOther",
    "looking_at_each_other",
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
    normaliser is evaluated at the bandwidth's shape only. A cosine that rounding put above 1
    counts as 1: a dot product of two unit float32 vectors can be ``1 + 10⁻⁷``, and with a
    narrow cone ``κ · 10⁻⁷`` is a gain without bound (two equal gazes in a row made a fit's
    widths collapse to 10⁻¹⁴ rad).
    """
    kappa = 1.0 / jnp.square(bandwidth)
    log_normaliser = jnp.log(kappa) - math.log(2.0 * math.pi) - jnp.log(-jnp.expm1(-2.0 * kappa))
    return log_normaliser + kappa * (jnp.minimum(cosine, 1.0) - 1.0)


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


# ------------------------------------------------------------------ looking at each other

# Gauss–Legendre rule of the Rice integral in disc_probability: 48 nodes on a window of ±10 sd
# around the offset reproduce scipy.stats.ncx2.cdf to 1e-14 (tests/test_looking_at_each_other.py).
_RICE_NODES, _RICE_WEIGHTS = np.polynomial.legendre.leggauss(48)
_RICE_HALF_WINDOW = 10.0


@jax.jit
def disc_probability(
    offset: Float[Array, "..."], radius: Float[Array, "..."], bandwidth: Float[Array, "..."]
) -> Float[Array, "..."]:
    """``P(‖x − c‖ < r)`` for ``x ~ N(0, h² I₂)`` and ``‖c‖ = δ``: ``1 − Q₁(δ/h, r/h)`` (Marcum Q).

    With ``a = δ/h`` and ``b = r/h`` this is the non-central χ² CDF with 2 degrees of
    freedom, ``F(b²; 2, a²)``, the integral of the Rice density over ``[0, b]``:
    ``∫₀ᵇ ρ e^{−(ρ−a)²/2} i0e(aρ) dρ`` (``i0e(x) = e^{−x} I₀(x)`` keeps it finite). It is
    taken by a fixed 48-point Gauss–Legendre rule on ``[0, b] ∩ [a − 10, a + 10]``, where
    the density lives; outside it the density is below ``e^{−50}``. At ``δ = 0`` it is
    ``1 − exp(−r²/2h²)``. Shapes broadcast; jit- and grad-able.
    """
    a = jnp.asarray(offset) / bandwidth
    b = jnp.asarray(radius) / bandwidth
    a, b = jnp.broadcast_arrays(a, b)
    dtype = jnp.result_type(a, b, jnp.float32)
    a, b = a.astype(dtype), b.astype(dtype)
    lo = jnp.maximum(a - _RICE_HALF_WINDOW, 0.0)
    hi = jnp.minimum(b, a + _RICE_HALF_WINDOW)
    width = jnp.maximum(hi - lo, 0.0)
    nodes = jnp.asarray(_RICE_NODES, dtype)
    weights = jnp.asarray(_RICE_WEIGHTS, dtype)
    rho = lo[..., None] + 0.5 * width[..., None] * (nodes + 1.0)
    density = rho * jnp.exp(-0.5 * jnp.square(rho - a[..., None])) * i0e(a[..., None] * rho)
    return jnp.clip(0.5 * width * jnp.sum(weights * density, axis=-1), 0.0, 1.0)


class LookingAtEachOther(NamedTuple):
    """Who looks at whom, per frame (:func:`looking_at_each_other`).

    Attributes:
        looks_at: ``(..., N, N)`` ``P(i looks at j)``, gazer ``i`` on the rows, target ``j``
            on the columns; 0 on the diagonal, for masked rays and for targets behind the eye.
        mutual: ``(..., N, N)`` ``P(i ↔ j) = P(i → j)·P(j → i)``, symmetric; the two gazes'
            errors are taken as independent.
    """

    looks_at: Float[Array, "... N N"]
    mutual: Float[Array, "... N N"]


def looking_at_each_other(
    rays: GazeRays, heads: Float[Array, "... N 3"], *, threshold: float = math.radians(10.0)
) -> LookingAtEachOther:
    """``P(i looks at j)`` and mutual gaze ``P(i ↔ j)`` for every ordered pair of every frame (Siegfried et al. 2017, eq. 1, under Park's cone).

    Siegfried's eq. 1 says ``i`` looks at ``j`` when the angle between ``i``'s gaze and
    the direction ``u_ij`` from ``i``'s eyes to ``j``'s head is below ``τ`` (10°). Under
    ``i``'s cone (Park et al. 2012, Sec. 3.1) the true gaze lies around the ray ``v_i``
    with sd ``h_i``, so the event has the probability that a 2D Gaussian of sd ``h_i``,
    centred ``θ_ij = ∠(v_i, u_ij)`` away, falls in the disc of radius ``τ`` around
    ``u_ij``: ``P(i → j) = 1 − Q₁(θ_ij/h_i, τ/h_i)`` (:func:`disc_probability`). Offset
    and radius are measured as angles on the sphere, which keeps both lengths exact
    along the great circle through ``v_i`` and ``u_ij`` (on the plane at unit depth the
    disc is stretched radially by ``1/cos²θ``; in a Monte Carlo of the cone the angle
    form is within 0.01 for ``h`` up to 15°). The flat prior on the true gaze is implied:
    the result is a calibrated posterior where people look anywhere around the partner
    equally often. ``P(i ↔ j) = P(i → j)·P(j → i)`` treats the two people's gaze errors
    as independent.

    Args:
        rays: ``(..., N)`` gaze rays in the world frame, any batch axes (frames).
        heads: ``(..., N, 3)`` the point each person is looked at, world frame, the rays'
            slots (usually ``rays.origins``, the eye midpoints). Masked slots are ignored.
        threshold: ``τ`` in radians, in ``(0, π/2)``.

    Targets behind the eye (``v_iᵀ(x_j − p_i) ≤ 0``), oneself and masked rays give 0.
    Vectorised over frames and pairs; jit-able.
    """
    try:
        tau = float(threshold)
    except (TypeError, jax.errors.ConcretizationTypeError):
        raise ValueError(f"looking_at_each_other: threshold must be a number (radians), got {threshold!r}") from None
    if not 0.0 < tau < 0.5 * math.pi:
        raise ValueError(f"looking_at_each_other: threshold {tau:g} rad must lie in (0, π/2) radians "
                         f"(degrees? 10° is {math.radians(10.0):.4f} rad)")
    heads = jnp.asarray(heads)
    if heads.shape != rays.origins.shape:
        raise ValueError(f"looking_at_each_other: heads shape {heads.shape} must match the rays' origins "
                         f"{rays.origins.shape} (one head per ray slot)")
    if not any(isinstance(x, jax.core.Tracer) for x in (heads, rays.mask)):
        bad = ~np.all(np.isfinite(np.asarray(heads)), axis=-1) & np.asarray(rays.mask)
        if bad.any():
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            frame = index[:-1]
            where = f"slot {index[-1]}" + (f" of frame {frame[0] if len(frame) == 1 else frame}" if frame else "")
            raise ValueError(f"looking_at_each_other: heads of {where} is not finite (NaN or inf) "
                             "where the ray is real")
    looks_at = _looks_at(rays, heads.astype(rays.origins.dtype), jnp.asarray(tau, rays.origins.dtype))
    return LookingAtEachOther(looks_at, looks_at * jnp.swapaxes(looks_at, -1, -2))


@jax.jit
def _looks_at(rays: GazeRays, heads: Float[Array, "... N 3"], tau: Float[Array, ""]) -> Float[Array, "... N N"]:
    mask = rays.mask
    heads = jnp.where(mask[..., None], heads, 0.0)
    toward = heads[..., None, :, :] - rays.origins[..., :, None, :]  # (..., gazer i, target j, 3)
    v = rays.directions[..., :, None, :]
    in_front = jnp.sum(v * toward, axis=-1) > 0
    angle = angle_between(v, toward)
    n = mask.shape[-1]
    valid = mask[..., :, None] & mask[..., None, :] & ~jnp.eye(n, dtype=bool) & in_front
    p = disc_probability(angle, tau, rays.bandwidth[..., :, None])
    return jnp.where(valid, p, 0.0)
