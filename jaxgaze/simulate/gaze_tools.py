"""Camera gaze tools' outputs with known truth: Gaze360-style angles whose errors follow their own ``var``
(Kellnhofer et al. 2019, Sec. 4: the 10%/90% quantile loss).

People stand in front of one camera; each frame each looks somewhere with a true gaze direction.
The tool reports Gaze360's eye-frame angles (see :mod:`jaxgaze.io.tools.gaze360`) with an error drawn
per angle from ``N(0, σ²)``, ``σ = var / z₀.₉``, ``var`` uniform per ray in ``var_range_deg``: exactly
what a well-calibrated Gaze360 claims. The eye frame is built here on its own (``E_x = up × E_z``
normalised, ``E_y = E_z × E_x``), as an independent check of the reader's.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from jaxgaze.geometry import deg_to_rad

__all__ = ["Gaze360Outputs", "simulate_gaze360_outputs"]

#: The 90% quantile of the standard normal: Gaze360's ``var`` is ``Z_90 σ``.
_Z_90 = 1.2815515655446004
#: True gaze angles, uniform within ± these (degrees): yaw, pitch (eye frame).
TRUE_YAW_RANGE_DEG = 60.0
TRUE_PITCH_RANGE_DEG = 20.0


class Gaze360Outputs(NamedTuple):
    """Simulated Gaze360 outputs, one row per (frame, person), frame-major.

    Attributes:
        frames: ``(M,)`` frame of each row.
        persons: ``(M,)`` person index of each row.
        eyes_camera: ``(M, 3)`` mid-eye points, our camera frame (+x forward, +y left, +z up), metres.
        yaw, pitch: ``(M,)`` the reported Gaze360 angles, radians.
        var: ``(M,)`` the reported ``var``, radians.
        true_directions: ``(M, 3)`` unit true gaze directions, our camera frame.
    """

    frames: Int[Array, " M"]
    persons: Int[Array, " M"]
    eyes_camera: Float[Array, "M 3"]
    yaw: Float[Array, " M"]
    pitch: Float[Array, " M"]
    var: Float[Array, " M"]
    true_directions: Float[Array, "M 3"]


def _eye_frame(eyes: Float[Array, "M 3"]) -> Float[Array, "M 3 3"]:
    z = eyes / jnp.linalg.norm(eyes, axis=-1, keepdims=True)
    x = jnp.cross(jnp.array([0.0, 0.0, 1.0]), z)
    x = x / jnp.linalg.norm(x, axis=-1, keepdims=True)
    return jnp.stack([x, jnp.cross(z, x), z], axis=-1)


def _spherical(yaw, pitch):
    return jnp.stack([jnp.cos(pitch) * jnp.sin(yaw), jnp.sin(pitch), -jnp.cos(pitch) * jnp.cos(yaw)], axis=-1)


def simulate_gaze360_outputs(key: PRNGKeyArray, num_frames: int, num_people: int, *,
                             var_range_deg: tuple[float, float] = (2.0, 25.0)) -> Gaze360Outputs:
    """``num_frames × num_people`` Gaze360 outputs with their truth (see the module).

    People stand 1.5–4 m in front of the camera, within ±1.5 m sideways and ±0.3 m of its height.
    True angles are uniform within ±60° yaw and ±20° pitch; reported pitch is kept inside
    Gaze360's ``(−π/2, π/2)``.
    """
    if num_frames < 1 or num_people < 1:
        raise ValueError(f"num_frames and num_people must be at least 1, got {num_frames} and {num_people}")
    low, high = var_range_deg
    if not 0 < low <= high:
        raise ValueError(f"var_range_deg must be (low, high) with 0 < low <= high, got {var_range_deg}")
    return _simulate(key, num_frames, num_people, float(low), float(high))


@partial(jax.jit, static_argnums=(1, 2, 3, 4))
def _simulate(key, num_frames: int, num_people: int, low: float, high: float) -> Gaze360Outputs:
    m = num_frames * num_people
    k_eyes, k_true, k_var, k_error = jax.random.split(key, 4)
    eyes_of_person = jax.random.uniform(k_eyes, (num_people, 3), minval=jnp.array([1.5, -1.5, -0.3]),
                                        maxval=jnp.array([4.0, 1.5, 0.3]))
    persons = jnp.tile(jnp.arange(num_people), num_frames)
    eyes = eyes_of_person[persons]
    angles = jax.random.uniform(k_true, (m, 2), minval=-1.0, maxval=1.0)
    true_yaw = angles[:, 0] * deg_to_rad(TRUE_YAW_RANGE_DEG)
    true_pitch = angles[:, 1] * deg_to_rad(TRUE_PITCH_RANGE_DEG)
    var = deg_to_rad(jax.random.uniform(k_var, (m,), minval=low, maxval=high))
    error = jax.random.normal(k_error, (m, 2)) * (var / _Z_90)[:, None]
    edge = math.pi / 2 - 1e-6
    yaw = true_yaw + error[:, 0]
    pitch = jnp.clip(true_pitch + error[:, 1], -edge, edge)
    true_directions = jnp.einsum("mij,mj->mi", _eye_frame(eyes), _spherical(true_yaw, true_pitch))
    return Gaze360Outputs(jnp.repeat(jnp.arange(num_frames), num_people), persons, eyes, yaw, pitch, var,
                          true_directions)
