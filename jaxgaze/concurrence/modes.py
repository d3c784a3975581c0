"""Gaze concurrences: modes of the social saliency field (Park et al. 2012, Sec. 3.3).

Pipeline for one frame (all in JAX, fixed shapes, so it vmaps over frames):

1. **Seeds** at fixed depths along every primary ray.
2. **Mean-shift** (eq. 5–6) on the field smoothed with bandwidth
   ``search_scale · h`` from every seed, until a step is shorter than ``tol`` or
   after ``max_iter`` steps. On CPU each step is one evaluation of the update ``m``
   and the field ``f``, stretched adaptively so that ``f`` never falls, and the seeds
   still moving are compacted every few steps, so converged seeds cost nothing; on
   GPU the fused kernel runs every seed. Two noisy
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
    mean_c2, dof = _noise_scale(rss, jnp.sum(members))
    laplace = _laplace_covariance(jac, prior_scale)
    # The data pin x down only where JᵀJ outweighs the prior's I/s²; tr Σ_L ≥ s²/2 means that
    # along some direction the prior, not the rays, holds the location (unbounded). A covariance
    # that is not finite (a NaN or inf in the Jacobian) is no bound either.
    bounded = jnp.all(jnp.isfinite(laplace)) & (jnp.trace(laplace) < 0.5 * prior_scale**2)
    return x, laplace * mean_c2, dof, bounded


def _laplace_covariance(jac: Float[Array, "M 3"], prior_scale) -> Float[Array, "3 3"]:
    """``Σ_L = (JᵀJ + I/s²)⁻¹`` as the Gram matrix ``R⁻¹R⁻ᵀ`` (Park et al. 2012, Sec. 3.3; module docstring, step 4).

    ``R`` is the triangle of the QR of ``[J; I/s]``, so ``RᵀR = JᵀJ + I/s²`` without forming
    ``JᵀJ``: its conditioning is the square root of the precision's, and ``R⁻¹R⁻ᵀ`` is symmetric
    positive semi-definite in any arithmetic. Inverting ``JᵀJ + I/s²`` itself in float32 could give
    negative variances in crowded frames (eigenvalues −0.67, 5e-9, 8e-9 m² with 1,000 people).
    ``R⁻¹`` of the 3 × 3 triangle is written out (no LAPACK call).
    """
    stacked = jnp.concatenate([jac, jnp.eye(3, dtype=jac.dtype) / prior_scale])
    r = jnp.linalg.qr(stacked, mode="r")
    (a, b, c), (_, d, e), (_, _, f) = r[0], r[1], r[2]
    zero = jnp.zeros_like(a)
    inverse = jnp.stack([
        jnp.stack([1.0 / a, -b / (a * d), (b * e - c * d) / (a * d * f)]),
        jnp.stack([zero, 1.0 / d, -e / (d * f)]),
        jnp.stack([zero, zero, 1.0 / f]),
    ])
    return inverse @ inverse.T


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


_CLIMB_STRETCH = 32  # longest stretch of an accepted step, as meanshift's default max_stretch
_CLIMB_CHUNK = 256  # seeds climbed together between compactions (all of them when there are fewer)
_CLIMB_ROUND = 8  # evaluations per seed between compactions in the first stage


class _Climb(NamedTuple):
    """Per-seed state of the adaptive ascent of :func:`_two_stage_meanshift`."""

    x: Float[Array, "S 3"]
    value: Float[Array, " S"]  # f(x), eq. 3
    target: Float[Array, "S 3"]  # m(x), eq. 6
    stretch: Float[Array, " S"]  # the next proposal is x + stretch · (m(x) − x)
    iterations: Int[Array, " S"]  # evaluations of f and m spent on the seed
    done: Bool[Array, " S"]  # ‖m(x) − x‖ < tol (also where every weight underflows: m(x) = x)
    alive: Bool[Array, " S"]  # Σ w > 0 at x


def _climb_values(proj: RayProjector, x: Float[Array, "3"]) -> tuple[Array, Array, Array]:
    """``(m(x), f(x), Σ w)`` in one pass over the rays: eq. 6's update (as :func:`_meanshift_step`) and
    eq. 3's field (as :func:`_field_value`) share the kernel ``exp(−r²/2h²t²)``."""
    t, r2, ok, inv_t = _ray_coordinates(proj, x)
    inv_t2 = inv_t * inv_t
    kernel = jnp.where(ok, jnp.exp(proj.exponent_scale * r2 * inv_t2), 0.0)
    w = kernel * (inv_t2 * proj.weight_scale)
    total = jnp.sum(w)
    exact = jax.lax.Precision.HIGHEST
    target = jnp.matmul(w, proj.origins, precision=exact) + jnp.matmul(w * (r2 * inv_t + t), proj.directions, precision=exact)
    m = jnp.where(total > 0, target / jnp.where(total > 0, total, 1.0), x)
    value = jnp.sum(kernel / (proj.bandwidth * math.sqrt(2.0 * math.pi))) / jnp.maximum(jnp.sum(proj.mask), 1)
    return m, value, total


def _climb_start(proj: RayProjector, seeds: Float[Array, "S 3"], tol) -> _Climb:
    m, value, total = jax.vmap(functools.partial(_climb_values, proj))(seeds)
    count = seeds.shape[0]
    return _Climb(seeds, value, m, jnp.ones(count, seeds.dtype), jnp.zeros(count, jnp.int32),
                  jnp.linalg.norm(m - seeds, axis=-1) < tol, total > 0)


def _climb_step(proj: RayProjector, state: _Climb, go: Bool[Array, " S"], tol, limit) -> _Climb:
    """One evaluation per seed of ``go`` still climbing: the proposal ``x + s (m(x) − x)`` is taken if
    ``f`` does not fall there (always for ``s = 1``, eq. 6, by Park et al. 2012, Theorem 1); then ``s``
    doubles, up to ``_CLIMB_STRETCH``. A refused proposal costs the evaluation and sets ``s = 1``."""
    x, s = state.x, state.stretch
    active = go & ~state.done & (state.iterations < limit)
    proposal = x + s[:, None] * (state.target - x)
    m, value, total = jax.vmap(functools.partial(_climb_values, proj))(proposal)
    accept = (value >= state.value) | (s <= 1)
    move = active & accept
    x = jnp.where(move[:, None], proposal, x)
    m = jnp.where(move[:, None], m, state.target)
    return _Climb(
        x=x,
        value=jnp.where(move, value, state.value),
        target=m,
        stretch=jnp.where(active, jnp.where(accept, jnp.minimum(2.0 * s, _CLIMB_STRETCH), 1.0), s),
        iterations=state.iterations + active.astype(jnp.int32),
        done=state.done | (move & (jnp.linalg.norm(m - x, axis=-1) < tol)),
        alive=jnp.where(move, total > 0, state.alive),
    )


def _climb(proj: RayProjector, state: _Climb, eligible: Bool[Array, " S"], tol, limit) -> _Climb:
    """Climb every ``eligible`` seed until it is done or has spent ``limit`` evaluations.

    The seeds still climbing are gathered first and taken ``_CLIMB_CHUNK`` at a
    time, each chunk a ``lax.while_loop`` that ends when its last seed stops, so
    seeds that are done cost nothing.
    """
    count = state.x.shape[0]
    chunk = min(_CLIMB_CHUNK, count)
    climbing = eligible & ~state.done & (state.iterations < limit)
    order = jnp.argsort(~climbing, stable=True)
    remaining = jnp.sum(climbing)

    def one_chunk(k, state):
        position = k * chunk + jnp.arange(chunk)
        go = position < remaining
        index = jnp.where(go, order.at[position].get(mode="clip"), count)  # out of range: not written back
        part = jax.tree_util.tree_map(lambda a: a.at[index].get(mode="clip"), state)
        part = jax.lax.while_loop(
            lambda p: jnp.any(go & ~p.done & (p.iterations < limit)),
            lambda p: _climb_step(proj, p, go, tol, limit),
            part,
        )
        return jax.tree_util.tree_map(lambda a, b: a.at[index].set(b, mode="drop"), state, part)

    return jax.lax.fori_loop(0, (remaining + chunk - 1) // chunk, one_chunk, state)


def _two_stage_meanshift(rays, seeds, seed_ok, *, tol, max_iter, keep):
    """Mean-shift all seeds for a few iterations, then only the most promising to the end (Park et al. 2012, eq. 6).

    Under ``vmap`` every seed would run as long as the slowest one, and the slow
    ones are mostly seeds sliding along a lone ray that will be rejected anyway.
    So all seeds get ``_FIRST_STAGE_ITERATIONS``; of those still moving, the
    ``keep`` with the highest ``f`` continue up to ``max_iter``. The others keep
    their (uphill) positions and stay candidates.

    On GPU each stage is :func:`meanshift` (the fused kernel). On CPU each
    iteration is a single evaluation of ``m`` and ``f`` per seed: the step is
    stretched adaptively (:func:`_climb_step`, ``f`` never decreases) rather than
    by trying every stretch, and the seeds still moving are compacted every
    ``_CLIMB_ROUND`` iterations (:func:`_climb`), so converged seeds stop costing.
    """
    first_stage = min(max_iter, _FIRST_STAGE_ITERATIONS)
    keep = min(keep, seeds.shape[0])
    if jax.default_backend() == "gpu":
        return _two_stage_fused(rays, seeds, seed_ok, tol=tol, max_iter=max_iter, keep=keep)
    proj = ray_projector(rays)

    def rounds(state, eligible, limits):  # one compiled loop body per stage
        limits = jnp.asarray(limits, jnp.int32)
        return jax.lax.fori_loop(0, len(limits), lambda r, st: _climb(proj, st, eligible, tol, limits[r]), state)

    state = rounds(_climb_start(proj, seeds, tol), seed_ok, [*range(_CLIMB_ROUND, first_stage, _CLIMB_ROUND), first_stage])
    if max_iter > first_stage:
        moving = seed_ok & ~state.done
        _, chosen = jax.lax.top_k(jnp.where(moving, state.value, -jnp.inf), keep)
        eligible = jnp.zeros_like(moving).at[chosen].set(moving[chosen])
        longer = [first_stage * 2**k for k in range(1, 4) if first_stage * 2**k < max_iter]
        state = rounds(state, eligible, [*longer, max_iter])
    return MeanShiftResult(state.x, state.value, state.iterations, state.done & state.alive)


def _two_stage_fused(rays, seeds, seed_ok, *, tol, max_iter, keep):
    """:func:`_two_stage_meanshift` with :func:`meanshift` (on GPU, the fused kernel) for each stage."""
    first = meanshift(rays, seeds, tol=tol, max_iter=min(max_iter, _FIRST_STAGE_ITERATIONS))
    if max_iter <= _FIRST_STAGE_ITERATIONS:
        return first
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


def _seeds_along_rays(rays: GazeRays, depths: Float[Array, " D"]) -> tuple[Array, Array]:
    """``(N·D, 3)`` seeds at ``depths`` along every primary ray, and which belong to real rays."""
    seeds = rays.origins[:, None, :] + depths[None, :, None] * rays.directions[:, None, :]
    return seeds.reshape(-1, 3), jnp.repeat(rays.mask, depths.shape[0])


def _concurrences_one_frame(
    rays: GazeRays,
    seed_depths: Float[Array, " S"],
    region: tuple[Float[Array, "2 3"], Float[Array, ""]],
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> Concurrences:
    seeds, seed_ok = _seeds_along_rays(rays, seed_depths)
    return _concurrences_from_seeds(rays, seeds, seed_ok, region, options=options, max_modes=max_modes,
                                    modes_per_batch=modes_per_batch)


def _concurrences_from_seeds(
    rays: GazeRays,
    seeds: Float[Array, "S 3"],
    seed_ok: Bool[Array, " S"],
    region: tuple[Float[Array, "2 3"], Float[Array, ""]],
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> Concurrences:
    """Steps 2–5 of the module docstring from the given mean-shift seeds (Park et al. 2012, Sec. 3.3)."""
    min_rays, claim_bandwidths, dominance = options.min_rays, options.claim_bandwidths, options.dominance
    merge_radius, prior_scale, refine_steps = options.merge_radius, options.prior_scale, options.refine_steps
    search_scale, tol, max_iter = options.search_scale, options.tol, options.max_iter
    n = rays.num_rays
    dtype = rays.origins.dtype
    search = eqx.tree_at(lambda r: r.bandwidth, rays, rays.bandwidth * search_scale)
    proj, search_proj = ray_projector(rays), ray_projector(search)
    ms = _two_stage_meanshift(search, seeds, seed_ok, tol=tol, max_iter=max_iter, keep=2 * max_modes + 2)
    # Seeds that hit the iteration cap have still only climbed f, so they stay candidates.
    # The box, raised to the floor: at most floor_below_eyes (inf: off) under the lowest eye.
    bounds = _region_box(rays, region)
    inside = lambda x: jnp.all((x >= bounds[0]) & (x <= bounds[1]), axis=-1)  # noqa: E731
    # Two people looking at each other: their rays alone make a flat ridge between the eyes, not a mode.
    partner = _mutual_gaze(proj, claim_bandwidths * search_scale)
    # A ray set that is exactly one such pair (O(N): a member whose partner is a member too).
    has_partner = partner >= 0
    only_a_pair = lambda m: (jnp.sum(m, -1) == 2) & jnp.any(m & has_partner & m[..., jnp.maximum(partner, 0)], -1)  # noqa: E731
    score = jnp.where(seed_ok & (ms.field_values > 0) & inside(ms.points), ms.field_values, -jnp.inf)

    def claim(claim_proj):
        """Exclusive support (step 3) with distances whitened by ``claim_proj``'s bandwidths."""

        # What does not depend on the claims so far, for every seed at once; the scan then
        # only does O(N + K) work per seed.
        dist, ok = jax.vmap(lambda x: _whitened_distances(claim_proj, x))(ms.points)
        near = ok & (dist < claim_bandwidths)
        eligible = jnp.isfinite(score) & (jax.vmap(lambda x: _dominant_share(claim_proj, x))(ms.points) <= dominance)

        def visit(carry, s):
            claimed, membership, modes, mode_conv, count = carry
            x = ms.points[s]
            candidates = near[s] & ~claimed
            slot = jnp.arange(max_modes)
            near_existing = jnp.any((slot < count) & (jnp.linalg.norm(modes - x, axis=-1) < merge_radius))
            accept = (
                eligible[s]
                & ~near_existing
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
        # Only seeds near enough rays can become modes: visit just those, in the same order.
        possible = eligible & (jnp.sum(near, axis=1) >= min_rays)
        visits = jnp.argsort(jnp.where(possible, -score, jnp.inf))
        _, membership, modes, mode_conv, count = jax.lax.fori_loop(
            0, jnp.sum(possible), lambda i, carry: visit(carry, visits[i])[0], init)
        return membership, modes, mode_conv, jnp.arange(max_modes) < count

    def over_modes(fn, *xs, active):
        """``fn`` vmapped over the mode slots; on XLA:CPU in batches of ``modes_per_batch``, which keep the
        batched LAPACK calls below the size at which it can deadlock (see _batching). A batch with no
        ``active`` slot is skipped (zeros): the slots past the frame's modes cost nothing."""
        if modes_per_batch >= max_modes:
            return jax.vmap(fn)(*xs)
        batches = -(-max_modes // modes_per_batch)
        extra = batches * modes_per_batch - max_modes

        def split(a):
            a = jnp.concatenate([a, jnp.repeat(a[:1], extra, axis=0)]) if extra else a
            return a.reshape((batches, modes_per_batch) + a.shape[1:])

        batched = jax.vmap(fn)
        empty = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype),
                                       jax.eval_shape(batched, *(split(x)[0] for x in xs)))

        def one(args):
            go, *part = args
            return jax.lax.cond(jnp.any(go), lambda: batched(*part), lambda: empty)

        out = jax.lax.map(one, (split(active),) + tuple(split(x) for x in xs))
        return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[:max_modes], out)

    def refine(members, x0, before=None):
        """Refine every slot with members; with ``before = (members, outputs)`` of an earlier refinement, a
        slot whose members did not change keeps its outputs (the maximum-likelihood location of the same
        rays, reached again from a start near it), and only the changed slots are refined."""
        changed = jnp.ones(max_modes, bool) if before is None else jnp.any(members != before[0], axis=1)
        out = over_modes(lambda m, x: _refine_and_laplace(rays, m, x, prior_scale, refine_steps), members, x0,
                         active=changed & jnp.any(members, axis=1))
        if before is None:
            return out
        pick = lambda new, old: jnp.where(changed.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
        return jax.tree_util.tree_map(pick, out, before[1])
    slots = jnp.arange(max_modes)[:, None]

    # Claims at the user's bandwidth give a first estimate of how much wider the
    # rays scatter: the robust noise ratio ĉ ≥ 1 of the members at their refined
    # locations, pooled over the frame. The claims are made again with the
    # bandwidth times max(1, ĉ/1.25), so that a bandwidth too small for the rays
    # does not cut off the tail of each concurrence's residuals (which would make
    # its noise scale, and its covariance, too small). With ĉ ≤ 1.25 nothing changes.
    membership, modes, mode_conv, valid = claim(search_proj)
    initial = (membership[None, :] == slots) & valid[:, None]
    refined = refine(initial, modes)
    dist, _ = jax.vmap(lambda x: _whitened_distances(search_proj, x))(refined[0])
    ratio = _robust_noise_ratio(dist * search_scale, initial)
    widen = jnp.maximum(1.0, ratio / _CLAIM_RATIO_MARGIN)
    wide_proj = ray_projector(eqx.tree_at(lambda r: r.bandwidth, search, search.bandwidth * widen))
    # With ĉ ≤ 1.25 the claims at the wider radius are the same claims: skip them.
    membership, modes, mode_conv, valid = jax.lax.cond(
        widen > 1.0, lambda: claim(wide_proj), lambda: (membership, modes, mode_conv, valid))

    # The mixture mode sits where a subset of rays crosses tightly, so a true
    # member with a large residual can lie outside the claim radius there. Claim
    # the still-unclaimed rays again at each mode's refined (maximum-likelihood)
    # location, nearest mode first, and refine once more. These claims cannot merge
    # groups, so their radius takes the whole ratio ĉ.
    member_mask = membership[None, :] == slots
    refined = refine(member_mask, modes, (initial, refined))
    first = refined[0]
    dist, ok = jax.vmap(lambda x: _whitened_distances(search_proj, x))(first)
    dist = jnp.where(valid[:, None] & ok & (dist < claim_bandwidths * ratio), dist, jnp.inf)
    nearest = jnp.argmin(dist, axis=0)
    late = (membership < 0) & jnp.isfinite(jnp.min(dist, axis=0))
    membership = jnp.where(late, nearest, membership)
    before, member_mask = member_mask, membership[None, :] == slots
    refined = refine(member_mask, first, (before, refined))
    second = refined[0]
    # A wide search radius can also take in a stray ray of another group. Drop
    # members that the cone model rejects at the refined location
    # (‖d‖ > prune_bandwidths · ĉ h, ĉ the frame's robust noise ratio, at least 1),
    # drop modes left with too few rays, refine again.
    dist, _ = jax.vmap(lambda x: _whitened_distances(proj, x))(second)
    stray = member_mask & (dist > _PRUNE_BANDWIDTHS * _robust_noise_ratio(dist, member_mask & valid[:, None]))
    member_mask = member_mask & ~stray
    valid = valid & (jnp.sum(member_mask, axis=1) >= min_rays) & inside(second) & ~only_a_pair(member_mask)
    before, member_mask = member_mask | stray, member_mask & valid[:, None]
    locations, covariances, dof, bounded = refine(member_mask, second, (before, refined))
    # A mode the rays do not bound (the prior holds it along some direction) is no concurrence.
    valid = valid & bounded
    member_mask = member_mask & valid[:, None]
    membership = jnp.where(jnp.any(member_mask, axis=0), jnp.argmax(member_mask, axis=0), -1).astype(jnp.int32)
    axes, semi = over_modes(lambda x: _region(rays, x), locations, active=valid)
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
    if rays.num_rays > MAX_RAYS_PER_FRAME:
        raise ValueError(
            f"{rays.num_rays} people in one frame: the concurrence search handles at most {MAX_RAYS_PER_FRAME} "
            f"(its memory grows with the square of the people, {_search_gib(rays.num_rays):.0f} GiB here)")
    dtype = rays.origins.dtype
    box = np.array([[-np.inf] * 3, [np.inf] * 3]) if options.bounds is None else np.asarray(options.bounds)
    floor = np.inf if options.floor_below_eyes is None else options.floor_below_eyes
    n = rays.num_rays
    k = n // options.min_rays if options.max_modes is None else min(options.max_modes, n // options.min_rays)
    program_options = dataclasses.replace(options, bounds=None, floor_below_eyes=None)
    static = dict(options=program_options, max_modes=k, modes_per_batch=_batch_plan(n, k)[1])
    # device_put of host arrays compiles nothing (jnp.asarray would compile a conversion per process).
    host = lambda a: jax.device_put(np.asarray(a, dtype=dtype))  # noqa: E731
    return host(options.seed_depths), (host(box), host(floor)), static


#: Rays whose eyes lie farther than this from the world origin (metres) are recentred before the search.
RECENTRE_DISTANCE = 1024.0
#: Farthest eye from the reference point (metres) float32 resolves to 1 mm (its grid is 2 mm from 2¹⁴ m on).
FLOAT32_SCENE_RADIUS = 2.0**14


def _recentred(rays: GazeRays, options: ConcurrenceOptions, reference=None):
    """``(rays, options, reference)`` with the world origin moved to ``reference`` (docs/conventions.md).

    Far from the world origin (UTM or ECEF coordinates: 5,000 km, where float32's grid is
    0.5 m) the search's float32 sums cancel. When a real eye lies farther than
    :data:`RECENTRE_DISTANCE`, ``reference`` is the mean of the real eyes rounded to whole
    metres (float64, ``(3,)``), every origin and ``options.bounds`` have it subtracted
    (exactly: a float32 coordinate minus a whole number of metres is a float32), and
    :func:`_moved_back` adds it back to the locations; covariances do not change. Otherwise
    ``reference`` is ``None`` and nothing changes. A given ``reference`` (a stream's, fixed by its
    first frame) is used as it is. Float32 rays spread over more than
    :data:`FLOAT32_SCENE_RADIUS` around the reference cannot be recentred: ``ValueError``.
    """
    if not isinstance(rays, GazeRays) or not _concrete(rays.origins, rays.mask):
        return rays, options, None
    mask = np.asarray(rays.mask, dtype=bool)
    origins = np.asarray(rays.origins, dtype=np.float64)
    if reference is None:
        if not mask.any() or np.abs(origins[mask]).max() <= RECENTRE_DISTANCE:
            return rays, options, None
        reference = np.round(origins[mask].mean(axis=0))
    local = np.where(mask[..., None], origins - reference, 0.0)
    farthest = np.abs(local).max()
    if jnp.finfo(rays.origins.dtype).bits < 64 and farthest > FLOAT32_SCENE_RADIUS:
        raise ValueError(
            f"the eyes spread {farthest / 1e3:.4g} km around their mean ({', '.join(f'{v:.0f}' for v in reference)}) m: "
            f"float32 resolves positions only to 1 mm within {FLOAT32_SCENE_RADIUS / 1e3:.4g} km (split the recording, "
            "or enable float64)")
    rays = eqx.tree_at(lambda r: r.origins, rays, jax.device_put(local.astype(rays.origins.dtype)))
    if options.bounds is not None:
        options = dataclasses.replace(options, bounds=np.asarray(options.bounds) - reference)
    return rays, options, reference


def _concrete(*arrays) -> bool:
    return not any(isinstance(a, jax.core.Tracer) for a in arrays)


def _moved_back(found: Concurrences, reference) -> Concurrences:
    """``found`` with ``reference`` (see :func:`_recentred`) added back to the valid locations, which are then
    float64 host arrays, so that the offset does not round them (float32 has a 0.5 m grid at 5,000 km)."""
    if reference is None:
        return found
    valid = np.asarray(found.valid)[..., None]
    return found._replace(locations=np.where(valid, np.asarray(found.locations, np.float64) + reference, 0.0))


#: Most rays (people) in one frame: the search holds several ``(seeds, rays)`` arrays, ``16 N × N``
#: floats each, so its memory grows as ``N²`` (3,000 people took 6.1 GB and 275 s; 10,000 would need 46 GB).
MAX_RAYS_PER_FRAME = 2048


def _search_gib(n: int) -> float:
    """Rough peak memory (GiB) of one frame's search with ``n`` rays: 46 GB measured at 10,000, as ``n²``."""
    return 46e9 / 2**30 * (n / 10_000) ** 2


#: Frames per compiled batch on XLA:CPU when the LAPACK bound allows more.
MAX_FRAMES_PER_BATCH = 64


def _lapack_cost_per_mode(n: int) -> int:
    """Largest LAPACK flop estimate that one mode adds to a batched call.

    The Levenberg–Marquardt step solves the damped ``(3n + 3) × 3`` least-squares
    system by QR, the covariance takes the QR of ``[J; I/s]`` (the same shape) and the
    region an ``eigh`` of a ``3 × 3``.
    """
    return max(lapack_qr_cost(3 * n + 3, 3), lapack_eigh_cost(3))


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
    # Host arrays sent to the device once: eager jnp.zeros/full would compile a program per shape.
    z = lambda *s, dt=dtype: np.zeros(batch_shape + (0,) + s, dt)  # noqa: E731
    partner = np.full(batch_shape + (n,), -1, np.int32)
    if n >= 2 and math.prod(batch_shape) > 0:
        flat = jax.tree_util.tree_map(lambda a: np.asarray(a).reshape((-1,) + a.shape[len(batch_shape):]), rays)
        radius = options.claim_bandwidths * options.search_scale
        partner = np.asarray(_mutual_gaze_over_frames(flat, radius)).reshape(batch_shape + (n,))
    return Concurrences(**jax.device_put(dict(
        locations=z(3), covariances=z(3, 3), field_values=z(), num_rays=z(dt=np.int32),
        membership=np.full(batch_shape + (n,), -1, np.int32), region_axes=z(3, 3),
        region_semi_axes=z(3), converged=z(dt=bool), valid=z(dt=bool), degrees_of_freedom=z(),
        mutual_gaze=partner,
    )))


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
    and field values. A scene farther than ``RECENTRE_DISTANCE`` (1 km) from the world
    origin is searched around its mean eye and its locations come back in float64
    (docs/conventions.md, "Far from the origin"): 5,000 km away it gives the same answer.
    More than ``MAX_RAYS_PER_FRAME`` (2,048) rays in a frame is a ``ValueError``.
    """
    if isinstance(rays, GazeRays) and rays.batch_shape:
        raise ValueError(
            f"find_concurrences takes one frame; rays have batch shape {rays.batch_shape}. "
            "Use find_concurrences_over_frames for a recording."
        )
    rays, options, reference = _recentred(rays, options)
    if _prepare(rays, options)[2]["max_modes"] == 0:
        check_units(rays)
        return _empty(rays, options)
    n = rays.num_rays
    # Pad to at least 24 rays, and above that to a multiple of 8, so that scenes of
    # similar size share one compilation: every scene of up to 24 people runs one
    # program (one compilation of ~5 s; a 4-person frame then takes ~50 ms, not ~10).
    # Padded rays are masked and can never be claimed, so K stays ≤ n // min_rays.
    padded = _pad_rays(rays, bucket_size(n, minimum=24, multiple=_RAY_BUCKET))
    check_units(rays)
    depths, box, static = _prepare(padded, options)
    # The kept modes are selected on the host: eager indexing of device arrays would
    # compile small programs for every new (N, K) pair.
    result = jax.device_get(_one_frame_jit(padded, depths, box, **static))
    keep = result.valid
    found = Concurrences(
        **jax.device_put({
            name: (value[:n] if name in _PER_RAY else value[keep])
            for name, value in result._asdict().items()
        })
    )
    return _moved_back(found, reference)


_RAY_BUCKET = 8


def _pad_rays(rays: GazeRays, n: int) -> GazeRays:
    extra = n - rays.num_rays
    if extra == 0:
        return rays
    # On the host (the rays are concrete here), so that no program is compiled per size.
    pad = lambda a: np.concatenate([np.asarray(a), np.zeros((extra,) + a.shape[1:], a.dtype)])  # noqa: E731
    return GazeRays(pad(rays.origins), pad(rays.directions), pad(rays.bandwidth), pad(rays.mask))


def find_concurrences_over_frames(
    rays: GazeRays,
    options: ConcurrenceOptions = ConcurrenceOptions(),
    *,
    frames_per_batch: int | None = None,
    progress: bool = False,
    warm_start: bool | None = None,
) -> Concurrences:
    """:func:`find_concurrences` for a whole recording, vmapped over batches of frames (Park et al. 2012, Sec. 3.3).

    ``rays`` has shape ``(T, N, 3)`` with ``rays.mask`` marking the people
    present in each frame (see :meth:`GazeRays.stack`); ``options`` is a
    :class:`ConcurrenceOptions`. The result is padded to
    ``K = options.max_modes`` (default ``N // min_rays``) modes per frame; ``valid``
    marks the real ones and ``count`` gives K per frame. Its arrays are numpy
    arrays on the host.

    **Warm start** (by default for recordings of at least
    ``WARM_START_MIN_FRAMES`` (1,024) frames, whose time it saves exceeds the
    compilation of its program; ``warm_start=True`` for any of at least
    ``2 · LANE_FRAMES``). Consecutive frames are nearly equal, so the
    recording is cut into lanes of ``LANE_FRAMES`` (64) consecutive frames; each
    lane's first frame is searched from the full seed set, and every later frame
    from the previous frame's modes plus ``FRESH_SEEDS_PER_RAY`` (4) fresh seeds per
    ray, at depths that rotate through ``seed_depths`` from frame to frame, with at
    most ``WARM_MAX_ITER`` mean-shift steps. A frame where two rays that support no
    mode still cross within each other's claim radius (a concurrence the warm seeds
    may have missed) is searched again from the full seed set. On the simulated
    recordings this gives the full search's count in every frame and its locations
    to within 1 cm for ≥ 99.8 % of the modes (the others: a ray about as close to two
    groups, grouped differently), at a fraction of the cost. ``warm_start=False``
    searches every frame from the full seed set, e.g. for frames that are not
    consecutive in time. Lanes start at fixed frames, so the answer does not depend
    on the batching.

    The frames (lanes) go through one compiled program of ``frames_per_batch``
    frames (lanes; the last batch is padded with empty frames), so recordings of
    any length share one compilation. On CPU the default is the largest batch, at
    most ``MAX_FRAMES_PER_BATCH``, whose batched LAPACK calls stay below the size
    at which XLA:CPU splits them over its thread pool and can deadlock (see
    ``docs/runtime.md``); a larger ``frames_per_batch`` is refused there. Batches
    run on one host thread per core. On GPU every frame goes in one batch.
    With several local devices each batch is split over them (a ``Mesh`` and a
    ``NamedSharding`` over the frame axis); under ``jax.distributed.initialize`` each
    process computes a contiguous share of the batches and every process returns the
    whole result. The answer does not depend on the number of devices or processes
    (``docs/runtime.md``, "Many devices and many machines").
    ``progress`` shows a bar of frames (lanes) done on stderr. What is not a concurrence, the
    unit checks and scenes far from the world origin: as for :func:`find_concurrences`.
    """
    if not isinstance(rays, GazeRays) or len(rays.batch_shape) != 1:
        shape = rays.batch_shape if isinstance(rays, GazeRays) else None
        raise ValueError(f"find_concurrences_over_frames needs rays of shape (T, N, 3); batch shape is {shape}")
    rays, options, reference = _recentred(rays, options)
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
    cold = functools.partial(_cold_frames, depths=depths, box=box, static=static)
    if warm_start is None:
        warm_start = total >= WARM_START_MIN_FRAMES
    if not warm_start or total < 2 * LANE_FRAMES:
        found = map_in_batches(cold, rays, batch, pad=_masked_padding, progress=progress, desc="concurrences")
    else:
        found = _warm_started(rays, cold, depths, box, static, batch, progress)
    return _moved_back(found, reference)


def _cold_frames(part: GazeRays, *, depths, box, static) -> Concurrences:
    return _over_frames_jit(part, depths, box, **static)


def _empty_lanes(part, size: int):
    """Pad a batch of lanes ``(rays, first locations, first valid, first frame)`` with empty lanes
    (every ray masked, no previous mode), whose mean-shift stops at once."""
    rays, locations, valid, frames = repeat_last(part, size)
    count = part[0].batch_shape[0]
    mask, valid = np.array(rays.mask), np.array(valid)
    mask[count:], valid[count:] = False, False
    return eqx.tree_at(lambda r: r.mask, rays, mask), locations, valid, frames


def _warm_started(rays: GazeRays, cold, depths, box, static, batch: int, progress: bool) -> Concurrences:
    """The recording in lanes of ``LANE_FRAMES`` consecutive frames: each lane's first frame from the full
    seed set, the others warm-started (:func:`_warm_lanes`), and the frames left with unexplained rays
    searched again from the full seed set. Lanes start at fixed frames, so the answer does not depend on
    how the lanes are batched or spread over devices."""
    total = rays.batch_shape[0]
    lanes = -(-total // LANE_FRAMES)
    host = _masked_padding(jax.tree_util.tree_map(np.asarray, rays), lanes * LANE_FRAMES)
    starts = np.arange(lanes) * LANE_FRAMES
    first = map_in_batches(cold, jax.tree_util.tree_map(lambda a: a[starts], host), batch, pad=_masked_padding,
                           progress=progress, desc="concurrences, first frame of each lane")
    in_lanes = jax.tree_util.tree_map(lambda a: a.reshape((lanes, LANE_FRAMES) + a.shape[1:])[:, 1:], host)
    warm, unexplained = map_in_batches(
        lambda part: _warm_lanes_jit(*part, depths, box, **static),
        (in_lanes, first.locations, first.valid, starts.astype(np.int32)), batch, pad=_empty_lanes,
        progress=progress, desc=f"concurrences, {LANE_FRAMES}-frame lanes", unit="lane",
    )
    joined = jax.tree_util.tree_map(
        lambda a, b: np.concatenate([a[:, None], b], axis=1).reshape((lanes * LANE_FRAMES,) + a.shape[1:])[:total],
        first, warm,
    )
    again = np.flatnonzero(np.concatenate([np.zeros((lanes, 1), bool), unexplained], axis=1).reshape(-1)[:total])
    if again.size:
        searched = map_in_batches(cold, jax.tree_util.tree_map(lambda a: np.asarray(a)[again], rays), batch,
                                  pad=_masked_padding)
        for full, part in zip(joined, searched):
            full[again] = part
    return joined


# ---------------------------------------------------------------------------
# Warm starts: a frame's seeds from the previous frame's modes


#: Fresh seeds per ray in a warm-started frame; their depths rotate through ``seed_depths``.
FRESH_SEEDS_PER_RAY = 4
#: Mean-shift iterations of a warm-started frame's seeds.
WARM_MAX_ITER = 10
#: Shortest recording warm-started by default: shorter ones cost less than compiling the warm program.
WARM_START_MIN_FRAMES = 1024
#: Frames per lane of the warm-started batch path; every lane starts cold.
LANE_FRAMES = 64


def _fresh_depths(seed_depths: Float[Array, " D"], frame: Int[Array, ""]) -> Float[Array, " F"]:
    """``FRESH_SEEDS_PER_RAY`` of the seed depths, spread over their range and shifted by one every frame,
    so that consecutive frames together seed every depth."""
    count = seed_depths.shape[0]
    fresh = min(FRESH_SEEDS_PER_RAY, count)
    stride = count // fresh
    return seed_depths[jnp.arange(fresh) * stride + frame % stride]


def _unexplained(rays: GazeRays, found: Concurrences, bounds: Float[Array, "2 3"], claim_radius: float) -> Array:
    """Whether two rays that support no mode cross within each other's claim radius (Park et al. 2012, Sec. 3.3).

    Such a pair could make a concurrence that seeds from the previous frame's modes
    missed, so the frame is searched again from the full seed set. The crossing is
    the midpoint ``m`` of the two lines' closest points; it must lie in front of
    both eyes, inside ``bounds`` and within ``claim_radius`` whitened distances
    (search bandwidths) of both rays. Pairs in mutual gaze do not count.
    """
    n = rays.num_rays
    free = rays.mask & (found.membership < 0)
    p, v, h = rays.origins, rays.directions, rays.bandwidth
    w0 = p[:, None, :] - p[None, :, :]  # p_i − p_j
    b = jnp.einsum("ik,jk->ij", v, v)
    d_i, e_j = jnp.einsum("ijk,ik->ij", w0, v), jnp.einsum("ijk,jk->ij", w0, v)
    denom = 1.0 - b * b
    parallel = denom < 1e-6
    safe = jnp.where(parallel, 1.0, denom)
    s = (b * e_j - d_i) / safe  # depth along ray i of its point closest to ray j
    t = (e_j - b * d_i) / safe  # … and along ray j
    on_i = p[:, None, :] + s[..., None] * v[:, None, :]  # the two closest points
    on_j = p[None, :, :] + t[..., None] * v[None, :, :]
    m, gap = 0.5 * (on_i + on_j), jnp.linalg.norm(on_i - on_j, axis=-1)
    # The perspective distance of m from each ray is gap/2 at depth s (or t).
    close = (0.5 * gap < claim_radius * h[:, None] * s) & (0.5 * gap < claim_radius * h[None, :] * t)
    inside = jnp.all((m >= bounds[0]) & (m <= bounds[1]), axis=-1)
    partners = found.mutual_gaze[:, None] == jnp.arange(n)[None, :]
    pair = free[:, None] & free[None, :] & ~jnp.eye(n, dtype=bool) & ~parallel & ~partners
    return jnp.any(pair & (s > 0) & (t > 0) & close & inside)


def _region_box(rays: GazeRays, region) -> Float[Array, "2 3"]:
    bounds, floor_below_eyes = region
    lowest = jnp.min(jnp.where(rays.mask, rays.origins[:, 2], jnp.inf))
    return bounds.at[0, 2].max(jnp.where(jnp.isfinite(lowest), lowest - floor_below_eyes, -jnp.inf))


def _warm_frame(
    rays: GazeRays,
    previous: tuple[Float[Array, "K 3"], Bool[Array, " K"]],
    frame: Int[Array, ""],
    seed_depths: Float[Array, " D"],
    region,
    *,
    options: ConcurrenceOptions,
    max_modes: int,
    modes_per_batch: int,
) -> tuple[Concurrences, Array]:
    """One frame seeded from the previous frame's modes plus ``FRESH_SEEDS_PER_RAY`` seeds per ray
    (Park et al. 2012, Sec. 3.3), and whether rays are left unexplained (:func:`_unexplained`)."""
    locations, valid = previous
    fresh, fresh_ok = _seeds_along_rays(rays, _fresh_depths(seed_depths, frame))
    seeds = jnp.concatenate([locations, fresh])
    seed_ok = jnp.concatenate([valid, fresh_ok])
    # The previous modes converge in a few steps; fresh seeds still climbing after the first stage
    # stay candidates, and a new concurrence they miss leaves unexplained rays behind.
    warm = dataclasses.replace(options, max_iter=min(options.max_iter, WARM_MAX_ITER))
    found = _concurrences_from_seeds(rays, seeds, seed_ok, region, options=warm, max_modes=max_modes,
                                     modes_per_batch=modes_per_batch)
    radius = options.claim_bandwidths * options.search_scale
    return found, _unexplained(rays, found, _region_box(rays, region), radius)


def _warm_lanes(rays, first_locations, first_valid, first_frame, seed_depths, region, **static):
    """Frames ``1 … L−1`` of ``B`` lanes, each warm-started from the one before: a ``lax.scan`` over
    time of the frames vmapped over lanes. Returns ``(Concurrences (B, L−1, …), unexplained (B, L−1))``."""
    time_major = jax.tree_util.tree_map(lambda a: jnp.swapaxes(a, 0, 1), rays)
    one = functools.partial(_warm_frame, seed_depths=seed_depths, region=region, **static)

    def step(carry, frame_rays):
        locations, valid, frame = carry
        found, unexplained = jax.vmap(lambda r, loc, ok, t: one(r, (loc, ok), t))(frame_rays, locations, valid, frame)
        return (found.locations, found.valid, frame + 1), (found, unexplained)

    _, (found, unexplained) = jax.lax.scan(step, (first_locations, first_valid, first_frame + 1), time_major)
    return jax.tree_util.tree_map(lambda a: jnp.swapaxes(a, 0, 1), (found, unexplained))


_warm_lanes_jit = jax.jit(_warm_lanes, static_argnames=_STATIC)


# ---------------------------------------------------------------------------
# Tracking over frames


def track_concurrences(concurrences: Concurrences, *, max_distance: float = 0.5, max_gap: int = 2) -> Tracks:
    """Link the modes of consecutive frames into trajectories with birth and death (Park et al. 2012, Sec. 3.3).

    A ``lax.scan`` over frames. In each frame the modes, strongest first, take
    the nearest live track within ``max_distance`` metres that is not yet taken;
    a mode with none starts a new track (birth). A track not seen for more than
    ``max_gap`` frames ends (death) and is never revived. A recording with no mode
    slot (``K = 0``: one person per frame, or fewer than ``min_rays``) has no track.
    """
    if concurrences.locations.ndim != 3:
        raise ValueError("track_concurrences needs the padded (T, K) result of find_concurrences_over_frames")
    if not max_distance > 0 or max_gap < 0:
        raise ValueError("max_distance must be positive and max_gap non-negative")
    locations, valid, values = (np.asarray(a) for a in (concurrences.locations, concurrences.valid,
                                                        concurrences.field_values))
    total = locations.shape[0]
    carry = _tracker_init(locations.shape[1], locations.dtype)
    ids = []
    for start in range(0, total, _TRACK_CHUNK):
        # Chunks of one length (the last padded with empty frames): one compilation for any recording.
        part = [np.concatenate([a[start:start + _TRACK_CHUNK],
                                np.zeros((max(0, start + _TRACK_CHUNK - total),) + a.shape[1:], a.dtype)])
                for a in (locations, valid, values)]
        carry, chunk = _track_chunk(carry, *part, max_distance=float(max_distance), max_gap=int(max_gap))
        ids.append(np.asarray(chunk))
    ids = np.concatenate(ids)[:total] if ids else np.zeros((0, locations.shape[1]), np.int32)
    return Tracks(track_ids=jax.device_put(ids), num_tracks=carry.next_id)


_TRACK_CHUNK = 512  # frames per compiled tracking program


@functools.partial(jax.jit, static_argnames=("max_distance", "max_gap"))
def _track_chunk(carry, locations, valid, values, *, max_distance, max_gap):
    step = functools.partial(_track_frame, max_distance=max_distance, max_gap=max_gap)
    return jax.lax.scan(step, carry, (locations, valid, values))


class TrackerState(NamedTuple):
    """What :func:`track_concurrences` carries from frame to frame: ``2K`` slots of live tracks."""

    track_id: Int[Array, " S"]  # −1: empty slot
    location: Float[Array, "S 3"]  # last location of the slot's track
    unseen: Int[Array, " S"]  # frames since the track was last seen
    next_id: Int[Array, ""]


def _tracker_init(max_modes: int, dtype) -> TrackerState:
    slots = 2 * max_modes  # live tracks at once: this frame's and those waiting out a gap
    return TrackerState(jnp.full(slots, -1, jnp.int32), jnp.zeros((slots, 3), dtype), jnp.zeros(slots, jnp.int32),
                        jnp.int32(0))


def _track_frame(carry: TrackerState, inputs, *, max_distance: float, max_gap: int):
    """One frame of :func:`track_concurrences`: ``(new state, track id of each of the frame's K modes or −1)``."""
    track_id, track_loc, unseen, next_id = carry
    locations, valid, values = inputs
    k = locations.shape[0]
    if k == 0:  # no mode can be found (fewer rays than min_rays, e.g. one person): nothing to link
        return carry, jnp.zeros(0, jnp.int32)
    big = jnp.asarray(jnp.inf, locations.dtype)
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
        0, k, assign, (ids_out, jnp.zeros(track_id.shape[0], bool), track_id, track_loc, next_id)
    )
    unseen = jnp.where(taken, 0, unseen + 1)
    track_id = jnp.where(unseen > max_gap, -1, track_id)
    return TrackerState(track_id, track_loc, unseen, next_id), ids_out
