"""Exclusive support: which rays claim which mode (Park et al. 2012, Sec. 3.1 and 3.3; :mod:`jaxgaze.concurrence.frame`, step 3).

Seeds are visited by decreasing field value; each claims the rays not yet claimed
within the claim radius and becomes a mode if they are enough (:func:`claim`). Two
people looking at each other (:func:`mutual_gaze`) are no mode on their own, and
the frame's robust noise ratio (:func:`robust_noise_ratio`) widens the claims when
the rays scatter more than their bandwidths say.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.concurrence.field import RayProjector, ray_coordinates
from jaxgaze.concurrence.options import ConcurrenceOptions

__all__ = ["whitened_distances", "mutual_gaze", "only_a_pair", "dominant_share", "robust_noise_ratio", "claim"]

ROBUST_MIN_MEMBERS = 4  # fewest members from which the noise ratio of the claims is estimated


def whitened_distances(proj: RayProjector, x: Float[Array, "3"]) -> tuple[Array, Array]:
    """``(‖d_i(x)‖ / h_i, in front and real)`` for every ray."""
    _, r2, ok, inv_t = ray_coordinates(proj, x)
    return jnp.sqrt(r2) * inv_t / proj.bandwidth, ok


def mutual_gaze(proj: RayProjector, radius: float) -> Int[Array, " N"]:
    """Each ray's partner in mutual gaze, or −1 (Park et al. 2012, Sec. 3.1: the eye in the other's cone).

    ``i`` and ``j`` look at each other when each eye lies in front of the other's ray
    with a whitened perspective distance ``‖d_i(p_j)‖/h_i`` below ``radius`` (the claim
    radius, so that the two rays alone would make a mode between the eyes). A ray
    that sees several partners takes the one with the smallest
    ``‖d_i(p_j)‖²/h_i² + ‖d_j(p_i)‖²/h_j²``, and a pair is kept only when that choice is
    mutual, so ``partner[partner[i]] = i``.
    """
    n = proj.mask.shape[0]
    dist, ok = jax.vmap(lambda eye: whitened_distances(proj, eye))(proj.origins)  # [j, i]: eye j from ray i
    sees = ok & (dist < radius) & proj.mask[:, None]
    mutual = sees & sees.T & ~jnp.eye(n, dtype=bool)
    score = jnp.where(mutual, dist * dist + (dist * dist).T, jnp.inf)
    best = jnp.argmin(score, axis=1)
    partner = jnp.where(jnp.any(mutual, axis=1), best, -1)
    return jnp.where((partner >= 0) & (partner[jnp.maximum(partner, 0)] == jnp.arange(n)), partner, -1).astype(
        jnp.int32)


def dominant_share(proj: RayProjector, x: Float[Array, "3"]) -> Array:
    """Largest share of one ray in the mean-shift weights ``Σ_i w_i`` at ``x`` (log-space, no underflow)."""
    _, r2, ok, inv_t = ray_coordinates(proj, x)
    log_w = proj.exponent_scale * r2 * inv_t**2 + jnp.log(proj.weight_scale * inv_t**2)
    log_w = jnp.where(ok, log_w, -jnp.inf)
    return jnp.exp(jnp.max(log_w) - jax.nn.logsumexp(log_w))


def robust_noise_ratio(dist: Float[Array, "K N"], members: Bool[Array, "K N"]) -> Array:
    """``max(1, ĉ)``: how much wider than their bandwidths the frame's member rays scatter (Park et al. 2012, Sec. 3.3).

    ``dist`` holds the whitened distances ``‖d_i‖/h_i`` of every ray from each of
    ``K`` refined locations and ``members`` marks each location's members. A
    member's ``s_i = ‖d_i‖²/h_i²`` is about ``ĉ²·χ²₂`` (median ``2 ln 2``), shrunk
    by the 3 coordinates fitted per location, so with ``n`` members in ``k``
    concurrences ``ĉ² = median(s) / (2 ln 2) · 2n/(2n − 3k)``. The estimate is
    pooled over the frame (the bandwidths are taken to be off by one common factor
    here; each covariance still gets its own noise scale, :func:`~jaxgaze.concurrence.laplace.noise_scale`), and
    the median ignores a stray ray of another group. With fewer than
    ``ROBUST_MIN_MEMBERS`` members, and when the rays scatter less than the
    bandwidths say, the ratio is 1. Used only to widen the claim and prune radii.
    """
    n = jnp.sum(members)
    k = jnp.sum(jnp.any(members, axis=-1))
    s = jnp.sort(jnp.where(members, dist * dist, jnp.inf).reshape(-1))
    half = jnp.maximum(n - 1, 0) // 2
    median = 0.5 * (s[half] + s[jnp.maximum(n, 1) // 2])
    ratio2 = median / (2.0 * math.log(2.0)) * (2.0 * n) / jnp.maximum(2.0 * n - 3.0 * k, 1.0)
    return jnp.where(n >= ROBUST_MIN_MEMBERS, jnp.sqrt(jnp.maximum(ratio2, 1.0)), 1.0)


def only_a_pair(members: Bool[Array, "... N"], partner: Int[Array, " N"]) -> Bool[Array, "..."]:
    """Whether each member set is exactly one pair in mutual gaze (O(N): a member whose partner is a member too)."""
    has_partner = partner >= 0
    return (jnp.sum(members, -1) == 2) & jnp.any(members & has_partner & members[..., jnp.maximum(partner, 0)], -1)


def claim(
    claim_proj: RayProjector,
    points: Float[Array, "S 3"],
    converged: Bool[Array, " S"],
    score: Float[Array, " S"],
    partner: Int[Array, " N"],
    *,
    options: ConcurrenceOptions,
    max_modes: int,
) -> tuple[Int[Array, " N"], Float[Array, "K 3"], Bool[Array, " K"], Bool[Array, " K"]]:
    """Exclusive support (Park et al. 2012, Sec. 3.3) with distances whitened by ``claim_proj``'s bandwidths.

    The seeds ``points`` (with mean-shift ``converged`` flags) are visited by decreasing
    ``score`` (their field value, ``-inf`` for seeds that cannot be modes). A seed within
    ``merge_radius`` of an accepted mode merges into it; one whose mean-shift weight one ray
    dominates (share > ``dominance``) is rejected; otherwise it claims every unclaimed ray
    closer than ``claim_bandwidths`` and becomes a mode if it claims at least ``min_rays``
    that are not only a pair in mutual gaze (``partner``, :func:`mutual_gaze`). Returns
    ``(membership (N,), modes (K, 3), their converged flags, valid (K,))``, ``K = max_modes``.
    """
    min_rays, claim_bandwidths = options.min_rays, options.claim_bandwidths
    dominance, merge_radius = options.dominance, options.merge_radius
    n = claim_proj.mask.shape[0]
    dtype = claim_proj.origins.dtype
    # What does not depend on the claims so far, for every seed at once; the scan then
    # only does O(N + K) work per seed.
    dist, ok = jax.vmap(lambda x: whitened_distances(claim_proj, x))(points)
    near = ok & (dist < claim_bandwidths)
    eligible = jnp.isfinite(score) & (jax.vmap(lambda x: dominant_share(claim_proj, x))(points) <= dominance)

    def visit(carry, s):
        claimed, membership, modes, mode_conv, count = carry
        x = points[s]
        candidates = near[s] & ~claimed
        slot = jnp.arange(max_modes)
        near_existing = jnp.any((slot < count) & (jnp.linalg.norm(modes - x, axis=-1) < merge_radius))
        accept = (
            eligible[s]
            & ~near_existing
            & (jnp.sum(candidates) >= min_rays)
            & ~only_a_pair(candidates, partner)
            & (count < max_modes)
        )
        claimed = claimed | (candidates & accept)
        membership = jnp.where(candidates & accept, count, membership)
        modes = jnp.where(accept & (slot == count)[:, None], x, modes)
        mode_conv = jnp.where(accept & (slot == count), converged[s], mode_conv)
        return (claimed, membership, modes, mode_conv, count + accept.astype(jnp.int32)), None

    init = (
        jnp.zeros(n, bool),
        jnp.full(n, -1, jnp.int32),
        jnp.zeros((max_modes, 3), dtype),
        jnp.zeros(max_modes, bool),
        jnp.int32(0),
    )
    # Only seeds near enough rays can become modes: visit just those, in the same order.
    possible = eligible & (jnp.sum(near, axis=1) >= min_rays)
    visits = jnp.argsort(jnp.where(possible, -score, jnp.inf))
    _, membership, modes, mode_conv, count = jax.lax.fori_loop(
        0, jnp.sum(possible), lambda i, carry: visit(carry, visits[i])[0], init)
    return membership, modes, mode_conv, jnp.arange(max_modes) < count
