"""GMM point localisation inside a facial-feature ROI (ROVIS gaze following,
"Human–Robot Interaction Through Robust Gaze Following", Sec. 4, "GMM segmentation").

The pointwise location ``m_i`` of a feature is extracted from the pixel likelihoods
``p(l_i | g_j)`` of its ROI: a Gaussian mixture is fitted by EM to the ROI's pixel
coordinates, each pixel weighted by its (non-negative) likelihood, and the point is
the mixture mode on which the heaviest component sits (:func:`mixture_mode`, started
at that component's mean; with one blob EM may split into two components and the
plain heaviest mean would be off-centre). The heaviest component's mixing weight
(the fraction of the ROI's likelihood mass it explains, in ``[0, 1]``) is the
localisation confidence and its covariance the point's spatial spread.

EM (pure JAX, ``lax.scan`` over a fixed number of iterations, a fixed number ``K``
of components), with pixel weights ``w_p`` normalised to sum to 1::

    log r_pk = log π_k + log N(x_p | μ_k, Σ_k) − logsumexp_k(...)      (log space)
    N_k = Σ_p w_p r_pk,  π_k = N_k,  μ_k = Σ_p w_p r_pk x_p / N_k
    Σ_k = Σ_p w_p r_pk (x_p − μ_k)(x_p − μ_k)ᵀ / N_k + jitter · I

Initialisation is deterministic: the means are spread along the principal axis of
the weighted pixel cloud (``μ_k = m + √λ₁ v₁ t_k``, ``t_k`` evenly in [−1, 1]), each
covariance the cloud's covariance divided by ``K``, equal weights.

Coordinates: ``(x, y) = (column, row)`` in pixels with the pixel ``(r, c)`` centred at
``origin + (c + 0.5, r + 0.5)`` (the image origin is the top-left pixel corner, as in
:mod:`jaxgaze.simulate.faces`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

__all__ = ["GMMFit", "PointEstimate", "fit_gmm", "mixture_mode", "pixel_coordinates", "localize_point"]


class GMMFit(NamedTuple):
    """A fitted mixture; ``K`` components in 2-D."""

    weights: Array  # (K,) mixing weights π_k, sum 1
    means: Array  # (K, 2)
    covariances: Array  # (K, 2, 2)
    log_likelihood: Array  # (num_iters,) weighted mean log-likelihood before each M-step


class PointEstimate(NamedTuple):
    """The localised point of one ROI."""

    point: Array  # (2,) mixture mode reached from the heaviest component's mean, px
    covariance: Array  # (2, 2) that component's covariance (the feature's spatial spread), px²
    weight: Array  # () its mixing weight: the fraction of the likelihood mass it explains
    fit: GMMFit


def _log_gauss(x, mean, cov):
    """``log N(x | mean, cov)`` for ``x (P, 2)``, ``mean (2,)``, ``cov (2, 2)`` (closed-form 2×2)."""
    a, b, c = cov[0, 0], cov[0, 1], cov[1, 1]
    det = a * c - b * b
    dx, dy = x[:, 0] - mean[0], x[:, 1] - mean[1]
    q = (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det
    return -0.5 * q - 0.5 * jnp.log(det) - jnp.log(2 * jnp.pi)


def fit_gmm(coords, weights, num_components: int = 2, *, num_iters: int = 30, jitter: float = 1e-2) -> GMMFit:
    """Weighted EM (ROVIS gaze following, Sec. 4) for a ``num_components`` Gaussian mixture on ``coords (P, 2)``
    with non-negative ``weights (P,)`` (pixel likelihoods; normalised internally). Jittable.

    ``jitter`` (px²) is added to every covariance each M-step so a component collapsing
    on one pixel stays invertible. A zero total weight gives NaN (check before calling;
    :func:`localize_point` does).
    """
    if num_components < 1 or num_iters < 1:
        raise ValueError(f"num_components and num_iters must be ≥ 1, got {num_components}, {num_iters}")
    x = jnp.asarray(coords, jnp.result_type(float))
    w = jnp.clip(jnp.asarray(weights, x.dtype), 0.0)
    w = w / jnp.sum(w)
    K = num_components
    eye = jnp.eye(2, dtype=x.dtype)

    m = w @ x
    x = x - m  # work centred on the weighted mean (float32-safe second moments)
    S = (w[:, None] * x).T @ x + jitter * eye
    # principal axis of the 2×2 S in closed form: λ₁ = tr/2 + √((a−c)²/4 + b²), v₁ ∝ (b, λ₁ − a)
    a_, b_, c_ = S[0, 0], S[0, 1], S[1, 1]
    lam1 = 0.5 * (a_ + c_) + jnp.sqrt(0.25 * (a_ - c_) ** 2 + b_**2)
    v = jnp.where(jnp.abs(b_) > 1e-12 * (a_ + c_), jnp.stack([b_, lam1 - a_]), jnp.where(a_ >= c_, eye[0], eye[1]))
    v = v / jnp.linalg.norm(v)
    t = jnp.linspace(-1.0, 1.0, K) if K > 1 else jnp.zeros(1)
    means0 = jnp.sqrt(lam1) * t[:, None] * v
    covs0 = jnp.broadcast_to(S / K, (K, 2, 2))
    logpi0 = jnp.full((K,), -jnp.log(K), x.dtype)
    xx = jnp.stack([x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2], -1)  # (P, 3)

    def step(carry, _):
        logpi, means, covs = carry
        logp = jax.vmap(_log_gauss, in_axes=(None, 0, 0))(x, means, covs).T + logpi  # (P, K)
        lse = jax.scipy.special.logsumexp(logp, axis=1, keepdims=True)
        wr = w[:, None] * jnp.exp(logp - lse)  # (P, K) weighted responsibilities
        Nk = jnp.maximum(wr.sum(0), 1e-12)
        means = (wr.T @ x) / Nk[:, None]
        mom = (wr.T @ xx) / Nk[:, None]  # E[x²], E[xy], E[y²] per component
        sxx = mom[:, 0] - means[:, 0] ** 2
        sxy = mom[:, 1] - means[:, 0] * means[:, 1]
        syy = mom[:, 2] - means[:, 1] ** 2
        covs = jnp.stack([jnp.stack([sxx, sxy], -1), jnp.stack([sxy, syy], -1)], -2) + jitter * eye
        return (jnp.log(Nk), means, covs), jnp.sum(w * lse[:, 0])

    (logpi, means, covs), ll = jax.lax.scan(step, (logpi0, means0, covs0), None, length=num_iters)
    means = means + m
    return GMMFit(jnp.exp(logpi), means, covs, ll)


def _inv2(M):
    """Closed-form inverse of a 2×2 matrix (cheaper to compile than LAPACK calls)."""
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return jnp.stack([jnp.stack([M[1, 1], -M[0, 1]]), jnp.stack([-M[1, 0], M[0, 0]])]) / det


def mixture_mode(fit: GMMFit, start, num_iters: int = 30) -> Array:
    """Mode of the mixture density reached from ``start`` by fixed-point mean-shift (Carreira-Perpiñán 2000):
    the iteration ``x ← (Σ_k r_k(x) Σ_k⁻¹)⁻¹ Σ_k r_k(x) Σ_k⁻¹ μ_k``, ``r_k(x)`` the responsibilities at ``x``.
    Started at the heaviest component's mean, it finds the peak that component sits on,
    even when EM splits one blob in two."""
    prec = jax.vmap(_inv2)(fit.covariances)  # (K, 2, 2)
    logw = jnp.log(jnp.maximum(fit.weights, 1e-30))
    pm = jnp.einsum("kij,kj->ki", prec, fit.means)

    def step(x, _):
        lp = jax.vmap(_log_gauss, in_axes=(None, 0, 0))(x[None], fit.means, fit.covariances)[:, 0] + logw
        r = jax.nn.softmax(lp)
        A = jnp.einsum("k,kij->ij", r, prec)
        return _inv2(A) @ (r @ pm), None

    x, _ = jax.lax.scan(step, jnp.asarray(start, fit.means.dtype), None, length=num_iters)
    return x


def pixel_coordinates(shape, origin=(0.0, 0.0)) -> Array:
    """``(h·w, 2)`` pixel-centre coordinates ``(x, y)`` of an ``(h, w)`` map, row-major."""
    h, w = shape
    yy, xx = jnp.meshgrid(jnp.arange(h) + 0.5, jnp.arange(w) + 0.5, indexing="ij")
    return jnp.stack([xx.ravel(), yy.ravel()], -1) + jnp.asarray(origin, xx.dtype)


def localize_point(
    likelihood, origin=(0.0, 0.0), *, num_components: int = 2, num_iters: int = 30, jitter: float = 1e-2
) -> PointEstimate:
    """Localise the feature point in an ``(h, w)`` pixel-likelihood map (ROVIS gaze following, Sec. 4).

    The map's top-left corner sits at image position ``origin (x, y)``. Jittable / vmappable.

    Returns the mixture mode reached from the heaviest component, with that
    component's covariance and weight. A map
    with no positive likelihood (or NaN) gives a NaN point and weight 0, never a silent
    number.
    """
    L = jnp.asarray(likelihood)
    if L.ndim != 2:
        raise ValueError(f"likelihood must be an (h, w) map, got shape {L.shape}")
    w = jnp.clip(L.ravel(), 0.0)
    ok = jnp.isfinite(jnp.sum(w)) & (jnp.sum(w) > 0)
    w = jnp.where(ok, w, 1.0)  # keep EM finite; the result is masked below
    fit = fit_gmm(pixel_coordinates(L.shape, origin), w, num_components, num_iters=num_iters, jitter=jitter)
    k = jnp.argmax(fit.weights)
    nan = jnp.nan
    return PointEstimate(
        point=jnp.where(ok, mixture_mode(fit, fit.means[k]), nan),
        covariance=jnp.where(ok, fit.covariances[k], nan),
        weight=jnp.where(ok, fit.weights[k], 0.0),
        fit=fit,
    )
