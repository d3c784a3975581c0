"""Joint inference: one numpyro model of a group recording (Park et al. 2012; Siegfried, Odobez et al. 2017).

Where people look, each person's gaze bias and cone width, who looks at whom and
the shared gaze concurrences, inferred together with calibrated posteriors.

| equation or section | function | file |
|---|---|---|
| Siegfried Sec. 2, Park Sec. 3.1: the recording, frames and units checked | ``joint_data``, ``JointData`` | ``joint/data.py`` |
| Park eq. 3 for directions, Siegfried eq. 1 and Sec. 3.2: the model, the target chain summed out | ``joint_model``, ``marginal_log_likelihood``, ``target_marginals`` | ``joint/model.py`` |
| Siegfried eq. 2, Park Sec. 3.3: the pipeline as the start | ``joint_start``, ``speaker_rule_bias``, ``initial_concurrences`` | ``joint/init.py`` |
| NUTS, SVI, diagnostics, predictive check | ``fit_joint``, ``JointPosterior`` | ``joint/infer.py`` |
| Siegfried eq. 1, Park Sec. 4.1: the pipeline's target rule, the oracle, calibration | ``nearest_target``, ``ray_intersection``, ``expected_calibration_error`` | ``joint/metrics.py`` |
"""

from jaxgaze.joint.data import JointData, joint_data
from jaxgaze.joint.model import (
    BLOCK_FRAMES,
    JointPrior,
    ModelArrays,
    candidate_log_probabilities,
    concurrence_locations,
    marginal_log_likelihood,
    joint_model,
    target_marginals,
)
from jaxgaze.joint.init import (
    DEFAULT_CONCURRENCE_OPTIONS,
    JointStart,
    corrected_rays,
    initial_concurrences,
    joint_start,
    speaker_rule_bias,
)
from jaxgaze.joint.infer import MAX_DIVERGENT_SHARE, MAX_RHAT, METHODS, MIN_ESS, JointPosterior, fit_joint
from jaxgaze.joint.metrics import expected_calibration_error, nearest_target, ray_intersection, reliability_curve

__all__ = [
    "JointData",
    "joint_data",
    "BLOCK_FRAMES",
    "JointPrior",
    "ModelArrays",
    "candidate_log_probabilities",
    "concurrence_locations",
    "marginal_log_likelihood",
    "joint_model",
    "target_marginals",
    "DEFAULT_CONCURRENCE_OPTIONS",
    "JointStart",
    "corrected_rays",
    "initial_concurrences",
    "joint_start",
    "speaker_rule_bias",
    "MAX_DIVERGENT_SHARE",
    "MAX_RHAT",
    "METHODS",
    "MIN_ESS",
    "JointPosterior",
    "fit_joint",
    "expected_calibration_error",
    "nearest_target",
    "ray_intersection",
    "reliability_curve",
]
