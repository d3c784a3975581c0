"""Random numbers for the JAX simulators: one draw per program, handed out in order."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["Pool", "smooth"]


class Pool:
    """Uniform random numbers drawn in **one** ``jax.random`` call and handed out in order.

    Every ``jax.random`` call adds a threefry kernel to the compiled program and
    XLA compile time grows with each; the scene layouts need a few hundred
    numbers, so one draw keeps compilation fast. Slices are static.
    """

    def __init__(self, key, size: int):
        self._u = jax.random.uniform(key, (size,))
        self._next = 0

    def uniform(self, shape=(), minval=0.0, maxval=1.0):
        shape = tuple(shape)
        n = math.prod(shape)
        if self._next + n > self._u.shape[0]:
            raise RuntimeError("simulate: random pool exhausted (internal error; enlarge the pool)")
        out = self._u[self._next : self._next + n].reshape(shape)
        self._next += n
        return minval + (maxval - minval) * out

    def seek(self, position: int):
        """Continue from ``position`` (≥ the numbers used so far): fixed offsets per block."""
        if position < self._next:
            raise RuntimeError("simulate: random pool block overflow (internal error)")
        self._next = position

    def randint(self, shape, low: int, high: int):
        """Integers uniform in ``[low, high)``."""
        u = self.uniform(shape, float(low), float(high))
        return jnp.clip(jnp.floor(u), low, high - 1).astype(jnp.int32)


def smooth(pool: Pool, times: Float[Array, " T"], shape: tuple[int, ...], periods=(4.0, 16.0), components: int = 3):
    """Smooth random signal in ``[−1, 1]`` of shape ``(T, *shape)``.

    A sum of ``components`` sinusoids with random periods (seconds), phases and
    amplitudes, normalised by the sum of amplitudes. Stationary and bounded.
    """
    full = shape + (components,)
    period = pool.uniform(full, periods[0], periods[1])
    phase = pool.uniform(full, 0.0, 2 * math.pi)
    amp = pool.uniform(full, 0.5, 1.0)
    t = times.reshape((-1,) + (1,) * len(full))
    waves = amp * jnp.sin(2 * math.pi * t / period + phase)
    return jnp.sum(waves, axis=-1) / jnp.sum(amp, axis=-1)
