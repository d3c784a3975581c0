"""The cylindrical head model (renderer) and the 6-DoF CHM tracker (T-CYB 2013 Sec. IV)."""

import time

import numpy as np
import pytest

from jaxgaze.vision.head_model import (
    BACKGROUND_RGB,
    HAIR_RGB,
    CylinderHead,
    distance_for_width_px,
    frontal_rotation,
    load_face_texture,
    projected_width_px,
    render_head,
)
from jaxgaze.vision.tracker import HeadTrack, _update, initial_head_position, track_head
from jaxgaze.geometry import head_pose_to_rotation, rotation_to_head_pose
from jaxgaze.results import RESULTS, code, succeeded


def pose_to_rotation(pose):
    """``R_frontal_from_head`` of ``(..., 3)`` poses in the tracker's column order (pitch, yaw, roll)."""
    pose = np.asarray(pose)
    return head_pose_to_rotation(yaw=pose[..., 1], pitch=pose[..., 0], roll=pose[..., 2])


def rotation_to_pose(R):
    """Inverse of :func:`pose_to_rotation`: ``(..., 3)`` (pitch, yaw, roll)."""
    yaw, pitch, roll = rotation_to_head_pose(R)
    return np.stack([pitch, yaw, roll], axis=-1)

W, H, F = 320, 240, 300.0
DEG = np.pi / 180
T0 = np.array([0.01, 0.005, 0.45])  # about 102 px wide at f = 300 px


def _render(pose, position, Rf=None, **kw):
    kw.setdefault("image_size", (W, H))
    return render_head(pose, focal_px=kw.pop("focal_px", F), position_optical=position, R_optical_from_frontal=Rf, **kw)


def _mask_box(mask):
    ys, xs = np.nonzero(mask)
    return (xs.min(), ys.min(), xs.max() + 1 - xs.min(), ys.max() + 1 - ys.min())


def _box_of_head(frame):
    """A stand-in face detector: the box of everything that is not background."""
    fg = np.any(frame != np.asarray(BACKGROUND_RGB, np.uint8), axis=-1)
    return [_mask_box(fg)] if fg.any() else []


def _project(point):
    return F * point[0] / point[2] + W / 2, F * point[1] / point[2] + H / 2


# ---------------------------------------------------------------------------
# Geometry and rendering


def test_pose_rotation_round_trip_and_signs():
    poses = np.array([[0.3, -0.5, 0.2], [-0.8, 1.2, -0.3], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(rotation_to_pose(pose_to_rotation(poses)), poses, atol=1e-5)
    R = np.asarray(pose_to_rotation(np.array([0.0, 0.3, 0.0])))
    assert R[1, 0] > 0  # yaw > 0 turns forward (+x) towards the left (+y)
    R = np.asarray(pose_to_rotation(np.array([0.3, 0.0, 0.0])))
    assert R[2, 0] > 0  # pitch > 0 turns forward up (+z)
    R = np.asarray(pose_to_rotation(np.array([0.0, 0.0, 0.3])))
    assert R[2, 1] > 0  # roll > 0 turns left (+y) up (+z)


def test_frontal_rotation_on_axis_faces_the_camera():
    Rf = frontal_rotation([0.0, 0.0, 1.0])
    np.testing.assert_allclose(Rf, [[0, 1, 0], [0, 0, -1], [-1, 0, 0]], atol=1e-12)
    Rf = frontal_rotation([0.2, -0.1, 1.0])
    np.testing.assert_allclose(Rf @ Rf.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rf) == pytest.approx(1.0)
    np.testing.assert_allclose(Rf[:, 0], -np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0]))


def test_texture_is_packaged():
    tex = load_face_texture()
    assert tex.shape == (128, 128, 3) and tex.dtype == np.uint8 and tex.std() > 20


def test_frontal_render_puts_texture_centre_at_head_centre():
    # Four quadrants: the texture's centre is where they meet.
    quad = np.zeros((64, 64, 3), np.uint8)
    colours = {(0, 0): (255, 0, 0), (0, 1): (0, 255, 0), (1, 0): (0, 0, 255), (1, 1): (255, 255, 0)}
    for (r, c), rgb in colours.items():
        quad[r * 32 : (r + 1) * 32, c * 32 : (c + 1) * 32] = rgb
    head = CylinderHead()
    for position in ([0.0, 0.0, 0.45], [0.03, -0.02, 0.5]):
        image, mask = _render(np.zeros(3), np.array(position), texture=quad)
        Rf = frontal_rotation(position)
        u, v = _project(Rf @ np.array([head.half_depth_m, 0.0, 0.0]) + position)  # the middle of the face
        i, j = int(round(u)), int(round(v))  # the pixel corner nearest to it
        assert abs(u - i) < 0.3 and abs(v - j) < 0.3
        for (r, c), rgb in colours.items():  # the 2 x 2 pixels around it, 2 px away to skip the seams
            np.testing.assert_allclose(image[j - 2 + 3 * r, i - 2 + 3 * c], rgb, atol=16)  # bilinear texture
        assert mask[j, i]


def test_mask_width_matches_closed_form():
    head = CylinderHead()
    for distance, focal, size in [(0.45, 300.0, (320, 240)), (0.8, 600.0, (640, 480))]:
        _, mask = render_head(np.zeros(3), focal_px=focal, image_size=size, position_optical=(0, 0, distance))
        expected = projected_width_px(head, distance, focal)
        assert abs(mask[size[1] // 2].sum() - expected) <= 1.0
        assert distance_for_width_px(head, expected, focal) == pytest.approx(distance)
        # The silhouette's sides are vertical: the width is the same on every row of the side.
        rows = mask[size[1] // 2 - 20 : size[1] // 2 + 20].sum(axis=1)
        assert rows.max() - rows.min() <= 1


def test_render_pose_signs_move_the_face_as_documented():
    position = np.array([0.0, 0.0, 0.45])
    nose = np.array([CylinderHead().half_depth_m, 0.0, 0.0])
    forehead = np.array([CylinderHead().half_depth_m, 0.0, 0.08])
    Rf = frontal_rotation(position)

    def image_of(pose, p):
        return np.array(_project(Rf @ np.asarray(pose_to_rotation(pose)) @ p + position))

    centre = image_of(np.zeros(3), nose)
    assert image_of(np.array([0.0, 0.3, 0.0]), nose)[0] > centre[0] + 10  # yaw > 0: face to the image's right
    assert image_of(np.array([0.3, 0.0, 0.0]), nose)[1] < centre[1] - 10  # pitch > 0: face up the image
    top = image_of(np.array([0.0, 0.0, 0.3]), forehead)
    assert top[0] < centre[0] - 5  # roll > 0: counter-clockwise in the image
    # ... and the rendered head follows: turned to its left, it shows its back on the image's left.
    image, _ = _render(np.array([0.0, 0.4, 0.0]), position)
    hair = np.all(image == np.asarray(HAIR_RGB, np.uint8), axis=-1)
    assert hair[:, : W // 2].sum() > hair[:, W // 2 :].sum()  # the back of the head shows on the image's left


def test_render_is_fast():
    pose, position = np.array([0.1, 0.3, 0.1]), np.array([0.02, 0.01, 0.45])
    _render(pose, position)
    start = time.perf_counter()
    for _ in range(5):
        _render(pose, position)
    assert (time.perf_counter() - start) / 5 < 0.05


def test_render_rejects_bad_arguments():
    with pytest.raises(ValueError, match="position_optical"):
        _render(np.zeros(3), np.array([0.0, 0.0, -1.0]))
    with pytest.raises(ValueError, match="pose"):
        _render(np.array([0.0, np.nan, 0.0]), T0)
    with pytest.raises(ValueError, match="image_size"):
        _render(np.zeros(3), T0, image_size=(0, 240))
    with pytest.raises(TypeError, match="texture"):
        _render(np.zeros(3), T0, texture=np.zeros((8, 8), bool))


# ---------------------------------------------------------------------------
# Tracking a known trajectory


def _trajectory(num_frames=100):
    k = np.arange(num_frames)
    pose = np.stack(
        [20 * DEG * np.sin(2 * np.pi * k / 60), 30 * DEG * np.sin(2 * np.pi * k / 100), 10 * DEG * np.sin(2 * np.pi * k / 80)],
        axis=-1,
    )
    trans = T0 + np.stack(
        [0.02 * np.sin(2 * np.pi * k / 90), 0.015 * np.sin(2 * np.pi * k / 70), 0.03 * np.sin(2 * np.pi * k / 110)], axis=-1
    )
    return pose, trans


@pytest.fixture(scope="module")
def sequence():
    pose, trans = _trajectory()
    Rf = frontal_rotation(trans[0])
    rendered = [_render(p, t, Rf) for p, t in zip(pose, trans)]
    frames = [image for image, _ in rendered]
    return pose, trans, frames, _mask_box(rendered[0][1])


@pytest.fixture(scope="module")
def tracked(sequence):
    pose, trans, frames, box = sequence
    track_head(frames[:2], initial_box=box, focal_px=F)  # compile
    compiled = _update._cache_size()
    start = time.perf_counter()
    track = track_head(frames, initial_box=box, focal_px=F)
    seconds = (time.perf_counter() - start) / len(frames)
    assert _update._cache_size() == compiled  # compiled once per frame shape, not per frame
    return track, seconds


def test_track_known_trajectory_within_3_degrees(sequence, tracked):
    pose, trans, frames, box = sequence
    track, seconds = tracked
    assert isinstance(track, HeadTrack)
    assert track.pose.shape == (100, 3) and track.translation.shape == (100, 3)
    assert track.residual.shape == track.reinitialised.shape == np.shape(succeeded(track)) == (100,)
    rms = np.sqrt(np.mean((track.pose - pose) ** 2, axis=0)) / DEG
    translation_rms = np.sqrt(np.mean((track.translation - trans) ** 2, axis=0))
    print(f"\nCHM track: RMS pitch {rms[0]:.2f}°, yaw {rms[1]:.2f}°, roll {rms[2]:.2f}°; translation RMS "
          f"x {translation_rms[0] * 1e3:.1f} mm, y {translation_rms[1] * 1e3:.1f} mm, z {translation_rms[2] * 1e3:.1f} mm; "
          f"{seconds * 1e3:.1f} ms/frame; converged {np.mean(succeeded(track)):.0%}")
    assert rms[0] < 3.0 and rms[1] < 3.0  # the target
    assert rms[2] < 3.0
    assert np.all(translation_rms < 0.01)
    assert not track.reinitialised.any()
    assert np.all(np.isfinite(track.residual)) and track.residual.max() < 0.05
    np.testing.assert_array_equal(track.pose[0], 0.0)
    assert np.mean(succeeded(track)) > 0.7


def test_first_frame_reference_also_tracks(sequence):
    pose, trans, frames, box = sequence
    track = track_head(frames[:40], initial_box=box, focal_px=F, reference="first")
    rms = np.sqrt(np.mean((track.pose - pose[:40]) ** 2, axis=0)) / DEG
    assert np.all(rms < 3.0)


def test_frames_may_be_an_array_or_an_iterator(sequence, tracked):
    pose, trans, frames, box = sequence
    a = track_head(np.stack(frames[:4]), initial_box=box, focal_px=F)
    b = track_head(iter(frames[:4]), initial_box=box, focal_px=F)
    np.testing.assert_allclose(a.pose, tracked[0].pose[:4], atol=1e-6)
    np.testing.assert_allclose(b.pose, a.pose, atol=1e-6)


def test_zero_motion_gives_zero_update(sequence):
    frames = sequence[2]
    box = sequence[3]
    track = track_head([frames[0], frames[0], frames[0]], initial_box=box, focal_px=F)
    assert np.abs(track.pose).max() < 1e-3
    assert np.abs(track.translation - track.translation[0]).max() < 1e-4
    assert track.residual[1:].max() < 1e-3


def test_small_known_yaw_is_recovered():
    Rf = frontal_rotation(T0)
    image0, mask0 = _render(np.zeros(3), T0, Rf)
    image1, _ = _render(np.array([0.0, 3 * DEG, 0.0]), T0, Rf)
    track = track_head([image0, image1], initial_box=_mask_box(mask0), focal_px=F)
    np.testing.assert_allclose(track.pose[1] / DEG, [0.0, 3.0, 0.0], atol=0.2)


def test_tracker_runs_in_float64_too(x64):
    # Under jax_enable_x64 the whole pose solve is float64 (optimistix's damping term follows
    # the default float, so a float32 solve there failed on mismatched structures).
    Rf = frontal_rotation(T0)
    frames = [_render(np.array([0.0, k * 2 * DEG, 0.0]), T0, Rf)[0] for k in range(3)]
    track = track_head(frames, initial_box=_mask_box(_render(np.zeros(3), T0, Rf)[1]), focal_px=F)
    np.testing.assert_allclose(track.pose[:, 1] / DEG, [0.0, 2.0, 4.0], atol=0.2)
    assert np.all(succeeded(track))


def test_initial_box_sets_depth_and_centre():
    box = (110.0, 40.0, projected_width_px(CylinderHead(), 0.5, F), 160.0)
    position = initial_head_position(box, focal_px=F, image_size=(W, H))
    assert position[2] == pytest.approx(0.5)
    u, v = _project(position)
    assert u == pytest.approx(110 + box[2] / 2) and v == pytest.approx(120.0)


def test_reinitialises_when_yaw_leaves_the_range():
    Rf = frontal_rotation(T0)
    yaws = np.linspace(0.0, 60.0, 31) * DEG  # 2° a frame up to 60°
    frames = [_render(np.array([0.0, y, 0.0]), T0, Rf)[0] for y in yaws]
    box = _box_of_head(frames[0])[0]
    track = track_head(frames, initial_box=box, focal_px=F, detector=_box_of_head)
    first = int(np.argmax(track.reinitialised))
    assert track.reinitialised.any()
    assert 40 * DEG <= yaws[first] <= 46 * DEG  # fires as the estimate passes 40°
    assert np.all(np.abs(track.pose[:first, 1]) <= 40 * DEG)
    np.testing.assert_array_equal(track.pose[first], 0.0)  # reset to frontal on the re-detected face

    # With no face to re-detect the tracker is lost: NaN, not converged, until one is found.
    lost = track_head(frames, initial_box=box, focal_px=F, detector=lambda frame: [])
    first = int(np.argmax(lost.reinitialised))
    assert np.all(np.isnan(lost.pose[first:])) and not np.asarray(succeeded(lost))[first:].any()
    assert np.all(np.isfinite(lost.pose[:first]))
    # ... and each frame says why: the lost frames are `lost`, not a solver failure.
    codes = np.asarray(code(lost.result))
    assert np.all(codes[first:] == code(RESULTS.lost)) and not np.any(codes[:first] == code(RESULTS.lost))


def test_initialises_from_the_face_detector():
    pytest.importorskip("jaxgaze.vision.faces")
    image, _ = _render(np.zeros(3), np.array([0.0, 0.0, 0.45]))
    track = track_head([image, image], focal_px=F)
    assert np.abs(track.translation[0, 2] - 0.45) < 0.1 * 0.45
    assert np.abs(track.pose).max() < 1e-3


# ---------------------------------------------------------------------------
# Errors


def test_errors_are_clear(sequence):
    frames, box = sequence[2], sequence[3]
    with pytest.raises(ValueError, match="empty"):
        track_head([], initial_box=box, focal_px=F)
    with pytest.raises(ValueError, match=r"frames\[1\] is 160x120"):
        track_head([frames[0], frames[1][::2, ::2]], initial_box=box, focal_px=F)
    bad = frames[1].astype(np.float32) / 255
    bad[3, 3] = np.nan
    with pytest.raises(ValueError, match=r"frames\[1\] contains NaN"):
        track_head([frames[0], bad], initial_box=box, focal_px=F)
    with pytest.raises(TypeError, match=r"frames\[0\]"):
        track_head([frames[0].astype(bool)], initial_box=box, focal_px=F)
    with pytest.raises(ValueError, match="outside"):
        track_head(frames[:2], initial_box=(400.0, 10.0, 50.0, 50.0), focal_px=F)
    with pytest.raises(ValueError, match="initial_box"):
        track_head(frames[:2], initial_box=(10.0, 10.0, -5.0, 50.0), focal_px=F)
    with pytest.raises(ValueError, match="no face found"):
        track_head(frames[:2], focal_px=F, detector=lambda frame: [])
    blank = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(ValueError, match="no face found"):
        track_head([blank], focal_px=F, detector=lambda frame: None)
    with pytest.raises(ValueError, match="sequence of images"):
        track_head(frames[0], initial_box=box, focal_px=F)
    with pytest.raises(ValueError, match="focal_px"):
        track_head(frames[:2], initial_box=box, focal_px=0.0)
    with pytest.raises(ValueError, match="reference"):
        track_head(frames[:2], initial_box=box, focal_px=F, reference="static")
