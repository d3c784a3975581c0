"""Starting points of the joint model: the two-step pipeline it improves on (Siegfried et al. 2017, eq. 2; Park et al. 2012, Sec. 3.3).

1. Each person's bias from the Spk rule generalised to a group: frames where exactly
   one other person speaks and the head is within 30° of them, ``N`` of them drawn
   at random from the first minute, then LMedS (eq. 2) on the offsets to the speaker.
2. The concurrences of the bias-corrected rays, frame by frame (mean-shift, eq. 5–6,
   with exclusive support), minus the modes at a person's head (those are people,
   which the model knows).
3. The remaining modes of all frames, clustered in space: each cluster seen in
   enough frames becomes one free concurrence, its centre per window the median of
   its modes there.
"""

from __future__ import annotations

from typing import NamedTuple

import math

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Float, Int

from jaxgaze.bias.estimators import lmeds_bias
from jaxgaze.bias.looking import (candidate_frames, direction_to_gaze_angles, gaze_angles_to_direction, gaze_offsets,
                                  head_target_angle, head_to_world, target_direction_head)
from jaxgaze.calibration import calibrate_cone
from jaxgaze.concurrence import ConcurrenceOptions, find_concurrences_over_frames
from jaxgaze.joint.data import JointData
from jaxgaze.joint.model import JointPrior, ModelArrays, head_gaze_angles, marginal_log_likelihood, people_head_angles
from jaxgaze.rays import GazeRays
from jaxgaze.results import name

__all__ = ["JointStart", "directions_to_people", "wearer_eyes", "calibrate_wearers", "speaker_rule_bias", "coupling_profile", "tilt_width_profile", "model_arrays", "corrected_rays", "initial_concurrences", "joint_start",
           "DEFAULT_CONCURRENCE_OPTIONS"]

#: The head's lag (s) the start assumes with head pose only (lags of a few tenths of a second are common).
START_HEAD_LAG = 0.2
#: The couplings :func:`coupling_profile` scores each person's head pose on.
COUPLING_GRID = np.array([0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95])
#: The ratios ``r`` of the gaze's scatter in tilt to that in yaw that :func:`tilt_width_profile` scores (head pose
#: only; a factor of about 1.26 apart, from the isotropic 1 to a tracker reading pitch 4× worse).
TILT_WIDTH_GRID = np.array([1.0, 1.25, 1.6, 2.0, 2.5, 3.2, 4.0])

#: The mean-shift options of the start: modes above the floor and below 3 m, and a
#: bandwidth-scaled search (Park et al. 2012, Sec. 3.3).
DEFAULT_CONCURRENCE_OPTIONS = ConcurrenceOptions(bounds=((-np.inf, -np.inf, 0.0), (np.inf, np.inf, 3.0)))


class JointStart(NamedTuple):
    """Where the joint fit starts, and the pipeline's own answer.

    Attributes:
        bias: ``(P, 2)`` Spk-LMedS biases (0 for a person with too few frames).
        bias_frames: ``(P,)`` frames each bias used.
        concurrence_centres: ``(W, K, 3)`` initial free concurrences per window.
        concurrence_support: ``(K,)`` frames in which each was found.
        eye_offset: ``(Nw, 3)`` each wearer's eye centre in the camera frame, from Park's
            calibration (:func:`~jaxgaze.calibration.calibrate_cone`); their bias is
            the angles of its primary direction.
        coupling: ``(P, 2)`` the head's share ``κ`` of the line of sight the start assumes
            (head pose only; ``None`` otherwise), with ``head_lag`` ``(P,)`` its lag ``τ`` (s).
        tilt_width_ratio: the ratio ``r`` of the gaze's scatter in tilt to that in yaw the start assumes (head pose
            only, :func:`tilt_width_profile`; ``None``: 1).
    """

    bias: Float[np.ndarray, "P 2"]
    bias_frames: Int[np.ndarray, " P"]
    concurrence_centres: Float[np.ndarray, "W K 3"]
    concurrence_support: Int[np.ndarray, " K"]
    eye_offset: Float[np.ndarray, "Nw 3"] = np.zeros((0, 3))
    coupling: Float[np.ndarray, "P 2"] | None = None
    head_lag: Float[np.ndarray, " P"] | None = None
    tilt_width_ratio: float | None = None

    @property
    def num_concurrences(self) -> int:
        return self.concurrence_centres.shape[1]


def directions_to_people(data: JointData) -> np.ndarray:
    """``(T, P, P, 3)``: the head-frame unit direction from person ``i`` (axis 1) to person ``j`` (axis 2)."""
    eyes = jnp.asarray(data.eye_positions)
    R = jnp.asarray(data.R_world_from_head)
    T, P = data.present.shape
    return np.asarray(target_direction_head(jnp.broadcast_to(eyes[:, :, None], (T, P, P, 3)),
                                            jnp.broadcast_to(eyes[:, None, :], (T, P, P, 3)),
                                            jnp.broadcast_to(R[:, :, None], (T, P, P, 3, 3))))


def speaker_rule_bias(
    data: JointData,
    key,
    *,
    num_frames: int = 40,
    window_s: float = 60.0,
    max_head_angle_deg: float = 30.0,
    min_frames: int = 5,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-person Spk-LMedS bias in a group (Siegfried et al. 2017, Sec. 3.2 and eq. 2).

    A frame is a candidate for person ``i`` when exactly one other present person
    speaks, ``i``'s head is within ``max_head_angle_deg`` of them and the frame lies
    in the first ``window_s`` seconds; ``num_frames`` candidates are drawn with
    ``key`` and the bias is the LMedS estimate of their offsets to the speaker.
    Fewer than ``min_frames`` candidates give a zero bias. Returns ``(bias (P, 2),
    frames used (P,))``.
    """
    T, P = data.present.shape
    speaking = (data.speaking > 0) & data.present
    u = directions_to_people(data)  # (T, i, j, 3)
    others_speaking = speaking[:, None, :] & ~np.eye(P, dtype=bool)[None]  # (T, i, j)
    single = others_speaking.sum(-1) == 1
    speaker = np.argmax(others_speaking, axis=-1)  # (T, i)
    to_speaker = np.take_along_axis(u, speaker[..., None, None], axis=2)[:, :, 0]  # (T, P, 3)
    angle = np.asarray(head_target_angle(jnp.asarray(to_speaker)))
    bias = np.zeros((P, 2))
    used = np.zeros(P, np.int64)
    keys = jax.random.split(key, P)
    for i in range(P):
        ok = single[:, i] & data.present[:, i]
        mask = np.asarray(candidate_frames(jnp.asarray(ok), jnp.asarray(angle[:, i]), fps=data.fps,
                                           max_head_angle_deg=max_head_angle_deg, window_s=window_s))
        frames = np.flatnonzero(mask)
        if frames.size < min_frames:
            continue
        pick = np.sort(frames[np.asarray(jax.random.choice(keys[i], frames.size, (min(num_frames, frames.size),),
                                                           replace=False))])
        o = gaze_offsets(jnp.asarray(data.gaze_angles[pick, i]), jnp.asarray(to_speaker[pick, i]))
        bias[i] = np.asarray(lmeds_bias(o)[0])
        used[i] = pick.size
    return bias, used


def model_arrays(data: JointData, centres, dtype) -> ModelArrays:
    """The joint model's arrays (:class:`~jaxgaze.joint.model.ModelArrays`) of a recording and initial concurrences."""
    T, P = data.present.shape
    f = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return ModelArrays(f(data.eye_positions), f(data.R_world_from_head), f(data.gaze_angles),
                       jnp.asarray(data.present), f(data.speaking), f(data.measurement_scale),
                       jnp.asarray(data.window, jnp.int32),
                       f(directions_to_people(data)) if data.head_motion is None else
                       people_head_angles(f(data.eye_positions), f(data.R_world_from_head)),
                       f(np.zeros((T, P, 0)) if data.head_motion is None else data.head_motion), f(centres),
                       f(data.calibration_points), jnp.asarray(data.calibration_mask),
                       jnp.asarray(data.wearers, jnp.int32).reshape(-1), jnp.ones(np.shape(centres)[1], bool))


def coupling_profile(data: JointData, key, *, head_lag: float = START_HEAD_LAG, prior: JointPrior = JointPrior(),
                     tilt_width_ratio: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each person's log likelihood of their head pose on a grid of couplings ``κ`` (head pose only; Stiefelhagen & Zhu 2002; Siegfried et al. 2017, eq. 2).

    For every ``κ`` of :data:`COUPLING_GRID` (both axes), the gaze read from the head
    (:func:`~jaxgaze.joint.model.head_gaze_angles`), each person's Spk-LMedS bias of that
    gaze refined with their cone width (BFGS), and the model's likelihood (:func:`~jaxgaze.joint.model.marginal_log_likelihood`,
    with the Jacobian) with the prior's cone width, speaker effect and no concurrences;
    the tilt's scatter ``tilt_width_ratio`` times the yaw's (``None``: the same).
    People are independent given these, so one grid serves everyone. A wrong ``κ`` maps
    a person's looks at one neighbour onto another; the refinement from a single ``κ``
    can stay in that mode. Returns ``(log likelihood (G, P), bias (G, P, 2))``.
    """
    _needs_head_only(data, "coupling_profile")
    P = data.num_people
    arrays = model_arrays(data, np.zeros((data.num_windows, 0, 3)), jnp.float32)
    scores, biases = [], []
    for kappa in COUPLING_GRID:
        coupling, lag = np.full((P, 2), kappa), np.full(P, head_lag)
        score, bias = _profile_score(arrays, _head_bias(data, key, coupling, lag), coupling, lag, prior,
                                     tilt_width_ratio)
        scores.append(score)
        biases.append(bias)
    return np.asarray(scores), np.asarray(biases)


def tilt_width_profile(data: JointData, key, coupling, *, head_lag: float = START_HEAD_LAG,
                       prior: JointPrior = JointPrior()) -> np.ndarray:
    """The log likelihood of everyone's head pose on the grid :data:`TILT_WIDTH_GRID` of ``r``, the ratio of the
    gaze's scatter in tilt to that in yaw (head pose only; Stiefelhagen & Zhu 2002), at the couplings ``coupling``
    ``(P, 2)``, as :func:`coupling_profile` scores a coupling. A tracker that reads pitch worse than yaw needs
    ``r > 1``; read at ``r = 1``, its wide tilts pull the couplings into wrong modes. Returns ``(R,)``."""
    _needs_head_only(data, "tilt_width_profile")
    coupling, lag = np.asarray(coupling, float), np.full(data.num_people, head_lag)
    if coupling.shape != (data.num_people, 2) or not np.all((coupling > 0) & (coupling <= 1)):
        raise ValueError(f"tilt_width_profile needs couplings of shape ({data.num_people}, 2) in (0, 1], got shape "
                         f"{coupling.shape} with values {np.round(coupling, 3).tolist()}")
    arrays = model_arrays(data, np.zeros((data.num_windows, 0, 3)), jnp.float32)
    bias = _head_bias(data, key, coupling, lag)
    scores = [np.sum(_profile_score(arrays, bias, coupling, lag, prior, float(ratio))[0]) for ratio in TILT_WIDTH_GRID]
    return np.asarray(scores)


def _needs_head_only(data: JointData, caller: str) -> None:
    if data.head_motion is None:
        raise ValueError(f"{caller} needs head pose only data (joint_data(..., gaze_angles=None))")


def _head_bias(data: JointData, key, coupling, lag) -> np.ndarray:
    """``(P, 2)``: each person's Spk-LMedS bias of the gaze read from the head at ``coupling`` and ``lag``."""
    gaze = np.asarray(head_gaze_angles(jnp.asarray(data.head_motion), jnp.asarray(coupling), jnp.asarray(lag)))
    return speaker_rule_bias(data._replace(gaze_angles=np.where(data.present[..., None], gaze, 0.0)), key)[0]


def _profile_score(arrays: ModelArrays, bias, coupling, lag, prior: JointPrior,
                   tilt_width_ratio: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each person's log likelihood ``(P,)`` at ``coupling`` and ``tilt_width_ratio``, with their bias refined from
    ``bias`` ``(P, 2)`` and their cone width from the prior's, and the refined bias."""
    P = arrays.present.shape[1]
    params = {"alpha_person": 0.0, "alpha_object": 0.0, "speaker_effect": prior.speaker_log_ratio, "stay": 0.9,
              "locations": np.zeros(arrays.location_centres.shape), "coupling": coupling, "head_lag": lag,
              # 1 is the isotropic model's scatter exactly; always present, one compiled program serves both
              "tilt_width_ratio": 1.0 if tilt_width_ratio is None else tilt_width_ratio}
    params = {k: jnp.asarray(v, jnp.float32) for k, v in params.items()}
    free = {"bias": jnp.asarray(bias, jnp.float32), "log_width": jnp.full(P, math.log(prior.cone_width_median),
                                                                          jnp.float32)}
    score, free = _profile_point(free, params, arrays)
    return np.asarray(score), np.asarray(free["bias"])


@jax.jit
def _profile_point(free: dict, params: dict, arrays: ModelArrays):
    """Every person's bias and cone width refined (BFGS, 50 steps) at fixed ``κ``; their log likelihoods ``(P,)``."""
    def per_person(z):
        return jnp.sum(marginal_log_likelihood({**params, "bias": z["bias"], "cone_width": jnp.exp(z["log_width"])},
                                               arrays), axis=0)

    flat, unravel = ravel_pytree(free)
    solution = optx.minimise(lambda x, _: -jnp.sum(per_person(unravel(x))), optx.BFGS(rtol=1e-4, atol=1e-4), flat,
                             max_steps=50, throw=False)
    better = jnp.all(jnp.isfinite(solution.value)) & (jnp.sum(per_person(unravel(solution.value)))
                                                      >= jnp.sum(per_person(free)))
    z = unravel(jnp.where(better, solution.value, flat))
    return per_person(z), z


def wearer_eyes(data: JointData, eye_offset) -> np.ndarray:
    """``(T, P, 3)`` eye midpoints: the camera centre plus ``R c`` for each wearer (Park et al. 2012, Sec. 3.2)."""
    eyes = np.array(data.eye_positions, copy=True)
    for n, i in enumerate(data.wearers):
        eyes[:, i] += np.einsum("tij,j->ti", data.R_world_from_head[:, i], np.asarray(eye_offset)[n])
    return eyes


def calibrate_wearers(data: JointData, key) -> tuple[np.ndarray, np.ndarray]:
    """Park's calibration of each wearer (Sec. 3.2): ``(eye offsets (Nw, 3), primary-ray biases (Nw, 2))``."""
    offsets, biases = [], []
    for n, i in enumerate(data.wearers):
        points = data.calibration_points[i][data.calibration_mask[i]]
        fit = calibrate_cone(jnp.asarray(points), key=jax.random.fold_in(key, n), throw=False)
        ok = name(fit.result) == "successful"
        offsets.append(np.asarray(fit.eye_center) if ok else np.zeros(3))
        direction = np.asarray(fit.direction) if ok else np.array([1.0, 0.0, 0.0])
        biases.append(np.asarray(direction_to_gaze_angles(jnp.asarray(direction))))
    return np.reshape(offsets, (-1, 3)), np.reshape(biases, (-1, 2))


def corrected_rays(data: JointData, bias, cone_width, eye_offset=None) -> GazeRays:
    """``(T, P)`` world-frame rays ``(p_ti, R_ti Φ(g_ti + b_i))`` with bandwidth ``h_i``, masked by presence.

    Wearers' rays start at their eyes, the camera centre plus ``R c`` (``eye_offset``, default 0).
    """
    d = head_to_world(gaze_angles_to_direction(jnp.asarray(data.gaze_angles) + jnp.asarray(bias)[None]),
                      jnp.asarray(data.R_world_from_head))
    h = jnp.broadcast_to(jnp.asarray(cone_width, d.dtype), data.present.shape)
    offset = np.zeros((len(data.wearers), 3)) if eye_offset is None else eye_offset
    return GazeRays(wearer_eyes(data, offset), d, h, data.present)


def initial_concurrences(
    data: JointData,
    rays: GazeRays,
    *,
    options: ConcurrenceOptions = DEFAULT_CONCURRENCE_OPTIONS,
    stride: int = 1,
    person_angle: float = 0.2,
    cluster_angle: float = 0.15,
    min_share: float = 0.03,
    max_concurrences: int = 8,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Free concurrences from the mean-shift modes of every ``stride``-th frame (Park et al. 2012, Sec. 3.3).

    A mode is a person, not a free concurrence, when at least half of its rays pass
    within ``person_angle`` (radians) of another person's eyes; those modes are
    dropped. The rest are clustered greedily: two modes are neighbours when, seen
    from the eyes of either one's rays, they lie within ``cluster_angle`` (radians)
    of each other (a far mode's error runs along the rays, so distance in metres
    would split it); the mode with most neighbours takes them all, and so on. A cluster found in at least
    ``min_share`` of the searched frames (and at least 2) is kept, up to
    ``max_concurrences``. Returns ``(centres (W, K, 3), support (K,))``.
    """
    frames = np.arange(0, data.num_frames, stride)
    # Frames a stride apart are no recording to warm-start (the default decides for consecutive ones).
    found = find_concurrences_over_frames(rays[frames], options, progress=progress,
                                          warm_start=None if stride == 1 else False)
    valid = np.asarray(found.valid)
    locations = np.asarray(found.locations)
    membership = np.asarray(found.membership)  # (F, P): each ray's mode, −1 for none
    directions = np.asarray(rays.directions)[frames]
    eyes = data.eye_positions[frames]
    to_people = eyes[:, None, :, :] - eyes[:, :, None, :]
    to_people /= np.maximum(np.linalg.norm(to_people, axis=-1, keepdims=True), 1e-9)
    others = data.present[frames][:, None, :] & ~np.eye(data.num_people, dtype=bool)[None]
    cosine = np.where(others, np.einsum("fik,fijk->fij", directions, to_people), -1.0)
    at_person = cosine.max(axis=-1) > np.cos(person_angle)  # (F, P)

    points, t_index, viewpoints = [], [], []
    for f, k in zip(*np.nonzero(valid)):
        members = membership[f] == k
        if not members.any() or at_person[f, members].mean() >= 0.5:
            continue
        points.append(locations[f, k])
        t_index.append(f)
        viewpoints.append(eyes[f, members].mean(axis=0))
    W = data.num_windows
    centres, support = [], []
    if points:
        points, t_index, viewpoints = np.asarray(points), np.asarray(t_index), np.asarray(viewpoints)
        a = points[None, :, :] - viewpoints[:, None, :]  # (viewpoint m, mode n)
        a /= np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-9)
        own = np.einsum("mmk->mk", a)
        angle = np.arccos(np.clip(np.einsum("mk,mnk->mn", own, a), -1.0, 1.0))
        neighbours = np.minimum(angle, angle.T) < cluster_angle
        free = np.ones(len(points), bool)
        least = max(2, int(np.ceil(min_share * frames.size)))
        for m in np.argsort(-neighbours.sum(axis=1), kind="stable"):
            if not free[m] or len(centres) >= max_concurrences:
                continue
            members = np.flatnonzero(neighbours[m] & free)
            free[members] = False
            seen = np.unique(t_index[members])
            if seen.size < least:
                continue
            centre = np.median(points[members], axis=0)
            windows = data.window[frames[t_index[members]]]
            per_window = np.stack([np.median(points[members][windows == w], axis=0) if np.any(windows == w)
                                   else centre for w in range(W)])
            centres.append(per_window)
            support.append(seen.size * stride)
    if not centres:
        return np.zeros((W, 0, 3)), np.zeros(0, np.int64)
    return np.stack(centres, axis=1), np.asarray(support, np.int64)


def joint_start(
    data: JointData,
    *,
    key,
    cone_width: float = 0.07,
    options: ConcurrenceOptions = DEFAULT_CONCURRENCE_OPTIONS,
    stride: int | None = None,
    progress: bool = False,
) -> JointStart:
    """The pipeline's answer as the joint fit's start: Spk-LMedS biases (Park's calibration for wearers),
    then the concurrences of the corrected rays.

    ``stride`` thins the frames searched for concurrences (default: about 300 frames).
    With head pose only, the gaze is read from the head with each person's
    best ``κ`` of :func:`coupling_profile` and ``τ =`` :data:`START_HEAD_LAG`
    (:func:`~jaxgaze.joint.model.head_gaze_angles`). The tilt's width ratio ``r`` is the best of
    :func:`tilt_width_profile` at those couplings; where it is not 1, the couplings are scored again at it.
    """
    coupling = head_lag = ratio = None
    if data.head_motion is not None:
        head_lag = np.full(data.num_people, START_HEAD_LAG)
        scores, _ = coupling_profile(data, key)
        coupling = np.repeat(COUPLING_GRID[np.argmax(scores, axis=0)][:, None], 2, axis=1)
        ratio = float(TILT_WIDTH_GRID[np.argmax(tilt_width_profile(data, key, coupling))])
        if ratio != 1.0:
            scores, _ = coupling_profile(data, key, tilt_width_ratio=ratio)
            coupling = np.repeat(COUPLING_GRID[np.argmax(scores, axis=0)][:, None], 2, axis=1)
        gaze = np.asarray(head_gaze_angles(jnp.asarray(data.head_motion), jnp.asarray(coupling), jnp.asarray(head_lag)))
        data = data._replace(gaze_angles=np.where(data.present[..., None], gaze, 0.0))
    bias, used = speaker_rule_bias(data, key)
    eye_offset, wearer_bias = calibrate_wearers(data, key)
    bias[list(data.wearers)] = wearer_bias
    rays = corrected_rays(data, bias, cone_width, eye_offset)
    stride = max(1, data.num_frames // 300) if stride is None else int(stride)
    centres, support = initial_concurrences(data, rays, options=options, stride=stride, progress=progress)
    return JointStart(bias, used, centres, support, eye_offset, coupling, head_lag, ratio)

