"""The evaluation of speaker-prior bias adaptation (Siegfried et al. 2017, Table 1) on the simulator.

One module-scoped evaluation (2 presets × 12 sessions × 2 people = 48 people, 90 s
each, NUTS 200 + 200 per person) feeds the paper's must-shows; the metric functions
are checked on tiny hand-made cases.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgaze.bias.estimators import estimate_bias
from jaxgaze.papers.siegfried2017 import (
    METHODS,
    BiasEvaluation,
    accuracy_by_threshold,
    chi2_2dof_quantile,
    classification_accuracy,
    credible_region_covers,
    error_by_time_deg,
    evaluate_bias_methods,
    format_figure_tables,
    format_table1,
    mean_angular_error_deg,
    random_frames,
    thinned_frames,
)
from tests import helpers as zoo

SESSIONS = 12
DURATION_S = 90.0


@pytest.fixture(scope="module")
def evaluation() -> BiasEvaluation:
    interview, desk, k_eval = zoo.bias_evaluation_dyads(SESSIONS, DURATION_S)
    recordings = [interview, desk]
    ev = evaluate_bias_methods(recordings, k_eval, num_warmup=200, num_samples=200, time_bin_s=10.0)
    print()
    print(format_table1(ev))
    return ev


def overall(ev, field="error_deg"):
    agg = ev.aggregate()["overall"][field]
    return {m: float(agg[i]) for i, m in enumerate(ev.methods)}


# ----------------------------------------------------------------------- structure


def test_structure(evaluation):
    ev = evaluation
    n, M = 4 * SESSIONS, len(METHODS)
    assert ev.methods == METHODS and ev.num_people == n
    assert ev.bias.shape == (n, M, 2) and ev.error_deg.shape == (n, M) and ev.accuracy.shape == (n, M)
    assert ev.scenarios == ["interview", "desk"]
    assert ev.bias_draws.shape == (n, 200, 2)
    np.testing.assert_array_equal(ev.bias[:, 0], 0.0)  # Baseline: no correction
    assert np.isfinite(ev.error_deg).all() and np.isfinite(ev.accuracy).all()
    assert ((ev.accuracy >= 0) & (ev.accuracy <= 1)).all()
    # Bayes frames: thinned Spk candidates, 40 or more for most people, never above 64.
    assert ev.num_bayes_frames.max() <= 64 and np.median(ev.num_bayes_frames) >= 40
    assert (ev.num_candidates >= ev.num_bayes_frames).all()
    # Fig. 5: 10 s bins from 60 s to 90 s; Fig. 6: τ = 2 … 20°.
    np.testing.assert_allclose(ev.time_bin_edges_s, [60, 70, 80, 90])
    assert ev.error_by_time_deg.shape == (n, M, 3)
    assert ev.accuracy_by_threshold.shape == (n, M, 19)
    # τ = 10° column of Fig. 6 is the Table 1 accuracy.
    j = int(np.flatnonzero(ev.thresholds_deg == 10)[0])
    np.testing.assert_allclose(ev.accuracy_by_threshold[..., j], ev.accuracy, atol=1e-6)
    # The Fig. 5 bins partition the evaluated frames: their frame-weighted mean is the Table 1 error
    # (checked loosely through the unweighted mean, the bins being of equal length).
    np.testing.assert_allclose(np.nanmean(ev.error_by_time_deg, axis=-1), ev.error_deg, rtol=0.15)
    agg = ev.aggregate()
    assert set(agg) == {"interview", "desk", "overall"} and agg["overall"]["people"] == n
    text = format_table1(ev) + format_figure_tables(ev)
    for label in ("Baseline", "Spk-Mean", "Spk-Med", "GT-Mean", "GT-Med", "Bayes (ours)", "23.62", "Fig. 5", "Fig. 6"):
        assert label in text


# ----------------------------------------------------------------------- must-shows


def test_paper_ordering(evaluation):
    """Table 1: Baseline worst, then the Spk methods, the GT oracles best (overall mean error)."""
    e = overall(evaluation)
    print({k: round(v, 2) for k, v in e.items()})
    assert max(e["gt_mean"], e["gt_med"]) <= min(e["spk_mean"], e["spk_med"])
    assert max(e["spk_mean"], e["spk_med"]) <= e["baseline"]
    # LMedS is what makes the speaker prior usable (Sec. 4.2): well below Spk-Mean.
    assert e["spk_med"] < e["spk_mean"] - 1.0
    a = overall(evaluation, "accuracy")
    assert a["gt_mean"] > a["spk_med"] > a["baseline"]


def test_bayes_beats_spk_med(evaluation):
    e = overall(evaluation)
    assert e["bayes"] < e["spk_med"]


def test_bayes_within_half_a_degree_of_gt_mean(evaluation):
    e = overall(evaluation)
    print(f"Bayes {e['bayes']:.2f}°, GT-Mean {e['gt_mean']:.2f}°")
    assert abs(e["bayes"] - e["gt_mean"]) <= 0.5


def test_bayes_close_to_gt_mean_where_the_speaker_prior_holds(evaluation):
    """On people whose Spk candidates mostly look at the partner (the paper's premise), Bayes ≈ GT-Mean."""
    ev = evaluation
    ok = ev.spk_precision >= 0.5
    assert ok.mean() > 0.8
    err = np.nanmean(ev.error_deg[ok], axis=0)
    i = {m: k for k, m in enumerate(ev.methods)}
    assert abs(err[i["bayes"]] - err[i["gt_mean"]]) <= 0.5
    assert err[i["bayes"]] < err[i["spk_med"]]


def test_bayes_credible_region_coverage(evaluation):
    """The 90% credible region of b covers the true bias for 80–98% of the 48 people."""
    covered = evaluation.covered
    assert np.isfinite(covered).all()
    rate = covered.mean()
    print(f"coverage {rate:.3f} of {covered.size}")
    assert 0.80 <= rate <= 0.98


def test_bayes_probability_decision(evaluation):
    """Deciding by P(e < τ) > 0.5 over the posterior is as good as the posterior-mean decision."""
    ev = evaluation
    bayes = ev.accuracy[:, ev.method_index("bayes")]
    assert abs(np.nanmean(ev.bayes_prob_accuracy) - np.nanmean(bayes)) < 0.02
    assert np.nanmean(ev.bayes_prob_accuracy) > overall(ev, "accuracy")["spk_med"] - 0.01


def test_reproducible_and_single_recording():
    rec = zoo.dyad("desk", 70.0)
    a = evaluate_bias_methods(rec, jax.random.key(4), num_warmup=50, num_samples=50, time_bin_s=5.0)
    b = evaluate_bias_methods(rec, jax.random.key(4), num_warmup=50, num_samples=50, time_bin_s=5.0)
    assert a.num_people == 2 and a.scenarios == ["desk"]
    np.testing.assert_array_equal(a.bias, b.bias)
    np.testing.assert_array_equal(a.error_deg, b.error_deg)
    with pytest.raises(ValueError, match="no frame after"):
        evaluate_bias_methods(rec, jax.random.key(4), window_s=80.0)


# ------------------------------------------------------------------ hand-made cases


def test_mean_angular_error_and_accuracy_by_hand():
    error = np.radians([[1.0, 2.0, 3.0, 4.0, 20.0]])
    looking = np.array([[True, False, True, True, False]])
    frames = np.array([[False, True, True, True, True]])
    # Looking and evaluated: frames 2 and 3 → (3 + 4) / 2.
    np.testing.assert_allclose(mean_angular_error_deg(error, looking, frames), [3.5], rtol=1e-6)
    # τ = 3.5°: predicted [T, T, T, F, F] vs truth on frames 1–4: F≠T, T=T, F≠T, F=F → 2 of 4.
    predicted = error < np.radians(3.5)
    np.testing.assert_allclose(classification_accuracy(predicted, looking, frames), [0.5])
    # No looking frame evaluated → NaN (left out of the means).
    assert np.isnan(mean_angular_error_deg(error, looking, np.array([[False, True, False, False, True]])))[0]
    # Fig. 6, truth on frames 1–4 = [F, T, T, F] (errors 2°, 3°, 4°, 20°):
    # τ = 2.5: [T, F, F, F] → 1 right (frame 4); τ = 3.5: [T, T, F, F] → 2; τ = 5: [T, T, T, F] → 3.
    np.testing.assert_allclose(accuracy_by_threshold(error, looking, frames, [2.5, 3.5, 5.0]), [[0.25, 0.5, 0.75]])


def test_error_by_time_by_hand():
    error = np.radians([5.0, 7.0, 1.0, 3.0, 9.0, 11.0])
    looking = np.array([True, True, True, False, True, False])
    times = np.arange(6) * 10.0  # 0, 10, …, 50 s
    out = error_by_time_deg(error, looking, times, np.array([0.0, 20.0, 40.0, 60.0]))
    # Bins [0, 20): frames 0, 1 → 6; [20, 40): frame 2 → 1 (frame 3 not looking); [40, 60): frame 4 → 9.
    np.testing.assert_allclose(out, [6.0, 1.0, 9.0], rtol=1e-6)


def test_credible_region_by_hand():
    # Draws (±1, 0), (0, ±1): mean 0, covariance (2/3) I (ddof 1).
    draws = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    covered, m2 = credible_region_covers(np.stack([draws, draws]), np.array([[1.0, 1.0], [2.0, 0.0]]))
    np.testing.assert_allclose(m2, [3.0, 6.0])  # (1 + 1) · 3/2 and 4 · 3/2
    np.testing.assert_array_equal(covered, [True, False])  # against χ²₂(0.9) = 4.605
    assert math.isclose(chi2_2dof_quantile(0.9), 4.60517, rel_tol=1e-5)
    assert math.isclose(chi2_2dof_quantile(0.5), 2 * math.log(2), rel_tol=1e-12)


def test_random_frames_draws_allowed_frames_without_replacement():
    allowed = jnp.array([[True, False, True, True, False, True], [False, True, False, False, False, False]])
    idx, valid = random_frames(jax.random.key(0), allowed, 3)
    idx, valid = np.asarray(idx), np.asarray(valid)
    assert valid[0].all() and len(set(idx[0])) == 3 and allowed[0][idx[0]].all()
    np.testing.assert_array_equal(valid[1], [True, False, False])
    assert idx[1, 0] == 1
    # Uniform: each of the 4 allowed frames of row 0 is drawn 3/4 of the time.
    counts = np.zeros(6)
    for k in jax.random.split(jax.random.key(1), 400):
        counts[np.asarray(random_frames(k, allowed[:1], 3)[0][0])] += 1
    np.testing.assert_allclose(counts[[0, 2, 3, 5]] / 400, 0.75, atol=0.08)
    assert counts[[1, 4]].sum() == 0


def test_thinned_frames_by_hand():
    allowed = jnp.array([[True] * 12 + [False] * 4 + [True] * 4])  # 16 allowed frames
    idx, valid = thinned_frames(jax.random.key(0), allowed, min_stride=5, max_frames=8)
    kept = np.asarray(idx[0])[np.asarray(valid[0])]
    ranks = np.flatnonzero(np.asarray(allowed[0]))
    position = np.searchsorted(ranks, kept)
    assert np.all(np.diff(position) == 5) and len(kept) in (3, 4)  # every 5th allowed frame
    assert np.all(np.diff(kept) >= 5)
    # A cap below count / stride raises the stride: 16 frames, at most 2 → every 8th.
    idx, valid = thinned_frames(jax.random.key(0), allowed, min_stride=1, max_frames=2)
    assert np.asarray(valid).sum() == 2
    kept = np.asarray(idx[0])[np.asarray(valid[0])]
    assert np.diff(np.searchsorted(ranks, kept))[0] == 8


def test_lmeds_and_mean_rows_match_estimate_bias():
    """The vectorised Spk/GT estimators equal estimate_bias on the same frames."""
    from jaxgaze.papers.siegfried2017 import _lmeds_or_zero, _mean_or_zero

    o = np.asarray(jax.random.normal(jax.random.key(5), (2, 40, 2))) * 0.05
    o[1, 25:] += 0.5  # outliers
    valid = np.ones((2, 40), bool)
    valid[1, 35:] = False
    med = np.asarray(_lmeds_or_zero(jnp.asarray(o), jnp.asarray(valid)))
    mean = np.asarray(_mean_or_zero(jnp.asarray(o), jnp.asarray(valid)))
    for p in range(2):
        rows = o[p][valid[p]]
        np.testing.assert_allclose(med[p], estimate_bias(rows, "lmeds").bias, atol=1e-6)
        np.testing.assert_allclose(mean[p], estimate_bias(rows, "mean").bias, atol=1e-6)
    np.testing.assert_array_equal(_mean_or_zero(jnp.zeros((1, 3, 2)), jnp.zeros((1, 3), bool)), [[0.0, 0.0]])
