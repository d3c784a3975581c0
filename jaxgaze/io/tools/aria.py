"""Project Aria (Machine Perception Services, Aria Digital Twin) → world-frame gaze rays, one folder per wearer.

**Input.** Each wearer is a folder as downloaded, or its gaze CSV; ``read_aria([wearer_a, wearer_b, …])``
puts every wearer's rays in the one world of their trajectories; person names are the folder names (or
``persons``). Layouts read:

* the gaze CSV under any name Aria has shipped (:data:`GAZE_FILES`, ``MpsFileNames.h``): MPS's
  ``general_eye_gaze.csv`` (earlier ``generalized_eye_gaze.csv``, legacy ``eyegaze.csv``) and
  ``personalized_eye_gaze.csv`` (earlier ``calibrated_eye_gaze.csv``), in the folder or its
  ``eye_gaze/``; the Aria Digital Twin (ADT) sequence's ``eyegaze.csv``. A folder holding two is an
  error naming them (``eye_gaze="general"`` / ``"personalized"`` or the file's path chooses): which
  model a user wants is theirs to say;
* the trajectory: MPS's ``closed_loop_trajectory.csv`` beside the gaze CSV or under ``slam/`` (older
  MPS: ``trajectory/``) of its folder or that folder's parent; else ADT's ``aria_trajectory.csv``
  (MPS's columns, ``AriaDigitalTwinDataFileNames.h``) beside it, or for the gaze of an ADT
  sequence's ``mps/`` folder (which has no trajectory), the sequence's.

World rays without a trajectory are an :class:`InputFileError` naming what is missing, unless
``camera`` gives the CPF's poses (one wearer); ``frame="cpf"`` asks for rays in each wearer's
Central Pupil Frame (our axes), the head frame.

**Gaze (CPF).** The eye gaze is in the Central Pupil Frame: origin between the eyes, X left, Y up,
Z forward (projectaria_tools docs, "3D Coordinate Frame Conventions"). The direction of
``(yaw, pitch)`` is projectaria_tools' ``getUnitVectorFromYawPitch``: ``normalise(tan yaw,
tan pitch, 1)``, so yaw is positive to the wearer's left and pitch positive up. In our axes
(+x forward, +y left, +z up) that is ``R_OURS_FROM_CPF @ v_cpf``. Three schemas are read, as
``readEyeGaze`` / ``readEyeGazeVergence`` read them:

* legacy: ``yaw_rads_cpf, pitch_rads_cpf`` with ``yaw_/pitch_low|high_rads_cpf`` bounds;
* vergence (Gen1): ``left_yaw_rads_cpf, right_yaw_rads_cpf, pitch_rads_cpf`` with per-eye yaw bounds
  and the eye origins ``t{x,y,z}_{left,right}_eye_cpf``. The combined yaw is
  ``computeDepthAndCombinedGazeDirection``'s ``atan(x/z)`` of the two rays' intersection, which is
  ``atan((tan left + tan right) / 2)``;
* Gen2: a combined ``yaw_rads_cpf`` next to the per-eye columns, no bounds, no ``depth_m``.

The ray's origin ``o`` is the midpoint of the eye origins when the file has them, else the CPF origin.

**Depth.** ``depth_m`` (ADT: the ground-truth gaze depth; MPS Gen1: the vergence depth) places the
point of regard at ``depth_m · d`` from the CPF origin (``getEyeGazePointAtDepth``; 0 or empty: not
available). Along our ray that is ``depth = depth_m − o · d`` from ``o`` (``depth_m`` itself when
``o`` is the CPF origin), kept as :attr:`RayRecording.depth` (NaN where absent) and invariant under
the rigid maps below: the point of regard is ``origin + depth · d`` in the world too. Its sd along the ray
(:attr:`RayRecording.depth_sd`): MPS's depth is where the two eyes' rays meet, so an error ``δ`` in the
vergence angle moves it by ``δ d² / b`` (``b`` the eyes' baseline from the file's eye origins, else
:data:`TYPICAL_IPD_M``); with each eye's angle off by ``h``, ``σ_d = √2 h d² / b`` (7 cm at 1 m for
``h`` = 2°, 28 cm at 2 m). The ADT sequence's own ``eyegaze.csv`` (beside ``aria_trajectory.csv``) holds the
digital twin's ground truth: ``σ_d = 0``.

**Bandwidth.** MPS gives each angle an interval ``[low, high]`` containing it; its level is not
documented, and we read it as a central :data:`INTERVAL_COVERAGE` (80 %) interval of a normal
error, the 10 %/90 % quantile pair of quantile-loss gaze models such as Gaze360. So the sd of an
angle is ``(high − low) / (2 z)`` with ``z = Φ⁻¹(0.9) = 1.2816``; a combined yaw takes the mean of
the two eyes' sds; and ``h = √((σ_yaw² + σ_pitch²) / 2)``, the per-axis sd whose cone has the
same mean squared offset. Rows without bounds get :data:`DEFAULT_BANDWIDTH_ARIA`; widths beyond
:data:`MAX_BANDWIDTH_ARIA` (blinks) are clipped to it, with a warning that counts them.

**World.** ``x_world = R_up · T_world_device · T_device_cpf · x_cpf`` with ``T_world_device`` the
trajectory's ``t{x,y,z}_world_device`` and Hamilton quaternion ``q{x,y,z,w}_world_device``,
interpolated to each gaze timestamp (translation linearly, rotation by slerp between the two nearest
poses; a sample at most :data:`POSE_EDGE_S` beyond the trajectory's ends takes the end pose; one
further out, or in a gap longer than ``max_pose_gap_s``, is dropped and counted). ``R_up``
(:func:`up_rotation`) turns the trajectory's up axis onto our +z: ``up`` defaults to the axis opposite
the trajectory's ``gravity_{x,y,z}_world`` columns (MPS: ``(0, 0, −9.81)``, z up; ADT: ``(0, −9.81, 0)``,
y up), and a given ``up`` that contradicts them is an error. ``T_device_cpf`` comes from the device
calibration (projectaria_tools ``DeviceCalibration.get_transform_device_cpf()``; :func:`read_aria_device_cpf`
reads it from a VRS file with the ``aria`` extra; :func:`aria_cad_device_cpf` gives its default for a
Gen1 device from the CAD tables). Without it the reader uses the identity, i.e. takes the device
frame (the left SLAM camera) as the CPF, and warns: directions are then off by that camera's
mounting angle.

**Frames.** One time grid for all wearers: ``frame = round((t − start_ns) · fps / 1e9)``,
``start_ns`` by default the earliest gaze sample, ``fps`` by default the highest native rate
``1e9 / median Δt`` of the files (each sample its own frame); one sample per frame (the nearest to the
frame's time). Dropped samples are counted per wearer in a warning and in ``RayRecording.sampling``.
``tracking_timestamp_us`` is each device's own clock, so several wearers are put on a shared clock
through the trajectory's ``utc_timestamp_ns`` (``clock="utc"``, the default for several wearers:
``t = tracking · 1000 + median(utc − tracking · 1000)``); ``clock="device"`` (the default for one)
uses the device clock as it is. Trajectories of different ``graph_uid`` are in different worlds,
which draws a warning.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from typing import Optional, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgaze.io.tools.common import bandwidth_from_mean_angular_error, require_extra
from jaxgaze.io.poses import check_quaternion
from jaxgaze.io.tools.pupil import TimedRays, as_paths, grid_fps, person_rays, rays_on_time_grid, wearer_names
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import InputFileError, format_float, read_csv_table, read_text, write_csv_rows
from jaxgaze.poses import CameraPoses

__all__ = [
    "GAZE_FILE",
    "GAZE_FILES",
    "TRAJECTORY_FILE",
    "ADT_TRAJECTORY_FILE",
    "TYPICAL_IPD_M",
    "UP_AXES",
    "POSE_EDGE_S",
    "LEGACY_GAZE_COLUMNS",
    "VERGENCE_GAZE_COLUMNS",
    "TRAJECTORY_COLUMNS",
    "R_OURS_FROM_CPF",
    "INTERVAL_COVERAGE",
    "DEFAULT_BANDWIDTH_ARIA",
    "MAX_BANDWIDTH_ARIA",
    "ARIA_FPS",
    "aria_gaze_to_direction",
    "direction_to_aria_gaze",
    "read_aria",
    "write_aria",
    "read_aria_device_cpf",
    "read_device_calibration",
    "aria_cad_device_cpf",
    "up_rotation",
]

GAZE_FILE = "general_eye_gaze.csv"
#: The eye gaze file names Aria has shipped (``MpsFileNames.h``; ADT's ``eyegaze.csv``) → their model:
#: ``general`` (calibration-free) or ``personalized`` (after an in-session calibration).
GAZE_FILES = {
    "general_eye_gaze.csv": "general", "generalized_eye_gaze.csv": "general", "eyegaze.csv": "general",
    "personalized_eye_gaze.csv": "personalized", "calibrated_eye_gaze.csv": "personalized",
}
TRAJECTORY_FILE = "closed_loop_trajectory.csv"
#: The Aria Digital Twin's ground-truth device trajectory (``AriaDigitalTwinDataFileNames.h``): MPS's columns.
ADT_TRAJECTORY_FILE = "aria_trajectory.csv"
#: The eyes' baseline (m) of a file without eye origins: an adult's mean interpupillary distance (63 mm).
TYPICAL_IPD_M = 0.063
#: The ``up=`` values of :func:`read_aria` → the unit vector of that axis in the input world.
UP_AXES = {f"{sign}{axis}": (1.0 if sign != "-" else -1.0) * np.eye(3)[i]
           for sign in ("", "+", "-") for i, axis in enumerate("xyz")}
#: A gaze sample at most this far (seconds) beyond the first or last pose of its trajectory takes that
#: pose (ADT's gaze starts 3 µs before its trajectory); 1 ms turns a head at 1 rad/s by 0.06°.
POSE_EDGE_S = 0.001
#: projectaria_tools ``kEyeGazeColumns`` (``EyeGazeReader.cpp``): the legacy schema (also what :func:`write_aria` writes).
LEGACY_GAZE_COLUMNS = (
    "tracking_timestamp_us", "yaw_rads_cpf", "pitch_rads_cpf", "depth_m", "yaw_low_rads_cpf", "pitch_low_rads_cpf",
    "yaw_high_rads_cpf", "pitch_high_rads_cpf", "session_uid",
)
#: projectaria_tools ``kEyeGazeVergenceColumns``: the Gen1 vergence schema and the Gen2 extras.
VERGENCE_GAZE_COLUMNS = (
    "tracking_timestamp_us", "left_yaw_rads_cpf", "right_yaw_rads_cpf", "pitch_rads_cpf", "depth_m",
    "left_yaw_low_rads_cpf", "right_yaw_low_rads_cpf", "pitch_low_rads_cpf", "left_yaw_high_rads_cpf",
    "right_yaw_high_rads_cpf", "pitch_high_rads_cpf", "tx_left_eye_cpf", "ty_left_eye_cpf", "tz_left_eye_cpf",
    "tx_right_eye_cpf", "ty_right_eye_cpf", "tz_right_eye_cpf", "session_uid", "yaw_rads_cpf",
    "left_pitch_rads_cpf", "right_pitch_rads_cpf",
)
#: projectaria_tools ``kCloseLoopTrajectoryColumns`` (``TrajectoryReaders.cpp``).
TRAJECTORY_COLUMNS = (
    "graph_uid", "tracking_timestamp_us", "utc_timestamp_ns", "tx_world_device", "ty_world_device", "tz_world_device",
    "qx_world_device", "qy_world_device", "qz_world_device", "qw_world_device", "device_linear_velocity_x_device",
    "device_linear_velocity_y_device", "device_linear_velocity_z_device", "angular_velocity_x_device",
    "angular_velocity_y_device", "angular_velocity_z_device", "gravity_x_world", "gravity_y_world", "gravity_z_world",
    "quality_score",
)
#: ``v_ours = R_OURS_FROM_CPF @ v_cpf``: CPF X left, Y up, Z forward → ours x forward, y left, z up.
R_OURS_FROM_CPF = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
R_OURS_FROM_CPF.setflags(write=False)
#: The coverage we read MPS's ``[low, high]`` gaze intervals as (not documented by Meta; module docstring).
INTERVAL_COVERAGE = 0.8
_Z = 1.2815515655446004  # Φ⁻¹(0.9): a central 80 % interval is ±1.2816 sd
#: Bandwidth ``h`` of a row without bounds: a mean angular error of 2°, the level of calibration-free
#: wearable gaze (Neon 1.8°; Meta publishes no figure for MPS general eye gaze): 0.0279 rad.
DEFAULT_BANDWIDTH_ARIA = bandwidth_from_mean_angular_error(math.radians(2.0))
#: The widest bandwidth a row keeps (radians, 29°; a wider interval, as in a blink, is clipped to it).
MAX_BANDWIDTH_ARIA = 0.5
#: The frame rate (Hz) :func:`write_aria` writes by default, the simulated scenes' rate (:func:`read_aria`
#: reads at the files' own rate unless given ``fps``).
ARIA_FPS = 10.0
#: ``T_cpf_slam_left`` of projectaria_tools' Gen1 CAD tables (``ConfigData.cpp``): translation (m), unit Y, unit Z.
_CAD_CPF_SLAM_LEFT = {
    "DVT-L": ((0.071351, 0.002372, 0.008454), (0.793353, 0.0, -0.608761), (0.607927, -0.052336, 0.792266)),
    "DVT-S": ((0.069051, 0.002372, 0.009254), (0.793353, 0.0, -0.608761), (0.607927, -0.052336, 0.792266)),
}

_TRAJECTORY_REQUIRED = ("tracking_timestamp_us", "tx_world_device", "ty_world_device", "tz_world_device",
                        "qx_world_device", "qy_world_device", "qz_world_device", "qw_world_device")
_GRAVITY = ("gravity_x_world", "gravity_y_world", "gravity_z_world")
_EYES = ("tx_left_eye_cpf", "ty_left_eye_cpf", "tz_left_eye_cpf", "tx_right_eye_cpf", "ty_right_eye_cpf",
         "tz_right_eye_cpf")


# ---------------------------------------------------------------------------
# Angles, rotations


def aria_gaze_to_direction(yaw, pitch) -> np.ndarray:
    """MPS ``(yaw, pitch)`` (radians, CPF) → unit directions ``(..., 3)`` in our axes of the CPF
    (+x forward, +y left, +z up): ``getUnitVectorFromYawPitch``'s ``normalise(tan yaw, tan pitch, 1)``
    in CPF axes, i.e. ``normalise(1, tan yaw, tan pitch)`` in ours."""
    yaw, pitch = np.broadcast_arrays(np.asarray(yaw, np.float64), np.asarray(pitch, np.float64))
    v = np.stack([np.ones_like(yaw), np.tan(yaw), np.tan(pitch)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def direction_to_aria_gaze(directions) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`aria_gaze_to_direction`: ``yaw = atan(left / forward)``,
    ``pitch = atan(up / forward)``; a direction not in front of the CPF is a ``ValueError``."""
    v = np.asarray(directions, dtype=np.float64)
    if np.any(v[..., 0] <= 0):
        raise ValueError("a gaze direction points sideways or behind the wearer (forward component ≤ 0): "
                         "MPS yaw/pitch cannot express it")
    return np.arctan(v[..., 1] / v[..., 0]), np.arctan(v[..., 2] / v[..., 0])


def _matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """``(M, 3, 3)`` rotations → Hamilton quaternions ``(M, 4)`` as ``(x, y, z, w)`` with ``w ≥ 0``."""
    q = Rotation.from_matrix(np.asarray(R, np.float64).reshape(-1, 3, 3)).as_quat()
    return np.where(q[:, 3:] < 0, -q, q)


def _slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Spherical interpolation of unit quaternions ``(M, 4)`` ``(x, y, z, w)`` at fractions ``s (M,)``
    (shortest arc), as rotation matrices ``(M, 3, 3)``: ``R₀ · exp(s · log(R₀ᵀ R₁))``."""
    r0 = Rotation.from_quat(q0)
    step = (r0.inv() * Rotation.from_quat(q1)).as_rotvec()
    return (r0 * Rotation.from_rotvec(np.asarray(s, np.float64)[:, None] * step)).as_matrix()


def _as_transform(T, name: str) -> np.ndarray:
    T = np.eye(4) if T is None else np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6) \
            or not np.allclose(T[3], [0, 0, 0, 1]) or np.linalg.det(T[:3, :3]) < 0:
        raise ValueError(f"{name} must be a 4×4 rigid transform (rotation and translation), got {T!r}")
    return T


def up_rotation(up: str) -> np.ndarray:
    """The rotation ``R`` (3×3) that turns a world whose up is the axis ``up`` (``"z"``, ``"y"``, ``"-y"``,
    …; :data:`UP_AXES`) into ours, z up: ``x_ours = R @ x_in``. It is the shortest turn taking that axis
    onto +z (about ``u × z`` by ``acos(u · z)``; a half turn about x for ``"-z"``), so ``"y"`` maps
    ``(x, y, z) → (x, −z, y)``."""
    if up not in UP_AXES:
        raise ValueError(f"up must be one of {', '.join(a for a in UP_AXES if not a.startswith('+'))} (the axis of "
                         f"the input world that points up), got {up!r}")
    u = UP_AXES[up]
    if u[2] == -1.0:
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(u, [0.0, 0.0, 1.0])
    return Rotation.from_rotvec(axis * (math.pi / 2) if u[2] == 0 else np.zeros(3)).as_matrix()


def aria_cad_device_cpf(subtype: str) -> np.ndarray:
    """The 4×4 ``T_device_cpf`` projectaria_tools gives a Gen1 device of ``subtype`` (``"DVT-L"`` or
    ``"DVT-S"``, the calibration's ``DeviceClassInfo.BuildVersion``) by default
    (``get_transform_device_cpf()``, ``use_svd=False``): the inverse of the CAD pose ``T_cpf_slam_left``
    of the left SLAM camera, the device frame (``DeviceCadExtrinsics.cpp``: rotation columns
    ``Y × Z, Y, Z`` of the normalised CAD axes)."""
    if subtype not in _CAD_CPF_SLAM_LEFT:
        raise ValueError(f"no CAD extrinsics for Aria Gen1 subtype {subtype!r}: choose from "
                         + ", ".join(_CAD_CPF_SLAM_LEFT))
    t, y, z = (np.asarray(v, np.float64) for v in _CAD_CPF_SLAM_LEFT[subtype])
    y, z = y / np.linalg.norm(y), z / np.linalg.norm(z)
    u, _, vt = np.linalg.svd(np.stack([np.cross(y, z), y, z], axis=1))  # the nearest rotation (Sophus)
    T_cpf_device = np.eye(4)
    T_cpf_device[:3, :3], T_cpf_device[:3, 3] = u @ vt, t
    return np.linalg.inv(T_cpf_device)


# ---------------------------------------------------------------------------
# Reading


def _gaze_file(folder: str, eye_gaze: Optional[str]) -> str:
    """The one eye gaze CSV of a wearer folder: any name of :data:`GAZE_FILES`, in the folder or its
    ``eye_gaze/``, of the model ``eye_gaze`` (``"general"`` or ``"personalized"``; None: any). One model in
    several schemas: the first in :data:`GAZE_FILES`' order (the newest), with a warning; two models: an error."""
    found = [os.path.join(sub, name) for sub in ("", "eye_gaze") for name in GAZE_FILES
             if os.path.isfile(os.path.join(folder, sub, name))]
    chosen = [f for f in found if eye_gaze is None or GAZE_FILES[os.path.basename(f)] == eye_gaze]
    if len(chosen) == 1:
        return os.path.join(folder, chosen[0])
    names = ", ".join(f"{f} ({GAZE_FILES[os.path.basename(f)]})" for f in found)
    if not chosen:
        wanted = "" if eye_gaze is None else f"{eye_gaze} "
        raise InputFileError(f"no {wanted}eye gaze CSV ({', '.join(n for n in GAZE_FILES if eye_gaze in (None, GAZE_FILES[n]))}) "
                             f"in this wearer folder nor in its eye_gaze/" + (f" (it holds {names})" if found else ""),
                             folder)
    models = sorted({GAZE_FILES[os.path.basename(f)] for f in chosen})
    if len(models) == 1:  # one model in several schemas (Gen1: generalized_eye_gaze.csv and legacy eyegaze.csv)
        preference = list(GAZE_FILES)
        chosen.sort(key=lambda f: preference.index(os.path.basename(f)))
        warnings.warn(f"{folder}: several {models[0]} eye gaze CSVs ({names}): reading {chosen[0]}, the newest "
                      "schema; pass the path of another to read it", stacklevel=4)
        return os.path.join(folder, chosen[0])
    choose = "eye_gaze='general' or 'personalized', or " if eye_gaze is None else ""
    raise InputFileError(f"several eye gaze CSVs in this wearer folder: {names}; pass {choose}the path of the one "
                         "to read", folder)


def _trajectory_file(gaze: str) -> Optional[str]:
    """The trajectory of a gaze CSV: MPS's ``closed_loop_trajectory.csv`` beside it or under ``slam/`` or
    (older MPS) ``trajectory/`` of its folder or its folder's parent, else ADT's ``aria_trajectory.csv``
    beside it or, for the gaze of an ADT sequence's ``mps/``, in the sequence folder; None if none."""
    folder = os.path.dirname(os.path.abspath(gaze))
    parent = os.path.dirname(folder)
    candidates = [os.path.join(where, sub, TRAJECTORY_FILE) for where in (folder, parent)
                  for sub in ("", "slam", "trajectory") if (where, sub) != (parent, "")]
    candidates.append(os.path.join(folder, ADT_TRAJECTORY_FILE))
    for mps in (folder, parent):
        if os.path.basename(mps) == "mps":
            candidates.append(os.path.join(os.path.dirname(mps), ADT_TRAJECTORY_FILE))
    return next((c for c in candidates if os.path.isfile(c)), None)


def _wearer_files(path, eye_gaze: Optional[str] = None) -> tuple[str, Optional[str]]:
    """The gaze CSV and the trajectory CSV (or None) of a wearer folder (or of its gaze CSV)."""
    path = os.fspath(path)
    if eye_gaze not in (None, "general", "personalized"):
        raise ValueError(f"eye_gaze must be 'general' or 'personalized', got {eye_gaze!r}")
    if not os.path.exists(path):
        raise InputFileError("no such file or folder", path)
    gaze = _gaze_file(path, eye_gaze) if os.path.isdir(path) else path
    return gaze, _trajectory_file(gaze)


def _interval_sd(row, low: str, high: str) -> Optional[float]:
    if not (row.table.has(low) and row.table.has(high)) or not (row.cell(low) and row.cell(high)):
        return None
    lo, hi = row.number(low), row.number(high)
    if lo > hi:
        raise row.error(f"{low} {lo:g} is above {high} {hi:g}")
    return (hi - lo) / (2 * _Z)


def _depth_m(row) -> float:
    """``depth_m`` of a row (metres from the CPF origin along the gaze), NaN when empty or 0 (not available)."""
    if not (row.table.has("depth_m") and row.cell("depth_m")):
        return math.nan
    depth = row.number("depth_m")
    if depth < 0:
        raise row.error(f"depth_m must be 0 (not available) or positive (metres), got {depth:g}")
    return depth if depth > 0 else math.nan


def _recording_folder(path) -> str:
    """A wearer's path without MPS's own ``eye_gaze/`` folder (or a gaze CSV in it), so that the person is named
    after the recording (``mps_sample/eye_gaze`` → ``mps_sample``), not the folder MPS writes into it."""
    path = os.path.normpath(os.fspath(path))
    if os.path.isfile(path) and os.path.basename(os.path.dirname(path)) == "eye_gaze":
        return os.path.dirname(os.path.dirname(path))
    return os.path.dirname(path) if os.path.basename(path) == "eye_gaze" else path


def _read_gaze(path):
    """Device times (µs), CPF origins and directions (CPF axes), bandwidths, depths along the rays and their sd
    (the vergence rule of the module docstring) of one gaze CSV."""
    table = read_csv_table(path, ("tracking_timestamp_us", "pitch_rads_cpf"),
                           tuple(c for c in dict.fromkeys(VERGENCE_GAZE_COLUMNS + LEGACY_GAZE_COLUMNS)
                                 if c not in ("tracking_timestamp_us", "pitch_rads_cpf")),
                           hint=f"an Aria MPS {GAZE_FILE} (tracking_timestamp_us, pitch_rads_cpf and yaw_rads_cpf "
                                "or left_yaw_rads_cpf and right_yaw_rads_cpf)")
    combined = table.has("yaw_rads_cpf")
    if not combined and not (table.has("left_yaw_rads_cpf") and table.has("right_yaw_rads_cpf")):
        raise table.fail("missing column 'yaw_rads_cpf' (or 'left_yaw_rads_cpf' and 'right_yaw_rads_cpf') in the "
                         "header of this eye gaze CSV")
    eyes = all(table.has(c) for c in _EYES)
    times, origins, tangents, bandwidth, depth_cpf, baselines = [], [], [], [], [], []
    clipped = defaulted = 0
    for row in table.rows:
        times.append(row.integer("tracking_timestamp_us"))
        pitch = row.number("pitch_rads_cpf")
        if combined:
            yaws = [row.number("yaw_rads_cpf")]
        else:
            yaws = [row.number("left_yaw_rads_cpf"), row.number("right_yaw_rads_cpf")]
        if max(abs(pitch), *map(abs, yaws)) >= math.pi / 2:
            raise row.error(f"gaze angles (yaw {yaws}, pitch {pitch:g}) must lie in (−π/2, π/2) radians (degrees?)")
        tangents.append([float(np.mean(np.tan(yaws))), math.tan(pitch)])
        origin, ipd = np.zeros(3), TYPICAL_IPD_M
        if eyes and all(row.cell(c) for c in _EYES):
            left, right = np.array([row.number(c) for c in _EYES[:3]]), np.array([row.number(c) for c in _EYES[3:]])
            origin, ipd = 0.5 * (left + right), float(np.linalg.norm(left - right)) or TYPICAL_IPD_M
        origins.append(origin)
        baselines.append(ipd)
        depth_cpf.append(_depth_m(row))
        sd_pitch = _interval_sd(row, "pitch_low_rads_cpf", "pitch_high_rads_cpf")
        if combined:
            sd_yaw = _interval_sd(row, "yaw_low_rads_cpf", "yaw_high_rads_cpf")
        else:
            eye_sds = [_interval_sd(row, f"{eye}_yaw_low_rads_cpf", f"{eye}_yaw_high_rads_cpf")
                       for eye in ("left", "right")]
            sd_yaw = None if None in eye_sds else float(np.mean(eye_sds))
        if sd_yaw is None or sd_pitch is None or sd_yaw + sd_pitch == 0:
            h = DEFAULT_BANDWIDTH_ARIA
            defaulted += 1
        else:
            h = math.sqrt((sd_yaw ** 2 + sd_pitch ** 2) / 2)
        if h > MAX_BANDWIDTH_ARIA:
            h = MAX_BANDWIDTH_ARIA
            clipped += 1
        bandwidth.append(h)
    if clipped:
        warnings.warn(f"{table.path}: {clipped} of {len(table.rows)} gaze rows have intervals wider than a "
                      f"{MAX_BANDWIDTH_ARIA} rad bandwidth (blinks?): clipped to {MAX_BANDWIDTH_ARIA}", stacklevel=3)
    if defaulted:  # Gen2 files carry no intervals at all: said, not silent
        warnings.warn(f"{table.path}: {defaulted} of {len(table.rows)} gaze rows have no usable yaw/pitch interval: "
                      f"their bandwidth is the default {DEFAULT_BANDWIDTH_ARIA:.4f} rad (a mean error of 2°), "
                      f"not the tool's own; --bandwidth (bandwidth=) sets another", stacklevel=3)
    tangents = np.asarray(tangents)
    directions = np.stack([tangents[:, 0], tangents[:, 1], np.ones(len(tangents))], axis=1)  # CPF axes
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    times = np.asarray(times, np.int64)
    if np.any(np.diff(times) <= 0):
        i = int(np.argmax(np.diff(times) <= 0)) + 1
        raise InputFileError(f"tracking_timestamp_us does not increase ({times[i - 1]} then {times[i]})", table.path,
                             table.rows[i].line)
    # getEyeGazePointAtDepth: the point is depth_m · direction from the CPF origin; along our ray from
    # its origin o that is (depth_m · d − o) · d = depth_m − o · d (equal when o is the CPF origin)
    origins = np.asarray(origins)
    depth = np.asarray(depth_cpf) - np.einsum("mi,mi->m", origins, directions)
    bandwidth = np.asarray(bandwidth)
    depth_sd = np.square(np.asarray(depth_cpf)) * math.sqrt(2.0) * bandwidth / np.asarray(baselines)
    return table.path, times, origins, directions, bandwidth, depth, depth_sd


class _Trajectory:
    """One ``closed_loop_trajectory.csv`` (or ADT ``aria_trajectory.csv``): device times (µs), poses, UTC
    offset, graph ids and the median gravity in the world (``None`` without the columns)."""

    def __init__(self, path):
        table = read_csv_table(path, _TRAJECTORY_REQUIRED, ("utc_timestamp_ns", "graph_uid") + _GRAVITY,
                               hint=f"an Aria MPS {TRAJECTORY_FILE} (columns " + ", ".join(_TRAJECTORY_REQUIRED) + ")")
        times, translations, quaternions, utc = [], [], [], []
        for row in table.rows:
            times.append(row.integer("tracking_timestamp_us"))
            translations.append([row.number(f"t{a}_world_device") for a in "xyz"])
            q = [row.number(f"q{a}_world_device") for a in "xyzw"]
            check_quaternion([q[3], *q[:3]], table.path, row.line)
            quaternions.append(np.asarray(q) / np.linalg.norm(q))
            utc.append(row.integer("utc_timestamp_ns") if table.has("utc_timestamp_ns") and row.cell("utc_timestamp_ns")
                       else -1)
        self.path = table.path
        self.times = np.asarray(times, np.int64)
        steps = np.diff(self.times)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0)) + 1
            raise InputFileError(f"tracking_timestamp_us does not increase ({self.times[i - 1]} then "
                                 f"{self.times[i]})", table.path, table.rows[i].line)
        self.translations = np.asarray(translations)
        self.quaternions = np.asarray(quaternions)
        utc = np.asarray(utc, np.int64)
        known = utc >= 0
        self.utc_offset_ns = int(np.median(utc[known] - 1000 * self.times[known])) if known.any() else None
        self.graph_uids = sorted({row.cell("graph_uid") for row in table.rows}) if table.has("graph_uid") else []
        self.gravity = None
        if all(table.has(c) for c in _GRAVITY):
            gravity = np.median([[row.number(c) for c in _GRAVITY] for row in table.rows], axis=0)
            self.gravity = gravity if np.linalg.norm(gravity) > 0 else None

    def up(self) -> Optional[str]:
        """The axis of :data:`UP_AXES` opposite to the gravity column (within 1°), None without one."""
        if self.gravity is None:
            return None
        g = -self.gravity / np.linalg.norm(self.gravity)
        axis = max((a for a in UP_AXES if not a.startswith("+")), key=lambda a: float(UP_AXES[a] @ g))
        if UP_AXES[axis] @ g < math.cos(math.radians(1.0)):
            raise InputFileError(f"the gravity columns point along {np.round(self.gravity, 3).tolist()}, not along "
                                 "a world axis: turn the world upright first", self.path)
        return axis

    def poses_at(self, times_us: np.ndarray, max_gap_us: float):
        """``(R_world_device (M, 3, 3), t_world_device (M, 3))`` at ``times_us`` and the mask of the
        times the trajectory covers (inside it, between poses at most ``max_gap_us`` apart, or at most
        :data:`POSE_EDGE_S` beyond its ends, which take the end pose)."""
        t = self.times
        edge_us = POSE_EDGE_S * 1e6
        upper = np.clip(np.searchsorted(t, times_us, side="left"), 0, len(t) - 1)
        lower = np.clip(upper - 1, 0, len(t) - 1)
        exact = t[upper] == times_us
        lower = np.where(exact, upper, lower)
        inside = (times_us >= t[0] - edge_us) & (times_us <= t[-1] + edge_us)
        covered = inside & (exact | (t[upper] - t[lower] <= max_gap_us))
        span = np.maximum(t[upper] - t[lower], 1)
        s = np.clip(np.where(exact, 0.0, (times_us - t[lower]) / span), 0.0, 1.0)
        translations = self.translations[lower] + s[:, None] * (self.translations[upper] - self.translations[lower])
        return _slerp(self.quaternions[lower], self.quaternions[upper], s), translations, covered


def _choose_up(up: Optional[str], trajectories: dict) -> str:
    """The input world's up axis: ``up`` checked against the trajectories' gravity, or read from it."""
    found = {person: trajectory.up() for person, trajectory in trajectories.items()}
    if up is not None:
        up_rotation(up)  # checks the name
        for person, axis in found.items():
            if axis is not None and UP_AXES[axis] @ UP_AXES[up] < 0.5:
                raise InputFileError(f"up={up!r}, but this trajectory's gravity columns point down its {axis} axis "
                                     f"(pass up={axis!r})", trajectories[person].path)
        return up
    axes = {axis for axis in found.values() if axis is not None}
    if len(axes) > 1:
        raise ValueError("read_aria: the trajectories' gravity columns give different up axes ("
                         + "; ".join(f"{p}: {a}" for p, a in found.items()) + "): their worlds differ")
    return axes.pop() if axes else "z"


def read_aria(paths, *, camera: Optional[CameraPoses] = None, persons: Optional[Sequence[str]] = None,
              T_device_cpf=None, fps: Optional[float] = None, start_ns: Optional[int] = None,
              clock: Optional[str] = None, max_pose_gap_s: float = 0.05, frame: str = "world",
              up: Optional[str] = None, eye_gaze: Optional[str] = None) -> RayRecording:
    """Aria wearer folders (MPS, or an ADT sequence; a gaze CSV and its trajectory each, module docstring)
    → one world :class:`RayRecording` with each ray's ``depth`` (``depth_m``), ``sampling`` and ``up``.

    ``T_device_cpf``: the 4×4 ``T_device_cpf`` of the device calibration (one for all wearers, or a
    list in folder order; :func:`read_aria_device_cpf`, :func:`aria_cad_device_cpf`); default identity,
    with a warning. ``frame``: ``"world"`` (the trajectory's world turned z-up; a wearer without a
    trajectory is an :class:`InputFileError` unless ``camera`` places it) or ``"cpf"`` (each wearer's
    Central Pupil Frame in our axes, the head's frame; trajectories unused). ``up``: the axis of the
    trajectories' world that points up (``"z"``, ``"y"``, ``"-y"``, …), turned onto our +z by
    :func:`up_rotation`; default: opposite to their ``gravity_*_world`` columns, else ``"z"``.
    ``eye_gaze``: ``"general"`` or ``"personalized"`` where a folder holds both. ``fps``: the time grid's
    rate; default the highest native rate of the files (``1e9 / median Δt``), so each sample gets its own
    frame. ``clock``: ``"utc"`` or ``"device"`` (default: device for one wearer, UTC for several).
    ``camera``: poses of the CPF (our axes) for one wearer without a trajectory. Samples without a pose
    (outside the trajectory or in a gap) or sharing a frame with a nearer sample are dropped, counted
    in a warning and in ``sampling``; a wearer left without any is an :class:`InputFileError`.
    """
    paths = as_paths(paths)
    names = wearer_names([_recording_folder(p) for p in paths], persons, ())
    if clock is None:
        clock = "device" if len(paths) == 1 else "utc"
    if clock not in ("device", "utc"):
        raise ValueError(f"clock must be 'device' or 'utc', got {clock!r}")
    if frame not in ("world", "cpf"):
        raise ValueError(f"frame must be 'world' or 'cpf' (the wearer's head frame), got {frame!r}")
    if frame == "cpf" and (camera is not None or up not in (None, "z", "+z")):
        raise ValueError("frame='cpf' gives each wearer's rays in its own head frame (z up): camera= and up= "
                         "place rays in a world")
    transforms = list(T_device_cpf) if isinstance(T_device_cpf, (list, tuple)) else [T_device_cpf] * len(paths)
    if len(transforms) != len(paths):
        raise ValueError(f"T_device_cpf has {len(transforms)} transforms for {len(paths)} wearers")
    transforms = [_as_transform(T, "T_device_cpf") for T in transforms]
    wearers, trajectories = [], {}
    no_pose = f"without a pose (outside the trajectory, or in a gap over {max_pose_gap_s:g} s)"
    for path, person, T in zip(paths, names, transforms):
        gaze_path, trajectory_path = _wearer_files(path, eye_gaze)
        gaze_path, times_us, origins_cpf, directions_cpf, bandwidth, depth, depth_sd = _read_gaze(gaze_path)
        if trajectory_path is not None and os.path.basename(trajectory_path) == ADT_TRAJECTORY_FILE:
            depth_sd = np.zeros_like(depth_sd)  # the ADT sequence's own gaze: its depth is the digital twin's truth
        read = len(times_us)
        if frame == "cpf" or trajectory_path is None:
            if frame == "world" and (camera is None or len(paths) > 1):
                raise InputFileError(
                    f"no trajectory for this wearer ({TRAJECTORY_FILE} beside the gaze or under slam/ or trajectory/, "
                    f"nor an ADT {ADT_TRAJECTORY_FILE}): world rays need one"
                    + (" (several wearers share a world only through their trajectories)" if len(paths) > 1 else
                       "; pass camera= with the head's poses, or frame='cpf' for rays in the head frame"), path)
            origins, directions = origins_cpf @ R_OURS_FROM_CPF.T, directions_cpf @ R_OURS_FROM_CPF.T
            wearers.append(TimedRays(gaze_path, person, 1000 * times_us, origins, directions, bandwidth, depth, camera,
                                     read, (("outside", 0, no_pose),), depth_sd=depth_sd))
            continue
        if camera is not None:
            raise ValueError("camera= places a wearer without a trajectory; this wearer's world is its "
                             f"{os.path.basename(trajectory_path)}")
        if T_device_cpf is None and not trajectories:
            warnings.warn("read_aria: no T_device_cpf given: taking the device frame (left SLAM camera) as the CPF; "
                          "world gaze directions are off by that camera's mounting angle. Pass the device "
                          "calibration's get_transform_device_cpf().to_matrix() (read_aria_device_cpf, or "
                          "aria_cad_device_cpf for a Gen1 device's default)", stacklevel=2)
        trajectory = _Trajectory(trajectory_path)
        trajectories[person] = trajectory
        R_wd, t_wd, covered = trajectory.poses_at(times_us, max_pose_gap_s * 1e6)
        if not covered.any():
            raise InputFileError(f"no gaze sample falls within the trajectory {trajectory.path} "
                                 f"(gaze {times_us[0]}–{times_us[-1]} µs, trajectory {trajectory.times[0]}–"
                                 f"{trajectory.times[-1]} µs)", gaze_path)
        R_wc = R_wd[covered] @ T[:3, :3]
        t_wc = np.einsum("mij,j->mi", R_wd[covered], T[:3, 3]) + t_wd[covered]
        origins = np.einsum("mij,mj->mi", R_wc, origins_cpf[covered]) + t_wc
        directions = np.einsum("mij,mj->mi", R_wc, directions_cpf[covered])
        shared_ns = 1000 * times_us[covered]
        if clock == "utc":
            if trajectory.utc_offset_ns is None:
                raise InputFileError("no utc_timestamp_ns (all −1 or absent): the wearers' device clocks cannot be "
                                     "put on one clock; pass clock='device' if the recordings share a clock "
                                     "(e.g. Aria TimeSync)", trajectory.path)
            shared_ns = shared_ns + trajectory.utc_offset_ns
        wearers.append(TimedRays(gaze_path, person, shared_ns, origins, directions, bandwidth[covered], depth[covered],
                                 None, read, (("outside", int((~covered).sum()), no_pose),),
                                 depth_sd=depth_sd[covered]))
    distinct = {tuple(t.graph_uids) for t in trajectories.values()}
    if len(distinct) > 1:
        warnings.warn("read_aria: the trajectories have different graph_uid ("
                      + "; ".join(f"{p}: {', '.join(t.graph_uids) or '?'}" for p, t in trajectories.items())
                      + "): their worlds differ unless MPS multi-SLAM aligned them", stacklevel=2)
    up = "z" if frame == "cpf" else _choose_up(up, trajectories)
    recording = rays_on_time_grid(wearers, fps=grid_fps(fps, wearers, ARIA_FPS), start_ns=start_ns,
                                  rotation=up_rotation(up), path=paths[0] if len(paths) == 1 else ", ".join(paths))
    return recording._replace(up=up)


# ---------------------------------------------------------------------------
# Writing


def _upright_poses(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R_world_from_cpf`` (our axes) with +x along each direction and +z as close to world up as
    it goes (no roll), centred on the origins: the pose that sees every ray straight ahead."""
    forward = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    left = np.cross([0.0, 0.0, 1.0], forward)
    norm = np.linalg.norm(left, axis=1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("a gaze ray points straight up or down: give poses= to write it")
    left /= norm
    return np.stack([forward, left, np.cross(forward, left)], axis=-1), origins


def write_aria(directory, recording: RayRecording, *, person: Optional[str] = None,
               poses: Optional[CameraPoses] = None, T_device_cpf=None, fps: float = ARIA_FPS, start_ns: int = 0,
               device_offset_ns: int = 0, graph_uid: str = "jaxgaze-world") -> int:
    """Write one person's rays as an MPS wearer folder: ``general_eye_gaze.csv`` (legacy schema) and
    ``closed_loop_trajectory.csv`` in ``directory`` (created if needed), atomically; returns the
    number of gaze rows.

    ``poses``: the CPF's poses in our axes (``R_camera_from_world``, ``centers`` on the ray origins,
    one per ray frame, or sampled at ``poses.timestamps`` seconds on the shared clock); default: an
    upright CPF looking along each ray. Gaze in CPF (:func:`direction_to_aria_gaze`); bounds
    ``angle ± z·h`` (:data:`INTERVAL_COVERAGE`); ``T_world_device = T_world_cpf · T_device_cpf⁻¹``.
    The shared clock is ``start_ns + frame · 1e9 / fps``; the device clock is that minus
    ``device_offset_ns`` (``tracking_timestamp_us``, whole µs), ``utc_timestamp_ns`` the shared one.
    """
    frames, origins, directions, bandwidth = person_rays(recording, person, directory)
    T = _as_transform(T_device_cpf, "T_device_cpf")
    shared_ns = start_ns + np.rint(frames * (1e9 / fps)).astype(np.int64)
    if poses is None:
        R_wc, centers = _upright_poses(origins, directions)
        pose_ns, R_at, c_at = shared_ns, R_wc, centers
    elif poses.timestamps is None:
        at = np.clip(np.searchsorted(np.asarray(poses.frame_ids), frames), 0, len(poses.frame_ids) - 1)
        if np.any(np.asarray(poses.frame_ids)[at] != frames):
            raise ValueError("poses= has no pose for some ray frames (give it timestamps to interpolate)")
        R_wc, centers = poses.R_world_from_camera[at], np.asarray(poses.centers, np.float64)[at]
        pose_ns, R_at, c_at = shared_ns, R_wc, centers
    else:
        R_wc, centers = poses.R_world_from_camera, np.asarray(poses.centers, np.float64)
        pose_ns = np.rint(np.asarray(poses.timestamps, np.float64) * 1e9).astype(np.int64)
        if shared_ns.min() < pose_ns.min() or shared_ns.max() > pose_ns.max():
            raise ValueError("poses.timestamps do not cover the rays' times (start_ns + frame · 1e9 / fps)")
        R_at, c_at = _poses_at_times(pose_ns, R_wc, centers, shared_ns)
    local_origin = np.einsum("mji,mj->mi", R_at, origins - c_at)
    if np.abs(local_origin).max() > 1e-3:
        raise ValueError(f"{GAZE_FILE} (legacy schema) starts every ray at the CPF, but a ray starts "
                         f"{1000 * np.abs(local_origin).max():.1f} mm from its pose's centre: centre poses= on the "
                         "ray origins")
    yaw, pitch = direction_to_aria_gaze(np.einsum("mji,mj->mi", R_at, directions))
    half = _Z * bandwidth
    device_us = np.rint((shared_ns - device_offset_ns) / 1000).astype(np.int64)
    gaze_rows = [[int(t), *map(format_float, (y, p)), "0.0", *map(format_float, (y - h, p - h, y + h, p + h)),
                  "jaxgaze"] for t, y, p, h in zip(device_us, yaw, pitch, half)]
    R_w_cpf_aria = R_wc @ R_OURS_FROM_CPF  # CPF axes → world
    R_wd = R_w_cpf_aria @ T[:3, :3].T
    t_wd = centers - np.einsum("mij,j->mi", R_wd, T[:3, 3])
    q = _matrix_to_quaternion(R_wd)
    pose_us = np.rint((pose_ns - device_offset_ns) / 1000).astype(np.int64)
    trajectory_rows = [[graph_uid, int(t), int(t) * 1000 + int(device_offset_ns), *map(format_float, tr),
                        *map(format_float, qq), *["0.0"] * 6, "0.0", "0.0", "-9.81", "1.0"]
                       for t, tr, qq in zip(pose_us, t_wd, q)]
    os.makedirs(directory, exist_ok=True)
    write_csv_rows(os.path.join(directory, TRAJECTORY_FILE), TRAJECTORY_COLUMNS, trajectory_rows)
    return write_csv_rows(os.path.join(directory, GAZE_FILE), LEGACY_GAZE_COLUMNS, gaze_rows)


def _poses_at_times(pose_ns, R_world_cpf, centers, times_ns):
    """Poses (our axes) interpolated at ``times_ns`` from poses at ``pose_ns`` (as the reader does)."""
    q = _matrix_to_quaternion(R_world_cpf)
    upper = np.clip(np.searchsorted(pose_ns, times_ns), 0, len(pose_ns) - 1)
    lower = np.clip(upper - 1, 0, len(pose_ns) - 1)
    lower = np.where(pose_ns[upper] == times_ns, upper, lower)
    span = np.maximum(pose_ns[upper] - pose_ns[lower], 1)
    s = np.clip(np.where(upper == lower, 0.0, (times_ns - pose_ns[lower]) / span), 0.0, 1.0)
    return (_slerp(q[lower], q[upper], s),
            centers[lower] + s[:, None] * (centers[upper] - centers[lower]))


def read_aria_device_cpf(vrs_path) -> np.ndarray:
    """The 4×4 ``T_device_cpf`` of a recording's device calibration, from its VRS file through
    projectaria-tools (``pip install 'jaxgaze[aria]'``; :class:`MissingExtraError` without it):
    ``create_vrs_data_provider(path).get_device_calibration().get_transform_device_cpf().to_matrix()``."""
    data_provider = require_extra("projectaria_tools.core.data_provider", "aria")
    provider = data_provider.create_vrs_data_provider(os.fspath(vrs_path))
    if provider is None:
        raise InputFileError("projectaria-tools cannot open this VRS file", vrs_path)
    return np.asarray(provider.get_device_calibration().get_transform_device_cpf().to_matrix(), dtype=np.float64)


def read_device_calibration(path) -> np.ndarray:
    """A device calibration's 4×4 ``T_device_cpf`` from a file: a recording's ``.vrs`` (through
    :func:`read_aria_device_cpf`, the ``aria`` extra), a ``.json`` holding the matrix (a 4×4 list of rows,
    or an object with one such list, e.g. ``{"T_device_cpf": [[...], ...]}``), or text: 16 numbers, four
    rows of four, separated by spaces, tabs or commas (``#`` starts a comment). Anything else, or a
    matrix that is not a rigid transform, is an :class:`InputFileError` naming the formats."""
    path = os.fspath(path)
    expected = ("expected a .vrs recording, a JSON 4×4 matrix (a list of 4 rows, or {\"T_device_cpf\": rows}) "
                "or text of 4 rows of 4 numbers (T_device_cpf, metres)")
    if path.lower().endswith(".vrs"):
        return read_aria_device_cpf(path)
    text = read_text(path)
    if path.lower().endswith(".json"):
        try:
            value = json.loads(text)
        except json.JSONDecodeError as error:
            raise InputFileError(f"not JSON ({error.msg}): {expected}", path, error.lineno) from None
        if isinstance(value, dict):
            matrices = [v for v in value.values() if isinstance(v, list)]
            value = matrices[0] if len(matrices) == 1 else None
    else:
        rows = [line.split("#", 1)[0].replace(",", " ").split() for line in text.splitlines()]
        value = [row for row in rows if row]
    try:
        matrix = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        matrix = None
    if matrix is None or matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise InputFileError(f"no 4×4 matrix of numbers: {expected}", path)
    try:
        return _as_transform(matrix, "T_device_cpf")
    except ValueError:
        raise InputFileError("the 4×4 matrix is not a rigid transform (an orthonormal rotation of determinant 1 "
                             "and a translation, last row 0 0 0 1)", path) from None
