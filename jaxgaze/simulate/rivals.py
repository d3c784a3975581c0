"""Conversations in which a person's gaze has a rival explanation (issue 37; Siegfried et al. 2017, eq. 1).

A bias ``b'`` that differs from the true ``b`` by the angle between two of a person's
targets, as seen from their head, explains the gaze at one target as gaze at the
other: ``g + b'`` lands on a neighbour when ``g + b`` lands on the table object.
When the person looks at the object often and speaks rarely (so the speaker rule
has little to start from), the model has two modes for that person, and a chain
started in the wrong one can stay there.

:data:`RIVAL_CONFIG` makes such scenes: seated groups of 5–8 (neighbours 22–36°
apart as seen by a gazer), one object near the table centre that joint-attention
episodes make the most frequent target, biases of 5–30°, and two quiet people.
:func:`rival_bias` gives, for a person, the bias of the rival explanation that
maps their looks at the object onto a neighbour; a start there is a start in the
rival mode.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxgaze.simulate.conversation import Conversation, conversation_config

__all__ = ["RIVAL_CONFIG", "RivalBias", "rival_bias"]

#: Scenes with a rival explanation: a frequent shared object near the centre of a table of 5–8, biases of
#: 5–30°, the last two people speaking rarely.
RIVAL_CONFIG = conversation_config(
    num_people_range=(5, 8),
    num_objects_range=(1, 1),
    standing_prob=0.0,
    screen_prob=0.0,
    object_disc=0.15,
    bias_deg=(5.0, 30.0),
    w_object=1.0,
    w_episode_object=40.0,
    episode_interval_s=(8.0, 14.0),
    episode_s=(3.0, 7.0),
    quiet_people=2,
    quiet_weight=0.05,
)


class RivalBias(NamedTuple):
    """The rival explanation of one person's gaze.

    Attributes:
        bias: ``(2,)`` the rival bias (yaw, tilt), radians.
        neighbour: the person the object looks are moved onto.
        shift_deg: ``‖bias − true bias‖`` in degrees.
        object_frames: frames in which the person looks at the object.
    """

    bias: np.ndarray
    neighbour: int
    shift_deg: float
    object_frames: int


def _head_angles(scene: Conversation, person: int, points: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """``(F, 2)`` yaw and tilt of ``points (F, 3)`` seen from the person's eyes in the reported head frame."""
    d = points - scene.eye_positions[frames, person]
    d = np.einsum("fji,fj->fi", scene.R_world_from_head[frames, person], d)  # R_head_from_world = Rᵀ
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.stack([np.arctan2(d[:, 1], d[:, 0]), np.arcsin(np.clip(d[:, 2], -1.0, 1.0))], axis=-1)


def rival_bias(scene: Conversation, person: int, *, min_shift_deg: float = 10.0) -> RivalBias:
    """The bias that moves ``person``'s looks at the object onto the nearest neighbour (in angle).

    With ``u_o`` and ``u_j`` the head-frame angles of the object and of person ``j`` in
    the frames where ``person`` looks at the object, ``b' = b + median(u_j − u_o)`` for
    the ``j`` whose shift is smallest but at least ``min_shift_deg``. Raises
    ``ValueError`` when the person never looks at an object or no one qualifies.
    """
    P = scene.num_people
    if not 0 <= person < P:
        raise ValueError(f"person must lie in [0, {P}), got {person!r}")
    frames = np.flatnonzero(scene.present[:, person] & (scene.target[:, person] >= P))
    if frames.size == 0:
        raise ValueError(f"person {person} never looks at an object in this scene")
    on_object = _head_angles(scene, person, scene.target_positions[frames, person], frames)
    best = None
    for j in range(P):
        if j == person:
            continue
        seen = _head_angles(scene, person, scene.eye_positions[frames, j], frames)
        delta = seen - on_object
        delta[:, 0] = np.angle(np.exp(1j * delta[:, 0]))
        shift = np.median(delta, axis=0)
        size = float(np.degrees(np.linalg.norm(shift)))
        if size >= min_shift_deg and (best is None or size < best[2]):
            best = (shift, j, size)
    if best is None:
        raise ValueError(f"no neighbour of person {person} is at least {min_shift_deg}° from the object")
    return RivalBias(scene.bias[person] + best[0], best[1], best[2], int(frames.size))
