"""Gaze direction and target depth from head pose (Yücel et al. 2013, Sec. V).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| T-CYB Sec. V: the input, the tracked head pose | ``head_pose_features`` | ``headpose/features.py`` |
| T-CYB Sec. V, eq. 6–13: the ``f1`` (direction) and ``f2`` (depth) GPs | ``fit_gaze_regression``, ``GazeRegression.predict`` | ``headpose/regression.py`` |
| T-CYB Sec. VII, CogSci: the neural-network baseline | ``nn.fit_mlp``; ``fit_gaze_regression_nn`` | ``headpose/nn.py``; ``headpose/regression.py`` |
| T-CYB Sec. VI, Fig. 9: the target point | ``target_point``, ``target.reaches_row`` | ``headpose/target.py`` |
| T-CYB Sec. VI: pooling over windows | ``pool``, ``target.pool_labels`` | ``headpose/target.py`` |
| T-CYB eq. 14: ``Q1`` | ``q1`` | ``headpose/target.py`` |
| T-CYB eq. 15: ``Q2`` | ``q2`` | ``headpose/target.py`` |
| CogSci Q1, Q2 and Fig. 5 (CMC) | ``target.mean_angular_deviation``, ``target.cone_rates``, ``target.disk_rates``, ``cmc_curve`` | ``headpose/target.py`` |
| self- and cross-referencing splits | ``self_referencing_splits``, ``cross_referencing_splits`` | ``headpose/target.py`` |

The door holds the entry points, their result types and options; the rest (the network's
training steps, hit tests, rates) is in its module: :mod:`jaxgaze.headpose.nn`,
:mod:`jaxgaze.headpose.regression`, :mod:`jaxgaze.headpose.target`.
"""

from jaxgaze.headpose.features import head_pose_features
from jaxgaze.headpose.regression import (
    GazePrediction,
    GazeRegression,
    NNGazeRegression,
    fit_gaze_regression,
    fit_gaze_regression_nn,
)
from jaxgaze.headpose.target import (
    TOLERANCE,
    Pooled,
    cmc_curve,
    cross_referencing_splits,
    pool,
    q1,
    q2,
    self_referencing_splits,
    target_point,
)

__all__ = [
    # entry points
    "head_pose_features",
    "fit_gaze_regression",
    "fit_gaze_regression_nn",
    "target_point",
    "pool",
    "q1",
    "q2",
    "cmc_curve",
    "self_referencing_splits",
    "cross_referencing_splits",
    # result types
    "GazeRegression",
    "NNGazeRegression",
    "GazePrediction",
    "Pooled",
    # options
    "TOLERANCE",
]
