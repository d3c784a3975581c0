"""Extremum-seeking control of the hypothesis threshold ``T_h`` (ROVIS gaze following,
"Human–Robot Interaction Through Robust Gaze Following", Sec. 3–4, Fig. 5–6).

The cascade's confidence ``y_f = J(T_h)`` (eq. 2) has an unknown maximum in ``T_h``:
too low a threshold floods the cascade with false hypotheses, too high a threshold
rejects true ones. Extremum seeking finds the maximiser from measurements of ``y``
alone (Ariyur & Krstić 2003, discrete time). At step ``k``:

.. code-block:: text

    θ_k   = θ̂_k + a sin(ω k)                 probe (perturbation, amplitude a)
    y_k   = J(θ_k) (+ noise)                  measure
    ȳ_k   = ȳ_{k−1} + h (y_k − ȳ_{k−1})        low-pass (washout), 0 < h ≤ 1
    η_k   = y_k − ȳ_{k−1}                     high-pass: removes the DC level of J
    ξ_k   = η_k sin(ω k)                      demodulate with the same sinusoid
    θ̂_{k+1} = clip(θ̂_k + γ ξ_k, bounds)       integrate (gain γ > 0 maximises)

For small ``a``, ``J(θ̂ + a sin ωk) ≈ J(θ̂) + a J'(θ̂) sin ωk``; averaged over a
period ``E[ξ] ≈ (a / 2) J'(θ̂)``, so ``θ̂`` follows gradient ascent at rate ``γ a / 2``
and settles where ``J' = 0`` (a maximum; a negative ``gain`` seeks a minimum). The
residual ripple is of order ``γ a² / 2``; use ``ω`` well below Nyquist (π per step).
A vector ``θ`` needs distinct frequencies per component (``frequency`` broadcasts).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

__all__ = ["ESCTrajectory", "extremum_seeking"]


class ESCTrajectory(NamedTuple):
    """Per-step history, leading axis ``num_steps``.

    Attributes:
        theta_hat: the estimate ``θ̂_k`` (before the update at step ``k``).
        theta: the probed parameter ``θ_k = θ̂_k + a sin ωk``.
        y: the measured objective ``y_k``.
        gradient: the demodulated signal ``ξ_k`` (≈ ``(a/2) J'(θ̂)`` on average).
        final: ``θ̂`` after the last step (no leading axis).
    """

    theta_hat: Array
    theta: Array
    y: Array
    gradient: Array
    final: Array


def extremum_seeking(
    objective: Callable,
    theta0,
    *,
    amplitude,
    frequency,
    gain: float,
    num_steps: int,
    highpass: float = 0.1,
    bounds: tuple[float, float] | None = None,
    key: Array | None = None,
) -> ESCTrajectory:
    """Run a discrete extremum-seeking loop with ``lax.scan`` (ROVIS gaze following, Fig. 5–6).

    Pure JAX and jittable; the loop is that of the module docstring (Ariyur & Krstić 2003).

    Args:
        objective: ``objective(theta, key) -> y`` (scalar); ``key`` is a fresh
            ``jax.random`` key per step for noisy objectives (ignore it otherwise).
        theta0: initial estimate (scalar or vector).
        amplitude: perturbation amplitude ``a`` (broadcast to ``theta0``).
        frequency: perturbation frequency ``ω`` in radians per step, in (0, π).
        gain: integrator gain ``γ`` (> 0 maximises, < 0 minimises).
        num_steps: number of steps.
        highpass: washout filter coefficient ``h`` in (0, 1]; smaller = lower cut-off.
        bounds: optional ``(lo, hi)`` to clip ``θ̂`` (e.g. a threshold in [0, 1]).
        key: PRNG key for the objective (default ``jax.random.key(0)``).
    """
    if num_steps < 1:
        raise ValueError(f"num_steps must be ≥ 1, got {num_steps}")
    if not 0.0 < highpass <= 1.0:
        raise ValueError(f"highpass must be in (0, 1], got {highpass}")
    theta0 = jnp.asarray(theta0, dtype=jnp.result_type(float))
    a = jnp.broadcast_to(jnp.asarray(amplitude, theta0.dtype), theta0.shape)
    w = jnp.broadcast_to(jnp.asarray(frequency, theta0.dtype), theta0.shape)
    key = jax.random.key(0) if key is None else key
    keys = jax.random.split(key, num_steps)
    lo, hi = (None, None) if bounds is None else bounds

    def step(carry, inp):
        theta_hat, ybar = carry
        k, kk = inp
        s = jnp.sin(w * k)
        theta = theta_hat + a * s
        y = jnp.asarray(objective(theta, kk), theta0.dtype)
        ybar = jnp.where(k == 0, y, ybar)  # start the washout at the first value
        eta = y - ybar
        xi = eta * s
        new = theta_hat + gain * xi
        if bounds is not None:
            new = jnp.clip(new, lo, hi)
        ybar = ybar + highpass * (y - ybar)
        return (new, ybar), (theta_hat, theta, y, xi)

    ks = jnp.arange(num_steps, dtype=theta0.dtype)
    (final, _), (th, t, y, xi) = jax.lax.scan(step, (theta0, jnp.zeros((), theta0.dtype)), (ks, keys))
    return ESCTrajectory(theta_hat=th, theta=t, y=y, gradient=xi, final=final)
