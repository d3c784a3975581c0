"""Gaussian-process regression of gaze from head pose (Yücel et al. T-CYB 2013, Sec. V).

* :mod:`jaxgaze.gp.kernels` — covariance functions (equinox modules): RBF,
  rational quadratic, arc-sine (neural network), linear, white noise, constant,
  sums and products; the paper's ``f1``/``f2`` kernels.
* :mod:`jaxgaze.gp.transforms` — the positive-parameter transform.
* :mod:`jaxgaze.gp.exact` — exact GP: log marginal likelihood, prediction
  (eq. 12–13), Type-II maximum-likelihood fit.
* :mod:`jaxgaze.gp.posterior` — NUTS over the hyperparameters, predictions averaged over draws.
* :mod:`jaxgaze.gp.nn` — the CogSci neural-network baseline (online SGD, early stopping).
* :mod:`jaxgaze.gp.regression` — ``f1`` (gaze direction) and ``f2`` (target depth) from head pose.
* :mod:`jaxgaze.gp.target` — target points, pooling, Q1/Q2 (T-CYB eq. 14–15, CogSci), CMC, splits.
* :mod:`jaxgaze.gp.evaluate` — Table I and the CogSci table on simulated sessions.
* :mod:`jaxgaze.gp.io` — fitted regressions to and from JSON model files (``gp.json``).
"""

from jaxgaze.gp.exact import (
    DEFAULT_RELATIVE_JITTER,
    FitResult,
    FittedGP,
    fit,
    log_marginal_likelihood,
    predict,
)
from jaxgaze.gp.kernels import (
    RBF,
    ArcSine,
    Constant,
    Kernel,
    Linear,
    Product,
    RationalQuadratic,
    Sum,
    White,
    gaze_direction_kernel,
    target_depth_kernel,
)
from jaxgaze.gp.transforms import POSITIVE_FLOOR, positive, unconstrain_positive
from jaxgaze.gp.nn import MLPFit, fit_mlp
from jaxgaze.gp.posterior import HyperparameterPosterior, sample_hyperparameter_posterior
from jaxgaze.gp.regression import (
    GazePrediction,
    GazeRegression,
    NNGazeRegression,
    fit_gaze_regression,
    fit_gaze_regression_nn,
)
from jaxgaze.gp.target import (
    TOLERANCE,
    cmc_curve,
    cross_referencing_splits,
    pool,
    q1,
    q2,
    self_referencing_splits,
    target_point,
)
from jaxgaze.gp.evaluate import RegressionScores, evaluate_regression, evaluate_split
from jaxgaze.gp.io import ModelFileError, load_gaze_regression, save_gaze_regression

__all__ = [
    "Kernel",
    "Sum",
    "Product",
    "Constant",
    "RBF",
    "RationalQuadratic",
    "ArcSine",
    "Linear",
    "White",
    "gaze_direction_kernel",
    "target_depth_kernel",
    "POSITIVE_FLOOR",
    "positive",
    "unconstrain_positive",
    "DEFAULT_RELATIVE_JITTER",
    "FitResult",
    "FittedGP",
    "fit",
    "log_marginal_likelihood",
    "predict",
    "MLPFit",
    "fit_mlp",
    "HyperparameterPosterior",
    "sample_hyperparameter_posterior",
    "GazePrediction",
    "GazeRegression",
    "NNGazeRegression",
    "fit_gaze_regression",
    "fit_gaze_regression_nn",
    "TOLERANCE",
    "target_point",
    "pool",
    "q1",
    "q2",
    "cmc_curve",
    "self_referencing_splits",
    "cross_referencing_splits",
    "RegressionScores",
    "evaluate_regression",
    "evaluate_split",
    "ModelFileError",
    "load_gaze_regression",
    "save_gaze_regression",
]
