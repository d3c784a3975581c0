"""Precision does not change the answer (issue 19, item 5).

Every public numerical entry point runs on one fixed scene twice: on float32 inputs with
``jax_enable_x64`` off (how the suite runs) and on float64 inputs with it on. Each run must
compute in its own dtype, and the two answers must agree within the tolerance that the
entry point's docstring states. The float64 inputs are the float32 values widened, so what
differs is the arithmetic, not the data; the orientation estimators are the exception:
they compute in float64 whatever they are given, so their float64 run gets the unrounded
points and the test checks that rounding the points to float32 does not matter.

Both settings of ``jax_enable_x64`` are entered with ``jax.enable_x64(...)`` as a context
manager, which restores the previous setting (xdist runs other tests in the same process).
Each ``run_*`` function returns NumPy values, converted inside the context: a lazily
computed JAX value would otherwise be computed after the setting is restored.
"""

import math

import jax
import numpy as np
import pytest

import jaxgaze as jg
import jaxgaze.gp as gp
from jaxgaze.bias import estimate_bias
from jaxgaze.calibration.cone_fit import solve_cone_apex
from jaxgaze.facial import generic_face, orientation_gee_cipolla, orientation_pnp, to_gaze_rays
from jaxgaze.facial.orientation import head_orientation_gee_cipolla, head_pose_to_optical_rotation

DEG = math.pi / 180


def in_both_precisions(run):
    """``(run(float32) with x64 off, run(float64) with x64 on)``; the setting is restored after each."""
    with jax.enable_x64(False):
        low = run(np.float32)
    with jax.enable_x64(True):
        high = run(np.float64)
    return low, high


def assert_dtypes(values: dict, dtype, names=None) -> None:
    for name in values if names is None else names:
        assert np.asarray(values[name]).dtype == dtype, (name, np.asarray(values[name]).dtype)


def angle(u, v) -> np.ndarray:
    """Angle between unit vectors (radians), accurate for tiny angles."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    return 2 * np.arcsin(np.clip(np.linalg.norm(u - v, axis=-1) / 2, 0.0, 1.0))


# ---------------------------------------------------------------------------
# Concurrences (Park et al. 2012, Sec. 3.3)

TARGETS = np.array([[2.0, 3.0, 1.2], [-2.5, -1.0, 1.0]])


def two_groups_and_a_bystander() -> tuple[np.ndarray, np.ndarray]:
    """Two groups of four looking at TARGETS (0.02 rad direction noise) and a bystander."""
    rng = np.random.default_rng(3)
    origins, directions = [], []
    for g, target in enumerate(TARGETS):
        for a in np.linspace(0, 2 * np.pi, 4, endpoint=False) + 0.3:
            origin = target + [(2.0 + g) * np.cos(a), (2.0 + g) * np.sin(a), 0.6]
            d = (target - origin) / np.linalg.norm(target - origin)
            origins.append(origin)
            directions.append(d + 0.02 * rng.standard_normal(3))
    origins.append([8.0, 8.0, 1.7])
    directions.append([1.0, 0.0, 0.0])
    return np.array(origins, np.float32), np.array(directions, np.float32)


def run_concurrences(dtype) -> dict:
    origins, directions = two_groups_and_a_bystander()
    found = jg.find_concurrences(jg.GazeRays(origins.astype(dtype), directions.astype(dtype), dtype(0.02)))
    return {name: np.asarray(value) for name, value in found._asdict().items()}


CONCURRENCE_FLOATS = ("locations", "covariances", "field_values", "region_semi_axes")


def test_find_concurrences_float32_matches_float64():
    low, high = in_both_precisions(run_concurrences)
    assert_dtypes(low, np.float32, CONCURRENCE_FLOATS)
    assert_dtypes(high, np.float64, CONCURRENCE_FLOATS)
    assert low["locations"].shape == high["locations"].shape == (2, 3)
    for name in ("membership", "num_rays", "converged"):
        np.testing.assert_array_equal(low[name], high[name], err_msg=name)
    # Tolerances: 10 µm on the locations (below the mean-shift stopping step of 0.1 mm, so
    # the refinement must have converged in both precisions), 1e-5 relative on the
    # covariances (of each one's largest entry) and field values, 1e-4 on the semi-axes.
    np.testing.assert_allclose(low["locations"], high["locations"], rtol=0, atol=1e-5)
    cov_scale = np.abs(high["covariances"]).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(low["covariances"] - high["covariances"]) <= 1e-5 * cov_scale)
    np.testing.assert_allclose(low["field_values"], high["field_values"], rtol=1e-5)
    finite = np.isfinite(high["region_semi_axes"])
    np.testing.assert_array_equal(np.isfinite(low["region_semi_axes"]), finite)
    np.testing.assert_allclose(low["region_semi_axes"][finite], high["region_semi_axes"][finite], rtol=1e-4)


# ---------------------------------------------------------------------------
# Calibration (Park et al. 2012, Sec. 3.2)


def points_of_regard() -> np.ndarray:
    """80 points of regard of one wearer (camera frame, m): a cone with h = 0.03 rad from an
    eye centre 9 cm below and 2 cm left of the camera, at depths 1–4 m; 6 of them outliers."""
    rng = np.random.default_rng(11)
    eye = np.array([0.0, 0.02, -0.09])
    v = np.array([1.0, -0.03, 0.04]) / np.linalg.norm([1.0, -0.03, 0.04])
    basis = np.linalg.svd(v[None])[2][1:]  # two unit vectors ⊥ v
    depth = rng.uniform(1.0, 4.0, 80)
    points = eye + depth[:, None] * (v + 0.03 * rng.standard_normal((80, 2)) @ basis)
    points[:6] = rng.uniform([0.5, -2, -1], [4, 2, 1], (6, 3))
    return points.astype(np.float32)


def run_calibration(dtype) -> dict:
    points = points_of_regard().astype(dtype)
    fit = jg.calibrate_cone(points, key=jax.random.key(0))
    out = {name: np.asarray(getattr(fit, name)) for name in ("eye_center", "direction", "bandwidth", "alpha", "xi")}
    out["inliers"] = np.asarray(fit.inliers)
    # The apex programme (eq. 2) on its own, on the fitted cone's a_i, b_i (computed in dtype).
    rel = points - (out["eye_center"] + out["alpha"] * out["direction"])
    b = rel @ out["direction"]
    a = np.linalg.norm(rel - b[:, None] * out["direction"], axis=-1)
    apex_alpha, apex_xi = solve_cone_apex(a, np.maximum(b, 0), mask=out["inliers"])
    out.update(apex_alpha=np.asarray(apex_alpha), apex_xi=np.asarray(apex_xi))
    return out


CALIBRATION_FLOATS = ("eye_center", "direction", "bandwidth", "alpha", "xi", "apex_alpha", "apex_xi")


def test_calibrate_cone_float32_matches_float64():
    low, high = in_both_precisions(run_calibration)
    assert_dtypes(low, np.float32, CALIBRATION_FLOATS)
    assert_dtypes(high, np.float64, CALIBRATION_FLOATS)
    np.testing.assert_array_equal(low["inliers"], high["inliers"])
    assert 70 <= low["inliers"].sum() <= 74  # the cone's points, not the outliers
    # Tolerances: 10 µm on the eye centre and α, 1e-6 rad on the direction, 1e-5 relative
    # on h and ξ.
    np.testing.assert_allclose(low["eye_center"], high["eye_center"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(low["alpha"], high["alpha"], rtol=0, atol=1e-5)
    assert angle(low["direction"], high["direction"]) < 1e-6
    np.testing.assert_allclose(low["bandwidth"], high["bandwidth"], rtol=1e-5)
    np.testing.assert_allclose(low["xi"], high["xi"], rtol=1e-5)
    np.testing.assert_allclose(low["apex_alpha"], high["apex_alpha"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(low["apex_xi"], high["apex_xi"], rtol=1e-5)


# ---------------------------------------------------------------------------
# Bias estimators (Siegfried et al. 2017)


def bias_offsets() -> np.ndarray:
    """40 offsets (rad): 24 around a bias of (5°, −8°) with 3° noise, 16 glances elsewhere within ±40°."""
    rng = np.random.default_rng(2017)
    looking = np.radians([5.0, -8.0]) + 3 * DEG * rng.standard_normal((24, 2))
    elsewhere = 40 * DEG * rng.uniform(-1, 1, (16, 2))
    return np.concatenate([looking, elsewhere]).astype(np.float32)


def run_bias(method):
    def run(dtype) -> dict:
        options = dict(key=jax.random.key(1), num_warmup=200, num_samples=200) if method == "bayes" else {}
        est = estimate_bias(bias_offsets().astype(dtype), method, **options)
        out = {"bias": np.asarray(est.bias), "inliers": np.asarray(est.inliers), "candidate": est.candidate}
        if method == "bayes":
            out.update(draws=np.asarray(est.samples["bias"]), sd=np.sqrt(np.diag(est.covariance)),
                       responsibilities=np.asarray(est.responsibilities))
        return out

    return run


@pytest.mark.parametrize("method", ["mean", "lmeds"])
def test_point_bias_estimators_float32_match_float64(method):
    low, high = in_both_precisions(run_bias(method))
    assert low["bias"].dtype == np.float32 and high["bias"].dtype == np.float64
    np.testing.assert_array_equal(low["inliers"], high["inliers"])
    assert low["candidate"] == high["candidate"]
    np.testing.assert_allclose(low["bias"], high["bias"], rtol=0, atol=1e-6)  # rad


def test_bayes_bias_float32_matches_float64_within_the_posterior_spread():
    low, high = in_both_precisions(run_bias("bayes"))
    assert low["draws"].dtype == np.float32 and high["draws"].dtype == np.float64
    # The two precisions give different chains, so their posterior means differ by Monte
    # Carlo error (≈ 0.14 sd for two chains of ~100 effective draws each). Tolerances:
    # 0.5 posterior sd on the mean, 30 % on the sd, 0.1 on each frame's responsibility.
    sd = high["sd"]
    np.testing.assert_array_less(np.abs(low["bias"] - high["bias"]), 0.5 * sd)
    np.testing.assert_allclose(low["sd"], sd, rtol=0.3)
    np.testing.assert_allclose(low["responsibilities"], high["responsibilities"], rtol=0, atol=0.1)


# ---------------------------------------------------------------------------
# GP engine (Rasmussen & Williams 2006)


def gp_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """60 noisy points of a smooth surface on [−2, 2]² and 20 test inputs on [−2.5, 2.5]²."""
    rng = np.random.default_rng(7)
    X = rng.uniform(-2, 2, (60, 2))
    y = np.sin(1.5 * X[:, 0]) * np.cos(X[:, 1]) + 0.2 * rng.standard_normal(60)
    X_new = rng.uniform(-2.5, 2.5, (20, 2))
    return X.astype(np.float32), y.astype(np.float32), X_new.astype(np.float32)


def run_gp(dtype) -> tuple[dict, object]:
    """``predict`` with a fixed kernel, then ``fit`` (one start) and ``FittedGP.predict``.

    ``predict`` goes through the same compiled factorisation and prediction as the fit's
    last step (same kernel structure and shapes), so it costs no compilation of its own.
    ``explore_in_float32=False`` keeps float32 out of the float64 fit (by default it
    explores in float32 and polishes in float64), so the two fits share no arithmetic, and
    ``tol=1e-4`` takes the float64 fit close to the optimum (float32 stops at its own floor).
    """
    X, y, X_new = (a.astype(dtype) for a in gp_scene())
    mean, var = gp.predict(gp.RBF(0.2, 0.9) + gp.White(0.03), X, y, X_new)
    out = {"fixed mean": np.asarray(mean), "fixed var": np.asarray(var)}
    fitted = gp.fit(gp.RBF(1.0, 1.0) + gp.White(0.1), X, y, key=jax.random.key(0), num_restarts=1, tol=1e-4,
                    explore_in_float32=False)
    mean, var = fitted.predict(X_new)
    out.update({f"hyper {k}": np.asarray(v) for k, v in fitted.kernel.hyperparameters().items()})
    out.update(lml=np.asarray(fitted.log_marginal_likelihood), mean=np.asarray(mean), var=np.asarray(var))
    return out, fitted.result


@pytest.fixture(scope="module")
def gp_runs():
    (low, low_result), (high, high_result) = in_both_precisions(run_gp)
    assert low_result == jg.RESULTS.successful and high_result == jg.RESULTS.successful
    assert_dtypes(low, np.float32)
    assert_dtypes(high, np.float64)
    return low, high


def test_gp_predict_float32_matches_float64(gp_runs):
    low, high = gp_runs
    # Tolerances: the mean within 1e-3 predictive sd, the variance within 1e-3 relative
    # (the float32 run also adds a 10× larger default jitter).
    sd = np.sqrt(high["fixed var"])
    np.testing.assert_array_less(np.abs(low["fixed mean"] - high["fixed mean"]), 1e-3 * sd)
    np.testing.assert_allclose(low["fixed var"], high["fixed var"], rtol=1e-3)


def test_gp_fit_float32_matches_float64(gp_runs):
    low, high = gp_runs
    # Tolerances: 1e-2 on the log marginal likelihood, 5 % on each hyperparameter (all
    # well determined here), and from the fitted GPs the mean within 5 % of the predictive
    # sd and the variance within 2 %. The float32 fit stops at its rounding level (Newton
    # decrement 1e-5 × points, 6e-4 here), about 1 % short of the optimum in the
    # hyperparameters; the float64 one (tol=1e-4) is the reference.
    np.testing.assert_allclose(low["lml"], high["lml"], rtol=0, atol=1e-2)
    hyper = [name for name in low if name.startswith("hyper")]
    assert len(hyper) == 3
    for name in hyper:
        np.testing.assert_allclose(low[name], high[name], rtol=5e-2, err_msg=name)
    sd = np.sqrt(high["var"])
    np.testing.assert_array_less(np.abs(low["mean"] - high["mean"]), 5e-2 * sd)
    np.testing.assert_allclose(low["var"], high["var"], rtol=2e-2)


# ---------------------------------------------------------------------------
# Head orientation from facial points (ROVIS gaze following, Sec. 4)

F = 800.0
C = (320.0, 240.0)


def face_points() -> np.ndarray:
    """The generic face at yaw 0.3, pitch −0.15, roll 0.05 rad, 0.6 m away, 1 px noise (float64 px)."""
    R = head_pose_to_optical_rotation(0.3, -0.15, 0.05)
    X = generic_face().points @ R.T + [0.03, -0.02, 0.6]
    uv = np.column_stack([F * X[:, 0] / X[:, 2] + C[0], F * X[:, 1] / X[:, 2] + C[1]])
    return uv + np.random.default_rng(5).standard_normal(uv.shape)


def run_orientation(dtype) -> tuple[dict, dict]:
    uv = face_points().astype(dtype)  # float64: the unrounded points
    pnp = orientation_pnp(uv, focal_px=F, principal_point=C, pixel_sigma=1.0)
    gee = head_orientation_gee_cipolla(uv, focal_px=F, principal_point=C, pixel_sigma=1.0)
    rays = to_gaze_rays([pnp, gee])
    return {
        "pnp pose": np.array([pnp.yaw, pnp.pitch, pnp.roll]),
        "pnp covariance": pnp.pose_covariance,
        "pnp translation": pnp.translation_optical,
        "gee pose": np.array([gee.yaw, gee.pitch, gee.roll]),
        "gee covariance": gee.covariance,
        "gee translation": gee.translation_optical,
        "gee yaw pitch (weak perspective)": np.array(orientation_gee_cipolla(uv)),
    }, {"origins": np.asarray(rays.origins), "directions": np.asarray(rays.directions),
        "bandwidth": np.asarray(rays.bandwidth)}


def test_orientation_float32_points_match_float64():
    (low, low_rays), (high, high_rays) = in_both_precisions(run_orientation)
    # The estimators compute in float64 whatever the input (NumPy, OpenCV and a JAX
    # Jacobian under x64); the rays follow the x64 setting like every GazeRays.
    assert_dtypes(low, np.float64)
    assert_dtypes(high, np.float64)
    assert_dtypes(low_rays, np.float32)
    assert_dtypes(high_rays, np.float64)
    # Tolerances: 1e-5 rad on the angles, 1e-4 relative on the covariances, 10 µm on the
    # head position (rounding the points to float32 moves them by up to 2e-5 px).
    for name in ("pnp pose", "gee pose", "gee yaw pitch (weak perspective)"):
        np.testing.assert_allclose(low[name], high[name], rtol=0, atol=1e-5, err_msg=name)
    for name in ("pnp covariance", "gee covariance"):
        np.testing.assert_allclose(low[name], high[name], rtol=1e-4, err_msg=name)
    for name in ("pnp translation", "gee translation"):
        np.testing.assert_allclose(low[name], high[name], rtol=0, atol=1e-5, err_msg=name)
    np.testing.assert_allclose(low_rays["origins"], high_rays["origins"], rtol=0, atol=1e-5)
    assert np.all(angle(low_rays["directions"], high_rays["directions"]) < 1e-5)
    np.testing.assert_allclose(low_rays["bandwidth"], high_rays["bandwidth"], rtol=1e-4)
