"""OpenFace 2 with several faces (FaceLandmarkVidMulti) → gaze rays: known gazes from OpenFace's own
conversion (GetGazeAngle, eye vectors in OpenCV camera axes, millimetres), the round trip
file → rays → file → rays, face_id swaps re-linked into people, and errors naming file and line."""

import jax
import numpy as np
import pytest

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.tools.common import bandwidth_from_mean_angular_error
from jaxgaze.io.tools.openface import (
    DEFAULT_BANDWIDTH_OPENFACE,
    OpenFaceFileError,
    link_openface_faces,
    read_openface_rays,
    write_openface_faces,
    write_openface_rays,
)
from jaxgaze.poses import camera_poses
from jaxgaze.simulate import simulate_openface_tracks
from jaxgaze.simulate.dyadic import FOCUS_PARTNER, DyadicRecording

GAZE = [f"gaze_{e}_{a}" for e in (0, 1) for a in "xyz"]
LANDMARKS = [f"eye_lmk_{a}_{k}" for a in "XYZ" for k in range(56)]
HEADER = ["frame", "face_id", "timestamp", "confidence", "success", *GAZE, "gaze_angle_x", "gaze_angle_y",
          "pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz"]  # fmt: skip


def _csv(tmp_path, rows, header=HEADER, name="multi.csv"):
    """An OpenFace CSV (", "-separated like OpenFace's); each row is a dict overriding a valid default:
    a face 1 m in front of the camera looking at it."""
    lines = [", ".join(header)]
    for k, row in enumerate(rows):
        values = {"frame": k + 1, "face_id": 0, "timestamp": k / 30, "confidence": 0.98, "success": 1,
                  "gaze_0_z": -1.0, "gaze_1_z": -1.0, "pose_Tz": 1000.0}
        values.update(row)
        lines.append(", ".join(str(values.get(c, 0.0)) for c in header))
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _eyes(g_cv):
    """Both eyes' gaze vectors ``g_cv`` (OpenCV camera axes), and GetGazeAngle of their mean."""
    g = np.asarray(g_cv, float) / np.linalg.norm(g_cv)
    row = {f"gaze_{e}_{a}": repr(float(v)) for e in (0, 1) for a, v in zip("xyz", g)}
    row.update(gaze_angle_x=repr(float(np.arctan2(g[0], -g[2]))), gaze_angle_y=repr(float(np.arctan2(g[1], -g[2]))))
    return row


TEN = np.radians(10.0)
# A face 1 m in front of the camera, facing it (pose 0). OpenCV axes: x right, y down, z forward.
# The person's left is the image's right (+x_cv); up is −y_cv. In our camera frame (+x forward,
# +y left, +z up) the person's left is −y and "toward the camera" is −x.
KNOWN = {
    "at the camera": ([0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]),
    "10° to the person's left": ([np.sin(TEN), 0.0, -np.cos(TEN)], [-np.cos(TEN), -np.sin(TEN), 0.0]),
    "10° up": ([0.0, -np.sin(TEN), -np.cos(TEN)], [-np.cos(TEN), 0.0, np.sin(TEN)]),
}


@pytest.mark.parametrize("columns", ["eye vectors", "gaze angles only"])
def test_known_gazes_come_out_as_world_directions(tmp_path, columns):
    rows = [_eyes(g_cv) for g_cv, _ in KNOWN.values()]
    header = HEADER if columns == "eye vectors" else [c for c in HEADER if c not in GAZE]
    rec = read_openface_rays(_csv(tmp_path, rows, header))
    for t, (_, expected) in enumerate(KNOWN.values()):
        np.testing.assert_allclose(rec.rays.directions[t, 0], expected, atol=1e-6)
        np.testing.assert_allclose(rec.rays.origins[t, 0], [1.0, 0.0, 0.0], atol=1e-6)  # pose_T, mm → m
    assert rec.persons == [["person_0"]] * 3
    np.testing.assert_allclose(rec.rays.bandwidth, DEFAULT_BANDWIDTH_OPENFACE)


def test_eye_vectors_may_point_away_from_the_camera(tmp_path):
    """GetGazeAngle's atan2 leaves (−π/2, π/2) for a gaze across or away from the camera: the eye vectors
    still give it (someone filmed from the side looking at a partner)."""
    g_cv = np.array([1.0, 0.0, 0.3])  # to the image's right and away from the camera
    rec = read_openface_rays(_csv(tmp_path, [_eyes(g_cv)]))
    np.testing.assert_allclose(rec.rays.directions[0, 0], R_OURS_FROM_OPENCV @ g_cv / np.linalg.norm(g_cv), atol=1e-6)


def test_origin_is_the_mean_of_the_3d_eye_landmarks(tmp_path):
    rng = np.random.default_rng(0)
    landmarks = rng.normal([[-30.0], [-50.0], [900.0]], 15.0, (3, 56))  # X, Y, Z (mm, OpenCV)
    row = {c: repr(float(v)) for c, v in zip(LANDMARKS, landmarks.ravel())}
    rec = read_openface_rays(_csv(tmp_path, [row], HEADER + LANDMARKS))
    np.testing.assert_allclose(rec.rays.origins[0, 0], R_OURS_FROM_OPENCV @ landmarks.mean(1) / 1000, atol=1e-6)


def test_bandwidth_is_openfaces_published_error():
    # OpenFace 2.0: 9.1° mean angular error (MPIIGaze, cross-dataset); mean of a Rayleigh(h) is h √(π/2).
    assert DEFAULT_BANDWIDTH_OPENFACE == pytest.approx(np.radians(9.1) / np.sqrt(np.pi / 2))
    assert DEFAULT_BANDWIDTH_OPENFACE == bandwidth_from_mean_angular_error(np.radians(9.1))


def test_swapped_face_ids_stay_with_their_person(tmp_path):
    """Face A 1.2 m ahead and 0.5 m left, face B 1.5 m ahead and 0.6 m right (our camera frame), both
    moving 1 cm a frame. In frame 5 A is lost and B takes slot 0; from frame 8 on the ids swap."""
    frames, ids, eyes, is_a = [], [], [], []
    for t in range(1, 21):
        a, b = [1.2, 0.5 + 0.01 * t, 0.0], [1.5, -0.6, 0.01 * t]
        faces = [(0, b, False)] if t == 5 else [(1, a, True), (0, b, False)] if t >= 8 else [(0, a, True), (1, b, False)]
        for face_id, eye, a_here in faces:
            frames.append(t), ids.append(face_id), eyes.append(eye), is_a.append(a_here)
    gaze = np.where(np.array(is_a)[:, None], [[0.0, -1.0, 0.0]], [[0.0, 1.0, 0.0]])  # they look at each other's side
    path = tmp_path / "swap.csv"
    write_openface_faces(path, frames, ids, eyes, gaze)
    with pytest.warns(UserWarning, match=r"face_id is not stable: re-linked 4 rows.*2 people"):
        # B in frame 5 (1 → 0) and 6 (0 → 1); A and B in frame 8
        rec = read_openface_rays(path)
    origins, mask = np.asarray(rec.rays.origins), np.asarray(rec.rays.mask)
    for t, names in enumerate(rec.persons):
        for n, name in enumerate(names):
            person = "A" if name == "person_0" else "B"
            assert mask[t, n]
            assert (origins[t, n, 1] > 0) == (person == "A"), (rec.frame_ids[t], name)
    assert rec.persons[4] == ["person_1"]  # frame 5: only B
    assert rec.persons == [["person_1"] if t == 5 else ["person_0", "person_1"] for t in range(1, 21)]


def test_link_openface_faces_gate_starts_new_people():
    frames = np.array([3, 1, 1, 2])  # any row order
    ids = np.array([0, 1, 0, 0])
    positions = np.array([[1.0, 0.9, 0], [1.0, 1.0, 0], [1.0, 0, 0], [1.02, 0, 0]])
    # frame 3: face_id 0 is 0.1 m from person 1's last place (seen as face_id 1), 0.9 m from person 0's
    track, relinks = link_openface_faces(frames, ids, positions, gate_m=0.5)
    np.testing.assert_array_equal(track, [1, 1, 0, 0])
    assert relinks == 1
    track, relinks = link_openface_faces(frames, ids, positions, gate_m=0.05)
    np.testing.assert_array_equal(track, [2, 1, 0, 0])  # beyond the gate of both: somebody new
    assert relinks == 0
    with pytest.raises(ValueError, match="gate_m"):
        link_openface_faces(frames, ids, positions, gate_m=0.0)


@pytest.mark.parametrize("with_camera", [False, True])
def test_round_trip_file_rays_file_rays(tmp_path, with_camera):
    rng = np.random.default_rng(1)
    rows = []
    for t in range(1, 13):
        for face, y in ((0, 0.6), (1, -0.5), (2, 0.0)):
            if (t + face) % 5:  # some faces missing in some frames
                gaze = rng.normal([-1.0, 0.0, 0.0], 0.6)
                rows.append((t, face, [1.0 + 0.3 * face, y, 0.02 * t], gaze))
    frames, ids, eyes, gaze = (np.array(x) for x in zip(*rows))
    camera = None
    if with_camera:
        R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # camera +x = world −y
        camera = camera_poses(R, [2.0, -1.0, 1.5], [0])
    first = tmp_path / "first.csv"
    write_openface_faces(first, frames, ids, eyes, gaze)
    rec = read_openface_rays(first, camera=camera)
    second = tmp_path / "second.csv"
    assert write_openface_rays(second, rec, camera=camera) == len(rows)
    again = read_openface_rays(second, camera=camera)
    assert again.frame_ids == rec.frame_ids and again.persons == rec.persons
    for field in ("origins", "directions", "bandwidth", "mask"):  # float32 rays: equal to their precision
        np.testing.assert_allclose(getattr(again.rays, field), getattr(rec.rays, field), atol=1e-6)
    # and the rays are the written ones, in the world
    eyes_world = eyes if camera is None else eyes @ camera.R_camera_from_world[0] + camera.centers[0]
    t = rec.frame_ids.index(3)
    np.testing.assert_allclose(rec.rays.origins[t, : len(rec.persons[t])], eyes_world[frames == 3], atol=1e-6)


def test_several_files_number_their_people_on(tmp_path):
    a = _csv(tmp_path, [{}, {}], name="a.csv")
    b = _csv(tmp_path, [{"face_id": 3}, {"frame": 2, "face_id": 3}], name="b.csv")
    rec = read_openface_rays([a, b])
    assert rec.persons == [["person_0", "person_1"]] * 2


def test_dropped_rows_are_counted(tmp_path):
    path = _csv(tmp_path, [{}, {"success": 0}, {"confidence": 0.5}, {"gaze_0_z": "nan", "success": 0}])
    with pytest.warns(UserWarning, match=r"dropped 3 of 4 rows \(success == 0: 2, confidence < 0.75: 1\)"):
        rec = read_openface_rays(path)
    assert rec.frame_ids == [1]


def _dyad(num_frames=400, fps=10.0, seed=0):
    """Two people 2 m apart facing each other, each looking at the partner or turning the head 60° to
    one side, for 1 s at a time: a DyadicRecording built in NumPy (nothing to compile) with what
    simulate_openface_tracks reads. The true gaze is the head's forward axis."""
    rng = np.random.default_rng(seed)
    eyes = np.array([[0.0, 0.0, 1.2], [2.0, 0.0, 1.2]])[:, None] + 0.01 * rng.standard_normal((2, num_frames, 3))
    choice = rng.integers(0, 3, (2, num_frames // 10 + 1)).repeat(10, axis=1)[:, :num_frames]  # partner, left, right
    yaw = np.array([[0.0], [np.pi]]) + np.radians(60.0) * np.select([choice == 1, choice == 2], [1.0, -1.0], 0.0)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((2, num_frames, 3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    focus = np.where(choice == 0, FOCUS_PARTNER, -1)
    zeros = np.zeros((2, num_frames, 2))
    return DyadicRecording(
        speaking=np.zeros((2, num_frames), bool), focus=focus, looking=focus == FOCUS_PARTNER, eye_positions=eyes,
        target_positions=eyes[::-1], focus_points=None, R_world_from_head=R, true_gaze_angles=zeros,
        gaze_angles=zeros, bias=np.zeros((2, 2)), object_positions=None, head_fraction=np.ones(2), fps=fps,
        preset="interview", config=None)


def test_simulated_openface_tracks_relink_into_the_true_people(tmp_path):
    """Two people filmed by one camera, OpenFace-style (faces lost, ids swapping): every person read
    back is one true person, and the measured gaze is as wide as the bandwidth says."""
    dyad = _dyad()
    tracks = simulate_openface_tracks(jax.random.key(5), dyad, gaze_sd=DEFAULT_BANDWIDTH_OPENFACE,
                                      dropout_rate_hz=1.0)
    t, p = np.nonzero(tracks.tracked)
    assert 0.3 < tracks.tracked.mean() < 0.9
    assert (tracks.face_id[t, p] != p).any(), "the simulated ids never swapped"
    np.testing.assert_array_equal(tracks.looks_at[:, 0, 1], dyad.focus[0] == FOCUS_PARTNER)
    # the measured gaze's angle to the true one (the head's forward axis): Rayleigh(h), mean h √(π/2) = 9.1°
    error = np.arccos(np.clip(np.einsum("tpi,tpi->tp", tracks.gaze_camera, tracks.R_camera_from_head[..., 0]), -1, 1))
    assert np.degrees(error.mean()) == pytest.approx(9.1, abs=0.5)
    path = tmp_path / "sim.csv"
    write_openface_faces(path, tracks.frames[t], tracks.face_id[t, p], tracks.eyes_camera[t, p],
                         tracks.gaze_camera[t, p], R_camera_from_head=tracks.R_camera_from_head[t, p])
    with pytest.warns(UserWarning, match="face_id is not stable"):
        rec = read_openface_rays(path)
    truth_of = {}
    for k, (frame, names) in enumerate(zip(rec.frame_ids, rec.persons)):
        for n, name in enumerate(names):
            true = np.argmin(np.linalg.norm(tracks.eyes_camera[frame - 1] - rec.rays.origins[k, n], axis=-1))
            assert truth_of.setdefault(name, true) == true, (frame, name)
    assert sorted(truth_of.values()) == [0, 1]


BAD = [
    ([{"gaze_0_z": "nan"}], None, "column 'gaze_0_z' is not finite in a kept row", 2),
    ([{}, {"frame": 1}], None, r"duplicate face_id 0 in frame 1 \(first on line 2\)", 3),
    ([{"gaze_0_z": 1.0}], None, "gaze_0 and gaze_1 average to a zero vector", 2),
    ([{"success": 2}], None, "success must be 0 or 1", 2),
    ([{"face_id": 0.5}], None, "column 'face_id' must be a 64-bit integer", 2),
    ([{"pose_Tx": "abc"}], None, "column 'pose_Tx' is not a number", 2),
    ([{"gaze_angle_x": 1.6}], [c for c in HEADER if c not in GAZE], "column 'gaze_angle_x' = 1.6 is outside", 2),
    ([{}], [c for c in HEADER if not c.startswith("gaze")], "no gaze in the header .* -gaze", 1),
    ([{}], [c for c in HEADER if not c.startswith("pose")], "no head position in the header .* -pose", 1),
    ([{}], HEADER + LANDMARKS[:3], "incomplete 3D eye landmarks: missing eye_lmk_X_3", 1),
    ([{"success": 0}], None, r"no faces left: all 1 rows dropped \(success == 0: 1", None),
    ([{}], ["frame", "x", "y"], "missing columns 'timestamp', 'confidence', 'success'", 1),
]


@pytest.mark.parametrize("rows, header, message, line", BAD)
def test_bad_input_names_file_and_line(tmp_path, rows, header, message, line):
    path = _csv(tmp_path, rows, header or HEADER)
    with pytest.raises(OpenFaceFileError, match=message) as caught:
        read_openface_rays(path)
    assert caught.value.path == str(path) and caught.value.line == line
    assert str(caught.value).startswith(f"{path}, line {line}:" if line else f"{path}:")
