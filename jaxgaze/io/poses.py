"""Camera-pose files: COLMAP's ``images.txt``, a pose CSV, and a CSV of several wearers'
camera poses (Park et al. 2012, Sec. 3.2).

All are read into :class:`~jaxgaze.poses.CameraPoses` in **our** camera convention
(+x forward, +y left, +z up; ``docs/conventions.md``, "Camera poses and COLMAP"):
the COLMAP reader and writer apply :data:`~jaxgaze.geometry.R_OURS_FROM_OPENCV`.
Quaternions are ``(w, x, y, z)``, scalar first. Errors raise :class:`PoseFileError`
whose message starts with ``path, line N:``.
"""

from __future__ import annotations

import io
import math
import os
import re
from typing import NamedTuple, Optional

import numpy as np

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.text import InputFileError, atomic_path, csv_writer, parse_integer, parse_number, read_csv_table, read_lines
from jaxgaze.poses import CameraPoses, as_camera_poses, camera_poses, matrices_to_quaternions, quaternions_to_matrices

__all__ = [
    "PoseFileError",
    "POSE_CSV_COLUMNS",
    "read_colmap_images",
    "write_colmap_images",
    "read_pose_csv",
    "write_pose_csv",
    "read_poses",
    "PoseTrack",
    "compile_frame_pattern",
    "check_quaternion",
    "CAMERA_POSE_COLUMNS",
    "WearerPoses",
    "read_camera_poses_csv",
    "write_camera_poses_csv",
]

#: Required columns of :func:`read_pose_csv` (``timestamp`` is optional).
POSE_CSV_COLUMNS = ("frame", "qw", "qx", "qy", "qz", "cx", "cy", "cz")

#: Columns of a camera-pose CSV of several wearers, one row per (frame, person): ``q`` the unit
#: quaternion (w, x, y, z) of R_camera_from_world in our camera convention, ``c`` the centre (m).
CAMERA_POSE_COLUMNS = ("frame", "person", "qw", "qx", "qy", "qz", "cx", "cy", "cz")

#: Largest accepted ``|‖q‖ − 1|`` for a quaternion read from a file.
QUATERNION_NORM_TOLERANCE = 1e-3


class PoseFileError(InputFileError):
    """A pose file is malformed. The message starts with ``path, line N:``."""


def _read_text(path) -> list[str]:
    return read_lines(path, PoseFileError, "pose")


def _number(text: str, what: str, path, line: int) -> float:
    return parse_number(text, what, path, line, PoseFileError)


def _integer(text: str, what: str, path, line: int) -> int:
    return parse_integer(text, what, path, line, PoseFileError)


def check_quaternion(q, path, line: int) -> None:
    """Raise :class:`PoseFileError` at ``path, line`` unless ``|‖q‖ − 1| ≤ QUATERNION_NORM_TOLERANCE``."""
    norm = math.sqrt(sum(x * x for x in q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise PoseFileError(
            f"quaternion (qw, qx, qy, qz) = {tuple(q)} is not unit: norm {norm:.6g} "
            f"(allowed |norm − 1| ≤ {QUATERNION_NORM_TOLERANCE:g})",
            path,
            line,
        )


def _check_duplicates(frames: list[int], lines: list[int], path, hint: str = "") -> None:
    first: dict[int, int] = {}
    for frame, line in zip(frames, lines):
        seen = first.setdefault(frame, line)
        if seen != line:
            raise PoseFileError(f"duplicate frame {frame} (first on line {seen}){hint}", path, line)


_DIGITS = re.compile(r"\d+")
_LARGEST_FRAME = np.iinfo(np.int64).max
_SELECT_HINT = "select one wearer's images by camera id or name prefix"


def compile_frame_pattern(pattern: str) -> re.Pattern:
    """A frame pattern: a regular expression with exactly one group, the frame id's digits,
    searched for in each image name (e.g. ``r"_(\\d+)_leftImg8bit"``); ``ValueError`` otherwise."""
    try:
        compiled = re.compile(pattern)
    except re.error as error:
        raise ValueError(f"frame pattern '{pattern}' is not a regular expression: {error}") from None
    if compiled.groups != 1:
        raise ValueError(f"frame pattern '{pattern}' must have exactly one group (the frame id's digits), "
                         f"it has {compiled.groups}")
    return compiled


def _stem(name: str) -> str:
    """The image name without its extension (directories kept)."""
    head, _, base = name.replace("\\", "/").rpartition("/")
    return head + "/" * bool(head) + (base.rsplit(".", 1)[0] if "." in base else base)


def _frame_id(digits: str, name: str, path, line: int) -> int:
    value = int(digits)
    if value > _LARGEST_FRAME:
        raise PoseFileError(f"frame id {digits} in image name {name!r} is too large", path, line)
    return value


def _frame_ids(names, image_ids, lines, path, pattern) -> tuple[list[int], str]:
    """Frame ids of COLMAP images and the rule that gave them (see :func:`read_colmap_images`)."""
    if pattern is not None:
        compiled = compile_frame_pattern(pattern)
        frames = []
        for name, line in zip(names, lines):
            match = compiled.search(name)
            if match is None:
                raise PoseFileError(f"image name {name!r} does not match the frame pattern '{pattern}'", path, line)
            if not (match.group(1) or "").isdecimal():
                raise PoseFileError(f"the frame pattern '{pattern}' picks {match.group(1)!r} out of image name "
                                    f"{name!r}, not a frame number", path, line)
            frames.append(_frame_id(match.group(1), name, path, line))
        return frames, f"the image names by the pattern '{pattern}'"
    runs = [_DIGITS.findall(_stem(name)) for name in names]
    counts = sorted({len(r) for r in runs})
    if counts == [0]:
        for image_id, line in zip(image_ids, lines):
            if abs(image_id) > _LARGEST_FRAME:
                raise PoseFileError(f"IMAGE_ID {image_id} is too large for a frame id", path, line)
        return list(image_ids), "IMAGE_ID (the image names hold no digits)"
    ambiguous = f"give a frame pattern (a regular expression with one group, e.g. '_(\\d+)\\.png$'), or {_SELECT_HINT}"
    if len(counts) > 1:
        k = next(i for i, r in enumerate(runs) if len(r) != len(runs[0]))
        raise PoseFileError(f"frame ids are ambiguous: image names hold different numbers of digit runs "
                            f"({names[0]!r} has {len(runs[0])}, {names[k]!r} has {len(runs[k])}); {ambiguous}",
                            path, lines[k])
    size = counts[0]
    columns = [[int(r[k]) for r in runs] for k in range(size)]
    varying = [0] if size == 1 else [k for k in range(size) if len(set(columns[k])) > 1]
    if len({tuple(columns[k]) for k in varying}) != 1:  # none of several runs changes, or several change differently
        what = "change from image to image" if varying else "could each be the frame id"
        raise PoseFileError(f"frame ids are ambiguous: the image names hold {size} numbers that {what} "
                            f"(e.g. {names[0]!r}: {', '.join(runs[0])}); {ambiguous}", path, lines[0])
    k = varying[0]
    frames = [_frame_id(r[k], name, path, line) for r, name, line in zip(runs, names, lines)]
    which = "the number in the image names" if size == 1 else "the one number that changes in the image names"
    return frames, f"{which} (e.g. {names[0]!r} → {frames[0]})"


def _select(images: list, camera_id, name_prefix, path) -> tuple[list, str]:
    """The images of one camera id and/or name prefix, and a phrase saying which ('' for all)."""
    chosen, said = images, []
    if camera_id is not None:
        chosen = [image for image in chosen if image[2] == camera_id]
        if not chosen:
            known = sorted({image[2] for image in images})
            raise PoseFileError(f"no image has CAMERA_ID {camera_id} (the file's camera ids: "
                                f"{', '.join(str(c) for c in known[:10])}{', …' if len(known) > 10 else ''})", path)
        said.append(f"CAMERA_ID {camera_id}")
    if name_prefix is not None:
        kept = [image for image in chosen if image[3].startswith(name_prefix)]
        if not kept:
            among = f" among those of CAMERA_ID {camera_id}" if camera_id is not None else ""
            raise PoseFileError(f"no image name starts with {name_prefix!r}{among} (e.g. {chosen[0][3]!r})", path)
        chosen = kept
        said.append(f"names starting with {name_prefix!r}")
    return chosen, (f"{len(chosen)} of {len(images)} images, {' and '.join(said)}" if said else "")


# ---------------------------------------------------------------------------
# COLMAP


def read_colmap_images(path, *, frame_pattern: Optional[str] = None, camera_id: Optional[int] = None,
                       name_prefix: Optional[str] = None) -> CameraPoses:
    """Read COLMAP's text ``images.txt`` into :class:`CameraPoses` (our convention).

    Format: lines starting with ``#`` are comments. Each image takes two lines:
    ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and then its POINTS2D line
    (``X Y POINT3D_ID`` triples; it may be empty). COLMAP's pose is world to
    camera in the OpenCV camera frame, ``x_cam = R(q) x_world + t``, so the
    centre is ``C = −R(q)ᵀ t`` and ``R_camera_from_world = R_OURS_FROM_OPENCV @ R(q)``.

    ``camera_id`` and ``name_prefix`` keep one wearer's images of a joint
    reconstruction: those of that CAMERA_ID, and those whose NAME starts with the prefix.

    Frame ids come from the kept images' names (directories included, extension dropped):

    * with ``frame_pattern``, a regular expression with one group
      (:func:`compile_frame_pattern`) searched for in each NAME, e.g. ``r"_(\\d+)_leftImg8bit"``;
    * otherwise from the runs of digits in the names: with one run per name, that number
      (``frame_000123.jpg`` → 123); with several, the one run that changes from image to
      image (``aachen_000000_000019_leftImg8bit.png`` → 19: the ``000000`` and the ``8`` of
      ``leftImg8bit`` are the same in every name);
    * IMAGE_ID when no name holds a digit.

    Anything else is ambiguous, and an error rather than a guess: names with different
    numbers of digit runs, or several runs that change (two wearers' images mixed, say).
    Poses are sorted by frame; ``timestamps`` is ``None``. :func:`read_poses` also says
    which rule gave the frame ids.

    Raises :class:`PoseFileError` (a ``ValueError``) naming file and line for a
    missing or non-numeric field, a NaN/inf, a non-unit quaternion
    (``|‖q‖ − 1| > 1e-3``), a missing POINTS2D line, ambiguous frame ids, a name
    the pattern does not match, a duplicate frame, a file with no images, or no
    image selected; ``ValueError`` for a pattern without exactly one group.
    """
    return _read_colmap(path, frame_pattern, camera_id, name_prefix)[0]


def _read_colmap(path, frame_pattern, camera_id, name_prefix) -> tuple[CameraPoses, str, str]:
    """:func:`read_colmap_images`, with the rule that gave the frame ids and the phrase of the selection."""
    if frame_pattern is not None:
        compile_frame_pattern(frame_pattern)
    lines = _read_text(path)
    images = []  # (q, t, CAMERA_ID, NAME, line, IMAGE_ID)
    i = 0
    while i < len(lines):
        raw = lines[i]
        number = i + 1
        i += 1
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split()
        if len(fields) < 10:
            raise PoseFileError(
                f"expected 10 fields 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {len(fields)}",
                path,
                number,
            )
        image_id = _integer(fields[0], "IMAGE_ID", path, number)
        q = [_number(fields[1 + k], name, path, number) for k, name in enumerate(("QW", "QX", "QY", "QZ"))]
        t = [_number(fields[5 + k], name, path, number) for k, name in enumerate(("TX", "TY", "TZ"))]
        camera = _integer(fields[8], "CAMERA_ID", path, number)
        name = " ".join(fields[9:])
        check_quaternion(q, path, number)
        # The next line, whatever it holds, is this image's POINTS2D line (as in COLMAP).
        if i < len(lines):
            points = lines[i].split()
            if len(points) % 3 != 0:
                raise PoseFileError(
                    f"expected the POINTS2D line of image {image_id} (X Y POINT3D_ID triples, "
                    f"possibly empty), got {len(points)} fields",
                    path,
                    i + 1,
                )
            i += 1
        images.append((q, t, camera, name, number, image_id))
    if not images:
        raise PoseFileError("no images: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME' lines", path)
    images, selection = _select(images, camera_id, name_prefix, path)
    where = [image[4] for image in images]
    frames, rule = _frame_ids([image[3] for image in images], [image[5] for image in images], where, path,
                              frame_pattern)
    _check_duplicates(frames, where, path, f" (several wearers' images? {_SELECT_HINT})")
    q = np.asarray([image[0] for image in images], dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    R_cv = quaternions_to_matrices(q)
    t = np.asarray([image[1] for image in images], dtype=np.float64)
    centers = -np.einsum("tji,tj->ti", R_cv, t)
    R = np.einsum("ij,tjk->tik", R_OURS_FROM_OPENCV, R_cv)
    return camera_poses(R, centers, frames), rule, selection


def write_colmap_images(path, poses: CameraPoses, *, camera_id: int = 1) -> None:
    """Write :class:`CameraPoses` as COLMAP text ``images.txt``.

    The inverse of :func:`read_colmap_images`: image ``k`` (1-based) is named
    ``frame_%06d.jpg`` after its frame id, with ``camera_id`` and an empty
    POINTS2D line. Frame ids must be ≥ 0. Timestamps are not stored. The file is
    written atomically.
    """
    poses = as_camera_poses(poses, "poses")
    frames = np.asarray(poses.frame_ids)
    if np.any(frames < 0):
        raise ValueError("write_colmap_images: frame ids must be non-negative")
    if len(np.unique(frames)) != len(frames):
        raise ValueError("write_colmap_images: duplicate frame ids")
    R_cv = np.einsum("ji,tjk->tik", R_OURS_FROM_OPENCV, poses.R_camera_from_world)
    q = matrices_to_quaternions(R_cv)
    t = -np.einsum("tij,tj->ti", R_cv, poses.centers)
    out = io.StringIO()
    out.write("# Image list with two lines of data per image:\n")
    out.write("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n")
    out.write("#   POINTS2D[] as (X, Y, POINT3D_ID)\n")
    out.write(f"# Number of images: {len(frames)}, written by jaxgaze.poses (no 2D points)\n")
    for k in range(len(frames)):
        values = " ".join(repr(float(x)) for x in (*q[k], *t[k]))
        out.write(f"{k + 1} {values} {camera_id} frame_{int(frames[k]):06d}.jpg\n\n")
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as handle:
        handle.write(out.getvalue())


# ---------------------------------------------------------------------------
# CSV


def read_pose_csv(path) -> CameraPoses:
    """Read camera poses from a CSV file with a header row.

    Columns (any order, case-insensitive): ``frame, qw, qx, qy, qz, cx, cy, cz``
    and optionally ``timestamp`` (seconds). ``(qw, qx, qy, qz)`` is the unit
    quaternion of ``R_camera_from_world`` in **our** camera convention (+x
    forward, +y left, +z up), not OpenCV's; ``(cx, cy, cz)`` is the camera
    centre in the world, metres. Other columns are ignored; blank lines and
    lines starting with ``#`` are skipped. Poses are sorted by frame.

    Raises :class:`PoseFileError` (a ``ValueError``) naming file and line for a
    missing column, an empty or non-numeric cell, NaN/inf, a non-integer frame,
    a non-unit quaternion (``|‖q‖ − 1| > 1e-3``), a duplicate frame or an empty
    file.
    """
    table = read_csv_table(path, POSE_CSV_COLUMNS, ("timestamp",), error=PoseFileError, what="pose", comments=True)
    frames, quats, centers, stamps, where = [], [], [], [], []
    for row in table.rows:
        frames.append(row.integer("frame"))
        quats.append(_row_quaternion(row))
        centers.append([row.number(c) for c in ("cx", "cy", "cz")])
        if table.has("timestamp"):
            stamps.append(row.number("timestamp"))
        where.append(row.line)
    _check_duplicates(frames, where, table.path)
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return camera_poses(quaternions_to_matrices(q), centers, frames, stamps if table.has("timestamp") else None)


def _row_quaternion(row) -> list:
    q = [row.number(c) for c in ("qw", "qx", "qy", "qz")]
    check_quaternion(q, row.table.path, row.line)
    return q


def write_pose_csv(path, poses: CameraPoses) -> None:
    """Write :class:`CameraPoses` in the format of :func:`read_pose_csv` (with
    ``timestamp`` when the poses have timestamps), atomically."""
    poses = as_camera_poses(poses, "poses")
    q = matrices_to_quaternions(poses.R_camera_from_world)
    columns = list(POSE_CSV_COLUMNS) + (["timestamp"] if poses.timestamps is not None else [])
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv_writer(handle)
        writer.writerow(columns)
        for k in range(poses.num_frames):
            row = [int(poses.frame_ids[k]), *(repr(float(x)) for x in q[k]), *(repr(float(x)) for x in poses.centers[k])]
            if poses.timestamps is not None:
                row.append(repr(float(poses.timestamps[k])))
            writer.writerow(row)


class PoseTrack(NamedTuple):
    """One wearer's camera poses read by :func:`read_poses`, and where they came from.

    ``frame_ids_from`` says which rule gave the frame ids (e.g. ``"its 'frame' column"``,
    ``"IMAGE_ID (the image names hold no digits)"``); ``selection`` which images of a
    COLMAP file were kept (``""``: all of them).
    """

    poses: CameraPoses
    path: str
    frame_ids_from: str
    selection: str = ""

    def describe(self) -> str:
        """One phrase: the file's name, the images kept, the rule of the frame ids."""
        kept = f" ({self.selection})" if self.selection else ""
        return f"{os.path.basename(self.path)}{kept}: frame ids from {self.frame_ids_from}"


def read_poses(path, *, frame_pattern: Optional[str] = None, camera_id: Optional[int] = None,
               name_prefix: Optional[str] = None) -> PoseTrack:
    """One wearer's camera poses from a COLMAP ``images.txt`` (``.txt``, :func:`read_colmap_images`,
    with its keywords) or a pose CSV (``.csv``, :func:`read_pose_csv`, frame ids from its ``frame``
    column; ``frame_pattern`` does not apply), as a :class:`PoseTrack` that says how frames were identified.

    :class:`PoseFileError` for another extension, or ``camera_id``/``name_prefix`` with a pose CSV
    (it holds one wearer).
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".txt", ".csv"):
        raise PoseFileError(f"unknown pose file type '{ext}': expected a COLMAP images.txt (.txt) or a pose CSV "
                            "(.csv)", path)
    if ext == ".txt":
        poses, rule, selection = _read_colmap(path, frame_pattern, camera_id, name_prefix)
        return PoseTrack(poses, path, rule, selection)
    if camera_id is not None or name_prefix is not None:
        raise PoseFileError("a camera id or name prefix selects images of a COLMAP images.txt; a pose CSV holds one "
                            "wearer's poses", path)
    return PoseTrack(read_pose_csv(path), path, "its 'frame' column")


# ---------------------------------------------------------------------------
# Several wearers in one CSV


class WearerPoses(NamedTuple):
    """The camera poses of several wearers from one camera-pose CSV.

    ``poses`` maps each person (in the order of their first row) to their
    :class:`CameraPoses` (sorted by frame); ``lines`` maps each person to the file
    line of each of those poses; ``path`` is the file.
    """

    poses: dict
    lines: dict
    path: str


def read_camera_poses_csv(path) -> WearerPoses:
    """Read a CSV of camera poses, one row per (frame, person), columns :data:`CAMERA_POSE_COLUMNS`.

    Columns are in any order (case-insensitive); other columns are ignored, blank lines
    skipped. ``(qw, qx, qy, qz)`` is the unit quaternion of ``R_camera_from_world`` in
    our camera convention (+x forward, +y left, +z up), checked as by
    :func:`read_pose_csv`; ``(cx, cy, cz)`` is the camera centre in the world (metres).
    Raises :class:`PoseFileError` naming the file and line for a header problem, an
    empty or non-numeric cell, NaN/inf, a non-integer frame, a non-unit quaternion or
    a duplicate (frame, person).
    """
    table = read_csv_table(path, CAMERA_POSE_COLUMNS, error=PoseFileError)
    rows: dict[str, list] = {}
    seen: dict[tuple[int, str], int] = {}
    for row in table.rows:
        frame = row.integer("frame")
        person = row.text("person")
        q = _row_quaternion(row)
        centre = [row.number(c) for c in ("cx", "cy", "cz")]
        first = seen.setdefault((frame, person), row.line)
        if first != row.line:
            raise row.error(f"duplicate pose for frame {frame}, person '{person}' (first on line {first})")
        rows.setdefault(person, []).append((frame, q, centre, row.line))
    poses, lines = {}, {}
    for person, mine in rows.items():
        q = np.asarray([r[1] for r in mine], dtype=np.float64)
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        frames = np.asarray([r[0] for r in mine], dtype=np.int64)
        poses[person] = camera_poses(quaternions_to_matrices(q), [r[2] for r in mine], frames)
        lines[person] = np.asarray([r[3] for r in mine], dtype=np.int64)[np.argsort(frames, kind="stable")]
    return WearerPoses(poses, lines, table.path)


def write_camera_poses_csv(path, poses: dict) -> None:
    """Write ``{person: CameraPoses}`` as a camera-pose CSV (:data:`CAMERA_POSE_COLUMNS`),
    rows sorted by frame, then in the order of ``poses``; atomically."""
    rows = []
    for k, (person, p) in enumerate(poses.items()):
        p = as_camera_poses(p, f"poses[{person!r}]")
        q = matrices_to_quaternions(p.R_camera_from_world)
        for t in range(p.num_frames):
            rows.append((int(p.frame_ids[t]), k, [int(p.frame_ids[t]), person, *(repr(float(x)) for x in q[t]),
                                                 *(repr(float(x)) for x in p.centers[t])]))
    rows.sort(key=lambda r: r[:2])
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv_writer(handle)
        writer.writerow(CAMERA_POSE_COLUMNS)
        writer.writerows(r[2] for r in rows)
