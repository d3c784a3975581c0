"""The table-top simulator (T-CYB Sec. VII) against its own ground truth."""

import math

import jax
import numpy as np
import pytest

from jaxgaze.geometry import yaw_pitch_to_direction
from jaxgaze.headpose import target as tg
from jaxgaze.simulate.tabletop import (
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    TabletopSession,
    session_features,
    project_optical_to_image,
    simulate_tabletop_sessions,
    tabletop_config,
)


@pytest.fixture(scope="module")
def sessions():
    return simulate_tabletop_sessions(jax.random.key(3), num_people=4, sessions_per_person=2, duration_s=60.0)


@pytest.fixture(scope="module")
def quiet_sessions():
    """No sway, long dwells: the head settles exactly on its target pose."""
    config = tabletop_config()._replace(head_sway_deg=0.0, head_sway_m=0.0, dwell_s=(4.0, 5.0))
    return simulate_tabletop_sessions(
        jax.random.key(11), num_people=3, sessions_per_person=2, duration_s=90.0, config=config
    )


@pytest.fixture(scope="module")
def sessions_x64():
    with jax.enable_x64(True):
        return simulate_tabletop_sessions(jax.random.key(5), num_people=2, sessions_per_person=2, duration_s=30.0)


def _np(s: TabletopSession):
    return {k: (np.asarray(v) if hasattr(v, "shape") else v) for k, v in s._asdict().items()}


def _frames_into_fixation(target):
    """For each frame, how many frames since the attended object last changed."""
    t = np.asarray(target)
    out = np.zeros(t.shape[0], dtype=int)
    for i in range(1, t.shape[0]):
        out[i] = out[i - 1] + 1 if t[i] == t[i - 1] else 0
    return out


def test_shapes_and_counts(sessions):
    assert len(sessions) == 8
    assert [s.person for s in sessions] == [0, 0, 1, 1, 2, 2, 3, 3]
    assert [s.session for s in sessions] == [0, 1] * 4
    for s in sessions:
        T, K = s.num_frames, s.num_objects
        assert T == 600 and 5 <= K <= 7 and s.fps == 10.0
        assert s.head_pose.shape == (T, 3) and s.head_position_optical.shape == (T, 3)
        assert s.head_centre_image.shape == (T, 2) and s.gaze_angles.shape == (T, 2)
        assert s.target.shape == (T,) and s.gaze_direction_image.shape == (T,)
        assert s.target_depth_image.shape == (T,) and s.head_direction_image.shape == (T,)
        assert s.object_centres_optical.shape == (K, 3) and s.object_centres_image.shape == (K, 2)
        assert s.object_boxes_image.shape == (K, 4)
        assert s.object_is_near.shape == (K,) and s.object_is_central.shape == (K,)
        assert s.object_is_near.dtype == bool
        for v in _np(s).values():
            if isinstance(v, np.ndarray) and v.dtype.kind == "f":
                assert np.all(np.isfinite(v))
        np.testing.assert_array_equal(np.asarray(session_features(s)), np.asarray(s.head_pose))
        feats = np.asarray(session_features(s, include_position=True))
        assert feats.shape == (T, 6)
        np.testing.assert_array_equal(feats[:, :3], np.asarray(s.head_pose))
        np.testing.assert_array_equal(feats[:, 3:], np.asarray(s.head_position_optical))


def test_head_under_rotates(sessions):
    for s in sessions:
        d = _np(s)
        yaw_slope = np.polyfit(d["gaze_angles"][:, 0], d["head_pose"][:, 1], 1)[0]
        pitch_slope = np.polyfit(d["gaze_angles"][:, 1], d["head_pose"][:, 0], 1)[0]
        assert 0.3 < yaw_slope < 1.0, yaw_slope
        assert 0.3 < pitch_slope < 1.0, pitch_slope
        assert yaw_slope < s.traits.yaw_gain + 0.05  # the dead zone only lowers the slope


def test_head_model_closed_form_and_dead_zone(quiet_sessions):
    """With no sway, settled frames follow yaw = offset + κ s(gaze), s(u) = u − w tanh(u/w)."""
    w = tabletop_config().dead_zone
    small, large = [], []
    for s in quiet_sessions:
        d, tr = _np(s), s.traits
        settled = _frames_into_fixation(d["target"]) >= 30
        g_yaw, g_pitch = d["gaze_angles"][settled].T
        pitch, yaw, roll = d["head_pose_true"][settled].T
        np.testing.assert_allclose(yaw, tr.yaw_offset + tr.yaw_gain * (g_yaw - w * np.tanh(g_yaw / w)), atol=1e-3)
        np.testing.assert_allclose(
            pitch, tr.pitch_offset + tr.pitch_gain * (g_pitch - w * np.tanh(g_pitch / w)), atol=1e-3
        )
        np.testing.assert_allclose(roll, tr.roll_offset + tr.roll_coupling * yaw, atol=1e-5)
        ratio = np.abs(yaw - tr.yaw_offset) / np.abs(g_yaw)
        small.append(ratio[np.abs(g_yaw) < 0.1])
        large.append(ratio[np.abs(g_yaw) > 0.3])
    small, large = np.concatenate(small), np.concatenate(large)
    assert small.size > 20 and large.size > 20
    # Inside the ocular motor range the head turns by a small fraction of the gaze shift.
    assert small.mean() < 0.25 * large.mean()
    assert np.all(small < 0.85 * 0.1**2 / (3 * w**2) + 1e-2)


def test_head_lags_after_a_saccade(quiet_sessions):
    """The true gaze jumps at a switch; the head follows over several frames."""
    s = quiet_sessions[0]
    d = _np(s)
    switch = np.flatnonzero(np.diff(d["target"]) != 0) + 1
    jumps = np.abs(d["gaze_angles"][switch, 0] - d["gaze_angles"][switch - 1, 0])
    k = switch[np.argmax(jumps)]
    yaw = d["head_pose_true"][:, 1]
    total = yaw[k + 30] - yaw[k - 1]
    first = yaw[k] - yaw[k - 1]
    assert abs(total) > 0.1
    alpha = 1 - math.exp(-1 / (s.traits.head_lag_s * s.fps))
    np.testing.assert_allclose(first / total, alpha, atol=0.02)
    assert 0.1 < abs(first / total) < 0.5


def test_tracker_noise_level(sessions):
    for s in sessions:
        noise = np.asarray(s.head_pose) - np.asarray(s.head_pose_true)
        assert 0.02 <= s.traits.tracker_noise <= 0.04
        np.testing.assert_allclose(noise.std(), s.traits.tracker_noise, rtol=0.1)
        assert abs(noise.mean()) < 0.005


def test_objects_spacing_table_and_image(sessions):
    for s in sessions:
        d = _np(s)
        c = d["object_centres_optical"]
        xz = c[:, [0, 2]]
        dist = np.linalg.norm(xz[:, None] - xz[None], axis=-1)
        np.fill_diagonal(dist, np.inf)
        nearest = dist.min(axis=1)
        assert np.all(nearest >= 0.2 - 1e-6) and np.all(nearest <= 0.3 + 1e-6)
        sizes = d["object_sizes_m"]
        assert np.all((sizes >= 0.06) & (sizes <= 0.10))
        bottoms = c[:, 1] + sizes / 2
        np.testing.assert_allclose(bottoms, bottoms[0], atol=1e-6)  # all on one table plane
        assert np.all(c[:, 1] > d["head_position_optical"][:, 1].max() + 0.2)  # well below the head
        assert np.all(c[:, 2] < d["head_rest_optical"][2])  # between the experimenter and the camera
        b = d["object_boxes_image"]
        assert np.all(b[:, 0] >= 0) and np.all(b[:, 1] >= 0)
        assert np.all(b[:, 2] <= IMAGE_WIDTH) and np.all(b[:, 3] <= IMAGE_HEIGHT)
        ci = d["object_centres_image"]
        assert np.all((ci[:, 0] > b[:, 0]) & (ci[:, 0] < b[:, 2]) & (ci[:, 1] > b[:, 1]) & (ci[:, 1] < b[:, 3]))
        np.testing.assert_allclose(ci, project_optical_to_image(c, s.focal_px), atol=1e-3)
        # Boxes: the bounding boxes of the 8 projected cube corners, recomputed here.
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        corners = c[:, None, :] + 0.5 * sizes[:, None, None] * signs
        proj = project_optical_to_image(corners, s.focal_px)
        np.testing.assert_allclose(b, np.concatenate([proj.min(1), proj.max(1)], axis=1), atol=1e-3)
        hc = d["head_centre_image"]
        assert np.all((hc[:, 0] > 0) & (hc[:, 0] < IMAGE_WIDTH) & (hc[:, 1] > 0) & (hc[:, 1] < IMAGE_HEIGHT))
        np.testing.assert_allclose(hc, project_optical_to_image(d["head_position_optical"], s.focal_px), atol=1e-3)
        assert 300 <= s.focal_px <= 350
        assert 1.35 < d["head_rest_optical"][2] < 1.65


def test_frontal_frame_and_gaze_angles(sessions):
    for s in sessions:
        d = _np(s)
        R = d["R_optical_from_frontal"]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-5)
        assert np.linalg.det(R) > 0.999
        # +x points from the rest eye to the camera, +y to the image right, +z up (−y in the camera).
        np.testing.assert_allclose(R[:, 0], -d["head_rest_optical"] / np.linalg.norm(d["head_rest_optical"]), atol=1e-6)
        assert R[0, 1] > 0.99 and R[1, 2] < -0.95
        # Gaze angles: eye -> attended centre, in the frontal frame.
        sight = (d["object_centres_optical"][d["target"]] - d["head_position_optical"]) @ R
        np.testing.assert_allclose(d["gaze_angles"][:, 0], np.arctan2(sight[:, 1], sight[:, 0]), atol=1e-5)
        assert np.all(d["gaze_angles"][:, 1] < -0.1)  # objects lie below the eyes
        # Positive yaw = the experimenter's left = the image's right.
        right = d["object_centres_image"][d["target"], 0] > d["head_centre_image"][:, 0] + 20
        assert np.all(d["gaze_angles"][right, 0] > 0)


def test_image_targets_f1_f2(sessions):
    for s in sessions:
        d = _np(s)
        att = d["object_centres_image"][d["target"]]
        np.testing.assert_array_equal(d["target_depth_image"], att[:, 1])
        delta = att - d["head_centre_image"]
        np.testing.assert_allclose(d["gaze_direction_image"], np.arctan2(delta[:, 1], delta[:, 0]), atol=1e-5)
        # Objects lie below the head: f1 points down the image.
        assert np.all((d["gaze_direction_image"] > 0) & (d["gaze_direction_image"] < math.pi))
        np.testing.assert_allclose(
            np.asarray(tg.target_point(s.head_centre_image, s.gaze_direction_image, s.target_depth_image)),
            att,
            atol=2e-3,
        )


def test_target_point_of_true_f1_f2_is_exact_in_x64(sessions_x64, x64):
    for s in sessions_x64:
        assert s.head_centre_image.dtype == np.float64
        p = np.asarray(tg.target_point(s.head_centre_image, s.gaze_direction_image, s.target_depth_image))
        np.testing.assert_allclose(p, np.asarray(s.object_centres_image)[np.asarray(s.target)], atol=1e-9, rtol=0)
        assert np.all(np.asarray(tg.reaches_row(s.head_centre_image, s.gaze_direction_image, s.target_depth_image)))


def test_head_direction_image_is_projected_facing(sessions):
    """Recompute from the reported pose with jaxgaze.geometry and a small finite step in 3-D."""
    for s in sessions[:3]:
        d = _np(s)
        pitch, yaw = d["head_pose"][:, 0], d["head_pose"][:, 1]
        facing = np.asarray(yaw_pitch_to_direction(yaw, pitch)) @ d["R_optical_from_frontal"].T
        h = d["head_position_optical"].astype(np.float64)
        step = project_optical_to_image(h + 1e-4 * facing, s.focal_px) - project_optical_to_image(h, s.focal_px)
        expected = np.arctan2(step[:, 1], step[:, 0])
        err = np.abs(np.angle(np.exp(1j * (expected - d["head_direction_image"]))))
        assert np.all(err < 2e-3)
        # The only-head baseline is informative but worse than the truth.
        dev = tg.mean_angular_deviation(s.head_direction_image, s.gaze_direction_image)
        assert 0.02 < dev < 0.6


def test_attention_sequence(sessions):
    for s in sessions:
        t = np.asarray(s.target)
        change = np.flatnonzero(np.diff(t) != 0) + 1
        runs = np.diff(np.concatenate([[0], change, [t.size]]))
        assert np.all(runs[:-1] >= 20) and np.all(runs <= 50)  # dwell 2–5 s at 10 fps
        assert set(np.unique(t)) == set(range(s.num_objects))  # every object attended
        assert np.all(t[change] != t[change - 1])


def test_groups(sessions):
    near_all, central_all = [], []
    cfg = tabletop_config()
    for s in sessions:
        d = _np(s)
        c, h0, R = d["object_centres_optical"], d["head_rest_optical"], d["R_optical_from_frontal"]
        near = (h0[2] - c[:, 2]) < cfg.near_threshold_m
        v = (c - h0) @ R
        central = np.abs(np.arctan2(v[:, 1], v[:, 0])) < cfg.central_threshold
        np.testing.assert_array_equal(d["object_is_near"], near)
        np.testing.assert_array_equal(d["object_is_central"], central)
        near_all.append(near)
        central_all.append(central)
    assert 0.25 < np.concatenate(near_all).mean() < 0.75
    assert 0.25 < np.concatenate(central_all).mean() < 0.75


def test_idiosyncrasies_per_person(sessions):
    by_person = {}
    for s in sessions:
        by_person.setdefault(s.person, []).append(s)
    traits = []
    for p, ss in by_person.items():
        assert ss[0].traits == ss[1].traits
        # One table for all sessions (T-CYB recording set), but the experimenter sits a little differently.
        np.testing.assert_array_equal(ss[0].object_centres_optical, ss[1].object_centres_optical)
        assert not np.allclose(ss[0].head_rest_optical, ss[1].head_rest_optical)
        traits.append(np.array(ss[0].traits))
    traits = np.array(traits)
    # Every trait differs between every pair of people.
    for i in range(len(traits)):
        for j in range(i + 1, len(traits)):
            assert np.all(traits[i] != traits[j])
    cfg = tabletop_config()
    assert np.all((traits[:, 0] >= cfg.yaw_gain[0]) & (traits[:, 0] <= cfg.yaw_gain[1]))
    assert np.all(np.abs(traits[:, 2]) <= math.radians(cfg.yaw_offset_deg))


def test_unshared_layout_draws_a_table_per_session():
    a, b = simulate_tabletop_sessions(jax.random.key(3), num_people=1, sessions_per_person=2, duration_s=5.0,
                                      shared_layout=False)
    assert a.object_centres_optical.shape != b.object_centres_optical.shape or not np.allclose(
        a.object_centres_optical, b.object_centres_optical)
    with pytest.raises(TypeError, match="shared_layout"):
        simulate_tabletop_sessions(jax.random.key(3), shared_layout="yes")


def test_same_key_same_data_other_key_other_data(sessions):
    again = simulate_tabletop_sessions(jax.random.key(3), num_people=4, sessions_per_person=2, duration_s=60.0)
    for a, b in zip(sessions, again):
        for x, y in zip(a, b):
            if hasattr(x, "shape"):
                np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
            else:
                assert x == y
    other = simulate_tabletop_sessions(jax.random.key(4), num_people=4, sessions_per_person=2, duration_s=60.0)
    assert not np.allclose(np.asarray(other[0].head_pose), np.asarray(sessions[0].head_pose))
    assert other[0].traits != sessions[0].traits
    raw = simulate_tabletop_sessions(jax.random.PRNGKey(3), num_people=1, sessions_per_person=1, duration_s=2.0)
    assert raw[0].num_frames == 20


def test_other_rates_and_counts():
    ss = simulate_tabletop_sessions(
        jax.random.key(0), num_people=1, sessions_per_person=1, duration_s=10.0, fps=25.0, num_objects=7
    )
    assert ss[0].num_frames == 250 and ss[0].num_objects == 7 and ss[0].fps == 25.0
    t = np.asarray(ss[0].target)
    runs = np.diff(np.concatenate([[0], np.flatnonzero(np.diff(t) != 0) + 1, [t.size]]))
    assert np.all(runs[:-1] >= 50) and np.all(runs <= 125)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(num_people=0), "num_people"),
        (dict(num_people=1.5), "num_people"),
        (dict(sessions_per_person=0), "sessions_per_person"),
        (dict(duration_s=0.1), "at least 2 frames"),
        (dict(duration_s=float("nan")), "duration_s"),
        (dict(fps=-1.0), "fps"),
        (dict(num_objects=1), "num_objects"),
        (dict(num_objects=(7, 5)), "num_objects"),
        (dict(num_objects=(5, 6, 7)), "num_objects"),
        (dict(config=tabletop_config()._replace(object_spacing_m=(1.0, 1.2))), "could not place"),
        (dict(config=tabletop_config()._replace(yaw_gain=(0.9, 0.5))), "yaw_gain"),
        (dict(config=tabletop_config()._replace(tracker_noise=(0.02, float("nan")))), "tracker_noise"),
        (dict(config=tabletop_config()._replace(camera_above_table_m=(0.5, 0.6))), "camera_above_table_m"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        simulate_tabletop_sessions(jax.random.key(0), **{"duration_s": 5.0, **kwargs})


def test_bad_key_config_and_session_types():
    with pytest.raises(ValueError, match="key"):
        simulate_tabletop_sessions(0)
    with pytest.raises(ValueError, match="key"):
        simulate_tabletop_sessions(jax.random.split(jax.random.key(0), 2))
    with pytest.raises(TypeError, match="config"):
        simulate_tabletop_sessions(jax.random.key(0), config={"focal_px": (300, 350)})
    with pytest.raises(TypeError, match="TabletopSession"):
        session_features(np.zeros((5, 6)))
    with pytest.raises(ValueError, match="in front"):
        project_optical_to_image(np.array([0.0, 0.0, -1.0]), 300.0)
    with pytest.raises(ValueError, match="NaN"):
        project_optical_to_image(np.array([np.nan, 0.0, 1.0]), 300.0)
