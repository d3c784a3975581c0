"""The observed recording of the joint model, checked at the door (Siegfried et al. 2017, Sec. 2; Park et al. 2012, Sec. 3.1).

Frames and units (``docs/conventions.md``): positions in the **world** frame
(metres), ``R_world_from_head`` maps head-frame vectors to the world frame, and
gaze angles ``g = (yaw, tilt)`` are in the **head** frame (+x forward, +y left,
+z up), radians. Arrays are frame-major: ``(T, P, …)`` for ``T`` frames and ``P``
people.
"""

from __future__ import annotations

from typing import Mapping, NamedTuple, Sequence

import warnings

import numpy as np
from jaxtyping import Bool, Float, Int

from jaxgaze.geometry import wrap_angle
from jaxgaze.rays import UnitWarning

__all__ = ["JointData", "joint_data"]

#: Largest plausible distance (m) of an eye from the scene centre: beyond it the positions are
#: almost surely in millimetres or centimetres.
MAX_SCENE_EXTENT_M = 50.0


class JointData(NamedTuple):
    """One group recording, as the joint model sees it (all numpy, checked by :func:`joint_data`).

    Attributes:
        eye_positions: ``(T, P, 3)`` eye midpoints, world frame, metres.
        R_world_from_head: ``(T, P, 3, 3)`` head rotations.
        gaze_angles: ``(T, P, 2)`` measured gaze ``(yaw, tilt)`` in the head frame, radians
            (0 where a person is absent).
        present: ``(T, P)`` who is tracked in each frame.
        speaking: ``(T, P)`` 0/1 speaking status (all 0 when unknown).
        measurement_scale: ``(T, P)`` per-frame measurement sd (radians; 0 when not given).
        window: ``(T,)`` index of each frame's concurrence window.
        people: ``P`` names.
        fps: frames per second.
        window_s: the concurrence window length (seconds).
        calibration_points: ``(P, M, 3)`` each wearer's calibration points of regard in
            their camera frame (Park et al. 2012, Sec. 3.2); padding elsewhere.
        calibration_mask: ``(P, M)`` the real points (none for a person without a camera).
        head_motion: head pose only (no eye tracker): ``(T, P, 5)`` the head's yaw and tilt
            (world, radians) from ``head_reference``, their rates (radians per second,
            backward differences) and the frame rate where the previous frame is present
            (0 where it is not: no rate); ``gaze_angles`` are then 0. ``None`` when the
            gaze is measured.
        head_reference: ``(P, 2)`` each person's mean head direction ``(yaw, tilt)``, world
            frame (head pose only).

    For a **wearer** (a person with calibration points) ``eye_positions`` holds the
    head-mounted camera's centre and ``R_world_from_head`` its rotation
    (``R_world_from_camera``); the gaze angles are in the camera frame (``(0, 0)``
    without an eye tracker: the primary ray). The model infers the eyes' offset
    from the camera with the rest.
    """

    eye_positions: Float[np.ndarray, "T P 3"]
    R_world_from_head: Float[np.ndarray, "T P 3 3"]
    gaze_angles: Float[np.ndarray, "T P 2"]
    present: Bool[np.ndarray, "T P"]
    speaking: Float[np.ndarray, "T P"]
    measurement_scale: Float[np.ndarray, "T P"]
    window: Int[np.ndarray, " T"]
    people: tuple[str, ...]
    fps: float
    window_s: float
    calibration_points: Float[np.ndarray, "P M 3"]
    calibration_mask: Bool[np.ndarray, "P M"]
    head_motion: Float[np.ndarray, "T P 4"] | None = None
    head_reference: Float[np.ndarray, "P 2"] | None = None

    @property
    def wearers(self) -> tuple[int, ...]:
        """Indices of the people with calibration points (head-mounted cameras)."""
        return tuple(int(i) for i in np.flatnonzero(self.calibration_mask.any(axis=1)))

    @property
    def num_frames(self) -> int:
        return self.eye_positions.shape[0]

    @property
    def num_people(self) -> int:
        return self.eye_positions.shape[1]

    @property
    def num_windows(self) -> int:
        return int(self.window.max()) + 1 if self.window.size else 0

    @property
    def head_only(self) -> bool:
        """Whether the gaze is inferred from head pose alone (no gaze measurement)."""
        return self.head_motion is not None

    @property
    def has_speech(self) -> bool:
        return bool(np.any(self.speaking > 0))

    @property
    def times(self) -> Float[np.ndarray, " T"]:
        return np.arange(self.num_frames) / self.fps


def _array(name: str, value, shape: tuple) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}") from None
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape} (frames, people, …) to match gaze_angles, got {a.shape}")
    return a


def _first_bad(name: str, bad: np.ndarray, people: Sequence[str]) -> None:
    if bad.any():
        t, p = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} is not finite (NaN or inf) at frame {t}, person {people[p]!r}, where they are present")


def _speaking(speaking, shape: tuple[int, int], people: tuple[str, ...]) -> np.ndarray:
    if speaking is None:
        return np.zeros(shape)
    if isinstance(speaking, Mapping):
        flags = np.zeros(shape)
        for who, values in speaking.items():
            if who not in people:
                raise ValueError(f"speaking flags for an unknown person {who!r}; the people are {', '.join(people)}")
            v = np.asarray(values)
            if v.shape != (shape[0],):
                raise ValueError(f"speaking flags of {who!r} must have shape ({shape[0]},) (one per frame), got {v.shape}")
            flags[:, people.index(who)] = _flags(f"speaking[{who!r}]", v)
        return flags
    v = np.asarray(speaking)
    if v.ndim == 2 and v.shape[0] == shape[0] and v.shape[1] != shape[1]:
        raise ValueError(f"speaking has flags for {v.shape[1]} people, but there are {shape[1]} ({', '.join(people)}); "
                         "pass a mapping name → flags to name them")
    if v.shape != shape:
        raise ValueError(f"speaking must have shape (T, P) = {shape}, got {v.shape}")
    return _flags("speaking", v)


def _flags(name: str, v: np.ndarray) -> np.ndarray:
    if v.dtype != bool:
        f = np.asarray(v, dtype=float)
        if not np.all(np.isin(f, (0.0, 1.0))):
            raise ValueError(f"{name} must be boolean (or 0/1)")
        return f
    return v.astype(float)


def joint_data(
    eye_positions,
    R_world_from_head,
    gaze_angles,
    *,
    present=None,
    speaking=None,
    measurement_scale=None,
    people: Sequence[str] | None = None,
    fps: float = 10.0,
    window_s: float = 60.0,
    calibration_points: Mapping[str, object] | None = None,
) -> JointData:
    """Check a recording and pack it as :class:`JointData` (Siegfried et al. 2017, Sec. 2; Park et al. 2012, Sec. 3.1).

    Args:
        eye_positions: ``(T, P, 3)`` eye midpoints, world frame, metres.
        R_world_from_head: ``(T, P, 3, 3)`` head rotations (``v_world = R v_head``).
        gaze_angles: ``(T, P, 2)`` measured gaze ``(yaw, tilt)``, head frame, radians; ``None``
            for head pose only (a head tracker, OpenFace's ``pose_R*``, mocap): the model
            then infers each person's head–gaze coupling (see :mod:`jaxgaze.joint.model`).
        present: ``(T, P)`` bool; default: where the gaze angles (head pose only: the
            eye positions and rotations) are not NaN.
        speaking: ``(T, P)`` 0/1 flags, or a mapping from person name to ``(T,)`` flags
            (people left out never speak); ``None`` when speech is unknown.
        measurement_scale: ``(T, P)`` per-frame measurement sd (radians, ≥ 0), e.g. a
            tool's own uncertainty (head pose only: of the head direction); ``None`` when
            not known.
        people: ``P`` names (default ``"0"``, ``"1"``, …).
        fps: frames per second; window_s: concurrence window length (seconds).
        calibration_points: for wearers of head-mounted cameras, a mapping from name to
            ``(M, 3)`` points of regard in their camera frame (+x forward, metres; Park
            et al. 2012, Sec. 3.2). Their ``eye_positions`` are then the camera centres
            and ``R_world_from_head`` the camera rotations (see :class:`JointData`).

    Raises:
        ValueError: naming the array, frame and person, for inconsistent shapes, NaN
            where a person is present, a person never present, flags for an unknown
            person, a rotation that is not one, or angles beyond π (degrees?).

    Warns (:class:`~jaxgaze.rays.UnitWarning`, implausible rather than impossible: the
    library's unit rule) when an eye lies more than :data:`MAX_SCENE_EXTENT_M` from the
    scene centre (millimetres?), naming the person and frame.
    """
    head_only = gaze_angles is None
    if head_only:
        if R_world_from_head is None:
            raise ValueError("head pose only (gaze_angles=None) needs R_world_from_head: the head rotations are "
                             "then all there is to infer the gaze from")
        shape = np.shape(eye_positions)
        if len(shape) != 3 or shape[-1] != 3:
            raise ValueError(f"eye_positions must have shape (T, P, 3), got {shape}")
        gaze_angles = np.zeros(shape[:2] + (2,))
        if present is None:
            with np.errstate(invalid="ignore"):
                present = (np.isfinite(np.asarray(eye_positions, float)).all(-1)
                           & np.isfinite(np.asarray(R_world_from_head, float)).all((-2, -1)))
    gaze = np.asarray(gaze_angles, dtype=float)
    if gaze.ndim != 3 or gaze.shape[-1] != 2:
        raise ValueError(f"gaze_angles must have shape (T, P, 2) (yaw, tilt per frame and person), got {gaze.shape}")
    T, P = gaze.shape[:2]
    if T < 1 or P < 2:
        raise ValueError(f"the joint model needs at least 1 frame and 2 people, got T={T}, P={P}")
    eyes = _array("eye_positions", eye_positions, (T, P, 3))
    R = _array("R_world_from_head", R_world_from_head, (T, P, 3, 3))
    people = tuple(str(p) for p in (range(P) if people is None else people))
    if len(people) != P:
        raise ValueError(f"people names {len(people)} for {P} people (gaze_angles has shape {gaze.shape})")
    if len(set(people)) != P:
        raise ValueError(f"people names must be unique, got {people}")
    if present is None:
        mask = ~np.isnan(gaze).any(axis=-1)
    else:
        mask = np.asarray(present)
        if mask.shape != (T, P):
            raise ValueError(f"present must have shape (T, P) = {(T, P)}, got {mask.shape}")
        mask = _flags("present", mask).astype(bool)
    never = np.flatnonzero(~mask.any(axis=0))
    if never.size:
        raise ValueError(f"person {people[never[0]]!r} is never present; drop them or mark the frames where they are")
    _first_bad("gaze_angles", ~np.isfinite(gaze).all(-1) & mask, people)
    _first_bad("eye_positions", ~np.isfinite(eyes).all(-1) & mask, people)
    _first_bad("R_world_from_head", ~np.isfinite(R).all((-2, -1)) & mask, people)
    if not fps > 0 or not np.isfinite(fps):
        raise ValueError(f"fps must be positive, got {fps!r}")
    if not window_s > 0:
        raise ValueError(f"window_s must be positive, got {window_s!r}")

    m = mask
    if np.abs(gaze[m]).max() > np.pi + 1e-6:
        raise ValueError(f"gaze_angles reach {np.abs(gaze[m]).max():.3g}, beyond π: they must be radians (degrees?)")
    centre = np.median(eyes[m], axis=0)
    offset = np.where(m, np.linalg.norm(np.where(m[..., None], eyes, centre) - centre, axis=-1), 0.0)
    if offset.max() > MAX_SCENE_EXTENT_M:
        t, p = (int(i) for i in np.unravel_index(np.argmax(offset), offset.shape))
        warnings.warn(f"eye_positions of person {people[p]!r} at frame {t} are {offset[t, p]:.3g} m from the scene "
                      f"centre, beyond {MAX_SCENE_EXTENT_M:g} m: they must be metres (millimetres?)", UnitWarning,
                      stacklevel=2)
    gram = np.einsum("...ji,...jk->...ik", R, R) - np.eye(3)
    error = np.where(m, np.abs(gram).max(axis=(-2, -1)), 0.0)
    det = np.where(m, np.linalg.det(np.where(m[..., None, None], R, np.eye(3))), 1.0)
    bad = (error > 1e-3) | (det < 0)
    if bad.any():
        t, p = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"R_world_from_head at frame {t}, person {people[p]!r} is not a rotation "
                         f"(RᵀR − I up to {error[t, p]:.2g}, det {det[t, p]:.3g})")

    speak = _speaking(speaking, (T, P), people)
    if measurement_scale is None:
        scale = np.zeros((T, P))
    else:
        scale = _array("measurement_scale", measurement_scale, (T, P))
        bad = (~np.isfinite(scale) | (scale < 0)) & mask
        if bad.any():
            t, p = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(f"measurement_scale must be finite and ≥ 0; frame {t}, person {people[p]!r} has {scale[t, p]}")
        if scale[mask].max() > 1.0:
            raise ValueError(f"measurement_scale reaches {scale[mask].max():.3g} rad: it must be radians (degrees?)")
    scale = np.where(mask, scale, 0.0)
    # Absent entries get harmless placeholders; the mask keeps them out of the likelihood.
    gaze = np.where(mask[..., None], gaze, 0.0)
    eyes = np.where(mask[..., None], eyes, np.where(np.isfinite(eyes), eyes, 0.0))
    R = np.where(mask[..., None, None], R, np.eye(3))
    window = (np.arange(T) / fps // window_s).astype(np.int64)
    points, point_mask = _calibration(calibration_points, people)
    motion = reference = None
    if head_only:
        if point_mask.any():
            raise ValueError("head pose only (gaze_angles=None) is for people without head-mounted cameras; "
                             "wearers with calibration points need their gaze angles (0 for the primary ray)")
        motion, reference = _head_motion(R, mask, float(fps))
    return JointData(eyes, R, gaze, mask, np.where(mask, speak, 0.0), scale, window, people, float(fps),
                     float(window_s), points, point_mask, motion, reference)


def _head_motion(R: np.ndarray, present: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``(T, P, 5)`` head yaw and tilt (world) from each person's mean direction ``(P, 2)``, their rates (rad/s,
    backward differences) and ``fps`` where the previous frame is present (0 elsewhere: no rate there)."""
    forward = R[..., :, 0]  # the head's +x in the world
    yaw = np.arctan2(forward[..., 1], forward[..., 0])
    tilt = np.arcsin(np.clip(forward[..., 2], -1.0, 1.0))
    reference = np.stack([np.angle(np.sum(np.where(present, np.exp(1j * yaw), 0.0), axis=0)),
                          np.sum(np.where(present, tilt, 0.0), axis=0) / present.sum(axis=0)], axis=-1)
    angles = np.stack([wrap_angle(yaw - reference[:, 0]), tilt - reference[:, 1]], axis=-1)
    angles = np.where(present[..., None], angles, 0.0)
    after = np.zeros(present.shape)  # fps where frame t − 1 is present too
    after[1:] = np.where(present[1:] & present[:-1], fps, 0.0)
    rate = np.zeros_like(angles)
    rate[1:] = np.concatenate([wrap_angle(angles[1:, :, :1] - angles[:-1, :, :1]), angles[1:, :, 1:] - angles[:-1, :, 1:]],
                              -1) * after[1:, :, None]
    return np.concatenate([angles, rate, after[..., None]], axis=-1), reference


def _calibration(calibration_points, people: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    P = len(people)
    if not calibration_points:
        return np.zeros((P, 0, 3)), np.zeros((P, 0), bool)
    if not isinstance(calibration_points, Mapping):
        raise ValueError("calibration_points must be a mapping from person name to (M, 3) points of regard")
    arrays = {}
    for who, value in calibration_points.items():
        if who not in people:
            raise ValueError(f"calibration points for an unknown person {who!r}; the people are {', '.join(people)}")
        y = np.asarray(value, dtype=float)
        if y.ndim != 2 or y.shape[1] != 3 or y.shape[0] < 3:
            raise ValueError(f"calibration points of {who!r} must have shape (M, 3) with M ≥ 3, got {y.shape}")
        if not np.all(np.isfinite(y)):
            raise ValueError(f"calibration point {int(np.argwhere(~np.isfinite(y))[0, 0])} of {who!r} is not finite")
        if np.median(y[:, 0]) <= 0:
            raise ValueError(f"calibration points of {who!r} are mostly behind the camera (x ≤ 0): they must be in "
                             "the camera frame (+x forward, +y left, +z up), not OpenCV's or the world frame")
        if np.linalg.norm(y, axis=1).max() > MAX_SCENE_EXTENT_M:
            raise ValueError(f"calibration points of {who!r} reach {np.linalg.norm(y, axis=1).max():.3g} m: "
                             "they must be metres (millimetres?)")
        arrays[people.index(who)] = y
    M = max(len(y) for y in arrays.values())
    points = np.zeros((P, M, 3))
    points[..., 0] = 1.0  # padding: harmless points ahead of the camera
    point_mask = np.zeros((P, M), bool)
    for i, y in arrays.items():
        points[i, : len(y)] = y
        point_mask[i, : len(y)] = True
    return points, point_mask
