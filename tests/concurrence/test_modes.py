"""Mean-shift, gaze concurrences and tracking against known truth."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

import jaxgaze as jg
from jaxgaze.concurrence.field import meanshift_step, ray_projector
from jaxgaze.cone import sample_gaze_directions
from jaxgaze.rays import UnitWarning, check_units

TARGETS = np.array([[2.0, 3.0, 1.2], [-2.5, -1.0, 1.0]])


def noisy_rays(key, origins, targets, noise, bandwidth=None):
    """Rays from ``origins`` toward ``targets`` with cone-model direction noise ``noise``."""
    exact = jg.GazeRays(origins, targets - origins, noise)
    directions = sample_gaze_directions(key, exact)
    return jg.GazeRays(origins, directions, noise if bandwidth is None else bandwidth)


def two_group_scene(key, noise=0.02, per_group=4):
    """Two groups looking at TARGETS plus one bystander whose ray crosses nobody's."""
    angles = np.linspace(0, 2 * np.pi, per_group, endpoint=False) + 0.3
    origins, targets = [], []
    for g, target in enumerate(TARGETS):
        radius = 2.0 + g
        for a in angles:
            origins.append(target + [radius * np.cos(a), radius * np.sin(a), 0.6])
            targets.append(target)
    origins.append([8.0, 8.0, 1.7])
    targets.append([12.0, 8.0, 1.7])
    return noisy_rays(key, np.array(origins), np.array(targets), noise)


@pytest.fixture(scope="module")
def scene_result():
    rays = two_group_scene(jax.random.key(3))
    return rays, jg.find_concurrences(rays)


def test_two_groups_found_with_membership(scene_result):
    rays, result = scene_result
    assert result.locations.shape == (2, 3)
    order = np.argsort(np.asarray(result.locations)[:, 0])[::-1]  # group 0 has x = 2
    errors = np.linalg.norm(np.asarray(result.locations)[order] - TARGETS, axis=1)
    assert np.all(errors < 0.15)
    membership = np.asarray(result.membership)
    assert set(membership[:4]) == {order[0]} and set(membership[4:8]) == {order[1]}
    assert membership[8] == -1  # the bystander supports nothing
    assert np.all(np.asarray(result.num_rays) == 4)
    assert np.all(np.asarray(result.converged))
    assert np.all(np.diff(np.asarray(result.field_values)) <= 0)


def test_covariances_are_symmetric_positive_definite(scene_result):
    _, result = scene_result
    cov = np.asarray(result.covariances)
    np.testing.assert_allclose(cov, np.swapaxes(cov, 1, 2), rtol=1e-4, atol=1e-8)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    semi = np.asarray(result.region_semi_axes)
    assert np.all(np.isfinite(semi)) and np.all(semi > 0)


def test_empty_results_for_no_or_one_ray():
    none = jg.find_concurrences(jg.GazeRays(np.zeros((0, 3)), np.zeros((0, 3))))
    assert none.locations.shape == (0, 3) and none.membership.shape == (0,)
    one = jg.find_concurrences(jg.GazeRays([[0.0, 0, 0]], [[1.0, 0, 0]]))
    assert one.locations.shape == (0, 3) and np.asarray(one.membership).tolist() == [-1]
    assert int(one.count) == 0


def test_disjoint_rays_give_no_concurrence():
    # Two skew rays that pass 2 m apart: no point is seen by both.
    rays = jg.GazeRays([[0.0, 0, 0], [0, 0, 2]], [[1.0, 0, 0], [0, 1, 0]], 0.02)
    assert jg.find_concurrences(rays).locations.shape == (0, 3)


def test_near_parallel_rays_give_long_covariance_along_rays():
    # A row of seated people looking at a stage 10 m away: rays almost parallel.
    origins = np.stack([np.linspace(-1.5, 1.5, 7), np.zeros(7), np.full(7, 1.2)], axis=1)
    stage = np.array([0.0, 10.0, 1.5])
    rays = noisy_rays(jax.random.key(0), origins, np.broadcast_to(stage, origins.shape), 0.01)
    result = jg.find_concurrences(rays)
    assert result.locations.shape[0] >= 1
    assert np.all(np.isfinite(np.asarray(result.covariances)))
    cov = np.asarray(result.covariances[0])
    eigenvalues, eigenvectors = np.linalg.eigh(cov)
    longest = eigenvectors[:, -1]
    mean_ray = np.asarray(rays.directions).mean(0)
    assert abs(longest @ mean_ray / np.linalg.norm(mean_ray)) > 0.95
    assert eigenvalues[-1] > 25 * eigenvalues[0]
    # The truth lies inside the 99 % region despite the elongation.
    e = np.asarray(result.locations[0]) - stage
    assert e @ np.linalg.solve(cov, e) < chi2.ppf(0.99, 3)


def test_bounds_reject_modes_outside_the_scene_volume():
    # Two people look down through the floor (z = 0) at a point 1 m below it, and two
    # others at a point on a table. With the room as bounds only the table remains.
    origins = np.array([[-2.0, 0, 1.7], [2.0, 0, 1.7], [0, 3, 1.7], [0, 6, 1.7]])
    targets = np.array([[0.0, 0, -1.0], [0, 0, -1.0], [1, 4.5, 0.8], [1, 4.5, 0.8]])
    rays = jg.GazeRays(origins, targets - origins, 0.02)
    no_floor = jg.ConcurrenceOptions(floor_below_eyes=None)
    assert len(jg.find_concurrences(rays, no_floor).locations) == 2
    room = [[-10.0, -10.0, 0.0], [10.0, 10.0, 3.0]]
    for options in (jg.ConcurrenceOptions(bounds=room, floor_below_eyes=None),
                    jg.ConcurrenceOptions(floor_below_eyes=2.5),  # the default: 2.7 m under the eyes is too low
                    jg.ConcurrenceOptions()):
        inside = jg.find_concurrences(rays, options)
        assert len(inside.locations) == 1
        np.testing.assert_allclose(np.asarray(inside.locations[0]), [1, 4.5, 0.8], atol=1e-3)
        np.testing.assert_array_equal(np.asarray(inside.membership), [-1, -1, 0, 0])
    # A floor 3 m under the eyes keeps the point 2.7 m under them.
    assert len(jg.find_concurrences(rays, jg.ConcurrenceOptions(floor_below_eyes=3.0)).locations) == 2
    with pytest.raises(ValueError, match="bounds"):
        jg.find_concurrences(rays, jg.ConcurrenceOptions(bounds=[[0.0, 0, 0], [1.0, -1, 1]]))


def test_exclusive_support_each_ray_in_at_most_one_mode(scene_result):
    _, result = scene_result
    membership = np.asarray(result.membership)
    counts = np.bincount(membership[membership >= 0], minlength=len(result.num_rays))
    np.testing.assert_array_equal(counts, np.asarray(result.num_rays))


def test_min_rays_rule():
    rays = two_group_scene(jax.random.key(3))
    assert jg.find_concurrences(rays, jg.ConcurrenceOptions(min_rays=5)).locations.shape == (0, 3)
    assert jg.find_concurrences(rays, jg.ConcurrenceOptions(min_rays=4)).locations.shape == (2, 3)


def test_location_is_maximum_likelihood_point_of_members(scene_result, x64):
    """The refined location minimises Σ‖d_i(x)‖²/h² over member rays (scipy reference)."""
    rays32, result32 = scene_result
    rays = jg.GazeRays(
        np.asarray(rays32.origins, np.float64), np.asarray(rays32.directions, np.float64), 0.02
    )
    result = jg.find_concurrences(rays)
    origins, directions = np.asarray(rays.origins), np.asarray(rays.directions)
    for k in range(len(result.locations)):
        m = np.asarray(result.membership) == k

        def residuals(x):
            diff = x - origins[m]
            t = np.sum(diff * directions[m], axis=1)
            return ((diff - t[:, None] * directions[m]) / (0.02 * t[:, None])).ravel()

        ref = least_squares(residuals, np.asarray(result.locations[k]) + 0.05, xtol=1e-14, ftol=1e-14)
        np.testing.assert_allclose(np.asarray(result.locations[k]), ref.x, atol=1e-6)
        # Gauss–Newton Laplace covariance (JᵀJ)⁻¹, with the tiny prior of scale 100 m, times the
        # posterior mean of the noise scale c² (log-uniform on [1/64, 64], 2n − 3 residual dof).
        laplace = np.linalg.inv(ref.jac.T @ ref.jac + np.eye(3) / 100.0**2)
        dof, rss = 2 * m.sum() - 3, np.sum(ref.fun**2)
        density = lambda log_u, power: np.exp(power * log_u - dof / 2 * log_u - rss / 2 * np.exp(-log_u))  # noqa: E731
        mean_c2 = quad(density, -np.log(64), np.log(64), args=(1,))[0] / quad(density, -np.log(64), np.log(64), args=(0,))[0]
        np.testing.assert_allclose(np.asarray(result.covariances[k]), mean_c2 * laplace, rtol=1e-4)


def test_meanshift_mode_matches_brute_force_grid_maximum(x64):
    """float64: the mean-shift fixed point is the maximum of f on a fine grid around it."""
    key = jax.random.key(11)
    origins = np.array([[0.0, -3, 1.7], [3, 0, 1.6], [-2, 2, 1.5], [2.5, 2.5, 1.8]])
    rays = noisy_rays(key, origins, np.broadcast_to([0.0, 0.5, 1.2], origins.shape), 0.03)
    seeds = jnp.asarray(origins + 2.5 * np.asarray(rays.directions))
    ms = jg.meanshift(rays, seeds, tol=1e-10, max_iter=2000)
    best = int(jnp.argmax(ms.field_values))
    assert bool(ms.converged[best])
    mode = np.asarray(ms.points[best])
    # Coarse-to-fine brute-force search for the grid maximum around the mode.
    centre, half = mode.copy(), 0.4
    for _ in range(6):
        axis = np.linspace(-half, half, 41)
        grid = centre + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        values = np.asarray(jg.saliency_field(rays, jnp.asarray(grid)))
        centre = grid[np.argmax(values)]
        half /= 8
    np.testing.assert_allclose(mode, centre, atol=2e-4)
    assert float(ms.field_values[best]) >= values.max() * (1 - 1e-9)


ray_sets = st.integers(min_value=0, max_value=2**31 - 1)


@settings(max_examples=40, deadline=None)
@given(seed=ray_sets, n=st.integers(min_value=2, max_value=7))
def test_meanshift_never_decreases_the_field(seed, n):
    """Theorem 1 of Park et al.: f(x_{j+1}) ≥ f(x_j) from random seeds on random rays (float64).

    Checked for the paper's update (eq. 6) step by step, and for the public
    ``meanshift`` (stretched steps) through its end points after 1, 2, … iterations.
    """
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        # Always 8 ray slots (the rest masked) so that one compilation serves every example.
        rays = jg.GazeRays(
            rng.normal(size=(8, 3)) * 2, rng.normal(size=(8, 3)), rng.uniform(0.02, 0.4, 8), np.arange(8) < n
        )
        seeds = jnp.asarray(rng.normal(size=(4, 3)) * 3)
        trajectory = _plain_trajectory(rays, seeds)
        values = np.asarray(jax.vmap(jax.vmap(lambda x: jg.saliency_field(rays, x)))(trajectory))
        stretched = np.stack(
            [np.asarray(jg.meanshift(rays, seeds, tol=0.0, max_iter=i).field_values) for i in (1, 2, 4, 8, 16)]
        )
        start = np.asarray(jg.saliency_field(rays, seeds))
    scale = max(values.max(), 1e-300)
    assert np.all(np.diff(values, axis=0) >= -1e-12 * scale)
    assert np.all(np.diff(np.vstack([start, stretched]), axis=0) >= -1e-12 * scale)


@jax.jit
def _plain_trajectory(rays, seeds):
    proj = ray_projector(rays)

    def step(x, _):
        x_new = jax.vmap(lambda y: meanshift_step(proj, y)[0])(x)
        return x_new, x_new

    _, path = jax.lax.scan(step, seeds, None, length=30)
    return jnp.concatenate([seeds[None], path])


def random_rigid(rng):
    return Rotation.random(random_state=rng).as_matrix(), rng.uniform(-10, 10, 3)


@settings(max_examples=15, deadline=None)
@given(seed=ray_sets)
def test_concurrences_invariant_under_rigid_transforms(seed):
    """Rotating and translating the scene moves the result with it (float64, so that
    rays sitting on a claim or prune threshold cannot flip on rounding). The floor rule
    is about world +z up, so it is off here."""
    rng = np.random.default_rng(seed)
    R, t = random_rigid(rng)
    any_frame = jg.ConcurrenceOptions(floor_below_eyes=None)
    with jax.enable_x64(True):
        rays32 = two_group_scene(jax.random.key(5))
        origins = np.asarray(rays32.origins, np.float64)
        directions = np.asarray(rays32.directions, np.float64)
        base = jg.find_concurrences(jg.GazeRays(origins, directions, 0.02), any_frame)
        result = jg.find_concurrences(jg.GazeRays(origins @ R.T + t, directions @ R.T, 0.02), any_frame)
    np.testing.assert_array_equal(np.asarray(result.membership), np.asarray(base.membership))
    np.testing.assert_allclose(np.asarray(result.locations), np.asarray(base.locations) @ R.T + t, atol=1e-6)
    rotated = R @ np.asarray(base.covariances) @ R.T
    np.testing.assert_allclose(np.asarray(result.covariances), rotated, rtol=1e-4, atol=1e-10)
    np.testing.assert_allclose(np.asarray(result.field_values), np.asarray(base.field_values), rtol=1e-6)


def test_laplace_covariance_is_calibrated():
    """Coverage of the 90 % ellipsoid on 300 replicate scenes drawn from the cone model."""
    replicates, people, h = 300, 5, 0.03
    target = jnp.array([0.0, 0.0, 1.5])
    k1, k2, k3 = jax.random.split(jax.random.key(2024), 3)
    dist = jax.random.uniform(k1, (replicates, people), minval=2.0, maxval=5.0)
    azimuth = jax.random.uniform(k2, (replicates, people), maxval=2 * math.pi)
    origins = jnp.stack([dist * jnp.cos(azimuth), dist * jnp.sin(azimuth), jnp.full_like(dist, 1.7)], -1)
    exact = jg.GazeRays(origins, target - origins, h)
    directions = jax.vmap(sample_gaze_directions)(jax.random.split(k3, replicates), exact)
    result = jg.find_concurrences_over_frames(jg.GazeRays(origins, directions, h))
    single = np.asarray(result.count) == 1
    assert single.mean() > 0.98
    error = np.asarray(result.locations[single, 0] - target)
    m2 = np.einsum("ti,tij,tj->t", error, np.linalg.inv(np.asarray(result.covariances[single, 0])), error)
    coverage = np.mean(m2 <= chi2.ppf(0.9, 3))
    assert 0.85 <= coverage <= 0.95, coverage  # ±2.5 standard errors around 0.9 at 300 replicates


def test_over_frames_matches_single_frames_and_handles_padding():
    frames = [two_group_scene(jax.random.key(k)) for k in range(3)]
    frames[1] = jg.GazeRays(frames[1].origins[:5], frames[1].directions[:5], 0.02)  # fewer people
    batch = jg.GazeRays.stack(frames)
    over = jg.find_concurrences_over_frames(batch)
    assert over.locations.shape[0] == 3 and over.membership.shape == (3, 9)
    for t, rays in enumerate(frames):
        single = jg.find_concurrences(rays)
        framed = over.frame(t)
        assert int(over.count[t]) == len(single.locations)
        np.testing.assert_allclose(np.asarray(framed.locations), np.asarray(single.locations), atol=1e-3)
        n = rays.num_rays
        np.testing.assert_array_equal(np.asarray(over.membership[t, :n]), np.asarray(single.membership))
        assert np.all(np.asarray(over.membership[t, n:]) == -1)


def synthetic_sequence(locations_per_frame, k=3):
    """Padded Concurrences with the given locations (list of (K_t, 3) lists)."""
    T = len(locations_per_frame)
    locations = np.zeros((T, k, 3), np.float32)
    valid = np.zeros((T, k), bool)
    for t, locs in enumerate(locations_per_frame):
        locations[t, : len(locs)] = np.reshape(locs, (-1, 3))
        valid[t, : len(locs)] = True
    z = np.zeros((T, k), np.float32)
    return jg.Concurrences(
        locations=jnp.asarray(locations), covariances=jnp.zeros((T, k, 3, 3)), field_values=jnp.asarray(z + 1),
        num_rays=jnp.asarray(valid * 3), membership=jnp.full((T, 6), -1), region_axes=jnp.zeros((T, k, 3, 3)),
        region_semi_axes=jnp.zeros((T, k, 3)), converged=jnp.asarray(valid), valid=jnp.asarray(valid),
    )


def test_tracker_links_births_and_deaths():
    a = lambda t: [0.05 * t, 0, 1]  # noqa: E731  slowly moving concurrence
    b = [5.0, 5, 1]
    frames = [[a(t)] for t in range(3)] + [[b, a(t)] for t in range(3, 6)] + [[a(t)] for t in range(6, 9)]
    frames += [[] for _ in range(4)] + [[a(0)]]
    seq = synthetic_sequence(frames)
    tracks = jg.track_concurrences(seq, max_distance=0.5, max_gap=2)
    ids = np.asarray(tracks.track_ids)
    trajectories = tracks.trajectories(seq)
    assert int(tracks.num_tracks) == 3
    assert trajectories[0]["birth"] == 0 and trajectories[0]["death"] == 8
    assert trajectories[1]["birth"] == 3 and trajectories[1]["death"] == 5
    assert trajectories[2]["birth"] == 13  # the old track died during the 4-frame gap
    np.testing.assert_allclose(trajectories[1]["locations"], np.tile(b, (3, 1)))
    assert np.all(ids[9:13] == -1)


def test_tracker_bridges_short_gaps():
    frames = [[[0.0, 0, 1]], [], [[0.1, 0, 1]], [[0.2, 0, 1]]]
    tracks = jg.track_concurrences(synthetic_sequence(frames), max_gap=1)
    assert int(tracks.num_tracks) == 1


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"min_rays": 1}, "min_rays"),
        ({"dominance": 0.0}, "dominance"),
        ({"claim_bandwidths": -1.0}, "claim_bandwidths"),
        ({"merge_radius": 0.0}, "merge_radius"),
        ({"seed_depths": [1.0, -2.0]}, "seed_depths"),
        ({"seed_depths": []}, "seed_depths"),
        ({"seed_depths": [1.0, float("nan")]}, "seed_depths"),
        ({"prior_scale": 0.0}, "prior_scale"),
        ({"floor_below_eyes": 0.0}, "floor_below_eyes"),
        ({"floor_below_eyes": float("inf")}, "floor_below_eyes"),
    ],
)
def test_bad_options_raise(scene_result, kwargs, message):
    rays, _ = scene_result
    with pytest.raises(ValueError, match=message):
        jg.find_concurrences(rays, jg.ConcurrenceOptions(**kwargs))


def test_wrong_ray_shapes_raise(scene_result):
    rays, _ = scene_result
    batch = jg.GazeRays.stack([rays, rays])
    with pytest.raises(ValueError, match="find_concurrences_over_frames"):
        jg.find_concurrences(batch)
    with pytest.raises(ValueError, match=r"\(T, N, 3\)"):
        jg.find_concurrences_over_frames(rays)
    with pytest.raises(TypeError, match="GazeRays"):
        jg.find_concurrences(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="track_concurrences"):
        jg.track_concurrences(jg.find_concurrences(rays))


# ---------------------------------------------------------------------------
# What the defaults do not call a concurrence, and the unit checks at the door (issue 20).
# Closed forms: two people facing each other (mutual gaze), a third looking at one of them,
# two people in a line looking the same way (a ridge, not a mode); a millimetre scene and
# bandwidths in degrees. (Here, not in a file of their own: they share this file's compiled
# 8-ray program.)

EYE_A = np.array([0.0, 0.0, 1.6])
EYE_B = np.array([2.0, 0.0, 1.6])
EYE_C = np.array([1.0, 2.0, 1.6])
H = 0.02


def turned(direction, angle):
    """``direction`` turned by ``angle`` radians about world +z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ direction


def test_two_people_facing_each_other_are_mutual_gaze_not_a_concurrence():
    found = jg.find_concurrences(jg.GazeRays([EYE_A, EYE_B], [EYE_B - EYE_A, EYE_A - EYE_B], H))
    assert found.locations.shape == (0, 3)  # before: a mode between them with sd 100 m along their line
    np.testing.assert_array_equal(np.asarray(found.membership), [-1, -1])
    np.testing.assert_array_equal(np.asarray(found.mutual_gaze), [1, 0])
    np.testing.assert_array_equal(found.mutual_gaze_pairs(), [[0, 1]])


@pytest.mark.parametrize("offset_bandwidths, mutual", [(2.0, True), (5.5, True), (6.5, False), (12.0, False)])
def test_mutual_gaze_is_each_eye_in_the_others_claim_radius(offset_bandwidths, mutual):
    """Closed form: a ray turned by α from the other's eye misses it by ‖d‖ = tan α; the pair is
    mutual gaze while tan α / h is below the claim radius, 3 claim bandwidths × search scale 2 = 6."""
    alpha = math.atan(offset_bandwidths * H)
    rays = jg.GazeRays([EYE_A, EYE_B], [turned(EYE_B - EYE_A, alpha), turned(EYE_A - EYE_B, -alpha)], H)
    found = jg.find_concurrences(rays)
    np.testing.assert_array_equal(np.asarray(found.mutual_gaze), [1, 0] if mutual else [-1, -1])
    # One looking at the other, the other away: not mutual.
    away = jg.find_concurrences(jg.GazeRays([EYE_A, EYE_B], [EYE_B - EYE_A, turned(EYE_A - EYE_B, 0.5)], H))
    np.testing.assert_array_equal(np.asarray(away.mutual_gaze), [-1, -1])


def test_a_person_in_mutual_gaze_still_supports_a_concurrence_with_others():
    """A and B look at each other, C looks at A: B and C concur at A's eyes."""
    found = jg.find_concurrences(jg.GazeRays([EYE_A, EYE_B, EYE_C], [EYE_B - EYE_A, EYE_A - EYE_B, EYE_A - EYE_C], H))
    assert len(found.locations) == 1
    np.testing.assert_allclose(np.asarray(found.locations[0]), EYE_A, atol=1e-3)
    np.testing.assert_array_equal(np.asarray(found.membership), [-1, 0, 0])
    np.testing.assert_array_equal(np.asarray(found.mutual_gaze), [1, 0, -1])


def test_a_mode_the_rays_do_not_bound_is_not_reported():
    """Two people in a line looking the same way (B in front of A, no one facing anyone): their rays
    overlap along the whole line, the prior alone would hold the mode there."""
    rays = jg.GazeRays([EYE_A, EYE_B], [EYE_B - EYE_A, EYE_B - EYE_A], H)
    found = jg.find_concurrences(rays)
    assert found.locations.shape == (0, 3)
    np.testing.assert_array_equal(np.asarray(found.mutual_gaze), [-1, -1])
    # A slight convergence bounds it again: the rays cross 3 m ahead of B.
    target = EYE_B + np.array([3.0, 0.0, 0.0]) + np.array([0.0, 0.5, 0.0])
    crossing = jg.find_concurrences(jg.GazeRays([EYE_A, EYE_B + [0, 0.0, 0.3]], [target - EYE_A, target - EYE_B - [0, 0, 0.3]], H))
    assert len(crossing.locations) == 1 and np.all(np.linalg.eigvalsh(np.asarray(crossing.covariances[0])) < 25.0)


def test_mutual_gaze_with_too_few_people_for_a_mode_over_frames():
    """min_rays 3 with two people per frame: no mode can exist, the mutual gaze is still reported
    (the full search over frames reports it too: tests/cli/test_concurrences_demo.py)."""
    frames = [jg.GazeRays([EYE_A, EYE_B], [EYE_B - EYE_A, EYE_A - EYE_B], H), jg.GazeRays([EYE_A, EYE_C], [turned(EYE_C - EYE_A, 0.5), EYE_A - EYE_C], H),
              jg.GazeRays([EYE_C, EYE_A], [EYE_A - EYE_C, EYE_C - EYE_A], H)]
    over = jg.find_concurrences_over_frames(jg.GazeRays.stack(frames), jg.ConcurrenceOptions(min_rays=3))
    assert over.locations.shape == (3, 0, 3)
    np.testing.assert_array_equal(np.asarray(over.mutual_gaze), [[1, 0], [-1, -1], [1, 0]])
    np.testing.assert_array_equal(over.mutual_gaze_pairs(), [[0, 0, 1], [2, 0, 1]])
    np.testing.assert_array_equal(np.asarray(over.frame(2).mutual_gaze), [1, 0])  # per person, not per mode
    few = jg.find_concurrences(frames[0], jg.ConcurrenceOptions(min_rays=3))
    np.testing.assert_array_equal(np.asarray(few.mutual_gaze), [1, 0])


def test_units_caught_at_the_door():
    origins = np.array([EYE_A, EYE_B, EYE_C, [1.0, -2.0, 1.2]])
    target = np.array([1.0, 0.5, 0.8])
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)  # a room in metres, a bandwidth in radians: no warning
        assert len(jg.find_concurrences(jg.GazeRays(origins, target - origins, H)).locations) == 1
    with pytest.warns(UnitWarning, match=r"spread over 4000 m.*\(millimetres\?\)"):
        found = jg.find_concurrences(jg.GazeRays(1000.0 * origins, target - origins, H))
    assert len(found.locations) == 0  # what a millimetre scene gives: hence the warning
    with pytest.raises(ValueError, match=r"bandwidth 3 rad \(172°\) is no gaze cone width.*degrees\? 3° is 0.0524"):
        jg.find_concurrences(jg.GazeRays(origins, target - origins, 3.0))
    with pytest.warns(UnitWarning, match=r"bandwidth reaches 0.7 rad \(40°\).*degrees\?"):
        check_units(jg.GazeRays(origins, target - origins, 0.7))
    recording = jg.GazeRays.stack([jg.GazeRays(origins, target - origins, H), jg.GazeRays(1000.0 * origins,
                                                                                          target - origins, H)])
    with pytest.warns(UnitWarning, match="the eyes of frame 1 spread"):
        check_units(recording)
