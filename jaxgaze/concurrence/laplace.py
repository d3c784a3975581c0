"""Location and uncertainty of one concurrence: maximum likelihood, Laplace covariance, noise scale (Park et al. 2012, Sec. 3.3).

Each mode is refined to the maximum-likelihood common point of regard of its
member rays under the cone model, ``argmin_x Σ_i ‖d_i(x)‖² / 2h_i²``
(Levenberg–Marquardt, ``optimistix``), and its covariance built from the Laplace
(Gauss–Newton) matrix ``Σ_L = (JᵀJ + I/s²)⁻¹`` (:func:`refine_and_laplace`). When
the refinement fails the start is kept and the failure is a
:class:`~jaxgaze.results.RESULTS` code (:func:`jaxgaze.results.from_optimistix`).

**Noise scale.** ``Σ_L`` alone trusts the user's bandwidth: rays that scatter
more than ``h`` says make the ellipsoid too small, rays that scatter less make it
too large. The noise of a concurrence's members is taken to be ``c·h_i``, with one
unknown factor per concurrence and a log-uniform prior on ``u = c²`` over
``[1/64, 64]`` (``c`` within 8× of the user's bandwidth, either way; flat in
``log u`` is the scale-invariant choice, so inside those bounds the answer does
not depend on how wrong ``h`` is). Each member's whitened residual is 2-D
(perpendicular to its ray), so with ``n`` members, 3 location coordinates and
``RSS = Σ_i ‖d_i(x̂)/h_i‖²`` at the location ``x̂``, integrating the location out of
the linearised likelihood leaves ``p(u | RSS) ∝ u^{−(2n−3)/2} exp(−RSS/2u)`` on the
prior's support — an inverse gamma ``IG((2n−3)/2, RSS/2)``, truncated. It is
evaluated on a fixed grid of ``log u`` and summarised by the inverse gamma
``IG(a, b)`` with the same mean and variance; integrating ``u`` out of
``N(x̂, u Σ_L)`` then gives a 3-D Student-t with ``ν = 2a`` degrees of freedom and
scale matrix ``(b/a) Σ_L``. ``covariances`` is that t's covariance,
``E[u]·Σ_L``, and ``degrees_of_freedom`` its ``ν`` (always above 4, since the
support is bounded). Its ``level`` region is
``(x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤ 3 (ν − 2)/ν · F⁻¹(level; 3, ν)`` (see
:func:`~jaxgaze.concurrence.metrics.region_threshold`). With 4 or more members
the data decide ``u`` (``ν`` close to ``2n − 3`` and ``E[u]`` close to
``RSS/(2n − 5)``), so a bandwidth 2× too small or too large is corrected. A
2-ray concurrence has one residual degree of freedom, and its covariance leans on
the prior: about 4× ``Σ_L`` when the bandwidth is right. A conjugate
scaled-inverse-χ² prior centred on 1 with ``ν₀`` pseudo-degrees of freedom would
be simpler, but it cannot do both: ``ν₀ > 1`` is needed for a 2-ray mode to have
a finite covariance, and with ``ν₀ ≥ 1`` a bandwidth 2× too large still gives
95–99 % coverage of the 90 % region with 4–8 members.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float

from jaxgaze.concurrence.field import field_value, ray_projector
from jaxgaze.rays import GazeRays
from jaxgaze.results import RESULTS, from_optimistix

__all__ = [
    "member_residuals", "noise_scale", "refine_and_laplace", "laplace_covariance", "field_region",
]

_REGION_LEVEL = 0.8  # Park et al. Sec. 4.1: region above 80 % of the local maximum
_NOISE_RATIO_RANGE = 8.0  # prior: the rays scatter between 1/8 and 8 times their bandwidth (log-uniform)
_NOISE_GRID_POINTS = 256  # grid of the noise-scale posterior: steps of 0.033 in log c²

def member_residuals(x: Float[Array, "3"], args) -> Float[Array, "N 3"]:
    """Whitened perspective distances ``d_i(x)/h_i`` of the member rays (0 for others)."""
    rays, members = args
    diff = x - rays.origins
    t = jnp.einsum("nk,nk->n", diff, rays.directions, precision=jax.lax.Precision.HIGHEST)
    # Members sit in front of the eye at the mode; clamp so a wild LM step cannot divide by 0.
    t_safe = jnp.maximum(t, 1e-3)
    d = (diff - t[:, None] * rays.directions) / (t_safe * rays.bandwidth)[:, None]
    return jnp.where(members[:, None], d, 0.0)


def noise_scale(rss, num_members):
    """``(E[c²], ν)`` of a concurrence's noise-scale posterior (Park et al. 2012, Sec. 3.3; module docstring, **Noise scale**).

    On a fixed grid of ``u = c²``, log-spaced over the prior's support, the
    posterior weights are ``∝ u^{−(2n−3)/2} exp(−RSS/2u)`` (trapezoidal rule in
    ``log u``); ``ν = 2a`` with ``a = 2 + E[u]²/Var[u]``, the shape of the inverse
    gamma with the same mean and variance. Fewer than 2 members (padding) count as 2.
    """
    log_u = jnp.linspace(-2.0 * math.log(_NOISE_RATIO_RANGE), 2.0 * math.log(_NOISE_RATIO_RANGE),
                         _NOISE_GRID_POINTS, dtype=rss.dtype)
    u = jnp.exp(log_u)
    k = 2.0 * jnp.maximum(num_members, 2).astype(rss.dtype) - 3.0
    ends = jnp.zeros_like(log_u).at[jnp.array([0, -1])].set(math.log(0.5))  # trapezoidal rule
    w = jax.nn.softmax(-0.5 * k * log_u - 0.5 * rss / u + ends)
    mean = jnp.sum(w * u)
    var = jnp.sum(w * (u - mean) ** 2)
    return mean, 2.0 * (2.0 + mean * mean / var)


def refine_and_laplace(rays: GazeRays, members, x0, prior_scale, max_steps: int):
    """ML location of the members, its covariance (the Student-t's), degrees of freedom, whether the rays bound it and the refinement's result (Park et al. 2012, Sec. 3.3).

    Levenberg–Marquardt from ``x0`` to ``argmin_x Σ_i ‖d_i(x)/h_i‖²`` over the
    members, then ``Σ_L = (JᵀJ + I/s²)⁻¹`` at the solution and, from the residual
    sum of squares there, the covariance ``E[c²]·Σ_L`` and ``ν`` (:func:`noise_scale`).
    ``c²`` scales the covariance only: the location does not depend on it.

    The result is LM's, through :func:`jaxgaze.results.from_optimistix` (``max_steps_reached`` keeps the best
    point reached); where LM's point is not finite or fits the members worse than ``x0``, the
    location falls back to ``x0`` and the result is ``optimiser_failed`` (or ``nonfinite``).
    """
    # float32 cannot meet float64's tolerances: LM would reach the minimum, keep stepping
    # to max_steps and report failure.
    single = jnp.finfo(x0.dtype).bits < 64
    solver = optx.LevenbergMarquardt(rtol=1e-6 if single else 1e-7, atol=1e-7 if single else 1e-9)
    sol = optx.least_squares(
        member_residuals, solver, x0, args=(rays, members), max_steps=max_steps, throw=False
    )
    # Keep LM's point whenever it fits the members at least as well as the start, also when
    # it ran out of steps (it only ever takes steps that lower the cost).
    cost = lambda y: jnp.sum(member_residuals(y, (rays, members)) ** 2)  # noqa: E731
    solved_cost, start_cost = cost(sol.value), cost(x0)
    ok = jnp.all(jnp.isfinite(sol.value)) & (solved_cost <= start_cost)
    x = jnp.where(ok, sol.value, x0)
    rss = jnp.where(ok, solved_cost, start_cost)  # the residual sum of squares at x
    jac = jax.jacfwd(member_residuals)(x, (rays, members)).reshape(-1, 3)
    mean_c2, dof = noise_scale(rss, jnp.sum(members))
    laplace = laplace_covariance(jac, prior_scale)
    # The data pin x down only where JᵀJ outweighs the prior's I/s²; tr Σ_L ≥ s²/2 means that
    # along some direction the prior, not the rays, holds the location (unbounded). A covariance
    # that is not finite (a NaN or inf in the Jacobian) is no bound either.
    bounded = jnp.all(jnp.isfinite(laplace)) & (jnp.trace(laplace) < 0.5 * prior_scale**2)
    theirs = from_optimistix(sol.result)
    fell_back = ~ok & ((theirs == RESULTS.successful) | (theirs == RESULTS.max_steps_reached))
    return x, laplace * mean_c2, dof, bounded, RESULTS.where(fell_back, RESULTS.optimiser_failed, theirs)


def laplace_covariance(jac: Float[Array, "M 3"], prior_scale) -> Float[Array, "3 3"]:
    """``Σ_L = (JᵀJ + I/s²)⁻¹`` as the Gram matrix ``R⁻¹R⁻ᵀ`` (Park et al. 2012, Sec. 3.3; module docstring, step 4).

    ``R`` is the triangle of the QR of ``[J; I/s]``, so ``RᵀR = JᵀJ + I/s²`` without forming
    ``JᵀJ``: its conditioning is the square root of the precision's, and ``R⁻¹R⁻ᵀ`` is symmetric
    positive semi-definite in any arithmetic. Inverting ``JᵀJ + I/s²`` itself in float32 could give
    negative variances in crowded frames (eigenvalues −0.67, 5e-9, 8e-9 m² with 1,000 people).
    ``R⁻¹`` of the 3 × 3 triangle is written out (no LAPACK call).
    """
    stacked = jnp.concatenate([jac, jnp.eye(3, dtype=jac.dtype) / prior_scale])
    r = jnp.linalg.qr(stacked, mode="r")
    (a, b, c), (_, d, e), (_, _, f) = r[0], r[1], r[2]
    zero = jnp.zeros_like(a)
    inverse = jnp.stack([
        jnp.stack([1.0 / a, -b / (a * d), (b * e - c * d) / (a * d * f)]),
        jnp.stack([zero, 1.0 / d, -e / (d * f)]),
        jnp.stack([zero, zero, 1.0 / f]),
    ])
    return inverse @ inverse.T


def field_region(rays: GazeRays, x: Float[Array, "3"]) -> tuple[Array, Array]:
    """Principal axes and semi-axes of ``{f ≥ 0.8 f(x)}`` from the Hessian of ``log f``."""
    proj = ray_projector(rays)
    hess = jax.hessian(lambda y: jnp.log(field_value(proj, y)))(x)
    curvature, axes = jnp.linalg.eigh(-0.5 * (hess + hess.T))
    level = 2.0 * math.log(1.0 / _REGION_LEVEL)
    semi = jnp.where(curvature > 0, jnp.sqrt(level / jnp.where(curvature > 0, curvature, 1.0)), jnp.inf)
    return axes, semi
