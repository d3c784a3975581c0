"""Pupil Labs gaze → world-frame gaze rays: Pupil Core exports (``gaze_positions.csv``) and Neon
exports (``gaze.csv``).

**Pupil Core.** Pupil Player's raw data exporter (``Gaze_Positions_Exporter`` in
``raw_data_exporter.py``) writes one row per gaze datum with the columns :data:`PUPIL_COLUMNS`.
The 3D fields (``gaze_point_3d_*``, ``eye_center{0,1}_3d_*``, ``gaze_normal{0,1}_*``) are in the
world (scene) camera's 3D camera space, which is OpenCV's (x right, y down, z forward; Pupil docs,
"Terminology / Coordinate System"), in millimetres (developer docs, "Gaze Datum Format"). Eye 0 is
the wearer's right eye, eye 1 the left. A monocular datum fills one eye's columns; a 2D-mapper
datum leaves every 3D cell empty. The ray of a datum:

* origin: the midpoint of the eye centres present (one eye: its centre), converted to metres;
* direction: the normalised mean of the unit gaze normals present (the visual axes). Averaging
  the normals treats the two visual axes as parallel, which holds beyond a metre; the binocular
  ``gaze_point_3d`` is their vergence point, whose depth is poor beyond a metre, so it is used
  only when no normal is present (direction ``gaze_point_3d − origin``, origin the scene camera
  when no eye centre is present either).

Both are rotated into our camera axes by :data:`~jaxgaze.geometry.R_OURS_FROM_OPENCV`
(+x forward, +y left, +z up). Rows with ``confidence`` below ``min_confidence`` (Pupil Player's
own default ``min_data_confidence = 0.6``) and rows without 3D data are dropped. Frames come from
``gaze_timestamp`` (Pupil time, seconds) on the time grid of :func:`rays_on_time_grid`, by default at
the stream's own rate, so every datum keeps its own frame; ``camera=`` poses are looked up by each
datum's ``world_index`` (the scene video frame the exporter matched it to). Pupil reports no per-datum angular uncertainty
(``confidence`` grades the pupil detection), so every ray gets :data:`DEFAULT_BANDWIDTH_PUPIL`.

**Neon.** Pupil Cloud's timeseries export and Neon Player write ``gaze.csv`` (:data:`NEON_COLUMNS`):
``azimuth [deg]`` and ``elevation [deg]`` of the gaze ray in the scene camera, from Pupil Labs'
``cart_to_spherical`` on the undistorted, unprojected gaze point (x right, y down, z forward):
``elevation = arccos(y/r) − π/2`` (positive up) and ``azimuth = π/2 − atan2(z, x)`` (positive to
the wearer's right). So the direction is
``(x, y, z)_OpenCV = (cos el sin az, −sin el, cos el cos az)``, i.e. in our camera axes yaw
``= −azimuth`` and pitch ``= elevation`` (:func:`neon_angles_to_direction`). Neon gives no gaze
origin: the ray starts at the scene camera (the module's centre, between the eyes). Samples with
``worn`` 0 or a ``blink id`` are dropped (counted in a warning). Timestamps are UTC nanoseconds,
shared by several Neons, so frames come from one time grid. Bandwidth :data:`DEFAULT_BANDWIDTH_NEON`.
A native Neon recording folder needs ``pupil-labs-neon-recording`` (``pip install 'jaxgaze[neon]'``,
:func:`read_neon_recording`, which also drops the samples its ``worn`` and ``blinks`` streams mark);
the CSV path does not.

**Time grid and counts** (both tools, and :mod:`~jaxgaze.io.tools.aria`): ``frame = round((t − start_ns)
· fps / 1e9)`` with ``start_ns`` the earliest kept sample of the files and ``fps`` by default the
highest of the streams' own rates (``1e9 / median Δt``, :func:`native_fps`), so each sample keeps its
own frame; a frame with several samples of one wearer keeps the one nearest its time. An explicit
``fps`` resamples (several wearers on one clock). Every sample dropped, by the reader's filters or by
the grid, is counted per wearer in one warning and in ``RayRecording.sampling``
(:func:`rays_on_time_grid`).

**Several wearers** are several files: the person names come from ``persons`` or, by default, from
each file's name (its recording folder's when the file keeps the tool's own name: ``ann`` for
Pupil Player's ``ann/exports/000/gaze_positions.csv``; :func:`wearer_names`); each file's rays
are in its own scene camera frame, so several files need ``camera``: one
:class:`~jaxgaze.poses.CameraPoses` per wearer (a sequence in file order, or a dict by person)
placing that wearer's scene camera in the shared world (frame ids = the files' frames).
Errors are :class:`~jaxgaze.io.text.InputFileError` naming the file and line.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Mapping, NamedTuple, Optional, Sequence, Union

import cv2
import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.common import (
    bandwidth_from_mean_angular_error,
    camera_rays_to_world,
    require_extra,
    tool_bandwidth,
    world_rays_to_camera,
)
from jaxgaze.io.rays import RayRecording, Sampling, stack_rays
from jaxgaze.io.text import InputFileError, format_float, read_csv_table, read_text, write_csv_rows
from jaxgaze.poses import CameraPoses

__all__ = [
    "PUPIL_COLUMNS",
    "NEON_COLUMNS",
    "MIN_CONFIDENCE",
    "DEFAULT_BANDWIDTH_PUPIL",
    "DEFAULT_BANDWIDTH_NEON",
    "NEON_FPS",
    "neon_angles_to_direction",
    "direction_to_neon_angles",
    "read_pupil",
    "write_pupil",
    "read_neon",
    "write_neon",
    "read_neon_recording",
    "read_pupil_labs",
]

#: The header of Pupil Player's ``gaze_positions.csv`` (``Gaze_Positions_Exporter.csv_export_labels``).
PUPIL_COLUMNS = (
    "gaze_timestamp", "world_index", "confidence", "norm_pos_x", "norm_pos_y", "base_data",
    "gaze_point_3d_x", "gaze_point_3d_y", "gaze_point_3d_z",
    "eye_center0_3d_x", "eye_center0_3d_y", "eye_center0_3d_z",
    "gaze_normal0_x", "gaze_normal0_y", "gaze_normal0_z",
    "eye_center1_3d_x", "eye_center1_3d_y", "eye_center1_3d_z",
    "gaze_normal1_x", "gaze_normal1_y", "gaze_normal1_z",
)
#: The header of Neon's ``gaze.csv`` (Pupil Cloud "Timeseries Data" export).
NEON_COLUMNS = (
    "section id", "recording id", "timestamp [ns]", "gaze x [px]", "gaze y [px]", "worn",
    "fixation id", "blink id", "azimuth [deg]", "elevation [deg]",
)
#: Pupil Player's default ``min_data_confidence``: "useful data carries a confidence greater than ~0.6".
MIN_CONFIDENCE = 0.6
#: Bandwidth ``h`` of a Pupil Core 3D-gaze ray: the 3D pipeline's ~1.0°–2.0° visual error under good
#: conditions (Pupil docs, "Best Practices: Choose the Right Gaze Mapping Pipeline"), taken as a mean
#: angular error of 1.5° (:func:`~jaxgaze.io.tools.common.bandwidth_from_mean_angular_error`): 0.0209 rad.
DEFAULT_BANDWIDTH_PUPIL = bandwidth_from_mean_angular_error(math.radians(1.5))
#: Bandwidth ``h`` of a Neon ray: its calibration-free mean angular error of about 1.8° (Pupil Labs'
#: Neon accuracy white paper, linked from the docs' "Data Streams: Gaze"): 0.0251 rad.
DEFAULT_BANDWIDTH_NEON = bandwidth_from_mean_angular_error(math.radians(1.8))
#: Neon's scene camera rate (Hz): the default frame grid of :func:`read_neon`.
NEON_FPS = 30.0

_PUPIL_REQUIRED = ("gaze_timestamp", "world_index", "confidence", "gaze_point_3d_x", "gaze_point_3d_y", "gaze_point_3d_z")
_EYE_COLUMNS = {eye: (tuple(f"eye_center{eye}_3d_{a}" for a in "xyz"), tuple(f"gaze_normal{eye}_{a}" for a in "xyz"))
                for eye in (0, 1)}
_NEON_REQUIRED = ("timestamp [ns]", "azimuth [deg]", "elevation [deg]")
_MM = 1e-3
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
#: Half the distance between the eye centres the writer puts on either side of the origin (mm).
_HALF_EYE_SEPARATION_MM = 31.5

Cameras = Union[None, CameraPoses, Sequence[CameraPoses], Mapping[str, CameraPoses]]


# ---------------------------------------------------------------------------
# Shared pieces


def wearer_names(paths: Sequence[str], persons: Optional[Sequence[str]], default_names: Sequence[str]) -> list[str]:
    """One person name per path: ``persons`` if given, else each file's stem, or, when the stem is one of
    the tool's ``default_names`` (``gaze_positions``, ``gaze``…), the name of its recording folder:
    the file's folder, or the folder above ``exports/NNN`` (Pupil Player's and Neon Player's export
    layout, ``<recording>/exports/000/`` and ``<recording>/neon_player/exports/000/``). Names that
    still clash (two recordings both named ``000``) are replaced by the nearest folder above them
    whose names differ (``ann/2024_05_01/000`` and ``ben/2024_05_01/000`` → ``ann``, ``ben``)."""
    if persons is not None:
        persons = [str(p) for p in persons]
        if len(persons) != len(paths):
            raise ValueError(f"persons has {len(persons)} names for {len(paths)} files")
        if not all(p.strip() for p in persons):
            raise ValueError(f"persons has an empty name: {persons}")
    else:
        chains = [_name_chain(path, default_names) for path in paths]
        persons = [chain[0] for chain in chains]
        for name in [p for p in dict.fromkeys(persons) if persons.count(p) > 1]:
            clashing = [i for i, p in enumerate(persons) if p == name]
            for level in range(1, max(len(chains[i]) for i in clashing)):
                above = [chains[i][level] if level < len(chains[i]) else None for i in clashing]
                if None not in above and len(set(above)) == len(above):
                    for i, folder in zip(clashing, above):
                        persons[i] = folder
                    break
    twice = [p for p in dict.fromkeys(persons) if persons.count(p) > 1]
    if twice:
        raise ValueError(f"two files give the person name '{twice[0]}': pass persons=[...], one name per file")
    return persons


def _name_chain(path, default_names: Sequence[str]) -> list[str]:
    """A file's default person name (:func:`wearer_names`), then the folders above its recording folder, nearest first."""
    full = os.path.abspath(os.fspath(path))
    stem = os.path.splitext(os.path.basename(full))[0]
    folders = [f for f in os.path.dirname(full).split(os.sep) if f][::-1]  # nearest first
    if stem and stem not in default_names:
        return [stem] + folders
    if len(folders) > 2 and folders[0].isdigit() and folders[1] == "exports":  # <recording>/exports/000/
        folders = folders[3:] if folders[2] == "neon_player" and len(folders) > 3 else folders[2:]
    return folders or [stem]


def as_paths(paths) -> list[str]:
    """One path or a sequence of paths → a list of paths (at least one)."""
    if isinstance(paths, (str, os.PathLike)):
        return [os.fspath(paths)]
    paths = [os.fspath(p) for p in paths]
    if not paths:
        raise ValueError("no input files given")
    return paths


def camera_of(camera: Cameras, index: int, person: str, count: int) -> Optional[CameraPoses]:
    """The :class:`CameraPoses` of file ``index`` (``person``) among ``count`` files, from ``camera``:
    ``None``, one ``CameraPoses`` (one file only), a sequence in file order or a dict by person."""
    if camera is None:
        if count > 1:
            raise ValueError(f"{count} wearers' files, but no camera=: each file's rays are in its own wearer's "
                             "frame; pass camera= with one CameraPoses per wearer (a list in file order or a "
                             "dict by person) to place them in one world")
        return None
    if isinstance(camera, CameraPoses):
        if count > 1:
            raise ValueError(f"one CameraPoses for {count} wearers' files: pass one per wearer")
        return camera
    if isinstance(camera, Mapping):
        if person not in camera:
            raise ValueError(f"camera= has no CameraPoses for person '{person}'")
        return camera[person]
    camera = list(camera)
    if len(camera) != count:
        raise ValueError(f"camera= has {len(camera)} CameraPoses for {count} files")
    return camera[index]


def keep_one_per_frame(frames: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Indices of the rows to keep: in each frame the row of highest ``score`` (the first of equals),
    in row order."""
    frames = np.asarray(frames)
    order = np.lexsort((np.arange(len(frames)), -np.asarray(score, dtype=float), frames))
    first = np.ones(len(order), dtype=bool)
    first[1:] = frames[order][1:] != frames[order][:-1]
    return np.sort(order[first])


def _ours_from_opencv(vectors) -> np.ndarray:
    return np.asarray(vectors, dtype=np.float64) @ R_OURS_FROM_OPENCV.T


def _opencv_from_ours(vectors) -> np.ndarray:
    return np.asarray(vectors, dtype=np.float64) @ R_OURS_FROM_OPENCV


def person_rays(recording: RayRecording, person: Optional[str], path):
    """Frames, origins, directions and bandwidths of one person's rays in a recording (of its only
    person if ``person`` is None; ``path`` is the file about to be written, for the message)."""
    names = sorted({p for frame in recording.persons for p in frame})
    if person is None:
        if len(names) != 1:
            raise ValueError(f"the recording has {len(names)} persons {names}: pass person= to write one of them "
                             f"to {path}")
        person = names[0]
    mask = np.asarray(recording.rays.mask)
    origins, directions = recording.world_origins(), np.asarray(recording.rays.directions)
    bandwidth = np.asarray(recording.rays.bandwidth)
    rows = [(int(frame), t, n) for t, (frame, persons) in enumerate(zip(recording.frame_ids, recording.persons))
            for n, name in enumerate(persons) if name == person and mask[t, n]]
    if not rows:
        raise ValueError(f"the recording has no rays of person '{person}'")
    frames, t, n = (np.asarray(column) for column in zip(*rows))
    return (frames.astype(np.int64), origins[t, n].astype(np.float64), directions[t, n].astype(np.float64),
            bandwidth[t, n].astype(np.float64))


# ---------------------------------------------------------------------------
# Pupil Core


def _optional_vector(row, columns):
    """The three cells of ``columns`` as a vector, or None when all are empty (an error when some are)."""
    cells = [row.cell(c) for c in columns]
    if not any(cells):
        return None
    if not all(cells):
        raise row.error(f"partly empty 3D vector: columns {', '.join(columns)} hold {cells}")
    return np.array([row.number(c) for c in columns])


def _pupil_table(path, min_confidence: float):
    """The rows of one ``gaze_positions.csv`` kept as rays: path, times (ns), ``world_index``, origins and
    directions in our camera frame (metres, unit), the rows read and the drops of the confidence and
    3D filters (:class:`TimedRays`)."""
    optional = tuple(c for eye in (0, 1) for group in _EYE_COLUMNS[eye] for c in group)
    table = read_csv_table(path, _PUPIL_REQUIRED, optional,
                           hint="a Pupil Player gaze_positions.csv export with 3D gaze (columns "
                                + ", ".join(_PUPIL_REQUIRED) + ")")
    if not 0.0 <= min_confidence <= 1.0:
        raise ValueError(f"min_confidence must be in [0, 1], got {min_confidence!r}")
    times, frames, origins, directions, all_times = [], [], [], [], []
    low, flat = 0, 0
    for row in table.rows:
        time = row.number("gaze_timestamp")
        all_times.append(time)
        c = row.number("confidence")
        if not 0.0 <= c <= 1.0:
            raise row.error(f"confidence must be in [0, 1], got {row.cell('confidence')}")
        frame = row.integer("world_index")
        point = _optional_vector(row, ("gaze_point_3d_x", "gaze_point_3d_y", "gaze_point_3d_z"))
        centers, normals = [], []
        for eye in (0, 1):
            center_columns, normal_columns = _EYE_COLUMNS[eye]
            center = _optional_vector(row, center_columns) if all(map(table.has, center_columns)) else None
            normal = _optional_vector(row, normal_columns) if all(map(table.has, normal_columns)) else None
            if center is not None:
                centers.append(center)
            if normal is not None:
                length = np.linalg.norm(normal)
                if length == 0:
                    raise row.error(f"gaze_normal{eye} has zero length")
                normals.append(normal / length)
        if c < min_confidence:
            low += 1
            continue
        if point is None and not normals:
            flat += 1
            continue
        origin = np.mean(centers, axis=0) if centers else np.zeros(3)
        direction = np.sum(normals, axis=0) if normals else point - origin
        if np.linalg.norm(direction) == 0:
            raise row.error("the gaze direction has zero length (gaze point at the eye centre, or opposite normals)")
        times.append(time)
        frames.append(frame)
        origins.append(origin * _MM)
        directions.append(direction / np.linalg.norm(direction))
    drops = (("filtered", low, f"of confidence < {min_confidence:g}"),
             ("filtered", flat, "without 3D gaze (2D gaze mapper?)"))
    times_ns = np.rint(np.asarray(times, dtype=np.float64) * 1e9).astype(np.int64)  # Pupil time: seconds
    rate = native_fps(np.rint(np.asarray(all_times, dtype=np.float64) * 1e9).astype(np.int64))
    return (table.path, times_ns, np.asarray(frames, np.int64), _ours_from_opencv(np.asarray(origins).reshape(-1, 3)),
            _ours_from_opencv(np.asarray(directions).reshape(-1, 3)), len(table.rows), drops, rate)


def read_pupil(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
               min_confidence: float = MIN_CONFIDENCE, bandwidth: float = DEFAULT_BANDWIDTH_PUPIL,
               fps: Optional[float] = None, start_ns: Optional[int] = None) -> RayRecording:
    """Pupil Core ``gaze_positions.csv`` exports (one per wearer) → a world :class:`RayRecording`.

    Origin: the midpoint of the eye centres; direction: the mean unit gaze normal (module docstring),
    both from the scene camera's OpenCV axes (mm) to ours (m), then to the world by ``camera``
    (``x_world = R_world_from_camera @ x_camera + center``, looked up by each datum's ``world_index``;
    without it the world is the one wearer's scene camera frame). Frames: ``round((t − start_ns) · fps
    / 1e9)`` of ``gaze_timestamp`` (``start_ns`` default the earliest kept datum, ``fps`` default the
    files' own rate, so each datum gets its own frame). Rows below ``min_confidence`` or without 3D
    data, and data sharing a frame with a nearer one, are dropped, counted in a warning and in
    ``sampling``. ``bandwidth``: every ray's ``h`` (radians).
    """
    paths = as_paths(paths)
    names = wearer_names(paths, persons, ("gaze_positions",))
    h = tool_bandwidth(bandwidth, "read_pupil")
    wearers = []
    for index, (path, person) in enumerate(zip(paths, names)):
        pose = camera_of(camera, index, person, len(paths))
        path, times, frames, origins, directions, read, drops, rate = _pupil_table(path, min_confidence)
        wearers.append(TimedRays(path, person, times, origins, directions, np.full(len(times), h), None, pose, read,
                                 drops, pose_frames=frames, rate=rate))
    return rays_on_time_grid(wearers, fps=grid_fps(fps, wearers, NEON_FPS), start_ns=start_ns,
                             path=paths[0] if len(paths) == 1 else ", ".join(paths))


def write_pupil(path, recording: RayRecording, *, person: Optional[str] = None, camera: Optional[CameraPoses] = None,
                timestamps=None) -> int:
    """Write one person's rays as a Pupil Player ``gaze_positions.csv`` (binocular 3D gaze), atomically;
    returns the number of rows.

    The inverse of :func:`read_pupil`: world → scene camera (``camera``) → OpenCV axes, millimetres.
    Both eye centres sit ±31.5 mm along the camera's x axis around the origin (eye 0, the right eye,
    on +x), both gaze normals are the direction, ``gaze_point_3d`` is 1 m along it; ``confidence`` is
    1. ``gaze_timestamp`` is ``timestamps`` (seconds, one per frame), else the frame's time on the
    recording's grid (``(start_ns + frame · 1e9 / fps) / 1e9`` from ``recording.sampling``), else ``frame /
    30``; reading it back with that ``sampling``'s ``fps`` and ``start_ns`` gives the same frames. ``norm_pos``
    and ``base_data`` are left empty (they need the camera intrinsics and the pupil data).
    """
    frames, origins, directions, _ = person_rays(recording, person, path)
    origins, directions = world_rays_to_camera(frames, origins, directions, camera, path=path)
    origins_mm = _opencv_from_ours(origins) / _MM
    directions = _opencv_from_ours(directions)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    grid = recording.sampling
    if timestamps is not None:
        times = np.asarray(timestamps, dtype=float).reshape(-1)
    elif grid is not None:
        times = (grid.start_ns + frames * (1e9 / grid.fps)) / 1e9
    else:
        times = frames / 30.0
    if len(times) != len(frames):
        raise ValueError(f"timestamps has {len(times)} values for {len(frames)} frames")
    offset = np.array([_HALF_EYE_SEPARATION_MM, 0.0, 0.0])
    rows = []
    for frame, time, origin, direction in zip(frames, times, origins_mm, directions):
        point = origin + 1000.0 * direction
        rows.append([format_float(time), int(frame), "1.0", "", "", "", *map(format_float, point),
                     *map(format_float, origin + offset), *map(format_float, direction),
                     *map(format_float, origin - offset), *map(format_float, direction)])
    return write_csv_rows(path, PUPIL_COLUMNS, rows)


# ---------------------------------------------------------------------------
# Neon


def neon_angles_to_direction(azimuth_deg, elevation_deg) -> np.ndarray:
    """Neon's ``azimuth [deg]`` (positive right) and ``elevation [deg]`` (positive up) → unit
    directions ``(..., 3)`` in our camera frame: yaw ``= −azimuth``, pitch ``= elevation``.

    The inverse of Pupil Labs' ``cart_to_spherical``: ``(x, y, z)_OpenCV = (cos el sin az, −sin el,
    cos el cos az)``, i.e. ``(cos el cos az, −cos el sin az, sin el)`` in ours.
    """
    az = np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    el = np.radians(np.asarray(elevation_deg, dtype=np.float64))
    return np.stack([np.cos(el) * np.cos(az), -np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


def direction_to_neon_angles(directions) -> tuple[np.ndarray, np.ndarray]:
    """Directions ``(..., 3)`` in our camera frame → ``(azimuth_deg, elevation_deg)`` as Pupil Labs'
    ``cart_to_spherical`` computes them from the OpenCV vector ``(x, y, z)``:
    ``azimuth = π/2 − atan2(z, x)``, ``elevation = arccos(y / r) − π/2``."""
    v = _opencv_from_ours(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
    r = np.linalg.norm(v, axis=1)
    azimuth = np.pi / 2 - np.arctan2(v[:, 2], v[:, 0])
    azimuth = (azimuth + np.pi) % (2 * np.pi) - np.pi  # the same direction, in (−180°, 180°]
    elevation = np.arccos(np.clip(v[:, 1] / r, -1.0, 1.0)) - np.pi / 2
    shape = np.shape(directions)[:-1]
    return np.degrees(azimuth).reshape(shape), np.degrees(elevation).reshape(shape)


def _neon_table(path):
    """Times (ns) and our-camera directions of the kept samples of one Neon ``gaze.csv``."""
    table = read_csv_table(path, _NEON_REQUIRED, ("worn", "blink id"),
                           hint="a Neon gaze.csv export (columns " + ", ".join(_NEON_REQUIRED) + ")")
    times, azimuth, elevation, all_times = [], [], [], []
    not_worn, blink = 0, 0
    for row in table.rows:
        time = row.integer("timestamp [ns]")
        all_times.append(time)
        az, el = row.number("azimuth [deg]"), row.number("elevation [deg]")
        if not (-180.0 <= az <= 180.0 and -90.0 <= el <= 90.0):
            raise row.error(f"azimuth {az:g}°, elevation {el:g}° out of range (azimuth in [−180, 180], "
                            "elevation in [−90, 90] degrees)")
        if table.has("worn") and row.cell("worn") and row.number("worn") == 0:
            not_worn += 1
            continue
        if table.has("blink id") and row.cell("blink id"):
            blink += 1
            continue
        times.append(time)
        azimuth.append(az)
        elevation.append(el)
    drops = (("filtered", not_worn, "not worn (worn = 0)"), ("filtered", blink, "in a blink"))
    return (table.path, np.asarray(times, np.int64), neon_angles_to_direction(azimuth, elevation).reshape(-1, 3),
            len(table.rows), drops, native_fps(all_times))


def frames_on_grid(times_ns: np.ndarray, start_ns: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``frame = round((t − start_ns) · fps / 1e9)`` and the rows to keep: in each frame the sample
    nearest the frame's time (the first of equals)."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    exact = (np.asarray(times_ns, dtype=np.int64) - np.int64(start_ns)).astype(np.float64) * (fps / 1e9)
    frames = np.rint(exact).astype(np.int64)
    return frames, keep_one_per_frame(frames, -np.abs(exact - frames))


def native_fps(times_ns) -> Optional[float]:
    """A stream's own rate: ``1e9 / median Δt`` of its sorted sample times (ns); None for fewer than two
    distinct times."""
    steps = np.diff(np.sort(np.asarray(times_ns, np.int64)))
    steps = steps[steps > 0]
    return 1e9 / float(np.median(steps)) if len(steps) else None


class TimedRays(NamedTuple):
    """One wearer's samples before the time grid (:func:`rays_on_time_grid`): ``times_ns`` on the shared
    clock, ``origins``/``directions`` ``(M, 3)`` in the frame ``camera`` places in the world (``None``: as
    they are), ``bandwidth`` ``(M,)``, ``depth`` ``(M,)`` or None. ``pose_frames``: the frame ids to look
    the poses up by (Pupil Core's ``world_index``; None: the grid's frames). ``read``: the samples read
    before the reader's own drops, ``drops``: those drops as ``(Sampling field, count, why)``; ``rate``: the
    stream's own rate (Hz) from all the samples read (:func:`native_fps`; None: from ``times_ns``)."""

    path: str
    person: str
    times_ns: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    bandwidth: np.ndarray
    depth: Optional[np.ndarray]
    camera: Optional[CameraPoses]
    read: int
    drops: tuple = ()
    pose_frames: Optional[np.ndarray] = None
    rate: Optional[float] = None
    depth_sd: Optional[np.ndarray] = None


def grid_fps(fps: Optional[float], wearers: Sequence[TimedRays], default: float) -> float:
    """The time grid's rate: ``fps`` when given, else the highest native rate of the wearers' streams
    (:func:`native_fps`, so each sample gets its own frame), else ``default`` (single samples)."""
    if fps is not None:
        return float(fps)
    rates = [r for r in (native_fps(w.times_ns) if w.rate is None else w.rate for w in wearers) if r is not None]
    return max(rates, default=default)


def rays_on_time_grid(wearers: Sequence[TimedRays], *, fps: float, start_ns: Optional[int] = None,
                      rotation: Optional[np.ndarray] = None, path) -> RayRecording:
    """Wearers' timestamped samples → one world :class:`RayRecording` on the grid
    ``frame = round((t − start_ns) · fps / 1e9)`` (:func:`frames_on_grid`; ``start_ns`` default the earliest
    sample), each wearer's rays placed by its ``camera`` then turned by ``rotation`` (3×3, e.g. a y-up
    world onto z-up). A sample sharing its frame with a nearer one of the same wearer is merged away.
    Every drop, the reader's own and the grid's, is counted per wearer in one warning and in all in
    ``RayRecording.sampling`` (:class:`~jaxgaze.io.rays.Sampling`); a wearer with no sample left is an
    :class:`InputFileError`."""
    for wearer in wearers:
        if len(wearer.times_ns) == 0:
            why = ", ".join(f"{count} {text}" for _, count, text in wearer.drops if count)
            raise InputFileError(f"no gaze sample left of {wearer.read}" + (f" ({why})" if why else ""), wearer.path)
    if start_ns is None:
        start_ns = min(int(np.min(w.times_ns)) for w in wearers)
    counts = {"read": 0, "kept": 0, "outside": 0, "merged": 0, "filtered": 0}
    frames_all, persons, origins_all, directions_all, bandwidth_all, depth_all, sd_all = [], [], [], [], [], [], []
    for wearer in wearers:
        frames, keep = frames_on_grid(wearer.times_ns, start_ns, fps)
        merged = len(frames) - len(keep)
        drops = [*wearer.drops, ("merged", merged, f"sharing a frame of the {fps:.6g} fps grid with a nearer sample")]
        dropped = wearer.read - len(keep)
        if dropped:
            warnings.warn(f"{wearer.path}: dropped {dropped} of {wearer.read} gaze samples (kept {len(keep)}): "
                          + ", ".join(f"{count} {text}" for _, count, text in drops), stacklevel=3)
        frames = frames[keep]
        pose_frames = frames if wearer.pose_frames is None else np.asarray(wearer.pose_frames)[keep]
        origins, directions = camera_rays_to_world(pose_frames, wearer.origins[keep], wearer.directions[keep],
                                                   wearer.camera, path=wearer.path)
        if rotation is not None:
            origins, directions = origins @ rotation.T, directions @ rotation.T
        frames_all += frames.tolist()
        persons += [wearer.person] * len(frames)
        origins_all.append(origins)
        directions_all.append(directions)
        bandwidth_all.append(np.asarray(wearer.bandwidth, dtype=np.float64)[keep])
        depth_all.append(np.full(len(keep), np.nan) if wearer.depth is None else np.asarray(wearer.depth)[keep])
        sd_all.append(np.full(len(keep), np.nan) if wearer.depth_sd is None else np.asarray(wearer.depth_sd)[keep])
        counts["read"] += wearer.read
        counts["kept"] += len(keep)
        for field, count, _ in drops:
            counts[field] += count
    depth = None if all(w.depth is None for w in wearers) else np.concatenate(depth_all)
    depth_sd = None if depth is None or all(w.depth_sd is None for w in wearers) else np.concatenate(sd_all)
    recording = stack_rays(frames_all, persons, np.concatenate(origins_all), np.concatenate(directions_all),
                           np.concatenate(bandwidth_all), path=path, depth=depth, depth_sd=depth_sd)
    return recording._replace(sampling=Sampling(float(fps), int(start_ns), **counts))


def read_neon(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
              fps: Optional[float] = None, start_ns: Optional[int] = None,
              bandwidth: float = DEFAULT_BANDWIDTH_NEON) -> RayRecording:
    """Neon ``gaze.csv`` exports (one per wearer) → a world :class:`RayRecording`.

    Direction from ``azimuth [deg]`` / ``elevation [deg]`` (:func:`neon_angles_to_direction`), origin
    the scene camera, then to the world by ``camera`` (per frame; without it the world is the one
    wearer's scene camera frame). Frames: ``round((t − start_ns) · fps / 1e9)``, ``start_ns`` by
    default the earliest kept sample of all files, ``fps`` by default the files' own rate (each sample
    its own frame). Samples not worn or in a blink, and samples sharing a frame with a nearer one, are
    dropped, counted in a warning and in ``sampling``. ``bandwidth``: every ray's ``h`` (radians).
    """
    paths = as_paths(paths)
    names = wearer_names(paths, persons, ("gaze",))
    return _neon_rays([_neon_table(path) for path in paths], names, camera, start_ns, fps, tool_bandwidth(bandwidth, "read_neon"))


def _neon_rays(samples, names, camera, start_ns, fps, bandwidth) -> RayRecording:
    """Each wearer's ``(path, times_ns, scene-camera directions, rows read, drops, native rate)`` → one world
    :class:`RayRecording` on the time grid (:func:`rays_on_time_grid`), origin the scene camera, placed
    by ``camera`` (:func:`read_neon`, :func:`read_neon_recording`)."""
    paths = [sample[0] for sample in samples]
    wearers = [TimedRays(path, person, times, np.zeros_like(directions), directions,
                         np.full(len(times), float(bandwidth)), None, camera_of(camera, index, person, len(paths)),
                         read, drops, rate=rate)
               for index, ((path, times, directions, read, drops, rate), person) in enumerate(zip(samples, names))]
    return rays_on_time_grid(wearers, fps=grid_fps(fps, wearers, NEON_FPS), start_ns=start_ns,
                             path=paths[0] if len(paths) == 1 else ", ".join(paths))


def write_neon(path, recording: RayRecording, *, person: Optional[str] = None, camera: Optional[CameraPoses] = None,
               fps: Optional[float] = None, start_ns: Optional[int] = None) -> int:
    """Write one person's rays as a Neon ``gaze.csv``, atomically; returns the number of rows.

    The inverse of :func:`read_neon`: ``timestamp [ns] = start_ns + round(frame · 1e9 / fps)`` (both by
    default the recording's ``sampling``, else :data:`NEON_FPS` and 0),
    azimuth and elevation by :func:`direction_to_neon_angles`, ``worn`` 1, no fixation or blink;
    ``gaze x/y [px]`` are left empty (they need the scene camera's intrinsics). Neon has no gaze
    origin, so every ray must start at the scene camera (within 1 mm), else ``ValueError``.
    """
    frames, origins, directions, _ = person_rays(recording, person, path)
    origins, directions = world_rays_to_camera(frames, origins, directions, camera, path=path)
    off = np.linalg.norm(origins, axis=1)
    if off.max() > 1e-3:
        raise ValueError(f"Neon's gaze.csv holds no gaze origin, but the ray of frame {int(frames[np.argmax(off)])} "
                         f"starts {1000 * off.max():.0f} mm from the scene camera: pass the wearer's scene camera "
                         "poses as camera=")
    grid = recording.sampling
    fps = fps if fps is not None else grid.fps if grid is not None else NEON_FPS
    start_ns = start_ns if start_ns is not None else grid.start_ns if grid is not None else 0
    azimuth, elevation = direction_to_neon_angles(directions)
    rows = [["", "", int(start_ns + round(int(frame) * 1e9 / fps)), "", "", "1.0", "", "", format_float(az),
             format_float(el)] for frame, az, el in zip(frames, azimuth, elevation)]
    return write_csv_rows(path, NEON_COLUMNS, rows)


def read_neon_recording(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
                        fps: Optional[float] = None, start_ns: Optional[int] = None,
                        bandwidth: float = DEFAULT_BANDWIDTH_NEON) -> RayRecording:
    """Native Neon recording folders (one per wearer) → a world :class:`RayRecording`, through
    ``pupil-labs-neon-recording`` (``pip install 'jaxgaze[neon]'``; :class:`MissingExtraError` without it).

    The gaze stream (``gaze_200hz`` when the recording has it, else the real-time ``gaze ps*``: the
    library's ``recording.gaze``, ``time`` in UTC ns and ``point`` in scene pixels) is undistorted with
    the recording's scene camera intrinsics (``calibration.bin``) and unprojected (OpenCV), then follows
    :func:`read_neon` (``cart_to_spherical`` angles, time grid at the stream's own rate by default,
    camera poses). As :func:`read_neon` drops the rows of ``worn`` 0 or with a ``blink id``, samples the
    recording's ``worn`` stream marks not worn (0) or that fall within one of its ``blinks`` (``start_time``
    to ``stop_time``) are dropped; these drops and the time grid's merges are counted in a warning and in
    ``sampling``.
    """
    neon = require_extra("pupil_labs.neon_recording", "neon")
    paths = as_paths(paths)
    names = wearer_names(paths, persons, ())
    samples = []
    for path in paths:
        if not os.path.isdir(path):
            raise InputFileError("not a folder: a native Neon recording is the folder holding info.json and the "
                                 "gaze streams", path)
        recording = neon.open(path)
        gaze = recording.gaze
        times = np.asarray(gaze.time if hasattr(gaze, "time") else gaze.ts, dtype=np.int64)  # ns; renamed in 2.0
        points = np.asarray(gaze.point) if hasattr(gaze, "point") else np.stack([gaze.x, gaze.y], axis=-1)  # 2.0: point
        pixels = points.astype(np.float64).reshape(-1, 1, 2)
        calibration = recording.calibration
        if calibration is None:
            raise InputFileError("the recording has no scene camera calibration to unproject its gaze with", path)
        # iterated to convergence (OpenCV's default 5 iterations leave 0.01 px near the image's edge)
        undistorted = cv2.undistortPointsIter(pixels, np.asarray(calibration.scene_camera_matrix, dtype=np.float64),
                                              np.asarray(calibration.scene_distortion_coefficients, dtype=np.float64),
                                              None, None, _UNDISTORT_CRITERIA).reshape(-1, 2)
        rays_opencv = np.concatenate([undistorted, np.ones((len(undistorted), 1))], axis=1)
        directions = _ours_from_opencv(rays_opencv)
        not_worn, blink = _neon_native_drops(recording, times)
        keep = ~(not_worn | blink)
        drops = (("filtered", int(not_worn.sum()), "not worn (worn stream 0)"),
                 ("filtered", int((blink & ~not_worn).sum()), "in a blink (blinks stream)"))
        samples.append((os.fspath(path), times[keep],
                        (directions / np.linalg.norm(directions, axis=1, keepdims=True))[keep], len(times), drops,
                        native_fps(times)))
    return _neon_rays(samples, names, camera, start_ns, fps, tool_bandwidth(bandwidth, "read_neon_recording"))


def _neon_native_drops(recording, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the gaze samples at ``times`` (ns) that a native recording's ``worn`` stream marks not worn
    (value 0 at the same time) and that fall within one of its ``blinks`` (``start_time ≤ t ≤ stop_time``);
    all False for a stream the recording lacks (the library raises ``AttributeError``)."""
    try:
        worn = recording.worn
        off = np.asarray(worn.time, dtype=np.int64)[np.asarray(worn.worn) == 0]
    except AttributeError:
        off = np.empty(0, np.int64)
    try:
        blinks = recording.blinks
        starts, stops = np.asarray(blinks.start_time, np.int64), np.asarray(blinks.stop_time, np.int64)
    except AttributeError:
        starts = stops = np.empty(0, np.int64)
    blink = np.zeros(len(times), dtype=bool)
    for start, stop in zip(starts, stops):
        blink |= (times >= start) & (times <= stop)
    return np.isin(times, off), blink


def _is_neon(path) -> bool:
    """Whether a Pupil Labs CSV is Neon's export (its header names ``azimuth [deg]``), not Pupil Core's."""
    text = read_text(path)
    header = next((line for line in text.splitlines() if line.strip()), "")
    return "azimuth [deg]" in header.lower()


def read_pupil_labs(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
                    fps: Optional[float] = None, **options) -> RayRecording:
    """Pupil Core or Neon CSV exports, told apart by their header (Neon's names ``azimuth [deg]``), or
    native Neon recording folders (holding ``info.json``): :func:`read_neon`, :func:`read_pupil` or
    :func:`read_neon_recording`, with ``fps`` (default: the files' own rate) and the reader's own
    ``options`` (all: ``start_ns``, ``bandwidth``; Pupil Core: ``min_confidence``, which Neon refuses).
    Kinds mixed are an :class:`InputFileError`."""
    paths = as_paths(paths)
    folders = [os.path.isdir(path) for path in paths]
    if any(folders):
        if not all(folders):
            raise InputFileError("Neon recording folders and CSV exports mixed: convert them separately",
                                 paths[folders.index(False)])
        for path in paths:
            if not os.path.isfile(os.path.join(path, "info.json")):
                raise InputFileError("a folder, but no info.json in it: expected a native Neon recording folder "
                                     "(or pass the export's gaze.csv / gaze_positions.csv)", path)
        if "min_confidence" in options:
            raise ValueError("min_confidence= filters Pupil Core's gaze_positions.csv; Neon gaze has no confidence")
        return read_neon_recording(paths, camera=camera, persons=persons, fps=fps, **options)
    neon = [_is_neon(path) for path in paths]
    if any(neon) and not all(neon):
        raise InputFileError("Pupil Core and Neon exports mixed: convert them separately", paths[neon.index(False)])
    if neon[0]:
        if "min_confidence" in options:
            raise ValueError("min_confidence= filters Pupil Core's gaze_positions.csv; a Neon gaze.csv has no "
                             "confidence column")
        return read_neon(paths, camera=camera, persons=persons, fps=fps, **options)
    return read_pupil(paths, camera=camera, persons=persons, fps=fps, **options)
