"""The regression's input per frame: the tracked head pose (Yücel et al., T-CYB 2013, Sec. V)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["head_pose_features"]


def head_pose_features(pose, position=None) -> Float[Array, "T D"]:
    """Gaze-regression features ``x_t``: ``(pitch, yaw, roll)`` (radians), ``(T, 3)`` (Yücel et al. 2013, Sec. V).

    With ``position`` (the head position ``(x, y, z)`` per frame, metres, ``(T, 3)``)
    the features are T-CYB's full pose ``[pose, position]``, ``(T, 6)``. Leaving the
    position out is usually better: the head's rest position differs between sessions
    by centimetres while it sways by millimetres within one, so a regressor trained on
    one session extrapolates badly in those columns.

    Raises ``ValueError`` naming the argument when a shape is not ``(T, 3)``.
    """
    pose = jnp.asarray(pose)
    if pose.ndim != 2 or pose.shape[-1] != 3:
        raise ValueError(f"head_pose_features: pose must be (T, 3) (pitch, yaw, roll), got shape {pose.shape}")
    if position is None:
        return pose
    position = jnp.asarray(position)
    if position.shape != pose.shape:
        raise ValueError(
            f"head_pose_features: position must be (T, 3) like pose {pose.shape}, got shape {position.shape}"
        )
    return jnp.concatenate([pose, position], axis=-1)
