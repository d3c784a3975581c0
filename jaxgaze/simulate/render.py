"""Rendered table-top scenes with ground truth (Yücel et al., T-CYB 2013, Sec. VII, Table II).

:func:`render_tabletop_scene` draws, with OpenCV, the robot camera's 320 × 240
picture of a :class:`~jaxgaze.simulate.tabletop.TabletopSession` (or of explicit
object boxes): a low-contrast wall with some clutter (shelf and books, a poster,
a clock, a cabinet), a wooden table seen in perspective, and ``K`` cube-shaped
objects of distinct saturated colours, each with a texture (plain, stripes, dots,
checker), a lit top face, a darker side face and a contact shadow. No person is
drawn: the wall around the session's ``head_centre_image`` is left plain so a
rendered head can be pasted in with :func:`composite`.

Images are ``(240, 320, 3)`` **RGB** (not OpenCV's BGR) ``uint8``, in the image
frame: x right, y down. Box and centre coordinates are those of
:mod:`jaxgaze.simulate.tabletop` (origin at the top-left pixel *corner*, so pixel
``(row i, col j)`` covers ``[j, j + 1] × [i, i + 1]``).

Conditions (T-CYB Table II): ``"natural"``; ``"artificial"`` (a warm tungsten
colour cast and a slight gamma); ``"dimmed"`` (exposure × 0.35 and sensor noise);
``"blur"`` (motion blur, a 9–15 px line kernel at a random angle). The layout,
colours and clutter depend only on the key, so one key gives the same scene
under every condition.
"""

from __future__ import annotations

import colorsys
import math
from typing import NamedTuple

import cv2
import numpy as np

from jaxgaze._checks import check_key
from jaxgaze.simulate.tabletop import (
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    TabletopSession,
    project_optical_to_image,
)
from jaxgaze.vision.images import check_image

__all__ = ["CONDITIONS", "RenderedScene", "composite", "render_tabletop_scene"]

CONDITIONS = ("natural", "artificial", "dimmed", "blur")
MAX_OBJECTS = 12
MIN_BOX_PX = 4.0
TEXTURES = ("plain", "stripes", "dots", "checker")

_SHIFT = 4  # fixed-point bits for sub-pixel cv2 polygons
_ONE = 1 << _SHIFT


class RenderedScene(NamedTuple):
    """One rendered picture and its ground truth.

    Attributes:
        image: ``(240, 320, 3)`` uint8, RGB.
        object_boxes: ``(K, 4)`` float64 ``(x_min, y_min, x_max, y_max)`` px.
        object_centres: ``(K, 2)`` float64 px (the projected cube centre, or the box centre).
        object_colours: ``(K, 3)`` uint8 RGB base colour of each object's front face
            (textures use a darker shade of it; before the condition is applied).
        object_labels: ``(240, 320)`` int16, the object ``k`` seen at each pixel or ``-1``
            (geometry before blur; a far object hidden by a nearer one loses those pixels).
        condition: one of :data:`CONDITIONS`.
    """

    image: np.ndarray
    object_boxes: np.ndarray
    object_centres: np.ndarray
    object_colours: np.ndarray
    object_labels: np.ndarray
    condition: str


# ---------------------------------------------------------------------------
# Validation


def _check_boxes(boxes) -> np.ndarray:
    try:
        b = np.asarray(boxes, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise TypeError(f"object boxes must be a numeric (K, 4) array, got {type(boxes).__name__}") from err
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"object boxes must have shape (K, 4) as (x_min, y_min, x_max, y_max), got {b.shape}")
    if not 1 <= b.shape[0] <= MAX_OBJECTS:
        raise ValueError(f"need 1 to {MAX_OBJECTS} object boxes, got {b.shape[0]}")
    bad = ~np.all(np.isfinite(b), axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"object box {k} contains NaN or inf: {b[k].tolist()}")
    for k, (x0, y0, x1, y1) in enumerate(b):
        if x0 < 0 or y0 < 0 or x1 > IMAGE_WIDTH or y1 > IMAGE_HEIGHT:
            raise ValueError(
                f"object box {k} = {[x0, y0, x1, y1]} is outside the {IMAGE_WIDTH}x{IMAGE_HEIGHT} image "
                f"(need 0 <= x <= {IMAGE_WIDTH}, 0 <= y <= {IMAGE_HEIGHT})"
            )
        if x1 - x0 < MIN_BOX_PX or y1 - y0 < MIN_BOX_PX:
            raise ValueError(
                f"object box {k} = {[x0, y0, x1, y1]} must have x_max - x_min and y_max - y_min "
                f">= {MIN_BOX_PX:g} px (is it (x_min, y_min, x_max, y_max)?)"
            )
    return b


# ---------------------------------------------------------------------------
# Geometry: each cube as its front and back faces in the image, corners TL, TR, BR, BL


class _Layout(NamedTuple):
    boxes: np.ndarray  # (K, 4)
    centres: np.ndarray  # (K, 2)
    front: np.ndarray  # (K, 4, 2)
    back: np.ndarray  # (K, 4, 2)
    order: np.ndarray  # drawing order, far to near
    table: np.ndarray  # (4, 2) table corners far-left, far-right, near-right, near-left
    head_zone: tuple[float, float, float, float] | None  # kept plain (x0, y0, x1, y1)


def _session_layout(s: TabletopSession, rng: np.random.Generator) -> _Layout:
    boxes = _check_boxes(s.object_boxes_image)
    c = np.asarray(s.object_centres_optical, dtype=np.float64)
    size = np.asarray(s.object_sizes_m, dtype=np.float64)
    f = float(s.focal_px)
    if c.shape != (len(boxes), 3) or size.shape != (len(boxes),):
        raise ValueError(f"session has {len(boxes)} boxes but object centres {c.shape}, sizes {size.shape}")
    h = size[:, None] / 2
    x0, x1, y0, y1 = c[:, 0:1] - h, c[:, 0:1] + h, c[:, 1:2] - h, c[:, 1:2] + h
    xs, ys = np.concatenate([x0, x1, x1, x0], 1), np.concatenate([y0, y0, y1, y1], 1)

    def face(z):
        return project_optical_to_image(np.stack([xs, ys, np.broadcast_to(z, xs.shape)], -1), f)

    front, back = face(c[:, 2:3] - h), face(c[:, 2:3] + h)
    table_y = float(np.mean(c[:, 1] + size / 2))
    rest = np.asarray(s.head_rest_optical, dtype=np.float64)
    z_far = max(float(rest[2]) - 0.12, float(np.max(c[:, 2] + size / 2)) + 0.06)
    half, shift, z_near = rng.uniform(0.9, 1.1), rng.uniform(-0.05, 0.05), 0.15
    table = project_optical_to_image(
        [[shift - half, table_y, z_far], [shift + half, table_y, z_far], [shift + half, table_y, z_near],
         [shift - half, table_y, z_near]], f,
    )
    head = np.asarray(s.head_centre_image, dtype=np.float64).reshape(-1, 2)
    r = 0.12 * f / float(rest[2])  # head radius, px
    lo, hi = head.min(0), head.max(0)
    zone = (lo[0] - 2.4 * r, lo[1] - 1.8 * r, hi[0] + 2.4 * r, float(IMAGE_HEIGHT))
    return _Layout(boxes, np.asarray(s.object_centres_image, np.float64), front, back,
                   np.argsort(-c[:, 2], kind="stable"), table, zone)


def _box_layout(boxes: np.ndarray, rng: np.random.Generator) -> _Layout:
    """Oblique cubes filling each box: the top face above, the side face towards the image centre."""
    x0, y0, x1, y1 = boxes.T
    w, h = x1 - x0, y1 - y0
    t = np.maximum(1.5, 0.12 * h)  # top face height
    toward_centre = np.where((x0 + x1) / 2 >= IMAGE_WIDTH / 2, 1, -1)
    s = np.maximum(1.5, 0.18 * w) * toward_centre  # the back face's shift
    fx0, fx1 = np.where(s > 0, x0 + s, x0), np.where(s > 0, x1, x1 + s)
    bx0, bx1 = fx0 - s, fx1 - s

    def quad(a, b, top, bottom):
        return np.stack([np.stack([a, top], -1), np.stack([b, top], -1), np.stack([b, bottom], -1),
                         np.stack([a, bottom], -1)], 1)

    front, back = quad(fx0, fx1, y0 + t, y1), quad(bx0, bx1, y0, y1 - t)
    edge = float(np.clip(np.min(y1 - t) - 6, 0.35 * IMAGE_HEIGHT, 0.8 * IMAGE_HEIGHT))
    dx = rng.uniform(80, 120)
    table = np.array([[-20, edge], [IMAGE_WIDTH + 20, edge], [IMAGE_WIDTH + 20 + dx, IMAGE_HEIGHT + 60],
                      [-20 - dx, IMAGE_HEIGHT + 60]])
    centres = np.stack([(x0 + x1) / 2, (y0 + y1) / 2], -1)
    return _Layout(boxes, centres, front, back, np.argsort(y1, kind="stable"), table, None)


# ---------------------------------------------------------------------------
# Drawing helpers (float RGB images in [0, 1])


def _pts(points) -> np.ndarray:
    """Image-frame points (pixel corner origin) as cv2 fixed-point pixel-centre coordinates."""
    return np.round((np.asarray(points, dtype=np.float64) - 0.5) * _ONE).astype(np.int32).reshape(-1, 1, 2)


_XC, _YC = np.meshgrid(np.arange(IMAGE_WIDTH) + 0.5, np.arange(IMAGE_HEIGHT) + 0.5)  # pixel centres


def _poly_mask(points) -> np.ndarray:
    """Pixels whose centre lies in the convex polygon ``points`` (image frame), exactly."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    q = np.roll(p, -1, axis=0)
    area2 = float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))
    mask = np.zeros((IMAGE_HEIGHT, IMAGE_WIDTH), bool)
    x0, y0 = (max(0, int(math.floor(v - 0.5))) for v in p.min(axis=0))
    x1, y1 = (int(math.ceil(v)) for v in p.max(axis=0))
    if abs(area2) <= 1e-9 or x0 >= min(x1, IMAGE_WIDTH) or y0 >= min(y1, IMAGE_HEIGHT):
        return mask
    xc, yc = _XC[y0:y1, x0:x1], _YC[y0:y1, x0:x1]
    inside = np.ones(xc.shape, bool)
    for a, b in zip(p, q):
        inside &= np.sign(area2) * ((b[0] - a[0]) * (yc - a[1]) - (b[1] - a[1]) * (xc - a[0])) >= 0
    mask[y0:y1, x0:x1] = inside
    return mask


def _c(colour) -> tuple[float, ...]:
    """A colour as cv2 wants it."""
    return tuple(float(v) for v in np.ravel(colour))


def _hsv(h, s, v) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb(h % 1.0, s, v))


def _smooth_noise(rng, shape, cells) -> np.ndarray:
    """Zero-mean, unit-ish smooth noise ``shape`` from a ``cells`` grid (bicubic)."""
    small = rng.standard_normal(cells).astype(np.float32)
    return cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


def _wall(rng) -> tuple[np.ndarray, np.ndarray]:
    colour = _hsv(rng.uniform(0.05, 0.6), rng.uniform(0.05, 0.14), rng.uniform(0.72, 0.84))
    rows = np.linspace(0, 1, IMAGE_HEIGHT)[:, None, None]
    light = 1.04 - 0.08 * rows + 0.012 * _smooth_noise(rng, (IMAGE_HEIGHT, IMAGE_WIDTH), (6, 8))[..., None]
    return np.clip(colour * light, 0, 1), colour


def _clutter(img, rng, wall, edge_row, zone) -> None:
    """Low-contrast wall clutter: shelves with books, a poster, a clock, a cabinet, a socket."""

    def tone(lo=0.85, hi=1.1, sat=0.2):
        return np.clip(wall * rng.uniform(lo, hi) + _hsv(rng.uniform(), 1, 1) * rng.uniform(0, sat) * 0.15, 0, 1)

    placed: list[tuple[float, float, float, float]] = []

    def place(w, h, ymax):
        for _ in range(30):
            x, y = rng.uniform(2, IMAGE_WIDTH - w - 2), rng.uniform(2, max(3.0, ymax - h))
            r = (x - 3, y - 3, x + w + 3, y + h + 3)
            taken = placed + ([zone] if zone else [])
            if not any(r[0] < q[2] and q[0] < r[2] and r[1] < q[3] and q[1] < r[3] for q in taken):
                placed.append(r)
                return int(x), int(y)
        return None

    def rect(x0, y0, x1, y1, colour, thickness=-1):
        cv2.rectangle(img, (int(x0), int(y0)), (int(x1), int(y1)), _c(colour), thickness)

    kinds = ["shelf", "poster", "shelf", "clock", "cabinet", "poster", "socket", "frame"]
    for kind in kinds[: rng.integers(5, len(kinds) + 1)]:
        if kind == "shelf":
            w = rng.uniform(60, 110)
            at = place(w, 26, edge_row - 8)
            if at is None:
                continue
            x, y = at
            rect(x, y + 22, x + w, y + 25, tone(0.8, 0.88, 0.05))
            rect(x, y + 26, x + w, y + 28, wall * 0.93)
            bx = x + rng.uniform(2, 10)
            while bx < x + w - 8:
                bw, bh = rng.uniform(3, 7), rng.uniform(10, 21)
                rect(bx, y + 22 - bh, bx + bw, y + 21, tone(0.8, 1.08, 1.0))
                bx += bw + rng.uniform(0.5, 6)
        elif kind in ("poster", "frame"):
            w, h = rng.uniform(28, 55), rng.uniform(30, 50)
            at = place(w, h, edge_row - 15)
            if at is None:
                continue
            x, y = at
            rect(x, y, x + w, y + h, tone(0.9, 1.08, 0.6))
            rect(x, y, x + w, y + h, wall * (0.8 if kind == "frame" else 0.9), 2 if kind == "frame" else 1)
            for _ in range(rng.integers(1, 4)):
                cx, cy = x + rng.uniform(0.25, 0.75) * w, y + rng.uniform(0.25, 0.75) * h
                r = rng.uniform(3, 0.25 * min(w, h))
                cv2.circle(img, (int(cx), int(cy)), int(r), _c(tone(0.86, 1.1, 0.8)), -1, cv2.LINE_AA)
        elif kind == "clock":
            r = rng.uniform(8, 13)
            at = place(2 * r, 2 * r, edge_row - 20)
            if at is None:
                continue
            cx, cy = at[0] + r, at[1] + r
            cv2.circle(img, (int(cx), int(cy)), int(r), _c(wall * 1.06), -1, cv2.LINE_AA)
            cv2.circle(img, (int(cx), int(cy)), int(r), _c(wall * 0.82), 1, cv2.LINE_AA)
            for a, ln in ((rng.uniform(0, 2 * math.pi), 0.8), (rng.uniform(0, 2 * math.pi), 0.55)):
                tip = (int(cx + ln * r * math.cos(a)), int(cy + ln * r * math.sin(a)))
                cv2.line(img, (int(cx), int(cy)), tip, _c(wall * 0.78), 1, cv2.LINE_AA)
        elif kind == "cabinet":
            w, h = rng.uniform(40, 70), rng.uniform(40, 70)
            at = place(w, h, edge_row + 0.5 * h)  # may stand behind the table
            if at is None:
                continue
            x, y = at
            rect(x, y, x + w, y + h, tone(0.88, 1.0, 0.3))
            rect(x, y, x + w, y + h, wall * 0.84, 1)
            cv2.line(img, (int(x + w / 2), int(y)), (int(x + w / 2), int(y + h)), _c(wall * 0.84))
        else:  # socket
            at = place(9, 7, edge_row - 4)
            if at is not None:
                rect(at[0], at[1], at[0] + 9, at[1] + 7, wall * 1.05)
                rect(at[0], at[1], at[0] + 9, at[1] + 7, wall * 0.88, 1)


def _table(img, rng, corners) -> np.ndarray:
    """Wooden planks (grain along the table edge) warped onto the table polygon; returns its mask."""
    tw, th = 512, 384
    base = _hsv(rng.uniform(0.07, 0.1), rng.uniform(0.4, 0.55), rng.uniform(0.5, 0.65))
    grain = _smooth_noise(rng, (th, tw), (96, 6)) * 0.05 + _smooth_noise(rng, (th, tw), (12, 3)) * 0.04
    plank = th / rng.integers(4, 8)
    rows = np.arange(th)[:, None]
    seam = np.where(np.mod(rows, plank) < 2.5, 0.82, 1.0)
    tex = np.clip(base * ((1 + grain) * seam)[..., None], 0, 1).astype(np.float32)
    src = np.float32([[0, 0], [tw, 0], [tw, th], [0, th]])
    H = cv2.getPerspectiveTransform(src, np.float32(np.asarray(corners) - 0.5))
    size = (IMAGE_WIDTH, IMAGE_HEIGHT)
    warped = cv2.warpPerspective(tex, H, size, flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REFLECT)
    mask = _poly_mask(corners)
    img[mask] = warped[mask]
    far_l, far_r = corners[0], corners[1]
    cv2.line(img, tuple(int(v) for v in _pts(far_l)[0, 0]), tuple(int(v) for v in _pts(far_r)[0, 0]),
             _c(np.clip(base * 1.35, 0, 1)), 1, cv2.LINE_AA, _SHIFT)
    return mask


def _object_colours(rng, k) -> np.ndarray:
    hues = (rng.uniform() + np.arange(k) / k) % 1.0
    rng.shuffle(hues)
    return np.stack([_hsv(h, rng.uniform(0.82, 1.0), rng.uniform(0.78, 0.95)) for h in hues])


def _pattern(rng, kind, origin, size) -> np.ndarray:
    """Texture factor (H, W) in {shade, 1}, anchored at the front face's corner."""
    u, v = _XC - origin[0], _YC - origin[1]
    shade = rng.uniform(0.5, 0.62)
    period = max(4.0, size * rng.uniform(0.2, 0.3))
    if kind == "stripes":
        a = rng.choice([0.0, math.pi / 2, math.pi / 4, -math.pi / 4])
        d = u * math.cos(a) + v * math.sin(a)
        on = np.mod(d, period) < period / 3
    elif kind == "dots":
        r = period * 0.25
        on = (np.mod(u, period) - period / 2) ** 2 + (np.mod(v, period) - period / 2) ** 2 < r * r
    elif kind == "checker":
        on = (np.floor(u / period) + np.floor(v / period)) % 2 == 1
    else:
        on = np.zeros_like(u, dtype=bool)
    return np.where(on, shade, 1.0)


def _objects(img, rng, lay: _Layout, table_mask) -> tuple[np.ndarray, np.ndarray]:
    k = len(lay.boxes)
    colours = _object_colours(rng, k)
    labels = np.full((IMAGE_HEIGHT, IMAGE_WIDTH), -1, np.int16)
    # contact shadows on the table first, so that no object is darkened by another's
    shade = np.ones((IMAGE_HEIGHT, IMAGE_WIDTH), np.float32)
    for i in range(k):
        foot = np.concatenate([lay.front[i, [3, 2]], lay.back[i, [2, 3]]])
        offset = np.array([0.06, -0.02]) * (lay.boxes[i, 2] - lay.boxes[i, 0])
        cv2.fillPoly(shade, [_pts(foot + offset)], 0.55, cv2.LINE_AA, _SHIFT)
    shade = cv2.GaussianBlur(shade, (0, 0), 2.0)
    img *= np.where(table_mask, shade, 1.0)[..., None]
    yy = np.arange(IMAGE_HEIGHT)[:, None] + 0.5
    for i in lay.order:
        f, b, base = lay.front[i], lay.back[i], colours[i]
        kind = TEXTURES[rng.integers(len(TEXTURES))]
        face_h = f[2, 1] - f[0, 1]
        light = 1.06 - 0.14 * np.clip((yy - f[0, 1]) / max(face_h, 1.0), 0, 1)
        front = base * (_pattern(rng, kind, f[0], f[1, 0] - f[0, 0]) * light)[..., None]
        faces = [(f, front)]
        if b[0, 0] < f[0, 0]:
            faces.append((np.stack([f[0], b[0], b[3], f[3]]), base * 0.58))
        elif b[1, 0] > f[1, 0]:
            faces.append((np.stack([f[1], b[1], b[2], f[2]]), base * 0.58))
        faces.append((np.stack([f[0], f[1], b[1], b[0]]), base * 0.72 + 0.28))  # top: lit, paler
        for poly, paint in faces:
            m = _poly_mask(poly)
            img[m] = paint[m] if paint.ndim == 3 else paint
            labels[m] = i
        # highlight along the top front edge
        cv2.line(img, tuple(int(v) for v in _pts(f[0])[0, 0]), tuple(int(v) for v in _pts(f[1])[0, 0]),
                 _c(base * 0.5 + 0.5), 1, cv2.LINE_AA, _SHIFT)
    return np.round(colours * 255).astype(np.uint8), labels


def _line_kernel(rng) -> np.ndarray:
    n = int(rng.integers(9, 16)) | 1
    a = rng.uniform(0, math.pi)
    kernel = np.zeros((n, n), np.float32)
    c, r = (n - 1) / 2, (n - 1) / 2
    p0 = (int(round((c - r * math.cos(a)) * _ONE)), int(round((c - r * math.sin(a)) * _ONE)))
    p1 = (int(round((c + r * math.cos(a)) * _ONE)), int(round((c + r * math.sin(a)) * _ONE)))
    cv2.line(kernel, p0, p1, 1.0, 1, cv2.LINE_AA, _SHIFT)
    return kernel / kernel.sum()


def _apply_condition(img, condition, rng) -> np.ndarray:
    noise = 0.004
    if condition == "artificial":
        img = np.clip(img, 0, 1) ** 1.12 * np.array([1.05, 0.8, 0.52])
    elif condition == "dimmed":
        img = img * 0.35
        noise = 0.015
    elif condition == "blur":
        img = cv2.filter2D(img.astype(np.float32), -1, _line_kernel(rng), borderType=cv2.BORDER_REFLECT_101)
    img = img + rng.normal(0, noise, img.shape)
    return np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------------
# Public API


def render_tabletop_scene(session_or_boxes, *, key, condition: str = "natural", clutter: bool = True) -> RenderedScene:
    """Draw a 320 × 240 RGB table-top picture with ``K`` cubes at known boxes.

    Args:
        session_or_boxes: a :class:`~jaxgaze.simulate.tabletop.TabletopSession` (its cubes,
            camera and head position are used) or ``(K, 4)`` boxes ``(x_min, y_min, x_max,
            y_max)`` px inside the image, ``1 <= K <= 12``, each drawn as a cube filling it.
        key: a single ``jax.random`` key; the same key gives the same scene under every
            condition, and the same picture for the same condition.
        condition: one of :data:`CONDITIONS`.
        clutter: draw the wall clutter (``False`` leaves a bare wall, all else unchanged).

    Raises:
        ValueError: unknown condition, bad key, boxes of the wrong shape, with NaN or
            outside the image; TypeError for non-numeric boxes.
    """
    if not isinstance(condition, str) or condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r}; valid conditions are {', '.join(CONDITIONS)}")
    if not isinstance(clutter, (bool, np.bool_)):
        raise TypeError(f"clutter must be True or False, got {clutter!r}")
    seed = check_key(key)
    s_base, s_clutter, s_objects, s_condition = np.random.SeedSequence([int(x) for x in seed]).spawn(4)
    rng = np.random.default_rng(s_base)
    if isinstance(session_or_boxes, TabletopSession):
        lay = _session_layout(session_or_boxes, rng)
    else:
        lay = _box_layout(_check_boxes(session_or_boxes), rng)
    img, wall = _wall(rng)
    edge_row = float(min(lay.table[0, 1], lay.table[1, 1]))
    if clutter:
        _clutter(img, np.random.default_rng(s_clutter), wall, edge_row, lay.head_zone)
    table_mask = _table(img, rng, lay.table)
    colours, labels = _objects(img, np.random.default_rng(s_objects), lay, table_mask)
    image = _apply_condition(img, condition, np.random.default_rng(s_condition))
    return RenderedScene(image, lay.boxes.copy(), lay.centres.copy(), colours, labels, condition)


def composite(background, foreground, mask) -> np.ndarray:
    """``background`` with the pixels where ``mask`` is True taken from ``foreground``.

    ``background`` and ``foreground`` are images of the same shape and dtype, ``mask`` a
    bool ``(H, W)`` array; the result is a new array. Raises ValueError/TypeError otherwise.
    """
    bg = check_image(background, "background")
    fg = check_image(foreground, "foreground")
    if bg.shape != fg.shape or bg.dtype != fg.dtype:
        raise ValueError(f"foreground {fg.shape} {fg.dtype} must match background {bg.shape} {bg.dtype}")
    m = np.asarray(mask)
    if m.dtype != np.bool_:
        raise TypeError(f"mask must be a bool array, got dtype {m.dtype}")
    if m.shape != bg.shape[:2]:
        raise ValueError(f"mask has shape {m.shape}; expected {bg.shape[:2]} to match the images")
    out = bg.copy()
    out[m] = fg[m]
    return out
