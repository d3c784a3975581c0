"""The library's unit rule (issue 34, item 5): impossible values raise, implausible ones warn.

A value that cannot be right in its unit (a bandwidth of a radian or more) is a ``ValueError``;
one that is only implausible (positions in millimetres: a scene thousands of "metres" across) is
a :class:`jaxgaze.rays.UnitWarning`, and the computation goes on as given. The commands turn the
warning into exit 2 unless ``--trust-units`` (``tests/cli/test_units.py``).
"""

import warnings
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxgaze.bias import adapt_bias
from jaxgaze.io.gaze import read_gaze_csv
from jaxgaze.io.joint import read_speech
from jaxgaze.rays import PLAUSIBLE_SCENE_EXTENT, UnitWarning, check_bandwidth, check_distance

GAZE = Path(__file__).resolve().parents[1] / "examples" / "bias" / "ann_gaze.csv"
SPEECH = GAZE.parent / "dyad_segments.csv"


def test_check_distance_warns_beyond_the_scene_and_names_the_frame():
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        check_distance([0.5, PLAUSIBLE_SCENE_EXTENT, np.nan], "a distance")  # at the bound, and NaN: quiet
    with pytest.warns(UnitWarning, match=r"^a distance reaches 2500 m \(frame 12\), implausibly far for one scene "
                                         r"\(more than 100 m\): positions are in metres \(millimetres\?\)$"):
        check_distance([0.5, 2500.0, 3.0], "a distance", labels=[11, 12, 13])


def test_an_impossible_bandwidth_still_raises():
    with pytest.raises(ValueError, match="degrees"):
        check_bandwidth(3.0)


def test_adapt_bias_on_millimetres_warns_and_goes_on():
    """Directions only: the bias in millimetres is the one in metres, after one UnitWarning naming the frame."""
    track = read_gaze_csv(GAZE)
    segments = read_speech(SPEECH)
    args = (track.gaze_angles, track.R_world_from_head)
    rest = dict(partner="ben", frames=track.frame, method="mean", key=jax.random.key(0))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        metres = adapt_bias(*args, track.eye, track.target, track.time, segments, **rest)
    with pytest.warns(UnitWarning, match=r"the distance from the eyes to the target reaches \d+ m \(frame \d+\)"):
        millimetres = adapt_bias(*args, 1000 * track.eye, 1000 * track.target, track.time, segments, **rest)
    np.testing.assert_allclose(millimetres.bias, metres.bias, atol=1e-6)  # float32 directions
