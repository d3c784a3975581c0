"""Shared input checks and the padding rule that limits recompiles (private module, public names).

Each check returns the value in plain Python form or raises ``ValueError`` naming the argument,
what it must be and what it got (``"fps must be a finite number > 0, got -1.0"``).

Imports nothing of ``jaxgaze``, so every module may use it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["bucket_size", "check_key", "check_number", "check_pair", "check_int", "check_int_pair", "check_frames"]


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


def _bounds(lo, hi, lo_open) -> str:
    if lo is not None and hi is not None and not lo_open:
        return f" in [{lo}, {hi}]"
    parts = ([f"{'>' if lo_open else '≥'} {lo}"] if lo is not None else []) + ([f"≤ {hi}"] if hi is not None else [])
    return (" " + " and ".join(parts)) if parts else ""


def check_number(name: str, value, *, lo=None, hi=None, lo_open: bool = False) -> float:
    """``value`` as a finite ``float`` with ``lo ≤ value ≤ hi`` (``lo < value`` when ``lo_open``); either
    bound may be ``None``. Booleans and strings are not numbers."""
    try:
        v = float("nan") if isinstance(value, (bool, np.bool_, str, bytes)) else float(value)
    except (TypeError, ValueError):
        v = float("nan")
    bad = not np.isfinite(v) or (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and v > hi)
    if bad:
        raise ValueError(f"{name} must be a finite number{_bounds(lo, hi, lo_open)}, got {value!r}")
    return v


def check_pair(name: str, value, *, lo=None, hi=None, lo_open: bool = False) -> tuple[float, float]:
    """A range ``(low, high)`` of two :func:`check_number` values with ``low ≤ high``."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a pair (low, high), got {value!r}")
    low = check_number(f"{name}[0]", value[0], lo=lo, hi=hi, lo_open=lo_open)
    high = check_number(f"{name}[1]", value[1], lo=lo, hi=hi, lo_open=lo_open)
    if high < low:
        raise ValueError(f"{name} must satisfy low ≤ high, got {value!r}")
    return low, high


def check_int(name: str, value, *, lo: int | None = 1, hi: int | None = None) -> int:
    """``value`` as an ``int`` (a Python or NumPy integer, not a bool or a float) with ``lo ≤ value ≤ hi``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or (
        (lo is not None and value < lo) or (hi is not None and value > hi)
    ):
        raise ValueError(f"{name} must be an integer{_bounds(lo, hi, False)}, got {value!r}")
    return int(value)


def check_int_pair(name: str, value, *, lo: int | None = 1, hi: int | None = None) -> tuple[int, int]:
    """A range ``(low, high)`` of two :func:`check_int` values with ``low ≤ high`` (both inclusive)."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a pair (low, high), got {value!r}")
    low, high = (check_int(f"{name}[{i}]", v, lo=lo, hi=hi) for i, v in enumerate(value))
    if high < low:
        raise ValueError(f"{name} must satisfy low ≤ high, got {value!r}")
    return low, high


def check_frames(duration_s, fps, *, max_frames: int = 10_000_000) -> tuple[int, float]:
    """``(round(duration_s · fps), fps)`` for a recording of ``duration_s`` seconds at ``fps`` (both > 0):
    at least 2 frames and at most ``max_frames``."""
    fps = check_number("fps", fps, lo=0.0, lo_open=True)
    duration_s = check_number("duration_s", duration_s, lo=0.0, lo_open=True)
    num_frames = int(round(duration_s * fps))
    if num_frames < 2:
        raise ValueError(
            f"duration_s · fps must give at least 2 frames, got duration_s={duration_s!r}, fps={fps!r} "
            f"({num_frames} frames)"
        )
    if num_frames > max_frames:
        raise ValueError(f"duration_s · fps gives {num_frames} frames; at most {max_frames:,} per recording")
    return num_frames, fps
