"""Gaze360 (Kellnhofer et al. 2019) → world-frame rays, the cone width taken from Gaze360's own ``var``.

**What Gaze360 gives.** ``GazeLSTM.forward`` (code/model.py) returns per person and frame
``angular_output = (yaw, pitch)``, radians (``yaw = π tanh(·)``, ``pitch = π/2 tanh(·)``), and
``var = π sigmoid(·)`` (radians, the same for both angles).

**Frame.** The angles live in Gaze360's *eye coordinate system* E (dataset README, "Eye coordinate
system"; the authors, gaze360 issue #30: "M is only a function of person_eyes3d"): a right-handed
frame whose ``E_z`` points from the camera to the eyes (away from the camera), ``E_y`` up and ``E_x``
to the camera's left (the person's right when they face the camera). So looking into the camera
is ``[0, 0, −1]`` wherever the person stands. In our camera frame (+x optical axis, +y left, +z up),
with ``e`` the eye centre: ``E_z = e/‖e‖``, ``E_y`` = our +z made orthogonal to ``E_z`` and
normalised, ``E_x = E_y × E_z`` (:func:`gaze360_eye_frame`). For a person on the optical axis
``E = (our y, our z, our x)``.

**Angles → vector** (``spherical2cartesial`` in code/run.py; its inverse is in code/data_loader.py):
``g_E = (cos p sin y, sin p, −cos p cos y)``. ``yaw = pitch = 0`` looks into the camera; ``yaw > 0``
turns towards the camera's left (the person's right), ``pitch > 0`` up.

**Bandwidth** (:func:`bandwidth_from_gaze360_var`). ``PinBallLoss`` (code/model.py) trains
``angle − var`` as the 10% quantile and ``angle + var`` as the 90% quantile of each true angle, so for
a Gaussian error of standard deviation σ per angle ``var = z₀.₉ σ`` (``z₀.₉ = 1.2816``). The angle α
between reported and true direction is then ``σ‖δ‖``, ``δ ~ N(0, I₂)``; our cone has ``tan α = h‖δ‖``.
Matching the two at the 90% cone, ``‖δ‖ = r₉₀ = √(2 ln 10) = 2.146``, gives
``h = tan(r₉₀ σ) / r₉₀`` (≈ σ for small σ). ``h`` is clipped at :data:`MAX_BANDWIDTH_GAZE360`
(0.5 rad, reached at ``var`` ≈ 0.49 rad = 28°; Gaze360's ``var`` goes up to π, e.g. for people seen
from behind) with a warning naming how many rays. For a large pitch the yaw error moves the
direction by only ``cos(pitch)`` of itself, so ``h`` is then slightly wide (conservative).

**The dump CSV** (:func:`read_gaze360` / :func:`write_gaze360`): Gaze360 has no file format of its
own, so one row per person and frame with Gaze360's names: :data:`GAZE360_COLUMNS` =
``frame, person_identity, yaw, pitch, var, person_eyes3d_x, person_eyes3d_y, person_eyes3d_z``.
``person_identity`` is any text (one person keeps it across frames); ``person_eyes3d_*`` is the
mid-eye point in the **OpenCV camera frame of the image** (x right, y down, z forward), metres, e.g.
the back-projection of the eyes' pixel at their depth (``x = (u − cx) Z / fx``). Several files are
rows of one recording (one camera), e.g. one file per person.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Optional, Sequence

import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.common import eye_axes_problem, rays_from_camera, world_rays_to_camera
from jaxgaze.io.rays import RayRecording
from jaxgaze.io.text import InputFileError, format_float, read_csv_table, write_csv_rows
from jaxgaze.poses import CameraPoses
from jaxgaze.rays import PLAUSIBLE_BANDWIDTH

__all__ = [
    "GAZE360_COLUMNS",
    "MAX_BANDWIDTH_GAZE360",
    "Z_90",
    "R_90",
    "gaze360_eye_frame",
    "gaze360_directions",
    "gaze360_angles",
    "bandwidth_from_gaze360_var",
    "gaze360_var_from_bandwidth",
    "gaze360_to_rays",
    "read_gaze360",
    "write_gaze360",
]

#: Columns of a Gaze360 dump CSV (see the module docstring).
GAZE360_COLUMNS = ("frame", "person_identity", "yaw", "pitch", "var",
                   "person_eyes3d_x", "person_eyes3d_y", "person_eyes3d_z")
#: The widest cone a Gaze360 ray gets (radians): wider cones are taken for degrees by
#: :func:`jaxgaze.rays.check_units` and say little about where someone looks.
MAX_BANDWIDTH_GAZE360 = PLAUSIBLE_BANDWIDTH
#: The 90% quantile of the standard normal: ``var = Z_90 σ`` (Gaze360's 10%/90% quantile loss).
Z_90 = 1.2815515655446004
#: The radius of the 90% disc of a 2-D standard normal: ``√(2 ln 10)``.
R_90 = math.sqrt(2.0 * math.log(10.0))

_ARRAYS = "<arrays>"
_ANGLE_SLACK = 1e-9
_UP = np.array([0.0, 0.0, 1.0])


# ---------------------------------------------------------------------------
# The eye frame and the angles


def gaze360_eye_frame(eyes_camera) -> np.ndarray:
    """Gaze360's eye coordinate system at each eye centre ``eyes_camera`` ``(M, 3)`` (our camera axes: +x
    the optical axis, +y left, +z up; metres): ``(M, 3, 3)`` whose columns are ``E_x, E_y, E_z`` in our
    camera frame (``v_camera = R @ g_E``).

    ``E_z = e/‖e‖`` (away from the camera), ``E_y`` = our +z minus its ``E_z`` part, normalised,
    ``E_x = E_y × E_z`` (the camera's left). Eyes must be in front of the camera (``e_x > 0``).
    """
    eyes = np.asarray(eyes_camera, dtype=np.float64).reshape(-1, 3)
    z = eyes / np.linalg.norm(eyes, axis=-1, keepdims=True)
    y = _UP - z[:, 2:3] * z
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


def gaze360_directions(yaw, pitch, eyes_camera) -> np.ndarray:
    """Gaze360 angles (radians, eye frame) and eye centres ``eyes_camera`` ``(M, 3)`` (our camera axes, as
    :func:`gaze360_eye_frame`) → unit gaze directions ``(M, 3)`` in our camera frame: ``spherical2cartesial`` (``g_E = (cos p sin y, sin p, −cos p cos y)``), then :func:`gaze360_eye_frame`."""
    yaw = np.asarray(yaw, dtype=np.float64).reshape(-1)
    pitch = np.asarray(pitch, dtype=np.float64).reshape(-1)
    g = np.stack([np.cos(pitch) * np.sin(yaw), np.sin(pitch), -np.cos(pitch) * np.cos(yaw)], axis=-1)
    return np.einsum("mij,mj->mi", gaze360_eye_frame(eyes_camera), g)


def gaze360_angles(directions_camera, eyes_camera) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`gaze360_directions`: ``(yaw, pitch)`` with ``yaw = atan2(g_x, −g_z)``
    and ``pitch = asin(g_y)`` (as Gaze360's data_loader.py), ``g`` the unit direction in the eye frame."""
    d = np.asarray(directions_camera, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    g = np.einsum("mji,mj->mi", gaze360_eye_frame(eyes_camera), d)
    return np.arctan2(g[:, 0], -g[:, 2]), np.arcsin(np.clip(g[:, 1], -1.0, 1.0))


# ---------------------------------------------------------------------------
# The bandwidth


def bandwidth_from_gaze360_var(var) -> tuple[np.ndarray, np.ndarray]:
    """Gaze360's ``var`` (radians) → ``(h, clipped)``: ``h = tan(R_90 var/Z_90) / R_90``, at most
    :data:`MAX_BANDWIDTH_GAZE360` (``clipped`` marks the rays cut there). See the module docstring."""
    var = np.asarray(var, dtype=np.float64)
    angle_90 = R_90 * var / Z_90
    limit = math.atan(R_90 * MAX_BANDWIDTH_GAZE360)
    clipped = angle_90 > limit * (1.0 + 1e-9)
    return np.minimum(np.tan(np.minimum(angle_90, limit)) / R_90, MAX_BANDWIDTH_GAZE360), clipped


def gaze360_var_from_bandwidth(h) -> np.ndarray:
    """The inverse of :func:`bandwidth_from_gaze360_var`: ``var = Z_90 atan(R_90 h) / R_90``."""
    return Z_90 * np.arctan(R_90 * np.asarray(h, dtype=np.float64)) / R_90


# ---------------------------------------------------------------------------
# Arrays → rays


def _fail(message: str, path, lines, i: int) -> InputFileError:
    """The error for row ``i``: at its file line, or, for arrays, naming the row."""
    if lines is None:
        return InputFileError(f"row {i}: {message}", path)
    return InputFileError(message, path, int(lines[i]))


def check_rows(columns: dict, eyes_camera: np.ndarray, path, lines, *, limits: dict, axes: str) -> None:
    """Raise :class:`InputFileError` at the first bad row: a non-finite value, an angle outside
    ``limits`` (``{name: bound}``: ``|angle| ≤ bound``, radians) or eyes (in our axes) implausible for
    input given in ``axes`` (``"ours"``: the arrays; ``"opencv"``: the dump CSV): behind the camera, or
    most of them out of its view (:func:`~jaxgaze.io.tools.common.eye_axes_problem`, the message naming
    the convention and the swap). Shared with the L2CS-Net adapter."""
    for name, values in list(columns.items()) + [("eye centre", eyes_camera)]:
        bad = ~np.isfinite(values).reshape(len(values), -1).all(axis=-1)
        if bad.any():
            raise _fail(f"{name} is not finite", path, lines, int(np.argmax(bad)))
    for name, bound in limits.items():
        bad = np.abs(columns[name]) > bound + _ANGLE_SLACK
        if bad.any():
            i = int(np.argmax(bad))
            raise _fail(f"{name} {columns[name][i]:g} is outside [−{bound:.4g}, {bound:.4g}]: the angles are "
                        "radians (degrees?)", path, lines, i)
    problem = eye_axes_problem(eyes_camera, axes)
    if problem is not None:
        raise _fail(problem[1], path, lines, problem[0])


def check_unique(frames, persons, places) -> None:
    """Raise :class:`InputFileError` at the second row of a duplicate (frame, person);
    ``places[i] = (path, line or None)``."""
    seen: dict = {}
    for i, key in enumerate(zip(frames, persons)):
        first = seen.setdefault(key, i)
        if first != i:
            path, line = places[i]
            where = places[first][0] if places[first][0] != path else "this file"
            first_line = places[first][1]
            at = f"line {first_line}" if first_line is not None else f"row {first}"
            message = f"duplicate ray for frame {key[0]}, person '{key[1]}' (first at {at} of {where})"
            raise InputFileError(message if line is not None else f"row {i}: {message}", path, line)


def default_rows(count: int, frames, persons) -> tuple[np.ndarray, list]:
    """``frames`` (default ``0 … M−1``) and ``persons`` (default ``"0"``) of ``count`` rows, checked."""
    frames = np.arange(count) if frames is None else np.asarray(frames).reshape(-1)
    persons = ["0"] * count if persons is None else [str(p) for p in np.asarray(persons, dtype=object).reshape(-1)]
    if len(frames) != count or len(persons) != count:
        raise ValueError(f"{count} rays but {len(frames)} frames and {len(persons)} persons")
    if not np.issubdtype(frames.dtype, np.integer):
        if not (np.isfinite(frames.astype(float)).all() and (frames.astype(float) % 1 == 0).all()):
            raise ValueError("frames must be integers")
    return frames.astype(np.int64), persons


def _columns(*arrays, names):
    out = [np.asarray(a, dtype=np.float64).reshape(-1) for a in arrays]
    if len({len(a) for a in out}) != 1:
        raise ValueError(", ".join(names) + " must have one value per ray, got lengths "
                         + ", ".join(str(len(a)) for a in out))
    return out


def _eyes(eyes_camera, count: int) -> np.ndarray:
    eyes = np.asarray(eyes_camera, dtype=np.float64)
    if eyes.shape != (count, 3):
        raise ValueError(f"eyes_camera must be ({count}, 3) (one eye centre per ray), got {eyes.shape}")
    return eyes


def _check_var(var, path, lines) -> None:
    bad = ~(var > 0)
    if bad.any():
        i = int(np.argmax(bad))
        raise _fail(f"var must be positive (radians), got {var[i]:g}", path, lines, i)
    bad = var > math.pi + _ANGLE_SLACK
    if bad.any():
        i = int(np.argmax(bad))
        raise _fail(f"var {var[i]:g} is beyond π: Gaze360's var is π·sigmoid, in radians (degrees?)", path, lines, i)


def _bandwidth_warned(var, where: str) -> np.ndarray:
    h, clipped = bandwidth_from_gaze360_var(var)
    if clipped.any():
        warnings.warn(f"{where}: {int(clipped.sum())} of {len(var)} Gaze360 rays have var above "
                      f"{gaze360_var_from_bandwidth(MAX_BANDWIDTH_GAZE360):.3f} rad "
                      f"({math.degrees(gaze360_var_from_bandwidth(MAX_BANDWIDTH_GAZE360)):.0f}°): their bandwidth is clipped "
                      f"to {MAX_BANDWIDTH_GAZE360} rad", stacklevel=3)
    return h


def gaze360_to_rays(yaw, pitch, var, eyes_camera, *, frames: Optional[Sequence[int]] = None,
                    persons: Optional[Sequence[str]] = None, camera: Optional[CameraPoses] = None) -> RayRecording:
    """Gaze360 outputs as arrays → a world :class:`~jaxgaze.io.rays.RayRecording` (Kellnhofer et al. 2019).

    ``yaw``, ``pitch``, ``var`` ``(M,)`` as ``GazeLSTM`` returns them (radians, eye frame);
    ``eyes_camera`` ``(M, 3)`` the mid-eye points in **our** camera axes (origin the camera centre,
    +x along the optical axis, +y left, +z up), metres. These are *not* the OpenCV axes (x right,
    y down, z forward) of Gaze360's ``person_eyes3d`` and of the dump CSV: turn those into ours with
    ``eyes_opencv @ R_OURS_FROM_OPENCV.T`` (:data:`jaxgaze.geometry.R_OURS_FROM_OPENCV`), as
    :func:`read_gaze360` does. ``frames`` (default ``0 … M−1``) and ``persons`` (default ``"0"``) per ray;
    ``camera`` places the camera in a world (default: the world is the camera frame). Directions
    by :func:`gaze360_directions`, bandwidth by :func:`bandwidth_from_gaze360_var` (a warning
    names the rays clipped). Bad values raise :class:`InputFileError` naming the row.
    """
    yaw, pitch, var = _columns(yaw, pitch, var, names=("yaw", "pitch", "var"))
    eyes = _eyes(eyes_camera, len(yaw))
    frames, persons = default_rows(len(yaw), frames, persons)
    check_rows({"yaw": yaw, "pitch": pitch, "var": var}, eyes, _ARRAYS, None,
               limits={"yaw": math.pi, "pitch": math.pi / 2}, axes="ours")
    _check_var(var, _ARRAYS, None)
    check_unique(frames, persons, [(_ARRAYS, None)] * len(frames))
    h = _bandwidth_warned(var, _ARRAYS)
    return rays_from_camera(frames, persons, eyes, gaze360_directions(yaw, pitch, eyes), h, camera=camera,
                            path=_ARRAYS)


# ---------------------------------------------------------------------------
# The dump CSV


def as_paths(paths) -> list:
    """One path or a sequence of paths → a non-empty list of paths."""
    if isinstance(paths, (str, bytes, os.PathLike)):
        return [paths]
    paths = list(paths)
    if not paths:
        raise ValueError("no input files given")
    return paths


def read_dump(paths, columns: Sequence[str], person_column: str, number_columns: Sequence[str],
              eye_columns: Sequence[str]):
    """Rows of dump CSVs → ``(frames, persons, numbers {name: (M,)}, eyes_camera (M, 3), places)``.

    Eye columns are OpenCV camera coordinates, returned in our camera frame
    (``R_OURS_FROM_OPENCV``); ``places[i] = (path, line)``. Shared with the L2CS-Net adapter.
    """
    frames, persons, places, eyes = [], [], [], []
    numbers: dict = {name: [] for name in number_columns}
    for path in as_paths(paths):
        table = read_csv_table(path, columns, empty="input is empty: expected a header row with columns "
                               + ", ".join(columns), empty_at_end=True)
        for row in table.rows:
            frames.append(row.integer("frame"))
            persons.append(row.text(person_column))
            for name in number_columns:
                numbers[name].append(row.number(name))
            eyes.append([row.number(c) for c in eye_columns])
            places.append((table.path, row.line))
    eyes_camera = np.asarray(eyes, dtype=np.float64).reshape(-1, 3) @ R_OURS_FROM_OPENCV.T
    return (np.asarray(frames, dtype=np.int64), persons, {k: np.asarray(v, dtype=np.float64) for k, v in numbers.items()},
            eyes_camera, places)


def validate_by_file(places, check) -> None:
    """Run ``check(path, lines, rows)`` on each file's rows (``rows`` an index array) so that errors
    name the right file and line."""
    paths = [p for p, _ in places]
    for path in dict.fromkeys(paths):
        rows = np.flatnonzero(np.asarray([p == path for p in paths]))
        check(path, np.asarray([places[i][1] for i in rows]), rows)


def read_gaze360(paths, *, camera: Optional[CameraPoses] = None) -> RayRecording:
    """Read Gaze360 dump CSVs (:data:`GAZE360_COLUMNS`, see the module docstring) into world rays.

    One path or several (rows of one recording). Raises :class:`InputFileError` naming the file
    and line for a missing column, an empty or non-numeric cell, NaN, an angle out of Gaze360's
    range (degrees?), ``var ≤ 0`` or beyond π, eyes not in front of the camera, or a duplicate
    (frame, person_identity); warns when bandwidths are clipped.
    """
    frames, persons, numbers, eyes, places = read_dump(
        paths, GAZE360_COLUMNS, "person_identity", ("yaw", "pitch", "var"), GAZE360_COLUMNS[5:])
    yaw, pitch, var = numbers["yaw"], numbers["pitch"], numbers["var"]

    def check(path, lines, rows):
        check_rows({"yaw": yaw[rows], "pitch": pitch[rows], "var": var[rows]}, eyes[rows], path, lines,
                   limits={"yaw": math.pi, "pitch": math.pi / 2}, axes="opencv")
        _check_var(var[rows], path, lines)

    validate_by_file(places, check)
    check_unique(frames, persons, places)
    where = places[0][0] if len({p for p, _ in places}) == 1 else f"{places[0][0]} and the other files"
    h = _bandwidth_warned(var, where)
    return rays_from_camera(frames, persons, eyes, gaze360_directions(yaw, pitch, eyes), h, camera=camera,
                            path=places[0][0])


def recording_rows(recording: RayRecording, camera: Optional[CameraPoses]):
    """The real rays of a recording in our camera frame: ``(frames, persons, eyes, directions, h)``.
    Eyes must be in front of the camera (a ``ValueError`` names the first that is not)."""
    mask = np.asarray(recording.rays.mask)
    t, n = np.nonzero(mask)
    frames = np.asarray(recording.frame_ids, dtype=np.int64)[t]
    persons = [recording.persons[i][j] for i, j in zip(t, n)]
    eyes, directions = world_rays_to_camera(frames, recording.world_origins()[t, n],
                                            np.asarray(recording.rays.directions, dtype=np.float64)[t, n], camera)
    behind = ~(eyes[:, 0] > 0)
    if behind.any():
        i = int(np.argmax(behind))
        raise ValueError(f"the eyes of person '{persons[i]}' in frame {frames[i]} are not in front of the camera: "
                         "a camera-based tool sees only people in front of it")
    return frames, persons, eyes, directions, np.asarray(recording.rays.bandwidth, dtype=np.float64)[t, n]


def write_gaze360(path, recording: RayRecording, *, camera: Optional[CameraPoses] = None) -> int:
    """Write rays as a Gaze360 dump CSV (atomically); returns the number of rows.

    The inverse of :func:`read_gaze360`: eyes and directions into the camera frame (``camera``,
    default: the world is the camera frame), angles by :func:`gaze360_angles`, ``var`` by
    :func:`gaze360_var_from_bandwidth` (bandwidths above :data:`MAX_BANDWIDTH_GAZE360` read back clipped).
    """
    frames, persons, eyes, directions, h = recording_rows(recording, camera)
    yaw, pitch = gaze360_angles(directions, eyes)
    var = gaze360_var_from_bandwidth(h)
    eyes_opencv = eyes @ R_OURS_FROM_OPENCV  # rows: R_OURS_FROM_OPENCV.T @ e
    rows = ([int(frames[i]), persons[i], format_float(yaw[i]), format_float(pitch[i]), format_float(var[i]),
             *map(format_float, eyes_opencv[i])] for i in range(len(frames)))
    return write_csv_rows(path, GAZE360_COLUMNS, rows)
