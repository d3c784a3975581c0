"""Fused mean-shift kernel for GPUs (Pallas), used by :func:`jaxgaze.meanshift` there.

The XLA formulation of eq. 6 (Park et al. 2012; ``concurrence._meanshift_step``)
writes the ``seeds × rays`` weights and projections to GPU memory at every
iteration, which caps it at about 40 bytes of memory traffic per
pair-iteration. This kernel keeps a block of seeds in registers for the whole
run and streams the per-ray constants (a few KiB, L1/L2-resident) past them:

* one program owns ``block_seeds`` seeds and loops over iterations;
* per iteration it sweeps the rays in tiles of ``block_rays``, computing each
  pair's depth ``t`` and cross-section offsets ``(a, b)`` from the ray's
  orthonormal frame, the weight ``w = exp(−r²/2h²t²)/(h³t²)`` and the sums
  ``Σw``, ``Σw p`` and ``Σw (r²/t + t) v`` of eq. 6 — nothing of size
  ``seeds × rays`` ever leaves the chip;
* with stretched steps (``max_stretch > 1``) a second sweep evaluates ``f``
  (eq. 3, up to its positive constant) at the candidates ``x + s (m − x)`` and
  keeps the best, exactly as the XLA path does.

Seeds stop moving once a step is shorter than ``tol`` (that step is taken, as
in the XLA path); a program ends when all its seeds are done or at
``max_iter``. On CPU the same kernel runs in Pallas' interpreter, which is how
the tests compare it with the XLA path.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl

# Rows of the per-ray table (columns are rays, padded rays have zero weights).
_V, _U1, _U2, _OFFSET, _ORIGIN = 0, 3, 6, 9, 12  # each 3 rows
_EXPONENT, _WEIGHT, _FIELD = 15, 16, 17  # −log2(e)/2h², 1/h³ (0 if padded), 1/(h√2π) (0 if padded)
_TOL2, _MAX_ITER = 18, 19  # tol² and max_iter in every column (traced values reach the kernel as data)
_TABLE_ROWS = 32  # padded to a power of two for Triton


def ray_table(proj, num_columns: int, tol, max_iter):
    """The ``(32, num_columns)`` per-ray constants of a ``RayProjector`` (zero-padded rays) with ``tol²`` and ``max_iter``."""
    n = proj.origins.shape[0]
    basis = proj.basis.reshape(n, 3, 3)  # rows v, u1, u2 per ray
    offsets = proj.offsets.reshape(n, 3)
    field_weight = jnp.where(proj.mask, 1.0 / (proj.bandwidth * math.sqrt(2.0 * math.pi)), 0.0)
    rows = jnp.concatenate(
        [
            basis[:, 0, :].T, basis[:, 1, :].T, basis[:, 2, :].T, offsets.T, proj.origins.T,
            proj.exponent_scale[None] * math.log2(math.e), proj.weight_scale[None], field_weight[None],
        ],
        axis=0,
    ).astype(proj.origins.dtype)
    rows = jnp.where(jnp.isfinite(rows), rows, 0.0)
    table = jnp.zeros((_TABLE_ROWS, num_columns), rows.dtype)
    table = table.at[_TOL2].set(jnp.asarray(tol, rows.dtype) ** 2)
    table = table.at[_MAX_ITER].set(jnp.asarray(max_iter, rows.dtype))
    return table.at[: rows.shape[0], :n].set(rows)


def _approximate_reciprocal(x):
    """``1/x`` by the GPU's ``rcp.approx`` instruction (float32, relative error about 2⁻²³)."""
    from jax.experimental.pallas import triton as plgpu

    (out,) = plgpu.elementwise_inline_asm(
        "rcp.approx.ftz.f32 $0, $1;", args=[x], constraints="=r,r", pack=1,
        result_shape_dtypes=[jax.ShapeDtypeStruct(x.shape, x.dtype)],
    )
    return out


def _coordinates(tab_ref, columns, x, y, z, fast):
    """``(t, r², 1/t)`` of the seeds ``(x, y, z)`` against one tile of rays, each ``(S, R)``.

    ``1/t`` is 0 behind the eye; ``fast`` uses the hardware's approximate reciprocal (float32).
    """

    def row(k):
        return tab_ref[k, columns][None, :]

    def project(base, offset):
        return (x[:, None] * row(base) - row(offset)) + y[:, None] * row(base + 1) + z[:, None] * row(base + 2)

    t = project(_V, _OFFSET)
    a = project(_U1, _OFFSET + 1)
    b = project(_U2, _OFFSET + 2)
    r2 = a * a + b * b
    front = t > 0
    safe_t = jnp.where(front, t, 1.0)
    inv_t = jnp.where(front, _approximate_reciprocal(safe_t) if fast else 1.0 / safe_t, 0.0)
    return t, r2, inv_t, row


def _kernel(tab_ref, x_ref, y_ref, z_ref, ox_ref, oy_ref, oz_ref, it_ref, ok_ref, *,
            num_tiles, block_rays, stretches, fast):
    dtype = x_ref.dtype
    zero_tile = jnp.zeros((x_ref.shape[0], block_rays), dtype)

    def tile_columns(j):
        start = j * block_rays if isinstance(j, int) else pl.multiple_of(j * block_rays, block_rays)
        return pl.ds(start, block_rays)

    # Sums are kept per (seed, ray-in-tile) lane and reduced once after the sweep.
    def weighted_sums(x, y, z):
        def tile(j, acc):
            total, sx, sy, sz = acc
            t, r2, inv_t, row = _coordinates(tab_ref, tile_columns(j), x, y, z, fast)
            inv_t2 = inv_t * inv_t
            w = jnp.exp2(row(_EXPONENT) * r2 * inv_t2) * (inv_t2 * row(_WEIGHT))
            c = w * (r2 * inv_t + t)
            return (
                total + w,
                sx + w * row(_ORIGIN) + c * row(_V),
                sy + w * row(_ORIGIN + 1) + c * row(_V + 1),
                sz + w * row(_ORIGIN + 2) + c * row(_V + 2),
            )

        sums = jax.lax.fori_loop(0, num_tiles, tile, (zero_tile,) * 4)
        return tuple(jnp.sum(a, axis=1) for a in sums)

    def field(x, y, z):
        def tile(j, acc):
            _, r2, inv_t, row = _coordinates(tab_ref, tile_columns(j), x, y, z, fast)
            k = jnp.where(inv_t > 0, jnp.exp2(row(_EXPONENT) * r2 * inv_t * inv_t), 0.0) * row(_FIELD)
            return acc + k

        return jnp.sum(jax.lax.fori_loop(0, num_tiles, tile, zero_tile), axis=1)

    tol2 = jnp.max(tab_ref[_TOL2, tile_columns(0)])
    max_iter = jnp.max(tab_ref[_MAX_ITER, tile_columns(0)]).astype(jnp.int32)

    def cond(state):
        it, pending = state[3], state[5]
        return (it < max_iter) & (pending > 0)

    def body(state):
        x, y, z, it, done, _, alive, count = state
        total, sx, sy, sz = weighted_sums(x, y, z)
        moves = total > 0
        safe = jnp.where(moves, total, 1.0)
        mx = jnp.where(moves, sx / safe, x)
        my = jnp.where(moves, sy / safe, y)
        mz = jnp.where(moves, sz / safe, z)
        if len(stretches) == 1:
            nx, ny, nz = mx, my, mz
        else:
            # Candidates x + s (m − x), s = 1 first, as the XLA path builds them.
            nx, ny, nz = x + (mx - x), y + (my - y), z + (mz - z)
            best_f = field(nx, ny, nz)
            for s in stretches[1:]:
                cx, cy, cz = x + s * (mx - x), y + s * (my - y), z + s * (mz - z)
                f = field(cx, cy, cz)
                better = f > best_f
                best_f = jnp.where(better, f, best_f)
                nx, ny, nz = jnp.where(better, cx, nx), jnp.where(better, cy, ny), jnp.where(better, cz, nz)
        step2 = (mx - x) ** 2 + (my - y) ** 2 + (mz - z) ** 2
        active = done == 0
        x, y, z = jnp.where(active, nx, x), jnp.where(active, ny, y), jnp.where(active, nz, z)
        alive = jnp.where(active, moves.astype(jnp.int32), alive)
        count = jnp.where(active, count + 1, count)
        done = jnp.where(active & (step2 < tol2), 1, done)
        pending = jnp.max(1 - done)
        return x, y, z, it + 1, done, pending, alive, count

    ones = jnp.ones(x_ref.shape, jnp.int32)
    state = (x_ref[...], y_ref[...], z_ref[...], jnp.int32(0), 0 * ones, jnp.int32(1), ones, 0 * ones)
    x, y, z, _, done, _, alive, count = jax.lax.while_loop(cond, body, state)
    ox_ref[...] = x
    oy_ref[...] = y
    oz_ref[...] = z
    it_ref[...] = count
    ok_ref[...] = done * alive


@functools.partial(
    jax.jit, static_argnames=("max_stretch", "block_seeds", "block_rays", "num_warps", "approximate", "interpret")
)
def fused_meanshift(proj, seeds, tol, *, max_iter, max_stretch: int, block_seeds: int = 64,
                    block_rays: int = 32, num_warps: int = 4, approximate: bool = True, interpret: bool = False):
    """Mean-shift every seed with the fused kernel (Park et al. 2012, eq. 6): ``(points, iterations, converged)``.

    ``proj`` is the ``RayProjector`` of the rays; arguments as in :func:`jaxgaze.meanshift`.
    ``approximate`` uses the hardware reciprocal for ``1/t`` in float32 on a GPU.
    The tile defaults are the fastest of 14 shapes timed on an H100 (``benchmarks/RESULTS.md``).
    Triton (jax 0.11) crashed compiling shapes with ``block_seeds ≥ 32 num_warps``; they are refused.
    """
    if block_seeds >= 32 * num_warps and not interpret:
        raise ValueError(f"block_seeds ({block_seeds}) must be below 32 × num_warps ({32 * num_warps}) for the GPU kernel")
    dtype = seeds.dtype
    num_seeds, num_rays = seeds.shape[0], proj.origins.shape[0]
    padded_rays = max(block_rays, pl.cdiv(num_rays, block_rays) * block_rays)
    padded_seeds = max(block_seeds, pl.cdiv(num_seeds, block_seeds) * block_seeds)
    table = ray_table(proj, padded_rays, tol, max_iter)
    coords = jnp.zeros((3, padded_seeds), dtype).at[:, :num_seeds].set(seeds.T)
    stretches = tuple(float(2.0**k) for k in range(int(math.log2(max_stretch)) + 1))
    kernel = functools.partial(
        _kernel, num_tiles=padded_rays // block_rays, block_rays=block_rays, stretches=stretches,
        fast=approximate and (dtype == jnp.float32) and not interpret,
    )
    seed_block = pl.BlockSpec((block_seeds,), lambda i: (i,))
    whole = pl.BlockSpec((_TABLE_ROWS, padded_rays), lambda i: (0, 0))
    vec = jax.ShapeDtypeStruct((padded_seeds,), dtype)
    ivec = jax.ShapeDtypeStruct((padded_seeds,), jnp.int32)
    compiler_params = None
    if not interpret:
        from jax.experimental.pallas import triton as plgpu

        compiler_params = plgpu.CompilerParams(num_warps=num_warps, num_stages=1)
    x, y, z, iterations, converged = pl.pallas_call(
        kernel,
        out_shape=(vec, vec, vec, ivec, ivec),
        grid=(padded_seeds // block_seeds,),
        in_specs=[whole, seed_block, seed_block, seed_block],
        out_specs=(seed_block,) * 5,
        interpret=interpret,
        compiler_params=compiler_params,
    )(table, coords[0], coords[1], coords[2])
    points = jnp.stack([x, y, z], axis=1)[:num_seeds]
    return points, iterations[:num_seeds], converged[:num_seeds] > 0
