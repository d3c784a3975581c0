"""The shipped example inputs (``examples/``): every file the READMEs name exists, every command
they show parses, and the fast commands give the simulators' truth (``examples/truth.json``) on them."""

import csv
import json
import pathlib
import re
import shlex

import numpy as np
import pytest

from jaxgaze.cli import build_parser, main
from jaxgaze.io.joint import read_joint_gaze, read_speech, speaking_by_person
from jaxgaze.io.poses import read_colmap_images, read_pose_csv
from jaxgaze.io.rays import read_rays_csv

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
TRUTH = json.loads((EXAMPLES / "truth.json").read_text())
GUIDE = (EXAMPLES / "README.md").read_text()
README = (ROOT / "README.md").read_text()


def _commands(text: str) -> list[list[str]]:
    """The ``jaxgaze ...`` lines of the bash blocks of a markdown text, split into arguments."""
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    return [shlex.split(line, comments=True)[1:] for block in blocks for line in block.splitlines()
            if line.startswith("jaxgaze ")]


def test_every_file_named_exists_and_every_shipped_file_is_named():
    named = set(re.findall(r"(?:concurrences|calibrate|bias|joint|convert)/[\w./-]+\.\w+", GUIDE))
    named |= {name for name in ("truth.json", "make_examples.py") if f"`{name}`" in GUIDE}
    shipped = {p.relative_to(EXAMPLES).as_posix() for p in EXAMPLES.rglob("*")
               if p.is_file() and p.name != "README.md" and "__pycache__" not in p.parts}
    assert len(named) >= 16
    assert named == shipped, (named - shipped, shipped - named)
    in_readme = set(re.findall(r"examples/[\w/.-]*[\w/]", README))
    assert {"examples/README.md", "examples/truth.json"} <= in_readme
    assert all((ROOT / path).exists() for path in in_readme), in_readme
    assert sum(p.stat().st_size for p in EXAMPLES.rglob("*") if p.is_file()) < 1_000_000  # small


def test_every_command_shown_parses_and_its_inputs_exist():
    commands = _commands(GUIDE) + _commands(README[README.index("## Example inputs"):README.index("## Use")])
    shown = {argv[0] for argv in commands}
    assert shown == {"concurrences", "calibrate", "bias", "joint", "fit-gaze", "attend", "demo", "convert"}
    parser = build_parser()
    for argv in commands:
        parser.parse_args(argv)  # an option renamed or gone: SystemExit
        for arg in argv:
            if arg.startswith("examples/"):
                assert (ROOT / arg).is_file(), arg


def _check_concurrences(out, truth_m: dict, frames: int, within_m: float = 0.2):
    """The concurrences CSV ``out`` against the truth ``{frame: [[x, y, z], ...]}``: the right count in 90 % of
    the frames, and there every true concurrence has an estimate within ``within_m``."""
    with open(out, newline="") as handle:
        rows = list(csv.DictReader(handle))
    found = {}
    for row in rows:
        found.setdefault(int(row["frame"]), []).append([float(row[c]) for c in "xyz"])
    truth = {int(t): np.asarray(points).reshape(-1, 3) for t, points in truth_m.items()}
    assert len(truth) == frames
    right_count = [len(found.get(t, [])) == len(points) for t, points in truth.items()]
    assert np.mean(right_count) >= 0.9
    # every true concurrence of a frame with the right count has an estimate within 20 cm
    for t, points in truth.items():
        if len(found.get(t, [])) == len(points):
            distance = np.linalg.norm(np.asarray(found[t])[:, None] - points[None], axis=-1).min(axis=0)
            assert np.all(distance < within_m), (t, distance)


def test_concurrences_example(tmp_path, capsys):
    out = tmp_path / "concurrences.csv"
    assert main(["concurrences", str(EXAMPLES / "concurrences/rays.csv"), "--out", str(out), "-q",
                 "--chunk", "12"]) == 0, capsys.readouterr().err
    _check_concurrences(out, TRUTH["concurrences"]["rays.csv"]["concurrences_m"], 30)


@pytest.mark.parametrize(("tool", "within_m"), [("gaze360", 0.2), ("openface", 0.4)])
def test_convert_example_camera_tools_then_concurrences(tool, within_m, tmp_path, capsys):
    """A fixed camera's Gaze360 or OpenFace file, placed in the world by its pose, converts to rays whose
    concurrences are the simulator's (the commands of examples/README.md). OpenFace reports no uncertainty:
    its rays get the cone of its published error (0.127 rad, 6 × the scene's 0.022), which pulls a mode made of
    three rays (a frame where people switch) up to 36 cm toward the others."""
    rays, out = tmp_path / "rays.csv", tmp_path / "concurrences.csv"
    d = EXAMPLES / "convert"
    assert main(["convert", "--from", tool, str(d / f"{tool}.csv"), "--camera-poses", str(d / "camera.csv"),
                 "--out", str(rays), "-q"]) == 0, capsys.readouterr().err
    assert main(["concurrences", str(rays), "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    _check_concurrences(out, TRUTH["convert"][f"{tool}.csv"]["concurrences_m"], 10, within_m)


def test_convert_example_pupil_wearer(tmp_path, capsys):
    """One Pupil Core wearer, placed in the world by her scene camera's poses: her rays point within 5° of what
    she looks at (the simulated gaze errs by up to 3° here), she is named after her recording folder, and one person
    alone shares no concurrence."""
    rays, out = tmp_path / "rays.csv", tmp_path / "concurrences.csv"
    d = EXAMPLES / "convert"
    assert main(["convert", "--from", "pupil", str(d / "ann/exports/000/gaze_positions.csv"), "--camera-poses",
                 str(d / "ann_scene_camera.csv"), "--out", str(rays), "-q"]) == 0, capsys.readouterr().err
    truth = TRUTH["convert"]["ann/exports/000/gaze_positions.csv"]
    recording = read_rays_csv(rays)
    assert recording.persons == [[truth["person"]]] * len(truth["looks_at_m"])
    # the gaze's own 10 Hz frames (every datum kept), each placed by the pose of its scene frame (world_index 0, 3, …)
    assert recording.frame_ids == list(range(len(truth["looks_at_m"])))
    origins, directions = (np.asarray(a, float)[:, 0] for a in (recording.rays.origins, recording.rays.directions))
    offset = np.asarray(list(truth["looks_at_m"].values())) - origins
    depth = np.einsum("ij,ij->i", offset, directions)
    miss = np.linalg.norm(offset - depth[:, None] * directions, axis=1)
    assert np.all(depth > 0.5) and np.all(np.arctan2(miss, depth) < np.radians(5.0)), np.arctan2(miss, depth)
    assert main(["concurrences", str(rays), "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    with open(out, newline="") as handle:
        assert list(csv.DictReader(handle)) == []


def test_calibrate_example_and_its_colmap_twin(tmp_path, capsys):
    out = tmp_path / "calib.json"
    a, b = (str(EXAMPLES / f"calibrate/wearer_{w}.csv") for w in "ab")
    assert main(["calibrate", a, b, "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    calib = json.loads(out.read_text())
    truth = TRUTH["calibrate"]["wearer_a"]
    direction, true_direction = np.asarray(calib["direction"]), np.asarray(truth["direction"])
    assert np.degrees(np.arccos(np.clip(direction @ true_direction, -1, 1))) < 2.0
    # the eye centre: well pinned across the gaze, poorly along it (the depth)
    error = np.asarray(calib["eye_center"]) - np.asarray(truth["eye_center_m"])
    assert np.linalg.norm(error - (error @ true_direction) * true_direction) < 0.08
    assert np.linalg.norm(error) < 0.3
    for w in "ab":  # the COLMAP files hold the same poses
        csv_poses = read_pose_csv(EXAMPLES / f"calibrate/wearer_{w}.csv")
        colmap = read_colmap_images(EXAMPLES / f"calibrate/wearer_{w}_images.txt")
        np.testing.assert_array_equal(colmap.frame_ids, csv_poses.frame_ids)
        np.testing.assert_allclose(colmap.centers, csv_poses.centers, atol=1e-6)
        np.testing.assert_allclose(colmap.R_camera_from_world, csv_poses.R_camera_from_world, atol=1e-6)


def test_bias_example_from_openface(tmp_path, capsys):
    out = tmp_path / "bias.json"
    d = EXAMPLES / "bias"
    status = main(["bias", str(d / "ann_openface.csv"), "--speech", str(d / "dyad.rttm"), "--partner", "ben",
                   "--targets", str(d / "ann_targets_camera.csv"), "--method", "lmeds", "--out", str(out), "-q"])
    assert status == 0, capsys.readouterr().err
    record = json.loads(out.read_text())
    assert np.linalg.norm(np.asarray(record["bias_deg"]) - TRUTH["bias"]["ann"]["bias_deg"]) < 2.0
    # the gaze CSV of the same recording, and the segments CSV of the same turns
    assert main(["bias", str(d / "ann_gaze.csv"), "--speech", str(d / "dyad_segments.csv"), "--partner", "ben",
                 "--method", "lmeds", "--out", str(out), "-q"]) == 0, capsys.readouterr().err
    record = json.loads(out.read_text())
    assert np.linalg.norm(np.asarray(record["bias_deg"]) - TRUTH["bias"]["ann"]["bias_deg"]) < 2.0


@pytest.mark.parametrize("speech", ["speech.rttm", "speech_segments.csv"])
def test_joint_example_reads(speech):
    """The joint command's inputs read and line up (the fit itself runs NUTS: too slow here)."""
    d = EXAMPLES / "joint"
    gaze = read_joint_gaze([d / f"{name}.csv" for name in ("ann", "ben", "cat")])
    assert gaze.eye_positions.shape[1:] == (3, 3) and gaze.time is not None
    assert gaze.present.mean() > 0.8 and np.all(np.isfinite(gaze.gaze_angles[gaze.present]))
    speaking, unmatched = speaking_by_person(read_speech(d / speech), ("ann", "ben", "cat"), gaze.time)
    assert unmatched == [] and set(speaking) <= {"ann", "ben", "cat"} and len(speaking) >= 2
    assert all(0 < np.mean(flags) < 1 for flags in speaking.values())
