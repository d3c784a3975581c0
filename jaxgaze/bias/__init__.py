"""Speaker-prior gaze bias adaptation (Siegfried, Odobez et al. 2017).

* :mod:`jaxgaze.bias.looking`: head-frame gaze angles, offsets to the target, the
  looking-at decision (eq. 1) and the speaker-based frame selection.
* :mod:`jaxgaze.bias.estimators`: the bias from the offsets — mean, LMedS (eq. 2) and
  a Bayesian mixture (numpyro NUTS).
* :mod:`jaxgaze.bias.speech`: speech segments and per-frame speaking flags.

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| Sec. 2–3: gaze angles ``Φ``, target direction ``u_t`` in the head frame | ``gaze_angles_to_direction``, ``direction_to_gaze_angles``, ``target_direction_head`` | ``bias/looking.py`` |
| eq. 1: looking at the target, ``∠(Φ(g + b), u_t) < τ`` | ``angular_error``, ``is_looking_at``, ``looking_probability`` | ``bias/looking.py`` |
| Sec. 3: who speaks when | ``speaking_flags``, ``speaking_at`` | ``bias/speech.py`` |
| Sec. 3.2: Spk frame selection | ``candidate_frames``, ``select_frames`` | ``bias/looking.py`` |
| Sec. 3.2: offsets ``o_i`` of the selected frames | ``gaze_offsets`` | ``bias/looking.py`` |
| eq. 2: LMedS bias | ``lmeds_bias``, ``estimate_bias(..., "lmeds")`` | ``bias/estimators.py`` |
| Sec. 5, Fig. 7: Bayesian mixture bias (NUTS) | ``bias_model``, ``sample_bias_posterior``, ``estimate_bias(..., "bayes")`` | ``bias/estimators.py`` |
| Sec. 3–4: the whole adaptation, arrays in, report out | ``adapt_bias`` | ``bias/adapt.py`` |
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
from jaxgaze.bias.speech import SpeechSegments, choose_partner, speaking_at, speaking_flags
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
)
from jaxgaze.bias.adapt import (
    BIAS_FRAME_COLUMNS,
    DEFAULT_NUM_FRAMES,
    BiasAdaptation,
    BiasInputError,
    adapt_bias,
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
    "choose_partner",
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
    "BIAS_FRAME_COLUMNS",
    "DEFAULT_NUM_FRAMES",
    "BiasAdaptation",
    "BiasInputError",
    "adapt_bias",
]
