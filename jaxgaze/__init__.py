"""jaxgaze: probabilistic models of gaze and joint attention in JAX.

Frames and units are documented in ``docs/conventions.md``: world/head/camera
frames, metres, radians inside (degrees only in names ending ``_deg``).
"""

from jaxgaze import bias, facial, geometry, gp, metrics, poses, simulate, simulate_calibration, simulate_dyadic, simulate_tabletop, vision
from jaxgaze.bias import (
    BiasEstimate,
    estimate_bias,
    is_looking_at,
    looking_probability,
    read_openface,
    read_rttm,
    read_segments_csv,
    select_frames,
    speaking_flags,
    update_bias,
)
from jaxgaze.calibration import CalibrationResult, ConeCalibration, calibrate_cone
from jaxgaze.gp import GazeRegression, fit_gaze_regression, fit_gaze_regression_nn
from jaxgaze.calibration_posterior import (
    CalibrationPosterior,
    ConcurrenceEnsemble,
    calibrate_cone_posterior,
    calibrate_cone_posterior_batch,
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
from jaxgaze.vision import attend_frames, detect_faces, track_head

__version__ = "0.1.0"

__all__ = [
    "facial",
    "vision",
    "attend_frames",
    "detect_faces",
    "track_head",
    "bias",
    "gp",
    "simulate_tabletop",
    "GazeRegression",
    "fit_gaze_regression",
    "fit_gaze_regression_nn",
    "simulate_dyadic",
    "BiasEstimate",
    "estimate_bias",
    "update_bias",
    "is_looking_at",
    "looking_probability",
    "select_frames",
    "read_openface",
    "read_rttm",
    "read_segments_csv",
    "speaking_flags",
    "calibrate_cone_posterior_batch",
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
