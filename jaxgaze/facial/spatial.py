"""The spatial model of facial-feature configurations and the exact configuration
search (ROVIS gaze following, Sec. 4, eq. 1, Fig. 7).

A configuration picks one ROI hypothesis or "missing" per feature of
:data:`~jaxgaze.facial.face_model.FEATURES`, with at least 3 present (eq. 1: all four
features, or any three for profile views). Its shape is the present features' image
positions, centred on their centroid and divided by their RMS radius (the
configuration's own scale), kept in image orientation (so a left/right eye swap is
a different shape), as an 8-vector with zeros for the missing feature. One Gaussian
per subset (all 4, and each of the four 3-subsets) is fitted to simulated training
faces, in the subspace its data span (the centring and scaling remove 3 degrees of
freedom); a log prior per subset is the subset's training frequency.

Score of a configuration ``c`` (natural logs)::

    score(c) = log p(subset) + log N(shape(c) | subset) + Σ_{present i} log p(H_i|I)

:func:`best_configuration` enumerates all ``(H+1)^4`` combinations once, scores them
with a ``vmap`` and takes the max (exact); hypotheses with confidence ≤ ``threshold``
(``T_h``) are not used. The posterior of the best configuration is its softmax weight
over all valid combinations, the chain-confidence input of the feedback loop.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.facial.face_model import Hypotheses

__all__ = [
    "SUBSETS",
    "SpatialModel",
    "Configuration",
    "configuration_shape",
    "fit_spatial_model",
    "config_log_density",
    "best_configuration",
    "independent_detectors",
    "selected_positions",
    "enumerate_combinations",
    "check_hypotheses",
]

#: subset index → present mask over FEATURES: 0 all four, 1 + j feature j missing.
SUBSETS = np.array([[True] * 4] + [[j != k for k in range(4)] for j in range(4)])


class SpatialModel(NamedTuple):
    """One Gaussian per subset of :data:`SUBSETS` (5 subsets, 8-d shape vectors)."""

    mean: jnp.ndarray  # (5, 8)
    whiten: jnp.ndarray  # (5, 8, 8) z = (x − mean) @ whiten; zero columns for unused directions
    log_norm: jnp.ndarray  # (5,) −½ Σ log(2π λ) over the used directions
    log_prior: jnp.ndarray  # (5,) log p(subset)


class Configuration(NamedTuple):
    """Result of the search; leading batch dims ``...`` as in the input."""

    chosen: jnp.ndarray  # (..., 4) int, hypothesis slot per feature, −1 = missing
    score: jnp.ndarray  # (...,) the best score, −inf when there is no configuration
    posterior: jnp.ndarray  # (...,) softmax weight of the best configuration, 0 when none
    found: jnp.ndarray  # (...,) bool, a configuration with ≥ 3 features exists


def configuration_shape(positions, present):
    """Normalised shape vector ``(..., 8)`` of ``positions (..., 4, 2)`` under mask ``present (..., 4)``."""
    positions = jnp.asarray(positions, float)
    m = jnp.asarray(present, bool)
    w = m.astype(positions.dtype)[..., None]
    p = jnp.where(m[..., None], positions, 0.0)
    count = jnp.maximum(w.sum(-2, keepdims=True), 1.0)
    c = (p * w).sum(-2, keepdims=True) / count
    d = (p - c) * w
    r = jnp.sqrt((d**2).sum((-1, -2), keepdims=True) / count)
    return (d / jnp.maximum(r, 1e-12)).reshape(*d.shape[:-2], 8)


def fit_spatial_model(features_image, visible, *, min_count: int = 20, floor: float = 1e-4) -> SpatialModel:
    """Fit the spatial model to training faces (ROVIS gaze following, eq. 1, Fig. 7).

    The faces are given by their true feature centres ``(N, 4, 2)`` and ``visible (N, 4)``.
    Each subset's Gaussian uses the faces whose visible set is exactly that subset, or,
    when fewer than ``min_count`` such faces exist, every face showing the subset.
    Eigenvalues below ``1e-9 ×`` the largest are dropped (the constrained directions);
    the others get at least ``floor``.

    Raises:
        ValueError: shapes, NaNs, or a subset with fewer than 3 training faces.
    """
    F = np.asarray(features_image, float)
    V = np.asarray(visible, bool)
    if F.ndim != 3 or F.shape[1:] != (4, 2) or V.shape != F.shape[:2]:
        raise ValueError(f"features_image must be (N, 4, 2) and visible (N, 4), got {F.shape} and {V.shape}")
    if not np.all(np.isfinite(F)):
        raise ValueError("features_image contains NaN or inf")
    means, whitens, norms, priors = [], [], [], []
    n_valid = max(int((V.sum(1) >= 3).sum()), 1)
    for mask in SUBSETS:
        exact = np.all(V == mask, axis=1)
        use = exact if exact.sum() >= min_count else np.all(V[:, mask], axis=1)
        if use.sum() < 3:
            raise ValueError(f"fewer than 3 training faces show the subset {mask.tolist()}")
        X = np.asarray(configuration_shape(F[use], np.broadcast_to(mask, (int(use.sum()), 4))))
        mu = X.mean(0)
        lam, U = np.linalg.eigh(np.cov(X, rowvar=False))
        keep = lam > 1e-9 * lam.max()
        lam = np.maximum(lam, floor)
        W = np.where(keep[None], U / np.sqrt(lam)[None], 0.0)
        means.append(mu)
        whitens.append(W)
        norms.append(-0.5 * np.sum(np.log(2 * np.pi * lam[keep])))
        priors.append(np.log(max(exact.sum(), 1) / n_valid))
    return SpatialModel(*(jnp.asarray(np.array(a)) for a in (means, whitens, norms, priors)))


def _subset_index(present):
    present = jnp.asarray(present, bool)
    missing = jnp.argmin(present, axis=-1)  # the first missing feature
    return jnp.where(jnp.all(present, -1), 0, 1 + missing)


def config_log_density(positions, present, model: SpatialModel):
    """``log p(subset) + log N(shape | subset)`` of a configuration (ROVIS gaze following, eq. 1, Fig. 7).

    For ``positions (..., 4, 2)`` and ``present (..., 4)``; −inf with fewer than 3 present.
    """
    present = jnp.asarray(present, bool)
    s = _subset_index(present)
    x = configuration_shape(positions, present)
    z = jnp.einsum("...i,...ij->...j", x - model.mean[s], model.whiten[s])
    ld = model.log_prior[s] + model.log_norm[s] - 0.5 * jnp.sum(z**2, -1)
    return jnp.where(present.sum(-1) >= 3, ld, -jnp.inf)


def enumerate_combinations(num_hypotheses: int) -> np.ndarray:
    """All ``(K, 4)`` choices of one slot in ``0 … H−1`` or −1 per feature with ≥ 3 present."""
    combos = np.array(list(itertools.product(range(-1, num_hypotheses), repeat=4)), dtype=np.int32)
    return combos[(combos >= 0).sum(1) >= 3]


def _search_one(positions, confidences, model, threshold, combos):
    usable = confidences > threshold  # (4, H)
    logc = jnp.log(jnp.where(usable, confidences, 1.0))

    def score(combo):
        present = combo >= 0
        idx = jnp.maximum(combo, 0)
        ok = jnp.all(jnp.where(present, usable[jnp.arange(4), idx], True))
        pos = positions[jnp.arange(4), idx]  # (4, 2)
        s = config_log_density(pos, present, model) + jnp.sum(jnp.where(present, logc[jnp.arange(4), idx], 0.0))
        return jnp.where(ok, s, -jnp.inf)

    scores = jax.vmap(score)(combos)
    best = jnp.argmax(scores)
    top = scores[best]
    found = jnp.isfinite(top)
    lse = jax.scipy.special.logsumexp(jnp.where(jnp.isfinite(scores), scores, -jnp.inf))
    post = jnp.where(found, jnp.exp(top - lse), 0.0)
    chosen = jnp.where(found, combos[best], -1)
    return Configuration(chosen, top, post, found)


_search_jit = jax.jit(_search_one)


def check_hypotheses(hypotheses, threshold):
    """Validated ``(positions (..., 4, H, 2), confidences (..., 4, H), threshold)`` of ``Hypotheses``
    or a ``(positions, confidences)`` pair; ``ValueError`` naming the bad one."""
    if isinstance(hypotheses, Hypotheses):
        positions, confidences = hypotheses.positions, hypotheses.confidences
    else:
        positions, confidences = hypotheses
    positions = np.asarray(positions, float)
    confidences = np.asarray(confidences, float)
    if positions.ndim < 3 or positions.shape[-3] != 4 or positions.shape[-1] != 2:
        raise ValueError(f"positions must be (..., 4, H, 2), got {positions.shape}")
    if confidences.shape != positions.shape[:-1]:
        raise ValueError(f"confidences must be {positions.shape[:-1]}, got {confidences.shape}")
    if positions.shape[-2] < 1:
        raise ValueError("need at least one hypothesis slot per feature (H ≥ 1)")
    if not np.all(np.isfinite(positions)) or not np.all(np.isfinite(confidences)):
        raise ValueError("hypotheses contain NaN or inf (mark empty slots with confidence 0, not NaN)")
    if np.any(confidences < 0) or np.any(confidences > 1):
        raise ValueError("confidences p(H|I) must lie in [0, 1]")
    threshold = float(threshold)
    if not np.isfinite(threshold):
        raise ValueError(f"threshold must be finite, got {threshold}")
    return positions, confidences, threshold


def best_configuration(hypotheses, model: SpatialModel, threshold: float = 0.0) -> Configuration:
    """Exact best configuration of ``hypotheses`` (ROVIS gaze following, eq. 1, Fig. 7).

    ``hypotheses`` is a :class:`Hypotheses` or ``(positions, confidences)``, shapes
    ``(..., 4, H, 2)`` and ``(..., 4, H)``; only hypotheses with confidence > ``threshold``
    are used.

    With fewer than 3 features having a usable hypothesis, ``found`` is False,
    ``chosen`` is all −1, ``score`` −inf and ``posterior`` 0.

    Raises:
        ValueError: bad shapes, NaN/inf inputs, confidences outside [0, 1], NaN threshold.
    """
    positions, confidences, threshold = check_hypotheses(hypotheses, threshold)
    batch = positions.shape[:-3]
    H = positions.shape[-2]
    combos = jnp.asarray(enumerate_combinations(H))
    P = jnp.asarray(positions.reshape(-1, 4, H, 2))
    C = jnp.asarray(confidences.reshape(-1, 4, H))
    out = jax.vmap(_search_jit, in_axes=(0, 0, None, None, None))(P, C, model, threshold, combos)
    return Configuration(
        out.chosen.reshape(*batch, 4), out.score.reshape(batch), out.posterior.reshape(batch), out.found.reshape(batch)
    )


def independent_detectors(hypotheses, threshold: float = 0.0) -> jnp.ndarray:
    """Baseline: the best-confidence hypothesis per feature (confidence > ``threshold``), no
    spatial model; ``(..., 4)`` slot indices, −1 where a feature has none."""
    _, confidences, threshold = check_hypotheses(hypotheses, threshold)
    best = np.argmax(confidences, axis=-1)
    ok = np.take_along_axis(confidences, best[..., None], -1)[..., 0] > threshold
    return jnp.asarray(np.where(ok, best, -1))


def selected_positions(hypotheses, chosen) -> np.ndarray:
    """Positions ``(..., 4, 2)`` of the ``chosen (..., 4)`` slots; NaN for −1."""
    positions = np.asarray(hypotheses.positions if isinstance(hypotheses, Hypotheses) else hypotheses[0], float)
    chosen = np.asarray(chosen)
    pos = np.take_along_axis(positions, np.maximum(chosen, 0)[..., None, None], axis=-2)[..., 0, :]
    return np.where((chosen >= 0)[..., None], pos, np.nan)
