"""The Gaussian-process engine (Rasmussen & Williams 2006; used by Yücel et al. 2013, Sec. V): no gaze inside.

* :mod:`jaxgaze.gp.kernels` — covariance functions (equinox modules): RBF,
  rational quadratic, arc-sine (neural network), linear, white noise, constant,
  sums and products; the paper's ``f1``/``f2`` kernels.
* :mod:`jaxgaze.gp.transforms` — the positive-parameter transform.
* :mod:`jaxgaze.gp.exact` — exact GP: log marginal likelihood, prediction
  (eq. 12–13), Type-II maximum-likelihood fit.
* :mod:`jaxgaze.gp.posterior` — NUTS over the hyperparameters, predictions averaged over draws.
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
from jaxgaze.gp.posterior import HyperparameterPosterior, sample_hyperparameter_posterior

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
    "HyperparameterPosterior",
    "sample_hyperparameter_posterior",
]
