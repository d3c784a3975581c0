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
own default ``min_data_confidence = 0.6``) and rows without 3D data are dropped, with a warning
that counts them. The frame is ``world_index``, the scene video frame the exporter matched the
datum to; a frame with several data (gaze runs at 120–200 Hz, the scene at 30 Hz) keeps the one of
highest confidence (the first of equals). Pupil reports no per-datum angular uncertainty
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
shared by several Neons, so frames come from one time grid: ``frame = round((t − start_ns) · fps
/ 1e9)`` with ``start_ns`` the earliest sample of the files; a frame with several samples keeps
the one nearest its time. Bandwidth :data:`DEFAULT_BANDWIDTH_NEON`. A native Neon recording
folder needs ``pupil-labs-neon-recording`` (``pip install 'jaxgaze[neon]'``,
:func:`read_neon_recording`); the CSV path does not.

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
from typing import Mapping, Optional, Sequence, Union

import cv2
import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.common import (
    bandwidth_from_mean_angular_error,
    camera_rays_to_world,
    require_extra,
    world_rays_to_camera,
)
from jaxgaze.io.rays import RayRecording, stack_rays
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

_PUPIL_REQUIRED = ("world_index", "confidence", "gaze_point_3d_x", "gaze_point_3d_y", "gaze_point_3d_z")
_EYE_COLUMNS = {eye: (tuple(f"eye_center{eye}_3d_{a}" for a in "xyz"), tuple(f"gaze_normal{eye}_{a}" for a in "xyz"))
                for eye in (0, 1)}
_NEON_REQUIRED = ("timestamp [ns]", "azimuth [deg]", "elevation [deg]")
_MM = 1e-3
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


def _drop_warning(path, dropped: dict) -> None:
    parts = [f"{count} {why}" for why, count in dropped.items() if count]
    if parts:
        warnings.warn(f"{path}: dropped " + ", ".join(parts), stacklevel=3)


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
    """Rows of one ``gaze_positions.csv`` kept as rays: frames, confidence, origins and directions in
    our camera frame (metres, unit), after the confidence and 3D filters (one row per frame)."""
    optional = tuple(c for eye in (0, 1) for group in _EYE_COLUMNS[eye] for c in group) + ("gaze_timestamp",)
    table = read_csv_table(path, _PUPIL_REQUIRED, optional,
                           hint="a Pupil Player gaze_positions.csv export with 3D gaze (columns "
                                + ", ".join(_PUPIL_REQUIRED) + ")")
    frames, confidence, origins, directions = [], [], [], []
    dropped = {f"rows of confidence < {min_confidence:g}": 0, "rows without 3D gaze (2D gaze mapper?)": 0}
    for row in table.rows:
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
            dropped[f"rows of confidence < {min_confidence:g}"] += 1
            continue
        if point is None and not normals:
            dropped["rows without 3D gaze (2D gaze mapper?)"] += 1
            continue
        origin = np.mean(centers, axis=0) if centers else np.zeros(3)
        direction = np.sum(normals, axis=0) if normals else point - origin
        if np.linalg.norm(direction) == 0:
            raise row.error("the gaze direction has zero length (gaze point at the eye centre, or opposite normals)")
        frames.append(frame)
        confidence.append(c)
        origins.append(origin * _MM)
        directions.append(direction / np.linalg.norm(direction))
    _drop_warning(table.path, dropped)
    if not frames:
        raise InputFileError(f"no gaze row with 3D gaze and confidence ≥ {min_confidence:g} among "
                             f"{len(table.rows)} rows", table.path)
    keep = keep_one_per_frame(frames, confidence)
    return (table.path, np.asarray(frames, np.int64)[keep], _ours_from_opencv(np.asarray(origins)[keep]),
            _ours_from_opencv(np.asarray(directions)[keep]))


def read_pupil(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
               min_confidence: float = MIN_CONFIDENCE, bandwidth: float = DEFAULT_BANDWIDTH_PUPIL) -> RayRecording:
    """Pupil Core ``gaze_positions.csv`` exports (one per wearer) → a world :class:`RayRecording`.

    Origin: the midpoint of the eye centres; direction: the mean unit gaze normal (module docstring),
    both from the scene camera's OpenCV axes (mm) to ours (m), then to the world by ``camera``
    (``x_world = R_world_from_camera @ x_camera + center``, per ``world_index``; without it the world
    is the one wearer's scene camera frame). Rows below ``min_confidence`` or without 3D data are
    dropped with a warning; one ray per ``world_index`` (the most confident).
    """
    paths = as_paths(paths)
    names = wearer_names(paths, persons, ("gaze_positions",))
    all_frames, all_persons, all_origins, all_directions = [], [], [], []
    for index, (path, person) in enumerate(zip(paths, names)):
        pose = camera_of(camera, index, person, len(paths))
        path, frames, origins, directions = _pupil_table(path, min_confidence)
        origins, directions = camera_rays_to_world(frames, origins, directions, pose, path=path)
        all_frames += frames.tolist()
        all_persons += [person] * len(frames)
        all_origins.append(origins)
        all_directions.append(directions)
    origins, directions = np.concatenate(all_origins), np.concatenate(all_directions)
    return stack_rays(all_frames, all_persons, origins, directions, np.full(len(all_frames), float(bandwidth)),
                      path=paths[0] if len(paths) == 1 else ", ".join(paths))


def write_pupil(path, recording: RayRecording, *, person: Optional[str] = None, camera: Optional[CameraPoses] = None,
                timestamps=None) -> int:
    """Write one person's rays as a Pupil Player ``gaze_positions.csv`` (binocular 3D gaze), atomically;
    returns the number of rows.

    The inverse of :func:`read_pupil`: world → scene camera (``camera``) → OpenCV axes, millimetres.
    Both eye centres sit ±31.5 mm along the camera's x axis around the origin (eye 0, the right eye,
    on +x), both gaze normals are the direction, ``gaze_point_3d`` is 1 m along it; ``confidence`` is
    1. ``gaze_timestamp`` is ``timestamps`` (seconds, one per frame) or ``frame / 30``; ``norm_pos``
    and ``base_data`` are left empty (they need the camera intrinsics and the pupil data).
    """
    frames, origins, directions, _ = person_rays(recording, person, path)
    origins, directions = world_rays_to_camera(frames, origins, directions, camera, path=path)
    origins_mm = _opencv_from_ours(origins) / _MM
    directions = _opencv_from_ours(directions)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    times = frames / 30.0 if timestamps is None else np.asarray(timestamps, dtype=float).reshape(-1)
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
    times, azimuth, elevation = [], [], []
    dropped = {"samples not worn (worn = 0)": 0, "samples in a blink": 0}
    for row in table.rows:
        time = row.integer("timestamp [ns]")
        az, el = row.number("azimuth [deg]"), row.number("elevation [deg]")
        if not (-180.0 <= az <= 180.0 and -90.0 <= el <= 90.0):
            raise row.error(f"azimuth {az:g}°, elevation {el:g}° out of range (azimuth in [−180, 180], "
                            "elevation in [−90, 90] degrees)")
        if table.has("worn") and row.cell("worn") and row.number("worn") == 0:
            dropped["samples not worn (worn = 0)"] += 1
            continue
        if table.has("blink id") and row.cell("blink id"):
            dropped["samples in a blink"] += 1
            continue
        times.append(time)
        azimuth.append(az)
        elevation.append(el)
    _drop_warning(table.path, dropped)
    if not times:
        raise InputFileError(f"no worn, blink-free gaze sample among {len(table.rows)} rows", table.path)
    return table.path, np.asarray(times, np.int64), neon_angles_to_direction(azimuth, elevation)


def frames_on_grid(times_ns: np.ndarray, start_ns: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``frame = round((t − start_ns) · fps / 1e9)`` and the rows to keep: in each frame the sample
    nearest the frame's time (the first of equals)."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    exact = (np.asarray(times_ns, dtype=np.int64) - np.int64(start_ns)).astype(np.float64) * (fps / 1e9)
    frames = np.rint(exact).astype(np.int64)
    return frames, keep_one_per_frame(frames, -np.abs(exact - frames))


def read_neon(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None, fps: float = NEON_FPS,
              start_ns: Optional[int] = None, bandwidth: float = DEFAULT_BANDWIDTH_NEON) -> RayRecording:
    """Neon ``gaze.csv`` exports (one per wearer) → a world :class:`RayRecording`.

    Direction from ``azimuth [deg]`` / ``elevation [deg]`` (:func:`neon_angles_to_direction`), origin
    the scene camera, then to the world by ``camera`` (per frame; without it the world is the one
    wearer's scene camera frame). Frames: ``round((t − start_ns) · fps / 1e9)``, ``start_ns`` by
    default the earliest kept sample of all files, one sample per frame (the nearest). Samples not
    worn or in a blink are dropped with a warning.
    """
    paths = as_paths(paths)
    names = wearer_names(paths, persons, ("gaze",))
    return _neon_rays([_neon_table(path) for path in paths], names, camera, start_ns, fps, bandwidth)


def _neon_rays(samples, names, camera, start_ns, fps, bandwidth) -> RayRecording:
    """Each wearer's ``(path, times_ns, scene-camera directions)`` → one world :class:`RayRecording`: the
    nearest sample per frame of the time grid (:func:`frames_on_grid`), origin the scene camera, placed by
    ``camera`` (:func:`read_neon`, :func:`read_neon_recording`)."""
    paths = [path for path, _, _ in samples]
    if start_ns is None:
        start_ns = min(int(times.min()) for _, times, _ in samples)
    all_frames, all_persons, all_origins, all_directions = [], [], [], []
    for index, ((path, times, directions), person) in enumerate(zip(samples, names)):
        pose = camera_of(camera, index, person, len(paths))
        frames, keep = frames_on_grid(times, start_ns, fps)
        frames, directions = frames[keep], directions[keep]
        origins, directions = camera_rays_to_world(frames, np.zeros_like(directions), directions, pose, path=path)
        all_frames += frames.tolist()
        all_persons += [person] * len(frames)
        all_origins.append(origins)
        all_directions.append(directions)
    return stack_rays(all_frames, all_persons, np.concatenate(all_origins), np.concatenate(all_directions),
                      np.full(len(all_frames), float(bandwidth)),
                      path=paths[0] if len(paths) == 1 else ", ".join(paths))


def write_neon(path, recording: RayRecording, *, person: Optional[str] = None, camera: Optional[CameraPoses] = None,
               fps: float = NEON_FPS, start_ns: int = 0) -> int:
    """Write one person's rays as a Neon ``gaze.csv``, atomically; returns the number of rows.

    The inverse of :func:`read_neon`: ``timestamp [ns] = start_ns + round(frame · 1e9 / fps)``,
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
    azimuth, elevation = direction_to_neon_angles(directions)
    rows = [["", "", int(start_ns + round(int(frame) * 1e9 / fps)), "", "", "1.0", "", "", format_float(az),
             format_float(el)] for frame, az, el in zip(frames, azimuth, elevation)]
    return write_csv_rows(path, NEON_COLUMNS, rows)


def read_neon_recording(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
                        fps: float = NEON_FPS, start_ns: Optional[int] = None,
                        bandwidth: float = DEFAULT_BANDWIDTH_NEON) -> RayRecording:
    """Native Neon recording folders (one per wearer) → a world :class:`RayRecording`, through
    ``pupil-labs-neon-recording`` (``pip install 'jaxgaze[neon]'``; :class:`MissingExtraError` without it).

    The gaze pixels are undistorted with the recording's scene camera intrinsics and unprojected
    (OpenCV), then follow :func:`read_neon` (``cart_to_spherical`` angles, time grid, camera poses).
    Every sample is kept (the native gaze stream has no ``worn``/``blink id`` columns).
    """
    neon = require_extra("pupil_labs.neon_recording", "neon")
    paths = as_paths(paths)
    names = wearer_names(paths, persons, ())
    samples = []
    for path in paths:
        recording = neon.open(path)
        gaze = recording.gaze
        times = np.asarray(gaze.time if hasattr(gaze, "time") else gaze.ts, dtype=np.int64)  # ns; renamed in 2.0
        pixels = np.stack([np.asarray(gaze.x), np.asarray(gaze.y)], axis=-1).astype(np.float32).reshape(-1, 1, 2)
        calibration = recording.calibration
        if calibration is None:
            raise InputFileError("the recording has no scene camera calibration to unproject its gaze with", path)
        undistorted = cv2.undistortPoints(pixels, np.asarray(calibration.scene_camera_matrix),
                                          np.asarray(calibration.scene_distortion_coefficients)).reshape(-1, 2)
        rays_opencv = np.concatenate([undistorted, np.ones((len(undistorted), 1))], axis=1)
        samples.append((os.fspath(path), times, _ours_from_opencv(rays_opencv)))
    return _neon_rays(samples, names, camera, start_ns, fps, bandwidth)


def _is_neon(path) -> bool:
    """Whether a Pupil Labs CSV is Neon's export (its header names ``azimuth [deg]``), not Pupil Core's."""
    text = read_text(path)
    header = next((line for line in text.splitlines() if line.strip()), "")
    return "azimuth [deg]" in header.lower()


def read_pupil_labs(paths, *, camera: Cameras = None, persons: Optional[Sequence[str]] = None,
                    fps: Optional[float] = None) -> RayRecording:
    """Pupil Core or Neon CSV exports, told apart by their header (Neon's names ``azimuth [deg]``):
    :func:`read_neon` (with ``fps``, default :data:`NEON_FPS`) or :func:`read_pupil` (frames of its own).
    Both kinds at once are an :class:`InputFileError`."""
    paths = as_paths(paths)
    neon = [_is_neon(path) for path in paths]
    if any(neon) and not all(neon):
        raise InputFileError("Pupil Core and Neon exports mixed: convert them separately", paths[neon.index(False)])
    if neon[0]:
        return read_neon(paths, camera=camera, persons=persons, **({} if fps is None else {"fps": fps}))
    return read_pupil(paths, camera=camera, persons=persons)
