"""Shared geometry: directions, angles, rotations and the perspective distance.

Conventions (see ``docs/conventions.md``):

* Frames are right-handed. *World* is the scene frame (z up, metres). *Head* and
  *camera* frames have +x forward (the primary gaze direction), +y left, +z up.
* Angles are radians. Only names ending in ``_deg`` hold degrees.
* ``yaw`` turns about +z, positive to the left (from +x toward +y); ``pitch`` is
  elevation, positive up (toward +z).
* A rotation matrix ``R_world_from_head`` maps head-frame vectors to world:
  ``v_world = R_world_from_head @ v_head``. Quaternions are ``(w, x, y, z)``,
  scalar first, unit norm, and represent the same active rotation.

Every function works on a single item; lift it with ``jax.vmap`` or rely on the
broadcasting noted in each docstring.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "unit",
    "yaw_pitch_to_direction",
    "direction_to_yaw_pitch",
    "angle_between",
    "deg_to_rad",
    "rad_to_deg",
    "quaternion_to_rotation_matrix",
    "rotation_matrix_to_quaternion",
    "axis_angle_to_rotation_matrix",
    "head_pose_to_rotation",
    "rotation_to_head_pose",
    "wrap_angle",
    "orthonormal_basis",
    "ray_depth",
    "perspective_distance",
]


#: ``v_ours = R_OURS_FROM_OPENCV @ v_opencv``. OpenCV/COLMAP camera axes are
#: x right, y down, z forward; ours are x forward, y left, z up. So
#: our x = OpenCV z, our y = −(OpenCV x), our z = −(OpenCV y). det = +1.
#: A COLMAP world-to-camera rotation converts as
#: ``R_camera_from_world = R_OURS_FROM_OPENCV @ R_opencv_camera_from_world``.
R_OURS_FROM_OPENCV = np.array(
    [
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ]
)
R_OURS_FROM_OPENCV.setflags(write=False)


def _tiny(x: Array) -> Array:
    return jnp.finfo(jnp.result_type(x, jnp.float32)).tiny


def unit(v: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """``v / ‖v‖`` along the last axis. Zero vectors stay zero (no NaN).

    The gradient at a zero vector is zero rather than NaN (double ``where``:
    the square root is never taken of 0).
    """
    v = jnp.asarray(v)
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    nonzero = sq > _tiny(v)
    norm = jnp.sqrt(jnp.where(nonzero, sq, 1.0))
    return jnp.where(nonzero, v / norm, jnp.zeros_like(v))


def deg_to_rad(angle_deg):
    """Degrees → radians."""
    return jnp.deg2rad(angle_deg)


def rad_to_deg(angle):
    """Radians → degrees."""
    return jnp.rad2deg(angle)


def yaw_pitch_to_direction(yaw: Float[Array, "..."], pitch: Float[Array, "..."]) -> Float[Array, "... 3"]:
    """Unit direction from yaw (about +z, left positive) and pitch (up positive).

    ``(cos p cos y, cos p sin y, sin p)``; ``yaw = pitch = 0`` is +x. Broadcasts.
    """
    yaw, pitch = jnp.broadcast_arrays(jnp.asarray(yaw), jnp.asarray(pitch))
    cp = jnp.cos(pitch)
    return jnp.stack([cp * jnp.cos(yaw), cp * jnp.sin(yaw), jnp.sin(pitch)], axis=-1)


def direction_to_yaw_pitch(direction: Float[Array, "... 3"]) -> tuple[Array, Array]:
    """Inverse of :func:`yaw_pitch_to_direction` (the direction need not be unit).

    Returns ``(yaw, pitch)`` with yaw in (−π, π] and pitch in [−π/2, π/2].
    """
    x, y, z = direction[..., 0], direction[..., 1], direction[..., 2]
    # At a pole (x² + y² = 0, also when subnormal x, y are flushed to zero) yaw is 0:
    # XLA's atan2 and hypot give 0/0 = NaN for subnormal inputs (found by hypothesis).
    r2 = x * x + y * y
    off_pole = r2 > 0
    yaw = _arctan2(jnp.where(off_pole, y, 0.0), jnp.where(off_pole, x, 1.0))
    return yaw, _arctan2(z, jnp.sqrt(r2))


def _arctan2(y, x):
    """``atan2(y, x)``: XLA's in float64; in float32 the octant reduction and the polynomial of Cephes' ``atanf``
    (Moshier 1992) with the exact derivative ``(x dy − y dx) / (x² + y²)``.

    Measured reason: XLA:CPU's float32 ``atan2`` does not vectorise. Value and gradient of ``yaw`` and ``pitch`` of
    ``(640, 12)`` directions took 254 against 78 µs here, and a gradient of the head-pose-only joint model with a
    fixation's spot, whose concurrences' angles it gives, 3.47 against 3.17 ms (60 s × 6 people, one core,
    ``benchmarks/RESULTS.md``). Its largest error against a float64 ``atan2``, over 10⁵ pairs of magnitudes
    10⁻⁶–10⁶, is 2.7·10⁻⁷ rad, as XLA's own (``tests/test_geometry.py``).
    """
    y, x = jnp.broadcast_arrays(jnp.asarray(y), jnp.asarray(x))
    if jnp.result_type(y, x) != jnp.float32:
        return jnp.arctan2(y, x)
    return _arctan2_float32(y.astype(jnp.float32), x.astype(jnp.float32))


@jax.custom_jvp
def _arctan2_float32(y, x):
    ax, ay = jnp.abs(x), jnp.abs(y)
    big, small = jnp.maximum(ax, ay), jnp.minimum(ax, ay)
    t = small / jnp.where(big > 0, big, 1.0)  # tan of the angle folded into [0, π/4]
    above = t > math.tan(math.pi / 8)  # then tan(a − π/4), in [tan(−π/8), 0]
    u = jnp.where(above, (t - 1.0) / (t + 1.0), t)
    z = u * u
    a = (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * u + u
    a = jnp.where(above, math.pi / 4 + a, a)
    a = jnp.where(ay > ax, math.pi / 2 - a, a)
    a = jnp.where(x < 0, math.pi - a, a)
    return jnp.where(y < 0, -a, a)


@_arctan2_float32.defjvp
def _arctan2_float32_jvp(primals, tangents):
    y, x = primals
    dy, dx = tangents
    return _arctan2_float32(y, x), (x * dy - y * dx) / (x * x + y * y)


def angle_between(a: Float[Array, "... 3"], b: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """Angle in radians between two directions, in [0, π].

    Uses ``atan2(‖a×b‖, a·b)``, which stays accurate for tiny and near-π angles
    where ``arccos`` of the dot product loses precision.
    """
    c = jnp.cross(a, b)
    cross_sq = jnp.sum(c * c, axis=-1)
    # ‖a×b‖ with a finite (zero) gradient where a ∥ b instead of NaN.
    nonzero = cross_sq > 0
    cross = jnp.where(nonzero, jnp.sqrt(jnp.where(nonzero, cross_sq, 1.0)), 0.0)
    dot = jnp.sum(a * b, axis=-1)
    return jnp.arctan2(cross, dot)


def quaternion_to_rotation_matrix(q: Float[Array, "... 4"]) -> Float[Array, "... 3 3"]:
    """Unit quaternion ``(w, x, y, z)`` → rotation matrix (normalises ``q`` first)."""
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def rotation_matrix_to_quaternion(R: Float[Array, "3 3"]) -> Float[Array, "4"]:
    """Rotation matrix → unit quaternion ``(w, x, y, z)`` with ``w ≥ 0``.

    Shepperd's method: take the largest of the four candidate pivots so the
    division is always by a number ≥ 1/2. Single matrix; ``vmap`` for batches.
    """
    t = jnp.trace(R)
    candidates = jnp.stack(
        [
            jnp.array([1 + t, R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]),
            jnp.array([R[2, 1] - R[1, 2], 1 + 2 * R[0, 0] - t, R[0, 1] + R[1, 0], R[0, 2] + R[2, 0]]),
            jnp.array([R[0, 2] - R[2, 0], R[0, 1] + R[1, 0], 1 + 2 * R[1, 1] - t, R[1, 2] + R[2, 1]]),
            jnp.array([R[1, 0] - R[0, 1], R[0, 2] + R[2, 0], R[1, 2] + R[2, 1], 1 + 2 * R[2, 2] - t]),
        ]
    )
    pivots = jnp.array([1 + t, 1 + 2 * R[0, 0] - t, 1 + 2 * R[1, 1] - t, 1 + 2 * R[2, 2] - t])
    q = candidates[jnp.argmax(pivots)]
    q = q / jnp.linalg.norm(q)
    return jnp.where(q[0] < 0, -q, q)


def axis_angle_to_rotation_matrix(rotation_vector: Float[Array, "... 3"]) -> Float[Array, "... 3 3"]:
    """Rodrigues: rotation vector ``θ a`` (axis ``a``, angle θ in radians) → matrix.

    Uses the quaternion ``(cos θ/2, sin(θ/2) a)`` so that θ → 0 is smooth.
    """
    rotation_vector = jnp.asarray(rotation_vector)
    theta_sq = jnp.sum(rotation_vector * rotation_vector, axis=-1, keepdims=True)
    # sin(θ/2)/θ → 1/2 and cos(θ/2) → 1 as θ → 0. θ is never formed as √0 and
    # the double where keeps gradients finite (no NaN) at θ = 0.
    large = theta_sq > 1e-16
    safe = jnp.sqrt(jnp.where(large, theta_sq, 1.0))
    scale = jnp.where(large, jnp.sin(0.5 * safe) / safe, 0.5 - theta_sq / 48.0)
    w = jnp.where(large, jnp.cos(0.5 * safe), 1.0 - theta_sq / 8.0)
    q = jnp.concatenate([w, scale * rotation_vector], axis=-1)
    return quaternion_to_rotation_matrix(q)


def head_pose_to_rotation(yaw, pitch, roll) -> Float[Array, "... 3 3"]:
    """``R_frontal_from_head = R_z(yaw) R_y(−pitch) R_x(roll)`` (radians; broadcasts to ``(..., 3, 3)``).

    Head frame axes as in ``docs/conventions.md`` (+x forward, +y left, +z up). Yaw > 0
    turns the face to the person's left, pitch > 0 up, roll > 0 raises the left ear. The
    *frontal* frame is the head's pose at rest; a camera-specific frame is one fixed
    rotation more, e.g. ``R_optical_from_head = R_optical_from_frontal @ R_frontal_from_head``.
    """
    yaw, pitch, roll = jnp.broadcast_arrays(jnp.asarray(yaw), jnp.asarray(pitch), jnp.asarray(roll))
    zeros = jnp.zeros_like(yaw)

    def about(axis, angle):
        v = [zeros, zeros, zeros]
        v[axis] = angle
        return axis_angle_to_rotation_matrix(jnp.stack(v, axis=-1))

    return about(2, yaw) @ about(1, -pitch) @ about(0, roll)


def rotation_to_head_pose(R: Float[Array, "... 3 3"]) -> tuple[Array, Array, Array]:
    """Inverse of :func:`head_pose_to_rotation`: ``(yaw, pitch, roll)``, pitch in [−π/2, π/2].

    ``(yaw, pitch) = direction_to_yaw_pitch(R e_x)`` (the forward axis) and
    ``roll = atan2(R₂₁, R₂₂)``.
    """
    R = jnp.asarray(R)
    yaw, pitch = direction_to_yaw_pitch(R[..., :, 0])
    roll = jnp.arctan2(R[..., 2, 1], R[..., 2, 2])
    return yaw, pitch, roll


def wrap_angle(angle):
    """Angle wrapped to (−π, π]: ``a − 2π ⌈(a − π) / 2π⌉``.

    Exact (``a`` itself) for ``a`` in (−π, π], and π in the input's precision maps to
    +π. The gradient is 1. NumPy arrays and scalars are wrapped in NumPy at their own
    precision (and stay NumPy); anything else (Python numbers, JAX arrays, tracers) in JAX.
    """
    xp = np if isinstance(angle, (np.ndarray, np.generic)) else jnp
    angle = xp.asarray(angle)
    return angle - 2 * np.pi * xp.ceil((angle - np.pi) / (2 * np.pi))


def orthonormal_basis(v: Float[Array, "3"]) -> tuple[Array, Array]:
    """Two unit vectors ``u1, u2`` with ``(v, u1, u2)`` right-handed orthonormal.

    ``v`` must be unit. Branch-free (Duff et al. 2017, "Building an orthonormal
    basis, revisited"), so it is vmappable and accurate near ±z. It is smooth
    within each hemisphere ``z ≥ 0`` and ``z < 0`` but jumps at ``z = 0``: no
    continuous tangent frame exists on the whole sphere.
    """
    x, y, z = v[0], v[1], v[2]
    sign = jnp.where(z >= 0, 1.0, -1.0).astype(v.dtype)
    a = -1.0 / (sign + z)
    b = x * y * a
    u1 = jnp.array([1 + sign * x * x * a, sign * b, -sign * x])
    u2 = jnp.array([b, sign + y * y * a, -y])
    return u1, u2


def ray_depth(origin: Float[Array, "3"], direction: Float[Array, "3"], x: Float[Array, "3"]) -> Array:
    """Depth of ``x`` along a ray, ``t = vᵀ(x − p)`` (Park et al. 2012, eq. 4)."""
    return jnp.dot(direction, x - origin)


def perspective_distance(
    origin: Float[Array, "3"], direction: Float[Array, "3"], x: Float[Array, "3"]
) -> tuple[Float[Array, "3"], Array]:
    """Perspective distance vector ``d(l, x)`` (Park et al. 2012, eq. 4).

    With ``t = vᵀ(x − p)`` and the projection ``x̂ = p + t v``,
    ``d = (x − x̂) / t``: the offset of ``x`` from the ray divided by its depth,
    i.e. the tangent of the angle at the eye between the ray and ``x``.

    Returns ``(d, in_front)``. Behind the eye (``t ≤ 0``) the paper sets
    ``d = ∞``; here ``d`` is returned as zeros and ``in_front`` is ``False`` so
    callers can mask without producing inf/NaN in values or gradients.
    """
    t = ray_depth(origin, direction, x)
    in_front = t > 0
    safe_t = jnp.where(in_front, t, 1.0)
    offset = x - origin - t * direction
    d = jnp.where(in_front, offset / safe_t, 0.0)
    return d, in_front


def similarity_alignment(
    source: Float[Array, "M 3"], target: Float[Array, "M 3"]
) -> tuple[Array, Float[Array, "3 3"], Float[Array, "3"]]:
    """Least-squares similarity ``target ≈ scale · R @ source + t`` (Umeyama 1991).

    Closed form: with the centred point sets ``S``, ``T`` and the cross-covariance
    ``Σ = Tᵀ S / M = U D Vᵀ`` (SVD), ``R = U E Vᵀ`` with
    ``E = diag(1, 1, sign(det U · det V))`` (the reflection fix, so ``det R = +1``
    even when the best orthogonal fit is a mirror), ``scale = tr(D E) / σ²_source``
    and ``t = μ_target − scale · R μ_source``. It minimises
    ``Σ_i ‖target_i − (scale · R source_i + t)‖²``.

    Use it to bring one world frame into another, e.g. SfM camera centres into
    the mocap frame (Park et al. 2012, Sec. 4.1), then map points with
    :func:`apply_similarity`.

    Returns ``(scale, R, t)``: a scalar, ``(3, 3)`` and ``(3,)``.

    Raises ``ValueError`` if the shapes are not ``(M, 3)`` with the same ``M ≥ 3``
    and, for concrete (non-traced) inputs, if any value is NaN or infinite or the
    source points are degenerate (all coincident or collinear: the rotation about
    their line is undetermined). Under ``jit``/``vmap`` only the shape checks run.
    """
    source = jnp.asarray(source)
    target = jnp.asarray(target)
    if source.ndim != 2 or source.shape[-1] != 3:
        raise ValueError(f"similarity_alignment: source must be (M, 3), got shape {source.shape}")
    if target.shape != source.shape:
        raise ValueError(
            f"similarity_alignment: target must have the shape of source {source.shape}, got {target.shape}"
        )
    m = source.shape[0]
    if m < 3:
        raise ValueError(f"similarity_alignment: need at least 3 point pairs, got {m}")
    dtype = jnp.result_type(source, target, jnp.float32)
    source = source.astype(dtype)
    target = target.astype(dtype)

    if not any(isinstance(a, _jax.core.Tracer) for a in (source, target)):
        import numpy as np

        src = np.asarray(source, dtype=np.float64)
        if not (np.all(np.isfinite(src)) and np.all(np.isfinite(np.asarray(target)))):
            raise ValueError("similarity_alignment: source and target must be finite (no NaN or inf)")
        sv = np.linalg.svd(src - src.mean(axis=0), compute_uv=False)
        tol = 1000.0 * float(jnp.finfo(dtype).eps) * float(sv[0])  # rounding, not shape
        if sv[0] == 0.0 or sv[1] <= tol:
            raise ValueError(
                "similarity_alignment: source points are degenerate (coincident or collinear); "
                "need at least 3 points that span a plane"
            )
    return _similarity_alignment_core(source, target)


def _similarity_alignment_core(source, target):
    """Umeyama's closed form; no checks (see :func:`similarity_alignment`)."""
    m = source.shape[0]
    dtype = source.dtype
    mu_s = jnp.mean(source, axis=0)
    mu_t = jnp.mean(target, axis=0)
    src = source - mu_s
    tgt = target - mu_t
    sigma = tgt.T @ src / m
    U, D, Vt = jnp.linalg.svd(sigma)
    d = jnp.sign(jnp.linalg.det(U) * jnp.linalg.det(Vt))
    d = jnp.where(d == 0, 1.0, d).astype(dtype)
    E = jnp.array([1.0, 1.0, 0.0], dtype=dtype) + jnp.array([0.0, 0.0, 1.0], dtype=dtype) * d
    R = (U * E) @ Vt
    var_s = jnp.sum(src * src) / m
    scale = jnp.sum(D * E) / var_s
    t = mu_t - scale * R @ mu_s
    return scale, R, t


def apply_similarity(
    points: Float[Array, "... 3"], scale, R: Float[Array, "3 3"], t: Float[Array, "3"]
) -> Float[Array, "... 3"]:
    """``scale · R @ x + t`` for every point ``x`` along the last axis (broadcasts)."""
    points = jnp.asarray(points)
    return scale * jnp.einsum("ij,...j->...i", R, points) + t


import jax as _jax  # noqa: E402  (appended section)

_similarity_alignment_core = _jax.jit(_similarity_alignment_core)

__all__ += ["similarity_alignment", "apply_similarity"]
