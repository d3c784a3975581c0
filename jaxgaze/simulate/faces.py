"""Simulated faces with facial-feature ROI hypotheses and ground truth (ROVIS gaze
following, "Human–Robot Interaction Through Robust Gaze Following", Sec. 4).

Generative model, one face:

1. **Shape.** :func:`~jaxgaze.facial.face_model.generic_face` with every coordinate
   scaled by ``1 + N(0, shape_sd)`` per axis (a few per cent) and a per-point jitter
   ``N(0, point_sd²)`` (2 mm) in 3D: people differ from the generic face. With
   ``shape_sd = point_sd = 0`` every face is the generic one, the model the pose
   estimators assume.
2. **Pose.** ``R_frontal_from_head = R_z(yaw) R_y(−pitch) R_x(roll)`` (signs of
   ``docs/conventions.md``: yaw > 0 turns to the person's left, i.e. the image's
   right; pitch > 0 is up; roll > 0 lifts the left ear). Frontal faces have
   ``|yaw| < frontal_yaw_deg`` (20°), profile faces ``|yaw|`` in ``profile_yaw_deg``
   (50–80°), either sign. The frontal head frame faces the camera:
   ``R_optical_from_frontal`` maps head +x (forward) to optical −z, +y (left) to
   optical +x (image right) and +z (up) to optical −y.
3. **Camera.** A pinhole in the optical frame (x right, y down, z forward; image
   origin at the top-left pixel corner): ``u = f X/Z + c_x``, ``v = f Y/Z + c_y`` on a
   320 × 240 image, ``f = 300`` px, the eye midpoint at a depth giving an eye
   distance of ``face_size_px / 2`` (the face, ~2× the inter-ocular distance, spans
   60–120 px).
4. **Visibility.** An eye is hidden when the head turns it away from the camera
   by more than ``hide_yaw_deg`` (45°): the left eye for yaw > 45°, the right for
   yaw < −45°; so profile faces show three features. Each visible feature is also
   dropped (a detector miss) with probability ``drop_prob``.
5. **Hypotheses.** Per feature, ``num_hypotheses`` slots in random order: the
   true ROI (the feature centre plus Gaussian noise of ``loc_sd`` × face size;
   absent when the feature is hidden) with confidence ``Beta(true_beta)``, and
   distractors with confidence ``Beta(distractor_beta)``, placed at another
   feature's true centre (clutter: the left-eye detector fires on the right eye,
   the nose detector on the mouth) or uniformly in the face box. The distractors'
   confidences overlap the true ones', so the best-confidence hypothesis is often
   wrong; that is what the spatial model fixes. Empty slots have confidence 0.

All randomness comes from the ``jax.random`` key, whose data seed a NumPy
``Generator``; the same key gives the same faces.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgaze._checks import check_int, check_key, check_number
from jaxgaze.facial.face_model import R_OPTICAL_FROM_FRONTAL, Hypotheses, generic_face
from jaxgaze.facial.spatial import fit_spatial_model
from jaxgaze.geometry import head_pose_to_rotation

__all__ = [
    "default_spatial_model_fit",
    "write_default_spatial_models",
    "IMAGE_WIDTH",
    "IMAGE_HEIGHT",
    "FOCAL_PX",
    "R_OPTICAL_FROM_FRONTAL",

    "SimulatedFaces",
    "simulate_faces",
]

IMAGE_WIDTH = 320
IMAGE_HEIGHT = 240
FOCAL_PX = 300.0
#: columns: head +x (forward) → optical −z, +y (left) → optical +x, +z (up) → optical −y.

class SimulatedFaces(NamedTuple):
    """``N`` simulated faces with ground truth. Angles in radians."""

    yaw: np.ndarray  # (N,)
    pitch: np.ndarray  # (N,)
    roll: np.ndarray  # (N,)
    profile: np.ndarray  # (N,) bool, |yaw| in the profile range
    points_image: np.ndarray  # (N, 5, 2) true POINTS, px
    features_image: np.ndarray  # (N, 4, 2) true FEATURES centres, px (also hidden ones)
    visible: np.ndarray  # (N, 4) bool
    face_size_px: np.ndarray  # (N,) about 2 × the projected inter-ocular distance
    hypotheses: Hypotheses  # fields (N, 4, H, ...)


def simulate_faces(
    key,
    num_faces: int,
    *,
    view: str = "mixed",
    num_hypotheses: int = 4,
    frontal_yaw_deg: float = 20.0,
    profile_yaw_deg: tuple[float, float] = (50.0, 80.0),
    pitch_deg: float = 15.0,
    roll_deg: float = 10.0,
    face_size_px: tuple[float, float] = (60.0, 120.0),
    shape_sd: float = 0.04,
    point_sd: float = 0.002,
    hide_yaw_deg: float = 45.0,
    drop_prob: float = 0.03,
    loc_sd: float = 0.03,
    true_beta: tuple[float, float] = (4.0, 2.0),
    distractor_beta: tuple[float, float] = (2.5, 2.5),
    clutter_prob: float = 0.5,
) -> SimulatedFaces:
    """Simulate ``num_faces`` faces; ``view`` is ``"frontal"``, ``"profile"`` or ``"mixed"`` (half each).

    Raises:
        ValueError: bad key, count, view or ``num_hypotheses`` (< 1).
    """
    seed = check_key(key)
    check_int("num_faces", num_faces)
    if view not in ("frontal", "profile", "mixed"):
        raise ValueError(f"view must be 'frontal', 'profile' or 'mixed', got {view!r}")
    check_int("num_hypotheses", num_hypotheses)
    check_number("shape_sd", shape_sd, lo=0.0)
    check_number("point_sd", point_sd, lo=0.0)
    rng = np.random.default_rng([int(x) for x in seed])
    n, H = int(num_faces), int(num_hypotheses)

    if view == "frontal":
        profile = np.zeros(n, bool)
    elif view == "profile":
        profile = np.ones(n, bool)
    else:
        profile = rng.random(n) < 0.5
    yaw_f = rng.uniform(-frontal_yaw_deg, frontal_yaw_deg, n)
    yaw_p = rng.uniform(*profile_yaw_deg, n) * rng.choice([-1.0, 1.0], n)
    yaw = np.deg2rad(np.where(profile, yaw_p, yaw_f))
    pitch = np.deg2rad(rng.uniform(-pitch_deg, pitch_deg, n))
    roll = np.deg2rad(rng.uniform(-roll_deg, roll_deg, n))

    base = generic_face().points  # (5, 3)
    pts = base[None] * (1.0 + shape_sd * rng.standard_normal((n, 1, 3))) + point_sd * rng.standard_normal((n, 5, 3))
    pts[:, :2] -= pts[:, :2].mean(axis=1, keepdims=True) - base[:2].mean(axis=0)  # eye midpoint stays at origin
    with jax.enable_x64(True):
        R_frontal = np.asarray(head_pose_to_rotation(*(jnp.asarray(a, jnp.float64) for a in (yaw, pitch, roll))))
    R = R_OPTICAL_FROM_FRONTAL @ R_frontal  # R_optical_from_head, (n, 3, 3)
    ipd = np.linalg.norm(pts[:, 1] - pts[:, 0], axis=-1)
    size = rng.uniform(*face_size_px, n)
    depth = FOCAL_PX * ipd / (0.5 * size)
    centre = np.stack(
        [
            rng.uniform(-0.2, 0.2, n) * IMAGE_WIDTH / FOCAL_PX * depth,
            rng.uniform(-0.15, 0.0, n) * IMAGE_HEIGHT / FOCAL_PX * depth,
            depth,
        ],
        -1,
    )
    X = np.einsum("nij,npj->npi", R, pts) + centre[:, None]
    points_image = np.stack(
        [FOCAL_PX * X[..., 0] / X[..., 2] + IMAGE_WIDTH / 2, FOCAL_PX * X[..., 1] / X[..., 2] + IMAGE_HEIGHT / 2], -1
    )
    p = points_image
    feats = np.stack([p[:, 0], p[:, 1], p[:, 2], 0.5 * (p[:, 3] + p[:, 4])], 1)  # (n, 4, 2)

    hide = np.deg2rad(hide_yaw_deg)
    visible = np.ones((n, 4), bool)
    visible[:, 1] &= yaw <= hide  # left eye turned away
    visible[:, 0] &= yaw >= -hide
    visible &= rng.random((n, 4)) >= drop_prob

    pos = np.zeros((n, 4, H, 2))
    conf = np.zeros((n, 4, H))
    is_true = np.zeros((n, 4, H), bool)
    lo, hi = feats.min(axis=1), feats.max(axis=1)  # face box
    pad = 0.25 * size[:, None]
    for f in range(4):
        others = [g for g in range(4) if g != f]
        for h in range(H):
            which = rng.integers(0, 3, n)
            clutter = feats[np.arange(n), np.array(others)[which]] + loc_sd * size[:, None] * rng.standard_normal((n, 2))
            uniform = rng.uniform(lo - pad, hi + pad)
            pos[:, f, h] = np.where((rng.random(n) < clutter_prob)[:, None], clutter, uniform)
            conf[:, f, h] = rng.beta(*distractor_beta, n)
        # the true ROI takes slot 0 when the feature is visible
        pos[:, f, 0] = np.where(
            visible[:, f, None], feats[:, f] + loc_sd * size[:, None] * rng.standard_normal((n, 2)), pos[:, f, 0]
        )
        conf[:, f, 0] = np.where(visible[:, f], rng.beta(*true_beta, n), conf[:, f, 0])
        is_true[:, f, 0] = visible[:, f]
        # a few empty slots, so faces carry different numbers of hypotheses
        empty = (rng.random((n, H)) < 0.15) & ~is_true[:, f]
        conf[:, f][empty] = 0.0
        pos[:, f][empty] = 0.0
    # random slot order per face and feature
    order = np.argsort(rng.random((n, 4, H)), axis=-1)
    pos = np.take_along_axis(pos, order[..., None], axis=2)
    conf = np.take_along_axis(conf, order, axis=2)
    is_true = np.take_along_axis(is_true, order, axis=2)
    return SimulatedFaces(
        yaw, pitch, roll, profile, points_image, feats, visible, size, Hypotheses(pos, np.clip(conf, 0.0, 1.0), is_true)
    )


def default_spatial_model_fit(view: str = "mixed"):
    """Fit the spatial model that :func:`jaxgaze.facial.image_features.default_spatial_model`
    ships for ``view``: 4000 simulated faces (key 0, ``shape_sd = 0.12``)."""
    faces = simulate_faces(jax.random.PRNGKey(0), 4000, view=view, shape_sd=0.12)
    return fit_spatial_model(faces.features_image, faces.visible)


def write_default_spatial_models(folder) -> None:
    """Write ``spatial_model_{frontal,mixed}.npz`` into ``folder`` (the package's ``data/``)."""
    import os

    for view in ("frontal", "mixed"):
        model = default_spatial_model_fit(view)
        np.savez(os.path.join(folder, f"spatial_model_{view}.npz"),
                 **{name: np.asarray(value) for name, value in zip(model._fields, model)})
