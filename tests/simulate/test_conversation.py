"""Simulated multi-party conversations (jaxgaze.simulate.conversation): who looks at whom."""

import math
import time

import jax
import numpy as np
import pytest

from jaxgaze.bias.looking import direction_to_gaze_angles, gaze_angles_to_direction
from jaxgaze.geometry import head_pose_to_rotation
from jaxgaze.simulate import (
    Conversation,
    ConversationConfig,
    conversation_config,
    simulate_conversation,
    simulate_conversations,
)
from jaxgaze.simulate.conversation import _direction_to_yaw_pitch, _head_pose_to_rotation

DEG = math.pi / 180


@pytest.fixture(scope="module")
def scene():
    return simulate_conversation(jax.random.key(0), num_people=6, num_objects=2, standing=False)


@pytest.fixture(scope="module")
def scenes():
    return simulate_conversations(jax.random.key(1), 8)


def _phi(angles):
    yaw, tilt = angles[..., 0], angles[..., 1]
    return np.stack([np.cos(tilt) * np.cos(yaw), np.cos(tilt) * np.sin(yaw), np.sin(tilt)], axis=-1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def test_shapes_and_dtypes(scene):
    c = scene
    T, P, K = 600, 6, 2
    assert isinstance(c, Conversation)
    assert (c.num_frames, c.num_people, c.num_objects) == (T, P, K)
    assert c.fps == 10.0 and isinstance(c.config, ConversationConfig) and c.standing is False
    shapes = {
        "eye_positions": (T, P, 3),
        "R_world_from_head": (T, P, 3, 3),
        "true_R_world_from_head": (T, P, 3, 3),
        "gaze_angles": (T, P, 2),
        "measurement_scale": (T, P),
        "present": (T, P),
        "speaking": (T, P),
        "target": (T, P),
        "target_positions": (T, P, 3),
        "true_gaze_directions": (T, P, 3),
        "object_positions": (K, 3),
        "bias": (P, 2),
        "cone_width": (P,),
    }
    for name, shape in shapes.items():
        assert getattr(c, name).shape == shape, name
    for name in ("eye_positions", "R_world_from_head", "gaze_angles", "target_positions", "bias", "cone_width"):
        assert getattr(c, name).dtype == np.float64, name
    assert c.present.dtype == bool and c.speaking.dtype == bool
    assert np.issubdtype(c.target.dtype, np.integer)
    np.testing.assert_allclose(c.times, np.arange(T) / 10.0)
    for name in ("eye_positions", "R_world_from_head", "true_R_world_from_head", "measurement_scale"):
        assert np.all(np.isfinite(getattr(c, name))), name


def test_deterministic_and_key_dependent(scene):
    again = simulate_conversation(jax.random.key(0), num_people=6, num_objects=2, standing=False)
    for a, b in zip(scene, again):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
    other = simulate_conversation(jax.random.key(7), num_people=6, num_objects=2, standing=False)
    assert not np.allclose(np.nan_to_num(scene.gaze_angles), np.nan_to_num(other.gaze_angles))
    assert not np.array_equal(scene.target, other.target)
    batch = simulate_conversations(jax.random.key(3), 2, num_people=4)
    first = simulate_conversation(jax.random.split(jax.random.key(3), 2)[0], num_people=4)
    np.testing.assert_array_equal(batch[0].target, first.target)
    assert not np.array_equal(batch[0].eye_positions[:, :4], batch[1].eye_positions[:, :4])


def test_random_counts_and_fast():
    simulate_conversation(jax.random.key(10), num_people=3, duration_s=1.0)  # warm (key → seed draw)
    start = time.perf_counter()
    c = simulate_conversation(jax.random.key(11), num_people=8, duration_s=60.0, fps=10.0)
    assert time.perf_counter() - start < 1.0
    assert c.num_people == 8
    many = simulate_conversations(jax.random.key(2), 30, duration_s=5.0)
    people = {x.num_people for x in many}
    objects = {x.num_objects for x in many}
    standing = {x.standing for x in many}
    assert people <= set(range(3, 9)) and len(people) >= 4
    assert objects <= {1, 2, 3} and len(objects) >= 2
    assert standing == {True, False}


def test_rotations_orthonormal(scenes):
    for c in scenes:
        for R in (c.R_world_from_head, c.true_R_world_from_head):
            np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
            np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
        # The tracker error is a few degrees: the reported and true forward axes are close.
        err = _angle(c.R_world_from_head[..., :, 0], c.true_R_world_from_head[..., :, 0])
        assert 0.5 * DEG < np.median(err) < 4 * DEG and np.max(err) < 8 * DEG


def test_numpy_geometry_matches_jaxgaze():
    rng = np.random.default_rng(0)
    yaw, pitch, roll = rng.uniform(-3, 3, 50), rng.uniform(-1.4, 1.4, 50), rng.uniform(-1, 1, 50)
    np.testing.assert_allclose(_head_pose_to_rotation(yaw, pitch, roll), head_pose_to_rotation(yaw, pitch, roll), atol=1e-5)
    d = rng.normal(size=(50, 3))
    np.testing.assert_allclose(np.stack(_direction_to_yaw_pitch(d), -1), direction_to_gaze_angles(d), atol=1e-5)
    a = rng.uniform(-1, 1, (50, 2))
    np.testing.assert_allclose(_phi(a), gaze_angles_to_direction(a), atol=1e-6)


def test_gaze_reconstruction(scenes):
    """``R Φ(g + b) = v*`` exactly; ``v*`` scatters around the target as Rayleigh(sqrt(h² + s²))."""
    ratios = []
    for c in scenes:
        m = c.present
        v = np.einsum("tpij,tpj->tpi", c.R_world_from_head, _phi(c.gaze_angles + c.bias))
        np.testing.assert_allclose(v[m], c.true_gaze_directions[m], atol=1e-12)
        u = _unit(c.target_positions - c.eye_positions)
        sigma = np.sqrt(c.cone_width[None] ** 2 + c.measurement_scale**2)
        ratios.append(_angle(u[m], v[m]) / sigma[m])
        # Only relative to the *reported* head pose: with the true one the tracker error shows.
        v_true_head = np.einsum("tpij,tpj->tpi", c.true_R_world_from_head, _phi(c.gaze_angles + c.bias))
        assert np.median(_angle(v_true_head[m], v[m])) > 0.5 * DEG
    ratios = np.concatenate(ratios)
    assert abs(np.median(ratios) - math.sqrt(2 * math.log(2))) < 0.05
    assert np.mean(ratios**2) == pytest.approx(2.0, rel=0.1)



def test_held_cone_share_holds_the_cone_offset_for_a_fixation():
    """``held_cone_share = 1``: the angle to the target stays the same through each fixation (frames in a row
    on one target; a new segment on the same target is rare); 0 draws it afresh each frame. Only the held
    draws are added: the targets are those of the scene without them."""
    config = dict(measurement_scale_deg=(0.0, 0.0))
    scenes = [simulate_conversation(jax.random.key(4), num_people=5, duration_s=30.0,
                                    config=ConversationConfig(held_cone_share=c, **config)) for c in (0.0, 1.0)]
    assert np.array_equal(scenes[0].target, scenes[1].target)
    same = []
    for c in scenes:
        angle = _angle(_unit(c.target_positions - c.eye_positions), c.true_gaze_directions)
        kept = c.present[1:] & c.present[:-1] & (c.target[1:] == c.target[:-1])
        same.append(np.mean(np.abs(angle[1:] - angle[:-1])[kept] < 1e-9))
        sigma = angle[c.present] / np.broadcast_to(c.cone_width, c.present.shape)[c.present]
        assert np.mean(sigma ** 2) == pytest.approx(2.0, rel=0.35)  # the same Rayleigh marginal
    assert same[0] < 0.01 and same[1] > 0.9
    with pytest.raises(ValueError, match="held_cone_share"):
        conversation_config(held_cone_share=1.5)

def test_a_fixation_segment_holds_one_target_and_one_spot():
    """``fixation_segment``: each segment is one person's run of frames on one target; with ``held_cone_share = 1``
    the angle to the target stays the same through it, and a segment that follows one on the same target draws
    a new spot (the angle changes where the segment does and the target does not)."""
    scene = simulate_conversation(jax.random.key(4), num_people=5, duration_s=30.0,
                                  config=ConversationConfig(held_cone_share=1.0, measurement_scale_deg=(0.0, 0.0)))
    segment, present = scene.fixation_segment, scene.present
    np.testing.assert_array_equal(segment >= 1, present)
    angle = _angle(_unit(scene.target_positions - scene.eye_positions), scene.true_gaze_directions)
    for s in np.unique(segment[present]):
        t, i = np.nonzero(segment == s)
        assert np.unique(i).size == 1 and np.unique(scene.target[t, i]).size == 1
        assert np.all(np.diff(t) == 1) and np.ptp(angle[t, i]) < 1e-9
    both = present[1:] & present[:-1] & (scene.target[1:] == scene.target[:-1])
    again = both & (segment[1:] != segment[:-1])  # a new segment on the same target
    assert again.sum() >= 10
    assert np.all(np.abs(angle[1:] - angle[:-1])[again] > 1e-6)


def test_a_head_turn_limit_saturates_the_turn():
    """``head_turn_limit_deg = L``: the head turns ``L tanh(κ θ / L)`` of the line of sight's azimuth and elevation
    ``θ`` from the body (no lag, sway or tracker error here: the reported head is the true one)."""
    quiet = dict(head_lag_s=0.0, head_sway_deg=0.0, head_roll_deg=0.0, tracker_drift_deg=0.0, tracker_jitter_deg=0.0)
    _wrap = lambda a: np.angle(np.exp(1j * a))  # noqa: E731
    for limit in (0.0, 20.0):
        config = ConversationConfig()._replace(head_turn_limit_deg=limit, **quiet)
        c = simulate_conversation(jax.random.key(3), num_people=5, duration_s=20.0, config=config)
        P = c.target.shape[1]
        t, i = np.nonzero(c.present & (c.target >= 0) & (c.target < P))
        sight = c.eye_positions[t, c.target[t, i]] - c.eye_positions[t, i]
        yaw, pitch = _direction_to_yaw_pitch(sight)
        turn = c.head_fraction[i, None] * np.stack([_wrap(yaw - c.body_yaw[i]), pitch], axis=-1)
        if limit:
            turn = math.radians(limit) * np.tanh(turn / math.radians(limit))
        head_yaw, head_pitch = _direction_to_yaw_pitch(c.R_world_from_head[t, i, :, 0])
        np.testing.assert_allclose(_wrap(head_yaw - c.body_yaw[i]), turn[:, 0], atol=1e-6)
        np.testing.assert_allclose(head_pitch, turn[:, 1], atol=1e-6)
        assert np.abs(turn).max() > math.radians(15.0)  # turns that reach into the saturation
    with pytest.raises(ValueError, match="head_turn_limit_deg"):
        simulate_conversation(jax.random.key(3), config=ConversationConfig()._replace(head_turn_limit_deg=-1.0))


def test_the_trackers_tilt_factor_scales_its_pitch_error_only():
    """``tracker_tilt_factor = f``: the tracker error ``E = true_Rᵀ R`` (``R_z(yaw) R_y(−pitch) R_x(roll)``) has ``f``
    times the pitch of the default scene's, the same yaw and roll, and the true heads are the same."""
    def errors(factor):
        c = simulate_conversation(jax.random.key(4), num_people=4, duration_s=10.0,
                                  config=ConversationConfig(tracker_tilt_factor=factor))
        E = np.einsum("tpji,tpjk->tpik", c.true_R_world_from_head, c.R_world_from_head)
        yaw, pitch = _direction_to_yaw_pitch(E[..., :, 0])
        return c.true_R_world_from_head, yaw, pitch, np.arctan2(E[..., 2, 1], E[..., 2, 2])

    true_1, yaw_1, pitch_1, roll_1 = errors(1.0)
    true_3, yaw_3, pitch_3, roll_3 = errors(3.0)
    np.testing.assert_array_equal(true_1, true_3)
    np.testing.assert_allclose(pitch_3, 3.0 * pitch_1, atol=1e-9)
    np.testing.assert_allclose(yaw_3, yaw_1, atol=1e-9)
    np.testing.assert_allclose(roll_3, roll_1, atol=1e-9)
    assert np.std(pitch_1) > math.radians(0.5)  # a tracker error to scale
    with pytest.raises(ValueError, match="tracker_tilt_factor"):
        simulate_conversation(jax.random.key(3), config=ConversationConfig(tracker_tilt_factor=-1.0))


def test_targets_and_presence(scenes):
    for c in scenes:
        P, K = c.num_people, c.num_objects
        people = np.arange(P)[None]
        assert np.all(c.target != people)  # never self
        assert np.all((c.target >= -1) & (c.target < P + K))
        for j in range(P):
            m = c.target == j
            eye_j = np.broadcast_to(c.eye_positions[:, j][:, None], m.shape + (3,))
            np.testing.assert_array_equal(c.target_positions[m], eye_j[m])
            assert np.all(c.present[m.any(axis=1), j])  # nobody looks at an absent person
        for k in range(K):
            m = c.target == P + k
            np.testing.assert_array_equal(c.target_positions[m], np.broadcast_to(c.object_positions[k], (m.sum(), 3)))
        absent = ~c.present
        assert np.all(c.target[absent] == -1)
        assert np.all(np.isnan(c.gaze_angles[absent])) and np.all(np.isfinite(c.gaze_angles[c.present]))
        assert np.all(c.measurement_scale[absent] == 0)
        s = c.measurement_scale[c.present]
        assert s.min() >= 0.5 * DEG - 1e-12 and s.max() <= 3 * DEG + 1e-12
        # Elsewhere points are 2–5 m away.
        e = (c.target == -1) & c.present
        dist = np.linalg.norm(c.target_positions[e] - c.eye_positions[e], axis=-1)
        assert dist.min() > 1.9 and dist.max() < 5.1
    lost = np.mean(np.concatenate([(~c.present).ravel() for c in scenes]))
    assert 0.005 < lost < 0.1


def test_speaker_prior(scenes):
    """P(look at j | j speaks) / P(look at j | j silent) is about exp(β) = 6.5; listeners look at the speaker ~50 %."""
    look_s = n_s = look_n = n_n = 0
    at_speaker = n_single = 0
    for c in scenes:
        P = c.num_people
        for i in range(P):
            listening = c.present[:, i] & ~c.speaking[:, i]
            for j in range(P):
                if j == i:
                    continue
                ok = listening & c.present[:, j]
                look = c.target[:, i] == j
                look_s += np.sum(look & ok & c.speaking[:, j])
                n_s += np.sum(ok & c.speaking[:, j])
                look_n += np.sum(look & ok & ~c.speaking[:, j])
                n_n += np.sum(ok & ~c.speaking[:, j])
        single = c.speaking.sum(axis=1) == 1
        speaker = np.argmax(c.speaking, axis=1)
        m = single[:, None] & c.present & ~c.speaking
        at_speaker += np.sum((c.target == speaker[:, None]) & m)
        n_single += np.sum(m)
    ratio = (look_s / n_s) / (look_n / n_n)
    assert 4.0 < ratio < 10.0
    assert 0.4 < at_speaker / n_single < 0.7


def test_six_seated_outside_episodes():
    """With the defaults, a listener in a 6-person seated scene outside episodes looks at the speaker ~55 %."""
    hits = total = 0
    for c in simulate_conversations(jax.random.key(5), 6, num_people=6, standing=False):
        single = (c.speaking.sum(axis=1) == 1) & (c.episode_active() < 0)
        speaker = np.argmax(c.speaking, axis=1)
        m = single[:, None] & c.present & ~c.speaking
        hits += np.sum((c.target == speaker[:, None]) & m)
        total += np.sum(m)
    assert 0.45 < hits / total < 0.65


def test_joint_attention(scenes):
    shared = 0
    inside = outside = 0.0
    for c in scenes:
        P, K = c.num_people, c.num_objects
        counts = np.stack([np.sum(c.target == P + k, axis=1) for k in range(K)], axis=1)  # (T, K)
        shared += np.sum(counts.max(axis=1) >= 2)
        active = c.episode_active()
        on_active = np.array([counts[t, a] if a >= 0 else 0 for t, a in enumerate(active)])
        frac = on_active / np.maximum(c.present.sum(axis=1), 1)
        inside += frac[active >= 0].mean()
        outside += (counts.sum(axis=1) / np.maximum(c.present.sum(axis=1), 1))[active < 0].mean()
    assert shared > 100
    assert inside / len(scenes) > 0.4 > outside / len(scenes)


def test_traits_in_range(scenes):
    for c in scenes:
        norm = np.linalg.norm(c.bias, axis=1)
        assert np.all((norm >= 5 * DEG - 1e-12) & (norm <= 15 * DEG + 1e-12))
        assert np.all((c.cone_width >= 2 * DEG) & (c.cone_width <= 6 * DEG))
    directions = np.concatenate([np.arctan2(c.bias[:, 1], c.bias[:, 0]) for c in scenes])
    assert np.ptp(directions) > math.pi  # directions spread over the plane


def test_layout(scenes):
    for c in scenes:
        z = c.eye_positions[..., 2]
        if c.standing:
            assert z.min() > 1.45 and z.max() < 1.85
        else:
            assert z.min() > 1.1 and z.max() < 1.35
        centre = c.eye_positions.mean(axis=(0, 1))[:2]
        r = np.linalg.norm(c.eye_positions[0, :, :2] - centre, axis=-1)
        assert r.min() > 0.5 and r.max() < 1.6
        sway = np.abs(c.eye_positions - c.eye_positions.mean(axis=0)).max()
        assert 0.005 < sway <= 0.031
        table = [p for p in c.object_positions if abs(p[2] - 0.775) < 0.03]
        for a in range(len(table)):
            for b in range(a):
                assert np.linalg.norm(table[a][:2] - table[b][:2]) >= 0.3 - 1e-9


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(num_people=1), "num_people"),
        (dict(num_people=2.5), "num_people"),
        (dict(num_objects=-1), "num_objects"),
        (dict(fps=0.0), "fps"),
        (dict(fps=-3.0), "fps"),
        (dict(fps=float("nan")), "fps"),
        (dict(duration_s=0.0), "duration_s"),
        (dict(duration_s=float("nan")), "duration_s"),
        (dict(standing="yes"), "standing"),
        (dict(config=ConversationConfig(cone_width_deg=(2.0, float("nan")))), "cone_width_deg"),
    ],
)
def test_bad_arguments(kwargs, name):
    with pytest.raises(ValueError, match=name):
        simulate_conversation(jax.random.key(0), **kwargs)


def test_config():
    assert conversation_config() == ConversationConfig()
    assert conversation_config(w_elsewhere=1.0).w_elsewhere == 1.0
    assert math.exp(conversation_config().speaker_beta) == pytest.approx(6.5)
    with pytest.raises(ValueError, match="bias_deg"):
        conversation_config(bias_deg=(10.0, 5.0))
    with pytest.raises(ValueError, match="episode_s"):
        conversation_config(episode_s=(2.0, 30.0))
    with pytest.raises(ValueError, match="no_such_field"):
        conversation_config(no_such_field=1)
    with pytest.raises(ValueError, match="key"):
        simulate_conversation(0)
    with pytest.raises(ValueError, match="num_scenes"):
        simulate_conversations(jax.random.key(0), 0)


# ---------------------------------------------------------------------------
# Head-mounted cameras (step 10)


@pytest.fixture(scope="module")
def worn():
    """Two seated/standing scenes with 3 of 6 and 6 of 6 wearers."""
    a = simulate_conversation(jax.random.key(0), num_people=6, num_objects=2, standing=False, num_wearers=3)
    b = simulate_conversation(jax.random.key(1), num_people=6, standing=True, num_wearers=6, calibration_frames=150)
    return a, b


def test_no_wearers_unchanged(scene):
    """``num_wearers = 0`` is the default and gives exactly the scene from before the option existed."""
    zero = simulate_conversation(jax.random.key(0), num_people=6, num_objects=2, standing=False, num_wearers=0)
    for name in Conversation._fields:
        a, b = getattr(scene, name), getattr(zero, name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=name)
    P = scene.num_people
    assert not scene.wearer.any() and scene.wearer.shape == (P,) and scene.wearer.dtype == bool
    assert scene.camera_positions.shape == (600, P, 3) and np.all(np.isnan(scene.camera_positions))
    assert scene.eye_in_camera.shape == (P, 3) and np.all(np.isnan(scene.eye_in_camera))
    assert scene.calibration_points.shape == (P, 0, 3)
    # Weighted sums recorded before the head-mounted option was added (same key and arguments).
    c = simulate_conversation(jax.random.key(3), duration_s=10.0)
    assert (c.num_people, c.num_objects, c.standing, int(c.present.sum())) == (4, 2, True, 400)
    expected = {
        "eye_positions": 341390.84666156344,
        "R_world_from_head": 570763.7156853767,
        "gaze_angles": -16943.76632630048,
        "target": 171257.0,
        "target_positions": 284660.3321979551,
        "bias": -0.3487334231817787,
        "cone_width": 0.7212076463326433,
    }
    for name, value in expected.items():
        x = np.asarray(getattr(c, name), np.float64)
        weighted = np.nansum(x * np.arange(1, x.size + 1).reshape(x.shape))
        assert weighted == pytest.approx(value, rel=1e-9, abs=1e-9), name


def test_wearer_shapes_and_others_unchanged(worn, scene):
    a, b = worn
    for c, W, M in ((a, 3, 100), (b, 6, 150)):
        T, P = c.num_frames, c.num_people
        np.testing.assert_array_equal(c.wearer, np.arange(P) < W)
        assert c.camera_positions.shape == (T, P, 3)
        assert c.eye_in_camera.shape == (P, 3) and c.calibration_points.shape == (P, M, 3)
        w = c.wearer
        assert np.all(np.isfinite(c.camera_positions[:, w])) and np.all(np.isnan(c.camera_positions[:, ~w]))
        assert np.all(np.isfinite(c.eye_in_camera[w])) and np.all(np.isnan(c.eye_in_camera[~w]))
        assert np.all(np.isfinite(c.calibration_points[w])) and np.all(np.isnan(c.calibration_points[~w]))
        for name in ("eye_positions", "R_world_from_head", "true_R_world_from_head", "measurement_scale"):
            assert np.all(np.isfinite(getattr(c, name))), name
        for R in (c.R_world_from_head, c.true_R_world_from_head):
            np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
            np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
        # Mounting ranges (calibration.random_mounting): eyes below and behind the camera.
        e = c.eye_in_camera[w]
        assert np.all((e[:, 0] < -0.009) & (e[:, 0] > -0.041) & (e[:, 2] < -0.049) & (e[:, 2] > -0.101))
        # The wearer has no eye tracker: zero gaze where present, NaN where absent; no measurement noise.
        m = c.present[:, w]
        assert np.all(c.gaze_angles[:, w][m] == 0) and np.all(np.isnan(c.gaze_angles[:, w][~m]))
        assert np.all(c.measurement_scale[:, w] == 0)
        assert np.all(c.head_fraction[w] == 1.0)
        # The line of sight passes through the target.
        u = _unit(c.target_positions - c.eye_positions)
        np.testing.assert_allclose(c.true_gaze_directions[:, w][m], u[:, w][m], atol=1e-12)
        # Upright camera: its +z stays near the world vertical.
        assert np.min(c.true_R_world_from_head[:, w, 2, 2]) > 0.5
    # Wearers change nothing for the others (the wearer stream is separate).
    for name in ("eye_positions", "R_world_from_head", "true_R_world_from_head", "gaze_angles", "measurement_scale",
                 "present", "speaking", "target", "target_positions", "true_gaze_directions"):
        np.testing.assert_array_equal(getattr(a, name)[:, 3:], getattr(scene, name)[:, 3:], err_msg=name)
    for name in ("bias", "cone_width", "head_fraction"):
        np.testing.assert_array_equal(getattr(a, name)[3:], getattr(scene, name)[3:], err_msg=name)
    np.testing.assert_array_equal(a.cone_width, scene.cone_width)  # h_w is the person's cone width
    np.testing.assert_array_equal(a.object_positions, scene.object_positions)


def test_wearer_primary_ray(worn):
    """``R Φ(g + b) = R v_w`` is the primary ray; it misses the eye→target direction by ≈ Rayleigh(h_w)."""
    ratios, reported = [], []
    for c in worn:
        w = c.wearer
        m = c.present[:, w]
        v = _phi(c.bias[w])  # (W, 3) primary direction in the camera frame
        np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-12)
        g = np.where(m[..., None], c.gaze_angles[:, w], 0.0)
        np.testing.assert_allclose(_phi(g + c.bias[w]), np.broadcast_to(v, g.shape[:-1] + (3,)), atol=1e-12)
        u = _unit(c.target_positions - c.eye_positions)[:, w]
        primary_true = np.einsum("twij,wj->twi", c.true_R_world_from_head[:, w], v)
        ratios.append((_angle(primary_true, u) / c.cone_width[w])[m])
        primary = np.einsum("twij,wj->twi", c.R_world_from_head[:, w], v)
        reported.append((_angle(primary, u) / c.cone_width[w])[m])
        # Structure-from-motion noise ≈ 0.3° per axis: forward axes differ by ~Rayleigh(0.3°).
        err = _angle(c.R_world_from_head[:, w, :, 0], c.true_R_world_from_head[:, w, :, 0])
        assert 0.25 * DEG < np.median(err) < 0.5 * DEG
    ratios, reported = np.concatenate(ratios), np.concatenate(reported)
    assert abs(np.median(ratios) - math.sqrt(2 * math.log(2))) < 0.06
    assert np.mean(ratios**2) == pytest.approx(2.0, rel=0.12)
    assert abs(np.median(reported) - math.sqrt(2 * math.log(2))) < 0.1


def test_camera_centres(worn, monkeypatch):
    """``C + R e = eye``: exactly without pose noise, with N(0, 1 cm²) noise on the reported centre."""
    for c in worn:
        w = c.wearer
        eye_true = np.einsum("twij,wj->twi", c.true_R_world_from_head[:, w], c.eye_in_camera[w])
        residual = c.camera_positions[:, w] + eye_true - c.eye_positions[:, w]
        assert abs(np.std(residual) - 0.01) < 0.001 and abs(np.mean(residual)) < 0.001
        eye_rep = np.einsum("twij,wj->twi", c.R_world_from_head[:, w], c.eye_in_camera[w])
        assert np.median(np.linalg.norm(c.camera_positions[:, w] + eye_rep - c.eye_positions[:, w], axis=-1)) < 0.025
    import jaxgaze.simulate.conversation as conversation

    monkeypatch.setattr(conversation, "_SFM_POSITION_M", 0.0)
    monkeypatch.setattr(conversation, "_SFM_ROTATION_DEG", 0.0)
    c = simulate_conversation(jax.random.key(0), num_people=6, num_objects=2, standing=False, num_wearers=3)
    a = worn[0]
    np.testing.assert_array_equal(c.true_R_world_from_head, a.true_R_world_from_head)
    np.testing.assert_allclose(c.R_world_from_head[:, :3], c.true_R_world_from_head[:, :3], atol=1e-15)
    w = c.wearer
    eye = c.camera_positions[:, w] + np.einsum("twij,wj->twi", c.R_world_from_head[:, w], c.eye_in_camera[w])
    np.testing.assert_allclose(eye, c.eye_positions[:, w], atol=1e-12)


def test_calibration_points(worn):
    """Points of regard in the camera frame lie around the primary ray (e_w, v_w): angle / h ≈ Rayleigh."""
    ratios = []
    for c in worn:
        for i in np.flatnonzero(c.wearer):
            y = c.calibration_points[i] - c.eye_in_camera[i]
            ratios.append(_angle(y, np.broadcast_to(_phi(c.bias[i]), y.shape)) / c.cone_width[i])
            dist = np.linalg.norm(c.calibration_points[i], axis=-1)
            assert dist.min() > 0.3 and dist.max() < 6.0  # the partner is metres away
    ratios = np.concatenate(ratios)
    assert ratios.size == 3 * 100 + 6 * 150
    assert abs(np.median(ratios) - math.sqrt(2 * math.log(2))) < 0.1


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(num_people=4, num_wearers=-1), "num_wearers"),
        (dict(num_people=4, num_wearers=5), "num_wearers"),
        (dict(num_wearers=9), "num_wearers"),  # more than any drawn P (3–8)
        (dict(num_people=4, num_wearers=1.0), "num_wearers"),
        (dict(num_people=4, num_wearers=True), "num_wearers"),
        (dict(num_people=4, num_wearers=1, calibration_frames=1), "calibration_frames"),
        (dict(num_people=4, calibration_frames=2.5), "calibration_frames"),
    ],
)
def test_bad_wearer_arguments(kwargs, name):
    with pytest.raises(ValueError, match=name):
        simulate_conversation(jax.random.key(0), duration_s=2.0, **kwargs)
