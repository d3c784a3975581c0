"""One frame's concurrences: the modes of the social saliency field (Park et al. 2012, Sec. 3.3).

Pipeline for one frame (all in JAX, fixed shapes, so it vmaps over frames):

1. **Seeds** at fixed depths along every primary ray.
2. **Mean-shift** (eq. 5–6) on the field smoothed with bandwidth
   ``search_scale · h`` from every seed, until a step is shorter than ``tol`` or
   after ``max_iter`` steps. On CPU each step is one evaluation of the update ``m``
   and the field ``f``, stretched adaptively so that ``f`` never falls, and the seeds
   still moving are compacted every few steps, so converged seeds cost nothing; on
   GPU the fused kernel runs every seed. Two noisy
   rays that "meet" usually miss each other by about ``h``, and at the
   calibrated bandwidth their crossing is often not a single peak; the wider
   search bandwidth (default 2) finds it.
3. **Exclusive support.** Seeds are visited by decreasing field value. A seed
   within ``merge_radius`` of an accepted mode is merged into it. A seed whose
   mean-shift weight is dominated by one ray (share > ``dominance``) is
   rejected. Otherwise it claims every not-yet-claimed ray whose perspective
   distance is below ``claim_bandwidths`` search bandwidths, and becomes a mode
   if it claims at least ``min_rays`` rays. Each ray supports at most one mode.
   The claims are made twice: after the first pass the members' robust noise
   ratio ``ĉ ≥ 1`` (pooled over the frame: how much wider than ``h`` the rays
   scatter) is measured at the refined locations, and the second pass claims
   with the bandwidths times ``max(1, ĉ/1.25)``. With a bandwidth that is right
   ``ĉ`` is close to 1 and the claims stay as they were; with one too small the
   second pass keeps the tail of each concurrence's residuals, which a fixed
   radius would cut off.
4. **Location and uncertainty.** Each mode is refined to the maximum-likelihood
   common point of regard of its member rays under the cone model,
   ``argmin_x Σ_i ‖d_i(x)‖² / 2h_i²`` (Levenberg–Marquardt, ``optimistix``).
   Unclaimed rays within ``ĉ`` claim radii of the refined point join it; members
   farther than ``4 ĉ h`` from it (``ĉ`` measured again) are dropped (a mode left with fewer than
   ``min_rays`` is dropped too); the location is refined again. Its covariance is
   built from the Laplace (Gauss–Newton) matrix ``Σ_L = (JᵀJ + I/s²)⁻¹`` with
   ``J`` the Jacobian of the whitened residuals ``d_i(x)/h_i`` and a weak prior
   of scale ``s = prior_scale`` metres that keeps near-parallel rays finite,
   scaled by the noise the members actually show (:mod:`jaxgaze.concurrence.laplace`, **Noise scale**).
   Modes under the floor (``floor_below_eyes`` under the lowest eye), those of only
   a pair of people looking at each other (mutual gaze, reported in ``mutual_gaze``)
   and those the rays leave unbounded are not concurrences (:func:`~jaxgaze.concurrence.find_concurrences`).
   Each concurrence's ``result`` says whether its last refinement succeeded
   (:func:`~jaxgaze.concurrence.laplace.refine_and_laplace`; a failed one keeps its start).
5. **The paper's region.** ``{x : f(x) ≥ 0.8 f(x*)}`` is reported by its
   principal axes from the Hessian of ``log f`` at the location. It is a level
   set of the field: it says how sharply the group's gaze agrees, in units of the
   bandwidth, and does not shrink as members are added, so it is not a
   confidence region for the location (on the simulated mocap scene it holds the
   marker in 43.5 % of the frames). The covariance is the location's uncertainty.

The steps live in their modules: the field and its mean-shift in
:mod:`~jaxgaze.concurrence.field` and :mod:`~jaxgaze.concurrence.climb`, the claims in
:mod:`~jaxgaze.concurrence.claims`, location and covariance in
:mod:`~jaxgaze.concurrence.laplace`; :func:`concurrences_from_seeds` runs them in order.
A warm-started frame (:func:`warm_frame`) is seeded from the previous frame's modes.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.concurrence.claims import claim, mutual_gaze, only_a_pair, robust_noise_ratio, whitened_distances
from jaxgaze.concurrence.climb import two_stage_meanshift
from jaxgaze.concurrence.field import field_value, ray_projector
from jaxgaze.concurrence.laplace import field_region, refine_and_laplace
from jaxgaze.concurrence.options import ConcurrenceOptions
from jaxgaze.concurrence.types import Concurrences
from jaxgaze.rays import GazeRays
from jaxgaze.results import RESULTS, code

__all__ = [
    "seeds_along_rays", "over_modes", "refine", "concurrences_from_seeds", "concurrences_one_frame", "warm_frame",
    "unexplained", "region_box", "FRESH_SEEDS_PER_RAY", "WARM_MAX_ITER",
]

PRUNE_BANDWIDTHS = 4.0  # P(‖d‖ > 4h) = e⁻⁸ ≈ 3·10⁻⁴ for a true member
CLAIM_RATIO_MARGIN = 1.25  # second claims widen by ĉ/1.25: a right bandwidth's noisy ĉ ≥ 1 leaves them as
# they were (wider claims merge groups), one 2× too small still widens them 1.6×
#: Fresh seeds per ray in a warm-started frame; their depths rotate through ``seed_depths``.
FRESH_SEEDS_PER_RAY = 4
#: Mean-shift iterations of a warm-started frame's seeds.
WARM_MAX_ITER = 10


def seeds_along_rays(rays: GazeRays, depths: Float[Array, " D"]) -> tuple[Array, Array]:
    """``(N·D, 3)`` seeds at ``depths`` along every primary ray, and which belong to real rays."""
    seeds = rays.origins[:, None, :] + depths[None, :, None] * rays.directions[:, None, :]
    return seeds.reshape(-1, 3), jnp.repeat(rays.mask, depths.shape[0])



def over_modes(fn, *xs, active: Bool[Array, " K"], modes_per_batch: int):
    """``fn`` vmapped over the ``K`` mode slots of ``xs``; on XLA:CPU in batches of ``modes_per_batch``, which
    keep the batched LAPACK calls below the size at which it can deadlock (see ``jaxgaze._batching``). A batch
    with no ``active`` slot is skipped (zeros): the slots past the frame's modes cost nothing."""
    max_modes = active.shape[0]
    if modes_per_batch >= max_modes:
        return jax.vmap(fn)(*xs)
    batches = -(-max_modes // modes_per_batch)
    extra = batches * modes_per_batch - max_modes

    def split(a):
        a = jnp.concatenate([a, jnp.repeat(a[:1], extra, axis=0)]) if extra else a
        return a.reshape((batches, modes_per_batch) + a.shape[1:])

    batched = jax.vmap(fn)
    empty = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype),
                                   jax.eval_shape(batched, *(split(x)[0] for x in xs)))

    def one(args):
        go, *part = args
        return jax.lax.cond(jnp.any(go), lambda: batched(*part), lambda: empty)

    out = jax.lax.map(one, (split(active),) + tuple(split(x) for x in xs))
    return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[:max_modes], out)


def refine(
    rays: GazeRays,
    members: Bool[Array, "K N"],
    x0: Float[Array, "K 3"],
    before=None,
    *,
    options: ConcurrenceOptions,
    modes_per_batch: int,
):
    """:func:`~jaxgaze.concurrence.laplace.refine_and_laplace` of every slot with members (Park et al. 2012, Sec. 3.3).

    With ``before = (members, outputs)`` of an earlier refinement, a slot whose members did not
    change keeps its outputs (the maximum-likelihood location of the same rays, reached again from
    a start near it), and only the changed slots are refined."""
    max_modes = members.shape[0]
    changed = jnp.ones(max_modes, bool) if before is None else jnp.any(members != before[0], axis=1)
    out = over_modes(lambda m, x: refine_and_laplace(rays, m, x, options.prior_scale, options.refine_steps),
                     members, x0, active=changed & jnp.any(members, axis=1), modes_per_batch=modes_per_batch)
    if before is None:
        return out
    pick = lambda new, old: jnp.where(changed.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
    return jax.tree_util.tree_map(pick, out, before[1])


def concurrences_one_frame(
    rays: GazeRays,
    seed_depths: Float[Array, " S"],
    region: tuple[Float[Array, "2 3"], Float[Array, ""]],
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> Concurrences:
    """One frame's :class:`~jaxgaze.concurrence.Concurrences`, ``max_modes`` slots, from seeds at ``seed_depths``
    along every ray (steps 1–5 of the module docstring). ``region`` is ``(bounds box, floor below the eyes)``."""
    seeds, seed_ok = seeds_along_rays(rays, seed_depths)
    return concurrences_from_seeds(rays, seeds, seed_ok, region, options=options, max_modes=max_modes,
                                   modes_per_batch=modes_per_batch)


def concurrences_from_seeds(
    rays: GazeRays,
    seeds: Float[Array, "S 3"],
    seed_ok: Bool[Array, " S"],
    region: tuple[Float[Array, "2 3"], Float[Array, ""]],
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> Concurrences:
    """Steps 2–5 of the module docstring from the given mean-shift seeds (Park et al. 2012, Sec. 3.3)."""
    min_rays, claim_bandwidths, search_scale = options.min_rays, options.claim_bandwidths, options.search_scale
    search = eqx.tree_at(lambda r: r.bandwidth, rays, rays.bandwidth * search_scale)
    proj, search_proj = ray_projector(rays), ray_projector(search)
    ms = two_stage_meanshift(search, seeds, seed_ok, tol=options.tol, max_iter=options.max_iter,
                             keep=2 * max_modes + 2)
    # Seeds that hit the iteration cap have still only climbed f, so they stay candidates.
    # The box, raised to the floor: at most floor_below_eyes (inf: off) under the lowest eye.
    bounds = region_box(rays, region)
    inside = lambda x: jnp.all((x >= bounds[0]) & (x <= bounds[1]), axis=-1)  # noqa: E731
    # Two people looking at each other: their rays alone make a flat ridge between the eyes, not a mode.
    partner = mutual_gaze(proj, claim_bandwidths * search_scale)
    score = jnp.where(seed_ok & (ms.field_values > 0) & inside(ms.points), ms.field_values, -jnp.inf)
    claim_at = lambda p: claim(p, ms.points, ms.converged, score, partner, options=options, max_modes=max_modes)  # noqa: E731
    refine_slots = lambda *a: refine(rays, *a, options=options, modes_per_batch=modes_per_batch)  # noqa: E731
    slots = jnp.arange(max_modes)[:, None]

    # Claims at the user's bandwidth give a first estimate of how much wider the
    # rays scatter: the robust noise ratio ĉ ≥ 1 of the members at their refined
    # locations, pooled over the frame. The claims are made again with the
    # bandwidth times max(1, ĉ/1.25), so that a bandwidth too small for the rays
    # does not cut off the tail of each concurrence's residuals (which would make
    # its noise scale, and its covariance, too small). With ĉ ≤ 1.25 nothing changes.
    membership, modes, mode_conv, valid = claim_at(search_proj)
    initial = (membership[None, :] == slots) & valid[:, None]
    refined = refine_slots(initial, modes)
    dist, _ = jax.vmap(lambda x: whitened_distances(search_proj, x))(refined[0])
    ratio = robust_noise_ratio(dist * search_scale, initial)
    widen = jnp.maximum(1.0, ratio / CLAIM_RATIO_MARGIN)
    wide_proj = ray_projector(eqx.tree_at(lambda r: r.bandwidth, search, search.bandwidth * widen))
    # With ĉ ≤ 1.25 the claims at the wider radius are the same claims: skip them.
    membership, modes, mode_conv, valid = jax.lax.cond(
        widen > 1.0, lambda: claim_at(wide_proj), lambda: (membership, modes, mode_conv, valid))

    # The mixture mode sits where a subset of rays crosses tightly, so a true
    # member with a large residual can lie outside the claim radius there. Claim
    # the still-unclaimed rays again at each mode's refined (maximum-likelihood)
    # location, nearest mode first, and refine once more. These claims cannot merge
    # groups, so their radius takes the whole ratio ĉ.
    member_mask = membership[None, :] == slots
    refined = refine_slots(member_mask, modes, (initial, refined))
    first = refined[0]
    dist, ok = jax.vmap(lambda x: whitened_distances(search_proj, x))(first)
    dist = jnp.where(valid[:, None] & ok & (dist < claim_bandwidths * ratio), dist, jnp.inf)
    nearest = jnp.argmin(dist, axis=0)
    late = (membership < 0) & jnp.isfinite(jnp.min(dist, axis=0))
    membership = jnp.where(late, nearest, membership)
    before, member_mask = member_mask, membership[None, :] == slots
    refined = refine_slots(member_mask, first, (before, refined))
    second = refined[0]
    # A wide search radius can also take in a stray ray of another group. Drop
    # members that the cone model rejects at the refined location
    # (‖d‖ > prune_bandwidths · ĉ h, ĉ the frame's robust noise ratio, at least 1),
    # drop modes left with too few rays, refine again.
    dist, _ = jax.vmap(lambda x: whitened_distances(proj, x))(second)
    stray = member_mask & (dist > PRUNE_BANDWIDTHS * robust_noise_ratio(dist, member_mask & valid[:, None]))
    member_mask = member_mask & ~stray
    valid = valid & (jnp.sum(member_mask, axis=1) >= min_rays) & inside(second) & ~only_a_pair(member_mask, partner)
    before, member_mask = member_mask | stray, member_mask & valid[:, None]
    locations, covariances, dof, bounded, result = refine_slots(member_mask, second, (before, refined))
    # A mode the rays do not bound (the prior holds it along some direction) is no concurrence.
    valid = valid & bounded
    member_mask = member_mask & valid[:, None]
    membership = jnp.where(jnp.any(member_mask, axis=0), jnp.argmax(member_mask, axis=0), -1).astype(jnp.int32)
    axes, semi = over_modes(lambda x: field_region(rays, x), locations, active=valid, modes_per_batch=modes_per_batch)
    values = jax.vmap(lambda x: field_value(proj, x))(locations)

    return _valid_first(
        valid, membership, partner, num_rays=jnp.sum(member_mask, axis=1).astype(jnp.int32), converged=mode_conv,
        result=result, locations=locations, covariances=covariances, field_values=values, region_axes=axes,
        region_semi_axes=semi, degrees_of_freedom=dof,
    )


def _valid_first(valid, membership, partner, *, num_rays, converged, result, **floats) -> Concurrences:
    """The frame's :class:`~jaxgaze.concurrence.Concurrences` with the valid modes first (in claim order), so that
    ``membership`` indexes the modes a frame keeps. The other slots are padding: zeros, not ``converged``, and
    ``successful`` (nothing was refined there)."""
    max_modes = valid.shape[0]
    order = jnp.argsort(~valid, stable=True)
    slot_of = jnp.zeros(max_modes, jnp.int32).at[order].set(jnp.arange(max_modes, dtype=jnp.int32))
    membership = jnp.where(membership >= 0, slot_of[jnp.maximum(membership, 0)], -1)
    valid = valid[order]

    def pad(a, fill=0.0):
        a = a[order]
        mask = valid.reshape(valid.shape + (1,) * (a.ndim - 1))
        return jnp.where(mask, a, jnp.asarray(fill, a.dtype))

    return Concurrences(
        **{name: pad(a) for name, a in floats.items()},
        num_rays=num_rays[order],
        membership=membership,
        converged=pad(converged, False),
        valid=valid,
        mutual_gaze=partner,
        result=jax.tree_util.tree_map(lambda a: pad(a, code(RESULTS.successful)), result),
    )

def fresh_depths(seed_depths: Float[Array, " D"], frame: Int[Array, ""]) -> Float[Array, " F"]:
    """``FRESH_SEEDS_PER_RAY`` of the seed depths, spread over their range and shifted by one every frame,
    so that consecutive frames together seed every depth."""
    count = seed_depths.shape[0]
    fresh = min(FRESH_SEEDS_PER_RAY, count)
    stride = count // fresh
    return seed_depths[jnp.arange(fresh) * stride + frame % stride]


def unexplained(rays: GazeRays, found: Concurrences, bounds: Float[Array, "2 3"], claim_radius: float) -> Array:
    """Whether two rays that support no mode cross within each other's claim radius (Park et al. 2012, Sec. 3.3).

    Such a pair could make a concurrence that seeds from the previous frame's modes
    missed, so the frame is searched again from the full seed set. The crossing is
    the midpoint ``m`` of the two lines' closest points; it must lie in front of
    both eyes, inside ``bounds`` and within ``claim_radius`` whitened distances
    (search bandwidths) of both rays. Pairs in mutual gaze do not count.
    """
    n = rays.num_rays
    free = rays.mask & (found.membership < 0)
    p, v, h = rays.origins, rays.directions, rays.bandwidth
    w0 = p[:, None, :] - p[None, :, :]  # p_i − p_j
    b = jnp.einsum("ik,jk->ij", v, v)
    d_i, e_j = jnp.einsum("ijk,ik->ij", w0, v), jnp.einsum("ijk,jk->ij", w0, v)
    denom = 1.0 - b * b
    parallel = denom < 1e-6
    safe = jnp.where(parallel, 1.0, denom)
    s = (b * e_j - d_i) / safe  # depth along ray i of its point closest to ray j
    t = (e_j - b * d_i) / safe  # … and along ray j
    on_i = p[:, None, :] + s[..., None] * v[:, None, :]  # the two closest points
    on_j = p[None, :, :] + t[..., None] * v[None, :, :]
    m, gap = 0.5 * (on_i + on_j), jnp.linalg.norm(on_i - on_j, axis=-1)
    # The perspective distance of m from each ray is gap/2 at depth s (or t).
    close = (0.5 * gap < claim_radius * h[:, None] * s) & (0.5 * gap < claim_radius * h[None, :] * t)
    inside = jnp.all((m >= bounds[0]) & (m <= bounds[1]), axis=-1)
    partners = found.mutual_gaze[:, None] == jnp.arange(n)[None, :]
    pair = free[:, None] & free[None, :] & ~jnp.eye(n, dtype=bool) & ~parallel & ~partners
    return jnp.any(pair & (s > 0) & (t > 0) & close & inside)


def region_box(rays: GazeRays, region) -> Float[Array, "2 3"]:
    """The bounds box of ``region = (box, floor below the eyes)`` with its floor raised to that far under the lowest eye."""
    bounds, floor_below_eyes = region
    lowest = jnp.min(jnp.where(rays.mask, rays.origins[:, 2], jnp.inf))
    return bounds.at[0, 2].max(jnp.where(jnp.isfinite(lowest), lowest - floor_below_eyes, -jnp.inf))


def warm_frame(
    rays: GazeRays,
    previous: tuple[Float[Array, "K 3"], Bool[Array, " K"]],
    frame: Int[Array, ""],
    seed_depths: Float[Array, " D"],
    region,
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> tuple[Concurrences, Array]:
    """One frame seeded from the previous frame's modes plus ``FRESH_SEEDS_PER_RAY`` seeds per ray
    (Park et al. 2012, Sec. 3.3), and whether rays are left unexplained (:func:`unexplained`)."""
    locations, valid = previous
    fresh, fresh_ok = seeds_along_rays(rays, fresh_depths(seed_depths, frame))
    seeds = jnp.concatenate([locations, fresh])
    seed_ok = jnp.concatenate([valid, fresh_ok])
    # The previous modes converge in a few steps; fresh seeds still climbing after the first stage
    # stay candidates, and a new concurrence they miss leaves unexplained rays behind.
    warm = dataclasses.replace(options, max_iter=min(options.max_iter, WARM_MAX_ITER))
    found = concurrences_from_seeds(rays, seeds, seed_ok, region, options=warm, max_modes=max_modes,
                                     modes_per_batch=modes_per_batch)
    radius = options.claim_bandwidths * options.search_scale
    return found, unexplained(rays, found, region_box(rays, region), radius)
