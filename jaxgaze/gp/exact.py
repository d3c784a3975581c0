"""Exact Gaussian-process regression: marginal likelihood, prediction, Type-II ML fit.

The model is Yücel et al. T-CYB 2013 eq. 5–7: ``y = f(p) + ε`` with a zero-mean
GP prior ``f ~ GP(0, k)``. Independent noise ε is part of the kernel (a
:class:`~jaxgaze.gp.kernels.White` term, σ0² of eq. 7), so the covariance of the
observations is ``K = kernel(X) + jitter·I``.

* :func:`log_marginal_likelihood` — ``log p(y | X) = −½ yᵀK⁻¹y − Σ_i log L_ii −
  (n/2) log 2π`` with ``K = L Lᵀ`` (Cholesky). Its gradient with respect to
  ``K`` is ``½(ααᵀ − K⁻¹)`` with ``α = K⁻¹y`` (Rasmussen & Williams eq. 5.9);
  we supply that as a custom JVP, so one value-and-gradient costs a Cholesky
  plus one ``K⁻¹`` (LAPACK ``potri`` on CPU from n = 513), whatever the number of
  parameters (the linear algebra: ``gp/_linalg.py``).
* :func:`predict` — eq. 12–13: mean ``K*ᵀ K⁻¹ y`` and covariance
  ``K** − K*ᵀ K⁻¹ K*`` with ``K* = kernel(X, X_new)`` and ``K** = kernel(X_new)``.
  ``K**`` uses the same-set convention, so a White term adds the noise to the
  predictive variance as scikit-learn's ``predict(return_std=True)`` does (eq.
  13 is the noise-free ``f*``; drop the White term from the kernel to get it).
* :func:`jaxgaze.gp.fit` (in ``gp/_fit.py``) — Type-II maximum likelihood (the paper's
  "iterated until the marginal likelihood reaches an optimal value", after eq. 13) with
  optimistix quasi-Newton minimisers (Fisher scoring by default, or BFGS) over the kernel's
  unconstrained parameters, on growing random subsets; it returns a :class:`FittedGP`.

**Jitter.** ``jitter=None`` adds ``1e-6 × mean(diag K)`` (float64) or
``1e-5 × mean(diag K)`` (float32) to the diagonal; a number is used as the
absolute value instead (e.g. to match scikit-learn's ``alpha``). If the
Cholesky factor still has NaNs the matrix is not positive definite: the
functions raise ``ValueError`` naming the jitter (no silent retry), :func:`~jaxgaze.gp.fit`
reports :attr:`jaxgaze.results.RESULTS.not_positive_definite`.

All computations run in the dtype of the inputs (float32 or float64).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxgaze.gp._linalg import DEFAULT_RELATIVE_JITTER, _lml_checked, factorise, predict_from_factor
from jaxgaze.gp.kernels import Kernel
from jaxgaze.results import RESULTS, throw_if_failed

__all__ = [
    "DEFAULT_RELATIVE_JITTER",
    "FittedGP",
    "log_marginal_likelihood",
    "predict",
    "fitted_gp",
    "check_training_data",
]

_MIN_POINTS = 2


# ---------------------------------------------------------------------------
# Input checks


def _is_traced(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(xs))


def _float_dtype(*arrays):
    dtype = jnp.result_type(*arrays)
    if jnp.issubdtype(dtype, jnp.complexfloating):
        raise TypeError("complex inputs are not supported")
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    return dtype


def _check_X(X, name: str) -> None:
    shape = np.shape(X)
    if len(shape) != 2:
        raise ValueError(f"{name} must be 2-D (n, D), got shape {shape}")
    if shape[1] < 1:
        raise ValueError(f"{name} must have at least one feature column, got shape {shape}")
    if not _is_traced(X):
        arr = np.asarray(X)
        if arr.dtype.kind == "c":
            raise TypeError(f"{name} must be real, got dtype {arr.dtype}")
        bad = ~np.all(np.isfinite(arr), axis=1)
        if bad.any():
            raise ValueError(f"{name} contains NaN or inf (first bad row: {int(np.argmax(bad))})")


def check_training_data(X, y, min_points: int = _MIN_POINTS):
    """Validate training data ``X (n, d)``, ``y (n,)`` (finite, matching, at least ``min_points``
    rows); return ``(X, y)`` as arrays of a common float dtype."""
    _check_X(X, "X")
    yshape = np.shape(y)
    if len(yshape) != 1:
        hint = "; pass y.ravel() for a single output" if len(yshape) == 2 and 1 in yshape else ""
        raise ValueError(f"y must be 1-D (n,), got shape {yshape}{hint}")
    n = np.shape(X)[0]
    if yshape[0] != n:
        raise ValueError(f"X and y must have the same length: X has {n} rows, y has {yshape[0]} entries")
    if n < min_points:
        raise ValueError(f"need at least {min_points} training points, got {n}")
    if not _is_traced(y):
        arr = np.asarray(y)
        if arr.dtype.kind == "c":
            raise TypeError(f"y must be real, got dtype {arr.dtype}")
        bad = ~np.isfinite(arr)
        if bad.any():
            raise ValueError(f"y contains NaN or inf (first bad index: {int(np.argmax(bad))})")
    dtype = _float_dtype(X, y)
    return jnp.asarray(X, dtype), jnp.asarray(y, dtype)


def _check_kernel(kernel, num_features: int, dtype) -> Kernel:
    if not isinstance(kernel, Kernel):
        raise TypeError(f"kernel must be a jaxgaze.gp Kernel, got {type(kernel).__name__}")
    kernel.check_input_dim(num_features)
    return _cast(kernel, dtype)


def _cast(tree, dtype):
    return jax.tree.map(lambda a: a.astype(dtype) if eqx.is_inexact_array(a) else a, tree)


def _check_jitter(jitter) -> None:
    if jitter is None:
        return
    if isinstance(jitter, bool) or not isinstance(jitter, (int, float, np.floating, np.integer)):
        raise TypeError(f"jitter must be None or a non-negative number, got {type(jitter).__name__}")
    if not (math.isfinite(jitter) and jitter >= 0):
        raise ValueError(f"jitter must be None or a finite non-negative number, got {jitter!r}")


def _describe_jitter(jitter, used) -> str:
    if jitter is None:
        return f"jitter {float(used):.3g} (the default, relative to the mean diagonal)"
    return f"jitter {float(used):.3g}"



def _not_pd_message(where: str, jitter_text: str) -> str:
    return (
        f"{where}: the kernel matrix K(X, X) is not positive definite even with {jitter_text} added to its "
        "diagonal; add a White noise term to the kernel, remove duplicate inputs, or pass a larger jitter"
    )


# ---------------------------------------------------------------------------
# Public: marginal likelihood and prediction


def log_marginal_likelihood(kernel: Kernel, X: Float[Array, "n D"], y: Float[Array, " n"], *, jitter=None):
    """``log p(y | X, θ)`` of a zero-mean GP with ``K = kernel(X) + jitter·I`` (Rasmussen & Williams 2006, eq. 2.30).

    ``−½ yᵀK⁻¹y − Σ_i log L_ii − (n/2) log 2π`` with the Cholesky ``K = LLᵀ``
    (Rasmussen & Williams eq. 2.30; the objective behind Yücel et al. eq. 13).
    Differentiable in the kernel parameters (and ``y``); the gradient uses
    ``½ tr((ααᵀ − K⁻¹) ∂K)``. Raises ``ValueError`` when ``K`` is not positive
    definite (under ``jit`` through ``equinox.error_if``).
    """
    _check_jitter(jitter)
    X, y = check_training_data(X, y)
    kernel = _check_kernel(kernel, X.shape[1], X.dtype)
    value, j = _lml_checked(kernel, X, y, jitter)
    if _is_traced(value):
        return eqx.error_if(
            value, ~jnp.isfinite(value), _not_pd_message("log_marginal_likelihood", "the jitter")
        )
    if not np.isfinite(float(value)):
        raise ValueError(_not_pd_message("log_marginal_likelihood", _describe_jitter(jitter, j)))
    return value


def predict(
    kernel: Kernel,
    X: Float[Array, "n D"],
    y: Float[Array, " n"],
    X_new: Float[Array, "m D"],
    *,
    jitter=None,
    full_covariance: bool = False,
):
    """GP posterior at ``X_new`` (Yücel et al. 2013, eq. 12–13): ``(mean, variance)`` or ``(mean, covariance)``.

    Mean ``K*ᵀ K⁻¹ y``; variance ``diag(K**) − diag(K*ᵀ K⁻¹ K*)`` clipped at 0
    (rounding can make it slightly negative), or the full ``(m, m)`` covariance
    with ``full_covariance=True``. Noise terms of the kernel are included in
    ``K**`` (see the module docstring).

    Precision: float32 and float64 agree to within 1e-3 of the predictive standard
    deviation on the mean and 1e-3 relative on the variance while ``K`` is well
    conditioned (``cond K ≲ 500``, e.g. 60 points with a noise variance 15 % of the
    signal's; ``tests/test_precision.py``); the float32 error grows about as
    ``cond(K)^1.5`` beyond (2e-3 sd at ``cond K ≈ 1400``, 6e-2 sd at 14 000), so
    predict from badly conditioned data in float64.
    """
    _check_jitter(jitter)
    X, y = check_training_data(X, y)
    X_new = _check_new(X_new, X)
    kernel = _check_kernel(kernel, X.shape[1], X.dtype)
    L, alpha, value, j = factorise(kernel, X, y, jitter)
    if _is_traced(L):
        L = eqx.error_if(L, ~jnp.all(jnp.isfinite(L)), _not_pd_message("predict", "the jitter"))
    elif not np.all(np.isfinite(np.asarray(L))):
        raise ValueError(_not_pd_message("predict", _describe_jitter(jitter, j)))
    return predict_from_factor(kernel, X, L, alpha, X_new, bool(full_covariance))


def _check_new(X_new, X):
    _check_X(X_new, "X_new")
    if np.shape(X_new)[1] != X.shape[1]:
        raise ValueError(f"X_new has {np.shape(X_new)[1]} features but the training X has {X.shape[1]}")
    return jnp.asarray(X_new, X.dtype)


# ---------------------------------------------------------------------------
# The fitted GP (the result of jaxgaze.gp.fit)


class FittedGP(NamedTuple):
    """A GP with hyperparameters fitted by :func:`~jaxgaze.gp.fit`, and its cached Cholesky factor.

    ``jaxgaze.succeeded(fitted)`` reads :attr:`result`; a failed fit with ``throw=True`` raises a
    :class:`~jaxgaze.results.FitError` whose ``fit`` is this object."""

    #: the kernel at the optimum (natural values via its properties / ``hyperparameters()``).
    kernel: Kernel
    #: exact log marginal likelihood at ``kernel`` on all data, in the data dtype.
    log_marginal_likelihood: Float[Array, ""]
    #: a :class:`jaxgaze.results.RESULTS` item: ``successful``; ``max_steps_reached`` (the
    #: last stage, on all data, used ``max_steps``: the kernel is the best point reached);
    #: ``not_positive_definite`` (K + jitter·I at the final parameters); ``nonfinite`` (no
    #: starting point gave a finite marginal likelihood); ``optimiser_failed`` (the last
    #: stage stopped on another ``optimistix.RESULTS`` failure or at a non-finite
    #: likelihood: the previous stage's optimum is returned).
    result: RESULTS
    X: Float[Array, "n D"]
    y: Float[Array, " n"]
    #: lower Cholesky factor of ``kernel(X) + jitter·I``.
    cholesky: Float[Array, "n n"]
    #: ``K⁻¹ y``.
    alpha: Float[Array, " n"]
    #: absolute jitter added to the diagonal.
    jitter: float
    #: log marginal likelihood on the first subset reached from each starting point.
    restart_log_marginal_likelihoods: Float[Array, " restarts"]
    #: ``(points, dtype name, optimiser steps)`` of each stage; the first sums over restarts.
    stages: tuple[tuple[int, str, int], ...]

    @property
    def message(self) -> str:
        """``RESULTS[result]``, with the jitter where it matters."""
        return _message(self.result, self.jitter)

    def predict(self, X_new: Float[Array, "m D"], full_covariance: bool = False):
        """Posterior ``(mean, variance)`` or ``(mean, covariance)`` at ``X_new`` (Yücel et al. 2013, eq. 12–13)."""
        if bool(self.result == RESULTS.not_positive_definite) or bool(self.result == RESULTS.nonfinite):
            raise ValueError(f"cannot predict from a failed fit: {self.message}")
        X_new = _check_new(X_new, self.X)
        return predict_from_factor(self.kernel, self.X, self.cholesky, self.alpha, X_new, bool(full_covariance))


def fitted_gp(kernel, X, y, jitter, result, restart_lml, stages, throw) -> FittedGP:
    """A :class:`FittedGP` for ``kernel`` on ``(X, y)``: its Cholesky factor, ``α`` and log
    marginal likelihood, with ``result`` (a :data:`~jaxgaze.results.RESULTS` item; a
    non-finite factor becomes ``not_positive_definite``); when ``throw`` and it failed, raises a
    :class:`~jaxgaze.results.FitError` that carries it (``error.fit``)."""
    L, alpha, value, j = factorise(kernel, X, y, jitter)
    if not np.all(np.isfinite(np.asarray(L))) and not bool(result == RESULTS.nonfinite):
        result = RESULTS.not_positive_definite
    fitted = FittedGP(
        kernel=kernel,
        log_marginal_likelihood=value,
        result=result,
        X=X,
        y=y,
        cholesky=L,
        alpha=alpha,
        jitter=float(j),
        restart_log_marginal_likelihoods=restart_lml,
        stages=stages,
    )
    return throw_if_failed(fitted, result, _context(fitted.jitter)) if throw else fitted


def _context(jitter: float) -> str:
    return f"fit (jitter {jitter:.3g})"


def _message(result: RESULTS, jitter: float) -> str:
    if bool(result == RESULTS.not_positive_definite) or bool(result == RESULTS.nonfinite):
        return f"{_context(jitter)}: {RESULTS[result]}"
    return f"fit: {RESULTS[result]}"
