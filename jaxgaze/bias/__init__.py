"""Speaker-prior gaze bias adaptation (Siegfried, Odobez et al. 2017).

* :mod:`jaxgaze.bias.looking`: head-frame gaze angles, offsets to the target, the
  looking-at decision (eq. 1) and the speaker-based frame selection.
* :mod:`jaxgaze.bias.estimators`: the bias from the offsets — mean, LMedS (eq. 2) and
  a Bayesian mixture (numpyro NUTS).
* :mod:`jaxgaze.bias.speech`: speech segments and per-frame speaking flags.
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
from jaxgaze.bias.speech import SpeechSegments, speaking_at, speaking_flags
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
    "METHODS",
    "BiasEstimate",
    "bias_model",
    "estimate_bias",
    "lmeds_bias",
    "sample_bias_posterior",
    "update_bias",
    "SpeechSegments",
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
