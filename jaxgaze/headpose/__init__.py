"""Gaze direction and target depth from head pose (Yücel et al. 2013, Sec. V).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| T-CYB Sec. V: the input, the tracked head pose | ``head_pose_features`` | ``headpose/features.py`` |
| T-CYB Sec. V, eq. 6–13: the ``f1`` (direction) and ``f2`` (depth) GPs | ``fit_gaze_regression``, ``GazeRegression.predict`` | ``headpose/regression.py`` |
| T-CYB Sec. VII, CogSci: the neural-network baseline | ``fit_mlp``; ``fit_gaze_regression_nn`` | ``headpose/nn.py``; ``headpose/regression.py`` |
| T-CYB Sec. VI, Fig. 9: the target point | ``target_point``, ``reaches_row`` | ``headpose/target.py`` |
| T-CYB Sec. VI: pooling over windows | ``pool``, ``pool_labels`` | ``headpose/target.py`` |
| T-CYB eq. 14: ``Q1`` | ``q1`` | ``headpose/target.py`` |
| T-CYB eq. 15: ``Q2`` | ``q2`` | ``headpose/target.py`` |
| CogSci Q1, Q2 and Fig. 5 (CMC) | ``mean_angular_deviation``, ``cone_rates``, ``disk_rates``, ``cmc_curve`` | ``headpose/target.py`` |
| self- and cross-referencing splits | ``self_referencing_splits``, ``cross_referencing_splits`` | ``headpose/target.py`` |
"""

from jaxgaze.headpose.features import head_pose_features
from jaxgaze.headpose.regression import (
    Scaling,
    GazePrediction,
    GazeRegression,
    NNGazeRegression,
    RescaledRegression,
    fit_gaze_regression,
    fit_gaze_regression_nn,
)
from jaxgaze.headpose.nn import (
    MLPParams,
    Standardisation,
    MLPFit,
    init_mlp_params,
    mlp_forward,
    learning_rate_schedule,
    online_epoch,
    fit_mlp,
    min_points_for_split,
)
from jaxgaze.headpose.target import (
    TOLERANCE,
    MASK_RADIUS_PX,
    MAX_LENGTH_PX,
    Pooled,
    PooledLabels,
    TargetRates,
    target_point,
    reaches_row,
    pool,
    pool_labels,
    q1,
    q2,
    angular_errors,
    mean_angular_deviation,
    cone_hits_box,
    disk_hits_box,
    cone_rates,
    disk_rates,
    cmc_curve,
    self_referencing_splits,
    cross_referencing_splits,
)

__all__ = [
    "head_pose_features",
    "Scaling",
    "GazePrediction",
    "GazeRegression",
    "NNGazeRegression",
    "RescaledRegression",
    "fit_gaze_regression",
    "fit_gaze_regression_nn",
    "MLPParams",
    "Standardisation",
    "MLPFit",
    "init_mlp_params",
    "mlp_forward",
    "learning_rate_schedule",
    "online_epoch",
    "fit_mlp",
    "min_points_for_split",
    "TOLERANCE",
    "MASK_RADIUS_PX",
    "MAX_LENGTH_PX",
    "Pooled",
    "PooledLabels",
    "TargetRates",
    "target_point",
    "reaches_row",
    "pool",
    "pool_labels",
    "q1",
    "q2",
    "angular_errors",
    "mean_angular_deviation",
    "cone_hits_box",
    "disk_hits_box",
    "cone_rates",
    "disk_rates",
    "cmc_curve",
    "self_referencing_splits",
    "cross_referencing_splits",
]
