"""NUTS inside one ``jax.jit``, batched over independent datasets (shared by the numpyro models).

numpyro's ``MCMC`` runs one dataset at a time, and in numpyro 0.22 it recompiles
its sampling loop on every ``run`` when the progress bar is off (a fresh closure
defeats jit's cache; fixed upstream in numpyro PR #2171). Our fits are many small
independent posteriors of the same model (one per wearer or person), so
:func:`sample_nuts` runs numpyro's own NUTS kernel (``numpyro.infer.hmc.hmc``) for
each of them: ``lax.scan`` over iterations inside one ``jax.jit``, one compilation
per model, data shape and setting, reused for every dataset. The model's potential energy and
the constrained values come from ``numpyro.infer.util`` (``potential_energy``,
``constrain_fn``), so the model stays a plain numpyro function.

A progress bar (tqdm) is fed from inside the compiled loop by ``jax.debug.callback``.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer.hmc import hmc
from numpyro.infer.util import constrain_fn, potential_energy

__all__ = ["sample_nuts", "quiet_single_chain"]

#: The progress bar advances every this many iterations.
REPORT_EVERY = 25
_progress = None  # (tqdm bar, iterations done before this chain) of the fit that is running


def _report(iteration):
    if _progress is not None:
        bar, base = _progress
        bar.update(max(0, base + int(np.max(iteration)) - bar.n))


def _one_chain(model, key, model_args, init_params, num_warmup, num_samples, dense_mass, target_accept_prob):
    def potential_fn_gen(*args):
        return functools.partial(potential_energy, model, args, {})

    init_kernel, sample_kernel = hmc(potential_fn_gen=potential_fn_gen, algo="NUTS")
    state = init_kernel(init_params, num_warmup, dense_mass=dense_mass, target_accept_prob=target_accept_prob,
                        model_args=model_args, rng_key=key)

    def step(s, i):
        s = sample_kernel(s, model_args=model_args)
        jax.lax.cond((i + 1) % REPORT_EVERY == 0, lambda: jax.debug.callback(_report, i + 1), lambda: None)
        stats = {"diverging": s.diverging, "acceptance_rate": s.accept_prob, "n_steps": s.num_steps,
                 "lp": -s.potential_energy}
        return s, (s.z, stats)

    _, (z, stats) = jax.lax.scan(step, state, jnp.arange(num_warmup + num_samples))
    z, stats = jax.tree_util.tree_map(lambda a: a[num_warmup:], (z, stats))
    # One draw at a time (lax.map, not vmap): a model's batched LAPACK calls over all draws
    # can be large enough for XLA:CPU to split them over its thread pool and deadlock (see _batching).
    values = jax.lax.map(lambda u: constrain_fn(model, model_args, {}, u, return_deterministic=True), z)
    return values, stats


@functools.partial(jax.jit, static_argnames=("model", "num_warmup", "num_samples", "dense_mass", "target_accept_prob"))
def _single(model, key, model_args, init_params, num_warmup, num_samples, dense_mass, target_accept_prob):
    return _one_chain(model, key, model_args, init_params, num_warmup, num_samples, dense_mass, target_accept_prob)


def sample_nuts(
    model,
    key,
    model_args: tuple,
    init_params: dict,
    *,
    num_warmup: int,
    num_samples: int,
    dense_mass: bool = False,
    target_accept_prob: float = 0.8,
    progress_bar: bool = False,
    description: str = "NUTS",
) -> tuple[dict, dict]:
    """Draw from ``B`` independent posteriors of one numpyro ``model`` with NUTS.

    The ``B`` chains run one after the other through one compiled single-chain
    program. (A ``vmap`` over chains batches NUTS's tree-building while-loops: every
    chain waits for the deepest tree of the batch at every iteration, and it
    compiles far slower.)

    Args:
        model: a numpyro model ``model(*args)``; it must be hashable and the same
            object from call to call (e.g. a module-level function or a cached
            ``functools.partial``), since it keys the compilation.
        key: one ``jax.random`` key, split into ``B`` chain keys.
        model_args: a tuple of arrays, each with a leading batch axis ``B``.
        init_params: starting points in numpyro's *unconstrained* space, a dict of
            arrays with leading axis ``B`` (e.g. ``log σ`` for a positive site).
        num_warmup, num_samples: NUTS adaptation and kept iterations per chain.
        dense_mass, target_accept_prob: as in ``numpyro.infer.NUTS``.
        progress_bar: show a tqdm bar over all iterations of all chains.

    Returns:
        ``(values, stats)``: dicts of arrays ``(B, num_samples, ...)``; ``values``
        holds every sample and deterministic site in the constrained space,
        ``stats`` the sampler statistics (``diverging``, ``acceptance_rate``,
        ``n_steps``, ``lp``).
    """
    global _progress
    sizes = {np.shape(a)[0] for a in jax.tree_util.tree_leaves((model_args, init_params))}
    if len(sizes) != 1:
        raise ValueError(f"model_args and init_params need one common leading batch axis, got sizes {sorted(sizes)}")
    batch = sizes.pop()
    keys = jax.random.split(key, batch)
    per_chain = int(num_warmup) + int(num_samples)
    from tqdm.auto import tqdm

    runs = []
    with tqdm(total=batch * per_chain, desc=description, disable=not progress_bar, leave=False) as bar:
        try:
            for b in range(batch):
                _progress = (bar, b * per_chain) if progress_bar else None
                pick = functools.partial(jax.tree_util.tree_map, lambda a: a[b])
                runs.append(_single(model, keys[b], pick(model_args), pick(init_params), int(num_warmup),
                                    int(num_samples), bool(dense_mass), float(target_accept_prob)))
            runs = jax.block_until_ready(runs)
            jax.effects_barrier()
        finally:
            _progress = None
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *runs)


@contextlib.contextmanager
def quiet_single_chain(num_chains: int):
    """arviz logs that r-hat needs two chains (it is NaN then); keep one-chain summaries quiet."""
    if num_chains > 1:
        yield
        return
    import arviz

    # arviz logs through its own ``Logger("arviz")`` instance, not ``logging.getLogger``.
    loggers = [log for log in (getattr(arviz, "_log", None), logging.getLogger("arviz")) if log is not None]
    levels = [log.level for log in loggers]
    for log in loggers:
        log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            yield
    finally:
        for log, level in zip(loggers, levels):
            log.setLevel(level)
