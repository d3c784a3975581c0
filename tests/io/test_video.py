"""Video and frame-folder IO, and rendering a simulated table-top session as a video (jaxgaze.io.video)."""

import cv2
import jax
import numpy as np
import pytest

from jaxgaze.geometry import head_pose_to_rotation
from jaxgaze.vision.head_model import CylinderHead, frontal_rotation
from jaxgaze.simulate.video import render_tabletop_video
from jaxgaze.io.video import (
    VIDEO_CODECS,
    VideoFileError,
    check_frames_output,
    frame_count,
    iter_frames,
    read_frames,
    video_fps,
    write_frames,
    write_video,
)
from tests import helpers as zoo


def _frames(num=6, size=(64, 48)):
    """Smooth frames (codecs keep them well): a colour gradient with a square that moves right."""
    w, h = size
    x, y = np.meshgrid(np.arange(w), np.arange(h))
    frames = []
    for t in range(num):
        f = np.stack([x * 255 // w, y * 255 // h, np.full_like(x, 60 + 20 * t)], -1).astype(np.uint8)
        f[16:32, 8 + 4 * t:24 + 4 * t] = (250, 30, 30)
        frames.append(f)
    return frames


@pytest.mark.parametrize("ext", sorted(VIDEO_CODECS))
def test_write_read_round_trip(tmp_path, ext):
    frames = _frames()
    path = tmp_path / f"clip{ext}"
    assert write_video(path, frames, 12.5) == len(frames)
    back = read_frames(path)
    assert len(back) == len(frames) and frame_count(path) == len(frames)
    assert video_fps(path) == pytest.approx(12.5, rel=1e-3)
    for a, b in zip(frames, back):
        assert b.shape == a.shape and b.dtype == np.uint8
        error = np.abs(a.astype(int) - b.astype(int))
        if ext == ".mkv":  # FFV1 is lossless
            assert error.max() == 0
        else:  # mp4v / MJPG: a few grey levels on average
            assert error.mean() < 4.0
    # RGB order: the square is red.
    assert back[0][24, 12, 0] > 200 and back[0][24, 12, 2] < 80
    assert read_frames(path, max_frames=2)[1].shape == frames[1].shape and len(read_frames(path, max_frames=2)) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"clip{ext}"]  # no temporary file left


def test_write_video_accepts_grey_and_float_frames(tmp_path):
    grey = [np.full((48, 64), 100, np.uint8), np.full((48, 64), 0.5)]
    write_video(tmp_path / "g.mkv", grey, 5)
    back = read_frames(tmp_path / "g.mkv")
    assert back[0].shape == (48, 64, 3) and np.all(back[0] == 100) and np.all(back[1] == 128)


def test_write_video_errors_leave_nothing_behind(tmp_path):
    path = tmp_path / "v.mp4"
    path.write_bytes(b"old")
    with pytest.raises(ValueError, match="unknown extension '.mov'"):
        write_video(tmp_path / "v.mov", _frames(2), 10)
    with pytest.raises(ValueError, match="fps"):
        write_video(path, _frames(2), 0)
    with pytest.raises(ValueError, match="no frames"):
        write_video(path, [], 10)
    with pytest.raises(ValueError, match=r"frames\[1\] is 32x24 px but frames\[0\] is 64x48 px"):
        write_video(path, [_frames(1)[0], _frames(1, (32, 24))[0]], 10)
    with pytest.raises(OSError, match="does not exist"):
        write_video(tmp_path / "missing" / "v.mp4", _frames(2), 10)
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_write_frames_to_a_png_folder_or_a_video(tmp_path):
    frames = _frames(12)  # frame_000010.png after frame_000009.png: read back in order, losslessly
    assert write_frames(tmp_path / "out", frames, 10) == 12
    assert sorted(p.name for p in (tmp_path / "out").iterdir())[:2] == ["frame_000000.png", "frame_000001.png"]
    back = read_frames(tmp_path / "out")
    assert len(back) == 12 and all(np.array_equal(a, b) for a, b in zip(back, frames))
    (tmp_path / "empty").mkdir()  # an empty folder is filled; grey and float frames become RGB uint8
    assert write_frames(tmp_path / "empty", [np.full((8, 10), 0.5)] * 2, 10) == 2
    assert np.all(read_frames(tmp_path / "empty")[0] == 128)
    assert write_frames(tmp_path / "v.mkv", iter(frames), 12.5) == 12  # by extension: write_video
    assert video_fps(tmp_path / "v.mkv") == pytest.approx(12.5) and len(read_frames(tmp_path / "v.mkv")) == 12
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "out", "v.mkv"]  # no temporary file left


def test_write_frames_checks_first_and_leaves_nothing_behind(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("x")
    (tmp_path / "file").write_text("x")
    for path, message in [(tmp_path / "v.mov", r"'.mov' is not a video extension"),
                          (tmp_path / "full", "exists and is not an empty folder"),
                          (tmp_path / "file", "exists and is not an empty folder"),
                          (tmp_path / "missing" / "out", "does not exist")]:
        with pytest.raises(ValueError, match=message):
            check_frames_output(path)
        with pytest.raises(ValueError, match=message):
            write_frames(path, _frames(2), 10)

    def failing(after, error):
        yield from _frames(after)
        raise error

    for error in (ValueError("bad frame"), KeyboardInterrupt()):
        with pytest.raises(type(error)):
            write_frames(tmp_path / "out", failing(3, error), 10)
        with pytest.raises(type(error)):
            write_frames(tmp_path / "v.avi", failing(3, error), 10)
    with pytest.raises(ValueError, match=r"frames\[1\] is 32x24 px but frames\[0\] is 64x48 px"):
        write_frames(tmp_path / "out", [_frames(1)[0], _frames(1, (32, 24))[0]], 10)
    with pytest.raises(ValueError, match="no frames"):
        write_frames(tmp_path / "out", [], 10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "full"]
    assert [p.name for p in (tmp_path / "full").iterdir()] == ["keep.txt"]


def test_folder_is_read_in_natural_order(tmp_path):
    for index in (10, 2, 1):  # frame10 after frame2
        cv2.imwrite(str(tmp_path / f"frame{index}.png"), np.full((8, 10, 3), index, np.uint8))
    cv2.imwrite(str(tmp_path / "frame11.jpg"), np.full((8, 10, 3), 200, np.uint8))
    cv2.imwrite(str(tmp_path / "frame3.png"), np.full((8, 10), 3, np.uint8))  # grey: read as RGB
    (tmp_path / "notes.txt").write_text("not a frame")
    frames = read_frames(tmp_path)
    assert [int(f[0, 0, 0]) for f in frames[:4]] == [1, 2, 3, 10]
    assert abs(int(frames[4][0, 0, 0]) - 200) <= 2  # the jpg
    assert all(f.shape == (8, 10, 3) and f.dtype == np.uint8 for f in frames)
    assert frame_count(tmp_path) == 5 and video_fps(tmp_path) is None
    assert len(read_frames(tmp_path, max_frames=3)) == 3
    # BGR on disk, RGB in memory.
    cv2.imwrite(str(tmp_path / "frame99.png"), np.tile(np.array([255, 0, 0], np.uint8), (8, 10, 1)))  # blue
    assert tuple(read_frames(tmp_path)[-1][0, 0]) == (0, 0, 255)


def _error(call, *args, **kwargs) -> str:
    with pytest.raises(VideoFileError) as info:
        result = call(*args, **kwargs)
        if not isinstance(result, (list, int, float, type(None))):
            list(result)
    return str(info.value)


def test_reading_errors_name_the_file(tmp_path):
    missing = tmp_path / "missing.mp4"
    assert _error(read_frames, missing) == f"{missing}: no such video file or frame folder"
    text = tmp_path / "notes.mp4"
    text.write_text("this is not a video\n" * 20)
    assert _error(read_frames, text) == f"{text}: cannot open video: not a video OpenCV can read"
    assert "not a video OpenCV can read" in _error(video_fps, text)
    assert "not a video OpenCV can read" in _error(iter_frames, text)  # raised before iterating

    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("no frames here")
    assert _error(read_frames, empty).startswith(f"{empty}: the folder holds no frames")

    sizes = tmp_path / "sizes"
    sizes.mkdir()
    cv2.imwrite(str(sizes / "a1.png"), np.zeros((8, 10, 3), np.uint8))
    cv2.imwrite(str(sizes / "a2.png"), np.zeros((9, 10, 3), np.uint8))
    message = _error(read_frames, sizes)
    assert message.startswith(str(sizes / "a2.png")) and "10x9 px" in message and "a1.png is 10x8 px" in message

    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "f1.png").write_bytes(b"\x89PNG not really")
    assert _error(read_frames, corrupt).startswith(f"{corrupt / 'f1.png'}: cannot read the image")
    with pytest.raises(ValueError, match="max_frames"):
        read_frames(tmp_path, max_frames=0)


# ---------------------------------------------------------------------------
# A simulated session as a video


@pytest.fixture(scope="module")
def session():
    return zoo.tabletop_sessions(4, 1, 1, 1.0)[0]


def test_render_tabletop_video_draws_the_head_at_the_session_pose(session):
    frames, truth = render_tabletop_video(session, key=jax.random.key(1), scale=2, lead_in=3, num_frames=4)
    assert len(frames) == 7 and frames[0].shape == (480, 640, 3) and frames[0].dtype == np.uint8
    assert truth.image_size == (640, 480) and truth.scale == 2 and truth.lead_in == 3
    assert truth.focal_px == pytest.approx(2 * session.focal_px)
    np.testing.assert_array_equal(truth.session_frame, [-1, -1, -1, 0, 1, 2, 3])
    np.testing.assert_array_equal(truth.target[3:], np.asarray(session.target)[:4])
    assert np.all(truth.target[:3] == -1) and np.all(np.isnan(truth.gaze_direction_image[:3]))
    np.testing.assert_allclose(truth.head_pose[3:], np.asarray(session.head_pose_true)[:4], atol=1e-6)
    np.testing.assert_allclose(truth.target_depth_image[3:], 2 * np.asarray(session.target_depth_image)[:4], rtol=1e-6)
    np.testing.assert_allclose(truth.object_boxes_image, 2 * np.asarray(session.object_boxes_image), rtol=1e-5)
    np.testing.assert_allclose(truth.head_centre_image[3:], 2 * np.asarray(session.head_centre_image)[:4], rtol=1e-5)

    # The first frame is eye contact: the face's forward axis points from the eyes to the camera.
    R = truth.R_optical_from_frontal @ np.asarray(head_pose_to_rotation(yaw=truth.head_pose[0, 1], pitch=truth.head_pose[0, 0], roll=truth.head_pose[0, 2]), np.float64)
    eye = truth.head_position_optical[0]
    np.testing.assert_allclose(R[:, 0], -eye / np.linalg.norm(eye), atol=1e-6)
    np.testing.assert_allclose(frontal_rotation(truth.cylinder_centre_optical[0]), R, atol=1e-6)
    # The eye midpoint is the front of the face: half a head depth in front of the cylinder's centre.
    np.testing.assert_allclose(np.linalg.norm(truth.cylinder_centre_optical - truth.head_position_optical, axis=1),
                               CylinderHead().half_depth_m, rtol=1e-6)

    for frame, mask, centre in zip(frames, truth.head_masks, truth.head_centre_image):
        ys, xs = np.nonzero(mask)
        assert 50 <= xs.max() + 1 - xs.min() <= 75  # about 2 x 32 px wide at 1.5 m
        assert xs.min() <= centre[0] <= xs.max() + 1 and ys.min() <= centre[1] <= ys.max() + 1
    # Outside the head the frames are the (upscaled) scene, the same in every frame.
    outside = ~truth.head_masks.any(0)
    assert np.array_equal(frames[0][outside], frames[-1][outside])
    # The cubes stay in front of the head.
    assert not np.any(truth.head_masks & (truth.object_labels >= 0)[None])


def test_render_tabletop_video_at_the_simulator_scale_and_its_errors(session):
    frames, truth = render_tabletop_video(session, key=jax.random.key(1), scale=1, lead_in=0, num_frames=2,
                                          pose="reported")
    assert len(frames) == 2 and frames[0].shape == (240, 320, 3)
    np.testing.assert_allclose(truth.head_pose, np.asarray(session.head_pose)[:2], atol=1e-6)
    np.testing.assert_allclose(truth.head_centre_image, np.asarray(session.head_centre_image)[:2], atol=1e-3)
    with pytest.raises(ValueError, match="scale"):
        render_tabletop_video(session, key=jax.random.key(1), scale=1.5)
    with pytest.raises(ValueError, match="pose"):
        render_tabletop_video(session, key=jax.random.key(1), pose="noisy")
    with pytest.raises(ValueError, match="lead_in"):
        render_tabletop_video(session, key=jax.random.key(1), lead_in=-1)
    with pytest.raises(TypeError, match="TabletopSession"):
        render_tabletop_video("session", key=jax.random.key(1))
    with pytest.raises(ValueError, match="condition"):
        render_tabletop_video(session, key=jax.random.key(1), condition="sunny", num_frames=1)
