"""Figures for gaze rays, the social saliency field and gaze concurrences.

All functions draw with matplotlib's object API (no ``pyplot`` state is
needed, so they work under the non-interactive ``Agg`` backend), accept an
optional ``ax`` to draw into, and return the :class:`~matplotlib.figure.Figure`.
Positions are world-frame metres; the top view looks down the ``z`` axis.

Artists carry a ``gid`` (``artist.get_gid()``) so that figures can be inspected programmatically:
``"modes"`` (one marker per concurrence), ``"truth"``, ``"eyes"``,
``"mode ellipse"`` (one patch per concurrence), ``"saliency MIP"`` (the image),
``"mode label"`` (the track id beside each concurrence), ``"ray"``, ``"zoom"`` (one axes per concurrence
holding its own ``"mode ellipse"``, ``"modes"``, ``"truth"``, ``"ray"`` and ``"scale bar"``, titled by its
track), ``"births"``, ``"deaths"``, ``"track <id>"``, ``"track <id> points"``, ``"K"`` and ``"true K"``.
A concurrence has its track's colour (``C<id mod 10>``) in every panel, and each frame's ids come from
``tracks.track_ids[t]``.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.colors import Normalize, to_rgba
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.patches import Ellipse
from matplotlib.patheffects import withStroke
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from jaxgaze.cone import max_intensity_projection, saliency_field_grid
from jaxgaze.rays import GazeRays

__all__ = ["plot_top_view", "plot_trajectories", "plot_counts", "plot_scene_story", "plot_recording", "share_colour_scale",
           "top_view_bounds", "ELLIPSE_LEVEL", "FIELD_LABEL"]

#: Probability mass inside the drawn covariance ellipses.
ELLIPSE_LEVEL = 0.9
# Quantile of the chi-square distribution with 2 degrees of freedom: -2 log(1 - p).
_CHI2_2DOF = -2.0 * math.log(1.0 - ELLIPSE_LEVEL)

#: The colour bar's label: the field ``f = (1/N) Σ_i K_i`` (Park et al. 2012, eq. 3) of ``N`` rays, each kernel
#: ``K_i = exp(−‖d_i‖²/2h_i²) / (h_i √2π)`` per radian of the perspective distance ``d_i`` (:func:`~jaxgaze.ray_kernels`).
FIELD_LABEL = "max$_z$ saliency $f$ (rad$^{-1}$):\nmean of the $N$ rays' cone kernels"

_TRUTH_COLOUR = "cyan"
# Draw order: the estimate (a filled dot) above the truth (a hollow ring), so neither hides the other.
_TRUTH_ZORDER, _MODE_ZORDER = 5, 6
# The zoom insets (a row along the top or bottom edge) and the legend go where they cover the fewest drawn points.
_INSET_SIZE = 0.3
_LEGEND_SIZE = (0.6, 0.2)
_CORNERS = ("upper right", "upper left", "lower right", "lower left")


def _new_axes(ax, figsize=(6.0, 5.0)):
    if ax is not None:
        return ax.figure, ax
    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.add_subplot()


def _valid_modes(concurrences):
    """Host arrays ``(locations (K,3), covariances (K,3,3), membership (N,) or None, num_rays (K,))`` of one frame."""
    if concurrences is None:
        return np.zeros((0, 3)), np.zeros((0, 3, 3)), None, np.zeros(0, int)
    locations = np.asarray(concurrences.locations, dtype=float)
    if locations.ndim != 2:
        raise ValueError(
            f"plot_top_view: concurrences must be one frame (K, 3), got locations of shape {locations.shape}; "
            "use concurrences.frame(t)"
        )
    covariances = np.asarray(concurrences.covariances, dtype=float)
    valid = np.asarray(concurrences.valid, dtype=bool)
    membership = np.asarray(concurrences.membership)
    num_rays = np.asarray(concurrences.num_rays).reshape(-1)
    if valid.shape == (locations.shape[0],) and not valid.all():
        # A padded frame: keep the valid modes; membership indices stay valid
        # because the real modes come first.
        locations, covariances, num_rays = locations[valid], covariances[valid], num_rays[valid]
    return locations, covariances, membership, num_rays


def top_view_bounds(rays: GazeRays, points=None, margin: float = 0.5):
    """Default box ``(lower, upper)`` for :func:`plot_top_view`: the eyes and ``points`` plus ``margin`` metres.

    The z range always includes the floor (``z = 0``) up to just above the eyes.
    """
    origins = np.asarray(rays.origins, dtype=float)[np.asarray(rays.mask, dtype=bool)]
    pts = [origins.reshape(-1, 3)]
    if points is not None:
        pts.append(np.asarray(points, dtype=float).reshape(-1, 3))
    pts = np.concatenate(pts, axis=0)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 3))
    lower = pts.min(axis=0) - margin
    upper = pts.max(axis=0) + margin
    lower[2] = min(lower[2], 0.0)
    upper[2] = max(upper[2], lower[2] + 2.0 * margin)
    return lower, upper


def plot_top_view(
    rays_one_frame: GazeRays,
    concurrences_one_frame=None,
    truth=None,
    ax=None,
    extent=None,
    *,
    track_ids=None,
    z_range=None,
    grid_shape=(96, 96, 32),
    ray_length=None,
    title=None,
    colorbar=True,
    inset=True,
):
    """Top view of one frame: the saliency field's maximum-intensity projection, rays, modes and truth.

    Args:
        rays_one_frame: the frame's primary gaze rays, ``(N, 3)`` (world frame, m).
        concurrences_one_frame: :class:`~jaxgaze.Concurrences` of that frame
            (``find_concurrences`` or ``Concurrences.frame(t)``; padded modes
            are dropped via ``valid``), or ``None``.
        truth: optional ``(M, 3)`` true concurrence locations, drawn as hollow rings.
        ax: axes to draw into; a new figure is made if ``None``.
        extent: ``(xmin, xmax, ymin, ymax)`` in metres; by default the eyes,
            modes and truth plus a 0.5 m margin.
        track_ids: the track of each concurrence (``tracks.track_ids[t]``, padding ``−1``
            dropped), so that it has its track's colour and label as in :func:`plot_trajectories`;
            by default its index ``k`` in the frame.
        z_range: ``(zmin, zmax)`` of the projected slab; by default from the
            floor to just above the highest eye, mode or truth.
        grid_shape: ``(nx, ny, nz)`` grid on which ``f`` is evaluated
            (:func:`~jaxgaze.saliency_field_grid`); the image is its maximum over z.
        ray_length: length (m) of the drawn rays; by default the box diagonal.
        title: axes title.
        colorbar: add a colour bar for ``f`` (labelled :data:`FIELD_LABEL`).
        inset: ``True`` for a zoom inset (gid ``"zoom"``) on every concurrence, in a row along the
            top or bottom edge, whichever hides less; ``False`` for none; or axes to draw the
            zooms in, one per concurrence (as :func:`plot_recording` does, beside the view).

    The image is ``max_z f(x, y, z)`` shown with ``origin="lower"``, so
    ``image[j, i]`` is the cell at ``(xs[i], ys[j])``. Each mode is a filled dot
    with the ellipse holding 90 % of its Laplace posterior projected onto xy
    (the marginal of ``covariances[:2, :2]``, ``χ²₂`` quantile), labelled by its track;
    the truth is a hollow ring drawn below the dots. Rays are drawn from the eye centres,
    coloured by the mode they support (grey for none). The ellipses are
    centimetres across on a plot metres wide, so each zoom shows one of them at
    a scale where it is visible, with its rays, the nearby truth and a scale bar.
    """
    if not isinstance(rays_one_frame, GazeRays) or rays_one_frame.batch_shape:
        raise ValueError("plot_top_view: rays_one_frame must be one frame of GazeRays, shape (N, 3); use rays[t]")
    locations, covariances, membership, num_rays = _valid_modes(concurrences_one_frame)
    truth_np = np.zeros((0, 3)) if truth is None else np.asarray(truth, dtype=float).reshape(-1, 3)
    if track_ids is None:
        tracks = np.arange(len(locations))
    else:
        tracks = np.asarray(track_ids).reshape(-1)
        tracks = tracks[tracks >= 0]
        if len(tracks) != len(locations):
            raise ValueError(f"plot_top_view: track_ids has {len(tracks)} tracks (−1 dropped) for "
                             f"{len(locations)} concurrences; pass tracks.track_ids[t]")

    lower, upper = top_view_bounds(rays_one_frame, np.concatenate([locations, truth_np], axis=0))
    if extent is not None:
        if len(extent) != 4:
            raise ValueError(f"plot_top_view: extent must be (xmin, xmax, ymin, ymax), got {extent}")
        lower[:2] = extent[0], extent[2]
        upper[:2] = extent[1], extent[3]
    if z_range is not None:
        lower[2], upper[2] = z_range

    fig, ax = _new_axes(ax)
    values, (xs, ys, _) = saliency_field_grid(rays_one_frame, lower, upper, tuple(grid_shape))
    mip = np.asarray(max_intensity_projection(values, axis=2))
    dx = float(xs[1] - xs[0]) if len(xs) > 1 else 1.0
    dy = float(ys[1] - ys[0]) if len(ys) > 1 else 1.0
    image = ax.imshow(
        mip.T,
        origin="lower",
        extent=(lower[0] - dx / 2, upper[0] + dx / 2, lower[1] - dy / 2, upper[1] + dy / 2),
        cmap="magma",
        interpolation="nearest",
        aspect="equal",
        gid="saliency MIP",
    )
    if colorbar:
        fig.colorbar(image, ax=ax, shrink=0.8, label=FIELD_LABEL)
    ax.set_xlim(lower[0] - dx / 2, upper[0] + dx / 2)
    ax.set_ylim(lower[1] - dy / 2, upper[1] + dy / 2)

    mask = np.asarray(rays_one_frame.mask, dtype=bool)
    origins = np.asarray(rays_one_frame.origins, dtype=float)[mask]
    directions = np.asarray(rays_one_frame.directions, dtype=float)[mask]
    length = float(np.linalg.norm(upper - lower)) if ray_length is None else float(ray_length)
    member = membership[mask] if membership is not None and membership.shape == mask.shape else None
    mode_colours = [_track_colour(track) for track in tracks]
    ray_colours = [mode_colours[k] if 0 <= k < len(locations) else "0.75"
                   for k in (np.full(len(origins), -1) if member is None else member.astype(int))]
    _draw_rays(ax, origins, directions, ray_colours, length)
    if len(origins):
        ax.quiver(
            origins[:, 0], origins[:, 1], directions[:, 0], directions[:, 1],
            color="white", angles="xy", scale_units="inches", scale=3.0, width=0.006, gid="gaze",
        )
        ax.scatter(origins[:, 0], origins[:, 1], s=25, c="white", edgecolors="black", zorder=3, gid="eyes")
    _draw_modes(ax, locations, covariances, truth_np, mode_colours, truth is not None, size=1.0)
    for loc, track, colour in zip(locations, tracks, mode_colours):
        ax.annotate(str(int(track)), loc[:2], xytext=(5, 4), textcoords="offset points", color=colour,
                    fontsize="small", fontweight="bold", zorder=_MODE_ZORDER, gid="mode label",
                    path_effects=[withStroke(linewidth=2.5, foreground="black")])

    # What an inset or the legend should not hide: the concurrences and the truth most, then the eyes.
    drawn, corners = [(origins[:, :2], 1), (locations[:, :2], 5), (truth_np[:, :2], 5)], _CORNERS
    if inset is not True and inset is not False:  # the caller's axes, one per concurrence
        if len(inset) < len(locations):
            raise ValueError(f"plot_top_view: {len(inset)} zoom axes for {len(locations)} concurrences")
        for k, box in enumerate(inset[: len(locations)]):
            box.set_gid("zoom")
            _draw_zoom(box, k, locations, covariances, truth_np, origins, directions, ray_colours, mode_colours,
                       length, f"track {int(tracks[k])}" if track_ids is not None else f"concurrence {k}")
    elif inset and len(locations):
        size = min(_INSET_SIZE, 0.96 / len(locations))
        edge = _free_corners(ax, drawn, (1.0, size), ("upper left", "lower left"))[0].split()[0]
        for k in range(len(locations)):
            x0 = 0.5 - 0.5 * len(locations) * size + k * size
            box = ax.inset_axes((x0 + 0.01, 0.98 - size if edge == "upper" else 0.02, size - 0.02, size - 0.02),
                                gid="zoom")
            _draw_zoom(box, k, locations, covariances, truth_np, origins, directions, ray_colours, mode_colours,
                       length, f"track {int(tracks[k])}" if track_ids is not None else f"concurrence {k}")
        corners = [c for c in _CORNERS if not c.startswith(edge)]
    if len(locations) or len(truth_np):
        ax.legend(fontsize="small", loc=_free_corners(ax, drawn, _LEGEND_SIZE, corners)[0], framealpha=0.6)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title if title is not None else f"top view: {len(locations)} concurrence(s)")
    return fig


def _draw_rays(ax, origins, directions, colours, length):
    """A line from each eye centre along the xy projection of its direction ``v``."""
    for o, d, colour in zip(origins, directions, colours):
        end = o + length * d
        ax.plot([o[0], end[0]], [o[1], end[1]], color=colour, lw=0.8, alpha=0.7, gid="ray")


def _draw_modes(ax, locations, covariances, truth, colours, with_truth: bool, size: float):
    """The modes (filled dots) with their ``ELLIPSE_LEVEL`` ellipses in xy, above the truth (hollow rings)."""
    for k, (loc, cov) in enumerate(zip(locations, covariances)):
        width, height, angle = _ellipse_params(cov[:2, :2])
        ax.add_patch(Ellipse(loc[:2], width, height, angle=angle, fill=False, ec=colours[k], lw=1.5,
                             gid="mode ellipse", zorder=_MODE_ZORDER - 0.5))
    if with_truth:
        ax.scatter(truth[:, 0], truth[:, 1], s=110 * size, marker="o", facecolors="none", edgecolors=_TRUTH_COLOUR,
                   linewidths=1.8, zorder=_TRUTH_ZORDER, gid="truth", label="truth" if len(truth) else "_truth")
    ax.scatter(locations[:, 0], locations[:, 1], s=40 * size, marker="o", c=colours[: len(locations)] or None,
               edgecolors="black", zorder=_MODE_ZORDER, gid="modes",
               label=f"concurrence, its track id\n({ELLIPSE_LEVEL:.0%} ellipse: zoom)" if len(locations) else "_modes")


def _corner_box(corner: str, size) -> tuple[float, float, float, float]:
    """``(x0, y0, width, height)`` in axes fraction of a box of ``size`` in ``corner``, 2 % from the edges."""
    width, height = size
    x0 = 0.98 - width if corner.endswith("right") else 0.02
    y0 = 0.98 - height if corner.startswith("upper") else 0.02
    return x0, y0, width, height


def _free_corners(ax, points, size, corners=_CORNERS) -> list:
    """``corners`` sorted by the weight of the drawn ``points`` (``[(xy (n, 2) data, weight)]``) that a box
    of ``size`` there would cover; ties keep their order."""
    xy = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 2) for p, _ in points], axis=0)
    weights = np.concatenate([np.full(len(np.asarray(p).reshape(-1, 2)), float(w)) for p, w in points])
    fraction = ax.transLimits.transform(xy) if len(xy) else np.zeros((0, 2))

    def crowd(corner):
        x0, y0, width, height = _corner_box(corner, size)
        inside = (fraction >= [x0 - 0.05, y0 - 0.05]) & (fraction <= [x0 + width + 0.05, y0 + height + 0.05])
        return float(weights[np.all(inside, axis=1)].sum())

    return sorted(corners, key=crowd)


def _draw_zoom(box, k, locations, covariances, truth, origins, directions, ray_colours, mode_colours, length, label):
    """Mode ``k`` at a scale where its ellipse shows: its window is ``1.6 ×`` the larger of the
    ellipse's semi-major axis and the distance to the nearest truth (if that is within 0.5 m),
    at least 2 cm; a scale bar of 1, 2 or 5 × 10ⁿ cm, about a third of the window. The frame
    and the title ``label`` have the mode's colour."""
    width, height, _ = _ellipse_params(covariances[k][:2, :2])
    centre = locations[k, :2]
    near = np.linalg.norm(truth[:, :2] - centre, axis=1) if len(truth) else np.zeros(0)
    reach = max(0.5 * max(width, height), float(near.min()) if len(near) and near.min() < 0.5 else 0.0)
    half = max(1.6 * reach, 0.02)
    box.set_facecolor("black")
    _draw_rays(box, origins, directions, ray_colours, length)
    _draw_modes(box, locations, covariances, truth, mode_colours, len(truth) > 0, size=1.4)
    box.set_xlim(centre[0] - half, centre[0] + half)
    box.set_ylim(centre[1] - half, centre[1] + half)
    box.set_aspect("equal", adjustable="box")
    box.set_xticks([])
    box.set_yticks([])
    for spine in box.spines.values():
        spine.set(edgecolor=mode_colours[k], linewidth=2.0)
    box.set_title(label, color=mode_colours[k], fontsize="small", fontweight="bold", pad=2)
    step = 10.0 ** math.floor(math.log10(2.0 * half / 3.0))
    bar = max(m * step for m in (1.0, 2.0, 5.0) if m * step <= 2.0 * half / 3.0)
    text = f"{100 * bar:g} cm" if bar < 1.0 else f"{bar:g} m"
    scale = AnchoredSizeBar(box.transData, bar, text, "lower right", color="white", frameon=False,
                            size_vertical=0, pad=0.3, sep=3, fontproperties=FontProperties(size="x-small"))
    scale.set_gid("scale bar")
    box.add_artist(scale)


def _ellipse_params(cov_xy: np.ndarray):
    """Full width, height (m) and angle (degrees) of the ``ELLIPSE_LEVEL`` ellipse of a 2×2 covariance."""
    cov_xy = 0.5 * (cov_xy + cov_xy.T)
    if not np.all(np.isfinite(cov_xy)):
        return 0.0, 0.0, 0.0
    eigvals, eigvecs = np.linalg.eigh(cov_xy)
    eigvals = np.clip(eigvals, 0.0, None)
    width, height = 2.0 * np.sqrt(_CHI2_2DOF * eigvals[::-1])
    angle = math.degrees(math.atan2(eigvecs[1, -1], eigvecs[0, -1]))
    return float(width), float(height), angle


def _track_colour(track: int):
    """The colour of track ``track`` in every panel: ``C<track mod 10>``."""
    return to_rgba(f"C{int(track) % 10}")


def plot_trajectories(concurrences_over_frames, tracks, ax=None, *, fps=None, title=None):
    """Top view (xy) of concurrence trajectories, one colour per track, time as opacity.

    Args:
        concurrences_over_frames: padded ``(T, K)`` result of
            :func:`~jaxgaze.find_concurrences_over_frames`.
        tracks: :class:`~jaxgaze.Tracks` from :func:`~jaxgaze.track_concurrences`.
        ax: axes to draw into; a new figure is made if ``None``.
        fps: if given, the legend gives birth and death times in seconds.
        title: axes title.

    Each track is a line through its locations plus one dot per frame whose
    opacity grows from 0.15 (frame 0) to 1 (last frame). A triangle marks each
    birth (first frame of a track, collection ``"births"``) and a cross each
    death (last frame of a track that ends before the recording does, ``"deaths"``).
    """
    fig, ax = _new_axes(ax)
    trajectories = tracks.trajectories(concurrences_over_frames)
    num_frames = int(np.asarray(concurrences_over_frames.locations).shape[0])
    last = max(num_frames - 1, 1)
    births, deaths = [], []
    for track, traj in trajectories.items():
        colour = _track_colour(track)
        xy = np.asarray(traj["locations"], dtype=float)[:, :2]
        frames = np.asarray(traj["frames"])
        if fps:
            span = f"{traj['birth'] / fps:.1f}–{traj['death'] / fps:.1f} s"
        else:
            span = f"frames {traj['birth']}–{traj['death']}"
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.0, alpha=0.6, label=f"track {track} ({span})",
                gid=f"track {track}")
        rgba = np.tile(np.asarray(colour), (len(frames), 1))
        rgba[:, 3] = 0.15 + 0.85 * frames / last
        ax.scatter(xy[:, 0], xy[:, 1], s=12, c=rgba, edgecolors="none", gid=f"track {track} points")
        births.append((xy[0], colour))
        if traj["death"] < num_frames - 1:
            deaths.append((xy[-1], colour))
    for points, marker, name in ((births, "^", "births"), (deaths, "X", "deaths")):
        xy = np.array([p for p, _ in points]).reshape(-1, 2)
        ax.scatter(xy[:, 0], xy[:, 1], s=80, marker=marker, c=[c for _, c in points] or None,
                   edgecolors="black", zorder=5, gid=name, label=name if points else f"_{name}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title if title is not None else f"trajectories: {len(trajectories)} track(s), {num_frames} frames")
    if trajectories:
        ax.legend(fontsize="small", loc="best")
    return fig


def plot_counts(counts, true_counts=None, ax=None, *, fps=None, title=None):
    """Number of concurrences ``K`` per frame, with the true count if known.

    ``counts`` and ``true_counts`` are ``(T,)``. With ``fps`` the x axis is time (s).
    """
    fig, ax = _new_axes(ax, figsize=(6.0, 3.0))
    counts = np.asarray(counts).reshape(-1)
    t = np.arange(len(counts), dtype=float)
    if fps:
        t = t / fps
    if true_counts is not None:
        true_counts = np.asarray(true_counts).reshape(-1)
        if true_counts.shape != counts.shape:
            raise ValueError(f"plot_counts: true_counts shape {true_counts.shape} must match counts {counts.shape}")
    ax.step(t, counts, where="mid", color="tab:blue", lw=2.5, alpha=0.8, label="K", gid="K")
    if true_counts is not None:  # on top, dashed, so that both show where they agree
        ax.step(t, true_counts, where="mid", color="black", ls="--", lw=1.2, label="true K", gid="true K")
    top = max(int(counts.max(initial=0)), int(true_counts.max(initial=0)) if true_counts is not None else 0)
    ax.set_ylim(-0.3, top + 0.7)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("time (s)" if fps else "frame")
    ax.set_ylabel("number of concurrences K")
    if true_counts is not None:
        ax.set_title(title if title is not None else f"count correct in {np.mean(counts == true_counts):.0%} of frames")
        ax.legend(fontsize="small", loc="best")
    elif title is not None:
        ax.set_title(title)
    return fig


def share_colour_scale(fig: Figure, panels) -> None:
    """Put the top views ``panels`` (of :func:`plot_top_view`, drawn with ``colorbar=False``) on one
    colour scale, ``[min, max]`` of all their images, with one colour bar (:data:`FIELD_LABEL`) and one
    legend for them all, the legend just above the colour bar beside the panels: the same ``f`` is then
    the same colour in every panel."""
    images = [a for ax in panels for a in ax.get_images() if a.get_gid() == "saliency MIP"]
    if not images:
        raise ValueError("share_colour_scale: no top view (saliency MIP image) among the panels")
    norm = Normalize(min(float(np.min(im.get_array())) for im in images),
                     max(float(np.max(im.get_array())) for im in images))
    for image in images:
        image.set_norm(norm)
    with_legend = [ax for ax in panels if ax.get_legend() is not None]
    colorbar = fig.colorbar(images[0], ax=list(panels), shrink=0.65 if with_legend else 0.9, anchor=(0.0, 0.0))
    colorbar.set_label(FIELD_LABEL, fontsize="small")
    if with_legend:  # one legend for all the panels, on the colour bar's axes so that the layout makes room
        handles, labels = with_legend[0].get_legend_handles_labels()
        for ax in with_legend:
            ax.get_legend().remove()
        colorbar.ax.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.0, 1.03), fontsize="small",
                           borderaxespad=0.0)


def _top_view_row(fig, shown, rays, concurrences, tracks, truths, titles, lower, upper):
    """A grid of three rows: the top views of frames ``shown`` (row 0), on one colour scale, with a
    zoom per concurrence below each (row 1, in the same grid so that the columns line up), every
    concurrence in its track's colour; row 2 is left for the caller. Returns the grid and the column
    that splits row 2 in halves."""
    ids, valid = np.asarray(tracks.track_ids), np.asarray(concurrences.valid)
    columns = max(2, max(int(valid[t].sum()) for t in shown))  # per view: one zoom each
    width = max(len(shown), 2)
    grid = fig.add_gridspec(3, width * columns, height_ratios=(2.6, 1.2, 3.4))
    panels = []
    for i, t in enumerate(shown):
        one = concurrences.frame(t)
        panels.append(fig.add_subplot(grid[0, columns * i:columns * (i + 1)]))
        zooms = [fig.add_subplot(grid[1, columns * i + k]) for k in range(len(one.locations))]
        plot_top_view(rays[t], one, truth=truths[i], ax=panels[-1], extent=(lower[0], upper[0], lower[1], upper[1]),
                      track_ids=ids[t][valid[t]], z_range=(lower[2], upper[2]), grid_shape=(96, 64, 24),
                      colorbar=False, inset=zooms, title=titles[i])
    share_colour_scale(fig, panels)
    return grid, width * columns // 2


def plot_scene_story(scene, concurrences, tracks) -> Figure:
    """One figure for a simulated recording with truth (a :class:`jaxgaze.simulate.Scene`): the
    top view of the middle frame of every phase of its story, on one colour scale with one colour bar
    and a zoom on each concurrence's 90 % ellipse, the trajectories and the counts; a concurrence has
    its track's colour in every panel."""
    truth, truth_valid, phase = (np.asarray(x) for x in (scene.concurrences, scene.concurrence_valid, scene.phase))
    shown = [(int(p), int(np.flatnonzero(phase == p)[np.sum(phase == p) // 2])) for p in dict.fromkeys(phase.tolist())]
    lower, upper = top_view_bounds(scene.rays, truth.reshape(-1, 3), margin=0.6)
    width = max(len(shown), 2)
    fig = Figure(figsize=(4.6 * width, 9.6), layout="constrained")
    counts = np.asarray(concurrences.count)
    titles = [f"phase {p}: frame {t} (t = {t / scene.fps:.1f} s)\nK = {counts[t]}, true K = {int(truth_valid[t].sum())}"
              for p, t in shown]
    grid, half = _top_view_row(fig, [t for _, t in shown], scene.rays, concurrences, tracks,
                               [truth[t][truth_valid[t]] for _, t in shown], titles, lower, upper)
    plot_trajectories(concurrences, tracks, ax=fig.add_subplot(grid[2, :half]), fps=scene.fps)
    plot_counts(counts, np.asarray(scene.true_count), ax=fig.add_subplot(grid[2, half:]), fps=scene.fps)
    fig.suptitle(f"jaxgaze demo: simulated '{scene.name}' scene, {scene.num_frames} frames, {scene.num_people} people",
                 x=0.02, ha="left")
    return fig


def _shown_frames(counts: np.ndarray, panels: int = 3) -> list[int]:
    """One frame per equal part of the recording (up to ``panels``): the first with that part's most concurrences."""
    parts = [part for part in np.array_split(np.arange(len(counts)), min(panels, len(counts))) if len(part)]
    return [int(part[np.argmax(counts[part])]) for part in parts]


def plot_recording(rays: GazeRays, concurrences, tracks, frame_ids=None, *, title: str | None = None) -> Figure:
    """One figure for a recording without truth (``(T, N)`` rays and their padded concurrences): top
    views of up to three frames, one per third of the recording, the one with most concurrences, on
    one colour scale with a zoom on each concurrence's 90 % ellipse; the trajectories and the count
    per frame. A concurrence has its track's colour in every panel. ``frame_ids`` label the frames
    (default their rows ``0 … T−1``)."""
    counts = np.asarray(concurrences.count)
    frame_ids = list(range(len(counts))) if frame_ids is None else list(frame_ids)
    valid = np.asarray(concurrences.valid)
    lower, upper = top_view_bounds(rays, np.asarray(concurrences.locations)[valid], margin=0.6)
    shown = _shown_frames(counts)
    width = max(len(shown), 2)
    fig = Figure(figsize=(4.6 * width, 9.6), layout="constrained")
    grid, half = _top_view_row(fig, shown, rays, concurrences, tracks, [None] * len(shown),
                               [f"frame {frame_ids[t]}: K = {counts[t]}" for t in shown], lower, upper)
    plot_trajectories(concurrences, tracks, ax=fig.add_subplot(grid[2, :half]))
    plot_counts(counts, ax=fig.add_subplot(grid[2, half:]), title="concurrences per frame (row of the input)")
    fig.suptitle(title or f"{len(counts)} frames, {int(tracks.num_tracks)} track(s)", x=0.02, ha="left")
    return fig
