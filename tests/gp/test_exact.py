"""Exact GP: log marginal likelihood, prediction and fit against scikit-learn; gradients; errors."""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.flatten_util import ravel_pytree
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process import kernels as skk

import jaxgaze.gp as gp
from jaxgaze.gp.kernels import Kernel
from jaxgaze.results import NAMES, OPTIMISTIX, RESULTS, FitError, code, from_optimistix, name, succeeded

JITTER = 1e-8  # ours (absolute) = sklearn's alpha


def _data(n=40, d=3, seed=1):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1.5, 1.5, (n, d))
    y = np.sin(2 * X[:, 0]) + 0.5 * X[:, 1] * X[:, -1] + 0.1 * rng.normal(size=n)
    Xs = rng.uniform(-2, 2, (9, d))
    return X, y, Xs


PAIRS = {
    "rq": (lambda: gp.RationalQuadratic(1.7, 0.8, 0.6), lambda: skk.ConstantKernel(1.7) * skk.RationalQuadratic(0.8, 0.6)),
    "rbf+white": (lambda: gp.RBF(0.9, 1.3) + gp.White(0.05), lambda: skk.ConstantKernel(0.9) * skk.RBF(1.3) + skk.WhiteKernel(0.05)),
    "linear+white": (lambda: gp.Linear(1.0, 0.5**2) + gp.White(0.2), lambda: skk.DotProduct(0.5) + skk.WhiteKernel(0.2)),
    "white": (lambda: gp.White(0.7), lambda: skk.WhiteKernel(0.7)),
    "rq+linear+white": (
        lambda: gp.RationalQuadratic(1.7, 0.8, 0.6) + gp.Linear(1.0, 0.3**2) + gp.White(0.02),
        lambda: skk.ConstantKernel(1.7) * skk.RationalQuadratic(0.8, 0.6) + skk.DotProduct(0.3) + skk.WhiteKernel(0.02),
    ),
    "ard-rbf+white": (
        lambda: gp.RBF(1.2, np.array([0.5, 1.0, 2.0])) + gp.White(0.1),
        lambda: skk.ConstantKernel(1.2) * skk.RBF(np.array([0.5, 1.0, 2.0])) + skk.WhiteKernel(0.1),
    ),
}


@pytest.mark.parametrize("name", list(PAIRS))
def test_lml_and_prediction_match_sklearn(x64, name):
    ours, theirs = PAIRS[name][0](), PAIRS[name][1]()
    X, y, Xs = _data()
    model = GaussianProcessRegressor(theirs, optimizer=None, alpha=JITTER).fit(X, y)
    lml = gp.log_marginal_likelihood(ours, X, y, jitter=JITTER)
    np.testing.assert_allclose(lml, model.log_marginal_likelihood(model.kernel_.theta), rtol=1e-9, atol=1e-6)
    mean, var = gp.predict(ours, X, y, Xs, jitter=JITTER)
    sk_mean, sk_std = model.predict(Xs, return_std=True)
    np.testing.assert_allclose(mean, sk_mean, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.sqrt(var), sk_std, rtol=1e-6, atol=1e-6)
    mean_c, cov = gp.predict(ours, X, y, Xs, jitter=JITTER, full_covariance=True)
    _, sk_cov = model.predict(Xs, return_cov=True)
    np.testing.assert_allclose(mean_c, sk_mean, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(cov, sk_cov, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.diag(cov), var, rtol=1e-9, atol=1e-9)


def test_lml_gradient_matches_finite_differences_and_sklearn(x64):
    X, y, _ = _data(n=30)
    kernel = gp.RationalQuadratic(1.3, 0.7, 0.9) + gp.Linear(1.0, 0.4, fixed="variance") + gp.White(0.05)
    params, static = eqx.partition(kernel, kernel.trainable_filter())
    theta, unravel = ravel_pytree(params)

    def f(t):
        return gp.log_marginal_likelihood(eqx.combine(unravel(t), static), X, y, jitter=JITTER)

    grad = np.asarray(jax.grad(f)(theta))
    h = 1e-5
    fd = np.array([(f(theta.at[i].add(h)) - f(theta.at[i].add(-h))) / (2 * h) for i in range(theta.size)])
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-6)
    # sklearn's analytic gradient in its log-parameters; its order is sorted by name:
    # constant, RQ alpha, RQ length_scale, DotProduct sigma_0 (log σ0 = raw/2), noise.
    sk = skk.ConstantKernel(1.3) * skk.RationalQuadratic(0.7, 0.9) + skk.DotProduct(0.4**0.5) + skk.WhiteKernel(0.05)
    model = GaussianProcessRegressor(sk, optimizer=None, alpha=JITTER).fit(X, y)
    _, sk_grad = model.log_marginal_likelihood(model.kernel_.theta, eval_gradient=True)
    v, ls, a, b, w = grad  # ours: RQ variance, lengthscale, alpha; Linear bias_variance; White variance
    np.testing.assert_allclose([v, a, ls, 2 * b, w], sk_grad, rtol=1e-6, atol=1e-6)


def test_float32_follows_inputs_and_agrees_with_float64():
    X, y, Xs = _data()
    kernel = gp.RBF(0.9, 1.3) + gp.White(0.05)
    X32, y32 = X.astype(np.float32), y.astype(np.float32)
    lml32 = gp.log_marginal_likelihood(kernel, X32, y32)
    mean32, var32 = gp.predict(kernel, X32, y32, Xs.astype(np.float32))
    assert lml32.dtype == jnp.float32 and mean32.dtype == jnp.float32 and var32.dtype == jnp.float32
    with jax.enable_x64(True):
        k64 = gp.RBF(0.9, 1.3) + gp.White(0.05)
        lml64 = gp.log_marginal_likelihood(k64, X, y)
        mean64, _ = gp.predict(k64, X, y, Xs)
        assert lml64.dtype == jnp.float64
    np.testing.assert_allclose(lml32, lml64, rtol=1e-4)
    np.testing.assert_allclose(mean32, mean64, rtol=1e-3, atol=1e-3)


# -- fit ----------------------------------------------------------------------------------

TRUE = {"variance": 1.5, "lengthscale": 0.6, "noise": 0.05}


@pytest.fixture(scope="module")
def gp_sample():
    """200 points from a GP with RBF(1.5, 0.6) + White(0.05) on [−2, 2]², float64."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(7)
        X = rng.uniform(-2, 2, (200, 2))
        K = np.asarray(gp.RBF(TRUE["variance"], TRUE["lengthscale"])(jnp.asarray(X)))
        f = np.linalg.cholesky(K + 1e-10 * np.eye(200)) @ rng.normal(size=200)
        y = f + np.sqrt(TRUE["noise"]) * rng.normal(size=200)
        # ours: a fixed unit Constant times RBF (checks fixed parameters and products in fit)
        kernel = gp.Constant(1.0, fixed=("variance",)) * gp.RBF(1.0, 1.0) + gp.White(1.0)
        fitted = gp.fit(kernel, X, y, key=jax.random.key(0))
        jax.block_until_ready(fitted.alpha)
        sk = GaussianProcessRegressor(
            skk.ConstantKernel() * skk.RBF() + skk.WhiteKernel(), n_restarts_optimizer=3, random_state=0
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sk.fit(X, y)
    return X, y, fitted, sk


def test_fit_recovers_hyperparameters(x64, gp_sample):
    _, _, fitted, _ = gp_sample
    assert fitted.result == RESULTS.successful, fitted.message
    const, rbf = fitted.kernel.kernels[0].kernels
    white = fitted.kernel.kernels[1]
    assert float(const.variance) == 1.0  # fixed
    assert 0.5 < float(rbf.variance) / TRUE["variance"] < 2.0
    assert 0.7 < float(rbf.lengthscale) / TRUE["lengthscale"] < 1.4
    assert 0.75 < float(white.variance) / TRUE["noise"] < 1.33
    assert fitted.stages[-1][:2] == (200, "float64")


def test_fit_reaches_sklearn_likelihood(x64, gp_sample):
    X, y, fitted, sk = gp_sample
    assert float(fitted.log_marginal_likelihood) >= sk.log_marginal_likelihood_value_ - 1e-3
    # Same objective: sklearn at our optimum agrees with ours (up to the jitter difference).
    rbf = fitted.kernel.kernels[0].kernels[1]
    theta = np.log([float(rbf.variance), float(rbf.lengthscale), float(fitted.kernel.kernels[1].variance)])
    np.testing.assert_allclose(sk.log_marginal_likelihood(theta), fitted.log_marginal_likelihood, atol=1e-3)
    # The reported LML is the exact one at the returned kernel, and the cached factor predicts.
    np.testing.assert_allclose(
        fitted.log_marginal_likelihood, gp.log_marginal_likelihood(fitted.kernel, X, y, jitter=fitted.jitter), rtol=1e-12
    )
    Xs = X[:5] + 0.1
    mean, var = fitted.predict(Xs)
    ref_mean, ref_var = gp.predict(fitted.kernel, X, y, Xs, jitter=fitted.jitter)
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-9)
    np.testing.assert_allclose(var, ref_var, rtol=1e-9)
    sk_mean, sk_std = sk.predict(Xs, return_std=True)
    np.testing.assert_allclose(mean, sk_mean, atol=0.02)
    np.testing.assert_allclose(np.sqrt(var), sk_std, rtol=0.05)


# -- errors -------------------------------------------------------------------------------


class _Indefinite(Kernel):
    """−xᵀy − 1: negative definite, no parameters."""

    def evaluate(self, x1, x2):
        return -jnp.dot(x1, x2) - 1.0


@pytest.mark.parametrize("call", ["lml", "predict", "fit"])
def test_bad_data_raise_clear_errors(call):
    X, y, Xs = _data(n=10)
    kernel = gp.RBF() + gp.White(0.1)

    def run(X, y, Xs=Xs):
        if call == "lml":
            return gp.log_marginal_likelihood(kernel, X, y)
        if call == "predict":
            return gp.predict(kernel, X, y, Xs)
        return gp.fit(kernel, X, y, key=jax.random.key(0))

    bad = X.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"X contains NaN or inf \(first bad row: 3\)"):
        run(bad, y)
    bad_y = y.copy()
    bad_y[5] = np.inf
    with pytest.raises(ValueError, match=r"y contains NaN or inf \(first bad index: 5\)"):
        run(X, bad_y)
    with pytest.raises(ValueError, match="X must be 2-D"):
        run(X[:, 0], y)
    with pytest.raises(ValueError, match=r"y must be 1-D.*ravel"):
        run(X, y[:, None])
    with pytest.raises(ValueError, match="X has 10 rows, y has 9 entries"):
        run(X, y[:9])
    with pytest.raises(ValueError, match="at least 2 training points, got 1"):
        run(X[:1], y[:1])
    if call == "predict":
        with pytest.raises(ValueError, match="X_new has 2 features but the training X has 3"):
            run(X, y, Xs[:, :2])
    with pytest.raises(ValueError, match="lengthscale has 2 entries"):
        gp.log_marginal_likelihood(gp.RBF(1.0, np.ones(2)), X, y)
    with pytest.raises(ValueError, match="jitter"):
        gp.log_marginal_likelihood(kernel, X, y, jitter=-1.0)


def test_fit_argument_errors():
    X, y, _ = _data(n=10)
    kernel = gp.RBF() + gp.White(0.1)
    with pytest.raises(ValueError, match="num_restarts"):
        gp.fit(kernel, X, y, key=jax.random.key(0), num_restarts=0)
    with pytest.raises(ValueError, match="method"):
        gp.fit(kernel, X, y, key=jax.random.key(0), method="adam")
    with pytest.raises(TypeError, match="kernel"):
        gp.fit("rbf", X, y, key=jax.random.key(0))


def test_not_positive_definite_is_reported_with_the_jitter(x64):
    X, y, Xs = _data(n=10)
    with pytest.raises(ValueError, match=r"not positive definite even with jitter 1e-06"):
        gp.log_marginal_likelihood(_Indefinite(), X, y, jitter=1e-6)
    with pytest.raises(ValueError, match=r"not positive definite even with jitter .*default"):
        gp.predict(_Indefinite(), X, y, Xs)
    fitted = gp.fit(_Indefinite(), X, y, key=jax.random.key(0))
    assert fitted.result == RESULTS.not_positive_definite
    assert "jitter" in fitted.message
    with pytest.raises(ValueError, match="failed fit"):
        fitted.predict(Xs)
    with pytest.raises(RuntimeError, match="not positive definite"):
        gp.fit(_Indefinite(), X, y, key=jax.random.key(0), throw=True)
    # Under jit the check is an equinox runtime error.
    with pytest.raises(Exception, match="not positive definite"):
        jax.block_until_ready(jax.jit(lambda X, y: gp.log_marginal_likelihood(_Indefinite(), X, y))(X, y))


def test_a_failed_fit_is_its_result_and_throw_carries_the_fitted_gp(x64):
    """One spelling of success (``succeeded``), and ``throw=True`` loses nothing: the FitError holds the fit."""
    X, y, _ = _data(n=10)
    fitted = gp.fit(_Indefinite(), X, y, key=jax.random.key(0))
    assert succeeded(fitted) is False and fitted.result == RESULTS.not_positive_definite
    with pytest.raises(FitError, match="not positive definite") as error:
        gp.fit(_Indefinite(), X, y, key=jax.random.key(0), throw=True)
    assert isinstance(error.value.fit, gp.FittedGP) and error.value.result == RESULTS.not_positive_definite
    assert error.value.fit.result == fitted.result and error.value.fit.jitter == fitted.jitter
    np.testing.assert_array_equal(error.value.fit.cholesky, fitted.cholesky)


def test_optimistix_results_map_to_ours_through_one_table():
    """Every ``optimistix.RESULTS`` member maps through ``OPTIMISTIX`` (others: ``optimiser_failed``),
    concrete, batched and under ``jit``."""
    import optimistix as optx

    theirs = ["successful", "max_steps_reached", "singular", "breakdown", "stagnation", "conlim", "nonfinite_input",
              "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite"]  # optimistix 0.1's members
    for member in theirs:
        ours = from_optimistix(getattr(optx.RESULTS, member))
        assert name(ours) == OPTIMISTIX.get(member, "optimiser_failed"), member
    batch = jax.jit(jax.vmap(lambda ok: from_optimistix(optx.RESULTS.where(
        ok, optx.RESULTS.nonlinear_max_steps_reached, optx.RESULTS.nonlinear_divergence))))(jnp.array([True, False]))
    assert [NAMES[c] for c in np.asarray(code(batch))] == ["max_steps_reached", "optimiser_failed"]
    np.testing.assert_array_equal(succeeded(from_optimistix(optx.RESULTS.successful)), True)


def test_fit_float32_data_with_both_methods():
    """Float32 data fit in float32 throughout; Fisher scoring and whitened BFGS agree."""
    X, y, Xs = _data(n=80, d=2, seed=3)
    X, y = X.astype(np.float32), y.astype(np.float32)
    kernel = gp.RBF() + gp.White(1.0)
    fits = [gp.fit(kernel, X, y, key=jax.random.key(1), method=m, num_restarts=2) for m in ("fisher", "bfgs")]
    for fitted in fits:
        assert fitted.result == RESULTS.successful, fitted.message
        assert [s[1] for s in fitted.stages] == ["float32"]
        assert fitted.log_marginal_likelihood.dtype == jnp.float32
        assert fitted.predict(Xs.astype(np.float32))[0].dtype == jnp.float32
        assert 0.005 < float(fitted.kernel.kernels[1].variance) < 0.02  # noise 0.1² in _data
    np.testing.assert_allclose(fits[0].log_marginal_likelihood, fits[1].log_marginal_likelihood, atol=0.05)


@pytest.mark.parametrize("n", [57, 520])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_upper_inverse_from_cholesky_is_the_triangle_of_the_inverse(x64, dtype, n):
    # n = 57 takes XLA's triangular solves, n = 520 LAPACK potri in a host callback (CPU).
    from jaxgaze.gp._linalg import _HOST_POTRI_MIN_SIZE, _trace_weights, _upper_inverse_from_cholesky

    rng = np.random.default_rng(3)
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    L = jnp.linalg.cholesky(jnp.asarray(K, dtype))
    upper = np.asarray(jax.jit(_upper_inverse_from_cholesky)(L))
    assert upper.dtype == np.dtype(dtype)
    tol = dict(rtol=1e-4, atol=1e-8) if dtype == "float32" else dict(rtol=1e-10, atol=1e-14)
    np.testing.assert_array_equal(np.tril(upper, -1), 0.0)
    np.testing.assert_allclose(upper, np.triu(np.linalg.inv(K)), **tol)
    # The trace weights give tr(K⁻¹ S) for a symmetric S.
    S = rng.normal(size=(n, n))
    S = S + S.T
    weights = np.asarray(_trace_weights(jnp.asarray(upper)))
    np.testing.assert_allclose(np.vdot(weights, S), np.trace(np.linalg.solve(K, S)), **tol)
    assert np.isnan(np.asarray(_upper_inverse_from_cholesky(L.at[5, 5].set(0.0)))).all()
    batched = jax.vmap(_upper_inverse_from_cholesky)(jnp.stack([L, 2 * L]))
    np.testing.assert_allclose(batched[1], upper / 4, rtol=1e-5 if dtype == "float32" else 1e-12)
    # Only the large size has a host callback: JAX's persistent cache stores no program that has one.
    host_call = jax.default_backend() == "cpu" and n >= _HOST_POTRI_MIN_SIZE
    assert ("callback" in jax.jit(_upper_inverse_from_cholesky).lower(L).as_text()) == host_call


def test_lml_hessian_matches_finite_differences_of_the_gradient(x64):
    # Second derivatives go through the triangle's own JVP rule (forward over reverse).
    X, y, _ = _data(n=40)
    kernel = gp.RationalQuadratic(0.8, 0.7, 1.5) + gp.Linear(0.5, 0.3) + gp.White(0.05)
    template, static = eqx.partition(kernel, kernel.trainable_filter())
    theta, unravel = ravel_pytree(template)

    def lml(t):
        return gp.log_marginal_likelihood(eqx.combine(unravel(t), static), X, y)

    hessian = np.asarray(jax.jit(jax.hessian(lml))(theta))
    grad = jax.jit(jax.grad(lml))  # compiled once for the 2 × 6 evaluations below
    h = 1e-5
    columns = [(np.asarray(grad(theta + h * e)) - np.asarray(grad(theta - h * e))) / (2 * h) for e in np.eye(theta.size)]
    np.testing.assert_allclose(hessian, np.stack(columns, axis=1), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(hessian, hessian.T, rtol=1e-10, atol=1e-10)


def test_optimise_reports_the_objective_at_its_optimum(x64):
    # A float64 stage returns the solver's own last evaluation as its value (no re-evaluation):
    # it must be the objective at the returned parameters.
    from jaxgaze.gp import _fit

    X, y, _ = _data(n=60)
    kernel = gp.RationalQuadratic() + gp.White(0.1)
    template, static = eqx.partition(kernel, kernel.trainable_filter())
    theta, _ = ravel_pytree(template)
    X, y = jnp.asarray(X), jnp.asarray(y)
    for method in ("bfgs", "fisher"):
        out = _fit._optimise(theta[None], template, static, X, y, None, jax.random.key(0), 50, 1e-3, method)
        fn = _fit._objective(template, static, X, y, None)
        assert bool(succeeded(out.result)[0]) and int(out.steps[0]) > 1
        np.testing.assert_allclose(out.value[0], fn(out.theta[0], None), rtol=1e-10)


def test_fit_progress_bar_counts_evaluations_and_changes_nothing(monkeypatch, capsys):
    from tqdm import tqdm

    from jaxgaze import _progress

    class RecordingBar(tqdm):
        made = []

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.descriptions, self.count = [], 0
            RecordingBar.made.append(self)

        def set_description_str(self, desc=None, refresh=True):
            self.descriptions.append(desc)
            super().set_description_str(desc, refresh)

        def update(self, n=1):
            self.count += n
            return super().update(n)

    # The data, kernel and restarts of test_fit_float32_data_with_both_methods: one float32 stage,
    # whose programs that test has compiled already.
    X, y, _ = _data(n=80, d=2, seed=3)
    X, y = X.astype(np.float32), y.astype(np.float32)
    kernel = gp.RBF() + gp.White(1.0)
    monkeypatch.setattr(_progress, "tqdm", RecordingBar)
    quiet = gp.fit(kernel, X, y, key=jax.random.key(2), num_restarts=2)
    assert RecordingBar.made[0].disable and capsys.readouterr().err == ""  # no bar shown without progress
    shown = gp.fit(kernel, X, y, key=jax.random.key(2), num_restarts=2, progress=True)
    assert shown.stages == quiet.stages == ((80, "float32", shown.stages[0][2]),)
    assert float(shown.log_marginal_likelihood) == float(quiet.log_marginal_likelihood)
    bar = RecordingBar.made[1]
    assert bar.descriptions == ["GP fit, stage 1/1 (80 points, float32)"]
    # One evaluation per optimiser step, plus each start's own and its float32 re-evaluation.
    assert shown.stages[0][2] < bar.count <= shown.stages[0][2] + 2 * 2
    assert "GP fit, stage 1/1 (80 points, float32): " in capsys.readouterr().err
    assert _progress._current is None


@settings(max_examples=300, deadline=None)
@given(n=st.integers(2, 100_000), first=st.integers(8, 1024))
def test_stage_sizes_grow_to_all_data_with_a_last_subset_between_n_over_2_5_and_n_over_1_5(n, first):
    from jaxgaze.gp._fit import _stage_sizes

    sizes = _stage_sizes(n, first)
    assert sizes[0] == min(n, first) and sizes[-1] == n
    assert all(b > a for a, b in zip(sizes, sizes[1:]))
    assert all(b in (2 * a, 4 * a) for a, b in zip(sizes[:-1], sizes[1:-1]))  # ×4 steps, at most one ×2
    assert sum(b == 2 * a for a, b in zip(sizes[:-1], sizes[1:-1])) <= 1
    if len(sizes) > 1:
        last = sizes[-2]
        assert len(sizes) == 2 or 1.5 * last <= n  # a grown subset leaves at least a third of the data out
        # below n/2.5 only when doubling it would pass n/1.5
        assert 2.5 * last >= n or 2 * last * 1.5 > n
    assert _stage_sizes(1000, 256) == [256, 512, 1000] and _stage_sizes(2000, 256) == [256, 1024, 2000]
