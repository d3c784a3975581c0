"""Target point, pooling, Q1/Q2, CogSci metrics, CMC and splits (jaxgaze.headpose.target)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxgaze.headpose import target as tg
from tests import helpers as zoo

# ---------------------------------------------------------------------------
# target_point


def test_target_point_hand_cases():
    h = np.array([[100.0, 50.0]] * 6)
    d = np.array([math.pi / 4, math.pi / 2, 3 * math.pi / 4, -math.pi / 2, 0.0, -math.pi / 4])
    y = np.array([150.0, 150.0, 150.0, 150.0, 150.0, 20.0])
    p = np.asarray(tg.target_point(h, d, y))
    np.testing.assert_allclose(p[0], [200.0, 150.0], atol=1e-4)
    np.testing.assert_allclose(p[1], [100.0, 150.0], atol=1e-4)
    np.testing.assert_allclose(p[2], [0.0, 150.0], atol=1e-4)
    np.testing.assert_allclose(p[3], [100.0, 50.0])  # row behind the ray: the head centre
    np.testing.assert_allclose(p[4], [100.0, 50.0])  # parallel: the head centre
    np.testing.assert_allclose(p[5], [130.0, 20.0], atol=1e-4)  # upward ray meets a row above
    reach = np.asarray(tg.reaches_row(h, d, y))
    np.testing.assert_array_equal(reach, [True, True, True, False, False, True])


def test_target_point_near_horizontal_is_capped_and_finite():
    h = np.array([[100.0, 50.0], [100.0, 50.0], [100.0, 50.0]])
    d = np.array([1e-7, math.pi - 1e-7, 0.01])
    y = np.array([150.0, 150.0, 51.0])
    p = np.asarray(tg.target_point(h, d, y, max_length=400.0))
    assert np.all(np.isfinite(p))
    np.testing.assert_allclose(p[0], [500.0, 50.0 + 400 * math.sin(1e-7)], atol=1e-3)
    np.testing.assert_allclose(p[1], [-300.0, 50.0], atol=1e-3)
    np.testing.assert_allclose(p[2], [100.0 + 1 / math.tan(0.01), 51.0], atol=1e-3)  # 100 px: reached
    np.testing.assert_array_equal(np.asarray(tg.reaches_row(h, d, y)), [False, False, True])
    # The row through the head centre: the head centre, on the row.
    q = np.asarray(tg.target_point(h[:1], np.array([0.3]), np.array([50.0])))
    np.testing.assert_allclose(q, [[100.0, 50.0]])


@settings(max_examples=60, deadline=None)
@given(
    hx=st.floats(0, 320),
    hy=st.floats(0, 240),
    ox=st.floats(0, 320),
    oy=st.floats(0, 240),
)
def test_target_point_of_true_direction_and_row_is_the_object(hx, hy, ox, oy):
    with jax.enable_x64(True):
        dy = oy - hy
        if abs(dy) < 1e-3 or math.hypot(ox - hx, dy) > 399:
            return
        d = math.atan2(dy, ox - hx)
        p = np.asarray(tg.target_point(np.array([[hx, hy]]), np.array([d]), np.array([oy])))
        np.testing.assert_allclose(p[0], [ox, oy], atol=1e-8 * (1 + abs(ox - hx) / abs(dy)))


def test_target_point_jit_grad_batch_shapes():
    h = jnp.array([[100.0, 50.0], [100.0, 50.0], [100.0, 50.0]])
    y = jnp.array([150.0, 150.0, 150.0])
    f = jax.jit(lambda d: tg.target_point(h, d, y).sum())
    d = jnp.array([1.0, -1.0, 1e-6])  # reached, behind, capped
    g = jax.grad(f)(d)
    assert np.all(np.isfinite(np.asarray(g)))
    assert float(f(d)) == pytest.approx(float(tg.target_point(h, d, y).sum()), rel=1e-6)
    p = tg.target_point(jnp.ones((2, 3, 2)), jnp.ones((2, 3)), 5 * jnp.ones((2, 3)))
    assert p.shape == (2, 3, 2)


def test_target_point_errors():
    h, d, y = np.zeros((3, 2)), np.zeros(3), np.ones(3)
    with pytest.raises(ValueError, match="direction"):
        tg.target_point(h, np.zeros(2), y)
    with pytest.raises(ValueError, match="depth_y"):
        tg.target_point(h, d, np.ones((3, 1)))
    with pytest.raises(ValueError, match="head_centre"):
        tg.target_point(np.zeros((3, 3)), d, y)
    with pytest.raises(ValueError, match="direction contains NaN"):
        tg.target_point(h, np.array([0.0, np.nan, 0.0]), y)
    with pytest.raises(ValueError, match="head_centre contains NaN"):
        tg.target_point(np.full((3, 2), np.inf), d, y)
    with pytest.raises(ValueError, match="max_length"):
        tg.target_point(h, d, y, max_length=0.0)


# ---------------------------------------------------------------------------
# pooling


def test_pool_hand_example():
    pts = np.arange(18, dtype=float).reshape(9, 2)
    labels = np.array([0, 0, 0, 0, 1, 1, 2, 2, 2])
    out = tg.pool(pts, 4, labels=labels)
    np.testing.assert_allclose(out.values, [[3.0, 4.0], [11.0, 12.0]])  # frame 8 dropped
    np.testing.assert_array_equal(out.valid, [True, False])
    np.testing.assert_array_equal(out.labels, [0, -1])
    pl = tg.pool_labels(labels, 3)
    np.testing.assert_array_equal(pl.labels, [0, -1, 2])
    np.testing.assert_array_equal(pl.valid, [True, False, True])
    plain = tg.pool(np.arange(10.0), 5)
    np.testing.assert_allclose(plain.values, [2.0, 7.0])
    assert plain.labels is None and np.all(plain.valid)
    same = tg.pool(pts, 1, labels=labels)
    np.testing.assert_array_equal(same.values, pts)
    assert np.all(same.valid)


def test_pool_circular_angles():
    a = np.array([math.pi - 0.1, -math.pi + 0.1, math.pi - 0.2, -math.pi + 0.2, 0.1, 0.3, 0.2, 0.2])
    out = tg.pool(a, 4, circular=True)
    assert abs(abs(out.values[0]) - math.pi) < 1e-9  # circular mean near ±π, not the arithmetic 0
    np.testing.assert_allclose(out.values[1], 0.2, atol=1e-3)
    np.testing.assert_allclose(out.values[1], math.atan2(np.sin(a[4:]).sum(), np.cos(a[4:]).sum()))
    two = tg.pool(np.stack([a, a + 0.5], axis=1), 4, circular=True)
    assert two.values.shape == (2, 2)


@pytest.mark.parametrize("window", [0, -2, 2.5, True])
def test_pool_bad_window(window):
    with pytest.raises(ValueError, match="window"):
        tg.pool(np.zeros(8), window)
    with pytest.raises(ValueError, match="window"):
        tg.pool_labels(np.zeros(8, int), window)


def test_pool_errors():
    with pytest.raises(ValueError, match="fewer than one window"):
        tg.pool(np.zeros(3), 4)
    with pytest.raises(ValueError, match="NaN"):
        tg.pool(np.array([0.0, np.nan, 1.0, 2.0]), 2)
    with pytest.raises(ValueError, match="labels has 3 entries"):
        tg.pool(np.zeros(4), 2, labels=np.zeros(3, int))
    with pytest.raises(ValueError, match="integer"):
        tg.pool_labels(np.array([0.5, 1.0]), 1)


# ---------------------------------------------------------------------------
# Q1, Q2 (T-CYB eq. 14–15)

BOXES = np.array([[0.0, 0.0, 10.0, 10.0], [20.0, 0.0, 30.0, 10.0], [40.0, 0.0, 50.0, 10.0]])
CENTRES = np.array([[5.0, 5.0], [25.0, 5.0], [45.0, 5.0]])


def test_q1_hand():
    points = np.array([[5, 5], [10, 10], [11, 5], [25, 5], [35, 5], [0, 0], [30.0, 10.0]])
    target = np.array([0, 0, 0, 1, 1, 1, 1])
    r = tg.q1(points, BOXES, target)
    np.testing.assert_allclose(r.per_object, [2 / 3, 2 / 4, 0.0])  # edges count as inside
    np.testing.assert_array_equal(r.counts, [3, 4, 0])
    np.testing.assert_array_equal(r.hits, [2, 2, 0])
    assert r.mean == pytest.approx((2 / 3 + 2 / 4) / 2)  # object 2 never attended: left out
    assert r.overall == pytest.approx(4 / 7)
    assert r.group(np.array([False, True, True])) == pytest.approx(2 / 4)
    masked = tg.q1(points, BOXES, target, valid=np.array([True, True, False, True, True, True, True]))
    np.testing.assert_allclose(masked.per_object[0], 1.0)


def test_q2_hand_and_ties():
    points = np.array([[14.0, 5.0], [16.0, 5.0], [15.0, 5.0], [60.0, 5.0], [45.0, 100.0]])
    target = np.array([0, 1, 0, 2, 2])
    r = tg.q2(points, CENTRES, target)
    np.testing.assert_allclose(r.per_object, [0.5, 1.0, 1.0])  # [15, 5] is a tie: a miss
    assert r.mean == pytest.approx(2.5 / 3)


def test_q2_matches_a_loop():
    rng = np.random.default_rng(0)
    K, N = 6, 400
    centres = rng.uniform(0, [320, 240], size=(K, 2))
    points = rng.uniform(0, [320, 240], size=(N, 2))
    target = rng.integers(0, K, N)
    r = tg.q2(points, centres, target)
    hits = np.zeros(K)
    counts = np.zeros(K)
    for q, i in zip(points, target):
        counts[i] += 1
        d = [math.dist(q, c) for c in centres]
        hits[i] += all(d[i] < d[j] for j in range(K) if j != i)
    np.testing.assert_allclose(r.per_object, hits / counts)
    assert r.mean == pytest.approx(np.mean(hits / counts))
    assert 0.05 < r.overall < 0.5


def test_rates_errors():
    with pytest.raises(ValueError, match="target must index"):
        tg.q1(np.zeros((2, 2)), BOXES, np.array([0, 3]))
    with pytest.raises(ValueError, match="boxes"):
        tg.q1(np.zeros((2, 2)), np.zeros((3, 3)), np.array([0, 1]))
    with pytest.raises(ValueError, match="x_min"):
        tg.q1(np.zeros((1, 2)), np.array([[5.0, 0, 0, 10]]), np.array([0]))
    with pytest.raises(ValueError, match="points contains NaN"):
        tg.q2(np.array([[np.nan, 0.0]]), CENTRES, np.array([0]))
    with pytest.raises(ValueError, match="target has 1 entries"):
        tg.q2(np.zeros((2, 2)), CENTRES, np.array([0]))
    with pytest.raises(ValueError, match="no valid frames"):
        tg.q1(np.zeros((2, 2)), BOXES, np.array([0, 1]), valid=np.array([False, False]))
    with pytest.raises(ValueError, match="no frames"):
        tg.q1(np.zeros((2, 2)), BOXES, np.array([0, 1])).group(np.array([False, False, True]))


# ---------------------------------------------------------------------------
# CogSci metrics


def test_mean_angular_deviation_wraps():
    est = np.array([3.1, 0.2, -1.0])
    true = np.array([-3.1, 0.0, -1.5])
    expected = (2 * math.pi - 6.2 + 0.2 + 0.5) / 3
    assert tg.mean_angular_deviation(est, true) == pytest.approx(expected)
    assert tg.mean_angular_deviation(est, true, valid=np.array([False, True, False])) == pytest.approx(0.2)
    with pytest.raises(ValueError, match="same shape"):
        tg.mean_angular_deviation(est, true[:2])
    with pytest.raises(ValueError, match="NaN"):
        tg.mean_angular_deviation(np.array([np.nan]), np.array([0.0]))


def test_cone_hits_box_hand_cases():
    box = np.array([10.0, 10.0, 20.0, 20.0])
    apex = np.zeros(2)
    lo, hi = math.atan2(10, 20), math.atan2(20, 10)  # corner directions bounding the box
    tol = tg.TOLERANCE
    assert tol == pytest.approx(3 * math.pi / 64)
    cases = {
        math.pi / 4: True,
        hi + tol - 1e-9: True,
        hi + tol + 1e-6: False,
        lo - tol + 1e-9: True,
        lo - tol - 1e-6: False,
        math.pi / 4 + math.pi: False,
    }
    for d, expected in cases.items():
        assert bool(tg.cone_hits_box(apex, np.array(d), box)) is expected, d
    # Apex inside (or on the edge of) the box: always a hit.
    assert tg.cone_hits_box(np.array([15.0, 15.0]), np.array(-2.0), box)
    assert tg.cone_hits_box(np.array([10.0, 12.0]), np.array(math.pi), box)
    # A box straddling the ±π direction.
    behind = np.array([-20.0, -5.0, -10.0, 5.0])
    assert tg.cone_hits_box(apex, np.array(math.pi), behind)
    assert tg.cone_hits_box(apex, np.array(-math.pi + 0.01), behind)
    assert not tg.cone_hits_box(apex, np.array(0.0), behind)
    # tolerance 0: a ray.
    assert tg.cone_hits_box(apex, np.array(math.pi / 4), box, tolerance=0.0)
    assert not tg.cone_hits_box(apex, np.array(hi + 1e-6), box, tolerance=0.0)


def _sampled_box(box, n=60):
    xs = np.linspace(box[0], box[2], n)
    ys = np.linspace(box[1], box[3], n)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def test_cone_hits_box_matches_dense_sampling():
    rng = np.random.default_rng(1)
    n = 300
    apex = rng.uniform(-50, 370, size=(n, 2))
    lo = rng.uniform(0, [300, 220], size=(n, 2))
    size = rng.uniform(1, 60, size=(n, 2))
    boxes = np.concatenate([lo, lo + size], axis=1)
    direction = rng.uniform(-math.pi, math.pi, size=n)
    tol = rng.uniform(0.0, 0.5, size=n)
    decided = 0
    for i in range(n):
        exact = bool(tg.cone_hits_box(apex[i], direction[i], boxes[i], tolerance=tol[i]))
        pts = _sampled_box(boxes[i])
        v = pts - apex[i]
        excess = np.abs(np.angle(np.exp(1j * (np.arctan2(v[:, 1], v[:, 0]) - direction[i])))) - tol[i]
        sampled = bool(np.any(excess <= 0) or np.any(np.all(v == 0, axis=1)))
        if sampled:
            assert exact, i  # a sampled point of the box lies in the cone
        elif exact:
            # The cone can slip between samples: then it comes within one grid step.
            dist = np.linalg.norm(v, axis=1)
            step = np.linalg.norm(size[i]) / 59
            inside = np.all((apex[i] >= boxes[i, :2]) & (apex[i] <= boxes[i, 2:]))
            assert inside or np.min(excess - step / np.maximum(dist, 1e-9)) <= 0, i
        decided += sampled == exact
    assert decided >= n - 5
    # Vectorised call agrees with the loop.
    vec = tg.cone_hits_box(apex, direction, boxes, tolerance=0.2)
    loop = [bool(tg.cone_hits_box(apex[i], direction[i], boxes[i], tolerance=0.2)) for i in range(n)]
    np.testing.assert_array_equal(vec, loop)
    assert 0.05 < vec.mean() < 0.95


def test_disk_hits_box_matches_sampling():
    box = np.array([10.0, 10.0, 20.0, 20.0])
    assert tg.disk_hits_box(np.array([15.0, 15.0]), box)
    assert tg.disk_hits_box(np.array([30.0, 15.0]), box, radius=10.0)
    assert not tg.disk_hits_box(np.array([30.0 + 1e-6, 15.0]), box, radius=10.0)
    assert tg.disk_hits_box(np.array([27.0, 27.0]), box, radius=10.0)  # corner distance √98 ≈ 9.9
    assert not tg.disk_hits_box(np.array([27.0, 28.0]), box, radius=10.0)  # corner distance √113 ≈ 10.6
    rng = np.random.default_rng(2)
    centres = rng.uniform(-20, 50, size=(500, 2))
    got = tg.disk_hits_box(centres, box, radius=7.0)
    pts = _sampled_box(box, 201)
    dmin = np.min(np.linalg.norm(centres[:, None] - pts[None], axis=-1), axis=1)
    clear = np.abs(dmin - 7.0) > 0.1
    np.testing.assert_array_equal(got[clear], (dmin <= 7.0)[clear])
    assert 0.1 < got.mean() < 0.9
    with pytest.raises(ValueError, match="radius"):
        tg.disk_hits_box(centres, box, radius=-1.0)


def test_cone_and_disk_rates_match_loops():
    rng = np.random.default_rng(3)
    N = 200
    heads = rng.uniform([140, 40], [180, 80], size=(N, 2))
    target = rng.integers(0, 3, N)
    boxes = np.array([[60.0, 150, 90, 180], [150, 160, 180, 190], [230, 150, 260, 180]])
    centres = (boxes[:, :2] + boxes[:, 2:]) / 2
    true_dir = np.arctan2(centres[target, 1] - heads[:, 1], centres[target, 0] - heads[:, 0])
    noisy = true_dir + rng.normal(0, 0.3, N)
    r = tg.cone_rates(heads, noisy, boxes, target)
    loop = np.array([bool(tg.cone_hits_box(heads[i], noisy[i], boxes[target[i]])) for i in range(N)])
    for k in range(3):
        assert r.per_object[k] == pytest.approx(loop[target == k].mean())
    assert r.overall == pytest.approx(loop.mean())
    assert tg.cone_rates(heads, true_dir, boxes, target).mean == 1.0
    pts = centres[target] + rng.normal(0, 20, size=(N, 2))
    rd = tg.disk_rates(pts, boxes, target)
    loop = np.array([bool(tg.disk_hits_box(pts[i], boxes[target[i]], 10.0)) for i in range(N)])
    assert rd.overall == pytest.approx(loop.mean())
    assert 0.1 < rd.overall < 1.0
    with pytest.raises(ValueError, match="direction must have shape"):
        tg.cone_rates(heads, noisy[:5], boxes, target)
    with pytest.raises(ValueError, match="tolerance"):
        tg.cone_rates(heads, noisy, boxes, target, tolerance=2.0)


def test_cmc_curve():
    err = np.array([0.0, 0.1, -0.2, 0.3, 2 * math.pi + 0.05])  # the last wraps to 0.05
    tau = np.array([0.0, 0.05, 0.1, 0.2, 0.25, 0.3, math.pi])
    acc = tg.cmc_curve(err, tau)
    np.testing.assert_allclose(acc, [0.2, 0.4, 0.6, 0.8, 0.8, 1.0, 1.0], atol=1e-12)
    rng = np.random.default_rng(4)
    e = rng.normal(0, 0.3, 1000)
    taus = np.linspace(0, math.pi, 50)
    c = tg.cmc_curve(e, taus)
    assert np.all(np.diff(c) >= 0) and c[-1] == 1.0
    np.testing.assert_allclose(c, [(np.abs(e) <= t).mean() for t in taus])
    with pytest.raises(ValueError, match="thresholds"):
        tg.cmc_curve(e, np.array([-0.1]))
    with pytest.raises(ValueError, match="empty"):
        tg.cmc_curve(np.array([]), taus)
    with pytest.raises(ValueError, match="NaN"):
        tg.cmc_curve(np.array([np.nan]), taus)


# ---------------------------------------------------------------------------
# Splits


def test_self_referencing_splits():
    persons = [0, 0, 1, 1, 1, 2]
    splits = tg.self_referencing_splits(persons)
    assert len(splits) == 2 + 6  # ordered pairs; person 2 has one session
    seen = set()
    for train, test in splits:
        assert len(train) == 1 and len(test) == 1 and train != test
        assert persons[train[0]] == persons[test[0]]
        seen.add((train[0], test[0]))
    assert seen == {(0, 1), (1, 0), (2, 3), (2, 4), (3, 2), (3, 4), (4, 2), (4, 3)}
    with pytest.raises(ValueError, match="at least 2 sessions"):
        tg.self_referencing_splits([0, 1, 2])


def test_cross_referencing_splits_from_sessions():
    sessions = zoo.tabletop_sessions(0, 3, 2, 2.0)
    splits = tg.cross_referencing_splits(sessions)
    assert len(splits) == 3
    for p, (train, test) in enumerate(splits):  # leave person p out
        assert {sessions[i].person for i in test} == {p}
        assert {sessions[i].person for i in train} == {0, 1, 2} - {p}
        assert set(train).isdisjoint(test) and sorted(train + test) == list(range(6))
    assert tg.self_referencing_splits(sessions)[0] == ([0], [1])
    with pytest.raises(ValueError, match="at least 2 people"):
        tg.cross_referencing_splits([0, 0])
    with pytest.raises(ValueError, match="empty"):
        tg.cross_referencing_splits([])
    with pytest.raises(ValueError, match="person id"):
        tg.cross_referencing_splits([object(), object()])


# ---------------------------------------------------------------------------
# On simulated sessions


def test_pipeline_on_simulated_sessions():
    sessions = zoo.tabletop_sessions(7, 2, 1, 60.0)
    for s in sessions:
        h, f1, f2 = s.head_centre_image, s.gaze_direction_image, s.target_depth_image
        truth = tg.target_point(h, f1, f2)
        assert tg.q1(truth, s.object_boxes_image, s.target).mean == 1.0
        assert tg.q2(truth, s.object_centres_image, s.target).mean == 1.0
        assert tg.disk_rates(truth, s.object_boxes_image, s.target).mean == 1.0
        assert tg.cone_rates(h, f1, s.object_boxes_image, s.target).mean == 1.0
        # Pool at 4 frames: dwells of 2–5 s leave most bins on one object.
        pooled = tg.pool(truth, 4, labels=s.target)
        assert 0.85 < pooled.valid.mean() < 1.0
        pooled_dir = tg.pool(f1, 4, labels=s.target, circular=True)
        np.testing.assert_array_equal(pooled_dir.valid, pooled.valid)
        r = tg.q1(pooled.values, s.object_boxes_image, pooled.labels, valid=pooled.valid)
        assert r.mean == 1.0
        # Deviating by more than half the box seen from the head loses hits.
        off = tg.target_point(h, f1 + 0.3, f2)
        assert tg.q1(off, s.object_boxes_image, s.target).mean < 0.5
