"""ETH-XGaze / ptgaze and MediaPipe Face Landmarker adapters: known gazes from each tool's published
conversion, de-normalisation of a synthetic off-axis face, round trips of the dumps, bad input."""

import json
import math
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from jaxgaze.io.tools.mediapipe import (
    DEFAULT_BANDWIDTH_MEDIAPIPE,
    mediapipe_to_rays,
    read_mediapipe,
    write_mediapipe,
)
from jaxgaze.io.text import InputFileError
from jaxgaze.io.tools.xgaze import (
    DEFAULT_BANDWIDTH_XGAZE,
    ETH_XGAZE_FACE_MODEL,
    xgaze_head_pose,
    xgaze_to_rays,
    read_xgaze,
    write_xgaze,
)
from jaxgaze.poses import camera_poses

DATA = Path(__file__).parent.parent / "data"
XGAZE = DATA / "xgaze_ptgaze_dump.csv"
MEDIAPIPE = DATA / "mediapipe_face_landmarker.jsonl"
TEN = math.radians(10.0)
LOOK_AT_CAMERA = [-1.0, 0.0, 0.0]
LOOK_LEFT = [-math.cos(TEN), -math.sin(TEN), 0.0]  # the person's left is the camera's right: our −y
LOOK_UP = [-math.cos(TEN), 0.0, math.sin(TEN)]

# tests/data/xgaze_ptgaze_dump.csv (OpenCV face centres, metres; g_norm = −(cos p sin y, sin p, cos p cos y);
# ETH-XGaze's R is the identity for an upright face straight ahead, so g_camera = g_norm):
#   frame 0, a: (0, 0, 0.6), (0, 0)             -> into the camera, from ours (0.6, 0, 0)
#   frame 0, b: (0, 0, 1.2), yaw −10°           -> g = (sin 10°, 0, −cos 10°): the camera's right
#   frame 1, a: (0, 0, 0.6), pitch +10°         -> g = (0, −sin 10°, −cos 10°): up
#   frame 1, b: 30° to the camera's right, (0.6 sin 30°, 0, 0.6 cos 30°), R rows (cos 30°, 0, −sin 30°),
#               (0, 1, 0), (sin 30°, 0, cos 30°), (0, 0) -> Rᵀ(0, 0, −1) = (−sin 30°, 0, −cos 30°):
#               back into the camera, ours (−cos 30°, sin 30°, 0) from (0.6 cos 30°, −0.3, 0)
XGAZE_EXPECTED = {
    (0, "a"): ([0.6, 0.0, 0.0], LOOK_AT_CAMERA),
    (0, "b"): ([1.2, 0.0, 0.0], LOOK_LEFT),
    (1, "a"): ([0.6, 0.0, 0.0], LOOK_UP),
    (1, "b"): ([0.6 * math.cos(math.radians(30)), -0.3, 0.0], [-math.cos(math.radians(30)), 0.5, 0.0]),
}
# tests/data/mediapipe_face_landmarker.jsonl (MediaPipe camera space: x right, y up, z toward the viewer, cm;
# the face's forward is the matrix's third column):
#   frame 0, face 0: identity, t = (0, 0, −60)   -> forward (0, 0, 1): into the camera; eyes at
#                    (0, 2.624618, 3.465663 − 60) cm = ours (0.56534337, 0, 0.02624618) m
#   frame 0, face 1: R_y(10°), forward (sin 10°, 0, cos 10°): toward +x, the person's left
#   frame 1, face 0: R_x(−10°) (written as 4 rows of 4), forward (0, sin 10°, cos 10°): up
#   frame 2: no face
MEDIAPIPE_EXPECTED = {(0, "0"): LOOK_AT_CAMERA, (0, "1"): LOOK_LEFT, (1, "0"): LOOK_UP}


def _rows(recording):
    """{(frame, person): (origin, direction, bandwidth)} of the real rays."""
    out = {}
    for t, (frame, persons) in enumerate(zip(recording.frame_ids, recording.persons)):
        for n, person in enumerate(persons):
            out[(frame, person)] = (np.asarray(recording.rays.origins[t, n], float),
                                    np.asarray(recording.rays.directions[t, n], float),
                                    float(recording.rays.bandwidth[t, n]))
    return out


def _same_rays(a, b):
    ra, rb = _rows(a), _rows(b)
    assert ra.keys() == rb.keys()
    for key in ra:
        np.testing.assert_allclose(ra[key][0], rb[key][0], atol=1e-6)
        np.testing.assert_allclose(ra[key][1], rb[key][1], atol=1e-6)


def _rotvec(v):
    return cv2.Rodrigues(np.asarray(v, dtype=np.float64))[0]


# ---------------------------------------------------------------------------- ETH-XGaze / ptgaze


def test_xgaze_fixture_gives_the_hand_computed_world_rays():
    rows = _rows(read_xgaze(XGAZE))
    assert rows.keys() == XGAZE_EXPECTED.keys()
    for key, (origin, direction) in XGAZE_EXPECTED.items():
        np.testing.assert_allclose(rows[key][0], origin, atol=1e-6)
        np.testing.assert_allclose(rows[key][1], direction, atol=1e-6)
        assert rows[key][2] == pytest.approx(DEFAULT_BANDWIDTH_XGAZE)
    assert DEFAULT_BANDWIDTH_XGAZE == pytest.approx(math.radians(4.4929) / math.sqrt(math.pi / 2))


def test_xgaze_arrays_with_an_upright_frontal_head():
    rec = xgaze_to_rays([0.0, 0.0, TEN], [0.0, -TEN, 0.0], [0.0, 0.0, 0.6], R_head=np.eye(3))
    directions = np.asarray(rec.rays.directions, float).reshape(-1, 3)
    np.testing.assert_allclose(directions, [LOOK_AT_CAMERA, LOOK_LEFT, LOOK_UP], atol=1e-6)


def test_xgaze_denormalisation_recovers_the_true_gaze_of_an_off_axis_face():
    """Normalise as ETH-XGaze's normalizeData_face (forward, down = forward × h_x, right = down × forward;
    pitch = arcsin(−g_y), yaw = arctan2(−g_x, −g_z)), then de-normalise with the adapter."""
    rng = np.random.default_rng(3)
    centers = np.array([[0.25, -0.1, 0.7], [-0.4, 0.15, 1.1], [0.05, 0.3, 0.5]])
    R_heads = np.stack([_rotvec(v) for v in [(0.1, 0.5, 0.05), (-0.2, -0.7, 0.3), (0.4, 0.1, -0.2)]])
    targets = rng.normal(0.0, 0.5, (3, 3))
    truth = (targets - centers) / np.linalg.norm(targets - centers, axis=1, keepdims=True)
    pitch, yaw, Rs = [], [], []
    for c, h, g in zip(centers, R_heads, truth):
        forward = c / np.linalg.norm(c)
        down = np.cross(forward, h[:, 0])
        down /= np.linalg.norm(down)
        right = np.cross(down, forward)
        R = np.c_[right / np.linalg.norm(right), down, forward].T
        g_norm = R @ g
        pitch.append(np.arcsin(-g_norm[1]))
        yaw.append(np.arctan2(-g_norm[0], -g_norm[2]))
        Rs.append(R)
    truth_ours = truth @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0.0]]).T
    for kwargs in ({"R_head": R_heads}, {"R_normalizing": np.stack(Rs)}):
        rec = xgaze_to_rays(pitch, yaw, centers, frames=[0, 0, 0], persons=["p", "q", "r"], **kwargs)
        np.testing.assert_allclose(np.asarray(rec.rays.directions, float)[0], truth_ours, atol=1e-5)
    # From landmarks and intrinsics: project the face model, recover the head pose as ETH-XGaze's demo.
    K = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    rvec, tvec = np.array([0.1, 0.5, 0.05]), np.array([0.2, -0.08, 0.72])
    image, _ = cv2.projectPoints(np.asarray(ETH_XGAZE_FACE_MODEL), rvec, tvec, K, np.zeros(5))
    center, R_head = xgaze_head_pose(image.reshape(6, 2), K)
    face = ETH_XGAZE_FACE_MODEL @ _rotvec(rvec).T + tvec
    np.testing.assert_allclose(center, (face[:4].mean(0) + face[4:].mean(0)) / 2, atol=1e-6)
    np.testing.assert_allclose(R_head, _rotvec(rvec), atol=1e-6)


def test_xgaze_head_pose_rotvec_columns_and_the_round_trip(tmp_path):
    dump = tmp_path / "head.csv"
    dump.write_text("frame,person,pitch,yaw,center_x,center_y,center_z,head_pose_rot_x,head_pose_rot_y,"
                    "head_pose_rot_z\n0,a,0,0,0,0,0.6,0,0,0\n0,b,0,-0.17453292519943295,0,0,1.2,0,0,0\n")
    rows = _rows(read_xgaze(dump))
    np.testing.assert_allclose(rows[(0, "a")][1], LOOK_AT_CAMERA, atol=1e-9)
    np.testing.assert_allclose(rows[(0, "b")][1], LOOK_LEFT, atol=1e-9)
    camera = camera_poses(np.eye(3)[None], [[1.0, 2.0, 1.5]], [0])
    rec = read_xgaze(XGAZE, camera=camera)
    np.testing.assert_allclose(_rows(rec)[(0, "a")][0], [1.6, 2.0, 1.5], atol=1e-9)
    out = tmp_path / "again.csv"
    assert write_xgaze(out, rec, camera=camera) == 4
    _same_rays(read_xgaze(out, camera=camera), rec)


@pytest.mark.parametrize("row, line, message", [
    ("0,a,zero,0,0,0,0.6,1,0,0,0,1,0,0,0,1", 3, "pitch"),
    ("0,a,0,45,0,0,0.6,1,0,0,0,1,0,0,0,1", 3, "degrees"),
    ("0,a,0,0,0,0,600,1,0,0,0,1,0,0,0,1", 3, "millimetres"),
    ("0,a,0,0,0,0,0.6,1,0,0,0,2,0,0,0,1", 3, "rotation"),
    ("0,q,0,0,0,0,0.6,1,0,0,0,1,0,0,0,1", 3, "duplicate"),
])
def test_xgaze_bad_rows_name_the_file_and_line(tmp_path, row, line, message):
    text = XGAZE.read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([text[0], "0,q,0,0,0,0,0.6,1,0,0,0,1,0,0,0,1", row]) + "\n")
    with pytest.raises(InputFileError, match=message) as error:
        read_xgaze(bad)
    assert error.value.line == line and error.value.path == str(bad)


def test_xgaze_header_without_a_rotation_is_an_error(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,person,pitch,yaw,center_x,center_y,center_z,head_pose_rot_x\n0,a,0,0,0,0,0.6,0\n")
    with pytest.raises(InputFileError, match="normalising rotation is missing") as error:
        read_xgaze(bad)
    assert error.value.line == 1


# ---------------------------------------------------------------------------- MediaPipe


def test_mediapipe_fixture_gives_the_hand_computed_world_rays():
    rows = _rows(read_mediapipe(MEDIAPIPE))
    assert rows.keys() == MEDIAPIPE_EXPECTED.keys()
    for key, direction in MEDIAPIPE_EXPECTED.items():
        np.testing.assert_allclose(rows[key][1], direction, atol=1e-6)
        assert rows[key][2] == pytest.approx(DEFAULT_BANDWIDTH_MEDIAPIPE)
    np.testing.assert_allclose(rows[(0, "0")][0], [0.56534337, 0.0, 0.02624618], atol=1e-7)


def test_mediapipe_duck_typed_results_and_field_of_view():
    c, s = math.cos(TEN), math.sin(TEN)
    frontal = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -60.0], [0, 0, 0, 1]])
    left = np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, -60.0], [0, 0, 0, 1]])
    results = [SimpleNamespace(facial_transformation_matrixes=[frontal, left]),
               SimpleNamespace(facial_transformation_matrixes=[])]
    rec = mediapipe_to_rays(results, frames=[5, 6])
    assert rec.frame_ids == [5] and rec.persons == [["0", "1"]]
    np.testing.assert_allclose(np.asarray(rec.rays.directions, float)[0], [LOOK_AT_CAMERA, LOOK_LEFT], atol=1e-9)
    # A camera with a 90° vertical field of view: depth × tan(31.5°) / tan(45°); x and y unchanged.
    wide = mediapipe_to_rays(results[0], vertical_fov_deg=90.0)
    np.testing.assert_allclose(np.asarray(wide.rays.origins, float)[0, 0],
                               [(60 - 3.465663) * math.tan(math.radians(31.5)) / 100, 0.0, 0.02624618], atol=1e-7)
    with pytest.raises(ValueError, match="facial_transformation_matrixes"):
        mediapipe_to_rays([SimpleNamespace(face_landmarks=[])])
    with pytest.raises(ValueError, match="degrees"):
        mediapipe_to_rays(results, bandwidth=11.5)


def test_mediapipe_round_trip_and_landmarks(tmp_path):
    # A camera looking along the world's +y: R_world_from_camera turns our camera x into world y.
    R_world_from_camera = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    camera = camera_poses(R_world_from_camera.T[None], [[0.5, -1.0, 1.2]], [0])
    rec = read_mediapipe(MEDIAPIPE, camera=camera)
    into_camera = _rows(rec)[(0, "0")]
    np.testing.assert_allclose(into_camera[1], [0.0, -1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(into_camera[0], [0.5, -1.0 + 0.56534337, 1.2 + 0.02624618], atol=1e-6)
    out = tmp_path / "again.jsonl"
    assert write_mediapipe(out, rec, camera=camera) == 3
    _same_rays(read_mediapipe(out, camera=camera), rec)
    with_irises = tmp_path / "irises.jsonl"
    record = json.loads(MEDIAPIPE.read_text().splitlines()[1])
    record["face_landmarks"] = [[[0.5, 0.5, 0.0]] * 478]
    with_irises.write_text(json.dumps(record) + "\n")
    np.testing.assert_allclose(_rows(read_mediapipe(with_irises))[(1, "0")][1], LOOK_UP, atol=1e-6)


@pytest.mark.parametrize("line, message", [
    ('{"frame": 1, "facial_transformation_matrixes": [[1, 0, 0]', "not JSON"),
    ('{"facial_transformation_matrixes": []}', "no 'frame'"),
    ('{"frame": 0, "facial_transformation_matrixes": []}', "frame 0 again"),
    ('{"frame": 1, "facial_transformation_matrixes": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 60, 0, 0, 0, 1]]}',
     "not in front"),
    ('{"frame": 1, "facial_transformation_matrixes": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, -60]]}', "16 finite"),
    ('{"frame": 1, "facial_transformation_matrixes": [[1, 0, 0, 0, 0, 1, 0.5, 0, 0, 0, 1, -60, 0, 0, 0, 1]]}',
     "scaled rotation"),
    ('{"frame": 1, "facial_transformation_matrixes": [], "face_landmarks": [[]]}', "one face per"),
])
def test_mediapipe_bad_lines_name_the_file_and_line(tmp_path, line, message):
    bad = tmp_path / "bad.jsonl"
    bad.write_text(MEDIAPIPE.read_text().splitlines()[0] + "\n\n" + line + "\n")
    with pytest.raises(InputFileError, match=message) as error:
        read_mediapipe(bad)
    assert error.value.line == 3 and error.value.path == str(bad)
