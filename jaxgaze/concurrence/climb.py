"""The two-stage mean-shift of the concurrence search (Park et al. 2012, eq. 6; :mod:`jaxgaze.concurrence.frame`, step 2).

Every seed climbs ``FIRST_STAGE_ITERATIONS``; the most promising of those still
moving climb on to ``max_iter``. On CPU each iteration is one evaluation of the
update and the field per seed, stretched adaptively, with the seeds still moving
compacted between rounds; on GPU each stage is :func:`~jaxgaze.concurrence.meanshift`.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.concurrence.field import RayProjector, meanshift, ray_coordinates, ray_projector
from jaxgaze.concurrence.types import MeanShiftResult

__all__ = ["two_stage_meanshift", "FIRST_STAGE_ITERATIONS"]

#: Mean-shift iterations every seed gets before only the most promising go on.
FIRST_STAGE_ITERATIONS = 40


_CLIMB_STRETCH = 32  # longest stretch of an accepted step, as meanshift's default max_stretch
_CLIMB_CHUNK = 256  # seeds climbed together between compactions (all of them when there are fewer)
_CLIMB_ROUND = 8  # evaluations per seed between compactions in the first stage


class _Climb(NamedTuple):
    """Per-seed state of the adaptive ascent of :func:`two_stage_meanshift`."""

    x: Float[Array, "S 3"]
    value: Float[Array, " S"]  # f(x), eq. 3
    target: Float[Array, "S 3"]  # m(x), eq. 6
    stretch: Float[Array, " S"]  # the next proposal is x + stretch · (m(x) − x)
    iterations: Int[Array, " S"]  # evaluations of f and m spent on the seed
    done: Bool[Array, " S"]  # ‖m(x) − x‖ < tol (also where every weight underflows: m(x) = x)
    alive: Bool[Array, " S"]  # Σ w > 0 at x


def _climb_values(proj: RayProjector, x: Float[Array, "3"]) -> tuple[Array, Array, Array]:
    """``(m(x), f(x), Σ w)`` in one pass over the rays: eq. 6's update (as :func:`meanshift_step`) and
    eq. 3's field (as :func:`field_value`) share the kernel ``exp(−r²/2h²t²)``."""
    t, r2, ok, inv_t = ray_coordinates(proj, x)
    inv_t2 = inv_t * inv_t
    kernel = jnp.where(ok, jnp.exp(proj.exponent_scale * r2 * inv_t2), 0.0)
    w = kernel * (inv_t2 * proj.weight_scale)
    total = jnp.sum(w)
    exact = jax.lax.Precision.HIGHEST
    target = jnp.matmul(w, proj.origins, precision=exact) + jnp.matmul(w * (r2 * inv_t + t), proj.directions, precision=exact)
    m = jnp.where(total > 0, target / jnp.where(total > 0, total, 1.0), x)
    value = jnp.sum(kernel / (proj.bandwidth * math.sqrt(2.0 * math.pi))) / jnp.maximum(jnp.sum(proj.mask), 1)
    return m, value, total


def _climb_start(proj: RayProjector, seeds: Float[Array, "S 3"], tol) -> _Climb:
    m, value, total = jax.vmap(functools.partial(_climb_values, proj))(seeds)
    count = seeds.shape[0]
    return _Climb(seeds, value, m, jnp.ones(count, seeds.dtype), jnp.zeros(count, jnp.int32),
                  jnp.linalg.norm(m - seeds, axis=-1) < tol, total > 0)


def _climb_step(proj: RayProjector, state: _Climb, go: Bool[Array, " S"], tol, limit) -> _Climb:
    """One evaluation per seed of ``go`` still climbing: the proposal ``x + s (m(x) − x)`` is taken if
    ``f`` does not fall there (always for ``s = 1``, eq. 6, by Park et al. 2012, Theorem 1); then ``s``
    doubles, up to ``_CLIMB_STRETCH``. A refused proposal costs the evaluation and sets ``s = 1``."""
    x, s = state.x, state.stretch
    active = go & ~state.done & (state.iterations < limit)
    proposal = x + s[:, None] * (state.target - x)
    m, value, total = jax.vmap(functools.partial(_climb_values, proj))(proposal)
    accept = (value >= state.value) | (s <= 1)
    move = active & accept
    x = jnp.where(move[:, None], proposal, x)
    m = jnp.where(move[:, None], m, state.target)
    return _Climb(
        x=x,
        value=jnp.where(move, value, state.value),
        target=m,
        stretch=jnp.where(active, jnp.where(accept, jnp.minimum(2.0 * s, _CLIMB_STRETCH), 1.0), s),
        iterations=state.iterations + active.astype(jnp.int32),
        done=state.done | (move & (jnp.linalg.norm(m - x, axis=-1) < tol)),
        alive=jnp.where(move, total > 0, state.alive),
    )


def _climb(proj: RayProjector, state: _Climb, eligible: Bool[Array, " S"], tol, limit) -> _Climb:
    """Climb every ``eligible`` seed until it is done or has spent ``limit`` evaluations.

    The seeds still climbing are gathered first and taken ``_CLIMB_CHUNK`` at a
    time, each chunk a ``lax.while_loop`` that ends when its last seed stops, so
    seeds that are done cost nothing.
    """
    count = state.x.shape[0]
    chunk = min(_CLIMB_CHUNK, count)
    climbing = eligible & ~state.done & (state.iterations < limit)
    order = jnp.argsort(~climbing, stable=True)
    remaining = jnp.sum(climbing)

    def one_chunk(k, state):
        position = k * chunk + jnp.arange(chunk)
        go = position < remaining
        index = jnp.where(go, order.at[position].get(mode="clip"), count)  # out of range: not written back
        part = jax.tree_util.tree_map(lambda a: a.at[index].get(mode="clip"), state)
        part = jax.lax.while_loop(
            lambda p: jnp.any(go & ~p.done & (p.iterations < limit)),
            lambda p: _climb_step(proj, p, go, tol, limit),
            part,
        )
        return jax.tree_util.tree_map(lambda a, b: a.at[index].set(b, mode="drop"), state, part)

    return jax.lax.fori_loop(0, (remaining + chunk - 1) // chunk, one_chunk, state)


def two_stage_meanshift(rays, seeds, seed_ok, *, tol, max_iter, keep):
    """Mean-shift all seeds for a few iterations, then only the most promising to the end (Park et al. 2012, eq. 6).

    Under ``vmap`` every seed would run as long as the slowest one, and the slow
    ones are mostly seeds sliding along a lone ray that will be rejected anyway.
    So all seeds get ``FIRST_STAGE_ITERATIONS``; of those still moving, the
    ``keep`` with the highest ``f`` continue up to ``max_iter``. The others keep
    their (uphill) positions and stay candidates.

    On GPU each stage is :func:`meanshift` (the fused kernel). On CPU each
    iteration is a single evaluation of ``m`` and ``f`` per seed: the step is
    stretched adaptively (:func:`_climb_step`, ``f`` never decreases) rather than
    by trying every stretch, and the seeds still moving are compacted every
    ``_CLIMB_ROUND`` iterations (:func:`_climb`), so converged seeds stop costing.
    """
    first_stage = min(max_iter, FIRST_STAGE_ITERATIONS)
    keep = min(keep, seeds.shape[0])
    if jax.default_backend() == "gpu":
        return _two_stage_fused(rays, seeds, seed_ok, tol=tol, max_iter=max_iter, keep=keep)
    proj = ray_projector(rays)

    def rounds(state, eligible, limits):  # one compiled loop body per stage
        limits = jnp.asarray(limits, jnp.int32)
        return jax.lax.fori_loop(0, len(limits), lambda r, st: _climb(proj, st, eligible, tol, limits[r]), state)

    state = rounds(_climb_start(proj, seeds, tol), seed_ok, [*range(_CLIMB_ROUND, first_stage, _CLIMB_ROUND), first_stage])
    if max_iter > first_stage:
        moving = seed_ok & ~state.done
        _, chosen = jax.lax.top_k(jnp.where(moving, state.value, -jnp.inf), keep)
        eligible = jnp.zeros_like(moving).at[chosen].set(moving[chosen])
        longer = [first_stage * 2**k for k in range(1, 4) if first_stage * 2**k < max_iter]
        state = rounds(state, eligible, [*longer, max_iter])
    return MeanShiftResult(state.x, state.value, state.iterations, state.done & state.alive)


def _two_stage_fused(rays, seeds, seed_ok, *, tol, max_iter, keep):
    """:func:`two_stage_meanshift` with :func:`meanshift` (on GPU, the fused kernel) for each stage."""
    first = meanshift(rays, seeds, tol=tol, max_iter=min(max_iter, FIRST_STAGE_ITERATIONS))
    if max_iter <= FIRST_STAGE_ITERATIONS:
        return first
    moving = seed_ok & ~first.converged
    _, chosen = jax.lax.top_k(jnp.where(moving, first.field_values, -jnp.inf), keep)
    second = meanshift(rays, first.points[chosen], tol=tol, max_iter=max_iter - FIRST_STAGE_ITERATIONS)
    go_on = moving[chosen]

    def merge(a, b):
        return a.at[chosen].set(jnp.where(go_on.reshape((-1,) + (1,) * (b.ndim - 1)), b, a[chosen]))

    return MeanShiftResult(
        points=merge(first.points, second.points),
        field_values=merge(first.field_values, second.field_values),
        iterations=merge(first.iterations, first.iterations[chosen] + second.iterations),
        converged=merge(first.converged, second.converged),
    )
