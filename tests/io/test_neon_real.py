"""Pupil Labs Neon: the real demo recording of ``pupil-labs/pl-neon-recording`` (tests/data/real/neon/,
PROVENANCE.md) read as downloaded through the ``neon`` extra, its counts checked against the raw streams
read here with numpy alone, its rays against OpenCV's forward projection."""

import ast
import json
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from jaxgaze.cli import main
from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.rays import read_rays_csv
from jaxgaze.io.tools import pupil, read_gaze_tool

neon_recording = pytest.importorskip("pupil_labs.neon_recording")  # the optional 'neon' extra

FOLDER = Path(__file__).resolve().parents[1] / "data" / "real" / "neon" / "demo_recording"


def raw_streams():
    """The gaze times (ns), the worn flags and the blink intervals, from the recording's binary files."""
    times = np.fromfile(FOLDER / "gaze_200hz.time", dtype="<i8")
    worn = np.fromfile(FOLDER / "worn_200hz.raw", dtype="u1")
    blink_dtype = np.dtype(ast.literal_eval((FOLDER / "blinks.dtype").read_text()))
    blinks = np.fromfile(FOLDER / "blinks ps1.raw", dtype=blink_dtype)
    return times, worn, blinks


def in_a_blink(times, blinks):
    return np.any((times[:, None] >= blinks["start_timestamp_ns"]) & (times[:, None] <= blinks["end_timestamp_ns"]),
                  axis=1)


def read(**options):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        recording = pupil.read_neon_recording(FOLDER, **options)
    return recording, [str(w.message) for w in caught if issubclass(w.category, UserWarning)]


def test_demo_recording_native_rate_and_counts():
    times, worn, blinks = raw_streams()
    blink = in_a_blink(times, blinks)
    assert len(times) == 1788 and worn.min() > 0 and blink.sum() == 100  # two blinks of 235 and 255 ms
    info = json.loads((FOLDER / "info.json").read_text())
    recording, messages = read()
    s = recording.sampling
    assert s.fps == info["gaze_frequency"] == 200  # the stream's own rate: median step 5 ms
    assert s.start_ns == times[~blink].min() and info["start_time"] <= s.start_ns
    # every sample outside the blinks keeps its own frame, except where the 200 Hz clock jitters two onto one
    frames = np.rint((times[~blink] - s.start_ns) * 200 / 1e9).astype(np.int64)
    merged = len(frames) - len(np.unique(frames))
    assert (s.read, s.filtered, s.merged, s.kept) == (1788, 100, merged, 1788 - 100 - merged) and merged == 3
    assert recording.frame_ids == sorted(np.unique(frames).tolist()) and recording.persons[0] == ["demo_recording"]
    assert messages == ["%s: dropped 103 of 1788 gaze samples (kept 1685): 0 not worn (worn stream 0), 100 in a "
                        "blink (blinks stream), 3 sharing a frame of the 200 fps grid with a nearer sample" % FOLDER]
    # on one 30 Hz clock, as asked: 257 frames kept of 1788 samples, and the message says so
    thirty, messages = read(fps=30.0)
    assert (thirty.sampling.kept, thirty.sampling.merged, thirty.sampling.filtered) == (257, 1431, 100)
    assert len(thirty.frame_ids) == 257 and "1431 sharing a frame of the 30 fps grid" in messages[0]


def test_demo_recording_rays_reproject_onto_the_gaze_pixels():
    recording, _ = read()
    native = neon_recording.open(FOLDER)
    times, pixels = np.asarray(native.gaze.time, np.int64), np.asarray(native.gaze.point, np.float64)
    calibration = native.calibration
    s = recording.sampling
    directions = np.asarray(recording.rays.directions, np.float64)[:, 0]
    origins = np.asarray(recording.rays.origins, np.float64)[:, 0]
    assert np.all(origins == 0)  # from the scene camera
    # each ray is its frame's nearest sample: the forward projection of its direction is that sample's pixel
    frame_times = s.start_ns + np.asarray(recording.frame_ids) * 1e9 / s.fps
    index = np.abs(times[None, :] - frame_times[:, None]).argmin(axis=1)
    opencv = directions @ R_OURS_FROM_OPENCV  # ours → OpenCV axes (z forward)
    assert np.all(opencv[:, 2] > 0)
    projected, _ = cv2.projectPoints(opencv.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                     np.asarray(calibration.scene_camera_matrix, np.float64),
                                     np.asarray(calibration.scene_distortion_coefficients, np.float64))
    np.testing.assert_allclose(projected.reshape(-1, 2), pixels[index], atol=1e-3)


def test_demo_recording_through_read_gaze_tool_and_convert(tmp_path, capsys):
    recording, _ = read()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        same = read_gaze_tool("pupil", [FOLDER])
    assert same.frame_ids == recording.frame_ids and same.sampling == recording.sampling
    out = tmp_path / "rays.csv"
    assert main(["convert", "--from", "pupil", str(FOLDER), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "dropped 103 of 1788 gaze samples" in err and "kept 1685 of 1788 samples at 200 fps" in err
    rays = read_rays_csv(out)
    assert rays.frame_ids == recording.frame_ids
    np.testing.assert_allclose(np.asarray(rays.rays.directions), np.asarray(recording.rays.directions), atol=1e-6)
    with pytest.raises(pupil.InputFileError, match="no info.json"):
        read_gaze_tool("pupil", [tmp_path])
