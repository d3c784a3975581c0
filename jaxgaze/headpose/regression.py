"""Gaze direction and target depth from head pose: the two regressors of Yücel et al.

T-CYB 2013 (Sec. V, eq. 6–13) learns two maps from the tracked head pose ``p``
(pitch, yaw, roll and the head position):

* ``f1(p)``: the gaze direction, the image-plane angle of the line from the
  head centre to the attended object (radians, ``atan2(dy, dx)`` in image
  coordinates);
* ``f2(p)``: the target depth, the image row of the attended object (pixels).

Each is a GP with zero prior mean on standardised inputs and outputs (the
paper's "offset", eq. 6): ``f1`` with rational quadratic + arc-sine + white
noise, ``f2`` with linear + white noise (:func:`~jaxgaze.gp.kernels.gaze_direction_kernel`,
:func:`~jaxgaze.gp.kernels.target_depth_kernel`). The neural-network baseline
(CogSci paper) fits the same two maps with :func:`~jaxgaze.headpose.nn.fit_mlp`.

Standardisation uses the training data: inputs per column, outputs by their
mean and standard deviation; predictions are mapped back, variances scaled by
the output variance.

``f2`` is a row of the training images, so a regression keeps their size
(``image_size = (width, height)`` px, ``None`` when unknown); on images of another
size :func:`training_image_scale` gives the factor ``h / h_train`` and
:class:`RescaledRegression` applies it (``f2' = s · f2``, ``var' = s² var``; ``f1``, an
angle, is unchanged). This assumes the same camera at another resolution (the same
field of view), so the focal length in pixels scales by the same factor.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxgaze.gp import FittedGP, fit
from jaxgaze.gp.kernels import gaze_direction_kernel, target_depth_kernel
from jaxgaze.headpose.nn import MLPFit, fit_mlp
from jaxgaze.results import RESULTS, throw_if_failed

__all__ = ["Scaling", "GazePrediction", "GazeRegression", "NNGazeRegression", "RescaledRegression",
           "fit_gaze_regression", "fit_gaze_regression_nn", "check_image_size", "training_image_scale"]


class Scaling(NamedTuple):
    """Affine standardisation ``z = (x − mean) / scale`` (per column for inputs)."""

    mean: Float[Array, "..."]
    scale: Float[Array, "..."]

    @staticmethod
    def of(values) -> "Scaling":
        values = np.asarray(values, dtype=np.float64)
        mean = values.mean(axis=0)
        scale = values.std(axis=0)
        scale = np.where(scale > 1e-12, scale, 1.0)  # a constant column stays as it is
        return Scaling(mean, scale)

    def apply(self, values):
        return (values - self.mean) / self.scale


class GazePrediction(NamedTuple):
    """Predicted ``f1`` (radians) and ``f2`` (px) per frame, with predictive variances.

    The variances are those of a new observation (they include the fitted white
    noise), so ``mean ± 1.645 sd`` is a 90 % predictive interval. The NN
    baseline has no variances (``None``).
    """

    direction: Float[Array, " T"]
    depth: Float[Array, " T"]
    direction_variance: Float[Array, " T"] | None = None
    depth_variance: Float[Array, " T"] | None = None


def _check_training_data(features, direction, depth):
    X = np.asarray(features)
    if X.ndim != 2:
        raise ValueError(f"features must be a 2-D array (frames, features), got shape {X.shape}")
    out = []
    for name, v in (("direction", direction), ("depth", depth)):
        v = np.asarray(v)
        if v.shape != (X.shape[0],):
            raise ValueError(f"{name} must have shape ({X.shape[0]},) to match features, got {v.shape}")
        out.append(v)
    for name, v in (("features", X), ("direction", out[0]), ("depth", out[1])):
        bad = ~np.isfinite(v)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ValueError(f"{name} contains NaN or inf (first at row {row})")
    return X, out[0], out[1]


def check_image_size(image_size, name: str = "image_size") -> tuple[int, int] | None:
    """``None``, or ``(width, height)`` as two positive integers (pixels); ``ValueError`` otherwise."""
    if image_size is None:
        return None
    try:
        width, height = image_size
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be (width, height) in pixels, got {image_size!r}") from None
    for v in (width, height):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be (width, height) as positive integers (pixels), got {image_size!r}")
    return int(width), int(height)


class GazeRegression(NamedTuple):
    """The fitted ``f1`` and ``f2`` GPs, the standardisation they were fitted in, and the size
    ``(width, height)`` (px) of the training images whose rows ``f2`` predicts (``None``: unknown)."""

    direction_gp: FittedGP
    depth_gp: FittedGP
    features: Scaling
    direction_scaling: Scaling
    depth_scaling: Scaling
    image_size: tuple[int, int] | None = None

    @property
    def result(self) -> RESULTS:
        """The :class:`~jaxgaze.results.RESULTS` of the fit: the first failed GP's (``f1`` before ``f2``),
        else ``successful``; :func:`jaxgaze.succeeded` reads it."""
        direction, depth = self.direction_gp.result, self.depth_gp.result
        return RESULTS.where(direction == RESULTS.successful, depth, direction)

    def standardised(self, features):
        X = np.asarray(features)
        if X.ndim != 2 or X.shape[1] != self.features.mean.shape[0]:
            raise ValueError(f"features must have shape (T, {self.features.mean.shape[0]}), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ValueError(f"features contain NaN or inf (first at row {int(np.argwhere(~np.isfinite(X))[0][0])})")
        dtype = self.direction_gp.X.dtype
        return jnp.asarray(self.features.apply(X), dtype)

    def predict(self, features: Float[Array, "T D"]) -> GazePrediction:
        """Predictive means and variances of ``f1`` and ``f2`` at new head poses (Yücel et al. 2013, eq. 12–13)."""
        Z = self.standardised(features)
        m1, v1 = self.direction_gp.predict(Z)
        m2, v2 = self.depth_gp.predict(Z)
        s1, s2 = self.direction_scaling, self.depth_scaling
        return GazePrediction(m1 * s1.scale + s1.mean, m2 * s2.scale + s2.mean, v1 * s1.scale**2, v2 * s2.scale**2)


def fit_gaze_regression(
    features: Float[Array, "T D"],
    direction: Float[Array, " T"],
    depth: Float[Array, " T"],
    *,
    key,
    ard: bool = False,
    progress: bool = False,
    image_size: tuple[int, int] | None = None,
    throw: bool = False,
) -> GazeRegression:
    """Fit the ``f1`` (direction) and ``f2`` (depth) GPs by type-II maximum likelihood (Yücel et al. 2013, Sec. V).

    ``features`` are head poses per frame (e.g. :func:`jaxgaze.headpose.features.head_pose_features`:
    pitch, yaw, roll in radians and the head position in metres); ``direction``
    the image-plane gaze angles (radians) and ``depth`` the target rows (px).
    ``ard`` gives the RQ and arc-sine kernels one lengthscale per feature;
    ``progress`` shows :func:`~jaxgaze.gp.fit`'s progress bar for each GP;
    ``image_size`` the ``(width, height)`` px of the images the rows ``depth`` are in
    (kept on the model, so that :func:`~jaxgaze.vision.attend.attend_frames` scales ``f2`` to
    another video size). The outcome is :attr:`GazeRegression.result` (read it with
    :func:`jaxgaze.succeeded`); ``throw=True`` raises :class:`~jaxgaze.results.FitError` instead,
    carrying the regression (``error.fit``).
    """
    X, f1, f2 = _check_training_data(features, direction, depth)
    size = check_image_size(image_size)
    scaling = Scaling.of(X)
    s1, s2 = Scaling.of(f1), Scaling.of(f2)
    dtype = jnp.asarray(np.zeros(1)).dtype  # float64 under jax_enable_x64, else float32
    Z = jnp.asarray(scaling.apply(X), dtype)
    k1, k2 = jax.random.split(key)
    gp1 = fit(gaze_direction_kernel(X.shape[1], ard=ard), Z, jnp.asarray(s1.apply(f1), dtype), key=k1,
              progress=progress)
    gp2 = fit(target_depth_kernel(X.shape[1], ard=ard), Z, jnp.asarray(s2.apply(f2), dtype), key=k2,
              progress=progress)
    model = GazeRegression(gp1, gp2, scaling, s1, s2, size)
    if throw:
        failed = "f1 (direction)" if gp1.result != RESULTS.successful else "f2 (depth)"
        throw_if_failed(model, model.result, f"fit_gaze_regression: the {failed} GP")
    return model


class NNGazeRegression(NamedTuple):
    """The NN baseline: one :class:`~jaxgaze.headpose.nn.MLPFit` each for ``f1`` and ``f2``, and the
    training images' ``(width, height)`` px (``None``: unknown), as :class:`GazeRegression`."""

    direction_net: MLPFit
    depth_net: MLPFit
    image_size: tuple[int, int] | None = None

    def predict(self, features: Float[Array, "T D"]) -> GazePrediction:
        X = jnp.asarray(features)
        return GazePrediction(self.direction_net.predict(X), self.depth_net.predict(X))


def fit_gaze_regression_nn(features, direction, depth, *, key, image_size=None, **options) -> NNGazeRegression:
    """Fit the NN baseline (Yücel et al. 2009, CogSci): two 10-unit networks (:func:`fit_mlp`).

    Each is trained by online SGD with early stopping; ``image_size`` as :func:`fit_gaze_regression`.
    """
    X, f1, f2 = _check_training_data(features, direction, depth)
    size = check_image_size(image_size)
    dtype = jnp.asarray(np.zeros(1)).dtype
    X = jnp.asarray(X, dtype)
    k1, k2 = jax.random.split(key)
    return NNGazeRegression(
        fit_mlp(X, jnp.asarray(f1, dtype), key=k1, **options), fit_mlp(X, jnp.asarray(f2, dtype), key=k2, **options),
        size,
    )


class RescaledRegression:
    """A fitted regression used on images of another size (Yücel et al. 2013, Sec. V).

    ``f2`` is an image row, so on images ``scale`` times as tall as the training images
    the prediction is ``f2' = scale · f2`` with variance ``scale² var(f2)``; ``f1`` (an
    angle) is unchanged. :meth:`predict` runs in float64 (whatever the global precision),
    so that a GP's Cholesky factor stays positive definite. ``features`` is the input
    standardisation (the identity for the NN baseline, which scales its own inputs);
    ``image_size`` the training size times ``scale`` (rounded), the images it now predicts for.
    """

    def __init__(self, regression, scale: float = 1.0):
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"RescaledRegression: scale must be finite and positive, got {scale}")
        self.regression, self.scale = regression, float(scale)

    @property
    def image_size(self) -> tuple[int, int] | None:
        size = getattr(self.regression, "image_size", None)
        return None if size is None else (round(size[0] * self.scale), round(size[1] * self.scale))

    @property
    def features(self) -> Scaling:
        features = getattr(self.regression, "features", None)
        if features is not None:
            return features
        width = self.regression.direction_net.params.W1.shape[0]
        return Scaling(np.zeros(width), np.ones(width))

    def predict(self, features) -> GazePrediction:
        with jax.enable_x64(True):
            p = self.regression.predict(np.asarray(features, np.float64))
            d, y = np.asarray(p.direction, np.float64), np.asarray(p.depth, np.float64)
            vd = None if p.direction_variance is None else np.asarray(p.direction_variance, np.float64)
            vy = None if p.depth_variance is None else np.asarray(p.depth_variance, np.float64)
        return GazePrediction(d, y * self.scale, vd, None if vy is None else vy * self.scale**2)


def training_image_scale(regression, image_size) -> float:
    """``h / h_train``: the factor from the regression's training images to images of
    ``image_size = (width, height)`` px (rows scale with the image height); 1 when the
    regression does not know its training size (its ``image_size`` is ``None``)."""
    width, height = check_image_size(image_size)
    size = getattr(regression, "image_size", None)
    return 1.0 if size is None else height / size[1]
