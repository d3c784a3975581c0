"""The point estimate against the posterior (issue 34, bug 3): which calibration is used, and when it is said.

Park's apex (eq. 2) is loose along the gaze ray; the posterior places it with its prior. The posterior
here is a Gaussian cloud of draws with a known covariance, so the credible level of a point is known in
closed form (chi-square with 3 degrees of freedom).
"""

import numpy as np
import pytest
from scipy.stats import chi2

from jaxgaze.calibration import ConeCalibration, MAX_EYE_OFFSET, choose_calibration, needs_posterior
from jaxgaze.calibration.posterior import CalibrationPosterior
from jaxgaze.results import RESULTS

MEAN = np.array([0.01, 0.03, -0.08])
SD = np.array([0.15, 0.03, 0.03])  # loose along the ray (+x), tight across it
DIRECTION = np.array([1.0, 0.0, 0.0])


def _posterior(result=RESULTS.successful, num_draws=4000):
    rng = np.random.default_rng(0)
    draws = MEAN + SD * rng.standard_normal((num_draws, 3))
    samples = {"eye_center": draws, "direction": np.tile(DIRECTION, (num_draws, 1)),
               "bandwidth": np.full(num_draws, 0.03), "inlier_probability": np.full((num_draws, 5), 0.9)}
    return CalibrationPosterior(sampler=None, eye_center=draws.mean(0), direction=DIRECTION,
                                bandwidth=0.03, samples=samples, predictive_check={}, result=result)


def _fit(eye_center):
    return ConeCalibration(eye_center=np.asarray(eye_center, float), direction=DIRECTION, bandwidth=np.float64(0.04),
                           alpha=np.float64(0.5), xi=np.float64(0.1), inliers=np.ones(5, bool),
                           result=RESULTS.successful)


def test_region_level_is_the_chi_square_level():
    """A point at Mahalanobis distance² q has credible level F_χ²₃(q) (to the Monte Carlo error of 4000 draws)."""
    post = _posterior()
    for level in (0.5, 0.9, 0.99):
        point = MEAN + SD * np.array([np.sqrt(chi2.ppf(level, 3)), 0.0, 0.0])
        assert post.region_level(point) == pytest.approx(level, abs=0.02)


def test_a_point_estimate_outside_the_posterior_is_replaced_and_said():
    post = _posterior()
    far = _fit(MEAN + [0.5, 0.0, 0.0])  # 3.3 sd along the ray: the 99.4% region, 0.52 m from the camera
    choice = choose_calibration(far, post)
    assert choice.disagrees and choice.method == "posterior mean" and choice.region_level > 0.99
    np.testing.assert_allclose(choice.cone.eye_center, post.eye_center)
    assert choice.distance == pytest.approx(np.linalg.norm(far.eye_center - post.eye_center))
    assert np.isnan(choice.cone.alpha) and choice.cone.inliers.all()

    near = _fit(MEAN + [0.1, 0.01, 0.0])  # inside the 90% region, near the camera: kept
    choice = choose_calibration(near, post)
    assert not choice.disagrees and choice.method == "ransac+cone" and choice.cone is near
    assert choice.region_level < 0.9 and not needs_posterior(near)


def test_an_implausible_point_estimate_disagrees_even_inside_the_region():
    """More than MAX_EYE_OFFSET from the camera is no eye of the wearer, whatever a broad posterior says."""
    wide = _posterior()._replace(samples={**_posterior().samples,
                                          "eye_center": MEAN + 3 * (_posterior().samples["eye_center"] - MEAN)})
    fit = _fit([MAX_EYE_OFFSET + 0.05, 0.03, -0.08])
    assert needs_posterior(fit) and wide.region_level(fit.eye_center) < 0.9
    choice = choose_calibration(fit, wide)
    assert choice.disagrees and choice.method == "posterior mean"


def test_a_failed_posterior_does_not_replace_the_point_estimate():
    fit = _fit(MEAN + [0.5, 0.0, 0.0])
    choice = choose_calibration(fit, _posterior(result=RESULTS.not_mixed))
    assert choice.disagrees and choice.method == "ransac+cone" and choice.cone is fit
    with pytest.raises(ValueError, match="level"):
        choose_calibration(fit, _posterior(), level=1.0)
