"""``adapt_bias``: the speaker-prior bias adaptation as one call (Siegfried et al. 2017, Sec. 3–4).

On a simulated dyad (person 0 "ann" looks at "ben", 60 s at 10 fps) it must recover
the simulator's bias within its credible region (bayes) or a few degrees (lmeds),
label the frames where ann looks at ben, give what ``jaxgaze bias`` writes for the
same input (the CLI is read → adapt_bias → write), and reject bad input naming it.
"""

import csv
import json

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxgaze.bias import BiasAdaptation, BiasInputError, SpeechSegments, adapt_bias
from jaxgaze.bias.adapt import BIAS_FRAME_COLUMNS
from jaxgaze.cli import main
from jaxgaze.io.bias_report import bias_record
from jaxgaze.io.gaze import read_gaze_csv
from jaxgaze.results import succeeded
from jaxgaze.simulate.dyadic import simulate_dyadic

FPS = 10.0
SAMPLES = 500  # NUTS warm-up steps and draws: the default; at 200 the tail ESS was 94.9 on two machines (floor 100)


def _runs(flags):
    padded = np.concatenate([[False], np.asarray(flags, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[::2], edges[1::2]))


@pytest.fixture(scope="module")
def dyad(tmp_path_factory):
    rec = simulate_dyadic(jax.random.key(3), "interview", duration_s=60.0, fps=FPS)
    p = 0
    arrays = {
        "gaze_angles": np.asarray(rec.gaze_angles[p], float),
        "R_world_from_head": np.asarray(rec.R_world_from_head[p], float),
        "eye": np.asarray(rec.eye_positions[p], float),
        "target": np.asarray(rec.target_positions[p], float),
    }
    T = len(arrays["eye"])
    speaking = np.asarray(rec.speaking, bool)
    directory = tmp_path_factory.mktemp("adapt")
    q = Rotation.from_matrix(arrays["R_world_from_head"]).as_quat(scalar_first=True)
    gaze_csv = directory / "ann.csv"
    with open(gaze_csv, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["frame", "timestamp", "yaw", "tilt", "qw", "qx", "qy", "qz", "ex", "ey", "ez", "tx", "ty", "tz"])
        for t in range(T):
            writer.writerow([t, f"{t / FPS:.3f}", *map(repr, map(float, [*arrays["gaze_angles"][t], *q[t],
                                                                          *arrays["eye"][t], *arrays["target"][t]]))])
    starts, ends, names, lines = [], [], [], []
    for name, flags in zip(("ann", "ben"), speaking):
        for i, j in _runs(flags):
            starts.append(i / FPS)
            ends.append(j / FPS)
            names.append(name)
            lines.append(f"SPEAKER dyad 1 {i / FPS:.3f} {(j - i) / FPS:.3f} <NA> <NA> {name} <NA> <NA>")
    rttm = directory / "dyad.rttm"
    rttm.write_text("\n".join(lines) + "\n")
    return {
        **arrays, "times": np.arange(T) / FPS, "partner_speaking": speaking[1], "num_frames": T,
        "segments": SpeechSegments(np.array(starts), np.array(ends), tuple(names)),
        "bias": np.asarray(rec.bias[p], float), "looking": np.asarray(rec.looking[p], bool),
        "gaze_csv": gaze_csv, "rttm": rttm, "dir": directory,
    }


def _args(d):
    return [d[k] for k in ("gaze_angles", "R_world_from_head", "eye", "target", "times", "partner_speaking")]


def _cli_record(d, tmp_path, *options):
    out = tmp_path / "bias.json"
    assert main(["bias", str(d["gaze_csv"]), "--speech", str(d["rttm"]), "--partner", "ben", "--out", str(out), "-q",
                 *options]) == 0
    return json.loads(out.read_text())


def _record(d, result, seed=0):
    """The BIAS.json record of ``result`` with the inputs ``jaxgaze bias`` names for the dyad's files."""
    inputs = {"gaze": str(d["gaze_csv"]), "format": "csv", "frame_of_reference": "world", "speech": str(d["rttm"]),
              "targets": str(d["gaze_csv"]), "targets_from": "the gaze file's columns tx, ty, tz"}
    return bias_record(result, inputs=inputs, fps=FPS, seed=seed)


def _from_file(d, **kwargs):
    """adapt_bias on the arrays as the CLI reads them from the gaze CSV (quaternions → matrices)."""
    track = read_gaze_csv(d["gaze_csv"])
    return adapt_bias(track.gaze_angles, track.R_world_from_head, track.eye, track.target, track.time,
                      d["partner_speaking"], partner="ben", frames=track.frame, **kwargs)


def test_lmeds_recovers_the_bias_and_the_looking_frames(dyad):
    result = adapt_bias(*_args(dyad), method="lmeds", key=jax.random.key(0))
    assert isinstance(result, BiasAdaptation)
    assert np.degrees(np.linalg.norm(result.bias - dyad["bias"])) < 3.0, (result.bias, dyad["bias"])
    sel = result.selection
    assert sel.num_selected == len(sel.indices) == 40 < sel.num_candidates
    # The drawn frames are candidates: partner speaking, head within 30° of the target, first 60 s.
    assert np.all(result.partner_speaking[sel.indices]) and np.all(sel.candidates[sel.indices])
    assert np.all(result.head_target_angle[sel.indices] <= np.radians(30.0) + 1e-6)
    assert result.selected.sum() == 40 and result.estimate.inliers.sum() == 20
    # Eq. 1 with the estimated bias labels the frames better than without it.
    assert np.array_equal(result.looking, result.error < np.radians(10.0))
    accuracy = np.mean(result.looking == dyad["looking"])
    assert accuracy > 0.8 and accuracy > np.mean((result.error_uncorrected < np.radians(10.0)) == dyad["looking"])
    assert np.array_equal(result.probability, result.looking.astype(float))
    table = result.frame_table()
    assert tuple(table) == BIAS_FRAME_COLUMNS and all(len(v) == dyad["num_frames"] for v in table.values())


def test_bayes_credible_region_covers_the_true_bias_and_equals_the_cli(dyad, tmp_path):
    result = _from_file(dyad, method="bayes", key=jax.random.key(0), num_warmup=SAMPLES, num_samples=SAMPLES)
    est = result.estimate
    assert succeeded(est), est.sampler.diagnostics
    # The truth lies within the posterior's 3-sigma ellipse (Mahalanobis distance), and within 3°.
    diff = dyad["bias"] - result.bias
    assert float(diff @ np.linalg.solve(est.covariance, diff)) < 9.0, (result.bias, dyad["bias"], est.covariance)
    assert np.degrees(np.linalg.norm(diff)) < 3.0
    assert len(result.silent) > 0 and result.selection.num_selected == 60
    assert np.all((0 <= result.probability) & (result.probability <= 1))
    assert np.mean((result.probability > 0.5) == dyad["looking"]) > 0.8
    assert _record(dyad, result) == _cli_record(dyad, tmp_path, "--samples", str(SAMPLES))


@pytest.mark.parametrize("method, options", [("mean", ["--seed", "2"]), ("lmeds", ["--window", "30", "--frames", "25",
                                                                                   "--threshold-deg", "8"])])
def test_equals_what_the_cli_writes(dyad, tmp_path, method, options):
    kwargs = {"mean": dict(key=jax.random.key(2)),
              "lmeds": dict(window_s=30.0, num_frames=25, threshold_deg=8.0, key=jax.random.key(0))}[method]
    result = _from_file(dyad, method=method, **kwargs)
    seed = int(options[1]) if options[0] == "--seed" else 0
    assert _record(dyad, result, seed) == _cli_record(dyad, tmp_path, "--method", method, *options)


def test_speech_segments_give_the_flags_and_the_same_result(dyad):
    args = _args(dyad)
    from_flags = adapt_bias(*args, method="mean")
    from_segments = adapt_bias(*args[:5], dyad["segments"], partner="ben", method="mean")
    assert from_segments.partner == "ben" and from_flags.partner is None
    assert np.array_equal(from_segments.partner_speaking, dyad["partner_speaking"])
    np.testing.assert_array_equal(from_segments.bias, from_flags.bias)
    # A constant target (3,) is broadcast to every frame.
    constant = adapt_bias(*args[:3], args[3][0], *args[4:], method="mean")
    assert constant.target_dir_head.shape == (dyad["num_frames"], 3)


def _bad(d, **change):
    args = dict(zip(("gaze_angles", "R_world_from_head", "eye", "target", "times", "partner_speaking"), _args(d)))
    kwargs = {k: change.pop(k) for k in list(change) if k not in args}
    args.update(change)
    return list(args.values()), kwargs


def _nan_at(a, i):
    a = a.copy()
    a[i] = np.nan
    return a


BAD = {
    # name: (change(d) -> keyword changes, argument named, words in the message)
    "NaN gaze": (lambda d: dict(gaze_angles=_nan_at(d["gaze_angles"], 7)), "gaze_angles",
                 ["gaze_angles", "not finite", "frame index 7"]),
    "gaze shape": (lambda d: dict(gaze_angles=d["gaze_angles"][:, :1]), "gaze_angles", ["gaze_angles", "shape"]),
    "rotation frames": (lambda d: dict(R_world_from_head=d["R_world_from_head"][:-1]), "R_world_from_head",
                        ["R_world_from_head", "(600, 3, 3)"]),
    "inf eye": (lambda d: dict(eye=_nan_at(d["eye"], 3) * np.inf), "eye", ["eye", "not finite"]),
    "target at the eyes": (lambda d: dict(target=d["eye"]), "target", ["target is at the eyes", "frame 0"]),
    "times decrease": (lambda d: dict(times=d["times"][::-1]), "times", ["times must not decrease"]),
    "flags shape": (lambda d: dict(partner_speaking=d["partner_speaking"][:10]), "partner_speaking",
                    ["partner_speaking", "shape"]),
    "no selectable frames": (lambda d: dict(partner_speaking=np.zeros(d["num_frames"], bool)), "partner_speaking",
                             ["no selectable frames", "the partner speaks in 0 frames"]),
    # ben speaks only after the window; ann speaks inside it: the span given is ben's own.
    "partner speaks late": (lambda d: dict(partner_speaking=SpeechSegments(
        np.array([0.0, 10.0, 80.0]), np.array([5.0, 20.0, 95.5]), ("ann", "ann", "ben")), partner="ben"),
        "partner_speaking", ["partner 'ben' speaks in 0 frames (partner 'ben' speaks from 80 to 95.5 s)"]),
    "one speaking frame": (lambda d: dict(partner_speaking=np.arange(d["num_frames"]) == 3,
                                          target=d["target"] + [0.0, 0.0, 50.0]), "partner_speaking",
                           ["speaks in 1 frame, and in none of those is the head within 30 degrees"]),
    "too few for lmeds": (lambda d: dict(method="lmeds", num_frames=2), "num_frames", ["lmeds", "num_frames >= 3"]),
    "unknown method": (lambda d: dict(method="median"), "method", ["unknown method 'median'"]),
    "unknown partner": (lambda d: dict(partner_speaking=d["segments"], partner="cat"), "partner",
                        ["unknown partner speaker 'cat'", "'ann', 'ben'"]),
    "several speakers": (lambda d: dict(partner_speaking=d["segments"]), "partner", ["several speakers", "partner"]),
}


@pytest.mark.parametrize("name", list(BAD))
def test_rejects_bad_input(dyad, name):
    change, argument, words = BAD[name]
    args, kwargs = _bad(dyad, **change(dyad))
    with pytest.raises(BiasInputError) as info:
        adapt_bias(*args, **{"method": "mean", **kwargs})
    assert isinstance(info.value, ValueError) and info.value.argument == argument
    for word in words:
        assert word in str(info.value), (word, str(info.value))
    if name == "NaN gaze":
        assert info.value.index == 7
