"""Kernels of jaxgaze.gp: scikit-learn equivalence, closed forms, algebra, ARD, PSD, errors."""

import math

import equinox as eqx
import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.gaussian_process import kernels as skk

import jaxgaze.gp as gp
from jaxgaze.gp.kernels import Kernel
from jaxgaze.gp.transforms import POSITIVE_FLOOR, positive, unconstrain_positive

RNG = np.random.default_rng(0)
XA = RNG.normal(size=(7, 3))
XB = RNG.normal(size=(4, 3))


# -- scikit-learn equivalence -----------------------------------------------------------

SKLEARN_PAIRS = [
    (lambda: gp.RationalQuadratic(1.7, 0.8, 0.6), lambda: skk.ConstantKernel(1.7) * skk.RationalQuadratic(0.8, 0.6)),
    (lambda: gp.RBF(0.9, 1.3), lambda: skk.ConstantKernel(0.9) * skk.RBF(1.3)),
    (lambda: gp.Linear(1.0, 0.5**2), lambda: skk.DotProduct(sigma_0=0.5)),
    (lambda: gp.White(0.3), lambda: skk.WhiteKernel(0.3)),
    (lambda: gp.Constant(2.5), lambda: skk.ConstantKernel(2.5)),
    (
        lambda: gp.RationalQuadratic(1.7, 0.8, 0.6) + gp.Linear(1.0, 0.25) + gp.White(0.3),
        lambda: skk.ConstantKernel(1.7) * skk.RationalQuadratic(0.8, 0.6) + skk.DotProduct(0.5) + skk.WhiteKernel(0.3),
    ),
    (
        lambda: gp.RBF(0.9, np.array([0.5, 1.0, 2.0])) + gp.White(0.1),
        lambda: skk.ConstantKernel(0.9) * skk.RBF(np.array([0.5, 1.0, 2.0])) + skk.WhiteKernel(0.1),
    ),
    (lambda: 2.0 * gp.RBF(1.0, 0.7), lambda: skk.ConstantKernel(2.0) * skk.RBF(0.7)),
    (
        lambda: gp.Constant(1.5) * (gp.RBF(1.0, 0.7) + gp.White(0.2)),
        lambda: skk.ConstantKernel(1.5) * (skk.RBF(0.7) + skk.WhiteKernel(0.2)),
    ),
]


@pytest.mark.parametrize("ours, theirs", SKLEARN_PAIRS)
def test_kernel_matrices_match_sklearn(x64, ours, theirs):
    k, s = ours(), theirs()
    np.testing.assert_allclose(k(jnp.asarray(XA)), s(XA), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(k(jnp.asarray(XA), jnp.asarray(XB)), s(XA, XB), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(k.diag(jnp.asarray(XA)), s.diag(XA), rtol=1e-12, atol=1e-12)


def test_white_is_noise_on_the_same_set_only(x64):
    w = gp.White(0.3)
    X = jnp.asarray(XA)
    np.testing.assert_allclose(w(X), 0.3 * np.eye(7), atol=1e-15)
    np.testing.assert_array_equal(w(X, X), np.zeros((7, 7)))  # a second argument is another set
    np.testing.assert_allclose(w.diag(X), np.full(7, 0.3))
    assert w.has_noise and w.is_noise_only
    k = gp.RBF() + w
    np.testing.assert_allclose(k(X) - k(X, X), 0.3 * np.eye(7), atol=1e-12)


# -- closed forms -------------------------------------------------------------------------


def test_arcsine_hand_computed_values(x64):
    # (σw² xᵀy + σb²) / sqrt((σw² xᵀx + σb² + 1)(σw² yᵀy + σb² + 1)), times σ² 2/π asin.
    k = gp.ArcSine(variance=1.0, weight_variance=1.0, bias_variance=1.0)
    e1, e2 = jnp.array([1.0, 0.0]), jnp.array([0.0, 1.0])
    # x=(1,0), y=(0,1): 1 / sqrt(3·3) = 1/3 → (2/π) asin(1/3)
    np.testing.assert_allclose(k.evaluate(e1, e2), 0.21634689593878545, rtol=1e-12)
    # x = y = (1,0): 2/3 → (2/π) asin(2/3)
    np.testing.assert_allclose(k.evaluate(e1, e1), 0.46455905439753997, rtol=1e-12)
    # σ²=3, σw²=0.5, σb²=2, x=(1,2), y=(−1,1): 2.5 / sqrt(5.5·4) → 3 (2/π) asin(2.5/√22)
    k2 = gp.ArcSine(variance=3.0, weight_variance=0.5, bias_variance=2.0)
    np.testing.assert_allclose(k2.evaluate(jnp.array([1.0, 2.0]), jnp.array([-1.0, 1.0])), 1.073616633710025, rtol=1e-12)
    X = jnp.array([[1.0, 2.0], [-1.0, 1.0]])
    np.testing.assert_allclose(k2(X)[0, 1], 1.073616633710025, rtol=1e-12)


def test_rational_quadratic_tends_to_rbf(x64):
    X = jnp.asarray(XA)
    np.testing.assert_allclose(gp.RationalQuadratic(1.3, 0.9, 1e8)(X), gp.RBF(1.3, 0.9)(X), rtol=1e-5)


# -- algebra, ARD, the vectorised matrices --------------------------------------------------


def test_sum_and_product_compose(x64):
    X1, X2 = jnp.asarray(XA), jnp.asarray(XB)
    a, b, c = gp.RBF(1.2, 0.7), gp.Linear(0.4, 0.2), gp.ArcSine(0.8, 0.5, 1.5)
    np.testing.assert_allclose((a + b + c)(X1, X2), a(X1, X2) + b(X1, X2) + c(X1, X2), rtol=1e-12)
    np.testing.assert_allclose((a * b)(X1, X2), a(X1, X2) * b(X1, X2), rtol=1e-12)
    np.testing.assert_allclose((3.0 * a)(X1), 3.0 * a(X1), rtol=1e-12)
    np.testing.assert_allclose((a + 0.5)(X1), a(X1) + 0.5, rtol=1e-12)
    assert len((a + b + c).kernels) == 3  # sums flatten
    # A product's noise diagonal: (k1 + n1)(k2 + n2) on the diagonal, k1 k2 off it.
    w = gp.White(0.3)
    prod = (a + w) * (b + w)
    expected = (a(X1) + 0.3 * np.eye(7)) * (b(X1) + 0.3 * np.eye(7))
    np.testing.assert_allclose(prod(X1), expected, rtol=1e-12)
    np.testing.assert_allclose(prod.diag(X1), np.diag(expected), rtol=1e-12)


@pytest.mark.parametrize(
    "scalar, vector",
    [
        (lambda: gp.RBF(1.1, 0.7), lambda: gp.RBF(1.1, np.full(3, 0.7))),
        (lambda: gp.RationalQuadratic(1.1, 0.7, 2.0), lambda: gp.RationalQuadratic(1.1, np.full(3, 0.7), 2.0)),
        (lambda: gp.ArcSine(1.1, 0.4, 0.9), lambda: gp.ArcSine(1.1, np.full(3, 0.4), 0.9)),
        (lambda: gp.Linear(0.6, 0.3), lambda: gp.Linear(np.full(3, 0.6), 0.3)),
    ],
)
def test_ard_with_equal_entries_equals_scalar(x64, scalar, vector):
    X1, X2 = jnp.asarray(XA), jnp.asarray(XB)
    np.testing.assert_allclose(vector()(X1, X2), scalar()(X1, X2), rtol=1e-12)


def test_ard_lengthscales_scale_each_feature(x64):
    X = jnp.asarray(XA)
    ls = np.array([0.5, 1.0, 2.0])
    np.testing.assert_allclose(gp.RBF(1.0, ls)(X), gp.RBF(1.0, 1.0)(X / ls), rtol=1e-12)


ALL_KERNELS = [
    lambda: gp.RBF(1.2, np.array([0.5, 1.0, 2.0])),
    lambda: gp.RationalQuadratic(0.7, 0.9, 0.4),
    lambda: gp.ArcSine(1.5, np.array([0.3, 0.6, 0.9]), 0.7),
    lambda: gp.Linear(np.array([0.5, 1.0, 2.0]), 0.3),
    lambda: gp.White(0.2),
    lambda: gp.Constant(0.8),
    lambda: gp.gaze_direction_kernel(3) * gp.Constant(0.5) + gp.target_depth_kernel(3),
]


@pytest.mark.parametrize("make", ALL_KERNELS)
def test_vectorised_matrix_equals_vmap_of_evaluate(x64, make):
    kernel = make()
    X1, X2 = jnp.asarray(XA), jnp.asarray(XB)
    reference = Kernel._cross(kernel, X1, X2)  # the base class: double vmap of evaluate
    np.testing.assert_allclose(kernel(X1, X2), reference, rtol=1e-12, atol=1e-14)


@settings(max_examples=40, deadline=None)
@given(
    X=hnp.arrays(np.float64, st.tuples(st.integers(2, 8), st.integers(1, 3)), elements=st.floats(-3, 3)),
    logs=st.lists(st.floats(-2, 2), min_size=4, max_size=4),
    which=st.integers(0, 4),
)
def test_kernel_matrices_are_symmetric_and_psd(X, logs, which):
    with jax.enable_x64(True):
        v, ls, a, b = np.exp(logs)
        kernel = [
            gp.RBF(v, ls),
            gp.RationalQuadratic(v, ls, a),
            gp.ArcSine(v, a, b),
            gp.Linear(v, b),
            gp.RationalQuadratic(v, ls, a) + gp.ArcSine(v, a, b) * gp.Linear(v, b),
        ][which]
        K = np.asarray(kernel(jnp.asarray(X)))
        np.testing.assert_allclose(K, K.T, rtol=1e-12, atol=1e-12)
        scale = max(1.0, float(np.abs(K).max()))
        assert np.linalg.eigvalsh(K).min() >= -1e-9 * scale


def test_kernels_work_under_jit_and_grad(x64):
    k = gp.RationalQuadratic(1.0, 0.8, 1.5) + gp.Linear(0.5, 0.2) + gp.White(0.1)
    X = jnp.asarray(XA)
    np.testing.assert_allclose(jax.jit(lambda k, X: k(X))(k, X), k(X), rtol=1e-12)
    params, static = eqx.partition(k, k.trainable_filter())
    grads = jax.grad(lambda p: jnp.sum(eqx.combine(p, static)(X)))(params)
    # d/d raw_variance of Σ K for White is n·σ² (= Σ diag), and σ² = exp(raw) + floor.
    np.testing.assert_allclose(grads.kernels[2].raw_variance, 7 * (0.1 - POSITIVE_FLOOR), rtol=1e-9)


# -- parameters ----------------------------------------------------------------------------


def test_parameters_round_trip_and_fixed_filter(x64):
    k = gp.RationalQuadratic(2.0, np.array([0.3, 4.0]), 0.5)
    np.testing.assert_allclose(k.variance, 2.0, rtol=1e-12)
    np.testing.assert_allclose(k.lengthscale, [0.3, 4.0], rtol=1e-12)
    np.testing.assert_allclose(k.alpha, 0.5, rtol=1e-12)
    for value in (1e-8, 1.0, 3e5):
        np.testing.assert_allclose(positive(unconstrain_positive(value)), value, rtol=1e-10)
    lin = gp.Linear(1.0, 0.3, fixed=("variance",))
    spec = (gp.RBF() + lin).trainable_filter()
    assert spec.kernels[1].raw_variance is False and spec.kernels[1].raw_bias_variance is True
    assert spec.kernels[0].raw_lengthscale is True
    names = (gp.RBF() + lin).hyperparameters()
    assert set(names) == {"0.RBF.variance", "0.RBF.lengthscale", "1.Linear.variance", "1.Linear.bias_variance"}


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda: gp.RBF(-1.0), ["RBF", "variance", "positive"]),
        (lambda: gp.RBF(1.0, 0.0), ["RBF", "lengthscale", "positive"]),
        (lambda: gp.RationalQuadratic(1.0, 1.0, float("nan")), ["RationalQuadratic", "alpha"]),
        (lambda: gp.ArcSine(1.0, np.array([1.0, -2.0])), ["ArcSine", "weight_variance"]),
        (lambda: gp.White(float("inf")), ["White", "variance"]),
        (lambda: gp.Linear(1.0, np.ones(2)), ["Linear", "bias_variance", "scalar"]),
        (lambda: gp.RBF(1.0, np.ones((2, 2))), ["RBF", "lengthscale", "vector"]),
        (lambda: gp.Linear(1.0, 1.0, fixed=("slope",)), ["Linear", "slope"]),
        (lambda: -2.0 * gp.RBF(), ["Constant", "variance"]),
        (lambda: gp.gaze_direction_kernel(0), ["num_features"]),
    ],
)
def test_bad_parameters_raise(make, words):
    with pytest.raises(ValueError) as err:
        make()
    for word in words:
        assert word in str(err.value)


def test_ard_length_must_match_features():
    with pytest.raises(ValueError, match="lengthscale has 2 entries"):
        gp.RBF(1.0, np.ones(2)).check_input_dim(3)
    with pytest.raises(TypeError):
        gp.RBF() + "a"


def test_paper_kernels_structure():
    f1 = gp.gaze_direction_kernel(3)
    assert [type(k).__name__ for k in f1.kernels] == ["RationalQuadratic", "ArcSine", "White"]
    np.testing.assert_allclose(f1.kernels[0].lengthscale, math.sqrt(3), rtol=1e-6)
    np.testing.assert_allclose(f1.kernels[1].weight_variance, 1 / 3, rtol=1e-6)
    f2 = gp.target_depth_kernel(4, ard=True)
    assert [type(k).__name__ for k in f2.kernels] == ["Linear", "White"]
    assert f2.kernels[0].variance.shape == (4,)
