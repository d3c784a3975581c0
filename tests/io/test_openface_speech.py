"""Inputs of the speaker-prior gaze bias: the OpenFace 2 CSV reader (OpenCV → our
frames, mm → m, dropped frames), RTTM / CSV speech segments and speaking flags."""

import warnings
from fractions import Fraction
from pathlib import Path

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxgaze.bias.speech import SpeechSegments, speaking_flags
from jaxgaze.io.gaze import read_gaze
from jaxgaze.io.tools.openface import R_OPENFACE_MODEL_FROM_HEAD, OpenFaceFileError, read_openface
from jaxgaze.io.speech import SpeechFileError, read_rttm, read_segments_csv
from jaxgaze.geometry import axis_angle_to_rotation_matrix, yaw_pitch_to_direction
from jaxgaze.geometry import R_OURS_FROM_OPENCV

DATA = Path(__file__).parent.parent / "data"
OPENFACE = DATA / "openface_sample.csv"
RTTM = DATA / "speech_segments.rttm"
SEGMENTS_CSV = DATA / "speech_segments.csv"

# tests/data/openface_sample.csv, one face (face_id 0), 12 rows:
#   frame 1: pose 0, gaze angles 0, T = (0, 0, 500) mm  -> faces and looks at the camera
#   frame 2, 9: success 0 (frame 9 also has confidence 0.10: counted once, as success == 0)
#   frame 3: pose_Ry = 0.5     frame 4: pose_Rx = 0.3     frame 5: pose_Rz = 0.2
#   frame 6: confidence 0.60, frame 11: confidence 0.50   -> dropped at min_confidence 0.75
#   frame 7: gaze_angle_x = 0.4     frame 8: gaze_angle_y = 0.2
#   frame 10: T = (-100, 50, 800) mm     frame 12: a general pose and gaze
# gaze_0/gaze_1 are the two eyes' vectors; gaze_angle_* is atan2 of their mean.
KEPT = [1, 3, 4, 5, 7, 8, 10, 12]


def _read_sample(**kwargs):
    with pytest.warns(UserWarning, match="dropped"):
        return read_openface(OPENFACE, **kwargs)


def _row(track, frame):
    return int(np.nonzero(track.frame == frame)[0][0])


HEADER = ["frame", "face_id", "timestamp", "confidence", "success", "gaze_angle_x", "gaze_angle_y",
          "pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz", "AU01_r"]  # fmt: skip


def _openface_csv(tmp_path, rows, header=HEADER, sep=", ", name="openface_test.csv"):
    """A CSV with ``header``; each row is a dict overriding a valid default row."""
    lines = [sep.join(header)]
    for k, row in enumerate(rows):
        values = {"frame": k + 1, "face_id": 0, "timestamp": k / 30, "confidence": 0.98, "success": 1, "AU01_r": 0.5}
        values.update(row)
        lines.append(sep.join(str(values.get(c, 0.0)) for c in header))
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


# ---------------------------------------------------------------------------
# OpenFace: conventions


def test_R_openface_model_from_head_maps_our_head_axes():
    M = R_OPENFACE_MODEL_FROM_HEAD
    np.testing.assert_array_equal(M @ [1, 0, 0], [0, 0, -1])  # forward: toward the camera at pose 0 (−z)
    np.testing.assert_array_equal(M @ [0, 1, 0], [1, 0, 0])  # the person's left: image right (+x)
    np.testing.assert_array_equal(M @ [0, 0, 1], [0, -1, 0])  # up: image up (−y)
    np.testing.assert_array_equal(np.cross(M[:, 0], M[:, 1]), M[:, 2])  # forward × left = up
    np.testing.assert_allclose(M.T @ M, np.eye(3))
    assert np.linalg.det(M) == pytest.approx(1.0)


def test_read_openface_sample_keeps_frames_and_reports_drops():
    expected = r"dropped 4 of 12 frames of face_id 0 \(success == 0: 2, confidence < 0.75: 2\)"
    with pytest.warns(UserWarning, match=expected):
        track = read_openface(OPENFACE)
    np.testing.assert_array_equal(track.frame, KEPT)
    assert track.frame.dtype == np.int64
    assert track.dropped == {"success == 0": 2, "confidence < 0.75": 2}
    np.testing.assert_allclose(track.timestamp, [0.0, 0.067, 0.1, 0.133, 0.2, 0.233, 0.3, 0.367])
    np.testing.assert_allclose(track.confidence, [0.98, 0.97, 0.96, 0.95, 0.93, 0.92, 0.91, 0.90])
    assert track.gaze_direction_camera.shape == (8, 3)
    assert track.R_camera_from_head.shape == (8, 3, 3)
    assert track.head_position_camera.shape == (8, 3)
    assert track.gaze_angles_head.shape == (8, 2)
    assert track.gaze_direction_camera.dtype == track.R_camera_from_head.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(track.gaze_direction_camera, axis=1), 1.0)


def test_read_openface_min_confidence_changes_what_is_dropped():
    with pytest.warns(UserWarning, match=r"dropped 3 of 12 .*confidence < 0.55: 1"):
        track = read_openface(OPENFACE, min_confidence=0.55)
    assert track.dropped == {"success == 0": 2, "confidence < 0.55": 1}
    assert 6 in track.frame and 11 not in track.frame


def test_openface_zero_pose_and_gaze_face_and_look_at_the_camera():
    track = _read_sample()
    i = _row(track, 1)
    # Looking at the camera: the gaze points back along −x of our camera frame.
    np.testing.assert_allclose(track.gaze_direction_camera[i], [-1, 0, 0], atol=1e-12)
    # Head facing the camera: forward = −x_cam, the person's left = −y_cam (the camera's right), up = up.
    np.testing.assert_allclose(track.R_camera_from_head[i], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    np.testing.assert_allclose(track.head_direction_camera[i], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(track.gaze_angles_head[i], [0, 0], atol=1e-12)


def test_openface_position_mm_to_metres_in_our_camera_axes():
    track = _read_sample()
    # T = (0, 0, 500) mm: 0.5 m straight ahead of the camera.
    np.testing.assert_allclose(track.head_position_camera[_row(track, 1)], [0.5, 0, 0], atol=1e-12)
    # T = (−100, 50, 800) mm (OpenCV: 10 cm image-left, 5 cm below): ours x = 0.8, y = +0.1 (left), z = −0.05.
    np.testing.assert_allclose(track.head_position_camera[_row(track, 10)], [0.8, 0.1, -0.05], atol=1e-12)


def test_openface_pose_Ry_positive_turns_the_head_to_the_persons_right():
    track = _read_sample()
    i = _row(track, 3)  # pose_Ry = 0.5, gaze still at the camera
    b = 0.5
    # Forward swings from −x_cam toward +y_cam. Facing the camera, the person's right is +y_cam.
    np.testing.assert_allclose(track.head_direction_camera[i], [-np.cos(b), np.sin(b), 0], atol=1e-12)
    person_right = -track.R_camera_from_head[_row(track, 1)][:, 1]
    assert track.head_direction_camera[i] @ person_right > 0
    # To keep looking at the camera the eyes turn back to the person's left: yaw = +0.5.
    np.testing.assert_allclose(track.gaze_angles_head[i], [b, 0], atol=1e-12)


def test_openface_pose_Rx_positive_pitches_the_head_down():
    track = _read_sample()
    i = _row(track, 4)  # pose_Rx = 0.3
    a = 0.3
    np.testing.assert_allclose(track.head_direction_camera[i], [-np.cos(a), 0, -np.sin(a)], atol=1e-12)
    np.testing.assert_allclose(track.gaze_angles_head[i], [0, a], atol=1e-12)  # eyes look up at the camera


def test_openface_pose_Rz_positive_rolls_the_top_of_the_head_to_the_persons_left():
    track = _read_sample()
    i = _row(track, 5)  # pose_Rz = 0.2
    c = 0.2
    np.testing.assert_allclose(track.head_direction_camera[i], [-1, 0, 0], atol=1e-12)
    # Up axis: (0, −sin c, cos c); the person's left at pose 0 is −y_cam.
    np.testing.assert_allclose(track.R_camera_from_head[i][:, 2], [0, -np.sin(c), np.cos(c)], atol=1e-12)


def test_openface_gaze_angle_signs():
    track = _read_sample()
    # gaze_angle_x = 0.4 > 0: looking to the person's left (−y_cam); head-frame yaw +0.4.
    i = _row(track, 7)
    np.testing.assert_allclose(track.gaze_direction_camera[i], [-np.cos(0.4), -np.sin(0.4), 0], atol=1e-12)
    np.testing.assert_allclose(track.gaze_angles_head[i], [0.4, 0], atol=1e-12)
    # gaze_angle_y = 0.2 > 0: looking down (OpenCV +y is down); head-frame tilt −0.2.
    i = _row(track, 8)
    np.testing.assert_allclose(track.gaze_direction_camera[i], [-np.cos(0.2), 0, -np.sin(0.2)], atol=1e-12)
    np.testing.assert_allclose(track.gaze_angles_head[i], [0, -0.2], atol=1e-12)


def test_openface_gaze_is_the_mean_of_the_two_eye_vectors():
    """OpenFace's gaze_angle_* = atan2 of the mean of gaze_0 and gaze_1 (GetGazeAngle):
    our gaze must be that mean, unit, in our camera axes."""
    track = _read_sample()
    lines = OPENFACE.read_text().splitlines()
    names = [c.strip() for c in lines[0].split(",")]
    table = {int(r[0]): r for r in (np.array(ln.split(","), dtype=float) for ln in lines[1:])}
    for k, frame in enumerate(track.frame):
        row = table[int(frame)]
        g0 = row[[names.index(f"gaze_0_{a}") for a in "xyz"]]
        g1 = row[[names.index(f"gaze_1_{a}") for a in "xyz"]]
        mean = (g0 + g1) / 2
        expected = R_OURS_FROM_OPENCV @ mean / np.linalg.norm(mean)
        np.testing.assert_allclose(track.gaze_direction_camera[k], expected, atol=2e-6)


def test_openface_pose_is_intrinsic_xyz_euler_of_the_model_in_opencv():
    """R = Rx·Ry·Rz (scipy's intrinsic "XYZ"; also the product of our axis-angle rotations)."""
    track = _read_sample()
    lines = OPENFACE.read_text().splitlines()
    names = [c.strip() for c in lines[0].split(",")]
    table = {int(r[0]): r for r in (np.array(ln.split(","), dtype=float) for ln in lines[1:])}
    with jax.enable_x64(True):
        for k, frame in enumerate(track.frame):
            rx, ry, rz = table[int(frame)][[names.index(c) for c in ("pose_Rx", "pose_Ry", "pose_Rz")]]
            R_cv = Rotation.from_euler("XYZ", [rx, ry, rz]).as_matrix()
            R_ours = np.asarray(
                axis_angle_to_rotation_matrix(np.array([rx, 0, 0]))
                @ axis_angle_to_rotation_matrix(np.array([0, ry, 0]))
                @ axis_angle_to_rotation_matrix(np.array([0, 0, rz]))
            )
            np.testing.assert_allclose(R_ours, R_cv, atol=1e-12)
            expected = R_OURS_FROM_OPENCV @ R_cv @ R_OPENFACE_MODEL_FROM_HEAD
            np.testing.assert_allclose(track.R_camera_from_head[k], expected, atol=1e-12)
            R = track.R_camera_from_head[k]
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(R) == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(
    pose=st.tuples(*[st.floats(-0.5, 0.5)] * 3),
    yaw=st.floats(-0.6, 0.6),
    tilt=st.floats(-0.6, 0.6),
)
def test_openface_round_trip_head_frame_gaze(tmp_path_factory, pose, yaw, tilt):
    """Forward model as OpenFace computes it (gaze in the model frame → camera, then
    GetGazeAngle), written to CSV, reads back as the same head-frame (yaw, tilt)."""
    with jax.enable_x64(True):
        d_head = np.asarray(yaw_pitch_to_direction(yaw, tilt))
    g_cv = Rotation.from_euler("XYZ", pose).as_matrix() @ R_OPENFACE_MODEL_FROM_HEAD @ d_head
    ax, ay = np.arctan2(g_cv[0], -g_cv[2]), np.arctan2(g_cv[1], -g_cv[2])
    row = {"gaze_angle_x": repr(float(ax)), "gaze_angle_y": repr(float(ay)), "pose_Tz": 600.0}
    row.update({f"pose_R{a}": repr(v) for a, v in zip("xyz", pose)})
    path = _openface_csv(tmp_path_factory.mktemp("of"), [row])
    track = read_openface(path)
    np.testing.assert_allclose(track.gaze_angles_head[0], [yaw, tilt], atol=1e-9)
    np.testing.assert_allclose(track.gaze_direction_camera[0], R_OURS_FROM_OPENCV @ g_cv, atol=1e-9)


def test_openface_header_without_spaces_and_without_face_id(tmp_path):
    rows = [{"gaze_angle_x": 0.1, "pose_Tz": 400}, {"gaze_angle_x": 0.2, "pose_Tz": 400}]
    plain = read_openface(_openface_csv(tmp_path, rows, sep=",", name="a.csv"))
    no_face = read_openface(_openface_csv(tmp_path, rows, header=[c for c in HEADER if c != "face_id"], name="b.csv"))
    for track in (plain, no_face):
        np.testing.assert_array_equal(track.frame, [1, 2])
        np.testing.assert_allclose(track.gaze_angles_head[:, 0], [0.1, 0.2], atol=1e-12)
        assert track.dropped == {"success == 0": 0, "confidence < 0.75": 0}


def test_openface_no_warning_when_nothing_is_dropped(tmp_path):
    path = _openface_csv(tmp_path, [{}, {}])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_openface(path)


def test_openface_sorts_by_frame(tmp_path):
    path = _openface_csv(tmp_path, [{"frame": f, "pose_Tz": 100 * f} for f in (3, 1, 2)])
    track = read_openface(path)
    np.testing.assert_array_equal(track.frame, [1, 2, 3])
    np.testing.assert_allclose(track.head_position_camera[:, 0], [0.1, 0.2, 0.3])


def test_openface_several_faces_need_face_id(tmp_path):
    rows = [
        {"frame": 1, "face_id": 0, "pose_Tz": 500},
        {"frame": 1, "face_id": 1, "pose_Tz": 900},
        {"frame": 2, "face_id": 0, "pose_Tz": 500},
        {"frame": 2, "face_id": 1, "pose_Tz": 900, "success": 0},
    ]
    path = _openface_csv(tmp_path, rows)
    with pytest.raises(OpenFaceFileError, match=r"several faces \(face_id 0, 1\); pass face_id="):
        read_openface(path)
    with pytest.warns(UserWarning, match="dropped 1 of 2 frames of face_id 1"):
        track = read_openface(path, face_id=1)
    np.testing.assert_array_equal(track.frame, [1])
    np.testing.assert_allclose(track.head_position_camera, [[0.9, 0, 0]])
    np.testing.assert_array_equal(read_openface(path, face_id=0).frame, [1, 2])
    with pytest.raises(OpenFaceFileError, match=r"no rows with face_id 5 \(face_id present: 0, 1\)"):
        read_openface(path, face_id=5)


def test_openface_every_frame_dropped_is_an_error(tmp_path):
    path = _openface_csv(tmp_path, [{"success": 0}, {"confidence": 0.2}])
    with pytest.raises(ValueError, match=r"no frames left: all 2 frames .*success == 0: 1, confidence < 0.75: 1"):
        read_openface(path)


def test_openface_nan_in_a_dropped_frame_is_ignored(tmp_path):
    path = _openface_csv(tmp_path, [{}, {"success": 0, "gaze_angle_x": "nan", "pose_Tx": "inf"}])
    with pytest.warns(UserWarning, match="dropped 1 of 2"):
        np.testing.assert_array_equal(read_openface(path).frame, [1])


@pytest.mark.parametrize(
    "rows, message, line",
    [
        ([{"gaze_angle_x": "abc"}], r"column 'gaze_angle_x' is not a number: 'abc'", 2),
        ([{}, {"pose_Tz": ""}], r"column 'pose_Tz' is not a number: ''", 3),
        ([{}, {"gaze_angle_y": "nan"}], r"column 'gaze_angle_y' is not finite in a kept frame", 3),
        ([{"pose_Rx": "inf"}], r"column 'pose_Rx' is not finite in a kept frame", 2),
        ([{}, {"confidence": "nan"}], r"column 'confidence' is not finite", 3),
        ([{"frame": 1}, {"frame": 2}, {"frame": 1}], r"duplicate frame 1 of face_id 0 \(first on line 2\)", 4),
        ([{"frame": 1.5}], r"column 'frame' must be a 64-bit integer", 2),
        ([{"success": 2}], r"success must be 0 or 1", 2),
        ([{"gaze_angle_x": 1.6}], r"'gaze_angle_x' = 1.6 is outside", 2),
    ],
)
def test_openface_errors_name_file_and_line(tmp_path, rows, message, line):
    path = _openface_csv(tmp_path, rows)
    with pytest.raises(OpenFaceFileError, match=message) as info:
        read_openface(path)
    assert str(info.value).startswith(f"{path}, line {line}: ")
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    "text, message, line",
    [
        ("", r"empty file", 1),
        ("\n  \n", r"empty file", 1),
        (
            "frame, face_id, timestamp, confidence, success\n1, 0, 0, 1, 1\n",
            r"missing columns 'gaze_angle_x', 'gaze_angle_y', 'pose_Tx'",
            1,
        ),
        (", ".join(h for h in HEADER if h != "pose_Ry") + "\n", r"missing column 'pose_Ry' in the header", 1),
        (", ".join(HEADER) + "\n", r"no data rows after the header", 1),
        (", ".join(HEADER) + "\n1, 0, 0.0, 0.9\n", rf"expected {len(HEADER)} fields as in the header, got 4", 2),
        (", ".join(HEADER + ["frame"]) + "\n", r"duplicate column 'frame'", 1),
    ],
)
def test_openface_file_errors(tmp_path, text, message, line):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(OpenFaceFileError, match=message) as info:
        read_openface(path)
    assert str(info.value).startswith(f"{path}, line {line}: ")


@pytest.mark.parametrize(
    "name, missing, flags",
    [
        ("openface_pose_aus.csv", "'gaze_angle_x', 'gaze_angle_y'", "-gaze (it writes gaze_0_x … gaze_angle_y)"),
        ("openface_gaze_2dfp.csv", "'pose_Tx', 'pose_Ty', 'pose_Tz', 'pose_Rx', 'pose_Ry', 'pose_Rz'",
         "-pose (it writes pose_Tx … pose_Rz)"),
    ],
)
def test_openface_written_without_gaze_or_pose_names_the_flag(name, missing, flags):
    """Genuine FeatureExtraction output (-pose -aus; -gaze -2Dfp, with its eye landmarks): the error names
    the missing columns and the flag that writes them, and does not ask whether it is OpenFace's."""
    path = DATA / name
    for reader in (read_openface, read_gaze):  # read_gaze recognises the header as OpenFace's
        with pytest.raises(OpenFaceFileError) as info:
            reader(path)
        assert str(info.value) == (f"{path}, line 1: missing columns {missing} in the header (this OpenFace output "
                                   f"was written without them: run FeatureExtraction with {flags}, or with no output "
                                   "flag at all for every column)")
    assert "is this" not in str(info.value)


def test_openface_hint_for_a_file_that_is_not_openface(tmp_path):
    path = tmp_path / "other.csv"
    path.write_text("frame,yaw,tilt\n1,0,0\n")
    with pytest.raises(OpenFaceFileError, match=r"missing columns 'timestamp', .*\(is this an OpenFace 2 "
                       r"FeatureExtraction CSV\?\)$"):
        read_openface(path)


def test_openface_truncated_last_row_is_dropped_with_a_warning(tmp_path):
    """A recording cut off mid-write: the last of 5 rows stops after 145 of 299 fields, with no newline."""
    path = DATA / "openface_gaze_pose_cut.csv"
    with pytest.warns(UserWarning) as record:
        track = read_openface(path)
    (message,) = [str(w.message) for w in record]
    assert message == (f"{path}: dropped the last row: line 6 is cut off (145 of 299 fields and no newline at the "
                       "end of the file); read the 4 complete row(s) before it")
    np.testing.assert_array_equal(track.frame, [1, 2, 3, 4])
    text = path.read_text()
    complete = tmp_path / "complete.csv"
    complete.write_text(text[: text.rindex("\n") + 1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        expected = read_openface(complete)
    for a, b in zip(track[:-1], expected[:-1]):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(track.head_position_camera[:, 0], 0.512)  # pose_Tz 512 mm


@pytest.mark.parametrize(
    "cut, message, line",
    [
        (lambda t: t.replace("\n2, 0", "\n2, 0, 0.0\n9, 0", 1), "expected 14 fields as in the header, got 3", 3),
        (lambda t: t[: t.rindex(",")] + "\n", "expected 14 fields as in the header, got 13", 4),
        (lambda t: t[: t.index(",", t.index("\n"))], "no data rows after the header: line 2 is cut off (1 of 14 "
         "fields and no newline at the end of the file)", 1),
    ],
)
def test_openface_short_rows_that_are_not_a_cut_off_end_stay_errors(tmp_path, cut, message, line):
    """A short row in the middle, or a short last row that ends in a newline, is an error; a cut-off
    only row leaves no data."""
    text = _openface_csv(tmp_path, [{}, {}, {}]).read_text()
    path = tmp_path / "short.csv"
    path.write_text(cut(text))
    with pytest.raises(OpenFaceFileError) as info:
        read_openface(path)
    assert str(info.value) == f"{path}, line {line}: {message}"


def test_openface_missing_file_and_bad_min_confidence(tmp_path):
    with pytest.raises(OpenFaceFileError, match="file not found"):
        read_openface(tmp_path / "nope.csv")
    with pytest.raises(ValueError, match="min_confidence"):
        read_openface(OPENFACE, min_confidence=float("nan"))


# ---------------------------------------------------------------------------
# Speaking status

# Expected flags at fps = 10 for 15 frames (times 0.0 … 1.4 s), from the files' headers.
FLAGS_A = [1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 0]  # [0, 0.35) and [1.0, 1.4) (merged)
FLAGS_B = [0, 0, 0, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0]  # [0.3, 0.7): 0.3 in, 0.7 out
FLAGS_C = [1] * 10 + [0] * 5  # file "other": [0, 1.0)


def _both_recordings():
    """meeting1 and other of tests/data/speech_segments.rttm as one list of segments (for the flag tests)."""
    with pytest.warns(UserWarning, match="merged"):
        meeting = read_rttm(RTTM, file_id="meeting1")
    other = read_rttm(RTTM, file_id="other")
    return SpeechSegments(np.concatenate([meeting.start, other.start]), np.concatenate([meeting.end, other.end]),
                          meeting.speaker + other.speaker)


def test_read_rttm_merges_same_speaker_overlap_within_a_recording():
    expected = r"merged 1 overlapping segment\(s\) of the same speaker: 'A' line 9 overlaps line 8$"
    with pytest.warns(UserWarning, match=expected):
        segments = read_rttm(RTTM, file_id="meeting1")
    assert isinstance(segments, SpeechSegments)
    np.testing.assert_allclose(segments.start, [0.0, 0.3, 1.0])
    np.testing.assert_allclose(segments.end, [0.35, 0.7, 1.4])
    assert segments.speaker == ("A", "B", "A")
    assert segments.end[2] == 1.4  # 1.1 + 0.3 rounded to 1 ns: exactly the decimal 1.4


def test_read_rttm_of_several_recordings_needs_a_file_id():
    """AMI's dev.rttm holds 18 recordings whose speaker names repeat: without file_id they must not be
    put on one timeline (the fixture: 3 recordings in AMI's format, FEE041 speaking in two of them)."""
    ami = DATA / "ami_style_three_recordings.rttm"
    with pytest.raises(SpeechFileError) as info:
        read_rttm(ami)
    assert str(info.value) == (f"{ami}, line 6: a second recording 'ES2011b' starts here: the RTTM holds 3 "
                               "recordings (file ids ES2011a, ES2011b, IS1008a) on separate clocks; choose one "
                               "(file_id, --speech-file-id)")
    with pytest.raises(SpeechFileError, match=r"line 10: a second recording 'other'"):
        read_rttm(RTTM)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one recording: nothing of the others merged into it
        segments = read_rttm(ami, file_id="ES2011b")
    np.testing.assert_allclose(segments.start, [0.72, 2.15, 4.4, 5.61])
    np.testing.assert_allclose(segments.end, [3.78, 3.35, 5.35, 7.63])
    assert segments.speaker == ("FEE041", "MEE044", "MEO069", "FEE041")


def test_read_rttm_lists_the_first_few_of_many_recordings(tmp_path):
    path = tmp_path / "set.rttm"
    path.write_text("".join(f"SPEAKER rec{k:02d} 1 0.0 1.0 <NA> <NA> A <NA> <NA>\n" for k in range(40)))
    with pytest.raises(SpeechFileError) as info:
        read_rttm(path)
    assert "40 recordings (file ids rec00, rec01, rec02, rec03, rec04 … and 35 more)" in str(info.value)
    assert len(info.value.what) < 200
    with pytest.raises(SpeechFileError) as info:
        read_rttm(path, file_id="x")
    assert "(files present: rec00, rec01, rec02, rec03, rec04 … and 35 more)" in str(info.value)


def test_read_rttm_warning_of_many_overlaps_stays_short(tmp_path):
    path = tmp_path / "overlaps.rttm"
    path.write_text("".join(f"SPEAKER f 1 {k}.0 1.5 <NA> <NA> A <NA> <NA>\n" for k in range(1001)))
    with pytest.warns(UserWarning) as record:
        segments = read_rttm(path)
    (message,) = [str(w.message) for w in record]
    assert message.startswith(f"{path}: merged 1000 overlapping segment(s) of the same speaker: 'A' line 2 overlaps "
                              "line 1; 'A' line 3 overlaps line 1; 'A' line 4 overlaps line 1 … and 997 more")
    assert len(message) - len(str(path)) < 300
    np.testing.assert_allclose([segments.start[0], segments.end[0]], [0.0, 1001.5])


def test_read_rttm_file_id_filter():
    with pytest.warns(UserWarning, match="merged"):
        segments = read_rttm(RTTM, file_id="meeting1")
    assert segments.speakers == ("A", "B")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        other = read_rttm(RTTM, file_id="other")
    assert other.speaker == ("C",)
    with pytest.raises(SpeechFileError, match=r"no SPEAKER lines for file 'x' \(files present: meeting1, other\)"):
        read_rttm(RTTM, file_id="x")


def test_read_segments_csv_matches_rttm():
    with pytest.warns(UserWarning, match=r"'A' line 6 overlaps line 5"):
        from_csv = read_segments_csv(SEGMENTS_CSV)
    with pytest.warns(UserWarning, match="merged"):
        from_rttm = read_rttm(RTTM, file_id="meeting1")
    np.testing.assert_array_equal(from_csv.start, from_rttm.start)
    np.testing.assert_array_equal(from_csv.end, from_rttm.end)
    assert from_csv.speaker == from_rttm.speaker == ("A", "B", "A")


def test_speaking_flags_known_values_fps_10():
    segments = _both_recordings()
    # A and B both speak at frame 3 (0.3 s) only.
    with pytest.warns(UserWarning, match=r"1 of 15 frames have two or more of the speakers speaking at once"):
        flags = speaking_flags(segments, ["A", "B"], 15, 10)
    assert flags.dtype == bool and flags.shape == (2, 15)
    np.testing.assert_array_equal(flags, np.array([FLAGS_A, FLAGS_B], dtype=bool))
    # Adding C (file "other", [0, 1.0)): A&C on frames 0-3, B&C on 3-6 -> 7 overlapping frames.
    with pytest.warns(UserWarning, match=r"7 of 15 frames"):
        flags = speaking_flags(segments, ["A", "B", "C"], 15, 10)
    np.testing.assert_array_equal(flags, np.array([FLAGS_A, FLAGS_B, FLAGS_C], dtype=bool))


def test_speaking_flags_overlap_counts_only_requested_speakers():
    segments = _both_recordings()
    # A and C overlap on frames 0-3 only (B is not asked for).
    with pytest.warns(UserWarning, match=r"4 of 15 frames"):
        speaking_flags(segments, ["C", "A"], 15, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # B alone: nothing overlaps, nothing unknown
        flags = speaking_flags(segments, ["B"], 15, 10)
    np.testing.assert_array_equal(flags[0], np.array(FLAGS_B, dtype=bool))


def test_speaking_flags_unknown_speaker_is_all_false_with_warning():
    with pytest.warns(UserWarning, match="merged"):
        segments = read_rttm(RTTM, file_id="meeting1")
    with pytest.warns(UserWarning) as record:
        flags = speaking_flags(segments, ["C", "A", "Z"], 15, 10)
    messages = [str(w.message) for w in record]
    assert any("unknown speaker(s) 'C', 'Z'" in m for m in messages)
    assert not any("at once" in m for m in messages)  # C and Z never speak, A alone
    np.testing.assert_array_equal(flags[0], False)
    np.testing.assert_array_equal(flags[2], False)
    np.testing.assert_array_equal(flags[1], np.array(FLAGS_A, dtype=bool))


def test_speaking_flags_start_time_and_boundaries():
    segments = SpeechSegments(np.array([1.0, 2.0]), np.array([1.3, 2.0]), ("A", "A"))
    # Frames at 0.9, 1.0, 1.1, 1.2, 1.3, 1.4 s: start included, end excluded.
    flags = speaking_flags(segments, ["A"], 6, 10, start_time=0.9)
    np.testing.assert_array_equal(flags[0], [False, True, True, True, False, False])
    # The zero-length segment [2.0, 2.0) flags nothing.
    np.testing.assert_array_equal(speaking_flags(segments, ["A"], 3, 10, start_time=1.9)[0], [False, False, False])
    assert speaking_flags(segments, ["A"], 0, 10).shape == (1, 0)


def test_touching_segments_of_one_speaker_are_not_merged(tmp_path):
    path = tmp_path / "speech_touching.csv"
    path.write_text("speaker,start,end\nA,0.0,0.5\nA,0.5,1.0\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        segments = read_segments_csv(path)
    assert segments.speaker == ("A", "A")
    np.testing.assert_array_equal(speaking_flags(segments, ["A"], 10, 10)[0], True)


@settings(max_examples=60, deadline=None)
@given(
    data=st.lists(
        st.tuples(st.sampled_from(["A", "B"]), st.integers(0, 3000), st.integers(0, 800)), min_size=0, max_size=8
    ),
    fps=st.sampled_from([10, 24, 25, 30, 50]),
    start_ms=st.integers(-500, 1500),
    num_frames=st.integers(0, 120),
)
def test_speaking_flags_equal_brute_force(data, fps, start_ms, num_frames):
    """Segments on a 1 ms grid; exact rational per-frame check of start ≤ t < end."""
    segments = SpeechSegments(
        np.array([s / 1000 for _, s, _ in data], dtype=float),
        np.array([(s + d) / 1000 for _, s, d in data], dtype=float),
        tuple(name for name, _, _ in data),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flags = speaking_flags(segments, ["A", "B"], num_frames, fps, start_time=start_ms / 1000)
    for row, name in enumerate(["A", "B"]):
        for t in range(num_frames):
            time = Fraction(start_ms, 1000) + Fraction(t, fps)
            expected = any(Fraction(s, 1000) <= time < Fraction(s + d, 1000) for n, s, d in data if n == name)
            assert flags[row, t] == expected


@pytest.mark.parametrize(
    "text, message, line",
    [
        ("", r"empty file", 1),
        (";; only a comment\nSPKR-INFO f 1 <NA> <NA> <NA> unknown A <NA> <NA>\n", r"no SPEAKER lines", None),
        ("SPEAKER f 1 0.0 1.0 <NA> <NA>\n", r"at least 8 fields", 1),
        (
            "SPEAKER f 1 0.0 1.0 <NA> <NA> A <NA> <NA>\nSPEAKER f 1 abc 1.0 <NA> <NA> A <NA> <NA>\n",
            r"onset is not a number: 'abc'",
            2,
        ),
        ("SPEAKER f 1 0.0 nan <NA> <NA> A <NA> <NA>\n", r"duration is not finite: 'nan'", 1),
        (";; c\nSPEAKER f 1 2.0 -0.5 <NA> <NA> A <NA> <NA>\n", r"negative duration -0.5", 2),
    ],
)
def test_read_rttm_errors(tmp_path, text, message, line):
    path = tmp_path / "bad.rttm"
    path.write_text(text)
    with pytest.raises(SpeechFileError, match=message) as info:
        read_rttm(path)
    where = f"{path}, line {line}: " if line else f"{path}: "
    assert str(info.value).startswith(where)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    "text, message, line",
    [
        ("", r"empty file", 1),
        ("# comment only\n", r"empty file", 1),
        ("start,end\n0,1\n", r"missing column 'speaker'", 1),
        ("start,end,speaker\n", r"no data rows after the header", 1),
        ("start,end,speaker\n0,1,A\nx,1,A\n", r"column 'start' is not a number: 'x'", 3),
        ("start,end,speaker\n0,nan,A\n", r"column 'end' is not finite: 'nan'", 2),
        ("start,end,speaker\n2.0,1.5,A\n", r"end 1.5 is before start 2.0", 2),
        ("start,end,speaker\n0,1, \n", r"empty speaker name", 2),
        ("start,end,speaker\n0,1\n", r"expected 3 fields as in the header, got 2", 2),
    ],
)
def test_read_segments_csv_errors(tmp_path, text, message, line):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(SpeechFileError, match=message) as info:
        read_segments_csv(path)
    assert str(info.value).startswith(f"{path}, line {line}: ")


def test_speech_missing_file(tmp_path):
    for reader in (read_rttm, read_segments_csv):
        with pytest.raises(SpeechFileError, match="file not found"):
            reader(tmp_path / "nope")


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"speakers": "A"}, TypeError, "not the string"),
        ({"speakers": ["A", "A"]}, ValueError, "duplicate"),
        ({"num_frames": -1}, ValueError, "num_frames"),
        ({"fps": 0.0}, ValueError, "fps"),
        ({"fps": float("inf")}, ValueError, "fps"),
        ({"start_time": float("nan")}, ValueError, "start_time"),
        ({"segments": SpeechSegments(np.array([1.0]), np.array([0.5]), ("A",))}, ValueError, "end ≥ start"),
        ({"segments": SpeechSegments(np.array([0.0, 1.0]), np.array([0.5]), ("A",))}, ValueError, "2 starts, 1 ends"),
    ],
)
def test_speaking_flags_argument_errors(kwargs, error, message):
    segments = SpeechSegments(np.array([0.0]), np.array([1.0]), ("A",))
    args = {"segments": segments, "speakers": ["A"], "num_frames": 5, "fps": 10.0}
    args.update(kwargs)
    with pytest.raises(error, match=message):
        speaking_flags(**args)


def test_openface_pose_and_gaze_is_the_inverse_of_the_reader(tmp_path):
    """Columns written by openface_pose_and_gaze read back (read_openface) as the same pose and gaze."""
    from scipy.spatial.transform import Rotation

    from jaxgaze.io.tools.openface import OPENFACE_COLUMNS, openface_pose_and_gaze

    rng = np.random.default_rng(4)
    T = 40
    # heads facing the camera (our −x) within ±40°, gaze toward the camera within ±50°
    R = Rotation.from_euler("zyx", rng.uniform(-0.7, 0.7, (T, 3))).as_matrix() @ Rotation.from_euler(
        "z", np.pi).as_matrix()
    position = np.column_stack([rng.uniform(0.5, 3.0, T), rng.uniform(-0.5, 0.5, (T, 2))])
    gaze = Rotation.from_euler("zy", rng.uniform(-0.8, 0.8, (T, 2))).apply([-1.0, 0.0, 0.0])
    columns = openface_pose_and_gaze(R, position, gaze)
    rows = [", ".join([str(t + 1), f"{t / 10:.1f}", "0.98", "1", *(repr(float(columns[c][t])) for c in
                                                                  OPENFACE_COLUMNS[4:])]) for t in range(T)]
    path = tmp_path / "of.csv"
    path.write_text(", ".join(OPENFACE_COLUMNS) + "\n" + "\n".join(rows) + "\n")
    track = read_openface(path)
    np.testing.assert_allclose(track.R_camera_from_head, R, atol=1e-12)
    np.testing.assert_allclose(track.head_position_camera, position, atol=1e-12)
    np.testing.assert_allclose(track.gaze_direction_camera, gaze, atol=1e-12)
