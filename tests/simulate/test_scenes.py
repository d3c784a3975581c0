"""Simulated social scenes (jaxgaze.simulate): shapes, determinism, the cone model, stories."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.geometry import angle_between, perspective_distance
from jaxgaze.simulate import PRESETS, Scene, SceneConfig, scene_config, simulate_scene

EXPECTED = {  # preset: (people, foci)
    "mocap": (6, 2),
    "meeting": (11, 3),
    "party": (11, 4),
    "musical": (7, 2),
}


@pytest.fixture(scope="module")
def scenes():
    return {p: simulate_scene(jax.random.key(0), p) for p in PRESETS}


def _tangent_offsets(scene: Scene) -> np.ndarray:
    """Perspective distance d(l, target) of every ray from its true target, (T, N, 3)."""
    pd = jax.vmap(jax.vmap(perspective_distance))
    d, in_front = pd(scene.rays.origins, scene.rays.directions, scene.targets)
    assert bool(jnp.all(in_front)), "a target lies behind its viewer"
    return np.asarray(d)


def test_presets_listed():
    assert set(PRESETS) == set(EXPECTED)


@pytest.mark.parametrize("preset", PRESETS)
def test_shapes_and_types(scenes, preset):
    scene = scenes[preset]
    n, m = EXPECTED[preset]
    t = scene_config(preset).num_frames
    assert 60 <= t <= 150
    assert scene.rays.batch_shape == (t,) and scene.rays.num_rays == n
    assert scene.targets.shape == (t, n, 3)
    assert scene.attending.shape == (t, n) and jnp.issubdtype(scene.attending.dtype, jnp.integer)
    assert scene.focus.shape == (t, n)
    assert scene.concurrences.shape == (t, m, 3)
    assert scene.concurrence_valid.shape == (t, m) and scene.concurrence_valid.dtype == jnp.bool_
    assert scene.true_count.shape == (t,)
    assert scene.phase.shape == (t,)
    assert scene.name == preset and scene.fps > 0
    assert scene.num_frames == t and scene.num_people == n
    np.testing.assert_allclose(scene.rays.bandwidth, math.hypot(scene.eye_in_head, scene.head_noise), rtol=1e-6)
    for a in (scene.rays.origins, scene.rays.directions, scene.targets, scene.concurrences):
        assert np.all(np.isfinite(np.asarray(a)))


@pytest.mark.parametrize("preset", PRESETS)
def test_ground_truth_is_consistent(scenes, preset):
    scene = scenes[preset]
    focus, attending = np.asarray(scene.focus), np.asarray(scene.attending)
    valid = np.asarray(scene.concurrence_valid)
    m = valid.shape[1]
    counts = np.stack([(focus == k).sum(axis=1) for k in range(m)], axis=1)
    np.testing.assert_array_equal(valid, counts >= 2)
    shared = np.take_along_axis(valid, focus, axis=1)
    np.testing.assert_array_equal(attending, np.where(shared, focus, -1))
    np.testing.assert_allclose(
        np.asarray(scene.targets), np.take_along_axis(np.asarray(scene.concurrences), focus[..., None], axis=1)
    )
    # People look at something at a plausible range, never at their own eyes.
    dist = np.linalg.norm(np.asarray(scene.targets - scene.rays.origins), axis=-1)
    assert dist.min() > 0.5 and dist.max() < 15.0


def test_determinism_and_keys(scenes):
    again = simulate_scene(jax.random.key(0), "mocap")
    for a, b in zip(jax.tree_util.tree_leaves(scenes["mocap"]), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    other = simulate_scene(jax.random.key(1), "mocap")
    assert not np.allclose(np.asarray(other.rays.origins), np.asarray(again.rays.origins))
    assert not np.allclose(np.asarray(other.rays.directions), np.asarray(again.rays.directions))


def test_config_and_overrides():
    config = scene_config("mocap")
    assert isinstance(config, SceneConfig)
    assert (config.eye_in_head, config.head_noise) == (0.02, 0.01)
    scene = simulate_scene(jax.random.key(0), config._replace(head_noise=0.005), eye_in_head=0.01)
    assert (scene.eye_in_head, scene.head_noise) == (0.01, 0.005)
    np.testing.assert_allclose(scene.rays.bandwidth, math.hypot(0.01, 0.005), rtol=1e-6)
    short = simulate_scene(jax.random.key(0), "mocap", 7)
    assert short.targets.shape[0] == 7


@pytest.mark.parametrize(
    "eye, head",
    [(0.02, 0.0), (0.0, 0.015), (0.02, 0.01)],
    ids=["eye-in-head only", "head only", "both"],
)
def test_cone_spread(eye, head):
    """Mean squared tangent offset of the target from the primary ray is 2(h_e² + σ_h²).

    Under the cone model (Park et al. Sec. 3.1) ``d = (d1, d2)`` with
    ``d_i ~ N(0, h²)``, so ``‖d‖²/h² ~ χ²₂``: mean 2, variance 4. Pooling the
    presets gives ~4500 rays, standard error of the mean ≈ 0.03.
    """
    h2 = eye**2 + head**2
    d = np.concatenate(
        [_tangent_offsets(simulate_scene(jax.random.key(3), p, eye_in_head=eye, head_noise=head)).reshape(-1, 3)
         for p in PRESETS]
    )
    s = np.sum(d * d, axis=-1) / h2
    assert abs(s.mean() - 2.0) < 0.15
    assert abs(np.mean(s > -2 * np.log(0.1)) - 0.1) < 0.025  # χ²₂ tail: P(s > 2 ln 10) = 0.1
    # Direction of the offset is isotropic: no preferred side on the unit plane.
    assert np.linalg.norm(d.mean(axis=0)) / math.sqrt(h2) < 0.1


def test_angle_matches_offset(scenes):
    """The angle between primary ray and target direction is atan ‖d‖."""
    scene = scenes["meeting"]
    d = _tangent_offsets(scene)
    to_target = scene.targets - scene.rays.origins
    angle = np.asarray(angle_between(scene.rays.directions, to_target))
    np.testing.assert_allclose(angle, np.arctan(np.linalg.norm(d, axis=-1)), atol=1e-5)


def _phase_counts(scene: Scene, margin: int) -> list[np.ndarray]:
    """True counts per nominal phase, dropping ``margin`` frames around each boundary."""
    phase, count = np.asarray(scene.phase), np.asarray(scene.true_count)
    boundaries = np.flatnonzero(np.diff(phase)) + 1
    frames = np.arange(len(phase))
    near = np.zeros(len(phase), bool)
    for b in boundaries:
        near |= np.abs(frames - b) <= margin
    return [count[(phase == k) & ~near] for k in range(phase.max() + 1)]


def test_meeting_story(scenes):
    scene = scenes["meeting"]
    per_phase = _phase_counts(scene, margin=4)
    assert [set(c.tolist()) for c in per_phase] == [{2}, {1}, {2}]
    t = scene.num_frames
    np.testing.assert_array_equal(np.bincount(np.asarray(scene.phase)), [t // 3, t // 3, t - 2 * (t // 3)])
    # Phase 1: everyone looks at the presenter (focus 2).
    mid = np.asarray(scene.phase) == 1
    assert np.mean(np.asarray(scene.attending)[mid] == 2) > 0.95
    # Groups of 6 and 5 in the outer phases.
    first = np.asarray(scene.attending)[0]
    assert sorted(np.bincount(first[first >= 0]).tolist()) == [5, 6]


def test_party_story(scenes):
    scene = scenes["party"]
    per_phase = _phase_counts(scene, margin=4)
    assert [set(c.tolist()) for c in per_phase] == [{4}, {1}]
    first = np.asarray(scene.attending)[0]
    assert sorted(np.bincount(first).tolist()) == [2, 3, 3, 3]
    assert np.all(np.asarray(scene.attending)[-1] == 2)  # everyone on the table tennis ball
    # The spectators walked over: at the end everyone is within 5 m of the ball.
    dist = np.linalg.norm(np.asarray(scene.targets - scene.rays.origins)[-1], axis=-1)
    assert dist.max() < 5.0


def test_mocap_story(scenes):
    scene = scenes["mocap"]
    np.testing.assert_array_equal(np.asarray(scene.true_count), 2)
    # Static markers inside the 8.3 × 17.7 × 4.3 m volume, people too.
    markers = np.asarray(scene.concurrences)
    np.testing.assert_array_equal(markers, np.broadcast_to(markers[0], markers.shape))
    half = np.array([8.3, 17.7]) / 2
    for pts in (markers, np.asarray(scene.rays.origins)):
        assert np.all(np.abs(pts[..., :2]) <= half) and np.all((pts[..., 2] > 0) & (pts[..., 2] < 4.3))
    # Each person mostly looks at their home marker from 2-6 m.
    focus = np.asarray(scene.focus)
    home = np.array([0, 0, 0, 1, 1, 1])
    assert 0.0 < np.mean(focus != home) < 0.1
    dist = np.linalg.norm(np.asarray(scene.targets - scene.rays.origins), axis=-1)[focus == home]
    assert dist.min() > 1.9 and dist.max() < 6.0
    # People move.
    path = np.linalg.norm(np.diff(np.asarray(scene.rays.origins), axis=0), axis=-1).sum(axis=0)
    assert np.all(path > 1.0)


def test_musical_rays_near_parallel(scenes):
    """Audience rays to the stage span a narrow fan, unlike the meeting's converging circles."""

    def max_fan(scene):
        v, focus = np.asarray(scene.rays.directions), np.asarray(scene.focus)
        worst = np.zeros(scene.num_frames)
        for i, j in itertools.combinations(range(scene.num_people), 2):
            same = focus[:, i] == focus[:, j]
            ang = np.arccos(np.clip(np.sum(v[:, i] * v[:, j], axis=-1), -1, 1))
            worst = np.maximum(worst, np.where(same, ang, 0.0))
        return worst

    musical = scenes["musical"]
    assert np.all(max_fan(musical) < 0.45)  # rad (≈ 26°)
    assert np.median(max_fan(scenes["meeting"])) > 2.0
    dist = np.linalg.norm(np.asarray(musical.targets - musical.rays.origins), axis=-1)
    assert dist.min() > 8.0 and dist.max() < 12.5
    # Attention alternates between the two groups of actors, in quarters.
    per_phase = _phase_counts(musical, margin=4)
    assert [set(c.tolist()) for c in per_phase] == [{1}] * 4
    att = np.asarray(musical.attending)
    phase = np.asarray(musical.phase)
    for k in range(4):
        assert np.mean(att[phase == k] == k % 2) > 0.9


def test_bad_arguments():
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="unknown scene preset 'cocktail'.*mocap"):
        simulate_scene(key, "cocktail")
    with pytest.raises(ValueError, match="num_frames"):
        simulate_scene(key, "mocap", 0)
    with pytest.raises(ValueError, match="num_frames"):
        simulate_scene(key, "mocap", 2.5)
    with pytest.raises(ValueError, match="eye_in_head"):
        simulate_scene(key, "mocap", eye_in_head=-0.1)
    with pytest.raises(ValueError, match="head_noise"):
        simulate_scene(key, "mocap", head_noise=float("nan"))
    with pytest.raises(ValueError, match="both 0"):
        simulate_scene(key, "mocap", eye_in_head=0.0, head_noise=0.0)
    with pytest.raises(ValueError, match="SceneConfig.preset"):
        simulate_scene(key, SceneConfig("cocktail", 10, 0.02, 0.01))
    with pytest.raises(ValueError, match="preset must be"):
        simulate_scene(key, 3)
    with pytest.raises(ValueError, match="jax.random key"):
        simulate_scene(0, "mocap")
    with pytest.raises(ValueError, match="fps"):
        simulate_scene(key, scene_config("mocap")._replace(fps=0.0))
