"""Person-specific gaze bias from frame offsets (Siegfried, Odobez et al. 2017, Sec. 3.2).

The offsets ``o_i = angles(u_t) − g_i`` ``(N, 2)`` (yaw, tilt; radians; see
:func:`jaxgaze.bias.looking.gaze_offsets`) of frames where the person probably looks
at the partner scatter around the bias ``b``; frames where they looked elsewhere are
outliers. Three estimators:

* ``"mean"``: ``b̂ = (1/N) Σ o_i`` (the paper's *Mean*, N = 20; with ground-truth
  looking frames this is *GT-Mean*).
* ``"lmeds"``: least median of squares, eq. 2, ``b^med = argmin_b median_i ‖o_i − b‖²``
  over the candidates ``b ∈ {o_i}``, then ``b̂`` = the mean of the ``⌈N/2⌉`` offsets
  closest to ``b^med`` (the paper's *Med*, N = 40 → 20 kept).
* ``"bayes"``: a two-component mixture (looking at the partner, Gaussian / elsewhere,
  uniform over the offsets' box) sampled with NUTS, giving a posterior over ``b`` and per-frame responsibilities
  (:func:`bias_model`).

The oracle variants (GT-Mean, GT-Med) need no separate API: pass the offsets of the
ground-truth looking frames.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxgaze._checks import bucket_size
from jaxgaze.geometry import rad_to_deg
from jaxgaze.nuts import SamplerReport, quiet_single_chain, sample_nuts, sampler_report
from jaxgaze.results import RESULTS, throw_if_failed

__all__ = [
    "BiasEstimate",
    "estimate_bias",
    "update_bias",
    "lmeds_bias",
    "bias_model",
    "sample_bias_posterior",
    "contrast_log_density",
    "elsewhere_log_density",
    "ELSEWHERE_MIN_WIDTH_DEG",
    "METHODS",
]

METHODS = ("mean", "lmeds", "bayes")

_DEG = math.radians(1.0)  # not deg_to_rad: a program compiled at import would never be cached


class BiasEstimate(NamedTuple):
    """A person's gaze bias ``b = (b_φ, b_θ)`` (radians); corrected gaze is ``g + b``.

    Attributes:
        bias: ``(2,)`` the estimate (``"bayes"``: the posterior mean).
        method: ``"mean"``, ``"lmeds"`` or ``"bayes"``.
        num_frames: ``N``, the number of offsets used.
        inliers: ``(N,)`` frames taken as "looking": all (mean), the ``⌈N/2⌉`` kept by
            LMedS, or responsibility > 0.5 (bayes).
        covariance: ``(2, 2)`` uncertainty of ``bias``: the squared standard error
            ``S/N`` of the mean (``S`` the sample covariance; of the kept subset for
            LMedS, which ignores the selection and so is optimistic), or the posterior
            covariance of ``b`` (bayes). ``None`` when fewer than 2 frames enter the mean.
        responsibilities: ``(N,)`` posterior probability that each frame looks at the
            partner (bayes), else ``None``.
        sampler: the :class:`~jaxgaze.nuts.SamplerReport` of the NUTS run (bayes: ``idata``, the
            sampler's ``result``, its mixing ``diagnostics`` and the ``summary`` table of the model's
            parameters), else ``None`` (mean and LMedS sample nothing).
        samples: dict of posterior draws, chains flattened (bayes: ``bias (S, 2)``,
            ``noise_scale (S, 2)``, ``correlation (S,)``, ``looking_share (S,)``,
            ``responsibilities (S, N)``), else ``None``. Sampler statistics
            (divergences, step sizes, …) are in ``sampler.idata.sample_stats``.
        candidate: index of the LMedS candidate ``b^med = o_candidate`` (lmeds), else ``None``.
        offsets: ``(N, 2)`` the offsets used, kept for :func:`update_bias`.
        options: the keyword options of the fit, reused by :func:`update_bias`.
        result: ``RESULTS.successful``, or (bayes) ``RESULTS.not_mixed`` when the sampler
            failed the checks of :func:`jaxgaze.nuts.mixing_result` (split r-hat, bulk and
            tail ESS, divergences, acceptance): its draws are then not a reliable posterior.
            :func:`jaxgaze.succeeded` reads it.
    """

    bias: Float[np.ndarray, "2"]
    method: str
    num_frames: int
    inliers: Bool[np.ndarray, " N"]
    covariance: Float[np.ndarray, "2 2"] | None = None
    responsibilities: Float[np.ndarray, " N"] | None = None
    sampler: SamplerReport | None = None
    samples: dict | None = None
    candidate: int | None = None
    offsets: Float[np.ndarray, "N 2"] | None = None
    options: dict | None = None
    result: RESULTS = RESULTS.successful

    @property
    def bias_deg(self) -> np.ndarray:
        """The bias in degrees."""
        return np.asarray(rad_to_deg(np.asarray(self.bias)))


# -------------------------------------------------------------------------- checks


def _offsets(offsets, *, minimum: int = 1, method: str = "") -> jax.Array:
    if isinstance(offsets, jax.core.Tracer):
        raise TypeError("estimate_bias needs concrete offsets; use lmeds_bias / sample_bias_posterior under jit")
    o = np.asarray(offsets)
    if o.ndim != 2 or o.shape[1] != 2:
        raise ValueError(f"offsets must have shape (N, 2) (yaw, tilt in radians), got {o.shape}")
    if not np.issubdtype(o.dtype, np.number) or np.issubdtype(o.dtype, np.complexfloating):
        raise ValueError(f"offsets must be real numbers, got dtype {o.dtype}")
    if o.shape[0] == 0:
        raise ValueError("no frames: offsets is empty (N = 0); select at least one frame to estimate a bias")
    bad = ~np.isfinite(o).all(axis=1)
    if bad.any():
        raise ValueError(f"offsets row {int(np.flatnonzero(bad)[0])} is not finite (NaN or inf): {o[bad][0]}")
    if o.shape[0] < minimum:
        raise ValueError(
            f"{method} needs at least {minimum} frames, got {o.shape[0]}: with fewer it cannot tell the frames "
            "that look at the partner from the others; use method='mean'"
        )
    return jnp.asarray(o, dtype=jax.dtypes.canonicalize_dtype(np.result_type(o.dtype, np.float32)))


def _standard_error(x: np.ndarray) -> np.ndarray | None:
    """``S / n`` with ``S`` the unbiased sample covariance; ``None`` for n < 2."""
    n = x.shape[0]
    if n < 2:
        return None
    return np.cov(x, rowvar=False, ddof=1).reshape(2, 2) / n


# ------------------------------------------------------------------------- LMedS


@jax.jit
def lmeds_bias(
    offsets: Float[Array, "N 2"], mask: Bool[Array, " N"] | None = None
) -> tuple[Float[Array, "2"], Int[Array, ""], Bool[Array, " N"]]:
    """LMedS bias (Siegfried et al. 2017, eq. 2), vectorised over the ``N × N`` squared distances.

    For every candidate ``b = o_i``, ``m_i = median_j ‖o_j − o_i‖²`` (the usual median:
    the mean of the two middle values when ``n`` is even); ``b^med = o_{i*}`` with
    ``i* = argmin_i m_i`` (ties: lowest index). The estimate is the mean of the
    ``k = ⌈n/2⌉`` offsets closest to ``b^med`` (ties: lowest index) — the paper's
    "0.5 N", rounded up so that ``n = 1`` keeps one frame.

    ``mask (N,)`` marks real rows (padding is ignored; ``n = Σ mask``). Returns
    ``(bias (2,), i*, inliers (N,))``. Jittable and vmappable; no value checks.
    """
    o = jnp.asarray(offsets)
    mask = jnp.ones(o.shape[0], bool) if mask is None else jnp.asarray(mask, bool)
    n = jnp.sum(mask)
    diff = o[:, None, :] - o[None, :, :]  # (candidate i, frame j)
    # XLA contracts ``dx·dx + dy·dy`` into a fused multiply-add, which rounds differently from
    # plain IEEE arithmetic and can break ties between candidates. ``sort`` is never fused, so
    # the squares are rounded on their own; their sum in either order is ``dx² + dy²`` exactly.
    squares = jnp.sort(diff * diff, axis=-1)
    r2 = squares[..., 0] + squares[..., 1]
    r2 = jnp.where(mask[None, :], r2, jnp.inf)
    ordered = jnp.sort(r2, axis=1)
    lo, hi = (n - 1) // 2, n // 2
    median = (jnp.take(ordered, lo, axis=1) + jnp.take(ordered, hi, axis=1)) / 2
    median = jnp.where(mask, median, jnp.inf)
    best = jnp.argmin(median)
    order = jnp.argsort(r2[best], stable=True)
    rank = jnp.zeros(o.shape[0], jnp.int32).at[order].set(jnp.arange(o.shape[0], dtype=jnp.int32))
    k = (n + 1) // 2
    inliers = (rank < k) & mask
    bias = jnp.sum(jnp.where(inliers[:, None], o, 0.0), axis=0) / k
    return bias, best, inliers


# ---------------------------------------------------------------- Bayesian mixture


#: The "elsewhere" box is at least this wide on each axis (degrees): glances away spread over
#: tens of degrees, and a box as narrow as the looking cluster would compete with it.
ELSEWHERE_MIN_WIDTH_DEG = 20.0


def elsewhere_log_density(offsets: Float[Array, "N 2"], mask: Bool[Array, " N"] | None = None) -> Float[Array, ""]:
    """``log u``: the uniform density of glances away over the box the offsets span (Siegfried et al. 2017, Sec. 3.2).

    Per axis the box is ``(max − min)·(n + 1)/(n − 1)`` wide (the unbiased width of a
    uniform from ``n`` draws), at least :data:`ELSEWHERE_MIN_WIDTH_DEG`, so
    ``log u = −Σ_axis log width``. ``mask`` marks real rows.
    """
    o = jnp.asarray(offsets)
    mask = jnp.ones(o.shape[0], bool) if mask is None else jnp.asarray(mask, bool)
    n = jnp.sum(mask)
    hi = jnp.max(jnp.where(mask[:, None], o, -jnp.inf), axis=0)
    lo = jnp.min(jnp.where(mask[:, None], o, jnp.inf), axis=0)
    spread = jnp.where(n > 1, (hi - lo) * (n + 1) / jnp.maximum(n - 1, 1), 0.0)
    return -jnp.sum(jnp.log(jnp.maximum(spread, ELSEWHERE_MIN_WIDTH_DEG * _DEG)))


def bias_model(
    offsets: Float[Array, "N 2"],
    mask: Bool[Array, " N"] | None = None,
    log_contrast: Float[Array, " N"] | None = None,
    *,
    bias_scale_deg: float = 15.0,
    noise_scale_deg: float = 4.0,
    noise_scale_spread: float = 0.6,
    correlation_concentration: float = 2.0,
    looking_prior: tuple[float, float] = (5.7, 4.3),
):
    """numpyro model of the offsets: "looking at the partner" or "elsewhere" (Siegfried et al. 2017, Sec. 5, Fig. 7).

    * ``b ~ N(0, (15°)² I₂)``: biases of appearance-based gaze are a few to ~20°
      (Fig. 7 of the paper: within ±20° before correction).
    * per-axis noise ``σ ~ LogNormal(log 4°, 0.6)`` (95% in ≈ 1.2°–13°) and the
      correlation ``L ~ LKJCholesky(2, 2)``; ``Σ = diag(σ) L Lᵀ diag(σ)``.
    * looking share ``π ~ Beta(5.7, 4.3)``: mean 0.57, the measured probability of
      looking at a speaking partner (Sec. 5), worth 10 frames — weak against N = 40.
    * ``o_i ~ π N(b, Σ) + (1 − π) u`` (assignment marginalised with ``logaddexp``):
      a glance elsewhere lands anywhere in the box the offsets span, with the
      uniform density ``u`` of :func:`elsewhere_log_density`. The box depends on no
      parameter, so glances away exert no pull on ``b`` however they are spread
      (around the partner, to one side, or clustered), and the two components
      cannot swap. (A Gaussian "elsewhere" centred at ``b`` pulls ``b`` towards
      one-sided glances, and one of fixed width loses to LMedS when the glances are
      wider than it.)

    **Contrast with the silent partner** (``log_contrast``, optional): the log density
    of each offset under the glances made while the partner is *silent*
    (:func:`contrast_log_density`). The speaker prior says people look at a speaker
    5–8× more often than at a silent partner, so a cluster of offsets that is as
    dense in silent frames (the desk, the notes) is "elsewhere", and the partner is
    the cluster that speaking enriches. The elsewhere density becomes
    ``0.8 q(o_i) + 0.2 u``.

    ``mask (N,)`` marks real rows (padding adds nothing). Records
    ``responsibilities (N,)``, the posterior probability of "looking" per frame, and
    ``correlation``. Angles in radians; ``*_deg`` options in degrees.
    """
    o = jnp.asarray(offsets)
    dtype = o.dtype
    mask = jnp.ones(o.shape[0], bool) if mask is None else mask
    bias = numpyro.sample("bias", dist.Normal(jnp.zeros(2, dtype), bias_scale_deg * _DEG).to_event(1))
    log_noise = jnp.full(2, jnp.log(noise_scale_deg * _DEG), dtype)
    noise_scale = numpyro.sample("noise_scale", dist.LogNormal(log_noise, noise_scale_spread).to_event(1))
    corr_chol = numpyro.sample("corr_chol", dist.LKJCholesky(2, concentration=correlation_concentration))
    numpyro.deterministic("correlation", corr_chol[1, 0])
    looking_share = numpyro.sample("looking_share", dist.Beta(*looking_prior))
    scale_tril = noise_scale[:, None] * corr_chol
    looking = jnp.log(looking_share) + dist.MultivariateNormal(bias, scale_tril=scale_tril).log_prob(o)
    broad = jnp.broadcast_to(elsewhere_log_density(o, mask), looking.shape)
    if log_contrast is not None:
        broad = jnp.logaddexp(jnp.log(0.8) + log_contrast, jnp.log(0.2) + broad)
    elsewhere = jnp.log1p(-looking_share) + broad
    per_frame = jnp.logaddexp(looking, elsewhere)
    numpyro.deterministic("responsibilities", jnp.exp(looking - per_frame))
    numpyro.factor("offsets", jnp.sum(jnp.where(mask, per_frame, 0.0)))


_SUMMARY_VARS = ["bias", "noise_scale", "correlation", "looking_share"]


@jax.jit
def contrast_log_density(
    offsets: Float[Array, "... N 2"],
    silent_offsets: Float[Array, "... M 2"],
    silent_mask: Bool[Array, "... M"] | None = None,
    bandwidth: float = 4.0 * _DEG,
) -> Float[Array, "... N"]:
    """``log q(o_i)``: a Gaussian kernel density (bandwidth in radians) of the silent-partner offsets.

    ``q(o) = (1/M) Σ_j N(o; o'_j, bandwidth² I₂)`` over the masked silent offsets
    ``o'_j`` (frames of the same window where the partner does not speak and the
    head faces them, :func:`jaxgaze.bias.looking.candidate_frames` with the
    partner's silence). With no silent frame it is ``−inf`` (no contrast).
    """
    o = jnp.asarray(offsets)
    silent = jnp.asarray(silent_offsets, o.dtype)
    mask = jnp.ones(silent.shape[:-1], bool) if silent_mask is None else jnp.asarray(silent_mask, bool)
    kernel = dist.Normal(silent[..., None, :, :], bandwidth).to_event(1).log_prob(o[..., :, None, :])  # (..., N, M)
    kernel = jnp.where(mask[..., None, :], kernel, -jnp.inf)
    count = jnp.sum(mask, axis=-1, keepdims=True)
    return jax.nn.logsumexp(kernel, axis=-1) - jnp.log(jnp.maximum(count, 1))


@functools.lru_cache(maxsize=8)
def _model(options: tuple):
    """One model object per option set: it keys the compilation in :func:`jaxgaze.nuts.sample_nuts`."""
    return functools.partial(bias_model, **dict(options))


def sample_bias_posterior(
    offsets: Float[Array, "... N 2"],
    mask: Bool[Array, "... N"] | None = None,
    silent_offsets: Float[Array, "... M 2"] | None = None,
    silent_mask: Bool[Array, "... M"] | None = None,
    *,
    key: PRNGKeyArray,
    num_warmup: int = 500,
    num_samples: int = 500,
    num_chains: int = 1,
    target_accept_prob: float = 0.8,
    progress: bool = False,
    **model_options,
) -> tuple[dict, dict]:
    """NUTS draws from :func:`bias_model` (Siegfried et al. 2017, Sec. 5, Fig. 7) for one person or many at once.

    ``offsets`` is ``(N, 2)`` for one person or ``(P, N, 2)`` for many.
    Runs numpyro's NUTS kernel through :func:`jaxgaze.nuts.sample_nuts`: one
    compiled single-chain program, reused for every person and chain, with ``N``
    padded to a power of two (masked) so that fits of similar size share it. Each
    chain starts at the person's LMedS estimate, in the "looking" mode rather than
    at a cluster of glances elsewhere. With ``silent_offsets`` (the offsets of the
    silent-partner frames, see :func:`bias_model`) the model contrasts the two.
    The chains still start at LMedS, not at the candidate that the contrast model
    scores best: that start can land on a wrong cluster the model itself prefers.

    ``key`` is one key (split over people and chains). Returns ``(values, stats)``:
    dicts of arrays ``(..., chains, draws, ...)`` — ``bias``, ``noise_scale``,
    ``corr_chol``, ``correlation``, ``looking_share``, ``responsibilities`` (cut to
    ``N``) — and the sampler statistics (``diverging``, ``acceptance_rate``,
    ``n_steps``, ``lp``). No value checks here (see :func:`estimate_bias`).
    """
    o = jnp.asarray(offsets)
    if o.ndim < 2 or o.shape[-1] != 2:
        raise ValueError(f"offsets must have shape (..., N, 2), got {o.shape}")
    n = o.shape[-2]
    if n == 0:
        raise ValueError("no frames: offsets is empty (N = 0)")
    m = jnp.ones(o.shape[:-1], bool) if mask is None else jnp.broadcast_to(jnp.asarray(mask, bool), o.shape[:-1])
    pad = bucket_size(n) - n
    o = jnp.pad(o.astype(jnp.promote_types(o.dtype, jnp.float32)), [(0, 0)] * (o.ndim - 2) + [(0, pad), (0, 0)])
    m = jnp.pad(m, [(0, 0)] * (m.ndim - 1) + [(0, pad)])
    batch = o.shape[:-2]
    flat_o = jnp.repeat(o.reshape((-1,) + o.shape[-2:]), num_chains, axis=0)
    flat_m = jnp.repeat(m.reshape((-1, o.shape[-2])), num_chains, axis=0)
    model_args = (flat_o, flat_m)
    start = jax.vmap(lmeds_bias)(flat_o, flat_m)[0]
    if silent_offsets is not None:
        silent = jnp.broadcast_to(jnp.asarray(silent_offsets, o.dtype), batch + jnp.shape(silent_offsets)[-2:])
        sm = (jnp.ones(silent.shape[:-1], bool) if silent_mask is None
              else jnp.broadcast_to(jnp.asarray(silent_mask, bool), silent.shape[:-1]))
        log_q = contrast_log_density(o, silent, sm)  # (..., N_padded)
        flat_q = jnp.repeat(log_q.reshape((-1, o.shape[-2])), num_chains, axis=0)
        flat_q = jnp.where(jnp.isfinite(flat_q), flat_q, -1e30)  # no silent frame: no contrast
        model_args = (flat_o, flat_m, flat_q)
    noise0 = model_options.get("noise_scale_deg", 4.0) * _DEG
    count = flat_o.shape[0]
    init = {  # numpyro's unconstrained space
        "bias": start,
        "noise_scale": jnp.full((count, 2), jnp.log(noise0), flat_o.dtype),  # log σ
        "corr_chol": jnp.zeros((count, 1), flat_o.dtype),  # ρ = 0
        "looking_share": jnp.full(count, 0.3, flat_o.dtype),  # logit π ≈ 0.57
    }
    values, stats = sample_nuts(
        _model(tuple(sorted(model_options.items()))), key, model_args, init,
        num_warmup=num_warmup, num_samples=num_samples, target_accept_prob=target_accept_prob,
        progress=progress, description="gaze bias posterior",
    )
    shape = batch + (num_chains,)
    values = {k: v.reshape(shape + v.shape[1:]) for k, v in values.items()}
    stats = {k: v.reshape(shape + v.shape[1:]) for k, v in stats.items()}
    values["responsibilities"] = values["responsibilities"][..., :n]
    return values, stats


def _fit_bayes(o: jax.Array, key, num_warmup, num_samples, num_chains, target_accept_prob, progress,
               model_options, silent_offsets=None):
    import arviz as az

    key = jax.random.key(0) if key is None else key
    values, stats = sample_bias_posterior(o, None, silent_offsets, key=key, num_warmup=num_warmup,
                                          num_samples=num_samples, num_chains=num_chains,
                                          target_accept_prob=target_accept_prob, progress=progress,
                                          **model_options)
    values = {k: np.asarray(v) for k, v in values.items()}
    stats = {k: np.asarray(v) for k, v in stats.items()}
    posterior = {k: values[k] for k in ("bias", "noise_scale", "correlation", "looking_share", "responsibilities")}
    with quiet_single_chain(num_chains):
        idata = az.from_dict(
            posterior=posterior,
            sample_stats=stats,
            observed_data={"offsets": np.asarray(o)},
            dims={"bias": ["axis"], "noise_scale": ["axis"], "responsibilities": ["frame"],
                  "offsets": ["frame", "axis"]},
            coords={"axis": ["yaw", "tilt"], "frame": np.arange(o.shape[0])},
        )
    sampler = sampler_report(idata, _SUMMARY_VARS)
    flat = {k: v.reshape((-1,) + v.shape[2:]) for k, v in values.items()}
    bias_draws = flat["bias"]
    responsibilities = flat["responsibilities"].mean(0)
    return BiasEstimate(
        bias=bias_draws.mean(0),
        method="bayes",
        num_frames=int(o.shape[0]),
        inliers=responsibilities > 0.5,
        covariance=np.cov(bias_draws, rowvar=False).reshape(2, 2),
        responsibilities=responsibilities,
        sampler=sampler,
        samples=flat,
        result=sampler.result,
    )


# --------------------------------------------------------------------------- API


def estimate_bias(
    offsets: Float[Array, "N 2"],
    method: str = "lmeds",
    *,
    key: PRNGKeyArray | None = None,
    num_warmup: int = 500,
    num_samples: int = 500,
    num_chains: int = 1,
    target_accept_prob: float = 0.8,
    progress: bool = False,
    silent_offsets: Float[Array, "M 2"] | None = None,
    throw: bool = False,
    **model_options,
) -> BiasEstimate:
    """Estimate a person's gaze bias from the offsets ``o_i`` of selected frames (Siegfried et al. 2017, Sec. 3.2).

    ``offsets`` are ``(N, 2)`` (radians).
    ``method``: ``"mean"`` (N ≥ 1), ``"lmeds"`` (eq. 2, N ≥ 3; the default, the
    paper's Spk-Med) or ``"bayes"`` (:func:`bias_model` with NUTS; ``key`` defaults
    to ``jax.random.key(0)``, so a fit is reproducible; ``model_options`` go to the
    model, e.g. ``looking_prior=(2.85, 2.15)``). For ``"bayes"``, ``silent_offsets``
    ``(M, 2)`` are the offsets of frames of the same window where the partner is
    silent (and the head faces them): the model then contrasts speaking with silence
    (:func:`bias_model`), which keeps a cluster of glances at the desk or the notes
    from passing for the partner.

    A ``"bayes"`` run that did not mix is the estimate's ``result``
    (``RESULTS.not_mixed``, ``throw=False``, the default; :func:`jaxgaze.succeeded` reads it) or a
    :class:`~jaxgaze.results.FitError` carrying the estimate as ``error.fit`` (``throw=True``);
    ``"mean"`` and ``"lmeds"`` always succeed (their ``sampler`` is ``None``).

    Precision: ``"mean"`` and ``"lmeds"`` give the same frames and agree to within
    1e-6 rad in float32 and float64 (barring LMedS candidates whose medians tie within
    float32 rounding); ``"bayes"`` runs different chains in the two precisions, so its
    posterior means agree to within 0.5 posterior sd and its sds to within 30%.

    Raises ``ValueError`` for an unknown method, offsets that are not ``(N, 2)``,
    NaN/inf (naming the row), and for no frames (N = 0).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {METHODS}")
    if method != "bayes" and model_options:
        raise TypeError(f"method {method!r} takes no model options, got {sorted(model_options)}")
    o = _offsets(offsets, minimum=3 if method == "lmeds" else 1, method=method)
    n = int(o.shape[0])
    options = dict(model_options)
    if method == "bayes":
        options.update(num_warmup=num_warmup, num_samples=num_samples, num_chains=num_chains,
                       target_accept_prob=target_accept_prob)
        silent = None
        if silent_offsets is not None and len(silent_offsets):
            silent = _offsets(silent_offsets, method="silent_offsets")
            options["silent_offsets"] = np.asarray(silent)
        result = _fit_bayes(o, key, num_warmup, num_samples, num_chains, target_accept_prob, progress,
                            model_options, silent)
    elif method == "mean":
        x = np.asarray(o)
        result = BiasEstimate(bias=np.asarray(jnp.mean(o, axis=0)), method="mean", num_frames=n,
                              inliers=np.ones(n, bool), covariance=_standard_error(x))
    else:
        pad = bucket_size(n) - n  # padded (masked) so that similar N share one compilation
        bias, best, inliers = lmeds_bias(jnp.pad(o, ((0, pad), (0, 0))), jnp.arange(n + pad) < n)
        inliers = np.asarray(inliers)[:n]
        result = BiasEstimate(bias=np.asarray(bias), method="lmeds", num_frames=n, inliers=inliers,
                              covariance=_standard_error(np.asarray(o)[inliers]), candidate=int(best))
    result = result._replace(offsets=np.asarray(o), options=options)
    return throw_if_failed(result, result.result, f"estimate_bias(method={method!r})") if throw else result


def update_bias(
    previous: BiasEstimate, new_offsets: Float[Array, "M 2"], *, key: PRNGKeyArray | None = None,
    throw: bool = False,
) -> BiasEstimate:
    """Update an estimate as frames arrive: refit on all the offsets seen so far.

    The previous offsets are kept in the estimate, so this is the exact posterior
    (or estimate) given every frame — no Gaussian approximation of the previous
    posterior, which would be poor for a mixture. The cost grows with ``N``, but
    ``N`` is small (tens of frames from the first minute) and padded sizes share a
    compilation. Same method and options as ``previous``; ``key`` and ``throw`` as in
    :func:`estimate_bias`.
    """
    if previous.offsets is None:
        raise ValueError("previous has no offsets to update from; build it with estimate_bias")
    new = np.asarray(new_offsets)
    if new.ndim != 2 or new.shape[1] != 2:
        raise ValueError(f"new_offsets must have shape (M, 2), got {new.shape}")
    offsets = np.concatenate([np.asarray(previous.offsets), new.astype(previous.offsets.dtype)], axis=0)
    options = dict(previous.options or {})
    sampler = {k: options.pop(k) for k in ("num_warmup", "num_samples", "num_chains", "target_accept_prob")
               if k in options}
    return estimate_bias(offsets, previous.method, key=key, throw=throw, **sampler, **options)
