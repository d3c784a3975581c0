"""A failed location refinement is a result code per concurrence, not a silent fallback (issue 36)."""

import jax.numpy as jnp
import numpy as np
import optimistix as optx

import jaxgaze as jg
from jaxgaze.concurrence import ConcurrenceOptions, find_concurrences, find_concurrences_over_frames
from jaxgaze.concurrence.laplace import refine_and_laplace
from jaxgaze.results import RESULTS, from_optimistix, succeeded


def four_people_looking_at_one_point():
    """Four noisy rays at one target (1, 2, 1.2) m: one concurrence; N // min_rays = 2 slots."""
    rng = np.random.default_rng(0)
    eyes = np.array([[0.0, 0.0, 1.7], [2.0, 0.0, 1.7], [0.0, 3.0, 1.7], [3.0, 3.0, 1.6]])
    d = np.array([1.0, 2.0, 1.2]) + rng.normal(0.0, 0.03, (4, 3)) - eyes
    return jg.GazeRays(eyes, d / np.linalg.norm(d, axis=1, keepdims=True), np.full(4, 0.02))


def test_refinement_out_of_steps_is_a_code_per_concurrence():
    rays = four_people_looking_at_one_point()
    solved = find_concurrences(rays)
    assert solved.count == 1 and np.all(succeeded(solved))
    # Two Levenberg–Marquardt steps cannot meet the tolerance: the best point reached is kept,
    # and the concurrence says so.
    short = find_concurrences(rays, ConcurrenceOptions(refine_steps=2))
    assert short.count == 1
    assert np.all(short.result == RESULTS.max_steps_reached)
    assert succeeded(short).tolist() == [False]
    np.testing.assert_allclose(short.locations, solved.locations, atol=1e-3)


def test_over_frames_codes_keep_the_frame_shape_and_padding_is_successful():
    rays = four_people_looking_at_one_point()
    recording = jg.GazeRays.stack([rays, rays])
    found = find_concurrences_over_frames(recording, ConcurrenceOptions(refine_steps=2))
    ok = np.asarray(succeeded(found))
    assert ok.shape == found.valid.shape == (2, 2)
    assert np.array_equal(np.asarray(found.valid), [[True, False], [True, False]])
    assert np.array_equal(ok, ~np.asarray(found.valid))  # the real modes failed; the padding did not
    assert found.frame(1).result == RESULTS.max_steps_reached


def test_a_start_that_is_not_finite_falls_back_with_a_code():
    rays = four_people_looking_at_one_point()
    start = jnp.array([jnp.nan, 0.0, 0.0])
    location, _, _, _, result = refine_and_laplace(rays, jnp.ones(4, bool), start, 100.0, 64)
    assert np.isnan(location[0]) and np.array_equal(location[1:], [0.0, 0.0])  # the start, as before
    assert result == RESULTS.nonfinite


def test_optimistix_results_map_through_one_table():
    assert from_optimistix(optx.RESULTS.successful) == RESULTS.successful
    assert from_optimistix(optx.RESULTS.nonlinear_max_steps_reached) == RESULTS.max_steps_reached
    assert from_optimistix(optx.RESULTS.nonlinear_divergence) == RESULTS.optimiser_failed
