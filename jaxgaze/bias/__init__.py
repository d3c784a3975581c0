"""Speaker-prior gaze bias adaptation (Siegfried, Odobez et al. 2017).

* :mod:`jaxgaze.bias.looking`: head-frame gaze angles, offsets to the target, the
  looking-at decision (eq. 1) and the speaker-based frame selection.
* :mod:`jaxgaze.bias.estimators`: the bias from the offsets — mean, LMedS (eq. 2) and
  a Bayesian mixture (numpyro NUTS).
* :mod:`jaxgaze.bias.speech`: speech segments and per-frame speaking flags.
* :mod:`jaxgaze.bias.adapt`: the whole adaptation, arrays in, report out.

This door holds the entry points, result types and options; every other name is
imported from its module (``from jaxgaze.bias.looking import is_looking_at``).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| Sec. 2–3: gaze angles ``Φ``, target direction ``u_t`` in the head frame | ``looking.gaze_angles_to_direction``, ``looking.direction_to_gaze_angles``, ``target_direction_head``, ``head_target_angle`` | ``bias/looking.py`` |
| eq. 1: looking at the target, ``∠(Φ(g + b), u_t) < τ`` | ``looking.angular_error``, ``looking.is_looking_at``, ``looking.looking_probability`` | ``bias/looking.py`` |
| Sec. 3: who speaks when | ``speech.speaking_flags``, ``speaking_at`` | ``bias/speech.py`` |
| Sec. 3.2: Spk frame selection | ``looking.candidate_frames``, ``select_frames`` | ``bias/looking.py`` |
| Sec. 3.2: offsets ``o_i`` of the selected frames | ``gaze_offsets`` | ``bias/looking.py`` |
| eq. 2: LMedS bias | ``estimators.lmeds_bias``, ``estimate_bias(..., "lmeds")`` | ``bias/estimators.py`` |
| Sec. 5, Fig. 7: Bayesian mixture bias (NUTS) | ``estimators.bias_model``, ``estimators.sample_bias_posterior``, ``estimate_bias(..., "bayes")``, ``update_bias`` | ``bias/estimators.py`` |
| Sec. 3–4: the whole adaptation, arrays in, report out | ``adapt_bias`` | ``bias/adapt.py`` |
"""

from jaxgaze.bias.estimators import METHODS, BiasEstimate, estimate_bias, update_bias
from jaxgaze.bias.speech import SpeechSegments, speaking_at
from jaxgaze.bias.looking import FrameSelection, gaze_offsets, head_target_angle, select_frames, target_direction_head
from jaxgaze.bias.adapt import DEFAULT_NUM_FRAMES, BiasAdaptation, BiasInputError, adapt_bias

__all__ = [
    # entry points
    "adapt_bias",
    "estimate_bias",
    "update_bias",
    "speaking_at",
    "target_direction_head",
    "head_target_angle",
    "select_frames",
    "gaze_offsets",
    # result types
    "BiasEstimate",
    "BiasAdaptation",
    "FrameSelection",
    "SpeechSegments",
    "BiasInputError",
    # options
    "METHODS",
    "DEFAULT_NUM_FRAMES",
]
