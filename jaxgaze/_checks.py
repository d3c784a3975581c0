"""Shared input checks and the padding rule that limits recompiles (private module, public names).

Imports nothing of ``jaxgaze``, so every module may use it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["bucket_size", "check_key"]


def bucket_size(n: int, *, minimum: int = 16, multiple: int | None = None) -> int:
    """The padded length for ``n`` items, so that similar sizes share one compilation.

    ``multiple=None``: the next power of two ``2^⌈log₂ n⌉``; otherwise ``n`` rounded up
    to a multiple of ``multiple``, ``⌈n / multiple⌉ · multiple``. Never below ``minimum``.
    """
    n = int(n)
    if multiple is None:
        return max(int(minimum), 1 << (n - 1).bit_length())
    return max(int(minimum), -(-n // int(multiple)) * int(multiple))


def check_key(key) -> np.ndarray:
    """The raw ``uint32`` words of a single ``jax.random`` key (new-style or legacy ``PRNGKey``).

    Raises ``ValueError`` for anything else (an int, a batch of keys, a float array).
    """
    if isinstance(key, (jax.Array, np.ndarray)):
        if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) and key.shape == ():
            return np.asarray(jax.random.key_data(key)).ravel()
        if key.dtype == np.uint32 and key.shape == (2,):
            return np.asarray(key).ravel()
    raise ValueError(
        "key must be a single jax.random key such as jax.random.key(0), got "
        f"{type(key).__name__}{'' if not hasattr(key, 'shape') else f' of shape {key.shape}'}"
    )
