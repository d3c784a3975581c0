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
import math
import warnings
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpyro.infer.hmc import hmc
from numpyro.infer.util import constrain_fn, potential_energy

from jaxgaze import _progress
from jaxgaze.results import RESULTS

__all__ = ["sample_nuts", "laplace_inverse_mass", "laplace_parts", "MixingDiagnostics", "SamplerReport", "sampler_report",
           "mixing_diagnostics", "mixing_result", "posterior_summary", "split_chains", "set_units",
           "quiet_single_chain", "MAX_RHAT", "MIN_ESS", "MAX_DIVERGENT_SHARE", "MIN_ACCEPTANCE", "HDI_PROB"]

#: Diagnostics every NUTS posterior must pass (:func:`mixing_result`): split r-hat at most this …
MAX_RHAT = 1.05
#: … bulk and tail ESS at least this …
MIN_ESS = 100
#: … at most this share of divergent transitions …
MAX_DIVERGENT_SHARE = 0.01
#: … and a mean acceptance probability of at least this (the step size adapts towards 0.8–0.9;
#: a chain that never moved has 0).
MIN_ACCEPTANCE = 0.5
#: The credible level of the HDIs in every posterior summary.
HDI_PROB = 0.9

#: The progress bar advances every this many iterations.
REPORT_EVERY = 25


def _one_chain(model, key, model_args, init_params, inverse_mass_matrix, num_warmup, num_samples, dense_mass,
               target_accept_prob):
    def potential_fn_gen(*args):
        return functools.partial(potential_energy, model, args, {})

    init_kernel, sample_kernel = hmc(potential_fn_gen=potential_fn_gen, algo="NUTS")
    state = init_kernel(init_params, num_warmup, inverse_mass_matrix=inverse_mass_matrix,
                        adapt_mass_matrix=inverse_mass_matrix is None, dense_mass=dense_mass,
                        target_accept_prob=target_accept_prob, model_args=model_args, rng_key=key)

    def step(s, i):
        s = sample_kernel(s, model_args=model_args)
        jax.lax.cond((i + 1) % REPORT_EVERY == 0, lambda: jax.debug.callback(_progress.reach, i + 1), lambda: None)
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
def _single(model, key, model_args, init_params, inverse_mass_matrix, num_warmup, num_samples, dense_mass,
            target_accept_prob):
    return _one_chain(model, key, model_args, init_params, inverse_mass_matrix, num_warmup, num_samples, dense_mass,
                      target_accept_prob)


def sample_nuts(
    model,
    key,
    model_args: tuple,
    init_params: dict,
    *,
    num_warmup: int,
    num_samples: int,
    dense_mass: bool = False,
    inverse_mass_matrix=None,
    target_accept_prob: float = 0.8,
    progress: bool = False,
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
        inverse_mass_matrix: ``None`` (start from the identity and adapt the mass matrix
            in the warm-up windows), or ``(B, D, D)`` (``(B, D)`` diagonal) per chain, over
            the parameters flattened in ``jax.tree_util`` order, kept fixed while the
            step size adapts. A good one, such as the inverse Hessian of the potential
            at the mode, saves the warm-up's early windows, which with the identity take
            hundreds of leapfrog steps per draw on a badly scaled posterior.
        progress: show a tqdm bar over all iterations of all chains.

    Returns:
        ``(values, stats)``: dicts of arrays ``(B, num_samples, ...)``; ``values``
        holds every sample and deterministic site in the constrained space,
        ``stats`` the sampler statistics (``diverging``, ``acceptance_rate``,
        ``n_steps``, ``lp``).
    """
    sizes = {np.shape(a)[0] for a in jax.tree_util.tree_leaves((model_args, init_params))}
    if len(sizes) != 1:
        raise ValueError(f"model_args and init_params need one common leading batch axis, got sizes {sorted(sizes)}")
    batch = sizes.pop()
    if inverse_mass_matrix is not None:
        inverse_mass_matrix = jnp.asarray(inverse_mass_matrix)
        D = sum(int(np.prod(np.shape(a)[1:])) for a in jax.tree_util.tree_leaves(init_params))
        wanted = (batch, D, D) if dense_mass else (batch, D)
        if inverse_mass_matrix.shape != wanted:
            raise ValueError(f"inverse_mass_matrix must have shape {wanted}, got {inverse_mass_matrix.shape}")
    keys = jax.random.split(key, batch)
    per_chain = int(num_warmup) + int(num_samples)
    runs = []
    with _progress.progress_bar(progress, total=batch * per_chain, desc=description):
        for b in range(batch):
            _progress.set_offset(b * per_chain)
            pick = functools.partial(jax.tree_util.tree_map, lambda a: a[b])
            mass = None if inverse_mass_matrix is None else inverse_mass_matrix[b]
            runs.append(_single(model, keys[b], pick(model_args), pick(init_params), mass, int(num_warmup),
                                int(num_samples), bool(dense_mass), float(target_accept_prob)))
        runs = jax.block_until_ready(runs)
        jax.effects_barrier()
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *runs)


#: Step (numpyro's unconstrained units) of the central differences of the gradient that give
#: :func:`laplace_inverse_mass` its Hessian.
HESSIAN_STEP = 1e-3


def laplace_inverse_mass(potential_fn, params: dict, min_curvature: float):
    """NUTS's inverse mass matrix from the curvature of the potential at ``params``: a Laplace covariance.

    With ``H = V diag(λ) Vᵀ`` the Hessian of ``potential_fn`` (the negative log
    density, numpyro's unconstrained space) at ``params``, it returns
    ``V diag(1 / max(|λ|, λ_min)) Vᵀ`` over ``params`` flattened in ``jax.tree_util``
    order, the order :func:`sample_nuts` expects. At a mode this is the posterior's
    covariance to second order, so NUTS needs no warm-up windows to learn the
    scales. Where ``params`` is not a mode, a negative curvature's magnitude still
    gives the local length scale (as Betancourt's SoftAbs metric does); curvatures
    below ``min_curvature`` in magnitude are raised to it, and a non-finite Hessian
    gives the identity.

    The Hessian is the central difference of the exact gradient with step
    :data:`HESSIAN_STEP` (``2d`` gradients, one after the other on CPU and in one batch on an accelerator: on
    XLA:CPU the batch of 96 took 0.63 s where the same gradients one by one took 0.20 s, head pose only, 60 s × 6
    people, ``benchmarks/RESULTS.md``), not ``jax.hessian``: on the
    joint model (60 s × 6 people, ``d = 29``, float32) forward-over-reverse took 26.7 s to
    compile and ``jax.jacrev(jax.grad)`` 24.7 s, the differences 13.2 s, with the log
    determinant 0.001 nats and the diagonal 0.6% from the exact one (2026-12-05,
    ``benchmarks/RESULTS.md``). Exact for a quadratic potential up to rounding.
    """
    return laplace_parts(potential_fn, params, min_curvature)[0]


def laplace_parts(potential_fn, params: dict, min_curvature: float):
    """:func:`laplace_inverse_mass` and the gradient at ``params`` from the same ``2d`` gradients (flattened alike).

    The gradient is the mean of the ``d`` central pairs ``(∇U(θ + h e_i) + ∇U(θ − h e_i)) / 2``, exact for a
    quadratic potential up to rounding: with the inverse Hessian, it gives a Newton step ``−Σ ∇U`` at no further
    gradient (:func:`~jaxgaze.joint.infer.fit_joint` takes such steps to its mode before sampling)."""
    flat, unravel = ravel_pytree(params)
    gradient = jax.grad(lambda x: potential_fn(unravel(x)))
    steps = HESSIAN_STEP * jnp.eye(flat.shape[0], dtype=flat.dtype)
    both = jax.lax.map(gradient, flat + jnp.concatenate([steps, -steps]),
                       batch_size=None if jax.default_backend() == "cpu" else 2 * flat.shape[0])  # (2d, d)
    hessian = (both[: flat.shape[0]] - both[flat.shape[0]:]) / (2.0 * HESSIAN_STEP)
    curvature, axes = jnp.linalg.eigh(0.5 * (hessian + hessian.T))
    inverse = (axes / jnp.maximum(jnp.abs(curvature), min_curvature)) @ axes.T
    finite = jnp.all(jnp.isfinite(hessian))
    return (jnp.where(finite, inverse, jnp.eye(flat.shape[0], dtype=flat.dtype)),
            jnp.mean(both, axis=0))


class MixingDiagnostics(NamedTuple):
    """How a NUTS run mixed (:func:`mixing_diagnostics`); :func:`mixing_result` judges it.

    ``max_rhat``: the largest split r-hat (NaN when a variable never moved); ``min_ess_bulk``,
    ``min_ess_tail``: the smallest bulk and tail ESS; ``divergences`` of ``draws`` kept transitions
    (all chains); ``chains``: the sampler's chains; ``acceptance_rate``: the mean acceptance probability.
    """

    max_rhat: float
    min_ess_bulk: float
    min_ess_tail: float
    divergences: int
    draws: int
    chains: int
    acceptance_rate: float


class SamplerReport(NamedTuple):
    """How one NUTS posterior went, the same in every family (bias, GP, calibration, joint).

    Attributes:
        idata: the draws as an ``arviz.InferenceData`` (``posterior``, ``sample_stats``).
        result: :class:`~jaxgaze.results.RESULTS` of the sampler: ``successful``, or ``not_mixed``
            when :attr:`diagnostics` fail :func:`mixing_result`.
        diagnostics: :class:`MixingDiagnostics` (split r-hat, bulk and tail ESS, divergences, acceptance).
        summary: :func:`posterior_summary` of the main parameters (a ``pandas.DataFrame``: mean, sd,
            90% HDI, ESS, r-hat).
    """

    idata: Any
    result: RESULTS
    diagnostics: MixingDiagnostics
    summary: Any

    @property
    def succeeded(self) -> bool:
        """Whether the sampler mixed (``result`` is ``successful``)."""
        return bool(np.all(np.asarray(self.result == RESULTS.successful)))


def sampler_report(idata, var_names) -> SamplerReport:
    """The :class:`SamplerReport` of ``idata`` judged on ``var_names``: :func:`mixing_diagnostics`,
    :func:`mixing_result` and :func:`posterior_summary` in one call."""
    diagnostics = mixing_diagnostics(idata, var_names)
    return SamplerReport(idata, mixing_result(diagnostics), diagnostics, posterior_summary(idata, var_names))


#: Attribute of a posterior group laid out by :func:`split_chains`: the number of the sampler's chains.
SAMPLER_CHAINS = "sampler_chains"
_LAYOUT = ("each sampler chain split into halves: chains 2k and 2k+1 are the first and second half of sampler "
           "chain k (an odd last draw dropped), so that arviz's r-hat and ESS are the split r-hat and ESS reported")


def _split_dataset(dataset, num_chains):
    import xarray as xr

    n = dataset.sizes["draw"] // 2
    variables = {v: (dataset[v].dims, dataset[v].values[:, : 2 * n].reshape((-1, n) + dataset[v].shape[2:]),
                     dataset[v].attrs) for v in dataset.data_vars}
    coords = {d: dataset.coords[d] for d in dataset.coords if d not in ("chain", "draw")}
    coords.update(chain=np.arange(2 * dataset.sizes["chain"]), draw=np.arange(n))
    attrs = {**dataset.attrs, SAMPLER_CHAINS: int(num_chains), "chain_layout": _LAYOUT}
    return xr.Dataset(variables, coords=coords, attrs=attrs)


def _is_split(dataset) -> bool:
    return SAMPLER_CHAINS in dataset.attrs


def split_chains(idata):
    """``idata`` with each chain of its posterior and sample stats split into halves, as chains of their own.

    Chains ``2k`` and ``2k+1`` are the first and second half of sampler chain ``k`` (an odd
    last draw is dropped); the posterior's attribute ``sampler_chains`` holds the number of
    sampler chains. Split r-hat needs this of a single chain, which arviz cannot judge (r-hat
    NaN, a shape warning): in this layout arviz's own tools (``az.summary``, ``az.rhat``,
    ``az.ess``) give the r-hat :func:`mixing_diagnostics` reports, by construction, and its ESS
    when the ``idata`` it judged was laid out so (the ESS of whole chains differs by a few per cent).
    Other groups are kept; an ``idata`` already split, or without a posterior, is returned as it is.
    """
    import arviz as az

    posterior = getattr(idata, "posterior", None)
    if posterior is None or _is_split(posterior):
        return idata
    chains = posterior.sizes["chain"]
    groups = {name: getattr(idata, name) for name in idata.groups()}
    for name in ("posterior", "sample_stats"):
        if name in groups:
            groups[name] = _split_dataset(groups[name], chains)
    return az.InferenceData(**groups)


def set_units(idata, units: dict):
    """Write ``units[name]`` (e.g. ``"m"``, ``"rad"``, ``"1"``) into the attributes of every variable ``name``
    of every group of ``idata`` (in place; the netCDF keeps them); returns ``idata``."""
    for group in idata.groups():
        dataset = getattr(idata, group)
        for name in dataset.data_vars:
            if name in units:
                dataset[name].attrs["units"] = units[name]
    return idata


def _diagnostic_table(posterior):
    """Per element of ``posterior``: bulk and tail ESS of its chains as laid out, and the rank-normalised r-hat
    of the chains split in halves (:func:`split_chains`; a posterior already split is used as it is); arviz's,
    unrounded. On a posterior laid out by :func:`split_chains` all three are arviz's on that layout.

    An element that never moved within a chain has no ESS (0; arviz would give a
    constant chain the full ESS) and a NaN r-hat.
    """
    import arviz as az

    split = posterior if _is_split(posterior) else _split_dataset(posterior, posterior.sizes["chain"])
    with quiet_single_chain(1), np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # arviz divides by a zero variance on a stuck chain
        table = az.summary(posterior, kind="diagnostics", round_to="none")[["ess_bulk", "ess_tail"]]
        table["r_hat"] = az.summary(split, kind="diagnostics", round_to="none")["r_hat"].reindex(table.index)
    moved = [np.ptp(posterior[v].values, axis=1).reshape(posterior[v].shape[0], -1) for v in posterior.data_vars]
    never_moved = np.concatenate([np.any(m == 0, axis=0) for m in moved])  # in summary row order
    table.loc[never_moved, ["ess_bulk", "ess_tail"]] = 0.0
    table.loc[never_moved, "r_hat"] = np.nan
    return table


def _checked(idata, var_names):
    posterior = idata.posterior[[v for v in var_names if v in idata.posterior]]
    if not posterior.data_vars:
        raise ValueError(f"none of {list(var_names)} is in the posterior")
    return posterior


def mixing_diagnostics(idata, var_names) -> MixingDiagnostics:
    """Whether a NUTS run mixed: split r-hat, bulk and tail ESS (arviz), divergences and acceptance.

    ``idata`` is an ``arviz.InferenceData`` with ``posterior`` ``(chain, draw, …)`` and
    ``sample_stats`` holding ``diverging`` and ``acceptance_rate``; ``var_names``
    are the posterior's variables to check. r-hat is arviz's rank-normalised r-hat of the
    chains split in halves (:func:`split_chains`), so it exists for a single chain too, and
    arviz gives the same on a file written in that layout; the ESS is arviz's of the chains
    as laid out (the halves, for an ``idata`` laid out by :func:`split_chains`). A
    variable that never moved within a chain has no ESS (0) and a NaN r-hat, which
    fail the checks. Returns a :class:`MixingDiagnostics`; :func:`mixing_result` judges it.
    """
    posterior = _checked(idata, var_names)
    table = _diagnostic_table(posterior)
    rhat = table["r_hat"].to_numpy()
    stats = idata.sample_stats
    diverging = np.asarray(stats["diverging"].values, bool)
    return MixingDiagnostics(
        max_rhat=math.nan if np.isnan(rhat).any() else float(rhat.max()),
        min_ess_bulk=float(table["ess_bulk"].min()), min_ess_tail=float(table["ess_tail"].min()),
        divergences=int(diverging.sum()), draws=int(diverging.size),
        chains=int(posterior.attrs.get(SAMPLER_CHAINS, posterior.sizes["chain"])),
        acceptance_rate=float(np.mean(stats["acceptance_rate"].values)))


def mixing_result(diagnostics: MixingDiagnostics) -> RESULTS:
    """``RESULTS.not_mixed`` unless every check of :func:`mixing_diagnostics` passes (NaN fails)."""
    d = diagnostics
    mixed = (d.max_rhat <= MAX_RHAT and d.min_ess_bulk >= MIN_ESS and d.min_ess_tail >= MIN_ESS
             and d.divergences <= MAX_DIVERGENT_SHARE * d.draws and d.acceptance_rate >= MIN_ACCEPTANCE)
    return RESULTS.successful if mixed else RESULTS.not_mixed


def posterior_summary(idata, var_names):
    """``az.summary`` of ``var_names``: mean, sd and the 90% HDI (unrounded), bulk and tail ESS and split r-hat.

    The ESS and r-hat are those :func:`mixing_diagnostics` judges: a single chain
    has an r-hat, and a variable that never moved has no ESS (0) and a NaN r-hat.
    """
    import arviz as az

    posterior = _checked(idata, var_names)
    with quiet_single_chain(1), np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        table = az.summary(posterior, kind="stats", hdi_prob=HDI_PROB, round_to="none")
    return table.join(_diagnostic_table(posterior))


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
