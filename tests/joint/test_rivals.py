"""Rival explanations of a person's gaze (issue 37): found before sampling, left when wrong, reported when the data
cannot decide."""

from __future__ import annotations

import csv
import json
import math

import arviz as az
import jax
import numpy as np
import pytest

from jaxgaze.bias.looking import direction_to_gaze_angles
from jaxgaze.geometry import head_pose_to_rotation
from jaxgaze.io.joint import write_joint_frames, write_joint_netcdf
from jaxgaze.joint import JointPrior, fit_joint, joint_data, joint_start
from jaxgaze.joint.infer import _arrays as model_arrays, _mixture, _refine_start, _search_modes, _start_values, _to_mode, _unconstrained
from jaxgaze.joint import infer, rivals
from jaxgaze.joint.rivals import bias_profile, profile_rivals, scan_offsets
from jaxgaze.results import RESULTS, FitError
from jaxgaze.simulate import simulate_conversation
from jaxgaze.simulate.rivals import RIVAL_CONFIG, rival_bias


def _degrees(a, b):
    return float(np.degrees(np.linalg.norm(np.asarray(a) - np.asarray(b))))


# -- a scene the data cannot decide ------------------------------------------------------------------------


def _circle(key, num_frames=300, width_deg=2.0):
    """Six people evenly on a circle, heads to the centre, who look at one another in turn, except ann (0): her
    measured gaze always points exactly between dan (3, straight across) and cal (2), 15° to either side, so a bias
    of ±15° explains it as looks at one or the other equally well."""
    angles = np.radians(90.0 + 60.0 * np.arange(6))
    eyes = np.stack([1.2 * np.cos(angles), 1.2 * np.sin(angles), np.full(6, 1.2)], axis=-1)
    R = np.asarray(head_pose_to_rotation(angles + np.pi, np.zeros(6), np.zeros(6)))  # +x to the centre
    rng = np.random.default_rng(int(jax.random.randint(key, (), 0, 2**31 - 1)))

    def towards(i, point):
        return np.asarray(direction_to_gaze_angles(R[i].T @ ((point - eyes[i]) / np.linalg.norm(point - eyes[i]))))

    gaze = np.zeros((num_frames, 6, 2))
    for t in range(num_frames):
        gaze[t, 0] = towards(0, 0.5 * (eyes[2] + eyes[3]))
        for i in range(1, 6):
            gaze[t, i] = towards(i, eyes[(i + 1 + (t // 20 + i) % 5) % 6])  # the five others in turn
    gaze = gaze + np.radians(width_deg) * rng.standard_normal(gaze.shape)
    return joint_data(np.broadcast_to(eyes, (num_frames, 6, 3)), np.broadcast_to(R, (num_frames, 6, 3, 3)), gaze,
                      people=["ann", "ben", "cal", "dan", "eve", "fay"], fps=10.0)


@pytest.fixture(scope="module")
def undecided():
    data = _circle(jax.random.key(3))
    return data, fit_joint(data, key=jax.random.key(4), num_warmup=150, num_samples=150)


def test_the_profile_has_both_explanations_of_the_undecided_person():
    data = _circle(jax.random.key(3))
    start = joint_start(data, key=jax.random.key(0))
    offsets, n = scan_offsets()
    params = {"bias": np.asarray(start.bias, np.float32), "cone_width": np.full(6, 0.05, np.float32),
              "alpha_person": np.float32(0.0), "speaker_effect": np.float32(0.0), "stay": np.float32(0.5),
              "alpha_object": np.float32(0.0), "locations": np.zeros((data.num_windows, 0, 3), np.float32)}
    arrays = model_arrays(data, start.concurrence_centres, np.float32)
    profile = np.asarray(bias_profile(params, arrays, JointPrior(), offsets))
    found = profile_rivals(profile, offsets, n, np.array([True] + [False] * 5))
    # From a bias of 0 (between the two), both are rivals, at ±15° in yaw (and the next two at ±45°).
    yaws = sorted(math.degrees(start.bias[0, 0] + delta[0]) for person, delta, _ in found)
    assert all(person == 0 for person, _, _ in found)
    assert [y for y in yaws if abs(y) < 30] == [pytest.approx(-15.0, abs=2.0), pytest.approx(15.0, abs=2.0)]


def test_a_recording_that_cannot_decide_is_ambiguous_with_both_explanations(undecided):
    data, post = undecided
    assert post.result == RESULTS.ambiguous
    (alternative,) = post.alternatives
    assert alternative.person == 0 and 0.2 < alternative.weight < 0.8
    # the two explanations: ann looks at cal, or at dan, 30° apart as ann sees them
    chosen = np.asarray(post.modes.start["bias"][0])
    assert _degrees(alternative.bias, chosen) == pytest.approx(30.0, abs=3.0)
    assert {int(np.argmax(alternative.membership.mean(0))), int(np.argmax(post.membership[:, 0].mean(0)))} == {2, 3}
    # Both modes are sampled: ann's draws sit at one or the other in proportion to the weight, and her 90%
    # interval spans both (never a narrow interval around one of two equal answers).
    yaw = post.samples["bias"][:, 0, 0]
    near_alternative = np.abs(yaw - alternative.bias[0]) < np.abs(yaw - chosen[0])
    assert near_alternative.mean() == pytest.approx(alternative.weight, abs=0.02)
    assert np.all(np.abs(yaw - np.where(near_alternative, alternative.bias[0], chosen[0])) < math.radians(3.0))
    low, high = post.interval("bias")[0, 0]
    assert low < min(chosen[0], alternative.bias[0]) + math.radians(2) and high > max(chosen[0], alternative.bias[0]) - math.radians(2)
    assert "ann's bias is" in post.message and "weight" in post.message
    with pytest.raises(FitError) as raised:
        fit_joint(data, key=jax.random.key(4), num_warmup=150, num_samples=150, throw=True)
    assert raised.value.result == RESULTS.ambiguous and raised.value.fit.alternatives


def test_the_mixture_takes_each_mode_in_proportion_to_its_weight():
    runs = [({"bias": np.full((2, 10, 3), float(m))}, {"diverging": np.full((2, 10), m)}) for m in range(3)]
    draws, stats = _mixture(runs, np.array([0.52, 0.31, 0.17]), 10)
    assert draws["bias"].shape == (2, 10, 3) and stats["diverging"].shape == (2, 10)
    for chain in range(2):  # round(5.2, 3.1, 1.7) = (5, 3, 2), in every chain, draws and stats alike
        assert np.bincount(draws["bias"][chain, :, 0].astype(int)).tolist() == [5, 3, 2]
        assert np.bincount(stats["diverging"][chain]).tolist() == [5, 3, 2]
    assert _mixture(runs[:1], np.array([1.0]), 10) is runs[0]


def test_the_per_frame_table_and_netcdf_hold_the_alternatives(undecided, tmp_path):
    data, post = undecided
    frames = np.arange(data.num_frames)
    write_joint_frames(tmp_path / "frames.csv", post, frames, frames / data.fps)
    with open(tmp_path / "frames.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    ann = [r for r in rows if r["person"] == "ann"]
    ben = [r for r in rows if r["person"] == "ben"]
    assert {r["alternative_target"] for r in ann} <= {"cal", "dan"} and all(r["alternative_target"] for r in ann)
    assert {r["alternative_target"] for r in ann} != {r["target"] for r in ann}
    assert float(ann[0]["alternative_weight"]) == pytest.approx(post.alternatives[0].weight, abs=1e-6)
    assert all(r["alternative_target"] == "" for r in ben)
    write_joint_netcdf(tmp_path / "post.nc", post)
    attrs = az.from_netcdf(tmp_path / "post.nc").posterior.attrs
    assert attrs["result"] == "ambiguous"
    (stored,) = json.loads(attrs["alternatives"])
    assert stored["person"] == "ann" and stored["weight"] == pytest.approx(post.alternatives[0].weight, abs=1e-5)


# -- a start in the rival mode -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rival_scene():
    return simulate_conversation(jax.random.key(11), num_people=6, duration_s=40.0, config=RIVAL_CONFIG)


def test_the_rival_of_a_frequent_object_is_a_neighbour_20_to_40_degrees_away(rival_scene):
    P = rival_scene.num_people
    looks = [(int(np.sum(rival_scene.present[:, i] & (rival_scene.target[:, i] >= P))), i) for i in range(P)]
    frames, person = max(looks)
    rival = rival_bias(rival_scene, person)
    assert rival.neighbour != person and rival.object_frames == frames > 50
    assert 15.0 <= rival.shift_deg <= 45.0
    assert _degrees(rival.bias, rival_scene.bias[person]) == pytest.approx(rival.shift_deg, rel=1e-6)
    with pytest.raises(ValueError, match="person must lie"):
        rival_bias(rival_scene, P)


def _rival_fit(scene, monkeypatch=None):
    """SVI from the pipeline's start with the most frequent object-looker's bias in its rival mode."""
    P = scene.num_people
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    person = max(range(P), key=lambda i: int(np.sum(scene.present[:, i] & (scene.target[:, i] >= P))))
    start = joint_start(data, key=jax.random.key(1))
    bias = start.bias.copy()
    bias[person] = rival_bias(scene, person).bias
    return fit_joint(data, key=jax.random.key(2), method="svi", num_steps=300, num_samples=150,
                     start=start._replace(bias=bias))


def test_wrong_modes_are_found_and_left(rival_scene):
    post = _rival_fit(rival_scene)
    errors = [_degrees(post.bias[i], rival_scene.bias[i]) for i in range(rival_scene.num_people)]
    assert max(errors) < 2.0
    # Person 3's start (Spk-LMedS) is 27° off and its descent settles in a wrong mode; the search moves it back.
    assert 3 in post.modes.moved and post.modes.rivals_tried >= 1
    # The pipeline found the one table object three times (0.15-0.3 m apart); the twin rule drops one, the
    # evidence the other (two slots on one target split its gazes: NUTS took 140 steps a draw, ESS 10 in 100).
    assert post.num_concurrences == 1 and post.start.num_concurrences == 1
    assert not post.predictive_check["flagged"].any() and not post.alternatives


def test_the_predictive_check_flags_a_person_left_in_a_wrong_mode(rival_scene, monkeypatch):
    """No rival refined (the fit before issue 37): person 3, whose start (Spk-LMedS) is 27° off, settles in a wrong
    mode 36° off, and person 5, planted 60° off in yaw, 32° off; they send 68% and 43% of their gaze elsewhere against
    the fifth the model predicts. (The 90°-off mode at the pole that this test used before was the missing area element
    of the angles: :func:`~jaxgaze.joint.model.measured_gaze_log_jacobian`.)"""
    monkeypatch.setattr(rivals, "PROFILE_MARGIN", -np.inf)
    scene = rival_scene
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    start = joint_start(data, key=jax.random.key(1))
    bias = start.bias.copy()
    bias[5] = scene.bias[5] + np.radians([60.0, 0.0])
    post = fit_joint(data, key=jax.random.key(2), method="svi", num_steps=300, num_samples=150,
                     start=start._replace(bias=bias))
    errors = np.array([_degrees(post.bias[i], scene.bias[i]) for i in range(scene.num_people)])
    assert np.all(errors[[3, 5]] > 20.0) and np.all(errors[[0, 1, 2, 4]] < 2.0) and post.modes.rivals_tried == 0
    # The old residual check saw nothing (no gaze left to compare); the others are not flagged.
    check = post.predictive_check
    assert check["flagged"].tolist() == [False, False, False, True, False, True]
    assert post.result == RESULTS.misfit  # whatever the sampler says, the fit is not a success
    assert np.all(check["elsewhere_observed"][[3, 5]] > 0.3) and np.all(check["elsewhere_predicted"][[3, 5]] < 0.3)
    assert np.all(check["elsewhere_observed"][[0, 1, 2, 4]] < 0.1)


def test_a_mode_beyond_the_scans_reach_is_scanned_from_the_priors_centre(rival_scene):
    """A person's bias planted 90° from the truth and settled in the mode there (93° off, 87° from 0): the scan around
    it (40°) finds nothing better, so the search stayed there. For a bias beyond the scan's radius from 0 it now
    scans around bias 0 as well, finds the truth and moves the person back."""
    scene = rival_scene
    data = joint_data(scene.eye_positions, scene.R_world_from_head, scene.gaze_angles, present=scene.present,
                      speaking=scene.speaking, measurement_scale=scene.measurement_scale, fps=scene.fps)
    start = joint_start(data, key=jax.random.key(1))
    arrays = model_arrays(data, start.concurrence_centres, np.float32)
    plain = JointPrior(held_scale=None)  # the search is the same with a spot; this scene has none
    values = {k: jax.numpy.asarray(v, np.float32) for k, v in
              _unconstrained(_start_values(start, plain, data.num_people)).items()}
    values = _refine_start(values, arrays, plain, True)
    person = 2
    planted = values["bias"].at[person].set(np.asarray(scene.bias[person]) + np.radians([90.0, 0.0]))
    settled = _to_mode({**values, "bias": planted}, arrays, plain)
    assert _degrees(settled["bias"][person], scene.bias[person]) > 80.0
    search, _ = _search_modes(settled, arrays, plain, (), False)
    assert person in search.moved
    assert _degrees(search.start["bias"][person], scene.bias[person]) < 2.0


def test_a_better_point_of_a_mode_already_found_replaces_it(monkeypatch):
    """Two rivals of ann's wrong bias (+15°) refine into the right basin (−15°): the first stops short of its mode
    with less evidence than the wrong one, the second reaches it. The second is the same mode (within 5°), so it was
    dropped as known and the search stayed in the wrong mode (adversarial scene 0: a bias 94° off); the higher
    point of a basin now replaces the lower, and wins."""
    data = _circle(jax.random.key(3))
    start = joint_start(data, key=jax.random.key(0))
    arrays = model_arrays(data, start.concurrence_centres, np.float32)
    prior = JointPrior(held_scale=None)
    values = {k: jax.numpy.asarray(v, np.float32) for k, v in _unconstrained(_start_values(start, prior, 6)).items()}
    wrong = {**values, "bias": values["bias"].at[0].set(np.radians([15.0, 0.0]).astype(np.float32))}
    ends = iter([-14.5, -15.0, -15.0, -15.0])  # the refinements' yaw for ann, in turn (degrees)
    evidence = {15.0: 100.0, -14.5: 90.0, -15.0: 120.0}

    def refine(trial, arrays, prior, to_mode, inverse=None):
        return {**trial, "bias": trial["bias"].at[0].set(np.radians([next(ends), 0.0]).astype(np.float32))}

    def laplace(values, arrays, prior):
        yaw = round(float(np.degrees(values["bias"][0, 0])), 1)
        return evidence[yaw], np.eye(2 * 6)

    offsets = np.radians([[-30.0, 0.0], [-26.0, 0.0]])
    monkeypatch.setattr(rivals, "bias_profile", lambda params, arrays, prior, offsets: np.zeros((2, 6)))
    monkeypatch.setattr(rivals, "profile_rivals", lambda *a, **k: [(0, offsets[0], 0.0), (0, offsets[1], 0.0)])
    monkeypatch.setattr(infer, "_refine_start", refine)
    monkeypatch.setattr(infer, "_laplace_evidence", laplace)
    search, _ = _search_modes(wrong, arrays, prior, (), False, (100.0, np.eye(12)))
    assert search.rivals_tried >= 2
    assert float(np.degrees(search.start["bias"][0, 0])) == pytest.approx(-15.0, abs=1e-3)
    assert search.moved == (0,) and search.log_evidence == 120.0 and not search.alternatives
