"""One result code for every fit in jaxgaze, after ``optimistix.RESULTS``.

A fit (:func:`jaxgaze.calibrate_cone`, :func:`jaxgaze.gp.fit`, …) reports its
outcome as a :class:`RESULTS` item, an ``equinox.Enumeration``: a JAX-compatible
enum that passes through ``jit`` and ``vmap`` (the code is an int32 array, with
the batch axes of a vmapped fit). Compare with ``==``, never with integers::

    ok = fitted.result == RESULTS.successful  # a bool array; per item when batched
    RESULTS[fitted.result]                    # its message (concrete results only)

**One throw rule.** ``throw=True`` raises :class:`FitError` (message: the
:class:`RESULTS` message, prefixed by what failed) when the result is not
``successful``; under ``jit``/``vmap`` the same message becomes an ``equinox``
runtime error. ``throw=False`` never raises on a failed fit: the code is returned
in the solution, with NaN-free placeholder values where the fit documents them.
Bad *arguments* (shapes, types, options) raise ``ValueError``/``TypeError``
either way. Both rules are :func:`throw_if_failed`.

**One default: ``throw=False``**, in every fit. Our fits are batched (one calibration per camera,
one bias per person, one GP per output, vmapped) and many are posteriors: one failed item must not
discard the others, and draws that did not mix are still worth looking at. The code is always in the
result and :func:`succeeded` reads it, from every fit alike; the command line turns a failure into an
error line. Pass ``throw=True`` to raise instead: the :class:`FitError` carries what was computed
(``error.fit``), so raising throws nothing away.

**One question, one function**: :func:`succeeded` (``fit.result == RESULTS.successful``), for every
fit and posterior (its ``result`` field), per item when batched, per concurrence for
:class:`~jaxgaze.concurrence.Concurrences`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

__all__ = ["RESULTS", "FitError", "NAMES", "code", "name", "from_name", "from_optimistix", "OPTIMISTIX",
           "succeeded", "throw_if_failed"]


class RESULTS(eqx.Enumeration):
    """Outcome of a fit. Each member's value is its message."""

    successful = "the fit succeeded"
    max_steps_reached = (
        "the solver used max_steps without meeting its tolerance; the result is the best point reached; "
        "raise max_steps or tol"
    )
    nonfinite = (
        "NaN or inf: the input contains NaN or inf, or the objective is not finite at any starting point; "
        "check the input and its scale (a GP fit: or pass a larger jitter)"
    )
    not_positive_definite = (
        "the covariance K(X, X) + jitter·I is not positive definite at the fitted parameters; "
        "add a White noise term or pass a larger jitter"
    )
    optimiser_failed = (
        "the optimiser stopped on an optimistix failure, or at a non-finite objective, in the last stage "
        "(the previous stage's optimum is returned)"
    )
    too_few_inliers = (
        "too few RANSAC inliers to fit the gaze line; check the points of regard or raise inlier_threshold"
    )
    degenerate = (
        "degenerate points of regard: they coincide or lie exactly on one line (no eye-in-head spread, "
        "so h = 0 and the apex is undefined)"
    )
    behind_camera = (
        "most points of regard are behind the camera (x ≤ 0 in the camera frame, where +x is forward); "
        "pass points in the camera frame (+x forward, +y left, +z up), not OpenCV's frame or the world frame"
    )
    collinear_through_camera = (
        "degenerate points of regard: the points are collinear through the camera centre (the fitted line "
        "passes through the origin), so the apex (centre of the eyes) is undefined"
    )
    not_mixed = (
        "the sampler did not mix: split r-hat above 1.05, bulk or tail ESS below 100, or more than 1% divergent "
        "transitions, or a mean acceptance below 0.5; the draws are not a reliable posterior; run more warm-up "
        "and draws, or check the data"
    )
    implausible = (
        "the estimate is physically implausible (an eye centre farther from its head-mounted camera than a head "
        "allows: 0.3 m for a posterior mean, 1 m for a point estimate); check that positions are in metres and "
        "that the inputs belong together"
    )
    lost = (
        "the head tracker lost the head: the pose left the tracked range, or tracking had failed before, and no "
        "face was found in the frame to start again; pose and translation are NaN until a later frame has a face"
    )
    ambiguous = (
        "the data cannot tell two explanations apart: another mode of the posterior (a person's bias that maps "
        "their gaze onto other targets) has a Laplace evidence within log 20 of the sampled one; its draws are "
        "one explanation, not the answer; see the posterior's alternatives"
    )
    misfit = (
        "the posterior predictive check flags a person: the fit sends far more of their gaze elsewhere than the "
        "model predicts and than it does for the others (a wrong mode of their bias, or a target the model lacks); "
        "their estimates are not to be trusted; see the posterior's predictive_check"
    )


#: Member names in code order (``NAMES[i]`` is the member whose code is ``i``); these are
#: the names stored in model files (``gp.json``).
NAMES = (
    "successful",
    "max_steps_reached",
    "nonfinite",
    "not_positive_definite",
    "optimiser_failed",
    "too_few_inliers",
    "degenerate",
    "behind_camera",
    "collinear_through_camera",
    "not_mixed",
    "implausible",
    "lost",
    "ambiguous",
    "misfit",
)


class FitError(RuntimeError, ValueError):
    """A fit called with ``throw=True`` did not succeed.

    A ``RuntimeError`` (the solver failed at run time) and a ``ValueError`` (the
    data, not the call, is the cause: e.g. degenerate points of regard), so code
    that catches either keeps working. ``result`` is the :class:`RESULTS` item and ``fit`` what the
    fit computed (its solution, posterior or estimate, as ``throw=False`` returns it), or ``None``.
    """

    def __init__(self, message: str, result: RESULTS | None = None, fit=None):
        super().__init__(message)
        self.result = result
        self.fit = fit


def code(result: RESULTS):
    """The int32 code array of a :class:`RESULTS` item (batch axes kept); ``NAMES[code]`` is its name."""
    if not isinstance(result, RESULTS):
        raise TypeError(f"expected a jaxgaze.results.RESULTS item, got {type(result).__name__}")
    (value,) = jax.tree.leaves(result)
    return value


def name(result: RESULTS) -> str:
    """The member name of one concrete :class:`RESULTS` item, e.g. ``"successful"``."""
    value = np.asarray(code(result))
    if value.ndim != 0:
        raise ValueError(f"name needs a single result, got a batch of shape {value.shape}")
    return NAMES[int(value)]


def from_name(member: str) -> RESULTS:
    """The :class:`RESULTS` item called ``member``; a ``ValueError`` lists the names if there is none."""
    if member not in NAMES:
        raise ValueError(f"unknown result {member!r}; expected one of {', '.join(NAMES)}")
    return getattr(RESULTS, member)


#: The one table from ``optimistix.RESULTS`` names to ours (:func:`from_optimistix`); every optimistix
#: failure not listed is ``optimiser_failed``.
OPTIMISTIX = {
    "successful": "successful",
    "max_steps_reached": "max_steps_reached",
    "nonlinear_max_steps_reached": "max_steps_reached",
    "nonfinite_input": "nonfinite",
    "nonfinite": "nonfinite",
}


def from_optimistix(result: optx.RESULTS) -> RESULTS:
    """Our :class:`RESULTS` item for an ``optimistix.RESULTS`` item, through the table :data:`OPTIMISTIX`
    (any other optimistix failure is ``optimiser_failed``); batch axes kept, traceable under ``jit``/``vmap``."""
    (theirs,) = jax.tree.leaves(result)
    ours = jnp.full(jnp.shape(theirs), code(RESULTS.optimiser_failed))
    for their_name, our_name in OPTIMISTIX.items():
        (their_code,) = jax.tree.leaves(getattr(optx.RESULTS, their_name))
        ours = jnp.where(theirs == their_code, code(getattr(RESULTS, our_name)), ours)
    return jax.tree.unflatten(jax.tree.structure(RESULTS.successful), [ours])


def succeeded(fit):
    """Whether ``fit`` succeeded: ``fit.result == RESULTS.successful`` for any fit, posterior or
    concurrence set with a ``result`` field (or a :class:`RESULTS` item itself). A Python ``bool``
    for one concrete result; a bool array with the batch axes otherwise (per item of a vmapped fit,
    per concurrence of :class:`~jaxgaze.concurrence.Concurrences`)."""
    result = fit if isinstance(fit, RESULTS) else getattr(fit, "result", None)
    if not isinstance(result, RESULTS):
        raise TypeError(f"succeeded needs a fit with a jaxgaze.results.RESULTS `result`, got {type(fit).__name__}")
    ok = result == RESULTS.successful
    value = code(result)
    if not isinstance(value, jax.core.Tracer) and np.ndim(value) == 0:
        return bool(ok)
    return ok


def throw_if_failed(token, result: RESULTS, context: str, fit=None):
    """Apply ``throw=True``: raise unless ``result`` is ``successful``; returns ``token``.

    Concrete results raise :class:`FitError` with message ``"{context}: {RESULTS
    message}"`` (for a batch, that of the first failure). Traced results (under
    ``jit``/``vmap``) thread an ``equinox`` runtime error with the same message onto
    the arrays of ``token``, which is returned to be used in their place. ``fit`` (default ``token``)
    is what :attr:`FitError.fit` carries.
    """
    value = code(result)
    if isinstance(value, jax.core.Tracer):
        messages = [f"{context}: {RESULTS[getattr(RESULTS, n)]}" for n in NAMES]
        return eqx.branched_error_if(token, result != RESULTS.successful, value, messages)
    values = np.asarray(value).reshape(-1)
    failed = np.flatnonzero(values != 0)
    if failed.size:
        first = from_name(NAMES[int(values[failed[0]])])
        where = f" (item {int(failed[0])} of the batch)" if np.ndim(value) else ""
        raise FitError(f"{context}{where}: {RESULTS[first]}", result, token if fit is None else fit)
    return token


for _i, _name in enumerate(NAMES):  # NAMES must list the members in code order
    assert int(code(getattr(RESULTS, _name))) == _i, _name
assert len(RESULTS) == len(NAMES)
del _i, _name
