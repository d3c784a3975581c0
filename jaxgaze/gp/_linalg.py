"""The linear algebra of the exact GP: Cholesky, ``K⁻¹`` by LAPACK ``potri``, and the LML with its custom JVP.

``log N(y | 0, K) = −½ yᵀK⁻¹y − Σ_i log L_ii − (n/2) log 2π`` with ``K = L Lᵀ``
(Rasmussen & Williams 2006, eq. 2.30). Its gradient with respect to ``K`` is
``½(ααᵀ − K⁻¹)`` with ``α = K⁻¹y`` (eq. 5.9), supplied as a custom JVP, so one
value-and-gradient costs a Cholesky plus one ``K⁻¹`` (LAPACK ``potri`` in a host
callback on CPU from n = 513) whatever the number of parameters. Everything here is
traceable and checks nothing; :mod:`jaxgaze.gp.exact` checks the inputs.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from jax.scipy.linalg import cho_solve, solve_triangular
from jaxtyping import Array, Float

from jaxgaze.gp.kernels import Kernel

#: Default jitter, as a fraction of mean(diag K), per dtype.
DEFAULT_RELATIVE_JITTER = {"float64": 1e-6, "float32": 1e-5}

_LOG_2PI = math.log(2.0 * math.pi)


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
#: :func:`jaxgaze.gp.fit` then come from the cache in a new process (``benchmarks/RESULTS.md``).
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
