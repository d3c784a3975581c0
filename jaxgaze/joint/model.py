"""The joint numpyro model of a group recording (Park et al. 2012, eq. 3; Siegfried et al. 2017, eq. 1 and Sec. 3.2).

For person ``i`` at frame ``t`` the measured head-frame gaze ``g_ti``, corrected by
the person's bias ``b_i``, gives the world direction ``d_ti = R_ti Φ(g_ti + b_i)``.
The person looks at one target ``z_ti``, chosen among

* the other people present (their eye midpoints, known),
* ``K`` free concurrences, latent 3D points shared by several people, piecewise
  constant over windows,
* "elsewhere": a new glance away falls in a broad cone of fixed spread ``σ_e``
  around the head's forward direction (people glance away mostly ahead of the
  head; a uniform sphere makes a glance just off a target look like a wide cone and
  inflates ``h``). A glance away is at a point held for its fixation: while the
  chain stays elsewhere, ``d_t`` scatters around ``d_{t−1}`` with width
  ``√(w_t² + w_{t−1}²)``. So a held glance just beside a person is told apart from
  looking at them, which scatters around the person instead.

The prior on a new target depends on who speaks: ``logit π_t(j) = α_person + β·s_tj``
for a person ``j`` (``s`` = 1 while ``j`` speaks), ``α_object`` for a concurrence and
0 for elsewhere, so a speaker is ``e^β`` times as likely a target as a silent
person (the paper: 5–8 times). People hold a target for a while (a fixation), so
``z_ti`` is a sticky Markov chain over the frames: with probability ``ρ`` the
target of the previous frame is kept, otherwise it is drawn afresh from ``π_t``,

``P(z_t = j | z_{t−1} = k) = ρ·[j = k] + (1 − ρ)·π_t(j)``.

Given the target ``x``, ``d_ti`` scatters around ``u = unit(x − p_ti)`` as Park's
cone with width ``w_ti = √(h_i² + σ_ti²)`` (``σ`` the optional per-frame
measurement sd). Through a fixation the eyes rest on one spot of the target, so the
residuals of one fixation are correlated. With a fixation's spot (``JointPrior.held_scale``, where
the data need it) a share ``c`` (``held_cone_share``, learnt, at most :data:`MAX_HELD_CONE_SHARE`) of the
cone's variance is an offset drawn when the target is chosen and held while it is kept
(:func:`_held_spot`); each frame's marginal is still the cone of width ``w``. A glance elsewhere held
scatters around its last frame by the rest, ``e_t + e_{t−1}`` with ``e = w² − c h²``: the spot moves its point for the
whole fixation (:func:`_held_elsewhere`; scored with ``w²``, the cone widths' 90% intervals covered 0.73 with
``c = 0.5``; with ``e``, 0.82). Frames
counted as independent made the 90% bias intervals cover 0.48 on recordings with
``c = 0.5``; with the spot 0.89 (issue 37, item 5). ``z`` is summed
out exactly by the forward algorithm, ``O(C)`` per frame and person for this transition. The chain restarts from ``π`` every
:data:`BLOCK_FRAMES` frames: the blocks are independent, run in parallel, and
are what SVI subsamples. A frame where the gazer is absent moves the chain on
without an observation.

**Head pose only** (no eye tracker; ``head_motion`` of :class:`ModelArrays` given): the
head turns a share ``κ`` of the line of sight away from a rest direction and lags it
(Stiefelhagen & Zhu 2002; Ba & Odobez 2009; the linear form of Yücel et al. 2013's
head-to-gaze regression): ``κ (gaze_t − rest) = x_t − rest`` per axis with
``x_t = h_t + τ ḣ_t`` the head ``h`` undone of a first-order lag (``ḣ`` the backward
difference per second, ``τ`` the lag). Relative to the head the gaze is then
``g = λ (h − ref) + (1 + λ) τ ḣ + λ (ref − rest)`` with ``λ = 1/κ − 1`` and ``ref``
each person's mean head direction: the constant last term is the bias ``b``, so the
rest of the model reads ``g`` as it reads a measured gaze, except that all angles are
azimuths about the world's vertical and elevations: ``g + b`` scatters around a target's
azimuth and elevation minus the head's (not its angles in the head's frame, which the
head's roll and pitch would mix). The data are the head's
angles, so each observed frame adds the log Jacobian of the map from head to gaze,
``Σ_axes log((1 + τ·fps) / κ)`` (``log(1/κ)`` after a gap: no rate there); without
it a head that turns fully (``κ → 1``) looks best, as it packs the gazes tightest.
``κ`` (per person and axis) and ``τ`` (per person) are inferred with the rest; a head
tracker's per-frame sd ``σ`` enters the width as ``σ / κ``. The gaze scatters ``r`` times as
widely in tilt as in yaw (``JointPrior.tilt_width_ratio_log_sd``; one ``r`` for the recording):
the residuals' tilt is divided by ``r`` and each observed frame adds ``−log r``. Face trackers read
pitch worse than yaw; with one width for both axes the tilt couplings took up the difference (a
simulated pitch error 2.5 times the yaw's sent ``κ_tilt`` 0.2–0.5 too high on 3 conversations, none of 16
intervals covering, 5 people confidently wrong in a fit reported successful; ``benchmarks/RESULTS.md``). With
``JointPrior.coupling_shape_scale`` the map from head to gaze is the linear one plus a
Gaussian process per person and axis (Yücel et al. 2013's regression as a latent function,
:func:`coupling_shape`), for heads whose turn is not proportional to the gaze's.

Candidate order, everywhere: people ``0 … P−1``, concurrences ``P … P+K−1``,
elsewhere ``P+K``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpyro
import numpyro.distributions as dist
from jax.scipy.special import logsumexp
from jaxtyping import Array, Bool, Float, Int
from numpyro.contrib.hsgp.approximation import diag_spectral_density_squared_exponential
from numpyro.contrib.hsgp.laplacian import eigenfunctions

from jaxgaze.bias.looking import direction_to_gaze_angles, gaze_angles_to_direction, head_to_world
from jaxgaze.calibration.posterior import calibration_log_likelihood
from jaxgaze.cone import cone_direction_log_density
from jaxgaze.geometry import direction_to_yaw_pitch, unit, wrap_angle

__all__ = ["BLOCK_FRAMES", "JointPrior", "ModelArrays", "joint_model", "head_gaze_angles", "head_log_jacobian", "measured_gaze_log_jacobian", "coupling_shape", "people_head_angles", "gaze_angles", "candidate_log_probabilities",
           "marginal_log_likelihood", "target_marginals", "target_log_prior", "model_params", "concurrence_locations", "eye_positions"]

#: The model's sites on the positive half-line and in (0, 1): numpyro samples them as logs and logits.
POSITIVE_SITES = ("cone_width", "head_lag", "tilt_width_ratio", "coupling")
UNIT_SITES = ("stay", "calibration_outlier_share")
#: The largest share ``c`` of the cone's variance a fixation's spot may hold (:func:`held_cone_share`):
#: with ``c → 1`` and ``ρ → 1`` a block is one fixation whose spot may lie anywhere, only its first frame pays for the
#: cone's width, and NUTS ran away to widths of 10⁸ rad; with ``c ≤ 0.8`` every frame pays for a fifth of it.
MAX_HELD_CONE_SHARE = 0.8
#: The Gaussian process of a non-linear head–gaze map (:func:`coupling_shape`): its squared-exponential length
#: scale (radians of head turn), the half-width of the interval its basis spans and the number of basis functions
#: (Riutort-Mayol et al. 2023: ``m ≥ 1.75 · half-width / length`` for a ``1.5``-wide margin).
COUPLING_SHAPE_LENGTH = 0.4
COUPLING_SHAPE_HALF_WIDTH = 1.5
COUPLING_SHAPE_BASIS = 12
#: Frames per block of the target chain (it restarts from the prior at each block).
BLOCK_FRAMES = 64
# Impossible candidates (oneself, an absent person) enter the forward pass at this log
# weight instead of −inf, so that no gradient is NaN.
_LOG_FLOOR = -1e4
# The forward pass's bounds on probabilities scaled by a frame's best new target (:func:`_forward`).
_HELD_CAP = 60.0
_NORM_FLOOR = math.exp(-60.0)


class JointPrior(NamedTuple):
    """Priors of the joint model (radians, metres). Hashable: it keys the compilation.

    Attributes:
        bias_scale: sd of each bias component (yaw, tilt); biases of 5–15° are common.
        cone_width_median, cone_width_log_sd: log-normal prior of the cone width ``h``.
        logit_scale: sd of ``α_person`` and ``α_object``.
        speaker_log_ratio, speaker_log_ratio_sd: normal prior of ``β``; ``e^β`` is how much
            more often a speaker is looked at than a silent person (Siegfried et al.
            2017: 5–8 times, so the centre is log 6.3).
        location_scale: sd (m) of a concurrence around its mean-shift initialisation.
        window_drift: sd (m) of a concurrence's per-window move around its own centre.
        eye_offset_scale: sd (m) of a wearer's eye centre in the camera frame (Park et al.
            2012, Sec. 3.2); a head-mounted camera sits within about 10 cm of the eyes.
            The data pin the eye's depth along the primary ray only weakly: moving the
            eye back along the ray shrinks every angle to a target, as a narrower cone
            would, and the held glances elsewhere can absorb the others' looks that
            then miss. Wider than 0.1 m, a wearer's eye can run metres back.
        elsewhere_spread: the spread (radians) of glances elsewhere around the head's
            forward direction, a Fisher cone with ``κ = 1/σ_e²``.
        stay_concentration: ``(a, b)`` of the Beta prior of ``ρ``, the probability that a
            person keeps the previous frame's target.
        coupling_median, coupling_log_sd: the log-normal prior of ``κ``, the share of the line of sight the
            head turns (head pose only; most people turn 0.3–1: the prior's 90% lie in 0.39–1.25, its density peaks
            at 0.62; a peak of 0.51 left the tilt couplings of a tracker reading pitch badly too low, RESULTS
            2026-12-07). Sampled in ``log κ``, in which the tilt's near-symmetry (every tilt coupling, the tilt
            widths, the biases' tilts and the concurrences' heights scaled together) is a straight line; with a Beta
            prior and a logit it curved, and fits of small groups mixed badly (RESULTS, 2026-12-07).
        head_lag_scale: scale (seconds) of the half-normal prior of ``τ``, the head's lag
            behind the eyes (head pose only).
        held_scale: a fixation's spot (:func:`_held_spot`) holding a share ``c`` of the cone's
            variance, ``c = held_cone_share(s)``, ``s ~ N(0, held_scale²)``, gaze measured or head pose
            only. :func:`~jaxgaze.joint.fit_joint` keeps it where its Bayes factor against the model
            without exceeds 3 (``JointPosterior.spot_log_bayes_factor``), and then ``held_cone_share``
            is among the draws; with wearers of head-mounted cameras it is not weighed, and the fit is without
            one.
            ``None``: every frame's residual is independent given its target.
        coupling_shape_scale: head pose only: the amplitude (radians, gaze units) of a Gaussian process
            added to the linear map from head to gaze, per person and axis (Yücel et al. 2013, Sec. V:
            the head-to-gaze map as a GP; :func:`coupling_shape`). :func:`~jaxgaze.joint.fit_joint` keeps it where
            its Bayes factor against the linear map exceeds 3 (``JointPosterior.shape_log_bayes_factor``).
            The factor weighs the heads, not the targets. On 3 simulated conversations, each with heads turning
            in proportion and saturating, it dropped the process for every proportional one and kept it for every
            saturating one. There it raised the gazes at a person got right on two (0.78 → 0.95, 0.81 → 0.89)
            and lowered them on one (0.996 → 0.940), at 7–12 times the linear fit's time
            (``benchmarks/RESULTS.md``). ``None`` (the default): the map is linear.
        tilt_width_ratio_log_sd: head pose only: the sd of ``log r``, ``r`` the ratio of the gaze's scatter in tilt to
            its scatter in yaw (one for the recording: the tracker reads every head), log-normal around 1.
            ``None``: the same scatter on both axes (``r = 1``).
    """

    bias_scale: float = 0.25
    cone_width_median: float = 0.07
    cone_width_log_sd: float = 0.6
    logit_scale: float = 3.0
    speaker_log_ratio: float = math.log(6.3)
    speaker_log_ratio_sd: float = 0.15
    location_scale: float = 0.5
    window_drift: float = 0.1
    eye_offset_scale: float = 0.1
    elsewhere_spread: float = 0.6
    stay_concentration: tuple[float, float] = (2.0, 1.0)
    coupling_median: float = 0.7
    coupling_log_sd: float = 0.35
    head_lag_scale: float = 0.4
    held_scale: float | None = 1.0
    coupling_shape_scale: float | None = None
    tilt_width_ratio_log_sd: float | None = 0.5


class ModelArrays(NamedTuple):
    """The arrays the model reads, as JAX arrays (see :class:`~jaxgaze.joint.JointData`).

    ``to_people_head[t, i, j]`` is the unit direction from person ``i``'s eyes to
    person ``j``'s, in ``i``'s head frame (data: the people's positions are known;
    with wearers of head-mounted cameras it is recomputed from the inferred eyes); for head pose
    only ``(T, P, P, 2)``, that direction's world azimuth and elevation minus the head's (:func:`people_head_angles`).
    ``wearer_index`` lists the wearers; for them ``eye_positions`` are camera centres.
    ``head_motion`` is ``(T, P, 5)`` for head pose only (the head's yaw and tilt from
    its mean direction, their rates per second and the frame rate where the previous
    frame is present, else 0; ``gaze_angles`` unused; :class:`~jaxgaze.joint.JointData`) and
    ``(T, P, 0)`` when the gaze is measured. The first nine fields are per frame.
    ``slot_active`` ``(K,)`` marks the concurrence slots that are candidates (``None``: all). A masked slot is no
    target (its prior is 0 and the others' share is as if it were gone), and its latent offsets are left to their
    prior. So the pruning of :func:`~jaxgaze.joint.fit_joint` tries fewer slots with the same compiled programs.
    """

    eye_positions: Float[Array, "T P 3"]
    R_world_from_head: Float[Array, "T P 3 3"]
    gaze_angles: Float[Array, "T P 2"]
    present: Bool[Array, "T P"]
    speaking: Float[Array, "T P"]
    measurement_scale: Float[Array, "T P"]
    window: Int[Array, " T"]
    to_people_head: Float[Array, "T P P _"]
    head_motion: Float[Array, "T P _"]
    location_centres: Float[Array, "W K 3"]
    calibration_points: Float[Array, "P M 3"]
    calibration_mask: Bool[Array, "P M"]
    wearer_index: Int[Array, " Nw"]
    slot_active: Bool[Array, " K"] | None = None


def concurrence_locations(latent: dict, centres: Float[Array, "W K 3"], prior: JointPrior) -> Float[Array, "W K 3"]:
    """Concurrence ``k`` in window ``w``: ``c_wk + s·a_k + δ·e_wk`` (non-centred; ``a, e ~ N(0, I)``)."""
    locations = centres + prior.location_scale * latent["concurrence_offset"][None]
    if "concurrence_drift" in latent:
        locations = locations + prior.window_drift * latent["concurrence_drift"]
    return locations


def model_params(values: dict, centres: Float[Array, "W K 3"], prior: JointPrior) -> dict:
    """The parameters the likelihood reads, from the latent sites' constrained values (one draw, or a mode):
    locations from the concurrence offsets (:func:`concurrence_locations`), ``α_object = 0`` without concurrences."""
    p = {k: values[k] for k in ("bias", "cone_width", "alpha_person", "speaker_effect", "stay")}
    p.update({k: values[k] for k in ("coupling", "head_lag", "tilt_width_ratio") if k in values})
    if "coupling_shape" in values:
        p["coupling_shape"] = values["coupling_shape"] * coupling_shape_spectrum(prior.coupling_shape_scale,
                                                                                 values["coupling_shape"].dtype)
    if centres.shape[1]:
        p["alpha_object"] = values["alpha_object"]
        p["locations"] = concurrence_locations(values, centres, prior)
    else:
        p["alpha_object"] = jnp.zeros((), centres.dtype)
        p["locations"] = centres
    if "eye_offset" in values:
        p["eye_offset"] = values["eye_offset"]
    if "held_spread" in values:
        p["held_cone_share"] = held_cone_share(values["held_spread"])
    return p


def eye_positions(params: dict, arrays: ModelArrays) -> Float[Array, "T P 3"]:
    """Everyone's eye midpoints: as given, and for a wearer ``C_t + R_t c`` (camera centre plus the inferred offset)."""
    if not arrays.wearer_index.shape[0]:
        return arrays.eye_positions
    w = arrays.wearer_index
    offset = jnp.einsum("tnij,nj->tni", arrays.R_world_from_head[:, w], params["eye_offset"])
    return arrays.eye_positions.at[:, w].add(offset)


def head_gaze_angles(head_motion: Float[Array, "T P 5"], coupling: Float[Array, "P 2"], head_lag: Float[Array, " P"],
                     shape: Float[Array, "P 2 M"] | None = None) -> Float[Array, "T P 2"]:
    """The gaze's angles relative to the head, from head pose alone: ``λ (h − ref) + (1 + λ) τ ḣ`` with ``λ = 1/κ − 1`` (Stiefelhagen & Zhu 2002; Ba & Odobez 2009).

    The inverse of ``κ (gaze − rest) = h + τ ḣ − rest`` per axis, without its constant
    ``λ (ref − rest)``, which the bias carries. With ``shape``, plus the non-linear part
    ``f(h + τ ḣ − ref)`` of :func:`coupling_shape`.
    """
    lam = 1.0 / coupling - 1.0  # (P, 2)
    gaze = lam * head_motion[..., :2] + (1.0 + lam) * head_lag[:, None] * head_motion[..., 2:4]
    if shape is None:
        return gaze
    return gaze + coupling_shape(_undone(head_motion, head_lag), shape)[0]


def _undone(head_motion, head_lag):
    """``x − ref = h − ref + τ ḣ``: the head undone of its lag, from its mean direction ``(T, P, 2)``."""
    return head_motion[..., :2] + head_lag[:, None] * head_motion[..., 2:4]


def coupling_shape(undone: Float[Array, "T P 2"], shape: Float[Array, "P 2 M"]) -> tuple[Array, Array]:
    """``f(v)`` and ``f'(v)``, the non-linear part of the head–gaze map per person and axis (Yücel et al. 2013, Sec. V; Solin & Särkkä 2020, eq. 56).

    A Gaussian process of squared-exponential kernel on the head's turn ``v = x − ref``, in the
    reduced-rank basis of the Laplacian's eigenfunctions on ``[−L, L]`` (numpyro's ``hsgp``):
    ``f(v) = Σ_m φ_m(v) c_m``, ``c = √S(√λ_m) z``, ``z ~ N(0, 1)``; ``shape`` holds ``c``
    (:func:`coupling_shape_spectrum` times the draws).
    """
    basis = lambda v: eigenfunctions(v[..., None], COUPLING_SHAPE_HALF_WIDTH, COUPLING_SHAPE_BASIS)  # noqa: E731
    phi, dphi = jax.jvp(basis, (undone,), (jnp.ones_like(undone),))  # (T, P, 2, M)
    return jnp.sum(phi * shape[None], axis=-1), jnp.sum(dphi * shape[None], axis=-1)


def coupling_shape_spectrum(scale: float, dtype) -> Float[Array, " M"]:
    """``√S(√λ_m)``: the squared-exponential kernel's spectral density at the basis's frequencies (amplitude
    ``scale``, length :data:`COUPLING_SHAPE_LENGTH`), the prior sd of each basis function's weight."""
    density = diag_spectral_density_squared_exponential(jnp.asarray(scale, dtype), COUPLING_SHAPE_LENGTH,
                                                        COUPLING_SHAPE_HALF_WIDTH, COUPLING_SHAPE_BASIS, 1)
    return jnp.sqrt(density)


def head_log_jacobian(head_motion: Float[Array, "T P 5"], coupling: Float[Array, "P 2"], head_lag: Float[Array, " P"],
                      shape: Float[Array, "P 2 M"] | None = None) -> Float[Array, "T P"]:
    """``Σ_axes log((1 + τ·fps) / κ)`` per frame: the log Jacobian of the map from the head's angles to the gaze's
    (``fps`` is 0 after a gap). The density of a head pose is the gaze's density times it. With ``shape``,
    ``Σ_axes log((1 + τ·fps) (1/κ + f'(v)))``, the slope floored at 10⁻³ (a map that folds back has none)."""
    lag = 2.0 * jnp.log1p(head_lag * head_motion[..., 4])
    if shape is None:
        return lag - jnp.sum(jnp.log(coupling), axis=-1)
    slope = 1.0 / coupling + coupling_shape(_undone(head_motion, head_lag), shape)[1]
    return lag + jnp.sum(jnp.log(jnp.maximum(slope, 1e-3)), axis=-1)


def measured_gaze_log_jacobian(gaze_angles: Float[Array, "T P 2"], bias: Float[Array, "P 2"],
                               wearer_index: Int[Array, " W"]) -> Float[Array, "T P"]:
    """``log |cos(θ + b_θ)|`` per frame: the area element of ``Φ`` (Siegfried et al. 2017, Sec. 2–3) at the gaze's
    tilt, so that the cone's density of the direction ``Φ(g + b)`` on the sphere becomes a density of the measured
    angles ``g`` (0 for the wearers of head-mounted cameras, whose angles are the primary ray's, not data).

    Without it a bias that sends someone's gaze to the pole (``θ + b_θ`` near ±90°) squeezes the yaw's scatter out of
    the directions for free: on one adversarial conversation a converged descent sent a person's bias 98.7° off, to
    ``θ + b_θ ≈ 89°``, and explained every frame as one glance elsewhere held, 54 nats above the truth's mode
    (``benchmarks/RESULTS.md``). The cosine is floored at 10⁻⁶.
    """
    cosine = jnp.abs(jnp.cos(gaze_angles[..., 1] + bias[:, 1]))
    measured = jnp.ones(bias.shape[0], bool).at[wearer_index].set(False)
    return jnp.where(measured, jnp.log(jnp.maximum(cosine, 1e-6)), 0.0)


def _jacobian(params: dict, arrays: ModelArrays) -> Float[Array, "T P"]:
    """Each frame's log Jacobian from the density the chain scores to the data's: head pose only,
    :func:`head_log_jacobian` of the parameters and ``−log r`` of the tilt's width ratio; the gaze measured,
    :func:`measured_gaze_log_jacobian`."""
    if not arrays.head_motion.shape[-1]:
        return measured_gaze_log_jacobian(arrays.gaze_angles, params["bias"], arrays.wearer_index)
    jacobian = head_log_jacobian(arrays.head_motion, params["coupling"], params["head_lag"],
                                 params.get("coupling_shape"))
    if "tilt_width_ratio" in params:
        jacobian = jacobian - jnp.log(params["tilt_width_ratio"])
    return jacobian


def gaze_angles(params: dict, arrays: ModelArrays) -> Float[Array, "T P 2"]:
    """The head-frame gaze angles the likelihood reads: measured, or from head pose (:func:`head_gaze_angles`)."""
    if not arrays.head_motion.shape[-1]:
        return arrays.gaze_angles
    return head_gaze_angles(arrays.head_motion, params["coupling"], params["head_lag"], params.get("coupling_shape"))


def measurement_width(params: dict, arrays: ModelArrays) -> Float[Array, "T P"]:
    """``w = √(h² + σ²)``; for head pose only the tracker's ``σ`` is carried to the gaze as ``(1 + λ_yaw) σ``."""
    scale = arrays.measurement_scale
    if arrays.head_motion.shape[-1]:
        scale = scale / params["coupling"][:, 0]
    return jnp.sqrt(jnp.square(params["cone_width"])[None] + jnp.square(scale))


def _to_people_head(eyes, R):
    toward = unit(eyes[:, None, :, :] - eyes[:, :, None, :])  # (T, gazer, target, 3), world
    return jnp.einsum("tiab,tija->tijb", R, toward)  # R_head_from_world = Rᵀ


def _parts(params: dict, arrays: ModelArrays, prior: JointPrior):
    """Per candidate group (people, concurrences): the prior logits, the log likelihoods and the validity masks."""
    _, R, _, present, speaking, _, window, to_people_head = arrays[:8]
    gaze = gaze_angles(params, arrays)
    eyes = eye_positions(params, arrays)
    if arrays.wearer_index.shape[0]:
        to_people_head = _to_people_head(eyes, R)
    T, P = present.shape
    width = measurement_width(params, arrays)[..., None]  # (T, P, 1)
    others = present[:, None, :] & ~jnp.eye(P, dtype=bool)[None]
    people_logit = jnp.where(others, params["alpha_person"] + params["speaker_effect"] * speaking[:, None, :], -jnp.inf)
    locations = params["locations"]
    if arrays.head_motion.shape[-1]:
        return (people_logit, others) + _head_only_terms(gaze + params["bias"], to_people_head, eyes, R, locations,
                                                         window, width, arrays.head_motion, prior,
                                                         params.get("tilt_width_ratio"))
    directions_head = gaze_angles_to_direction(gaze + params["bias"])  # (T, P, 3)
    people_lik = cone_direction_log_density(jnp.einsum("tik,tijk->tij", directions_head, to_people_head), width)
    directions = head_to_world(directions_head, R)  # (T, P, 3), world frame
    targets = [jnp.einsum("tiab,tijb->tija", R, to_people_head)]  # world directions to the people
    if locations.shape[1]:
        targets.append(unit(locations[window][:, None] - eyes[:, :, None]))  # (T, P, K, 3)
        slot_lik = cone_direction_log_density(jnp.einsum("tik,tijk->tij", directions, targets[-1]), width)
    else:
        slot_lik = jnp.zeros((T, P, 0), directions_head.dtype)
    forward = directions_head[..., 0]  # cosine to the head's +x
    elsewhere = cone_direction_log_density(forward, jnp.asarray(prior.elsewhere_spread, forward.dtype))
    targets = jnp.concatenate(targets, axis=2)  # (T, P, P + K, 3), world
    residuals = tuple(directions[:, :, None, d] - targets[..., d] for d in range(3))  # components apart
    return people_logit, others, people_lik, slot_lik, elsewhere, directions, width[..., 0], residuals


def _from_head(direction: Float[Array, "... 3"], head_yaw, head_tilt) -> tuple[Array, Array]:
    """A direction's azimuth and elevation minus the head's, the azimuth wrapped: angles on the plane of world angles,
    as two arrays (stacked, a fusion over a short last axis was slow: :func:`_on_rows`)."""
    yaw, tilt = direction_to_yaw_pitch(direction)
    return wrap_angle(yaw - head_yaw), tilt - head_tilt


def people_head_angles(eye_positions: Float[Array, "T P 3"], R_world_from_head: Float[Array, "T P 3 3"]
                       ) -> Float[Array, "T P P 2"]:
    """``[t, i, j]``: the azimuth and elevation of person ``j``'s eyes seen from ``i``'s, minus those of ``i``'s head
    (head pose only: what :class:`ModelArrays` holds as ``to_people_head``). They are data, so computed once: in
    every evaluation they took a third of a gradient's time on its own (4.7 against 3.2 ms, 60 s × 6 people);
    inside NUTS's and BFGS's compiled loops XLA had already hoisted them, and a fit's time did not change."""
    head = direction_to_gaze_angles(R_world_from_head[..., :, 0])  # (T, P, 2)
    toward = eye_positions[:, None, :, :] - eye_positions[:, :, None, :]
    return jnp.stack(_from_head(toward, head[:, :, None, 0], head[:, :, None, 1]), axis=-1)


def _angle_log_density(residual, width):
    """``log N(r; 0, w² I)`` of a 2-D angle residual (yaw, tilt), not wrapped: a density on the plane of angles.
    ``residual`` is ``(…, 2)`` or its two components apart (a pair of arrays, :func:`_head_only_terms`)."""
    square = sum(map(jnp.square, residual)) if isinstance(residual, tuple) else jnp.sum(jnp.square(residual), axis=-1)
    return -0.5 * square / jnp.square(width) - jnp.log(2.0 * math.pi * jnp.square(width))


def _head_only_terms(gaze, people_angles, eyes, R, locations, window, width, head_motion, prior: JointPrior,
                     tilt_ratio=None):
    """The likelihoods of head pose only, on the plane of world angles (azimuth about the world's +z, elevation).

    ``gaze`` ``(T, P, 2)`` is ``g + b``, the gaze's azimuth and elevation minus the head's,
    which grows without bound as ``κ → 0``; a density on the sphere is bounded below once
    angles wrap, and with the Jacobian of :func:`head_log_jacobian` the likelihood would
    then grow without bound. Each target's angles are its direction's azimuth and elevation
    minus the head's (the azimuth wrapped, the residual not): the coupling turns the head by
    a share of the line of sight's azimuth and elevation, so the head's roll, or its pitch,
    must not mix them, as the angles of the target in the head's own frame would.
    ``people_angles`` are the people's angles so, ``(T, gazer, target, 2)`` (data:
    :func:`people_head_angles`). Returns the people's, the concurrences' and elsewhere's log likelihoods, the world
    gaze angles from the head's mean direction ``(T, P, 2)`` that a held glance elsewhere is scored by,
    the widths, and the residuals from the people and concurrences, yaw and tilt apart (two ``(T, P, P + K)``).
    With ``tilt_ratio`` ``r``, every tilt (residuals, the gaze elsewhere and the held glances' world angles) is
    divided by ``r``: on that plane the scatter is the same on both axes, and :func:`_jacobian` adds the change of
    variable's ``−log r`` to each observed frame.
    """
    T, P = gaze.shape[:2]
    shrink = jnp.ones((), gaze.dtype) if tilt_ratio is None else 1.0 / tilt_ratio
    # components apart, (yaw, tilt) each (T, P, C): the gradient's sums over the candidates are then over the last
    # axis (XLA:CPU summed over the middle axis of (T, P, C, 2) at a fifth of a gradient's time)
    apart = lambda a: (a[..., 0], a[..., 1])  # noqa: E731
    gaze_yaw, gaze_tilt = (g[:, :, None] for g in apart(gaze))

    def people(gaze_yaw, gaze_tilt, target_yaw, target_tilt, width):
        residual = (gaze_yaw - target_yaw, (gaze_tilt - target_tilt) * shrink)
        return residual + (_angle_log_density(residual, width),)

    *residuals, people_lik = _on_rows(people, gaze_yaw, gaze_tilt, *apart(people_angles), width)  # (T, gazer, target)
    residuals = [residuals]
    if locations.shape[1]:
        head = direction_to_gaze_angles(R[..., :, 0])  # (T, P, 2): the head's azimuth and elevation, world

        def slots(gaze_yaw, gaze_tilt, x, y, z, head_yaw, head_tilt, width):
            yaw, tilt = _from_head(jnp.stack([x, y, z], axis=-1), head_yaw, head_tilt)
            residual = (gaze_yaw - yaw, (gaze_tilt - tilt) * shrink)
            return residual + (_angle_log_density(residual, width),)

        toward = locations[window][:, None] - eyes[:, :, None]  # (T, P, K, 3)
        *slot_residuals, slot_lik = _on_rows(slots, gaze_yaw, gaze_tilt, toward[..., 0], toward[..., 1],
                                             toward[..., 2], *(h[:, :, None] for h in apart(head)), width)
        residuals.append(slot_residuals)
    else:
        slot_lik = jnp.zeros((T, P, 0), gaze.dtype)
    axes = jnp.stack([jnp.ones_like(shrink), shrink])  # (yaw, tilt) onto the plane of equal scatter
    elsewhere = _angle_log_density(gaze * axes, jnp.asarray(prior.elsewhere_spread, gaze.dtype))
    residuals = tuple(jnp.concatenate(parts, axis=2) for parts in zip(*residuals))
    return people_lik, slot_lik, elsewhere, (head_motion[..., :2] + gaze) * axes, width[..., 0], residuals


def _log_normaliser(people_logit, slot_active, alpha_object):
    """``log Σ_j exp(logit_j)`` over every candidate: people, the active concurrences, elsewhere (logit 0)."""
    # floored: with nobody else present, a logsumexp of −inf alone has a NaN derivative in forward mode
    terms = [logsumexp(jnp.maximum(people_logit, _LOG_FLOOR), axis=-1), jnp.zeros(people_logit.shape[:2], people_logit.dtype)]
    if slot_active.shape[0]:
        count = jnp.sum(slot_active).astype(people_logit.dtype)
        slots = jnp.where(count > 0, alpha_object + jnp.log(jnp.maximum(count, 1.0)), -jnp.inf)
        terms.append(jnp.broadcast_to(slots, people_logit.shape[:2]))
    return logsumexp(jnp.stack(terms), axis=0)


def slot_mask(arrays: ModelArrays):
    """``(K,)``: which concurrence slots are candidates (all of them unless :class:`ModelArrays` masks some)."""
    K = arrays.location_centres.shape[1]
    return jnp.ones(K, bool) if arrays.slot_active is None else arrays.slot_active


def _candidate_terms(params: dict, arrays: ModelArrays, prior: JointPrior):
    """``log π_ti(j)`` (the prior of a new target) and ``log p(g_ti | z_ti = j)``, each ``(T, P, C)``, with the
    world gaze directions ``(T, P, 3)`` and widths ``(T, P)`` that a held glance elsewhere is scored by."""
    people_logit, others, people_lik, slot_lik, elsewhere, directions, width, residuals = _parts(params, arrays, prior)
    active = slot_mask(arrays)
    log_z = _log_normaliser(people_logit, active, params["alpha_object"])[..., None]
    slot_logit = jnp.broadcast_to(jnp.where(active, params["alpha_object"], -jnp.inf), slot_lik.shape)
    log_prior = jnp.concatenate([people_logit, slot_logit, jnp.zeros_like(elsewhere)[..., None]], axis=-1) - log_z
    log_lik = jnp.concatenate([jnp.where(others, people_lik, -jnp.inf), slot_lik, elsewhere[..., None]], axis=-1)
    return log_prior, log_lik, directions, width, residuals


def candidate_log_probabilities(params: dict, arrays: ModelArrays, prior: JointPrior = JointPrior()
                                ) -> Float[Array, "T P C"]:
    """``log π_ti(j) + log p(g_ti | z_ti = j)`` for every candidate ``j``, one frame on its own (Park et al. 2012, eq. 3; Siegfried et al. 2017, Sec. 3.2).

    ``params`` holds ``bias (P, 2)``, ``cone_width (P,)``, ``alpha_person``,
    ``alpha_object``, ``speaker_effect`` and ``locations (W, K, 3)``. Impossible
    candidates (oneself, an absent person) are ``−inf``. Rows of absent gazers are
    meaningless; the caller masks them. The posterior over targets, which also
    uses the neighbouring frames, is :func:`target_marginals`.
    """
    log_prior, log_lik = _candidate_terms(params, arrays, prior)[:2]
    return log_prior + log_lik


def target_log_prior(params: dict, arrays: ModelArrays, prior: JointPrior = JointPrior()) -> Float[Array, "T P C"]:
    """``log π_ti(j)``: the prior of a new target, and the chain's share of ``j`` over a stretch of
    constant ``π`` (Siegfried et al. 2017, Sec. 3.2). ``params`` as :func:`candidate_log_probabilities`."""
    return _candidate_terms(params, arrays, prior)[0]


def _blocks(num_frames: int):
    """Frame index ``(B, L)`` of each block position (the last frame repeated as padding) and its validity."""
    B = -(-num_frames // BLOCK_FRAMES)
    index = jnp.arange(B * BLOCK_FRAMES).reshape(B, BLOCK_FRAMES)
    return jnp.minimum(index, num_frames - 1), index < num_frames


def _held_elsewhere(log_lik, directions, width, observed, spot_variance=None):
    """``(B, L, P)``: log p(g_t | a glance elsewhere held from frame t−1) − log p(g_t | a new glance elsewhere).

    A glance elsewhere is at a point fixed for its fixation, so while it is held,
    ``d_t`` scatters around ``d_{t−1}`` with width ``√(e_t + e_{t−1})``, ``e_t = w_t² − c h²``:
    a fixation's spot (``spot_variance = c h²``, :func:`_held_spot`) moves the point for the
    whole fixation and cancels in the difference (``e_t = w_t²`` without it). 0 at a block's
    first frame and where frame ``t`` or ``t − 1`` is not observed (a new glance's
    density is used there). ``directions`` are world unit vectors ``(…, 3)``, or (head
    pose only) world gaze angles ``(…, 2)`` scored on the plane of angles.
    """
    e = jnp.square(width) if spot_variance is None else jnp.square(width) - spot_variance
    pair = jnp.sqrt(e[:, 1:] + e[:, :-1])
    both = observed[:, 1:] & observed[:, :-1]
    if directions.shape[-1] == 2:
        density = _angle_log_density(directions[:, 1:] - directions[:, :-1], pair)
    else:
        cosine = jnp.sum(directions[:, 1:] * directions[:, :-1], axis=-1)
        density = cone_direction_log_density(jnp.where(both, cosine, 1.0), pair)
    held = jnp.where(both, density - jnp.maximum(log_lik[:, 1:, :, -1], _LOG_FLOOR), 0.0)  # as _forward floors it
    return jnp.concatenate([jnp.zeros_like(held[:, :1]), held], axis=1)


def _forward(log_prior, log_lik, held, observed, stay, shift=None, per_frame=False):
    """The forward algorithm of the sticky chain on blocks: ``(B, L, P, C)`` inputs, returns ``log p (B, P)``.

    ``α_t(j) = p(z_t = j | g_{≤t})``; a new block starts from ``π``, then
    ``α_t(j) ∝ (ρ α_{t−1}(j) e^{η_t(j)} + (1 − ρ) π_t(j)) p(g_t | j)``, the emission only where
    ``observed`` and ``η`` the held term: of a glance elsewhere (:func:`_held_elsewhere`, ``(…, 1)``: 0 for
    the other candidates) or of every candidate (``(…, C)``, with :func:`_held_spot`); ``log p`` sums the
    log normalisers (``per_frame``: each frame's, ``log p(g_t | g_{<t})``, ``(B, L, P)``). The gradient with
    respect to ``shift``, added to every emission, is the posterior ``P(z_t = j | g)``.

    The recursion runs on probabilities, each frame's terms scaled by the largest new-target term
    ``m_t = max_j log π_t(j) p(g_t | j)``, so the sequential step is a multiply-add and a sum: in logs
    (``logaddexp``, ``logsumexp`` in the step) value and gradient took 1.44 ms against 0.53 ms here
    (60 s × 6 people, one core; ``benchmarks/RESULTS.md``). A held term more than ``e^{60}`` above
    ``m_t`` is capped there (no overflow; such a frame is ``e^{60}`` times likelier kept than anything new),
    and a frame's normaliser is floored at ``e^{−60}`` times ``e^{m_t}`` (it only reaches it with ``ρ``
    rounded to 1, where the logs held every path's weight).
    """
    log_prior = jnp.maximum(log_prior, _LOG_FLOOR)
    log_lik = jnp.maximum(log_lik, _LOG_FLOOR)
    if shift is not None:
        log_lik = log_lik + shift
    log_lik = jnp.where(observed[..., None], log_lik, 0.0)
    if held.shape[-1] == 1:  # elsewhere's term only
        held = jnp.zeros_like(log_lik).at[..., -1:].set(held)
    top = jax.lax.stop_gradient(jnp.max(log_prior + log_lik, axis=-1, keepdims=True))
    first = (jnp.arange(log_prior.shape[1]) == 0)[None, :, None, None]

    def scaled(log_prior, log_lik, held, top, first):
        new = jnp.exp(log_prior + log_lik - top) * jnp.where(first, 1.0, 1.0 - stay)
        return new, jnp.where(first, 0.0, stay * jnp.exp(jnp.minimum(log_lik + held - top, _HELD_CAP)))

    new, kept = _on_rows(scaled, log_prior, log_lik, held, top, first)

    swap = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
    if per_frame:  # log p(g_t | g_{<t}) of each frame of a block, (B, L, P); the plain scan, for forward mode
        return swap(jnp.log(_sticky_recursion(swap(new), swap(kept))[1])) + top[..., 0]
    return jnp.sum(_log_normalisers(swap(new), swap(kept)), axis=0) + jnp.sum(top[..., 0], axis=1)


def _sticky_recursion(new, kept):
    """The forward recursion ``α_t ∝ kept_t ⊙ α_{t−1} + new_t`` on time-major ``(L, B, P, C)`` terms: every ``α_t``
    (normalised) and its normaliser ``n_t`` ``(L, B, P)``, floored at :data:`_NORM_FLOOR`."""

    def step(alpha, x):
        new_t, kept_t = x
        joint = kept_t * alpha + new_t
        norm = jnp.maximum(jnp.sum(joint, axis=-1, keepdims=True), _NORM_FLOOR)
        return joint / norm, (joint / norm, norm[..., 0])

    return jax.lax.scan(step, jnp.zeros_like(new[0]), (new, kept))[1]


@jax.custom_vjp
def _log_normalisers(new, kept):
    """``log n_t`` of :func:`_sticky_recursion`, ``(L, B, P)``, differentiated by the backward recursion written out
    (:func:`_log_normalisers_bwd`) rather than by JAX's transpose of the scan: it keeps only ``α_t`` and ``n_t``, and
    a gradient of the gaze model inside a compiled loop (as NUTS runs it) took 1.65 against 1.72 ms (60 s × 6 people,
    one core; ``benchmarks/RESULTS.md``). Reverse mode only: :func:`frame_log_likelihood`, which
    :func:`~jaxgaze.joint.infer.fit_joint` differentiates forwards, uses the plain scan."""
    return jnp.log(_sticky_recursion(new, kept)[1])


def _log_normalisers_fwd(new, kept):
    alphas, norms = _sticky_recursion(new, kept)
    return jnp.log(norms), (alphas, norms, kept)


def _log_normalisers_bwd(residuals, bar):
    """The backward pass of the forward algorithm (Rabiner 1989, eq. 24–25, in its adjoint form): with
    ``G_t = ∂L/∂α_t`` and ``m_t`` 1 where the normaliser is above its floor,
    ``∂L/∂joint_t = (G_t + m_t (ḡ_t − G_t·α_t)) / n_t``, ``G_{t−1} = kept_t ⊙ ∂L/∂joint_t``; then
    ``∂L/∂new_t = ∂L/∂joint_t`` and ``∂L/∂kept_t = ∂L/∂joint_t ⊙ α_{t−1}``."""
    alphas, norms, kept = residuals
    unfloored = (norms > _NORM_FLOOR).astype(norms.dtype)

    def step(G, x):
        kept_t, alpha_t, bar_t, unfloored_t, norm_t = x
        d_joint = (G + unfloored_t[..., None] * (bar_t[..., None] - jnp.sum(G * alpha_t, axis=-1, keepdims=True))
                   ) / norm_t[..., None]
        return kept_t * d_joint, d_joint

    _, d_joint = jax.lax.scan(step, jnp.zeros_like(alphas[0]), (kept, alphas, bar, unfloored, norms), reverse=True)
    before = jnp.concatenate([jnp.zeros_like(alphas[:1]), alphas[:-1]], axis=0)
    return d_joint, d_joint * before


_log_normalisers.defvjp(_log_normalisers_fwd, _log_normalisers_bwd)


def _on_rows(fn, *arrays):
    """``fn`` of ``arrays`` broadcast to their common shape ``(B, L, …)``, run on rows ``(B, L, −1)`` and reshaped
    back: elementwise work only. A three-axis shape such as head pose only's ``(T, P, C)`` keeps its axes (its inputs are
    only broadcast into one fusion): flattening it further was slower inside the model (3.65 against 3.44 ms for one
    axis, 2026-12-06). XLA:CPU ran a fusion of a log, an exp or a division over ``(…, P, C)``, whose last two
    axes are short, 5–7 times slower than over the same numbers in rows (225 against 41 µs for a log, an exp and a
    reciprocal of ``(640, 6, 8)``; alone, each took 20–36 µs in either shape). On rows, the spot's part of a gradient
    fell from 1.75 to 1.26 ms (head pose only, 60 s × 6 people, ``benchmarks/RESULTS.md``)."""
    shape = jnp.broadcast_shapes(*(a.shape for a in arrays))
    out = fn(*(jnp.broadcast_to(a, shape).reshape(shape[:2] + (-1,)) for a in arrays))
    return jax.tree.map(lambda a: a.reshape(shape), out)


def _held_spot(log_prior, log_lik, residuals, width, observed, stay, spot_variance):
    """``(B, L, P, P + K)``: log p(g_t | person or concurrence j held from t−1) − log p(g_t | j new) (a fixation's spot).

    Through a fixation the eyes rest on one spot of the target: the residual ``r_t = d_t − u_t(j)``
    is the spot's offset ``o ~ N(0, c h²)``, drawn at the fixation's start, plus ``N(0, e_t)``,
    ``e_t = w_t² − c h²`` (so each frame's marginal stays the cone of width ``w_t``). While ``j``
    is held, ``r_t`` is predicted from the earlier frames weighed by the chance that they belong
    to this fixation, ``γ_{t−1} = 1``, ``γ_{s−1} = γ_s a_s`` with
    ``a_s = ρ q_{s−1}(j) / (ρ q_{s−1}(j) + (1 − ρ) π_s(j))`` the chance that ``j`` was kept from
    ``s − 1`` rather than chosen anew (``q`` the one-frame posterior of ``j``, ``ρ`` the stay
    probability, ``π`` the prior of a new target): ``o | earlier ~ N(V S, V)`` with
    ``V = c h² / (1 + c h² A)``, ``A = Σ γ_s / e_s``, ``S = Σ γ_s r_s / e_s``, one linear
    recurrence per block (``A_{t+1} = 1/e_t + a_t A_t``). The held frame's density is the
    new glance's cone times ``N(r_t; V S, V + e_t) / N(r_t; 0, w_t²)``, on the 2-D tangent plane
    (the world directions' difference, or head pose only the angles'). 0 at a block's first frame,
    where ``t`` is not observed, and for ``c = 0``. ``spot_variance`` is ``c h²`` per person; ``residuals`` are the
    ``D`` components of ``r`` apart, each ``(B, L, P, P + K)``.
    """
    log_prior = jnp.maximum(log_prior, _LOG_FLOOR)
    score = log_prior + jnp.maximum(log_lik, _LOG_FLOOR)
    top = jax.lax.stop_gradient(jnp.max(score, axis=-1, keepdims=True))
    log_norm = top + jnp.log(jnp.sum(_on_rows(lambda s, m: jnp.exp(s - m), score, top), axis=-1, keepdims=True))
    earlier = lambda a, fill: jnp.concatenate([jnp.full_like(a[:, :1], fill), a[:, :-1]], axis=1)  # noqa: E731

    def weights(score, log_norm, observed, log_prior):  # of frame t − 1, t − 1, t − 1, t
        log_q = jnp.where(observed, score - log_norm, 0.0)  # an unobserved frame: the fixation may go on through it
        return jax.nn.sigmoid(jnp.log(stay) + log_q - jnp.log1p(-stay) - log_prior)

    # P(z_{t−1} = j, kept at t | z_t = j); the block's first frame has no t − 1 (log q = -10⁴)
    decay = _on_rows(weights, earlier(score[..., :-1], 0.0), earlier(log_norm, -_LOG_FLOOR),
                     earlier(observed, True)[..., None], log_prior[..., :-1])
    w2 = jnp.square(width)  # (B, L, P)
    e = w2 - spot_variance
    inv_e = jnp.where(observed, 1.0 / e, 0.0)
    r = tuple(jnp.where(observed[..., None], d, 0.0) for d in residuals)  # D components, each (B, L, P, C')

    inv_e = inv_e[..., None]
    weighed = jnp.stack([jnp.broadcast_to(inv_e, decay.shape)] + [inv_e * d for d in r])  # (1/e, r/e): (1 + D, B, L, …)
    to_time, from_time = (lambda x: jnp.moveaxis(x, 2, 0)), (lambda x: jnp.moveaxis(x, 0, 2))  # noqa: E731
    totals = from_time(_discounted_sums(to_time(weighed), to_time(decay[None])))  # A and S of the frames before t

    def density(spot, e, w2, observed, A, *r_and_S):
        r, S = r_and_S[:len(r_and_S) // 2], r_and_S[len(r_and_S) // 2:]
        V = spot / (1.0 + spot * A)
        spread = V + e  # (B, L, P, C')
        miss = sum(jnp.square(d - V * s) for d, s in zip(r, S))
        held_density = -0.5 * miss / spread - jnp.log(spread)
        new_density = -0.5 * sum(map(jnp.square, r)) / w2 - jnp.log(w2)
        # Both floored as _forward floors the emission: with only the new glance's density unfloored, a residual far
        # outside a narrowing cone raised the held frame without bound (the potential reached -1e13 as h -> 0).
        held = jnp.maximum(held_density, _LOG_FLOOR) - jnp.maximum(new_density, _LOG_FLOOR)
        return jnp.where(observed, held, 0.0)

    return _on_rows(density, spot_variance[:, None], e[..., None], w2[..., None], observed[..., None], totals[0],
                    *r, *totals[1:])


def _discounted_sums(x, decay):
    """``y_t = Σ_{s<t} x_s Π_{s<u<t} decay_u`` on time-major arrays: the linear recurrence
    ``y_0 = 0``, ``y_{t+1} = x_t + decay_t y_t`` (``decay`` broadcast against ``x``)."""

    def step(total, x_t):
        return x_t[0] + x_t[1] * total, total

    return jax.lax.scan(step, jnp.zeros_like(x[0]), (x, decay))[1]


def _chain_log_likelihood(blocked_terms, observed, stay, shift=None, spot_variance=None, per_frame=False):
    """``log p (B, P)`` of candidate terms already in blocks ``(B, L, …)``: held glances and spots, then the forward pass
    (``per_frame``: ``(B, L, P)``, each frame's ``log p(g_t | g_{<t})``)."""
    log_prior, log_lik, directions, width, residuals = blocked_terms
    held = _held_elsewhere(log_lik, directions, width, observed, spot_variance)[..., None]
    if spot_variance is not None:
        held = jnp.concatenate([_held_spot(log_prior, log_lik, residuals, width, observed, stay, spot_variance),
                                held], axis=-1)
    return _forward(log_prior, log_lik, held, observed, stay, shift, per_frame)


def _blocked_log_likelihood(terms, present, stay, frames, shift=None, spot_variance=None):
    """The forward pass over every block of ``(T, …)`` candidate terms (gathered into ``(B, L, …)``)."""
    index, valid = frames
    return _chain_log_likelihood(jax.tree.map(lambda a: a[index], terms), present[index] & valid[..., None], stay,
                                 None if shift is None else shift[index], spot_variance)


def held_cone_share(spread):
    """``c = MAX_HELD_CONE_SHARE · s² / (1 + s²)``: the share of the cone's variance a fixation's spot holds, from the real ``s``.

    ``c`` is sampled through ``s`` (the site ``held_spread``), not through a logit: where the recordings hold no spot
    the posterior of ``c`` lies against 0, a long tail of its logit that the mass matrix taken at the mode does not
    fit (bulk ESS 4 of 400 draws on one of 30 conversations, 19 of 30 fits ``not_mixed``); in ``s`` it is a bell
    around 0 (RESULTS). ``s ~ N(0, 1)`` puts ``c``'s prior median at 0.25, with ``P(c < 0.08) = 0.26``.
    """
    square = jnp.square(spread)
    return MAX_HELD_CONE_SHARE * square / (1.0 + square)


def _spot_variance(params: dict):
    """``c h²`` per person, the variance of a fixation's spot (:func:`_held_spot`); ``None`` without ``held_cone_share``."""
    if "held_cone_share" not in params:
        return None
    return params["held_cone_share"] * jnp.square(params["cone_width"])


def marginal_log_likelihood(params: dict, arrays: ModelArrays, prior: JointPrior = JointPrior()
                            ) -> Float[Array, "B P"]:
    """``log p(g_i | block)`` with the target chain summed out, per block of :data:`BLOCK_FRAMES` frames and person (Park et al. 2012, eq. 3; Siegfried et al. 2017, Sec. 3.2).

    ``params`` as :func:`candidate_log_probabilities`, plus ``stay`` (``ρ``). The
    sum over blocks is the log likelihood of the recording: of the measured gaze angles, with
    :func:`measured_gaze_log_jacobian`; head pose only, of the head's angles, with :func:`head_log_jacobian`.
    """
    terms = _candidate_terms(params, arrays, prior)
    index, valid = _blocks(arrays.present.shape[0])
    log_lik = _blocked_log_likelihood(terms, arrays.present, params["stay"], (index, valid),
                                      spot_variance=_spot_variance(params))
    jacobian = _jacobian(params, arrays)[index]  # (B, L, P)
    return log_lik + jnp.sum(jnp.where(arrays.present[index] & valid[..., None], jacobian, 0.0), axis=1)


def frame_log_likelihood(params: dict, arrays: ModelArrays, prior: JointPrior = JointPrior()) -> Float[Array, "T P"]:
    """``log p(g_ti | g_{<t, i})`` per frame and person (the chain restarting at each block): the terms that
    :func:`marginal_log_likelihood` sums, in the order of the frames (0 where the gazer is absent; with
    :func:`measured_gaze_log_jacobian`, head pose only :func:`head_log_jacobian`). Their gradients are the scores of
    a time series, whose correlation from frame to frame the model's own curvature does not see
    (:func:`~jaxgaze.joint.infer.fit_joint`'s coupling intervals)."""
    T = arrays.present.shape[0]
    index, valid = _blocks(T)
    terms = jax.tree.map(lambda a: a[index], _candidate_terms(params, arrays, prior))
    observed = arrays.present[index] & valid[..., None]
    per_frame = _chain_log_likelihood(terms, observed, params["stay"], spot_variance=_spot_variance(params),
                                      per_frame=True)
    per_frame = jnp.where(observed, per_frame + _jacobian(params, arrays)[index], 0.0)
    return per_frame.reshape((-1,) + per_frame.shape[2:])[:T]


def target_marginals(params: dict, arrays: ModelArrays, prior: JointPrior = JointPrior()
                     ) -> Float[Array, "T P C"]:
    """``P(z_ti = j | all gaze)``: the smoothed posterior of every target (0 where the gazer is absent).

    The gradient of ``log p(g)`` with respect to a shift of ``log p(g_ti | z_ti = j)``
    is that posterior (forward–backward by automatic differentiation).
    """
    terms = _candidate_terms(params, arrays, prior)
    frames = _blocks(arrays.present.shape[0])
    spot = _spot_variance(params)
    total = lambda shift: jnp.sum(_blocked_log_likelihood(terms, arrays.present, params["stay"], frames, shift, spot))  # noqa: E731
    probabilities = jax.grad(total)(jnp.zeros_like(terms[0]))
    return jnp.where(arrays.present[..., None], probabilities, 0.0)


def joint_model(
    eye_positions,
    R_world_from_head,
    gaze_angles,
    present,
    speaking,
    measurement_scale,
    window,
    to_people_head,
    head_motion,
    location_centres,
    calibration_points,
    calibration_mask,
    wearer_index,
    slot_active=None,
    *,
    prior: JointPrior = JointPrior(),
    blocks_per_step: int | None = None,
):
    """numpyro model of a whole recording: biases, cone widths, speaker prior and concurrences (Park et al. 2012, eq. 3; Siegfried et al. 2017, eq. 1).

    The arguments are the fields of :class:`ModelArrays`. ``location_centres
    (W, K, 3)`` are the concurrences' initial locations per window (``K`` may be 0).
    A wearer's calibration points (Park et al. 2012, Sec. 3.2) lie on the cone of
    the same primary ray ``(c, Φ(b))`` and width ``h`` as their gaze in the
    recording (:func:`~jaxgaze.calibration.posterior.calibration_log_likelihood`), so the
    calibration is inferred with the rest.
    ``blocks_per_step`` subsamples blocks of :data:`BLOCK_FRAMES` frames for SVI
    (the likelihood is rescaled by ``numpyro.plate``); ``None`` uses every block.
    """
    T, P = present.shape
    W, K = location_centres.shape[:2]
    dtype = gaze_angles.dtype
    bias = numpyro.sample("bias", dist.Normal(jnp.zeros((P, 2), dtype), prior.bias_scale).to_event(2))
    cone_width = numpyro.sample(
        "cone_width", dist.LogNormal(jnp.full((P,), math.log(prior.cone_width_median), dtype),
                                     prior.cone_width_log_sd).to_event(1))
    alpha_person = numpyro.sample("alpha_person", dist.Normal(jnp.zeros((), dtype), prior.logit_scale))
    speaker_effect = numpyro.sample("speaker_effect",
                                    dist.Normal(jnp.asarray(prior.speaker_log_ratio, dtype), prior.speaker_log_ratio_sd))
    stay = numpyro.sample("stay", dist.Beta(*(jnp.asarray(c, dtype) for c in prior.stay_concentration)))
    params = {"bias": bias, "cone_width": cone_width, "alpha_person": alpha_person, "speaker_effect": speaker_effect,
              "stay": stay}
    if prior.held_scale is not None:
        spread = numpyro.sample("held_spread", dist.Normal(jnp.zeros((), dtype), prior.held_scale))
        params["held_cone_share"] = numpyro.deterministic("held_cone_share", held_cone_share(spread))
    if K:
        params["alpha_object"] = numpyro.sample("alpha_object", dist.Normal(jnp.zeros((), dtype), prior.logit_scale))
        latent = {"concurrence_offset": numpyro.sample(
            "concurrence_offset", dist.Normal(jnp.zeros((K, 3), dtype), 1.0).to_event(2))}
        if W > 1:
            latent["concurrence_drift"] = numpyro.sample(
                "concurrence_drift", dist.Normal(jnp.zeros((W, K, 3), dtype), 1.0).to_event(3))
        params["locations"] = numpyro.deterministic(
            "concurrence_locations", concurrence_locations(latent, location_centres, prior))
    else:
        params["alpha_object"] = jnp.zeros((), dtype)
        params["locations"] = location_centres

    if head_motion.shape[-1]:
        params["coupling"] = numpyro.sample("coupling", dist.LogNormal(
            jnp.full((P, 2), math.log(prior.coupling_median), dtype), prior.coupling_log_sd).to_event(2))
        params["head_lag"] = numpyro.sample("head_lag", dist.HalfNormal(
            jnp.full((P,), prior.head_lag_scale, dtype)).to_event(1))
        if prior.tilt_width_ratio_log_sd is not None:
            params["tilt_width_ratio"] = numpyro.sample("tilt_width_ratio", dist.LogNormal(
                jnp.zeros((), dtype), prior.tilt_width_ratio_log_sd))
        if prior.coupling_shape_scale is not None:
            weights = numpyro.sample("coupling_shape", dist.Normal(
                jnp.zeros((P, 2, COUPLING_SHAPE_BASIS), dtype), 1.0).to_event(3))
            params["coupling_shape"] = weights * coupling_shape_spectrum(prior.coupling_shape_scale, dtype)
    arrays = ModelArrays(eye_positions, R_world_from_head, gaze_angles, present, speaking, measurement_scale, window,
                         to_people_head, head_motion, location_centres, calibration_points, calibration_mask,
                         wearer_index, slot_active)
    num_wearers = wearer_index.shape[0]
    if num_wearers:
        params["eye_offset"] = numpyro.sample(
            "eye_offset", dist.Normal(jnp.zeros((num_wearers, 3), dtype), prior.eye_offset_scale).to_event(2))
        outlier_share = numpyro.sample("calibration_outlier_share",
                                       dist.Beta(jnp.ones(num_wearers, dtype), 9.0).to_event(1))
        direction = gaze_angles_to_direction(bias[wearer_index])  # the primary ray, camera frame
        per_point, _ = jax.vmap(calibration_log_likelihood)(
            calibration_points[wearer_index], params["eye_offset"], direction, cone_width[wearer_index], outlier_share)
        numpyro.factor("calibration", jnp.sum(jnp.where(calibration_mask[wearer_index], per_point, 0.0)))
    index, valid = _blocks(T)
    with numpyro.plate("blocks", index.shape[0], subsample_size=blocks_per_step) as blocks:
        index, valid = index[blocks], valid[blocks]
        local = ModelArrays(*(a[index.reshape(-1)] for a in arrays[:9]), *arrays[9:])  # (B·L, …), blocks in a row
        terms = jax.tree.map(lambda a: a.reshape(index.shape + a.shape[1:]), _candidate_terms(params, local, prior))
        observed = local.present.reshape(index.shape + (P,)) & valid[..., None]
        log_lik = jnp.sum(_chain_log_likelihood(terms, observed, stay, spot_variance=_spot_variance(params)), axis=-1)
        jacobian = _jacobian(params, local).reshape(observed.shape)
        log_lik = log_lik + jnp.sum(jnp.where(observed, jacobian, 0.0), axis=(1, 2))
        numpyro.factor("gaze", log_lik)
