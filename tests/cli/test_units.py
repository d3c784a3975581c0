"""One unit rule in every command that reads positions or angles (issue 34, item 5).

Implausible units (millimetres for metres) are exit 2 with one line naming the file and what looks
wrong, and no output file; ``--trust-units`` (the same flag everywhere) turns them into a warning
and the command runs. ``concurrences`` is tested in ``test_concurrences_demo.py``
(``test_concurrences_units_caught_at_the_door``), next to its compiled programs.
"""

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from tests import helpers as zoo
from tests.cli.helpers import assert_failed, run_main

import jaxgaze.joint
from jaxgaze.cli import build_parser
from jaxgaze.io.poses import write_pose_csv
from jaxgaze.poses import CameraPoses

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
EXAMPLES = ROOT / "examples"
RULE = "pass --trust-units if they are right"


def scaled(src, dst, columns, factor=1000.0):
    """``src`` with ``columns`` multiplied by ``factor`` (metres → millimetres)."""
    with open(src, newline="") as f:
        rows = list(csv.reader(f))
    header = [c.strip().lower() for c in rows[0]]
    index = [header.index(c) for c in columns]
    for row in rows[1:]:
        for i in index:
            row[i] = repr(float(row[i]) * factor)
    with open(dst, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return dst


def test_every_command_that_reads_positions_has_the_one_override():
    commands = build_parser()._subparsers._group_actions[0].choices
    with_flag = {name for name, parser in commands.items()
                 if any("--trust-units" in a.option_strings for a in parser._actions)}
    assert with_flag == {"concurrences", "convert", "calibrate", "bias", "joint"}


@pytest.mark.parametrize("tool, columns", [("gaze360", ["person_eyes3d_x", "person_eyes3d_y", "person_eyes3d_z"]),
                                           ("l2cs", ["eye_x", "eye_y", "eye_z"])])
def test_convert(tool, columns, tmp_path, capsys):
    src = DATA / f"{tool}_dump.csv"
    mm = scaled(src, tmp_path / f"{tool}_mm.csv", columns)
    out = tmp_path / "rays.csv"
    status, stdout, stderr = run_main(capsys, ["convert", "--from", tool, mm, "--out", out])
    # Frame 3 (its third row of frames) holds two faces 1 m apart: 1000 "m" in millimetres.
    assert_failed(status, stdout, stderr, "the eyes of frame 3 spread over 1000 m", "(millimetres?)", RULE, str(mm))
    assert not out.exists()
    status, stdout, stderr = run_main(capsys, ["convert", "--from", tool, mm, "--out", out, "--trust-units", "-q"])
    assert status == 0 and stderr.startswith("jaxgaze: warning: the eyes of frame 3 spread over 1000 m")
    with open(out, newline="") as f:
        origins = np.array([[float(r[c]) for c in ("ox", "oy", "oz")] for r in csv.DictReader(f)])
    status, _, _ = run_main(capsys, ["convert", "--from", tool, src, "--out", tmp_path / "metres.csv", "-q"])
    with open(tmp_path / "metres.csv", newline="") as f:
        metres = np.array([[float(r[c]) for c in ("ox", "oy", "oz")] for r in csv.DictReader(f)])
    np.testing.assert_allclose(origins, 1000.0 * metres, rtol=1e-6)


def test_convert_one_face_in_millimetres_is_far_from_the_camera(tmp_path, capsys):
    """One face per frame has no spread: the distance from the camera catches it."""
    with open(DATA / "l2cs_dump.csv", newline="") as f:
        rows = [r for r in csv.reader(f)]
    one = tmp_path / "one.csv"
    with open(one, "w", newline="") as f:
        csv.writer(f).writerows([rows[0]] + [r for r in rows[1:] if r[1] == "0"])
    mm = scaled(one, tmp_path / "one_mm.csv", ["eye_x", "eye_y", "eye_z"])
    status, stdout, stderr = run_main(capsys, ["convert", "--from", "l2cs", mm, "--out", tmp_path / "o.csv"])
    assert_failed(status, stdout, stderr, "an eye's distance from the camera reaches 2000 m (frame 1)",
                  "(millimetres?)", RULE, str(mm))
    status, _, _ = run_main(capsys, ["convert", "--from", "l2cs", one, "--out", tmp_path / "o.csv", "-q"])
    assert status == 0  # metres pass


@pytest.fixture(scope="module")
def session():
    s = zoo.calibration_session(80)
    frames = np.asarray(s.frame_ids)
    a = CameraPoses(np.asarray(s.R_camera_from_world_a, float), np.asarray(s.centers_a, float), frames)
    b = CameraPoses(np.asarray(s.R_camera_from_world_b, float), np.asarray(s.centers_b, float), frames)
    return a, b


def test_calibrate_in_millimetres(session, tmp_path, capsys):
    """With --trust-units the fit itself refuses the eye centre (test_calibrate.py: a session close by, trusted)."""
    a, b = session
    write_pose_csv(tmp_path / "a.csv", a._replace(centers=1000 * a.centers))
    write_pose_csv(tmp_path / "b.csv", b._replace(centers=1000 * b.centers))
    out = tmp_path / "calib.json"
    status, stdout, stderr = run_main(capsys, ["calibrate", tmp_path / "a.csv", tmp_path / "b.csv", "--out", out])
    assert_failed(status, stdout, stderr, "positions look like millimetres", RULE, str(tmp_path / "a.csv"))
    assert not out.exists()


def test_bias_in_millimetres(tmp_path, capsys):
    """Eyes and targets in millimetres: exit 2; trusted, the bias is the one of metres (it uses directions only)."""
    mm = scaled(EXAMPLES / "bias" / "ann_gaze.csv", tmp_path / "ann_mm.csv", ["ex", "ey", "ez", "tx", "ty", "tz"])
    speech = ["--speech", EXAMPLES / "bias" / "dyad_segments.csv", "--partner", "ben", "--method", "lmeds"]
    out = tmp_path / "bias.json"
    status, stdout, stderr = run_main(capsys, ["bias", mm, *speech, "--out", out])
    assert_failed(status, stdout, stderr, "the distance from the eyes to the target reaches", "(millimetres?)",
                  RULE, str(mm))
    assert not out.exists()
    status, _, stderr = run_main(capsys, ["bias", mm, *speech, "--out", out, "--trust-units", "-q"])
    assert status == 0 and stderr.startswith("jaxgaze: warning: the distance from the eyes to the target")
    metres = tmp_path / "metres.json"
    status, _, _ = run_main(capsys, ["bias", EXAMPLES / "bias" / "ann_gaze.csv", *speech, "--out", metres, "-q"])
    assert status == 0
    np.testing.assert_allclose(json.loads(out.read_text())["bias_deg"], json.loads(metres.read_text())["bias_deg"],
                               atol=1e-6)


def test_bias_targets_in_millimetres_name_the_targets_file(tmp_path, capsys):
    targets = scaled(EXAMPLES / "bias" / "ann_targets_camera.csv", tmp_path / "targets_mm.csv", ["tx", "ty", "tz"])
    status, stdout, stderr = run_main(capsys, ["bias", EXAMPLES / "bias" / "ann_openface.csv", "--speech",
                                               EXAMPLES / "bias" / "dyad.rttm", "--partner", "ben", "--targets",
                                               targets, "--method", "lmeds", "--out", tmp_path / "b.json"])
    assert_failed(status, stdout, stderr, "the distance from the eyes to the target", RULE, str(targets))


class Reached(Exception):
    """The fit was reached."""


def test_joint_in_millimetres(tmp_path, capsys, monkeypatch):
    """ben in millimetres: exit 2 naming ben's file; with --trust-units the data reach the fit."""
    gaze = [EXAMPLES / "joint" / f"{name}.csv" for name in ("ann", "ben", "cat")]
    gaze[0] = Path(shutil.copy(gaze[0], tmp_path / "ann.csv"))
    gaze[1] = scaled(gaze[1], tmp_path / "ben.csv", ["ex", "ey", "ez"])

    def fit(data, *args, **kwargs):
        raise Reached(float(np.abs(data.eye_positions).max()))

    monkeypatch.setattr(jaxgaze.joint, "fit_joint", fit)
    out = tmp_path / "joint.nc"
    status, stdout, stderr = run_main(capsys, ["joint", *gaze, "--out", out])
    assert_failed(status, stdout, stderr, "eye_positions of person 'ben' at frame", "(millimetres?)", RULE,
                  f"({gaze[1]})")
    with pytest.raises(Reached) as reached:
        run_main(capsys, ["joint", *gaze, "--out", out, "--trust-units"])
    assert float(str(reached.value)) > 100.0  # the millimetres themselves, as trusted
    assert "jaxgaze: warning: eye_positions of person 'ben'" in capsys.readouterr().err
