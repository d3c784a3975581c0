"""jaxgaze: probabilistic models of gaze and joint attention in JAX.

Each model family has a subpackage with one door (its ``__init__``):

| family | paper | subpackage |
|---|---|---|
| gaze rays and cones | Park, Jain & Sheikh 2012, Sec. 3 | :mod:`jaxgaze.rays`, :mod:`jaxgaze.cone` |
| gaze-ray calibration | Park, Jain & Sheikh 2012, Sec. 3.2 | :mod:`jaxgaze.calibration` |
| gaze concurrences | Park, Jain & Sheikh 2012, Sec. 4 | :mod:`jaxgaze.concurrence` |
| speaker-prior gaze bias | Siegfried, Yu & Odobez 2017 | :mod:`jaxgaze.bias` |
| Gaussian-process engine | Rasmussen & Williams 2006 | :mod:`jaxgaze.gp` |
| gaze from head pose | Yücel et al. 2013, Sec. V | :mod:`jaxgaze.headpose` |
| attended object in images | Yücel et al. 2013, Sec. VI–VII | :mod:`jaxgaze.vision` |
| head orientation from facial features | ROVIS, "Human–Robot Interaction Through Robust Gaze Following" | :mod:`jaxgaze.facial` |
| joint inference of a group recording | Park et al. 2012 with Siegfried et al. 2017 | :mod:`jaxgaze.joint` |

Around them: :mod:`jaxgaze.geometry` (frames, rotations, angles), :mod:`jaxgaze.poses`
(camera trajectories), :mod:`jaxgaze.simulate` (every simulator), :mod:`jaxgaze.io`
(every file format), :mod:`jaxgaze.papers` (each paper's table), :mod:`jaxgaze.plotting`
and the command line :mod:`jaxgaze.cli`.

Frames and units are documented in ``docs/conventions.md``: world/head/camera
frames, metres, radians inside (degrees only in names ending ``_deg``).
``import jaxgaze`` loads neither OpenCV nor the simulators: :mod:`jaxgaze.vision`,
:mod:`jaxgaze.facial`, :mod:`jaxgaze.simulate`, :mod:`jaxgaze.io`,
:mod:`jaxgaze.papers` and :mod:`jaxgaze.plotting` load on first use. ``import jaxgaze``
turns on JAX's persistent compilation cache (:func:`jaxgaze.runtime.enable_default_compilation_cache`;
``JAXGAZE_CACHE_DIR=off`` switches it off).
"""

import importlib

from jaxgaze import bias, calibration, concurrence, cone, geometry, gp, headpose, joint, poses, rays, results, runtime
from jaxgaze.runtime import enable_compilation_cache
from jaxgaze.rays import GazeRays
from jaxgaze.results import RESULTS, FitError, succeeded
from jaxgaze.cone import (
    LookingAtEachOther,
    cone_log_density,
    looking_at_each_other,
    max_intensity_projection,
    ray_kernels,
    saliency_field,
    saliency_field_grid,
    sample_gaze_directions,
    sample_points_of_regard,
)
from jaxgaze.calibration import (
    CalibrationPosterior,
    ConeCalibration,
    calibrate_cone,
    calibrate_cone_posterior,
    calibrate_cone_posterior_batch,
)
from jaxgaze.concurrence import (
    ConcurrenceEnsemble,
    ConcurrenceOptions,
    Concurrences,
    MeanShiftResult,
    Tracks,
    find_concurrences,
    find_concurrences_over_frames,
    meanshift,
    propagate_to_concurrences,
    track_concurrences,
    ConcurrenceStream,
)
from jaxgaze.bias import BiasEstimate, estimate_bias, select_frames, update_bias
from jaxgaze.bias.looking import is_looking_at, looking_probability
from jaxgaze.bias.speech import speaking_flags
from jaxgaze.headpose import GazeRegression, fit_gaze_regression, fit_gaze_regression_nn
from jaxgaze.joint import JointPosterior, fit_joint, joint_data

# JAX's persistent compilation cache, so that a second process compiles nothing (docs/runtime.md):
# in ~/.cache/jaxgaze/xla or $JAXGAZE_CACHE_DIR; JAXGAZE_CACHE_DIR=off, or a JAX cache of your own, leaves it off.
runtime.enable_default_compilation_cache()

__version__ = "0.1.0"

_ON_FIRST_USE = ("vision", "facial", "simulate", "io", "papers", "plotting", "cli")


def __getattr__(name):
    """Load the subpackages that need OpenCV or hold simulators only when they are used."""
    if name in _ON_FIRST_USE:
        return importlib.import_module(f"jaxgaze.{name}")
    raise AttributeError(f"module 'jaxgaze' has no attribute {name!r}")


__all__ = [
    # ground floor
    "geometry",
    "rays",
    "cone",
    "poses",
    "GazeRays",
    "cone_log_density",
    "sample_gaze_directions",
    "sample_points_of_regard",
    "ray_kernels",
    "saliency_field",
    "saliency_field_grid",
    "max_intensity_projection",
    "looking_at_each_other",
    "LookingAtEachOther",
    # runtime: the persistent compilation cache
    "runtime",
    "enable_compilation_cache",
    # result codes of every fit
    "results",
    "RESULTS",
    "FitError",
    "succeeded",
    # calibration
    "calibration",
    "calibrate_cone",
    "ConeCalibration",
    "calibrate_cone_posterior",
    "calibrate_cone_posterior_batch",
    "CalibrationPosterior",
    # concurrences
    "concurrence",
    "meanshift",
    "MeanShiftResult",
    "find_concurrences",
    "find_concurrences_over_frames",
    "ConcurrenceOptions",
    "Concurrences",
    "track_concurrences",
    "ConcurrenceStream",
    "Tracks",
    "propagate_to_concurrences",
    "ConcurrenceEnsemble",
    # speaker-prior bias
    "bias",
    "speaking_flags",
    "select_frames",
    "is_looking_at",
    "looking_probability",
    "BiasEstimate",
    "estimate_bias",
    "update_bias",
    # joint inference
    "joint",
    "joint_data",
    "fit_joint",
    "JointPosterior",
    # gaze from head pose
    "gp",
    "headpose",
    "GazeRegression",
    "fit_gaze_regression",
    "fit_gaze_regression_nn",
]
