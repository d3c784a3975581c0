"""Rival explanations of a person's gaze: the bias modes a start can miss (Siegfried et al. 2017, eq. 1; Park et al. 2012, eq. 3).

A bias that differs from the true one by the angle between two of a person's targets
explains the looks at one as looks at the other (the table object as a neighbour, the
neighbours as glances elsewhere). The posterior then has a mode per explanation, and a
chain started in one stays there with a narrow interval, whichever is right. So
before sampling:

1. **Profile.** Every person's bias is moved over a disc of offsets ``δ`` (radius
   :data:`SCAN_RADIUS_DEG`, step :data:`SCAN_STEP_DEG`) with the other parameters at the
   refined start and independent frames (``log p(g_t) = log Σ_j π_tj p(g_t | j)``, the
   first descent's model), its cone width the best of three, plus the bias prior. A
   person's gaze terms depend on no other person's bias, so one evaluation of the
   model with every bias moved by ``δ`` gives every person's profile at ``δ``.
2. **Rivals.** A local maximum of a person's profile at least :data:`MIN_SEPARATION_DEG`
   from the start, and within :data:`PROFILE_MARGIN` nats of the start's profile value,
   is a rival (at most :data:`MAX_RIVALS` per person, the best first).
3. **Compare.** The start is refined again with that person's bias at the rival (both
   descents of the fit's start), and each distinct mode is scored by its Laplace
   evidence ``−U(θ*) + ½ log det Σ + d/2 log 2π`` (``U`` the potential, ``Σ`` the inverse
   Hessian in numpyro's unconstrained space). A mode whose evidence is within
   :data:`AMBIGUITY_MARGIN` of the best (posterior weight ≥ 1/21 of it) is an
   :class:`Alternative` the data cannot rule out, and the fit says ``ambiguous``; NUTS
   samples the best mode and each alternative, mixed by weight. A rival
   that wins becomes the mode the next round scans around (at most :data:`MAX_ROUNDS`).
4. **Couplings (head pose only).** A coupling ``κ`` and the bias ``λ (ref − rest)``, ``λ = 1/κ − 1``, explain a
   head's turns together, and a wrong ``κ`` has a mode of its own with the bias tens of degrees off (a tracker
   that reads pitch 2.5 times worse: ``κ`` 0.55 for 0.41, the bias 15.6° off at 24 posterior sd), which a bias
   rival, at the mode's ``κ``, cannot reach. So each round also profiles every person's bias at each move of
   :data:`COUPLING_SHIFTS` (:func:`coupling_trial`; the head's log Jacobian makes the profiles compare), and a move
   whose profile beats the mode's is refined and compared as a bias rival is (:func:`coupling_rivals`).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp
from scipy.ndimage import maximum_filter

from jaxgaze.joint.model import (
    POSITIVE_SITES,
    UNIT_SITES,
    JointPrior,
    ModelArrays,
    _jacobian,
    candidate_log_probabilities,
)

__all__ = ["Alternative", "ModeSearch", "bias_profile", "scan_offsets", "profile_rivals", "coupling_trial", "coupling_move",
           "coupling_rivals", "SCAN_RADIUS_DEG", "SCAN_STEP_DEG", "MIN_SEPARATION_DEG", "PROFILE_MARGIN", "MAX_RIVALS",
           "MAX_ROUNDS", "AMBIGUITY_MARGIN", "COUPLING_SHIFTS", "COUPLING_SCAN_STEP_DEG",
           "COUPLING_SEPARATION"]

#: Radius and step (degrees) of the disc of bias offsets each person's profile is scanned over.
SCAN_RADIUS_DEG = 40.0
SCAN_STEP_DEG = 2.0
#: A rival lies at least this far (degrees) from the start's bias.
MIN_SEPARATION_DEG = 5.0
#: A rival's profile (nats) may fall this far below the start's and still be refined: the profile holds the
#: other parameters at the start and ignores the fixations, so it ranks modes only roughly.
PROFILE_MARGIN = 30.0
#: Rivals refined per person, the best first.
MAX_RIVALS = 2
#: Rounds of scanning: a round that moves the mode scans again around the new one.
MAX_ROUNDS = 3
#: Modes whose Laplace evidence is within this (nats) of the best are alternatives: weight ≥ 1/21 of the best.
AMBIGUITY_MARGIN = math.log(20.0)
#: Cone-width factors the profile takes the best of at each offset.
_WIDTH_FACTORS = (0.5, 1.0, 2.0)
#: Head pose only: the moves of one coupling (one axis at a time; the gain ``λ = 1/κ − 1`` times ``e^{−shift}``, a shift
#: of ``logit κ`` where ``κ < 1``) whose bias profiles are scanned for a rival ``(κ, bias)`` mode; ±0.6 moves
#: ``κ = 0.55`` to 0.41 or 0.69.
COUPLING_SHIFTS = (-0.9, -0.6, 0.6, 0.9)
#: The step (degrees) of the disc scanned at each coupling's move: coarser than a bias rival's, as each move costs a
#: profile (4°: 441 offsets, 0.11 s on a 6-person minute, against 0.39 s at 2°); the refinement does the rest.
COUPLING_SCAN_STEP_DEG = 4.0
#: Two modes whose couplings differ by at least this much (on some axis of some person) are distinct.
COUPLING_SEPARATION = 0.1


class Alternative(NamedTuple):
    """A mode of the posterior that the data cannot rule out against the sampled one.

    Attributes:
        person: whose gaze it explains differently.
        bias: ``(2,)`` that person's bias (yaw, tilt) at the alternative mode, radians.
        bias_sd: ``(2,)`` its Laplace standard deviations, radians.
        log_evidence_gap: its Laplace log evidence minus the sampled mode's (≤ 0).
        weight: its share of the posterior among the modes found (the Laplace evidences normalised).
        membership: ``(T, C)`` the person's target probabilities at that mode (candidates in the
            posterior's order; 0 where absent).
    """

    person: int
    bias: np.ndarray
    bias_sd: np.ndarray
    log_evidence_gap: float
    weight: float
    membership: np.ndarray


class ModeSearch(NamedTuple):
    """What the search found (:func:`~jaxgaze.joint.fit_joint` samples ``start``).

    Attributes:
        start: the unconstrained values of the mode with the largest Laplace evidence.
        alternatives: the other modes within :data:`AMBIGUITY_MARGIN` of it.
        moved: people whose bias (head pose only: or a coupling) the chosen mode moved to a rival of the start.
        rivals_tried: rivals refined (0 when no profile had one).
        log_evidence: the chosen mode's Laplace log evidence.
        alternative_starts: per alternative, its unconstrained values and inverse Hessian (where
            :func:`~jaxgaze.joint.fit_joint` samples it).
    """

    start: dict
    alternatives: tuple[Alternative, ...]
    moved: tuple[int, ...]
    rivals_tried: int
    log_evidence: float
    alternative_starts: tuple = ()


def scan_offsets(radius_deg: float = SCAN_RADIUS_DEG, step_deg: float = SCAN_STEP_DEG) -> tuple[np.ndarray, int]:
    """The square grid of offsets ``(n², 2)`` (radians, yaw-major) covering the disc, and ``n``."""
    half = int(round(radius_deg / step_deg))
    axis = np.radians(step_deg * np.arange(-half, half + 1))
    yaw, tilt = np.meshgrid(axis, axis, indexing="ij")
    return np.stack([yaw.ravel(), tilt.ravel()], axis=-1), 2 * half + 1


@functools.partial(jax.jit, static_argnames=("prior",))
def bias_profile(params: dict, arrays: ModelArrays, prior: JointPrior, offsets) -> jax.Array:
    """``(G, P)``: each person's log likelihood with independent frames plus bias log prior at ``b + δ_g``.

    ``params`` as :func:`~jaxgaze.joint.model.candidate_log_probabilities`; at each offset the cone
    width is the best of ``h × (0.5, 1, 2)`` per person. The likelihood is the data's: head pose only with
    :func:`~jaxgaze.joint.model.head_log_jacobian` and the tilt's width ratio (the same at every offset), so that
    profiles at different couplings compare (:func:`coupling_rivals`); the gaze measured with
    :func:`~jaxgaze.joint.model.measured_gaze_log_jacobian` at each offset's bias.
    """
    present = arrays.present
    head_only = bool(arrays.head_motion.shape[-1])
    if head_only:  # the head's Jacobian is the same at every bias
        jacobian = jnp.sum(jnp.where(present, _jacobian(params, arrays), 0.0), axis=0)  # (P,)

    def one(delta):
        bias = params["bias"] + delta
        prior_term = -0.5 * jnp.sum(jnp.square(bias / prior.bias_scale), axis=-1)

        def at(factor):
            moved = {**params, "bias": bias, "cone_width": params["cone_width"] * factor}
            frame = logsumexp(candidate_log_probabilities(moved, arrays, prior), axis=-1)  # (T, P)
            return jnp.sum(jnp.where(present, frame, 0.0), axis=0)

        best = jnp.max(jnp.stack([at(f) for f in _WIDTH_FACTORS]), axis=0)
        moved_jacobian = jacobian if head_only else jnp.sum(
            jnp.where(present, _jacobian({**params, "bias": bias}, arrays), 0.0), axis=0)
        return best + prior_term + moved_jacobian

    return jax.lax.map(one, jnp.asarray(offsets, params["bias"].dtype), batch_size=16)


def profile_rivals(profile: np.ndarray, offsets: np.ndarray, n: int, candidates: np.ndarray,
                   reference: np.ndarray | None = None) -> list[tuple]:
    """Rivals ``(person, offset (2,), profile gap)`` of the people in ``candidates`` (bool ``(P,)``), best first.

    A rival is a local maximum of the person's profile on the ``n × n`` grid inside the
    disc, at least :data:`MIN_SEPARATION_DEG` from the centre and at most
    :data:`PROFILE_MARGIN` below the centre's value; with ``reference`` (``(P,)``, the value of
    a mode elsewhere, whose scan this is not), anywhere in the disc and at most that far below it.
    """
    radius = np.radians(SCAN_RADIUS_DEG) + 1e-9
    inside = (np.linalg.norm(offsets, axis=-1) <= radius).reshape(n, n)
    centre = (n * n) // 2
    out = []
    for i in np.flatnonzero(candidates):
        values = np.where(inside, profile[:, i].reshape(n, n), -np.inf)
        if not np.isfinite(values).any():
            continue
        peaks = (values == maximum_filter(values, size=3, mode="constant", cval=-np.inf)) & np.isfinite(values)
        found = []
        for flat in np.flatnonzero(peaks.ravel()):
            gap = float(values.ravel()[flat] - (profile[centre, i] if reference is None else reference[i]))
            far = reference is not None or np.degrees(np.linalg.norm(offsets[flat])) >= MIN_SEPARATION_DEG
            if far and gap >= -PROFILE_MARGIN:
                found.append((int(i), offsets[flat], gap))
        out.extend(sorted(found, key=lambda r: -r[2])[:MAX_RIVALS])
    return out


def coupling_move(kappa, shift: float):
    """``(κ', λ'/λ)``: the coupling whose gain ``λ = 1/κ − 1`` is ``λ e^{−shift}`` (for ``κ < 1`` a shift of
    ``logit κ``; a head that overshoots, ``κ > 1``, at most to ``κ' = 2``), and the factor that keeps the bias
    ``λ (ref − rest)`` on the same rest direction."""
    gain = 1.0 / kappa - 1.0
    moved = jnp.maximum(gain * math.exp(-shift), -0.5)
    ratio = jnp.where(jnp.abs(gain) > 1e-6, moved / jnp.where(jnp.abs(gain) > 1e-6, gain, 1.0), 1.0)
    return 1.0 / (1.0 + moved), ratio


def coupling_trial(params: dict, axis: int, shift: float) -> dict:
    """``params`` with every person's coupling on ``axis`` moved by :func:`coupling_move`, and the bias on that axis
    scaled by ``λ'/λ``, so the rest direction stays put."""
    kappa = params["coupling"]
    moved, ratio = coupling_move(kappa, shift)
    keep = jnp.arange(kappa.shape[-1]) != axis
    return {**params, "coupling": jnp.where(keep, kappa, moved),
            "bias": params["bias"] * jnp.where(keep, 1.0, ratio)}


def coupling_rivals(profiles: np.ndarray, trials: list[tuple[int, float]], offsets: np.ndarray,
                    centre_values: np.ndarray, candidates: np.ndarray) -> list[tuple]:
    """Head pose only: rivals ``(person, axis, shift, offset (2,), gap)`` in ``(κ, bias)``, best first.

    ``profiles[m]`` is :func:`bias_profile` ``(G, P)`` over ``offsets`` at :func:`coupling_trial`
    ``trials[m] = (axis, shift)``; ``centre_values`` ``(P,)`` the profile at the current mode. A person's best offset
    at a trial is a rival where it beats the current mode's value, at most :data:`MAX_RIVALS` per person. Unlike a
    bias rival, which may fall :data:`PROFILE_MARGIN` below, a coupling's rival must win outright in the profile:
    within the margin, small moves of the couplings qualified on every scene.
    """
    out = []
    for i in np.flatnonzero(candidates):
        found = []
        for (axis, shift), profile in zip(trials, profiles):
            column = np.where(np.isfinite(profile[:, i]), profile[:, i], -np.inf)
            g = int(np.argmax(column))
            gap = float(column[g] - centre_values[i])
            if gap > 0.0:
                found.append((int(i), int(axis), float(shift), offsets[g], gap))
        out.extend(sorted(found, key=lambda r: -r[-1])[:MAX_RIVALS])
    return out


def constrained(unconstrained: dict) -> dict:
    """The model's parameters from numpyro's unconstrained values (widths, lags from logs; shares, couplings from
    logits: :data:`~jaxgaze.joint.model.POSITIVE_SITES`, :data:`~jaxgaze.joint.model.UNIT_SITES`)."""
    out = dict(unconstrained)
    for site in POSITIVE_SITES:
        if site in out:
            out[site] = jnp.exp(unconstrained[site])
    for site in UNIT_SITES:
        if site in out:
            out[site] = jax.nn.sigmoid(unconstrained[site])
    return out


def log_evidence(energy, inverse_mass):
    """Laplace log evidence ``−U(θ) + ½ log det Σ + d/2 log 2π`` (MacKay 2003, eq. 28.10) from the potential ``U`` at
    the mode and the inverse Hessian ``Σ`` there: comparable between models of different dimension ``d`` (a
    concurrence more or less). Traceable; ``float`` it outside ``jit``."""
    _, logdet = jnp.linalg.slogdet(inverse_mass)
    return -energy + 0.5 * logdet + 0.5 * inverse_mass.shape[0] * math.log(2 * math.pi)
