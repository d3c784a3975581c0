"""Covariance functions for Gaussian-process regression (tinygp style).

A kernel is an ``equinox.Module`` (so a pytree, usable under ``jit``/``grad``)
with one abstract method, ``evaluate(x1, x2)``, the covariance of two single
input vectors of shape ``(D,)``. Everything else is derived from it:

* ``kernel(X1, X2)`` is the ``(n1, n2)`` matrix, a double ``jax.vmap`` of
  ``evaluate``;
* ``kernel(X)`` (``X2=None``) means "the covariance of the set ``X`` with
  itself": the same matrix plus the *independent-noise diagonal*
  ``diag(evaluate_noise(x_i))``;
* ``kernel.diag(X)`` is the ``(n,)`` diagonal of ``kernel(X)``.

**Independent noise (White).** :class:`White` is σ² on the diagonal of
``k(X, X)`` and nothing else: ``White.evaluate`` is 0 and its
``evaluate_noise`` is σ². So ``White(X)`` is σ² I, ``White(X1, X2)`` is 0 for
any second argument (even ``X2 is X1``, as in scikit-learn's ``WhiteKernel``
whenever ``Y`` is passed) and ``White.diag(X)`` is σ². A GP's prior covariance
of noisy observations is ``kernel(X)`` and the cross-covariance to new inputs is
``kernel(X, X_new)``, so the predictive variance ``kernel.diag(X_new) − …``
contains the noise exactly as scikit-learn's ``predict(return_std=True)`` does.
Sums add the noise diagonals; a product's noise diagonal is
``∏(k_i(x,x) + n_i(x)) − ∏ k_i(x,x)`` (the diagonal of the elementwise product).

**Parameters.** Positive parameters are stored unconstrained (``raw_*`` fields)
and mapped through :mod:`jaxgaze.gp.transforms` (``value = exp(raw) + 1e-12``).
Constructors take natural values and properties return natural values. A
non-positive or NaN value raises ``ValueError`` naming kernel and parameter.
``fixed=("variance",)`` marks parameters that :func:`jaxgaze.gp.fit` leaves
alone (see :meth:`Kernel.trainable_filter`).

**ARD.** ``lengthscale`` (RBF, RationalQuadratic), ``weight_variance``
(ArcSine) and ``variance`` (Linear) may be scalars or ``(D,)`` vectors.

``a + b`` and ``a * b`` build :class:`Sum` and :class:`Product`; a positive
number on either side becomes a :class:`Constant` kernel (trainable, like
scikit-learn's ``ConstantKernel``), so ``2.0 * k`` scales ``k`` by 2.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxgaze.gp.transforms import positive, unconstrain_positive

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
    "DataStats",
    "data_stats",
]


class DataStats(NamedTuple):
    """Summaries of the training data ``(X, y)`` that seed the kernels' hyperparameters (data-driven initialisation)."""

    y_var: float
    y_mean_sq: float
    #: median Euclidean distance between pairs of inputs.
    dist_median: float
    #: per-feature median absolute difference between pairs of inputs, (D,).
    dist_median_per_feature: np.ndarray
    #: mean of ‖x‖².
    x_norm_sq: float
    #: per-feature mean of x_d², (D,).
    x_sq_per_feature: np.ndarray


def data_stats(X: np.ndarray, y: np.ndarray) -> DataStats:
    """The :class:`DataStats` of training data ``X (n, D)``, ``y (n,)`` (NumPy, on the host)."""
    n, d = X.shape
    iu = np.triu_indices(n, k=1)
    diff = np.abs(X[:, None, :] - X[None, :, :])[iu]  # (pairs, D)
    dist = np.sqrt(np.sum(diff**2, axis=1))
    med = float(np.median(dist)) if dist.size else 1.0
    scale = med if med > 0 else 1.0
    med_d = np.median(diff, axis=0) if dist.size else np.ones(d)
    med_d = np.where(med_d > 0, med_d, scale / math.sqrt(d)) * math.sqrt(d)
    y_var = float(np.var(y))
    y_var = y_var if y_var > 0 else max(float(np.mean(y**2)), 1.0)
    return DataStats(
        y_var=y_var,
        y_mean_sq=float(np.mean(y) ** 2),
        dist_median=scale,
        dist_median_per_feature=med_d,
        x_norm_sq=float(np.mean(np.sum(X**2, axis=1))),
        x_sq_per_feature=np.mean(X**2, axis=0),
    )


class Kernel(eqx.Module):
    """Base class: subclasses implement :meth:`evaluate` for single inputs."""

    @abc.abstractmethod
    def evaluate(self, x1: Float[Array, " D"], x2: Float[Array, " D"]) -> Float[Array, ""]:
        """Covariance of two single inputs (without the independent-noise term)."""

    def evaluate_noise(self, x: Float[Array, " D"]) -> Float[Array, ""]:
        """Independent-noise variance at ``x``, added on the diagonal of ``k(X)`` only. 0 here."""
        return jnp.zeros((), jnp.result_type(x, float))

    # -- structure ---------------------------------------------------------------

    @property
    def has_noise(self) -> bool:
        """Whether :meth:`evaluate_noise` can be non-zero (a :class:`White` term is inside)."""
        return False

    @property
    def is_noise_only(self) -> bool:
        """Whether the kernel is zero off the diagonal (pure independent noise)."""
        return False

    # -- matrices ----------------------------------------------------------------

    def __call__(
        self, X1: Float[Array, "n1 D"], X2: Float[Array, "n2 D"] | None = None
    ) -> Float[Array, "n1 n2"]:
        """Covariance matrix. ``X2=None`` means ``X1`` with itself, noise diagonal included."""
        same = X2 is None
        K = self._cross(X1, X1 if same else X2)
        if same and self.has_noise:
            noise = jax.vmap(self.evaluate_noise)(X1)
            K = K + jnp.diag(noise.astype(K.dtype))
        return K

    def _cross(self, X1: Float[Array, "n1 D"], X2: Float[Array, "n2 D"]) -> Float[Array, "n1 n2"]:
        """``[evaluate(x1_i, x2_j)]``: a double ``vmap``. Built-in kernels override it with
        algebraically identical vectorised code (tested against the ``vmap``), because
        XLA:CPU reduces the ``(n1, n2, D)`` differences of a ``vmap`` slowly."""
        return jax.vmap(lambda a: jax.vmap(lambda b: self.evaluate(a, b))(X2))(X1)

    def diag(self, X: Float[Array, "n D"]) -> Float[Array, " n"]:
        """Diagonal of ``self(X)`` (noise included), without forming the matrix."""
        d = jax.vmap(lambda x: self.evaluate(x, x))(X)
        if self.has_noise:
            d = d + jax.vmap(self.evaluate_noise)(X).astype(d.dtype)
        return d

    # -- algebra -----------------------------------------------------------------

    def __add__(self, other):
        other = _as_kernel(other, "+")
        if other is NotImplemented:
            return NotImplemented
        return Sum(self, other)

    def __radd__(self, other):
        other = _as_kernel(other, "+")
        if other is NotImplemented:
            return NotImplemented
        return Sum(other, self)

    def __mul__(self, other):
        other = _as_kernel(other, "*")
        if other is NotImplemented:
            return NotImplemented
        return Product(self, other)

    def __rmul__(self, other):
        other = _as_kernel(other, "*")
        if other is NotImplemented:
            return NotImplemented
        return Product(other, self)

    # -- parameters --------------------------------------------------------------

    def hyperparameters(self) -> dict[str, Array]:
        """Natural parameter values by name (``"1.Linear.variance"`` inside sums/products)."""
        return {}

    def trainable_filter(self):
        """Pytree of bools shaped like the kernel: True for leaves :func:`fit` optimises.

        For ``eqx.partition(kernel, kernel.trainable_filter())``. Fixed parameters
        (``fixed=...`` at construction) are False.
        """
        return jax.tree.map(lambda _: False, self)

    def check_input_dim(self, num_features: int) -> None:
        """Raise ``ValueError`` if a vector (ARD) parameter's length is not ``num_features``."""

    def _initialise(self, stats: DataStats, variance: float) -> Kernel:
        """Copy with data-driven values; ``variance`` is this term's share of var(y)."""
        return self


_HIGHEST = jax.lax.Precision.HIGHEST


def _squared_distances(Z1: Float[Array, "n1 D"], Z2: Float[Array, "n2 D"]) -> Float[Array, "n1 n2"]:
    """``Σ_d (Z1_id − Z2_jd)²``, summed feature by feature (exact, unlike the matmul identity)."""
    r2 = jnp.zeros((Z1.shape[0], Z2.shape[0]), jnp.result_type(Z1, Z2))
    for d in range(Z1.shape[1]):
        r2 = r2 + (Z1[:, d, None] - Z2[None, :, d]) ** 2
    return r2


def _scaled_squared_distances(X1: Float[Array, "n1 D"], X2: Float[Array, "n2 D"], lengthscale) -> Float[Array, "n1 n2"]:
    """``r² = Σ_d (X1_id − X2_jd)² / ℓ_d²``.

    A scalar ``ℓ`` divides the unscaled distances once: ``r²`` then depends on ``ℓ``
    through one elementwise division, and the gradient of an LML with respect to
    ``ℓ`` is one reduction instead of ``D`` passes back through the differences.
    ARD lengthscales scale the features.
    """
    if jnp.ndim(lengthscale) == 0:
        return _squared_distances(X1, X2) / lengthscale**2
    return _squared_distances(X1 / lengthscale, X2 / lengthscale)


def _as_kernel(other, op: str):
    if isinstance(other, Kernel):
        return other
    if isinstance(other, (int, float, np.floating, np.integer)) and not isinstance(other, bool):
        return Constant(float(other))
    return NotImplemented


# ---------------------------------------------------------------------------
# Parametrised leaf kernels


def _natural_value(name: str) -> property:
    """Read-only natural value of the positive parameter ``name`` (stored as ``raw_<name>``)."""
    return property(lambda self: self._natural(name), doc=f"natural value of ``{name}``")


class Parametrised(Kernel):
    """Leaf kernel with positive parameters stored as ``raw_<name>`` fields."""

    #: names of the positive parameters, in order.
    PARAMETERS: ClassVar[tuple[str, ...]] = ()
    #: names of the parameters that may be (D,) vectors (ARD).
    VECTOR_PARAMETERS: ClassVar[tuple[str, ...]] = ()

    fixed: tuple[str, ...] = eqx.field(static=True)

    def _set(self, name: str, value) -> None:
        kname = type(self).__name__
        shape = np.shape(value)
        if name in self.VECTOR_PARAMETERS:
            if len(shape) > 1 or (len(shape) == 1 and shape[0] == 0):
                raise ValueError(f"{kname}: {name} must be a scalar or a non-empty (D,) vector, got shape {shape}")
        elif shape != ():
            raise ValueError(f"{kname}: {name} must be a scalar, got shape {shape}")
        setattr(self, "raw_" + name, unconstrain_positive(value, name=f"{kname} {name}"))

    def _set_parameters(self, fixed, **values) -> None:
        """Store every parameter of :attr:`PARAMETERS` (natural values) and the ``fixed`` names."""
        for name in self.PARAMETERS:
            self._set(name, values[name])
        self._set_fixed(fixed)

    def _set_fixed(self, fixed) -> None:
        kname = type(self).__name__
        fixed = (fixed,) if isinstance(fixed, str) else tuple(fixed)
        for name in fixed:
            if name not in self.PARAMETERS:
                raise ValueError(f"{kname}: fixed names unknown parameter {name!r}; parameters are {self.PARAMETERS}")
        self.fixed = fixed

    def _natural(self, name: str) -> Array:
        return positive(getattr(self, "raw_" + name))

    def hyperparameters(self) -> dict[str, Array]:
        return {name: self._natural(name) for name in self.PARAMETERS}

    def trainable_filter(self):
        spec = jax.tree.map(eqx.is_inexact_array, self)
        for name in self.fixed:
            spec = eqx.tree_at(lambda k, n=name: getattr(k, "raw_" + n), spec, False)
        return spec

    def check_input_dim(self, num_features: int) -> None:
        for name in self.VECTOR_PARAMETERS:
            shape = jnp.shape(getattr(self, "raw_" + name))
            if shape and shape[0] != num_features:
                raise ValueError(
                    f"{type(self).__name__}: {name} has {shape[0]} entries (ARD) but the inputs have "
                    f"{num_features} features"
                )

    def _with(self, **values) -> Kernel:
        """Copy with new natural values (fixed parameters kept; shapes kept)."""
        new = self
        for name, value in values.items():
            if name in self.fixed:
                continue
            old = getattr(self, "raw_" + name)
            value = np.asarray(value, dtype=np.float64)
            if np.ndim(old) == 0:
                value = np.mean(value)
            else:
                value = np.broadcast_to(value, np.shape(old))
            value = np.maximum(value, 1e-6)
            raw = jnp.asarray(np.log(value), dtype=jnp.result_type(old))
            new = eqx.tree_at(lambda k, n=name: getattr(k, "raw_" + n), new, raw)
        return new


class Constant(Parametrised):
    """``k(x, y) = σ²`` (scikit-learn's ``ConstantKernel``): a constant offset, or a scale in products."""

    PARAMETERS: ClassVar[tuple[str, ...]] = ("variance",)
    raw_variance: Float[Array, ""]

    def __init__(self, variance: float = 1.0, *, fixed=()):
        self._set_parameters(fixed, variance=variance)

    variance = _natural_value("variance")

    def evaluate(self, x1, x2):
        return self.variance.astype(jnp.result_type(x1, self.variance))

    def _cross(self, X1, X2):
        return jnp.full((X1.shape[0], X2.shape[0]), self.variance, jnp.result_type(X1, self.variance))

    def _initialise(self, stats, variance):
        return self._with(variance=variance)


class RBF(Parametrised):
    """Squared exponential ``k(x, y) = σ² exp(−½ Σ_d (x_d − y_d)² / ℓ_d²)`` (ARD if ℓ is a vector)."""

    PARAMETERS: ClassVar[tuple[str, ...]] = ("variance", "lengthscale")
    VECTOR_PARAMETERS: ClassVar[tuple[str, ...]] = ("lengthscale",)
    raw_variance: Float[Array, ""]
    raw_lengthscale: Float[Array, "*D"]

    def __init__(self, variance: float = 1.0, lengthscale=1.0, *, fixed=()):
        self._set_parameters(fixed, variance=variance, lengthscale=lengthscale)

    variance = _natural_value("variance")
    lengthscale = _natural_value("lengthscale")

    def evaluate(self, x1, x2):
        r2 = jnp.sum(((x1 - x2) / self.lengthscale) ** 2)
        return self.variance * jnp.exp(-0.5 * r2)

    def _cross(self, X1, X2):
        r2 = _scaled_squared_distances(X1, X2, self.lengthscale)
        return self.variance * jnp.exp(-0.5 * r2)

    def _initialise(self, stats, variance):
        ls = stats.dist_median if np.ndim(self.raw_lengthscale) == 0 else stats.dist_median_per_feature
        return self._with(variance=variance, lengthscale=ls)


class RationalQuadratic(Parametrised):
    """``k(x, y) = σ² (1 + r² / (2 α))^(−α)`` (Rasmussen & Williams 2006, eq. 4.19).

    With ``r² = Σ_d (x_d − y_d)² / ℓ_d²``: a scale mixture of RBFs; α → ∞ gives the RBF.
    Yücel et al. T-CYB 2013 (Sec. V) use the isotropic form in ``f1``. Same as
    scikit-learn's ``ConstantKernel(σ²) * RationalQuadratic(ℓ, α)``.
    """

    PARAMETERS: ClassVar[tuple[str, ...]] = ("variance", "lengthscale", "alpha")
    VECTOR_PARAMETERS: ClassVar[tuple[str, ...]] = ("lengthscale",)
    raw_variance: Float[Array, ""]
    raw_lengthscale: Float[Array, "*D"]
    raw_alpha: Float[Array, ""]

    def __init__(self, variance: float = 1.0, lengthscale=1.0, alpha: float = 1.0, *, fixed=()):
        self._set_parameters(fixed, variance=variance, lengthscale=lengthscale, alpha=alpha)

    variance = _natural_value("variance")
    lengthscale = _natural_value("lengthscale")
    alpha = _natural_value("alpha")

    def _of_r2(self, r2):
        alpha = self.alpha
        return self.variance * jnp.exp(-alpha * jnp.log1p(r2 / (2.0 * alpha)))

    def evaluate(self, x1, x2):
        return self._of_r2(jnp.sum(((x1 - x2) / self.lengthscale) ** 2))

    def _cross(self, X1, X2):
        return self._of_r2(_scaled_squared_distances(X1, X2, self.lengthscale))

    def _initialise(self, stats, variance):
        ls = stats.dist_median if np.ndim(self.raw_lengthscale) == 0 else stats.dist_median_per_feature
        return self._with(variance=variance, lengthscale=ls, alpha=1.0)


class ArcSine(Parametrised):
    """Williams' neural-network kernel (Williams 1998; GPy ``MLP``, GPML ``covNN``).

    ``k(x, y) = σ² (2/π) asin( (xᵀΣy + σb²) / sqrt((xᵀΣx + σb² + 1)(yᵀΣy + σb² + 1)) )``
    with ``Σ = diag(σw²)`` (``weight_variance``, scalar or (D,)) and ``σb²``
    (``bias_variance``): the covariance of an infinitely wide erf network
    (Williams 1998). Used with the rational quadratic in Yücel et al. ``f1``.
    """

    PARAMETERS: ClassVar[tuple[str, ...]] = ("variance", "weight_variance", "bias_variance")
    VECTOR_PARAMETERS: ClassVar[tuple[str, ...]] = ("weight_variance",)
    raw_variance: Float[Array, ""]
    raw_weight_variance: Float[Array, "*D"]
    raw_bias_variance: Float[Array, ""]

    def __init__(self, variance: float = 1.0, weight_variance=1.0, bias_variance: float = 1.0, *, fixed=()):
        self._set_parameters(fixed, variance=variance, weight_variance=weight_variance, bias_variance=bias_variance)

    variance = _natural_value("variance")
    weight_variance = _natural_value("weight_variance")
    bias_variance = _natural_value("bias_variance")

    def evaluate(self, x1, x2):
        w = self.weight_variance
        b = self.bias_variance
        num = jnp.sum(w * x1 * x2) + b
        d1 = jnp.sum(w * x1 * x1) + b + 1.0
        d2 = jnp.sum(w * x2 * x2) + b + 1.0
        # |num| < sqrt(d1 d2) by Cauchy–Schwarz; clip only guards rounding.
        s = jnp.clip(num * jax.lax.rsqrt(d1 * d2), -1.0, 1.0)
        return self.variance * (2.0 / math.pi) * jnp.arcsin(s)

    def _cross(self, X1, X2):
        w = self.weight_variance
        b = self.bias_variance
        num = jnp.matmul(X1 * w, X2.T, precision=_HIGHEST) + b
        d1 = jnp.sum(w * X1 * X1, axis=1) + b + 1.0
        d2 = jnp.sum(w * X2 * X2, axis=1) + b + 1.0
        s = jnp.clip(num * jax.lax.rsqrt(d1[:, None] * d2[None, :]), -1.0, 1.0)
        return self.variance * (2.0 / math.pi) * jnp.arcsin(s)

    def _initialise(self, stats, variance):
        if np.ndim(self.raw_weight_variance) == 0:
            w = 1.0 / max(stats.x_norm_sq, 1e-12)
        else:
            w = 1.0 / (len(stats.x_sq_per_feature) * np.maximum(stats.x_sq_per_feature, 1e-12))
        return self._with(variance=variance, weight_variance=w, bias_variance=1.0)


class Linear(Parametrised):
    """Dot-product kernel ``k(x, y) = σb² + Σ_d σ_d² x_d y_d``.

    ``Linear(variance=1, bias_variance=σ0², fixed=("variance",))`` is
    scikit-learn's ``DotProduct(sigma_0=σ0)``. Yücel et al. ``f2`` (target
    depth) uses it with independent noise.
    """

    PARAMETERS: ClassVar[tuple[str, ...]] = ("variance", "bias_variance")
    VECTOR_PARAMETERS: ClassVar[tuple[str, ...]] = ("variance",)
    raw_variance: Float[Array, "*D"]
    raw_bias_variance: Float[Array, ""]

    def __init__(self, variance=1.0, bias_variance: float = 1.0, *, fixed=()):
        self._set_parameters(fixed, variance=variance, bias_variance=bias_variance)

    variance = _natural_value("variance")
    bias_variance = _natural_value("bias_variance")

    def evaluate(self, x1, x2):
        return self.bias_variance + jnp.sum(self.variance * x1 * x2)

    def _cross(self, X1, X2):
        return self.bias_variance + jnp.matmul(X1 * self.variance, X2.T, precision=_HIGHEST)

    def _initialise(self, stats, variance):
        if np.ndim(self.raw_variance) == 0:
            v = variance / max(stats.x_norm_sq, 1e-12)
        else:
            v = variance / (len(stats.x_sq_per_feature) * np.maximum(stats.x_sq_per_feature, 1e-12))
        return self._with(variance=v, bias_variance=max(stats.y_mean_sq, 0.1 * variance))


class White(Parametrised):
    """Independent noise: σ² on the diagonal of ``k(X)`` only (Yücel et al. 2013, eq. 7).

    As scikit-learn's ``WhiteKernel``: ``evaluate`` is 0 (no covariance between distinct evaluations, nor between
    two different sets); ``evaluate_noise`` is σ². In Yücel et al. (T-CYB eq. 7)
    this is the i.i.d. observation noise σ0², attributed to eye movements.
    """

    PARAMETERS: ClassVar[tuple[str, ...]] = ("variance",)
    raw_variance: Float[Array, ""]

    def __init__(self, variance: float = 1.0, *, fixed=()):
        self._set_parameters(fixed, variance=variance)

    variance = _natural_value("variance")

    @property
    def has_noise(self) -> bool:
        return True

    @property
    def is_noise_only(self) -> bool:
        return True

    def evaluate(self, x1, x2):
        return jnp.zeros((), jnp.result_type(x1, self.raw_variance))

    def _cross(self, X1, X2):
        return jnp.zeros((X1.shape[0], X2.shape[0]), jnp.result_type(X1, self.raw_variance))

    def evaluate_noise(self, x):
        return self.variance.astype(jnp.result_type(x, self.raw_variance))

    def _initialise(self, stats, variance):
        return self._with(variance=variance)


# ---------------------------------------------------------------------------
# Combinations


class _Combination(Kernel):
    kernels: tuple[Kernel, ...]

    def __init__(self, *kernels: Kernel):
        flat: list[Kernel] = []
        for k in kernels:
            if not isinstance(k, Kernel):
                raise TypeError(f"{type(self).__name__} takes kernels, got {type(k).__name__}")
            flat.extend(k.kernels if type(k) is type(self) else (k,))
        if len(flat) < 1:
            raise ValueError(f"{type(self).__name__} needs at least one kernel")
        self.kernels = tuple(flat)

    @property
    def has_noise(self) -> bool:
        return any(k.has_noise for k in self.kernels)

    def hyperparameters(self) -> dict[str, Array]:
        out = {}
        for i, k in enumerate(self.kernels):
            for name, value in k.hyperparameters().items():
                out[f"{i}.{type(k).__name__}.{name}"] = value
        return out

    def trainable_filter(self):
        spec = jax.tree.map(lambda _: False, self)
        return eqx.tree_at(lambda s: s.kernels, spec, tuple(k.trainable_filter() for k in self.kernels))

    def check_input_dim(self, num_features: int) -> None:
        for k in self.kernels:
            k.check_input_dim(num_features)


class Sum(_Combination):
    """``k(x, y) = Σ_i k_i(x, y)``; noise diagonals add."""

    @property
    def is_noise_only(self) -> bool:
        return all(k.is_noise_only for k in self.kernels)

    def evaluate(self, x1, x2):
        return sum(k.evaluate(x1, x2) for k in self.kernels)

    def _cross(self, X1, X2):
        return sum(k._cross(X1, X2) for k in self.kernels)

    def evaluate_noise(self, x):
        return sum(k.evaluate_noise(x) for k in self.kernels)

    def _initialise(self, stats, variance):
        noise = [k.is_noise_only for k in self.kernels]
        num_noise = sum(noise)
        num_signal = len(noise) - num_noise
        if num_signal == 0:
            shares = [variance / num_noise] * num_noise
        else:
            signal = (0.9 if num_noise else 1.0) * variance / num_signal
            noise_var = 0.1 * variance / max(num_noise, 1)
            shares = [noise_var if is_noise else signal for is_noise in noise]
        kernels = tuple(k._initialise(stats, s) for k, s in zip(self.kernels, shares))
        return eqx.tree_at(lambda s: s.kernels, self, kernels)


class Product(_Combination):
    """``k(x, y) = ∏_i k_i(x, y)``; the noise diagonal is ``∏(k_i(x,x) + n_i(x)) − ∏ k_i(x,x)``."""

    @property
    def is_noise_only(self) -> bool:
        return any(k.is_noise_only for k in self.kernels)

    def evaluate(self, x1, x2):
        out = self.kernels[0].evaluate(x1, x2)
        for k in self.kernels[1:]:
            out = out * k.evaluate(x1, x2)
        return out

    def _cross(self, X1, X2):
        out = self.kernels[0]._cross(X1, X2)
        for k in self.kernels[1:]:
            out = out * k._cross(X1, X2)
        return out

    def evaluate_noise(self, x):
        with_noise = 1.0
        without = 1.0
        for k in self.kernels:
            s = k.evaluate(x, x)
            with_noise = with_noise * (s + k.evaluate_noise(x))
            without = without * s
        return with_noise - without

    def _initialise(self, stats, variance):
        share = variance ** (1.0 / len(self.kernels))
        kernels = tuple(k._initialise(stats, share) for k in self.kernels)
        return eqx.tree_at(lambda s: s.kernels, self, kernels)


# ---------------------------------------------------------------------------
# Factories (Yücel et al. T-CYB 2013, Sec. V)


def _check_num_features(num_features) -> int:
    if isinstance(num_features, bool) or not isinstance(num_features, (int, np.integer)) or num_features < 1:
        raise ValueError(f"num_features must be a positive integer, got {num_features!r}")
    return int(num_features)


def gaze_direction_kernel(num_features: int, *, ard: bool = False, noise_variance: float = 0.1) -> Sum:
    """Kernel of ``f1``, the gaze direction from head pose (Yücel et al. 2013, Sec. V, eq. 5–7).

    ``RationalQuadratic + ArcSine + White``: an isotropic rational quadratic
    plus the neural-network (arc-sine) kernel, plus the i.i.d. noise σ0² of
    eq. 7 (eye movements). Defaults are for standardised inputs and outputs
    (zero mean, unit variance per feature): RQ lengthscale ``sqrt(D)`` (the
    scale of distances between points), α = 1, arc-sine weight variance ``1/D``
    (so ``σw² xᵀx ≈ 1``), unit variances. ``ard=True`` gives per-feature
    lengthscales and weight variances.
    """
    d = _check_num_features(num_features)
    ls = math.sqrt(d)
    wv = 1.0 / d
    if ard:
        ls = np.full(d, ls)
        wv = np.full(d, wv)
    return RationalQuadratic(1.0, ls, 1.0) + ArcSine(1.0, wv, 1.0) + White(noise_variance)


def target_depth_kernel(num_features: int, *, ard: bool = False, noise_variance: float = 0.1) -> Sum:
    """Kernel of ``f2``, the depth of the attended object (Yücel et al. 2013, Sec. V).

    ``Linear + White``: a linear covariance (the geometry of camera, person and
    objects) plus independent noise (eye movements). Defaults for standardised
    data: weight variance ``1/D`` so the linear part has unit variance, unit
    bias variance. ``ard=True`` gives per-feature weight variances.
    """
    d = _check_num_features(num_features)
    v = 1.0 / d
    if ard:
        v = np.full(d, v)
    return Linear(v, 1.0) + White(noise_variance)
