"""Frame checks at the door: eye positions given in the other axis convention (ours: +x forward, +y left, +z up;
OpenCV: x right, y down, z forward) are refused with a message naming the convention expected and the swap,
while correct input, and a lone eye out of view among correct ones, pass."""

import numpy as np
import pytest

from jaxgaze.geometry import R_OURS_FROM_OPENCV
from jaxgaze.io.text import InputFileError
from jaxgaze.io.tools.common import eye_axes_problem
from jaxgaze.io.tools.gaze360 import gaze360_to_rays, read_gaze360
from jaxgaze.io.tools.l2cs import l2cs_to_rays, read_l2cs
from jaxgaze.io.tools.xgaze import xgaze_to_rays

#: Three people 1.2–2.5 m in front of the camera, in our axes, and the same points in OpenCV's.
EYES_OURS = np.array([[1.2, 0.3, 0.1], [2.0, -0.4, 0.05], [2.5, 0.9, 0.2]])
EYES_OPENCV = EYES_OURS @ R_OURS_FROM_OPENCV  # (−y, −z, x): z the depth
OURS_EXPECTED = r"taken in our camera axes \(\+x forward along the optical axis, \+y left, \+z up\); they look like OpenCV"
OPENCV_EXPECTED = r"taken in OpenCV camera axes \(x right, y down, z forward along the optical axis\); they look like our"
ZERO = np.zeros(3)


def test_the_two_conventions_are_the_same_points():
    np.testing.assert_allclose(EYES_OPENCV[:, 2], EYES_OURS[:, 0])  # the depth
    np.testing.assert_allclose(EYES_OPENCV[:, 0], -EYES_OURS[:, 1])  # right = −left


@pytest.mark.parametrize("to_rays", [lambda eyes: gaze360_to_rays(ZERO, ZERO, ZERO + 0.1, eyes),
                                     lambda eyes: l2cs_to_rays(ZERO, ZERO, eyes)])
def test_arrays_in_our_axes_pass_and_opencv_axes_are_refused(to_rays):
    recording = to_rays(EYES_OURS)
    np.testing.assert_allclose(np.asarray(recording.rays.origins)[:, 0], EYES_OURS, atol=1e-6)
    # OpenCV's (−0.3, −0.1, 1.2) read as ours: x = −0.3, behind the camera
    with pytest.raises(ValueError, match="row 0: the eye centre .* is not in front of the camera .*" + OURS_EXPECTED
                                         + r".*eyes_opencv @ R_OURS_FROM_OPENCV\.T"):
        to_rays(EYES_OPENCV)
    # people to the camera's right in OpenCV ((0.3, −0.1, 1.2) …) read as ours: in front (x > 0), but 70°–79° up
    left = np.abs(EYES_OPENCV) * [1, -1, 1]
    with pytest.raises(ValueError, match=r"° above or below it, out of any camera.s view, as 3 of the 3 eyes do: eye positions are "
                                         + OURS_EXPECTED):
        to_rays(left)


def test_xgaze_arrays_in_opencv_axes_pass_and_ours_are_refused():
    rotations = np.broadcast_to(np.eye(3), (3, 3, 3))
    recording = xgaze_to_rays(ZERO, ZERO, EYES_OPENCV, R_normalizing=rotations)
    np.testing.assert_allclose(np.asarray(recording.rays.origins)[:, 0], EYES_OURS, atol=1e-6)
    # ours (1.2, 0.3, 0.1) read as OpenCV: depth 0.1 m with 1.2 m to the right, 85° off the axis
    with pytest.raises(ValueError, match="face_centers_opencv row 0: .*out of any camera's view.*" + OPENCV_EXPECTED):
        xgaze_to_rays(ZERO, ZERO, EYES_OURS, R_normalizing=rotations)


@pytest.mark.parametrize("read, header", [
    (read_gaze360, "frame,person_identity,yaw,pitch,var,person_eyes3d_x,person_eyes3d_y,person_eyes3d_z"),
    (read_l2cs, "frame,face,pitch,yaw,eye_x,eye_y,eye_z"),
])
def test_dump_csv_in_opencv_axes_passes_and_ours_is_refused(tmp_path, read, header):
    gaze = "0,0,0.1" if read is read_gaze360 else "0,0"

    def dump(eyes):
        rows = [f"{frame},p{frame},{gaze}," + ",".join(map(repr, eye)) for frame, eye in enumerate(eyes.tolist())]
        path = tmp_path / "dump.csv"
        path.write_text(header + "\n" + "\n".join(rows) + "\n")
        return path

    recording = read(dump(EYES_OPENCV))
    origins = np.asarray(recording.rays.origins)[np.asarray(recording.rays.mask)]
    np.testing.assert_allclose(np.sort(origins, axis=0), np.sort(EYES_OURS, axis=0), atol=1e-6)
    with pytest.raises(InputFileError, match=r"dump\.csv, line 2: the eye centre \(1\.2, 0\.3, 0\.1\) lies 85° from "
                                             r".*" + OPENCV_EXPECTED):
        read(dump(EYES_OURS))


def test_one_eye_out_of_view_among_plausible_ones_passes():
    # a lone detection 85° off the axis (in front of the camera) is odd but possible: the rule is about the majority
    eyes = np.vstack([EYES_OURS, [[0.1, 1.2, 0.0]]])
    assert eye_axes_problem(eyes, "ours") is None
    assert eye_axes_problem(eyes[[0, 3, 3]], "ours")[0] == 1  # most out of view: refused at the first of them
    with pytest.raises(ValueError, match="axes must be"):
        eye_axes_problem(eyes, "opengl")
