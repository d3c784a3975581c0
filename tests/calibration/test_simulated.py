"""Issue 3's must-shows on simulated wearers with known mounting offsets.

The sessions come from :mod:`jaxgaze.simulate.calibration` (pairs looking at each
other's camera while moving back and forth and side to side, with eye-in-head
deviations ``h = 0.03`` rad, camera pose noise, and optional outlier frames), not
from the cone model directly, so the mounting, the pose noise and the outliers all
stand between the truth and the estimate. 300 frames are 30 s at 10 fps: three
back-and-forth cycles of 5–10 s (Park et al. 2012, Sec. 4).
"""

import jax
import numpy as np
import pytest

import jaxgaze as jg
from tests import helpers as zoo

FRAMES = 300
WEARERS = 50
OUTLIER_WEARERS = 16


def _points_and_truth(sessions, count):
    y = np.asarray(sessions.points_of_regard_a())[:count]
    return y, np.asarray(sessions.eye_center_a)[:count], np.asarray(sessions.direction_a)[:count]


def _errors(eye_centers, directions, true_eye, true_direction):
    """Direction error (degrees) and eye-centre error perpendicular to the true axis (m)."""
    angle = np.degrees(np.asarray(jg.geometry.angle_between(directions, true_direction)))
    offset = eye_centers - true_eye
    perpendicular = offset - np.sum(offset * true_direction, -1, keepdims=True) * true_direction
    return angle, np.linalg.norm(perpendicular, axis=-1)


@jax.jit
def _ransac_many(points, keys):
    return jax.vmap(lambda y, k: jg.calibrate_cone(y, key=k, throw=False))(points, keys)


def _posteriors(y, seed):
    """Posterior of every wearer (one batched run), started at its RANSAC estimate as the experiment does."""
    point = _ransac_many(y, jax.random.split(jax.random.key(seed), len(y)))
    ok = np.asarray(point.result == jg.RESULTS.successful)
    posteriors = jg.calibrate_cone_posterior_batch(
        y, key=jax.random.key(seed + 1), num_warmup=300, num_samples=300,
        init_eye_centers=np.where(ok[:, None], np.asarray(point.eye_center), 0.0),
        init_directions=np.where(ok[:, None], np.asarray(point.direction), [1.0, 0.0, 0.0]))
    return point, posteriors


@pytest.fixture(scope="module")
def clean():
    sessions = zoo.wearers(WEARERS, FRAMES, 2024)
    y, eye, direction = _points_and_truth(sessions, WEARERS)
    point, posteriors = _posteriors(y, 7)
    return eye, direction, point, posteriors


@pytest.fixture(scope="module")
def with_outliers():
    sessions = zoo.wearers(OUTLIER_WEARERS, FRAMES, 99, outlier_fraction=0.2)
    y, eye, direction = _points_and_truth(sessions, OUTLIER_WEARERS)
    point, posteriors = _posteriors(y, 8)
    return eye, direction, point, posteriors


def test_ransac_recovers_simulated_mountings(clean):
    eye, direction, point, _ = clean
    assert np.all(np.asarray(point.result == jg.RESULTS.successful))
    angle, perpendicular = _errors(np.asarray(point.eye_center), np.asarray(point.direction), eye, direction)
    assert np.median(angle) < 2.0, angle
    assert np.median(perpendicular) < 0.04, perpendicular


def test_posterior_mean_recovers_simulated_mountings(clean):
    eye, direction, _, posteriors = clean
    angle, perpendicular = _errors(np.array([p.eye_center for p in posteriors]),
                                   np.array([p.direction for p in posteriors]), eye, direction)
    assert np.median(angle) < 2.0, angle
    assert np.median(perpendicular) < 0.04, perpendicular


def test_posterior_90_percent_regions_are_calibrated(clean):
    """The 90 % credible regions hold the truth for 80–98 % of 50 wearers (not too narrow, not too wide)."""
    eye, direction, _, posteriors = clean
    inside = np.array([p.contains(e, d, level=0.9) for p, e, d in zip(posteriors, eye, direction)])
    direction_coverage, eye_coverage = inside.mean(0)
    assert 0.80 <= direction_coverage <= 0.98, direction_coverage
    assert 0.80 <= eye_coverage <= 0.98, eye_coverage


def test_posterior_is_at_least_as_accurate_as_ransac_with_20_percent_outliers(with_outliers):
    eye, direction, point, posteriors = with_outliers
    ransac = _errors(np.asarray(point.eye_center), np.asarray(point.direction), eye, direction)
    bayes = _errors(np.array([p.eye_center for p in posteriors]), np.array([p.direction for p in posteriors]),
                    eye, direction)
    for ours, theirs in zip(bayes, ransac):
        assert np.median(ours) <= np.median(theirs), (np.median(ours), np.median(theirs))
        assert np.percentile(ours, 90) <= np.percentile(theirs, 90)
    # The posterior sees the outliers: its outlier share is near the simulated 20 %.
    share = np.median([p.samples["outlier_share"].mean() for p in posteriors])
    assert 0.12 < share < 0.28, share


def test_credible_radii_reject_a_bad_level(clean):
    posterior = clean[3][0]
    direction_radius, eye_radius = posterior.credible_radii(0.5)
    assert 0 < direction_radius < posterior.credible_radii(0.95)[0]
    assert 0 < eye_radius < posterior.credible_radii(0.95)[1]
    with pytest.raises(ValueError, match="level"):
        posterior.credible_radii(1.0)
