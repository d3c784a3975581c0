"""The facial-feature cascade as a function of the hypothesis threshold ``T_h``, and
its extremum-seeking tuning (ROVIS gaze following,
"Human–Robot Interaction Through Robust Gaze Following", Sec. 3–4, Fig. 6, eq. 2).

Cascade, per face:

1. **Hypotheses** with ``p(H|I) > T_h`` are kept.
2. **Spatial model** (:mod:`jaxgaze.facial.spatial`): the exact best configuration of
   the kept hypotheses (≥ 3 features) and its posterior ``p(c | H, I)`` (softmax over
   all valid configurations). ``method="independent"`` is the baseline instead: the
   best-confidence kept hypothesis per feature, no spatial model (posterior 1 when
   ≥ 3 features are present, as it claims certainty).
3. **GMM localisation** (:mod:`jaxgaze.facial.gmm`) in a ``(2·roi_half+1)²`` ROI
   centred on each chosen hypothesis. **Simulated pixel likelihood** (a stand-in for
   the paper's colour/feature classifier ``p(l_i | g_j)``): one Gaussian blob of
   s.d. ``blob_sd`` px, peak 1, centred on the feature's *true* centre when that
   feature is visible and lies within the ROI window (the ROI covers the feature),
   otherwise on the ROI centre (the detector fired on something feature-like: a
   distractor), plus i.i.d. ``noise · U(0, 1)`` per pixel. So the GMM refines a
   correct ROI to the true point but cannot rescue a wrong ROI.
4. **Chain confidence** ``y_f`` (eq. 2, ``p(m | I, H, g, l)``), defined here as the
   product of the cascade's stage confidences::

       y_f = p(c | H, I) · mean_{i ∈ c} p(H_i | I) · mean_{i ∈ c} π_i

   (configuration posterior × mean confidence of the chosen hypotheses × mean GMM
   weight of the localised points, the fraction of ROI likelihood mass each point
   explains). No configuration (fewer than 3 features with a kept hypothesis, e.g.
   no face or a threshold above every confidence) gives ``found = False``,
   ``y_f = 0`` and NaN points: a flagged result, never a silent number.

``y_f`` has an interior maximum in ``T_h``: a low threshold keeps many distractors
(low posterior, low mean confidence), a high one rejects true hypotheses until no
configuration is left (``y_f = 0``). :func:`tune_threshold` finds it with
:func:`~jaxgaze.facial.control.extremum_seeking` on the batch mean of ``y_f``;
:func:`sweep_threshold` gives the reference curve.

Everything after input checking is pure JAX (jittable, traced threshold), which the
extremum-seeking ``lax.scan`` needs; the configuration search re-implements
:func:`~jaxgaze.facial.spatial.best_configuration` with a traced threshold from the
public :func:`~jaxgaze.facial.spatial.config_log_density` (a test checks they agree).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from jaxgaze.facial.control import ESCTrajectory, extremum_seeking
from jaxgaze.facial.gmm import localize_point
from jaxgaze.facial.spatial import SpatialModel, check_hypotheses, config_log_density, enumerate_combinations

__all__ = ["ChainResult", "run_chain", "select_face", "sweep_threshold", "tune_threshold"]


class ChainResult(NamedTuple):
    """Cascade output; leading batch dims ``...`` as the hypotheses'."""

    chosen: Array  # (..., 4) int slot per feature, −1 = missing / not chosen
    found: Array  # (...,) bool: a configuration (≥ 3 features) was chosen
    num_kept: Array  # (...,) int hypotheses with p(H|I) > T_h (0: no face at this threshold)
    points: Array  # (..., 4, 2) GMM-localised points, px; NaN for missing features / not found
    point_cov: Array  # (..., 4, 2, 2) GMM component covariances, NaN where no point
    posterior: Array  # (...,) p(c | H, I) of the chosen configuration, 0 when not found
    hypothesis_conf: Array  # (...,) mean p(H|I) of the chosen hypotheses, 0 when not found
    gmm_weight: Array  # (...,) mean GMM weight of the localised points, 0 when not found
    y_f: Array  # (...,) chain confidence (eq. 2), 0 when not found


def _search(positions, confidences, threshold, model, combos):
    """Best configuration of one face (``(4, H, 2)``, ``(4, H)``) with a traced threshold."""
    usable = confidences > threshold
    logc = jnp.log(jnp.where(usable, confidences, 1.0))
    f = jnp.arange(4)

    def score(combo):
        present = combo >= 0
        idx = jnp.maximum(combo, 0)
        ok = jnp.all(jnp.where(present, usable[f, idx], True))
        s = config_log_density(positions[f, idx], present, model) + jnp.sum(jnp.where(present, logc[f, idx], 0.0))
        return jnp.where(ok, s, -jnp.inf)

    scores = jax.vmap(score)(combos)
    best = jnp.argmax(scores)
    top = scores[best]
    found = jnp.isfinite(top)
    post = jnp.where(found, jnp.exp(top - jax.scipy.special.logsumexp(scores)), 0.0)
    return jnp.where(found, combos[best], -1), found, post


def _independent(confidences, threshold):
    best = jnp.argmax(confidences, -1)
    ok = confidences[jnp.arange(4), best] > threshold
    chosen = jnp.where(ok, best, -1)
    found = ok.sum() >= 3
    return jnp.where(found, chosen, -1), found, jnp.where(found, 1.0, 0.0)


def _render(roi_centre, true_centre, visible, u, roi_half, blob_sd, noise):
    """Simulated pixel-likelihood patch and its top-left origin (see the module doc)."""
    size = 2 * roi_half + 1
    origin = jnp.round(roi_centre) - roi_half - 0.5  # pixel centres on integer + 0.5 grid
    covers = visible & jnp.all(jnp.abs(true_centre - roi_centre) <= roi_half)
    c = jnp.where(covers, true_centre, roi_centre)
    yy, xx = jnp.meshgrid(jnp.arange(size) + 0.5, jnp.arange(size) + 0.5, indexing="ij")
    d2 = (xx + origin[0] - c[0]) ** 2 + (yy + origin[1] - c[1]) ** 2
    return jnp.exp(-0.5 * d2 / blob_sd**2) + noise * u, origin  # u: (size, size) U(0, 1) draws


def select_face(positions, confidences, loc, threshold, model, combos, method):
    """Threshold-dependent part of the cascade for one face (ROVIS gaze following, Sec. 4): the spatial
    (or independent) selection of its hypotheses ``(4, H)`` and the GMM-localised points ``loc``."""
    points_all, cov_all, weight_all = loc
    if method == "spatial":
        chosen, found, post = _search(positions, confidences, threshold, model, combos)
    else:
        chosen, found, post = _independent(confidences, threshold)
    present = chosen >= 0
    f = jnp.arange(4)
    idx = jnp.maximum(chosen, 0)
    conf = confidences[f, idx]
    k = jnp.maximum(present.sum(), 1)
    hconf = jnp.where(found, jnp.sum(jnp.where(present, conf, 0.0)) / k, 0.0)
    gw = jnp.where(found, jnp.sum(jnp.where(present, weight_all[f, idx], 0.0)) / k, 0.0)
    points = jnp.where(present[:, None], points_all[f, idx], jnp.nan)
    cov = jnp.where(present[:, None, None], cov_all[f, idx], jnp.nan)
    num_kept = jnp.sum(confidences > threshold)
    return ChainResult(chosen, found, num_kept, points, cov, post, hconf, gw, post * hconf * gw)


@partial(jax.jit, static_argnames=("cfg",))
def _localise_batch(P, T, V, key, cfg):
    """GMM-localise every hypothesis slot: points ``(N, 4, H, 2)``, covariances, weights ``(N, 4, H)``.

    The pixel-likelihood map of an ROI is a property of the frame, not of ``T_h``, so
    it is computed once per frame and the threshold only selects among slots."""
    _, roi_half, blob_sd, noise, K, iters = cfg
    size = 2 * roi_half + 1
    N, _, H, _ = P.shape
    u = jax.random.uniform(key, (N * 4 * H, size, size), P.dtype)
    roi = P.reshape(-1, 2)
    truth = jnp.broadcast_to(T[:, :, None], P.shape).reshape(-1, 2)
    vis = jnp.broadcast_to(V[:, :, None], P.shape[:3]).reshape(-1)
    maps, origins = jax.vmap(_render, in_axes=(0, 0, 0, 0, None, None, None))(roi, truth, vis, u, roi_half, blob_sd, noise)
    est = jax.vmap(partial(localize_point, num_components=K, num_iters=iters))(maps, origins)
    return est.point.reshape(N, 4, H, 2), est.covariance.reshape(N, 4, H, 2, 2), est.weight.reshape(N, 4, H)


@partial(jax.jit, static_argnames=("method",))
def _select_batch(P, C, loc, threshold, model, combos, method):
    return jax.vmap(select_face, in_axes=(0, 0, 0, None, None, None, None))(P, C, loc, threshold, model, combos, method)


def _prepare(hypotheses, features_image, visible):
    P, C, _ = check_hypotheses(hypotheses, 0.0)  # the same checks as the spatial search
    batch = P.shape[:-3]
    T = np.asarray(features_image, float)
    if T.shape != (*batch, 4, 2) or not np.all(np.isfinite(T)):
        raise ValueError(f"features_image must be finite with shape {(*batch, 4, 2)}, got {T.shape}")
    V = np.ones(T.shape[:-1], bool) if visible is None else np.asarray(visible, bool)
    if V.shape != T.shape[:-1]:
        raise ValueError(f"visible must have shape {T.shape[:-1]}, got {V.shape}")
    H = P.shape[-2]
    return batch, (P.reshape(-1, 4, H, 2), C.reshape(-1, 4, H), T.reshape(-1, 4, 2), V.reshape(-1, 4)), H


def _cfg(method, roi_half, blob_sd, noise, num_components, num_iters):
    if method not in ("spatial", "independent"):
        raise ValueError(f"method must be 'spatial' or 'independent', got {method!r}")
    if roi_half < 1 or blob_sd <= 0 or noise < 0:
        raise ValueError("need roi_half ≥ 1, blob_sd > 0, noise ≥ 0")
    return (method, int(roi_half), float(blob_sd), float(noise), int(num_components), int(num_iters))


def run_chain(
    hypotheses,
    spatial_model: SpatialModel,
    threshold: float,
    *,
    features_image,
    visible=None,
    key=None,
    method: str = "spatial",
    roi_half: int = 6,
    blob_sd: float = 2.0,
    noise: float = 0.05,
    num_components: int = 2,
    num_iters: int = 15,
) -> ChainResult:
    """Run the cascade (ROVIS gaze following, eq. 2, Fig. 6) at threshold ``T_h = threshold`` on ``hypotheses`` (a
    :class:`~jaxgaze.facial.face_model.Hypotheses` or ``(positions, confidences)``,
    ``(..., 4, H, 2)``, ``(..., 4, H)``).

    ``features_image (..., 4, 2)`` and ``visible (..., 4)`` (default all) are the
    simulator's truth, used **only** to render the simulated pixel-likelihood maps
    (module doc); ``key`` draws their noise (default ``jax.random.key(0)``).

    Raises:
        ValueError: bad shapes / values, NaN threshold, unknown ``method``.
    """
    cfg = _cfg(method, roi_half, blob_sd, noise, num_components, num_iters)
    threshold = float(threshold)
    if not np.isfinite(threshold):
        raise ValueError(f"threshold must be finite, got {threshold}")
    batch, (P, C, T, V), H = _prepare(hypotheses, features_image, visible)
    key = jax.random.key(0) if key is None else key
    combos = jnp.asarray(enumerate_combinations(H))
    P, C = jnp.asarray(P), jnp.asarray(C)
    loc = _localise_batch(P, jnp.asarray(T), jnp.asarray(V), key, cfg)
    out = _select_batch(P, C, loc, jnp.asarray(threshold, P.dtype), spatial_model, combos, cfg[0])
    return ChainResult(*(a.reshape(*batch, *a.shape[1:]) for a in out))


def _faces_arrays(faces):
    _, arrs, H = _prepare(faces.hypotheses, faces.features_image, faces.visible)
    return tuple(jnp.asarray(a) for a in arrs), jnp.asarray(enumerate_combinations(H))


def sweep_threshold(faces, spatial_model: SpatialModel, thresholds, *, key=None, **chain_kw) -> np.ndarray:
    """Mean ``y_f`` (ROVIS gaze following, eq. 2) over all ``faces`` at each threshold of ``thresholds``.

    The same noise key is used for each threshold.
    """
    cfg = _cfg(chain_kw.pop("method", "spatial"), chain_kw.pop("roi_half", 6), chain_kw.pop("blob_sd", 2.0),
               chain_kw.pop("noise", 0.05), chain_kw.pop("num_components", 2), chain_kw.pop("num_iters", 15))
    if chain_kw:
        raise TypeError(f"unexpected arguments {sorted(chain_kw)}")
    (P, C, T, V), combos = _faces_arrays(faces)
    key = jax.random.key(0) if key is None else key
    loc = _localise_batch(P, T, V, key, cfg)
    ths = np.asarray(thresholds, float).ravel()
    return np.array([float(_select_batch(P, C, loc, jnp.asarray(t, P.dtype), spatial_model, combos, cfg[0]).y_f.mean()) for t in ths])


def tune_threshold(
    faces,
    spatial_model: SpatialModel,
    *,
    key,
    theta0: float = 0.2,
    batch_size: int = 128,
    num_steps: int = 200,
    amplitude: float = 0.04,
    frequency: float = 1.0,
    gain: float = 2.0,
    highpass: float = 0.2,
    bounds: tuple[float, float] = (0.0, 0.95),
    **chain_kw,
) -> ESCTrajectory:
    """Tune ``T_h`` by extremum seeking on the mean ``y_f`` of a batch of frames (ROVIS gaze following, Fig. 5–6).

    The objective is noisy: each step draws a fresh batch of ``batch_size`` frames
    (indices sampled with replacement from the simulated pool ``faces``) from the
    step's key. Each frame's pixel-likelihood maps (and so its GMM points) are drawn
    once per frame, as they do not depend on ``T_h``. Returns the ESC trajectory
    (``final`` is the tuned threshold). The whole loop is one ``lax.scan``.
    """
    cfg = _cfg(chain_kw.pop("method", "spatial"), chain_kw.pop("roi_half", 6), chain_kw.pop("blob_sd", 2.0),
               chain_kw.pop("noise", 0.05), chain_kw.pop("num_components", 2), chain_kw.pop("num_iters", 15))
    if chain_kw:
        raise TypeError(f"unexpected arguments {sorted(chain_kw)}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be ≥ 1, got {batch_size}")
    (P, C, T, V), combos = _faces_arrays(faces)
    key, kloc = jax.random.split(key)
    loc = _localise_batch(P, T, V, kloc, cfg)
    return _tune(P, C, loc, spatial_model, combos, key, float(theta0), float(amplitude), float(frequency), float(gain),
                 float(highpass), tuple(float(b) for b in bounds), int(batch_size), int(num_steps), cfg)


@partial(jax.jit, static_argnums=tuple(range(6, 15)))
def _tune(P, C, loc, model, combos, key, theta0, amplitude, frequency, gain, highpass, bounds, batch_size, num_steps, cfg):
    n = P.shape[0]

    def objective(theta, k):
        i = jax.random.randint(k, (batch_size,), 0, n)
        sub = jax.tree_util.tree_map(lambda a: a[i], loc)
        return _select_batch(P[i], C[i], sub, theta, model, combos, cfg[0]).y_f.mean()

    return extremum_seeking(
        objective, theta0, amplitude=amplitude, frequency=frequency, gain=gain,
        num_steps=num_steps, highpass=highpass, bounds=bounds, key=key,
    )
