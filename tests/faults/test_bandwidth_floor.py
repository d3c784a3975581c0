"""Issue 35, item 11: a bandwidth narrower than float32 resolves is an error, not a silent loss.

One ray at ≤ 1e-38 rad used to remove every concurrence of its frame (its ``1/2h²`` is
infinite in float32 and turns the frame's field into NaN), also those it does not support;
all rays at 1e-30 gave 0 concurrences, exit 0, no warning.
"""

import csv

import numpy as np
import pytest

from jaxgaze import GazeRays, find_concurrences, find_concurrences_over_frames
from jaxgaze.rays import MIN_BANDWIDTH
from tests.cli.helpers import assert_failed, run_main

TARGET = np.array([2.0, 0.0, 1.0])
EYES = np.array([[0.0, 0.0, 1.6], [2.0, 2.5, 1.6], [4.0, -1.0, 1.6], [0.0, -2.0, 1.6]])


def _frame(stray_bandwidth):
    """Three people look at TARGET; the fourth (ray 3) looks away with ``stray_bandwidth``."""
    directions = TARGET - EYES
    directions[3] = [0.0, -1.0, 0.0]
    return GazeRays(EYES, directions, np.array([0.03, 0.03, 0.03, stray_bandwidth], np.float32))


@pytest.mark.parametrize("h", [1e-38, 1e-30, 1e-7])
def test_library_refuses_a_bandwidth_below_float32_resolution(h):
    with pytest.raises(ValueError, match=r"bandwidth of ray 3 is .* narrower than float32"):
        find_concurrences(_frame(h))
    recording = GazeRays.stack([_frame(0.03), _frame(h)])
    with pytest.raises(ValueError, match=r"bandwidth of ray \(1, 3\) is"):
        find_concurrences_over_frames(recording)


def test_the_narrowest_accepted_bandwidth_keeps_the_other_rays_concurrence():
    found = find_concurrences(_frame(MIN_BANDWIDTH))
    assert len(found.locations) == 1
    np.testing.assert_allclose(np.asarray(found.locations[0]), TARGET, atol=1e-3)
    assert found.members(0).tolist() == [0, 1, 2]


@pytest.mark.parametrize("h", ["1e-30", "1e-38"])
def test_cli_refuses_a_tiny_bandwidth_with_one_line(tmp_path, capsys, h):
    path = tmp_path / "rays.csv"
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["frame", "person", "ox", "oy", "oz", "dx", "dy", "dz", "bandwidth"])
        for k, eye in enumerate(EYES[:3]):
            writer.writerow([0, f"p{k}", *eye, *(TARGET - eye), h])
    out = tmp_path / "out.csv"
    assert_failed(*run_main(capsys, ["concurrences", path, "--out", out]), "rays.csv:2", "narrower than float32")
    assert not out.exists()
    assert_failed(*run_main(capsys, ["concurrences", path, "--out", out, "--bandwidth", "1e-30"]),
                  "--bandwidth", "narrower than float32")
