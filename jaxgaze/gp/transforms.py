"""The one map between constrained (natural) and unconstrained kernel parameters.

Every positive kernel parameter (variances, lengthscales, the rational-quadratic
``alpha``) is stored unconstrained as ``raw`` and read as

    value = exp(raw) + POSITIVE_FLOOR.

The log map makes the optimiser work on relative changes: one unit of ``raw``
multiplies a lengthscale by e whatever its size, which suits BFGS for
parameters whose plausible ranges span decades. Away from the floor ``raw`` is
``log(value)``, i.e. scikit-learn's ``theta``. The floor (1e-12) keeps a
lengthscale or variance from underflowing to exactly 0 (``exp`` underflows for
``raw`` < −103 in float32), which would make the kernel divide by zero.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

__all__ = ["FIT_BOUNDS", "POSITIVE_FLOOR", "bound_penalty", "positive", "unconstrain_positive"]

#: Smallest value a positive parameter can take.
POSITIVE_FLOOR = 1e-12

#: ``(low, high)`` natural values that :func:`jaxgaze.gp.fit` keeps every trained
#: parameter within: scikit-learn's default hyperparameter bounds. Some likelihoods
#: rise forever along a ridge (the arc-sine weight and bias variances growing
#: together towards a scale-free limit, measured running to 1e6–1e12); there ``K``
#: becomes singular in float32 and the fit stopped on a non-finite gradient.
FIT_BOUNDS = (1e-5, 1e5)


def bound_penalty(raw: Float[Array, " p"], stiffness) -> Float[Array, ""]:
    """``½ · stiffness · Σ d²``, ``d`` the distance of ``raw`` outside ``log FIT_BOUNDS``.

    Zero inside the bounds (the fit's objective is the exact −LML there); a quadratic
    wall outside, so the optimiser stays a smooth unconstrained one.
    """
    lo, hi = (float(np.log(b)) for b in FIT_BOUNDS)
    excess = jnp.maximum(raw - hi, 0.0) + jnp.maximum(lo - raw, 0.0)
    return 0.5 * stiffness * jnp.sum(excess**2)


def positive(raw: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
    """Natural value ``exp(raw) + POSITIVE_FLOOR`` of an unconstrained parameter."""
    raw = jnp.asarray(raw)
    return jnp.exp(raw) + jnp.asarray(POSITIVE_FLOOR, raw.dtype)


def unconstrain_positive(value: ArrayLike, *, name: str = "value") -> Float[Array, "*shape"]:
    """Inverse of :func:`positive`: ``log(value − POSITIVE_FLOOR)``.

    A concrete ``value`` must be finite and larger than ``POSITIVE_FLOOR``
    (else ``ValueError`` naming ``name``). Traced values (inside ``jit``) are
    not checked.
    """
    if isinstance(value, jax.core.Tracer):
        return jnp.log(value - POSITIVE_FLOOR)
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be a real number or array, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite and positive, got {value!r}")
    if np.any(arr <= POSITIVE_FLOOR):
        raise ValueError(f"{name} must be positive (> {POSITIVE_FLOOR:g}), got {value!r}")
    return jnp.asarray(np.log(arr - POSITIVE_FLOOR))
