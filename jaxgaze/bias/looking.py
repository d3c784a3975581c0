"""Gaze angles, target directions and the looking-at decision (Siegfried et al. 2017, Sec. 2–3).

Conventions (``docs/conventions.md``): the head frame has +x forward, +y left,
+z up; angles are radians (degrees only in names ending ``_deg``).

* Gaze angles ``g = (φ, θ)`` = (yaw, tilt) in the **head** frame, arrays ``(..., 2)``.
  ``Φ(g) = yaw_pitch_to_direction(φ, θ)`` is the unit gaze vector in the head frame.
* A bias ``b (2,)`` corrects the gaze: the corrected angles are ``g + b``.
* ``u_t`` is the unit vector from the eye midpoint to the target (the partner's eye
  midpoint), in the head frame: ``R_head_from_world @ unit(target − eye)``.
* The offset of a frame is ``o = angles(u_t) − g`` (yaw difference wrapped to
  (−π, π]); on frames where the person looks at the target, ``o ≈ b + noise``.

Every function here broadcasts over leading batch axes and works under ``jit`` and
``vmap``. Value checks (NaN) run only on concrete inputs; shape checks always run.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxgaze.geometry import angle_between, deg_to_rad, direction_to_yaw_pitch, unit, wrap_angle, yaw_pitch_to_direction

__all__ = [
    "gaze_angles_to_direction",
    "direction_to_gaze_angles",
    "head_to_world",
    "target_direction_head",
    "gaze_offsets",
    "angular_error",
    "is_looking_at",
    "looking_probability",
    "head_target_angle",
    "candidate_frames",
    "select_frames",
    "FrameSelection",
]


# --------------------------------------------------------------------------- checks


def _is_concrete(*arrays) -> bool:
    return not any(isinstance(a, jax.core.Tracer) for a in arrays)


def _where(index: tuple[int, ...]) -> str:
    return f"frame {index[0]}" if len(index) == 1 else f"frame {tuple(int(i) for i in index)}"


def _check_finite(name: str, value, last_axis: bool = True) -> None:
    """Raise ``ValueError`` naming ``name`` and the first frame holding NaN/inf (concrete values only)."""
    if not _is_concrete(value):
        return
    v = np.asarray(value)
    if v.dtype == bool or np.issubdtype(v.dtype, np.integer):
        return
    bad = ~np.isfinite(v)
    if not bad.any():
        return
    if last_axis and v.ndim >= 1:
        bad = bad.any(axis=-1)
        if bad.ndim == 0:
            raise ValueError(f"{name} is not finite (NaN or inf): {v}")
    first = tuple(int(i) for i in np.argwhere(bad)[0]) if bad.ndim else ()
    where = _where(first) if first else "the value"
    raise ValueError(f"{name} is not finite (NaN or inf) at {where}")


def _last_axis(name: str, value, size: int) -> Array:
    value = jnp.asarray(value)
    if value.ndim < 1 or value.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got {value.shape}")
    return value


def _batch_shape(**arrays_and_cores) -> tuple[int, ...]:
    """Broadcast the leading (batch) shapes; raise a ValueError naming the arrays that do not fit."""
    shapes = {name: a.shape[: a.ndim - core] for name, (a, core) in arrays_and_cores.items()}
    try:
        return np.broadcast_shapes(*shapes.values())
    except ValueError:
        listed = ", ".join(f"{n} batch shape {s}" for n, s in shapes.items())
        raise ValueError(f"the frame (batch) shapes do not broadcast: {listed}") from None


def _gaze_and_target(gaze_angles, target_dir_head):
    g = _last_axis("gaze_angles", gaze_angles, 2)
    u = _last_axis("target_dir_head", target_dir_head, 3)
    _batch_shape(gaze_angles=(g, 1), target_dir_head=(u, 1))
    _check_finite("gaze_angles", g)
    _check_finite("target_dir_head", u)
    return g, u


def _bias(bias, like: Array) -> Array:
    if bias is None:
        return jnp.zeros((2,), jnp.result_type(like, jnp.float32))
    b = _last_axis("bias", bias, 2)
    _check_finite("bias", b)
    return b


# ------------------------------------------------------------------ angles and frames


def gaze_angles_to_direction(angles: Float[Array, "... 2"]) -> Float[Array, "... 3"]:
    """``Φ(g)``: gaze angles ``(yaw, tilt)`` → unit direction in the head frame (Siegfried et al. 2017, Sec. 2–3).

    ``Φ(φ, θ) = (cos θ cos φ, cos θ sin φ, sin θ)``; ``(0, 0)`` is +x (forward),
    ``(π/2, 0)`` is +y (left) and ``(0, π/2)`` is +z (up).
    """
    angles = _last_axis("angles", angles, 2)
    return yaw_pitch_to_direction(angles[..., 0], angles[..., 1])


def direction_to_gaze_angles(direction: Float[Array, "... 3"]) -> Float[Array, "... 2"]:
    """``Φ⁻¹`` (Siegfried et al. 2017, Sec. 2–3): a direction (need not be unit) → ``(yaw, tilt)``.

    Yaw in (−π, π], tilt in [−π/2, π/2].
    """
    direction = _last_axis("direction", direction, 3)
    yaw, tilt = direction_to_yaw_pitch(direction)
    return jnp.stack([yaw, tilt], axis=-1)


def head_to_world(
    direction_head: Float[Array, "... 3"], R_world_from_head: Float[Array, "... 3 3"]
) -> Float[Array, "... 3"]:
    """``v_world = R_world_from_head @ v_head`` (broadcasts over frames)."""
    v = _last_axis("direction_head", direction_head, 3)
    R = jnp.asarray(R_world_from_head)
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError(f"R_world_from_head must have shape (..., 3, 3), got {R.shape}")
    _batch_shape(direction_head=(v, 1), R_world_from_head=(R, 2))
    return jnp.einsum("...ij,...j->...i", R, v)


def target_direction_head(
    eye_world: Float[Array, "... 3"], target_world: Float[Array, "... 3"], R_world_from_head: Float[Array, "... 3 3"]
) -> Float[Array, "... 3"]:
    """``u_t = R_world_from_headᵀ · unit(target − eye)`` (Siegfried et al. 2017, Sec. 2–3).

    The unit eye→target direction in the head frame. ``eye_world`` is the eye midpoint
    and ``target_world`` the partner's eye midpoint (world frame, metres). A coincident
    eye and target gives zeros.
    """
    eye = _last_axis("eye_world", eye_world, 3)
    target = _last_axis("target_world", target_world, 3)
    R = jnp.asarray(R_world_from_head)
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError(f"R_world_from_head must have shape (..., 3, 3), got {R.shape}")
    _batch_shape(eye_world=(eye, 1), target_world=(target, 1), R_world_from_head=(R, 2))
    _check_finite("eye_world", eye)
    _check_finite("target_world", target)
    # R_head_from_world = R_world_from_headᵀ: contract over R's first (world) index.
    return jnp.einsum("...ji,...j->...i", R, unit(target - eye))


def gaze_offsets(gaze_angles: Float[Array, "... 2"], target_dir_head: Float[Array, "... 3"]) -> Float[Array, "... 2"]:
    """Offsets ``o = angles(u_t) − g``, the ``o_i`` of eq. 2 (Siegfried et al. 2017, Sec. 3.2).

    The yaw difference is wrapped to (−π, π]. On frames where the person looks at the
    target ``o ≈ b``: adding ``o`` to ``g`` turns the gaze onto ``u_t``.
    """
    g, u = _gaze_and_target(gaze_angles, target_dir_head)
    o = direction_to_gaze_angles(u) - g
    return jnp.stack([wrap_angle(o[..., 0]), o[..., 1]], axis=-1)


def angular_error(
    gaze_angles: Float[Array, "... 2"],
    target_dir_head: Float[Array, "... 3"],
    bias: Float[Array, "... 2"] | None = None,
) -> Float[Array, "..."]:
    """``e = arccos(Φ(g + b) · u_t)`` (Siegfried et al. 2017, eq. 1), radians in [0, π].

    Evaluated as :func:`jaxgaze.geometry.angle_between` (``atan2(‖a×b‖, a·b)``),
    accurate near 0 where ``arccos`` loses precision. ``u_t`` need not be unit.
    """
    g, u = _gaze_and_target(gaze_angles, target_dir_head)
    b = _bias(bias, g)
    return angle_between(gaze_angles_to_direction(g + b), u)


def is_looking_at(
    gaze: Float[Array, "... 2"],
    target_dir: Float[Array, "... 3"],
    bias: Float[Array, "... 2"] | None = None,
    threshold_deg: float = 10.0,
) -> Bool[Array, "..."]:
    """Looking at the target: ``e = ∠(Φ(g + b), u_t) < τ`` (strict), ``τ = 10°`` (Siegfried et al. 2017, eq. 1)."""
    return angular_error(gaze, target_dir, bias) < deg_to_rad(threshold_deg)


def looking_probability(
    gaze: Float[Array, "... 2"],
    target_dir: Float[Array, "... 3"],
    bias_samples: Float[Array, "S 2"],
    threshold_deg: float = 10.0,
) -> Float[Array, "..."]:
    """Posterior probability of looking at the target (Siegfried et al. 2017, eq. 1).

    ``P(e < τ) ≈ (1/S) Σ_s 1[∠(Φ(g + b_s), u_t) < τ]``; ``bias_samples (S, 2)`` are
    posterior draws of ``b`` (e.g. ``BiasEstimate.samples["bias"]``).
    Memory is O(frames): the draws are looped over with ``lax.scan``.
    """
    g, u = _gaze_and_target(gaze, target_dir)
    draws = jnp.asarray(bias_samples)
    if draws.ndim != 2 or draws.shape[-1] != 2:
        raise ValueError(f"bias_samples must have shape (S, 2), got {draws.shape}")
    if draws.shape[0] == 0:
        raise ValueError("bias_samples is empty: need at least one draw of the bias")
    _check_finite("bias_samples", draws)
    tau = deg_to_rad(threshold_deg)
    shape = np.broadcast_shapes(g.shape[:-1], u.shape[:-1])
    dtype = jnp.result_type(g, u, draws, jnp.float32)

    def count(total, b):
        return total + (angle_between(gaze_angles_to_direction(g + b), u) < tau).astype(dtype), None

    total, _ = jax.lax.scan(count, jnp.zeros(shape, dtype), draws.astype(dtype))
    return total / draws.shape[0]


# ------------------------------------------------------------------- frame selection


def head_target_angle(target_dir_head: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """Angle between the head direction (+x of the head frame) and ``u_t``, radians in [0, π]."""
    u = _last_axis("target_dir_head", target_dir_head, 3)
    _check_finite("target_dir_head", u)
    forward = jnp.zeros((3,), jnp.result_type(u, jnp.float32)).at[0].set(1.0)
    return angle_between(jnp.broadcast_to(forward, u.shape), u)


def candidate_frames(
    partner_speaking: Bool[Array, " T"],
    head_target_angle: Float[Array, " T"],
    *,
    fps: float,
    max_head_angle_deg: float = 30.0,
    window_s: float = 60.0,
    start_s: float = 0.0,
) -> Bool[Array, " T"]:
    """Spk candidates (Siegfried et al. 2017, Sec. 3.2): partner speaking, head–target angle ≤ 30°, in the window.

    Frame ``t`` is at time ``t / fps`` seconds and is in the window when
    ``start_s ≤ t / fps < start_s + window_s``. Jittable (no value checks).
    """
    speaking = jnp.asarray(partner_speaking)
    angle = jnp.asarray(head_target_angle)
    if speaking.ndim != 1 or angle.shape != speaking.shape:
        raise ValueError(
            f"partner_speaking and head_target_angle must both have shape (T,), got {speaking.shape} and {angle.shape}"
        )
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    time = jnp.arange(speaking.shape[0]) / fps
    in_window = (time >= start_s) & (time < start_s + window_s)
    return speaking.astype(bool) & (angle <= deg_to_rad(max_head_angle_deg)) & in_window


class FrameSelection(NamedTuple):
    """Frames drawn for bias estimation.

    Attributes:
        indices: ``(K,)`` selected frame indices, ascending (``K = min(num_frames, num_candidates)``).
        num_candidates: how many frames met the criteria.
        num_selected: ``K``.
        num_requested: the ``num_frames`` asked for.
        candidates: ``(T,)`` boolean mask of the candidate frames.
    """

    indices: Int[np.ndarray, " K"]
    num_candidates: int
    num_selected: int
    num_requested: int
    candidates: Bool[np.ndarray, " T"]

    @property
    def partial(self) -> bool:
        """``True`` when fewer candidates than requested were available (all of them were taken)."""
        return self.num_selected < self.num_requested


def select_frames(
    key: PRNGKeyArray,
    partner_speaking: Bool[Array, " T"],
    head_target_angle: Float[Array, " T"],
    *,
    num_frames: int,
    fps: float,
    max_head_angle_deg: float = 30.0,
    window_s: float = 60.0,
    start_s: float = 0.0,
) -> FrameSelection:
    """Spk frame selection (Siegfried et al. 2017, Sec. 3.2): draw ≤ ``num_frames`` candidates without replacement.

    Candidates (:func:`candidate_frames`) are frames where the partner speaks and the
    angle between the head direction and the target direction is at most
    ``max_head_angle_deg``, within the first ``window_s`` seconds (from ``start_s``).
    With fewer candidates than ``num_frames`` all of them are returned. The draw is
    deterministic given ``key``. Not jittable: the result's size depends on the data.

    Raises ``ValueError`` ("no frames: ...") when there is no candidate, and for
    NaN/inf angles (naming the frame) or mismatched shapes.
    """
    speaking = np.asarray(partner_speaking)
    angle = np.asarray(head_target_angle)
    if speaking.ndim != 1:
        raise ValueError(f"partner_speaking must have shape (T,), got {speaking.shape}")
    if angle.shape != speaking.shape:
        raise ValueError(
            f"head_target_angle must have the shape of partner_speaking {speaking.shape}, got {angle.shape}"
        )
    if not (speaking.dtype == bool or np.isin(speaking, (0, 1)).all()):
        raise ValueError("partner_speaking must be boolean (or 0/1)")
    _check_finite("head_target_angle", angle, last_axis=False)
    if int(num_frames) != num_frames or num_frames < 1:
        raise ValueError(f"num_frames must be a positive integer, got {num_frames}")
    mask = np.asarray(
        candidate_frames(speaking.astype(bool), angle, fps=fps, max_head_angle_deg=max_head_angle_deg,
                         window_s=window_s, start_s=start_s)
    )
    candidates = np.flatnonzero(mask)
    if candidates.size == 0:
        raise ValueError(
            f"no frames: none of the {speaking.shape[0]} frames has the partner speaking with a head–target angle "
            f"≤ {max_head_angle_deg}° within {start_s}–{start_s + window_s} s (fps {fps}); cannot estimate a bias"
        )
    k = min(int(num_frames), candidates.size)
    chosen = np.asarray(jax.random.choice(key, candidates.size, (k,), replace=False))
    indices = np.sort(candidates[chosen])
    return FrameSelection(indices=indices, num_candidates=int(candidates.size), num_selected=k,
                         num_requested=int(num_frames), candidates=mask)
