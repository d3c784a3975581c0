"""Groups around shared targets, for the coverage of the concurrence covariances (issue 19, item 2).

A generator independent of :mod:`jaxgaze.simulate.scenes` (so that a check of the concurrence search
does not share its assumptions with the scenes it was tuned on): 1–3 groups of 4–8 people, each person
1.5–4 m (3-D) from the group's target, targets at least 2.5 m apart on the floor plan, and each gaze
direction turned away from the target by a rotation whose angle components perpendicular to the
direction are ``N(0, σ²)``. Used by ``tests/concurrence/test_covariance_coverage.py`` and
``experiments/concurrence_coverage.py``. NumPy's ``Generator`` draws everything, in a fixed order,
so one seed gives the same scenes everywhere.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_PEOPLE", "turn_directions", "group_scene", "group_frames"]

#: Rays per padded frame: 3 groups of at most 8 people, so one compiled program serves every frame.
MAX_PEOPLE = 24


def turn_directions(rng: np.random.Generator, directions, sigma: float) -> np.ndarray:
    """Rotate unit ``directions`` (n, 3) by rotation vectors ``a u1 + b u2`` ⟂ each one, ``a, b ~ N(0, σ²)``."""
    helper = np.where(np.abs(directions[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u1 = np.cross(directions, helper)
    u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
    u2 = np.cross(directions, u1)
    a, b = rng.normal(0.0, sigma, (2, len(directions), 1))
    axis_angle = a * u1 + b * u2
    angle = np.linalg.norm(axis_angle, axis=1, keepdims=True)
    axis = axis_angle / np.maximum(angle, 1e-300)
    # Rodrigues' formula; the axis is perpendicular to the direction, so no (k·v) k term.
    return np.cos(angle) * directions + np.sin(angle) * np.cross(axis, directions)


def group_scene(rng: np.random.Generator, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eyes (n, 3), noisy unit directions (n, 3) and targets (g, 3), metres, of one random scene."""
    groups = int(rng.integers(1, 4))
    targets = []
    while len(targets) < groups:  # targets at least 2.5 m apart on the floor plan
        t = np.array([rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(0.6, 1.6)])
        if all(np.linalg.norm(t[:2] - s[:2]) > 2.5 for s in targets):
            targets.append(t)
    eyes, looks_at = [], []
    for target in targets:
        n = int(rng.integers(4, 9))
        distance = rng.uniform(1.5, 4.0, n)  # eye to target, 3-D
        azimuth = rng.uniform(0, 2 * np.pi, n)
        height = rng.uniform(1.5, 1.8, n)
        across = np.sqrt(distance**2 - (height - target[2]) ** 2)
        eyes.append(np.stack([target[0] + across * np.cos(azimuth), target[1] + across * np.sin(azimuth), height], 1))
        looks_at.append(np.broadcast_to(target, (n, 3)))
    eyes, looks_at = np.concatenate(eyes), np.concatenate(looks_at)
    exact = (looks_at - eyes) / np.linalg.norm(looks_at - eyes, axis=1, keepdims=True)
    return eyes, turn_directions(rng, exact, sigma), np.array(targets)


def group_frames(rng: np.random.Generator, sigma: float, count: int):
    """``count`` scenes (:func:`group_scene`) padded to :data:`MAX_PEOPLE` rays: origins ``(count, 24, 3)``,
    directions, ray mask ``(count, 24)``, targets ``(count, 3, 3)`` and target mask ``(count, 3)``."""
    origins = np.zeros((count, MAX_PEOPLE, 3))
    directions = np.tile([1.0, 0.0, 0.0], (count, MAX_PEOPLE, 1))
    mask = np.zeros((count, MAX_PEOPLE), bool)
    targets = np.zeros((count, 3, 3))
    target_mask = np.zeros((count, 3), bool)
    for t in range(count):
        eyes, dirs, tgt = group_scene(rng, sigma)
        origins[t, : len(eyes)], directions[t, : len(eyes)], mask[t, : len(eyes)] = eyes, dirs, True
        targets[t, : len(tgt)], target_mask[t, : len(tgt)] = tgt, True
    return origins, directions, mask, targets, target_mask
