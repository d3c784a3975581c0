"""Contaminated gaze offsets with a known bias: the test bed of the bias estimators (Siegfried et al. 2017, Sec. 3.2).

A person with bias ``b`` who looks at the partner gives an offset ``o = b + ε`` with
``ε ~ N(0, s² I₂)`` (``s`` the on-target spread); a glance elsewhere, displaced by
``δ`` from the partner, gives ``o = b + δ``, with ``δ`` uniform in the square
``[−w, w]²`` (``w`` the glance spread). Each frame is a glance with probability
``outlier_share``. The bias is uniform in ``[−15°, 15°]²``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from jaxgaze.geometry import deg_to_rad

__all__ = ["ContaminatedOffsets", "simulate_offsets"]

#: The biases are uniform within ± this many degrees on each axis.
BIAS_RANGE_DEG = 15.0


class ContaminatedOffsets(NamedTuple):
    """Offset sets with their truth (radians; leading axis: the set).

    Attributes:
        offsets: ``(S, N, 2)`` offsets (yaw, tilt).
        bias: ``(S, 2)`` the true bias of each set.
        looking: ``(S, N)`` whether each frame looks at the partner.
    """

    offsets: Float[Array, "S N 2"]
    bias: Float[Array, "S 2"]
    looking: Bool[Array, "S N"]


def simulate_offsets(
    key: PRNGKeyArray,
    num_sets: int,
    num_frames: int,
    *,
    outlier_share: float,
    outlier_spread_deg: float,
    on_target_spread_deg: float,
) -> ContaminatedOffsets:
    """``num_sets`` independent sets of ``num_frames`` offsets, each with its own bias (see the module)."""
    if num_sets < 1 or num_frames < 1:
        raise ValueError(f"num_sets and num_frames must be at least 1, got {num_sets} and {num_frames}")
    if not 0.0 <= outlier_share < 1.0:
        raise ValueError(f"outlier_share must lie in [0, 1), got {outlier_share}")
    if not (outlier_spread_deg > 0 and on_target_spread_deg > 0):
        raise ValueError("outlier_spread_deg and on_target_spread_deg must be positive")
    k_bias, k_noise, k_glance, k_which = jax.random.split(key, 4)
    bias = jax.random.uniform(k_bias, (num_sets, 2), minval=-1.0, maxval=1.0) * deg_to_rad(BIAS_RANGE_DEG)
    noise = jax.random.normal(k_noise, (num_sets, num_frames, 2)) * deg_to_rad(on_target_spread_deg)
    glance = jax.random.uniform(k_glance, (num_sets, num_frames, 2), minval=-1.0, maxval=1.0)
    glance = glance * deg_to_rad(outlier_spread_deg)
    looking = jax.random.uniform(k_which, (num_sets, num_frames)) >= outlier_share
    offsets = bias[:, None, :] + jnp.where(looking[..., None], noise, glance)
    return ContaminatedOffsets(offsets, bias, looking)
