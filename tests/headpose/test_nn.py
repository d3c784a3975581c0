"""Tests of the NN baseline regressor (jaxgaze.headpose.nn; Yücel et al. CogSci / T-CYB Sec. VII)."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgaze.headpose.nn as nn


# --------------------------------------------------------------------------- references


def _numpy_online_epoch(params, X, y, order, lr):
    """Hand-written per-sample back-propagation for f(x) = W2ᵀ tanh(W1ᵀx + b1) + b2, loss ½r²."""
    W1, b1, W2, b2 = (np.array(p, dtype=np.float64) for p in params)
    for i in order:
        x = X[i]
        h = np.tanh(x @ W1 + b1)
        r = h @ W2 + b2 - y[i]
        ga = r * W2 * (1.0 - h * h)  # gradient at the hidden pre-activation, before W2 changes
        W2 = W2 - lr * r * h
        b2 = b2 - lr * r
        W1 = W1 - lr * np.outer(x, ga)
        b1 = b1 - lr * ga
    return W1, b1, W2, b2


def _numpy_forward(params, X):
    W1, b1, W2, b2 = params
    return np.tanh(X @ W1 + b1) @ W2 + b2


def _smooth_data(seed, n):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2.0, 2.0, (n, 2))
    y = np.sin(1.5 * X[:, 0]) + 0.5 * X[:, 1] + 0.05 * rng.normal(size=n)
    return X.astype(np.float32), y.astype(np.float32)


@pytest.fixture(scope="module")
def smooth():
    """One float32 fit on y = sin(1.5 x1) + 0.5 x2 + N(0, 0.05²), n = 400, defaults of the paper."""
    X, y = _smooth_data(0, 400)
    X_test, y_test = _smooth_data(100, 1000)
    fit = nn.fit_mlp(X, y, key=jax.random.key(0))
    return X, y, X_test, y_test, fit


# --------------------------------------------------------------------------- init and schedule


def test_initial_weights_uniform_in_half_interval_and_reproducible():
    key = jax.random.key(3)
    p = nn.init_mlp_params(key, 3, 10)
    assert [a.shape for a in p] == [(3, 10), (10,), (10,), ()]
    for a in p:
        assert a.dtype == jnp.float32
        assert np.all(np.abs(np.asarray(a)) <= 0.5)
    q = nn.init_mlp_params(key, 3, 10)
    for a, b in zip(p, q):
        np.testing.assert_array_equal(a, b)
    r = nn.init_mlp_params(jax.random.key(4), 3, 10)
    assert not np.allclose(p.W1, r.W1)
    # many draws: they fill (−0.5, 0.5) with the uniform's mean 0 and sd 1/√12
    big = np.concatenate([np.ravel(a) for a in nn.init_mlp_params(key, 40, 100)])
    assert big.min() >= -0.5 and big.max() <= 0.5
    assert big.min() < -0.49 and big.max() > 0.49
    assert abs(big.mean()) < 0.02
    assert abs(big.std() - 1 / np.sqrt(12)) < 0.01


def test_learning_rate_schedule_is_exponential():
    lr, decay, E = 0.1, 0.9, 40
    s = np.asarray(nn.learning_rate_schedule(lr, decay, E), dtype=np.float64)
    assert s.shape == (E,)
    assert s[0] == pytest.approx(lr)
    np.testing.assert_allclose(s[1:] / s[:-1], decay, rtol=1e-5)  # constant ratio
    np.testing.assert_allclose(np.diff(np.log(s)), np.log(decay), rtol=1e-4)  # log-linear
    assert s[-1] == pytest.approx(lr * decay ** (E - 1), rel=1e-5)
    np.testing.assert_allclose(nn.learning_rate_schedule(0.3, 1.0, 5), 0.3, rtol=1e-7)  # decay 1 = constant


# --------------------------------------------------------------------------- online training


def test_online_epoch_matches_per_sample_python_loop(x64):
    rng = np.random.default_rng(1)
    X = rng.normal(size=(15, 3))
    y = np.sin(X[:, 0]) + 0.3 * X[:, 1]
    params = nn.init_mlp_params(jax.random.key(0), 3, 10, dtype=jnp.float64)
    order = rng.permutation(15)
    lr = 0.1
    got = nn.online_epoch(params, jnp.asarray(X), jnp.asarray(y), jnp.asarray(order), lr)
    want = _numpy_online_epoch(params, X, y, order, lr)
    for g, w in zip(got, want):
        assert g.dtype == jnp.float64
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-12, atol=1e-13)
    # "online" is not "batch": one full-gradient step from the same start lands elsewhere,
    # and visiting the samples in another order gives another result
    grads = jax.vmap(nn._sample_grad, in_axes=(None, 0, 0))(params, jnp.asarray(X), jnp.asarray(y))
    batch = [p - lr * g.sum(0) for p, g in zip(params, grads)]
    assert np.max(np.abs(np.asarray(batch[0]) - want[0])) > 1e-3
    other = _numpy_online_epoch(params, X, y, order[::-1], lr)
    assert np.max(np.abs(other[0] - want[0])) > 1e-3


def test_fit_equals_hand_written_pipeline(x64):
    """Split, standardisation, init, per-epoch shuffling and learning rates as documented in fit_mlp."""
    rng = np.random.default_rng(2)
    n, D = 25, 3
    X = rng.normal(size=(n, D)) * [1.0, 3.0, 0.2] + [0.0, 5.0, -1.0]
    y = 2.0 + 0.8 * X[:, 0] - 0.1 * X[:, 1] + 0.1 * rng.normal(size=n)
    key = jax.random.key(7)
    lr, decay, E = 0.1, 0.9, 3
    fit = nn.fit_mlp(X, y, key=key, learning_rate=lr, decay=decay, max_epochs=E, patience=10)
    assert fit.params.W1.dtype == jnp.float64 and fit.train_loss.dtype == jnp.float64

    k_init, k_split, k_shuffle = jax.random.split(key, 3)
    perm = np.asarray(jax.random.permutation(k_split, n))
    val, tr = perm[:5], perm[5:]
    np.testing.assert_array_equal(fit.validation_indices, val)
    np.testing.assert_array_equal(fit.train_indices, tr)
    xm, xs = X[tr].mean(0), X[tr].std(0)
    ym, ys = y[tr].mean(), y[tr].std()
    np.testing.assert_allclose(fit.standardisation.x_mean, xm, rtol=1e-12)
    np.testing.assert_allclose(fit.standardisation.x_scale, xs, rtol=1e-12)
    Xt, yt = (X[tr] - xm) / xs, (y[tr] - ym) / ys
    Xv, yv = (X[val] - xm) / xs, (y[val] - ym) / ys

    p = nn.init_mlp_params(k_init, D, 10, dtype=jnp.float64)
    history, tr_loss, va_loss = [], [], []
    for e in range(E):
        order = np.asarray(jax.random.permutation(jax.random.fold_in(k_shuffle, e), n - 5))
        p = _numpy_online_epoch(p, Xt, yt, order, lr * decay**e)
        history.append(p)
        tr_loss.append(np.mean((_numpy_forward(p, Xt) - yt) ** 2) * ys**2)
        va_loss.append(np.mean((_numpy_forward(p, Xv) - yv) ** 2) * ys**2)
    np.testing.assert_allclose(fit.train_loss, tr_loss, rtol=1e-10)
    np.testing.assert_allclose(fit.validation_loss, va_loss, rtol=1e-10)
    best = int(np.argmin(va_loss))
    assert fit.best_epoch == best and fit.epochs_run == E and not fit.stopped_early
    for g, w in zip(fit.params, history[best]):
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fit.predict(X), _numpy_forward(history[best], (X - xm) / xs) * ys + ym, rtol=1e-10)


# --------------------------------------------------------------------------- fitting


def test_learns_smooth_function_like_sklearn(smooth):
    from sklearn.neural_network import MLPRegressor
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    X, y, X_test, y_test, fit = smooth
    pred = np.asarray(fit.predict(X_test))
    assert pred.shape == (1000,) and pred.dtype == np.float32
    rmse = float(np.sqrt(np.mean((pred - y_test) ** 2)))
    assert rmse < 0.12
    assert rmse < 0.15 * float(y_test.std())  # far better than predicting the mean

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk = make_pipeline(
            StandardScaler(),
            MLPRegressor(
                hidden_layer_sizes=(10,),
                activation="tanh",
                solver="sgd",
                batch_size=32,
                learning_rate_init=0.1,
                early_stopping=True,
                validation_fraction=0.2,
                n_iter_no_change=20,
                max_iter=300,
                random_state=0,
            ),
        ).fit(X, y)
    rmse_sk = float(np.sqrt(np.mean((sk.predict(X_test) - y_test) ** 2)))
    assert rmse_sk < 0.12  # the reference itself learned the function
    assert rmse < 1.5 * rmse_sk


def test_histories_are_finite_where_run_and_inf_after(smooth):
    *_, fit = smooth
    tr, va = np.asarray(fit.train_loss), np.asarray(fit.validation_loss)
    assert tr.shape == va.shape == (200,)
    assert not np.isnan(tr).any() and not np.isnan(va).any()
    k = fit.epochs_run
    assert np.isfinite(tr[:k]).all() and np.isfinite(va[:k]).all()
    assert np.isposinf(tr[k:]).all() and np.isposinf(va[k:]).all()
    assert fit.best_epoch == int(np.argmin(va))
    assert tr[fit.best_epoch] < 0.1 * tr[0] or tr[0] < 0.01  # training reduced the error


def test_deterministic_for_fixed_key(smooth):
    X, y, _, _, fit = smooth
    again = nn.fit_mlp(X, y, key=jax.random.key(0))
    for a, b in zip(jax.tree.leaves(fit), jax.tree.leaves(again)):
        np.testing.assert_array_equal(a, b)
    other = nn.fit_mlp(X, y, key=jax.random.key(1))
    assert not np.allclose(other.params.W1, fit.params.W1)


def test_early_stopping_returns_best_validation_weights():
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, (30, 3)).astype(np.float32)
    y = (X[:, 0] + 0.7 * rng.normal(size=30)).astype(np.float32)
    patience, max_epochs = 15, 200
    fit = nn.fit_mlp(X, y, key=jax.random.key(3), decay=0.995, patience=patience, max_epochs=max_epochs)
    va = np.asarray(fit.validation_loss)
    assert fit.stopped_early
    assert fit.epochs_run == fit.best_epoch + patience + 1 < max_epochs
    assert fit.best_epoch < max_epochs - 1
    assert fit.best_epoch == int(np.argmin(va))
    # the returned weights are those of the best epoch, not the last
    vi = np.asarray(fit.validation_indices)
    val_mse = float(np.mean((np.asarray(fit.predict(X[vi])) - y[vi]) ** 2))
    assert val_mse == pytest.approx(float(va.min()), rel=1e-4)
    last = va[fit.epochs_run - 1]
    assert last > va.min() * 1.05  # it did overfit after the best epoch
    tr = np.asarray(fit.train_loss)
    assert tr[fit.epochs_run - 1] < tr[fit.best_epoch]  # ... while the training error kept falling


# --------------------------------------------------------------------------- errors


def _xy(n=20, D=3):
    rng = np.random.default_rng(0)
    return rng.normal(size=(n, D)), rng.normal(size=n)


def _bad(X=None, y=None, **kw):
    X0, y0 = _xy()
    return (X0 if X is None else X), (y0 if y is None else y), kw


def _with_nan_x():
    X, _ = _xy()
    X[7, 1] = np.nan
    return X


def _with_inf_y():
    _, y = _xy()
    y[4] = np.inf
    return y


@pytest.mark.parametrize(
    ("args", "exc", "match"),
    [
        (_bad(X=_with_nan_x()), ValueError, r"X holds NaN or inf; first bad row is 7"),
        (_bad(y=_with_inf_y()), ValueError, r"y holds NaN or inf; first bad row is 4"),
        (_bad(X=np.zeros(20)), ValueError, r"X must be 2-D"),
        (_bad(y=np.zeros((20, 1))), ValueError, r"y must be 1-D"),
        (_bad(y=np.zeros(19)), ValueError, r"same number of rows, got 20 and 19"),
        (_bad(X=np.zeros((2, 3)), y=np.zeros(2)), ValueError, r"too few points.*got 2, need at least 3"),
        (_bad(X=np.zeros((3, 3)), y=np.zeros(3), validation_fraction=0.5), ValueError, r"need at least 4"),
        (_bad(X=np.array([["a", "b"]] * 20)), TypeError, r"X must hold real numbers"),
        (_bad(hidden_units=0), ValueError, r"hidden_units must be an integer ≥ 1"),
        (_bad(hidden_units=2.5), TypeError, r"hidden_units"),
        (_bad(learning_rate=0.0), ValueError, r"learning_rate must be a finite number > 0"),
        (_bad(learning_rate=-0.1), ValueError, r"learning_rate"),
        (_bad(learning_rate=float("nan")), ValueError, r"learning_rate"),
        (_bad(decay=0.0), ValueError, r"decay must lie in \(0, 1\]"),
        (_bad(decay=1.01), ValueError, r"decay"),
        (_bad(validation_fraction=0.0), ValueError, r"validation_fraction must lie in \(0, 1\)"),
        (_bad(validation_fraction=1.0), ValueError, r"validation_fraction"),
        (_bad(max_epochs=0), ValueError, r"max_epochs"),
        (_bad(patience=0), ValueError, r"patience"),
    ],
)
def test_clear_errors(args, exc, match):
    X, y, kw = args
    with pytest.raises(exc, match=match):
        nn.fit_mlp(X, y, key=jax.random.key(0), **kw)


def test_min_points_for_split():
    assert nn.min_points_for_split(0.2) == 3
    assert nn.min_points_for_split(0.5) == 4
    for f in (0.1, 0.3, 0.5, 0.7, 0.9):
        n = nn.min_points_for_split(f)
        n_val = max(1, round(f * n))
        assert n - n_val >= 2 and n_val >= 1
        m = n - 1
        assert m < 3 or m - max(1, round(f * m)) < 2


def test_predict_errors(smooth):
    *_, fit = smooth
    with pytest.raises(ValueError, match=r"X_new must have shape \(m, 2\)"):
        fit.predict(np.zeros((4, 3)))
    bad = np.zeros((4, 2))
    bad[2, 0] = np.nan
    with pytest.raises(ValueError, match=r"X_new holds NaN or inf; first bad row is 2"):
        fit.predict(bad)
