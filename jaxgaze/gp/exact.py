"""Exact Gaussian-process regression: marginal likelihood, prediction, Type-II ML fit.

The model is Yücel et al. T-CYB 2013 eq. 5–7: ``y = f(p) + ε`` with a zero-mean
GP prior ``f ~ GP(0, k)``. Independent noise ε is part of the kernel (a
:class:`~jaxgaze.gp.kernels.White` term, σ0² of eq. 7), so the covariance of the
observations is ``K = kernel(X) + jitter·I``.

* :func:`log_marginal_likelihood` — ``log p(y | X) = −½ yᵀK⁻¹y − Σ_i log L_ii −
  (n/2) log 2π`` with ``K = L Lᵀ`` (Cholesky). Its gradient with respect to
  ``K`` is ``½(ααᵀ − K⁻¹)`` with ``α = K⁻¹y`` (Rasmussen & Williams eq. 5.9);
  we supply that as a custom JVP, so one value-and-gradient costs a Cholesky
  plus one ``K⁻¹`` (LAPACK ``potri`` on CPU from n = 513), whatever the number of parameters.
* :func:`predict` — eq. 12–13: mean ``K*ᵀ K⁻¹ y`` and covariance
  ``K** − K*ᵀ K⁻¹ K*`` with ``K* = kernel(X, X_new)`` and ``K** = kernel(X_new)``.
  ``K**`` uses the same-set convention, so a White term adds the noise to the
  predictive variance as scikit-learn's ``predict(return_std=True)`` does (eq.
  13 is the noise-free ``f*``; drop the White term from the kernel to get it).
* :func:`fit` — Type-II maximum likelihood (the paper's "iterated until the
  marginal likelihood reaches an optimal value", after eq. 13) with optimistix
  quasi-Newton minimisers (Fisher scoring by default, or BFGS) over the kernel's
  unconstrained parameters, on growing random subsets; see its docstring.

**Jitter.** ``jitter=None`` adds ``1e-6 × mean(diag K)`` (float64) or
``1e-5 × mean(diag K)`` (float32) to the diagonal; a number is used as the
absolute value instead (e.g. to match scikit-learn's ``alpha``). If the
Cholesky factor still has NaNs the matrix is not positive definite: the
functions raise ``ValueError`` naming the jitter (no silent retry), :func:`fit`
reports :attr:`jaxgaze.results.RESULTS.not_positive_definite`.

All computations run in the dtype of the inputs (float32 or float64).
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import scipy.linalg
from jax.flatten_util import ravel_pytree
from jax.scipy.linalg import cho_solve, solve_triangular
from jaxtyping import Array, Float, PRNGKeyArray
from tqdm import tqdm

from jaxgaze.gp.transforms import bound_penalty
from jaxgaze.gp.kernels import Kernel, DataStats
from jaxgaze.results import RESULTS, throw_if_failed

__all__ = [
    "DEFAULT_RELATIVE_JITTER",
    "FittedGP",
    "log_marginal_likelihood",
    "predict",
    "fit",
]

#: Default jitter, as a fraction of mean(diag K), per dtype.
DEFAULT_RELATIVE_JITTER = {"float64": 1e-6, "float32": 1e-5}

_MIN_POINTS = 2
_LOG_2PI = math.log(2.0 * math.pi)


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


# ---------------------------------------------------------------------------
# Core maths (traceable)


def _jitter_value(K: Float[Array, "n n"], jitter):
    if jitter is None:
        rel = DEFAULT_RELATIVE_JITTER["float64" if K.dtype == jnp.float64 else "float32"]
        return rel * jnp.mean(jnp.diagonal(K))
    return jnp.asarray(jitter, K.dtype)


def _covariance(kernel: Kernel, X, jitter):
    K = kernel(X)
    j = _jitter_value(K, jitter)
    return K + j * jnp.eye(K.shape[0], dtype=K.dtype), j


def _host_potri(bits: np.ndarray, dtype) -> np.ndarray:
    """LAPACK ``potri`` on the bit pattern of a Cholesky factor; returns the bits of ``triu(K⁻¹)``.

    ``potri`` (``lower=1``) works in place on one Fortran-ordered copy of ``L``; that
    array's memory, read row-major, is its transpose: ``K⁻¹``'s lower triangle lands in
    the upper one, and the strict lower triangle holds ``L``'s strict upper (zero). The
    caller uses that triangle as it is, with no further pass or copy in NumPy.
    """
    bits = np.asarray(bits)
    L = np.ascontiguousarray(bits).view(dtype).reshape(bits.shape[:2])
    potri = scipy.linalg.lapack.dpotri if dtype == np.float64 else scipy.linalg.lapack.spotri
    inv, info = potri(np.asfortranarray(L), lower=1, overwrite_c=1)
    upper = inv.T  # row-major view of the Fortran-ordered result
    if info != 0 or not np.all(np.isfinite(upper)):
        upper = np.full_like(L, np.nan)
    return np.ascontiguousarray(upper).view(np.uint32).reshape(bits.shape)


#: Smallest ``n`` whose ``K⁻¹`` is taken by LAPACK ``potri`` in a host callback on CPU.
#: Below it, XLA's two triangular solves cost about the same (float64 n = 512: 9.6 against
#: 6.4 ms, float32: 4.0 against 4.0 ms, one thread) and keep the program free of host
#: callbacks, which JAX's persistent compilation cache never stores: the subset stages of
#: :func:`fit` then come from the cache in a new process (``benchmarks/RESULTS.md``).
_HOST_POTRI_MIN_SIZE = 513


@jax.custom_jvp
def _upper_inverse_from_cholesky(L: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """``triu(K⁻¹)`` (zeros below the diagonal) from the lower Cholesky factor of ``K``.

    On CPU from ``n = 513`` (:data:`_HOST_POTRI_MIN_SIZE`) this calls LAPACK ``potri``
    through SciPy (``2n³/3`` flops, about a third of ``cho_solve(L, I)``, which XLA:CPU
    runs as two full triangular solves); otherwise it is ``triu(cho_solve(L, I))``. NaN
    when ``L`` is not a valid factor. The gradient of the LML needs ``K⁻¹`` only through
    ``tr(K⁻¹ S)`` for symmetric ``S``, which the triangle gives without the
    transposing pass that would mirror it (:func:`_gaussian_lml`). The callback
    exchanges the matrices as ``uint32`` bit patterns: JAX hands callbacks arrays
    canonicalised by the *calling thread's* x64 setting, which under the
    ``jax.enable_x64`` context manager would silently round float64 to float32.
    """
    if jax.default_backend() == "cpu" and L.shape[0] >= _HOST_POTRI_MIN_SIZE:
        bits = jax.lax.bitcast_convert_type(L, jnp.uint32)
        shape = jax.ShapeDtypeStruct(bits.shape, jnp.uint32)
        callback = functools.partial(_host_potri, dtype=np.dtype(L.dtype))
        out = jax.pure_callback(callback, shape, bits, vmap_method="sequential")
        return jax.lax.bitcast_convert_type(out, L.dtype)
    upper = jnp.triu(cho_solve((L, True), jnp.eye(L.shape[0], dtype=L.dtype)))
    return jnp.where(jnp.all(jnp.isfinite(upper)), upper, jnp.nan)


def _symmetric_from_upper(U: Float[Array, "n n"]) -> Float[Array, "n n"]:
    return U + jnp.triu(U, 1).T


@_upper_inverse_from_cholesky.defjvp
def _upper_inverse_from_cholesky_jvp(primals, tangents):
    # d K⁻¹ = −K⁻¹ dK K⁻¹ with dK = dL Lᵀ + L dLᵀ (used by second derivatives only).
    (L,), (dL,) = primals, tangents
    U = _upper_inverse_from_cholesky(L)
    K_inv = _symmetric_from_upper(U)
    dK = dL @ L.T + L @ dL.T
    return U, jnp.triu(-K_inv @ dK @ K_inv)


def _trace_weights(U: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """``M = 2·triu(K⁻¹) − diag(K⁻¹)`` from ``U = triu(K⁻¹)``: ``vdot(M, S) = tr(K⁻¹ S)`` for symmetric ``S``."""
    return U * (2.0 - jnp.eye(U.shape[0], dtype=U.dtype))


@jax.custom_jvp
def _gaussian_lml(K: Float[Array, "n n"], y: Float[Array, " n"]) -> Float[Array, ""]:
    """log N(y | 0, K) by Cholesky; NaN when K is not positive definite.

    Its derivative assumes a symmetric tangent ``dK`` (as for any ``K(θ)`` built by a
    kernel): the trace term is taken from ``triu(K⁻¹)`` alone (:func:`_trace_weights`).
    """
    L = jnp.linalg.cholesky(K)
    alpha = cho_solve((L, True), y)
    return -0.5 * jnp.dot(y, alpha) - jnp.sum(jnp.log(jnp.diagonal(L))) - 0.5 * y.shape[0] * _LOG_2PI


@_gaussian_lml.defjvp
def _gaussian_lml_jvp(primals, tangents):
    # d log N = ½ tr((ααᵀ − K⁻¹) dK) − αᵀ dy  (Rasmussen & Williams eq. 5.9).
    K, y = primals
    dK, dy = tangents
    L = jnp.linalg.cholesky(K)
    alpha = cho_solve((L, True), y)
    value = -0.5 * jnp.dot(y, alpha) - jnp.sum(jnp.log(jnp.diagonal(L))) - 0.5 * y.shape[0] * _LOG_2PI
    # tr(K⁻¹ dK) as vdot with the triangle's weights: dK is symmetric (K(θ) is).
    W = jnp.outer(alpha, alpha) - _trace_weights(_upper_inverse_from_cholesky(L))
    return value, 0.5 * jnp.vdot(W, dK) - jnp.dot(alpha, dy)


def gaussian_log_marginal_likelihood(kernel: Kernel, X, y, jitter):
    """(Rasmussen & Williams 2006, eq. 2.30) ``log p(y | X) = −½ yᵀK⁻¹y − ½ log|K| − (n/2) log 2π``
    with ``K = k(X, X)`` plus the jitter; no input checks (traceable, for samplers)."""
    K, _ = _covariance(kernel, X, jitter)
    return _gaussian_lml(K, y)


@eqx.filter_jit
def _lml_checked(kernel, X, y, jitter):
    K, j = _covariance(kernel, X, jitter)
    value = _gaussian_lml(K, y)
    return value, j


@eqx.filter_jit
def factorise(kernel: Kernel, X, y, jitter):
    """Cholesky factor, α = K⁻¹y, the log marginal likelihood and the jitter used (Rasmussen & Williams 2006)."""
    K, j = _covariance(kernel, X, jitter)
    L = jnp.linalg.cholesky(K)
    alpha = cho_solve((L, True), y)
    value = -0.5 * jnp.dot(y, alpha) - jnp.sum(jnp.log(jnp.diagonal(L))) - 0.5 * y.shape[0] * _LOG_2PI
    return L, alpha, value, j


@eqx.filter_jit
def predict_from_factor(kernel: Kernel, X, L, alpha, X_new, full_covariance: bool):
    """(Rasmussen & Williams 2006, eq. 2.25–2.26) the predictive mean ``K*ᵀα`` and (co)variance
    ``K** − VᵀV`` with ``V = L⁻¹K*``, from the Cholesky factor ``L`` and ``α = K⁻¹y``."""
    K_star = kernel(X, X_new)  # (n, n_new), no noise: different sets
    mean = K_star.T @ alpha
    V = solve_triangular(L, K_star, lower=True)
    if full_covariance:
        cov = kernel(X_new) - V.T @ V
        cov = 0.5 * (cov + cov.T)
        return mean, cov
    var = kernel.diag(X_new) - jnp.sum(V * V, axis=0)
    return mean, jnp.maximum(var, 0.0)


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
# Fit



#: multiplicative growth between the subset sizes of successive fit stages.
_STAGE_GROWTH = 4
#: the last subset before all data has at most n / this points.
_STAGE_MIN_LAST_RATIO = 1.5
#: ... and, where a doubling fits, at least n / this points (n = 1000: 256 → 512 → 1000).
_STAGE_MAX_LAST_RATIO = 2.5
#: stages before the last stop at a Newton decrement of this × tol × (stage size / n).
_STAGE_TOL_FACTOR = 100.0
#: floor on the per-point Fisher eigenvalues: directions the data barely constrain
#: (e.g. a constant offset shared by two kernel terms) take steps of bounded length.
_FISHER_FLOOR = 1e-4
#: per-point stiffness of the wall that keeps parameters inside FIT_BOUNDS.
_WALL_STIFFNESS = 10.0
#: random probes of the Hutchinson estimate of the Fisher information.
_NUM_PROBES = 16
#: float32 stages stop at a decrement of at least this × stage size (rounding level).
_FLOAT32_DECREMENT_FLOOR = 1e-5
_METHODS = ("fisher", "bfgs")


class FittedGP(NamedTuple):
    """A GP with hyperparameters fitted by :func:`fit`, and its cached Cholesky factor."""

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


def _data_stats(X: np.ndarray, y: np.ndarray) -> DataStats:
    n, d = X.shape
    iu = np.triu_indices(n, k=1)
    diff = np.abs(X[:, None, :] - X[None, :, :])[iu]  # (pairs, D)
    dist = np.sqrt(np.sum(diff**2, axis=1))
    med = float(np.median(dist)) if dist.size else 1.0
    scale = med if med > 0 else 1.0
    med_d = np.median(diff, axis=0) if dist.size else np.ones(d)
    med_d = np.where(med_d > 0, med_d, scale / math.sqrt(d)) * math.sqrt(d)
    y_var = float(np.var(y))
    y_var = y_var if y_var > 0 else max(float(np.mean(y**2)), 1.0)
    return DataStats(
        y_var=y_var,
        y_mean_sq=float(np.mean(y) ** 2),
        dist_median=scale,
        dist_median_per_feature=med_d,
        x_norm_sq=float(np.mean(np.sum(X**2, axis=1))),
        x_sq_per_feature=np.mean(X**2, axis=0),
    )


# -- the objective and its curvature ----------------------------------------------


_progress_bar = None  # the tqdm bar of the fit running with progress=True, else None


def _report_evaluation() -> None:
    bar = _progress_bar
    if bar is not None:
        bar.update(1)


def _objective(template, static, X, y, jitter, report: bool = False):
    """``θ ↦ −log p(y | X, θ)`` over the flattened trainable parameters, plus the wall
    that keeps them inside :data:`~jaxgaze.gp.transforms.FIT_BOUNDS` (zero inside).
    ``report``: each evaluation advances the progress bar (a ``jax.debug.callback``)."""
    _, unravel = ravel_pytree(template)

    stiffness = _WALL_STIFFNESS * X.shape[0]

    def fn(theta, args):
        value = -gaussian_log_marginal_likelihood(eqx.combine(unravel(theta), static), X, y, jitter) + bound_penalty(theta, stiffness)
        if report:
            jax.debug.callback(_report_evaluation)
        return value

    return fn


@eqx.filter_jit
def _fisher_estimate(theta, template, static, X, jitter, key, num_probes: int):
    """Hutchinson estimate of the Fisher information of the LML in ``theta`` on all of ``X``.

    ``F_ij = ½ tr(K⁻¹∂_iK K⁻¹∂_jK) = ½ tr(M_i M_j)`` with ``M_i = L⁻¹ ∂_iK L⁻ᵀ``,
    which is ``½ E[(M_i z)ᵀ(M_j z)]`` for ``z ~ N(0, I)``: one Cholesky plus
    O(p s n²) for ``s`` probes, against O(p n³) for the exact value. It is the
    expected Hessian of −LML (Fisher scoring; Rasmussen & Williams Sec. 5.4.1).
    """
    _, unravel = ravel_pytree(template)

    def cov(t):
        return _covariance(eqx.combine(unravel(t), static), X, jitter)[0]

    n, p = X.shape[0], theta.shape[0]
    K = cov(theta)
    L = jnp.linalg.cholesky(K)
    Z = jax.random.normal(key, (n, num_probes), K.dtype)
    Q = solve_triangular(L, Z, lower=True, trans="T")  # L⁻ᵀ z

    def directional(e):
        return jax.jvp(lambda t: cov(t) @ Q, (theta,), (e,))[1]

    R = jax.vmap(directional)(jnp.eye(p, dtype=theta.dtype))  # (p, n, s): ∂_iK L⁻ᵀ z
    M = solve_triangular(L, jnp.moveaxis(R, 0, 1).reshape(n, p * num_probes), lower=True)
    M = M.reshape(n, p, num_probes)
    return 0.5 * jnp.einsum("nis,njs->ij", M, M) / num_probes


def _floored_fisher(theta, template, static, X, jitter, key):
    """Fisher estimate with eigenvalues floored at ``n × _FISHER_FLOOR`` (so positive definite)."""
    n = X.shape[0]
    F = _fisher_estimate(theta, template, static, X, jitter, key, _NUM_PROBES)
    F = F + jnp.diag(jax.vmap(jax.grad(jax.grad(lambda t: bound_penalty(t, _WALL_STIFFNESS * n))))(theta))
    lam, vec = jnp.linalg.eigh(0.5 * (F + F.T))
    floor = n * _FISHER_FLOOR
    lam = jnp.where(jnp.isfinite(lam), jnp.maximum(lam, floor), floor)
    vec = jnp.where(jnp.all(jnp.isfinite(vec)), vec, jnp.eye(vec.shape[0], dtype=vec.dtype))
    return vec, lam


# -- solvers ------------------------------------------------------------------------


def _decrement_test(state, decrement_tol, decrement):
    return (state.num_accepted_steps > 0) & jnp.isfinite(decrement) & (decrement < decrement_tol)


def _quiet(**kwargs) -> None:
    return None


class _BFGS(optx.AbstractBFGS):
    """``optimistix.BFGS`` that also stops once the predicted remaining gain is small.

    Besides optimistix's Cauchy test (small step and small change of the
    objective), it stops at an accepted point where the Newton decrement
    ``½ gᵀ B⁻¹ g`` (the decrease a quasi-Newton step predicts) is below
    ``decrement_tol``. Marginal likelihoods often keep rising by ever smaller
    amounts while a parameter drifts towards ±∞ in log space (RQ α → ∞ for
    RBF-like data, a bias variance → 0); there the step test never fires.
    """

    rtol: float
    atol: float
    decrement_tol: float
    norm: Callable = optx.max_norm
    use_inverse: bool = True
    descent: optx.NewtonDescent = optx.NewtonDescent(linear_solver=lx.Cholesky())
    search: optx.BacktrackingArmijo = optx.BacktrackingArmijo()
    verbose: Callable = eqx.field(static=True, default=_quiet)

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        grad = state.f_info.grad
        decrement = 0.5 * jnp.vdot(grad, state.f_info.hessian_inv.mv(grad))
        return done | _decrement_test(state, self.decrement_tol, decrement), result


class _FisherScoring(optx.AbstractQuasiNewton):
    """Optimistix quasi-Newton minimiser whose curvature is the Fisher information.

    At each accepted point the Hessian model is ``fisher(y)`` (positive definite):
    the descent is the Newton step on it with a backtracking Armijo search, i.e.
    Fisher scoring. Stops like :class:`_BFGS`, the decrement being ``½ gᵀF⁻¹g``.
    """

    rtol: float
    atol: float
    decrement_tol: float
    fisher: Callable
    norm: Callable = optx.max_norm
    use_inverse: bool = False
    descent: optx.NewtonDescent = optx.NewtonDescent(linear_solver=lx.Cholesky())
    search: optx.BacktrackingArmijo = optx.BacktrackingArmijo()
    verbose: Callable = eqx.field(static=True, default=_quiet)

    def init_hessian(self, y, f, grad):
        eye = lx.MatrixLinearOperator(jnp.eye(y.shape[0], dtype=y.dtype), lx.positive_semidefinite_tag)
        return optx.FunctionInfo.EvalGradHessian(f, grad, eye), None

    def update_hessian(self, y, y_eval, f_info, f_eval_info, hessian_update_state):
        vec, lam = self.fisher(y_eval)
        op = lx.MatrixLinearOperator((vec * lam) @ vec.T, lx.positive_semidefinite_tag)
        return optx.FunctionInfo.EvalGradHessian(f_eval_info.f, f_eval_info.grad, op), None

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        grad = state.f_info.grad
        decrement = 0.5 * jnp.vdot(grad, jnp.linalg.solve(state.f_info.hessian.as_matrix(), grad))
        return done | _decrement_test(state, self.decrement_tol, decrement), result


class _Outcome(NamedTuple):
    theta: Array
    value: Array
    successful: Array
    max_steps: Array
    steps: Array


@eqx.filter_jit
def _optimise(thetas, template, static, X, y, jitter, key, max_steps: int, decrement_tol: float, method: str,
              report: bool = False):
    """Minimise −LML of ``(X, y)`` from each row of ``thetas`` (one compiled loop over them)."""
    fn = _objective(template, static, X, y, jitter, report)

    def fisher(theta):
        return _floored_fisher(theta, template, static, X, jitter, key)

    def one(theta0):
        if method == "fisher":
            solver = _FisherScoring(rtol=0.0, atol=1e-2, decrement_tol=decrement_tol, fisher=fisher)
            start, objective, back = theta0, fn, lambda z: z
        else:
            # BFGS in coordinates whitened by the Fisher information at the start, so that
            # its initial Hessian model (the identity) has the right scale and shape.
            vec, lam = fisher(theta0)
            S = vec * jax.lax.rsqrt(lam)[None, :]
            solver = _BFGS(rtol=0.0, atol=1e-2, decrement_tol=decrement_tol)
            start = jnp.zeros_like(theta0)

            def objective(z, args):
                return fn(theta0 + S @ z, args)

            def back(z):
                return theta0 + S @ z

        sol = optx.minimise(objective, solver, start, max_steps=max_steps, throw=False)
        result = sol.result
        if theta0.dtype == jnp.float64:
            # The solver's own evaluation at the returned (last accepted) point; saves one
            # O(n³) evaluation per stage. (In float32 the value along the JVP path differs
            # from a plain evaluation by rounding, ~0.05 at 256 points, enough to change
            # which restart wins; those stages are small and re-evaluate.)
            value = jax.lax.cond(
                sol.state.num_accepted_steps > 0,
                lambda: sol.state.f_info.f.astype(theta0.dtype),
                lambda: objective(sol.value, None).astype(theta0.dtype),
            )
        else:
            value = objective(sol.value, None)
        return _Outcome(
            back(sol.value),
            value,
            result == optx.RESULTS.successful,
            (result == optx.RESULTS.max_steps_reached) | (result == optx.RESULTS.nonlinear_max_steps_reached),
            sol.stats["num_steps"],
        )

    return jax.lax.map(one, thetas)


def _stage_sizes(n: int, first: int) -> list[int]:
    """Nested subset sizes: ``first``, ×4, … (the last at most n/1.5), one doubling more
    when the last is still below n/2.5 and the doubled one stays at most n/1.5, then ``n``.

    The float64 stage on all data starts from the last subset's optimum; on the flat
    ridges of the benchmark's likelihood that start is only as good as the subset is
    large (step counts with and without the extra doubling: ``benchmarks/RESULTS.md``).
    """
    sizes = [min(n, first)]
    while sizes[-1] * _STAGE_GROWTH * _STAGE_MIN_LAST_RATIO <= n:
        sizes.append(sizes[-1] * _STAGE_GROWTH)
    if n > _STAGE_MAX_LAST_RATIO * sizes[-1] and 2 * sizes[-1] * _STAGE_MIN_LAST_RATIO <= n:
        sizes.append(2 * sizes[-1])
    if sizes[-1] < n:
        sizes.append(n)
    return sizes


def _check_int(name: str, value, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer ≥ {low}, got {value!r}")


def fit(
    kernel: Kernel,
    X: Float[Array, "n D"],
    y: Float[Array, " n"],
    *,
    key: PRNGKeyArray,
    num_restarts: int = 4,
    max_steps: int = 100,
    subset_size: int | None = 256,
    explore_in_float32: bool = True,
    method: str = "fisher",
    perturbation: float = 1.0,
    tol: float = 1e-3,
    jitter=None,
    throw: bool = False,
    progress: bool = False,
) -> FittedGP:
    """Type-II maximum likelihood: kernel parameters maximising the LML (Yücel et al. 2013, after eq. 13).

    Optimises the kernel's trainable unconstrained (log) parameters
    (``kernel.trainable_filter()``; ``fixed=`` parameters stay put) with an
    optimistix quasi-Newton minimiser on −LML. An exact value-and-gradient on
    all data costs a Cholesky and a ``K⁻¹`` (O(n³)), so the default strategy
    spends few of them there:

    1. **Explore** on a random subset of ``subset_size`` points (all if
       ``n ≤ subset_size`` or ``subset_size=None``) from ``num_restarts``
       starting points: the data-driven one (variances from var(y),
       lengthscales from median pairwise distances, noise 10 % of var(y)), the
       kernel as passed, then perturbations of the data-driven point by
       N(0, ``perturbation``²) in the log-parameters (drawn with ``key``). The
       best is kept.
    2. **Grow** the subset 4× at a time (nested subsets; the last before all
       data has at most n/1.5 points, and one doubling more when it would
       otherwise be below n/2.5), each stage starting from the previous
       optimum, then finish on all ``n`` points. Stages before the last stop
       early (Newton decrement below ``100 × tol × m/n``).
    3. ``method="fisher"`` (default) is Fisher scoring on the subsets: Newton
       steps on the Fisher information ``½ tr(K⁻¹∂_iK K⁻¹∂_jK)`` (the expected
       Hessian), estimated at each accepted point from 16 random probes (one
       extra Cholesky), with eigenvalues floored at 1e-4 per point and a
       backtracking line search. From poor starts it needs fewer steps than
       BFGS. The **last stage** on all data in float64 (when
       there was an earlier one) is ``optimistix`` BFGS in coordinates whitened by the
       Fisher estimate at its start: near the optimum it walks the flat ridges
       of the likelihood (RQ ``α`` and a bias variance trading off) much faster
       than Fisher scoring, whose curvature model stays fixed to the expected
       Hessian, and each step costs one exact evaluation instead of two
       Choleskys (timings: ``benchmarks/RESULTS.md``).
       In float32 its curvature updates drown in rounding (it ran to
       ``max_steps``), so a float32 last stage stays with Fisher scoring.
       ``method="bfgs"`` uses that whitened BFGS in every stage.
    4. ``explore_in_float32=True`` (default) runs the subset stages in float32
       when the data are float64, then one float64 stage on all data, which
       starts from the last subset's optimum and polishes. (A float32 stage on
       all data before it cost more than it saved: ``benchmarks/RESULTS.md``.) With a single subset stage that is all data, as for
       ``n ≤ subset_size``, that float32 stage stays.
       A float32 stage that fails at every start (``K`` not positive definite
       in float32) is rerun in float64.

    Trained parameters are kept inside scikit-learn's default bounds
    (natural values in ``[1e-5, 1e5]``, :data:`~jaxgaze.gp.transforms.FIT_BOUNDS`)
    by a quadratic wall in log space that is zero inside, so the objective there is
    the exact −LML. Without it the arc-sine kernel's weight and bias variances ran
    off together to 1e6–1e12 on table-top data, ``K`` became singular in float32
    and the fit stopped on a non-finite gradient (``optimiser_failed``); with it
    those fits converge, to log likelihoods 0.2–4.7 higher.

    The last stage stops when the Newton decrement (the gain a Newton step
    predicts) is below ``tol`` log-likelihood units (a float32 stage: below
    ``max(tol, 1e-5 × points)``, its rounding level), when both the step
    (<1e-2 in max norm) and the change of −LML (< 1e-2) are small, or after
    ``max_steps`` steps (per stage, and per start in the first). In directions the data barely determine (Fisher
    eigenvalue below 1e-4 per point; e.g. RQ ``α → ∞``, a bias variance → 0)
    steps are short and a parameter may stop short of its limit, with an LML
    typically within ~1e-2 of the supremum.

    Returns a :class:`FittedGP`; ``result`` (a :class:`jaxgaze.results.RESULTS`)
    says whether the last stage converged (a failed fit is a value);
    ``throw=True`` raises :class:`jaxgaze.results.FitError` instead. The whole fit is seeded by ``key``.
    ``progress=True`` shows a tqdm bar on stderr that counts exact evaluations
    (one per optimiser step) and names the stage running, with the best log
    likelihood of each finished stage.

    Precision: fits of the same data in float32 and float64 agree to within what the
    float32 stopping rule (decrement ``1e-5 × n``) allows: 1e-2 on the log marginal
    likelihood (for ``n ≤ 1000``), 5 % on hyperparameters the data determine well, and
    from the fitted GPs the predictive mean within 5 % of the predictive standard
    deviation and the variance within 2 %, with ``K`` well conditioned (see
    :func:`predict`; ``tests/test_precision.py``).
    """
    _check_jitter(jitter)
    X, y = check_training_data(X, y)
    kernel = _check_kernel(kernel, X.shape[1], X.dtype)
    _check_int("num_restarts", num_restarts, 1)
    _check_int("max_steps", max_steps, 1)
    if subset_size is not None:
        _check_int("subset_size", subset_size, _MIN_POINTS)
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (tol > 0 and math.isfinite(tol)):
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    if isinstance(perturbation, bool) or not isinstance(perturbation, (int, float)) or not perturbation >= 0:
        raise ValueError(f"perturbation must be a non-negative number, got {perturbation!r}")

    n = X.shape[0]
    dtype = X.dtype
    low = jnp.float32 if (explore_in_float32 and dtype == jnp.float64) else dtype
    key_subset, key_perturb, key_probe = jax.random.split(key, 3)
    perm = np.asarray(jax.random.permutation(key_subset, n))
    sizes = _stage_sizes(n, n if subset_size is None else int(subset_size))
    # (size, dtype) of each stage; the last is all data in the data dtype.
    plan = [(m, low) for m in sizes] + ([(n, dtype)] if low != dtype else [])
    if low != dtype and len(sizes) > 1:
        plan.remove((n, low))  # the float64 stage on all data starts from the last float32 subset's optimum
    probe_keys = jax.random.split(key_probe, len(plan))

    X_host, y_host = np.asarray(X), np.asarray(y)

    def subset(m, dt):
        # On the host: indexing the device arrays would compile a few programs per stage.
        index = np.sort(perm[:m])
        return jax.device_put((X_host[index].astype(np.dtype(dt)), y_host[index].astype(np.dtype(dt))))

    def stage_tol(m, dt):
        t = tol if (m == n and dt == dtype) else _STAGE_TOL_FACTOR * tol * m / n
        return max(t, _FLOAT32_DECREMENT_FLOOR * m) if dt == jnp.float32 else t

    # Starting points: data-driven, as passed, perturbed data-driven.
    m0, dt0 = plan[0]
    X0, y0 = subset(m0, dt0)
    stats = _data_stats(np.asarray(X0, np.float64), np.asarray(y0, np.float64))
    start_kernel = _cast(kernel._initialise(stats, stats.y_var), dtype)
    spec = kernel.trainable_filter()
    template, static = eqx.partition(start_kernel, spec)
    theta_data, unravel = ravel_pytree(template)
    p = theta_data.shape[0]
    if p == 0:
        return fitted_gp(kernel, X, y, jitter, RESULTS.successful, jnp.zeros((0,), dtype), (), throw)
    starts = [theta_data]
    if num_restarts >= 2:
        starts.append(ravel_pytree(eqx.partition(kernel, spec)[0])[0])
    if num_restarts > len(starts):
        noise = perturbation * jax.random.normal(key_perturb, (num_restarts - len(starts), p), dtype)
        starts.extend(theta_data + noise)

    global _progress_bar
    bar = tqdm(desc="GP fit", disable=not progress, file=sys.stderr, leave=False,
               bar_format="{desc}: {n_fmt} evaluations [{elapsed}{postfix}]")
    _progress_bar = bar if progress else None
    try:
        stages = []
        theta = None
        result = RESULTS.nonfinite
        restart_lml = None
        for i, (m, dt) in enumerate(plan):
            bar.set_description_str(f"GP fit, stage {i + 1}/{len(plan)} ({m} points, {jnp.dtype(dt).name})")
            thetas = jnp.stack(starts) if i == 0 else theta[None]
            for dt in (dt, dtype) if dt != dtype else (dt,):
                # A float32 stage that fails everywhere (K not positive definite in float32)
                # is rerun in the data dtype.
                Xs, ys = subset(m, dt)
                out = _optimise(
                    thetas.astype(dt),
                    _cast(template, dt),
                    _cast(static, dt),
                    Xs,
                    ys,
                    jitter,
                    probe_keys[i],
                    int(max_steps),
                    float(stage_tol(m, dt)),
                    "bfgs" if (m == n and dt == jnp.float64 and len(plan) > 1) else method,
                    bool(progress),
                )
                values = np.asarray(out.value, np.float64)  # −LML of the stage
                stages.append((m, jnp.dtype(dt).name, int(np.sum(np.asarray(out.steps)))))
                if np.isfinite(values).any():
                    break
            if i == 0:
                restart_lml = jnp.asarray(-values, dtype)
            finite = np.isfinite(values)
            if not finite.any():
                if theta is None:
                    return fitted_gp(start_kernel, X, y, jitter, RESULTS.nonfinite, restart_lml, tuple(stages), throw)
                result = RESULTS.optimiser_failed
                continue
            best = int(np.argmin(np.where(finite, values, np.inf)))
            bar.set_postfix_str(f"log likelihood {-values[best]:.4f} on {m} points")
            theta = out.theta[best].astype(dtype)
            if bool(out.successful[best]):
                result = RESULTS.successful
            elif bool(out.max_steps[best]):
                result = RESULTS.max_steps_reached
            else:
                result = RESULTS.optimiser_failed
    finally:
        _progress_bar = None
        bar.close()

    fitted = eqx.combine(unravel(theta), static)
    return fitted_gp(fitted, X, y, jitter, result, restart_lml, tuple(stages), throw)


def fitted_gp(kernel, X, y, jitter, result, restart_lml, stages, throw) -> FittedGP:
    """A :class:`FittedGP` for ``kernel`` on ``(X, y)``: its Cholesky factor, ``α`` and log
    marginal likelihood, with ``result`` (a :data:`~jaxgaze.results.RESULTS` item; a
    non-finite factor becomes ``not_positive_definite``); raises when ``throw`` and it failed."""
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
    if throw:
        throw_if_failed(None, result, _context(fitted.jitter))
    return fitted


def _context(jitter: float) -> str:
    return f"fit (jitter {jitter:.3g})"


def _message(result: RESULTS, jitter: float) -> str:
    if bool(result == RESULTS.not_positive_definite) or bool(result == RESULTS.nonfinite):
        return f"{_context(jitter)}: {RESULTS[result]}"
    return f"fit: {RESULTS[result]}"
