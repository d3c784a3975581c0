"""``jaxgaze fit-gaze`` and ``jaxgaze attend``: a model fitted on simulated sessions, attention on a rendered video."""

import csv
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import jax
import numpy as np
import pytest
from tests.cli.helpers import assert_failed, run_main

import jaxgaze
from jaxgaze.cli import main
from jaxgaze.io.attend import ATTEND_COLUMNS
from jaxgaze.io.models import load_gaze_regression
from jaxgaze.headpose.regression import GazeRegression
from jaxgaze.simulate.tabletop import simulate_tabletop_sessions
from jaxgaze.geometry import head_pose_to_rotation, rotation_to_head_pose
from jaxgaze.vision.head_model import frontal_rotation
from jaxgaze.io.video import read_frames, write_video
from jaxgaze.simulate.video import render_tabletop_video
from jaxgaze.vision import attend as vision_attend
from jaxgaze.vision.attend import OVERLAY_COLOURS, AttentionWindows

DEMO_FRAMES = 14  # + 10 lead-in frames = 24 frames = 6 windows of 4


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """``jaxgaze fit-gaze`` on 2 short simulated sessions, with a lossless demo video of a held-out session."""
    folder = tmp_path_factory.mktemp("attend")
    model, video = folder / "gp.json", folder / "demo.mkv"
    status = main(["fit-gaze", "--out", str(model), "--seed", "0", "--people", "2", "--sessions", "1",
                   "--duration", "5", "--demo-video", str(video), "--demo-frames", str(DEMO_FRAMES), "-q"])
    assert status == 0
    # The same held-out session, rendered again for its ground truth (fit-gaze's seed → keys → 3rd person).
    key_sim, _, key_render = jax.random.split(jax.random.key(0), 3)
    demo = simulate_tabletop_sessions(key_sim, num_people=3, sessions_per_person=1, duration_s=5.0, fps=10.0)[2]
    frames, truth = render_tabletop_video(demo, key=key_render, num_frames=DEMO_FRAMES)
    return SimpleNamespace(folder=folder, model=model, video=video, frames=frames, truth=truth)


def _rows(path):
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        return tuple(reader.fieldnames), list(reader)


def _pooled_true_pose(truth, window):
    """The rendered pose relative to the first frame's eye-contact frame (what the tracker reports), pooled."""
    R0 = frontal_rotation(truth.head_position_optical[0])
    p = truth.head_pose  # (pitch, yaw, roll)
    R = truth.R_optical_from_frontal @ np.asarray(head_pose_to_rotation(yaw=p[:, 1], pitch=p[:, 0], roll=p[:, 2]), np.float64)
    yaw, pitch, roll = rotation_to_head_pose(R0.T @ R)
    pose = np.stack([pitch, yaw, roll], axis=-1).astype(np.float64)
    n = len(pose) // window
    return pose[: n * window].reshape(n, window, 3).mean(1)


def test_fit_gaze_writes_a_model_with_metadata_and_a_demo_video(fitted):
    doc = json.loads(fitted.model.read_text())
    assert doc["format"] == "jaxgaze.gaze_regression" and doc["model"] == "gp" and doc["dtype"] == "float32"
    meta = doc["metadata"]
    assert meta["image_size"] == [320, 240] and meta["fps"] == 10.0 and meta["window"] == 4
    assert meta["focal_px"] == pytest.approx(fitted.truth.focal_px / 2)
    assert meta["num_training_frames"] == 100 and "converged" in meta
    with jax.enable_x64(True):  # a float32 fit loads in float64 (as 'attend' loads it)
        model = load_gaze_regression(fitted.model)
        assert isinstance(model, GazeRegression) and model.direction_gp.X.dtype == np.float64
    # The demo video is the held-out session rendered at 640 x 480 with 10 lead-in frames, losslessly.
    frames = read_frames(fitted.video)
    assert len(frames) == 10 + DEMO_FRAMES and frames[0].shape == (480, 640, 3)
    assert all(np.array_equal(a, b) for a, b in zip(frames, fitted.frames))


def test_attend_end_to_end_on_the_rendered_video(fitted, tmp_path, capsys):
    out = tmp_path / "attend.csv"
    status, stdout, stderr = run_main(capsys, ["attend", fitted.video, "--model", fitted.model, "--out", out,
                                               "--no-progress"])
    assert status == 0, stderr
    assert stdout == ""
    assert "of 6 window(s) of 4 frames attended" in stderr and "scaled x 2" in stderr and str(out) in stderr
    columns, rows = _rows(out)
    assert columns == ATTEND_COLUMNS
    assert len(rows) == (10 + DEMO_FRAMES) // 4
    assert [int(r["start_frame"]) for r in rows] == [0, 4, 8, 12, 16, 20]
    assert [float(r["start_time"]) for r in rows] == pytest.approx([0.0, 0.4, 0.8, 1.2, 1.6, 2.0])
    valid = [r for r in rows if r["valid"] == "1"]
    assert len(valid) >= 4
    for r in valid:
        assert 0.0 < float(r["probability"]) <= 1.0 and r["reason"] == ""
        x, y = float(r["attended_x"]), float(r["attended_y"])
        assert 0 <= x <= 640 and 0 <= y <= 480
        assert float(r["region_x_min"]) <= x <= float(r["region_x_max"])
    # The tracked head pose follows the rendered one (64 px head: within a few degrees).
    pose = np.array([[float(r[c]) for c in ("pitch", "yaw", "roll")] for r in rows])
    error = np.degrees(np.abs(pose - _pooled_true_pose(fitted.truth, 4)))
    assert error.max() < 5.0, error
    # The head centre is the projected front of the face, the session's eye midpoint.
    head = np.array([[float(r["head_x"]), float(r["head_y"])] for r in rows])
    true_head = fitted.truth.head_centre_image[:24].reshape(6, 4, 2).mean(1)
    assert np.abs(head - true_head).max() < 6.0


def test_attend_reads_a_frame_folder_with_options(fitted, tmp_path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    for t, frame in enumerate(fitted.frames[:12]):
        cv2.imwrite(str(folder / f"f{t}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    out = tmp_path / "a.csv"
    status, _, stderr = run_main(capsys, ["attend", folder, "--model", fitted.model, "--out", out, "--window", "5",
                                          "--max-frames", "11", "--method", "spectral_residual",
                                          "--focal-px", fitted.truth.focal_px, "--fps", "25", "-q"])
    assert status == 0, stderr
    assert stderr == ""
    _, rows = _rows(out)
    assert [int(r["start_frame"]) for r in rows] == [0, 5]  # 11 frames: 2 windows of 5, the last frame dropped
    assert [float(r["start_time"]) for r in rows] == pytest.approx([0.0, 0.2])
    assert all(r["valid"] in ("0", "1") for r in rows)


# ---------------------------------------------------------------------------
# Errors: exit status 2, one line on stderr, no output file


def _fails(capsys, argv, out, *words):
    status, stdout, stderr = run_main(capsys, argv)
    assert_failed(status, stdout, stderr, *words)
    assert not out.exists() or out.read_text() == "old"
    assert [p.name for p in out.parent.iterdir() if p.name.startswith(".")] == []  # no temporary file


def test_attend_errors(fitted, tmp_path, capsys):
    out = tmp_path / "attend.csv"
    text = tmp_path / "clip.mp4"
    text.write_text("not a video\n" * 50)
    _fails(capsys, ["attend", text, "--model", fitted.model, "--out", out], out,
           "not a video OpenCV can read", "clip.mp4")
    _fails(capsys, ["attend", tmp_path / "nope.mp4", "--model", fitted.model, "--out", out], out,
           "no such video file or frame folder", "nope.mp4")
    _fails(capsys, ["attend", fitted.video, "--model", tmp_path / "none.json", "--out", out], out,
           "model file not found", "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    _fails(capsys, ["attend", fitted.video, "--model", bad, "--out", out], out, "invalid JSON", "bad.json:1")
    doc = json.loads(fitted.model.read_text())
    doc["metadata"] = {}
    blind = tmp_path / "blind.json"
    blind.write_text(json.dumps(doc))
    out.write_text("old")  # an existing output is kept
    _fails(capsys, ["attend", fitted.video, "--model", blind, "--out", out], out, "--focal-px", "blind.json")
    _fails(capsys, ["attend", fitted.video, "--model", fitted.model, "--out", out, "--max-frames", "3"], out,
           "fewer than one window of 4")
    _fails(capsys, ["attend", fitted.video, "--model", fitted.model, "--out", tmp_path / "no" / "a.csv"],
           out, "directory does not exist")
    blank = tmp_path / "blank.mkv"
    write_video(blank, [np.full((120, 160, 3), 90, np.uint8)] * 4, 10)
    _fails(capsys, ["attend", blank, "--model", fitted.model, "--out", out], out,
           "no face found in the first frame", "pass --initial-box", "blank.mkv")
    status, _, stderr = run_main(capsys, ["attend", blank, "--model", fitted.model, "--out", out, "--initial-box",
                                          "500", "10", "20", "20"])
    assert status == 2 and "--initial-box (500" in stderr and "initial_box" not in stderr
    for overlay, words in ((tmp_path / "o.mov", ("--overlay", "'.mov' is not a video extension", "o.mov")),
                           (tmp_path, ("--overlay", "exists and is not an empty folder")),
                           (out, ("--overlay and --out must be different files",))):
        _fails(capsys, ["attend", fitted.video, "--model", fitted.model, "--out", out, "--overlay", overlay], out,
               *words)


@pytest.mark.parametrize("argv", [
    ["attend", "v.mp4"],  # --model is required
    ["attend", "v.mp4", "--model", "m.json", "--window", "0"],
    ["attend", "v.mp4", "--model", "m.json", "--method", "bogus"],
    ["attend", "v.mp4", "--model", "m.json", "--focal-px", "-3"],
    ["fit-gaze"],  # --out is required
    ["fit-gaze", "--out", "m.json", "--method", "svm"],
])
def test_usage_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert "usage: jaxgaze" in capsys.readouterr().err


def test_fit_gaze_errors(tmp_path, capsys):
    out = tmp_path / "gp.json"
    _fails(capsys, ["fit-gaze", "--out", out, "--demo-video", tmp_path / "demo.mov"], out, "--demo-video",
           "demo.mov")
    _fails(capsys, ["fit-gaze", "--out", tmp_path / "no" / "gp.json"], out, "directory does not exist")
    _fails(capsys, ["fit-gaze", "--out", out, "--duration", "0.1"], out, "fewer than 2 frames")


def test_fit_gaze_progress_bar_on_tty(fitted, tmp_path, capsys, monkeypatch):
    """fit-gaze asks the GP fits for their progress bar when stderr is a terminal, not with -q.
    (The fit is faked by the fixture's model: the bar itself is tested in test_gp_exact.)"""
    import sys

    import jaxgaze.headpose.regression as regression

    calls = []

    def recording(*args, progress, **kwargs):
        calls.append(progress)
        return load_gaze_regression(fitted.model)

    monkeypatch.setattr(regression, "fit_gaze_regression", recording)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    out = tmp_path / "gp.json"
    for quiet in ([], ["-q"]):
        status, _, stderr = run_main(capsys, ["fit-gaze", "--out", out, "--people", "1", "--sessions", "1",
                                              "--duration", "3", *quiet])
        assert status == 0, stderr
        assert out.exists()
    assert calls == [True, False]


# ---------------------------------------------------------------------------
# The README's example, the overlay, a corrupt video

README = Path(__file__).resolve().parents[2] / "README.md"


def _readme_video_example():
    """The Python snippet and the ``jaxgaze attend`` command of the README's "From video to the attended object"."""
    text = README.read_text(encoding="utf-8")
    section = text[text.index("From video to the attended object"):]
    python = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    bash = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    command = next(line for line in bash.splitlines() if line.startswith("jaxgaze attend "))
    return python, shlex.split(command.split("#")[0])[1:]


def test_the_readme_snippet_and_the_command_attend_the_same_points(fitted, tmp_path, capsys, monkeypatch):
    """The README's video example as written, on the demo video and model of 'fit-gaze' (Yücel et al. 2013):
    the Python snippet and 'jaxgaze attend' agree window by window, on the objects on the table (the
    model's 320 x 240 rows scaled to the 640 x 480 video; unscaled, the points land by the face)."""
    python, argv = _readme_video_example()
    write_video(tmp_path / "demo.mp4", fitted.frames, 10.0)  # as 'fit-gaze --demo-video demo.mp4' writes it
    shutil.copy(fitted.model, tmp_path / "gp.json")
    monkeypatch.chdir(tmp_path)
    namespace = {"jg": jaxgaze}
    exec(python, namespace)
    snippet = namespace["out"]
    status, _, stderr = run_main(capsys, argv)
    assert status == 0, stderr
    assert "model image rows scaled x 2 to the 640x480 px video" in stderr and "warning" not in stderr
    _, rows = _rows(tmp_path / "attend.csv")
    assert snippet.image_scale == 2.0 and len(rows) == len(snippet.valid) == 6
    valid = np.array([r["valid"] == "1" for r in rows])
    np.testing.assert_array_equal(valid, snippet.valid)
    assert valid.sum() >= 4

    def table(*columns):
        return np.array([[float(r[c]) for c in columns] for r in rows if r["valid"] == "1"])

    np.testing.assert_array_equal(table("attended_x", "attended_y"), snippet.attended_xy[valid])
    np.testing.assert_array_equal(table("region_x_min", "region_y_min", "region_x_max", "region_y_max"),
                                  snippet.region_box[valid])
    np.testing.assert_allclose(table("probability")[:, 0], snippet.probability[valid], rtol=1e-4)  # float32/64
    boxes = fitted.truth.object_boxes_image  # the attended points are in the band of the objects' rows
    y = snippet.attended_xy[valid, 1]
    assert np.all((y >= boxes[:, 1].min() - 10) & (y <= boxes[:, 3].max() + 10)), (y, boxes)
    # The overlay: every frame of the windows, with the attended point drawn (mp4: lossy, so a red patch).
    overlay = read_frames(tmp_path / argv[argv.index("--overlay") + 1])
    assert len(overlay) == 24 and overlay[0].shape == (480, 640, 3)
    for t, frame in enumerate(overlay):
        if valid[t // 4]:
            x, y = np.floor(snippet.attended_xy[t // 4]).astype(int)
            r, g, b = frame[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3).mean(0)
            assert r > 170 and g < 90 and b < 90, (t, r, g, b)


def _windows(count, window):
    """Windows with nothing attended (what the overlay draws does not matter here)."""
    nan2 = np.full((count, 2), np.nan)
    return AttentionWindows(np.arange(count) * window, np.zeros((count, 3)), np.zeros(count), np.zeros(count), nan2,
                            nan2, np.full((count, 4), np.nan), np.zeros(count), np.zeros(count, bool), nan2,
                            ("tracker lost",) * count, window, 1.0)


def test_attend_overlay_as_png_folder_and_an_interrupt_while_drawing(fitted, tmp_path, capsys, monkeypatch):
    """The overlay is exact in a PNG folder (the attended discs where the windows say); an interrupt while
    drawing leaves neither the CSV nor the overlay (exit 130). The attention itself is stubbed."""
    windows = _windows(6, 4)._replace(valid=np.ones(6, bool), reason=("",) * 6,
                                      attended_xy=np.array([[100.5 + 20 * w, 300.5] for w in range(6)]))
    monkeypatch.setattr(vision_attend, "attend_frames", lambda *args, **kwargs: windows)
    out, folder = tmp_path / "a.csv", tmp_path / "frames"
    status, _, stderr = run_main(capsys, ["attend", fitted.video, "--model", fitted.model, "--out", out,
                                          "--overlay", folder])
    assert status == 0, stderr
    assert f"overlay of 24 frames written to {folder}" in stderr
    drawn = read_frames(folder)
    assert len(drawn) == 24
    for t, (frame, original) in enumerate(zip(drawn, fitted.frames)):
        red = np.argwhere(np.any(frame != original, -1) & np.all(frame == OVERLAY_COLOURS["attended"], -1))
        np.testing.assert_allclose(red.mean(0) + 0.5, windows.attended_xy[t // 4][::-1], atol=1e-9)

    def interrupted(image, windows, index):
        if index == 2:
            raise KeyboardInterrupt
        return image

    monkeypatch.setattr(vision_attend, "draw_attention", interrupted)
    out.write_text("old")
    for overlay in (tmp_path / "new", tmp_path / "new.avi"):
        status, _, stderr = run_main(capsys, ["attend", fitted.video, "--model", fitted.model, "--out", out,
                                              "--overlay", overlay])
        assert status == 130 and stderr.strip().splitlines()[-1] == "jaxgaze: interrupted"
        assert out.read_text() == "old"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "frames"]  # no overlay, no temporary file


def test_a_corrupt_video_gives_one_error_line_and_exit_2(fitted, tmp_path):
    """FFmpeg's own complaint ('moov atom not found') stays off stderr: only jaxgaze's line (a subprocess,
    as FFmpeg's logging is set up once per process)."""
    corrupt, out = tmp_path / "clip.mp4", tmp_path / "a.csv"
    corrupt.write_bytes(np.random.default_rng(0).bytes(20000))
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FFMPEG_LOGLEVEL"} | {"JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, "-m", "jaxgaze.cli", "attend", str(corrupt), "--model", str(fitted.model),
                           "--out", str(out)], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [f"jaxgaze: error: cannot open video: not a video OpenCV can read ({corrupt})"]
    assert done.stdout == "" and not out.exists()
