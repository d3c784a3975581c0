"""``jaxgaze joint``: the joint model of a group recording from the command line.

A tiny simulated conversation (``simulate_conversation``: 3 people, 10 s at 5 fps) is
written out as one gaze CSV per person ("ann", "ben", "cat"; frames where a person is
not tracked are left out of their file) and its speaking turns as RTTM, where cat is
speaker "spk3" (``--speaker-map``) and a speaker "dan" matches nobody (a warning).

ONE end-to-end fit (very few NUTS draws: it may not mix, so its exit status is 0 or 1
as the posterior says) checks the files; the other tests reuse its posterior in place
of the fit (exit 1 for a failed fit, Ctrl-C) or fail before any fit (bad input: status
2, one line on stderr, no output file).
"""

import contextlib
import csv
import io
import math
import os
import types

import arviz as az
import jax
import numpy as np
import pytest
from tests.cli.helpers import assert_failed, run_main

import jaxgaze.joint
from jaxgaze.cli import main
from jaxgaze.cli._joint_summary import summary
from jaxgaze.io.gaze import GAZE_COLUMNS
from jaxgaze.io.joint import write_joint_netcdf
from jaxgaze.io.tools.openface import OPENFACE_COLUMNS
from jaxgaze.io.text import atomic_path
from jaxgaze.joint.rivals import Alternative, ModeSearch
from jaxgaze.poses import matrices_to_quaternions
from jaxgaze.results import RESULTS, succeeded

FPS = 5.0
NAMES = ("ann", "ben", "cat")
SPEAKERS = ("ann", "ben", "spk3")


def _write_csv(path, header, rows):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
    return str(path)


def _runs(flags):
    padded = np.concatenate([[False], np.asarray(flags, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[::2], edges[1::2]))


def _gaze_rows(scene, p, scale=1.0):
    q = matrices_to_quaternions(scene.R_world_from_head[:, p])
    rows = []
    for t in np.flatnonzero(scene.present[:, p]):
        rows.append([int(t), repr(float(t) / FPS), *(repr(float(x)) for x in scene.gaze_angles[t, p]),
                     *(repr(float(x)) for x in q[t]), *(repr(float(x) * scale) for x in scene.eye_positions[t, p])])
    return rows


def _openface(path, start=0.0):
    rows = [[f, 0, repr(start + f / FPS), 0.98, 1, 0.1, 0.0, 0.0, 0.0, 1000.0, 0.0, 0.0, 0.0] for f in range(1, 6)]
    return _write_csv(path, ("frame", "face_id", "timestamp", "confidence", "success", "gaze_angle_x",
                             "gaze_angle_y", "pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz"), rows)


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    from jaxgaze.simulate import simulate_conversation

    scene = simulate_conversation(jax.random.key(0), num_people=3, num_objects=1, duration_s=10.0, fps=FPS)
    d = tmp_path_factory.mktemp("scene")
    header = ("frame", "timestamp") + GAZE_COLUMNS[1:]
    gaze = [_write_csv(d / f"{name}.csv", header, _gaze_rows(scene, p)) for p, name in enumerate(NAMES)]
    lines = []
    for p, speaker in enumerate(SPEAKERS):
        for s, e in _runs(scene.speaking[:, p]):
            lines.append(f"SPEAKER meet 1 {s / FPS:.3f} {(e - s) / FPS:.3f} <NA> <NA> {speaker} <NA> <NA>")
    lines.append("SPEAKER meet 1 9.000 0.500 <NA> <NA> dan <NA> <NA>")
    rttm = d / "speech.rttm"
    rttm.write_text("\n".join(lines) + "\n")
    assert set(OPENFACE_COLUMNS) <= set(open(_openface(d / "face0.csv")).readline().strip().split(","))
    files = {"dir": d, "scene": scene, "gaze": gaze, "rttm": str(rttm), "header": header,
             "openface": [_openface(d / "face0.csv"), _openface(d / "face1.csv")],
             "broken": _write_csv(d / "broken.csv", header[:-1], [r[:-1] for r in _gaze_rows(scene, 0)]),
             "millimetres": _write_csv(d / "ben_mm.csv", header, _gaze_rows(scene, 1, scale=1000.0))}
    return files


@pytest.fixture(scope="module")
def fitted(scene_files, tmp_path_factory):
    """The one end-to-end run (tiny NUTS), with the posterior the command got from fit_joint."""
    out_dir = tmp_path_factory.mktemp("fit")
    out, frames = out_dir / "joint.nc", out_dir / "frames.csv"
    captured = []
    fit = jaxgaze.joint.fit_joint

    def spy(*args, **kwargs):
        captured.append(fit(*args, **kwargs))
        return captured[-1]

    stdout, stderr = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        mp.setattr(jaxgaze.joint, "fit_joint", spy)
        status = main(["joint", *scene_files["gaze"], "--speech", scene_files["rttm"], "--speaker-map", "cat=spk3",
                       "--out", str(out), "--per-frame", str(frames), "--warmup", "30",
                       "--draws", "30"])
    (posterior,) = captured
    return {"status": status, "stdout": stdout.getvalue(), "stderr": stderr.getvalue(), "out": out,
            "frames": frames, "dir": out_dir, "posterior": posterior}


def test_joint_end_to_end(fitted, scene_files):
    import arviz as az

    scene, post = scene_files["scene"], fitted["posterior"]
    T, P = scene.present.shape
    assert fitted["status"] == (0 if succeeded(post) else 1)
    assert sorted(os.listdir(fitted["dir"])) == ["frames.csv", "joint.nc"]  # written either way, no temporary file
    lines = fitted["stderr"].splitlines()
    assert "Traceback" not in fitted["stderr"]
    assert lines[0].startswith("jaxgaze: warning: ") and "'dan'" in lines[0] and "--speaker-map" in lines[0]
    if succeeded(post):
        assert len(lines) == 1
    else:
        assert len(lines) == 2 and lines[1] == f"jaxgaze joint: {RESULTS[post.result]}"
    out = fitted["stdout"]
    assert "people: ann, ben, cat" in out and "bias (yaw, tilt) deg:" in out and "cone width deg:" in out
    assert f"concurrences: {post.num_concurrences}" in out and "diagnostics (nuts)" in out

    assert post.people == NAMES
    idata = az.from_netcdf(fitted["out"])
    assert idata.posterior["bias"].shape == (2, 15, P, 2)  # the one chain as its two halves (arviz's split r-hat)
    assert idata.posterior.attrs["sampler_chains"] == 1 and idata.posterior["bias"].attrs["units"] == "rad"
    assert list(idata.posterior["person"].values) == list(NAMES)
    # Speakers matched by name and through --speaker-map; 'dan' ignored.
    np.testing.assert_array_equal(idata.observed_data["speaking"].values, scene.speaking & scene.present)
    np.testing.assert_array_equal(idata.observed_data["present"].values, scene.present)

    with open(fitted["frames"], newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == T * P
    columns = [c for c in rows[0] if c.startswith("p_") and c != "p_mutual"]
    assert columns == ["p_" + c.replace(" ", "_") for c in post.candidates]
    for n, row in enumerate(rows):
        t, p = divmod(n, P)
        assert (int(row["frame"]), row["person"]) == (t, NAMES[p])
        assert float(row["time"]) == pytest.approx(t / FPS)
        assert row["present"] == str(int(scene.present[t, p]))
        if scene.present[t, p]:
            probabilities = [float(row[c]) for c in columns]
            assert sum(probabilities) == pytest.approx(1.0, abs=1e-4)
            assert row["target"] in post.candidates and row["target"] != NAMES[p]
            assert float(row["probability"]) == pytest.approx(max(probabilities), abs=1e-6)
        else:
            assert row["target"] == ""


def test_joint_says_whether_the_fit_kept_a_fixation_spot(fitted, scene_files, tmp_path, capsys, monkeypatch):
    post = fitted["posterior"]
    assert post.spot_log_bayes_factor is not None  # the default prior asks for a spot
    assert ("held_cone_share" in post.samples) == (post.spot_log_bayes_factor > math.log(3.0))
    dropped = post._replace(samples={k: v for k, v in post.samples.items() if k != "held_cone_share"},
                            spot_log_bayes_factor=-2.5)
    monkeypatch.setattr(jaxgaze.joint, "fit_joint", lambda *a, **k: dropped)
    status, stdout, _ = run_main(capsys, ["joint", *scene_files["gaze"], "--out", tmp_path / "j.nc"])
    assert "held through a fixation: none (the data favour a fixation's spot by a factor of 0.082, under the 3" in stdout
    assert az.from_netcdf(tmp_path / "j.nc").posterior.attrs["spot_log_bayes_factor"] == -2.5
    assert "shape_log_bayes_factor" not in az.from_netcdf(tmp_path / "j.nc").posterior.attrs  # the linear map asked for


@pytest.mark.parametrize("kept", [True, False])
def test_joint_says_which_head_gaze_map_the_fit_kept(fitted, tmp_path, kept):
    """Head pose only with a Gaussian-process map asked for: the summary names the map kept and the Bayes factor,
    and the netCDF holds the factor."""
    post = fitted["posterior"]
    S, P = post.samples["bias"].shape[:2]
    kappa = np.full((S, P, 2), 0.6)
    samples = {**post.samples, "coupling": kappa, "head_lag": np.full((S, P), 0.2)}
    if kept:
        samples["coupling_shape"] = np.zeros((S, P, 2, 12))
    shaped = post._replace(samples=samples, shape_log_bayes_factor=math.log(40.0) if kept else -3.0)
    data = types.SimpleNamespace(num_frames=post.membership.shape[0], fps=FPS, has_speech=True)
    lines = summary(shaped, data, ["j.nc"]).splitlines()
    line = next(x for x in lines if x.startswith("head-gaze map"))
    assert line == (f"head-gaze map: {'a Gaussian process on the linear map' if kept else 'linear'} (the data favour "
                    f"the Gaussian process by a factor of {'40' if kept else '0.05'}; 3 keeps it)")
    assert lines.index(line) + 1 == next(i for i, x in enumerate(lines) if x.startswith("head-gaze coupling"))
    write_joint_netcdf(tmp_path / "j.nc", shaped)
    assert az.from_netcdf(tmp_path / "j.nc").posterior.attrs["shape_log_bayes_factor"] == pytest.approx(
        math.log(40.0) if kept else -3.0, abs=1e-6)


@pytest.mark.parametrize("result", ["successful", "not_mixed"])
def test_joint_exit_status_follows_the_fit(fitted, scene_files, tmp_path, capsys, monkeypatch, result):
    monkeypatch.setattr(jaxgaze.joint, "fit_joint",
                        lambda *a, **k: fitted["posterior"]._replace(result=getattr(RESULTS, result)))
    out, frames = tmp_path / "j.nc", tmp_path / "f.csv"
    status, stdout, stderr = run_main(capsys, ["joint", *scene_files["gaze"], "--out", out, "--per-frame", frames, "-q"])
    assert sorted(os.listdir(tmp_path)) == ["f.csv", "j.nc"]
    assert stdout == ""  # -q
    if result == "successful":
        assert (status, stderr) == (0, "")
    else:
        assert status == 1 and stderr.splitlines() == [f"jaxgaze joint: {RESULTS[RESULTS.not_mixed]}"]


def test_joint_ambiguous_exits_1_naming_the_person_and_the_alternatives(fitted, scene_files, tmp_path, capsys,
                                                                        monkeypatch):
    post = fitted["posterior"]
    T, C = post.membership.shape[0], len(post.candidates)
    membership = np.zeros((T, C))
    membership[:, post.candidates.index("cat")] = 1.0
    other = Alternative(1, post.bias[1] + np.radians([20.0, 0.0]), np.radians([0.5, 0.5]), -0.4, 0.4, membership)
    check = {**post.predictive_check, "flagged": np.array([False, True, False]),
             "elsewhere_observed": np.array([0.1, 0.95, 0.1]), "elsewhere_predicted": np.array([0.1, 0.06, 0.1])}
    ambiguous = post._replace(result=RESULTS.ambiguous, modes=ModeSearch({"bias": post.bias}, (other,), (), 1, 0.0),
                              predictive_check=check)
    monkeypatch.setattr(jaxgaze.joint, "fit_joint", lambda *a, **k: ambiguous)
    out, frames = tmp_path / "j.nc", tmp_path / "f.csv"
    status, stdout, stderr = run_main(capsys, ["joint", *scene_files["gaze"], "--out", out, "--per-frame", frames])
    (line,) = stderr.splitlines()
    assert status == 1 and line.startswith("jaxgaze joint: the data cannot tell two explanations apart: ben's bias")
    here, there = np.degrees(post.bias[1]), np.degrees(other.bias)
    assert f"({here[0]:+.1f}°, {here[1]:+.1f}°) or ({there[0]:+.1f}°, {there[1]:+.1f}°) with weight 0.40" in line
    assert "predictive check: ben's gaze goes elsewhere in 95% of frames, the fit predicts 6%" in stdout
    with open(frames, newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["alternative_target"] for r in rows if r["person"] == "ben" and r["present"] == "1"} == {"cat"}
    assert {r["alternative_target"] for r in rows if r["person"] != "ben"} == {""}


def test_joint_ctrl_c_leaves_no_file(fitted, scene_files, tmp_path, capsys, monkeypatch):
    import jaxgaze.cli.joint as command

    def interrupt(path, posterior):  # as the real writer: into atomic_path's temporary file
        with atomic_path(path) as tmp, open(tmp, "w") as f:
            f.write("half")
            raise KeyboardInterrupt

    monkeypatch.setattr(jaxgaze.joint, "fit_joint", lambda *a, **k: fitted["posterior"])
    monkeypatch.setattr(command, "write_joint_netcdf", interrupt)
    status, _, stderr = run_main(capsys, ["joint", *scene_files["gaze"], "--out", tmp_path / "j.nc",
                                          "--per-frame", tmp_path / "f.csv"])
    assert status == 130 and stderr.splitlines() == ["jaxgaze: interrupted"]
    assert os.listdir(tmp_path) == []


def test_joint_same_camera_openface(scene_files, tmp_path, capsys, monkeypatch):
    """With --same-camera two OpenFace files reach the model (stopped there by a stand-in)."""

    def stop(*args, **kwargs):
        assert kwargs["people"] == ["face0", "face1"] and kwargs["present"].shape == (5, 2)
        raise ValueError("reached joint_data")

    monkeypatch.setattr(jaxgaze.joint, "joint_data", stop)
    status, stdout, stderr = run_main(capsys, ["joint", *scene_files["openface"], "--same-camera",
                                               "--out", tmp_path / "j.nc"])
    assert_failed(status, stdout, stderr, "reached joint_data")
    assert os.listdir(tmp_path) == []


def _bad_cases(f):
    gaze, d = f["gaze"], f["dir"]
    return {
        "missing gaze file": ([str(d / "nobody.csv"), *gaze[1:]], [], "gaze file not found"),
        "malformed gaze CSV": ([f["broken"], *gaze[1:]], [], "missing column 'ez'"),
        "--people count": (gaze, ["--people", "a,b"], "--people names 2 people for the 3 in the GAZE files (ann, "),
        "reserved name": (gaze, ["--people", "a,elsewhere,c"], "reserved"),
        "duplicate name": ([gaze[0], gaze[0], gaze[1]], [], "two people are named 'ann'"),
        "bad --draws": (gaze, ["--draws", "many"], "--draws: not an integer"),
        "too few --draws": (gaze, ["--draws", "6"], "--draws: must be at least 8"),
        "bad --fps": (gaze, ["--fps", "-5"], "--fps: must be a positive"),
        "bad --window-s": (gaze, ["--window-s", "0"], "--window-s"),
        "--fps against timestamps": (gaze, ["--fps", "30"], "disagrees with the timestamps"),
        "one person": (gaze[:1], [], "2 people"),
        "millimetres": ([gaze[0], f["millimetres"], gaze[2]], [], "millimetres"),
        "several OpenFace": (f["openface"], [], "--same-camera"),
        "OpenFace and CSV": ([f["openface"][0], *gaze[1:]], ["--same-camera"], "cannot mix OpenFace"),
        "missing speech": (gaze, ["--speech", str(d / "none.rttm")], "speech file not found"),
        "--speaker-map person": (gaze, ["--speech", f["rttm"], "--speaker-map", "zed=spk3"], "unknown person 'zed'"),
        "--speaker-map speaker": (gaze, ["--speech", f["rttm"], "--speaker-map", "cat=spk9"], "'spk9'"),
        "--speaker-map syntax": (gaze, ["--speech", f["rttm"], "--speaker-map", "cat"], "NAME=SPEAKER"),
        "--speaker-map without --speech": (gaze, ["--speaker-map", "cat=spk3"], "need --speech"),
        "--head-gaze-gp without --head-only": (gaze, ["--head-gaze-gp", "0.2"], "it needs --head-only"),
        "--head-gaze-gp in degrees": (gaze, ["--head-only", "--head-gaze-gp", "15"], "radians"),
    }


BAD = ["missing gaze file", "malformed gaze CSV", "--people count", "reserved name", "duplicate name", "bad --draws",
       "too few --draws", "bad --fps", "bad --window-s", "--fps against timestamps", "one person", "millimetres",
       "several OpenFace", "OpenFace and CSV", "missing speech", "--speaker-map person", "--speaker-map speaker",
       "--speaker-map syntax", "--speaker-map without --speech", "--head-gaze-gp without --head-only",
       "--head-gaze-gp in degrees"]


@pytest.mark.parametrize("case", BAD)
def test_joint_bad_input(scene_files, tmp_path, capsys, monkeypatch, case):
    monkeypatch.setattr(jaxgaze.joint, "fit_joint", lambda *a, **k: pytest.fail("bad input reached the fit"))
    files, extra, words = _bad_cases(scene_files)[case]
    status, stdout, stderr = run_main(capsys, ["joint", *files, *extra, "--out", tmp_path / "j.nc",
                                               "--per-frame", tmp_path / "f.csv"])
    assert_failed(status, stdout, stderr, words)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("extra, scale", [([], None), (["--head-gaze-gp", "0.2"], 0.2)])
def test_joint_head_gaze_gp_reaches_the_prior(scene_files, tmp_path, capsys, monkeypatch, extra, scale):
    """``--head-only --head-gaze-gp 0.2`` fits with ``JointPrior(coupling_shape_scale=0.2)``, the linear map without."""
    seen = []

    def stop(data, **kwargs):
        seen.append((data.head_motion is not None, kwargs["prior"].coupling_shape_scale))
        raise ValueError("reached fit_joint")

    monkeypatch.setattr(jaxgaze.joint, "fit_joint", stop)
    status, stdout, stderr = run_main(capsys, ["joint", *scene_files["gaze"], "--head-only", *extra,
                                               "--out", tmp_path / "j.nc"])
    assert_failed(status, stdout, stderr, "reached fit_joint")
    assert seen == [(True, scale)] and os.listdir(tmp_path) == []


def test_joint_bad_outputs(scene_files, tmp_path, capsys):
    gaze = scene_files["gaze"]
    for argv, words in [(["--out", tmp_path / "no" / "j.nc"], "directory does not exist"),
                        (["--out", tmp_path / "j.nc", "--per-frame", tmp_path / "j.nc"], "different files"),
                        (["--out", gaze[0]], "overwrite an input")]:
        status, stdout, stderr = run_main(capsys, ["joint", *gaze, *argv])
        assert_failed(status, stdout, stderr, words)
    assert os.listdir(tmp_path) == []
