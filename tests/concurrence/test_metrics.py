"""Evaluation metrics (jaxgaze.concurrence.metrics): Hungarian matching, errors, counts, coverage."""

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import chi2

from jaxgaze.concurrence.metrics import (
    count_accuracy,
    coverage,
    evaluate,
    localisation_errors,
    mahalanobis_squared,
    match_concurrences,
    match_over_frames,
    region_coverage,
)


class Estimates(NamedTuple):
    locations: np.ndarray
    covariances: np.ndarray
    valid: np.ndarray


class FakeScene(NamedTuple):
    concurrences: np.ndarray
    concurrence_valid: np.ndarray


def _brute_force(est: np.ndarray, tru: np.ndarray) -> float:
    """Smallest total distance over all one-to-one assignments of min(K, M) pairs."""
    k, m = len(est), len(tru)
    if k == 0 or m == 0:
        return 0.0
    cost = np.linalg.norm(est[:, None] - tru[None], axis=-1)
    if k <= m:
        return min(sum(cost[i, p[i]] for i in range(k)) for p in itertools.permutations(range(m), k))
    return min(sum(cost[p[j], j] for j in range(m)) for p in itertools.permutations(range(k), m))


def test_hungarian_matches_brute_force():
    cases = 60
    sizes = np.asarray(jax.random.randint(jax.random.key(0), (cases, 2), 0, 5))  # K, M in 0..4
    points = np.asarray(jax.random.uniform(jax.random.key(1), (cases, 2, 4, 3), minval=-2, maxval=2), dtype=float)
    for case in range(cases):
        k, m = sizes[case]
        est, tru = points[case, 0, :k], points[case, 1, :m]
        match = match_concurrences(est, tru)
        assert len(match.distances) == min(k, m)
        assert len(set(match.estimated.tolist())) == len(match.estimated)  # one-to-one
        assert len(set(match.truth.tolist())) == len(match.truth)
        np.testing.assert_allclose(
            match.distances, np.linalg.norm(est[match.estimated] - tru[match.truth], axis=-1), rtol=1e-12
        )
        assert match.distances.sum() == pytest.approx(_brute_force(est, tru), abs=1e-9)


def test_match_gate_and_obvious_case():
    est = np.array([[0.0, 0, 0], [5.0, 0, 0], [10.0, 0, 0]])
    tru = np.array([[10.1, 0, 0], [0.2, 0, 0]])
    match = match_concurrences(est, tru)
    assert dict(zip(match.estimated.tolist(), match.truth.tolist())) == {0: 1, 2: 0}
    np.testing.assert_allclose(sorted(match.distances), [0.1, 0.2], atol=1e-12)
    gated = match_concurrences(est, tru, max_distance=0.15)
    assert gated.estimated.tolist() == [2] and gated.truth.tolist() == [0]
    with pytest.raises(ValueError, match="max_distance"):
        match_concurrences(est, tru, max_distance=0.0)


def test_match_shape_errors():
    with pytest.raises(ValueError, match=r"estimated must have shape \(K, 3\)"):
        match_concurrences(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="truth must have shape"):
        match_concurrences(np.zeros((2, 3)), np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        match_concurrences(np.full((1, 3), np.nan), np.zeros((1, 3)))


def _padded_example():
    """3 frames, up to 2 estimates and 2 truths, with misses, false alarms and padding."""
    truth = np.array(
        [
            [[0.0, 0, 1], [3.0, 0, 1]],
            [[0.0, 0, 1], [3.0, 0, 1]],
            [[0.0, 0, 1], [99.0, 99, 99]],  # second truth invalid in frame 2
        ]
    )
    truth_valid = np.array([[True, True], [True, True], [True, False]])
    locations = np.array(
        [
            [[3.0, 0.1, 1], [0.0, 0, 1.2]],  # both found (order swapped)
            [[0.05, 0, 1], [0.0, 0, 0]],  # one found, slot 1 padding
            [[0.0, 0.3, 1], [2.9, 0, 1]],  # one right, one false alarm near an invalid truth
        ]
    )
    valid = np.array([[True, True], [True, False], [True, True]])
    cov = np.broadcast_to(np.eye(3) * 0.01, (3, 2, 3, 3)).copy()
    return Estimates(locations, cov, valid), truth, truth_valid


def test_localisation_errors_over_frames():
    est, truth, truth_valid = _padded_example()
    errors = localisation_errors(est, truth, truth_valid)
    np.testing.assert_allclose(sorted(errors), sorted([0.1, 0.2, 0.05, 0.3]), atol=1e-12)
    matches = match_over_frames(est, truth, truth_valid)
    assert matches.frames.tolist() == [0, 0, 1, 2]
    # A Scene-like truth gives the same answer; giving both is an error.
    scene = FakeScene(truth, truth_valid)
    np.testing.assert_allclose(localisation_errors(est, scene), errors)
    with pytest.raises(ValueError, match="truth_valid must be omitted"):
        localisation_errors(est, scene, truth_valid)
    # Gating drops the 0.3 m pair.
    assert len(localisation_errors(est, truth, truth_valid, max_distance=0.25)) == 3
    # A single frame (K, 3) without a mask works too.
    one = Estimates(est.locations[0], est.covariances[0], None)
    np.testing.assert_allclose(sorted(localisation_errors(one, truth[0])), [0.1, 0.2], atol=1e-12)


def test_localisation_shape_errors():
    est, truth, truth_valid = _padded_example()
    with pytest.raises(ValueError, match="2 frames but the estimates have 3"):
        localisation_errors(est, truth[:2], truth_valid[:2])
    with pytest.raises(ValueError, match="truth_valid shape"):
        localisation_errors(est, truth, truth_valid[:, :1])
    with pytest.raises(ValueError, match="valid shape"):
        localisation_errors(est._replace(valid=est.valid[:, :1]), truth, truth_valid)
    with pytest.raises(ValueError, match="locations must have shape"):
        localisation_errors(est._replace(locations=np.zeros((3, 2, 2))), truth, truth_valid)
    with pytest.raises(ValueError, match="covariances must have shape"):
        coverage(est._replace(covariances=np.zeros((3, 2, 3))), truth, truth_valid)
    with pytest.raises(ValueError, match="'locations' field"):
        localisation_errors(np.zeros((3, 2, 3)), truth, truth_valid)


def test_count_accuracy():
    assert count_accuracy(np.array([2, 2, 1, 0]), np.array([2, 1, 1, 0])) == 0.75
    assert count_accuracy(jnp.array([1, 1]), jnp.array([1, 1])) == 1.0
    with pytest.raises(ValueError, match="3 frames but true_count has 2"):
        count_accuracy(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="1-D"):
        count_accuracy(np.zeros((3, 1)), np.zeros((3, 1)))
    with pytest.raises(ValueError, match="at least one frame"):
        count_accuracy(np.zeros(0), np.zeros(0))


def _gaussian_case(key, num_frames: int, scale: float = 1.0):
    """Estimates with random SPD covariances; truth drawn from N(estimate, scale² Σ)."""
    draws = np.asarray(jax.random.normal(key, (num_frames, 15)), dtype=float)  # one draw: 9 + 3 + 3
    a = draws[:, :9].reshape(num_frames, 1, 3, 3) * 0.1
    cov = a @ np.swapaxes(a, -1, -2) + 1e-3 * np.eye(3)
    loc = 3.0 * draws[:, 9:12].reshape(num_frames, 1, 3)
    z = draws[:, 12:].reshape(num_frames, 1, 3, 1)
    truth = loc + scale * (np.linalg.cholesky(cov) @ z)[..., 0]
    return Estimates(loc, cov, np.ones((num_frames, 1), bool)), truth, np.ones((num_frames, 1), bool)


def test_coverage_on_gaussian():
    n = 4000
    est, truth, valid = _gaussian_case(jax.random.key(7), n)
    tol = 4 * np.sqrt(0.9 * 0.1 / n)  # 4 binomial standard errors ≈ 0.019
    assert abs(coverage(est, truth, valid, level=0.9) - 0.9) < tol
    assert abs(coverage(est, truth, valid, level=0.5) - 0.5) < 4 * np.sqrt(0.25 / n)
    m2 = mahalanobis_squared(est, truth, valid)
    assert abs(m2.mean() - 3.0) < 4 * np.sqrt(6.0 / n)  # χ²₃: mean 3, variance 6
    # Too-small covariances under-cover, too-large ones over-cover.
    wide_est, wide_truth, _ = _gaussian_case(jax.random.key(7), n, scale=1.5)
    assert coverage(wide_est, wide_truth, valid) < 0.8
    narrow_est, narrow_truth, _ = _gaussian_case(jax.random.key(7), n, scale=0.6)
    assert coverage(narrow_est, narrow_truth, valid) > 0.97
    assert chi2.ppf(0.9, 3) == pytest.approx(6.2514, abs=1e-4)


def test_coverage_errors_and_empty():
    est, truth, truth_valid = _padded_example()
    with pytest.raises(ValueError, match="level"):
        coverage(est, truth, truth_valid, level=1.0)
    none_valid = np.zeros_like(truth_valid)
    assert np.isnan(coverage(est, truth, none_valid))


def test_evaluate_summary():
    est, truth, truth_valid = _padded_example()
    summary = evaluate(est, FakeScene(truth, truth_valid))
    assert summary.num_matched == 4 and summary.num_frames == 3
    assert summary.median_error == pytest.approx(np.median([0.1, 0.2, 0.05, 0.3]))
    assert summary.count_accuracy == pytest.approx(1 / 3)  # frame 1 misses one, frame 2 has a false alarm
    assert 0 <= summary.coverage <= 1


class RegionEstimates(NamedTuple):
    locations: np.ndarray
    valid: np.ndarray
    region_axes: np.ndarray
    region_semi_axes: np.ndarray


def test_region_coverage():
    """Truth inside/outside the paper's 80 %-of-maximum ellipsoid, flat axes included."""
    rot = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # columns: principal axes
    est = RegionEstimates(
        locations=np.zeros((4, 1, 3)),
        valid=np.ones((4, 1), bool),
        region_axes=np.broadcast_to(rot, (4, 1, 3, 3)),
        region_semi_axes=np.broadcast_to(np.array([0.1, 0.5, np.inf]), (4, 1, 3)),
    )
    truth = np.array([[[0.0, 0.09, 0]], [[0.0, 0.11, 0]], [[0.4, 0, 0]], [[0.0, 0, 7.0]]])
    # axis 1 is world y (semi 0.1), axis 2 world -x (semi 0.5), axis 3 z (flat)
    assert region_coverage(est, truth) == 0.75
    with pytest.raises(ValueError, match="region_axes"):
        region_coverage(Estimates(est.locations, np.zeros((4, 1, 3, 3)), est.valid), truth)
