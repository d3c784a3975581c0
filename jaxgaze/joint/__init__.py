"""Joint inference: one numpyro model of a group recording (Park et al. 2012; Siegfried, Odobez et al. 2017).

Where people look, each person's gaze bias and cone width, who looks at whom and
the shared gaze concurrences, inferred together with calibrated posteriors.

This door holds the entry points, result types and options; every other name is imported
from its module (``from jaxgaze.joint.model import joint_model``).

| equation or section | function | file |
|---|---|---|
| Siegfried Sec. 2, Park Sec. 3.1: the recording, frames and units checked | ``joint_data``, ``JointData`` | ``joint/data.py`` |
| Park eq. 3 for directions, Siegfried eq. 1 and Sec. 3.2: the model, the target chain summed out | ``model.joint_model``, ``model.marginal_log_likelihood``, ``target_marginals`` | ``joint/model.py`` |
| Rabiner 1989, eq. 24–25 in adjoint form: the gradient of the chain's forward pass, written out | ``model._log_normalisers`` | ``joint/model.py`` |
| Siegfried et al. 2017, Sec. 2–3: the measured angles' density, the cone's on the sphere times the area element ``abs(cos(θ + b_θ))`` of ``Φ`` | ``model.measured_gaze_log_jacobian`` | ``joint/model.py`` |
| Park eq. 3 with a fixation's spot (issue 37): the residuals of one fixation share an offset ``N(0, c h²)``; a glance elsewhere held scatters by the rest, ``e_t + e_{t−1}``, ``e = w² − c h²`` | ``model._held_spot``, ``model._held_elsewhere``, ``JointPrior.held_scale``, ``model.held_cone_share`` | ``joint/model.py`` |
| Kass & Raftery 1995, eq. 1: the spot kept where its Bayes factor exceeds 3 | ``infer._choose_spot``, ``infer._spot_log_bayes_factor`` | ``joint/infer.py`` |
| Stiefelhagen & Zhu 2002, Ba & Odobez 2009, Yücel et al. 2013 (linear): head pose only, ``κ (gaze − rest) = head + τ ḣ − rest`` | ``model.head_gaze_angles``, ``model.head_log_jacobian``, ``joint_data(…, gaze_angles=None)`` | ``joint/model.py``, ``joint/data.py`` |
| Head pose only: the gaze's scatter ``r`` times as wide in tilt as in yaw (a change of variable, ``−log r`` a frame) | ``model._head_only_terms``, ``model._jacobian``, ``JointPrior.tilt_width_ratio_log_sd``; the start's ``r``: ``init.tilt_width_profile`` | ``joint/model.py``, ``joint/init.py`` |
| Yücel et al. 2013, Sec. V; Solin & Särkkä 2020, eq. 56: the head-to-gaze map as a reduced-rank GP, kept where its Bayes factor against the linear map exceeds 3 | ``model.coupling_shape``, ``JointPrior.coupling_shape_scale``, ``infer._choose_shape`` | ``joint/model.py``, ``joint/infer.py`` |
| Chandler & Bate 2007, Sec. 3; Newey & West 1987, eq. 2: head pose only, the couplings' draws widened to the sandwich variance of the frames' scores | ``infer._coupling_widening``, ``model.frame_log_likelihood`` | ``joint/infer.py``, ``joint/model.py`` |
| Siegfried eq. 2, Park Sec. 3.3: the pipeline as the start | ``joint_start``, ``init.speaker_rule_bias``, ``init.initial_concurrences`` | ``joint/init.py`` |
| Siegfried eq. 1, Park eq. 3: every person's rival bias modes before sampling, Laplace evidence, ``ambiguous`` | ``rivals.bias_profile``, ``rivals.profile_rivals``, ``rivals.Alternative`` | ``joint/rivals.py`` |
| MacKay 2003, eq. 28.10: the concurrences the data do not need dropped by Laplace evidence, after the start and again where the rival search moved someone | ``infer._prune_concurrences``, ``infer._prune_after_the_search`` | ``joint/infer.py`` |
| Head pose only: rival ``(κ, bias)`` modes, a coupling moved with the rest direction kept | ``rivals.coupling_trial``, ``rivals.coupling_rivals`` | ``joint/rivals.py`` |
| Nocedal & Wright 2006, eq. 6.20 and Sec. 3.3, 11.1: BFGS in a Laplace metric (run again where its line search stalled), chord and Newton's steps to the chosen mode, the Laplace Hessian as NUTS's mass matrix | ``infer._descend``, ``infer._polish_mode``, ``infer._descent_steps``, ``nuts.laplace_parts`` | ``joint/infer.py``, ``nuts.py`` |
| NUTS, SVI, diagnostics, predictive check | ``fit_joint``, ``JointPosterior``, ``infer.SVIDiagnostics`` | ``joint/infer.py`` |
| Siegfried eq. 1, Park Sec. 4.1: the pipeline's target rule, the oracle, calibration | ``nearest_target``, ``ray_intersection``, ``expected_calibration_error`` | ``joint/metrics.py`` |
"""

from jaxgaze.joint.data import JointData, joint_data
from jaxgaze.joint.model import BLOCK_FRAMES, JointPrior, target_marginals
from jaxgaze.joint.init import JointStart, joint_start
from jaxgaze.joint.infer import METHODS, JointPosterior, fit_joint
from jaxgaze.joint.metrics import expected_calibration_error, nearest_target, ray_intersection, reliability_curve

__all__ = [
    # entry points
    "joint_data",
    "joint_start",
    "fit_joint",
    "target_marginals",
    "nearest_target",
    "ray_intersection",
    "expected_calibration_error",
    "reliability_curve",
    # result types
    "JointData",
    "JointStart",
    "JointPosterior",
    # options
    "JointPrior",
    "METHODS",
    "BLOCK_FRAMES",
]
