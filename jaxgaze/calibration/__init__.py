"""Gaze-ray calibration from head-mounted cameras (Park, Jain & Sheikh 2012, Sec. 3.2).

* :mod:`jaxgaze.calibration.cone_fit` — RANSAC and the convex apex programme (eq. 1–3);
* :mod:`jaxgaze.calibration.posterior` — the Bayesian calibration: NUTS over eye centre,
  direction and bandwidth.
"""

from jaxgaze.calibration.cone_fit import (
    CalibrationResult,
    ConeCalibration,
    calibrate_cone,
    solve_cone_apex,
    points_in_camera_frame,
    DEFAULT_REGULARIZATION,
    DEFAULT_INLIER_THRESHOLD,
    DEFAULT_RANSAC_ITERATIONS,
)
from jaxgaze.calibration.posterior import (
    calibration_model,
    calibrate_cone_posterior,
    calibrate_cone_posterior_batch,
    CalibrationPosterior,
)

__all__ = [
    "CalibrationResult",
    "ConeCalibration",
    "calibrate_cone",
    "solve_cone_apex",
    "points_in_camera_frame",
    "DEFAULT_REGULARIZATION",
    "DEFAULT_INLIER_THRESHOLD",
    "DEFAULT_RANSAC_ITERATIONS",
    "calibration_model",
    "calibrate_cone_posterior",
    "calibrate_cone_posterior_batch",
    "CalibrationPosterior",
]
