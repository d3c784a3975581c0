"""Simulated Project Aria wearers: a scene's people as MPS wearer folders, with the truth.

:func:`write_aria_wearers` takes a :class:`~jaxgaze.simulate.Scene` (people, observed gaze rays,
true concurrences), puts Aria glasses on some of its people and writes, per wearer, the
``general_eye_gaze.csv`` and ``closed_loop_trajectory.csv`` that MPS would give
(:func:`jaxgaze.io.tools.aria.write_aria`), so that :func:`jaxgaze.io.tools.aria.read_aria` must recover the
scene's rays.

* Head: the CPF sits on the person's eyes, upright (no roll). It turns toward the true target
  only partly, as heads do: head yaw ``= gaze yaw + δ_yaw(t)``, head pitch ``= ½ gaze pitch +
  δ_pitch(t)`` with slow sinusoidal eye-in-head offsets ``δ`` (amplitude ``head_lag``, random phase
  per wearer). The eye gaze in the CPF is the scene's observed ray seen from that head.
* Device: ``T_device_cpf`` is :data:`SIMULATED_T_DEVICE_CPF`, a made-up rigid offset (not a real
  calibration) so that the device-to-CPF step is exercised.
* Clocks: each device's clock is the shared clock minus its own offset (seconds to days apart);
  the trajectories' ``utc_timestamp_ns`` carry the shared clock, as MPS gives UTC.
* Truth: the returned :class:`AriaWearers` holds the scene restricted to the wearers, whose
  concurrences are the foci at least two *wearers* look at.
"""

from __future__ import annotations

import os
from typing import NamedTuple, Optional, Sequence

import jax
import numpy as np

from jaxgaze.io.tools.aria import ARIA_FPS, write_aria
from jaxgaze.io.rays import stack_rays
from jaxgaze.poses import camera_poses
from jaxgaze.simulate.scenes import Scene

__all__ = ["SIMULATED_T_DEVICE_CPF", "AriaWearers", "write_aria_wearers"]


def _rotation(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


#: A made-up ``T_device_cpf`` (4×4, Aria frames): 25° about an oblique axis, 6 cm off. Not a real calibration.
SIMULATED_T_DEVICE_CPF = np.eye(4)
SIMULATED_T_DEVICE_CPF[:3, :3] = _rotation([0.3, -1.0, 0.2], np.radians(25.0))
SIMULATED_T_DEVICE_CPF[:3, 3] = [0.05, -0.02, 0.03]
SIMULATED_T_DEVICE_CPF.setflags(write=False)


class AriaWearers(NamedTuple):
    """Simulated MPS wearer folders and their truth.

    ``folders``: one per wearer (pass them to :func:`~jaxgaze.io.tools.aria.read_aria`); ``persons``: the
    folder names; ``people``: each wearer's index in the source scene; ``scene``: the scene restricted
    to the wearers (rays, targets, foci; ``concurrence_valid`` where ≥ 2 wearers look);
    ``T_device_cpf``, ``fps``, ``start_ns``: what reading them back needs.
    """

    folders: list
    persons: list
    people: np.ndarray
    scene: Scene
    T_device_cpf: np.ndarray
    fps: float
    start_ns: int


def _wearer_scene(scene: Scene, people: np.ndarray) -> Scene:
    """The scene seen by ``people`` only: a focus is a concurrence where ≥ 2 of them look at it."""
    focus = np.asarray(scene.focus)[:, people]
    M = np.asarray(scene.concurrences).shape[1]
    valid = (focus[:, :, None] == np.arange(M)).sum(axis=1) >= 2
    attending = np.where(np.take_along_axis(valid, focus, axis=1), focus, -1).astype(np.int32)
    rays = jax.tree_util.tree_map(lambda a: np.asarray(a)[:, people], scene.rays)
    return scene._replace(rays=rays, targets=np.asarray(scene.targets)[:, people], attending=attending,
                          concurrence_valid=valid, focus=focus)


def write_aria_wearers(key, scene: Scene, directory, *, people: Optional[Sequence[int]] = None,
                       head_lag: float = 0.15, T_device_cpf=SIMULATED_T_DEVICE_CPF,
                       start_ns: int = 1_700_000_000 * 10**9) -> AriaWearers:
    """Write ``people`` of ``scene`` (default: everyone) as Aria MPS wearer folders
    ``directory/wearer_<index>``, and return them with the truth (:class:`AriaWearers`).

    ``key`` draws the head motion's phases and the device clock offsets; ``head_lag`` (radians)
    is the amplitude of the eye-in-head offsets. Frame ``t`` is at ``start_ns + t / fps`` on the shared
    clock (``fps`` the scene's).
    """
    people = np.arange(scene.num_people) if people is None else np.asarray(people, dtype=int)
    truth = _wearer_scene(scene, people)
    fps = float(scene.fps) if scene.fps else ARIA_FPS
    T, K = truth.focus.shape
    phase_key, clock_key = jax.random.split(key)
    phases = np.asarray(jax.random.uniform(phase_key, (K, 2), maxval=2 * np.pi))
    offsets_ns = np.asarray(jax.random.randint(clock_key, (K,), 1, 86_400)).astype(np.int64) * 10**9
    origins = np.asarray(truth.rays.origins, np.float64)
    directions = np.asarray(truth.rays.directions, np.float64)
    targets = np.asarray(truth.targets, np.float64)
    seconds = np.arange(T) / fps
    folders, persons = [], []
    for k, person in enumerate(people):
        gaze = targets[:, k] - origins[:, k]
        gaze_yaw = np.arctan2(gaze[:, 1], gaze[:, 0])
        gaze_pitch = np.arctan2(gaze[:, 2], np.hypot(gaze[:, 0], gaze[:, 1]))
        head_yaw = gaze_yaw + head_lag * np.sin(2 * np.pi * seconds / 7.0 + phases[k, 0])
        head_pitch = 0.5 * gaze_pitch + 0.5 * head_lag * np.sin(2 * np.pi * seconds / 5.0 + phases[k, 1])
        R_world_from_head = np.stack([_rotation([0, 0, 1], y) @ _rotation([0, 1, 0], -p)
                                      for y, p in zip(head_yaw, head_pitch)])
        poses = camera_poses(np.swapaxes(R_world_from_head, 1, 2), origins[:, k], np.arange(T))
        name = f"wearer_{int(person)}"
        recording = stack_rays(list(range(T)), [name] * T, origins[:, k], directions[:, k],
                               np.asarray(truth.rays.bandwidth)[:, k], path=name)
        folder = os.path.join(os.fspath(directory), name)
        write_aria(folder, recording, poses=poses, T_device_cpf=T_device_cpf, fps=fps, start_ns=start_ns,
                   device_offset_ns=int(offsets_ns[k]))
        folders.append(folder)
        persons.append(name)
    return AriaWearers(folders, persons, people, truth, np.asarray(T_device_cpf), fps, int(start_ns))
