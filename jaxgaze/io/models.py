"""Saving and loading fitted gaze regressions (``f1`` direction, ``f2`` depth) as JSON.

:func:`save_gaze_regression` writes a :class:`~jaxgaze.headpose.regression.GazeRegression`
(the paper's two GPs) or a :class:`~jaxgaze.headpose.regression.NNGazeRegression` (the
CogSci network baseline) to one JSON file, atomically (a temporary file next to
the target, renamed on success); :func:`load_gaze_regression` rebuilds it. For a
GP the Cholesky factor is recomputed from the saved kernel, training data and
jitter, so the loaded model's ``predict`` equals the original's (to rounding:
within 1e-10 in float64; the computation is the same, so in practice exactly).

File format (``"format": "jaxgaze.gaze_regression"``, ``"version": 1``)::

    {
      "format": "jaxgaze.gaze_regression", "version": 1,
      "model": "gp" | "nn",
      "dtype": "float64" | "float32",        # the dtype the model was fitted in
      "metadata": {...},                     # free JSON object: focal_px, fps, window, image_size, ...
                                             # (image_size: the regression's training image size)
      "features": {"mean": [...], "scale": [...]},          # gp: the input standardisation
      "direction": {"scaling": {"mean": m, "scale": s}, "gp": GP},   # f1 (gp)
      "depth":     {"scaling": {"mean": m, "scale": s}, "gp": GP},   # f2 (gp)
      # nn: "direction": {"net": NET}, "depth": {"net": NET}
    }

    GP  = {"kernel": KERNEL, "X": [[...]] (standardised inputs), "y": [...] (standardised
           outputs), "jitter": j (absolute), "result": "successful" | ..., "log_marginal_likelihood": v,
           "restart_log_marginal_likelihoods": [...], "stages": [[points, dtype, steps], ...]}
    KERNEL = {"type": "Sum" | "Product", "kernels": [KERNEL, ...]}
           | {"type": "RationalQuadratic" (any registered leaf kernel), "parameters": {name: natural
              value (number or list)}, "raw": {name: unconstrained value}, "fixed": [names]}
    NET = {"W1": [[...]], "b1": [...], "W2": [...], "b2": b, "x_mean": [...], "x_scale": [...],
           "y_mean": m, "y_scale": s, "best_epoch": e, "epochs_run": n, "stopped_early": bool,
           "train_indices": [...], "validation_indices": [...]}

Kernels are rebuilt through a registry of kernel classes (:data:`KERNEL_TYPES`;
add your own ``Parametrised`` kernels with :func:`register_kernel`): a leaf is
constructed from its natural ``parameters`` and ``fixed`` names, then its
unconstrained ``raw`` values (when present) are put back exactly. Numbers are
written with Python's shortest round-trip ``repr``, so float64 values survive
bit for bit.

The regression's ``image_size`` (the ``(width, height)`` px of its training images) is
stored as ``metadata.image_size`` (``[width, height]``) and read back from there; a file
without it loads with ``image_size = None`` (unknown).

A file written in float64 and loaded without ``jax_enable_x64`` gives a float32
model (and vice versa): JAX's default dtype decides, as for fitting.

Errors reading a file are :class:`ModelFileError` (a ``ValueError`` whose message
starts with ``path:``): a missing file, invalid JSON, another format or version,
a missing key or a malformed value (named with its place in the file, e.g.
``direction.gp.kernel.kernels[1].parameters``).
"""

from __future__ import annotations

import json
import math
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jaxgaze.gp.exact import FittedGP, fitted_gp
from jaxgaze import results
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
    Parametrised,
)
from jaxgaze.headpose.nn import MLPFit, MLPParams, Standardisation
from jaxgaze.headpose.regression import GazeRegression, NNGazeRegression, Scaling
from jaxgaze.io.text import InputFileError, atomic_path, read_text

__all__ = ["FORMAT", "VERSION", "KERNEL_TYPES", "ModelFileError", "register_kernel", "kernel_to_json",
           "kernel_from_json", "regression_to_json", "save_gaze_regression", "load_gaze_regression",
           "read_model_metadata", "metadata_number", "metadata_image_size"]

FORMAT = "jaxgaze.gaze_regression"
VERSION = 1

#: Leaf kernels by name (``Parametrised`` subclasses: positive parameters ``PARAMETERS``).
KERNEL_TYPES: dict[str, type] = {cls.__name__: cls for cls in (Constant, RBF, RationalQuadratic, ArcSine, Linear,
                                                                White)}
_COMBINATIONS = {"Sum": Sum, "Product": Product}


class ModelFileError(InputFileError):
    """A model file that cannot be read. The message starts with ``path:``."""


def register_kernel(cls: type) -> type:
    """Make a leaf kernel class (a ``Parametrised`` subclass whose constructor takes its
    ``PARAMETERS`` by name and ``fixed=``) savable and loadable; returns ``cls`` (a decorator)."""
    if not (isinstance(cls, type) and issubclass(cls, Parametrised)):
        raise TypeError(f"only leaf kernels with positive parameters (Parametrised subclasses) can be registered, "
                        f"got {cls!r}")
    if cls.__name__ in _COMBINATIONS:
        raise ValueError(f"kernel name {cls.__name__!r} is reserved")
    KERNEL_TYPES[cls.__name__] = cls
    return cls


# ---------------------------------------------------------------------------
# Kernels


def _value(array):
    """A float or a (nested) list of floats, for JSON."""
    a = np.asarray(array, dtype=np.float64)
    return float(a) if a.ndim == 0 else a.tolist()


def kernel_to_json(kernel: Kernel) -> dict:
    """The kernel's structure and parameters as a JSON-able dict (see the module docstring)."""
    if isinstance(kernel, (Sum, Product)) and type(kernel).__name__ in _COMBINATIONS:
        return {"type": type(kernel).__name__, "kernels": [kernel_to_json(k) for k in kernel.kernels]}
    name = type(kernel).__name__
    if KERNEL_TYPES.get(name) is not type(kernel):
        raise TypeError(f"cannot save kernel {name}: not a registered kernel type (register it with "
                        "jaxgaze.io.models.register_kernel); known: " + ", ".join(sorted(KERNEL_TYPES)))
    return {
        "type": name,
        "parameters": {p: _value(getattr(kernel, p)) for p in kernel.PARAMETERS},
        "raw": {p: _value(getattr(kernel, "raw_" + p)) for p in kernel.PARAMETERS},
        "fixed": list(kernel.fixed),
    }


class _Reader:
    """Checks on the parsed JSON, raising :class:`ModelFileError` that names the place in the file."""

    def __init__(self, path: str, dtype, file_dtype=None):
        self.path = path
        self.dtype = dtype
        #: the dtype the model was fitted in (the saved log marginal likelihood is checked only if it is ``dtype``).
        self.file_dtype = file_dtype

    def fail(self, what: str):
        raise ModelFileError(what, self.path)

    def get(self, obj: dict, key: str, where: str):
        if not isinstance(obj, dict):
            self.fail(f"{where or 'the file'} must be a JSON object, got {type(obj).__name__}")
        if key not in obj:
            self.fail(f"missing key '{key}'" + (f" in {where}" if where else ""))
        return obj[key]

    def array(self, value, where: str, ndim: int | None = None, shape=None) -> np.ndarray:
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(f"{where} must be a number or an array of numbers")
        if isinstance(value, bool):
            self.fail(f"{where} must be a number or an array of numbers")
        if ndim is not None and a.ndim != ndim:
            self.fail(f"{where} must be a {ndim}-D array, got shape {a.shape}")
        if shape is not None and a.shape != tuple(shape):
            self.fail(f"{where} must have shape {tuple(shape)}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            self.fail(f"{where} contains NaN or inf")
        return a

    def number(self, value, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(f"{where} must be a finite number, got {json.dumps(value)}")
        return float(value)

    def integer(self, value, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(f"{where} must be an integer, got {json.dumps(value)}")
        return int(value)

    def jnp(self, value, where: str, ndim=None, shape=None):
        return jnp.asarray(self.array(value, where, ndim, shape), dtype=self.dtype)

    # -- kernels --------------------------------------------------------------

    def kernel(self, data, where: str) -> Kernel:
        kind = self.get(data, "type", where)
        if isinstance(kind, str) and kind in _COMBINATIONS:
            parts = self.get(data, "kernels", where)
            if not isinstance(parts, list) or not parts:
                self.fail(f"{where}.kernels must be a non-empty list of kernels")
            return _COMBINATIONS[kind](*(self.kernel(k, f"{where}.kernels[{i}]") for i, k in enumerate(parts)))
        cls = KERNEL_TYPES.get(kind) if isinstance(kind, str) else None
        if cls is None:
            self.fail(f"{where}.type: unknown kernel type {json.dumps(kind)}; known: "
                      + ", ".join(sorted([*KERNEL_TYPES, *_COMBINATIONS])))
        params = self.get(data, "parameters", where)
        if not isinstance(params, dict):
            self.fail(f"{where}.parameters must be a JSON object")
        missing = [p for p in cls.PARAMETERS if p not in params]
        unknown = [p for p in params if p not in cls.PARAMETERS]
        if missing or unknown:
            self.fail(f"{where}.parameters of {kind} must be " + ", ".join(cls.PARAMETERS)
                      + (f"; missing {', '.join(missing)}" if missing else "")
                      + (f"; unknown {', '.join(unknown)}" if unknown else ""))
        fixed = data.get("fixed", [])
        if not isinstance(fixed, list) or any(f not in cls.PARAMETERS for f in fixed):
            self.fail(f"{where}.fixed must be a list of parameter names of {kind} ({', '.join(cls.PARAMETERS)})")
        natural = {p: self.array(params[p], f"{where}.parameters.{p}") for p in cls.PARAMETERS}
        try:
            kernel = cls(**natural, fixed=tuple(fixed))
        except (TypeError, ValueError) as error:
            self.fail(f"{where}: {error}")
        raw = data.get("raw")
        if raw is not None:
            if not isinstance(raw, dict) or set(raw) != set(cls.PARAMETERS):
                self.fail(f"{where}.raw must be a JSON object with keys " + ", ".join(cls.PARAMETERS))
            for p in cls.PARAMETERS:
                value = self.array(raw[p], f"{where}.raw.{p}", shape=natural[p].shape)
                if not np.allclose(np.exp(value) + 1e-12, natural[p], rtol=1e-6, atol=0):
                    self.fail(f"{where}: raw.{p} does not match parameters.{p} (value = exp(raw) + 1e-12); "
                              "edit both or delete 'raw'")
                kernel = eqx.tree_at(lambda k, n=p: getattr(k, "raw_" + n), kernel, jnp.asarray(value))
        return _cast(kernel, self.dtype)

    # -- GPs ------------------------------------------------------------------

    def gp(self, data, where: str, num_features: int) -> FittedGP:
        kernel = self.kernel(self.get(data, "kernel", where), f"{where}.kernel")
        X = self.array(self.get(data, "X", where), f"{where}.X", ndim=2)
        if X.shape[1] != num_features:
            self.fail(f"{where}.X has {X.shape[1]} features but features.mean has {num_features}")
        if X.shape[0] < 1:
            self.fail(f"{where}.X has no rows")
        y = self.array(self.get(data, "y", where), f"{where}.y", shape=(X.shape[0],))
        try:
            kernel.check_input_dim(num_features)
        except ValueError as error:
            self.fail(f"{where}.kernel: {error}")
        jitter = self.number(self.get(data, "jitter", where), f"{where}.jitter")
        if jitter < 0:
            self.fail(f"{where}.jitter must be non-negative, got {jitter!r}")
        result_name = self.get(data, "result", where)
        if result_name not in results.NAMES:
            self.fail(f"{where}.result must be one of " + ", ".join(results.NAMES)
                      + f", got {json.dumps(result_name)}")
        result = results.from_name(result_name)
        restarts = data.get("restart_log_marginal_likelihoods", [])
        stages = data.get("stages", [])
        if not isinstance(restarts, list) or not isinstance(stages, list):
            self.fail(f"{where}.restart_log_marginal_likelihoods and .stages must be lists")
        if not all(r is None or (isinstance(r, (int, float)) and not isinstance(r, bool)) for r in restarts):
            self.fail(f"{where}.restart_log_marginal_likelihoods must hold numbers or null")
        restart_values = np.asarray([np.nan if r is None else r for r in restarts], dtype=np.float64)
        try:
            stage_tuples = tuple((int(n), str(d), int(s)) for n, d, s in stages)
        except (TypeError, ValueError, OverflowError):
            self.fail(f"{where}.stages must be a list of [points, dtype, steps]")
        Xj, yj = jnp.asarray(X, self.dtype), jnp.asarray(y, self.dtype)
        # The Cholesky factor as fit() leaves it; the jitter as an array, so that one
        # compiled factorisation serves every jitter value.
        fitted = fitted_gp(kernel, Xj, yj, jnp.asarray(jitter, self.dtype), result,
                         jnp.asarray(restart_values, self.dtype), stage_tuples, False)
        if bool((result == results.RESULTS.successful) | (result == results.RESULTS.max_steps_reached)) and not np.all(
                np.isfinite(np.asarray(fitted.cholesky))):
            self.fail(f"{where}: the kernel matrix is not positive definite with the saved kernel and jitter")
        value = fitted.log_marginal_likelihood
        saved = data.get("log_marginal_likelihood")
        if (saved is not None and self.file_dtype == np.dtype(self.dtype) and np.isfinite(float(value))
                and abs(float(value) - self.number(saved, f"{where}.log_marginal_likelihood"))
                > 1e-6 * max(1.0, abs(float(value)))):
            self.fail(f"{where}: the log marginal likelihood of the saved kernel and data is {float(value):.10g}, "
                      f"not the saved {saved!r}: the file was edited or is corrupt")
        return fitted

    def scaling(self, data, where: str, shape) -> Scaling:
        mean = self.array(self.get(data, "mean", where), f"{where}.mean", shape=shape)
        scale = self.array(self.get(data, "scale", where), f"{where}.scale", shape=shape)
        if np.any(scale <= 0):
            self.fail(f"{where}.scale must be positive")
        return Scaling(mean if mean.ndim else np.float64(mean), scale if scale.ndim else np.float64(scale))

    # -- networks -------------------------------------------------------------

    def net(self, data, where: str) -> MLPFit:
        W1 = self.jnp(self.get(data, "W1", where), f"{where}.W1", ndim=2)
        D, H = W1.shape
        params = MLPParams(
            W1=W1,
            b1=self.jnp(self.get(data, "b1", where), f"{where}.b1", shape=(H,)),
            W2=self.jnp(self.get(data, "W2", where), f"{where}.W2", shape=(H,)),
            b2=self.jnp(self.get(data, "b2", where), f"{where}.b2", shape=()),
        )
        s = Standardisation(*(self.jnp(self.get(data, k, where), f"{where}.{k}", shape=shape)
                              for k, shape in (("x_mean", (D,)), ("x_scale", (D,)), ("y_mean", ()),
                                               ("y_scale", ()))))

        def history(key):
            values = data.get(key, [])
            if not isinstance(values, list):
                self.fail(f"{where}.{key} must be a list")
            return jnp.asarray([np.inf if v is None else v for v in values], self.dtype)

        def indices(key):
            values = data.get(key, [])
            if not isinstance(values, list) or any(isinstance(v, bool) or not isinstance(v, int) for v in values):
                self.fail(f"{where}.{key} must be a list of integers")
            return jnp.asarray(values, jnp.int32)

        return MLPFit(
            params=params,
            standardisation=s,
            best_epoch=self.integer(data.get("best_epoch", 0), f"{where}.best_epoch"),
            epochs_run=self.integer(data.get("epochs_run", 0), f"{where}.epochs_run"),
            stopped_early=bool(data.get("stopped_early", False)),
            train_loss=history("train_loss"),
            validation_loss=history("validation_loss"),
            train_indices=indices("train_indices"),
            validation_indices=indices("validation_indices"),
        )


def _cast(tree, dtype):
    import jax

    return jax.tree.map(lambda a: a.astype(dtype) if eqx.is_inexact_array(a) else a, tree)


def kernel_from_json(data: dict, *, dtype=None) -> Kernel:
    """Inverse of :func:`kernel_to_json` (``ValueError`` for a malformed description)."""
    dtype = jnp.asarray(np.zeros(1)).dtype if dtype is None else dtype
    try:
        return _Reader("kernel", dtype).kernel(data, "kernel")
    except ModelFileError as error:
        raise ValueError(str(error)[len("kernel: "):]) from None


# ---------------------------------------------------------------------------
# Saving


def _gp_to_json(gp: FittedGP) -> dict:
    return {
        "kernel": kernel_to_json(gp.kernel),
        "X": np.asarray(gp.X, dtype=np.float64).tolist(),
        "y": np.asarray(gp.y, dtype=np.float64).tolist(),
        "jitter": float(gp.jitter),
        "result": results.name(gp.result),
        "log_marginal_likelihood": _finite_or_none(gp.log_marginal_likelihood),
        "restart_log_marginal_likelihoods": [_finite_or_none(v) for v in
                                             np.asarray(gp.restart_log_marginal_likelihoods).ravel()],
        "stages": [[int(n), str(d), int(s)] for n, d, s in gp.stages],
    }


def _finite_or_none(value):
    value = float(value)
    return value if math.isfinite(value) else None


def _scaling_to_json(s: Scaling) -> dict:
    return {"mean": _value(s.mean), "scale": _value(s.scale)}


def _net_to_json(net: MLPFit) -> dict:
    p, s = net.params, net.standardisation
    return {
        "W1": _value(p.W1), "b1": _value(p.b1), "W2": _value(p.W2), "b2": _value(p.b2),
        "x_mean": _value(s.x_mean), "x_scale": _value(s.x_scale), "y_mean": _value(s.y_mean),
        "y_scale": _value(s.y_scale),
        "best_epoch": int(net.best_epoch), "epochs_run": int(net.epochs_run), "stopped_early": bool(net.stopped_early),
        "train_loss": [_finite_or_none(v) for v in np.asarray(net.train_loss)],
        "validation_loss": [_finite_or_none(v) for v in np.asarray(net.validation_loss)],
        "train_indices": [int(i) for i in np.asarray(net.train_indices)],
        "validation_indices": [int(i) for i in np.asarray(net.validation_indices)],
    }


def regression_to_json(regression, *, metadata=None) -> dict:
    """The JSON document :func:`save_gaze_regression` writes, as a dict."""
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, dict):
        raise TypeError(f"metadata must be a dict, got {type(metadata).__name__}")
    try:
        json.dumps(metadata, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise ValueError(f"metadata must hold only JSON values (str, finite numbers, bool, None, lists, dicts): "
                         f"{error}") from None
    size = getattr(regression, "image_size", None)
    if size is not None:
        given = metadata.get("image_size")
        if given is not None and given != list(size):
            raise ValueError(f"metadata image_size {given!r} differs from the regression's image_size {list(size)}")
        metadata = {**metadata, "image_size": [int(size[0]), int(size[1])]}
    doc = {"format": FORMAT, "version": VERSION}
    if isinstance(regression, GazeRegression):
        doc.update({
            "model": "gp",
            "dtype": str(np.asarray(regression.direction_gp.X).dtype),
            "metadata": metadata,
            "features": _scaling_to_json(regression.features),
            "direction": {"scaling": _scaling_to_json(regression.direction_scaling),
                          "gp": _gp_to_json(regression.direction_gp)},
            "depth": {"scaling": _scaling_to_json(regression.depth_scaling), "gp": _gp_to_json(regression.depth_gp)},
        })
    elif isinstance(regression, NNGazeRegression):
        doc.update({
            "model": "nn",
            "dtype": str(np.asarray(regression.direction_net.params.W1).dtype),
            "metadata": metadata,
            "direction": {"net": _net_to_json(regression.direction_net)},
            "depth": {"net": _net_to_json(regression.depth_net)},
        })
    else:
        raise TypeError(f"regression must be a GazeRegression or NNGazeRegression, got {type(regression).__name__}")
    return doc


def save_gaze_regression(path, regression, *, metadata: dict | None = None) -> None:
    """Write a fitted :class:`GazeRegression` or :class:`NNGazeRegression` to ``path`` as JSON.

    ``metadata`` is any JSON object stored with it (``jaxgaze attend`` reads ``focal_px``,
    ``fps`` and ``window`` from it); the regression's ``image_size`` is stored there as
    ``image_size`` (a different ``metadata["image_size"]`` is a ``ValueError``). The file is replaced only once it is
    completely written. Raises ``TypeError`` for another model or an unsaveable kernel,
    ``ValueError`` for metadata that is not JSON, ``OSError`` when it cannot be written.
    """
    text = json.dumps(regression_to_json(regression, metadata=metadata), allow_nan=False) + "\n"
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as handle:
        handle.write(text)


# ---------------------------------------------------------------------------
# Loading


def _read_document(path: str) -> dict:
    text = read_text(path, ModelFileError, "model")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as error:
        raise ModelFileError(f"not a model file: invalid JSON ({error.msg})", path, error.lineno) from None
    if not isinstance(doc, dict):
        raise ModelFileError(f"not a model file: the JSON is a {type(doc).__name__}, not an object", path)
    if doc.get("format") != FORMAT:
        raise ModelFileError(f"not a gaze regression model: 'format' is {json.dumps(doc.get('format'))}, "
                             f"expected {json.dumps(FORMAT)}", path)
    version = doc.get("version")
    if version != VERSION:
        raise ModelFileError(f"unsupported model file version {json.dumps(version)} (this jaxgaze reads version "
                             f"{VERSION})", path)
    return doc


def read_model_metadata(path) -> dict:
    """The ``metadata`` object of a model file (checks the format and version only)."""
    path = os.fspath(path)
    doc = _read_document(path)
    metadata = doc.get("metadata", {})
    if not isinstance(metadata, dict):
        raise ModelFileError("'metadata' must be a JSON object", path)
    return metadata


def metadata_number(metadata: dict, key: str, path, *, integer: bool = False):
    """``metadata[key]`` checked as a positive number (or integer), or ``None`` when absent or null;
    :class:`ModelFileError` naming ``path`` otherwise."""
    value = metadata.get(key)
    if value is None:
        return None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
    if integer:
        ok = ok and float(value).is_integer()
    if not ok:
        kind = "positive integer" if integer else "positive number"
        raise ModelFileError(f"model metadata '{key}' must be a {kind}, got {json.dumps(value)}", path)
    return int(value) if integer else float(value)


def metadata_image_size(metadata: dict, path):
    """``metadata["image_size"]`` as ``(width, height)`` pixels, or ``None`` when absent;
    :class:`ModelFileError` naming ``path`` otherwise."""
    value = metadata.get("image_size")
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value)):
        raise ModelFileError(f"model metadata 'image_size' must be [width, height] in pixels, got "
                             f"{json.dumps(value)}", path)
    return int(value[0]), int(value[1])


def load_gaze_regression(path, *, with_metadata: bool = False):
    """Read a model written by :func:`save_gaze_regression`.

    Returns the :class:`GazeRegression` (or :class:`NNGazeRegression`), with its
    ``image_size`` from ``metadata.image_size`` (``None`` when absent), or
    ``(regression, metadata)`` with ``with_metadata=True``. The model's dtype is JAX's
    default (float64 under ``jax_enable_x64``). Raises :class:`ModelFileError`.
    """
    path = os.fspath(path)
    doc = _read_document(path)
    dtype = jnp.asarray(np.zeros(1)).dtype
    file_dtype = doc.get("dtype")
    if file_dtype not in ("float32", "float64"):
        raise ModelFileError(f"'dtype' must be \"float32\" or \"float64\", got {json.dumps(file_dtype)}", path)
    r = _Reader(path, dtype, np.dtype(file_dtype))
    metadata = doc.get("metadata", {})
    if not isinstance(metadata, dict):
        r.fail("'metadata' must be a JSON object")
    image_size = metadata_image_size(metadata, path)
    model = r.get(doc, "model", "")
    if model == "gp":
        features = r.get(doc, "features", "")
        mean = r.array(r.get(features, "mean", "features"), "features.mean", ndim=1)
        feature_scaling = r.scaling(features, "features", mean.shape)
        parts = []
        for name in ("direction", "depth"):
            part = r.get(doc, name, "")
            parts.append((r.gp(r.get(part, "gp", name), f"{name}.gp", mean.shape[0]),
                          r.scaling(r.get(part, "scaling", name), f"{name}.scaling", ())))
        regression = GazeRegression(parts[0][0], parts[1][0], feature_scaling, parts[0][1], parts[1][1], image_size)
    elif model == "nn":
        nets = [r.net(r.get(r.get(doc, name, ""), "net", name), f"{name}.net") for name in ("direction", "depth")]
        if nets[0].params.W1.shape[0] != nets[1].params.W1.shape[0]:
            r.fail("direction.net and depth.net take different numbers of features")
        regression = NNGazeRegression(*nets, image_size)
    else:
        r.fail(f"'model' must be \"gp\" or \"nn\", got {json.dumps(model)}")
    return (regression, metadata) if with_metadata else regression
