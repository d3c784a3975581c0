"""Figures of :mod:`jaxgaze.plotting`: built without error under Agg, with the expected artists."""

import io
import math

import matplotlib
import numpy as np
import pytest
from matplotlib.collections import PathCollection
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from jaxgaze import Concurrences, GazeRays, saliency_field_grid, track_concurrences
from jaxgaze.plotting import ELLIPSE_LEVEL, plot_counts, plot_top_view, plot_trajectories

matplotlib.use("Agg")

POINTS = np.array([[1.0, 0.5, 1.0], [-1.5, 2.0, 0.8]])
EYES = np.array(
    [[2.6, 0.3, 1.6], [1.2, -1.2, 1.7], [-0.3, -0.4, 1.5], [-3.2, 1.6, 1.2], [-1.0, 3.6, 1.3], [-2.4, 3.5, 1.6],
     [0.0, 4.5, 1.6]]
)
LOOKS_AT = [0, 0, 0, 1, 1, 1, -1]  # the last person looks away from everyone


def _one_frame_concurrences():
    """What find_concurrences returns for this frame, with anisotropic covariances to draw."""
    rotation = np.array([[math.cos(0.5), -math.sin(0.5), 0.0], [math.sin(0.5), math.cos(0.5), 0.0], [0, 0, 1]])
    covariances = np.stack([rotation @ np.diag([4e-3, 1e-3, 2e-3]) @ rotation.T, np.diag([1e-3, 3e-3, 1e-3])])
    return Concurrences(
        locations=POINTS.astype(np.float32),
        covariances=covariances.astype(np.float32),
        field_values=np.array([5.0, 4.0], np.float32),
        num_rays=np.array([3, 3], np.int32),
        membership=np.array(LOOKS_AT, np.int32),
        region_axes=np.broadcast_to(np.eye(3, dtype=np.float32), (2, 3, 3)).copy(),
        region_semi_axes=np.full((2, 3), 0.1, np.float32),
        converged=np.ones(2, bool),
        valid=np.ones(2, bool),
        degrees_of_freedom=np.array([9.0, 11.0], np.float32),
    )


@pytest.fixture(scope="module")
def frame():
    targets = np.array([POINTS[k] if k >= 0 else [0.0, 9.0, 1.6] for k in LOOKS_AT])
    rays = GazeRays(EYES, targets - EYES, 0.05)
    return rays, _one_frame_concurrences()


def by_gid(ax, gid):
    return [a for a in ax.get_children() if a.get_gid() == gid]


def test_top_view_artists_and_mip(frame):
    rays, conc = frame
    assert len(conc.locations) == 2
    extent, z_range, shape = (-4.0, 4.0, -2.0, 5.0), (0.0, 2.0), (24, 20, 10)
    fig = plot_top_view(rays, conc, truth=POINTS, extent=extent, z_range=z_range, grid_shape=shape)
    assert isinstance(fig, Figure)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"

    # The image is max over z of the field on the same grid (rows = y, columns = x).
    (image,) = by_gid(ax, "saliency MIP")
    values, (xs, ys, zs) = saliency_field_grid(rays, [extent[0], extent[2], z_range[0]],
                                               [extent[1], extent[3], z_range[1]], shape)
    np.testing.assert_allclose(np.asarray(image.get_array()), np.max(np.asarray(values), axis=2).T, rtol=1e-6)
    assert image.origin == "lower"
    x0, x1, y0, y1 = image.get_extent()
    assert x0 < extent[0] < extent[1] < x1 and y0 < extent[2] < extent[3] < y1

    # Each ray is coloured like the mode it supports; the loner's ray is grey.
    ray_colours = [line.get_color() for line in by_gid(ax, "ray")]
    assert ray_colours[0] == ray_colours[1] == ray_colours[2] != ray_colours[3] == ray_colours[5]
    assert ray_colours[6] == "0.75"

    (modes,) = by_gid(ax, "modes")
    assert isinstance(modes, PathCollection)
    np.testing.assert_allclose(modes.get_offsets(), np.asarray(conc.locations)[:, :2], rtol=1e-6)
    (truth,) = by_gid(ax, "truth")
    np.testing.assert_allclose(truth.get_offsets(), POINTS[:, :2])
    (eyes,) = by_gid(ax, "eyes")
    assert len(eyes.get_offsets()) == len(EYES)
    assert len(by_gid(ax, "ray")) == len(EYES)

    ellipses = by_gid(ax, "mode ellipse")
    assert len(ellipses) == 2 and all(isinstance(e, Ellipse) for e in ellipses)
    for ellipse, loc, cov in zip(ellipses, np.asarray(conc.locations), np.asarray(conc.covariances)):
        np.testing.assert_allclose(ellipse.center, loc[:2], rtol=1e-6)
        eig = np.linalg.eigvalsh(cov[:2, :2])
        scale = 2.0 * math.sqrt(-2.0 * math.log(1.0 - ELLIPSE_LEVEL))
        np.testing.assert_allclose(sorted([ellipse.width, ellipse.height]), scale * np.sqrt(eig), rtol=1e-4)
    # The first covariance's long axis is rotated by 0.5 rad.
    assert ellipses[0].width > ellipses[0].height
    assert math.isclose(ellipses[0].angle % 180.0, math.degrees(0.5), abs_tol=1e-3)
    fig.savefig(io.BytesIO(), format="png")


def test_top_view_padded_frame_none_and_given_axes(frame):
    rays, conc = frame
    # A padded frame of find_concurrences_over_frames: invalid slots are not drawn.
    padded = Concurrences(
        *(np.concatenate([np.asarray(a), np.zeros((1,) + np.asarray(a).shape[1:], np.asarray(a).dtype)])
          if name != "membership" else np.asarray(a) for name, a in conc._asdict().items())
    )
    assert padded.valid.tolist() == [True, True, False]
    fig = Figure()
    axes = fig.subplots(1, 2)
    assert plot_top_view(rays, padded, ax=axes[0], grid_shape=(24, 20, 10), colorbar=False) is fig
    assert len(by_gid(axes[0], "modes")[0].get_offsets()) == 2
    assert len(by_gid(axes[0], "mode ellipse")) == 2

    plot_top_view(rays, None, ax=axes[1], grid_shape=(24, 20, 10), colorbar=False)
    assert len(by_gid(axes[1], "modes")[0].get_offsets()) == 0
    assert by_gid(axes[1], "truth") == []
    fig.savefig(io.BytesIO(), format="png")


def test_top_view_rejects_a_recording(frame):
    rays, _ = frame
    recording = GazeRays.stack([rays, rays])
    with pytest.raises(ValueError, match="one frame"):
        plot_top_view(recording, None)


def _synthetic_recording():
    """6 frames: track A throughout, track B dies after frame 2, track C born at frame 4."""
    T, K = 6, 2
    locations = np.zeros((T, K, 3), np.float32)
    valid = np.zeros((T, K), bool)
    for t in range(T):
        locations[t, 0] = [0.1 * t, 0.0, 1.0]
        valid[t, 0] = True
        if t <= 2:
            locations[t, 1] = [3.0, 0.05 * t, 1.0]
            valid[t, 1] = True
        if t >= 4:
            locations[t, 1] = [-3.0, 2.0 + 0.05 * t, 1.0]
            valid[t, 1] = True
    conc = Concurrences(
        locations=locations,
        covariances=np.broadcast_to(np.eye(3, dtype=np.float32) * 1e-3, (T, K, 3, 3)).copy(),
        field_values=(np.where(valid, 1.0, 0.0) - 0.1 * np.arange(K)).astype(np.float32),
        num_rays=np.where(valid, 3, 0),
        membership=np.full((T, 6), -1),
        region_axes=np.broadcast_to(np.eye(3, dtype=np.float32), (T, K, 3, 3)).copy(),
        region_semi_axes=np.ones((T, K, 3), np.float32),
        converged=valid.copy(),
        valid=valid,
    )
    return conc, track_concurrences(conc, max_distance=0.5, max_gap=0)


def test_trajectories():
    conc, tracks = _synthetic_recording()
    assert int(tracks.num_tracks) == 3
    fig = plot_trajectories(conc, tracks)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    trajectories = tracks.trajectories(conc)
    for track, traj in trajectories.items():
        (line,) = by_gid(ax, f"track {track}")
        np.testing.assert_allclose(np.column_stack(line.get_data()), traj["locations"][:, :2])
        (points,) = by_gid(ax, f"track {track} points")
        alpha = points.get_facecolors()[:, 3]
        assert len(alpha) == len(traj["frames"]) and np.all(np.diff(alpha) > 0)  # later = more opaque
    (births,) = by_gid(ax, "births")
    (deaths,) = by_gid(ax, "deaths")
    assert len(births.get_offsets()) == 3
    assert len(deaths.get_offsets()) == 1  # only the track that ends before the last frame
    np.testing.assert_allclose(deaths.get_offsets()[0], [3.0, 0.1])
    fig.savefig(io.BytesIO(), format="png")


def test_counts():
    counts, truth = np.array([2, 2, 1, 1, 3]), np.array([2, 2, 1, 2, 2])
    fig = plot_counts(counts, truth)
    ax = fig.axes[0]
    (k,) = by_gid(ax, "K")
    (true_k,) = by_gid(ax, "true K")
    np.testing.assert_array_equal(k.get_ydata(), counts)
    np.testing.assert_array_equal(true_k.get_ydata(), truth)
    assert "60%" in ax.get_title()
    assert ax.get_xlabel() == "frame"
    fig = plot_counts(counts, fps=10.0)
    assert fig.axes[0].get_xlabel() == "time (s)" and by_gid(fig.axes[0], "true K") == []
    with pytest.raises(ValueError, match="shape"):
        plot_counts(counts, truth[:3])
