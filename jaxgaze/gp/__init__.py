"""The Gaussian-process engine (Rasmussen & Williams 2006; used by Yücel et al. 2013, Sec. V): no gaze inside.

* :mod:`jaxgaze.gp.kernels` — covariance functions (equinox modules): RBF,
  rational quadratic, arc-sine (neural network), linear, white noise, constant,
  sums and products; the paper's ``f1``/``f2`` kernels.
* :mod:`jaxgaze.gp.transforms` — the positive-parameter transform.
* :mod:`jaxgaze.gp.exact` — exact GP: log marginal likelihood, prediction
  (eq. 12–13) and the fitted GP; its linear algebra (Cholesky, ``K⁻¹``, the LML's
  custom JVP) is ``gp/_linalg.py``.
* :func:`fit` (``gp/_fit.py``) — the Type-II maximum-likelihood fit.
* :mod:`jaxgaze.gp.posterior` — NUTS over the hyperparameters, predictions averaged over draws.

This door holds the entry points, their results and the kernels one composes with ``+``
and ``*`` (``RBF() + White()``); everything else is imported from its module
(``from jaxgaze.gp.kernels import Sum``, ``from jaxgaze.gp.transforms import positive``).

Where each equation and section lives:

| equation or section | function | file |
|---|---|---|
| Yücel et al. eq. 5–7: the ``f1`` kernel (RQ + arc-sine + white) | ``gaze_direction_kernel`` | ``gp/kernels.py`` |
| Yücel et al. Sec. V: the ``f2`` kernel | ``target_depth_kernel`` | ``gp/kernels.py`` |
| Rasmussen & Williams eq. 4.19: rational quadratic | ``RationalQuadratic`` | ``gp/kernels.py`` |
| Yücel et al. eq. 7: white noise ``σ0²`` | ``White`` | ``gp/kernels.py`` |
| Rasmussen & Williams eq. 2.30: log marginal likelihood | ``log_marginal_likelihood`` | ``gp/exact.py`` (linear algebra: ``gp/_linalg.py``) |
| Rasmussen & Williams eq. 5.9: its gradient, ``½ tr((ααᵀ − K⁻¹) ∂K)`` | ``gaussian_log_marginal_likelihood`` (custom JVP) | ``gp/_linalg.py`` |
| Yücel et al. eq. 12–13: predictive mean and variance | ``predict`` | ``gp/exact.py`` |
| Yücel et al. after eq. 13: type-II maximum likelihood | ``fit`` | ``gp/_fit.py`` |
| Rasmussen & Williams Sec. 5.4.1: Fisher scoring (Fisher information of the LML) | ``_fisher_estimate``, ``_FisherScoring`` | ``gp/_fit.py`` |
| Yücel et al. eq. 11 with a prior: posterior of the hyperparameters | ``hyperparameter_model``, ``sample_hyperparameter_posterior`` | ``gp/posterior.py`` |
| positive parameters, ``exp(raw) + floor`` | ``positive``, ``unconstrain_positive``, ``bound_penalty`` | ``gp/transforms.py`` |
"""

from jaxgaze.gp._fit import fit
from jaxgaze.gp.exact import FittedGP, log_marginal_likelihood, predict
from jaxgaze.gp.kernels import (
    RBF,
    ArcSine,
    Constant,
    Kernel,
    Linear,
    RationalQuadratic,
    White,
    gaze_direction_kernel,
    target_depth_kernel,
)
from jaxgaze.gp.posterior import HyperparameterPosterior, sample_hyperparameter_posterior

__all__ = [
    "fit",
    "FittedGP",
    "log_marginal_likelihood",
    "predict",
    "sample_hyperparameter_posterior",
    "HyperparameterPosterior",
    "Kernel",
    "Constant",
    "RBF",
    "RationalQuadratic",
    "ArcSine",
    "Linear",
    "White",
    "gaze_direction_kernel",
    "target_depth_kernel",
]
