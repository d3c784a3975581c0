"""Head orientation from localised facial points (ROVIS gaze following, last stage;
"Human–Robot Interaction Through Robust Gaze Following", Sec. 4).

Two estimators take the five points of :data:`jaxgaze.facial.face_model.POINTS` (eye centres,
nose tip, mouth corners) in pixels, ``NaN`` rows for the points that were not found:

* :func:`orientation_gee_cipolla`: the facial-normal method of Gee & Cipolla (1994)
  under weak perspective, two model ratios, no camera needed;
* :func:`orientation_pnp`: ``cv2.solvePnP`` against :func:`generic_face`, with a
  Gauss–Newton (Laplace) covariance of (yaw, pitch) from the reprojection Jacobian.

:func:`to_gaze_rays` turns PnP orientations into :class:`jaxgaze.GazeRays`.

Frames (``docs/conventions.md``)
--------------------------------
* **image**: pixels, origin at the top-left corner of the top-left pixel, x right,
  y down. Pinhole ``u = f X/Z + c_x``, ``v = f Y/Z + c_y``; ``principal_point``
  defaults to the image centre ``(W/2, H/2)`` when ``image_size`` is given.
* **optical**: the camera's OpenCV frame, +x right, +y down, +z forward (metres).
* **head**: +x forward out of the face, +y the person's left, +z up, origin at the
  eye midpoint (:mod:`jaxgaze.facial.face_model`).
* **frontal**: the head frame of a face that looks straight down the optical axis
  back at the camera, ``R_OPTICAL_FROM_FRONTAL = [[0,1,0],[0,0,−1],[−1,0,0]]``
  (forward = −z, left = +x, up = −y). It is the same for every head position
  (unlike the eye-contact frame of :mod:`jaxgaze.simulate.tabletop`).
* **pose** ``(yaw, pitch, roll)``, as the head model of ``docs/conventions.md``:
  ``R_optical_from_head = R_OPTICAL_FROM_FRONTAL · R_z(yaw) R_y(−pitch) R_x(roll)``.
  yaw > 0 turns the face to the person's left (the image's right), pitch > 0 up,
  roll > 0 raises the left ear (counter-clockwise in the image). (yaw, pitch) are
  ``direction_to_yaw_pitch`` of the head's forward axis in the frontal frame.
* **camera** (the repo's, for :class:`GazeRays`): +x forward, +y left, +z up,
  ``v_camera = R_OURS_FROM_OPENCV @ v_optical``.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze.facial.face_model import POINTS, R_OPTICAL_FROM_FRONTAL, FaceModel, generic_face
from jaxgaze.geometry import R_OURS_FROM_OPENCV, head_pose_to_rotation, rotation_to_head_pose
from jaxgaze.rays import GazeRays

__all__ = [
    "R_OPTICAL_FROM_FRONTAL",
    "HeadOrientation",
    "gee_cipolla_covariance",
    "head_orientation_gee_cipolla",
    "gee_cipolla_ratios",
    "orientation_gee_cipolla",
    "orientation_pnp",
    "head_pose_to_optical_rotation",
    "optical_rotation_to_head_pose",
    "to_gaze_rays",
]

#: the frontal head frame's axes (columns: forward, left, up) in the optical frame.

_RE, _LE, _NOSE, _MR, _ML = range(5)


# ---------------------------------------------------------------------------
# Pose <-> rotation (built from jaxgaze.geometry, float64)


def _optical_from_head(yaw, pitch, roll):
    return jnp.asarray(R_OPTICAL_FROM_FRONTAL) @ head_pose_to_rotation(yaw, pitch, roll)


_optical_from_head_jit = jax.jit(_optical_from_head)
_rotation_to_head_pose_jit = jax.jit(rotation_to_head_pose)


def head_pose_to_optical_rotation(yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """``R_optical_from_head = R_OPTICAL_FROM_FRONTAL · head_pose_to_rotation(yaw, pitch, roll)``, ``(3, 3)`` float64.

    :func:`jaxgaze.geometry.head_pose_to_rotation` and the fixed frontal → optical frame change.
    """
    with jax.enable_x64(True):
        R = _optical_from_head_jit(jnp.float64(yaw), jnp.float64(pitch), jnp.float64(roll))
        return np.asarray(R, dtype=np.float64)


def optical_rotation_to_head_pose(R_optical_from_head) -> tuple[float, float, float]:
    """Inverse of :func:`head_pose_to_optical_rotation`: ``(yaw, pitch, roll)`` in radians."""
    R = R_OPTICAL_FROM_FRONTAL.T @ np.asarray(R_optical_from_head, dtype=np.float64)
    with jax.enable_x64(True):
        yaw, pitch, roll = _rotation_to_head_pose_jit(jnp.asarray(R))
        return float(yaw), float(pitch), float(roll)


# ---------------------------------------------------------------------------
# Input checks


def _check_points(points_2d, visible=None, *, min_points=3) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points_2d, dtype=np.float64)
    if p.shape != (len(POINTS), 2):
        raise ValueError(f"points_2d must be ({len(POINTS)}, 2) in the order {POINTS}, got shape {p.shape}")
    if visible is None:
        vis = ~np.any(np.isnan(p), axis=1)
    else:
        vis = np.asarray(visible, dtype=bool)
        if vis.shape != (len(POINTS),):
            raise ValueError(f"visible must be ({len(POINTS)},) bool, got shape {vis.shape}")
    bad = vis & ~np.all(np.isfinite(p), axis=1)
    if bad.any():
        raise ValueError(f"points_2d: {POINTS[int(np.argmax(bad))]} is marked visible but is NaN/inf")
    if vis.sum() < min_points:
        raise ValueError(f"need at least {min_points} visible points, got {int(vis.sum())}: {[POINTS[i] for i in np.flatnonzero(vis)]}")
    q = p[vis]
    # Degenerate: coincident points, or all of them on one line.
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    scale = d.max()
    if scale < 1e-6 or np.any(d[np.triu_indices(len(q), 1)] < 1e-6 * max(scale, 1.0)):
        raise ValueError("points_2d: degenerate configuration (coincident points)")
    c = q - q.mean(0)
    sv = np.linalg.svd(c, compute_uv=False)
    if sv[1] < 1e-3 * sv[0]:
        raise ValueError("points_2d: degenerate configuration (the visible points are collinear)")
    return p, vis


# ---------------------------------------------------------------------------
# Gee & Cipolla (1994)


def gee_cipolla_ratios(model: FaceModel | None = None) -> tuple[float, float]:
    """Model ratios ``(R_m, R_n)`` from a 3D face (Gee & Cipolla 1994).

    The symmetry axis runs from the eye midpoint ``E`` to the mouth midpoint ``M``
    (length ``L_f``). The nose base ``B`` is the foot of the perpendicular from the
    nose tip ``N`` onto that axis; ``R_m = |M − B| / L_f``, ``R_n = |N − B| / L_f``.
    """
    m = generic_face() if model is None else model
    _, _, E, M, N = _model_axes(m)
    a = (M - E) / np.linalg.norm(M - E)
    B = E + np.dot(N - E, a) * a
    L_f = np.linalg.norm(M - E)
    return float(np.linalg.norm(M - B) / L_f), float(np.linalg.norm(N - B) / L_f)


def _model_axes(m: FaceModel):
    p = np.asarray(m.points, dtype=np.float64)
    E = 0.5 * (p[_RE] + p[_LE])
    M = 0.5 * (p[_MR] + p[_ML])
    N = p[_NOSE]
    a = (M - E) / np.linalg.norm(M - E)
    B = E + np.dot(N - E, a) * a
    n = (N - B) / np.linalg.norm(N - B)
    return n, a, E, M, N


def _gee_cipolla_rotation(points_2d, R_m, R_n, model: FaceModel, focal_px=None, principal_point=None, full=False):
    p, vis = _check_points(points_2d)
    if not vis[_NOSE]:
        raise ValueError("orientation_gee_cipolla needs the nose tip (the facial normal ends there)")
    mp = np.asarray(model.points, dtype=np.float64)
    eye_ratio = abs(mp[_LE, 1] - mp[_RE, 1]) / abs(mp[_ML, 1] - mp[_MR, 1])  # IPD / mouth width
    if focal_px is not None:
        # Rotate to a virtual camera looking at the face (removes the off-axis bias of
        # weak perspective); the normal is rotated back at the end.
        cx, cy = principal_point
        rays = np.column_stack([(p[:, 0] - cx) / focal_px, (p[:, 1] - cy) / focal_px, np.ones(5)])
        centre = np.nanmean(rays, axis=0)
        Rv = _rotation_to_z(centre / np.linalg.norm(centre))  # v_virtual = Rv @ v_optical
        rv = rays @ Rv.T
        p = rv[:, :2] / rv[:, 2:3]
    else:
        Rv = np.eye(3)
    # Eye and mouth midpoints; a missing far eye (or mouth corner) from the other
    # pair: in the model the eye line and the mouth line are parallel, with length
    # ratio IPD / mouth width, and weak perspective keeps ratios of parallel lengths.
    if vis[_RE] and vis[_LE]:
        e = 0.5 * (p[_RE] + p[_LE])
    elif vis[_MR] and vis[_ML] and (vis[_RE] or vis[_LE]):
        near_eye, near_mouth = (_RE, _MR) if vis[_RE] else (_LE, _ML)
        e = p[near_eye] + eye_ratio * (0.5 * (p[_MR] + p[_ML]) - p[near_mouth])
    else:
        raise ValueError("orientation_gee_cipolla needs both eyes, or one eye and both mouth corners")
    if vis[_MR] and vis[_ML]:
        mth = 0.5 * (p[_MR] + p[_ML])
    elif vis[_RE] and vis[_LE] and (vis[_MR] or vis[_ML]):
        near_eye, near_mouth = (_RE, _MR) if vis[_MR] else (_LE, _ML)
        mth = p[near_mouth] + (0.5 * (p[_RE] + p[_LE]) - p[near_eye]) / eye_ratio
    else:
        raise ValueError("orientation_gee_cipolla needs both mouth corners, or one corner and both eyes")
    u = mth - e  # image of L_f · a (times the scale)
    b = mth - R_m * u  # image of the nose base
    w = p[_NOSE] - b  # image of L_n · n = R_n L_f · n
    U2 = np.dot(u, u)
    if U2 < 1e-12:
        raise ValueError("points_2d: degenerate configuration (eye and mouth midpoints coincide)")
    # Orthographic with scale s: u = s L_f (a_x, a_y), w = s R_n L_f (n_x, n_y). With
    # x = 1/(s L_f)^2, unit a and n, and a ⊥ n:  (a·n)^2 = (1−|a_xy|^2)(1−|n_xy|^2)
    #   ⇔  A x^2 − B x + 1 = 0,  A = |u|^2 |w'|^2 sin^2θ,  B = |u|^2 + |w'|^2  (w' = w / R_n).
    # 1/|u|^2 and 1/|w'|^2 lie between the roots, so the smaller root is the one with
    # |a_xy|, |n_xy| ≤ 1 (Gee & Cipolla's slant equation, rewritten in x).
    wp = w / R_n
    W2 = np.dot(wp, wp)
    cross = u[0] * wp[1] - u[1] * wp[0]
    A = cross * cross
    B = U2 + W2
    if A < 1e-12 * B * B:
        x = 1.0 / B
    else:
        x = (B - np.sqrt(max(B * B - 4 * A, 0.0))) / (2 * A)
    sx = np.sqrt(x)
    n_xy = sx * wp
    a_xy = sx * u
    n_z = -np.sqrt(max(1.0 - np.dot(n_xy, n_xy), 0.0))  # the face looks back at the camera
    a_z = -np.dot(a_xy, n_xy) / n_z if n_z < -1e-9 else np.sqrt(max(1.0 - np.dot(a_xy, a_xy), 0.0))
    n = np.array([n_xy[0], n_xy[1], n_z])
    a = np.array([a_xy[0], a_xy[1], a_z])
    a = a - np.dot(a, n) * n
    n, a = n / np.linalg.norm(n), a / np.linalg.norm(a)
    F_cam = np.column_stack([n, a, np.cross(n, a)])
    n_h, a_h, *_ = _model_axes(model)
    F_head = np.column_stack([n_h, a_h, np.cross(n_h, a_h)])
    R = Rv.T @ F_cam @ F_head.T
    if full:
        # Weak-perspective depth: the image scale is s = 1 / (sqrt(x) L_f) per metre;
        # in normalised coordinates (focal given) s = 1 / Z.
        L_f = np.linalg.norm(0.5 * (mp[_MR] + mp[_ML]) - 0.5 * (mp[_RE] + mp[_LE]))
        Z = sx * L_f
        return R, Rv.T @ np.array([e[0] * Z, e[1] * Z, Z])
    return R


def _rotation_to_z(d):
    """A rotation ``R`` with ``R @ d = e_z`` (the smallest one)."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(d, z)
    s, c = np.linalg.norm(v), float(np.dot(d, z))
    if s < 1e-12:
        return np.eye(3)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K * ((1 - c) / s**2)


def orientation_gee_cipolla(
    points_2d,
    *,
    R_m: float | None = None,
    R_n: float | None = None,
    model: FaceModel | None = None,
    focal_px: float | None = None,
    principal_point=None,
) -> tuple[float, float]:
    """(yaw, pitch) of the head from the facial normal, radians (Gee & Cipolla 1994).

    Args:
        points_2d: ``(5, 2)`` pixels in the order of :data:`POINTS`, NaN rows missing.
        R_m, R_n: model ratios (:func:`gee_cipolla_ratios`, from ``model`` by default).
        model: the 3D face (:func:`generic_face`); it also fixes the offset between
            the facial normal and the head's forward axis, and the IPD / mouth-width
            ratio used when a far eye or mouth corner is missing.
        focal_px, principal_point: optional camera; when given, the points are first
            rotated to a virtual camera aimed at the face, which removes most of the
            weak-perspective bias of faces away from the image centre.

    The symmetry axis runs from the eye midpoint ``e`` to the mouth midpoint ``m``;
    the nose base is ``b = m − R_m (m − e)`` (ratios along a line survive weak
    perspective) and ``b → nose tip`` is the image of the facial normal. Its tilt and
    the image ratio ``|nose| / |e m|`` give the slant (derivation in the code); the
    normal and the symmetry axis give a full rotation, reported as (yaw, pitch) of the
    head's forward axis (module docstring). **Profile reading**: with the far eye
    missing, ``e = eye_near + (IPD / mouth width)(m − mouth_corner_near)``: the eye
    line and the mouth line are parallel in the model. Likewise for a missing mouth
    corner when both eyes are seen. The nose tip is required.

    Precision: it computes in float64 whatever the input, so float32 and float64 points
    agree to within 1e-5 rad (what rounding the points to float32 moves;
    ``tests/test_precision.py``).
    """
    m = generic_face() if model is None else model
    r_m, r_n = gee_cipolla_ratios(m)
    R_m = r_m if R_m is None else float(R_m)
    R_n = r_n if R_n is None else float(R_n)
    if focal_px is not None and principal_point is None:
        raise ValueError("principal_point is required with focal_px")
    R = _gee_cipolla_rotation(points_2d, R_m, R_n, m, focal_px, principal_point)
    yaw, pitch, _ = optical_rotation_to_head_pose(R)
    return yaw, pitch


def gee_cipolla_covariance(
    points_2d,
    *,
    pixel_sigma: float,
    R_m: float | None = None,
    R_n: float | None = None,
    model: FaceModel | None = None,
    focal_px: float | None = None,
    principal_point=None,
    step_px: float = 1e-3,
) -> np.ndarray:
    """``(2, 2)`` covariance of the Gee & Cipolla (yaw, pitch), radians² (ROVIS gaze following, Sec. 4).

    Of :func:`orientation_gee_cipolla`, by the delta method: ``Σ = σ² G Gᵀ`` with ``G``
    the derivative of (yaw, pitch) with respect to the visible point coordinates
    (central differences of ``step_px``), for independent isotropic point noise
    σ = ``pixel_sigma`` px. It ignores the model error (a real face is not the
    generic one) and the weak-perspective bias.
    """
    sigma = float(pixel_sigma)
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"pixel_sigma must be positive, got {pixel_sigma}")
    kw = dict(R_m=R_m, R_n=R_n, model=model, focal_px=focal_px, principal_point=principal_point)
    p, vis = _check_points(points_2d)
    G = []
    for i in np.flatnonzero(vis):
        for j in range(2):
            hi, lo = p.copy(), p.copy()
            hi[i, j] += step_px
            lo[i, j] -= step_px
            G.append((np.array(orientation_gee_cipolla(hi, **kw)) - np.array(orientation_gee_cipolla(lo, **kw))) / (2 * step_px))
    G = np.array(G).T
    return sigma**2 * G @ G.T


# ---------------------------------------------------------------------------
# PnP


def _shape_px(shape_sd, focal: float, model: FaceModel, depth: float) -> float:
    """``shape_sd`` frontal eye distances in pixels at ``depth`` (0 when ``shape_sd`` is 0)."""
    shape_sd = float(shape_sd)
    if not (np.isfinite(shape_sd) and shape_sd >= 0):
        raise ValueError(f"shape_sd must be a finite number ≥ 0, got {shape_sd}")
    eye_distance = float(np.linalg.norm(model.points[1] - model.points[0]))
    return shape_sd * focal * eye_distance / depth


class HeadOrientation(NamedTuple):
    """One head pose from :func:`orientation_pnp` (NumPy float64).

    Attributes:
        R_optical_from_head: ``(3, 3)``.
        translation_optical: ``(3,)`` the head origin (eye midpoint) in the optical frame, metres.
        yaw, pitch, roll: radians, relative to the frontal frame (module docstring).
        covariance: ``(2, 2)`` Laplace covariance of (yaw, pitch), radians².
        pose_covariance: ``(6, 6)`` of (yaw, pitch, roll, t_x, t_y, t_z).
        pixel_sigma: the point noise used (given, or estimated from the residuals).
        rms_px: RMS reprojection error of the visible points.
        num_points: how many points were used.
    """

    R_optical_from_head: np.ndarray
    translation_optical: np.ndarray
    yaw: float
    pitch: float
    roll: float
    covariance: np.ndarray
    pose_covariance: np.ndarray
    pixel_sigma: float
    rms_px: float
    num_points: int


def _residual_fn(params, X, uv, w, focal, cx, cy):
    R = _optical_from_head(params[0], params[1], params[2])
    Xc = X @ R.T + params[3:6]
    proj = jnp.stack([focal * Xc[:, 0] / Xc[:, 2] + cx, focal * Xc[:, 1] / Xc[:, 2] + cy], axis=-1)
    return ((proj - uv) * w[:, None]).reshape(-1)


_jac = jax.jit(jax.jacfwd(_residual_fn))
_res = jax.jit(_residual_fn)


def orientation_pnp(
    points_2d,
    visible=None,
    *,
    focal_px: float,
    principal_point=None,
    image_size=None,
    model: FaceModel | None = None,
    pixel_sigma: float | None = None,
    shape_sd: float = 0.0,
) -> HeadOrientation:
    """Head pose by ``cv2.solvePnP`` against the generic face, Laplace covariance (ROVIS gaze following, Sec. 4).

    Args:
        points_2d: ``(5, 2)`` pixels in the order of :data:`POINTS`.
        visible: ``(5,)`` bool; default: the rows without NaN.
        focal_px: pinhole focal length in pixels.
        principal_point: ``(c_x, c_y)``; default the image centre of ``image_size = (W, H)``.
        model: the 3D face (:func:`generic_face`).
        pixel_sigma: the point noise σ (px). ``None`` estimates it from the residuals,
            ``σ² = Σ r² / (2n − 6)``, which needs ``n ≥ 4`` points and is itself noisy
            with few degrees of freedom: pass the detector's σ for calibrated ellipses.
        shape_sd: how far a real face's points lie from the generic face's, in frontal
            eye distances (:data:`~jaxgaze.facial.face_model.FACE_SHAPE_SD` for the
            simulator's faces). The point noise becomes
            ``σ² = pixel_sigma² + (shape_sd · f d / t_z)²`` (``d`` the model's eye
            distance, ``t_z`` the head depth). The residual estimate of σ is used only
            when neither ``pixel_sigma`` nor ``shape_sd`` is given.

    Solver: with ≥ 4 points ``SOLVEPNP_SQPNP``, refined by ``SOLVEPNP_ITERATIVE``
    (Levenberg–Marquardt on the reprojection error). With 3 points OpenCV's
    ``ITERATIVE`` with an extrinsic guess, started from frontal poses at yaw 0, ±35°;
    the exactly determined P3P problem has up to 4 exact solutions and we keep the one
    closest to frontal among those with the smallest reprojection error.

    Covariance: Gauss–Newton at the solution, ``Σ = σ² (JᵀJ)⁻¹`` with ``J`` the
    Jacobian (JAX, float64) of the pixel residuals with respect to
    (yaw, pitch, roll, t); ``covariance`` is its (yaw, pitch) block.

    Precision: it computes in float64 whatever the input and the x64 setting, so float32
    and float64 points agree to within 1e-5 rad on the angles, 10 µm on the translation and
    1e-4 relative on the covariances (what rounding the points to float32 moves;
    ``tests/test_precision.py``).
    """
    p, vis = _check_points(points_2d, visible)
    m = generic_face() if model is None else model
    if principal_point is None:
        if image_size is None:
            raise ValueError("give principal_point or image_size")
        principal_point = (image_size[0] / 2.0, image_size[1] / 2.0)
    cx, cy = (float(principal_point[0]), float(principal_point[1]))
    f = float(focal_px)
    if not (np.isfinite(f) and f > 0):
        raise ValueError(f"focal_px must be positive, got {focal_px}")
    X = np.asarray(m.points, dtype=np.float64)
    Xv, uvv = X[vis], p[vis]
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    dist = np.zeros(4)
    n = int(vis.sum())

    def reproj(rvec, tvec):
        proj, _ = cv2.projectPoints(Xv, rvec, tvec, K, dist)
        return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uvv) ** 2, axis=1))))

    if n >= 4:
        ok, rvec, tvec = cv2.solvePnP(Xv, uvv, K, dist, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            raise ValueError("cv2.solvePnP (SQPNP) failed")
        ok, rvec, tvec = cv2.solvePnP(Xv, uvv, K, dist, rvec.copy(), tvec.copy(), True, cv2.SOLVEPNP_ITERATIVE)
        candidates = [(rvec, tvec)]
    else:
        # Frontal guesses: depth from the image size of the visible configuration.
        d3 = np.linalg.norm(Xv[:, None] - Xv[None], axis=-1).max()
        d2 = np.linalg.norm(uvv[:, None] - uvv[None], axis=-1).max()
        depth = f * d3 / d2
        c = uvv.mean(0)
        t0 = np.array([(c[0] - cx) / f * depth, (c[1] - cy) / f * depth, depth])
        candidates = []
        for yaw0 in (0.0, 0.6, -0.6):
            r0, _ = cv2.Rodrigues(head_pose_to_optical_rotation(yaw0, 0.0, 0.0))
            ok, rvec, tvec = cv2.solvePnP(Xv, uvv, K, dist, r0.copy(), t0.reshape(3, 1).copy(), True, cv2.SOLVEPNP_ITERATIVE)
            if ok and tvec[2, 0] > 0:
                candidates.append((rvec, tvec))
        if not candidates:
            raise ValueError("cv2.solvePnP (ITERATIVE, 3 points) failed")
    errs = np.array([reproj(r, t) for r, t in candidates])
    best = errs.min()
    good = [c for c, e in zip(candidates, errs) if e <= best + 0.05]

    def off_frontal(c):
        y, pt, _ = optical_rotation_to_head_pose(cv2.Rodrigues(c[0])[0])
        return y * y + pt * pt

    rvec, tvec = min(good, key=off_frontal)
    R = cv2.Rodrigues(rvec)[0]
    t = tvec.reshape(3).astype(np.float64)
    if t[2] <= 0:
        raise ValueError("solvePnP put the face behind the camera")
    yaw, pitch, roll = optical_rotation_to_head_pose(R)
    params = np.array([yaw, pitch, roll, *t])
    w = vis.astype(np.float64)
    uv0 = np.where(vis[:, None], p, 0.0)
    with jax.enable_x64(True):
        args = (jnp.asarray(X), jnp.asarray(uv0), jnp.asarray(w), f, cx, cy)
        r = np.asarray(_res(jnp.asarray(params), *args))
        J = np.asarray(_jac(jnp.asarray(params), *args))
    dof = 2 * n - 6
    rss = float(r @ r)
    shape_px = _shape_px(shape_sd, f, m, t[2])
    if pixel_sigma is None and shape_px == 0.0:
        if dof <= 0:
            raise ValueError("with 3 points the pose is exactly determined: pass pixel_sigma or shape_sd")
        sigma = float(np.sqrt(rss / dof))
    else:
        sigma_px = 0.0 if pixel_sigma is None else float(pixel_sigma)
        if pixel_sigma is not None and not (np.isfinite(sigma_px) and sigma_px > 0):
            raise ValueError(f"pixel_sigma must be positive, got {pixel_sigma}")
        sigma = float(np.hypot(sigma_px, shape_px))
    JtJ = J.T @ J
    if np.linalg.cond(JtJ) > 1e14:
        raise ValueError("degenerate configuration: the pose is not determined by these points")
    cov6 = sigma**2 * np.linalg.inv(JtJ)
    cov6 = 0.5 * (cov6 + cov6.T)
    return HeadOrientation(
        R_optical_from_head=R,
        translation_optical=t,
        yaw=yaw,
        pitch=pitch,
        roll=roll,
        covariance=cov6[:2, :2].copy(),
        pose_covariance=cov6,
        pixel_sigma=sigma,
        rms_px=float(np.sqrt(rss / n)),
        num_points=n,
    )


def head_orientation_gee_cipolla(
    points_2d,
    *,
    focal_px: float,
    principal_point,
    pixel_sigma: float,
    shape_sd: float = 0.0,
    R_m: float | None = None,
    R_n: float | None = None,
    model: FaceModel | None = None,
) -> HeadOrientation:
    """Facial-normal pose (Gee & Cipolla 1994) as a :class:`HeadOrientation` (for :func:`to_gaze_rays`).

    The rotation is the full one from the normal and the symmetry axis; the head
    origin is the eye midpoint's ray at the weak-perspective depth
    ``Z = L_f / |image eye→mouth length in normalised units|`` (generalised with the
    slant); ``covariance`` from :func:`gee_cipolla_covariance` with the point noise
    ``σ² = pixel_sigma² + (shape_sd · f d / Z)²`` (as :func:`orientation_pnp`).
    ``pose_covariance`` holds that (yaw, pitch) block and NaN elsewhere (not estimated).

    Precision: it computes in float64 whatever the input, so float32 and float64 points
    agree to within 1e-5 rad on the angles, 10 µm on the translation and 1e-4 relative on
    the covariance (``tests/test_precision.py``).
    """
    m = generic_face() if model is None else model
    r_m, r_n = gee_cipolla_ratios(m)
    R_m = r_m if R_m is None else float(R_m)
    R_n = r_n if R_n is None else float(R_n)
    R, t = _gee_cipolla_rotation(points_2d, R_m, R_n, m, float(focal_px), principal_point, full=True)
    yaw, pitch, roll = optical_rotation_to_head_pose(R)
    sigma = float(np.hypot(float(pixel_sigma), _shape_px(shape_sd, float(focal_px), m, float(t[2]))))
    cov = gee_cipolla_covariance(
        points_2d, pixel_sigma=sigma, R_m=R_m, R_n=R_n, model=m, focal_px=focal_px, principal_point=principal_point
    )
    cov6 = np.full((6, 6), np.nan)
    cov6[:2, :2] = cov
    p, vis = _check_points(points_2d)
    return HeadOrientation(R, t, yaw, pitch, roll, cov, cov6, sigma, float("nan"), int(vis.sum()))


# ---------------------------------------------------------------------------
# Gaze rays


def to_gaze_rays(
    orientations,
    *,
    R_world_from_camera=None,
    camera_center=None,
    extra_bandwidth: float = 0.0,
    min_bandwidth: float = 1e-3,
) -> GazeRays:
    """Head orientations → primary gaze rays, one frame of :class:`jaxgaze.GazeRays` (ROVIS gaze following, Sec. 4).

    The origin is the head origin (eye midpoint), the direction the head's forward
    axis, both moved from the optical frame to the repo's camera frame by
    ``R_OURS_FROM_OPENCV`` (x forward, y left, z up), then to the world by
    ``x_world = R_world_from_camera @ x_camera + camera_center`` (default: identity,
    i.e. the rays stay in the camera frame).

    Bandwidth: the (yaw, pitch) covariance ``C`` maps to the plane at unit depth as
    ``D C D`` with ``D = diag(cos pitch, 1)``; ``h = sqrt(tr(D C D) / 2)`` (so that
    ``E[tan² α] = 2h²`` as in ``docs/conventions.md``), combined in quadrature with
    ``extra_bandwidth`` (e.g. the eye-in-head spread, since the head is not the gaze)
    and floored at ``min_bandwidth``.

    Precision: the rays are computed in float64 and stored in JAX's default float dtype
    (float32 unless x64 is on); the two agree to within 10 µm, 1e-5 rad and 1e-4 relative
    on the bandwidth (``tests/test_precision.py``).
    """
    if isinstance(orientations, HeadOrientation):
        orientations = [orientations]
    orientations = list(orientations)
    if not orientations:
        raise ValueError("to_gaze_rays needs at least one orientation")
    Rw = np.eye(3) if R_world_from_camera is None else np.asarray(R_world_from_camera, dtype=np.float64)
    cw = np.zeros(3) if camera_center is None else np.asarray(camera_center, dtype=np.float64)
    origins, dirs, bws = [], [], []
    for o in orientations:
        origins.append(Rw @ (R_OURS_FROM_OPENCV @ np.asarray(o.translation_optical)) + cw)
        dirs.append(Rw @ (R_OURS_FROM_OPENCV @ np.asarray(o.R_optical_from_head)[:, 0]))
        D = np.diag([np.cos(o.pitch), 1.0])
        var = 0.5 * np.trace(D @ np.asarray(o.covariance) @ D)
        bws.append(max(np.sqrt(var + extra_bandwidth**2), min_bandwidth))
    return GazeRays(np.array(origins), np.array(dirs), np.array(bws))
