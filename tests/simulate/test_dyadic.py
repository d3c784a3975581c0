"""Simulated dyadic interactions (jaxgaze.simulate.dyadic; Siegfried, Odobez et al. 2017).

Three compiled programs serve every test: one 40 s interview, a batch of 32
such interviews, and one 10-minute desk session (the same key and shape reuse
the compiled program).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.geometry import angle_between, direction_to_yaw_pitch, yaw_pitch_to_direction
from jaxgaze.simulate.dyadic import (
    FOCUS_ELSEWHERE,
    FOCUS_PARTNER,
    NUM_OBJECTS,
    PRESETS,
    DyadicConfig,
    DyadicRecording,
    dyadic_config,
    simulate_dyadic,
    simulate_dyadic_sessions,
)

DURATION = 40.0
FPS = 30.0
T = int(round(DURATION * FPS))
NUM_SESSIONS = 32
DESK_DURATION = 600.0


@pytest.fixture(scope="module")
def interview():
    return simulate_dyadic(jax.random.key(0), "interview", duration_s=DURATION, fps=FPS)


@pytest.fixture(scope="module")
def batch():
    return simulate_dyadic_sessions(jax.random.key(3), NUM_SESSIONS, "interview", duration_s=DURATION, fps=FPS)


@pytest.fixture(scope="module")
def desk():
    return simulate_dyadic(jax.random.key(0), "desk", duration_s=DESK_DURATION, fps=FPS)


@pytest.fixture(scope="module", params=["interview", "batch", "desk"])
def rec(request):
    return request.getfixturevalue(request.param)


def _np(rec: DyadicRecording) -> dict:
    return {k: np.asarray(v) for k, v in rec._asdict().items() if isinstance(v, jax.Array)}


# NumPy versions of the geometry (docs/conventions.md): eager jax.numpy would
# compile every op for every shape, and these arrays are large.


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _phi(angles):
    """Φ: (yaw, tilt) → unit direction, ``(cos t cos y, cos t sin y, sin t)``."""
    yaw, tilt = angles[..., 0], angles[..., 1]
    return np.stack([np.cos(tilt) * np.cos(yaw), np.cos(tilt) * np.sin(yaw), np.sin(tilt)], axis=-1)


def _angle_deg(a, b):
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _world(R, angles):
    """Head-frame (yaw, tilt) → world unit direction."""
    return np.einsum("...ij,...j->...i", np.asarray(R), _phi(np.asarray(angles)))


def _errors_deg(rec: DyadicRecording, angles):
    """Angle (degrees) between Φ(angles) in the world and the direction to the partner's eyes."""
    to_target = _unit(np.asarray(rec.target_positions - rec.eye_positions))
    return _angle_deg(_world(rec.R_world_from_head, angles), to_target)


def _offsets(rec: DyadicRecording):
    """Downstream offsets: yaw/tilt of the target in the head frame minus the estimate, yaw wrapped."""
    to_target = np.asarray(rec.target_positions - rec.eye_positions)
    head = np.einsum("...ji,...j->...i", np.asarray(rec.R_world_from_head), to_target)  # Rᵀ u
    yaw = np.arctan2(head[..., 1], head[..., 0])
    tilt = np.arctan2(head[..., 2], np.hypot(head[..., 0], head[..., 1]))
    off = np.stack([yaw, tilt], axis=-1) - np.asarray(rec.gaze_angles)
    off[..., 0] = np.arctan2(np.sin(off[..., 0]), np.cos(off[..., 0]))
    return off


def test_numpy_helpers_match_geometry():
    rng = np.random.default_rng(0)
    angles = rng.uniform(-1.2, 1.2, (50, 2)).astype(np.float32)
    other = rng.normal(size=(50, 3)).astype(np.float32)
    np.testing.assert_allclose(_phi(angles), yaw_pitch_to_direction(angles[:, 0], angles[:, 1]), atol=1e-6)
    np.testing.assert_allclose(
        _angle_deg(_phi(angles), other), np.degrees(angle_between(_phi(angles), other)), atol=1e-3
    )
    yaw, tilt = direction_to_yaw_pitch(jnp.asarray(_phi(angles)))
    np.testing.assert_allclose(np.stack([yaw, tilt], -1), angles, atol=1e-5)


# ---------------------------------------------------------------------------
# Shapes, dtypes, determinism, batching


def test_shapes_and_dtypes(rec):
    lead = (NUM_SESSIONS,) if rec.speaking.ndim == 3 else ()
    frames = rec.num_frames
    assert frames == (int(round(DESK_DURATION * FPS)) if rec.preset == "desk" else T)
    P, K = 2, NUM_OBJECTS
    expected = {
        "speaking": (P, frames),
        "focus": (P, frames),
        "looking": (P, frames),
        "eye_positions": (P, frames, 3),
        "target_positions": (P, frames, 3),
        "focus_points": (P, frames, 3),
        "R_world_from_head": (P, frames, 3, 3),
        "true_gaze_angles": (P, frames, 2),
        "gaze_angles": (P, frames, 2),
        "bias": (P, 2),
        "object_positions": (P, K, 3),
        "head_fraction": (P,),
    }
    arrays = _np(rec)
    assert set(arrays) == set(expected)
    for name, shape in expected.items():
        assert arrays[name].shape == lead + shape, name
        assert np.all(np.isfinite(arrays[name])), name
    assert arrays["speaking"].dtype == bool and arrays["looking"].dtype == bool
    assert arrays["focus"].dtype == np.int32
    for name in ("eye_positions", "R_world_from_head", "gaze_angles", "true_gaze_angles", "bias"):
        assert np.issubdtype(arrays[name].dtype, np.floating), name
    assert rec.fps == FPS and rec.num_people == 2
    assert rec.preset in PRESETS and rec.config == dyadic_config(rec.preset)


def test_deterministic_per_key(interview):
    again = simulate_dyadic(jax.random.key(0), "interview", duration_s=DURATION, fps=FPS)
    other = simulate_dyadic(jax.random.key(1), "interview", duration_s=DURATION, fps=FPS)
    for name, value in _np(interview).items():
        np.testing.assert_array_equal(value, np.asarray(getattr(again, name)), err_msg=name)
    assert not np.allclose(interview.bias, other.bias)
    assert not np.array_equal(interview.speaking, other.speaking)
    # A DyadicConfig equal to the preset is the same model.
    same = simulate_dyadic(jax.random.key(0), dyadic_config("interview"), duration_s=DURATION, fps=FPS)
    np.testing.assert_array_equal(np.asarray(same.gaze_angles), np.asarray(interview.gaze_angles))


def test_sessions_match_single_runs(batch):
    keys = jax.random.split(jax.random.key(3), NUM_SESSIONS)
    for i in (0, NUM_SESSIONS - 1):
        one = simulate_dyadic(keys[i], "interview", duration_s=DURATION, fps=FPS)
        part = batch.take(i)
        for name, value in _np(one).items():
            np.testing.assert_allclose(np.asarray(getattr(part, name)), value, atol=1e-5, err_msg=name)
    assert not np.allclose(batch.bias[0], batch.bias[1])


# ---------------------------------------------------------------------------
# Geometry


def test_rotations_orthonormal(rec):
    R = np.asarray(rec.R_world_from_head, np.float64)
    eye = np.einsum("...ij,...kj->...ik", R, R)
    np.testing.assert_allclose(eye, np.broadcast_to(np.eye(3), eye.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-5)


def test_targets_are_partner_eyes(rec):
    eyes = np.asarray(rec.eye_positions)
    np.testing.assert_array_equal(np.asarray(rec.target_positions), np.flip(eyes, axis=-3))
    distance = np.linalg.norm(eyes[..., 0, :, :] - eyes[..., 1, :, :], axis=-1)
    lo, hi = rec.config.distance_m
    assert np.all(distance > lo - 0.5) and np.all(distance < hi + 0.5)
    # Small motion: each eye stays within body_sway_m (per axis) of its mean.
    sway = eyes - eyes.mean(axis=-2, keepdims=True)
    assert np.max(np.abs(sway)) <= 2 * rec.config.body_sway_m + 1e-6


def test_focus_points_match_focus(rec):
    a = _np(rec)
    focus, points = a["focus"], a["focus_points"]
    assert np.all((focus >= FOCUS_ELSEWHERE) & (focus <= NUM_OBJECTS))
    np.testing.assert_array_equal(a["looking"], focus == FOCUS_PARTNER)
    look = focus == FOCUS_PARTNER
    np.testing.assert_array_equal(points[look], a["target_positions"][look])
    for k in range(1, NUM_OBJECTS + 1):
        objects = np.broadcast_to(a["object_positions"][..., None, k - 1, :], points.shape)
        on = focus == k
        np.testing.assert_allclose(points[on], objects[on], atol=1e-6)
    # Every kind of target occurs.
    assert {int(v) for v in np.unique(focus)} == {-1, 0, 1, 2, 3}


def test_true_gaze_points_at_focus(rec):
    sight = _unit(np.asarray(rec.focus_points - rec.eye_positions))
    err = _angle_deg(_world(rec.R_world_from_head, rec.true_gaze_angles), sight)
    # Fixation noise N(0, 1°) per axis: Rayleigh, median ≈ 1.18°.
    assert 0.8 < np.median(err) < 1.6
    assert np.percentile(err, 99.9) < 6.0


# ---------------------------------------------------------------------------
# Bias and estimator noise


def test_bias_correction_points_at_partner(rec):
    look = np.asarray(rec.looking)
    corrected = _errors_deg(rec, np.asarray(rec.gaze_angles) + np.asarray(rec.bias)[..., None, :])[look]
    baseline = _errors_deg(rec, rec.gaze_angles)[look]
    assert np.median(corrected) < 6.0
    assert np.median(baseline) > 8.0
    assert np.median(baseline) > 1.8 * np.median(corrected)
    # Per person too: every bias is at least bias_deg[0] = 6° (interview), 8° (desk).
    errs = _errors_deg(rec, rec.gaze_angles)
    for person in np.ndindex(look.shape[:-1]):
        assert np.median(errs[person][look[person]]) > 4.0


def test_offsets_are_bias_plus_noise(rec):
    look = np.asarray(rec.looking)
    off = _offsets(rec)
    bias = np.asarray(rec.bias)
    lo, hi = rec.config.bias_deg
    magnitude = np.degrees(np.linalg.norm(bias, axis=-1))
    assert np.all((magnitude >= lo - 1e-4) & (magnitude <= hi + 1e-4))
    for person in np.ndindex(look.shape[:-1]):
        o = off[person][look[person]]
        np.testing.assert_allclose(np.median(o, axis=0), bias[person], atol=math.radians(1.5))
    # Residual spread ≈ sqrt(noise² + fixation²) per axis (robust scale of the t₄ noise).
    resid = np.degrees((off - bias[..., None, :])[look])
    mad = 1.4826 * np.median(np.abs(resid - np.median(resid, axis=0)), axis=0)
    expected = math.hypot(rec.config.noise_deg, rec.config.fixation_noise_deg)
    # t₄ scaled to unit variance has MAD-σ ≈ 0.8 of its std; allow for it.
    assert np.all(mad > 0.6 * expected) and np.all(mad < 1.1 * expected)
    # Heavy-ish tails: some errors beyond 3 σ.
    assert np.mean(np.abs(resid) > 3 * expected) > 0.002


def test_gaze_is_true_minus_bias_plus_noise(rec):
    noise = np.asarray(rec.gaze_angles) + np.asarray(rec.bias)[..., None, :] - np.asarray(rec.true_gaze_angles)
    noise[..., 0] = np.arctan2(np.sin(noise[..., 0]), np.cos(noise[..., 0]))
    assert abs(np.degrees(np.mean(noise))) < 0.5
    assert 0.7 * rec.config.noise_deg < np.degrees(np.std(noise)) < 1.3 * rec.config.noise_deg
    # Correlated over a few frames (noise_corr_s = 0.1 s): lag-1 autocorrelation well above 0.
    x = noise[..., 0].reshape(-1, noise.shape[-2])
    lag1 = np.mean(x[:, 1:] * x[:, :-1]) / np.mean(x * x)
    assert 0.4 < lag1 < 0.95


# ---------------------------------------------------------------------------
# Conversation and attention statistics


@pytest.fixture(scope="module", params=["batch", "desk"])
def long_rec(request):
    return request.getfixturevalue(request.param)


def test_listener_looks_at_speaker(long_rec):
    look = np.asarray(long_rec.looking)
    partner = np.asarray(long_rec.partner_speaking)
    p_speaking = look[partner].mean()
    p_silent = look[~partner].mean()
    assert 0.50 <= p_speaking <= 0.64  # paper: 57%
    assert 4.0 <= p_speaking / p_silent <= 9.0  # paper: 5–8×


def test_speaking_fraction(long_rec):
    speaking = np.asarray(long_rec.speaking)
    fraction = speaking.mean(axis=-1)  # per person (and session)
    assert 0.40 <= fraction.mean() <= 0.50
    assert np.all(fraction > 0.15) and np.all(fraction < 0.8)
    both = (speaking[..., 0, :] & speaking[..., 1, :]).mean()
    neither = (~speaking[..., 0, :] & ~speaking[..., 1, :]).mean()
    assert 0.0 < both < 0.1
    assert 0.05 < neither < 0.25
    # Turns last a few seconds.
    s = speaking.reshape(-1, speaking.shape[-1]).astype(np.int8)
    starts = np.sum(np.diff(s, axis=-1) == 1)
    mean_turn = s.sum() / max(starts, 1) / FPS
    assert 2.5 < mean_turn < 7.0


def test_focus_is_piecewise_constant(rec):
    focus = np.asarray(rec.focus).reshape(-1, rec.num_frames)
    changes = np.diff(focus, axis=-1) != 0
    switches_per_s = changes.sum() / (focus.shape[0] * rec.num_frames / FPS)
    assert 0.2 < switches_per_s < 1.2
    # Run lengths: segments of ~0.5–3 s, shorter pieces only where a turn boundary cuts one.
    runs = []
    for row in focus:
        edges = np.flatnonzero(np.diff(row) != 0)
        runs.extend(np.diff(edges) / FPS)
    runs = np.asarray(runs)
    assert 1.0 < np.median(runs) < 3.5
    assert np.mean(runs < 0.3) < 0.15
    # The "elsewhere" direction is constant within a segment.
    points = np.asarray(rec.focus_points).reshape(-1, rec.num_frames, 3)
    eyes = np.asarray(rec.eye_positions).reshape(-1, rec.num_frames, 3)
    away = (focus[:, 1:] == FOCUS_ELSEWHERE) & ~changes
    step = np.linalg.norm(np.diff(points - eyes, axis=1), axis=-1)
    # (It moves only where one "elsewhere" segment follows another.)
    assert np.mean(step[away] > 1e-4) < 0.05


def test_head_turns_partially_toward_focus(rec):
    a = _np(rec)
    sight = _unit(a["focus_points"] - a["eye_positions"])
    head = a["R_world_from_head"][..., :, 0]
    head_err = _angle_deg(head, sight)
    eye_in_head = np.degrees(np.linalg.norm(a["true_gaze_angles"], axis=-1))
    far = a["focus"] > 0  # objects: large gaze shifts
    lo, hi = rec.config.head_fraction
    assert np.all((a["head_fraction"] >= lo) & (a["head_fraction"] <= hi))
    # The eyes make up a good part of large shifts, the head the rest.
    assert np.median(eye_in_head[far]) > 10.0
    assert np.median(head_err[far]) > 10.0
    # Looking at the partner, the head points roughly at them (the paper's 30° compatibility test).
    assert np.mean(head_err[a["looking"]] < 30.0) > 0.95


def test_interview_head_motion_smaller_than_desk(batch, desk):
    def head_spread(rec):
        forward = np.asarray(rec.R_world_from_head[..., :, 0])
        yaw = np.unwrap(np.arctan2(forward[..., 1], forward[..., 0]), axis=-1)
        pitch = np.arcsin(np.clip(forward[..., 2], -1, 1))
        return np.mean(np.std(yaw, axis=-1)), np.mean(np.std(pitch, axis=-1))

    yaw_i, pitch_i = head_spread(batch)
    yaw_d, pitch_d = head_spread(desk)
    assert yaw_i < yaw_d and pitch_i < pitch_d


# ---------------------------------------------------------------------------
# Argument validation


def test_bad_preset_name():
    with pytest.raises(ValueError, match="preset"):
        simulate_dyadic(jax.random.key(0), "meeting", duration_s=1.0)
    with pytest.raises(ValueError, match="preset"):
        simulate_dyadic(jax.random.key(0), 3, duration_s=1.0)
    with pytest.raises(ValueError, match="preset"):
        dyadic_config("Interview")
    with pytest.raises(ValueError, match="preset"):
        simulate_dyadic_sessions(jax.random.key(0), 2, "party", duration_s=1.0)


@pytest.mark.parametrize("duration_s", [0.0, -1.0, float("nan"), float("inf"), "long", None])
def test_bad_duration(duration_s):
    with pytest.raises(ValueError, match="duration_s"):
        simulate_dyadic(jax.random.key(0), duration_s=duration_s)


@pytest.mark.parametrize("fps", [0.0, -30.0, float("nan"), None])
def test_bad_fps(fps):
    with pytest.raises(ValueError, match="fps"):
        simulate_dyadic(jax.random.key(0), duration_s=1.0, fps=fps)


def test_too_few_frames():
    with pytest.raises(ValueError, match="at least 2 frames"):
        simulate_dyadic(jax.random.key(0), duration_s=0.01, fps=30.0)


@pytest.mark.parametrize(
    "key",
    [0, None, "key", np.zeros(3, np.float32), jax.random.split(jax.random.key(0), 2)],
    ids=["int", "none", "str", "float-array", "batch-of-keys"],
)
def test_bad_key(key):
    with pytest.raises(ValueError, match="key"):
        simulate_dyadic(key, duration_s=1.0)
    with pytest.raises(ValueError, match="key"):
        simulate_dyadic_sessions(key, 2, duration_s=1.0)


def test_raw_uint32_key_accepted():
    # Validation only (no run): the legacy PRNGKey format passes the key check.
    from jaxgaze._checks import check_key

    check_key(jax.random.PRNGKey(0))


@pytest.mark.parametrize("num_sessions", [0, -2, 2.0, True, "3"])
def test_bad_num_sessions(num_sessions):
    with pytest.raises(ValueError, match="num_sessions"):
        simulate_dyadic_sessions(jax.random.key(0), num_sessions, duration_s=1.0)


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(p_look_speaking=1.5), "p_look_speaking"),
        (dict(noise_deg=-1.0), "noise_deg"),
        (dict(bias_deg=(10.0, 5.0)), "bias_deg"),
        (dict(object_weights=(0.5, 0.4, 0.3)), "object_weights"),
        (dict(object_weights=(0.5, 0.4)), "object_weights"),
        (dict(noise_dof=2), "noise_dof"),
        (dict(turn_s=(0.3, 2.0)), "turn_s"),
        (dict(head_fraction=(0.5, 1.5)), "head_fraction"),
        (dict(preset="party"), "preset"),
    ],
)
def test_bad_config(change, match):
    config = dyadic_config("interview")._replace(**change)
    assert isinstance(config, DyadicConfig)
    with pytest.raises(ValueError, match=match):
        simulate_dyadic(jax.random.key(0), config, duration_s=1.0)
