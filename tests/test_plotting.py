"""Figures of :mod:`jaxgaze.plotting`: built without error under Agg, with the expected artists."""

import io
import math
from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PathCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from jaxgaze import Concurrences, GazeRays, saliency_field_grid, track_concurrences
from jaxgaze.plotting import ELLIPSE_LEVEL, plot_counts, plot_scene_story, plot_top_view, plot_trajectories

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
          if name != "membership" and a is not None else a for name, a in conc._asdict().items())
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


def test_top_view_estimate_drawn_above_a_hollow_truth(frame):
    """The estimate is a filled dot above the truth, which is a hollow ring: neither hides the other."""
    rays, conc = frame
    fig = plot_top_view(rays, conc, truth=POINTS + 0.01, grid_shape=(24, 20, 10), inset=False)
    ax = fig.axes[0]
    (modes,) = by_gid(ax, "modes")
    (truth,) = by_gid(ax, "truth")
    assert modes.get_zorder() > truth.get_zorder()
    assert len(truth.get_facecolors()) == 0 and len(truth.get_edgecolors()) > 0  # unfilled
    assert np.all(modes.get_facecolors()[:, 3] == 1.0)
    assert ax.child_axes == []  # inset=False


def test_top_view_zoom_insets_show_the_ellipse_of_every_mode(frame):
    """The 90 % ellipses are centimetres across on a plot metres wide: an inset zooms on each mode
    so that its ellipse fills a good part of the inset, with a scale bar."""
    rays, conc = frame
    conc = conc._replace(num_rays=np.array([3, 4], np.int32))  # mode 1 has the most rays
    truth = POINTS + [[0.0, 0.0, 0.0], [0.03, -0.02, 0.0]]
    fig = plot_top_view(rays, conc, truth=truth, grid_shape=(24, 20, 10))
    ax = fig.axes[0]
    assert [z.get_gid() for z in ax.child_axes] == ["zoom", "zoom"]  # one per concurrence
    zoom = ax.child_axes[1]
    assert zoom.get_title() == "concurrence 1"
    (ellipse,) = [e for e in by_gid(zoom, "mode ellipse") if np.allclose(e.center, POINTS[1, :2], atol=1e-6)]
    (x0, x1), (y0, y1) = zoom.get_xlim(), zoom.get_ylim()
    half = max(ellipse.width, ellipse.height) / 2
    # the whole ellipse and the nearby truth are inside the inset, and the ellipse spans much of it
    assert x0 < POINTS[1, 0] - half and POINTS[1, 0] + half < x1 and y0 < POINTS[1, 1] - half < POINTS[1, 1] + half < y1
    assert x0 < truth[1, 0] < x1 and y0 < truth[1, 1] < y1
    assert 2 * half > 0.25 * (x1 - x0)
    main_width = np.diff(ax.get_xlim())[0]
    assert 2 * half < 0.05 * main_width  # too small to see in the main axes: hence the zoom
    (modes,) = by_gid(zoom, "modes")
    assert by_gid(zoom, "truth")[0].get_zorder() < modes.get_zorder()
    (bar,) = by_gid(zoom, "scale bar")
    label = bar.txt_label.get_text()
    assert label.endswith(" cm") and 0 < float(label.split()[0]) / 100 < (x1 - x0)
    fig.savefig(io.BytesIO(), format="png")


def test_scene_story_one_colour_scale_and_one_colorbar(frame):
    """The phase panels share one norm (the min and max of every panel's image), one colour bar and one legend."""
    rays, conc = frame
    targets = np.asarray(rays.origins) + np.asarray(rays.directions)
    sharp = GazeRays(EYES, targets - EYES, 0.02)  # phase 1: sharper cones, a higher field maximum
    T = 4
    over = Concurrences(*(None if a is None else np.stack([np.asarray(a)] * T) for a in conc))
    scene = SimpleNamespace(
        rays=GazeRays.stack([rays, rays, sharp, sharp]), concurrences=np.stack([POINTS] * T),
        concurrence_valid=np.ones((T, 2), bool), phase=np.array([0, 0, 1, 1]), fps=10.0, num_frames=T,
        name="two phases", num_people=len(EYES), true_count=np.full(T, 2),
    )
    fig = plot_scene_story(scene, over, track_concurrences(over))
    panels = [ax for ax in fig.axes if by_gid(ax, "saliency MIP")]
    assert len(panels) == 2
    images = [by_gid(ax, "saliency MIP")[0] for ax in panels]
    maxima = [float(np.max(im.get_array())) for im in images]
    assert maxima[1] > 1.5 * maxima[0]  # so separate scales would differ
    assert images[0].norm is images[1].norm
    assert images[0].get_clim() == pytest.approx((min(float(np.min(im.get_array())) for im in images), max(maxima)))
    colorbars = [ax for ax in fig.axes if getattr(ax, "_colorbar", None) is not None]
    assert len(colorbars) == 1 and colorbars[0]._colorbar.mappable.norm is images[0].norm
    zooms = [ax for ax in fig.axes if ax.get_gid() == "zoom"]
    assert len(zooms) == 4 and all(ax.child_axes == [] for ax in panels)  # a zoom per concurrence, beside the view
    legends = fig.legends + [ax.get_legend() for ax in panels + colorbars if ax.get_legend() is not None]
    assert all(ax.get_legend() is None for ax in panels) and len(legends) == 1  # one legend for the phases
    assert legends[0].axes is colorbars[0]  # above the colour bar, beside the panels
    fig.savefig(io.BytesIO(), format="png")


def _recording_figure():
    """plot_recording of the synthetic recording: frame 4 (shown) holds track 2 in slot 1, so a mode's index and
    its track differ there."""
    from jaxgaze.plotting import plot_recording

    conc, tracks = _synthetic_recording()
    T = len(np.asarray(conc.count))
    eyes = EYES[:6]
    rays = GazeRays.stack([GazeRays(eyes, np.asarray(conc.locations)[t, [0, 0, 0, 1, 1, 1]] - eyes, 0.05)
                           for t in range(T)])
    assert np.asarray(tracks.track_ids)[4].tolist() == [0, 2]
    return plot_recording(rays, conc, tracks), conc, tracks


def _top_views(fig):
    return [ax for ax in fig.axes if by_gid(ax, "saliency MIP")]


def test_recording_a_concurrence_has_its_track_colour_in_every_panel():
    """The same track is the same colour in the top views (dot, ellipse, zoom) and in the trajectory panel."""
    fig, conc, tracks = _recording_figure()
    (trajectory_ax,) = [ax for ax in fig.axes if by_gid(ax, "births")]
    trajectories = tracks.trajectories(conc)
    track_colour = {track: to_rgba(by_gid(trajectory_ax, f"track {track}")[0].get_color()) for track in trajectories}
    assert len(set(track_colour.values())) == 3
    checked = set()
    for ax in _top_views(fig):
        (modes,) = by_gid(ax, "modes")
        ellipses = by_gid(ax, "mode ellipse")
        for xy, face, ellipse in zip(modes.get_offsets(), modes.get_facecolors(), ellipses):
            # the track through this location
            (track,) = [k for k, traj in trajectories.items()
                        if np.any(np.all(np.isclose(traj["locations"][:, :2], xy, atol=1e-6), axis=1))]
            assert tuple(face) == pytest.approx(track_colour[track])
            assert to_rgba(ellipse.get_edgecolor()) == pytest.approx(track_colour[track])
            checked.add(track)
    assert checked == {0, 1, 2}  # track 2 is slot 1 of frame 4, where slot 1 was track 1 before
    for zoom in [ax for ax in fig.axes if ax.get_gid() == "zoom"]:
        (modes,) = by_gid(zoom, "modes")
        track = int(zoom.get_title().split()[-1])
        centre = np.mean([zoom.get_xlim(), zoom.get_ylim()], axis=1)
        (k,) = [k for k, xy in enumerate(modes.get_offsets()) if np.allclose(xy, centre, atol=1e-4)]
        assert tuple(modes.get_facecolors()[k]) == pytest.approx(track_colour[track])
    fig.savefig(io.BytesIO(), format="png")


def test_recording_every_concurrence_has_its_ellipse_in_its_panel_and_a_zoom():
    """Every concurrence of a shown frame has its 90 % ellipse in the top view itself and, since the ellipse is
    centimetres across on a view metres wide, a zoom of its own where the ellipse spans much of the window."""
    fig, conc, _ = _recording_figure()
    zooms = [ax for ax in fig.axes if ax.get_gid() == "zoom"]
    total = 0
    for ax in _top_views(fig):
        (modes,) = by_gid(ax, "modes")
        ellipses = by_gid(ax, "mode ellipse")
        assert len(ellipses) == len(modes.get_offsets()) > 0
        for xy, ellipse in zip(modes.get_offsets(), ellipses):
            np.testing.assert_allclose(ellipse.center, xy, atol=1e-6)
            (zoom,) = [z for z in zooms if any(np.allclose(e.center, xy, atol=1e-6) and
                                               z.get_xlim()[0] < xy[0] < z.get_xlim()[1] and
                                               z.get_ylim()[0] < xy[1] < z.get_ylim()[1]
                                               for e in by_gid(z, "mode ellipse"))]
            assert max(ellipse.width, ellipse.height) > 0.25 * np.diff(zoom.get_xlim())[0]
            total += 1
    assert total == len(zooms) == 6  # frames 0, 2 and 4, two concurrences each


def test_recording_colourbar_says_what_the_field_is_and_its_units_and_the_legend_is_beside_the_panels():
    fig, _, _ = _recording_figure()
    (colorbar,) = [ax for ax in fig.axes if getattr(ax, "_colorbar", None) is not None]
    label = colorbar.get_ylabel()
    assert "saliency" in label and "rad$^{-1}$" in label and "mean" in label  # what, units, normalisation
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    (legend,) = [lg for lg in legends if any(t.get_text().startswith("concurrence") for t in lg.get_texts())]
    box = legend.get_window_extent(renderer)
    row = [ax.get_window_extent(renderer) for ax in _top_views(fig) + [colorbar]]
    right, bottom, top = max(b.x1 for b in row), min(b.y0 for b in row), max(b.y1 for b in row)
    assert bottom < 0.5 * (box.y0 + box.y1) < top  # level with the top views, not above the figure's title
    assert box.x0 - right < 0.05 * fig.bbox.width
