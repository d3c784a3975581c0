"""Gaze concurrences: modes of the social saliency field (Park et al. 2012, Sec. 3.3).

Pipeline for one frame (all in JAX, fixed shapes, so it vmaps over frames):

1. **Seeds** at fixed depths along every primary ray.
2. **Mean-shift** (eq. 5–6) on the field smoothed with bandwidth
   ``search_scale · h``, vmapped over seeds, each a ``lax.while_loop`` that stops
   when a step is shorter than ``tol`` or after ``max_iter`` steps. Two noisy
   rays that "meet" usually miss each other by about ``h``, and at the
   calibrated bandwidth their crossing is often not a single peak; the wider
   search bandwidth (default 2) finds it.
3. **Exclusive support.** Seeds are visited by decreasing field value. A seed
   within ``merge_radius`` of an accepted mode is merged into it. A seed whose
   mean-shift weight is dominated by one ray (share > ``dominance``) is
   rejected. Otherwise it claims every not-yet-claimed ray whose perspective
   distance is below ``claim_bandwidths`` search bandwidths, and becomes a mode
   if it claims at least ``min_rays`` rays. Each ray supports at most one mode.
   The claims are made twice: after the first pass the members' robust noise
   ratio ``ĉ ≥ 1`` (pooled over the frame: how much wider than ``h`` the rays
   scatter) is measured at the refined locations, and the second pass claims
   with the bandwidths times ``max(1, ĉ/1.25)``. With a bandwidth that is right
   ``ĉ`` is close to 1 and the claims stay as they were; with one too small the
   second pass keeps the tail of each concurrence's residuals, which a fixed
   radius would cut off.
4. **Location and uncertainty.** Each mode is refined to the maximum-likelihood
   common point of regard of its member rays under the cone model,
   ``argmin_x Σ_i ‖d_i(x)‖² / 2h_i²`` (Levenberg–Marquardt, ``optimistix``).
   Unclaimed rays within ``ĉ`` claim radii of the refined point join it; members
   farther than ``4 ĉ h`` from it (``ĉ`` measured again) are dropped (a mode left with fewer than
   ``min_rays`` is dropped too); the location is refined again. Its covariance is
   built from the Laplace (Gauss–Newton) matrix ``Σ_L = (JᵀJ + I/s²)⁻¹`` with
   ``J`` the Jacobian of the whitened residuals ``d_i(x)/h_i`` and a weak prior
   of scale ``s = prior_scale`` metres that keeps near-parallel rays finite,
   scaled by the noise the members actually show (**Noise scale** below).
   Modes under the floor (``floor_below_eyes`` under the lowest eye), those of only
   a pair of people looking at each other (mutual gaze, reported in ``mutual_gaze``)
   and those the rays leave unbounded are not concurrences (:func:`find_concurrences`).
5. **The paper's region.** ``{x : f(x) ≥ 0.8 f(x*)}`` is reported by its
   principal axes from the Hessian of ``log f`` at the location. It is a level
   set of the field: it says how sharply the group's gaze agrees, in units of the
   bandwidth, and does not shrink as members are added, so it is not a
   confidence region for the location (on the simulated mocap scene it holds the
   marker in 43.5 % of the frames). The covariance is the location's uncertainty.

**Noise scale.** ``Σ_L`` alone trusts the user's bandwidth: rays that scatter
more than ``h`` says make the ellipsoid too small, rays that scatter less make it
too large. The noise of a concurrence's members is taken to be ``c·h_i``, with one
unknown factor per concurrence and a log-uniform prior on ``u = c²`` over
``[1/64, 64]`` (``c`` within 8× of the user's bandwidth, either way; flat in
``log u`` is the scale-invariant choice, so inside those bounds the answer does
not depend on how wrong ``h`` is). Each member's whitened residual is 2-D
(perpendicular to its ray), so with ``n`` members, 3 location coordinates and
``RSS = Σ_i ‖d_i(x̂)/h_i‖²`` at the location ``x̂``, integrating the location out of
the linearised likelihood leaves ``p(u | RSS) ∝ u^{−(2n−3)/2} exp(−RSS/2u)`` on the
prior's support — an inverse gamma ``IG((2n−3)/2, RSS/2)``, truncated. It is
evaluated on a fixed grid of ``log u`` and summarised by the inverse gamma
``IG(a, b)`` with the same mean and variance; integrating ``u`` out of
``N(x̂, u Σ_L)`` then gives a 3-D Student-t with ``ν = 2a`` degrees of freedom and
scale matrix ``(b/a) Σ_L``. ``covariances`` is that t's covariance,
``E[u]·Σ_L``, and ``degrees_of_freedom`` its ``ν`` (always above 4, since the
support is bounded). Its ``level`` region is
``(x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤ 3 (ν − 2)/ν · F⁻¹(level; 3, ν)`` (see
:func:`~jaxgaze.concurrence.metrics.region_threshold`). With 4 or more members
the data decide ``u`` (``ν`` close to ``2n − 3`` and ``E[u]`` close to
``RSS/(2n − 5)``), so a bandwidth 2× too small or too large is corrected. A
2-ray concurrence has one residual degree of freedom, and its covariance leans on
the prior: about 4× ``Σ_L`` when the bandwidth is right. A conjugate
scaled-inverse-χ² prior centred on 1 with ``ν₀`` pseudo-degrees of freedom would
be simpler, but it cannot do both: ``ν₀ > 1`` is needed for a 2-ray mode to have
a finite covariance, and with ``ν₀ ≥ 1`` a bandwidth 2× too large still gives
95–99 % coverage of the 90 % region with 4–8 members.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from jaxgaze._checks import bucket_size
from jaxgaze._batching import (
    lapack_eigh_cost,
    lapack_guard_applies,
    lapack_lu_cost,
    lapack_qr_cost,
    lapack_safe_batch,
    map_in_batches,
    repeat_last,
)
from jaxgaze.geometry import orthonormal_basis
from jaxgaze.concurrence.meanshift_pallas import fused_meanshift
from jaxgaze.rays import GazeRays, check_units

__all__ = [
    "MeanShiftResult",
    "Concurrences",
    "Tracks",
    "ConcurrenceOptions",
    "meanshift",
    "find_concurrences",
    "find_concurrences_over_frames",
    "track_concurrences",
    "DEFAULT_SEED_DEPTHS",
]

#: Depths (metres) at which seeds are placed along each primary ray.
DEFAULT_SEED_DEPTHS = tuple(float(x) for x in np.geomspace(0.4, 16.0, 16))

_REGION_LEVEL = 0.8  # Park et al. Sec. 4.1: region above 80 % of the local maximum
_NOISE_RATIO_RANGE = 8.0  # prior: the rays scatter between 1/8 and 8 times their bandwidth (log-uniform)
_NOISE_GRID_POINTS = 256  # grid of the noise-scale posterior: steps of 0.033 in log c²


@dataclasses.dataclass(frozen=True)
class ConcurrenceOptions:
    """Options of the concurrence search (Park et al. 2012, Sec. 3.3); frozen, validated, hashable.

    One object serves :func:`find_concurrences`, :func:`find_concurrences_over_frames`
    and :func:`~jaxgaze.concurrence.propagate_to_concurrences`, and is the static
    argument of their compiled programs. Vary one field with
    ``dataclasses.replace(options, min_rays=3)``.

    Attributes:
        seed_depths: depths (m) of the mean-shift seeds along every ray.
        bounds: optional world-frame box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``
            (m; ``±inf`` allowed) where points of regard can lie, e.g. above the
            floor of the room. Modes outside it are rejected — a flat prior on the
            scene volume that removes chance crossings of two rays behind a wall or
            under the floor, which otherwise compete with real two-ray concurrences.
        floor_below_eyes: the floor is taken to lie at most this far (m) below the
            lowest eye of the frame (world +z up): modes lower than that are rejected,
            as if ``bounds`` had ``zmin = min_i p_i,z − floor_below_eyes`` (with
            ``bounds`` too, the higher floor counts). The default 2.5 m holds for
            standing adults (eyes 1.5–1.9 m above the floor they stand on) with room
            for the location's error; it removes two rays crossing under the floor by
            chance (on the simulated meeting, 3.5 m below the eyes). ``None`` turns it
            off, e.g. for spectators in a stand looking down at a field.
        min_rays: fewest rays a mode must claim to count (≥ 2).
        claim_bandwidths: a ray supports a mode if ``‖d(l, x)‖ < claim_bandwidths · search_scale · h``.
        search_scale: the mode search and the claims use the field smoothed with
            bandwidth ``search_scale · h``; locations and covariances use ``h``.
        dominance: reject a mode if one ray carries more than this share of ``Σ w``.
        merge_radius: seeds converging within this distance (m) of a mode merge into it.
        tol, max_iter: mean-shift stopping rule (step length in m, iteration cap).
        max_modes: cap on the number of modes (default ``N // min_rays``).
        prior_scale: standard deviation (m) of the weak Gaussian prior on a location.
        refine_steps: Levenberg–Marquardt steps for the location refinement.

    Sequences are stored as tuples of floats and numbers as ``int``/``float``, so
    equal options hash equal. Bad values raise ``ValueError`` naming the field.
    """

    seed_depths: tuple[float, ...] = DEFAULT_SEED_DEPTHS
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    floor_below_eyes: float | None = 2.5
    min_rays: int = 2
    claim_bandwidths: float = 3.0
    search_scale: float = 2.0
    dominance: float = 0.9
    merge_radius: float = 0.3
    tol: float = 1e-4
    max_iter: int = 500
    max_modes: int | None = None
    prior_scale: float = 100.0
    refine_steps: int = 64

    def __post_init__(self):
        def integer(name, value, least, what=""):
            real = not isinstance(value, bool) and isinstance(value, (int, np.integer, float, np.floating))
            if not (real and math.isfinite(value) and int(value) == value and value >= least):
                raise ValueError(f"{name} must be an integer ≥ {least}{what}, got {value}")
            return int(value)

        def number(name, value):
            try:
                return float(value)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a number, got {value!r}") from None

        set_ = functools.partial(object.__setattr__, self)
        set_("min_rays", integer("min_rays", self.min_rays, 2, " (a concurrence needs two people)"))
        set_("dominance", number("dominance", self.dominance))
        if not 0 < self.dominance <= 1:
            raise ValueError(f"dominance must lie in (0, 1], got {self.dominance}")
        for name in ("claim_bandwidths", "search_scale", "merge_radius", "tol", "prior_scale"):
            value = number(name, getattr(self, name))
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value}")
            set_(name, value)
        if self.floor_below_eyes is not None:
            value = number("floor_below_eyes", self.floor_below_eyes)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"floor_below_eyes must be a positive number of metres or None, got {value}")
            set_("floor_below_eyes", value)
        set_("max_iter", integer("max_iter", self.max_iter, 1))
        set_("refine_steps", integer("refine_steps", self.refine_steps, 1))
        if self.max_modes is not None:
            set_("max_modes", integer("max_modes", self.max_modes, 0, " or None"))
        try:
            depths = np.asarray(self.seed_depths, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            depths = np.zeros(0)
        if depths.size == 0 or not np.all(np.isfinite(depths)) or np.any(depths <= 0):
            raise ValueError("seed_depths must be a non-empty list of positive, finite depths (metres)")
        set_("seed_depths", tuple(float(d) for d in depths))
        if self.bounds is not None:
            try:
                box = np.asarray(self.bounds, dtype=float)
            except (TypeError, ValueError):
                box = np.zeros(0)
            if box.shape != (2, 3) or np.any(np.isnan(box)) or not np.all(box[0] < box[1]):
                raise ValueError(
                    f"bounds must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max, got {self.bounds!r}"
                )
            set_("bounds", tuple(tuple(float(v) for v in row) for row in box))


class MeanShiftResult(NamedTuple):
    """Output of :func:`meanshift` for ``S`` seeds."""

    points: Float[Array, "S 3"]
    field_values: Float[Array, " S"]
    iterations: Int[Array, " S"]
    converged: Bool[Array, " S"]


class Concurrences(NamedTuple):
    """Gaze concurrences of one frame (``K`` modes) or of many (``(T, K)``, padded).

    Attributes:
        locations: ``(…, K, 3)`` world-frame points (m).
        covariances: ``(…, K, 3, 3)`` covariance of each location (m²): the Laplace
            covariance scaled by the noise its member rays show, i.e. the covariance
            of a Student-t with ``degrees_of_freedom`` (module docstring, **Noise scale**).
        field_values: ``(…, K)`` social saliency ``f`` at each location.
        num_rays: ``(…, K)`` number of member rays.
        membership: ``(…, N)`` index of the mode each ray supports, or −1.
        region_axes: ``(…, K, 3, 3)`` columns are the principal directions of the
            paper's confidence region ``{f ≥ 0.8 f(mode)}`` (Park et al., Sec. 4.1): a
            level set of the field, not a confidence region for the location.
        region_semi_axes: ``(…, K, 3)`` its semi-axis lengths (m), from the
            quadratic approximation of ``log f``; ``inf`` along a flat direction.
        converged: ``(…, K)`` whether the mean-shift seed converged within ``tol``.
        valid: ``(…, K)`` mask of real modes (all ``True`` for a single frame).
        degrees_of_freedom: ``(…, K)`` degrees of freedom ``ν`` of the location's
            Student-t: its ``level`` region is ``(x − x̂)ᵀ Σ⁻¹ (x − x̂) ≤
            3 (ν − 2)/ν · F⁻¹(level; 3, ν)`` with ``Σ`` = ``covariances``.
            ``None`` (results built by hand) means Gaussian (``ν = ∞``).
        mutual_gaze: ``(…, N)`` the person each ray's person is in mutual gaze with,
            or −1 (``mutual_gaze[i] = j`` exactly when ``mutual_gaze[j] = i``; see
            :func:`find_concurrences`). ``None`` in results built by hand.
    """

    locations: Float[Array, "... K 3"]
    covariances: Float[Array, "... K 3 3"]
    field_values: Float[Array, "... K"]
    num_rays: Int[Array, "... K"]
    membership: Int[Array, "... N"]
    region_axes: Float[Array, "... K 3 3"]
    region_semi_axes: Float[Array, "... K 3"]
    converged: Bool[Array, "... K"]
    valid: Bool[Array, "... K"]
    degrees_of_freedom: Float[Array, "... K"] | None = None
    mutual_gaze: Int[Array, "... N"] | None = None

    @property
    def count(self) -> Int[Array, "..."]:
        """Number of concurrences (per frame for a recording)."""
        return jnp.sum(self.valid, axis=-1)

    def members(self, k: int) -> np.ndarray:
        """Indices of the rays that support mode ``k`` (single frame)."""
        return np.flatnonzero(np.asarray(self.membership) == k)

    def frame(self, t: int) -> "Concurrences":
        """Frame ``t`` of a recording, with the padding removed."""
        one = Concurrences(*(None if a is None else np.asarray(a)[t] for a in self))
        keep = np.asarray(one.valid)
        return one._replace(
            **{name: getattr(one, name)[keep] for name in one._fields
               if name not in _PER_RAY and getattr(one, name) is not None}
        )

    def mutual_gaze_pairs(self) -> np.ndarray:
        """``(P, 2)`` person indices ``i < j`` of the pairs in mutual gaze (single frame), or,
        for a recording, ``(P, 3)`` rows ``(frame index, i, j)``."""
        partner = np.full(np.shape(self.membership), -1) if self.mutual_gaze is None else np.asarray(self.mutual_gaze)
        index = np.argwhere(np.arange(partner.shape[-1]) < partner)
        return np.concatenate([index, partner[tuple(index.T)][:, None]], axis=1).astype(np.int64)


_PER_RAY = ("membership", "mutual_gaze")  # fields of Concurrences with one entry per ray, not per mode


class Tracks(NamedTuple):
    """Concurrences linked over frames. ``track_ids[t, k]`` is −1 for padding."""

    track_ids: Int[Array, "T K"]
    num_tracks: Int[Array, ""]

    def trajectories(self, concurrences: Concurrences) -> dict[int, dict[str, np.ndarray]]:
        """``{track id: {"frames", "locations", "birth", "death"}}`` on the host."""
        ids = np.asarray(self.track_ids)
        locations = np.asarray(concurrences.locations)
        out = {}
        for track in range(int(self.num_tracks)):
            frames, slots = np.nonzero(ids == track)
            if len(frames) == 0:
                continue
            order = np.argsort(frames)
            frames, slots = frames[order], slots[order]
            out[track] = {
                "frames": frames,
                "locations": locations[frames, slots],
                "birth": int(frames[0]),
                "death": int(frames[-1]),
            }
        return out


# ---------------------------------------------------------------------------
# Mean-shift kernel (eq. 5–6)


class RayProjector(NamedTuple):
    """Per-ray constants that turn a point into its ray coordinates with one matmul.

    For ray ``i`` with orthonormal ``(v_i, u1_i, u2_i)``, ``basis @ x − offsets``
    gives ``(t_i, a_i, b_i)``: the depth of ``x`` and its offset on the
    cross-section, so ``r_i² = a_i² + b_i²`` has no cancellation and, vmapped
    over seeds, the work is an ``(S,3)×(3,3N)`` product with no ``(S,N,3)`` temporary.
    """

    basis: Float[Array, "3N 3"]
    offsets: Float[Array, "3N"]
    origins: Float[Array, "N 3"]
    directions: Float[Array, "N 3"]
    bandwidth: Float[Array, " N"]
    mask: Bool[Array, " N"]
    exponent_scale: Float[Array, " N"]  # −1 / (2 h²)
    weight_scale: Float[Array, " N"]  # 1 / h³, 0 for padded rays


def ray_projector(rays: GazeRays) -> RayProjector:
    """Precompute the :class:`RayProjector` of one frame of rays (Park et al. 2012, eq. 5–6)."""
    u1, u2 = jax.vmap(orthonormal_basis)(rays.directions)
    basis = jnp.stack([rays.directions, u1, u2], axis=1)  # (N, 3, 3)
    offsets = jnp.einsum("nij,nj->ni", basis, rays.origins, precision=jax.lax.Precision.HIGHEST)
    h = rays.bandwidth
    return RayProjector(
        basis.reshape(-1, 3), offsets.reshape(-1), rays.origins, rays.directions, h, rays.mask,
        -0.5 / (h * h), jnp.where(rays.mask, 1.0 / (h * h * h), 0.0),
    )


def _ray_coordinates(proj: RayProjector, x: Float[Array, "3"]):
    """``(t, r², in front)`` of ``x`` for every ray, and ``1/t`` (0 where not in front)."""
    # HIGHEST: GPUs would otherwise round this float32 product through TF32 (10-bit mantissa).
    tab = (jnp.matmul(proj.basis, x, precision=jax.lax.Precision.HIGHEST) - proj.offsets).reshape(-1, 3)
    t, r2 = tab[:, 0], tab[:, 1] ** 2 + tab[:, 2] ** 2
    ok = (t > 0) & proj.mask
    inv_t = jnp.where(ok, 1.0 / jnp.where(ok, t, 1.0), 0.0)
    return t, r2, ok, inv_t


def _meanshift_step(proj: RayProjector, x: Float[Array, "3"]) -> tuple[Array, Array]:
    """One closed-form update ``x ← Σ w_i x̄_i / Σ w_i`` (eq. 6) and ``Σ w_i``.

    With ``t_i = v_iᵀ(x − p_i)`` and ``r_i² = ‖x − x̂_i‖²``:
    ``w_i = exp(−r_i² / 2h_i²t_i²) / (h_i³ t_i²)`` (Gaussian profile, ``g ∝ e^{−s/2}``)
    and ``x̄_i = x̂_i + (r_i²/t_i) v_i = p_i + (r_i²/t_i + t_i) v_i``.
    Rays with ``t_i ≤ 0`` (behind the eye) or masked get zero weight.
    """
    t, r2, _, inv_t = _ray_coordinates(proj, x)
    inv_t2 = inv_t * inv_t  # 0 behind the eye and for padded rays, so w = 0 there
    w = jnp.exp(proj.exponent_scale * r2 * inv_t2) * (inv_t2 * proj.weight_scale)
    total = jnp.sum(w)
    exact = jax.lax.Precision.HIGHEST
    target = jnp.matmul(w, proj.origins, precision=exact) + jnp.matmul(w * (r2 * inv_t + t), proj.directions, precision=exact)
    x_new = jnp.where(total > 0, target / jnp.where(total > 0, total, 1.0), x)
    return x_new, total


def _field_value(proj: RayProjector, x: Float[Array, "3"]) -> Array:
    """``f(x)`` of eq. 3 through the projector (same values as :func:`jaxgaze.saliency_field`)."""
    _, r2, ok, inv_t = _ray_coordinates(proj, x)
    h = proj.bandwidth
    k = jnp.where(ok, jnp.exp(proj.exponent_scale * r2 * inv_t * inv_t), 0.0) / (h * math.sqrt(2.0 * math.pi))
    return jnp.sum(k) / jnp.maximum(jnp.sum(proj.mask), 1)


def _xla_meanshift(proj: RayProjector, seeds, tol, max_iter: int, max_stretch: int):
    """:func:`meanshift`'s loop in plain XLA: each seed runs its own ``while_loop`` (vmapped)."""
    stretches = 2.0 ** jnp.arange(int(math.log2(max_stretch)) + 1, dtype=proj.origins.dtype)

    def run_one(x0):
        def cond(state):
            _, it, done, _ = state
            return (~done) & (it < max_iter)

        def body(state):
            x, it, _, _ = state
            m, total = _meanshift_step(proj, x)
            if max_stretch == 1:
                x_new = m
            else:
                candidates = x + stretches[:, None] * (m - x)
                values = jax.vmap(lambda c: _field_value(proj, c))(candidates)
                x_new = candidates[jnp.argmax(values)]
            step = jnp.linalg.norm(m - x)
            return x_new, it + 1, step < tol, total > 0

        x, it, done, alive = jax.lax.while_loop(cond, body, (x0, jnp.int32(0), jnp.bool_(False), jnp.bool_(True)))
        return x, it, done & alive

    return jax.vmap(run_one)(seeds)


@functools.partial(jax.jit, static_argnames=("max_stretch",))
def meanshift(
    rays: GazeRays,
    seeds: Float[Array, "S 3"],
    *,
    tol: float = 1e-4,
    max_iter: int = 500,
    max_stretch: int = 32,
) -> MeanShiftResult:
    """Run the mean-shift (Park et al. 2012, eq. 6) from each seed until a step is below ``tol`` metres.

    Jit-compatible and vmapped over seeds; each seed runs its own
    ``lax.while_loop``. Each iteration computes the closed-form update
    ``m(x)`` and then tries the stretched steps ``x + s (m(x) − x)`` for
    ``s = 1, 2, 4, …, max_stretch``, keeping the one with the largest ``f``.
    ``s = 1`` is the paper's update, so ``f`` still never decreases (Theorem 1),
    while long flat ridges (near-parallel rays) are climbed in far fewer
    iterations. ``max_stretch=1`` gives the plain eq. 6 iteration.
    A seed where every weight underflows (far from all rays) does not move and
    is reported as not converged.
    """
    if not isinstance(max_stretch, int) or max_stretch < 1 or max_stretch & (max_stretch - 1):
        raise ValueError(f"max_stretch must be a power of two ≥ 1, got {max_stretch}")
    proj = ray_projector(rays)
    if jax.default_backend() == "gpu":
        points, iterations, converged = fused_meanshift(proj, seeds, tol, max_iter=max_iter, max_stretch=max_stretch)
    else:
        points, iterations, converged = _xla_meanshift(proj, seeds, tol, max_iter, max_stretch)
    values = jax.vmap(lambda p: _field_value(proj, p))(points)
    return MeanShiftResult(points, values, iterations, converged)


# ---------------------------------------------------------------------------
# Modes, exclusive support, Laplace covariance


def _whitened_distances(proj: RayProjector, x: Float[Array, "3"]) -> tuple[Array, Array]:
    """``(‖d_i(x)‖ / h_i, in front and real)`` for every ray."""
    _, r2, ok, inv_t = _ray_coordinates(proj, x)
    return jnp.sqrt(r2) * inv_t / proj.bandwidth, ok


def _mutual_gaze(proj: RayProjector, radius: float) -> Int[Array, " N"]:
    """Each ray's partner in mutual gaze, or −1 (Park et al. 2012, Sec. 3.1: the eye in the other's cone).

    ``i`` and ``j`` look at each other when each eye lies in front of the other's ray
    with a whitened perspective distance ``‖d_i(p_j)‖/h_i`` below ``radius`` (the claim
    radius, so that the two rays alone would make a mode between the eyes). A ray
    that sees several partners takes the one with the smallest
    ``‖d_i(p_j)‖²/h_i² + ‖d_j(p_i)‖²/h_j²``, and a pair is kept only when that choice is
    mutual, so ``partner[partner[i]] = i``.
    """
    n = proj.mask.shape[0]
    dist, ok = jax.vmap(lambda eye: _whitened_distances(proj, eye))(proj.origins)  # [j, i]: eye j from ray i
    sees = ok & (dist < radius) & proj.mask[:, None]
    mutual = sees & sees.T & ~jnp.eye(n, dtype=bool)
    score = jnp.where(mutual, dist * dist + (dist * dist).T, jnp.inf)
    best = jnp.argmin(score, axis=1)
    partner = jnp.where(jnp.any(mutual, axis=1), best, -1)
    return jnp.where((partner >= 0) & (partner[jnp.maximum(partner, 0)] == jnp.arange(n)), partner, -1).astype(
        jnp.int32)


def _dominant_share(proj: RayProjector, x: Float[Array, "3"]) -> Array:
    """Largest share of one ray in the mean-shift weights ``Σ_i w_i`` at ``x`` (log-space, no underflow)."""
    _, r2, ok, inv_t = _ray_coordinates(proj, x)
    log_w = proj.exponent_scale * r2 * inv_t**2 + jnp.log(proj.weight_scale * inv_t**2)
    log_w = jnp.where(ok, log_w, -jnp.inf)
    return jnp.exp(jnp.max(log_w) - jax.nn.logsumexp(log_w))


def _member_residuals(x: Float[Array, "3"], args) -> Float[Array, "N 3"]:
    """Whitened perspective distances ``d_i(x)/h_i`` of the member rays (0 for others)."""
    rays, members = args
    diff = x - rays.origins
    t = jnp.einsum("nk,nk->n", diff, rays.directions, precision=jax.lax.Precision.HIGHEST)
    # Members sit in front of the eye at the mode; clamp so a wild LM step cannot divide by 0.
    t_safe = jnp.maximum(t, 1e-3)
    d = (diff - t[:, None] * rays.directions) / (t_safe * rays.bandwidth)[:, None]
    return jnp.where(members[:, None], d, 0.0)


def _noise_scale(rss, num_members):
    """``(E[c²], ν)`` of a concurrence's noise-scale posterior (Park et al. 2012, Sec. 3.3; module docstring, **Noise scale**).

    On a fixed grid of ``u = c²``, log-spaced over the prior's support, the
    posterior weights are ``∝ u^{−(2n−3)/2} exp(−RSS/2u)`` (trapezoidal rule in
    ``log u``); ``ν = 2a`` with ``a = 2 + E[u]²/Var[u]``, the shape of the inverse
    gamma with the same mean and variance. Fewer than 2 members (padding) count as 2.
    """
    log_u = jnp.linspace(-2.0 * math.log(_NOISE_RATIO_RANGE), 2.0 * math.log(_NOISE_RATIO_RANGE),
                         _NOISE_GRID_POINTS, dtype=rss.dtype)
    u = jnp.exp(log_u)
    k = 2.0 * jnp.maximum(num_members, 2).astype(rss.dtype) - 3.0
    ends = jnp.zeros_like(log_u).at[jnp.array([0, -1])].set(math.log(0.5))  # trapezoidal rule
    w = jax.nn.softmax(-0.5 * k * log_u - 0.5 * rss / u + ends)
    mean = jnp.sum(w * u)
    var = jnp.sum(w * (u - mean) ** 2)
    return mean, 2.0 * (2.0 + mean * mean / var)


def _refine_and_laplace(rays, members, x0, prior_scale, max_steps):
    """ML location of the members, its covariance (the Student-t's), degrees of freedom and whether the rays bound it (Park et al. 2012, Sec. 3.3).

    Levenberg–Marquardt from ``x0`` to ``argmin_x Σ_i ‖d_i(x)/h_i‖²`` over the
    members, then ``Σ_L = (JᵀJ + I/s²)⁻¹`` at the solution and, from the residual
    sum of squares there, the covariance ``E[c²]·Σ_L`` and ``ν`` (:func:`_noise_scale`).
    ``c²`` scales the covariance only: the location does not depend on it.
    """
    # float32 cannot meet float64's tolerances: LM would reach the minimum, keep stepping
    # to max_steps and report failure.
    single = jnp.finfo(x0.dtype).bits < 64
    solver = optx.LevenbergMarquardt(rtol=1e-6 if single else 1e-7, atol=1e-7 if single else 1e-9)
    sol = optx.least_squares(
        _member_residuals, solver, x0, args=(rays, members), max_steps=max_steps, throw=False
    )
    # Keep LM's point whenever it fits the members at least as well as the start, also when
    # it ran out of steps (it only ever takes steps that lower the cost).
    cost = lambda y: jnp.sum(_member_residuals(y, (rays, members)) ** 2)  # noqa: E731
    solved_cost, start_cost = cost(sol.value), cost(x0)
    ok = jnp.all(jnp.isfinite(sol.value)) & (solved_cost <= start_cost)
    x = jnp.where(ok, sol.value, x0)
    rss = jnp.where(ok, solved_cost, start_cost)  # the residual sum of squares at x
    jac = jax.jacfwd(_member_residuals)(x, (rays, members)).reshape(-1, 3)
    precision = jac.T @ jac + jnp.eye(3, dtype=x.dtype) / prior_scale**2
    mean_c2, dof = _noise_scale(rss, jnp.sum(members))
    laplace = jnp.linalg.inv(precision)
    # The data pin x down only where JᵀJ outweighs the prior's I/s²; tr Σ_L ≥ s²/2 means that
    # along some direction the prior, not the rays, holds the location (unbounded).
    bounded = jnp.trace(laplace) < 0.5 * prior_scale**2
    return x, laplace * mean_c2, dof, bounded


def _region(rays: GazeRays, x: Float[Array, "3"]) -> tuple[Array, Array]:
    """Principal axes and semi-axes of ``{f ≥ 0.8 f(x)}`` from the Hessian of ``log f``."""
    proj = ray_projector(rays)
    hess = jax.hessian(lambda y: jnp.log(_field_value(proj, y)))(x)
    curvature, axes = jnp.linalg.eigh(-0.5 * (hess + hess.T))
    level = 2.0 * math.log(1.0 / _REGION_LEVEL)
    semi = jnp.where(curvature > 0, jnp.sqrt(level / jnp.where(curvature > 0, curvature, 1.0)), jnp.inf)
    return axes, semi


_FIRST_STAGE_ITERATIONS = 40
_PRUNE_BANDWIDTHS = 4.0  # P(‖d‖ > 4h) = e⁻⁸ ≈ 3·10⁻⁴ for a true member
_ROBUST_MIN_MEMBERS = 4  # fewest members from which the noise ratio of the claims is estimated
_CLAIM_RATIO_MARGIN = 1.25  # second claims widen by ĉ/1.25: a right bandwidth's noisy ĉ ≥ 1 leaves them as
# they were (wider claims merge groups), one 2× too small still widens them 1.6×


def _robust_noise_ratio(dist: Float[Array, "K N"], members: Bool[Array, "K N"]) -> Array:
    """``max(1, ĉ)``: how much wider than their bandwidths the frame's member rays scatter (Park et al. 2012, Sec. 3.3).

    ``dist`` holds the whitened distances ``‖d_i‖/h_i`` of every ray from each of
    ``K`` refined locations and ``members`` marks each location's members. A
    member's ``s_i = ‖d_i‖²/h_i²`` is about ``ĉ²·χ²₂`` (median ``2 ln 2``), shrunk
    by the 3 coordinates fitted per location, so with ``n`` members in ``k``
    concurrences ``ĉ² = median(s) / (2 ln 2) · 2n/(2n − 3k)``. The estimate is
    pooled over the frame (the bandwidths are taken to be off by one common factor
    here; each covariance still gets its own noise scale, :func:`_noise_scale`), and
    the median ignores a stray ray of another group. With fewer than
    ``_ROBUST_MIN_MEMBERS`` members, and when the rays scatter less than the
    bandwidths say, the ratio is 1. Used only to widen the claim and prune radii.
    """
    n = jnp.sum(members)
    k = jnp.sum(jnp.any(members, axis=-1))
    s = jnp.sort(jnp.where(members, dist * dist, jnp.inf).reshape(-1))
    half = jnp.maximum(n - 1, 0) // 2
    median = 0.5 * (s[half] + s[jnp.maximum(n, 1) // 2])
    ratio2 = median / (2.0 * math.log(2.0)) * (2.0 * n) / jnp.maximum(2.0 * n - 3.0 * k, 1.0)
    return jnp.where(n >= _ROBUST_MIN_MEMBERS, jnp.sqrt(jnp.maximum(ratio2, 1.0)), 1.0)


def _two_stage_meanshift(rays, seeds, seed_ok, *, tol, max_iter, keep):
    """Mean-shift all seeds for a few iterations, then only the most promising to the end.

    Under ``vmap`` every seed runs as long as the slowest one, and the slow ones
    are mostly seeds sliding along a lone ray that will be rejected anyway. So
    all seeds get ``_FIRST_STAGE_ITERATIONS``; of those still moving, the
    ``keep`` with the highest ``f`` continue up to ``max_iter``. The others keep
    their (uphill) positions and stay candidates.
    """
    first = meanshift(rays, seeds, tol=tol, max_iter=min(max_iter, _FIRST_STAGE_ITERATIONS))
    if max_iter <= _FIRST_STAGE_ITERATIONS:
        return first
    keep = min(keep, seeds.shape[0])
    moving = seed_ok & ~first.converged
    _, chosen = jax.lax.top_k(jnp.where(moving, first.field_values, -jnp.inf), keep)
    second = meanshift(rays, first.points[chosen], tol=tol, max_iter=max_iter - _FIRST_STAGE_ITERATIONS)
    go_on = moving[chosen]

    def merge(a, b):
        return a.at[chosen].set(jnp.where(go_on.reshape((-1,) + (1,) * (b.ndim - 1)), b, a[chosen]))

    return MeanShiftResult(
        points=merge(first.points, second.points),
        field_values=merge(first.field_values, second.field_values),
        iterations=merge(first.iterations, first.iterations[chosen] + second.iterations),
        converged=merge(first.converged, second.converged),
    )


def _concurrences_one_frame(
    rays: GazeRays,
    seed_depths: Float[Array, " S"],
    region: tuple[Float[Array, "2 3"], Float[Array, ""]],
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> Concurrences:
    min_rays, claim_bandwidths, dominance = options.min_rays, options.claim_bandwidths, options.dominance
    merge_radius, prior_scale, refine_steps = options.merge_radius, options.prior_scale, options.refine_steps
    search_scale, tol, max_iter = options.search_scale, options.tol, options.max_iter
    n = rays.num_rays
    dtype = rays.origins.dtype
    search = eqx.tree_at(lambda r: r.bandwidth, rays, rays.bandwidth * search_scale)
    proj, search_proj = ray_projector(rays), ray_projector(search)
    seeds = rays.origins[:, None, :] + seed_depths[None, :, None] * rays.directions[:, None, :]
    seeds = seeds.reshape(-1, 3)
    seed_ok = jnp.repeat(rays.mask, seed_depths.shape[0])
    ms = _two_stage_meanshift(search, seeds, seed_ok, tol=tol, max_iter=max_iter, keep=2 * max_modes + 2)
    # Seeds that hit the iteration cap have still only climbed f, so they stay candidates.
    # The box, raised to the floor: at most floor_below_eyes (inf: off) under the lowest eye.
    bounds, floor_below_eyes = region
    lowest = jnp.min(jnp.where(rays.mask, rays.origins[:, 2], jnp.inf))
    bounds = bounds.at[0, 2].max(jnp.where(jnp.isfinite(lowest), lowest - floor_below_eyes, -jnp.inf))
    inside = lambda x: jnp.all((x >= bounds[0]) & (x <= bounds[1]), axis=-1)  # noqa: E731
    # Two people looking at each other: their rays alone make a flat ridge between the eyes, not a mode.
    partner = _mutual_gaze(proj, claim_bandwidths * search_scale)
    pair = partner[:, None] == jnp.arange(n)[None, :]
    only_a_pair = lambda m: (jnp.sum(m, -1) == 2) & jnp.any(m[..., :, None] & m[..., None, :] & pair, (-2, -1))  # noqa: E731
    score = jnp.where(seed_ok & (ms.field_values > 0) & inside(ms.points), ms.field_values, -jnp.inf)
    order = jnp.argsort(-score)

    def claim(claim_proj):
        """Exclusive support (step 3) with distances whitened by ``claim_proj``'s bandwidths."""

        def visit(carry, s):
            claimed, membership, modes, mode_conv, count = carry
            x = ms.points[s]
            dist, ok = _whitened_distances(claim_proj, x)
            candidates = ok & (dist < claim_bandwidths) & ~claimed
            slot = jnp.arange(max_modes)
            near_existing = jnp.any((slot < count) & (jnp.linalg.norm(modes - x, axis=-1) < merge_radius))
            accept = (
                jnp.isfinite(score[s])
                & ~near_existing
                & (_dominant_share(claim_proj, x) <= dominance)
                & (jnp.sum(candidates) >= min_rays)
                & ~only_a_pair(candidates)
                & (count < max_modes)
            )
            claimed = claimed | (candidates & accept)
            membership = jnp.where(candidates & accept, count, membership)
            modes = jnp.where(accept & (slot == count)[:, None], x, modes)
            mode_conv = jnp.where(accept & (slot == count), ms.converged[s], mode_conv)
            return (claimed, membership, modes, mode_conv, count + accept.astype(jnp.int32)), None

        init = (
            jnp.zeros(n, bool),
            jnp.full(n, -1, jnp.int32),
            jnp.zeros((max_modes, 3), dtype),
            jnp.zeros(max_modes, bool),
            jnp.int32(0),
        )
        (_, membership, modes, mode_conv, count), _ = jax.lax.scan(visit, init, order)
        return membership, modes, mode_conv, jnp.arange(max_modes) < count

    def over_modes(fn, *xs):
        # Keeps the batched LAPACK calls below the size at which XLA:CPU can deadlock (see _batching).
        if modes_per_batch >= max_modes:
            return jax.vmap(fn)(*xs)
        return jax.lax.map(lambda a: fn(*a), xs, batch_size=modes_per_batch)

    refine = functools.partial(over_modes, lambda m, x0: _refine_and_laplace(rays, m, x0, prior_scale, refine_steps))
    slots = jnp.arange(max_modes)[:, None]

    # Claims at the user's bandwidth give a first estimate of how much wider the
    # rays scatter: the robust noise ratio ĉ ≥ 1 of the members at their refined
    # locations, pooled over the frame. The claims are made again with the
    # bandwidth times max(1, ĉ/1.25), so that a bandwidth too small for the rays
    # does not cut off the tail of each concurrence's residuals (which would make
    # its noise scale, and its covariance, too small). With ĉ ≤ 1.25 nothing changes.
    membership, modes, _, valid = claim(search_proj)
    initial = (membership[None, :] == slots) & valid[:, None]
    first = refine(initial, modes)[0]
    dist, _ = jax.vmap(lambda x: _whitened_distances(search_proj, x))(first)
    ratio = _robust_noise_ratio(dist * search_scale, initial)
    widen = jnp.maximum(1.0, ratio / _CLAIM_RATIO_MARGIN)
    wide_proj = ray_projector(eqx.tree_at(lambda r: r.bandwidth, search, search.bandwidth * widen))
    membership, modes, mode_conv, valid = claim(wide_proj)

    # The mixture mode sits where a subset of rays crosses tightly, so a true
    # member with a large residual can lie outside the claim radius there. Claim
    # the still-unclaimed rays again at each mode's refined (maximum-likelihood)
    # location, nearest mode first, and refine once more. These claims cannot merge
    # groups, so their radius takes the whole ratio ĉ.
    first = refine(membership[None, :] == slots, modes)[0]
    dist, ok = jax.vmap(lambda x: _whitened_distances(search_proj, x))(first)
    dist = jnp.where(valid[:, None] & ok & (dist < claim_bandwidths * ratio), dist, jnp.inf)
    nearest = jnp.argmin(dist, axis=0)
    late = (membership < 0) & jnp.isfinite(jnp.min(dist, axis=0))
    membership = jnp.where(late, nearest, membership)
    member_mask = membership[None, :] == slots
    second = refine(member_mask, first)[0]
    # A wide search radius can also take in a stray ray of another group. Drop
    # members that the cone model rejects at the refined location
    # (‖d‖ > prune_bandwidths · ĉ h, ĉ the frame's robust noise ratio, at least 1),
    # drop modes left with too few rays, refine again.
    dist, _ = jax.vmap(lambda x: _whitened_distances(proj, x))(second)
    stray = member_mask & (dist > _PRUNE_BANDWIDTHS * _robust_noise_ratio(dist, member_mask & valid[:, None]))
    member_mask = member_mask & ~stray
    valid = valid & (jnp.sum(member_mask, axis=1) >= min_rays) & inside(second) & ~only_a_pair(member_mask)
    member_mask = member_mask & valid[:, None]
    locations, covariances, dof, bounded = refine(member_mask, second)
    # A mode the rays do not bound (the prior holds it along some direction) is no concurrence.
    valid = valid & bounded
    member_mask = member_mask & valid[:, None]
    membership = jnp.where(jnp.any(member_mask, axis=0), jnp.argmax(member_mask, axis=0), -1).astype(jnp.int32)
    axes, semi = over_modes(lambda x: _region(rays, x), locations)
    values = jax.vmap(lambda x: _field_value(proj, x))(locations)

    # The valid modes first (in claim order), so that membership indexes the modes a frame keeps.
    order = jnp.argsort(~valid, stable=True)
    slot_of = jnp.zeros(max_modes, jnp.int32).at[order].set(jnp.arange(max_modes, dtype=jnp.int32))
    membership = jnp.where(membership >= 0, slot_of[jnp.maximum(membership, 0)], -1)
    valid = valid[order]

    def pad(a, fill=0.0):
        a = a[order]
        mask = valid.reshape(valid.shape + (1,) * (a.ndim - 1))
        return jnp.where(mask, a, jnp.asarray(fill, a.dtype))

    return Concurrences(
        locations=pad(locations),
        covariances=pad(covariances),
        field_values=pad(values),
        num_rays=jnp.sum(member_mask, axis=1).astype(jnp.int32)[order],
        membership=membership,
        region_axes=pad(axes),
        region_semi_axes=pad(semi),
        converged=pad(mode_conv, False),
        valid=valid,
        degrees_of_freedom=pad(dof),
        mutual_gaze=partner,
    )


_STATIC = ("options", "max_modes", "modes_per_batch")
_one_frame_jit = jax.jit(_concurrences_one_frame, static_argnames=_STATIC)
# jax.vmap does not forward keyword arguments to in_axes, so wrap explicitly.
_over_frames_jit = jax.jit(
    lambda rays, depths, bounds, **kw: jax.vmap(lambda r: _concurrences_one_frame(r, depths, bounds, **kw))(rays),
    static_argnames=_STATIC,
)


def _prepare(rays, options):
    """``(seed depths, (bounds box, floor below the eyes), static keywords)`` of the compiled programs
    for ``rays``. The box and the floor are arguments, not part of the static options, so that
    changing them does not compile the program again."""
    if not isinstance(rays, GazeRays):
        raise TypeError(f"expected jaxgaze.GazeRays, got {type(rays).__name__}")
    if not isinstance(options, ConcurrenceOptions):
        raise TypeError(f"options must be a jaxgaze.ConcurrenceOptions, got {type(options).__name__}")
    dtype = rays.origins.dtype
    box = np.array([[-np.inf] * 3, [np.inf] * 3]) if options.bounds is None else np.asarray(options.bounds)
    floor = np.inf if options.floor_below_eyes is None else options.floor_below_eyes
    n = rays.num_rays
    k = n // options.min_rays if options.max_modes is None else min(options.max_modes, n // options.min_rays)
    program_options = dataclasses.replace(options, bounds=None, floor_below_eyes=None)
    static = dict(options=program_options, max_modes=k, modes_per_batch=_batch_plan(n, k)[1])
    return jnp.asarray(options.seed_depths, dtype), (jnp.asarray(box, dtype), jnp.asarray(floor, dtype)), static


#: Frames per compiled batch on XLA:CPU when the LAPACK bound allows more.
MAX_FRAMES_PER_BATCH = 64


def _lapack_cost_per_mode(n: int) -> int:
    """Largest LAPACK flop estimate that one mode adds to a batched call.

    The Levenberg–Marquardt step solves the damped ``(3n + 3) × 3`` least-squares
    system by QR; the covariance takes an LU of a ``3 × 3`` and the region an
    ``eigh`` of one.
    """
    return max(lapack_qr_cost(3 * n + 3, 3), lapack_eigh_cost(3), lapack_lu_cost(3))


def _batch_plan(n: int, k: int) -> tuple[int, int]:
    """``(frames, modes)`` per batched LAPACK call that keep XLA:CPU clear of its deadlock.

    On other backends every frame and mode go in one batch (frames ``0`` means all).
    """
    if k == 0 or not lapack_guard_applies():
        return 0, max(k, 1)
    per_mode = _lapack_cost_per_mode(n)
    modes = lapack_safe_batch(per_mode, k)
    frames = lapack_safe_batch(k * per_mode, MAX_FRAMES_PER_BATCH) if modes == k else 1
    return frames, modes


def _masked_padding(rays: GazeRays, size: int) -> GazeRays:
    """Pad a ``(B, N)`` slice to ``size`` frames with empty frames (every ray masked)."""
    padded = repeat_last(rays, size)
    mask = np.array(padded.mask)
    mask[rays.batch_shape[0]:] = False
    return eqx.tree_at(lambda r: r.mask, padded, mask)


@functools.partial(jax.jit, static_argnames=("radius",))
def _mutual_gaze_over_frames(rays: GazeRays, radius: float):
    return jax.vmap(lambda r: _mutual_gaze(ray_projector(r), radius))(rays)


def _empty(rays: GazeRays, options: ConcurrenceOptions) -> Concurrences:
    """No mode (too few rays for ``min_rays``); people may still look at each other."""
    batch_shape, n, dtype = rays.batch_shape, rays.num_rays, rays.origins.dtype
    z = lambda *s, dt=dtype: jnp.zeros(batch_shape + (0,) + s, dt)  # noqa: E731
    partner = jnp.full(batch_shape + (n,), -1, jnp.int32)
    if n >= 2 and math.prod(batch_shape) > 0:
        flat = jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[len(batch_shape):]), rays)
        radius = options.claim_bandwidths * options.search_scale
        partner = _mutual_gaze_over_frames(flat, radius).reshape(batch_shape + (n,))
    return Concurrences(
        locations=z(3), covariances=z(3, 3), field_values=z(), num_rays=z(dt=jnp.int32),
        membership=jnp.full(batch_shape + (n,), -1, jnp.int32), region_axes=z(3, 3),
        region_semi_axes=z(3), converged=z(dt=bool), valid=z(dt=bool), degrees_of_freedom=z(),
        mutual_gaze=partner,
    )


def find_concurrences(
    rays: GazeRays,
    options: ConcurrenceOptions = ConcurrenceOptions(),
) -> Concurrences:
    """Number, locations and uncertainty of the gaze concurrences in one frame (Park et al. 2012, Sec. 3.3).

    Args:
        rays: one frame of primary gaze rays, ``(N, 3)``, world frame, metres.
        options: the search options, a :class:`ConcurrenceOptions` (seeds, bounds,
            ``min_rays``, claim and merge radii, stopping rules, prior, ``max_modes``).

    Returns:
        :class:`Concurrences` with exactly the ``K`` modes found, ordered by
        decreasing field value. One ray or none gives ``K = 0``.

    What is not a concurrence (the defaults, documented in ``docs/index.md``):

    * **Under the floor.** Modes more than ``options.floor_below_eyes`` (2.5 m) below
      the lowest eye of the frame (world +z up) are rejected.
    * **Mutual gaze.** Two people whose eyes each lie in the other's ray's claim
      radius (``claim_bandwidths · search_scale · h``) look at each other. Their two
      rays alone make a flat ridge between the eyes, not a point of regard: a mode
      supported only by such a pair is rejected, and the pair is reported in
      ``mutual_gaze`` (each person's partner, or −1). Either may still support a
      concurrence with others, e.g. a third person looking at the same face.
    * **Unbounded.** A mode whose rays leave it unbounded in some direction (the
      weak prior, not the rays, holds it: ``tr Σ_L ≥ prior_scale²/2``) is rejected,
      so a reported covariance always comes from the rays.

    Units are checked at the door (:func:`jaxgaze.rays.check_units`): a bandwidth of
    1 rad or more is an error, one over 0.5 rad or eyes of one frame spread over more
    than 100 m a :class:`~jaxgaze.rays.UnitWarning` (degrees? millimetres?).

    Precision: float32 and float64 rays give the same modes and memberships and agree
    to within 10 µm on the locations (below the mean-shift stopping step of 0.1 mm;
    scenes within tens of metres of the origin) and 1e-5 relative on the covariances
    and field values.
    """
    if isinstance(rays, GazeRays) and rays.batch_shape:
        raise ValueError(
            f"find_concurrences takes one frame; rays have batch shape {rays.batch_shape}. "
            "Use find_concurrences_over_frames for a recording."
        )
    if _prepare(rays, options)[2]["max_modes"] == 0:
        check_units(rays)
        return _empty(rays, options)
    n = rays.num_rays
    # Pad to a multiple of 8 rays so that scenes of similar size share one compilation;
    # padded rays are masked and can never be claimed, so K stays ≤ n // min_rays.
    padded = _pad_rays(rays, bucket_size(n, minimum=0, multiple=_RAY_BUCKET))
    check_units(rays)
    depths, box, static = _prepare(padded, options)
    result = _one_frame_jit(padded, depths, box, **static)
    keep = np.asarray(result.valid)
    return Concurrences(
        **{
            name: (value[:n] if name in _PER_RAY else value[keep])
            for name, value in result._asdict().items()
        }
    )


_RAY_BUCKET = 8


def _pad_rays(rays: GazeRays, n: int) -> GazeRays:
    extra = n - rays.num_rays
    if extra == 0:
        return rays
    pad = lambda a: jnp.concatenate([a, jnp.zeros((extra,) + a.shape[1:], a.dtype)])  # noqa: E731
    return GazeRays(pad(rays.origins), pad(rays.directions), pad(rays.bandwidth), pad(rays.mask))


def find_concurrences_over_frames(
    rays: GazeRays,
    options: ConcurrenceOptions = ConcurrenceOptions(),
    *,
    frames_per_batch: int | None = None,
    progress: bool = False,
) -> Concurrences:
    """:func:`find_concurrences` for a whole recording, vmapped over batches of frames (Park et al. 2012, Sec. 3.3).

    ``rays`` has shape ``(T, N, 3)`` with ``rays.mask`` marking the people
    present in each frame (see :meth:`GazeRays.stack`); ``options`` is a
    :class:`ConcurrenceOptions`. The result is padded to
    ``K = options.max_modes`` (default ``N // min_rays``) modes per frame; ``valid``
    marks the real ones and ``count`` gives K per frame. Its arrays are numpy
    arrays on the host.

    The recording goes through one compiled program of ``frames_per_batch``
    frames (the last batch is padded with empty frames), so recordings of any
    length share one compilation. On CPU the default is the largest batch, at
    most ``MAX_FRAMES_PER_BATCH``, whose batched LAPACK calls stay below the size
    at which XLA:CPU splits them over its thread pool and can deadlock (see
    ``docs/runtime.md``); a larger ``frames_per_batch`` is refused there. Batches
    run on one host thread per core. On GPU every frame goes in one batch.
    ``progress`` shows a bar of frames done on stderr. What is not a concurrence, and
    the unit checks: as for :func:`find_concurrences`.
    """
    if not isinstance(rays, GazeRays) or len(rays.batch_shape) != 1:
        shape = rays.batch_shape if isinstance(rays, GazeRays) else None
        raise ValueError(f"find_concurrences_over_frames needs rays of shape (T, N, 3); batch shape is {shape}")
    depths, box, static = _prepare(rays, options)
    check_units(rays)
    total = rays.batch_shape[0]
    if static["max_modes"] == 0 or total == 0:
        return Concurrences(*(np.asarray(a) for a in _empty(rays, options)))
    safe, _ = _batch_plan(rays.num_rays, static["max_modes"])
    if frames_per_batch is None:
        batch = safe or total
    else:
        if int(frames_per_batch) != frames_per_batch or frames_per_batch < 1:
            raise ValueError(f"frames_per_batch must be a positive integer, got {frames_per_batch!r}")
        batch = int(frames_per_batch)
        if safe and batch > safe:
            raise ValueError(
                f"frames_per_batch={batch} is too large on CPU for {rays.num_rays} rays: at most {safe} frames keep "
                "XLA:CPU's batched LAPACK calls from deadlocking (see docs/runtime.md)"
            )
    return map_in_batches(lambda part: _over_frames_jit(part, depths, box, **static), rays, batch,
                          pad=_masked_padding, progress=progress, desc="concurrences")


# ---------------------------------------------------------------------------
# Tracking over frames


def track_concurrences(concurrences: Concurrences, *, max_distance: float = 0.5, max_gap: int = 2) -> Tracks:
    """Link the modes of consecutive frames into trajectories with birth and death (Park et al. 2012, Sec. 3.3).

    A ``lax.scan`` over frames. In each frame the modes, strongest first, take
    the nearest live track within ``max_distance`` metres that is not yet taken;
    a mode with none starts a new track (birth). A track not seen for more than
    ``max_gap`` frames ends (death) and is never revived.
    """
    if concurrences.locations.ndim != 3:
        raise ValueError("track_concurrences needs the padded (T, K) result of find_concurrences_over_frames")
    if not max_distance > 0 or max_gap < 0:
        raise ValueError("max_distance must be positive and max_gap non-negative")
    k = concurrences.locations.shape[1]
    slots = 2 * k  # live tracks at once: this frame's and those waiting out a gap
    big = jnp.asarray(jnp.inf, concurrences.locations.dtype)

    def frame(carry, inputs):
        track_id, track_loc, unseen, next_id = carry
        locations, valid, values = inputs
        order = jnp.argsort(jnp.where(valid, -values, jnp.inf))
        live = (track_id >= 0) & (unseen <= max_gap)

        def assign(j, state):
            ids_out, taken, track_id, track_loc, next_id = state
            m = order[j]
            dist = jnp.linalg.norm(track_loc - locations[m], axis=-1)
            dist = jnp.where(live & ~taken & (dist <= max_distance), dist, big)
            best = jnp.argmin(dist)
            matched = valid[m] & jnp.isfinite(dist[best])
            free = jnp.argmax(~live & ~taken)  # a dead or empty slot for a newborn
            slot = jnp.where(matched, best, free)
            born = valid[m] & ~matched
            new_id = jnp.where(matched, track_id[slot], next_id)
            ids_out = ids_out.at[m].set(jnp.where(valid[m], new_id, -1))
            taken = taken.at[slot].set(taken[slot] | valid[m])
            track_id = track_id.at[slot].set(jnp.where(valid[m], new_id, track_id[slot]))
            track_loc = track_loc.at[slot].set(jnp.where(valid[m], locations[m], track_loc[slot]))
            return ids_out, taken, track_id, track_loc, next_id + born.astype(jnp.int32)

        ids_out = jnp.full(k, -1, jnp.int32)
        ids_out, taken, track_id, track_loc, next_id = jax.lax.fori_loop(
            0, k, assign, (ids_out, jnp.zeros(slots, bool), track_id, track_loc, next_id)
        )
        unseen = jnp.where(taken, 0, unseen + 1)
        track_id = jnp.where(unseen > max_gap, -1, track_id)
        return (track_id, track_loc, unseen, next_id), ids_out

    init = (
        jnp.full(slots, -1, jnp.int32),
        jnp.zeros((slots, 3), concurrences.locations.dtype),
        jnp.zeros(slots, jnp.int32),
        jnp.int32(0),
    )
    (_, _, _, num), ids = jax.lax.scan(
        frame, init, (concurrences.locations, concurrences.valid, concurrences.field_values)
    )
    return Tracks(track_ids=ids, num_tracks=num)
