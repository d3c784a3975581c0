"""Saving and loading gaze regressions (jaxgaze.io.models): round trips and clear errors."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.gp.exact import fitted_gp
from jaxgaze.io.models import (
    FORMAT,
    VERSION,
    ModelFileError,
    kernel_from_json,
    kernel_to_json,
    load_gaze_regression,
    read_model_metadata,
    register_kernel,
    save_gaze_regression,
)
from jaxgaze.gp.kernels import RBF, ArcSine, Constant, Linear, Product, RationalQuadratic, Sum, White
from jaxgaze.headpose.nn import MLPFit, Standardisation, init_mlp_params
from jaxgaze.headpose.regression import GazeRegression, NNGazeRegression, Scaling
from jaxgaze.results import RESULTS


def _gp(kernel, X, y):
    """A FittedGP at the given hyperparameters (no optimisation: the tests need the file format, not a fit)."""
    dtype = jnp.asarray(np.zeros(1)).dtype
    return fitted_gp(kernel, jnp.asarray(X, dtype), jnp.asarray(y, dtype), None, RESULTS.successful,
                   jnp.asarray([-10.5, np.nan], dtype), ((40, "float32", 7), (len(X), "float64", 3)), False)


def _regression(f1_kernel=None, f2_kernel=None, n=40):
    rng = np.random.default_rng(0)
    pose = rng.normal(0.0, 0.3, (n, 3))
    direction = 1.5 + pose @ [0.2, 1.0, 0.1] + 0.05 * rng.normal(size=n)
    depth = 150.0 - 60.0 * pose[:, 0] + 2.0 * rng.normal(size=n)
    features, s1, s2 = Scaling.of(pose), Scaling.of(direction), Scaling.of(depth)
    Z = features.apply(pose)
    f1_kernel = f1_kernel or (RationalQuadratic(0.8, np.array([1.1, 1.7, 2.3]), 0.7)
                              + ArcSine(0.5, 0.3, 0.9) + White(0.05))
    f2_kernel = f2_kernel or (Product(Constant(2.0, fixed=("variance",)), RBF(1.0, 1.5))
                              + Linear(np.array([0.3, 0.2, 0.1]), 0.4, fixed=("bias_variance",)) + White(0.1))
    return GazeRegression(_gp(f1_kernel, Z, s1.apply(direction)), _gp(f2_kernel, Z, s2.apply(depth)), features, s1,
                          s2), pose


def _assert_same_prediction(a, b, X, tol):
    for x, y in zip(a.predict(X), b.predict(X)):
        if x is None:
            assert y is None
        else:
            np.testing.assert_allclose(np.asarray(y), np.asarray(x), rtol=0, atol=tol)


def test_gp_round_trip_predicts_the_same_in_float64(tmp_path, x64):
    model, pose = _regression()
    path = tmp_path / "gp.json"
    save_gaze_regression(path, model, metadata={"focal_px": 315.5, "fps": 10.0, "window": 4})
    loaded, metadata = load_gaze_regression(path, with_metadata=True)
    assert metadata == {"focal_px": 315.5, "fps": 10.0, "window": 4}
    assert loaded.direction_gp.X.dtype == jnp.float64
    X = np.concatenate([pose, np.random.default_rng(1).normal(0, 0.4, (25, 3))])
    _assert_same_prediction(model, loaded, X, 1e-10)
    for old, new in ((model.direction_gp, loaded.direction_gp), (model.depth_gp, loaded.depth_gp)):
        assert type(new.kernel) is type(old.kernel)
        assert [type(k) for k in new.kernel.kernels] == [type(k) for k in old.kernel.kernels]
        for name, value in old.kernel.hyperparameters().items():
            np.testing.assert_array_equal(np.asarray(new.kernel.hyperparameters()[name]), np.asarray(value))
        assert new.result == old.result and new.jitter == old.jitter and new.stages == old.stages
        assert float(new.log_marginal_likelihood) == pytest.approx(float(old.log_marginal_likelihood), rel=1e-12)
        np.testing.assert_allclose(np.asarray(new.cholesky), np.asarray(old.cholesky), rtol=0, atol=1e-12)
    # Structure and fixed parameters survive: Product(Constant fixed, RBF) + Linear(bias fixed) + White.
    product, linear, _ = loaded.depth_gp.kernel.kernels
    assert isinstance(product, Product) and product.kernels[0].fixed == ("variance",)
    assert linear.fixed == ("bias_variance",)
    assert np.shape(linear.variance) == (3,)
    for field in ("features", "direction_scaling", "depth_scaling"):
        for a, b in zip(getattr(model, field), getattr(loaded, field)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_file_format_is_documented_json(tmp_path, x64):
    model, _ = _regression()
    path = tmp_path / "gp.json"
    save_gaze_regression(path, model)
    doc = json.loads(path.read_text())
    assert doc["format"] == FORMAT == "jaxgaze.gaze_regression" and doc["version"] == VERSION == 1
    assert doc["model"] == "gp" and doc["dtype"] == "float64" and doc["metadata"] == {}
    kernel = doc["direction"]["gp"]["kernel"]
    assert kernel["type"] == "Sum" and [k["type"] for k in kernel["kernels"]] == ["RationalQuadratic", "ArcSine",
                                                                                   "White"]
    rq = kernel["kernels"][0]
    assert rq["parameters"]["lengthscale"] == pytest.approx([1.1, 1.7, 2.3])
    assert rq["parameters"]["alpha"] == pytest.approx(0.7) and rq["fixed"] == []
    assert len(doc["depth"]["gp"]["X"]) == 40 and len(doc["depth"]["gp"]["X"][0]) == 3
    assert doc["direction"]["gp"]["restart_log_marginal_likelihoods"] == [-10.5, None]
    assert set(doc["features"]) == {"mean", "scale"} and len(doc["features"]["mean"]) == 3


def test_nn_round_trip(tmp_path, x64):
    rng = np.random.default_rng(2)

    def net(key):
        params = init_mlp_params(key, 3, 10, dtype=jnp.float64)
        s = Standardisation(jnp.asarray(rng.normal(size=3)), jnp.asarray(rng.uniform(0.5, 2, 3)), jnp.asarray(1.2),
                            jnp.asarray(0.4))
        loss = jnp.asarray([0.5, 0.3, np.inf])
        return MLPFit(params, s, 1, 2, True, loss, loss, jnp.arange(8), jnp.arange(8, 10))

    model = NNGazeRegression(net(jax.random.key(0)), net(jax.random.key(1)), (64, 48))
    path = tmp_path / "nn.json"
    save_gaze_regression(path, model, metadata={"note": "baseline"})
    loaded = load_gaze_regression(path)
    assert isinstance(loaded, NNGazeRegression) and loaded.image_size == (64, 48)
    X = rng.normal(size=(20, 3))
    _assert_same_prediction(model, loaded, X, 1e-12)
    assert loaded.direction_net.stopped_early and loaded.direction_net.best_epoch == 1
    assert np.isinf(np.asarray(loaded.depth_net.train_loss)[-1])
    np.testing.assert_array_equal(np.asarray(loaded.depth_net.validation_indices), [8, 9])
    assert read_model_metadata(path) == {"note": "baseline", "image_size": [64, 48]}


def test_the_training_image_size_is_kept_in_the_metadata(tmp_path, x64):
    """The regression's ``image_size`` is written as ``metadata.image_size`` and read back from it;
    a file without it (written by hand, or by other code) loads with the size unknown."""
    model, _ = _regression()
    path = tmp_path / "gp.json"
    save_gaze_regression(path, model._replace(image_size=(320, 240)), metadata={"focal_px": 300.0})
    doc = json.loads(path.read_text())
    assert doc["metadata"] == {"focal_px": 300.0, "image_size": [320, 240]}
    loaded, metadata = load_gaze_regression(path, with_metadata=True)
    assert loaded.image_size == (320, 240) and metadata["image_size"] == [320, 240]
    for size, expected in (([640, 480], (640, 480)), (None, None)):
        doc["metadata"]["image_size"] = size
        path.write_text(json.dumps(doc))
        assert load_gaze_regression(path).image_size == expected
    del doc["metadata"]["image_size"]
    path.write_text(json.dumps(doc))
    assert load_gaze_regression(path).image_size is None
    doc["metadata"]["image_size"] = [640, "480"]
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=r"gp.json: model metadata 'image_size' must be \[width, height\]"):
        load_gaze_regression(path)
    other = tmp_path / "other.json"
    with pytest.raises(ValueError, match=r"metadata image_size \[640, 480\] differs .* \[320, 240\]"):
        save_gaze_regression(other, model._replace(image_size=(320, 240)), metadata={"image_size": [640, 480]})
    assert not other.exists()
    save_gaze_regression(other, model._replace(image_size=(320, 240)), metadata={"image_size": [320, 240]})
    assert load_gaze_regression(other).image_size == (320, 240)


def test_kernel_json_round_trip_and_registry(x64):
    kernel = Sum(Product(Constant(3.0), RBF(0.5, np.array([1.0, 2.0]), fixed="lengthscale")), White(0.2))
    again = kernel_from_json(json.loads(json.dumps(kernel_to_json(kernel))))
    X = np.random.default_rng(3).normal(size=(6, 2))
    np.testing.assert_array_equal(np.asarray(again(jnp.asarray(X))), np.asarray(kernel(jnp.asarray(X))))
    assert again.kernels[0].kernels[1].fixed == ("lengthscale",)

    class Scaled(RBF):  # a user kernel: not savable until registered
        pass

    with pytest.raises(TypeError, match="register_kernel"):
        kernel_to_json(Scaled(1.0, 1.0) + White(0.1))
    try:
        register_kernel(Scaled)
        assert type(kernel_from_json(kernel_to_json(Scaled(1.0, 2.0)))) is Scaled
    finally:
        from jaxgaze.io.models import KERNEL_TYPES

        KERNEL_TYPES.pop("Scaled", None)
    with pytest.raises(ValueError, match="unknown kernel type"):
        kernel_from_json({"type": "Matern", "parameters": {}})


def test_save_is_atomic_and_checks_its_arguments(tmp_path, monkeypatch, x64):
    model, _ = _regression(n=10)
    path = tmp_path / "gp.json"
    path.write_text("old")
    with pytest.raises(ValueError, match="metadata"):
        save_gaze_regression(path, model, metadata={"focal": np.nan})
    with pytest.raises(TypeError, match="GazeRegression"):
        save_gaze_regression(path, "not a model")

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        save_gaze_regression(path, model)
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gp.json"]  # no temporary file left


# ---------------------------------------------------------------------------
# Errors name the file and what is wrong


@pytest.fixture
def saved(tmp_path):
    with jax.enable_x64(True):
        model, _ = _regression(n=8)
        path = tmp_path / "gp.json"
        save_gaze_regression(path, model, metadata={"focal_px": 320.0})
    return path, json.loads(path.read_text())


def _load_error(path, doc=None, text=None):
    if doc is not None:
        text = json.dumps(doc)
    if text is not None:
        path.write_text(text)
    with jax.enable_x64(True), pytest.raises(ModelFileError) as info:
        load_gaze_regression(path)
    message = str(info.value)
    assert message.startswith(str(path)), message
    assert "\n" not in message
    return message


def test_missing_file_and_invalid_json(tmp_path, saved):
    assert "model file not found" in _load_error(tmp_path / "nope.json")
    path, _ = saved
    message = _load_error(path, text='{"format": "jaxgaze.gaze_regression",\n "version": 1,,}')
    assert "invalid JSON" in message and ", line 2:" in message
    assert "not an object" in _load_error(path, text="[1, 2]")
    assert "is a directory" in _load_error(tmp_path)


def test_wrong_format_or_version(saved):
    path, doc = saved
    assert "not a gaze regression model" in _load_error(path, {**doc, "format": "something.else"})
    assert "unsupported model file version 2" in _load_error(path, {**doc, "version": 2})


def test_missing_keys_are_named_with_their_place(saved):
    path, doc = saved
    broken = json.loads(json.dumps(doc))
    del broken["direction"]["gp"]["kernel"]
    assert "missing key 'kernel' in direction.gp" in _load_error(path, broken)
    broken = json.loads(json.dumps(doc))
    del broken["depth"]["gp"]["kernel"]["kernels"][1]["parameters"]["variance"]
    assert "depth.gp.kernel.kernels[1].parameters of Linear" in _load_error(path, broken)
    broken = json.loads(json.dumps(doc))
    del broken["features"]
    assert "missing key 'features'" in _load_error(path, broken)
    broken = json.loads(json.dumps(doc))
    broken["direction"]["gp"]["X"][0] = [1.0, 2.0]
    assert "direction.gp.X" in _load_error(path, broken)
    broken = json.loads(json.dumps(doc))
    broken["direction"]["gp"]["kernel"]["kernels"][0]["type"] = "Matern"
    assert "unknown kernel type \"Matern\"" in _load_error(path, broken)


def test_edited_hyperparameters_are_caught(saved):
    path, doc = saved
    broken = json.loads(json.dumps(doc))
    white = broken["direction"]["gp"]["kernel"]["kernels"][2]
    white["parameters"]["variance"] *= 2
    assert "raw.variance does not match parameters.variance" in _load_error(path, broken)
    del white["raw"]  # the natural value alone is accepted, but the data no longer give the saved likelihood
    assert "log marginal likelihood" in _load_error(path, broken)
