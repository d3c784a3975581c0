"""Neural-network baseline regressor of Yücel et al. (CogSci 2009; T-CYB 2013, Sec. VII).

Both papers map the head pose (3 inputs) to one output (the image-plane gaze
angle, or the object depth) with "a two-layer back-propagation network": ten
hidden units, an initial learning rate of 0.1 "exponentially decreased during
training", an online training scheme, weights of both layers drawn from
(−0.5, 0.5), and a validation set monitored "to prevent overfitting". Here:

* **Model.** ``f(x) = W2ᵀ tanh(W1ᵀ x + b1) + b2`` (tanh hidden layer, linear
  output; :func:`mlp_forward`). All four arrays, biases included, start from
  U(−0.5, 0.5) (:func:`init_mlp_params`); the papers do not say how the biases
  start.
* **Standardisation** (not in the papers). Inputs and output are standardised
  with the mean and standard deviation of the *training split*
  (a zero-variance column keeps scale 1), so that the U(−0.5, 0.5) weights and
  the learning rate 0.1 mean the same thing whatever the units (radians,
  pixels). Predictions are mapped back to the units of ``y``.
* **Online training.** Each epoch visits the training samples once, in an order
  drawn afresh from a ``jax.random`` key, and after *each* sample takes the
  gradient step ``θ ← θ − η_e ∇θ ½(f(x_i) − y_i)²`` (:func:`online_epoch`, one
  ``lax.scan``).
* **Schedule.** ``η_e = learning_rate · decay^e`` for epoch ``e = 0, 1, …``
  (:func:`learning_rate_schedule`).
* **Early stopping.** After every epoch the mean squared error on the held-out
  validation split is computed; the weights with the lowest one so far are kept
  and training stops once ``patience`` epochs in a row brought no improvement
  (or at ``max_epochs``). The whole epoch loop is one jit-compiled
  ``lax.while_loop``.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, PRNGKeyArray

__all__ = [
    "MLPParams",
    "Standardisation",
    "MLPFit",
    "init_mlp_params",
    "mlp_forward",
    "learning_rate_schedule",
    "online_epoch",
    "fit_mlp",
    "min_points_for_split",
    "INIT_HALF_WIDTH",
]

#: Initial weights are drawn from U(−INIT_HALF_WIDTH, INIT_HALF_WIDTH) (both papers).
INIT_HALF_WIDTH = 0.5


class MLPParams(NamedTuple):
    """Weights of the one-hidden-layer network ``f(x) = W2ᵀ tanh(W1ᵀ x + b1) + b2``."""

    W1: Float[Array, "D H"]
    b1: Float[Array, " H"]
    W2: Float[Array, " H"]
    b2: Float[Array, ""]


class Standardisation(NamedTuple):
    """Training-split statistics: the network sees ``(x − x_mean)/x_scale`` and
    predicts ``(y − y_mean)/y_scale``."""

    x_mean: Float[Array, " D"]
    x_scale: Float[Array, " D"]
    y_mean: Float[Array, ""]
    y_scale: Float[Array, ""]


class MLPFit(NamedTuple):
    """Result of :func:`fit_mlp`.

    ``params`` are the weights after epoch ``best_epoch`` (the lowest validation
    loss), acting on standardised data (see ``standardisation``).
    ``train_loss[e]`` / ``validation_loss[e]`` are the mean squared errors, in
    the squared units of ``y``, of the training / validation split after epoch
    ``e``; epochs that were not run (after early stopping) hold ``+inf``, so the
    histories never contain NaN. ``epochs_run`` epochs were run; ``stopped_early``
    says whether ``patience`` ended training before ``max_epochs``.
    ``train_indices`` / ``validation_indices`` index the rows of the ``X`` given
    to :func:`fit_mlp`.
    """

    params: MLPParams
    standardisation: Standardisation
    best_epoch: int
    epochs_run: int
    stopped_early: bool
    train_loss: Float[Array, " max_epochs"]
    validation_loss: Float[Array, " max_epochs"]
    train_indices: Int[Array, " n_train"]
    validation_indices: Int[Array, " n_validation"]

    def predict(self, X_new: Float[Array, "m D"]) -> Float[Array, " m"]:
        """Predicted outputs, in the units of the training ``y``, for the rows of ``X_new``."""
        D = self.params.W1.shape[0]
        dtype = self.params.W1.dtype
        X_new = _as_float_array(X_new, "X_new", "predict")
        if X_new.ndim != 2 or X_new.shape[1] != D:
            raise ValueError(f"predict: X_new must have shape (m, {D}), got {X_new.shape}")
        _check_finite_rows(X_new, "X_new", "predict")
        return _predict(self.params, self.standardisation, jnp.asarray(X_new, dtype=dtype))


# --------------------------------------------------------------------------- model


def init_mlp_params(
    key: PRNGKeyArray, n_inputs: int, hidden_units: int = 10, dtype=jnp.float32
) -> MLPParams:
    """Initial weights (Yücel et al. 2009, CogSci; 2013, Sec. VII): every entry of W1, b1, W2 and b2
    i.i.d. U(−0.5, 0.5) (CogSci: "Weights in both layers are initialized randomly from the
    (−0.5, 0.5) interval")."""
    _check_positive_int(n_inputs, "n_inputs", "init_mlp_params")
    _check_positive_int(hidden_units, "hidden_units", "init_mlp_params")
    k1, k2, k3, k4 = jax.random.split(key, 4)
    u = functools.partial(jax.random.uniform, dtype=dtype, minval=-INIT_HALF_WIDTH, maxval=INIT_HALF_WIDTH)
    return MLPParams(
        W1=u(k1, (n_inputs, hidden_units)),
        b1=u(k2, (hidden_units,)),
        W2=u(k3, (hidden_units,)),
        b2=u(k4, ()),
    )


def mlp_forward(params: MLPParams, X: Float[Array, "*batch D"]) -> Float[Array, " *batch"]:
    """``f(x) = W2ᵀ tanh(W1ᵀ x + b1) + b2`` (Yücel et al. 2009, CogSci; 2013, Sec. VII).

    The inputs ``X`` are already standardised.
    """
    return jnp.tanh(X @ params.W1 + params.b1) @ params.W2 + params.b2


def _sample_loss(params: MLPParams, x: Float[Array, " D"], y: Float[Array, ""]) -> Float[Array, ""]:
    """½ (f(x) − y)²: the per-sample error of online back-propagation."""
    r = mlp_forward(params, x) - y
    return 0.5 * r * r


_sample_grad = jax.grad(_sample_loss)


def learning_rate_schedule(learning_rate, decay, num_epochs: int) -> Float[Array, " num_epochs"]:
    """Learning rate of each epoch (Yücel et al. 2009, CogSci; 2013, Sec. VII): ``η_e = learning_rate · decay^e``
    for ``e = 0 … num_epochs − 1`` (an exponential decrease)."""
    e = jnp.arange(num_epochs)
    lr = jnp.asarray(learning_rate)
    return lr * jnp.asarray(decay, dtype=lr.dtype) ** e.astype(lr.dtype)


def online_epoch(
    params: MLPParams,
    X: Float[Array, "n D"],
    y: Float[Array, " n"],
    order: Int[Array, " n"],
    learning_rate,
) -> MLPParams:
    """One epoch of online (per-sample) gradient descent (Yücel et al. 2009, CogSci; 2013, Sec. VII):
    for ``i`` in ``order``, ``θ ← θ − learning_rate · ∇θ ½(f(X[i]) − y[i])²``. One ``lax.scan``."""

    def step(p, i):
        g = _sample_grad(p, X[i], y[i])
        return jax.tree.map(lambda w, gw: w - learning_rate * gw, p, g), None

    params, _ = jax.lax.scan(step, params, order)
    return params


def _mse(params: MLPParams, X, y):
    r = mlp_forward(params, X) - y
    return jnp.mean(r * r)


def _train(params, X_train, y_train, X_val, y_val, key, learning_rate, decay, patience, *, max_epochs):
    """Epoch loop with early stopping, on standardised data; losses in standardised units."""
    n_train = X_train.shape[0]
    dtype = X_train.dtype
    rates = learning_rate_schedule(jnp.asarray(learning_rate, dtype), jnp.asarray(decay, dtype), max_epochs)
    inf_hist = jnp.full((max_epochs,), jnp.inf, dtype)

    def cond(carry):
        e, _, _, _, _, since_best, _, _ = carry
        return (e < max_epochs) & (since_best < patience)

    def body(carry):
        e, p, best_p, best_val, best_epoch, since_best, tr_hist, va_hist = carry
        order = jax.random.permutation(jax.random.fold_in(key, e), n_train)
        p = online_epoch(p, X_train, y_train, order, rates[e])
        tr = _mse(p, X_train, y_train)
        va = _mse(p, X_val, y_val)
        better = va < best_val
        best_p = jax.tree.map(lambda new, old: jnp.where(better, new, old), p, best_p)
        best_val = jnp.where(better, va, best_val)
        best_epoch = jnp.where(better, e, best_epoch)
        since_best = jnp.where(better, 0, since_best + 1)
        return (e + 1, p, best_p, best_val, best_epoch, since_best, tr_hist.at[e].set(tr), va_hist.at[e].set(va))

    init = (
        jnp.asarray(0, jnp.int32),
        params,
        params,
        jnp.asarray(jnp.inf, dtype),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(0, jnp.int32),
        inf_hist,
        inf_hist,
    )
    e, _, best_p, _, best_epoch, since_best, tr_hist, va_hist = jax.lax.while_loop(cond, body, init)
    return best_p, best_epoch, e, tr_hist, va_hist


@jax.jit
def _predict(params: MLPParams, s: Standardisation, X):
    return mlp_forward(params, (X - s.x_mean) / s.x_scale) * s.y_scale + s.y_mean


# --------------------------------------------------------------------------- fit


def _n_validation(n: int, validation_fraction: float) -> int:
    return max(1, int(round(validation_fraction * n)))


def min_points_for_split(validation_fraction: float) -> int:
    """Smallest ``n`` that leaves ≥ 2 training points (for the standardisation) and
    ≥ 1 validation point when ``round(validation_fraction · n)`` (at least 1) are held out."""
    _check_fraction(validation_fraction, "min_points_for_split")
    n = 3
    while n - _n_validation(n, validation_fraction) < 2:
        n += 1
    return n


def fit_mlp(
    X: Float[Array, "n D"],
    y: Float[Array, " n"],
    *,
    key: PRNGKeyArray,
    hidden_units: int = 10,
    learning_rate: float = 0.1,
    decay: float = 0.98,
    max_epochs: int = 200,
    validation_fraction: float = 0.2,
    patience: int = 20,
) -> MLPFit:
    """Train the NN baseline (Yücel et al. 2009, CogSci; 2013, Sec. VII) on ``(X, y)``.

    ``round(validation_fraction · n)`` (at least one) random rows are held out for
    early stopping; the rest are trained on with online SGD, learning rate
    ``learning_rate · decay^e`` in epoch ``e``; training stops after ``patience``
    epochs without a new lowest validation MSE, and the weights of that lowest
    epoch are returned (see the module docstring and :class:`MLPFit`).

    Randomness: ``k_init, k_split, k_shuffle = jax.random.split(key, 3)``;
    the weights are ``init_mlp_params(k_init, D, hidden_units)``, the validation
    rows ``jax.random.permutation(k_split, n)[:n_validation]`` (training rows the
    rest, in that permuted order), and epoch ``e`` visits the training rows in the
    order ``jax.random.permutation(jax.random.fold_in(k_shuffle, e), n_train)``.
    The same key gives the same fit. The computation runs in the common floating
    dtype of ``X`` and ``y`` (integers count as JAX's default float).
    """
    fn = "fit_mlp"
    X = _as_float_array(X, "X", fn)
    y = _as_float_array(y, "y", fn)
    if X.ndim != 2:
        raise ValueError(f"{fn}: X must be 2-D with shape (n, D), got shape {X.shape}")
    if y.ndim != 1:
        raise ValueError(f"{fn}: y must be 1-D with shape (n,), got shape {y.shape}")
    if X.shape[0] != y.shape[0]:
        raise ValueError(f"{fn}: X and y must have the same number of rows, got {X.shape[0]} and {y.shape[0]}")
    if X.shape[1] < 1:
        raise ValueError(f"{fn}: X must have at least one column, got shape {X.shape}")
    _check_finite_rows(X, "X", fn)
    _check_finite_rows(y, "y", fn)
    _check_positive_int(hidden_units, "hidden_units", fn)
    _check_positive_int(max_epochs, "max_epochs", fn)
    _check_positive_int(patience, "patience", fn)
    real = (int, float, np.floating, np.integer)
    if not (isinstance(learning_rate, real) and math.isfinite(learning_rate) and learning_rate > 0):
        raise ValueError(f"{fn}: learning_rate must be a finite number > 0, got {learning_rate!r}")
    if not (isinstance(decay, real) and 0 < decay <= 1):
        raise ValueError(f"{fn}: decay must lie in (0, 1], got {decay!r}")
    _check_fraction(validation_fraction, fn)
    n, D = X.shape
    needed = min_points_for_split(validation_fraction)
    if n < needed:
        raise ValueError(
            f"{fn}: too few points to split into training and validation sets: got {n}, need at least "
            f"{needed} (≥ 2 training and ≥ 1 validation points at validation_fraction={validation_fraction})"
        )

    dtype = jax.dtypes.canonicalize_dtype(np.result_type(X.dtype, y.dtype))
    out = _fit_core(
        jnp.asarray(X, dtype=dtype),
        jnp.asarray(y, dtype=dtype),
        key,
        learning_rate,
        decay,
        patience,
        n_validation=_n_validation(n, validation_fraction),
        hidden_units=hidden_units,
        max_epochs=max_epochs,
    )
    params, s, best_epoch, epochs_run, tr_hist, va_hist, train_idx, val_idx = out
    epochs_run = int(epochs_run)
    return MLPFit(
        params=params,
        standardisation=s,
        best_epoch=int(best_epoch),
        epochs_run=epochs_run,
        stopped_early=epochs_run < max_epochs,
        train_loss=tr_hist,
        validation_loss=va_hist,
        train_indices=train_idx,
        validation_indices=val_idx,
    )


@functools.partial(jax.jit, static_argnames=("n_validation", "hidden_units", "max_epochs"))
def _fit_core(X, y, key, learning_rate, decay, patience, *, n_validation, hidden_units, max_epochs):
    """Split, standardise, initialise and train in one compiled call (see :func:`fit_mlp`)."""
    n, D = X.shape
    dtype = X.dtype
    k_init, k_split, k_shuffle = jax.random.split(key, 3)
    perm = jax.random.permutation(k_split, n)
    val_idx, train_idx = perm[:n_validation], perm[n_validation:]
    X_tr, y_tr = X[train_idx], y[train_idx]
    X_va, y_va = X[val_idx], y[val_idx]
    x_mean, x_std = X_tr.mean(axis=0), X_tr.std(axis=0)
    y_mean, y_std = y_tr.mean(), y_tr.std()
    # a (numerically) constant column keeps scale 1 instead of dividing by ~0
    tiny = jnp.finfo(dtype).eps * 100
    x_scale = jnp.where(x_std > tiny * (1 + jnp.abs(x_mean)), x_std, jnp.ones_like(x_std))
    y_scale = jnp.where(y_std > tiny * (1 + jnp.abs(y_mean)), y_std, jnp.ones_like(y_std))
    s = Standardisation(x_mean, x_scale, y_mean, y_scale)
    params0 = init_mlp_params(k_init, D, hidden_units, dtype=dtype)
    best, best_epoch, epochs_run, tr_hist, va_hist = _train(
        params0,
        (X_tr - x_mean) / x_scale,
        (y_tr - y_mean) / y_scale,
        (X_va - x_mean) / x_scale,
        (y_va - y_mean) / y_scale,
        k_shuffle,
        learning_rate,
        decay,
        patience,
        max_epochs=max_epochs,
    )
    return best, s, best_epoch, epochs_run, tr_hist * y_scale**2, va_hist * y_scale**2, train_idx, val_idx


# --------------------------------------------------------------------------- checks


def _as_float_array(a, name: str, fn: str) -> np.ndarray:
    try:
        arr = np.asarray(a)
    except Exception as exc:  # ragged lists and the like
        raise TypeError(f"{fn}: {name} must be a numeric array, got {type(a).__name__}") from exc
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise TypeError(f"{fn}: {name} must hold real numbers, got dtype {arr.dtype}")
    if np.issubdtype(arr.dtype, np.integer):
        arr = arr.astype(jax.dtypes.canonicalize_dtype(np.float64))
    return arr


def _check_finite_rows(a: np.ndarray, name: str, fn: str) -> None:
    ok = np.isfinite(a) if a.ndim == 1 else np.isfinite(a).all(axis=tuple(range(1, a.ndim)))
    if not ok.all():
        row = int(np.argmin(ok))
        raise ValueError(f"{fn}: {name} holds NaN or inf; first bad row is {row}: {a[row]!r}")


def _check_positive_int(v, name: str, fn: str) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise TypeError(f"{fn}: {name} must be an integer ≥ 1, got {v!r}")
    if v < 1:
        raise ValueError(f"{fn}: {name} must be an integer ≥ 1, got {v}")


def _check_fraction(f, fn: str) -> None:
    if not (isinstance(f, (int, float, np.floating)) and 0 < f < 1):
        raise ValueError(f"{fn}: validation_fraction must lie in (0, 1), got {f!r}")
