"""The files of the joint model (``jaxgaze joint``): one gaze file per person aligned on their frames,
the speech as per-person flags, and the outputs, the posterior as netCDF and its per-frame table as CSV.

Both writers are atomic (:func:`~jaxgaze.io.text.atomic_path`): on any failure, Ctrl-C
included, no partial file is left and an existing file is untouched.

The posterior is read by attribute only (``people``, ``candidates``, ``membership (T, P, C)``,
``mutual (T, P, P)``, ``sampler.idata``), as :class:`jaxgaze.joint.JointPosterior` has them.
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from typing import NamedTuple, Optional

import numpy as np

from jaxgaze.bias.speech import SpeechSegments, speaking_at
from jaxgaze.io.gaze import GazeFileError, GazeTrack, is_openface_csv, openface_gaze_track, read_gaze_csv
from jaxgaze.io.tools.openface import read_openface_people
from jaxgaze.io.speech import SpeechFileError, read_rttm, read_segments_csv
from jaxgaze.io.text import atomic_path, csv_writer, format_float, read_text
from jaxgaze.nuts import set_units, split_chains
from jaxgaze.results import name

__all__ = ["JOINT_FRAME_COLUMNS", "JOINT_FRAMES_FORMAT", "JOINT_INPUTS_FORMAT", "JointGaze", "read_joint_gaze",
           "read_speech", "speaking_by_person", "joint_frame_columns", "write_joint_frames", "write_joint_netcdf"]

#: Timestamps of one frame in two files may differ by this much (seconds).
TIME_TOLERANCE_S = 1e-3


class JointGaze(NamedTuple):
    """The gaze files of a group, aligned on the union of their frame ids (``T`` frames, ``P`` people).

    ``frames (T,)`` int64; ``time (T,)`` seconds when every file has timestamps, else ``None``;
    ``eye_positions (T, P, 3)``, ``R_world_from_head (T, P, 3, 3)``, ``gaze_angles (T, P, 2)``
    (NaN, identity and NaN where a person is absent; NaN gaze throughout for head pose only); ``present (T, P)``;
    ``tracks`` the :class:`~jaxgaze.io.gaze.GazeTrack` of each person; ``paths`` the file of each person;
    ``people`` each person's default name: the file's stem, ``<stem>_<k>`` for the ``k``-th person of an
    OpenFace file of several faces; ``measurement_scale (T, P)`` the per-frame sd of the angles (radians; 0 where
    no file gives one: our CSV's ``angle_sd``), for :func:`~jaxgaze.joint.joint_data`.
    """

    frames: np.ndarray
    time: Optional[np.ndarray]
    eye_positions: np.ndarray
    R_world_from_head: np.ndarray
    gaze_angles: np.ndarray
    present: np.ndarray
    tracks: tuple
    paths: tuple
    people: tuple
    measurement_scale: np.ndarray

    @property
    def formats(self) -> tuple:
        """``"csv"`` or ``"openface"`` per person."""
        return tuple(t.format for t in self.tracks)

    @property
    def some_timed(self) -> bool:
        """Whether some file, but not every one, has timestamps (they are then ignored)."""
        return self.time is None and any(t.time is not None for t in self.tracks)

    @property
    def timestamp_rate(self) -> Optional[float]:
        """Frames per second from the timestamps (``None`` without them or with one frame)."""
        if self.time is None or self.frames.size < 2:
            return None
        return round(float(1.0 / np.median(np.diff(self.time) / np.diff(self.frames))), 6)

    def times(self, fps: float) -> np.ndarray:
        """``(T,)`` frame times: the timestamps, else ``frame / fps``."""
        return self.frames / float(fps) if self.time is None else self.time


def _aligned_time(tracks: list[GazeTrack], paths, frames) -> Optional[np.ndarray]:
    if any(t.time is None for t in tracks):
        return None
    time = np.full(frames.size, np.nan)
    owner = np.full(frames.size, -1)
    for p, track in enumerate(tracks):
        rows = np.searchsorted(frames, track.frame)
        known = owner[rows] >= 0
        bad = np.flatnonzero(known & (np.abs(time[rows] - track.time) > TIME_TOLERANCE_S))
        if bad.size:
            i, row = int(bad[0]), int(rows[bad[0]])
            raise GazeFileError(f"the gaze files disagree on the time of frame {frames[row]}: {time[row]:g} s in "
                                f"{os.fspath(paths[owner[row]])}, {track.time[i]:g} s here", paths[p],
                                track.line_of(i))
        time[rows[~known]] = track.time[~known]
        owner[rows[~known]] = p
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise GazeFileError(f"timestamps must increase with the frame across the files: frame {frames[i]} at "
                            f"{time[i]:g} s is not after frame {frames[i - 1]} at {time[i - 1]:g} s", paths[owner[i]])
    return time


def read_joint_gaze(paths, *, min_confidence: float = 0.75, head_only: bool = False) -> JointGaze:
    """Read the gaze files of a group and align them on the union of their frame ids; a person missing from a
    frame is absent there.

    Each file is our gaze CSV (:func:`~jaxgaze.io.gaze.read_gaze_csv`, one person) or an OpenFace 2 CSV. An
    OpenFace file of several faces (``FaceLandmarkVidMulti``: a group filmed by one camera) gives one person
    per face, re-linked by head position (:func:`~jaxgaze.io.tools.openface.read_openface_people`); a warning
    names them. With ``head_only`` the gaze columns are not read, and may be absent (the gaze is NaN: pass
    ``None`` to :func:`~jaxgaze.joint.joint_data`).

    Every file must be in one frame of reference (checking that is the caller's: see
    :attr:`JointGaze.formats`). Warns when some files, not all, have timestamps. Raises the readers' errors, and
    :class:`~jaxgaze.io.gaze.GazeFileError` when the files' timestamps disagree on a frame or do not increase with the frame.
    """
    paths = tuple(paths)
    tracks, owners, people = [], [], []
    for path in paths:
        stem = os.path.splitext(os.path.basename(os.fspath(path)))[0]
        if not is_openface_csv(read_text(path, GazeFileError, "gaze")):
            tracks.append(read_gaze_csv(path, with_gaze=not head_only))
            owners.append(path)
            people.append(stem)
            continue
        found = read_openface_people(path, min_confidence=min_confidence, with_gaze=not head_only)
        names = [stem] if len(found.tracks) == 1 else [f"{stem}_{k}" for k in range(len(found.tracks))]
        for track in found.tracks:
            tracks.append(openface_gaze_track(track, path))
            owners.append(path)
        people.extend(names)
        if len(names) > 1:
            where = "; ".join(f"{n} at ({', '.join(f'{x:.2f}' for x in np.median(t.head_position_camera, 0))}) m, "
                              f"face_id {', '.join(map(str, ids))}" for n, t, ids in zip(names, found.tracks,
                                                                                        found.face_ids))
            warnings.warn(f"{os.fspath(path)}: {len(names)} people, OpenFace's faces re-linked by head position "
                          f"({found.relinks} re-links; median position in the camera frame, +x forward, +y left, "
                          f"+z up): {where}", stacklevel=2)
    frames = np.unique(np.concatenate([t.frame for t in tracks]))
    T, P = frames.size, len(tracks)
    eyes, gaze = np.full((T, P, 3), np.nan), np.full((T, P, 2), np.nan)
    R = np.broadcast_to(np.eye(3), (T, P, 3, 3)).copy()
    present = np.zeros((T, P), dtype=bool)
    scale = np.zeros((T, P))
    for p, track in enumerate(tracks):
        rows = np.searchsorted(frames, track.frame)
        eyes[rows, p], R[rows, p], gaze[rows, p] = track.eye, track.R_world_from_head, track.gaze_angles
        present[rows, p] = True
        if track.angle_sd is not None:
            scale[rows, p] = track.angle_sd
    gaze = JointGaze(frames, _aligned_time(tracks, owners, frames), eyes, R, gaze, present, tuple(tracks),
                     tuple(owners), tuple(people), scale)
    if gaze.some_timed:
        warnings.warn("not every gaze file has timestamps: they are ignored and frame f is at f / fps seconds",
                      stacklevel=2)
    return gaze


def read_speech(path, *, file_id: Optional[str] = None) -> SpeechSegments:
    """Speech segments from an RTTM (``.rttm``, :func:`~jaxgaze.io.speech.read_rttm`: one of several
    recordings needs ``file_id``) or a segments CSV (``.csv``); another extension is read as RTTM if it
    has SPEAKER lines, else as CSV."""
    text = read_text(path, SpeechFileError, "speech")
    ext = os.path.splitext(os.fspath(path))[1].lower()
    rttm = ext == ".rttm" or (ext != ".csv" and any(line.split()[:1] == ["SPEAKER"] for line in text.splitlines()))
    if file_id is not None and not rttm:
        raise SpeechFileError("a file id (--speech-file-id) is only for RTTM speech files", path)
    return read_rttm(path, file_id=file_id) if rttm else read_segments_csv(path)


def speaking_by_person(segments: SpeechSegments, people, times, speaker_map: Optional[dict] = None
                       ) -> tuple[dict, list]:
    """``({person: (T,) bool flags}, unmatched speakers)``: each person's speech at ``times`` (seconds).

    A person's speaker id is ``speaker_map[person]``, else their name; people without segments
    are left out (they never speak); speakers of no person are listed. Overlapping speech of
    several people is expected (no warning). ``ValueError`` for a mapped speaker that has no segment.
    """
    speaker_map = dict(speaker_map or {})
    speakers = segments.speakers
    missing = [s for s in speaker_map.values() if s not in speakers]
    if missing:
        raise ValueError(f"speaker(s) {', '.join(map(repr, missing))} of the speaker map have no segments "
                         f"(speakers: {', '.join(speakers)})")
    speaker_of = {name: speaker_map.get(name, name) for name in people}
    flags = {name: speaking_at(segments, [speaker], times)[0] for name, speaker in speaker_of.items()
             if speaker in speakers}
    return flags, [s for s in speakers if s not in set(speaker_of.values())]


#: The fixed columns of the per-frame table; ``p_<candidate>`` columns go between ``probability`` and
#: ``mutual_with`` (see :func:`joint_frame_columns`).
JOINT_FRAME_COLUMNS = ("frame", "time", "person", "present", "target", "probability", "mutual_with", "p_mutual",
                       "alternative_target", "alternative_probability", "alternative_weight")

#: The inputs of ``jaxgaze joint`` in words (its help shows it).
JOINT_INPUTS_FORMAT = """\
GAZE is one file per person (or per camera, see OpenFace), each one of
  * our gaze CSV (see 'jaxgaze bias -h'): frame, yaw, tilt (head frame,
    radians), qw, qx, qy, qz (R_world_from_head), ex, ey, ez (eye midpoint,
    world frame, metres), optional timestamp (seconds) and angle_sd (the
    per-frame sd of yaw and tilt, or with --head-only of the head pose; radians);
  * an OpenFace 2 CSV (--min-confidence): FeatureExtraction (one face), or
    FaceLandmarkVidMulti (a group filmed by one camera: one person per face,
    faces re-linked by head position, named <stem>_0, <stem>_1, ...; a note
    gives where each is). Each OpenFace file is in its own camera's frame
    (+x along the optical axis, +y left, +z up), so several of them are only
    accepted with --same-camera (one camera filmed everyone).
With --head-only (no eye tracker) only the head pose is used: the gaze
columns may be absent, and each person's head-gaze coupling is learnt.
All files must share one world frame. A person is named by the file's stem
unless --people is given (one name per person, in the order above). Frames
are aligned on the union of the frame ids of all files; a person missing from
a frame is absent there. Frame times are the timestamps when every file has
them, else frame / --fps.

--speech (RTTM or CSV of start, end, speaker; seconds, same clock) gives who
speaks when; speakers are matched to the people by name (--speaker-map to map
them). A speaker that matches nobody is ignored with a warning; a person with no
speech never speaks. Without --speech there is no speaker prior.

"""

#: The per-frame table in words (the ``jaxgaze joint`` help shows it).
JOINT_FRAMES_FORMAT = """\
PER_FRAME.csv has one row per frame and person (frame-major):
  frame, time (s), person, present (0/1),
  target       the most probable target: a person's name, 'concurrence K'
               (a shared gaze target found by the model) or 'elsewhere',
  probability  the posterior probability of that target,
  p_<candidate> the probability of every candidate (people, concurrence_0, ...,
               elsewhere; blanks in names become '_'); they sum to 1,
  mutual_with  the partner most probably in mutual gaze with the person
               (each looks at the other), empty when that is 0 to 6 decimals,
  p_mutual     that probability,
  alternative_target, alternative_probability, alternative_weight
               where the fit is ambiguous about the person (another bias
               explains their gaze nearly as well): the most probable target
               under that other explanation, its probability, and the
               explanation's weight; empty otherwise.
Rows of an absent person have present 0 and every other cell empty.
"""

_DIGITS = 6


def _column_name(candidate: str) -> str:
    return "p_" + re.sub(r"\s+", "_", str(candidate).strip())


def joint_frame_columns(candidates) -> tuple[str, ...]:
    """The header of the per-frame table for ``candidates`` (people, concurrences, ``elsewhere``, in
    membership order); ``ValueError`` when two candidates give the same ``p_`` column."""
    probabilities = [_column_name(c) for c in candidates]
    columns = JOINT_FRAME_COLUMNS[:6] + tuple(probabilities) + JOINT_FRAME_COLUMNS[6:]
    seen = {}
    for candidate, column in zip(candidates, probabilities):
        if column in seen or column in JOINT_FRAME_COLUMNS:
            other = seen.get(column, column)
            raise ValueError(f"candidates {other!r} and {candidate!r} give the same column {column!r}; rename one")
        seen[column] = candidate
    return columns


def _probability(value) -> str:
    value = float(value)
    if not math.isfinite(value):
        return ""
    return repr(round(min(max(value, 0.0), 1.0), _DIGITS))


def write_joint_frames(path, posterior, frames, times) -> int:
    """Write the per-frame table (:data:`JOINT_FRAMES_FORMAT`) of ``posterior`` atomically.

    Args:
        path: the CSV to write.
        posterior: a :class:`~jaxgaze.joint.JointPosterior` (or anything with ``people``,
            ``candidates``, ``membership (T, P, C)`` and ``mutual (T, P, P)``).
        frames: ``(T,)`` frame ids of the rows of ``membership``.
        times: ``(T,)`` their times, seconds.

    Returns the number of rows written (``T · P``). Raises ``ValueError`` for shapes that
    do not match; ``OSError`` propagates (no file is left).
    """
    people = tuple(str(p) for p in posterior.people)
    candidates = tuple(str(c) for c in posterior.candidates)
    membership = np.asarray(posterior.membership, dtype=np.float64)
    mutual = np.asarray(posterior.mutual, dtype=np.float64)
    if membership.ndim != 3 or membership.shape[1:] != (len(people), len(candidates)):
        raise ValueError(f"membership must have shape (T, {len(people)}, {len(candidates)}) (frames, people, "
                         f"candidates), got {membership.shape}")
    T, P, _ = membership.shape
    if mutual.shape != (T, P, P):
        raise ValueError(f"mutual must have shape {(T, P, P)}, got {mutual.shape}")
    frames, times = list(frames), list(times)
    if len(frames) != T or len(times) != T:
        raise ValueError(f"frames and times must give one value per frame of the posterior ({T}), got "
                         f"{len(frames)} and {len(times)}")
    columns = joint_frame_columns(candidates)
    alternative = {}  # person → (target (T,), probability (T,), weight) of their heaviest alternative
    for a in sorted(getattr(posterior, "alternatives", ()), key=lambda a: a.weight):
        chance = np.asarray(a.membership, dtype=np.float64)
        alternative[int(a.person)] = (np.argmax(chance, axis=-1), chance.max(axis=-1), float(a.weight))
    present = membership.sum(axis=-1) > 0
    best = np.argmax(membership, axis=-1)
    # Mutual gaze with oneself is not a thing: the diagonal never wins.
    others = np.where(np.eye(P, dtype=bool)[None], -np.inf, mutual)
    partner = np.argmax(others, axis=-1)
    p_partner = np.take_along_axis(others, partner[..., None], axis=-1)[..., 0]
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as handle:
        writer = csv_writer(handle)
        writer.writerow(columns)
        for t in range(T):
            frame = int(frames[t])
            time = format_float(round(float(times[t]), 9))
            for i in range(P):
                if not present[t, i]:
                    writer.writerow([frame, time, people[i], 0] + [""] * (len(columns) - 4))
                    continue
                k = int(best[t, i])
                chance = _probability(max(float(p_partner[t, i]), 0.0) if P > 1 else 0.0)
                other = alternative.get(i)
                writer.writerow([frame, time, people[i], 1, candidates[k], _probability(membership[t, i, k]),
                                 *(_probability(p) for p in membership[t, i]),
                                 people[int(partner[t, i])] if chance not in ("", "0.0") else "", chance or "0.0",
                                 *((candidates[int(other[0][t])], _probability(other[1][t]), _probability(other[2]))
                                   if other else ("", "", ""))])
    return T * P


#: Units of the joint model's variables, written into their netCDF attributes ("1": no unit).
NETCDF_UNITS = {"bias": "rad", "cone_width": "rad", "alpha_person": "1", "alpha_object": "1", "speaker_effect": "1",
                "stay": "1", "concurrence_offset": "1", "concurrence_drift": "1", "concurrence_locations": "m",
                "eye_offset": "m", "calibration_outlier_share": "1", "gaze_angles": "rad", "present": "1",
                "speaking": "1", "diverging": "1", "acceptance_rate": "1", "n_steps": "1", "lp": "1",
                "coupling": "1", "head_lag": "s", "tilt_width_ratio": "1", "held_spread": "1", "held_cone_share": "1", "head_motion": "rad, rad, rad/s, rad/s, 1/s (see coordinate motion)"}


def write_joint_netcdf(path, posterior) -> str:
    """Write ``posterior.sampler.idata`` (an arviz ``InferenceData``) to ``path`` as netCDF, atomically; returns ``path``.

    Read it back with ``arviz.from_netcdf(path)``. Each sampler chain is written as its two halves
    (:func:`jaxgaze.nuts.split_chains`), so that arviz's ``az.summary`` gives the split r-hat and ESS
    reported, and every variable has its ``units`` attribute (:data:`NETCDF_UNITS`).
    """
    idata = split_chains(posterior.sampler.idata)
    if hasattr(idata, "groups"):
        set_units(idata, NETCDF_UNITS)
        _set_result(idata, posterior)
    with atomic_path(path) as tmp:
        idata.to_netcdf(tmp)
    return str(path)


def _set_result(idata, posterior) -> None:
    """The fit's ``result`` and its ``alternatives`` (JSON: person, bias and sd in degrees, weight, log evidence
    gap) as attributes of the posterior group, and ``spot_log_bayes_factor`` where a fixation's spot was asked for
    (``shape_log_bayes_factor`` where a Gaussian-process head-gaze map was)."""
    result = getattr(posterior, "result", None)
    if result is None or "posterior" not in idata.groups():
        return
    people = list(posterior.people)
    idata.posterior.attrs["result"] = name(result)
    idata.posterior.attrs["alternatives"] = json.dumps([
        {"person": people[a.person], "bias_deg": np.degrees(a.bias).round(4).tolist(),
         "bias_sd_deg": np.degrees(a.bias_sd).round(4).tolist(), "weight": round(float(a.weight), 6),
         "log_evidence_gap": round(float(a.log_evidence_gap), 6)} for a in getattr(posterior, "alternatives", ())])
    for attr in ("spot_log_bayes_factor", "shape_log_bayes_factor"):  # asked for: a spot, a GP head-gaze map
        factor = getattr(posterior, attr, None)
        if factor is not None:
            idata.posterior.attrs[attr] = round(float(factor), 6)
