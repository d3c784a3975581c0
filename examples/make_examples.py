"""Write the example inputs of every ``jaxgaze`` command (see README.md here), from the simulators.

    python examples/make_examples.py            # rewrites the files next to this script

Every file comes from :mod:`jaxgaze.simulate` with a fixed key, so the output is the same on
every run; the readers' formats are written by :mod:`jaxgaze.io` where it has a writer (rays,
poses) and here otherwise (gaze CSV, OpenFace 2 CSV, RTTM, segments CSV). World frame: +z up,
metres; camera frame (ours): +x forward, +y left, +z up; angles in radians. The simulators'
truth goes to ``truth.json`` (what a good answer is near).
"""

from __future__ import annotations

import csv
import json
import pathlib

import jax
import numpy as np

from jaxgaze.io.tools.openface import OPENFACE_COLUMNS, openface_pose_and_gaze
from jaxgaze.io.poses import write_colmap_images, write_pose_csv
from jaxgaze.io.rays import RayRecording, write_rays_csv
from jaxgaze.poses import CameraPoses, matrices_to_quaternions
from jaxgaze.simulate import simulate_calibration_session, simulate_conversation, simulate_dyadic, simulate_scene
from jaxgaze.simulate import partner_camera_view

HERE = pathlib.Path(__file__).resolve().parent
GAZE_HEADER = ("frame", "timestamp", "yaw", "tilt", "qw", "qx", "qy", "qz", "ex", "ey", "ez")
OPENFACE_HEADER = ("frame", "face_id", "timestamp", "confidence", "success", "gaze_angle_x", "gaze_angle_y",
                   "pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz", "AU01_r")


def _g(x) -> str:
    """7 significant digits: micrometres and microradians, a few KB less per file than full precision."""
    return f"{float(x):.7g}"


def _write_csv(path: pathlib.Path, header, rows) -> pathlib.Path:
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(rows)
    return path


def _runs(flags) -> list[tuple[int, int]]:
    """``[(start, end)]`` frame ranges of the True runs of a boolean array."""
    padded = np.concatenate([[False], np.asarray(flags, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _speech(directory: pathlib.Path, name: str, recording: str, speaking, speakers, fps: float) -> None:
    """``speaking`` ``(P, T)`` as an RTTM (``name``.rttm) and a segments CSV (``name``_segments.csv)."""
    lines, segments = [], []
    for speaker, flags in zip(speakers, speaking):
        for start, end in _runs(flags):
            lines.append(f"SPEAKER {recording} 1 {start / fps:.3f} {(end - start) / fps:.3f} <NA> <NA> {speaker} "
                         "<NA> <NA>")
            segments.append([f"{start / fps:.3f}", f"{end / fps:.3f}", speaker])
    (directory / f"{name}.rttm").write_text("\n".join(lines) + "\n", encoding="utf-8")
    _write_csv(directory / f"{name}_segments.csv", ("start", "end", "speaker"), sorted(segments, key=lambda s:
                                                                                        float(s[0])))


def concurrences(directory: pathlib.Path) -> dict:
    """``rays.csv``: 30 frames (3 s) of the simulated meeting, all three phases of its story."""
    scene = simulate_scene(jax.random.key(0), "meeting", num_frames=30)
    people = [f"p{n:02d}" for n in range(scene.num_people)]
    write_rays_csv(directory / "rays.csv", RayRecording(list(range(scene.num_frames)),
                                                        [people] * scene.num_frames, scene.rays))
    truth, valid = np.asarray(scene.concurrences, float), np.asarray(scene.concurrence_valid, bool)
    return {"rays.csv": {"concurrences_m": {str(t): np.round(truth[t][valid[t]], 4).tolist()
                                            for t in range(scene.num_frames)}}}


def calibrate(directory: pathlib.Path) -> dict:
    """Wearer A looks at B's head-mounted camera for 80 frames: both cameras' poses as pose CSVs and
    as COLMAP ``images.txt``."""
    session = simulate_calibration_session(jax.random.key(2), num_frames=80)
    frames = np.asarray(session.frame_ids)
    for name, R, centres in (("wearer_a", session.R_camera_from_world_a, session.centers_a),
                             ("wearer_b", session.R_camera_from_world_b, session.centers_b)):
        poses = CameraPoses(np.asarray(R, float), np.asarray(centres, float), frames)
        write_pose_csv(directory / f"{name}.csv", poses)
        write_colmap_images(directory / f"{name}_images.txt", poses)
    return {"wearer_a": {"eye_center_m": np.round(np.asarray(session.eye_center_a, float), 5).tolist(),
                         "direction": np.round(np.asarray(session.direction_a, float), 6).tolist()}}


def _openface(rec, person: int, fps: float):
    """Rows of an OpenFace 2 FeatureExtraction CSV of ``person`` filmed by a fixed camera 25 cm below
    and 15 cm beside the partner's eyes, and the partner's eye midpoint in our camera frame."""
    view = partner_camera_view(rec, person)
    columns = openface_pose_and_gaze(view.R_camera_from_head, view.head_position_camera, view.gaze_direction_camera)
    success = view.faces_camera  # eyes turned away from the camera: OpenFace loses them
    rows = []
    for t in range(len(success)):
        values = [columns[c][t] for c in OPENFACE_COLUMNS[4:]] if success[t] else [0.0] * 8
        rows.append([t + 1, 0, f"{t / fps:.3f}", "0.98" if success[t] else "0.00", int(success[t]),
                     *(f"{v:.6f}" for v in values), "0.25"])  # OpenFace counts frames from 1
    return rows, view.target_camera


def _gaze_rows(frames, fps, gaze, R_world_from_head, eyes, targets=None):
    """Rows of our gaze CSV: frame, timestamp, yaw, tilt (head frame), R_world_from_head, eyes (and targets)."""
    q = matrices_to_quaternions(np.asarray(R_world_from_head, float))
    return [[int(t), f"{t / fps:.3f}", *map(_g, gaze[t]), *map(_g, q[t]), *map(_g, eyes[t]),
             *([] if targets is None else map(_g, targets[t]))] for t in frames]


def bias(directory: pathlib.Path) -> dict:
    """A 60 s dyadic interview at 10 fps; person 0 is ann, her partner ben."""
    fps = 10.0
    rec = simulate_dyadic(jax.random.key(3), "interview", duration_s=60.0, fps=fps)
    eye, target = np.asarray(rec.eye_positions[0], float), np.asarray(rec.target_positions[0], float)
    frames = range(len(eye))
    _write_csv(directory / "ann_gaze.csv", GAZE_HEADER + ("tx", "ty", "tz"),
               _gaze_rows(frames, fps, np.asarray(rec.gaze_angles[0], float), rec.R_world_from_head[0], eye, target))
    rows, target_camera = _openface(rec, 0, fps)
    (directory / "ann_openface.csv").write_text(
        ", ".join(OPENFACE_HEADER) + "\n" + "\n".join(", ".join(map(str, r)) for r in rows) + "\n", encoding="utf-8")
    _write_csv(directory / "ann_targets_camera.csv", ("frame", "tx", "ty", "tz"),
               [[t + 1, *map(_g, target_camera[t])] for t in frames])
    _speech(directory, "dyad", "dyad", np.asarray(rec.speaking, bool), ("ann", "ben"), fps)
    return {"ann": {"bias_deg": np.round(np.degrees(np.asarray(rec.bias[0], float)), 3).tolist()}}


def joint(directory: pathlib.Path) -> dict:
    """A 10 s conversation of three people at 5 fps, one gaze CSV per person (frames where the
    person is out of view are left out) and who speaks when."""
    fps, names = 5.0, ("ann", "ben", "cat")
    scene = simulate_conversation(jax.random.key(0), num_people=3, num_objects=1, duration_s=10.0, fps=fps)
    for p, name in enumerate(names):
        frames = np.flatnonzero(np.asarray(scene.present)[:, p])
        _write_csv(directory / f"{name}.csv", GAZE_HEADER,
                   _gaze_rows(frames, fps, np.asarray(scene.gaze_angles)[:, p], np.asarray(scene.R_world_from_head)
                              [:, p], np.asarray(scene.eye_positions)[:, p]))
    _speech(directory, "speech", "meeting", np.asarray(scene.speaking, bool).T, names, fps)
    bias_deg = np.round(np.degrees(np.asarray(scene.bias, float)), 3)
    return {name: {"bias_deg": bias_deg[p].tolist()} for p, name in enumerate(names)}


def _world_from_camera(forward_xy) -> np.ndarray:
    """``R_world_from_camera`` of an upright camera (ours: +x forward, +y left, +z up) facing ``forward_xy``."""
    forward = np.array([*forward_xy, 0.0]) / np.hypot(*forward_xy)
    return np.stack([forward, np.cross([0.0, 0.0, 1.0], forward), [0.0, 0.0, 1.0]], axis=1)


def convert(directory: pathlib.Path) -> dict:
    """Other tools' outputs for ``jaxgaze convert``: every third frame of the meeting of ``concurrences/rays.csv``
    (10 frames) seen by a fixed camera 6 m in front of the group (``camera.csv``) as Gaze360 and OpenFace 2
    multi-face CSVs, and one person's (``p03``, ann) Pupil Core export, her scene camera on her head facing
    where she looks, with its poses (``ann_scene_camera.csv``)."""
    from jaxgaze.io.tools.gaze360 import write_gaze360
    from jaxgaze.io.tools.openface import write_openface_rays
    from jaxgaze.io.tools.pupil import write_pupil

    scene = simulate_scene(jax.random.key(0), "meeting", num_frames=30)
    frames = np.arange(0, scene.num_frames, 3)
    people = [f"p{n:02d}" for n in range(scene.num_people)]
    rays = jax.tree_util.tree_map(lambda a: np.asarray(a)[frames], scene.rays)
    recording = RayRecording(frames.tolist(), [people] * len(frames), rays)
    camera = CameraPoses(_world_from_camera((0.0, 1.0)).T[None], np.array([[0.0, -6.0, 1.6]]), np.array([0]))
    write_pose_csv(directory / "camera.csv", camera)  # one pose: a fixed camera, for every frame
    write_gaze360(directory / "gaze360.csv", recording, camera=camera)
    write_openface_rays(directory / "openface.csv", recording._replace(frame_ids=(frames + 1).tolist()),
                        camera=camera, fps=scene.fps)  # OpenFace counts frames from 1

    ann = 3  # the wearer: her scene camera sits on her eyes, upright, facing her gaze's heading
    eyes, gaze = np.asarray(rays.origins, float)[:, ann], np.asarray(rays.directions, float)[:, ann]
    head = CameraPoses(np.stack([_world_from_camera(g[:2]).T for g in gaze]), eyes, frames)
    wearer = RayRecording(frames.tolist(), [["ann"]] * len(frames),
                          jax.tree_util.tree_map(lambda a: np.asarray(a)[:, ann:ann + 1], rays))
    (directory / "ann" / "exports" / "000").mkdir(parents=True, exist_ok=True)
    write_pupil(directory / "ann" / "exports" / "000" / "gaze_positions.csv", wearer, camera=head)
    write_pose_csv(directory / "ann_scene_camera.csv", head)

    truth, valid = np.asarray(scene.concurrences, float), np.asarray(scene.concurrence_valid, bool)
    targets = np.asarray(scene.targets, float)[frames, ann]
    found = {t: np.round(truth[t][valid[t]], 4).tolist() for t in frames.tolist()}
    return {"gaze360.csv": {"concurrences_m": {str(t): points for t, points in found.items()}},
            "openface.csv": {"concurrences_m": {str(t + 1): points for t, points in found.items()}},
            "ann/exports/000/gaze_positions.csv": {"person": "ann", "looks_at_m": {
                str(t): np.round(target, 4).tolist() for t, target in zip(frames.tolist(), targets)}}}


def main() -> None:
    truth = {}
    for make in (concurrences, calibrate, bias, joint, convert):
        directory = HERE / make.__name__
        directory.mkdir(exist_ok=True)
        truth[make.__name__] = make(directory)
    with open(HERE / "truth.json", "w", encoding="utf-8") as handle:
        json.dump(truth, handle, indent=1)
        handle.write("\n")
    files = sorted(p for p in HERE.rglob("*") if p.is_file() and p.suffix != ".py" and p.name != "README.md")
    total = sum(p.stat().st_size for p in files)
    print(f"wrote {len(files)} files, {total / 1024:.0f} KiB, under {HERE}")


if __name__ == "__main__":
    main()
