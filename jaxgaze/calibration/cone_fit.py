"""Gaze-ray calibration of a head-mounted camera (Park et al. 2012, Sec. 3.2).

Two people A and B look at each other's camera while they move. B's camera
centre is then A's point of regard; in A's **camera frame** (+x forward along
the optical axis, +y left, +z up, metres; see ``docs/conventions.md``) it is
``y = R_camera_from_world (C_B − C_A)`` (:func:`points_in_camera_frame`).
Because the camera is fixed to the head, the points ``{y_i}`` fill a cone whose
axis is the primary gaze direction ``v`` and whose apex is the centre of the
eyes ``p``. :func:`calibrate_cone` recovers ``(p, v, h)`` in the camera frame:

1. **Line.** A 2-point RANSAC line fit (all hypotheses scored at once with
   ``vmap``), then a least-squares refit to the inliers (principal axis of the
   inlier covariance), repeated once with the inliers of the refitted line.
   A point is an inlier when its distance to the line divided by its distance
   to the camera centre is below ``inlier_threshold``: the cone widens with
   depth, so a threshold in metres would be too tight far away and too loose
   near the eye. The ratio is (for a small angle) the angle in radians at the
   camera centre, which is a few cm from the eye.
2. **Sign of v.** ``p_a`` is the projection of the camera centre (the origin)
   onto the line. ``v`` is oriented so that more inliers have
   ``vᵀ(y_i − p_a) > 0`` than ``< 0`` (ties broken by the sum), i.e. the points
   lie ahead of the camera along ``v``.
3. ``p0 = p_a + min_i vᵀ(y_i − p_a) v`` over the inliers (eq. 1).
4. **Apex** ``p = p0 − α v`` with ``α > 0`` from the convex programme (eq. 2)
   ``minimise ξ + λα  s.t.  a_i/(b_i + α) ≤ ξ``, ``a_i = ‖(I − vvᵀ)(y_i − p0)‖``,
   ``b_i = vᵀ(y_i − p0) ≥ 0``. For a fixed α the best ξ is ``max_i a_i/(b_i+α)``,
   so this is the 1-D convex problem ``g(α) = max_i a_i/(b_i+α) + λα``, solved by
   bisection on the sign of a subgradient (:func:`solve_cone_apex`).
5. **Bandwidth** from the perspective distances ``d(l, y_i)`` of the inliers
   (eq. 4, :func:`jaxgaze.geometry.perspective_distance`); see
   :func:`calibrate_cone` for the estimator.

**λ** (``regularization``, units 1/metre because ξ is a tangent and α a length)
trades the cone's half-angle against the distance of the apex behind the
nearest point. λ → 0 pushes the apex to infinity (a cylinder, ξ → 0); a large λ
pulls it onto ``p0``. The paper leaves λ free ("controls how far the apex is
from p0"). At the optimum λ equals ``a_k/(b_k+α)² = ξ/t_k``, the cone's
half-angle tangent over the depth of the active point ``k`` from the apex; with
ξ ≈ 3h ≈ 0.1 and the active point about 2 m away that is ≈ 0.05 per metre, the
default (how λ moves the apex in simulation: ``benchmarks/RESULTS.md``). The line, and so
the eye centre *perpendicular* to the gaze axis, does not depend on λ; the
position along the axis does.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from jaxgaze.geometry import perspective_distance, unit
from jaxgaze.rays import GazeRays
from jaxgaze.results import RESULTS, code, succeeded, throw_if_failed

__all__ = [
    "ConeCalibration",
    "calibrate_cone",
    "solve_cone_apex",
    "points_in_camera_frame",
    "DEFAULT_REGULARIZATION",
    "DEFAULT_INLIER_THRESHOLD",
    "DEFAULT_RANSAC_ITERATIONS",
    "MAX_APEX_DISTANCE",
]

#: λ of eq. 2, in 1/metre.
DEFAULT_REGULARIZATION = 0.05
#: RANSAC inlier threshold: point-to-line distance / distance to the camera centre (≈ radians).
DEFAULT_INLIER_THRESHOLD = 0.15
#: Number of 2-point RANSAC hypotheses.
DEFAULT_RANSAC_ITERATIONS = 256
#: The farthest from the camera (metres) that :func:`calibrate_cone` accepts the apex of eq. 2; beyond it the
#: result is ``implausible``. The apex is loose along the primary ray (sliding along it leaves the ray's line
#: unchanged), so this bound is looser than the posterior's ``MAX_EYE_OFFSET``; it catches millimetres and
#: pose files that do not belong together.
MAX_APEX_DISTANCE = 1.0

_BISECTION_STEPS = 80
_MIN_POINTS = 3


class ConeCalibration(NamedTuple):
    """Calibrated cone gaze model of one wearer, in the wearer's **camera** frame.

    Attributes:
        eye_center: ``(3,)`` apex ``p`` of the cone, the centre of the eyes (m).
        direction: ``(3,)`` unit primary gaze direction ``v``.
        bandwidth: ``h``, per-axis std of the perspective distance (radians, a tangent).
        alpha: ``α``, distance of the apex behind ``p0`` along ``−v`` (m).
        xi: ``ξ = max_i a_i/(b_i+α)``, tangent of the cone's half-angle.
        inliers: ``(M,)`` RANSAC inlier mask.
        result: a :class:`jaxgaze.results.RESULTS` item: ``successful``, ``too_few_inliers``,
            ``degenerate``, ``collinear_through_camera``, ``behind_camera``, ``implausible``
            (the eye centre more than :data:`MAX_APEX_DISTANCE` from the camera) or ``nonfinite``
            (NaN or inf in the points; only reported under jit/vmap, concrete input raises).
            :func:`jaxgaze.succeeded` reads it (a bool array, per wearer, when batched).

    On failure (``result != RESULTS.successful``) the geometric fields hold NaN-free placeholders:
    eye centre 0, direction +x, bandwidth 1, α = ξ = 0 (the inlier mask is kept); an
    ``implausible`` fit keeps its estimate, to be inspected.
    Leading batch axes appear when ``calibrate_cone`` is vmapped.
    """

    eye_center: Float[Array, "3"]
    direction: Float[Array, "3"]
    bandwidth: Float[Array, ""]
    alpha: Float[Array, ""]
    xi: Float[Array, ""]
    inliers: Bool[Array, " M"]
    result: RESULTS

    @property
    def message(self) -> str:
        """Human-readable outcome (``RESULTS[result]``; concrete calibrations only)."""
        return RESULTS[self.result]

    @property
    def eye_distance(self) -> Array:
        """The eye centre's distance from the camera centre (metres; per wearer when batched)."""
        return jnp.linalg.norm(self.eye_center, axis=-1)

    def to_gaze_rays(self, R_world_from_camera, camera_centers) -> GazeRays:
        """Primary gaze rays in the world frame, one per camera pose (item 4).

        ``p_world = R @ eye_center + C`` and ``v_world = R @ direction`` with
        ``R = R_world_from_camera`` (maps camera-frame vectors to the world, its
        columns are the camera axes in world coordinates) and ``C`` the camera
        centre in the world (m).

        Args:
            R_world_from_camera: ``(..., 3, 3)``, e.g. ``(T, 3, 3)`` for T frames.
            camera_centers: ``(..., 3)`` with the same leading axes.

        Returns:
            :class:`GazeRays` with batch shape ``(...)`` (e.g. ``(T,)``) and
            ``N = 1`` ray (this wearer) per frame, bandwidth ``h``. Concatenate
            along axis −2 to combine wearers.

        Raises:
            ValueError: on mismatched shapes, or if the calibration failed
                (concrete ``result != RESULTS.successful``).
        """
        R = jnp.asarray(R_world_from_camera)
        C = jnp.asarray(camera_centers)
        if R.ndim < 2 or R.shape[-2:] != (3, 3):
            raise ValueError(f"to_gaze_rays: R_world_from_camera must have shape (..., 3, 3), got {R.shape}")
        if C.shape != R.shape[:-1]:
            raise ValueError(
                f"to_gaze_rays: camera_centers must have shape {R.shape[:-2] + (3,)} to match "
                f"R_world_from_camera {R.shape}, got {C.shape}"
            )
        if jnp.ndim(code(self.result)) != 0:
            raise ValueError("to_gaze_rays: needs a single calibration, not a batch; index it first")
        if _is_concrete(code(self.result)) and not succeeded(self):
            raise ValueError(f"to_gaze_rays: the calibration failed: {self.message}")
        origins = jnp.einsum("...ij,j->...i", R, self.eye_center) + C
        directions = jnp.einsum("...ij,j->...i", R, self.direction)
        return GazeRays(origins[..., None, :], directions[..., None, :], self.bandwidth)


def points_in_camera_frame(R_world_from_camera, camera_centers, points_world) -> Float[Array, "... 3"]:
    """World points of regard → the wearer's camera frame: ``y = Rᵀ (y_W − C)`` (Park et al. 2012, Sec. 3.2).

    This is the paper's ``y = R y_W − R C`` with its ``R`` (camera from world)
    equal to ``R_world_from_cameraᵀ``. Shapes ``(..., 3, 3)``, ``(..., 3)``, ``(..., 3)``.
    """
    R = jnp.asarray(R_world_from_camera)
    diff = jnp.asarray(points_world) - jnp.asarray(camera_centers)
    return jnp.einsum("...ji,...j->...i", R, diff)


# ---------------------------------------------------------------------------
# The 1-D convex apex problem (eq. 2)


def _apex_objective(alpha, a, b, valid, lam):
    ratios = jnp.where(valid, a / (b + alpha), -jnp.inf)
    return jnp.max(ratios) + lam * alpha


def solve_cone_apex(
    a: Float[Array, " M"],
    b: Float[Array, " M"],
    regularization: float = DEFAULT_REGULARIZATION,
    mask: Bool[Array, " M"] | None = None,
) -> tuple[Array, Array]:
    """Solve ``min_{α>0} g(α) = max_i a_i/(b_i+α) + λα`` (Park et al. 2012, eq. 2); returns ``(α, ξ)``.

    ``a_i ≥ 0`` (m) is the distance of point ``i`` from the axis and ``b_i ≥ 0``
    (m) its depth beyond ``p0``; ``λ = regularization`` (1/m) must be positive.
    ``g`` is convex (a max of convex functions plus a linear one), so its
    minimiser is where a subgradient ``λ − a_k/(b_k+α)²`` (``k`` an active
    index) changes sign. That is found by bisection on ``log α`` inside
    ``[α_lo, α_hi]``, with ``α_hi = √(max a/λ)`` (every subgradient is ≥ 0 there)
    and ``α_lo`` a tiny fraction of the data scale; if the subgradient is
    already ≥ 0 at ``α_lo`` the infimum is at the boundary α → 0⁺ and α_lo is
    returned. ``ξ = max_i a_i/(b_i+α)``. ``mask`` excludes points. Vmappable.

    Precision: float32 and float64 inputs agree to within 10 µm on α and 1e-5 relative
    on ξ (``tests/test_precision.py``).
    """
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    dtype = jnp.result_type(a.dtype, b.dtype, jnp.float32)
    a, b = a.astype(dtype), b.astype(dtype)
    if a.ndim != 1 or b.shape != a.shape:
        raise ValueError(f"solve_cone_apex: a and b must both have shape (M,), got {a.shape} and {b.shape}")
    valid = jnp.ones(a.shape, bool) if mask is None else jnp.asarray(mask, bool)
    return _solve_apex_jit(a, b, jnp.asarray(regularization, dtype), valid)


@jax.jit
def _solve_apex_jit(a, b, lam, valid):
    dtype = a.dtype
    a = jnp.where(valid, jnp.maximum(a, 0.0), 0.0)
    b = jnp.where(valid, jnp.maximum(b, 0.0), 1.0)
    tiny = jnp.finfo(dtype).tiny
    scale = jnp.maximum(jnp.max(jnp.where(valid, a + b, 0.0)), tiny)
    a_max = jnp.max(a)
    hi = jnp.maximum(jnp.sqrt(a_max / lam), 1e-6 * scale)
    lo = jnp.minimum(1e-9 * scale, 0.5 * hi)

    def subgradient(alpha):
        ratios = jnp.where(valid, a / (b + alpha), -jnp.inf)
        k = jnp.argmax(ratios)
        return lam - a[k] / (b[k] + alpha) ** 2

    def step(_, bracket):
        lo, hi = bracket
        mid = jnp.sqrt(lo * hi)  # bisection in log α: the bracket spans many decades
        positive = subgradient(mid) >= 0
        return jnp.where(positive, lo, mid), jnp.where(positive, mid, hi)

    at_boundary = subgradient(lo) >= 0
    lo_f, hi_f = jax.lax.fori_loop(0, _BISECTION_STEPS, step, (lo, hi))
    alpha = jnp.where(at_boundary, lo, jnp.sqrt(lo_f * hi_f))
    # The minimiser is a kink or a smooth stationary point inside [lo_f, hi_f];
    # take the better end of the final bracket to guard against rounding.
    g = lambda x: _apex_objective(x, a, b, valid, lam)  # noqa: E731
    for candidate in (lo_f, hi_f):
        alpha = jnp.where(~at_boundary & (g(candidate) < g(alpha)), candidate, alpha)
    xi = jnp.max(jnp.where(valid, a / (b + alpha), -jnp.inf))
    return alpha, xi


# ---------------------------------------------------------------------------
# RANSAC line fit


def _line_distances(origin, direction, points):
    """Distance of each point to the line ``(origin, direction)``, ``direction`` unit."""
    diff = points - origin
    along = diff @ direction
    perp = diff - along[:, None] * direction
    return jnp.sqrt(jnp.sum(perp * perp, axis=-1))


def _inlier_mask(origin, direction, points, ranges, threshold):
    return _line_distances(origin, direction, points) < threshold * ranges


def _least_squares_line(points, mask, weights):
    """Weighted centroid and principal axis (top eigenvector of the weighted covariance)."""
    w = mask.astype(points.dtype) * weights
    n = jnp.maximum(jnp.sum(w), jnp.finfo(points.dtype).tiny)
    centroid = jnp.sum(w[:, None] * points, axis=0) / n
    centred = points - centroid
    cov = (centred * w[:, None]).T @ centred / n
    return centroid, _principal_axis(cov)


def _principal_axis(cov):
    """Unit eigenvector of the largest eigenvalue of a symmetric 3×3 matrix."""
    _, vecs = jnp.linalg.eigh(cov)
    return vecs[:, -1]


def _ransac_line(points, key, iterations, threshold):
    M = points.shape[0]
    ranges = jnp.sqrt(jnp.sum(points * points, axis=-1))
    ranges = jnp.maximum(ranges, jnp.finfo(points.dtype).tiny)
    # The cone's cross-section grows with depth, so weight the least-squares refit
    # by 1/range²: the residuals over the range are then about equally spread.
    weights = 1.0 / (ranges * ranges)
    pairs = jax.random.randint(key, (2, iterations), 0, jnp.array([[M], [M - 1]]))
    i, j = pairs[0], pairs[1]
    j = j + (j >= i)  # two distinct indices per hypothesis

    def score(ii, jj):
        a, b = points[ii], points[jj]
        span = b - a
        ok = jnp.sum(span * span) > (1e-12 * (jnp.sum(a * a) + jnp.sum(b * b)))
        count = jnp.sum(_inlier_mask(a, unit(span), points, ranges, threshold))
        return jnp.where(ok, count, -1)

    counts = jax.vmap(score)(i, j)
    best = jnp.argmax(counts)  # first maximum: deterministic for a fixed key
    a, b = points[i[best]], points[j[best]]
    inliers = _inlier_mask(a, unit(b - a), points, ranges, threshold)
    for _ in range(2):  # least-squares refit, then re-select inliers with the refitted line
        centroid, direction = _least_squares_line(points, inliers, weights)
        refit = _inlier_mask(centroid, direction, points, ranges, threshold)
        inliers = jnp.where(jnp.sum(refit) >= jnp.sum(inliers), refit, inliers)
    centroid, direction = _least_squares_line(points, inliers, weights)
    return centroid, direction, inliers


# ---------------------------------------------------------------------------
# Public entry point


def _is_concrete(*arrays) -> bool:
    return not any(isinstance(x, jax.core.Tracer) for x in arrays)


def _calibrate(points, key, iterations, threshold, lam, min_inlier_fraction, degenerate_tol):
    dtype = points.dtype
    M = points.shape[0]
    finite = jnp.all(jnp.isfinite(points))
    pts = jnp.where(finite, points, 1.0)  # keep NaN out of every intermediate

    centroid, v, inliers = _ransac_line(pts, key, iterations, threshold)
    w = inliers
    n_in = jnp.sum(w)

    # Sign of v and p_a, the projection of the camera centre onto the line.
    p_a = centroid - jnp.dot(v, centroid) * v
    s = (pts - p_a) @ v
    ahead = jnp.sum(w & (s > 0))
    behind = jnp.sum(w & (s < 0))
    flip = (ahead < behind) | ((ahead == behind) & (jnp.sum(jnp.where(w, s, 0.0)) < 0))
    v = jnp.where(flip, -v, v)
    s = jnp.where(flip, -s, s)

    # eq. 1
    s_min = jnp.min(jnp.where(w, s, jnp.inf))
    s_max = jnp.max(jnp.where(w, s, -jnp.inf))
    s_min = jnp.where(n_in > 0, s_min, 0.0)
    s_max = jnp.where(n_in > 0, s_max, 0.0)
    p0 = p_a + s_min * v
    rel = pts - p0
    b = jnp.maximum(rel @ v, 0.0)
    perp = rel - (rel @ v)[:, None] * v
    a = jnp.sqrt(jnp.sum(perp * perp, axis=-1))

    # Degeneracy, relative to the extent of the inliers along the line.
    spread = s_max - s_min
    scale = jnp.maximum(jnp.max(jnp.where(w, jnp.sqrt(jnp.sum(pts * pts, -1)), 0.0)), jnp.finfo(dtype).tiny)
    coincident = spread <= degenerate_tol * scale
    through_origin = jnp.sqrt(jnp.sum(p_a * p_a)) <= degenerate_tol * jnp.maximum(spread, jnp.finfo(dtype).tiny)
    no_spread = jnp.max(jnp.where(w, a, 0.0)) <= degenerate_tol * jnp.maximum(spread, jnp.finfo(dtype).tiny)
    degenerate = coincident | no_spread

    # eq. 2
    alpha, xi = _solve_apex_jit(a, b, jnp.asarray(lam, dtype), w)
    p = p0 - alpha * v

    # Bandwidth from the perspective distances (eq. 4) of the inliers.
    d, in_front = jax.vmap(perspective_distance, in_axes=(None, None, 0))(p, v, pts)
    use = w & in_front
    n_use = jnp.maximum(jnp.sum(use), 1)
    h = jnp.sqrt(jnp.sum(jnp.where(use[:, None], d * d, 0.0)) / (2.0 * n_use))

    min_inliers = max(_MIN_POINTS, math.ceil(min_inlier_fraction * M))
    behind_camera = jnp.sum(pts[:, 0] <= 0) * 2 > M
    # The first failure that applies, in this order (RESULTS.where needs a scalar predicate:
    # one wearer here, vmapped outside).
    result = RESULTS.successful
    for failed, item in (
        (degenerate | ~(h > 0), RESULTS.degenerate),
        (through_origin, RESULTS.collinear_through_camera),
        (n_in < min_inliers, RESULTS.too_few_inliers),
        (behind_camera, RESULTS.behind_camera),
        (~finite, RESULTS.nonfinite),
    ):
        result = RESULTS.where(failed, item, result)
    ok = result == RESULTS.successful
    placeholder_v = jnp.zeros(3, dtype).at[0].set(1.0)
    return ConeCalibration(
        eye_center=jnp.where(ok, p, 0.0),
        direction=jnp.where(ok, v, placeholder_v),
        bandwidth=jnp.where(ok, h, 1.0).astype(dtype),
        alpha=jnp.where(ok, alpha, 0.0).astype(dtype),
        xi=jnp.where(ok, xi, 0.0).astype(dtype),
        inliers=inliers,
        result=result,
    )


def calibrate_cone(
    points: Float[Array, "M 3"],
    *,
    key: PRNGKeyArray,
    ransac_iterations: int = DEFAULT_RANSAC_ITERATIONS,
    inlier_threshold: float = DEFAULT_INLIER_THRESHOLD,
    regularization: float = DEFAULT_REGULARIZATION,
    min_inlier_fraction: float = 0.25,
    degenerate_tol: float = 1e-4,
    throw: bool = False,
) -> ConeCalibration:
    """Calibrate the cone gaze model of one wearer from points of regard (Park et al. 2012, Sec. 3.2).

    Args:
        points: ``(M, 3)`` points of regard ``y_i`` in the wearer's camera frame
            (+x forward, +y left, +z up; metres), ``M ≥ 3``.
        key: ``jax.random`` key that seeds the RANSAC pairs; a fixed key gives a
            fixed result.
        ransac_iterations: number of 2-point hypotheses (scored in parallel).
        inlier_threshold: a point is an inlier when its distance to the line over
            its distance to the camera centre is below this (≈ radians).
            Keep it a few times ``h``.
        regularization: λ of eq. 2 (1/metre); see the module docstring.
        min_inlier_fraction: fewer than ``max(3, ceil(fraction · M))`` inliers
            is a ``too_few_inliers`` failure.
        degenerate_tol: relative tolerance of the degeneracy tests (the line's
            distance to the origin, and the inliers' spread off the line, each
            relative to the inliers' extent along the line).
        throw: if ``False`` (the default, as in every jaxgaze fit) a failure is reported in
            ``result`` with NaN-free placeholder values; if ``True`` it raises
            :class:`jaxgaze.results.FitError`, whose ``fit`` is the calibration ``throw=False``
            returns (under ``jit``/``vmap`` an ``equinox`` runtime error).

    Returns:
        :class:`ConeCalibration`. The bandwidth is the per-axis standard
        deviation of the eye-in-head offset, the convention of
        ``docs/conventions.md`` and of :func:`jaxgaze.cone.sample_points_of_regard`:
        ``h = √(mean_i ‖d(l, y_i)‖² / 2)`` over the inliers, the maximum-likelihood
        estimate for ``d ~ N(0, h² I₂)``. The paper writes ``h = std_i ‖d‖``; for
        this model ``std ‖d‖ = √(2 − π/2) h ≈ 0.655 h`` (‖d‖ is Rayleigh), so the
        literal formula would understate the cone used everywhere else.

    Raises:
        ValueError: (always, for concrete input) ``points`` not ``(M, 3)``,
            ``M < 3``, or NaN/inf.
        FitError: (if ``throw``) the points are mostly behind the camera, too
            few are inliers, the eye centre is implausibly far from the camera,
            they are collinear through the camera centre, or
            they are degenerate (coincident or exactly collinear).

    Works under ``jit`` and ``vmap`` (value checks then become result codes).

    Precision: float32 and float64 points give the same inliers (barring a point within
    rounding of the threshold) and agree to within 10 µm on the eye centre and α, 1e-6 rad
    on the direction and 1e-5 relative on ``h`` and ξ (``tests/test_precision.py``; points
    of regard 1–4 m away).
    """
    points = jnp.asarray(points)
    if not jnp.issubdtype(points.dtype, jnp.floating):
        points = points.astype(jnp.result_type(float))
    points = points.astype(jnp.result_type(points.dtype, jnp.float32))
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"calibrate_cone: points must have shape (M, 3) in the camera frame, got {points.shape}")
    M = points.shape[0]
    if M < _MIN_POINTS:
        raise ValueError(f"calibrate_cone: need at least {_MIN_POINTS} points of regard to fit a cone, got {M}")
    if int(ransac_iterations) < 1:
        raise ValueError(f"calibrate_cone: ransac_iterations must be ≥ 1, got {ransac_iterations}")
    for name, value in (("inlier_threshold", inlier_threshold), ("regularization", regularization)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"calibrate_cone: {name} must be a positive finite number, got {value}")
    if not (math.isfinite(degenerate_tol) and degenerate_tol >= 0):
        raise ValueError(f"calibrate_cone: degenerate_tol must be a non-negative number, got {degenerate_tol}")
    if not 0 <= min_inlier_fraction <= 1:
        raise ValueError(f"calibrate_cone: min_inlier_fraction must lie in [0, 1], got {min_inlier_fraction}")
    concrete = _is_concrete(points)
    if concrete:
        bad = ~np.all(np.isfinite(np.asarray(points)), axis=-1)
        if bad.any():
            raise ValueError(
                f"calibrate_cone: point {int(np.flatnonzero(bad)[0])} is not finite (NaN or inf); "
                "drop frames without a reconstructed camera before calibrating"
            )

    out = _calibrate_jit(
        points, key, int(ransac_iterations), float(inlier_threshold), float(regularization),
        float(min_inlier_fraction), float(degenerate_tol),
    )
    far = (out.result == RESULTS.successful) & (out.eye_distance > MAX_APEX_DISTANCE)
    out = out._replace(result=RESULTS.where(far, RESULTS.implausible, out.result))
    if throw:
        out = out._replace(eye_center=throw_if_failed(out.eye_center, out.result, "calibrate_cone", fit=out))
    return out


_calibrate_jit = jax.jit(_calibrate, static_argnums=(2, 3, 4, 5, 6))
