"""Rendered table-top scenes (jaxgaze.simulate.render): ground truth, conditions, saliency sanity."""

import itertools

import cv2
import jax
import numpy as np
import pytest

from jaxgaze.simulate.tabletop import IMAGE_HEIGHT, IMAGE_WIDTH, simulate_tabletop_sessions
from jaxgaze.vision.images import check_image
from jaxgaze.simulate.render import CONDITIONS, RenderedScene, composite, render_tabletop_scene


@pytest.fixture(scope="module")
def sessions():
    return simulate_tabletop_sessions(
        jax.random.key(0), num_people=3, sessions_per_person=1, duration_s=0.2, shared_layout=False
    )


def _lab(image):
    return cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)


def _hue_deg(rgb):
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1, 1, 3), cv2.COLOR_RGB2HSV_FULL)
    return hsv[:, 0, 0].astype(np.float64) * 360.0 / 256.0


def _hue_diff(a, b):
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def _central_half(box):
    x0, y0, x1, y1 = box
    cx, cy, w, h = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0
    return slice(int(round(cy - h / 4)), int(round(cy + h / 4))), slice(int(round(cx - w / 4)), int(round(cx + w / 4)))


def _overlaps_other(boxes, k):
    a = boxes[k]
    return any(
        a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3] for j, b in enumerate(boxes) if j != k
    )


def test_output_format(sessions):
    s = sessions[0]
    r = render_tabletop_scene(s, key=jax.random.key(1))
    assert isinstance(r, RenderedScene) and r.condition == "natural"
    assert r.image.shape == (IMAGE_HEIGHT, IMAGE_WIDTH, 3) and r.image.dtype == np.uint8
    check_image(r.image)
    k = s.num_objects
    assert r.object_boxes.shape == (k, 4) and r.object_centres.shape == (k, 2)
    assert r.object_colours.shape == (k, 3) and r.object_colours.dtype == np.uint8
    assert r.object_labels.shape == (IMAGE_HEIGHT, IMAGE_WIDTH)
    assert set(np.unique(r.object_labels)) <= set(range(-1, k))


def test_ground_truth_matches_session_and_pixels(sessions):
    checked = 0
    for i, s in enumerate(sessions):
        r = render_tabletop_scene(s, key=jax.random.key(10 + i))
        np.testing.assert_array_equal(r.object_boxes, np.asarray(s.object_boxes_image, dtype=np.float64))
        np.testing.assert_array_equal(r.object_centres, np.asarray(s.object_centres_image, dtype=np.float64))
        hue = _hue_deg(r.image).reshape(IMAGE_HEIGHT, IMAGE_WIDTH)
        for k, box in enumerate(r.object_boxes):
            ys, xs = np.nonzero(r.object_labels == k)
            extent = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
            # a pixel is the object's if its centre is inside a face: never outside the box
            assert np.all(extent[:2] >= box[:2] - 0.5) and np.all(extent[2:] <= box[2:] + 0.5)
            want = _hue_deg(r.object_colours[k])[0]
            sl = _central_half(box)
            own = r.object_labels[sl] == k
            if not _overlaps_other(r.object_boxes, k):
                np.testing.assert_allclose(extent, box, atol=0.5)
                assert own.all()
                # the central half is dominated by the object's colour (same hue, saturated)
                assert np.median(_hue_diff(hue[sl], want)) < 5.0
                assert np.mean(_hue_diff(hue[sl], want) < 15.0) > 0.9
                checked += 1
            elif own.any():  # partly hidden by a nearer cube: its visible pixels still have its hue
                assert np.median(_hue_diff(hue[sl][own], want)) < 5.0
        lab = _lab(r.object_colours[None])[0]
        dists = [np.linalg.norm(a - b) for a, b in itertools.combinations(lab, 2)]
        assert min(dists) > 25.0, dists  # objects differ in colour (CIE76 ΔE)
        hsv = cv2.cvtColor(r.object_colours[None], cv2.COLOR_RGB2HSV)[0]
        assert np.all(hsv[:, 1] > 0.75 * 255)  # saturated
    assert checked >= 5


def test_explicit_boxes():
    boxes = np.array([[20, 150, 60, 190], [100, 140, 130, 170], [200, 160, 260, 220], [280, 120, 318, 150.5]])
    r = render_tabletop_scene(boxes, key=jax.random.key(3))
    np.testing.assert_array_equal(r.object_boxes, boxes)
    np.testing.assert_allclose(r.object_centres, (boxes[:, :2] + boxes[:, 2:]) / 2)
    for k, box in enumerate(boxes):
        ys, xs = np.nonzero(r.object_labels == k)
        np.testing.assert_allclose([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], box, atol=0.5)
    # twelve objects still get twelve distinct colours
    many = np.array([[5 + 26 * i, 150, 28 + 26 * i, 175] for i in range(12)])
    colours = render_tabletop_scene(many, key=jax.random.key(4)).object_colours
    lab = _lab(colours[None])[0]
    assert min(np.linalg.norm(a - b) for a, b in itertools.combinations(lab, 2)) > 10.0


def test_conditions_measured(sessions):
    s, key = sessions[1], jax.random.key(5)
    r = {c: render_tabletop_scene(s, key=key, condition=c) for c in CONDITIONS}
    for c in CONDITIONS:
        assert r[c].condition == c
        np.testing.assert_array_equal(r[c].object_labels, r["natural"].object_labels)  # same layout
        np.testing.assert_array_equal(r[c].object_colours, r["natural"].object_colours)
    img = {c: r[c].image.astype(np.float64) for c in CONDITIONS}
    assert img["dimmed"].mean() < 0.45 * img["natural"].mean()

    def r_over_b(x):
        return x[..., 0].mean() / x[..., 2].mean()

    assert r_over_b(img["artificial"]) > 1.5 * r_over_b(img["natural"])

    def laplacian_var(x):
        return cv2.Laplacian(cv2.cvtColor(x, cv2.COLOR_RGB2GRAY).astype(np.float32), cv2.CV_32F).var()

    assert laplacian_var(r["blur"].image) < 0.25 * laplacian_var(r["natural"].image)


def test_reproducible_and_key_dependent(sessions):
    s = sessions[0]
    a = render_tabletop_scene(s, key=jax.random.key(7), condition="dimmed")
    b = render_tabletop_scene(s, key=jax.random.key(7), condition="dimmed")
    np.testing.assert_array_equal(a.image, b.image)

    def clutter_mask(key):
        full = render_tabletop_scene(s, key=key).image
        bare = render_tabletop_scene(s, key=key, clutter=False).image
        return np.any(full != bare, axis=-1)

    m1, m2 = clutter_mask(jax.random.key(7)), clutter_mask(jax.random.key(8))
    assert m1.sum() > 500 and m2.sum() > 500
    assert np.mean(m1 != m2) > 0.02  # different keys, different clutter
    np.testing.assert_array_equal(a.object_boxes, render_tabletop_scene(s, key=jax.random.key(8)).object_boxes)


def test_objects_stand_out_more_than_clutter(sessions):
    """Odd-colour sanity check: Lab distance to the local surround (Gaussian σ = 8 px)."""
    for i, s in enumerate(sessions):
        key = jax.random.key(20 + i)
        r = render_tabletop_scene(s, key=key)
        bare = render_tabletop_scene(s, key=key, clutter=False)
        lab = _lab(r.image)
        contrast = np.linalg.norm(lab - cv2.GaussianBlur(lab, (0, 0), 8.0), axis=-1)
        objects = r.object_labels >= 0
        clutter = np.any(r.image != bare.image, axis=-1) & ~objects
        assert clutter.sum() > 1000
        on_objects, on_clutter = contrast[objects].mean(), contrast[clutter].mean()
        assert on_objects > 3.0 * on_clutter, (on_objects, on_clutter)
        assert np.percentile(contrast[clutter], 90) < on_objects / 1.5


def test_head_region_is_plain_wall(sessions):
    for i, s in enumerate(sessions):
        key = jax.random.key(30 + i)
        r = render_tabletop_scene(s, key=key)
        bare = render_tabletop_scene(s, key=key, clutter=False)
        x, y = np.asarray(s.head_centre_image, dtype=np.float64).mean(axis=0)
        rad = 0.12 * s.focal_px / float(s.head_rest_optical[2])
        sl = slice(int(y - 1.5 * rad), int(y + 1.5 * rad)), slice(int(x - 1.5 * rad), int(x + 1.5 * rad))
        np.testing.assert_array_equal(r.image[sl], bare.image[sl])
        assert np.all(r.object_labels[sl] < 0)
        assert r.image[sl].reshape(-1, 3).astype(np.float64).std(axis=0).max() < 5.0


def test_composite():
    rng = np.random.default_rng(0)
    bg = rng.integers(0, 256, (10, 12, 3), dtype=np.uint8)
    fg = rng.integers(0, 256, (10, 12, 3), dtype=np.uint8)
    mask = np.zeros((10, 12), bool)
    mask[2:5, 3:7] = True
    out = composite(bg, fg, mask)
    np.testing.assert_array_equal(out[mask], fg[mask])
    np.testing.assert_array_equal(out[~mask], bg[~mask])
    assert out is not bg
    with pytest.raises(ValueError, match="must match background"):
        composite(bg, fg[:, :11], mask)
    with pytest.raises(ValueError, match="mask has shape"):
        composite(bg, fg, mask[:9])
    with pytest.raises(TypeError, match="bool"):
        composite(bg, fg, mask.astype(np.uint8))


def test_bad_input(sessions):
    key = jax.random.key(0)
    good = np.array([[20.0, 150, 60, 190], [100, 140, 130, 170]])
    with pytest.raises(ValueError, match="valid conditions are natural, artificial, dimmed, blur"):
        render_tabletop_scene(good, key=key, condition="foggy")
    with pytest.raises(ValueError, match="outside the 320x240 image"):
        render_tabletop_scene(np.array([[300.0, 150, 330, 190]]), key=key)
    with pytest.raises(ValueError, match="outside"):
        render_tabletop_scene(np.array([[-5.0, 150, 30, 190]]), key=key)
    with pytest.raises(ValueError, match=r"shape \(K, 4\)"):
        render_tabletop_scene(good[:, :3], key=key)
    with pytest.raises(ValueError, match=r"shape \(K, 4\)"):
        render_tabletop_scene(good[0], key=key)
    bad = good.copy()
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="object box 1 contains NaN"):
        render_tabletop_scene(bad, key=key)
    with pytest.raises(ValueError, match="x_max - x_min"):
        render_tabletop_scene(np.array([[60.0, 150, 20, 190]]), key=key)
    with pytest.raises(ValueError, match="1 to 12 object boxes"):
        render_tabletop_scene(np.zeros((0, 4)), key=key)
    with pytest.raises(ValueError, match="key"):
        render_tabletop_scene(good, key=3)
    with pytest.raises(TypeError, match="clutter"):
        render_tabletop_scene(good, key=key, clutter="yes")
