"""Posterior over a GP's kernel hyperparameters, and predictions that integrate over it.

Type-II maximum likelihood (:func:`jaxgaze.gp.fit`) keeps one set of
hyperparameters ``θ``. Here ``θ`` gets a prior and is sampled with NUTS
(numpyro's kernel, :func:`jaxgaze.nuts.sample_nuts`):

    log θ_j ~ N(log θ₀_j, s²)         (every trainable positive parameter; θ₀ the kernel passed)
    y | θ  ~ N(0, K_θ(X, X) + jitter I)  (Yücel et al. T-CYB eq. 11, the marginal likelihood)

so the sampled site is ``raw = log θ`` (the unconstrained parameter of
:mod:`jaxgaze.gp.transforms`). Predictions average the GP posteriors of eq. 12–13
over draws: with per-draw means ``μ_s`` and variances ``σ_s²``, the mixture has
mean ``μ̄ = mean_s μ_s`` and variance ``mean_s σ_s² + var_s μ_s``.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from jaxtyping import Array, Float

from jaxgaze.gp._linalg import factorise, gaussian_log_marginal_likelihood, predict_from_factor
from jaxgaze.gp.exact import FittedGP, check_training_data
from jaxgaze.gp.kernels import Kernel
from jaxgaze.gp.transforms import positive
from jaxgaze.nuts import SamplerReport, quiet_single_chain, sample_nuts, sampler_report
from jaxgaze.results import RESULTS, throw_if_failed

__all__ = ["HyperparameterPosterior", "hyperparameter_model", "sample_hyperparameter_posterior"]


def _site_names(kernel: Kernel, params) -> list[str]:
    """Names of the raw leaves in the style of ``Kernel.hyperparameters()``: ``0.RationalQuadratic.lengthscale``."""
    names = []
    for path, _ in jax.tree_util.tree_flatten_with_path(params)[0]:
        owner, prefix = kernel, []
        for entry in path[:-1]:
            if hasattr(entry, "idx"):
                owner = owner[entry.idx]
                prefix.append(str(entry.idx))
            else:
                owner = getattr(owner, entry.name)
        leaf = path[-1].name.removeprefix("raw_")
        names.append(".".join(prefix + [type(owner).__name__, leaf]))
    return names


def hyperparameter_model(X, y, prior_loc, prior_scale, *, static, treedef, names):
    """numpyro model: ``log θ ~ N(prior_loc, prior_scale²)``, ``y ~ GP(0, k_θ)`` (Yücel et al. 2013, eq. 11).

    ``prior_loc`` is the list of raw (log) leaves of the prior centre; ``static``,
    ``treedef`` and ``names`` describe the kernel (from :func:`eqx.partition`).
    Deterministic sites ``<name>`` hold the natural hyperparameters.
    """
    raws = []
    for name, loc in zip(names, prior_loc):
        raw = numpyro.sample("log_" + name, dist.Normal(loc, prior_scale).to_event(jnp.ndim(loc)))
        numpyro.deterministic(name, positive(raw))
        raws.append(raw)
    kernel = eqx.combine(jax.tree_util.tree_unflatten(treedef, raws), static)
    numpyro.factor("log_marginal_likelihood", gaussian_log_marginal_likelihood(kernel, X, y, None))


@functools.lru_cache(maxsize=32)
def _model_for(static, treedef, names):
    # One model object per kernel structure, so sample_nuts compiles once per structure.
    return functools.partial(hyperparameter_model, static=static, treedef=treedef, names=names)


class HyperparameterPosterior(NamedTuple):
    """Draws of the kernel hyperparameters and the data they condition on.

    Attributes:
        kernels: the kernel with a leading draw axis ``S`` on every trainable leaf.
        samples: natural hyperparameters per draw, ``{name: (S, ...)}``.
        X, y: the training data.
        sampler: the :class:`~jaxgaze.nuts.SamplerReport` of the run: ``idata`` (posterior of the
            natural hyperparameters, sample stats; for ``az.plot_trace``), its mixing ``diagnostics``
            (split r-hat, bulk and tail ESS, divergences, acceptance) and ``summary`` (mean, sd,
            90% HDI, ESS, r-hat per hyperparameter).
        result: ``RESULTS.successful``, or ``not_mixed`` when the run failed the shared
            checks (:func:`jaxgaze.nuts.mixing_result`); ``jaxgaze.succeeded(posterior)`` reads it.
    """

    kernels: Kernel
    samples: dict
    X: Float[Array, "n D"]
    y: Float[Array, " n"]
    sampler: SamplerReport
    result: RESULTS

    def predict(self, X_new: Float[Array, "m D"], *, max_draws: int = 100) -> tuple[Array, Array]:
        """Mean and variance at ``X_new`` (Yücel et al. 2013, eq. 12–13), averaged over draws.

        Up to ``max_draws`` evenly spaced draws are used.
        """
        X_new = jnp.asarray(X_new, self.X.dtype)
        if X_new.ndim != 2 or X_new.shape[1] != self.X.shape[1]:
            raise ValueError(f"X_new must have shape (m, {self.X.shape[1]}), got {X_new.shape}")
        if not bool(jnp.all(jnp.isfinite(X_new))):
            raise ValueError("X_new contains NaN or inf")
        params, static = eqx.partition(self.kernels, eqx.is_inexact_array)
        num = jax.tree_util.tree_leaves(params)[0].shape[0]
        pick = np.unique(np.linspace(0, num - 1, min(max_draws, num)).round().astype(int))
        params = jax.tree_util.tree_map(lambda a: a[pick], params)
        means, variances = _mixture_parts(params, static, self.X, self.y, X_new)
        mean = jnp.mean(means, axis=0)
        return mean, jnp.mean(variances, axis=0) + jnp.var(means, axis=0)


@eqx.filter_jit
def _mixture_parts(params, static, X, y, X_new):
    def one(p):
        kernel = eqx.combine(p, static)
        L, alpha, _, _ = factorise(kernel, X, y, None)
        return predict_from_factor(kernel, X, L, alpha, X_new, False)

    return jax.lax.map(one, params)


def sample_hyperparameter_posterior(
    kernel: Kernel,
    X: Float[Array, "n D"],
    y: Float[Array, " n"],
    *,
    key,
    start: FittedGP | Kernel | None = None,
    prior_scale: float = 1.5,
    num_warmup: int = 300,
    num_samples: int = 300,
    progress: bool = False,
    throw: bool = False,
) -> HyperparameterPosterior:
    """Sample ``p(θ | X, y)`` for the trainable hyperparameters of ``kernel`` with NUTS (Yücel et al. 2013, eq. 11).

    ``kernel`` is the prior centre ``θ₀`` (its defaults suit standardised inputs
    and outputs); ``prior_scale`` is the prior sd of each ``log θ``. The chain
    starts at ``start`` (e.g. the :class:`FittedGP` of :func:`jaxgaze.gp.fit`,
    whose optimum sits in the bulk), else at ``θ₀``. One chain, dense mass matrix.
    The cost per leapfrog step is one Cholesky of the ``n × n`` kernel matrix
    plus its inverse for the gradient, so use a few hundred points. A run that did
    not mix is the posterior's ``result`` (``RESULTS.not_mixed``, ``throw=False``)
    or a :class:`~jaxgaze.results.FitError` (``throw=True``) whose ``fit`` is the posterior.
    ``progress=True`` shows a tqdm bar over the NUTS iterations.
    """
    import arviz as az

    X, y = check_training_data(X, y)
    if not (np.isfinite(prior_scale) and prior_scale > 0):
        raise ValueError(f"prior_scale must be positive, got {prior_scale!r}")
    if isinstance(start, FittedGP):
        start = start.kernel
    start = kernel if start is None else start
    if not isinstance(kernel, Kernel) or not isinstance(start, Kernel):
        raise TypeError("kernel and start must be jaxgaze.gp kernels (or start a FittedGP)")
    if jax.tree_util.tree_structure(start) != jax.tree_util.tree_structure(kernel):
        raise ValueError("start must have the same kernel structure as kernel")
    kernel = jax.tree_util.tree_map(lambda a: jnp.asarray(a, X.dtype) if eqx.is_inexact_array(a) else a, kernel)
    start = jax.tree_util.tree_map(lambda a: jnp.asarray(a, X.dtype) if eqx.is_inexact_array(a) else a, start)
    params, static = eqx.partition(kernel, kernel.trainable_filter())
    start_params, start_static = eqx.partition(start, kernel.trainable_filter())
    loc, treedef = jax.tree_util.tree_flatten(params)
    start_leaves = jax.tree_util.tree_leaves(start_params)
    if not loc:
        raise ValueError("kernel has no trainable hyperparameters to sample")
    names = tuple(_site_names(kernel, params))
    model = _model_for(static, treedef, names)
    prior_scale = jnp.asarray(prior_scale, X.dtype)
    init = {"log_" + n: leaf[None] for n, leaf in zip(names, start_leaves)}
    values, stats = sample_nuts(
        model, key, (X[None], y[None], [a[None] for a in loc], prior_scale[None]), init,
        num_warmup=num_warmup, num_samples=num_samples, dense_mass=True, target_accept_prob=0.9,
        progress=progress, description="GP hyperparameters",
    )
    values = jax.tree_util.tree_map(lambda a: a[0], values)
    raws = [values["log_" + n] for n in names]
    draws = eqx.combine(jax.tree_util.tree_unflatten(treedef, raws), static)
    samples = {n: np.asarray(values[n]) for n in names}
    with quiet_single_chain(1):
        idata = az.from_dict(
            posterior={n: v[None] for n, v in samples.items()},
            sample_stats={k: np.asarray(v)[:1] for k, v in stats.items()},
        )
    sampler = sampler_report(idata, names)
    posterior = HyperparameterPosterior(draws, samples, X, y, sampler, sampler.result)
    return throw_if_failed(posterior, posterior.result, "sample_hyperparameter_posterior") if throw else posterior
