"""jaxgaze: probabilistic models of gaze and joint attention in JAX.

Frames and units are documented in ``docs/conventions.md``: world/head/camera
frames, metres, radians inside (degrees only in names ending ``_deg``).
"""

from jaxgaze import geometry, metrics, poses, simulate, simulate_calibration
from jaxgaze.calibration import CalibrationResult, ConeCalibration, calibrate_cone
from jaxgaze.calibration_posterior import (
    CalibrationPosterior,
    ConcurrenceEnsemble,
    calibrate_cone_posterior,
    propagate_to_concurrences,
)
from jaxgaze.concurrence import (
    Concurrences,
    MeanShiftResult,
    Tracks,
    find_concurrences,
    find_concurrences_over_frames,
    meanshift,
    track_concurrences,
)
from jaxgaze.cone import (
    cone_log_density,
    max_intensity_projection,
    ray_kernels,
    saliency_field,
    saliency_field_grid,
    sample_gaze_directions,
    sample_points_of_regard,
)
from jaxgaze.rays import GazeRays

__version__ = "0.1.0"

__all__ = [
    "geometry",
    "metrics",
    "simulate",
    "simulate_calibration",
    "poses",
    "calibrate_cone",
    "ConeCalibration",
    "CalibrationResult",
    "calibrate_cone_posterior",
    "CalibrationPosterior",
    "propagate_to_concurrences",
    "ConcurrenceEnsemble",
    "GazeRays",
    "cone_log_density",
    "sample_gaze_directions",
    "sample_points_of_regard",
    "ray_kernels",
    "saliency_field",
    "saliency_field_grid",
    "max_intensity_projection",
    "meanshift",
    "MeanShiftResult",
    "find_concurrences",
    "find_concurrences_over_frames",
    "Concurrences",
    "track_concurrences",
    "Tracks",
]
