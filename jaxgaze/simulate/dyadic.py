"""Simulated dyadic interactions with ground truth (Siegfried, Odobez et al. 2017).

Two people ``P = 2`` talk for ``T = round(duration_s · fps)`` frames. A gaze
estimator reports, per person and frame, gaze angles ``g = (yaw, tilt)`` in the
**head** frame (+x forward, +y left, +z up) that carry a person-specific
systematic bias ``b``: the corrected gaze is ``g + b`` (Sec. 2, eq. 1,
``e = arccos(Φ(g + b) · u_t) < τ``). The speaking status of the partner is a
soft label for "looking at the partner" (Sec. 3.2). This module produces such
recordings with every hidden quantity known.

Generative model, for one session (world frame, z up, metres; radians inside,
``_deg`` names hold degrees, ``_s`` names seconds):

1. **Layout.** The pair faces each other along a random horizontal axis,
   ``distance_m`` apart (interview: seated about 2 m apart, Sec. 4.1; desk:
   standing across a counter), eye heights ``eye_height_m``. Each person's
   *body direction* points at the partner, turned by up to ``body_yaw_deg``
   (frontal in ``interview``). ``K = 3`` environment objects per person,
   ``object_positions (P, K, 3)``, fixed in the world:

   * ``interview``: 1 the table between the two, 2 notes on the person's lap
     or the table edge, 3 a point in the room 40°–80° to one side;
   * ``desk``: 1 the desk (a bill, the counter) below and in front,
     2 a phone on the desk, to one side, 3 a point in the room to one side.

   The eye midpoints sway smoothly by up to ``body_sway_m`` per axis.
2. **Speaking turns.** Turns alternate between the two people, lengths
   uniform in ``turn_s``; each is followed by a gap uniform in ``gap_s``
   (negative: the next speaker starts before the turn ends, an overlap;
   positive: mutual silence). The first turn starts at a random time before
   frame 0. With the defaults each person speaks ≈ 45% of the time (the
   paper's annotated data, Sec. 4.1, are dyads with turns of a few seconds).
3. **Visual focus.** Each person's attention is a sequence of fixation
   segments of length uniform in ``fixation_s``. For segment ``j`` the person
   draws ``u_j ~ U(0, 1)`` and a non-partner target ``o_j`` (object ``k`` with
   probability ``object_weights[k−1]``, otherwise *elsewhere*: a random point
   1.5–4 m away, 20°–70° to the side of the body direction, −30° to +20°
   elevation). At frame ``t`` of the segment the focus is the partner (id 0)
   if ``u_j < p_look_speaking`` when the partner speaks at ``t``, or
   ``u_j < p_look_silent`` when the partner is silent; otherwise ``o_j``
   (ids ``1 … K``, or −1 for elsewhere). Focus is piecewise constant; it can
   also switch at a turn boundary (listeners turn to a new speaker), so
   per frame ``P(looking | partner speaks) = p_look_speaking`` and
   ``P(looking | partner silent) = p_look_silent`` exactly in expectation.
   Defaults: 0.57 — "the average probability that a subject looks at his
   partner when this one speaks, obtaining a result of 57%" (Sec. 5) — and
   0.095, a ratio of 6 inside the "5 to 8 times more chances to look at a
   speaking person than at a non speaking one" (Sec. 3.2, after [2]).
   Ground truth ``looking = (focus == 0)``.
4. **Head.** Let ``(ψ, θ)`` be the world azimuth and elevation of the line of
   sight ``unit(focus point − eye)`` relative to the body direction (azimuth)
   and the elevation of the partner's eyes (the rest pose). The head
   turns by the person's fraction ``κ ~ U(head_fraction)`` of it, low-passed
   by a causal exponential filter with time constant ``head_lag_s``, plus a
   smooth sway of up to ``head_sway_deg``, i.i.d. jitter ``head_jitter_deg``
   and a smooth roll of up to ``head_roll_deg``:
   ``R_world_from_head = R_z(yaw) R_y(−pitch) R_x(roll)`` (docs/conventions.md).
   The eyes make up the rest of the gaze shift.
5. **True gaze.** ``true_gaze_angles = (yaw, tilt)`` of
   ``R_world_from_headᵀ · unit(focus point − eye)`` plus i.i.d. fixation
   noise ``N(0, fixation_noise_deg²)`` per axis. For the partner the focus
   point is the partner's eye midpoint, ``target_positions``.
6. **Estimated gaze.** Each person has a bias ``b`` of magnitude uniform in
   ``bias_deg`` and uniform direction in the (yaw, tilt) plane;
   ``gaze_angles = true_gaze_angles − b + n`` (yaw wrapped to (−π, π]).
   The estimator noise ``n`` is Student-t with ``noise_dof`` degrees of
   freedom (0: Gaussian) scaled to standard deviation ``noise_deg`` per axis,
   then made AR(1)-like over ``noise_corr_s`` seconds (a causal exponential
   filter normalised to keep the variance).

Hence on looking frames the downstream offset
``o = yaw_tilt(R_head_from_world · unit(target − eye)) − gaze_angles`` equals
``b + noise`` (Sec. 3.2, eq. 2), and ``Φ(gaze_angles + b)`` points at the
partner up to ``sqrt(noise_deg² + fixation_noise_deg²)`` per axis.

Presets (``PRESETS``; all values in :func:`dyadic_config`):

=============  =========  ========  =========  ==========  ===========  ============
preset         distance   κ         head sway  ‖b‖         noise (t₄)   objects
=============  =========  ========  =========  ==========  ===========  ============
``interview``  1.8–2.2 m  0.4–0.6   2°         6°–15°      3.0°         table, notes,
               seated                                                   room
``desk``       1.1–1.5 m  0.5–0.7   5°         8°–15°      4.5°         desk, phone,
               standing                                                 room
=============  =========  ========  =========  ==========  ===========  ============

Both: turns 1.5–8 s, gaps −0.5–1.5 s, P(look | partner speaks) = 0.57,
P(look | partner silent) = 0.095, fixation noise 1°, noise correlation 0.1 s.
Fixations last 0.6–3 s (interview) or 0.5–2.5 s (desk).

The biases are milder than the paper's (a few to 15 degrees), the residual noise
is of the paper's order, and the Spk selection keeps more truly-looking frames
than the 50 % that the LMedS estimator needs (Sec. 3.2); the statistics of both
presets against the paper's Table 1 are in ``benchmarks/RESULTS.md``.

All randomness comes from the ``jax.random`` key: the same key gives the same
recording. All frames are generated in one jitted, vectorised pass (no loop
over frames); :func:`simulate_dyadic_sessions` vmaps it over sessions.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxgaze._checks import check_frames, check_int, check_key, check_number, check_pair
from jaxgaze.geometry import (
    direction_to_yaw_pitch,
    head_pose_to_rotation,
    unit,
    wrap_angle,
    yaw_pitch_to_direction,
)
from jaxgaze.simulate._random import Pool, smooth

__all__ = [
    "PRESETS",
    "NUM_PEOPLE",
    "NUM_OBJECTS",
    "FOCUS_PARTNER",
    "FOCUS_ELSEWHERE",
    "DyadicConfig",
    "DyadicRecording",
    "dyadic_config",
    "simulate_dyadic",
    "simulate_dyadic_sessions",
    "PartnerCameraView",
    "partner_camera_view",
]

PRESETS = ("interview", "desk")
NUM_PEOPLE = 2
NUM_OBJECTS = 3
FOCUS_PARTNER = 0
FOCUS_ELSEWHERE = -1

# "Elsewhere" targets, relative to the body direction.
_ELSEWHERE_YAW_DEG = (20.0, 70.0)
_ELSEWHERE_PITCH_DEG = (-30.0, 20.0)
_ELSEWHERE_DISTANCE_M = (1.5, 4.0)


class DyadicConfig(NamedTuple):
    """Parameters of the dyadic generative model (see the module docstring).

    Pairs ``(lo, hi)`` are ranges of uniform draws. ``_deg`` fields are degrees,
    ``_s`` seconds, ``_m`` metres.

    Attributes:
        preset: ``"interview"`` or ``"desk"`` (selects the object layout).
        distance_m: distance between the two eye midpoints.
        eye_height_m: height of each person's eye midpoint.
        body_sway_m: amplitude of the smooth eye-position sway, per axis.
        body_yaw_deg: the body direction is turned by up to this much from the partner.
        head_fraction: range of κ, the fraction of a gaze shift made by the head.
        head_lag_s: time constant of the head's causal low-pass (0: none).
        head_sway_deg: amplitude of the smooth head yaw/pitch noise.
        head_jitter_deg: standard deviation of the i.i.d. head yaw/pitch noise.
        head_roll_deg: amplitude of the smooth head roll.
        turn_s: length of a speaking turn.
        gap_s: gap after a turn (negative: overlap of the next turn).
        fixation_s: length of a fixation segment.
        p_look_speaking: P(looking at the partner | the partner speaks).
        p_look_silent: P(looking at the partner | the partner is silent).
        object_weights: probabilities of objects 1 … K, given a non-partner
            focus; the remainder ``1 − Σ`` is "elsewhere".
        fixation_noise_deg: std of the true gaze around the focus, per axis.
        bias_deg: range of the bias magnitude ‖b‖.
        noise_deg: std of the estimator noise, per axis.
        noise_dof: Student-t degrees of freedom of the noise (≥ 3), or 0 for Gaussian.
        noise_corr_s: correlation time of the noise (0: i.i.d. per frame).
    """

    preset: str
    distance_m: tuple[float, float]
    eye_height_m: tuple[float, float]
    body_sway_m: float
    body_yaw_deg: float
    head_fraction: tuple[float, float]
    head_lag_s: float
    head_sway_deg: float
    head_jitter_deg: float
    head_roll_deg: float
    turn_s: tuple[float, float]
    gap_s: tuple[float, float]
    fixation_s: tuple[float, float]
    p_look_speaking: float
    p_look_silent: float
    object_weights: tuple[float, float, float]
    fixation_noise_deg: float
    bias_deg: tuple[float, float]
    noise_deg: float
    noise_dof: int
    noise_corr_s: float


_PRESET_CONFIGS = {
    "interview": DyadicConfig(
        preset="interview",
        distance_m=(1.8, 2.2),
        eye_height_m=(1.15, 1.30),
        body_sway_m=0.02,
        body_yaw_deg=5.0,
        head_fraction=(0.4, 0.6),
        head_lag_s=0.15,
        head_sway_deg=2.0,
        head_jitter_deg=0.3,
        head_roll_deg=2.0,
        turn_s=(1.5, 8.0),
        gap_s=(-0.5, 1.5),
        fixation_s=(0.6, 3.0),
        p_look_speaking=0.57,
        p_look_silent=0.095,
        object_weights=(0.3, 0.25, 0.15),
        fixation_noise_deg=1.0,
        bias_deg=(6.0, 15.0),
        noise_deg=3.0,
        noise_dof=4,
        noise_corr_s=0.1,
    ),
    "desk": DyadicConfig(
        preset="desk",
        distance_m=(1.1, 1.5),
        eye_height_m=(1.50, 1.75),
        body_sway_m=0.08,
        body_yaw_deg=20.0,
        head_fraction=(0.5, 0.7),
        head_lag_s=0.1,
        head_sway_deg=5.0,
        head_jitter_deg=0.5,
        head_roll_deg=4.0,
        turn_s=(1.5, 8.0),
        gap_s=(-0.5, 1.5),
        fixation_s=(0.5, 2.5),
        p_look_speaking=0.57,
        p_look_silent=0.095,
        object_weights=(0.35, 0.25, 0.1),
        fixation_noise_deg=1.0,
        bias_deg=(8.0, 15.0),
        noise_deg=4.5,
        noise_dof=4,
        noise_corr_s=0.1,
    ),
}


class DyadicRecording(NamedTuple):
    """A simulated dyad (``P = 2`` people, ``T`` frames, ``K`` objects) with ground truth.

    Array fields may carry a leading session axis (see
    :func:`simulate_dyadic_sessions`). Person ``p``'s partner is ``1 − p``.

    Attributes:
        speaking: ``(P, T)`` bool, person ``p`` speaks at frame ``t``.
        focus: ``(P, T)`` int32 focus target: 0 the partner, ``1 … K`` object
            ``object_positions[p, k − 1]``, −1 elsewhere (a random point).
        looking: ``(P, T)`` bool ground truth, ``focus == 0``.
        eye_positions: ``(P, T, 3)`` world midpoint of the eyes (metres).
        target_positions: ``(P, T, 3)`` the partner's eye midpoint (``eye_positions[1 − p]``).
        focus_points: ``(P, T, 3)`` world point of the focus target.
        R_world_from_head: ``(P, T, 3, 3)`` head orientation (``v_world = R @ v_head``).
        true_gaze_angles: ``(P, T, 2)`` true (yaw, tilt) of the gaze in the head frame (radians).
        gaze_angles: ``(P, T, 2)`` estimated (yaw, tilt): ``true − bias + noise``.
        bias: ``(P, 2)`` systematic bias (radians); ``gaze_angles + bias ≈ true``.
        object_positions: ``(P, K, 3)`` world positions of each person's objects.
        head_fraction: ``(P,)`` κ, the share of a gaze shift made by the head.
        fps: frames per second.
        preset: preset name.
        config: the :class:`DyadicConfig` used.
    """

    speaking: Bool[Array, "P T"]
    focus: Int[Array, "P T"]
    looking: Bool[Array, "P T"]
    eye_positions: Float[Array, "P T 3"]
    target_positions: Float[Array, "P T 3"]
    focus_points: Float[Array, "P T 3"]
    R_world_from_head: Float[Array, "P T 3 3"]
    true_gaze_angles: Float[Array, "P T 2"]
    gaze_angles: Float[Array, "P T 2"]
    bias: Float[Array, "P 2"]
    object_positions: Float[Array, "P K 3"]
    head_fraction: Float[Array, " P"]
    fps: float
    preset: str
    config: DyadicConfig

    @property
    def num_frames(self) -> int:
        return self.speaking.shape[-1]

    @property
    def num_people(self) -> int:
        return self.speaking.shape[-2]

    @property
    def times(self) -> Float[Array, " T"]:
        """Frame times in seconds, ``t / fps``."""
        return jnp.arange(self.num_frames) / self.fps

    @property
    def partner_speaking(self) -> Bool[Array, "... P T"]:
        """``(P, T)``: the partner of person ``p`` speaks (the soft label of Sec. 3.2)."""
        return jnp.flip(self.speaking, axis=-2)

    def head_directions(self) -> Float[Array, "... P T 3"]:
        """Head forward axis in the world, ``R_world_from_head[..., :, 0]``."""
        return self.R_world_from_head[..., :, 0]

    def take(self, i) -> "DyadicRecording":
        """Session ``i`` of a batch from :func:`simulate_dyadic_sessions` (arrays indexed, the rest kept)."""
        return DyadicRecording(*(f[i] if isinstance(f, jax.Array | np.ndarray) else f for f in self))


# ---------------------------------------------------------------------------
# Configuration and validation


def dyadic_config(preset: str) -> DyadicConfig:
    """Default :class:`DyadicConfig` of a preset (see the module docstring)."""
    if not isinstance(preset, str) or preset not in _PRESET_CONFIGS:
        raise ValueError(f"unknown dyadic preset {preset!r}; choose one of {PRESETS}")
    return _PRESET_CONFIGS[preset]


def _check_config(config: DyadicConfig) -> DyadicConfig:
    """Validate and normalise (plain floats, tuples: hashable, so usable as a static argument)."""
    if config.preset not in _PRESET_CONFIGS:
        raise ValueError(f"DyadicConfig.preset {config.preset!r} is not a preset; choose one of {PRESETS}")
    c = {"preset": config.preset}
    c["distance_m"] = check_pair("distance_m", config.distance_m, lo=0.3)
    c["eye_height_m"] = check_pair("eye_height_m", config.eye_height_m, lo=0.3, hi=2.5)
    c["body_sway_m"] = check_number("body_sway_m", config.body_sway_m, lo=0.0, hi=0.5)
    c["body_yaw_deg"] = check_number("body_yaw_deg", config.body_yaw_deg, lo=0.0, hi=60.0)
    c["head_fraction"] = check_pair("head_fraction", config.head_fraction, lo=0.0, hi=1.0)
    c["head_lag_s"] = check_number("head_lag_s", config.head_lag_s, lo=0.0, hi=5.0)
    for name in ("head_sway_deg", "head_jitter_deg", "head_roll_deg"):
        c[name] = check_number(name, getattr(config, name), lo=0.0, hi=30.0)
    c["turn_s"] = check_pair("turn_s", config.turn_s, lo=0.1)
    c["gap_s"] = check_pair("gap_s", config.gap_s)
    if c["turn_s"][0] + c["gap_s"][0] < 0.05 or c["turn_s"][0] <= -c["gap_s"][0] + 0.05:
        raise ValueError(
            f"turn_s {config.turn_s!r} and gap_s {config.gap_s!r}: the shortest turn must outlast the largest "
            "overlap (turn_s[0] > −gap_s[0] + 0.05 s)"
        )
    c["fixation_s"] = check_pair("fixation_s", config.fixation_s, lo=0.05)
    c["p_look_speaking"] = check_number("p_look_speaking", config.p_look_speaking, lo=0.0, hi=1.0)
    c["p_look_silent"] = check_number("p_look_silent", config.p_look_silent, lo=0.0, hi=1.0)
    w = config.object_weights
    if not isinstance(w, (tuple, list)) or len(w) != NUM_OBJECTS:
        raise ValueError(f"object_weights must hold {NUM_OBJECTS} probabilities, got {w!r}")
    w = tuple(check_number(f"object_weights[{i}]", x, lo=0.0, hi=1.0) for i, x in enumerate(w))
    if sum(w) > 1.0 + 1e-9:
        raise ValueError(
            f"object_weights must sum to at most 1 (the rest is 'elsewhere'), got {config.object_weights!r}"
        )
    c["object_weights"] = w
    c["fixation_noise_deg"] = check_number("fixation_noise_deg", config.fixation_noise_deg, lo=0.0, hi=30.0)
    c["bias_deg"] = check_pair("bias_deg", config.bias_deg, lo=0.0, hi=60.0)
    c["noise_deg"] = check_number("noise_deg", config.noise_deg, lo=0.0, hi=60.0)
    dof = config.noise_dof
    if isinstance(dof, bool) or not isinstance(dof, (int, np.integer)) or not (dof == 0 or 3 <= dof <= 100):
        raise ValueError(f"noise_dof must be an integer in [3, 100] (Student-t) or 0 (Gaussian), got {dof!r}")
    c["noise_dof"] = int(dof)
    c["noise_corr_s"] = check_number("noise_corr_s", config.noise_corr_s, lo=0.0, hi=5.0)
    return DyadicConfig(**c)


def _resolve(preset) -> DyadicConfig:
    if isinstance(preset, DyadicConfig):
        return _check_config(preset)
    if isinstance(preset, str):
        return _check_config(dyadic_config(preset))
    raise ValueError(f"preset must be a preset name {PRESETS} or a DyadicConfig, got {type(preset).__name__}")


# ---------------------------------------------------------------------------
# Building blocks (all vectorised; static shapes)


def _num_turns(duration: float, config: DyadicConfig) -> int:
    """Turns needed to cover ``[−turn_max, duration]``."""
    step = config.turn_s[0] + config.gap_s[0]
    return int(math.ceil((duration + config.turn_s[1]) / step)) + 2


def _num_segments(duration: float, config: DyadicConfig) -> int:
    return int(math.ceil((duration + config.fixation_s[1]) / config.fixation_s[0])) + 2


def _causal_filter(x: Float[Array, "... T"], weights: Float[Array, " L"]) -> Float[Array, "... T"]:
    """``y[t] = Σ_k w_k x[t − k]``, with ``x`` held at ``x[0]`` before the start."""
    L = weights.shape[0]
    if L == 1:
        return x * weights[0]
    flat = x.reshape(-1, x.shape[-1])
    padded = jnp.concatenate([jnp.repeat(flat[:, :1], L - 1, axis=1), flat], axis=1)
    out = jax.vmap(lambda s: jnp.convolve(s, weights, mode="valid"))(padded)
    return out.reshape(x.shape)


def _exp_kernel(time_constant_s: float, fps: float, *, unit_energy: bool) -> np.ndarray:
    """Causal exponential kernel ``ρ^k`` (ρ = exp(−1 / (τ fps))), truncated at 6τ.

    Normalised to unit sum (a low-pass: constants pass unchanged) or to unit
    energy (``Σ w² = 1``: white noise keeps its variance).
    """
    frames = time_constant_s * fps
    if frames < 1e-3:
        return np.ones(1, np.float32)
    L = int(math.ceil(6 * frames)) + 1
    w = np.exp(-np.arange(L) / frames)
    w = w / (np.sqrt(np.sum(w * w)) if unit_energy else np.sum(w))
    return w.astype(np.float32)


def _turns(pool: Pool, times, config: DyadicConfig, num_turns: int) -> Bool[Array, "P T"]:
    """Speaking flags ``(2, T)`` from alternating turns with gaps and overlaps."""
    dur = pool.uniform((num_turns,), *config.turn_s)
    gap = pool.uniform((num_turns,), *config.gap_s)
    first = (pool.uniform(()) < 0.5).astype(jnp.int32)
    start0 = -pool.uniform(()) * dur[0]
    starts = start0 + jnp.concatenate([jnp.zeros(1), jnp.cumsum(dur + gap)[:-1]])
    speaker = (first + jnp.arange(num_turns)) % 2
    k = jnp.clip(jnp.searchsorted(starts, times, side="right") - 1, 0, num_turns - 1)
    km1 = jnp.maximum(k - 1, 0)
    in_k = times < starts[k] + dur[k]
    in_km1 = (k >= 1) & (times < starts[km1] + dur[km1])
    people = jnp.arange(NUM_PEOPLE)[:, None]
    return (in_k & (speaker[k] == people)) | (in_km1 & (speaker[km1] == people))


def _segment_index(pool: Pool, times, config: DyadicConfig, num_segments: int) -> Int[Array, "P T"]:
    """Index of each person's fixation segment at every frame, ``(2, T)``."""
    dur = pool.uniform((NUM_PEOPLE, num_segments), *config.fixation_s)
    start0 = -pool.uniform((NUM_PEOPLE, 1)) * dur[:, :1]
    starts = start0 + jnp.concatenate([jnp.zeros((NUM_PEOPLE, 1)), jnp.cumsum(dur, axis=1)[:, :-1]], axis=1)
    idx = jax.vmap(lambda s: jnp.searchsorted(s, times, side="right") - 1)(starts)
    return jnp.clip(idx, 0, num_segments - 1)


def _objects(pool: Pool, config: DyadicConfig, eye0, forward, left) -> Float[Array, "P K 3"]:
    """World positions of each person's ``K = 3`` objects, from their mean eye and body frame.

    ``eye0 (P, 3)``; ``forward``, ``left`` ``(P, 3)`` horizontal unit vectors.
    """
    P = NUM_PEOPLE
    if config.preset == "interview":
        # 1 table between the two (0.75 m high), 2 notes on the lap / table edge.
        fwd = jnp.stack([pool.uniform((P,), 0.55, 0.8), pool.uniform((P,), 0.25, 0.4)], axis=1)
        lat = jnp.stack([pool.uniform((P,), -0.2, 0.2), pool.uniform((P,), -0.25, 0.25)], axis=1)
        height = jnp.stack([pool.uniform((P,), 0.72, 0.78), pool.uniform((P,), 0.6, 0.75)], axis=1)
    else:
        # 1 the desk (bill, counter) below and in front, 2 a phone on the desk, to one side.
        desk = pool.uniform((P,), 0.95, 1.1)
        side = jnp.where(pool.uniform((P,)) < 0.5, -1.0, 1.0)
        fwd = jnp.stack([pool.uniform((P,), 0.3, 0.5), pool.uniform((P,), 0.25, 0.4)], axis=1)
        lat = jnp.stack([pool.uniform((P,), -0.2, 0.2), side * pool.uniform((P,), 0.3, 0.45)], axis=1)
        height = jnp.stack([desk, desk + 0.02], axis=1)
    near = (
        eye0[:, None, :2]
        + fwd[..., None] * forward[:, None, :2]
        + lat[..., None] * left[:, None, :2]
    )
    near = jnp.concatenate([near, height[..., None]], axis=-1)  # (P, 2, 3)
    # 3 a point in the room, 40°–80° to one side, 2.5–3.5 m away.
    azimuth = jnp.where(pool.uniform((P,)) < 0.5, -1.0, 1.0) * pool.uniform((P,), math.radians(40), math.radians(80))
    dist = pool.uniform((P,), 2.5, 3.5)
    room_xy = eye0[:, :2] + dist[:, None] * (
        jnp.cos(azimuth)[:, None] * forward[:, :2] + jnp.sin(azimuth)[:, None] * left[:, :2]
    )
    room = jnp.concatenate([room_xy, pool.uniform((P, 1), 1.0, 1.8)], axis=-1)
    return jnp.concatenate([near, room[:, None, :]], axis=1)


def _normals(pool: Pool, shape) -> Float[Array, "..."]:
    """Standard normals by Box–Muller from the pool's uniforms (compiles much
    faster than ``jax.random.normal``, above all under ``vmap``). The last axis must be even."""
    half = shape[:-1] + (shape[-1] // 2,)
    u = pool.uniform((2,) + half)
    radius = jnp.sqrt(-2.0 * jnp.log1p(-u[0]))  # 1 − u ∈ (0, 1]
    angle = 2 * math.pi * u[1]
    return jnp.concatenate([radius * jnp.cos(angle), radius * jnp.sin(angle)], axis=-1)


def _pool_size(num_turns: int, num_segments: int) -> int:
    return 512 + 2 * num_turns + NUM_PEOPLE * num_segments * 7


def _session_arrays(key, *, config: DyadicConfig, num_frames: int, fps: float):
    P, K = NUM_PEOPLE, NUM_OBJECTS
    duration = num_frames / fps
    n_turns = _num_turns(duration, config)
    n_segments = _num_segments(duration, config)
    dof = config.noise_dof
    n_normals = 2 + 2 + 2 * (1 + dof)  # fixation, head jitter, estimator noise and its χ² parts
    # One jax.random call per session (each adds a threefry kernel and compile
    # time): the per-frame normals first, then blocks at fixed offsets from ``base``.
    base = P * num_frames * n_normals
    pool = Pool(key, base + _pool_size(n_turns, n_segments))
    normal = _normals(pool, (P, num_frames, n_normals))

    def seek(offset):
        pool.seek(base + offset)

    times = jnp.arange(num_frames) / fps
    deg = math.pi / 180.0

    # 1. Layout: pair axis, mean eye positions, body frames, objects, sway.
    mid = pool.uniform((2,), -1.0, 1.0)
    phi = pool.uniform((), 0.0, 2 * math.pi)
    axis = jnp.stack([jnp.cos(phi), jnp.sin(phi)])
    distance = pool.uniform((), *config.distance_m)
    height = pool.uniform((P,), *config.eye_height_m)
    xy0 = mid + jnp.array([-0.5, 0.5])[:, None] * distance * axis  # (P, 2)
    eye0 = jnp.concatenate([xy0, height[:, None]], axis=-1)  # (P, 3)
    to_partner = eye0[::-1] - eye0
    partner_azimuth, partner_elevation = direction_to_yaw_pitch(to_partner)
    body_yaw = partner_azimuth + pool.uniform((P,), -1.0, 1.0) * config.body_yaw_deg * deg
    body_pitch = partner_elevation
    forward = yaw_pitch_to_direction(body_yaw, jnp.zeros(P))
    left = yaw_pitch_to_direction(body_yaw + math.pi / 2, jnp.zeros(P))
    objects = _objects(pool, config, eye0, forward, left)  # (P, K, 3)
    seek(64)
    sway = config.body_sway_m * smooth(pool, times, (P, 3), periods=(3.0, 15.0))  # (T, P, 3)
    eyes = eye0[:, None, :] + jnp.transpose(sway, (1, 0, 2))  # (P, T, 3)
    targets = eyes[::-1]
    seek(64 + 3 * 3 * P * 3)

    # Person parameters: head fraction, bias, smooth head sway and roll.
    kappa = pool.uniform((P,), *config.head_fraction)
    bias_mag = pool.uniform((P,), *config.bias_deg) * deg
    bias_dir = pool.uniform((P,), 0.0, 2 * math.pi)
    bias = bias_mag[:, None] * jnp.stack([jnp.cos(bias_dir), jnp.sin(bias_dir)], axis=-1)  # (P, 2)
    head_sway = config.head_sway_deg * deg * smooth(pool, times, (P, 2), periods=(2.0, 10.0))  # (T, P, 2)
    roll = config.head_roll_deg * deg * smooth(pool, times, (P,), periods=(3.0, 12.0))  # (T, P)
    seek(256)

    # 2. Speaking turns.
    speaking = _turns(pool, times, config, n_turns)  # (P, T)
    seek(256 + 2 * n_turns + 8)

    # 3. Visual focus.
    seg = _segment_index(pool, times, config, n_segments)  # (P, T)
    u = pool.uniform((P, n_segments, 5))
    u_look, u_obj = u[..., 0], u[..., 1]
    cum = jnp.cumsum(jnp.asarray(config.object_weights))
    obj = jnp.sum(u_obj[..., None] >= cum, axis=-1) + 1  # 1 … K, or K + 1 for elsewhere
    obj = jnp.where(obj > K, FOCUS_ELSEWHERE, obj).astype(jnp.int32)
    sign = jnp.where(u[..., 2] < 0.5, -1.0, 1.0)
    lo, hi = _ELSEWHERE_YAW_DEG
    away_yaw = sign * (lo + (hi - lo) * u[..., 3]) * deg
    lo, hi = _ELSEWHERE_PITCH_DEG
    away_pitch = (lo + (hi - lo) * u[..., 4]) * deg
    away_dist = pool.uniform((P, n_segments), *_ELSEWHERE_DISTANCE_M)

    partner_speaking = speaking[::-1]
    take = jax.vmap(lambda a, i: a[i])  # per person: (S,), (T,) -> (T,)
    p_look = jnp.where(partner_speaking, config.p_look_speaking, config.p_look_silent)
    looking = take(u_look, seg) < p_look
    focus = jnp.where(looking, FOCUS_PARTNER, take(obj, seg)).astype(jnp.int32)
    away_dir = yaw_pitch_to_direction(
        body_yaw[:, None] + take(away_yaw, seg), body_pitch[:, None] + take(away_pitch, seg)
    )  # (P, T, 3)
    away_point = eyes + take(away_dist, seg)[..., None] * away_dir
    obj_point = jnp.take_along_axis(objects, jnp.clip(focus - 1, 0, K - 1)[..., None], axis=1)  # (P, T, 3)
    focus_points = jnp.where((focus == FOCUS_ELSEWHERE)[..., None], away_point, obj_point)
    focus_points = jnp.where((focus == FOCUS_PARTNER)[..., None], targets, focus_points)

    # 4. Head: a fraction κ of the gaze shift from the body direction, lagged, plus noise.
    sight = unit(focus_points - eyes)
    sight_yaw, sight_pitch = direction_to_yaw_pitch(sight)
    rel = jnp.stack([wrap_angle(sight_yaw - body_yaw[:, None]), sight_pitch - body_pitch[:, None]], axis=-1)
    head_rel = kappa[:, None, None] * rel
    lag = jnp.asarray(_exp_kernel(config.head_lag_s, fps, unit_energy=False))
    head_rel = jnp.moveaxis(_causal_filter(jnp.moveaxis(head_rel, -1, 1), lag), 1, -1)
    head_rel = head_rel + jnp.transpose(head_sway, (1, 0, 2)) + config.head_jitter_deg * deg * normal[..., 2:4]
    head_yaw = body_yaw[:, None] + head_rel[..., 0]
    head_pitch = body_pitch[:, None] + head_rel[..., 1]
    R = head_pose_to_rotation(head_yaw, head_pitch, roll.T)  # (P, T, 3, 3)

    # 5. True gaze in the head frame.
    sight_head = jnp.einsum("ptji,ptj->pti", R, sight)  # Rᵀ · sight
    true_yaw, true_pitch = direction_to_yaw_pitch(sight_head)
    true = jnp.stack([true_yaw, true_pitch], axis=-1) + config.fixation_noise_deg * deg * normal[..., 0:2]

    # 6. Estimated gaze: true − bias + heavy-tailed, short-range correlated noise.
    z = normal[..., 4:6]
    if dof > 0:
        chi2 = jnp.sum(jnp.square(normal[..., 6:].reshape(P, num_frames, 2, dof)), axis=-1)
        z = z * jnp.sqrt((dof - 2) / jnp.maximum(chi2, 1e-6))  # Student-t with unit variance
    corr = jnp.asarray(_exp_kernel(config.noise_corr_s, fps, unit_energy=True))
    z = jnp.moveaxis(_causal_filter(jnp.moveaxis(z, -1, 1), corr), 1, -1)
    gaze = true - bias[:, None, :] + config.noise_deg * deg * z
    gaze = jnp.stack([wrap_angle(gaze[..., 0]), jnp.clip(gaze[..., 1], -math.pi / 2, math.pi / 2)], axis=-1)

    return dict(
        speaking=speaking,
        focus=focus,
        looking=focus == FOCUS_PARTNER,
        eye_positions=eyes,
        target_positions=targets,
        focus_points=focus_points,
        R_world_from_head=R,
        true_gaze_angles=true,
        gaze_angles=gaze,
        bias=bias,
        object_positions=objects,
        head_fraction=kappa,
    )


@partial(jax.jit, static_argnames=("config", "num_frames", "fps"))
def _simulate_one(key, *, config, num_frames, fps):
    return _session_arrays(key, config=config, num_frames=num_frames, fps=fps)


@partial(jax.jit, static_argnames=("config", "num_frames", "fps"))
def _simulate_many(keys, *, config, num_frames, fps):
    return jax.vmap(partial(_session_arrays, config=config, num_frames=num_frames, fps=fps))(keys)


# ---------------------------------------------------------------------------
# Public API


def simulate_dyadic(
    key,
    preset: str | DyadicConfig = "interview",
    *,
    duration_s: float = 120.0,
    fps: float = 30.0,
) -> DyadicRecording:
    """Simulate one dyadic interaction with ground truth (Siegfried, Odobez et al. 2017).

    Args:
        key: a single ``jax.random`` key; the same key gives the same recording.
        preset: ``"interview"``, ``"desk"`` (see :data:`PRESETS`) or a
            :class:`DyadicConfig` (e.g. ``dyadic_config("desk")._replace(noise_deg=2.0)``).
        duration_s: length in seconds (> 0); ``T = round(duration_s · fps) ≥ 2``.
        fps: frames per second (> 0); the paper's Kinect data are 30 fps.

    Returns:
        :class:`DyadicRecording` with ``P = 2`` people and ``T`` frames.

    Raises:
        ValueError: for a bad key, preset name or configuration, or a
            non-positive / non-finite ``duration_s`` or ``fps``.
    """
    check_key(key)
    config = _resolve(preset)
    num_frames, fps = check_frames(duration_s, fps)
    arrays = _simulate_one(key, config=config, num_frames=num_frames, fps=fps)
    return DyadicRecording(**arrays, fps=fps, preset=config.preset, config=config)


def simulate_dyadic_sessions(
    key,
    num_sessions: int,
    preset: str | DyadicConfig = "interview",
    *,
    duration_s: float = 120.0,
    fps: float = 30.0,
) -> DyadicRecording:
    """A batch of ``num_sessions`` independent dyads, in one vmapped, jitted pass.

    Session ``i`` uses key ``jax.random.split(key, num_sessions)[i]`` and equals
    ``simulate_dyadic(that key, ...)``. Array fields gain a leading axis
    ``(num_sessions, ...)``; ``take(i)`` returns session ``i``. Other arguments
    as in :func:`simulate_dyadic`.
    """
    check_key(key)
    num_sessions = check_int("num_sessions", num_sessions)
    config = _resolve(preset)
    num_frames, fps = check_frames(duration_s, fps)
    keys = jax.random.split(key, int(num_sessions))
    arrays = _simulate_many(keys, config=config, num_frames=num_frames, fps=fps)
    return DyadicRecording(**arrays, fps=fps, preset=config.preset, config=config)


class PartnerCameraView(NamedTuple):
    """One person of a :class:`DyadicRecording` seen by a fixed camera by the partner, in **our**
    camera frame (+x forward along the optical axis, +y left, +z up; metres).

    Attributes:
        R_world_from_camera: ``(3, 3)`` the camera's axes in the world.
        center: ``(3,)`` the camera centre, world.
        R_camera_from_head: ``(T, 3, 3)`` the person's head orientation.
        head_position_camera: ``(T, 3)`` the person's eye midpoint.
        gaze_direction_camera: ``(T, 3)`` the *estimated* gaze (``gaze_angles``, bias included).
        target_camera: ``(T, 3)`` the partner's eye midpoint.
    """

    R_world_from_camera: np.ndarray
    center: np.ndarray
    R_camera_from_head: np.ndarray
    head_position_camera: np.ndarray
    gaze_direction_camera: np.ndarray
    target_camera: np.ndarray

    @property
    def faces_camera(self) -> np.ndarray:
        """``(T,)`` frames whose gaze turns toward the camera by more than ~6° (a face tracker sees the eyes)."""
        return self.gaze_direction_camera[:, 0] < -0.1


def partner_camera_view(recording: DyadicRecording, person: int, *, below_m: float = 0.25,
                        beside_m: float = 0.15) -> PartnerCameraView:
    """``person`` filmed by a fixed camera ``below_m`` under and ``beside_m`` beside the mean of the
    partner's eyes, looking at the person's mean eye position (upright: its +y is horizontal)."""
    R_world_from_head = np.asarray(recording.R_world_from_head[person], float)
    eye, target = np.asarray(recording.eye_positions[person], float), np.asarray(recording.target_positions[person], float)
    yaw, tilt = np.asarray(recording.gaze_angles[person], float).T

    def unit_np(v):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    up = np.array([0.0, 0.0, 1.0])
    side = unit_np(np.cross(up, unit_np(eye.mean(0) - target.mean(0))))
    center = target.mean(0) - below_m * up + beside_m * side
    forward = unit_np(eye.mean(0) - center)
    left = unit_np(np.cross(up, forward))
    R_world_from_camera = np.stack([forward, left, np.cross(forward, left)], axis=1)
    R_camera_from_head = R_world_from_camera.T @ R_world_from_head
    gaze_head = np.stack([np.cos(tilt) * np.cos(yaw), np.cos(tilt) * np.sin(yaw), np.sin(tilt)], axis=-1)
    return PartnerCameraView(
        R_world_from_camera=R_world_from_camera, center=center, R_camera_from_head=R_camera_from_head,
        head_position_camera=(eye - center) @ R_world_from_camera,
        gaze_direction_camera=np.einsum("tij,tj->ti", R_camera_from_head, gaze_head),
        target_camera=(target - center) @ R_world_from_camera,
    )
