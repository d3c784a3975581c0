"""The speaker-prior bias adaptation pipeline, arrays in, report out (Siegfried et al. 2017, Sec. 3–4).

One call, :func:`adapt_bias`, runs what ``jaxgaze bias`` runs between reading its
files and writing its report: the eye→target direction ``u_t`` in the head frame,
the Spk candidates (partner speaking, head within ``max_head_angle_deg`` of the
target, first ``window_s`` seconds), a random draw of ``num_frames`` of them, the
bias from their offsets ``o = angles(u_t) − g`` (mean, LMedS eq. 2, or the Bayesian
mixture), and per frame the error ``∠(Φ(g + b), u_t)`` and the looking-at decision
(eq. 1) or its posterior probability. No file is read and nothing is printed.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.bias.estimators import METHODS, BiasEstimate, estimate_bias
from jaxgaze.bias.looking import (
    FrameSelection,
    angular_error,
    candidate_frames,
    gaze_offsets,
    head_target_angle,
    is_looking_at,
    looking_probability,
    select_frames,
    target_direction_head,
)
from jaxgaze.bias.speech import SpeechSegments, choose_partner, speaking_at
from jaxgaze.rays import check_distance

__all__ = ["BIAS_FRAME_COLUMNS", "DEFAULT_NUM_FRAMES", "BiasAdaptation", "BiasInputError", "adapt_bias"]

#: The per-frame table of a :class:`BiasAdaptation` (:meth:`BiasAdaptation.frame_table`).
BIAS_FRAME_COLUMNS = ("frame", "time", "partner_speaking", "head_target_angle_deg", "selected",
                      "error_uncorrected_deg", "error_deg", "looking", "probability")
#: Default ``num_frames`` per method: the paper's N (Spk-Mean 20, Spk-Med 40); the mixture uses more.
DEFAULT_NUM_FRAMES = {"bayes": 60, "lmeds": 40, "mean": 20}
#: Targets closer than this to the eyes (metres) have no direction.
MIN_TARGET_DISTANCE = 1e-3


class BiasInputError(ValueError):
    """Bad input to :func:`adapt_bias`: ``argument`` names it, ``index`` is the first bad frame (or ``None``)."""

    def __init__(self, message: str, argument: str, index: Optional[int] = None):
        super().__init__(message)
        self.argument = argument
        self.index = index


class BiasAdaptation(NamedTuple):
    """What :func:`adapt_bias` found (T frames, K drawn; angles in radians).

    Attributes:
        estimate: the :class:`BiasEstimate` from the drawn frames' offsets.
        selection: the :class:`FrameSelection` (``indices (K,)``, ``candidates (T,)``, counts).
        frames: ``(T,)`` frame ids; ``times``: ``(T,)`` seconds.
        partner: the partner's speaker name (``None`` when flags were given).
        partner_speaking: ``(T,)`` bool; ``in_window``: ``(T,)`` bool, ``time − time[0] < window_s``.
        target_dir_head: ``(T, 3)`` unit ``u_t``; ``head_target_angle``: ``(T,)`` ``∠(+x, u_t)``.
        offsets: ``(K, 2)`` offsets of the drawn frames (what the estimator saw).
        silent: ``(M,)`` indices of the partner-silent frames given to ``"bayes"`` as contrast.
        error_uncorrected, error: ``(T,)`` ``∠(Φ(g), u_t)`` and ``∠(Φ(g + b), u_t)``.
        looking: ``(T,)`` ``error < threshold`` (eq. 1).
        probability: ``(T,)`` share of the posterior draws of ``b`` that make the frame looking
            (``"bayes"``), else ``looking`` as 0/1.
        options: the settings used (method, num_frames, window_s, max_head_angle_deg,
            threshold_deg, num_warmup, num_samples).
    """

    estimate: BiasEstimate
    selection: FrameSelection
    frames: np.ndarray
    times: np.ndarray
    partner: Optional[str]
    partner_speaking: np.ndarray
    in_window: np.ndarray
    target_dir_head: np.ndarray
    head_target_angle: np.ndarray
    offsets: np.ndarray
    silent: np.ndarray
    error_uncorrected: np.ndarray
    error: np.ndarray
    looking: np.ndarray
    probability: np.ndarray
    options: dict

    @property
    def bias(self) -> np.ndarray:
        """``(2,)`` the bias ``b`` (yaw, tilt), float64 radians; corrected gaze is ``g + b``."""
        return np.asarray(self.estimate.bias, dtype=np.float64)

    @property
    def selected(self) -> np.ndarray:
        """``(T,)`` bool: the drawn frames."""
        mask = np.zeros(len(self.frames), dtype=bool)
        mask[np.asarray(self.selection.indices)] = True
        return mask

    def frame_table(self) -> dict:
        """The per-frame table, ``{column: (T,) array}`` for :data:`BIAS_FRAME_COLUMNS` (``_deg`` in degrees)."""
        return {
            "frame": self.frames,
            "time": self.times,
            "partner_speaking": self.partner_speaking,
            "head_target_angle_deg": np.degrees(self.head_target_angle),
            "selected": self.selected,
            "error_uncorrected_deg": np.degrees(self.error_uncorrected),
            "error_deg": np.degrees(self.error),
            "looking": self.looking,
            "probability": self.probability,
        }


def _frames_array(name: str, value, shape: tuple, num_frames: Optional[int]) -> np.ndarray:
    """``value`` as float64 of shape ``(T,) + shape`` (``T`` = ``num_frames`` when given), finite."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BiasInputError(f"{name} must be an array of numbers", name) from None
    want = ("T",) + shape
    if a.ndim != len(want) or a.shape[1:] != shape or (num_frames is not None and a.shape[0] != num_frames):
        size = "T" if num_frames is None else str(num_frames)
        raise BiasInputError(f"{name} must have shape ({', '.join((size,) + tuple(map(str, shape)))}), "
                             f"got {a.shape}", name)
    bad = ~np.isfinite(a.reshape(len(a), -1)).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BiasInputError(f"{name} is not finite (NaN or inf) at frame index {i}", name, i)
    return a


def _speaking(partner_speaking, partner, times, num_frames):
    """``(flags (T,), partner)`` from flags or from speech segments and the partner's name."""
    if isinstance(partner_speaking, SpeechSegments):
        try:
            partner = choose_partner(partner_speaking, partner)
        except ValueError as error:
            raise BiasInputError(str(error), "partner") from None
        return speaking_at(partner_speaking, [partner], times)[0], partner
    flags = np.asarray(partner_speaking)
    if flags.shape != (num_frames,):
        raise BiasInputError(f"partner_speaking must have shape ({num_frames},), got {flags.shape}",
                             "partner_speaking")
    if not (flags.dtype == bool or np.isin(flags, (0, 1)).all()):
        raise BiasInputError("partner_speaking must be boolean (or 0/1)", "partner_speaking")
    return flags.astype(bool), partner


def adapt_bias(
    gaze_angles,
    R_world_from_head,
    eye,
    target,
    times,
    partner_speaking,
    *,
    partner: Optional[str] = None,
    frames=None,
    method: str = "bayes",
    num_frames: Optional[int] = None,
    window_s: float = 60.0,
    max_head_angle_deg: float = 30.0,
    threshold_deg: float = 10.0,
    key=None,
    num_warmup: int = 500,
    num_samples: int = 500,
    max_silent_frames: int = 256,
    progress: bool = False,
) -> BiasAdaptation:
    """Speaker-prior gaze bias adaptation of one person (Siegfried et al. 2017, Sec. 3–4).

    Inputs per frame (``T`` frames, any one frame of reference "world"):
    ``gaze_angles (T, 2)`` the estimated (yaw, tilt) in the head frame (radians),
    ``R_world_from_head (T, 3, 3)``, ``eye (T, 3)`` the eye midpoint and ``target``
    ``(T, 3)`` or ``(3,)`` the partner's eye midpoint (metres), ``times (T,)`` seconds
    (non-decreasing), and ``partner_speaking``: ``(T,)`` bool flags, or
    :class:`SpeechSegments` with ``partner`` the partner's name (optional when one
    speaker) — the flags are then ``speaking_at(segments, [partner], times)``.

    With ``u_t = R_world_from_headᵀ unit(target − eye)``, the candidates are the frames
    of the first ``window_s`` seconds (``time − time[0] < window_s``) where the partner
    speaks and ``∠(+x, u_t) ≤ max_head_angle_deg``; ``num_frames`` of them
    (:data:`DEFAULT_NUM_FRAMES`) are drawn at random (``key``, split into the draw and
    the fit; default ``jax.random.key(0)``) and ``b`` is estimated from their offsets
    by ``method`` (:func:`estimate_bias`; ``"bayes"`` also gets up to
    ``max_silent_frames`` candidates-but-silent frames as contrast, and runs
    ``num_warmup``/``num_samples`` NUTS steps). Frame ``t`` looks at the partner when
    ``∠(Φ(g_t + b), u_t) < threshold_deg`` (eq. 1).

    Raises :class:`BiasInputError` (a ``ValueError`` naming the argument and, where one
    applies, the frame index) for wrong shapes, NaN/inf, decreasing times, a target at
    the eyes, an unknown method, too few frames for LMedS, no candidate frame, or a
    posterior with non-finite draws. A target more than 100 m from the eyes is a
    :class:`~jaxgaze.rays.UnitWarning` (millimetres?; :func:`jaxgaze.rays.check_distance`).
    """
    if method not in METHODS:
        raise BiasInputError(f"unknown method {method!r}; choose one of {METHODS}", "method")
    requested = DEFAULT_NUM_FRAMES[method] if num_frames is None else num_frames
    if int(requested) != requested or requested < 1:
        raise BiasInputError(f"num_frames must be a positive integer, got {requested}", "num_frames")
    requested = int(requested)
    if method == "lmeds" and requested < 3:
        raise BiasInputError(f"method 'lmeds' needs num_frames >= 3, got {requested}: with fewer it cannot tell the "
                             "frames that look at the partner from the others", "num_frames")
    for name, value in (("window_s", window_s), ("max_head_angle_deg", max_head_angle_deg),
                        ("threshold_deg", threshold_deg)):
        if not (math.isfinite(value) and value > 0):
            raise BiasInputError(f"{name} must be a positive finite number, got {value}", name)
    g = _frames_array("gaze_angles", gaze_angles, (2,), None)
    T = len(g)
    if T == 0:
        raise BiasInputError("gaze_angles has no frames (T = 0)", "gaze_angles")
    R = _frames_array("R_world_from_head", R_world_from_head, (3, 3), T)
    eye = _frames_array("eye", eye, (3,), T)
    target = np.asarray(target, dtype=np.float64)
    target = _frames_array("target", np.broadcast_to(target, (T, 3)) if target.shape == (3,) else target, (3,), T)
    times = _frames_array("times", times, (), T)
    if np.any(np.diff(times) < 0):
        i = int(np.flatnonzero(np.diff(times) < 0)[0]) + 1
        raise BiasInputError(f"times must not decrease: frame index {i} at {times[i]:g} s is before {times[i - 1]:g} s",
                             "times", i)
    frames = np.arange(T, dtype=np.int64) if frames is None else np.asarray(frames, dtype=np.int64)
    if frames.shape != (T,):
        raise BiasInputError(f"frames must have shape ({T},), got {frames.shape}", "frames")
    speaking, partner = _speaking(partner_speaking, partner, times, T)
    close = np.flatnonzero(np.linalg.norm(target - eye, axis=1) < MIN_TARGET_DISTANCE)
    if close.size:
        i = int(close[0])
        raise BiasInputError(f"the target is at the eyes (closer than 1 mm) in frame {frames[i]}", "target", i)
    check_distance(np.linalg.norm(target - eye, axis=1), "the distance from the eyes to the target", frames)

    u = np.asarray(target_direction_head(jnp.asarray(eye), jnp.asarray(target), jnp.asarray(R)))
    head_angle = np.asarray(head_target_angle(jnp.asarray(u)))
    in_window = (times - times[0]) < window_s
    # The window is applied here on the frame times (frames may be missing); select_frames sees it as open.
    open_window = dict(fps=1.0, max_head_angle_deg=max_head_angle_deg, window_s=math.inf)
    candidates = np.asarray(candidate_frames(jnp.asarray(speaking & in_window), jnp.asarray(head_angle),
                                             **open_window))
    who = "the partner" if partner is None else f"partner '{partner}'"
    if not candidates.any():
        speech = ""
        if isinstance(partner_speaking, SpeechSegments):  # the partner's own segments
            own = np.asarray([s == partner for s in partner_speaking.speaker], dtype=bool)
            speech = (f" ({who} speaks from {float(np.min(partner_speaking.start[own])):g} to "
                      f"{float(np.max(partner_speaking.end[own])):g} s)") if own.any() else f" ({who} never speaks)"
        spoken = int((speaking & in_window).sum())
        raise BiasInputError(f"no selectable frames: in the first {window_s:g} s ({int(in_window.sum())} frames, "
                             f"{times[0]:g}-{times[in_window][-1]:g} s) {who} speaks in {spoken} frame"
                             f"{'' if spoken == 1 else 's'}" + (f", and in none of those is the head within "
                             f"{max_head_angle_deg:g} degrees of the target" if spoken else "") + speech,
                             "partner_speaking")
    if method == "lmeds" and candidates.sum() < 3:
        raise BiasInputError(f"lmeds needs at least 3 selectable frames, found {int(candidates.sum())}: use method "
                             "'mean' or 'bayes', or a longer window", "partner_speaking")

    key_select, key_fit = jax.random.split(jax.random.key(0) if key is None else key)
    selection = select_frames(key_select, speaking & in_window, head_angle, num_frames=requested, **open_window)
    chosen = np.asarray(selection.indices)
    offsets = np.asarray(gaze_offsets(jnp.asarray(g[chosen]), jnp.asarray(u[chosen])))
    extra = {}
    silent = np.zeros(0, dtype=np.int64)
    if method == "bayes":  # the contrast: same window and head filter while the partner is silent
        silent = np.flatnonzero(np.asarray(candidate_frames(jnp.asarray(~speaking & in_window),
                                                            jnp.asarray(head_angle), **open_window)))
        silent = silent[:: max(1, -(-len(silent) // max_silent_frames))]
        if len(silent):
            extra["silent_offsets"] = np.asarray(gaze_offsets(jnp.asarray(g[silent]), jnp.asarray(u[silent])))
    estimate = estimate_bias(offsets, method, key=key_fit, num_warmup=num_warmup, num_samples=num_samples,
                             progress=progress and method == "bayes", **extra)
    bias = np.asarray(estimate.bias, dtype=np.float64)
    draws = None
    if method == "bayes":
        draws = np.asarray(estimate.samples["bias"], dtype=np.float64)
        if not np.all(np.isfinite(draws)):
            raise BiasInputError("posterior sampling failed: non-finite draws of the bias", "gaze_angles")

    gj, uj, bj = jnp.asarray(g), jnp.asarray(u), jnp.asarray(bias)
    looking = np.asarray(is_looking_at(gj, uj, bj, threshold_deg=threshold_deg), dtype=bool)
    if draws is not None:
        probability = np.asarray(looking_probability(gj, uj, jnp.asarray(draws), threshold_deg=threshold_deg),
                                 dtype=np.float64)
    else:
        probability = looking.astype(np.float64)
    return BiasAdaptation(
        estimate=estimate, selection=selection, frames=frames, times=times, partner=partner,
        partner_speaking=speaking, in_window=in_window, target_dir_head=u, head_target_angle=head_angle,
        offsets=offsets, silent=silent,
        error_uncorrected=np.asarray(angular_error(gj, uj), dtype=np.float64),
        error=np.asarray(angular_error(gj, uj, bj), dtype=np.float64), looking=looking, probability=probability,
        options=dict(method=method, num_frames=requested, window_s=window_s, max_head_angle_deg=max_head_angle_deg,
                     threshold_deg=threshold_deg, num_warmup=num_warmup, num_samples=num_samples),
    )
