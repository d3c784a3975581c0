"""Batch sizes that keep XLA:CPU's batched LAPACK calls from deadlocking, and a chunked driver.

jaxlib 0.10.0 – 0.11.0 split a batched LAPACK call (``jnp.linalg.inv``, ``eigh``,
``qr``, ``cholesky``, triangular solves …) across XLA:CPU's intra-op thread pool
when ``batch × flops per matrix ≥ 200 000``, and the pool thread that made the
call then *blocks* until its pieces are done. When the thunk executor runs as
many such calls at once as the pool has threads (two on a 2-core machine),
every pool thread waits for work that only a pool thread could do: the
process hangs forever at 0 % CPU. ``--xla_cpu_multi_thread_eigen=false`` does
not change the pool these calls use. ``docs/runtime.md`` has the whole story.

A call whose batch stays below the threshold runs inline and never waits, so a
program in which *every* batched LAPACK call stays below it cannot deadlock this
way, however many of its calls or programs run at once. The models size their
batches with :func:`lapack_safe_batch` and the cost formulas below (those of
jaxlib's ``GetLapackBatchChunkSize``), with a factor of two to spare, and run
long batches through :func:`map_in_batches`. The test suite checks the compiled
programs' LAPACK calls against the same formulas.
"""

from __future__ import annotations

import itertools
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "LAPACK_SPLIT_WORK",
    "lapack_qr_cost",
    "lapack_eigh_cost",
    "lapack_lu_cost",
    "lapack_safe_batch",
    "lapack_guard_applies",
    "map_in_batches",
    "frame_sharding",
    "repeat_last",
]

#: ``batch × flops per matrix`` at which jaxlib splits a batched LAPACK call over the pool.
LAPACK_SPLIT_WORK = 200_000
#: What the models allow themselves: half of it, in case a cost estimate is low.
_BUDGET = LAPACK_SPLIT_WORK // 2


def lapack_qr_cost(rows: int, cols: int) -> int:
    """jaxlib's flop estimate of one ``geqrf`` of a ``rows × cols`` matrix."""
    k = min(rows, cols)
    return 2 * rows * cols * k - (2 * k**3) // 3


def lapack_eigh_cost(n: int) -> int:
    """jaxlib's flop estimate of one symmetric eigendecomposition (``syevd``) of ``n × n``."""
    return 5 * n**3


def lapack_lu_cost(n: int) -> int:
    """jaxlib's flop estimate of one LU factorisation (``getrf``) of ``n × n``."""
    return n**3


def lapack_safe_batch(cost_per_item: int, cap: int) -> int:
    """Largest batch ``≤ cap`` (and ≥ 1) whose LAPACK work stays within half the split threshold.

    ``cost_per_item`` is the largest LAPACK flop estimate that one batch element
    adds to a single call (e.g. ``modes × lapack_qr_cost(m, 3)`` for one frame).
    Returns 1 when even one element is over budget: the caller must then batch
    inside the element too.
    """
    if cost_per_item <= 0:
        return max(1, int(cap))
    return max(1, min(int(cap), _BUDGET // int(cost_per_item)))


def lapack_guard_applies() -> bool:
    """Whether the default backend is XLA:CPU, whose LAPACK calls need the batch bound."""
    return jax.default_backend() == "cpu"


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def repeat_last(tree, size: int):
    """Pad every leaf's leading axis to ``size`` by repeating its last entry."""
    def pad(a):
        extra = size - a.shape[0]
        return np.concatenate([a, np.repeat(a[-1:], extra, axis=0)]) if extra else a

    return jax.tree_util.tree_map(pad, tree)


def map_in_batches(
    fn: Callable,
    tree,
    batch: int,
    *,
    pad: Callable | None = None,
    progress: bool = False,
    desc: str | None = None,
    unit: str = "frame",
):
    """``fn`` over consecutive ``batch``-long slices of ``tree``'s leading axis, joined on the host.

    Every call of ``fn`` sees the same leading size (the last or only slice is
    padded by ``pad(part, size)``, by default by repeating its last entry, and the
    padding is cut from the result), so a jitted ``fn`` compiles once whatever the
    length. On XLA:CPU the slices run on as many host threads as the process has
    cores: a batch small enough for the LAPACK bound keeps one core busy, so two
    slices at a time keep two busy. Returns ``fn``'s output pytree with numpy
    leaves of length ``T``.

    **Many devices.** With ``D > 1`` local devices each slice is padded to
    ``size = ⌈batch / D⌉ · D`` entries and its leading axis is split over a
    one-axis ``Mesh`` of them (``NamedSharding(mesh, PartitionSpec("frames"))``),
    so a device's share of every batched LAPACK call is smaller than the batch
    the bound was sized for. **Many processes.** Under ``jax.distributed``
    (``jax.process_count() = P > 1``) process ``p`` runs the slices
    ``⌊pS/P⌋ … ⌊(p+1)S/P⌋ − 1`` of the ``S`` and the parts are gathered on every
    process with ``process_allgather``. Slice boundaries are those of one
    device in one process, so ``fn`` must treat the entries of a slice independently
    (a ``vmap``); then the result does not depend on ``D`` or ``P``, up to the
    rounding of differently sized programs.
    """
    leaves = jax.tree_util.tree_leaves(tree)
    if not leaves:
        raise ValueError("map_in_batches needs at least one array")
    total = int(np.shape(leaves[0])[0])
    if total == 0:
        raise ValueError("map_in_batches needs at least one entry along the leading axis")
    batch = max(1, int(batch))
    host = jax.tree_util.tree_map(np.asarray, tree)
    pad = pad or repeat_last
    devices = jax.local_devices()
    size = -(-batch // len(devices)) * len(devices)
    sharding = frame_sharding(devices) if len(devices) > 1 else None
    starts = range(0, total, batch)
    processes = jax.process_count()
    share = [starts[_process_share(len(starts), p, processes)] for p in range(processes)]
    mine = share[jax.process_index()]

    def frames_in(slices):
        return sum(min(batch, total - start) for start in slices)

    def slice_at(start):
        part = jax.tree_util.tree_map(lambda a: a[start:start + batch], host)
        count = min(batch, total - start)
        return (pad(part, size) if count < size else part), count

    def run(start):
        part, count = slice_at(start)
        if sharding is not None:
            part = jax.device_put(part, sharding)
        out = fn(part)
        return jax.tree_util.tree_map(lambda a: np.asarray(a)[:count], out), count

    from tqdm.auto import tqdm

    cores = _cpu_count() if lapack_guard_applies() else 1
    workers = max(1, min(len(mine), cores // len(devices)))
    pool = ThreadPoolExecutor(max_workers=workers)
    parts = []
    try:
        with tqdm(total=frames_in(mine), unit=unit, desc=desc, disable=not progress, file=sys.stderr) as bar:
            if mine:
                # The first slice alone, so that ``fn`` compiles once rather than once per thread.
                first = run(mine[0])
                futures = [pool.submit(run, start) for start in mine[1:]]
                for out, count in itertools.chain([first], (future.result() for future in futures)):
                    parts.append(out)
                    bar.update(count)
    finally:
        # On an error or Ctrl-C: drop the slices not started, let the running ones finish.
        pool.shutdown(wait=True, cancel_futures=True)
    if processes == 1:
        return jax.tree_util.tree_map(lambda *a: np.concatenate(a, axis=0), *parts)
    if parts:
        local = jax.tree_util.tree_map(lambda *a: np.concatenate(a, axis=0), *parts)
    else:  # more processes than slices: this one only takes part in the gathering
        shapes = jax.eval_shape(fn, slice_at(0)[0])
        local = jax.tree_util.tree_map(lambda s: np.zeros((0,) + s.shape[1:], s.dtype), shapes)
    return _gather_shares(local, [frames_in(slices) for slices in share])


def frame_sharding(devices) -> NamedSharding:
    """The leading (frame) axis split over ``devices``: ``NamedSharding(Mesh(devices, ("frames",)), P("frames"))``."""
    return NamedSharding(Mesh(np.asarray(devices), ("frames",)), PartitionSpec("frames"))


def _process_share(num_slices: int, process: int, processes: int) -> slice:
    """Process ``process``'s contiguous share of ``num_slices`` slices: ``⌊pS/P⌋ … ⌊(p+1)S/P⌋ − 1``."""
    return slice(process * num_slices // processes, (process + 1) * num_slices // processes)


def _gather_shares(local, shares: list[int]):
    """Every process's part (``shares[p]`` entries long), joined in process order on every process.

    ``process_allgather`` needs one shape everywhere, so each part is padded with zeros to the longest.
    """
    longest = max(shares)

    def pad(a):
        return np.concatenate([a, np.zeros((longest - a.shape[0],) + a.shape[1:], a.dtype)])

    gathered = multihost_utils.process_allgather(jax.tree_util.tree_map(pad, local), tiled=False)
    return jax.tree_util.tree_map(
        lambda g, a: np.concatenate([np.asarray(g[p, :n]) for p, n in enumerate(shares)]).astype(a.dtype, copy=False),
        gathered, local)
