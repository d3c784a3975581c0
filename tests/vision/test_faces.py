"""Viola–Jones face and eye detection (``jaxgaze.vision.faces``) on scikit-image's real photos."""

import numpy as np
import pytest

skimage_data = pytest.importorskip("skimage.data")
pytest.importorskip("cv2")

from jaxgaze.vision import faces as F  # noqa: E402
from jaxgaze.vision.faces import EyeBox, FaceBox, detect_eyes, detect_faces  # noqa: E402

# Hand-checked on a zoomed astronaut(): cheeks at x ≈ 180 and 270, hairline y ≈ 73,
# chin y ≈ 182; eye centres ≈ (203, 101) and (246, 103).
ASTRONAUT_FACE = (180.0, 73.0, 90.0, 109.0)
ASTRONAUT_EYES = ((203.0, 101.0), (246.0, 103.0))


def iou(a, b):
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    return ix * iy / (a[2] * a[3] + b[2] * b[3] - ix * iy)


def centre(box):
    return box[0] + box[2] / 2, box[1] + box[3] / 2


def in_middle(box, side=25):
    """The box's centre lies in the middle half of a ``side`` × ``side`` crop."""
    cx, cy = centre(box)
    return side / 4 <= cx <= 3 * side / 4 and side / 4 <= cy <= 3 * side / 4


@pytest.fixture(scope="module")
def astronaut():
    return skimage_data.astronaut()


@pytest.fixture(scope="module")
def astronaut_faces(astronaut):
    return detect_faces(astronaut)


@pytest.fixture(scope="module")
def lfw():
    images = skimage_data.lfw_subset()  # (200, 25, 25) float64 in [0, 1]: 100 faces, then 100 non-faces
    assert images.shape == (200, 25, 25) and images.dtype == np.float64
    return images


@pytest.fixture(scope="module")
def lfw_faces(lfw):
    return [detect_faces(image) for image in lfw]


def test_astronaut_face_is_found_where_it_is(astronaut_faces):
    assert len(astronaut_faces) == 1  # one face, the duplicates merged
    face = astronaut_faces[0]
    assert isinstance(face, FaceBox) and face.kind == "frontal" and face.score >= 5
    assert iou(face[:4], ASTRONAUT_FACE) > 0.6


def test_lfw_subset_detection_and_false_positive_rates(lfw_faces):
    detected = [any(in_middle(b) for b in boxes) for boxes in lfw_faces]
    rate = np.mean(detected[:100])
    false_rate = np.mean(detected[100:])
    any_box_rate = np.mean([len(boxes) > 0 for boxes in lfw_faces[100:]])
    # Measured: 98 % of the faces, 0 % of the non-faces (no box at all on any of them).
    assert rate >= 0.95, rate
    assert false_rate <= 0.02 and any_box_rate <= 0.02, (false_rate, any_box_rate)


def test_boxes_are_sorted_and_in_original_pixels(lfw_faces):
    for boxes in lfw_faces[:100]:
        assert [b.score for b in boxes] == sorted((b.score for b in boxes), reverse=True)
        for b in boxes:
            assert b.kind in F.FACE_KINDS
            # a 25 px crop holds a face of about its own size, not one 4x larger (the upsampling undone)
            assert 12 <= b.width <= 40 and -10 <= b.x and b.x + b.width <= 35


def test_shift_moves_boxes_by_the_offset(astronaut, astronaut_faces):
    dy, dx = 37, 23
    shifted = np.pad(astronaut, ((dy, 0), (dx, 0), (0, 0)), mode="edge")
    (face,) = detect_faces(shifted, kinds="frontal")
    ref = astronaut_faces[0]
    # the detector's windows sit on a 2 px grid of each 1.1x scale: sizes differ by a scale step
    np.testing.assert_allclose(np.subtract(centre(face), centre(ref)), (dx, dy), atol=3)
    assert abs(face.width - ref.width) <= 0.1 * ref.width


def test_small_image_is_upsampled_and_mapped_back(astronaut):
    # The face region shrunk 4x to 48 x 48 px: found after automatic upsampling, and
    # its box, scaled back by 4 and offset, lands on the full-resolution face.
    import cv2

    x0, y0 = 128, 32
    small = cv2.resize(astronaut[y0 : y0 + 192, x0 : x0 + 192], (48, 48), interpolation=cv2.INTER_AREA)
    boxes = detect_faces(small, kinds="frontal")
    assert boxes, "no face in the 48 px image"
    b = boxes[0]
    assert iou((x0 + 4 * b.x, y0 + 4 * b.y, 4 * b.width, 4 * b.height), ASTRONAUT_FACE) > 0.5
    # the same with an explicit, different upsampling factor
    (c, *_) = detect_faces(small, kinds="frontal", upsample=3.0)
    assert iou(b[:4], c[:4]) > 0.6


def test_mirrored_astronaut_still_has_a_face(astronaut):
    faces = detect_faces(astronaut[:, ::-1])
    assert faces and faces[0].kind == "frontal"
    mirrored_truth = (512 - ASTRONAUT_FACE[0] - ASTRONAUT_FACE[2], *ASTRONAUT_FACE[1:])
    assert iou(faces[0][:4], mirrored_truth) > 0.6


def test_profile_cascade_sees_one_side_and_the_mirror_gives_the_other(lfw):
    # lfw_subset faces 46 and 75 are turned towards the image's left: the shipped
    # profile cascade finds them as they are ("profile_left"). Mirroring the image
    # mirrors every profile box exactly and swaps left and right.
    for image in (lfw[46], lfw[75]):
        left = detect_faces(image, kinds="profile_left")
        assert left and in_middle(left[0])
        assert detect_faces(image, kinds="profile_right") == []
        both = detect_faces(image, kinds="profile")
        mirrored = detect_faces(image[:, ::-1], kinds="profile")
        swap = {"profile_left": "profile_right", "profile_right": "profile_left"}
        expected = sorted((25 - b.x - b.width, b.y, b.width, b.height, swap[b.kind], b.score) for b in both)
        np.testing.assert_allclose(
            np.array([b[:4] for b in sorted(mirrored)]), np.array([e[:4] for e in expected]), atol=1e-9
        )
        assert [b.kind for b in sorted(mirrored)] == [e[4] for e in expected]


def test_eyes_of_the_astronaut(astronaut, astronaut_faces):
    eyes = detect_eyes(astronaut, astronaut_faces[0])
    assert len(eyes) == 2 and all(isinstance(e, EyeBox) for e in eyes)
    assert eyes[0].x < eyes[1].x
    for eye, truth in zip(eyes, ASTRONAUT_EYES):
        assert np.hypot(*np.subtract(centre(eye), truth)) < 8


def test_eyes_on_small_lfw_faces(lfw, lfw_faces):
    # 25 px crops: the eyes are 3-4 px wide. Both are found, each in its half of the
    # face's upper part and level with the other, for most of the first 50 faces.
    found, plausible = 0, 0
    for image, boxes in zip(lfw[:50], lfw_faces[:50]):
        if not boxes:
            continue
        found += 1
        face = boxes[0]
        eyes = detect_eyes(image, face)
        assert len(eyes) <= 2
        # in the face's upper part, in full-image pixels
        rel = [((centre(e)[0] - face.x) / face.width, (centre(e)[1] - face.y) / face.height) for e in eyes]
        assert all(0 <= u <= 1 and 0.15 <= v <= 0.65 for u, v in rel)
        if len(eyes) == 2:
            (u0, v0), (u1, v1) = rel
            plausible += 0.1 < u0 < 0.5 < u1 < 0.9 and abs(v0 - v1) < 0.12
    assert found >= 48 and plausible >= 0.8 * found, (found, plausible)


@pytest.mark.parametrize(
    "image, error",
    [
        (np.zeros((0, 0), np.uint8), ValueError),
        (np.zeros((64, 64), np.int16), TypeError),
        (np.full((64, 64), np.nan), ValueError),
        (None, TypeError),
    ],
    ids=["empty", "int16", "nan", "none"],
)
def test_bad_images_are_refused(image, error):
    with pytest.raises(error, match="image"):
        detect_faces(image)


def test_uniform_grey_image_has_no_face():
    assert detect_faces(np.full((120, 160), 0.5)) == []
    assert detect_faces(np.full((25, 25, 3), 128, np.uint8)) == []


def test_bad_arguments(astronaut_faces):
    grey = np.full((30, 30), 0.5)
    with pytest.raises(ValueError, match="kind"):
        detect_faces(grey, kinds=("sideways",))
    with pytest.raises(ValueError, match="upsample"):
        detect_faces(grey, upsample=0)
    with pytest.raises(ValueError, match="face"):
        detect_eyes(grey, FaceBox(0, 0, 0, 10, "frontal", 3.0))


def test_missing_cascade_file_says_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setattr(F, "_CASCADES", {})
    monkeypatch.setattr(F, "_haarcascade_dir", lambda: str(tmp_path))
    with pytest.raises(FileNotFoundError, match="opencv-python-headless<5"):
        detect_faces(np.full((30, 30), 0.5))


# ---------------------------------------------------------------- in-plane rotations


def _turn(image, angle):
    """``image`` turned by ``+angle`` (radians, +x towards +y) about its centre, same size."""
    from jaxgaze.vision.images import rotation_about, warp_affine

    h, w = image.shape[:2]
    forward, backward = rotation_about((w / 2, h / 2), -angle)  # turning by −(−angle)
    return warp_affine(image, forward, (w, h)), forward


@pytest.mark.parametrize("angle_deg", [25.0, -25.0])
def test_turned_face_is_found_with_its_rotation(angle_deg):
    """A face turned by 25° is missed upright and found by the rotation search, with the
    right sign of ``rotation`` and its centre where the turned face is."""
    image, forward = _turn(skimage_data.astronaut(), np.radians(angle_deg))
    face_centre = forward[:, :2] @ np.asarray(centre(ASTRONAUT_FACE)) + forward[:, 2]
    eyes = np.array(ASTRONAUT_EYES) @ forward[:, :2].T + forward[:, 2]

    def near(b):
        return np.hypot(*(np.asarray(b.centre) - face_centre)) < 30

    assert not any(near(b) and b.kind == "frontal" for b in detect_faces(image, kinds=("frontal",)))
    found = [b for b in detect_faces(image, kinds=("frontal",), rotations_deg=(0, -25, 25)) if near(b)]
    assert found and np.degrees(found[0].rotation) == pytest.approx(angle_deg)
    # the eye axis in the image is turned by the same angle
    axis = eyes[1] - eyes[0]
    assert np.degrees(np.arctan2(axis[1], axis[0])) == pytest.approx(angle_deg, abs=4)


def test_rotations_deg_errors():
    image = skimage_data.astronaut()
    for bad in ((), (np.nan,), (120.0,), "x"):
        with pytest.raises(ValueError, match="rotations_deg"):
            detect_faces(image, rotations_deg=bad)


def test_rotation_about_and_warp_affine_conventions():
    """``rotation_about``'s maps invert each other, turn +x towards +y for a positive
    angle, and ``warp_affine`` moves a pixel's content to where the map sends its centre."""
    from jaxgaze.vision.images import rotation_about, warp_affine

    forward, backward = rotation_about((10.0, 20.0), 0.3, (50.0, 40.0))
    p = np.array([[3.0, 4.0], [10.0, 20.0], [-7.0, 11.0]])
    q = p @ forward[:, :2].T + forward[:, 2]
    np.testing.assert_allclose(q @ backward[:, :2].T + backward[:, 2], p, atol=1e-12)
    np.testing.assert_allclose(q[1], [50.0, 40.0])
    # forward turns the image by −angle: a point turned by +angle about the centre comes back to +x
    t = 0.3
    turned = np.array([10.0 + 5 * np.cos(t), 20.0 + 5 * np.sin(t)])
    np.testing.assert_allclose(turned @ forward[:, :2].T + forward[:, 2], [55.0, 40.0], atol=1e-12)

    image = np.zeros((21, 31), np.float32)
    image[5, 7] = 1.0  # pixel centre (7.5, 5.5)
    shift = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, 2.0]])
    out = warp_affine(image, shift, (31, 21))
    assert out[7, 10] == pytest.approx(1.0) and out.sum() == pytest.approx(1.0)
    # a mirror (x → W − x) maps pixel column j to W − 1 − j, with no half-pixel slip
    mirror = np.array([[-1.0, 0.0, 31.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(warp_affine(image, mirror, (31, 21)), image[:, ::-1], atol=1e-6)
    with pytest.raises(ValueError, match="2x3"):
        warp_affine(image, np.eye(3), (31, 21))
