"""Gaze-ray calibration from head-mounted cameras (Park, Jain & Sheikh 2012, Sec. 3.2).

* :mod:`jaxgaze.calibration.cone_fit` — RANSAC and the convex apex programme (eq. 1–3);
* :mod:`jaxgaze.calibration.posterior` — the Bayesian calibration: NUTS over eye centre,
  direction and bandwidth.

This door holds the entry points, result types and options; every other name is imported
from its module (``from jaxgaze.calibration.cone_fit import solve_cone_apex``).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| Sec. 3.2: points of regard ``y = R_camera_from_world (C_B − C_A)`` | ``points_in_camera_frame`` | ``calibration/cone_fit.py`` |
| Sec. 3.2: RANSAC line and the sign of ``v`` | ``calibrate_cone`` | ``calibration/cone_fit.py`` |
| eq. 1: ``p0``, the nearest inlier along the line | ``calibrate_cone`` | ``calibration/cone_fit.py`` |
| eq. 2: the convex apex programme ``min ξ + λα`` | ``cone_fit.solve_cone_apex`` | ``calibration/cone_fit.py`` |
| eq. 4: bandwidth ``h`` from perspective distances | ``calibrate_cone`` (with ``jaxgaze.geometry.perspective_distance``) | ``calibration/cone_fit.py`` |
| Sec. 3.2, Bayesian: posterior of ``p``, ``v``, ``h`` with outliers | ``posterior.calibration_model``, ``posterior.calibration_log_likelihood``, ``calibrate_cone_posterior``, ``calibrate_cone_posterior_batch`` | ``calibration/posterior.py`` |
| Sec. 3.2: the point estimate against the posterior (the apex is loose along the ray) | ``needs_posterior``, ``choose_calibration`` | ``calibration/posterior.py`` |
"""

from jaxgaze.calibration.cone_fit import (
    DEFAULT_INLIER_THRESHOLD,
    DEFAULT_RANSAC_ITERATIONS,
    DEFAULT_REGULARIZATION,
    MAX_APEX_DISTANCE,
    ConeCalibration,
    calibrate_cone,
    points_in_camera_frame,
)
from jaxgaze.calibration.posterior import (
    MAX_EYE_OFFSET,
    CalibrationChoice,
    CalibrationPosterior,
    calibrate_cone_posterior,
    calibrate_cone_posterior_batch,
    choose_calibration,
    needs_posterior,
)

__all__ = [
    # entry points
    "calibrate_cone",
    "calibrate_cone_posterior",
    "calibrate_cone_posterior_batch",
    "choose_calibration",
    "needs_posterior",
    "points_in_camera_frame",
    # result types
    "ConeCalibration",
    "CalibrationPosterior",
    "CalibrationChoice",
    # options
    "DEFAULT_REGULARIZATION",
    "DEFAULT_INLIER_THRESHOLD",
    "DEFAULT_RANSAC_ITERATIONS",
    "MAX_APEX_DISTANCE",
    "MAX_EYE_OFFSET",
]
