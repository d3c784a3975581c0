"""Simulated small groups who look at each other, with the truth of who looks at whom (Siegfried et al. 2017, eq. 1).

Each frame is an independent group of ``N`` people (2–4 by default) standing on
a circle of radius in ``radius_m`` around a common centre (seats evenly spaced up
to a jitter of a quarter of the spacing), eye heights uniform in ``eye_height_m``.
World frame z up, metres; radians inside, ``_deg`` names hold degrees.

1. **True gaze.** Person ``i``'s true gaze ``v*`` is uniform on the union of the
   caps of angular radius ``spread_deg`` (40°) around the directions ``u_ij`` from
   ``i``'s eyes to every partner ``j``'s (a partner's cap drawn uniformly, a point
   uniform in it, kept with probability ``1/c`` where ``c`` caps hold it, until
   kept: exactly uniform on the union). So around every partner the gaze
   density is flat, out to 40°: some people look at a partner, many just beside
   one (near misses), others elsewhere, and the flat-prior posterior of
   :func:`jaxgaze.cone.looking_at_each_other` is the honest one.
2. **Truth.** ``i`` looks at ``j`` when ``∠(v*_i, u_ij) < τ`` (``threshold_deg``, 10°):
   Siegfried's eq. 1 on the true gaze.
3. **Measured rays.** Park's cone around the true gaze: ``v = unit(v* + h (d₁ e₁ +
   d₂ e₂))``, ``d ~ N(0, I₂)``, ``(e₁, e₂)`` orthonormal and orthogonal to ``v*``,
   with a per-ray bandwidth ``h`` uniform in ``bandwidth_deg``. Rays start at the
   eyes, which are also the heads the others are looked at.

Slots beyond a frame's ``N`` are masked. All randomness comes from the
``jax.random`` key (its words seed one NumPy generator; everything runs in NumPy,
float64, nothing is compiled).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from jaxtyping import Bool, Float, Int

from jaxgaze._checks import check_key
from jaxgaze.rays import GazeRays

__all__ = ["MutualGaze", "simulate_mutual_gaze"]

_MAX_PEOPLE = 16


class MutualGaze(NamedTuple):
    """Frames of small groups with known gaze (:func:`simulate_mutual_gaze`).

    Attributes:
        rays: ``(T, N)`` the measured gaze rays (slots beyond a frame's group masked).
        heads: ``(T, N, 3)`` eye midpoints, world frame (metres); 0 in masked slots.
        true_directions: ``(T, N, 3)`` unit true gaze; ``(1, 0, 0)`` in masked slots.
        looks_at: ``(T, N, N)`` the truth ``∠(v*_i, u_ij) < τ``; False on the diagonal and for masked slots.
        num_people: ``(T,)`` the group size of each frame.
        threshold: ``τ`` in radians.
    """

    rays: GazeRays
    heads: Float[np.ndarray, "T N 3"]
    true_directions: Float[np.ndarray, "T N 3"]
    looks_at: Bool[np.ndarray, "T N N"]
    num_people: Int[np.ndarray, " T"]
    threshold: float


def _range(name: str, value, lo: float, hi: float) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"simulate_mutual_gaze: {name} must be a pair (low, high), got {value!r}") from None
    if not (lo <= a <= b <= hi):
        raise ValueError(f"simulate_mutual_gaze: {name} {value!r} must satisfy {lo:g} ≤ low ≤ high ≤ {hi:g}")
    return a, b


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _basis(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to the unit ``v`` and to each other."""
    helper = np.where(np.abs(v[..., 2:]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    e1 = _unit(np.cross(helper, v))
    return e1, np.cross(v, e1)


def _in_cap(rng: np.random.Generator, axis: np.ndarray, spread: float) -> np.ndarray:
    """Uniform directions within ``spread`` of the unit ``axis`` (``cos θ`` uniform, azimuth uniform)."""
    cos = 1.0 - rng.uniform(size=axis.shape[:-1]) * (1.0 - math.cos(spread))
    sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    phi = rng.uniform(0.0, 2.0 * math.pi, size=axis.shape[:-1])
    e1, e2 = _basis(axis)
    return (cos[..., None] * axis + sin[..., None] * (np.cos(phi)[..., None] * e1 + np.sin(phi)[..., None] * e2))


def simulate_mutual_gaze(
    key,
    num_frames: int,
    *,
    num_people: tuple[int, int] = (2, 4),
    spread_deg: float = 40.0,
    bandwidth_deg: tuple[float, float] = (2.0, 8.0),
    radius_m: tuple[float, float] = (0.4, 1.0),
    eye_height_m: tuple[float, float] = (1.15, 1.75),
    threshold_deg: float = 10.0,
) -> MutualGaze:
    """``num_frames`` independent groups with true gaze, measured rays and who looks at whom (see the module docstring).

    ``num_people`` is the range of the group size (integers, uniform). For the
    probabilities to be checkable, ``spread_deg`` must exceed ``threshold_deg`` by a few
    bandwidths (40° vs 10° + 3·8° by default).
    """
    words = check_key(key)
    if int(num_frames) != num_frames or num_frames < 1:
        raise ValueError(f"simulate_mutual_gaze: num_frames must be an integer ≥ 1, got {num_frames!r}")
    n_lo, n_hi = _range("num_people", num_people, 2, _MAX_PEOPLE)
    if int(n_lo) != n_lo or int(n_hi) != n_hi:
        raise ValueError(f"simulate_mutual_gaze: num_people {num_people!r} must be integers")
    h_lo, h_hi = _range("bandwidth_deg", bandwidth_deg, 1e-3, 30.0)
    r_lo, r_hi = _range("radius_m", radius_m, 0.1, 10.0)
    z_lo, z_hi = _range("eye_height_m", eye_height_m, 0.0, 3.0)
    if not 0.0 < threshold_deg < spread_deg <= 90.0:
        raise ValueError(f"simulate_mutual_gaze: need 0 < threshold_deg ({threshold_deg!r}) < spread_deg "
                         f"({spread_deg!r}) ≤ 90")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(w) for w in words])))
    T, N = int(num_frames), int(n_hi)
    spread, tau = math.radians(spread_deg), math.radians(threshold_deg)

    size = rng.integers(int(n_lo), N + 1, size=T)
    slot = np.arange(N)
    present = slot[None] < size[:, None]  # (T, N)
    spacing = 2.0 * math.pi / size
    azimuth = (rng.uniform(0.0, 2.0 * math.pi, size=(T, 1)) + spacing[:, None] * slot[None]
               + rng.uniform(-0.25, 0.25, size=(T, N)) * spacing[:, None])
    radius = rng.uniform(r_lo, r_hi, size=(T, 1))
    heads = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), rng.uniform(z_lo, z_hi, size=(T, N))], -1)
    heads = np.where(present[..., None], heads, 0.0)
    toward = heads[:, None, :, :] - heads[:, :, None, :]  # (T, gazer i, partner j, 3)
    partner = present[:, None, :] & present[:, :, None] & ~np.eye(N, dtype=bool)[None]
    toward = np.where(partner[..., None], toward, [1.0, 0.0, 0.0])
    toward = _unit(toward)

    # 1. uniform on the union of the partners' caps, by rejection (rounds over all gazers still drawing)
    true = np.tile([1.0, 0.0, 0.0], (T, N, 1))
    pending = np.argwhere(present)  # (M, 2): frame, gazer
    while len(pending):
        t, i = pending[:, 0], pending[:, 1]
        pick = (rng.uniform(size=len(t)) * (size[t] - 1)).astype(int)
        j = pick + (pick >= i)  # a partner of i, uniformly
        candidate = _in_cap(rng, toward[t, i, j], spread)
        caps = np.sum(partner[t, i] & (np.einsum("mk,mjk->mj", candidate, toward[t, i]) > math.cos(spread)), -1)
        keep = rng.uniform(size=len(t)) * caps < 1.0
        true[t[keep], i[keep]] = candidate[keep]
        pending = pending[~keep]

    # 2. the truth (Siegfried's eq. 1 on the true gaze)
    cos = np.clip(np.einsum("tik,tijk->tij", true, toward), -1.0, 1.0)
    looks_at = partner & (np.arccos(cos) < tau)

    # 3. Park's cone around the true gaze
    h = np.radians(rng.uniform(h_lo, h_hi, size=(T, N)))
    d = rng.normal(size=(T, N, 2))
    e1, e2 = _basis(true)
    measured = _unit(true + h[..., None] * (d[..., :1] * e1 + d[..., 1:] * e2))
    rays = GazeRays(heads, np.where(present[..., None], measured, [1.0, 0.0, 0.0]), h, mask=present)
    return MutualGaze(rays, heads, true, looks_at, size, tau)
