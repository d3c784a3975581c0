"""Bottom-up saliency, winner-take-all with inhibition of return, masks and regions
(``jaxgaze.vision.saliency_maps``; Yücel et al. T-CYB 2013 Sec. VI, Itti et al. 1998,
Hou & Zhang 2007). Every test checks behaviour against a known truth."""

import cv2
import numpy as np
import pytest

from jaxgaze.vision.saliency_maps import (
    SALIENCY_METHODS,
    Fixations,
    gaussian_mask,
    itti_normalize,
    salient_region,
    saliency,
    winner_take_all,
)

H, W = 240, 320
GREY, GREEN, RED = (128, 128, 128), (0, 160, 0), (255, 0, 0)
YELLOW, BLUE, BLACK = (230, 230, 40), (30, 30, 200), (20, 20, 20)


def square_scene(background, colour, x0, y0, size, shape=(H, W)):
    image = np.empty((*shape, 3), np.uint8)
    image[:] = background
    image[y0 : y0 + size, x0 : x0 + size] = colour
    return image


def argmax_xy(saliency_map):
    y, x = np.unravel_index(np.argmax(saliency_map), saliency_map.shape)
    return int(x), int(y)


def _cases(method, n, seed):
    """Random odd-object scenes (fixed seed): Itti's map has a 16 px grid (scale 4), so
    its objects are 20–50 px; spectral residual's transform is periodic, so its objects
    keep 24 px from the image edge (see the ``saliency`` docstring)."""
    rng = np.random.default_rng(seed)
    sizes, margin = ((20, 50), 8) if method == "itti" else ((12, 40), 24)
    pairs = [(GREY, RED), (GREEN, RED), (GREEN, YELLOW), (GREY, BLUE), ((200, 200, 200), BLACK)]
    cases = []
    for i in range(n):
        size = int(rng.integers(*sizes))
        x0 = int(rng.integers(margin, W - size - margin))
        y0 = int(rng.integers(margin, H - size - margin))
        cases.append((method, *pairs[i % len(pairs)], x0, y0, size))
    return cases


ODD_OBJECT_CASES = [
    *[(m, GREY, RED, 100, 80, 30) for m in SALIENCY_METHODS],
    *_cases("itti", 10, 0),
    *_cases("spectral_residual", 10, 1),
]


@pytest.mark.parametrize(("method", "background", "colour", "x0", "y0", "size"), ODD_OBJECT_CASES)
def test_odd_object_holds_the_saliency_maximum(method, background, colour, x0, y0, size):
    result = saliency(square_scene(background, colour, x0, y0, size), method)
    assert result.shape == (H, W) and result.dtype == np.float32
    assert result.min() == 0.0 and result.max() == pytest.approx(1.0)
    x, y = argmax_xy(result)
    assert x0 <= x < x0 + size and y0 <= y < y0 + size


def test_itti_finds_an_object_that_differs_in_colour_only():
    # red on green with the same intensity I = (r + g + b)/3: no intensity or
    # orientation contrast, so only the red–green opponency can find it
    image = square_scene((0, 200, 0), (200, 0, 0), 200, 60, 30)
    x, y = argmax_xy(saliency(image, "itti"))
    assert 200 <= x < 230 and 60 <= y < 90


@pytest.mark.parametrize("method", SALIENCY_METHODS)
def test_grey_image_runs_and_finds_a_dark_square(method):
    image = np.full((H, W), 180, np.uint8)
    image[150:180, 60:90] = 40
    result = saliency(image, method)
    assert result.shape == (H, W)
    x, y = argmax_xy(result)
    assert 60 <= x < 90 and 150 <= y < 180


@pytest.mark.parametrize("method", SALIENCY_METHODS)
@pytest.mark.parametrize(
    "image",
    [
        np.full((H, W, 3), 90, np.uint8),  # equal channels everywhere
        np.full((H, W, 3), (200, 10, 30), np.uint8),  # one colour everywhere
        np.full((H, W), 0.3, np.float32),  # grey
        np.zeros((H, W, 3), np.float64),  # black
    ],
    ids=["grey-rgb", "colour", "grey-2d", "black"],
)
def test_uniform_image_gives_an_all_zero_map(method, image):
    result = saliency(image, method)
    assert result.shape == (H, W) and result.dtype == np.float32
    assert np.all(result == 0.0)


@pytest.fixture(scope="module")
def cluttered_scene():
    image = np.repeat(np.repeat(np.linspace(60, 160, W).astype(np.uint8)[None, :, None], H, 0), 3, 2)
    cv2.rectangle(image, (40, 50), (80, 90), (220, 30, 30), -1)
    cv2.circle(image, (200, 160), 20, (30, 60, 220), -1)
    cv2.line(image, (230, 30), (300, 100), (240, 240, 60), 5)
    cv2.rectangle(image, (100, 170), (140, 200), (20, 20, 20), -1)
    return image


@pytest.mark.parametrize("k", [1, 2, 3])
def test_itti_commutes_with_rotation_by_90_degrees(cluttered_scene, k):
    # orientation channels 0°↔90° and 45°↔135° swap under rot90; their sum does not change
    rotated_map = saliency(np.ascontiguousarray(np.rot90(cluttered_scene, k)), "itti")
    expected = np.rot90(saliency(cluttered_scene, "itti"), k)
    assert rotated_map.shape == expected.shape
    assert np.corrcoef(rotated_map.ravel(), expected.ravel())[0, 1] > 0.99


def test_gabor_channels_swap_under_rotation():
    from jaxgaze.vision import saliency_maps as module

    level = cv2.GaussianBlur(np.random.default_rng(0).random((41, 41)).astype(np.float32), (0, 0), 1.0)

    def energy(img, pair):
        even, odd = pair
        return np.sqrt(cv2.filter2D(img, -1, even) ** 2 + cv2.filter2D(img, -1, odd) ** 2)

    rotated = np.ascontiguousarray(np.rot90(level))
    inner = (slice(5, -5), slice(5, -5))  # away from the border handling
    for a, b in [(0, 2), (1, 3), (2, 0), (3, 1)]:  # 0↔90°, 45↔135°
        got = energy(rotated, module._GABORS[a])
        want = np.rot90(energy(level, module._GABORS[b]))
        np.testing.assert_allclose(got[inner], want[inner], atol=1e-5)


def test_normalisation_promotes_one_strong_peak_over_many_equal_peaks():
    rng = np.random.default_rng(0)
    one = np.zeros((40, 40), np.float32)
    one[20, 20] = 1.0
    many = np.zeros((40, 40), np.float32)
    many[5::10, 5::10] = 10.0  # 16 equal peaks, ten times stronger
    one += 0.01 * rng.random(one.shape, dtype=np.float32)
    many += 0.01 * rng.random(many.shape, dtype=np.float32)
    n_one, n_many = itti_normalize(one), itti_normalize(many)
    assert n_one.max() > 0.9  # (M − m̄)² with no other maximum above M/10: kept
    assert n_many.max() < 0.01  # m̄ ≈ M: suppressed
    assert np.unravel_index(np.argmax(n_one + n_many), one.shape) == (20, 20)
    # fixed range: the map's own scale does not matter
    np.testing.assert_allclose(itti_normalize(7.0 * one + 3.0), n_one, atol=1e-6)
    # the factor is (1 − m̄)² with m̄ the mean of the other local maxima
    two = np.zeros((30, 30), np.float32)
    two[5, 5], two[20, 20], two[25, 8] = 1.0, 0.5, 0.3
    np.testing.assert_allclose(itti_normalize(two), two * (1 - 0.4) ** 2, atol=1e-6)
    assert np.all(itti_normalize(np.full((9, 9), 0.7)) == 0.0)


@pytest.mark.parametrize("method", SALIENCY_METHODS)
@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 1), (5, 7, 3), (3, 200), (97, 131, 3)])
def test_any_size_gives_a_map_of_that_size_in_unit_range(method, shape):
    image = np.random.default_rng(0).integers(0, 256, shape).astype(np.uint8)
    result = saliency(image, method)
    assert result.shape == shape[:2] and result.dtype == np.float32
    assert np.all(np.isfinite(result)) and result.min() >= 0.0 and result.max() <= 1.0


@pytest.mark.parametrize(
    ("image", "error", "match"),
    [
        (np.zeros((0, 5, 3), np.uint8), ValueError, "empty"),
        (np.zeros((10, 10, 3), np.int16), TypeError, "int16"),
        (np.full((10, 10, 3), np.nan), ValueError, "NaN"),
        (np.full((10, 10, 3), 2.0), ValueError, r"\[0, 1\]"),
        (np.zeros((10, 10, 4), np.uint8), ValueError, "shape"),
        (None, TypeError, "None"),
    ],
)
def test_bad_images_are_refused(image, error, match):
    for method in SALIENCY_METHODS:
        with pytest.raises(error, match=match):
            saliency(image, method)


def test_unknown_method_names_the_valid_ones():
    with pytest.raises(ValueError, match="itti.*spectral_residual"):
        saliency(np.zeros((8, 8), np.uint8), "judd")


# --------------------------------------------------------------------- gaussian_mask


def test_gaussian_mask_closed_form():
    sigma = 10.0
    # (160.5, 120.5) is the centre of pixel [120, 160] (corner origin)
    mask = gaussian_mask((H, W), (160.5, 120.5), sigma_px=sigma)
    assert mask.shape == (H, W) and mask.dtype == np.float32
    assert argmax_xy(mask) == (160, 120) and mask[120, 160] == pytest.approx(1.0)
    for x, y in [(170, 120), (150, 120), (160, 130), (160, 110)]:  # pixel indices at distance σ
        assert mask[y, x] == pytest.approx(np.exp(-0.5), rel=1e-6)
    ys, xs = np.mgrid[:H, :W] + 0.5  # pixel centres
    np.testing.assert_allclose(mask, np.exp(-((xs - 160.5) ** 2 + (ys - 120.5) ** 2) / (2 * sigma**2)), atol=1e-7)


def test_gaussian_mask_centre_on_a_pixel_corner_is_shared_by_four_pixels():
    # (160, 120) is the corner shared by pixels [119, 159], [119, 160], [120, 159], [120, 160]
    mask = gaussian_mask((H, W), (160.0, 120.0), sigma_px=10.0)
    peak = np.exp(-0.5 * 0.5 / 100.0)  # every one of them is √(½² + ½²) px away
    np.testing.assert_allclose(mask[119:121, 159:161], peak, rtol=1e-6)
    assert mask.max() == pytest.approx(peak, rel=1e-6)


def test_gaussian_mask_is_the_maximum_of_the_centres():
    centres = np.array([[50.0, 60.0], [58.0, 60.0], [300.5, 10.25]])
    mask = gaussian_mask((H, W, 3), centres, sigma_px=5.0)
    ys, xs = np.mgrid[:H, :W] + 0.5
    each = [np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / 50.0) for cx, cy in centres]
    np.testing.assert_allclose(mask, np.max(each, axis=0), atol=1e-7)
    assert mask.max() <= 1.0
    assert np.all(gaussian_mask((4, 5), np.zeros((0, 2))) == 0.0)


@pytest.mark.parametrize(
    ("shape", "centres", "sigma", "match"),
    [
        ((H, W), (np.nan, 3.0), 10.0, "NaN"),
        ((H, W), [(1.0, 2.0), (np.inf, 0.0)], 10.0, "NaN or inf"),
        ((H, W), (1.0, 2.0), 0.0, "sigma"),
        ((H, W), (1.0, 2.0), -1.0, "sigma"),
        ((H, W), (1.0, 2.0), np.nan, "sigma"),
        ((H, W), (1.0, 2.0, 3.0), 10.0, r"\(n, 2\)"),
        ((0, W), (1.0, 2.0), 10.0, "shape"),
        (5, (1.0, 2.0), 10.0, "shape"),
    ],
)
def test_gaussian_mask_refuses_bad_arguments(shape, centres, sigma, match):
    with pytest.raises(ValueError, match=match):
        gaussian_mask(shape, centres, sigma_px=sigma)


# ------------------------------------------------------------------- winner_take_all

PEAKS_XY = [(250, 60), (40, 200), (160, 120), (60, 30), (290, 220)]  # pixel indices (column, row)
PEAKS_CENTRE_XY = [(x + 0.5, y + 0.5) for x, y in PEAKS_XY]  # their centres in image coordinates
HEIGHTS = [1.0, 0.8, 0.6, 0.4, 0.2]


@pytest.fixture(scope="module")
def peaked_map():
    """Cones of radius 8 px and decreasing height on a zero background, listed out of order
    (the cone of peak (x, y) has its top on the pixel [y, x])."""
    ys, xs = np.mgrid[:H, :W]
    out = np.zeros((H, W), np.float32)
    for i in [2, 0, 4, 1, 3]:
        (x, y), h = PEAKS_XY[i], HEIGHTS[i]
        out = np.maximum(out, h * np.clip(1 - np.hypot(xs - x, ys - y) / 8, 0, None))
    return out


def test_winner_take_all_visits_peaks_in_decreasing_order(peaked_map):
    fix = winner_take_all(peaked_map, 3, ior_radius_px=12)
    assert isinstance(fix, Fixations)
    assert fix.xy.shape == (3, 2) and fix.xy.dtype == np.float64
    assert [tuple(p) for p in fix.xy] == PEAKS_CENTRE_XY[:3]  # pixel centres, corner origin
    np.testing.assert_allclose(fix.value, HEIGHTS[:3], rtol=1e-6)


def test_winner_take_all_stops_when_the_rest_is_flat(peaked_map):
    fix = winner_take_all(peaked_map, 50, ior_radius_px=12)
    assert [tuple(p) for p in fix.xy] == PEAKS_CENTRE_XY  # then only zeros remain
    assert np.all(np.diff(fix.value) <= 0)


def test_inhibition_of_return_never_revisits_within_its_radius():
    ramp = np.random.default_rng(3).random((60, 80))
    ramp = cv2.GaussianBlur(ramp, (0, 0), 3.0)
    radius = 9.0
    fix = winner_take_all(ramp, 40, ior_radius_px=radius)
    assert len(fix.value) > 5 and np.all(np.diff(fix.value) <= 0)
    gaps = np.hypot(*(fix.xy[:, None, :] - fix.xy[None, :, :]).transpose(2, 0, 1))
    assert np.all(gaps[np.triu_indices(len(fix.xy), 1)] > radius)


def test_winner_take_all_with_a_mask_attends_inside_it(peaked_map):
    mask = gaussian_mask((H, W), (45, 195), sigma_px=10.0)  # near the second-highest peak
    fix = winner_take_all(peaked_map, 1, mask=mask)
    assert tuple(fix.xy[0]) == PEAKS_CENTRE_XY[1]
    assert fix.value[0] == pytest.approx(HEIGHTS[1] * mask[200, 40], rel=1e-5)


def test_winner_take_all_breaks_ties_in_row_major_order():
    m = np.zeros((10, 10))
    m[7, 2] = m[3, 8] = m[3, 5] = 1.0
    assert [tuple(p) for p in winner_take_all(m, 3, ior_radius_px=1).xy] == [(5.5, 3.5), (8.5, 3.5), (2.5, 7.5)]


@pytest.mark.parametrize(
    ("smap", "kwargs", "match"),
    [
        (np.zeros((20, 30)), {}, "no location stands out"),
        (np.full((20, 30), 0.4), {}, "no location stands out"),
        (np.eye(20), {"mask": np.zeros((20, 20))}, "no location stands out"),
        (np.eye(20), {"mask": np.ones((20, 21))}, "shape"),
        (np.eye(20), {"mask": -np.ones((20, 20))}, "non-negative"),
        (np.eye(20) * np.nan, {}, "NaN"),
        (-np.eye(20), {}, "non-negative"),
        (np.ones((2, 3, 3)), {}, r"\(H, W\)"),
        (np.eye(20), {"ior_radius_px": -1.0}, "ior_radius_px"),
    ],
)
def test_winner_take_all_refuses_bad_input(smap, kwargs, match):
    with pytest.raises(ValueError, match=match):
        winner_take_all(smap, 3, **kwargs)
    with pytest.raises(ValueError, match="num_fixations"):
        winner_take_all(np.eye(20), 0)


# --------------------------------------------------------------------- salient_region


@pytest.fixture(scope="module")
def blocks_map():
    m = np.full((H, W), 0.1, np.float32)
    m[50:91, 30:111] = 1.0  # columns 30…110, rows 50…90: the box [30, 111] × [50, 91]
    m[150:171, 200:241] = 0.8  # another object: [200, 241] × [150, 171]
    m[60, 200] = 0.9  # an isolated bright pixel elsewhere: [200, 201] × [60, 61]
    return m


def test_salient_region_recovers_the_rectangle(blocks_map):
    assert salient_region(blocks_map, (70, 70)) == (30, 50, 111, 91)
    assert salient_region(blocks_map, (200.5, 150.5)) == (200, 150, 241, 171)
    # the pixel [60, 200] covers [200, 201) × [60, 61): any point in it names it
    for xy in [(200.0, 60.0), (200.5, 60.5), (200.99, 60.99)]:
        assert salient_region(blocks_map, xy) == (200, 60, 201, 61)
    assert salient_region(blocks_map, (199.99, 60.5)) == (0, 0, W, H)  # the background pixel left of it
    # at 5 % every pixel of the map passes and the component is the whole image
    assert salient_region(blocks_map, (70, 70), threshold_fraction=0.05) == (0, 0, W, H)
    # the box is in image coordinates: the region's pixel centres lie inside it, its edges on pixel edges
    x0, y0, x1, y1 = salient_region(blocks_map, (35.2, 88.9))
    assert (x1 - x0, y1 - y0) == (81, 41) and all(isinstance(v, float) for v in (x0, y0, x1, y1))


def test_salient_region_segments_the_attended_object_end_to_end():
    # the paper's chain: regression estimate → Gaussian mask → saliency → WTA → region
    image = square_scene(GREY, RED, 60, 60, 30)
    image[140:170, 220:250] = BLUE
    estimate = (230.0, 160.0)  # a few px off the blue object's centre (235, 155); its box is [220, 250] × [140, 170]
    smap = saliency(image, "itti")
    fix = winner_take_all(smap, 1, mask=gaussian_mask(smap.shape, estimate, sigma_px=10.0))
    x, y = fix.xy[0]
    assert 220 < x < 250 and 140 < y < 170
    x_min, y_min, x_max, y_max = salient_region(smap, fix.xy[0])
    assert x_min <= 224 and y_min <= 144 and x_max >= 246 and y_max >= 166  # covers the object
    assert x_max - x_min < 70 and y_max - y_min < 70 and x_max <= W and y_max <= H  # and not the scene


@pytest.mark.parametrize(
    ("xy", "kwargs", "match"),
    [
        ((400, 10), {}, "outside"),
        ((-1, 10), {}, "outside"),
        ((-0.01, 10), {}, "outside"),
        ((W, 10), {}, "outside"),  # x = W is the right edge, past the last pixel
        ((np.nan, 10), {}, "finite"),
        ((1, 2, 3), {}, "finite"),
        ((10, 10), {"threshold_fraction": 0.0}, "threshold_fraction"),
        ((10, 10), {"threshold_fraction": 1.5}, "threshold_fraction"),
    ],
)
def test_salient_region_refuses_bad_input(blocks_map, xy, kwargs, match):
    with pytest.raises(ValueError, match=match):
        salient_region(blocks_map, xy, **kwargs)
    with pytest.raises(ValueError, match="nothing to segment"):
        salient_region(np.zeros((5, 5)), (2.5, 2.5))
