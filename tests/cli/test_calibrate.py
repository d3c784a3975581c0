"""``jaxgaze calibrate`` and ``jaxgaze concurrences --calibration``.

A simulated calibration session (two wearers looking at each other's camera)
is written as a pose CSV (wearer A) and a COLMAP ``images.txt`` (wearer B); the
command must recover A's primary gaze ray. A tiny hand-made scene of three
calibrated wearers whose rays meet at known points checks the concurrences path.
Every failure is status 2, one stderr line, and no output file.
"""

import csv
import json
import math
import os
import sys
import warnings

import jax
import numpy as np
import pytest
from tests import helpers as zoo
from tests.cli.helpers import assert_failed, run_main

from jaxgaze.cli import main
from jaxgaze.io.concurrences import OUTPUT_COLUMNS
from jaxgaze.io.poses import CAMERA_POSE_COLUMNS
from jaxgaze.io.rays import CSV_COLUMNS
from jaxgaze.geometry import rotation_matrix_to_quaternion
from jaxgaze.io.poses import write_colmap_images, write_pose_csv
from jaxgaze.poses import CameraPoses

DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")
POSE_HEADER = "frame,qw,qx,qy,qz,cx,cy,cz\n"


def angle_deg(u, v):
    u, v = np.asarray(u, float), np.asarray(v, float)
    cos = np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def without_disagreement(stderr):
    """stderr without the warning that the RANSAC apex and the posterior disagree: the session's apex (eq. 2) lies
    0.33-0.36 m in front of both cameras, so every calibration of it samples the posterior and says so."""
    return "".join(line for line in stderr.splitlines(keepends=True)
                   if not line.startswith("jaxgaze: warning: the RANSAC eye centre"))


def perpendicular_error(estimate, truth, direction):
    """Distance between two eye centres across the gaze direction (depth along it is poorly observed)."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    e = np.asarray(estimate, float) - np.asarray(truth, float)
    return float(np.linalg.norm(e - np.dot(e, d) * d))


# ---------------------------------------------------------------------------
# calibrate


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Wearer A as a pose CSV ``alice.csv``, wearer B as COLMAP ``bob.txt``; with the truth."""
    s = zoo.calibration_session(80)
    directory = tmp_path_factory.mktemp("session")
    frames = np.asarray(s.frame_ids)
    a = CameraPoses(np.asarray(s.R_camera_from_world_a, float), np.asarray(s.centers_a, float), frames)
    b = CameraPoses(np.asarray(s.R_camera_from_world_b, float), np.asarray(s.centers_b, float), frames)
    write_pose_csv(directory / "alice.csv", a)
    write_colmap_images(directory / "bob.txt", b)
    return {
        "dir": directory, "a": directory / "alice.csv", "b": directory / "bob.txt", "poses_a": a, "poses_b": b,
        "eye_a": np.asarray(s.eye_center_a), "dir_a": np.asarray(s.direction_a),
        "eye_b": np.asarray(s.eye_center_b), "dir_b": np.asarray(s.direction_b),
    }


def test_calibrate_with_posterior(session, tmp_path, capsys):
    import arviz

    out, post = tmp_path / "calib.json", tmp_path / "posterior.nc"
    status, stdout, stderr = run_main(
        capsys, ["calibrate", session["a"], session["b"], "--out", out, "--posterior", post,
                 "--seed", "0", "--wearer", "ann"])  # the default 500 warm-up steps and draws
    assert status == 0, stderr
    assert stdout == ""
    # The RANSAC apex (eq. 2) lies 0.33 m in front of the camera, where no eye is: said, and the posterior mean used.
    warning, line = stderr.splitlines()
    assert warning.startswith("jaxgaze: warning: the RANSAC eye centre (0.332, 0.028, -0.063) m is ")
    assert "using the posterior mean" in warning
    assert line.startswith("jaxgaze: calibrated 'ann' from 80 frame(s)") and "eye centre (posterior mean)" in line
    assert sorted(os.listdir(tmp_path)) == ["calib.json", "posterior.nc"]  # no temporary file left

    record = json.loads(out.read_text())
    assert record["wearer"] == "ann" and record["frame"] == "camera" and record["method"] == "posterior mean"
    assert record["eye_center"] == record["posterior"]["eye_center_mean"] and record["point_estimate"]["disagrees"]
    errors = [np.linalg.norm(np.subtract(eye, session["eye_a"])) for eye in (record["eye_center"],
                                                                             record["point_estimate"]["eye_center"])]
    assert errors[0] < 0.1 < 0.3 < errors[1], errors
    assert record["num_points"] == 80 and 0.25 * 80 <= record["num_inliers"] <= 80
    assert abs(np.linalg.norm(record["direction"]) - 1) < 1e-9
    assert angle_deg(record["direction"], session["dir_a"]) < 2.0
    assert perpendicular_error(record["eye_center"], session["eye_a"], session["dir_a"]) < 0.04
    assert 0.005 < record["bandwidth"] < 0.1  # the simulated eye-in-head spread is 0.03 rad

    summary = record["posterior"]
    assert angle_deg(summary["direction_mean"], session["dir_a"]) < 2.0
    assert perpendicular_error(summary["eye_center_mean"], session["eye_a"], session["dir_a"]) < 0.04
    assert 0.005 < summary["bandwidth_mean"] < 0.1
    assert summary["result"] == "successful"
    assert summary["r_hat_max"] < 1.05  # split r-hat of the one chain
    assert summary["ess_bulk_min"] >= 100 and summary["ess_tail_min"] >= 100 and summary["divergences"] <= 3
    with warnings.catch_warnings():  # arviz's own tools on the file: no shape warning, r-hat as we report it
        warnings.simplefilter("error")
        idata = arviz.from_netcdf(post)
        everything = arviz.summary(idata, round_to="none")
    # the one chain of 500 draws, as its two halves (arviz needs two chains for r-hat)
    assert idata.posterior["eye_center"].shape[:2] == (2, 250) and idata.posterior.attrs["sampler_chains"] == 1
    assert idata.posterior["bandwidth"].shape == (2, 250) and summary["num_samples"] == 500
    assert np.all(np.isfinite(everything["r_hat"]))
    for name, row in summary["parameters"].items():
        for column in ("r_hat", "ess_bulk", "ess_tail"):
            assert row[column] == pytest.approx(everything.loc[name, column], rel=0, abs=1e-6), (name, column)
    units = {"eye_center": "m", "direction": "1", "bandwidth": "rad", "outlier_share": "1",
             "inlier_probability": "1"}
    assert {name: idata.posterior[name].attrs["units"] for name in units} == units
    assert idata.observed_data["points"].attrs["units"] == "m"
    # Every parameter has its mean, sd and 90% HDI in the JSON, as arviz computes them from the written draws,
    # and its ESS and split r-hat.
    names = ["eye_center", "direction", "bandwidth", "outlier_share"]
    table = arviz.summary(idata, var_names=names, kind="stats", hdi_prob=0.9, round_to="none")
    assert sorted(summary["parameters"]) == sorted(table.index) and len(table) == 8
    for name, row in summary["parameters"].items():
        expected = table.loc[name]
        for column in ("mean", "sd", "hdi_5%", "hdi_95%"):
            assert row[column] == pytest.approx(expected[column], rel=1e-9, abs=1e-12), (name, column)
        assert row["hdi_5%"] < row["mean"] < row["hdi_95%"] and row["sd"] > 0 and row["r_hat"] < 1.05
    for column in ("ess_bulk", "ess_tail"):  # the smallest ESS judged is that of one of these parameters
        assert min(row[column] for row in summary["parameters"].values()) == summary[f"{column}_min"]
    draws = idata.posterior["bandwidth"].values.ravel()
    assert summary["parameters"]["bandwidth"]["sd"] == pytest.approx(draws.std(ddof=1), rel=1e-9)


def test_calibrate_posterior_that_did_not_mix_exits_1(session, tmp_path, capsys, monkeypatch):
    """50 draws cannot give 100 effective ones: the command says so (one line, status 1, also with -q), files
    written; with -q no progress bar, even on a terminal (only the warning and the failure lines)."""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    out, post = tmp_path / "calib.json", tmp_path / "posterior.nc"
    status, stdout, stderr = run_main(
        capsys, ["calibrate", session["a"], session["b"], "--out", out, "--posterior", post, "--samples", "50", "-q"])
    assert status == 1 and stdout == ""
    warning, line = stderr.splitlines()  # the point estimate is implausible, but a failed posterior cannot replace it
    assert warning.startswith("jaxgaze: warning: the RANSAC eye centre") and "the point estimate is kept" in warning
    assert line.startswith("jaxgaze calibrate: the posterior failed: the sampler did not mix")
    assert "bulk ESS" in line and "tail ESS" in line and "RuntimeWarning" not in stderr
    record = json.loads(out.read_text())
    summary = record["posterior"]
    assert summary["result"] == "not_mixed" and summary["ess_bulk_min"] < 100
    assert record["method"] == "ransac+cone" and record["eye_center"] == record["point_estimate"]["eye_center"]
    assert sorted(os.listdir(tmp_path)) == ["calib.json", "posterior.nc"]


def test_calibrate_in_millimetres_is_refused(session, tmp_path, capsys):
    """Positions in millimetres put the eye centre metres from the camera: status 2, named."""
    directory = tmp_path / "mm"
    directory.mkdir()
    for name in ("a", "b"):
        poses = session[f"poses_{name}"]
        write_pose_csv(directory / f"{name}.csv", CameraPoses(poses.R_camera_from_world, 1000 * poses.centers,
                                                              poses.frame_ids))
    out = tmp_path / "c.json"
    status, stdout, stderr = run_main(capsys, ["calibrate", directory / "a.csv", directory / "b.csv", "--out", out])
    assert_failed(status, stdout, stderr, "positions look like millimetres (points of regard up to",
                  "poses must be in metres")
    assert not out.exists()


def test_calibrate_warns_of_implausible_speeds(session, tmp_path, capsys):
    """Timestamps in minutes make the cameras move at hundreds of m/s: an error naming the units (issue 34's unit
    rule); with --trust-units a warning, still a result."""
    for name in ("a", "b"):
        poses = session[f"poses_{name}"]
        write_pose_csv(tmp_path / f"{name}.csv", poses._replace(timestamps=poses.frame_ids / 1800.0))
    out = tmp_path / "c.json"
    status, stdout, stderr = run_main(capsys, ["calibrate", tmp_path / "a.csv", tmp_path / "b.csv", "--out", out])
    assert_failed(status, stdout, stderr, "camera A moves at a median", "pass --trust-units")  # the unit rule
    assert not out.exists()
    status, stdout, stderr = run_main(capsys, ["calibrate", tmp_path / "a.csv", tmp_path / "b.csv", "--out", out,
                                               "-q", "--trust-units"])
    assert status == 0 and stdout == "" and out.exists()
    lines = without_disagreement(stderr).splitlines()
    assert [line.split(" moves at")[0] for line in lines] == ["jaxgaze: warning: camera A", "jaxgaze: warning: camera B"]
    assert all("or timestamps are not in seconds; poses must be in metres and timestamps in seconds" in line
               for line in lines)


def test_calibrate_shows_reader_warnings_as_warning_lines(session, tmp_path, capsys):
    """A pose CSV cut off mid-write keeps its complete rows; the warning is one 'jaxgaze: warning:' line."""
    cut = tmp_path / "cut.csv"
    cut.write_text(session["a"].read_text() + "999,1,0")
    status, stdout, stderr = run_main(capsys, ["calibrate", cut, session["b"], "--out", tmp_path / "c.json", "-q"])
    assert status == 0 and stdout == ""
    stderr = without_disagreement(stderr)
    assert stderr.startswith("jaxgaze: warning: ") and "dropped the last row" in stderr
    assert len(stderr.splitlines()) == 1


JOINT = os.path.join(DATA, "colmap_joint_images.txt")


def test_calibrate_two_wearers_of_one_joint_reconstruction(tmp_path, capsys):
    """Cityscapes-like names in one COLMAP file of two wearers: selected by CAMERA_ID or name prefix, the frame ids
    are the number that changes; both give what the two wearers' own files give, and the summary says the rule."""
    records = []
    for i, selection in enumerate((["--camera-id", "1", "2"], ["--name-prefix", "ann/", "ben/"])):
        out = tmp_path / f"c{i}.json"
        status, stdout, stderr = run_main(capsys, ["calibrate", JOINT, JOINT, "--out", out, "--wearer", "ann",
                                                   *selection])
        assert status == 0 and stdout == "", stderr
        chosen = "CAMERA_ID 1" if i == 0 else "names starting with 'ann/'"
        assert (f"colmap_joint_images.txt (30 of 60 images, {chosen}): frame ids from the one number that changes "
                "in the image names (e.g. 'ann/aachen_000003_000000_leftImg8bit.png' → 0)") in stderr
        records.append(json.loads(out.read_text()))
    from jaxgaze.io.poses import read_colmap_images

    for name, camera in (("ann", 1), ("ben", 2)):
        write_pose_csv(tmp_path / f"{name}.csv", read_colmap_images(JOINT, camera_id=camera))
    status, _, stderr = run_main(capsys, ["calibrate", tmp_path / "ann.csv", tmp_path / "ben.csv", "--out",
                                          tmp_path / "own.json"])
    assert status == 0 and "ann.csv: frame ids from its 'frame' column; ben.csv: " in stderr
    assert records[0] == records[1] == json.loads((tmp_path / "own.json").read_text())
    assert records[0]["num_points"] == 30


def test_readme_joint_colmap_chain(tmp_path, capsys, monkeypatch):
    """The README's joint-COLMAP calibration, then concurrences with both calibrations (issue 34, bug 3 and item 6).

    The file holds ``simulate_calibration_session(jax.random.key(0), num_frames=30)`` (its header), so the
    truth is known. Wearer A's RANSAC apex (eq. 2) lies 0.53 m in front of the camera, 0.55 m from the truth,
    where no eye can be: the command samples the posterior (a progress bar on a terminal), says that the two
    disagree (both values and the distance) and stores the posterior mean, within 10 cm of the truth. Each
    wearer is named after its camera, so that the next command tells them apart without --wearer.
    """
    from jaxgaze.io.poses import read_colmap_images, write_camera_poses_csv
    from jaxgaze.simulate import simulate_calibration_session

    truth = np.asarray(simulate_calibration_session(jax.random.key(0), num_frames=30).eye_center_a)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    calib_a, calib_b = tmp_path / "calib.json", tmp_path / "calib_b.json"
    status, stdout, stderr = run_main(capsys, ["calibrate", JOINT, JOINT, "--camera-id", "1", "2", "--out", calib_a])
    assert status == 0 and stdout == "", stderr
    assert "calibration posterior" in stderr  # the NUTS progress bar
    warning = [line for line in stderr.splitlines() if line.startswith("jaxgaze: warning: the RANSAC eye centre")]
    assert len(warning) == 1, stderr
    assert "(0.534, 0.021, -0.070) m" in warning[0] and "posterior mean" in warning[0]
    assert "outside the posterior's 90% region" in warning[0] and "using the posterior mean" in warning[0]
    record = json.loads(calib_a.read_text())
    assert record["wearer"] == "camera_1" and record["method"] == "posterior mean"
    assert record["posterior"]["result"] == "successful" and record["posterior"]["file"] is None
    assert record["eye_center"] == record["posterior"]["eye_center_mean"]
    assert np.linalg.norm(np.subtract(record["eye_center"], truth)) < 0.1
    ransac = record["point_estimate"]["eye_center"]
    assert np.linalg.norm(np.subtract(ransac, truth)) > 0.5  # what the JSON held before
    distance = np.linalg.norm(np.subtract(ransac, record["eye_center"]))
    assert f"{distance:.2f} m from the posterior mean" in warning[0]

    status, stdout, stderr = run_main(capsys, ["calibrate", JOINT, JOINT, "--camera-id", "2", "1", "--out", calib_b,
                                               "-q"])
    assert status == 0 and stdout == "", stderr
    assert json.loads(calib_b.read_text())["wearer"] == "camera_2"
    poses = tmp_path / "camera_poses.csv"
    write_camera_poses_csv(poses, {f"camera_{c}": read_colmap_images(JOINT, camera_id=c) for c in (1, 2)})
    out = tmp_path / "concurrences.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", poses, "--calibration", calib_a, calib_b, "--out", out,
                                               "-q"])
    assert status == 0 and stdout == "", stderr
    assert out.exists()


def test_calibrate_frame_pattern(tmp_path, capsys):
    out = tmp_path / "c.json"
    status, _, stderr = run_main(capsys, ["calibrate", JOINT, JOINT, "--out", out, "--camera-id", "2", "1",
                                          "--frame-pattern", r"_(\d+)_leftImg8bit"])
    assert status == 0 and out.exists()
    assert stderr.count(r"frame ids from the image names by the pattern '_(\d+)_leftImg8bit'") == 2
    status, stdout, stderr = run_main(capsys, ["calibrate", JOINT, JOINT, "--out", tmp_path / "d.json",
                                               "--frame-pattern", r"\d+"])
    assert_failed(status, stdout, stderr, r"--frame-pattern: frame pattern '\d+' must have exactly one group")
    assert sorted(os.listdir(tmp_path)) == ["c.json"]


def test_calibrate_point_estimate_colmap_wearer(session, tmp_path, capsys):
    """B (COLMAP) calibrated against A (CSV); the wearer defaults to the stem of POSES_A."""
    out = tmp_path / "bob.json"
    out.write_text("old\n")  # replaced
    status, stdout, stderr = run_main(capsys, ["calibrate", session["b"], session["a"], "--out", out, "-q"])
    assert status == 0, stderr
    assert stdout == "" and stderr.startswith("jaxgaze: warning: the RANSAC eye centre") and without_disagreement(stderr) == ""
    record = json.loads(out.read_text())
    assert record["wearer"] == "bob" and record["posterior"]["file"] is None and record["method"] == "posterior mean"
    assert set(record) >= {"wearer", "frame", "eye_center", "direction", "bandwidth", "num_points",
                           "num_inliers", "method"}
    assert angle_deg(record["direction"], session["dir_b"]) < 2.0
    # 80 frames pin B's eye centre less tightly than A's (4.3 cm across the gaze with this session).
    assert perpendicular_error(record["eye_center"], session["eye_b"], session["dir_b"]) < 0.06
    assert sorted(os.listdir(tmp_path)) == ["bob.json"]


def _write_poses(path, rows, header=POSE_HEADER):
    path.write_text(header + "".join(",".join(str(x) for x in row) + "\n" for row in rows))
    return path


def _behind_camera(directory):
    """A at the origin looking along world +x; B always behind A: the points of regard have x < 0."""
    a = _write_poses(directory / "a.csv", [(f, 1, 0, 0, 0, 0, 0, 0) for f in range(6)])
    b = _write_poses(directory / "b.csv", [(f, 1, 0, 0, 0, -2 - 0.1 * f, 0.05 * f, 0.02 * f) for f in range(6)])
    return a, b


def _csv_lines(session):
    with open(session["a"]) as f:
        return f.read().splitlines(keepends=True)


def _non_unit(session, directory):
    lines = _csv_lines(session)
    cells = lines[4].split(",")
    cells[1] = str(2 * float(cells[1]))  # qw doubled: not unit
    lines[4] = ",".join(cells)
    path = directory / "bad.csv"
    path.write_text("".join(lines))
    return path, session["b"]


def _broken_colmap(session, directory):
    path = directory / "images.txt"
    path.write_text("# comment\n1 1 0 0 0 0 0 0 1 frame_000001.jpg\n\n2 1 0 0\n\n")
    return session["a"], path


def _shifted_frames(session, directory):
    p = session["poses_a"]
    path = directory / "far.csv"
    write_pose_csv(path, p._replace(frame_ids=p.frame_ids + 1000))
    return session["a"], path


def _two_frames(session, directory):
    path = directory / "two.csv"
    write_pose_csv(path, session["poses_b"].select(np.array([3, 7])))
    return session["a"], path


def _cityscapes(directory):
    """Names whose city and frame numbers both change: which one is the frame?"""
    path = directory / "images.txt"
    path.write_text("".join(f"{k + 1} 1 0 0 0 0 0 {k} 1 aachen_{k:06d}_{k + 19:06d}_leftImg8bit.png\n\n"
                            for k in range(4)))
    return path


CALIBRATE_FAILURES = {
    # name: (make(session, dir) -> (POSES_A, POSES_B), extra args, expected words, where: 'a', 'b', 'out', 'post', line)
    "missing file": (lambda s, d: (d / "nope.csv", s["b"]), [], ["pose file not found"], ("a", None)),
    "unknown type": (lambda s, d: (s["a"], s["b"].with_suffix(".dat")), [], ["unknown pose file type '.dat'"],
                     ("b", None)),
    "non-unit quaternion": (_non_unit, [], ["quaternion", "is not unit"], ("a", 5)),
    "broken colmap": (_broken_colmap, [], ["expected 10 fields"], ("b", 4)),
    "no matching frames": (_shifted_frames, [], ["no matching frames"], ("a", None)),
    "two frames": (_two_frames, [], ["only 2 frame(s) in common", "at least 3"], ("a", None)),
    "behind camera": (lambda s, d: _behind_camera(d), [], ["calibration failed", "behind the camera"], ("a", None)),
    "same file twice": (lambda s, d: (s["a"], s["a"]), [], ["the two pose tracks are identical in all 80 matched",
                                                            "same file twice", "every point of regard is zero"],
                        ("a", None)),
    "joint file, no selection": (lambda s, d: (JOINT, JOINT), [], ["duplicate frame 0", "several wearers' images? "
                                 "select one wearer's images by camera id or name prefix"], ("a", 13)),
    "unknown camera id": (lambda s, d: (JOINT, JOINT), ["--camera-id", "1", "3"], ["no image has CAMERA_ID 3"],
                          ("b", None)),
    "camera id of a csv": (lambda s, d: (s["a"], s["b"]), ["--camera-id", "1", "any"],
                           ["selects images of a COLMAP images.txt"], ("a", None)),
    "ambiguous frame ids": (lambda s, d: (s["a"], _cityscapes(d)), [], ["frame ids are ambiguous",
                            "give a frame pattern"], ("b", 1)),
    "unwritable out": (lambda s, d: (s["a"], s["b"]), ["--out", "{dir}/missing/c.json"],
                       ["cannot write output: directory does not exist"], ("out", None)),
    "unwritable posterior": (lambda s, d: (s["a"], s["b"]), ["--posterior", "{dir}/missing/p.nc"],
                             ["cannot write posterior: directory does not exist"], ("post", None)),
}


@pytest.mark.parametrize("name", list(CALIBRATE_FAILURES))
def test_calibrate_failure_modes(session, tmp_path, capsys, name):
    make, extra, words, (where, line) = CALIBRATE_FAILURES[name]
    inputs = tmp_path / "in"
    inputs.mkdir()
    poses_a, poses_b = make(session, inputs)
    outputs = tmp_path / "out"
    outputs.mkdir()
    kept = outputs / "calib.json"
    kept.write_text("precious\n")
    extra = [x.format(dir=outputs) for x in extra]
    argv = ["calibrate", poses_a, poses_b, "--out", kept, *extra]
    before = sorted(os.listdir(outputs)), sorted(os.listdir(inputs))
    status, stdout, stderr = run_main(capsys, argv)
    path = {"a": poses_a, "b": poses_b, "out": argv[argv.index("--out", 4) + 1] if "--out" in extra else kept,
            "post": extra[-1] if "--posterior" in extra else None}[where]
    assert_failed(status, stdout, stderr, *words)
    assert stderr.rstrip("\n").endswith(f"({path})" if line is None else f"({path}:{line})")
    assert (sorted(os.listdir(outputs)), sorted(os.listdir(inputs))) == before  # no output, no temporary file
    assert kept.read_text() == "precious\n"


def test_calibrate_json_write_failure_leaves_nothing(session, tmp_path, capsys, monkeypatch):
    real_replace = os.replace

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    out = tmp_path / "c.json"
    status, stdout, stderr = run_main(capsys, ["calibrate", session["a"], session["b"], "--out", out, "-q"])
    monkeypatch.setattr(os, "replace", real_replace)
    assert_failed(status, stdout, without_disagreement(stderr), "cannot write output: No space left on device", str(out))
    assert os.listdir(tmp_path) == []


def test_calibrate_posterior_written_only_with_the_json(session, tmp_path, capsys, monkeypatch):
    """If the JSON cannot be written, the NetCDF is not left behind either (the sampler is faked: fast)."""
    import arviz
    import pandas as pd

    import jaxgaze.calibration.posterior as calibration_posterior
    from jaxgaze.nuts import MixingDiagnostics, SamplerReport
    from jaxgaze.results import RESULTS

    def fake_posterior(points, **kwargs):
        idata = arviz.from_dict(posterior={"bandwidth": np.full((2, 5), 0.03)})
        summary = pd.DataFrame({"mean": [0.03], "r_hat": [1.01], "ess_bulk": [120.0]}, index=["bandwidth"])
        diagnostics = {"max_rhat": 1.01, "min_ess_bulk": 120.0, "min_ess_tail": 110.0, "divergences": 0,
                       "draws": 10, "chains": 2, "acceptance_rate": 0.8}
        eye = np.asarray(kwargs["init_eye_center"])  # draws around the point estimate: the two agree
        samples = {"eye_center": eye + 0.01 * np.random.default_rng(0).normal(size=(10, 3)),
                   "bandwidth": np.full(10, 0.03), "inlier_probability": np.ones((10, len(points)))}
        sampler = SamplerReport(idata, RESULTS.successful, MixingDiagnostics(**diagnostics), summary)
        return calibration_posterior.CalibrationPosterior(
            sampler, eye, np.asarray(kwargs["init_direction"]), 0.03, samples, {})

    monkeypatch.setattr(calibration_posterior, "calibrate_cone_posterior", fake_posterior)
    out, post = tmp_path / "c.json", tmp_path / "p.nc"
    status, _, stderr = run_main(capsys, ["calibrate", session["a"], session["b"], "--out", out,
                                          "--posterior", post, "-q"])
    assert status == 0, stderr
    summary = json.loads(out.read_text())["posterior"]
    assert summary["r_hat_max"] == 1.01 and summary["ess_bulk_min"] == 120.0
    assert summary["parameters"] == {"bandwidth": {"mean": 0.03, "r_hat": 1.01, "ess_bulk": 120.0}}
    assert arviz.from_netcdf(post).posterior["bandwidth"].shape == (2, 5)
    out.unlink()
    post.unlink()

    real_replace = os.replace

    def json_fails(src, dst):
        if str(dst).endswith(".json"):
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", json_fails)
    status, stdout, stderr = run_main(capsys, ["calibrate", session["a"], session["b"], "--out", out,
                                               "--posterior", post, "-q"])
    monkeypatch.setattr(os, "replace", real_replace)
    assert_failed(status, stdout, without_disagreement(stderr), "cannot write output: No space left on device",
                  str(out))
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("argv", [["calibrate", "a.csv", "b.csv"], ["calibrate", "a.csv", "--out", "c.json"],
                                  ["calibrate", "a.csv", "b.csv", "--out", "c.json", "--samples", "0"]])
def test_calibrate_usage_errors(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert "usage: jaxgaze" in capsys.readouterr().err


def test_calibrate_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["calibrate", "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "+x forward, +y left, +z up" in text and "--posterior" in text and "radians" in text


# ---------------------------------------------------------------------------
# concurrences --calibration

# Three wearers' calibrations (camera frame: +x forward, +y left, +z up).
WEARERS = {
    "ann": ((0.06, 0.00, -0.08), (1.0, 0.05, 0.03), 0.03),
    "ben": ((0.04, 0.02, -0.10), (1.0, -0.04, 0.02), 0.04),
    "cat": ((0.05, -0.01, -0.09), (1.0, 0.00, -0.05), 0.035),
}
# frame -> (point looked at, {wearer: eye position in the world})
SCENE = {
    4: ((1.0, 0.5, 1.2), {"ann": (2.8, 0.3, 1.6), "ben": (0.2, 2.1, 1.7), "cat": (-0.6, -0.7, 1.5)}),
    5: ((-0.5, 1.0, 0.9), {"ann": (1.5, 1.2, 1.6), "ben": (-0.3, 3.0, 1.65), "cat": (-2.2, -0.4, 1.55)}),
}


def _frame_of(forward, helper):
    """Right-handed orthonormal basis (columns) with first axis ``forward``."""
    x = forward / np.linalg.norm(forward)
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def calibrated_scene_rows():
    """Pose rows (frame, person, q of R_camera_from_world, centre) and the equivalent world rays."""
    poses, rays = [], []
    for frame, (target, eyes) in SCENE.items():
        for k, (person, eye_world) in enumerate(eyes.items()):
            eye_cam, dir_cam, h = (np.asarray(x, float) for x in WEARERS[person])
            eye_world = np.asarray(eye_world)
            look = np.asarray(target) - eye_world
            # R_world_from_camera maps the calibrated direction onto the line of sight, with some roll.
            roll = np.array([0.0, math.sin(0.3 * k), math.cos(0.3 * k)])
            R = _frame_of(look, roll) @ _frame_of(dir_cam, np.array([0.0, 0.0, 1.0])).T
            centre = eye_world - R @ eye_cam
            with jax.enable_x64(True):
                q = np.asarray(rotation_matrix_to_quaternion(np.asarray(R.T)), dtype=float)
            poses.append([frame, person, *(repr(float(x)) for x in q), *(repr(float(x)) for x in centre)])
            rays.append([frame, person, *eye_world, *(R @ dir_cam / np.linalg.norm(dir_cam)), float(h)])
    return poses, rays


def write_calibrations(directory, people=WEARERS):
    paths = []
    for person, (eye, direction, h) in people.items():
        path = directory / f"cli_calib_{person}.json"
        path.write_text(json.dumps({"wearer": person, "frame": "camera", "eye_center": list(eye),
                                    "direction": list(direction), "bandwidth": h, "method": "hand-made"},
                                   indent=2))
        paths.append(path)
    return paths


def write_rows(path, header, rows):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def read_output(path):
    with open(path, newline="") as f:
        reader = csv.reader(f)
        return next(reader), list(reader)


def test_concurrences_with_calibration(tmp_path, capsys):
    poses, rays = calibrated_scene_rows()
    src = write_rows(tmp_path / "poses.csv", CAMERA_POSE_COLUMNS, poses)
    calibrations = write_calibrations(tmp_path)
    out = tmp_path / "out.csv"
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--calibration", *calibrations, "--out", out,
                                               "--chunk", "2"])
    assert status == 0, stderr
    assert stdout == ""
    assert stderr.splitlines() == [f"jaxgaze: 2 concurrence(s) in 2 frame(s) written to {out}"]
    header, rows = read_output(out)
    assert tuple(header) == OUTPUT_COLUMNS
    assert [int(r[0]) for r in rows] == sorted(SCENE)
    for row in rows:
        target = np.asarray(SCENE[int(row[0])][0])
        location = np.array([float(row[header.index(c)]) for c in ("x", "y", "z")])
        assert np.linalg.norm(location - target) < 5e-3, (row, target)
        assert int(row[header.index("num_rays")]) == 3

    # The same rays written out by hand go through the plain path to the same result.
    plain = write_rows(tmp_path / "rays.csv", CSV_COLUMNS + ("bandwidth",), rays)
    status, _, stderr = run_main(capsys, ["concurrences", plain, "--out", tmp_path / "plain.csv", "-q",
                                          "--chunk", "2"])
    assert status == 0, stderr
    _, plain_rows = read_output(tmp_path / "plain.csv")
    assert np.allclose(np.array(plain_rows, dtype=float), np.array(rows, dtype=float), rtol=1e-4, atol=1e-5)


def _drop_calibration(directory, poses):
    return write_calibrations(directory, {k: v for k, v in WEARERS.items() if k != "cat"})


def _bad_json(directory, poses):
    paths = write_calibrations(directory)
    paths[1].write_text('{"wearer": "ben",\n "frame": "camera",\n oops}\n')
    return paths


def _missing_key(directory, poses):
    paths = write_calibrations(directory)
    data = json.loads(paths[0].read_text())
    del data["bandwidth"]
    paths[0].write_text(json.dumps(data))
    return paths


def _bad_direction(directory, poses):
    paths = write_calibrations(directory)
    data = json.loads(paths[2].read_text())
    data["direction"] = [0.0, 1.0]
    paths[2].write_text(json.dumps(data))
    return paths


def _non_unit_pose(directory, poses):
    poses[3][2] = "2.0"  # qw of frame 5, ann
    return write_calibrations(directory)


def _duplicate_wearer(directory, poses):
    paths = write_calibrations(directory)
    copy = directory / "cli_calib_ann_again.json"
    copy.write_text(paths[0].read_text())
    return paths + [copy]


CONCURRENCE_FAILURES = {
    # name: (make(dir, pose rows) -> calibration paths, expected words, where: 'input' or calibration index, line)
    "person without calibration": (_drop_calibration, ["no calibration for person 'cat'"], ("input", 4)),
    "malformed json": (_bad_json, ["calibration is not valid JSON"], (1, 3)),
    "missing key": (_missing_key, ["calibration is missing key 'bandwidth'"], (0, None)),
    "bad direction": (_bad_direction, ["calibration 'direction' must be a list of 3 numbers"], (2, 1)),
    "non-unit quaternion": (_non_unit_pose, ["is not unit"], ("input", 5)),
    "duplicate wearer": (_duplicate_wearer, ["two calibrations for wearer 'ann'"], (3, None)),
    "missing calibration": (lambda d, p: write_calibrations(d)[:2] + [d / "nope.json"],
                            ["calibration file not found"], (2, None)),
}


@pytest.mark.parametrize("name", list(CONCURRENCE_FAILURES))
def test_concurrences_with_calibration_failure_modes(tmp_path, capsys, name):
    make, words, (where, line) = CONCURRENCE_FAILURES[name]
    poses, _ = calibrated_scene_rows()
    calibrations = make(tmp_path, poses)
    src = write_rows(tmp_path / "poses.csv", CAMERA_POSE_COLUMNS, poses)
    out = tmp_path / "out.csv"
    before = sorted(os.listdir(tmp_path))
    status, stdout, stderr = run_main(capsys, ["concurrences", src, "--calibration", *calibrations, "--out", out])
    assert_failed(status, stdout, stderr, *words)
    path = src if where == "input" else calibrations[where]
    assert stderr.rstrip("\n").endswith(f"({path})" if line is None else f"({path}:{line})")
    assert sorted(os.listdir(tmp_path)) == before


def test_calibrate_a_partner_close_by_runs_with_the_override(session, tmp_path, capsys):
    """The unit rule (issue 34): B's camera 16 times closer along A's gaze rays (about 10 cm in front of A's eye)
    is implausible for a session, so exit 2 naming the file and --trust-units; trusted, the calibration runs and
    finds A's true eye centre (the rays from it, and the angles, are unchanged)."""
    a, b, eye = session["poses_a"], session["poses_b"], session["eye_a"]
    y = np.einsum("tij,tj->ti", a.R_camera_from_world, b.centers - a.centers)  # A's points of regard
    near = eye + (y - eye) / 16.0
    write_pose_csv(tmp_path / "b.csv", b._replace(centers=a.centers + np.einsum("tji,tj->ti", a.R_camera_from_world,
                                                                                 near)))
    out = tmp_path / "calib.json"
    argv = ["calibrate", session["a"], tmp_path / "b.csv", "--out", out]
    status, stdout, stderr = run_main(capsys, argv)
    assert_failed(status, stdout, stderr, "positions look too small for metres", "pass --trust-units",
                  f"({session['a']})")
    assert not out.exists()
    status, _, stderr = run_main(capsys, argv + ["--trust-units", "-q"])
    assert status == 0, stderr
    assert stderr.startswith("jaxgaze: warning: positions look too small for metres")
    found = np.asarray(json.loads(out.read_text())["eye_center"])
    assert np.linalg.norm(found - eye) < 0.05, (found, eye)
