"""Gaze-ray calibration from head-mounted cameras (Park, Jain & Sheikh 2012, Sec. 3.2).

* :mod:`jaxgaze.calibration.cone_fit` — RANSAC and the convex apex programme (eq. 1–3);
* :mod:`jaxgaze.calibration.posterior` — the Bayesian calibration: NUTS over eye centre,
  direction and bandwidth.

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| Sec. 3.2: points of regard ``y = R_camera_from_world (C_B − C_A)`` | ``points_in_camera_frame`` | ``calibration/cone_fit.py`` |
| Sec. 3.2: RANSAC line and the sign of ``v`` | ``calibrate_cone`` | ``calibration/cone_fit.py`` |
| eq. 1: ``p0``, the nearest inlier along the line | ``calibrate_cone`` | ``calibration/cone_fit.py`` |
| eq. 2: the convex apex programme ``min ξ + λα`` | ``solve_cone_apex`` | ``calibration/cone_fit.py`` |
| eq. 4: bandwidth ``h`` from perspective distances | ``calibrate_cone`` (with ``jaxgaze.geometry.perspective_distance``) | ``calibration/cone_fit.py`` |
| Sec. 3.2, Bayesian: posterior of ``p``, ``v``, ``h`` with outliers | ``calibration_model``, ``calibration_log_likelihood``, ``calibrate_cone_posterior``, ``calibrate_cone_posterior_batch`` | ``calibration/posterior.py`` |
| Sec. 3.2: the point estimate against the posterior (the apex is loose along the ray) | ``needs_posterior``, ``choose_calibration`` | ``calibration/posterior.py`` |
"""

from jaxgaze.calibration.cone_fit import (
    ConeCalibration,
    calibrate_cone,
    solve_cone_apex,
    points_in_camera_frame,
    DEFAULT_REGULARIZATION,
    DEFAULT_INLIER_THRESHOLD,
    DEFAULT_RANSAC_ITERATIONS,
    MAX_APEX_DISTANCE,
)
from jaxgaze.calibration.posterior import (
    calibration_model,
    calibration_log_likelihood,
    calibrate_cone_posterior,
    calibrate_cone_posterior_batch,
    CalibrationPosterior,
    CalibrationChoice,
    needs_posterior,
    choose_calibration,
    MAX_EYE_OFFSET,
)

__all__ = [
    "ConeCalibration",
    "calibrate_cone",
    "solve_cone_apex",
    "points_in_camera_frame",
    "DEFAULT_REGULARIZATION",
    "DEFAULT_INLIER_THRESHOLD",
    "DEFAULT_RANSAC_ITERATIONS",
    "MAX_APEX_DISTANCE",
    "calibration_model",
    "calibration_log_likelihood",
    "calibrate_cone_posterior",
    "calibrate_cone_posterior_batch",
    "CalibrationPosterior",
    "CalibrationChoice",
    "needs_posterior",
    "choose_calibration",
    "MAX_EYE_OFFSET",
]
