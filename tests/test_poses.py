"""Camera poses: COLMAP/CSV readers and writers, the OpenCV → ours camera
conversion, frame matching, points of regard, and the similarity alignment."""

import warnings
from pathlib import Path

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxgaze.geometry import apply_similarity, similarity_alignment
from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.poses import (PoseFileError, read_colmap_images, read_pose_csv, read_poses, write_colmap_images,
                              write_pose_csv)
from jaxgaze.poses import CameraPoses, match_frames, points_of_regard, transform_poses
from jaxgaze.rays import UnitWarning

DATA = Path(__file__).parent / "data"
COLMAP = DATA / "colmap_images.txt"
S = 0.7071067811865476

# Expected poses of tests/data/colmap_images.txt (computed by hand in its header).
EXPECTED_FRAMES = [10, 20, 30, 40]
EXPECTED_CENTERS = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 1.5], [1.0, 5.0, 1.5], [-2.0, 0.0, 1.6]])
EXPECTED_R = np.array(
    [
        [[0, 0, 1], [-1, 0, 0], [0, -1, 0]],  # frame 10: OpenCV identity, looks up (world +z)
        [[0, 1, 0], [-1, 0, 0], [0, 0, 1]],  # frame 20: looks along world +y
        [[0, -1, 0], [1, 0, 0], [0, 0, 1]],  # frame 30: looks along world -y
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]],  # frame 40: looks along world +x
    ],
    dtype=float,
)


def _poses(R, C, frames, ts=None):
    return CameraPoses(np.asarray(R, float), np.asarray(C, float), np.asarray(frames), None if ts is None else np.asarray(ts, float))


def _random_poses(rng, frames, ts=None):
    R = Rotation.random(len(frames), random_state=rng.integers(1 << 31)).as_matrix()
    return _poses(R, rng.normal(size=(len(frames), 3)), frames, ts)


def _write(tmp_path, text, name="poses.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------
# Convention


def test_R_ours_from_opencv_is_a_rotation_mapping_axes():
    M = R_OURS_FROM_OPENCV
    np.testing.assert_array_equal(M @ M.T, np.eye(3))
    assert np.linalg.det(M) == pytest.approx(1.0)
    np.testing.assert_array_equal(M @ [0, 0, 1], [1, 0, 0])  # OpenCV forward (z) -> our forward (x)
    np.testing.assert_array_equal(M @ [-1, 0, 0], [0, 1, 0])  # OpenCV left (-x) -> our left (y)
    np.testing.assert_array_equal(M @ [0, -1, 0], [0, 0, 1])  # OpenCV up (-y) -> our up (z)


def test_colmap_camera_looking_along_world_y_has_our_x_along_world_y(tmp_path):
    # COLMAP camera with z (forward) = world +y, x (right) = world +x, y (down) = world -z:
    # R_cv_from_world = R_x(90°), q = (cos 45°, sin 45°, 0, 0); t = 0 (centre at origin).
    path = _write(tmp_path, f"1 {S} {S} 0 0 0 0 0 1 frame_000007.jpg\n\n", "images.txt")
    poses = read_colmap_images(path)
    R = poses.R_camera_from_world[0]
    np.testing.assert_allclose(R.T @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # our +x (forward) = world +y
    np.testing.assert_allclose(R.T @ [0, 1, 0], [-1, 0, 0], atol=1e-12)  # our +y (left) = world -x
    np.testing.assert_allclose(R.T @ [0, 0, 1], [0, 0, 1], atol=1e-12)  # our +z (up) = world +z
    np.testing.assert_allclose(poses.forward[0], [0, 1, 0], atol=1e-12)
    assert poses.frame_ids.tolist() == [7]


# ---------------------------------------------------------------------------
# COLMAP


def test_read_colmap_images_hand_computed():
    poses = read_colmap_images(COLMAP)
    assert poses.frame_ids.tolist() == EXPECTED_FRAMES
    assert poses.frame_ids.dtype == np.int64
    assert poses.timestamps is None
    np.testing.assert_allclose(poses.centers, EXPECTED_CENTERS, atol=1e-12)
    np.testing.assert_allclose(poses.R_camera_from_world, EXPECTED_R, atol=1e-12)
    np.testing.assert_allclose(poses.R_world_from_camera, np.swapaxes(EXPECTED_R, 1, 2), atol=1e-12)


def test_colmap_write_read_round_trip(tmp_path):
    poses = read_colmap_images(COLMAP)
    out = tmp_path / "images.txt"
    write_colmap_images(out, poses)
    again = read_colmap_images(out)
    np.testing.assert_array_equal(again.frame_ids, poses.frame_ids)
    np.testing.assert_allclose(again.R_camera_from_world, poses.R_camera_from_world, atol=1e-12)
    np.testing.assert_allclose(again.centers, poses.centers, atol=1e-12)
    assert "frame_000010.jpg" in out.read_text()


def test_colmap_round_trip_random_poses(tmp_path):
    rng = np.random.default_rng(0)
    poses = _random_poses(rng, [3, 1, 1000000, 0, 42])
    write_colmap_images(tmp_path / "images.txt", poses)
    again = read_colmap_images(tmp_path / "images.txt")
    order = np.argsort(poses.frame_ids)
    np.testing.assert_array_equal(again.frame_ids, poses.frame_ids[order])
    np.testing.assert_allclose(again.R_camera_from_world, poses.R_camera_from_world[order], atol=1e-12)
    np.testing.assert_allclose(again.centers, poses.centers[order], atol=1e-12)


def _colmap(names, camera_ids=None):
    """images.txt text: identity poses 1 m apart along x, one image per name."""
    camera_ids = camera_ids or [1] * len(names)
    return "".join(f"{k + 1} 1 0 0 0 {-float(k)} 0 0 {c} {n}\n\n" for k, (n, c) in enumerate(zip(names, camera_ids)))


def test_colmap_frame_from_image_id_when_no_name_has_digits(tmp_path):
    path = _write(tmp_path, "5 1 0 0 0 0 0 0 1 left.jpg\n\n2 1 0 0 0 1 0 0 1 sub/dir/right.png\n\n", "images.txt")
    poses = read_colmap_images(path)
    assert poses.frame_ids.tolist() == [2, 5]
    np.testing.assert_allclose(poses.centers[0], [-1, 0, 0])
    assert read_poses(path).frame_ids_from == "IMAGE_ID (the image names hold no digits)"


def test_colmap_frame_ids_from_the_number_that_changes(tmp_path):
    """Cityscapes-like names: the frame is the one number that changes, not the 8 of 'leftImg8bit'."""
    names = [f"aachen_000003_{f:06d}_leftImg8bit.png" for f in (21, 19, 20)]
    track = read_poses(_write(tmp_path, _colmap(names), "images.txt"))
    assert track.poses.frame_ids.tolist() == [19, 20, 21]
    np.testing.assert_allclose(track.poses.centers[:, 0], [1, 2, 0])  # frame 19 is image 2, 1 m along x
    assert track.frame_ids_from == ("the one number that changes in the image names "
                                    "(e.g. 'aachen_000003_000021_leftImg8bit.png' → 21)")
    # Two numbers that change together are the same frame id; one number per name is that number.
    same = read_colmap_images(_write(tmp_path, _colmap(["000021/000021.png", "000022/000022.png"]), "same.txt"))
    assert same.frame_ids.tolist() == [21, 22]
    one = read_poses(_write(tmp_path, _colmap(["sub/img_12.png", "sub/img_7.png"]), "one.txt"))
    assert one.poses.frame_ids.tolist() == [7, 12] and one.frame_ids_from.startswith("the number in the image names")


@pytest.mark.parametrize("names, words, line", [
    (["left.jpg", "sub/dir/img_12.png"], "different numbers of digit runs ('left.jpg' has 0, 'sub/dir/img_12.png' "
                                         "has 1)", 3),
    (["cam1/f_000021.png", "cam2/f_000022.png"], "hold 2 numbers that change from image to image", 1),
    (["a_1_2.png"], "hold 2 numbers that could each be the frame id", 1),
])
def test_colmap_ambiguous_frame_ids_are_an_error(tmp_path, names, words, line):
    path = _write(tmp_path, _colmap(names), "images.txt")
    with pytest.raises(PoseFileError, match="frame ids are ambiguous") as info:
        read_colmap_images(path)
    assert words in str(info.value) and "give a frame pattern" in str(info.value)
    assert info.value.line == line


def test_colmap_frame_pattern(tmp_path):
    names = ["cam1/f_000021.png", "cam2/f_000022.png"]
    path = _write(tmp_path, _colmap(names), "images.txt")
    track = read_poses(path, frame_pattern=r"f_(\d+)\.png$")
    assert track.poses.frame_ids.tolist() == [21, 22]
    assert track.frame_ids_from == r"the image names by the pattern 'f_(\d+)\.png$'"
    assert read_colmap_images(path, frame_pattern=r"cam(\d)").frame_ids.tolist() == [1, 2]
    with pytest.raises(PoseFileError, match=r"image name 'cam2/f_000022.png' does not match") as info:
        read_colmap_images(path, frame_pattern=r"(\d+)1\.png")
    assert info.value.line == 3
    with pytest.raises(PoseFileError, match="picks 'f' out of image name"):
        read_colmap_images(path, frame_pattern=r"/(\w)_")
    for pattern, message in ((r"\d+", "exactly one group"), (r"(\d)(\d)", "exactly one group"),
                             ("(x", "not a regular expression")):
        with pytest.raises(ValueError, match=message):
            read_colmap_images(path, frame_pattern=pattern)


def test_colmap_frame_id_too_large(tmp_path):
    path = _write(tmp_path, _colmap(["f_1.png", "f_99999999999999999999.png"]), "images.txt")
    with pytest.raises(PoseFileError, match="frame id 99999999999999999999 in image name .* is too large") as info:
        read_colmap_images(path)
    assert info.value.line == 3


JOINT = DATA / "colmap_joint_images.txt"


def test_colmap_joint_reconstruction_select_one_wearer():
    """Two wearers in one reconstruction: selected by CAMERA_ID or by name prefix, the same poses."""
    ann, ben = read_poses(JOINT, camera_id=1), read_poses(JOINT, name_prefix="ben/")
    for track in (ann, ben):
        assert track.poses.frame_ids.tolist() == list(range(30))
        assert track.frame_ids_from.startswith("the one number that changes in the image names")
    assert ann.selection == "30 of 60 images, CAMERA_ID 1" and ben.selection == "30 of 60 images, names starting with 'ben/'"
    assert ann.describe().startswith("colmap_joint_images.txt (30 of 60 images, CAMERA_ID 1): frame ids from ")
    same = read_colmap_images(JOINT, name_prefix="ann/", camera_id=1)
    np.testing.assert_array_equal(same.centers, ann.poses.centers)
    np.testing.assert_array_equal(read_colmap_images(JOINT, camera_id=2).centers, ben.poses.centers)
    # The two cameras face each other: each sees the other ahead (+x) at 1-4 m.
    y = points_of_regard(ann.poses, ben.poses)
    assert np.all(y[:, 0] > 0.5) and np.all(np.linalg.norm(y, axis=1) < 5)
    with pytest.raises(PoseFileError, match=r"duplicate frame 0 \(first on line 11\) \(several wearers' images\? "
                                            "select one wearer's images by camera id or name prefix") as info:
        read_colmap_images(JOINT)
    assert info.value.line == 13
    with pytest.raises(PoseFileError, match=r"no image has CAMERA_ID 3 \(the file's camera ids: 1, 2\)"):
        read_colmap_images(JOINT, camera_id=3)
    with pytest.raises(PoseFileError, match="no image name starts with 'ben/' among those of CAMERA_ID 1"):
        read_colmap_images(JOINT, camera_id=1, name_prefix="ben/")


def test_read_poses_csv_reports_its_frame_column(tmp_path):
    path = _write(tmp_path, CSV_HAPPY)
    track = read_poses(path)
    assert track.poses.frame_ids.tolist() == [1, 2] and track.frame_ids_from == "its 'frame' column"
    assert track.describe() == "poses.csv: frame ids from its 'frame' column"
    with pytest.raises(PoseFileError, match="selects images of a COLMAP images.txt"):
        read_poses(path, camera_id=1)


@pytest.mark.parametrize(
    "text, message, line",
    [
        ("# only comments\n", "no images", None),
        ("", "no images", None),
        ("1 1 0 0 0 0 0 0 1\n\n", "expected 10 fields", 1),
        ("# c\n1 1 0 0 0 0 0 zero 1 f_1.jpg\n\n", "TZ is not a number", 2),
        ("1 nan 0 0 0 0 0 0 1 f_1.jpg\n\n", "QW is not finite", 1),
        ("1 1 0 0 0 0 0 inf 1 f_1.jpg\n\n", "TZ is not finite", 1),
        ("1 1 0 0 0.1 0 0 0 1 f_1.jpg\n\n", "not unit", 1),
        ("1 1 0 0 0 0 0 0 1 f_1.jpg\n\n2 1 0 0 0 0 0 0 1 g_1.jpg\n\n", r"duplicate frame 1 \(first on line 1\)", 3),
        ("1 1 0 0 0 0 0 0 1 f_1.jpg\n2 1 0 0 0 0 0 0 1 f_2.jpg\n", "POINTS2D", 2),
    ],
)
def test_colmap_errors_name_file_and_line(tmp_path, text, message, line):
    path = _write(tmp_path, text, "images.txt")
    with pytest.raises(ValueError, match=message) as info:
        read_colmap_images(path)
    assert str(path) in str(info.value)
    assert isinstance(info.value, PoseFileError)
    assert info.value.line == line
    if line is not None:
        assert f"line {line}" in str(info.value)


def test_colmap_quaternion_nearly_unit_is_accepted(tmp_path):
    path = _write(tmp_path, "1 1.0005 0 0 0 0 0 0 1 f_1.jpg\n\n", "images.txt")
    np.testing.assert_allclose(read_colmap_images(path).R_camera_from_world[0], R_OURS_FROM_OPENCV, atol=1e-12)


def test_missing_file_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        read_colmap_images(tmp_path / "nope.txt")
    with pytest.raises(ValueError, match="not found"):
        read_pose_csv(tmp_path / "nope.csv")


# ---------------------------------------------------------------------------
# CSV

CSV_HAPPY = f"""# comment line
frame,qw,qx,qy,qz,cx,cy,cz,timestamp
2,1,0,0,0,-2,0,1.6,0.2

1,{S},0,0,{S},1,2,1.5,0.1
"""


def test_read_pose_csv_happy_path(tmp_path):
    poses = read_pose_csv(_write(tmp_path, CSV_HAPPY))
    assert poses.frame_ids.tolist() == [1, 2]
    np.testing.assert_allclose(poses.timestamps, [0.1, 0.2])
    np.testing.assert_allclose(poses.centers, [[1, 2, 1.5], [-2, 0, 1.6]])
    # q is R_camera_from_world in OUR convention, used as is (no OpenCV conversion):
    # frame 2: identity looks along world +x; frame 1: 90° about z -> R = R_z(90°).
    np.testing.assert_allclose(poses.R_camera_from_world[1], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(poses.R_camera_from_world[0], Rotation.from_euler("z", 90, degrees=True).as_matrix(), atol=1e-12)


def test_read_pose_csv_without_timestamp_and_column_order(tmp_path):
    poses = read_pose_csv(_write(tmp_path, "CX,cy,cz,frame,qw,qx,qy,qz,note\n1,2,3,5,1,0,0,0,hello\n"))
    assert poses.timestamps is None
    assert poses.frame_ids.tolist() == [5]
    np.testing.assert_allclose(poses.centers, [[1, 2, 3]])


def test_pose_csv_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    poses = _random_poses(rng, [0, 1, 2, 5], ts=[0.0, 0.033, 0.066, 0.166])
    write_pose_csv(tmp_path / "p.csv", poses)
    again = read_pose_csv(tmp_path / "p.csv")
    np.testing.assert_array_equal(again.frame_ids, poses.frame_ids)
    np.testing.assert_allclose(again.R_camera_from_world, poses.R_camera_from_world, atol=1e-12)
    np.testing.assert_allclose(again.centers, poses.centers, atol=1e-12)
    np.testing.assert_allclose(again.timestamps, poses.timestamps)


HEADER = "frame,qw,qx,qy,qz,cx,cy,cz\n"


@pytest.mark.parametrize(
    "text, message, line",
    [
        ("", "empty file", 1),
        ("# nothing\n\n", "empty file", 1),
        (HEADER, "no data rows", 1),
        ("frame,qw,qx,qy,qz,cx,cy\n1,1,0,0,0,0,0\n", "missing column 'cz'", 1),
        ("frame,qw,qx,qy,qz,cx,cy,cz,cx\n", "duplicate column 'cx'", 1),
        (HEADER + "1,1,0,0,0,0,0\n", "expected 8 fields", 2),
        (HEADER + "1,1,0,0,0,0,,0\n", "empty cell in column 'cy'", 2),
        (HEADER + "1,1,0,0,0,0,abc,0\n", "column 'cy' is not a number", 2),
        (HEADER + "1,1,0,0,0,0,0,nan\n", "column 'cz' is not finite", 2),
        (HEADER + "1,inf,0,0,0,0,0,0\n", "column 'qw' is not finite", 2),
        (HEADER + "1.5,1,0,0,0,0,0,0\n", "column 'frame' must be an integer", 2),
        (HEADER + "1,1,0,0,0,0,0,0\n# c\n2,0.9,0,0,0,0,0,0\n", "not unit", 4),
        (HEADER + "1,1,0,0,0,0,0,0\n1,1,0,0,0,1,0,0\n", "duplicate frame 1 \\(first on line 2\\)", 3),
        ("frame,qw,qx,qy,qz,cx,cy,cz,timestamp\n1,1,0,0,0,0,0,0,x\n", "column 'timestamp' is not a number", 2),
    ],
)
def test_pose_csv_errors_name_file_and_line(tmp_path, text, message, line):
    path = _write(tmp_path, text)
    with pytest.raises(ValueError, match=message) as info:
        read_pose_csv(path)
    assert str(path) in str(info.value)
    assert f"line {line}" in str(info.value)


# ---------------------------------------------------------------------------
# Matching


def test_match_frames_by_frame():
    rng = np.random.default_rng(2)
    a = _random_poses(rng, [5, 1, 2, 3, 9])
    b = _random_poses(rng, [3, 4, 5, 0, 1])
    ma, mb = match_frames(a, b)
    assert ma.frame_ids.tolist() == [1, 3, 5]
    assert mb.frame_ids.tolist() == [1, 3, 5]
    np.testing.assert_array_equal(ma.centers, a.centers[[1, 3, 0]])
    np.testing.assert_array_equal(mb.centers, b.centers[[4, 0, 2]])
    np.testing.assert_array_equal(mb.R_camera_from_world, b.R_camera_from_world[[4, 0, 2]])


def test_match_frames_nothing_in_common_raises():
    rng = np.random.default_rng(3)
    with pytest.raises(ValueError, match="no common frames"):
        match_frames(_random_poses(rng, [1, 2]), _random_poses(rng, [3, 4]))
    with pytest.raises(ValueError, match="by must be"):
        match_frames(_random_poses(rng, [1]), _random_poses(rng, [1]), by="time")


def test_match_frames_by_timestamp():
    rng = np.random.default_rng(4)
    # A at 30 fps, B at 25 fps with an offset: pair nearest within 5 ms.
    a = _random_poses(rng, [0, 1, 2, 3, 4, 5, 6], ts=np.arange(7) / 30.0)
    b = _random_poses(rng, [10, 11, 12, 13, 14], ts=0.002 + np.arange(5) / 25.0)
    ma, mb = match_frames(a, b, by="timestamp", tolerance=0.005)
    # B: 0.002, 0.042, 0.082, 0.122, 0.162. Within 5 ms only A's 0 (vs 0.002, 2 ms)
    # and 5/30 = 0.1667 (vs 0.162, 4.7 ms); 1/30 vs 0.042 is 8.7 ms off.
    assert ma.frame_ids.tolist() == [0, 5]
    assert mb.frame_ids.tolist() == [10, 14]
    np.testing.assert_array_equal(mb.centers, b.centers[[0, 4]])
    assert np.all(np.abs(ma.timestamps - mb.timestamps) <= 0.005)


def test_match_frames_by_timestamp_is_one_to_one_and_needs_timestamps():
    rng = np.random.default_rng(5)
    a = _random_poses(rng, [0, 1, 2], ts=[0.0, 0.011, 0.1])
    b = _random_poses(rng, [7, 8], ts=[0.01, 0.1005])
    ma, mb = match_frames(a, b, by="timestamp", tolerance=0.02)
    # a0 and a1 both have b7 nearest; a1 (1 ms away) keeps it.
    assert ma.frame_ids.tolist() == [1, 2]
    assert mb.frame_ids.tolist() == [7, 8]
    with pytest.raises(ValueError, match="tolerance"):
        match_frames(a, b, by="timestamp")
    with pytest.raises(ValueError, match="no timestamps"):
        match_frames(a, _random_poses(rng, [7]), by="timestamp", tolerance=1.0)
    with pytest.raises(ValueError, match="tolerance"):
        match_frames(a, b, by="timestamp", tolerance=-1.0)


# ---------------------------------------------------------------------------
# Points of regard


def test_points_of_regard_cameras_facing_each_other():
    poses = read_colmap_images(COLMAP)
    a, b = poses.select([1]), poses.select([2])  # frame 20 looks +y at frame 30, 3 m away
    np.testing.assert_allclose(points_of_regard(a, b), [[3.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(points_of_regard(b, a), [[3.0, 0.0, 0.0]], atol=1e-12)


def test_points_of_regard_hand_computation_left_and_up():
    # A at the origin looking along world +x (R = I); B 2 m ahead, 0.5 m to the left, 0.3 m up.
    a = _poses([np.eye(3)], [[0, 0, 0]], [0])
    b = _poses([np.eye(3)], [[2, 0.5, 0.3]], [0])
    np.testing.assert_allclose(points_of_regard(a, b), [[2, 0.5, 0.3]])
    # A turned to look along world +y (R_z(90°)): world +y is A's +x, world -x is A's +y.
    a = _poses([Rotation.from_euler("z", 90, degrees=True).as_matrix().T], [[1, 1, 0]], [0])
    b = _poses([np.eye(3)], [[0, 3, 0]], [0])
    np.testing.assert_allclose(points_of_regard(a, b), [[2, 1, 0]], atol=1e-12)


def test_points_of_regard_after_matching_and_length_mismatch():
    rng = np.random.default_rng(6)
    a = _random_poses(rng, [0, 1, 2, 3])
    b = _random_poses(rng, [1, 2, 3, 4, 5])
    with pytest.raises(ValueError, match="match them first"):
        points_of_regard(a, b)
    ma, mb = match_frames(a, b)
    y = points_of_regard(ma, mb)
    assert y.shape == (3, 3)
    expected = [a.R_camera_from_world[i] @ (b.centers[i - 1] - a.centers[i]) for i in (1, 2, 3)]
    np.testing.assert_allclose(y, expected, atol=1e-12)


def test_points_of_regard_invariant_under_similarity_of_world():
    # Moving both cameras into another world frame scales y by the scale only.
    rng = np.random.default_rng(7)
    a, b = _random_poses(rng, [0, 1, 2]), _random_poses(rng, [0, 1, 2])
    R = Rotation.random(random_state=8).as_matrix()
    y = points_of_regard(a, b)
    y2 = points_of_regard(transform_poses(a, 2.0, R, [1, 2, 3]), transform_poses(b, 2.0, R, [1, 2, 3]))
    np.testing.assert_allclose(y2, 2.0 * y, atol=1e-12)


def _facing_pair(scale=1.0, num_frames=8, timestamps=None):
    """A at the origin, B 1.5-3 m ahead along world +x (in metres × ``scale``); R = I for both."""
    R = np.tile(np.eye(3), (num_frames, 1, 1))
    ahead = np.linspace(1.5, 3.0, num_frames)
    a = _poses(R, np.zeros((num_frames, 3)), range(num_frames), timestamps)
    b = _poses(R, scale * np.stack([ahead, 0.1 * np.ones(num_frames), np.zeros(num_frames)], 1), range(num_frames),
               timestamps)
    return a, b


@pytest.mark.parametrize("scale, words", [
    (1000.0, "positions look like millimetres (points of regard up to 3e+03 m away, median 2.25e+03 m"),
    (100.0, "positions look like centimetres (points of regard up to 300 m away, median 225 m"),
    (0.01, "positions look too small for metres (points of regard up to 0.03 m away, median 0.0225 m"),
])
def test_points_of_regard_outside_a_room_name_the_unit(scale, words):
    a, b = _facing_pair(scale)
    with pytest.warns(UnitWarning, match="poses must be in metres") as caught:  # implausible, not impossible
        points_of_regard(a, b)
    assert words in str(caught[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        points_of_regard(*_facing_pair(1.0))  # metres pass


def test_points_of_regard_of_the_same_track_twice():
    """The same file twice: every point of regard is zero, and the error says why (not 'behind the camera')."""
    a = _random_poses(np.random.default_rng(3), range(6))
    with pytest.raises(ValueError, match=r"the two pose tracks are identical in all 6 matched frame\(s\) \(the same "
                                         r"file twice\?\), so every point of regard is zero"):
        points_of_regard(a, a)
    turned = a._replace(R_camera_from_world=a.R_camera_from_world[::-1].copy())  # same centres, other rotations
    with pytest.raises(ValueError, match=r"less than 1 cm apart in 6 of 6 matched frame\(s\) \(first: frame 0\)"):
        points_of_regard(a, turned)


def test_points_of_regard_warn_about_a_few_coincident_frames_and_speed():
    a, b = _facing_pair(1.0, timestamps=np.arange(8) / 30)
    b = b._replace(centers=b.centers.copy())
    b.centers[5] = a.centers[5]
    with pytest.warns(UserWarning, match=r"less than 1 cm apart in 1 of 8 matched frame\(s\) \(first: frame 5\)"):
        points_of_regard(a, b)
    # B moves 0.21 m per 1/30 s, 6.4 m/s: plausible. The same poses stamped in minutes are not.
    a, b = _facing_pair(1.0, timestamps=np.arange(8) / 30)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        points_of_regard(a, b)
    a, b = _facing_pair(1.0, timestamps=np.arange(8) / 1800)
    with pytest.warns(UserWarning) as caught:
        points_of_regard(a, b)
    assert [str(w.message) for w in caught] == [
        "camera B moves at a median 386 m/s between frames (a head-mounted camera moves at most 10 m/s): positions "
        "look like millimetres, or timestamps are not in seconds; poses must be in metres and timestamps in seconds"]


# ---------------------------------------------------------------------------
# Similarity alignment (geometry.py)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    scale=st.floats(0.1, 10.0),
    m=st.sampled_from([3, 4, 7, 25]),  # few shapes: one compile each
)
def test_similarity_alignment_recovers_known_transform(seed, scale, m):
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(scale=5.0, size=3)
    source = rng.normal(size=(m, 3))
    target = scale * source @ R.T + t
    with jax.enable_x64(True):
        s_hat, R_hat, t_hat = similarity_alignment(source, target)
        mapped = np.asarray(apply_similarity(source, s_hat, R_hat, t_hat))
    assert float(s_hat) == pytest.approx(scale, rel=1e-8)
    np.testing.assert_allclose(np.asarray(R_hat), R, atol=1e-8)
    np.testing.assert_allclose(np.asarray(t_hat), t, atol=1e-7)
    np.testing.assert_allclose(mapped, target, atol=1e-7)


def test_similarity_alignment_matches_scipy_align_vectors():
    rng = np.random.default_rng(9)
    source = rng.normal(size=(20, 3))
    source -= source.mean(axis=0)
    R = Rotation.random(random_state=10).as_matrix()
    target = source @ R.T + 0.05 * rng.normal(size=source.shape)  # noisy: not an exact fit
    target -= target.mean(axis=0)
    with jax.enable_x64(True):
        _, R_hat, t_hat = similarity_alignment(source, target)
    R_scipy, _ = Rotation.align_vectors(target, source)  # minimises Σ‖target − R source‖²
    np.testing.assert_allclose(np.asarray(R_hat), R_scipy.as_matrix(), atol=1e-10)
    np.testing.assert_allclose(np.asarray(t_hat), 0.0, atol=1e-2)


def test_similarity_alignment_reflection_fix_gives_a_rotation():
    rng = np.random.default_rng(11)
    source = rng.normal(size=(10, 3))
    target = source * np.array([1.0, 1.0, -1.0])  # a mirror image
    with jax.enable_x64(True):
        scale, R, _ = similarity_alignment(source, target)
    assert np.linalg.det(np.asarray(R)) == pytest.approx(1.0)
    np.testing.assert_allclose(np.asarray(R) @ np.asarray(R).T, np.eye(3), atol=1e-12)
    assert 0 < float(scale) < 1.0


def test_similarity_alignment_float32_and_jit():
    rng = np.random.default_rng(12)
    source = rng.normal(size=(8, 3)).astype(np.float32)
    R = Rotation.random(random_state=13).as_matrix()
    target = (1.5 * source @ R.T + [0.5, -1, 2]).astype(np.float32)
    scale, R_hat, t_hat = jax.jit(similarity_alignment)(source, target)
    assert float(scale) == pytest.approx(1.5, rel=1e-4)
    np.testing.assert_allclose(np.asarray(R_hat), R, atol=1e-4)
    np.testing.assert_allclose(np.asarray(t_hat), [0.5, -1, 2], atol=1e-4)


@pytest.mark.parametrize(
    "source, message",
    [
        (np.zeros((2, 3)), "at least 3"),
        (np.zeros((4, 2)), r"\(M, 3\)"),
        (np.outer(np.arange(5.0), [1.0, 2.0, -0.5]) + 1.0, "degenerate"),
        (np.ones((4, 3)), "degenerate"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]]), "finite"),
    ],
)
def test_similarity_alignment_errors(source, message):
    target = np.random.default_rng(0).normal(size=source.shape)
    with pytest.raises(ValueError, match=message):
        similarity_alignment(source, target)


def test_similarity_alignment_shape_mismatch():
    with pytest.raises(ValueError, match="shape of source"):
        similarity_alignment(np.zeros((4, 3)), np.zeros((5, 3)))


def test_align_sfm_poses_to_mocap_with_similarity():
    # End to end: SfM poses live in an arbitrary similar frame; align their centres
    # to the "mocap" centres and map the poses across.
    rng = np.random.default_rng(14)
    truth = _random_poses(rng, list(range(6)))
    R = Rotation.random(random_state=15).as_matrix()
    sfm = transform_poses(truth, 0.3, R, [4.0, -1.0, 0.5])
    with jax.enable_x64(True):
        s, R_hat, t_hat = similarity_alignment(sfm.centers, truth.centers)
    back = transform_poses(sfm, float(s), np.asarray(R_hat), np.asarray(t_hat))
    np.testing.assert_allclose(back.centers, truth.centers, atol=1e-9)
    np.testing.assert_allclose(back.R_camera_from_world, truth.R_camera_from_world, atol=1e-9)
