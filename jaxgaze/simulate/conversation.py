"""Simulated multi-party conversations with full ground truth: who looks at whom.

``P`` people (3–8 by default) talk for ``T = round(duration_s · fps)`` frames
around a table or standing in a circle, with ``K`` shared objects. For every
person and frame a head tracker reports a head pose and a gaze estimator
reports gaze angles ``g = (yaw, tilt)`` in the **reported** head frame, which
carry a person-specific bias ``b`` (``Φ(g + b)`` is the gaze, Siegfried et al.
2017) and scatter around the target with a person-specific cone width ``h``
(Park et al.). This is the data of a joint model of the visual focus of
attention: per-person bias, cone width, a speaker prior and shared
concurrences (several people on one object at once). Every hidden quantity is
returned.

Frames: world z up, metres; head frame +x forward, +y left, +z up;
``R_world_from_head`` maps head to world, ``v_world = R v_head``. Radians
inside; ``_deg`` names hold degrees, ``_s`` seconds, ``_m`` metres.

Generative model, for one scene:

1. **Layout.** *Seated*: the people sit around a round table (top at
   ``table_height_m``) on a circle of radius growing linearly with ``P`` over
   ``seated_radius_m`` (``P = 3`` … ``8``), seats evenly spaced up to a jitter
   of ``seat_jitter`` of the spacing, eye heights uniform in
   ``seated_eye_height_m``. *Standing*: a circle of radius in
   ``standing_radius_m`` (also growing with ``P``), eye heights in
   ``standing_eye_height_m``. Objects lie on the table top (or a standing
   table) within ``object_disc`` of the radius from the centre, at least
   ``object_spacing_m`` apart; with probability ``screen_prob`` the last one is
   a screen on a wall ``screen_distance_m`` outside the circle, between two
   seats, at height ``screen_height_m``. Objects are static. Bodies face the
   circle centre; the eye midpoints sway smoothly by up to ``body_sway_m``
   per axis.
2. **Speaking turns.** One main speaker at a time. Turn lengths are lognormal
   with median ``turn_median_s`` and log-sd ``turn_sigma``, clipped to
   ``turn_s``; each turn is followed by a gap uniform in ``gap_s`` (negative:
   the next speaker starts before the turn ends, both speak; positive:
   silence). The next speaker is drawn uniformly among the others in the
   scene; with ``quiet_people = n > 0`` the last ``n`` people are drawn with
   weight ``quiet_weight`` against 1 (people who speak rarely).
3. **Per-person traits.** Bias ``b``: magnitude uniform in ``bias_deg``, in a
   uniformly random direction of the (yaw, tilt) plane. Cone width ``h``
   uniform in ``cone_width_deg``. Head fraction ``κ`` uniform in
   ``head_fraction``.
4. **Joint attention episodes.** Episode starts are ``episode_interval_s``
   apart, each lasting ``episode_s``; during one, a random object ``k`` is
   *active* and draws most people's attention at once.
5. **Visual focus.** Each person's focus is a sequence of fixation segments
   of length uniform in ``fixation_s``. A segment also ends when the set of
   speakers changes or an episode starts or ends (after a per-person
   reaction delay uniform in ``[0, reaction_s]``), when the person being
   looked at leaves the tracker, and when the person reappears after a gap.
   At the start of a segment the target is drawn with weights: person
   ``j ≠ i`` present: ``w_person · (exp(speaker_beta) if j speaks else 1)``;
   object ``k``: ``w_object``, or ``w_episode_object`` while ``k`` is active;
   elsewhere: ``w_elsewhere``. ``exp(speaker_beta) = 6.5`` (a speaker is
   looked at 5–8 times as often as a non-speaker, Siegfried et al. 2017 after
   Vertegaal et al.); with the defaults a listener in a 6-person seated scene
   outside episodes looks at the single speaker about 55 % of the time.
   *Elsewhere* is a point ``elsewhere_distance_m`` away, within
   ``±elsewhere_yaw_deg`` of the body direction, at elevation in
   ``elsewhere_elevation_deg``, fixed in the world for the segment.
   ``target``: ``j ∈ [0, P)`` person ``j``'s eye midpoint, ``P + k`` object
   ``k``, −1 elsewhere (and where the person is not present).
6. **Head.** The head turns by ``κ`` times the line of sight's azimuth and
   elevation relative to the body direction (horizontal, towards the centre),
   low-passed by a causal exponential filter with time constant
   ``head_lag_s`` (with ``head_turn_limit_deg = L > 0`` the turn saturates as
   ``L tanh(κ θ / L)``), plus a smooth sway of up to ``head_sway_deg`` and a smooth
   roll of up to ``head_roll_deg``:
   ``true_R_world_from_head = R_z(yaw) R_y(−pitch) R_x(roll)``
   (:func:`jaxgaze.geometry.head_pose_to_rotation`).
   The *reported* head pose is ``R_world_from_head = true_R · E`` with a
   tracker error ``E = R_z R_y R_x`` of smooth drift (up to
   ``tracker_drift_deg`` per axis) plus i.i.d. jitter ``N(0,
   tracker_jitter_deg²)`` per axis and frame, the pitch's times ``tracker_tilt_factor``.
7. **True gaze.** ``v* = exp_u(δ)``: the unit direction ``u`` from the eye to
   the target point, rotated on its tangent plane by ``δ = h z₁ + s z₂``,
   ``z₁, z₂ ~ N(0, I₂)`` i.i.d. per frame (Park's cone, and the estimator's
   extra noise of sd ``s = measurement_scale``, drawn per frame uniformly in
   ``measurement_scale_deg``). With ``held_cone_share = c > 0`` the cone's part
   is ``√(1 − c) z₁ + √c z₀``, ``z₀`` drawn once per fixation segment: the eyes
   rest on one spot of the target for the fixation (correlated residuals). The
   angle between ``v*`` and ``u`` is ``‖δ‖``, Rayleigh with scale ``sqrt(h² + s²)``
   in every frame.
8. **Measured gaze.** ``g = Φ⁻¹(R_world_from_headᵀ v*) − b`` (yaw wrapped to
   (−π, π]): the estimator reports gaze relative to the *reported* head pose,
   so ``R_world_from_head Φ(g + b) = v*`` exactly and the tracker error only
   moves the head direction.
9. **Presence.** Tracker dropouts of length uniform in ``dropout_s`` cover
   about ``dropout_fraction`` of each person's frames; with probability
   ``late_early_prob`` one person arrives late or leaves early, missing a
   fraction uniform in ``late_early_fraction`` of the scene (and not speaking
   then). Where a person is not present: ``target = −1``, ``gaze_angles`` and
   ``target_positions`` NaN, ``measurement_scale = 0``; nobody looks at an
   absent person. Positions and head poses stay finite everywhere.

10. **Head-mounted cameras (optional).** With ``num_wearers = W > 0`` the
    first ``W`` people wear a head-mounted camera and no eye tracker (Park,
    Jain & Sheikh 2012). Each wearer ``w`` has a mounting
    (:func:`jaxgaze.simulate.calibration.random_mounting`): eye centre
    ``e_w`` and unit primary gaze direction ``v_w`` in the camera frame (+x
    forward, +y left, +z up). The head *is* the camera and follows the gaze
    fully, without lag (``κ = 1``; Park's gaze = head-fixed primary ray +
    eye-in-head deviation): the actual gaze in the camera frame is
    ``v'_t = unit(v_w + d₁ u₁ + d₂ u₂)``, ``d ~ N(0, h_w² I₂)`` (``h_w`` the
    person's cone width), and the true camera rotation ``R_t`` (head to world)
    maps ``v'_t`` onto ``unit(target_t − eye_t)``, keeping the camera upright
    (camera +z in the vertical plane through the line of sight, as in
    :mod:`jaxgaze.simulate.calibration`, step 4), then rolling by a smooth roll
    of up to ``head_roll_deg`` about the line of sight. Where the wearer is
    absent the line of sight is the head model's forward axis (step 6). The
    camera centre is ``C_t = eye_t − R_t e_w``, so ``C_t + R_t e_w = eye_t``.
    Reported (structure from motion): ``R_world_from_head = R_t · E``, ``E``
    of i.i.d. ``N(0, (0.3°)²)`` per axis and frame, and ``camera_positions =
    C_t + N(0, (1 cm)² I₃)``. A wearer's ``gaze_angles`` are ``(0, 0)`` where
    present (NaN where absent), ``measurement_scale = 0``, and the truth is
    ``bias = Φ⁻¹(v_w)`` and ``cone_width = h_w``: ``R Φ(g + b) = R v_w`` is
    the primary ray, which deviates from the line of sight ``v* = R_t v'_t``
    by ``atan ‖d‖ ≈ ‖d‖`` (Rayleigh with scale ``h_w``). ``eye_positions``
    stay the true eye midpoints (what the others look at). Each wearer also
    has a calibration session with a partner camera (Park Sec. 3.2,
    :func:`jaxgaze.simulate.calibration.simulate_calibration_session` with the
    wearer's mounting, ``eye_in_head = h_w``, ``calibration_frames`` frames at
    the scene's fps and that module's default pose noise):
    ``calibration_points`` holds the reported points of regard in the
    wearer's camera frame, ``y = e_w + s v'`` up to pose noise. Non-wearers'
    camera fields are NaN. All wearer randomness comes from
    ``jax.random.fold_in(key, _WEARER_STREAM)`` (wearer ``w``: a further
    ``fold_in(·, w)``), so every non-wearer output, and the random stream of
    steps 1–9, is the same as with ``num_wearers = 0``.

All randomness comes from the ``jax.random`` key (one ``jax.random.bits``
draw seeds a NumPy generator): the same key gives the same scene. The
sequential logic runs in NumPy (float64); nothing is compiled per scene
(except, with wearers, the calibration sessions, jitted once per
``calibration_frames`` and fps).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze._checks import check_frames, check_int, check_int_pair, check_key, check_number, check_pair
from jaxgaze.simulate.calibration import random_mounting, simulate_calibration_session

__all__ = [
    "ELSEWHERE",
    "ConversationConfig",
    "Conversation",
    "conversation_config",
    "simulate_conversation",
    "simulate_conversations",
]

ELSEWHERE = -1
_MAX_PEOPLE = 64
_MAX_OBJECTS = 32
_MAX_CALIBRATION_FRAMES = 100_000
# Head-mounted cameras (step 10): the wearer stream is fold_in(key, _WEARER_STREAM)
# ("WEAR"), and the structure-from-motion noise of the reported camera pose.
_WEARER_STREAM = 0x57454152
_SFM_ROTATION_DEG = 0.3
_SFM_POSITION_M = 0.01


class ConversationConfig(NamedTuple):
    """Parameters of the conversation generative model (see the module docstring).

    Pairs ``(lo, hi)`` are ranges of uniform draws unless said otherwise.
    ``_deg`` fields are degrees, ``_s`` seconds, ``_m`` metres.

    Attributes:
        num_people_range: ``P`` drawn uniformly in ``[lo, hi]`` (integers) when not given.
        num_objects_range: ``K`` drawn uniformly in ``[lo, hi]`` (integers) when not given.
        standing_prob: probability of a standing scene when ``standing`` is not given.
        seated_radius_m: seat circle radius at ``P = 3`` and at ``P = 8`` (linear in ``P``, clamped).
        standing_radius_m: standing circle radius at ``P = 3`` and at ``P = 8``.
        radius_jitter_m: uniform ``±`` jitter of the circle radius.
        seated_eye_height_m: eye heights of seated people.
        standing_eye_height_m: eye heights of standing people.
        table_height_m: height of the table top (and of objects near the centre).
        seat_jitter: angular jitter of each seat, as a fraction of the seat spacing (``±``).
        body_sway_m: amplitude of the smooth eye-position sway, per axis.
        object_disc: objects near the centre lie within this fraction of the radius.
        object_spacing_m: minimum distance between objects near the centre.
        screen_prob: probability that the last object is a screen on a wall.
        screen_distance_m: distance of the screen outside the circle.
        screen_height_m: height of the screen.
        turn_median_s: median speaking-turn length (lognormal).
        turn_sigma: log-sd of the turn length.
        turn_s: turn lengths are clipped to this range.
        gap_s: gap after a turn (negative: overlap with the next turn).
        bias_deg: range of the bias magnitude ``‖b‖``.
        cone_width_deg: range of the cone width ``h``.
        head_fraction: range of ``κ``, the share of the line of sight turned by the head.
        episode_interval_s: time between the starts of joint-attention episodes.
        episode_s: length of an episode (``hi`` ≤ ``episode_interval_s`` ``lo``).
        fixation_s: length of a fixation segment.
        reaction_s: the largest delay of a forced re-draw after a turn or episode change.
        w_person: weight of a silent person.
        speaker_beta: log of the weight factor of a speaking person (``exp(β) = 6.5``).
        w_object: weight of an object outside its episodes.
        w_episode_object: weight of the active object during an episode.
        w_elsewhere: weight of looking elsewhere.
        elsewhere_distance_m: distance of an elsewhere point.
        elsewhere_yaw_deg: elsewhere points lie within ``±`` this of the body direction.
        elsewhere_elevation_deg: elevation range of elsewhere points.
        head_lag_s: time constant of the head's causal low-pass (0: none).
        head_sway_deg: amplitude of the smooth head yaw/pitch sway.
        head_roll_deg: amplitude of the smooth head roll.
        tracker_drift_deg: amplitude of the smooth head-tracker error, per axis.
        tracker_jitter_deg: sd of the i.i.d. head-tracker error, per axis and frame.
        tracker_tilt_factor: the tracker's pitch error (drift and jitter) is this many times its yaw and roll
            error: face trackers read pitch worse than yaw. 1: the same on every axis.
        measurement_scale_deg: range of the per-frame measurement noise sd ``s``.
        dropout_fraction: expected fraction of frames lost to tracker dropouts.
        head_turn_limit_deg: ``0``: the head turns ``κ`` of the line of sight (linear); ``L > 0``: the
            turn saturates, ``L tanh(κ θ / L)`` per axis (a non-linear head–gaze map).
        dropout_s: length of a dropout.
        late_early_prob: probability that one person arrives late or leaves early.
        late_early_fraction: fraction of the scene that person misses.
        quiet_people: the last ``quiet_people`` people speak rarely: they are the next speaker with
            weight ``quiet_weight`` against 1 for the others (0: everyone alike).
        quiet_weight: the next-speaker weight of a quiet person.
        held_cone_share: the share of the cone's variance ``h²`` held for a whole fixation segment
            (0: every frame's cone draw is independent; step 7).
    """

    num_people_range: tuple[int, int] = (3, 8)
    num_objects_range: tuple[int, int] = (1, 3)
    standing_prob: float = 0.5
    seated_radius_m: tuple[float, float] = (0.8, 1.4)
    standing_radius_m: tuple[float, float] = (0.7, 1.3)
    radius_jitter_m: float = 0.05
    seated_eye_height_m: tuple[float, float] = (1.15, 1.30)
    standing_eye_height_m: tuple[float, float] = (1.50, 1.80)
    table_height_m: float = 0.75
    seat_jitter: float = 0.15
    body_sway_m: float = 0.03
    object_disc: float = 0.45
    object_spacing_m: float = 0.3
    screen_prob: float = 0.3
    screen_distance_m: tuple[float, float] = (2.0, 3.0)
    screen_height_m: tuple[float, float] = (1.0, 1.8)
    turn_median_s: float = 4.0
    turn_sigma: float = 0.5
    turn_s: tuple[float, float] = (1.0, 15.0)
    gap_s: tuple[float, float] = (-0.7, 1.5)
    bias_deg: tuple[float, float] = (5.0, 15.0)
    cone_width_deg: tuple[float, float] = (2.0, 6.0)
    head_fraction: tuple[float, float] = (0.4, 0.8)
    episode_interval_s: tuple[float, float] = (10.0, 25.0)
    episode_s: tuple[float, float] = (2.0, 6.0)
    fixation_s: tuple[float, float] = (0.5, 3.0)
    reaction_s: float = 0.3
    w_person: float = 1.0
    speaker_beta: float = math.log(6.5)
    w_object: float = 0.25
    w_episode_object: float = 20.0
    w_elsewhere: float = 0.4
    elsewhere_distance_m: tuple[float, float] = (2.0, 5.0)
    elsewhere_yaw_deg: float = 70.0
    elsewhere_elevation_deg: tuple[float, float] = (-30.0, 20.0)
    head_lag_s: float = 0.25
    head_sway_deg: float = 1.5
    head_roll_deg: float = 2.0
    tracker_drift_deg: float = 2.0
    tracker_jitter_deg: float = 0.5
    tracker_tilt_factor: float = 1.0
    measurement_scale_deg: tuple[float, float] = (0.5, 3.0)
    dropout_fraction: float = 0.025
    head_turn_limit_deg: float = 0.0
    dropout_s: tuple[float, float] = (0.2, 1.5)
    late_early_prob: float = 0.3
    late_early_fraction: tuple[float, float] = (0.1, 0.3)
    quiet_people: int = 0
    quiet_weight: float = 0.1
    held_cone_share: float = 0.0


class Conversation(NamedTuple):
    """A simulated conversation (``T`` frames, ``P`` people, ``K`` objects) with ground truth.

    NumPy arrays (float64, bool, int64).

    Attributes:
        eye_positions: ``(T, P, 3)`` true world eye midpoints (metres), finite everywhere.
        R_world_from_head: ``(T, P, 3, 3)`` *reported* head rotation, ``true_R · E`` (tracker error ``E``).
        true_R_world_from_head: ``(T, P, 3, 3)`` true head rotation.
        gaze_angles: ``(T, P, 2)`` measured gaze (yaw, tilt) in the reported head frame
            (radians), ``Φ⁻¹(Rᵀ v*) − b``; NaN where not present.
        measurement_scale: ``(T, P)`` per-frame sd of the extra measurement noise (radians); 0 where absent.
        present: ``(T, P)`` bool presence mask (tracker dropouts, late arrival / early leave).
        speaking: ``(T, P)`` bool.
        target: ``(T, P)`` true gaze target: ``j ∈ [0, P)`` person ``j`` (never self),
            ``P + k`` object ``k``, −1 elsewhere or not present.
        target_positions: ``(T, P, 3)`` true world point looked at; NaN where not present.
        true_gaze_directions: ``(T, P, 3)`` true world gaze ``v*`` (unit); NaN where not present.
        object_positions: ``(K, 3)`` static world positions of the shared objects.
        bias: ``(P, 2)`` true gaze bias (yaw, tilt), radians: ``Φ(g + b)`` is the gaze.
        cone_width: ``(P,)`` true cone width ``h`` (radians, sd per tangent axis).
        head_fraction: ``(P,)`` ``κ``, the share of the line of sight turned by the head.
        body_yaw: ``(P,)`` world azimuth of each body's forward direction (towards the centre).
        episodes: ``(E, 3)`` joint-attention episodes ``(start_s, end_s, object k)``.
        standing: whether the scene is standing (else seated around a table).
        fps: frames per second.
        config: the :class:`ConversationConfig` used.
        wearer: ``(P,)`` bool, who wears a head-mounted camera (the first ``num_wearers``; step 10).
            For a wearer ``R_world_from_head`` is the reported camera rotation,
            ``true_R_world_from_head`` the true one, ``gaze_angles`` are ``(0, 0)``,
            ``bias = Φ⁻¹(v_w)`` (so ``R Φ(g + b)`` is the primary ray), ``head_fraction = 1``.
        camera_positions: ``(T, P, 3)`` reported world camera centres ``C_t + N(0, (1 cm)²)``
            (``C_t = eye_t − R_t e_w``); NaN for non-wearers.
        eye_in_camera: ``(P, 3)`` true eye centre ``e_w`` in the camera frame (metres); NaN for non-wearers.
        calibration_points: ``(P, M, 3)`` points of regard of each wearer's calibration session in
            the wearer's camera frame (``M = calibration_frames``; ``M = 0`` without wearers); NaN
            rows for non-wearers.
        fixation_segment: ``(T, P)`` the fixation segment of each frame (step 5), numbered from 1 through
            the scene; −1 where not present. A segment may follow one on the same target (a forced re-draw or the
            same choice again): with ``held_cone_share > 0`` it draws a new spot.
    """

    eye_positions: np.ndarray
    R_world_from_head: np.ndarray
    true_R_world_from_head: np.ndarray
    gaze_angles: np.ndarray
    measurement_scale: np.ndarray
    present: np.ndarray
    speaking: np.ndarray
    target: np.ndarray
    target_positions: np.ndarray
    true_gaze_directions: np.ndarray
    object_positions: np.ndarray
    bias: np.ndarray
    cone_width: np.ndarray
    head_fraction: np.ndarray
    body_yaw: np.ndarray
    episodes: np.ndarray
    standing: bool
    fps: float
    config: ConversationConfig
    wearer: np.ndarray
    camera_positions: np.ndarray
    eye_in_camera: np.ndarray
    calibration_points: np.ndarray
    fixation_segment: np.ndarray

    @property
    def num_frames(self) -> int:
        return self.eye_positions.shape[0]

    @property
    def num_people(self) -> int:
        return self.eye_positions.shape[1]

    @property
    def num_objects(self) -> int:
        return self.object_positions.shape[0]

    @property
    def times(self) -> np.ndarray:
        """Frame times in seconds, ``t / fps``."""
        return np.arange(self.num_frames) / self.fps

    def episode_active(self) -> np.ndarray:
        """``(T,)`` int: the active episode object at each frame, −1 outside episodes."""
        active = np.full(self.num_frames, -1, np.int64)
        t = self.times
        for start, end, k in self.episodes:
            active[(t >= start) & (t < end)] = int(k)
        return active


# ---------------------------------------------------------------------------
# Configuration and validation


def conversation_config(**overrides) -> ConversationConfig:
    """The default :class:`ConversationConfig` with ``overrides``, validated."""
    unknown = sorted(set(overrides) - set(ConversationConfig._fields))
    if unknown:
        raise ValueError(f"unknown ConversationConfig field(s) {unknown}; fields are {ConversationConfig._fields}")
    return _check_config(ConversationConfig()._replace(**overrides))


def _check_config(config: ConversationConfig) -> ConversationConfig:
    """Validate and normalise (plain floats and tuples); ValueError names the field."""
    if not isinstance(config, ConversationConfig):
        raise ValueError(f"config must be a ConversationConfig, got {type(config).__name__}")
    c = {}
    c["num_people_range"] = check_int_pair("num_people_range", config.num_people_range, lo=2, hi=_MAX_PEOPLE)
    c["num_objects_range"] = check_int_pair("num_objects_range", config.num_objects_range, lo=0, hi=_MAX_OBJECTS)
    c["standing_prob"] = check_number("standing_prob", config.standing_prob, lo=0.0, hi=1.0)
    c["seated_radius_m"] = check_pair("seated_radius_m", config.seated_radius_m, lo=0.2, hi=10.0)
    c["standing_radius_m"] = check_pair("standing_radius_m", config.standing_radius_m, lo=0.2, hi=10.0)
    c["radius_jitter_m"] = check_number("radius_jitter_m", config.radius_jitter_m, lo=0.0, hi=0.15)
    c["seated_eye_height_m"] = check_pair("seated_eye_height_m", config.seated_eye_height_m, lo=0.3, hi=2.5)
    c["standing_eye_height_m"] = check_pair("standing_eye_height_m", config.standing_eye_height_m, lo=0.3, hi=2.5)
    c["table_height_m"] = check_number("table_height_m", config.table_height_m, lo=0.0, hi=2.0)
    c["seat_jitter"] = check_number("seat_jitter", config.seat_jitter, lo=0.0, hi=0.45)
    c["body_sway_m"] = check_number("body_sway_m", config.body_sway_m, lo=0.0, hi=0.2)
    c["object_disc"] = check_number("object_disc", config.object_disc, lo=0.0, hi=0.9)
    c["object_spacing_m"] = check_number("object_spacing_m", config.object_spacing_m, lo=0.0, hi=2.0)
    c["screen_prob"] = check_number("screen_prob", config.screen_prob, lo=0.0, hi=1.0)
    c["screen_distance_m"] = check_pair("screen_distance_m", config.screen_distance_m, lo=0.1, hi=20.0)
    c["screen_height_m"] = check_pair("screen_height_m", config.screen_height_m, lo=0.0, hi=5.0)
    c["turn_median_s"] = check_number("turn_median_s", config.turn_median_s, lo=0.0, lo_open=True)
    c["turn_sigma"] = check_number("turn_sigma", config.turn_sigma, lo=0.0, hi=3.0)
    c["turn_s"] = check_pair("turn_s", config.turn_s, lo=0.1)
    c["gap_s"] = check_pair("gap_s", config.gap_s, lo=-60.0, hi=60.0)
    if c["turn_s"][0] + c["gap_s"][0] < 0.05:
        raise ValueError(
            f"turn_s {config.turn_s!r} and gap_s {config.gap_s!r}: the shortest turn must outlast the largest "
            "overlap (turn_s[0] + gap_s[0] ≥ 0.05 s)"
        )
    c["bias_deg"] = check_pair("bias_deg", config.bias_deg, lo=0.0, hi=60.0)
    c["cone_width_deg"] = check_pair("cone_width_deg", config.cone_width_deg, lo=0.0, hi=45.0)
    c["head_fraction"] = check_pair("head_fraction", config.head_fraction, lo=0.0, hi=1.0)
    c["episode_interval_s"] = check_pair("episode_interval_s", config.episode_interval_s, lo=0.1)
    c["episode_s"] = check_pair("episode_s", config.episode_s, lo=0.0)
    if c["episode_s"][1] > c["episode_interval_s"][0]:
        raise ValueError(
            f"episode_s {config.episode_s!r} must end before the next episode starts "
            f"(episode_s[1] ≤ episode_interval_s[0] = {c['episode_interval_s'][0]})"
        )
    c["fixation_s"] = check_pair("fixation_s", config.fixation_s, lo=0.01)
    c["reaction_s"] = check_number("reaction_s", config.reaction_s, lo=0.0, hi=10.0)
    c["w_person"] = check_number("w_person", config.w_person, lo=0.0)
    c["speaker_beta"] = check_number("speaker_beta", config.speaker_beta, lo=-20.0, hi=20.0)
    c["w_object"] = check_number("w_object", config.w_object, lo=0.0)
    c["w_episode_object"] = check_number("w_episode_object", config.w_episode_object, lo=0.0)
    c["w_elsewhere"] = check_number("w_elsewhere", config.w_elsewhere, lo=0.0, lo_open=True)
    c["elsewhere_distance_m"] = check_pair("elsewhere_distance_m", config.elsewhere_distance_m, lo=0.1, hi=100.0)
    c["elsewhere_yaw_deg"] = check_number("elsewhere_yaw_deg", config.elsewhere_yaw_deg, lo=0.0, hi=180.0)
    c["elsewhere_elevation_deg"] = check_pair(
        "elsewhere_elevation_deg", config.elsewhere_elevation_deg, lo=-80.0, hi=80.0
    )
    c["head_lag_s"] = check_number("head_lag_s", config.head_lag_s, lo=0.0, hi=5.0)
    for name in ("head_sway_deg", "head_roll_deg", "tracker_drift_deg", "tracker_jitter_deg"):
        c[name] = check_number(name, getattr(config, name), lo=0.0, hi=30.0)
    c["tracker_tilt_factor"] = check_number("tracker_tilt_factor", config.tracker_tilt_factor, lo=0.0, hi=10.0)
    c["measurement_scale_deg"] = check_pair("measurement_scale_deg", config.measurement_scale_deg, lo=0.0, hi=45.0)
    c["dropout_fraction"] = check_number("dropout_fraction", config.dropout_fraction, lo=0.0, hi=0.5)
    c["head_turn_limit_deg"] = check_number("head_turn_limit_deg", config.head_turn_limit_deg, lo=0.0, hi=180.0)
    c["dropout_s"] = check_pair("dropout_s", config.dropout_s, lo=0.0, lo_open=True)
    c["late_early_prob"] = check_number("late_early_prob", config.late_early_prob, lo=0.0, hi=1.0)
    c["late_early_fraction"] = check_pair("late_early_fraction", config.late_early_fraction, lo=0.0, hi=0.9)
    c["quiet_people"] = check_int("quiet_people", config.quiet_people, lo=0, hi=_MAX_PEOPLE)
    c["quiet_weight"] = check_number("quiet_weight", config.quiet_weight, lo=0.0, hi=1.0, lo_open=True)
    c["held_cone_share"] = check_number("held_cone_share", config.held_cone_share, lo=0.0, hi=1.0)
    return ConversationConfig(**c)


# ---------------------------------------------------------------------------
# NumPy geometry (float64; the conventions of jaxgaze.geometry)


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _yaw_pitch_to_direction(yaw, pitch):
    """NumPy :func:`jaxgaze.geometry.yaw_pitch_to_direction` (= ``Φ``)."""
    cp = np.cos(pitch)
    return np.stack(np.broadcast_arrays(cp * np.cos(yaw), cp * np.sin(yaw), np.sin(pitch)), axis=-1)


def _direction_to_yaw_pitch(d):
    """NumPy :func:`jaxgaze.geometry.direction_to_yaw_pitch` (= ``Φ⁻¹``)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.arctan2(y, x), np.arctan2(z, np.hypot(x, y))


def _wrap(a):
    return a - 2 * np.pi * np.ceil((a - np.pi) / (2 * np.pi))


def _head_pose_to_rotation(yaw, pitch, roll):
    """NumPy float64 :func:`jaxgaze.geometry.head_pose_to_rotation`: ``R_z(yaw) R_y(−pitch) R_x(roll)``."""
    yaw, pitch, roll = np.broadcast_arrays(yaw, pitch, roll)
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    # R_y(−p) = [[cp, 0, −sp], [0, 1, 0], [sp, 0, cp]]; forward +x ↦ (cp, 0, sp).
    R = np.empty(yaw.shape + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = -sy * cr - cy * sp * sr
    R[..., 0, 2] = sy * sr - cy * sp * cr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = cy * cr - sy * sp * sr
    R[..., 1, 2] = -cy * sr - sy * sp * cr
    R[..., 2, 0] = sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def _smooth(rng, times, shape, periods, components=3):
    """Smooth random signal in ``[−1, 1]``, shape ``(T, *shape)`` (sum of random sinusoids)."""
    full = tuple(shape) + (components,)
    period = rng.uniform(periods[0], periods[1], full)
    phase = rng.uniform(0.0, 2 * np.pi, full)
    amp = rng.uniform(0.5, 1.0, full)
    t = times.reshape((-1,) + (1,) * len(full))
    return np.sum(amp * np.sin(2 * np.pi * t / period + phase), axis=-1) / np.sum(amp, axis=-1)


def _low_pass(x, time_constant_s, fps):
    """Causal exponential filter along axis 0, ``y_t = a y_{t−1} + (1 − a) x_t``, ``y_0 = x_0``."""
    frames = time_constant_s * fps
    if frames < 1e-3:
        return x.copy()
    a = math.exp(-1.0 / frames)
    y = np.empty_like(x)
    y[0] = x[0]
    for t in range(1, x.shape[0]):
        y[t] = a * y[t - 1] + (1 - a) * x[t]
    return y


# ---------------------------------------------------------------------------
# Building blocks


def _layout(rng, config, P, K, standing):
    """Mean eye positions ``(P, 3)``, body yaw ``(P,)``, objects ``(K, 3)``, circle centre and radius."""
    lo, hi = config.standing_radius_m if standing else config.seated_radius_m
    radius = lo + (hi - lo) * min(max((P - 3) / 5.0, 0.0), 1.0)
    radius = radius + rng.uniform(-1.0, 1.0) * config.radius_jitter_m
    centre = np.array([*rng.uniform(-0.5, 0.5, 2), 0.0])
    spacing = 2 * np.pi / P
    angle = rng.uniform(0, 2 * np.pi) + spacing * np.arange(P) + rng.uniform(-1, 1, P) * config.seat_jitter * spacing
    heights = rng.uniform(*(config.standing_eye_height_m if standing else config.seated_eye_height_m), P)
    eye0 = np.stack([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle), heights], axis=-1)
    body_yaw = _wrap(angle + np.pi)

    screen = K >= 1 and rng.uniform() < config.screen_prob
    n_table = K - int(screen)
    disc = config.object_disc * radius
    table = []
    for _ in range(n_table):
        for attempt in range(200):
            r = disc * math.sqrt(rng.uniform())
            a = rng.uniform(0, 2 * np.pi)
            p = centre[:2] + r * np.array([math.cos(a), math.sin(a)])
            if all(np.linalg.norm(p - q) >= config.object_spacing_m for q in table) or attempt == 199:
                break
        table.append(p)
    objects = [np.array([p[0], p[1], config.table_height_m + rng.uniform(0.0, 0.05)]) for p in table]
    if screen:
        gap = rng.integers(P)  # between seat gap and gap + 1
        a = angle[gap] + 0.5 * ((angle[(gap + 1) % P] - angle[gap]) % (2 * np.pi))
        d = radius + rng.uniform(*config.screen_distance_m)
        objects.append(np.array([centre[0] + d * math.cos(a), centre[1] + d * math.sin(a),
                                 rng.uniform(*config.screen_height_m)]))
    objects = np.asarray(objects, np.float64).reshape(K, 3)
    return eye0, body_yaw, objects


def _presence(rng, config, T, P, fps):
    """``in_scene (T, P)`` (late arrival / early leave) and ``present (T, P)`` (also tracker dropouts)."""
    duration = T / fps
    in_scene = np.ones((T, P), bool)
    if rng.uniform() < config.late_early_prob:
        i = rng.integers(P)
        missing = int(round(rng.uniform(*config.late_early_fraction) * T))
        if rng.uniform() < 0.5:
            in_scene[:missing, i] = False  # arrives late
        else:
            in_scene[T - missing :, i] = False  # leaves early
    present = in_scene.copy()
    mean_len = 0.5 * (config.dropout_s[0] + config.dropout_s[1])
    rate = config.dropout_fraction * duration / mean_len
    for i in range(P):
        for _ in range(rng.poisson(rate)):
            start = rng.uniform(0, duration)
            length = rng.uniform(*config.dropout_s)
            a, b = int(round(start * fps)), int(round((start + length) * fps))
            present[a : max(b, a + 1), i] = False
    return in_scene, present


def _turns(rng, config, T, P, fps, in_scene):
    """Speaking flags ``(T, P)``: one main speaker at a time, with gaps and overlaps."""
    duration = T / fps
    times = np.arange(T) / fps
    speaking = np.zeros((T, P), bool)

    def length():
        d = config.turn_median_s * math.exp(config.turn_sigma * rng.standard_normal())
        return min(max(d, config.turn_s[0]), config.turn_s[1])

    def frame(t):
        return min(max(int(round(t * fps)), 0), T - 1)

    d = length()
    start = -rng.uniform() * d
    candidates = np.flatnonzero(in_scene[0])
    speaker = int(rng.choice(candidates if candidates.size else np.arange(P)))
    while start < duration:
        end = start + d
        speaking[(times >= start) & (times < end), speaker] = True
        start = end + rng.uniform(*config.gap_s)
        d = length()
        others = [j for j in np.flatnonzero(in_scene[frame(start)]) if j != speaker]
        if others and config.quiet_people:
            weight = np.where(np.asarray(others) >= P - config.quiet_people, config.quiet_weight, 1.0)
            speaker = int(rng.choice(others, p=weight / weight.sum()))
        elif others:
            speaker = int(others[rng.integers(len(others))])
        elif not in_scene[frame(start), speaker]:
            break
    return speaking & in_scene


def _episodes(rng, config, duration, K):
    """Joint-attention episodes ``(E, 3)``: start, end (seconds) and object index."""
    out = []
    if K == 0:
        return np.zeros((0, 3))
    start = rng.uniform(0.0, 0.5) * config.episode_interval_s[1]
    while start < duration:
        out.append((start, start + rng.uniform(*config.episode_s), rng.integers(K)))
        start += rng.uniform(*config.episode_interval_s)
    return np.asarray(out, np.float64).reshape(-1, 3)


def _focus(rng, config, T, P, K, fps, eyes, body_yaw, present, speaking, active):
    """Targets ``(T, P)``, target points ``(T, P, 3)`` and the fixation segment of each frame ``(T, P)`` (step 5)."""
    deg = math.pi / 180
    boost = math.exp(config.speaker_beta)
    # Frames where the speaking set or the active episode changes: forced re-draws, per-person delay.
    changed = np.zeros(T, bool)
    changed[1:] = np.any(speaking[1:] != speaking[:-1], axis=1) | (active[1:] != active[:-1])
    events = np.flatnonzero(changed)
    delay = np.rint(rng.uniform(0.0, config.reaction_s, (events.size, P)) * fps).astype(np.int64)
    force = np.zeros((T, P), bool)
    for i in range(P):
        f = events + delay[:, i]
        force[f[f < T], i] = True

    target = np.full((T, P), ELSEWHERE, np.int64)
    points = np.full((T, P, 3), np.nan)
    segment = np.zeros((T, P), np.int64)
    count = 0
    w_obj = np.full(K, config.w_object)
    for i in range(P):
        cur, seg_end, point = None, 0, None
        for t in range(T):
            if not present[t, i]:
                cur = None
                continue
            if cur is None or t >= seg_end or force[t, i] or (0 <= cur < P and not present[t, cur]):
                w_people = np.where(speaking[t], config.w_person * boost, config.w_person) * present[t]
                w_people[i] = 0.0
                w = w_obj.copy()
                if active[t] >= 0:
                    w[active[t]] = config.w_episode_object
                w = np.concatenate([w_people, w, [config.w_elsewhere]])
                c = np.cumsum(w)
                choice = min(int(np.searchsorted(c, rng.uniform() * c[-1], side="right")), P + K)
                cur = ELSEWHERE if choice == P + K else choice
                seg_end = t + max(1, int(round(rng.uniform(*config.fixation_s) * fps)))
                count += 1
                if cur == ELSEWHERE:
                    yaw = body_yaw[i] + rng.uniform(-1.0, 1.0) * config.elsewhere_yaw_deg * deg
                    pitch = rng.uniform(*config.elsewhere_elevation_deg) * deg
                    point = eyes[t, i] + rng.uniform(*config.elsewhere_distance_m) * _yaw_pitch_to_direction(
                        yaw, pitch
                    )
            target[t, i] = cur
            segment[t, i] = count
            if 0 <= cur < P:
                points[t, i] = eyes[t, cur]
            elif cur == ELSEWHERE:
                points[t, i] = point
    return target, points, segment  # object points are filled in by the caller


def _upright_frame(forward):
    """Columns ``(f, left, up')``, ``left = unit(e_z × f)``, ``up' = f × left`` (as in calibration, NumPy)."""
    f = _unit(forward)
    left = _unit(np.cross(np.array([0.0, 0.0, 1.0]), f))
    up = np.cross(f, left)
    return np.stack([f, left, up], axis=-1)


def _wearer(key, config, times, fps, cone, sight, calibration_frames):
    """One head-mounted-camera wearer (step 10), from its own key.

    ``sight (T, 3)``: unit world line of sight from the eye. Returns the eye centre
    ``e (3,)`` and primary direction ``v (3,)`` in the camera frame, the gaze in the
    camera frame ``v' (T, 3)``, the true and reported camera rotations ``(T, 3, 3)``
    (camera to world), the reported-centre noise ``(T, 3)`` and the calibration
    points of regard ``(M, 3)``.
    """
    deg = math.pi / 180
    k_mount, k_calibration, k_noise = jax.random.split(key, 3)
    mounting = random_mounting(k_mount)
    eye = np.asarray(mounting.eye_center_in_camera, np.float64)
    v = _unit(np.asarray(mounting.direction_in_camera, np.float64))
    rng = _seed(k_noise)
    T = times.size

    # Actual gaze in the camera frame: v' = unit(v + d₁ u₁ + d₂ u₂), d ~ N(0, h² I₂).
    basis = _upright_frame(v)  # columns (v, u₁, u₂), orthonormal
    d = cone * rng.standard_normal((T, 2))
    gaze = _unit(v + d[:, :1] * basis[:, 1] + d[:, 1:] * basis[:, 2])

    # R maps v' onto the line of sight, upright, then rolls about it (leaving v' ↦ sight).
    roll = config.head_roll_deg * deg * _smooth(rng, times, (), periods=(3.0, 12.0))
    frame_cam = _upright_frame(gaze)
    frame_world = _upright_frame(sight)
    cos, sin = np.cos(roll)[:, None], np.sin(roll)[:, None]
    left, up = frame_world[..., 1], frame_world[..., 2]
    frame_world = np.stack([frame_world[..., 0], cos * left + sin * up, cos * up - sin * left], axis=-1)
    R = np.einsum("tij,tkj->tik", frame_world, frame_cam)  # R_world_from_camera = F_world F_cameraᵀ

    # Structure-from-motion noise of the reported pose.
    err = _SFM_ROTATION_DEG * deg * rng.standard_normal((T, 3))
    R_rep = R @ _head_pose_to_rotation(err[:, 0], err[:, 1], err[:, 2])
    centre_noise = _SFM_POSITION_M * rng.standard_normal((T, 3))

    session = simulate_calibration_session(
        k_calibration, calibration_frames, mounting=mounting, eye_in_head=float(cone), fps=fps
    )
    points = np.asarray(session.points_of_regard_a(), np.float64)
    return eye, v, gaze, R, R_rep, centre_noise, points


# ---------------------------------------------------------------------------
# Public API


def _seed(key) -> np.random.Generator:
    """A NumPy generator seeded by one ``jax.random.bits`` draw from ``key``."""
    bits = np.asarray(jax.random.bits(key, (4,), dtype=jnp.uint32))
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(b) for b in bits])))


def simulate_conversation(
    key,
    *,
    num_people: int | None = None,
    num_objects: int | None = None,
    duration_s: float = 60.0,
    fps: float = 10.0,
    standing: bool | None = None,
    config: ConversationConfig | None = None,
    num_wearers: int = 0,
    calibration_frames: int = 100,
) -> Conversation:
    """Simulate one multi-party conversation with ground truth (see the module docstring).

    Args:
        key: a single ``jax.random`` key; the same key gives the same scene.
        num_people: ``P ≥ 2``; ``None`` draws it uniformly in ``config.num_people_range`` (3–8).
        num_objects: ``K ≥ 0``; ``None`` draws it uniformly in ``config.num_objects_range`` (1–3).
        duration_s: length in seconds (> 0); ``T = round(duration_s · fps) ≥ 2``.
        fps: frames per second (> 0).
        standing: standing in a circle (``True``) or seated at a table (``False``);
            ``None`` draws it with probability ``config.standing_prob``.
        config: a :class:`ConversationConfig` (default :func:`conversation_config`).
        num_wearers: the first ``num_wearers`` people (``0 … P``) wear head-mounted cameras
            (step 10 of the module docstring); 0 (the default) gives the plain scene, and
            wearers change no non-wearer output.
        calibration_frames: frames ``M ≥ 2`` of each wearer's calibration session.

    Returns:
        :class:`Conversation` with ``(T, P, ...)`` arrays.

    Raises:
        ValueError: naming the argument or config field, for a bad key, count,
            timing, ``standing``, ``num_wearers`` (also more than ``P``, drawn or given),
            ``calibration_frames`` or configuration.
    """
    check_key(key)
    config = _check_config(ConversationConfig() if config is None else config)
    if num_people is not None:
        num_people = check_int("num_people", num_people, lo=2, hi=_MAX_PEOPLE)
    if num_objects is not None:
        num_objects = check_int("num_objects", num_objects, lo=0, hi=_MAX_OBJECTS)
    num_wearers = check_int("num_wearers", num_wearers, lo=0, hi=_MAX_PEOPLE if num_people is None else num_people)
    calibration_frames = check_int("calibration_frames", calibration_frames, lo=2, hi=_MAX_CALIBRATION_FRAMES)
    if standing is not None and not isinstance(standing, (bool, np.bool_)):
        raise ValueError(f"standing must be True, False or None, got {standing!r}")
    T, fps = check_frames(duration_s, fps, max_frames=1_000_000)
    rng = _seed(key)
    deg = math.pi / 180

    # Scene-level draws (always made, so the rest of the stream does not depend on the arguments).
    p_draw = int(rng.integers(config.num_people_range[0], config.num_people_range[1] + 1))
    k_draw = int(rng.integers(config.num_objects_range[0], config.num_objects_range[1] + 1))
    s_draw = bool(rng.uniform() < config.standing_prob)
    P = p_draw if num_people is None else num_people
    K = k_draw if num_objects is None else num_objects
    standing = s_draw if standing is None else bool(standing)
    if num_wearers > P:
        raise ValueError(f"num_wearers must be at most the number of people P = {P} (drawn), got {num_wearers}")
    times = np.arange(T) / fps
    duration = T / fps

    # 1. Layout and sway.
    eye0, body_yaw, objects = _layout(rng, config, P, K, standing)
    eyes = eye0[None] + config.body_sway_m * _smooth(rng, times, (P, 3), periods=(3.0, 15.0))

    # 3. Traits.
    bias_mag = rng.uniform(*config.bias_deg, P) * deg
    bias_dir = rng.uniform(0, 2 * np.pi, P)
    bias = bias_mag[:, None] * np.stack([np.cos(bias_dir), np.sin(bias_dir)], axis=-1)
    cone = rng.uniform(*config.cone_width_deg, P) * deg
    kappa = rng.uniform(*config.head_fraction, P)

    # 9. Presence; 2. turns; 4. episodes.
    in_scene, present = _presence(rng, config, T, P, fps)
    speaking = _turns(rng, config, T, P, fps, in_scene)
    episodes = _episodes(rng, config, duration, K)
    active = np.full(T, -1, np.int64)
    for start, end, k in episodes:
        active[(times >= start) & (times < end)] = int(k)

    # 5. Visual focus.
    target, points, segment = _focus(rng, config, T, P, K, fps, eyes, body_yaw, present, speaking, active)
    on_object = target >= P
    points[on_object] = objects[target[on_object] - P]

    # 6. Head: κ of the line of sight relative to the body, lagged, plus sway and roll.
    sight = np.where(present[..., None], _unit(np.nan_to_num(points) - eyes), 0.0)
    sight_yaw, sight_pitch = _direction_to_yaw_pitch(sight)
    rel = np.stack([_wrap(sight_yaw - body_yaw), sight_pitch], axis=-1)
    rel = np.where(present[..., None], rel, 0.0)
    turn = kappa[:, None] * rel
    if config.head_turn_limit_deg > 0:  # the turn saturates: a non-linear head–gaze map
        limit = config.head_turn_limit_deg * deg
        turn = limit * np.tanh(turn / limit)
    head = _low_pass(turn, config.head_lag_s, fps)
    head = head + config.head_sway_deg * deg * _smooth(rng, times, (P, 2), periods=(2.0, 10.0))
    roll = config.head_roll_deg * deg * _smooth(rng, times, (P,), periods=(3.0, 12.0))
    R_true = _head_pose_to_rotation(body_yaw + head[..., 0], head[..., 1], roll)
    err = config.tracker_drift_deg * deg * _smooth(rng, times, (P, 3), periods=(5.0, 30.0))
    err = err + config.tracker_jitter_deg * deg * rng.standard_normal((T, P, 3))
    err[..., 1] *= config.tracker_tilt_factor  # pitch read worse (or better) than yaw and roll
    R_rep = R_true @ _head_pose_to_rotation(err[..., 0], err[..., 1], err[..., 2])

    # 7. True gaze: the direction to the target rotated on its tangent plane by δ = h z₁ + s z₂.
    scale = rng.uniform(*config.measurement_scale_deg, (T, P)) * deg
    z = rng.standard_normal((2, T, P, 2))
    if config.held_cone_share > 0:  # one draw per fixation segment (only then: other scenes keep their stream)
        held = rng.standard_normal((int(segment.max()) + 1, 2))[segment]
        z[0] = math.sqrt(1.0 - config.held_cone_share) * z[0] + math.sqrt(config.held_cone_share) * held
    delta = cone[None, :, None] * z[0] + scale[..., None] * z[1]
    u = sight
    e1 = _unit(np.cross(np.array([0.0, 0.0, 1.0]), u))
    e2 = np.cross(u, e1)
    step = delta[..., :1] * e1 + delta[..., 1:] * e2
    angle = np.linalg.norm(delta, axis=-1, keepdims=True)
    v_true = _unit(np.cos(angle) * u + np.sinc(angle / np.pi) * step)

    # 8. Measured gaze relative to the reported head pose.
    local = np.einsum("tpji,tpj->tpi", R_rep, v_true)
    yaw, tilt = _direction_to_yaw_pitch(local)
    gaze = np.stack([_wrap(yaw - bias[:, 0]), tilt - bias[:, 1]], axis=-1)

    # 10. Head-mounted cameras: a separate random stream, so nothing above changes.
    wearer = np.arange(P) < num_wearers
    camera_positions = np.full((T, P, 3), np.nan)
    eye_in_camera = np.full((P, 3), np.nan)
    calibration_points = np.full((P, calibration_frames if num_wearers else 0, 3), np.nan)
    if num_wearers:
        wearer_key = jax.random.fold_in(key, _WEARER_STREAM)
        for w in range(num_wearers):
            # Line of sight; where absent, the head model's forward axis.
            line = np.where(present[:, w, None], sight[:, w], R_true[:, w, :, 0])
            e, v, v_cam, R, R_cam, centre_noise, cal = _wearer(
                jax.random.fold_in(wearer_key, w), config, times, fps, cone[w], line, calibration_frames
            )
            R_true[:, w], R_rep[:, w] = R, R_cam
            v_true[:, w] = np.einsum("tij,tj->ti", R, v_cam)
            gaze[:, w] = 0.0
            scale[:, w] = 0.0
            bias[w] = np.stack(_direction_to_yaw_pitch(v))
            kappa[w] = 1.0
            camera_positions[:, w] = eyes[:, w] - np.einsum("tij,j->ti", R, e) + centre_noise
            eye_in_camera[w] = e
            calibration_points[w] = cal

    absent = ~present
    gaze[absent] = np.nan
    v_true[absent] = np.nan
    points[absent] = np.nan
    target[absent] = ELSEWHERE
    scale[absent] = 0.0
    return Conversation(
        eye_positions=eyes,
        R_world_from_head=R_rep,
        true_R_world_from_head=R_true,
        gaze_angles=gaze,
        measurement_scale=scale,
        present=present,
        speaking=speaking,
        target=target,
        target_positions=points,
        true_gaze_directions=v_true,
        object_positions=objects,
        bias=bias,
        cone_width=cone,
        head_fraction=kappa,
        body_yaw=body_yaw,
        episodes=episodes,
        standing=standing,
        fps=fps,
        config=config,
        wearer=wearer,
        camera_positions=camera_positions,
        eye_in_camera=eye_in_camera,
        calibration_points=calibration_points,
        fixation_segment=np.where(present, segment, -1),
    )


def simulate_conversations(key, num_scenes: int, **kwargs) -> list[Conversation]:
    """``num_scenes`` independent conversations: scene ``i`` uses ``jax.random.split(key, num_scenes)[i]``.

    Keyword arguments as in :func:`simulate_conversation`.
    """
    check_key(key)
    num_scenes = check_int("num_scenes", num_scenes)
    keys = jax.random.split(key, int(num_scenes))
    return [simulate_conversation(k, **kwargs) for k in keys]
