"""Simulated gaze-ray calibration sessions with ground truth (Park, Jain & Sheikh 2012, Sec. 3.2, 4).

Calibration protocol (Sec. 3.2): people form pairs and look at each other's
camera while they "move back and forth and side to side at least three times"
(Sec. 4). For wearer A with reported camera pose ``(R_A, C_A)``
(``R_A = R_camera_from_world``) the camera centre of B is A's point of regard;
in A's camera frame it is ``y = R_A (C_B − C_A)``. The points ``{y_i}`` fill a
cone around A's primary gaze ray, which is fixed in A's camera frame.

Generative model, for one pair (A, B) and frames ``t = 0 … T−1``:

1. **Mounting** (fixed per wearer, camera frame: +x forward, +y left, +z up):
   the centre of the eyes ``e`` (camera on the forehead, eyes 5–10 cm below
   and 1–4 cm behind it, ±2 cm sideways) and the primary gaze direction ``v``
   (yaw and pitch each within ±5° of +x). See :func:`random_mounting`.
2. **Motion** (world frame, z up, metres): the pair stands along a random
   horizontal axis, about 1–4 m apart. Each wearer's camera centre oscillates
   along the pair axis (back and forth) and across it (side to side) with
   sinusoids of at least 3.2 cycles each over the session (periods 5–10 s when
   the session is long enough), camera height 1.6–1.8 m with a 1 cm walking bob.
3. **Gaze** (cone model, Sec. 3.1): the actual gaze of the eye is
   ``v' = unit(v + d1 u1 + d2 u2)``, ``d1, d2 ~ N(0, eye_in_head²)``, with
   ``(v, u1, u2)`` orthonormal (:func:`jaxgaze.geometry.orthonormal_basis`).
   On *outlier* frames the wearer looks elsewhere: ``v'`` is instead a
   direction 10°–30° from ``v`` (uniform angle, uniform azimuth).
4. **Head orientation**: the head turns so that the ray ``(e, v')`` passes
   through the partner's camera centre. With ``D = ‖C_B − C_A‖`` the target in
   camera coordinates is ``y = e + s v'`` with ``s > 0`` and ``‖y‖ = D``; the
   rotation maps ``unit(y)`` (camera frame) onto ``unit(C_B − C_A)`` (world),
   keeping the camera upright (camera +z in the vertical plane through the
   line of sight), followed by a small smooth roll (≤ 5°) about that line,
   which leaves ``y`` unchanged. Hence, without pose noise, every inlier
   ``y`` lies in the cone of the true primary ray with perspective distance
   (eq. 4) exactly ``(d1, d2)``, and on the ray itself when ``eye_in_head = 0``.
5. **Pose noise** (structure from motion): the reported pose is
   ``R = R(ω) R_true``, ``ω ~ N(0, pose_noise_rotation² I₃)`` (axis-angle,
   camera frame) and ``C = C_true + N(0, pose_noise_position² I₃)``, i.i.d.
   per frame and wearer.

All randomness comes from the ``jax.random`` key: the same key gives the same
session, and the motion does not depend on whether the mounting is drawn or
passed in. All frames are generated in one jitted, vectorised pass.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxgaze.geometry import axis_angle_to_rotation_matrix, orthonormal_basis, unit, yaw_pitch_to_direction
from jaxgaze._checks import check_int, check_key, check_number
from jaxgaze.simulate._random import Pool

__all__ = [
    "Mounting",
    "CalibrationSession",
    "random_mounting",
    "simulate_calibration_session",
    "simulate_wearers",
]

# Ranges of the random mounting (camera frame, metres / radians).
EYE_CENTER_RANGE = ((-0.04, -0.01), (-0.02, 0.02), (-0.10, -0.05))
DIRECTION_OFFSET_MAX = math.radians(5.0)
# Outlier frames: the partner's camera is this far (radians) from the primary ray.
OUTLIER_ANGLE_RANGE = (math.radians(10.0), math.radians(30.0))
# Motion.
MIN_CYCLES = 3.2  # "at least three times" (Sec. 4), with a margin
PERIOD_RANGE = (5.0, 10.0)  # seconds per back-and-forth / side-to-side cycle
# The depth range sets how well the eye centre is found: the ray is pinned at the
# points, metres out, so its offset at the eyes is about depth × direction error.
# Measured with RANSAC + cone on 200 wearers × 3 seeds (300 frames, h = 0.03):
# pairs 1.6–3.7 m apart gave a median eye-centre error ⊥ axis of 3.4–4.0 cm and a
# direction error of 0.8–1.0°; pairs 1.0–4.1 m apart (the values below) 1.9–2.3 cm
# and 0.5–0.6°. Walking back and forth from ~1 m to ~4 m is the protocol to ask for.
SEPARATION_RANGE = (2.25, 2.75)  # mean distance between the pair (m)
AXIAL_AMPLITUDE_RANGE = (0.4, 0.7)  # each wearer, along the pair axis (m)
LATERAL_AMPLITUDE_RANGE = (0.2, 0.5)  # each wearer, across the pair axis (m)
HEIGHT_RANGE = (1.6, 1.8)  # camera height (m)
BOB_AMPLITUDE = 0.01  # walking bob (m)
ROLL_MAX = math.radians(5.0)  # head roll about the line of sight


class Mounting(NamedTuple):
    """How the eyes sit relative to the head-mounted camera (camera frame).

    Attributes:
        eye_center_in_camera: ``(..., 3)`` centre of the eyes ``p`` in metres.
        direction_in_camera: ``(..., 3)`` unit primary gaze direction ``v``.
    """

    eye_center_in_camera: Float[Array, "... 3"]
    direction_in_camera: Float[Array, "... 3"]


class CalibrationSession(NamedTuple):
    """One calibration pair (A, B) over ``T`` frames, with ground truth (Park et al. Sec. 3.2).

    Array fields may carry leading batch axes (see :func:`simulate_wearers`).

    Attributes:
        R_camera_from_world_a: ``(T, 3, 3)`` reported orientation of A's camera
            (``v_camera = R @ v_world``), with pose noise.
        centers_a: ``(T, 3)`` reported camera centre of A (world, metres).
        R_camera_from_world_b, centers_b: the same for B.
        frame_ids: ``(T,)`` frame numbers ``0 … T−1``.
        eye_center_a, direction_a: ``(3,)`` true centre of the eyes and unit
            primary gaze direction of A in A's camera frame.
        eye_center_b, direction_b: the same for B.
        eye_in_head: standard deviation ``h`` of each eye-in-head offset (radians).
        outlier_a, outlier_b: ``(T,)`` frames on which the wearer looks elsewhere.
        true_R_camera_from_world_a, true_centers_a, true_R_camera_from_world_b, true_centers_b: the poses
            before pose noise.
        pose_noise_rotation, pose_noise_position: the pose-noise standard
            deviations (radians, metres).
        fps: frames per second.
    """

    R_camera_from_world_a: Float[Array, "T 3 3"]
    centers_a: Float[Array, "T 3"]
    R_camera_from_world_b: Float[Array, "T 3 3"]
    centers_b: Float[Array, "T 3"]
    frame_ids: Int[Array, " T"]
    eye_center_a: Float[Array, "3"]
    direction_a: Float[Array, "3"]
    eye_center_b: Float[Array, "3"]
    direction_b: Float[Array, "3"]
    eye_in_head: float
    outlier_a: Bool[Array, " T"]
    outlier_b: Bool[Array, " T"]
    true_R_camera_from_world_a: Float[Array, "T 3 3"]
    true_centers_a: Float[Array, "T 3"]
    true_R_camera_from_world_b: Float[Array, "T 3 3"]
    true_centers_b: Float[Array, "T 3"]
    pose_noise_rotation: float
    pose_noise_position: float
    fps: float

    def points_of_regard_a(self) -> Float[Array, "... T 3"]:
        """A's points of regard in A's camera frame, ``y = R_A (C_B − C_A)`` (Sec. 3.2), from reported poses."""
        return jnp.einsum("...ij,...j->...i", self.R_camera_from_world_a, self.centers_b - self.centers_a)

    def points_of_regard_b(self) -> Float[Array, "... T 3"]:
        """B's points of regard in B's camera frame, ``y = R_B (C_A − C_B)``, from reported poses."""
        return jnp.einsum("...ij,...j->...i", self.R_camera_from_world_b, self.centers_a - self.centers_b)

    @property
    def mounting_a(self) -> Mounting:
        return Mounting(self.eye_center_a, self.direction_a)

    @property
    def mounting_b(self) -> Mounting:
        return Mounting(self.eye_center_b, self.direction_b)

    @property
    def num_frames(self) -> int:
        return self.frame_ids.shape[-1]

    def take(self, i) -> "CalibrationSession":
        """Session ``i`` of a batch from :func:`simulate_wearers` (array fields indexed, scalars kept)."""
        return CalibrationSession(*(f[i] if isinstance(f, jax.Array | np.ndarray) else f for f in self))


# ---------------------------------------------------------------------------
# Building blocks


def _mounting_from_pool(pool: Pool, shape=()) -> Mounting:
    lo = jnp.array([r[0] for r in EYE_CENTER_RANGE])
    hi = jnp.array([r[1] for r in EYE_CENTER_RANGE])
    eye = lo + (hi - lo) * pool.uniform(shape + (3,))
    yaw = pool.uniform(shape, -DIRECTION_OFFSET_MAX, DIRECTION_OFFSET_MAX)
    pitch = pool.uniform(shape, -DIRECTION_OFFSET_MAX, DIRECTION_OFFSET_MAX)
    return Mounting(eye, yaw_pitch_to_direction(yaw, pitch))


def random_mounting(key) -> Mounting:
    """Draw one wearer's mounting: eyes 5–10 cm below, 1–4 cm behind the camera; gaze ±5° yaw/pitch off +x.

    (Sessions draw their mountings from their own key; this helper is for
    building a ``mounting`` argument.)
    """
    return _mounting_from_pool(Pool(key, 5))


def _upright_frame(forward: Float[Array, "... 3"]) -> Float[Array, "... 3 3"]:
    """Columns ``(f, left, up')``: ``f`` unit, ``left = unit(e_z × f)``, ``up' = f × left``.

    Right-handed; ``up'`` lies in the vertical plane through ``f``. Requires ``f``
    away from ±z (true here: lines of sight are within ~45° of horizontal).
    """
    f = unit(forward)
    ez = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], f.dtype), f.shape)
    left = unit(jnp.cross(ez, f))
    up = jnp.cross(f, left)
    return jnp.stack([f, left, up], axis=-1)


def _motion(pool: Pool, num_frames: int, fps: float) -> Float[Array, "2 T 3"]:
    """True camera centres of A and B, ``(2, T, 3)``: back and forth, side to side (Sec. 4)."""
    duration = num_frames / fps
    t = jnp.arange(num_frames) / fps
    mid = pool.uniform((2,), -2.0, 2.0)
    phi = pool.uniform((), 0.0, 2 * math.pi)
    axis = jnp.stack([jnp.cos(phi), jnp.sin(phi)])
    perp = jnp.stack([-jnp.sin(phi), jnp.cos(phi)])
    separation = pool.uniform((), *SEPARATION_RANGE)

    def oscillation(amplitude_range):
        amp = pool.uniform((2,), *amplitude_range)
        period = pool.uniform((2,), *PERIOD_RANGE)
        cycles = jnp.maximum(MIN_CYCLES, duration / period)
        phase = pool.uniform((2,), 0.0, 2 * math.pi)
        return amp[:, None] * jnp.sin(2 * math.pi * cycles[:, None] * t[None, :] / duration + phase[:, None])

    along = oscillation(AXIAL_AMPLITUDE_RANGE)  # (2, T)
    across = oscillation(LATERAL_AMPLITUDE_RANGE)  # (2, T)
    sign = jnp.array([-1.0, 1.0])[:, None]
    s = sign * 0.5 * separation + along  # position along the axis; B − A = separation + along_B − along_A
    xy = mid + s[..., None] * axis + across[..., None] * perp
    height = pool.uniform((2,), *HEIGHT_RANGE)
    bob_freq = pool.uniform((2,), 1.5, 2.0)  # Hz, steps
    bob_phase = pool.uniform((2,), 0.0, 2 * math.pi)
    z = height[:, None] + BOB_AMPLITUDE * jnp.sin(2 * math.pi * bob_freq[:, None] * t[None, :] + bob_phase[:, None])
    return jnp.concatenate([xy, z[..., None]], axis=-1)


def _roll(pool: Pool, num_frames: int, fps: float) -> Float[Array, "2 T"]:
    t = jnp.arange(num_frames) / fps
    amp = pool.uniform((2,), 0.0, ROLL_MAX)
    period = pool.uniform((2,), 4.0, 12.0)
    phase = pool.uniform((2,), 0.0, 2 * math.pi)
    return amp[:, None] * jnp.sin(2 * math.pi * t[None, :] / period[:, None] + phase[:, None])


def _head_rotations(centers, eye, direction, z, u, roll, outlier, eye_in_head):
    """True ``R_camera_from_world`` of one wearer, ``(T, 3, 3)``, looking at the partner.

    ``centers (2, T, 3)`` is (self, partner); ``eye``, ``direction`` the mounting;
    ``z (T, 2)`` standard normals (eye-in-head); ``u (T, 2)`` uniforms (outlier
    angle, azimuth); ``roll (T,)``; ``outlier (T,)``.
    """
    c_self, c_other = centers
    u1, u2 = orthonormal_basis(direction)
    gaze = unit(direction + eye_in_head * (z[:, :1] * u1 + z[:, 1:] * u2))
    alpha = OUTLIER_ANGLE_RANGE[0] + (OUTLIER_ANGLE_RANGE[1] - OUTLIER_ANGLE_RANGE[0]) * u[:, :1]
    beta = 2 * math.pi * u[:, 1:]
    away = jnp.cos(alpha) * direction + jnp.sin(alpha) * (jnp.cos(beta) * u1 + jnp.sin(beta) * u2)
    gaze = jnp.where(outlier[:, None], away, gaze)  # (T, 3), camera frame

    # Point of regard in the camera frame: y = e + s v' with ‖y‖ = D = ‖C_other − C_self‖.
    w = c_other - c_self
    dist = jnp.linalg.norm(w, axis=-1, keepdims=True)
    b = gaze @ eye
    s = -b + jnp.sqrt(b * b - eye @ eye + dist[:, 0] ** 2)
    y = eye + s[:, None] * gaze

    # R_world_from_camera maps unit(y) to unit(w), upright, then roll about unit(w).
    # Rolling by r about unit(w) turns the world frame's (left, up) columns by r.
    frame_cam = _upright_frame(y)
    frame_world = _upright_frame(w)
    cos, sin = jnp.cos(roll)[:, None], jnp.sin(roll)[:, None]
    left, up = frame_world[..., 1], frame_world[..., 2]
    frame_world = jnp.stack([frame_world[..., 0], cos * left + sin * up, cos * up - sin * left], axis=-1)
    # R_camera_from_world = (F_world F_cameraᵀ)ᵀ = F_camera F_worldᵀ.
    return jnp.einsum("tij,tkj->tik", frame_cam, frame_world)


def _outlier_mask(u: Float[Array, " T"], fraction) -> Bool[Array, " T"]:
    """Exactly ``round(fraction · T)`` frames, chosen uniformly at random."""
    count = jnp.round(fraction * u.shape[0]).astype(jnp.int32)
    threshold = jnp.sort(u)[jnp.clip(count - 1, 0, u.shape[0] - 1)]
    return (u <= threshold) & (count > 0)


_SESSION_POOL = 10 + 64  # uniforms for the mounting (10) and the motion (64)


def _session_arrays(
    key, mounting, given, eye_in_head, pose_noise_rotation, pose_noise_position, outlier_fraction, *, num_frames, fps
):
    # One jax.random call per session: every threefry kernel adds compile time.
    # Mounting uniforms come first so the motion is the same whether or not
    # the mounting is drawn; per-frame normals come from the same uniforms.
    per_frame = 2 * num_frames * 11
    pool = Pool(key, _SESSION_POOL + per_frame)
    drawn = _mounting_from_pool(pool, (2,))
    pool.seek(10)
    # ``given`` is a traced flag, so drawn and given mountings share one compiled program.
    eye = jnp.where(given, jnp.asarray(mounting.eye_center_in_camera, jnp.float32), drawn.eye_center_in_camera)
    direction = jnp.where(given, jnp.asarray(mounting.direction_in_camera, jnp.float32), drawn.direction_in_camera)
    direction = unit(direction)

    centers = _motion(pool, num_frames, fps)  # (2, T, 3)
    roll = _roll(pool, num_frames, fps)  # (2, T)
    pool.seek(_SESSION_POOL)
    frame_u = pool.uniform((2, num_frames, 11))
    # Box–Muller: 8 standard normals from 8 uniforms (compiles faster than ndtri).
    radius = jnp.sqrt(-2.0 * jnp.log1p(-frame_u[..., :4]))  # 1 − u ∈ (0, 1]
    angle = 2 * math.pi * frame_u[..., 4:8]
    normal = jnp.concatenate([radius * jnp.cos(angle), radius * jnp.sin(angle)], axis=-1)
    uniform = frame_u[..., 8:]
    outlier = jax.vmap(_outlier_mask, in_axes=(0, None))(uniform[..., 0], outlier_fraction)

    pair = jnp.stack([centers, centers[::-1]])  # (2 wearers, 2 (self, other), T, 3)
    R_true = jax.vmap(_head_rotations, in_axes=(0, 0, 0, 0, 0, 0, 0, None))(
        pair, eye, direction, normal[..., :2], uniform[..., 1:], roll, outlier, eye_in_head
    )  # (2, T, 3, 3)

    R_noise = axis_angle_to_rotation_matrix(pose_noise_rotation * normal[..., 2:5])
    R_reported = jnp.einsum("wtij,wtjk->wtik", R_noise, R_true)
    centers_reported = centers + pose_noise_position * normal[..., 5:8]
    return R_reported, centers_reported, R_true, centers, eye, direction, outlier


@partial(jax.jit, static_argnames=("num_frames", "fps"))
def _simulate_one(key, mounting, given, eye_in_head, rot, pos, frac, *, num_frames, fps):
    return _session_arrays(key, mounting, given, eye_in_head, rot, pos, frac, num_frames=num_frames, fps=fps)


@partial(jax.jit, static_argnames=("num_frames", "fps"))
def _simulate_many(keys, mounting, given, eye_in_head, rot, pos, frac, *, num_frames, fps):
    one = partial(_session_arrays, num_frames=num_frames, fps=fps)
    in_axes = (0, None, None, None, None, None, None)
    return jax.vmap(one, in_axes=in_axes)(keys, mounting, given, eye_in_head, rot, pos, frac)


# ---------------------------------------------------------------------------
# Public API


def _check_params(num_frames, eye_in_head, pose_noise_rotation, pose_noise_position, outlier_fraction, fps):
    num_frames = check_int("num_frames", num_frames, lo=2)
    values = {
        "eye_in_head": check_number("eye_in_head", eye_in_head, lo=0.0),
        "pose_noise_rotation": check_number("pose_noise_rotation", pose_noise_rotation, lo=0.0),
        "pose_noise_position": check_number("pose_noise_position", pose_noise_position, lo=0.0),
        "outlier_fraction": check_number("outlier_fraction", outlier_fraction, lo=0.0, hi=1.0),
        "fps": check_number("fps", fps, lo=0.0, lo_open=True),
    }
    return num_frames, values


def _check_mounting(mounting) -> tuple[Mounting, bool]:
    """``None``; a :class:`Mounting` with ``(3,)`` fields (both wearers) or ``(2, 3)`` (A, B); or a pair.

    Returns ``(mounting with (2, 3) fields, given)``; a placeholder when ``None``.
    """
    if mounting is None:
        return Mounting(jnp.zeros((2, 3)), jnp.tile(jnp.array([1.0, 0.0, 0.0]), (2, 1))), False
    if not isinstance(mounting, Mounting):
        if isinstance(mounting, (tuple, list)) and len(mounting) == 2:
            a, b = (m if isinstance(m, Mounting) else Mounting(*m) for m in mounting)
            mounting = Mounting(
                jnp.stack([jnp.asarray(a[0]), jnp.asarray(b[0])]), jnp.stack([jnp.asarray(a[1]), jnp.asarray(b[1])])
            )
        else:
            raise ValueError("mounting must be None, a Mounting, or a pair (mounting_a, mounting_b)")
    eye = np.asarray(mounting.eye_center_in_camera, np.float32)
    direction = np.asarray(mounting.direction_in_camera, np.float32)
    if eye.shape == (3,):
        eye = np.broadcast_to(eye, (2, 3))
    if direction.shape == (3,):
        direction = np.broadcast_to(direction, (2, 3))
    if eye.shape != (2, 3) or direction.shape != (2, 3):
        raise ValueError(
            f"mounting fields must be (3,) or (2, 3), got {mounting.eye_center_in_camera!r} and "
            f"{mounting.direction_in_camera!r}"
        )
    if not (np.all(np.isfinite(eye)) and np.all(np.isfinite(direction))):
        raise ValueError("mounting holds NaN or inf")
    if np.any(np.linalg.norm(direction, axis=-1) < 1e-6):
        raise ValueError("mounting.direction_in_camera must be non-zero")
    if np.any(np.linalg.norm(eye, axis=-1) > 0.5):
        raise ValueError("mounting.eye_center_in_camera must lie within 0.5 m of the camera")
    return Mounting(jnp.asarray(eye), jnp.asarray(direction)), True


def _build(arrays, num_frames, values, batch_shape=()):
    R, C, R_true, C_true, eye, direction, outlier = arrays
    ids = jnp.broadcast_to(jnp.arange(num_frames, dtype=jnp.int32), batch_shape + (num_frames,))
    w = len(batch_shape)  # axis of the wearer index

    def pick(x, i):
        return jnp.take(x, i, axis=w)

    return CalibrationSession(
        R_camera_from_world_a=pick(R, 0),
        centers_a=pick(C, 0),
        R_camera_from_world_b=pick(R, 1),
        centers_b=pick(C, 1),
        frame_ids=ids,
        eye_center_a=pick(eye, 0),
        direction_a=pick(direction, 0),
        eye_center_b=pick(eye, 1),
        direction_b=pick(direction, 1),
        eye_in_head=values["eye_in_head"],
        outlier_a=pick(outlier, 0),
        outlier_b=pick(outlier, 1),
        true_R_camera_from_world_a=pick(R_true, 0),
        true_centers_a=pick(C_true, 0),
        true_R_camera_from_world_b=pick(R_true, 1),
        true_centers_b=pick(C_true, 1),
        pose_noise_rotation=values["pose_noise_rotation"],
        pose_noise_position=values["pose_noise_position"],
        fps=values["fps"],
    )


def simulate_calibration_session(
    key,
    num_frames: int = 300,
    *,
    mounting=None,
    eye_in_head: float = 0.03,
    pose_noise_rotation: float = 0.005,
    pose_noise_position: float = 0.01,
    outlier_fraction: float = 0.0,
    fps: float = 10.0,
) -> CalibrationSession:
    """Simulate one calibration pair (A, B) of Park et al. (2012), Sec. 3.2 and 4.

    A and B look at each other's camera while moving back and forth and side to
    side (≥ 3 cycles each); see the module docstring for the model.

    Args:
        key: ``jax.random`` key; the same key gives the same session.
        num_frames: number of frames ``T`` (≥ 2; ≥ ~20 to resolve 3 cycles).
        mounting: ``None`` to draw both wearers' mountings from ``key``; a
            :class:`Mounting` with ``(3,)`` fields (both wearers) or ``(2, 3)``
            fields (A, B); or a pair ``(mounting_a, mounting_b)``.
        eye_in_head: std ``h`` of each eye-in-head offset on the unit plane (radians).
        pose_noise_rotation: std of each axis-angle component of the reported
            camera orientation error (radians).
        pose_noise_position: std of each coordinate of the reported camera centre error (m).
        outlier_fraction: fraction of frames (rounded, chosen at random, per
            wearer) on which the wearer looks 10°–30° away from the partner.
        fps: frames per second.
    """
    check_key(key)
    num_frames, values = _check_params(
        num_frames, eye_in_head, pose_noise_rotation, pose_noise_position, outlier_fraction, fps
    )
    mounting, given = _check_mounting(mounting)
    arrays = _simulate_one(
        key,
        mounting,
        given,
        values["eye_in_head"],
        values["pose_noise_rotation"],
        values["pose_noise_position"],
        values["outlier_fraction"],
        num_frames=num_frames,
        fps=values["fps"],
    )
    return _build(arrays, num_frames, values)


def simulate_wearers(
    key,
    num_wearers: int,
    num_frames: int = 300,
    *,
    mounting=None,
    eye_in_head: float = 0.03,
    pose_noise_rotation: float = 0.005,
    pose_noise_position: float = 0.01,
    outlier_fraction: float = 0.0,
    fps: float = 10.0,
) -> CalibrationSession:
    """A batch of ``num_wearers`` independent calibration sessions (Park et al. Sec. 3.2, 4).

    Session ``i`` uses key ``jax.random.split(key, num_wearers)[i]``; wearer
    ``i`` is its A (the partner B is another independent wearer, so the batch
    holds ``2 · num_wearers`` calibratable wearers). Array fields gain a leading
    axis ``(num_wearers, ...)``; ``take(i)`` returns session ``i``. Other
    arguments as in :func:`simulate_calibration_session` (a given ``mounting``
    is shared by all sessions). One vmapped, jitted pass.
    """
    check_key(key)
    num_wearers = check_int("num_wearers", num_wearers)
    num_frames, values = _check_params(
        num_frames, eye_in_head, pose_noise_rotation, pose_noise_position, outlier_fraction, fps
    )
    mounting, given = _check_mounting(mounting)
    keys = jax.random.split(key, int(num_wearers))
    arrays = _simulate_many(
        keys,
        mounting,
        given,
        values["eye_in_head"],
        values["pose_noise_rotation"],
        values["pose_noise_position"],
        values["outlier_fraction"],
        num_frames=num_frames,
        fps=values["fps"],
    )
    return _build(arrays, num_frames, values, batch_shape=(int(num_wearers),))
