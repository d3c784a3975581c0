"""Two people of a simulated dyad filmed by **one** fixed camera, as OpenFace 2's
``FaceLandmarkVidMulti`` reports them: the setting of OpenFace issue #1035 ("how can I detect
mutual gaze between two people using the gaze vectors?").

A :class:`~jaxgaze.simulate.dyadic.DyadicRecording` gives the heads and the true gaze of two people
facing each other. The camera stands on the perpendicular bisector of their eyes, ``distance_m``
from the midpoint, at eye height, looking at the midpoint, on the side the heads turn to more. Per
frame and person:

* the face is tracked when the head's forward axis is within ``max_face_angle_deg`` of the
  direction to the camera, outside random tracker dropouts (a Poisson process of ``dropout_rate_hz``,
  lengths uniform in ``dropout_s``);
* ``face_id`` is the tracker's slot, as in OpenFace: a face keeps its slot while tracked, and a face
  found again takes the lowest free slot (found faces in random order), so ids swap when both
  faces are lost at once;
* the measured gaze is the true gaze with an offset ``gaze_sd · δ``, ``δ ~ N(0, I₂)`` on the plane at
  unit depth (the cone model of :class:`~jaxgaze.rays.GazeRays`, Park et al. 2012, Sec. 3.1).

Everything is in **our** camera frame (+x along the optical axis, +y left, +z up; metres, radians).
Host-side NumPy; the same key gives the same tracks.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxgaze._checks import check_key
from jaxgaze.simulate.dyadic import FOCUS_PARTNER, DyadicRecording

__all__ = ["OpenFaceTracks", "simulate_openface_tracks"]


class OpenFaceTracks(NamedTuple):
    """``P`` people over ``T`` frames seen by one camera, with the truth of who looks at whom.

    Attributes:
        frames: ``(T,)`` int64 OpenFace frame numbers, ``1 … T``.
        face_id: ``(T, P)`` int64 OpenFace's ``face_id`` of each person, −1 where not tracked.
        tracked: ``(T, P)`` bool, the tracker reports the face.
        eyes_camera: ``(T, P, 3)`` eye midpoints, camera frame, metres.
        R_camera_from_head: ``(T, P, 3, 3)`` head orientations (``v_camera = R @ v_head``).
        gaze_camera: ``(T, P, 3)`` measured unit gaze, camera frame.
        looks_at: ``(T, P, P)`` bool truth, person ``i`` looks at person ``j``'s eyes.
        R_world_from_camera: ``(3, 3)`` the camera's axes in the dyad's world.
        center: ``(3,)`` the camera centre, world.
    """

    frames: np.ndarray
    face_id: np.ndarray
    tracked: np.ndarray
    eyes_camera: np.ndarray
    R_camera_from_head: np.ndarray
    gaze_camera: np.ndarray
    looks_at: np.ndarray
    R_world_from_camera: np.ndarray
    center: np.ndarray

    @property
    def mutual(self) -> np.ndarray:
        """``(T,)`` bool truth: persons 0 and 1 look at each other."""
        return self.looks_at[:, 0, 1] & self.looks_at[:, 1, 0]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dropouts(rng, num_frames: int, fps: float, rate_hz: float, lengths_s) -> np.ndarray:
    """``(T,)`` bool: frames inside a dropout (starts Poisson at ``rate_hz``, lengths uniform)."""
    out = np.zeros(num_frames, dtype=bool)
    starts = np.flatnonzero(rng.random(num_frames) < rate_hz / fps)
    for start, length in zip(starts, rng.uniform(*lengths_s, size=starts.size)):
        out[start:start + max(1, round(length * fps))] = True
    return out


def _tracker_slots(rng, tracked: np.ndarray) -> np.ndarray:
    """OpenFace-like ``face_id``: kept while tracked; a face found again takes the lowest free slot."""
    num_frames, num_people = tracked.shape
    slots = np.full((num_frames, num_people), -1, dtype=np.int64)
    previous = np.full(num_people, -1, dtype=np.int64)
    for t in range(num_frames):
        now = np.where(tracked[t], previous, -1)
        for p in rng.permutation(np.flatnonzero(tracked[t] & (now < 0))):
            now[p] = min(set(range(num_people)) - set(now.tolist()))
        slots[t] = previous = now
    return slots


def simulate_openface_tracks(key, recording: DyadicRecording, *, gaze_sd: float, distance_m: float = 1.5,
                             max_face_angle_deg: float = 70.0, dropout_rate_hz: float = 0.3,
                             dropout_s: tuple[float, float] = (0.2, 1.0)) -> OpenFaceTracks:
    """Film one :class:`DyadicRecording` (a single session) with one camera, OpenFace-style.

    Args:
        key: a single ``jax.random`` key (noise, dropouts and slot order).
        recording: from :func:`~jaxgaze.simulate.simulate_dyadic`.
        gaze_sd: per-axis sd (radians) of the measured gaze's tangent offset; pass the reader's
            bandwidth (e.g. ``jaxgaze.io.tools.openface.DEFAULT_BANDWIDTH_OPENFACE``) for calibrated rays.
        distance_m: camera distance from the midpoint of the two people's eyes.
        max_face_angle_deg: the tracker loses a face turned farther than this from the camera.
        dropout_rate_hz, dropout_s: random tracker losses per person: rate, and range of lengths.

    Raises:
        ValueError: for a bad key, a batch of sessions, or a non-positive / non-finite argument.
    """
    rng = np.random.default_rng(check_key(key))
    for name, value in (("gaze_sd", gaze_sd), ("distance_m", distance_m), ("max_face_angle_deg", max_face_angle_deg)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"simulate_openface_tracks: {name} must be positive and finite, got {value!r}")
    if not (math.isfinite(dropout_rate_hz) and dropout_rate_hz >= 0 and 0 < dropout_s[0] <= dropout_s[1]):
        raise ValueError("simulate_openface_tracks: need dropout_rate_hz ≥ 0 and 0 < dropout_s[0] ≤ dropout_s[1]")
    if np.ndim(recording.speaking) != 2:
        raise ValueError("simulate_openface_tracks: pass one session (recording.take(i) of a batch)")
    eyes = np.asarray(recording.eye_positions, float)  # (P, T, 3)
    R_world_from_head = np.asarray(recording.R_world_from_head, float)  # (P, T, 3, 3)
    yaw, tilt = np.moveaxis(np.asarray(recording.true_gaze_angles, float), -1, 0)
    gaze_head = np.stack([np.cos(tilt) * np.cos(yaw), np.cos(tilt) * np.sin(yaw), np.sin(tilt)], axis=-1)
    gaze_world = np.einsum("ptij,ptj->pti", R_world_from_head, gaze_head)
    num_people, num_frames = eyes.shape[:2]

    up = np.array([0.0, 0.0, 1.0])
    middle = eyes.mean(axis=(0, 1))
    side = _unit(np.cross(up, eyes[1].mean(0) - eyes[0].mean(0)))
    if np.einsum("ptj,j->", R_world_from_head[..., :, 0], side) < 0:
        side = -side  # the side the heads turn to more
    center = middle + distance_m * side
    forward = -side
    left = _unit(np.cross(up, forward))
    R_world_from_camera = np.stack([forward, left, np.cross(forward, left)], axis=1)

    to_camera = _unit(center - eyes)
    facing = np.einsum("pti,pti->pt", R_world_from_head[..., :, 0], to_camera)
    tracked = facing > math.cos(math.radians(max_face_angle_deg))
    for p in range(num_people):
        tracked[p] &= ~_dropouts(rng, num_frames, recording.fps, dropout_rate_hz, dropout_s)

    # Measured gaze: the cone model's tangent offset around the true gaze.
    a = _unit(np.cross(gaze_world, up))
    b = np.cross(gaze_world, a)
    noise = gaze_sd * rng.standard_normal((2, num_people, num_frames, 1))
    measured = _unit(gaze_world + noise[0] * a + noise[1] * b)

    looks_at = np.zeros((num_frames, num_people, num_people), dtype=bool)
    focus = np.asarray(recording.focus)
    for p in range(num_people):
        looks_at[:, p, 1 - p] = focus[p] == FOCUS_PARTNER
    return OpenFaceTracks(
        frames=np.arange(1, num_frames + 1, dtype=np.int64),
        face_id=_tracker_slots(rng, tracked.T),
        tracked=tracked.T,
        eyes_camera=np.einsum("ji,ptj->tpi", R_world_from_camera, eyes - center),
        R_camera_from_head=np.einsum("ji,ptjk->tpik", R_world_from_camera, R_world_from_head),
        gaze_camera=np.einsum("ji,ptj->tpi", R_world_from_camera, measured),
        looks_at=looks_at,
        R_world_from_camera=R_world_from_camera,
        center=center,
    )
