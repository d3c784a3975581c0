"""Speaker-prior gaze bias adaptation (Siegfried, Odobez et al. 2017).

* :mod:`jaxgaze.bias.looking`: head-frame gaze angles, offsets to the target, the
  looking-at decision (eq. 1) and the speaker-based frame selection.
* :mod:`jaxgaze.bias.estimators`: the bias from the offsets — mean, LMedS (eq. 2) and
  a Bayesian mixture (numpyro NUTS).
* :mod:`jaxgaze.bias.io`: OpenFace 2 CSV files and speaking segments (RTTM, CSV).
* :mod:`jaxgaze.bias.evaluate`: the paper's Table 1, Fig. 5 and Fig. 6 on simulated dyads.
"""

from jaxgaze.bias.estimators import (
    METHODS,
    BiasEstimate,
    bias_model,
    estimate_bias,
    lmeds_bias,
    sample_bias_posterior,
    update_bias,
)
from jaxgaze.bias.evaluate import BiasEvaluation, evaluate_bias_methods, format_figure_tables, format_table1
from jaxgaze.bias.io import (
    OpenFaceFileError,
    OpenFaceTrack,
    SpeechFileError,
    SpeechSegments,
    read_openface,
    read_rttm,
    read_segments_csv,
    speaking_at,
    speaking_flags,
)
from jaxgaze.bias.looking import (
    FrameSelection,
    angular_error,
    candidate_frames,
    direction_to_gaze_angles,
    gaze_angles_to_direction,
    gaze_offsets,
    head_target_angle,
    head_to_world,
    is_looking_at,
    looking_probability,
    select_frames,
    target_direction_head,
    wrap_angle,
)

__all__ = [
    "BiasEvaluation",
    "evaluate_bias_methods",
    "format_table1",
    "format_figure_tables",
    "METHODS",
    "BiasEstimate",
    "bias_model",
    "estimate_bias",
    "lmeds_bias",
    "sample_bias_posterior",
    "update_bias",
    "OpenFaceFileError",
    "OpenFaceTrack",
    "SpeechFileError",
    "SpeechSegments",
    "read_openface",
    "read_rttm",
    "read_segments_csv",
    "speaking_flags",
    "speaking_at",
    "FrameSelection",
    "angular_error",
    "candidate_frames",
    "direction_to_gaze_angles",
    "gaze_angles_to_direction",
    "gaze_offsets",
    "head_target_angle",
    "head_to_world",
    "is_looking_at",
    "looking_probability",
    "select_frames",
    "target_direction_head",
    "wrap_angle",
]
