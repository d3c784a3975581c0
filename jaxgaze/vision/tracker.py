"""6-DoF head tracking with the cylindrical head model (Yücel et al. T-CYB 2013, Sec. IV, eq. 1–4).

The head is the elliptic cylinder of :mod:`jaxgaze.vision.head_model`, placed on
the first frame's face box in the frontal (eye-contact) pose. Between frames
``F_i`` and ``F_{i+1}`` the rigid update ``Δμ = (ω, τ)`` moves the head:
``p ↦ R(ω) (p − c) + c + τ`` (``R(ω)`` a rotation vector about the head
centre ``c``, in optical axes; ``τ`` metres). It minimises the photometric
difference (eq. 4, Lucas–Kanade as in Xiao, Kanade & Cohn 2003)::

    Σ_k  w_k [ I_{i+1}(P(M(Δμ) p_k)) − I_i(P(p_k)) ]²

over points ``p_k`` on a regular grid on the front half of the cylinder at
frame ``i``'s pose, ``P`` the pinhole of ``head_model``, ``w_k`` their
visibility (the cosine between the normal and the line of sight, ramped to 0
at grazing angles, and 0 outside the image). The dynamic template (the
previous frame) is the paper's choice. Each frame is solved with
``optimistix.LevenbergMarquardt`` on a coarse-to-fine pyramid (a Gaussian blur,
then ``cv2.pyrDown``), bilinear samples from ``jax.scipy.ndimage.map_coordinates``;
the step compiles once per frame shape and pyramid depth.

The default ``reference="previous"`` is the paper's dynamic template alone.
With ``reference="first"`` each frame is then registered again against the
**first frame's** template (the intensities at the cylinder's points in the
initial pose, for those points visible both then and now), to bound drift.
On synthetic sequences the dynamic template hardly drifts, and ``"first"``
gives the same rotation errors (it locks in the error of the initial box),
a smaller translation error, and costs more time, so it is an option, not the
default.

Poses are ``(pitch, yaw, roll)`` of ``R_frontal_from_head`` relative to the
initial frontal frame, signs as :mod:`jaxgaze.simulate.tabletop`: yaw > 0 to
the person's left (image right), pitch > 0 up, roll > 0 left ear up.
When the pose leaves ``±50°`` pitch, ``±40°`` yaw or ``±20°`` roll, the face
is detected again in that frame and the head reset to frontal on it
(``reinitialised``); if no face is found the tracker is *lost* (NaN pose and
translation) until a later frame has one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import lineax as lx
import optimistix as optx

from jaxgaze.geometry import axis_angle_to_rotation_matrix, rotation_to_head_pose
from jaxgaze.results import RESULTS, code, from_optimistix
from jaxgaze.vision.head_model import (
    CylinderHead,
    distance_for_width_px,
    frontal_rotation,
    surface_grid,
)
from jaxgaze.vision.images import check_image, iterate_frames, to_gray_float

__all__ = ["HeadTrack", "TRACKED_RANGE_DEG", "initial_head_position", "track_head"]

#: Largest |pitch|, |yaw|, |roll| (degrees) the tracker keeps before reinitialising (T-CYB Sec. IV).
TRACKED_RANGE_DEG = (50.0, 40.0, 20.0)

_TAU_SCALE = 0.1  # metres per unit of the translation parameters: balances ω (rad) and τ in LM's damping
_MIN_COARSE_SIDE = 40
_COS_RAMP = (0.4, 0.7)  # visibility weight: 0 below, 1 above this cosine between normal and line of sight


class HeadTrack(NamedTuple):
    """What :func:`track_head` returns, one row per frame (NumPy arrays).

    Attributes:
        pose: ``(T, 3)`` (pitch, yaw, roll) radians of the head relative to the
            (latest) initial frontal pose; NaN while lost.
        translation: ``(T, 3)`` the head centre (cylinder axis, mid-height) in the
            optical frame (x right, y down, z forward), metres; NaN while lost.
        residual: ``(T,)`` mean absolute intensity difference (grey, 0…1) over the
            visible points after the update; 0 on an initialisation, NaN while lost.
        reinitialised: ``(T,)`` True where the head was (re)placed on a detected face
            (not frame 0) or the range check fired.
        result: ``(T,)`` per frame, a :class:`~jaxgaze.results.RESULTS` item (read it with
            :func:`jaxgaze.succeeded`): ``successful`` where every least-squares solve stopped on its
            tolerance (or the head was placed on a detected face), the first failed solve's code
            (through :func:`~jaxgaze.results.from_optimistix`) otherwise, and ``lost`` while lost.
        R_optical_from_frontal: ``(T, 3, 3)`` the frontal frame the pose is relative to.
    """

    pose: np.ndarray
    translation: np.ndarray
    residual: np.ndarray
    reinitialised: np.ndarray
    result: RESULTS
    R_optical_from_frontal: np.ndarray


# ---------------------------------------------------------------------------
# Initialisation


def _box_tuple(box, name="initial_box") -> tuple[float, float, float, float]:
    try:
        if all(hasattr(box, k) for k in ("x", "y", "width", "height")):
            values = (box.x, box.y, box.width, box.height)
        else:
            values = tuple(box)[:4]
            if len(values) != 4:
                raise ValueError
        values = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be (x, y, width, height) in pixels or a FaceBox, got {box!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} must be finite, got {values}")
    if values[2] <= 0 or values[3] <= 0:
        raise ValueError(f"{name} must have a positive width and height, got {values}")
    return values


def initial_head_position(box, *, focal_px: float, image_size, head: CylinderHead = CylinderHead(), head_width_in_box=1.0):
    """The head centre (optical frame, metres) that puts the frontal cylinder on ``box``.

    The cylinder's projected width is ``head_width_in_box × box width``, which
    fixes its depth (:func:`~jaxgaze.vision.head_model.distance_for_width_px`);
    its centre is on the line of sight through the box centre.
    """
    x, y, w, h = _box_tuple(box)
    width, height = image_size
    cu, cv = x + w / 2.0, y + h / 2.0
    if not (0 <= cu <= width and 0 <= cv <= height) or w > 4 * width:
        raise ValueError(
            f"initial_box {(x, y, w, h)} is outside the {width}x{height} image (its centre must be inside)"
        )
    if w < 8:
        raise ValueError(f"initial_box is {w:g} px wide; the tracker needs a face at least 8 px wide")
    depth = distance_for_width_px(head, head_width_in_box * w, focal_px)
    return np.array([(cu - width / 2.0) * depth / focal_px, (cv - height / 2.0) * depth / focal_px, depth])


def _detected_box(detector, frame):
    found = detector(frame)
    if found is None:
        return None
    if all(hasattr(found, k) for k in ("x", "y", "width", "height")):
        return found
    found = list(found)
    if not found:
        return None
    if isinstance(found[0], (int, float, np.integer, np.floating)):
        return tuple(found)
    return found[0]


def _default_detector(frame):
    from jaxgaze.vision.faces import detect_faces  # lazily: written alongside this module

    return detect_faces(frame, kinds=("frontal",))  # the tracker starts from a frontal face


# ---------------------------------------------------------------------------
# The jitted update


def _float():
    """JAX's default float: float32, or float64 under ``jax_enable_x64`` (the pose solve
    must use one dtype throughout; optimistix's damping term follows the default)."""
    return jnp.zeros(()).dtype


def _project(points, focal, centre, scale):
    """Pixel ``(row, col)`` array indices at pyramid scale ``scale`` of optical points ``(N, 3)``."""
    z = jnp.maximum(points[:, 2], 1e-6)
    u = (focal * points[:, 0] / z + centre[0]) * scale - 0.5
    v = (focal * points[:, 1] / z + centre[1]) * scale - 0.5
    return v, u


def _sample(image, rows, cols):
    return jax.scipy.ndimage.map_coordinates(image, [rows, cols], order=1, mode="nearest")


def _visibility(points, normals, focal, centre, size):
    """Weight per point: cosine between normal and line of sight, ramped 0.15 → 0.45, times in-image."""
    cos = jnp.sum(normals * -points, axis=-1) / jnp.linalg.norm(points, axis=-1)
    weight = jnp.clip((cos - _COS_RAMP[0]) / (_COS_RAMP[1] - _COS_RAMP[0]), 0.0, 1.0)
    v, u = _project(points, focal, centre, 1.0)
    inside = (u > 1.0) & (u < size[0] - 2.0) & (v > 1.0) & (v < size[1] - 2.0) & (points[:, 2] > 1e-3)
    return jnp.where(inside, weight, 0.0)


def _moved(params, points, c):
    R = axis_angle_to_rotation_matrix(params[:3])
    return (points - c) @ R.T + c + _TAU_SCALE * params[3:]


def _residuals(params, args):
    points, c, template, sqrt_w, image, focal, centre, scale = args
    rows, cols = _project(_moved(params, points, c), focal, centre, scale)
    return sqrt_w * (_sample(image, rows, cols) - template)


def _linear_solver():
    # Cholesky on the (damped) normal equations: 6 unknowns, thousands of residuals; ~7x faster
    # than LM's default QR on CPU. lineax < 0.0.8 has no Normal: fall back to QR.
    normal = getattr(lx, "Normal", None)
    return lx.QR() if normal is None else normal(lx.Cholesky())


def _solve(params, args, max_steps):
    solver = optx.LevenbergMarquardt(rtol=1e-3, atol=1e-4, linear_solver=_linear_solver())
    sol = optx.least_squares(_residuals, solver, params, args=args, max_steps=max_steps, throw=False)
    return jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, params), from_optimistix(sol.result)


@jax.jit(static_argnames=("max_steps", "use_reference"))
def _update(prev, cur, R, t, points_head, normals_head, ref_values, ref_weights, focal, centre, *, max_steps, use_reference):
    """One frame: ``(R_new, t_new, residual, result)``, ``result`` the first failed solve's code.

    ``prev``/``cur`` are pyramids (tuples, fine first). ``ref_values``/``ref_weights``
    are the first frame's template, used when ``use_reference``.
    """
    size = jnp.array([prev[0].shape[1], prev[0].shape[0]], _float())
    points = points_head @ R.T + t
    normals = normals_head @ R.T
    weight = _visibility(points, normals, focal, centre, size)
    params = jnp.zeros(6, _float())
    result = RESULTS.successful
    for level in reversed(range(len(prev))):
        scale = 0.5**level
        rows, cols = _project(points, focal, centre, scale)
        template = _sample(prev[level], rows, cols)
        args = (points, t, template, jnp.sqrt(weight), cur[level], focal, centre, scale)
        params, level_result = _solve(params, args, max_steps)
        result = RESULTS.where(result == RESULTS.successful, level_result, result)

    R_new = axis_angle_to_rotation_matrix(params[:3]) @ R
    t_new = t + _TAU_SCALE * params[3:]

    if use_reference:  # re-register on the first frame's template (static template, finest level)
        moved = points_head @ R_new.T + t_new
        w_ref = ref_weights * _visibility(moved, normals_head @ R_new.T, focal, centre, size)
        enough = jnp.sum(w_ref) > 0.25 * jnp.sum(ref_weights) + 1e-6  # enough of the first face still in view
        args = (moved, t_new, ref_values, jnp.sqrt(w_ref), cur[0], focal, centre, 1.0)
        refined, refined_result = _solve(jnp.zeros(6, _float()), args, max_steps)
        refined = jnp.where(enough, refined, jnp.zeros(6, _float()))
        refined_result = RESULTS.where(enough, refined_result, RESULTS.successful)
        result = RESULTS.where(result == RESULTS.successful, refined_result, result)
        R_new = axis_angle_to_rotation_matrix(refined[:3]) @ R_new
        t_new = t_new + _TAU_SCALE * refined[3:]

    # Residual against the dynamic template at the final pose.
    rows, cols = _project(points, focal, centre, 1.0)
    template = _sample(prev[0], rows, cols)
    rows, cols = _project(points_head @ R_new.T + t_new, focal, centre, 1.0)
    diff = jnp.abs(_sample(cur[0], rows, cols) - template)
    residual = jnp.sum(weight * diff) / jnp.maximum(jnp.sum(weight), 1e-6)
    return R_new, t_new, residual, result


@jax.jit
def _template(image, R, t, points_head, normals_head, focal, centre):
    size = jnp.array([image.shape[1], image.shape[0]], _float())
    points = points_head @ R.T + t
    weight = _visibility(points, normals_head @ R.T, focal, centre, size)
    rows, cols = _project(points, focal, centre, 1.0)
    return _sample(image, rows, cols), weight


# ---------------------------------------------------------------------------
# Driver


def _pyramid(gray, levels, blur_sigma):
    import cv2

    image = cv2.GaussianBlur(gray, (0, 0), blur_sigma) if blur_sigma > 0 else gray
    out = [image]
    for _ in range(levels - 1):
        out.append(cv2.pyrDown(out[-1]))
    return tuple(out)


def track_head(
    frames,
    *,
    initial_box=None,
    focal_px: float,
    head: CylinderHead = CylinderHead(),
    head_width_in_box: float = 1.0,
    detector: Callable | None = None,
    reference: str = "previous",
    levels: int = 3,
    blur_sigma: float = 1.0,
    max_steps: int = 20,
    grid: tuple[int, int] = (48, 48),
) -> HeadTrack:
    """Track the 6-DoF head pose through ``frames`` with the cylinder model (Yücel et al. 2013, Sec. IV, eq. 1–4).

    Args:
        frames: a sequence, array ``(T, H, W[, 3])`` or iterator of images (grey or
            RGB, uint8 or float in [0, 1]; :func:`~jaxgaze.vision.images.check_image`),
            all the same size. Frame 0 must show the face frontally (eye contact).
        initial_box: the face box in frame 0, ``(x, y, width, height)`` pixels (image
            corner origin) or a ``FaceBox``. ``None`` detects it with ``detector``.
        focal_px: pinhole focal length; the principal point is the image centre.
        head: the cylinder's dimensions.
        head_width_in_box: the head's projected width as a fraction of the box width.
        detector: ``frame -> boxes`` (best first; a box; or None/empty for none), used
            for ``initial_box=None`` and reinitialisation. Default
            :func:`jaxgaze.vision.faces.detect_faces`.
        reference: ``"previous"`` (the paper's dynamic template) or ``"first"``
            (then re-registered on the first frame's template, see above).
        levels: pyramid levels (fewer if the coarsest side would drop below 40 px).
        blur_sigma: Gaussian blur (pixels) of the finest level before the pyramid.
        max_steps: Levenberg–Marquardt steps per level.
        grid: ``(angle, height)`` sample points on the cylinder's front half.

    Returns:
        :class:`HeadTrack`.

    Raises:
        ValueError: an empty sequence, frames of differing shapes, a bad image, an
            ``initial_box`` outside the image, or no face found in frame 0.
    """
    if reference not in ("first", "previous"):
        raise ValueError(f"reference must be 'first' or 'previous', got {reference!r}")
    focal = float(focal_px)
    if not math.isfinite(focal) or focal <= 0:
        raise ValueError(f"focal_px must be a positive finite number, got {focal_px!r}")
    head = head.checked()
    if int(levels) < 1 or int(max_steps) < 1:
        raise ValueError(f"levels and max_steps must be at least 1, got {levels}, {max_steps}")
    detector = _default_detector if detector is None else detector
    points_head, normals_head = (jnp.asarray(x, _float()) for x in surface_grid(head, *grid))
    ranges = np.radians(TRACKED_RANGE_DEG)

    rows = []  # (pose, translation, residual, reinitialised, result code, R_optical_from_frontal)
    ok, lost = int(code(RESULTS.successful)), int(code(RESULTS.lost))
    shape = None
    prev = None
    state = None  # (R_optical_from_head, t, R_optical_from_frontal) or None when lost
    ref = None
    nan3 = np.full(3, np.nan)

    def initialise(box):
        t0 = initial_head_position(
            box, focal_px=focal, image_size=(shape[1], shape[0]), head=head, head_width_in_box=head_width_in_box
        )
        Rf = frontal_rotation(t0)
        return (jnp.asarray(Rf, _float()), jnp.asarray(t0, _float()), Rf)

    def reference_template(image, st):
        if reference != "first":
            return jnp.zeros(points_head.shape[0], _float()), jnp.zeros(points_head.shape[0], _float())
        return _template(image, st[0], st[1], points_head, normals_head, focal_j, centre)

    for index, frame in enumerate(iterate_frames(frames)):
        gray = to_gray_float(frame, f"frames[{index}]")
        if shape is None:
            shape = gray.shape
            n = int(levels)
            while n > 1 and min(shape) / 2 ** (n - 1) < _MIN_COARSE_SIDE:
                n -= 1
            num_levels = n
            centre = jnp.array([shape[1] / 2.0, shape[0] / 2.0], _float())
            focal_j = jnp.asarray(focal, _float())
        elif gray.shape != shape:
            raise ValueError(f"frames[{index}] is {gray.shape[1]}x{gray.shape[0]} px but frame 0 is {shape[1]}x{shape[0]}")
        pyr = tuple(jnp.asarray(level, _float()) for level in _pyramid(gray, num_levels, float(blur_sigma)))

        if index == 0:
            box = initial_box
            if box is None:
                box = _detected_box(detector, check_image(frame, "frames[0]"))
                if box is None:
                    raise ValueError("no face found in frames[0] to initialise the head tracker; pass initial_box")
            state = initialise(box)
            ref = reference_template(pyr[0], state)
            rows.append((np.zeros(3), np.asarray(state[1], float), 0.0, False, ok, state[2]))
        elif state is None:  # lost: look for a face again
            box = _detected_box(detector, frame)
            if box is None:
                rows.append((nan3, nan3, np.nan, False, lost, np.full((3, 3), np.nan)))
            else:
                state = initialise(box)
                ref = reference_template(pyr[0], state)
                rows.append((np.zeros(3), np.asarray(state[1], float), 0.0, True, ok, state[2]))
        else:
            R, t, Rf = state
            R, t, residual, result = _update(
                prev, pyr, R, t, points_head, normals_head, ref[0], ref[1], focal_j, centre,
                max_steps=int(max_steps), use_reference=reference == "first",
            )
            yaw, pitch, roll = rotation_to_head_pose(jnp.asarray(Rf.T, _float()) @ R)
            pose = np.array([pitch, yaw, roll], dtype=float)
            if np.all(np.abs(pose) <= ranges) and np.all(np.isfinite(pose)):
                state = (R, t, Rf)
                rows.append((pose, np.asarray(t, float), float(residual), False, int(code(result)), Rf))
            else:
                box = _detected_box(detector, frame)
                if box is None:
                    state = None
                    rows.append((nan3, nan3, np.nan, True, lost, np.full((3, 3), np.nan)))
                else:
                    state = initialise(box)
                    ref = reference_template(pyr[0], state)
                    rows.append((np.zeros(3), np.asarray(state[1], float), 0.0, True, ok, state[2]))
        prev = pyr

    if not rows:
        raise ValueError("frames is empty: nothing to track")
    pose, translation, residual, reinit, codes, Rf = zip(*rows)
    return HeadTrack(
        pose=np.stack(pose),
        translation=np.stack(translation),
        residual=np.asarray(residual, float),
        reinitialised=np.asarray(reinit, bool),
        result=jax.tree.unflatten(jax.tree.structure(RESULTS.successful), [np.asarray(codes, np.int32)]),
        R_optical_from_frontal=np.stack(Rf),
    )
