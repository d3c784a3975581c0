"""Type-II maximum likelihood for the exact GP (Yücel et al. 2013, after eq. 13): :func:`fit`.

The objective is ``−log p(y | X, θ)`` (Rasmussen & Williams eq. 2.30, :mod:`jaxgaze.gp._linalg`)
over the kernel's unconstrained parameters, plus a wall that keeps them inside
:data:`~jaxgaze.gp.transforms.FIT_BOUNDS`. Two optimistix quasi-Newton minimisers walk it,
Fisher scoring (:class:`_FisherScoring`) and BFGS in whitened coordinates (:class:`_BFGS`),
on growing random subsets (:func:`_stage_sizes`); :func:`fit` runs the stages and returns
a :class:`~jaxgaze.gp.exact.FittedGP`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Float, PRNGKeyArray

from jaxgaze import _progress
from jaxgaze.gp._linalg import _covariance, gaussian_log_marginal_likelihood
from jaxgaze.gp.exact import (
    _MIN_POINTS,
    FittedGP,
    _cast,
    _check_jitter,
    _check_kernel,
    check_training_data,
    fitted_gp,
)
from jaxgaze.gp.kernels import Kernel, data_stats
from jaxgaze.gp.transforms import bound_penalty
from jaxgaze.results import NAMES, RESULTS, code, from_name, from_optimistix

__all__ = ["fit"]

#: multiplicative growth between the subset sizes of successive fit stages.
_STAGE_GROWTH = 4
#: the last subset before all data has at most n / this points.
_STAGE_MIN_LAST_RATIO = 1.5
#: ... and, where a doubling fits, at least n / this points (n = 1000: 256 → 512 → 1000).
_STAGE_MAX_LAST_RATIO = 2.5
#: stages before the last stop at a Newton decrement of this × tol × (stage size / n).
_STAGE_TOL_FACTOR = 100.0
#: floor on the per-point Fisher eigenvalues: directions the data barely constrain
#: (e.g. a constant offset shared by two kernel terms) take steps of bounded length.
_FISHER_FLOOR = 1e-4
#: per-point stiffness of the wall that keeps parameters inside FIT_BOUNDS.
_WALL_STIFFNESS = 10.0
#: random probes of the Hutchinson estimate of the Fisher information.
_NUM_PROBES = 16
#: float32 stages stop at a decrement of at least this × stage size (rounding level).
_FLOAT32_DECREMENT_FLOOR = 1e-5
_METHODS = ("fisher", "bfgs")


# -- the objective and its curvature ----------------------------------------------


def _objective(template, static, X, y, jitter, report: bool = False):
    """``θ ↦ −log p(y | X, θ)`` over the flattened trainable parameters, plus the wall
    that keeps them inside :data:`~jaxgaze.gp.transforms.FIT_BOUNDS` (zero inside).
    ``report``: each evaluation advances the progress bar (a ``jax.debug.callback``)."""
    _, unravel = ravel_pytree(template)

    stiffness = _WALL_STIFFNESS * X.shape[0]

    def fn(theta, args):
        value = -gaussian_log_marginal_likelihood(eqx.combine(unravel(theta), static), X, y, jitter) + bound_penalty(theta, stiffness)
        if report:
            jax.debug.callback(_progress.advance)
        return value

    return fn


@eqx.filter_jit
def _fisher_estimate(theta, template, static, X, jitter, key, num_probes: int):
    """Hutchinson estimate of the Fisher information of the LML in ``theta`` on all of ``X``.

    ``F_ij = ½ tr(K⁻¹∂_iK K⁻¹∂_jK) = ½ tr(M_i M_j)`` with ``M_i = L⁻¹ ∂_iK L⁻ᵀ``,
    which is ``½ E[(M_i z)ᵀ(M_j z)]`` for ``z ~ N(0, I)``: one Cholesky plus
    O(p s n²) for ``s`` probes, against O(p n³) for the exact value. It is the
    expected Hessian of −LML (Fisher scoring; Rasmussen & Williams Sec. 5.4.1).
    """
    _, unravel = ravel_pytree(template)

    def cov(t):
        return _covariance(eqx.combine(unravel(t), static), X, jitter)[0]

    n, p = X.shape[0], theta.shape[0]
    K = cov(theta)
    L = jnp.linalg.cholesky(K)
    Z = jax.random.normal(key, (n, num_probes), K.dtype)
    Q = solve_triangular(L, Z, lower=True, trans="T")  # L⁻ᵀ z

    def directional(e):
        return jax.jvp(lambda t: cov(t) @ Q, (theta,), (e,))[1]

    R = jax.vmap(directional)(jnp.eye(p, dtype=theta.dtype))  # (p, n, s): ∂_iK L⁻ᵀ z
    M = solve_triangular(L, jnp.moveaxis(R, 0, 1).reshape(n, p * num_probes), lower=True)
    M = M.reshape(n, p, num_probes)
    return 0.5 * jnp.einsum("nis,njs->ij", M, M) / num_probes


def _floored_fisher(theta, template, static, X, jitter, key):
    """Fisher estimate with eigenvalues floored at ``n × _FISHER_FLOOR`` (so positive definite)."""
    n = X.shape[0]
    F = _fisher_estimate(theta, template, static, X, jitter, key, _NUM_PROBES)
    F = F + jnp.diag(jax.vmap(jax.grad(jax.grad(lambda t: bound_penalty(t, _WALL_STIFFNESS * n))))(theta))
    lam, vec = jnp.linalg.eigh(0.5 * (F + F.T))
    floor = n * _FISHER_FLOOR
    lam = jnp.where(jnp.isfinite(lam), jnp.maximum(lam, floor), floor)
    vec = jnp.where(jnp.all(jnp.isfinite(vec)), vec, jnp.eye(vec.shape[0], dtype=vec.dtype))
    return vec, lam


# -- solvers ------------------------------------------------------------------------


def _decrement_test(state, decrement_tol, decrement):
    return (state.num_accepted_steps > 0) & jnp.isfinite(decrement) & (decrement < decrement_tol)


def _quiet(**kwargs) -> None:
    return None


class _BFGS(optx.AbstractBFGS):
    """``optimistix.BFGS`` that also stops once the predicted remaining gain is small.

    Besides optimistix's Cauchy test (small step and small change of the
    objective), it stops at an accepted point where the Newton decrement
    ``½ gᵀ B⁻¹ g`` (the decrease a quasi-Newton step predicts) is below
    ``decrement_tol``. Marginal likelihoods often keep rising by ever smaller
    amounts while a parameter drifts towards ±∞ in log space (RQ α → ∞ for
    RBF-like data, a bias variance → 0); there the step test never fires.
    """

    rtol: float
    atol: float
    decrement_tol: float
    norm: Callable = optx.max_norm
    use_inverse: bool = True
    descent: optx.NewtonDescent = optx.NewtonDescent(linear_solver=lx.Cholesky())
    search: optx.BacktrackingArmijo = optx.BacktrackingArmijo()
    verbose: Callable = eqx.field(static=True, default=_quiet)

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        grad = state.f_info.grad
        decrement = 0.5 * jnp.vdot(grad, state.f_info.hessian_inv.mv(grad))
        return done | _decrement_test(state, self.decrement_tol, decrement), result


class _FisherScoring(optx.AbstractQuasiNewton):
    """Optimistix quasi-Newton minimiser whose curvature is the Fisher information.

    At each accepted point the Hessian model is ``fisher(y)`` (positive definite):
    the descent is the Newton step on it with a backtracking Armijo search, i.e.
    Fisher scoring. Stops like :class:`_BFGS`, the decrement being ``½ gᵀF⁻¹g``.
    """

    rtol: float
    atol: float
    decrement_tol: float
    fisher: Callable
    norm: Callable = optx.max_norm
    use_inverse: bool = False
    descent: optx.NewtonDescent = optx.NewtonDescent(linear_solver=lx.Cholesky())
    search: optx.BacktrackingArmijo = optx.BacktrackingArmijo()
    verbose: Callable = eqx.field(static=True, default=_quiet)

    def init_hessian(self, y, f, grad):
        eye = lx.MatrixLinearOperator(jnp.eye(y.shape[0], dtype=y.dtype), lx.positive_semidefinite_tag)
        return optx.FunctionInfo.EvalGradHessian(f, grad, eye), None

    def update_hessian(self, y, y_eval, f_info, f_eval_info, hessian_update_state):
        vec, lam = self.fisher(y_eval)
        op = lx.MatrixLinearOperator((vec * lam) @ vec.T, lx.positive_semidefinite_tag)
        return optx.FunctionInfo.EvalGradHessian(f_eval_info.f, f_eval_info.grad, op), None

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        grad = state.f_info.grad
        decrement = 0.5 * jnp.vdot(grad, jnp.linalg.solve(state.f_info.hessian.as_matrix(), grad))
        return done | _decrement_test(state, self.decrement_tol, decrement), result


class _Outcome(NamedTuple):
    theta: Array
    value: Array
    result: RESULTS  # ours, from optimistix's through the one table (jaxgaze.results.OPTIMISTIX)
    steps: Array


@eqx.filter_jit
def _optimise(thetas, template, static, X, y, jitter, key, max_steps: int, decrement_tol: float, method: str,
              report: bool = False):
    """Minimise −LML of ``(X, y)`` from each row of ``thetas`` (one compiled loop over them)."""
    fn = _objective(template, static, X, y, jitter, report)

    def fisher(theta):
        return _floored_fisher(theta, template, static, X, jitter, key)

    def one(theta0):
        if method == "fisher":
            solver = _FisherScoring(rtol=0.0, atol=1e-2, decrement_tol=decrement_tol, fisher=fisher)
            start, objective, back = theta0, fn, lambda z: z
        else:
            # BFGS in coordinates whitened by the Fisher information at the start, so that
            # its initial Hessian model (the identity) has the right scale and shape.
            vec, lam = fisher(theta0)
            S = vec * jax.lax.rsqrt(lam)[None, :]
            solver = _BFGS(rtol=0.0, atol=1e-2, decrement_tol=decrement_tol)
            start = jnp.zeros_like(theta0)

            def objective(z, args):
                return fn(theta0 + S @ z, args)

            def back(z):
                return theta0 + S @ z

        sol = optx.minimise(objective, solver, start, max_steps=max_steps, throw=False)
        if theta0.dtype == jnp.float64:
            # The solver's own evaluation at the returned (last accepted) point; saves one
            # O(n³) evaluation per stage. (In float32 the value along the JVP path differs
            # from a plain evaluation by rounding, ~0.05 at 256 points, enough to change
            # which restart wins; those stages are small and re-evaluate.)
            value = jax.lax.cond(
                sol.state.num_accepted_steps > 0,
                lambda: sol.state.f_info.f.astype(theta0.dtype),
                lambda: objective(sol.value, None).astype(theta0.dtype),
            )
        else:
            value = objective(sol.value, None)
        return _Outcome(
            back(sol.value),
            value,
            _stage_result(from_optimistix(sol.result)),
            sol.stats["num_steps"],
        )

    return jax.lax.map(one, thetas)


def _stage_result(result: RESULTS) -> RESULTS:
    """A stage stopped by a non-finite objective is ``optimiser_failed``: the previous stage's optimum is used."""
    return RESULTS.where(result == RESULTS.nonfinite, RESULTS.optimiser_failed, result)


def _stage_sizes(n: int, first: int) -> list[int]:
    """Nested subset sizes: ``first``, ×4, … (the last at most n/1.5), one doubling more
    when the last is still below n/2.5 and the doubled one stays at most n/1.5, then ``n``.

    The float64 stage on all data starts from the last subset's optimum; on the flat
    ridges of the benchmark's likelihood that start is only as good as the subset is
    large (step counts with and without the extra doubling: ``benchmarks/RESULTS.md``).
    """
    sizes = [min(n, first)]
    while sizes[-1] * _STAGE_GROWTH * _STAGE_MIN_LAST_RATIO <= n:
        sizes.append(sizes[-1] * _STAGE_GROWTH)
    if n > _STAGE_MAX_LAST_RATIO * sizes[-1] and 2 * sizes[-1] * _STAGE_MIN_LAST_RATIO <= n:
        sizes.append(2 * sizes[-1])
    if sizes[-1] < n:
        sizes.append(n)
    return sizes


def _check_int(name: str, value, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer ≥ {low}, got {value!r}")


def fit(
    kernel: Kernel,
    X: Float[Array, "n D"],
    y: Float[Array, " n"],
    *,
    key: PRNGKeyArray,
    num_restarts: int = 4,
    max_steps: int = 100,
    subset_size: int | None = 256,
    explore_in_float32: bool = True,
    method: str = "fisher",
    perturbation: float = 1.0,
    tol: float = 1e-3,
    jitter=None,
    throw: bool = False,
    progress: bool = False,
) -> FittedGP:
    """Type-II maximum likelihood: kernel parameters maximising the LML (Yücel et al. 2013, after eq. 13).

    Optimises the kernel's trainable unconstrained (log) parameters
    (``kernel.trainable_filter()``; ``fixed=`` parameters stay put) with an
    optimistix quasi-Newton minimiser on −LML. An exact value-and-gradient on
    all data costs a Cholesky and a ``K⁻¹`` (O(n³)), so the default strategy
    spends few of them there:

    1. **Explore** on a random subset of ``subset_size`` points (all if
       ``n ≤ subset_size`` or ``subset_size=None``) from ``num_restarts``
       starting points: the data-driven one (variances from var(y),
       lengthscales from median pairwise distances, noise 10 % of var(y)), the
       kernel as passed, then perturbations of the data-driven point by
       N(0, ``perturbation``²) in the log-parameters (drawn with ``key``). The
       best is kept.
    2. **Grow** the subset 4× at a time (nested subsets; the last before all
       data has at most n/1.5 points, and one doubling more when it would
       otherwise be below n/2.5), each stage starting from the previous
       optimum, then finish on all ``n`` points. Stages before the last stop
       early (Newton decrement below ``100 × tol × m/n``).
    3. ``method="fisher"`` (default) is Fisher scoring on the subsets: Newton
       steps on the Fisher information ``½ tr(K⁻¹∂_iK K⁻¹∂_jK)`` (the expected
       Hessian), estimated at each accepted point from 16 random probes (one
       extra Cholesky), with eigenvalues floored at 1e-4 per point and a
       backtracking line search. From poor starts it needs fewer steps than
       BFGS. The **last stage** on all data in float64 (when
       there was an earlier one) is ``optimistix`` BFGS in coordinates whitened by the
       Fisher estimate at its start: near the optimum it walks the flat ridges
       of the likelihood (RQ ``α`` and a bias variance trading off) much faster
       than Fisher scoring, whose curvature model stays fixed to the expected
       Hessian, and each step costs one exact evaluation instead of two
       Choleskys (timings: ``benchmarks/RESULTS.md``).
       In float32 its curvature updates drown in rounding (it ran to
       ``max_steps``), so a float32 last stage stays with Fisher scoring.
       ``method="bfgs"`` uses that whitened BFGS in every stage.
    4. ``explore_in_float32=True`` (default) runs the subset stages in float32
       when the data are float64, then one float64 stage on all data, which
       starts from the last subset's optimum and polishes. (A float32 stage on
       all data before it cost more than it saved: ``benchmarks/RESULTS.md``.) With a single subset stage that is all data, as for
       ``n ≤ subset_size``, that float32 stage stays.
       A float32 stage that fails at every start (``K`` not positive definite
       in float32) is rerun in float64.

    Trained parameters are kept inside scikit-learn's default bounds
    (natural values in ``[1e-5, 1e5]``, :data:`~jaxgaze.gp.transforms.FIT_BOUNDS`)
    by a quadratic wall in log space that is zero inside, so the objective there is
    the exact −LML. Without it the arc-sine kernel's weight and bias variances ran
    off together to 1e6–1e12 on table-top data, ``K`` became singular in float32
    and the fit stopped on a non-finite gradient (``optimiser_failed``); with it
    those fits converge, to log likelihoods 0.2–4.7 higher.

    The last stage stops when the Newton decrement (the gain a Newton step
    predicts) is below ``tol`` log-likelihood units (a float32 stage: below
    ``max(tol, 1e-5 × points)``, its rounding level), when both the step
    (<1e-2 in max norm) and the change of −LML (< 1e-2) are small, or after
    ``max_steps`` steps (per stage, and per start in the first). In directions the data barely determine (Fisher
    eigenvalue below 1e-4 per point; e.g. RQ ``α → ∞``, a bias variance → 0)
    steps are short and a parameter may stop short of its limit, with an LML
    typically within ~1e-2 of the supremum.

    Returns a :class:`FittedGP`; ``result`` (a :class:`jaxgaze.results.RESULTS`)
    says whether the last stage converged (a failed fit is a value; ``jaxgaze.succeeded(fitted)``);
    ``throw=True`` raises :class:`jaxgaze.results.FitError` instead, whose ``fit`` is that
    :class:`FittedGP`. The whole fit is seeded by ``key``.
    ``progress=True`` shows a tqdm bar on stderr that counts exact evaluations
    (one per optimiser step) and names the stage running, with the best log
    likelihood of each finished stage.

    Precision: fits of the same data in float32 and float64 agree to within what the
    float32 stopping rule (decrement ``1e-5 × n``) allows: 1e-2 on the log marginal
    likelihood (for ``n ≤ 1000``), 5 % on hyperparameters the data determine well, and
    from the fitted GPs the predictive mean within 5 % of the predictive standard
    deviation and the variance within 2 %, with ``K`` well conditioned (see
    :func:`~jaxgaze.gp.predict`; ``tests/test_precision.py``).
    """
    _check_jitter(jitter)
    X, y = check_training_data(X, y)
    kernel = _check_kernel(kernel, X.shape[1], X.dtype)
    _check_options(num_restarts, max_steps, subset_size, method, tol, perturbation)
    n, dtype = X.shape[0], X.dtype
    key_subset, key_perturb, key_probe = jax.random.split(key, 3)
    perm = np.asarray(jax.random.permutation(key_subset, n))
    plan = _plan(n, dtype, subset_size, explore_in_float32)
    subset = functools.partial(_subset, np.asarray(X), np.asarray(y), perm)
    X0, y0 = subset(*plan[0])
    stats = data_stats(np.asarray(X0, np.float64), np.asarray(y0, np.float64))
    start_kernel = _cast(kernel._initialise(stats, stats.y_var), dtype)
    spec = kernel.trainable_filter()
    template, static = eqx.partition(start_kernel, spec)
    theta_data, unravel = ravel_pytree(template)
    if theta_data.shape[0] == 0:
        return fitted_gp(kernel, X, y, jitter, RESULTS.successful, jnp.zeros((0,), dtype), (), throw)
    starts = _starting_points(theta_data, eqx.partition(kernel, spec)[0], num_restarts, perturbation, key_perturb)
    options = _StageOptions(jitter, int(max_steps), float(tol), method, bool(progress))
    probe_keys = jax.random.split(key_probe, len(plan))
    theta, result, restart_lml, stages = _run_stages(plan, starts, template, static, subset, probe_keys, options)
    if theta is None:  # no start of the first stage had a finite likelihood
        return fitted_gp(start_kernel, X, y, jitter, RESULTS.nonfinite, restart_lml, stages, throw)
    return fitted_gp(eqx.combine(unravel(theta), static), X, y, jitter, result, restart_lml, stages, throw)


def _check_options(num_restarts, max_steps, subset_size, method, tol, perturbation) -> None:
    _check_int("num_restarts", num_restarts, 1)
    _check_int("max_steps", max_steps, 1)
    if subset_size is not None:
        _check_int("subset_size", subset_size, _MIN_POINTS)
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (tol > 0 and math.isfinite(tol)):
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    if isinstance(perturbation, bool) or not isinstance(perturbation, (int, float)) or not perturbation >= 0:
        raise ValueError(f"perturbation must be a non-negative number, got {perturbation!r}")


def _plan(n: int, dtype, subset_size, explore_in_float32: bool) -> list[tuple[int, object]]:
    """``(points, dtype)`` of each stage: the subsets of :func:`_stage_sizes` (in float32 when exploring
    float64 data in float32), the last on all data in the data dtype."""
    low = jnp.float32 if (explore_in_float32 and dtype == jnp.float64) else dtype
    sizes = _stage_sizes(n, n if subset_size is None else int(subset_size))
    plan = [(m, low) for m in sizes] + ([(n, dtype)] if low != dtype else [])
    if low != dtype and len(sizes) > 1:
        plan.remove((n, low))  # the float64 stage on all data starts from the last float32 subset's optimum
    return plan


def _subset(X: np.ndarray, y: np.ndarray, perm: np.ndarray, m: int, dtype):
    """The first ``m`` points of ``perm`` (nested subsets, kept in data order) in ``dtype``, on the device.
    Indexed on the host: indexing the device arrays would compile a few programs per stage."""
    index = np.sort(perm[:m])
    return jax.device_put((X[index].astype(np.dtype(dtype)), y[index].astype(np.dtype(dtype))))


def _starting_points(theta_data, passed, num_restarts: int, perturbation: float, key) -> list:
    """The data-driven point, the kernel as passed (``passed``: its trainable part), then the data-driven
    point perturbed by N(0, ``perturbation``²) in the log-parameters, ``num_restarts`` in all."""
    starts = [theta_data]
    if num_restarts >= 2:
        starts.append(ravel_pytree(passed)[0])
    if num_restarts > len(starts):
        noise = perturbation * jax.random.normal(key, (num_restarts - len(starts), theta_data.shape[0]),
                                                 theta_data.dtype)
        starts.extend(theta_data + noise)
    return starts


class _StageOptions(NamedTuple):
    jitter: object
    max_steps: int
    tol: float
    method: str
    progress: bool


def _run_stages(plan, starts, template, static, subset, probe_keys, options: _StageOptions):
    """Run the stages of ``plan``, each from the previous optimum (the first from every start), under one
    progress bar. Returns ``(theta, result, restart_lml, stages)``; ``theta`` is ``None`` when no start of
    the first stage reached a finite likelihood."""
    n, dtype = plan[-1]
    theta, result, restart_lml, stages = None, RESULTS.nonfinite, None, []
    with _progress.progress_bar(options.progress, desc="GP fit",
                                bar_format="{desc}: {n_fmt} evaluations [{elapsed}{postfix}]") as bar:
        for i, (m, dt) in enumerate(plan):
            bar.set_description_str(f"GP fit, stage {i + 1}/{len(plan)} ({m} points, {jnp.dtype(dt).name})")
            thetas = jnp.stack(starts) if i == 0 else theta[None]
            # A float32 stage that fails everywhere (K not positive definite in float32) is rerun in the data dtype.
            for dt in (dt, dtype) if dt != dtype else (dt,):
                Xs, ys = subset(m, dt)
                tol = options.tol if (m == n and dt == dtype) else _STAGE_TOL_FACTOR * options.tol * m / n
                tol = max(tol, _FLOAT32_DECREMENT_FLOOR * m) if dt == jnp.float32 else tol
                method = "bfgs" if (m == n and dt == jnp.float64 and len(plan) > 1) else options.method
                out = _optimise(thetas.astype(dt), _cast(template, dt), _cast(static, dt), Xs, ys, options.jitter,
                                probe_keys[i], options.max_steps, float(tol), method, options.progress)
                values = np.asarray(out.value, np.float64)  # −LML of the stage
                stages.append((m, jnp.dtype(dt).name, int(np.sum(np.asarray(out.steps)))))
                if np.isfinite(values).any():
                    break
            if i == 0:
                restart_lml = jnp.asarray(-values, dtype)
            finite = np.isfinite(values)
            if not finite.any():
                if theta is None:
                    return None, RESULTS.nonfinite, restart_lml, tuple(stages)
                result = RESULTS.optimiser_failed
                continue
            best = int(np.argmin(np.where(finite, values, np.inf)))
            bar.set_postfix_str(f"log likelihood {-values[best]:.4f} on {m} points")
            theta = out.theta[best].astype(dtype)
            result = from_name(NAMES[int(np.asarray(code(out.result))[best])])
    return theta, result, restart_lml, tuple(stages)
