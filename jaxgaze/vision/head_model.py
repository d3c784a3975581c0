"""The cylindrical head model (CHM) of Yücel et al. (T-CYB 2013, Sec. IV), and a renderer.

The head is an upright **elliptic cylinder** (Cascia et al. 2000; Xiao, Kanade &
Cohn 2003) with anthropometric proportions: half-breadth ``a`` (ear to ear),
half-depth ``b`` (nose to back of the head) and height ``h``. The face is the
front half of its lateral surface.

Frames (``docs/conventions.md``; radians inside, degrees only in ``_deg`` names):

* **head frame** of the cylinder: origin on the cylinder's axis at mid-height
  (the *head centre*), **+x forward** (out of the face), **+y the person's
  left**, **+z up** along the axis: the head frame of the conventions, with
  its origin moved from between the eyes to the centre of the cylinder. The
  surface is ``(b cos φ, a sin φ, z)``, ``|z| ≤ h/2``; ``φ = 0`` is the middle
  of the face and ``φ > 0`` goes to the person's left.
* **optical** camera frame: +x right, +y down, +z forward (OpenCV), metres.
  Pinhole ``u = f X/Z + W/2``, ``v = f Y/Z + H/2`` as
  :func:`jaxgaze.simulate.tabletop.project_optical_to_image`, in the image
  frame whose origin is the **top-left corner** of the top-left pixel, so the
  pixel in column ``i``, row ``j`` is centred on ``(i + ½, j + ½)``. (With
  this convention ``cv2.pyrDown`` halves coordinates exactly.)
* **frontal** frame: the head frame in the eye-contact pose at a position
  ``p``: +x points from ``p`` to the camera centre, +y is the person's left
  (the image's right), +z is up (:func:`frontal_rotation`, built as
  ``R_optical_from_frontal`` in :mod:`jaxgaze.simulate.tabletop`).
* **pose** ``(pitch, yaw, roll)`` of the head relative to the frontal frame,
  with the signs of :mod:`jaxgaze.simulate.tabletop`:
  ``R_frontal_from_head = R_z(yaw) R_y(−pitch) R_x(roll)``
  (:func:`jaxgaze.geometry.head_pose_to_rotation`, mind the column order); **yaw > 0 turns
  the face to the person's left** (towards the image's right), **pitch > 0
  turns it up**, **roll > 0 turns about the forward axis from +y to +z** (the
  left ear goes up; the head tilts to its right, which is counter-clockwise
  in the image).

The face texture ``jaxgaze/data/face_texture.png`` (128 × 128 RGB) is the
face region (rows 30–190, columns 144–304, resized) of
``skimage.data.astronaut()``: the NASA portrait of astronaut Eileen Collins,
a public-domain photograph. It wraps the front half of the cylinder by
``(φ, z)``: column ∝ ``φ ∈ [−π/2, π/2]``, row ∝ ``−z``.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import numpy as np

from jaxgaze.geometry import head_pose_to_rotation
from jaxgaze.vision.images import to_rgb_float

__all__ = [
    "CylinderHead",
    "frontal_rotation",
    "load_face_texture",
    "projected_width_px",
    "distance_for_width_px",
    "render_head",
    "surface_grid",
]

HAIR_RGB = (70, 50, 35)
NECK_RGB = (150, 105, 85)
BACKGROUND_RGB = (60, 70, 90)


class CylinderHead(NamedTuple):
    """An upright elliptic cylinder, metres.

    Defaults: a head breadth of 0.15 m and a depth of 0.19 m (adult means,
    e.g. the ANSUR anthropometric survey), so semi-axes 0.075 m and 0.095 m,
    and a height of 0.20 m (chin to crown is about 0.23 m; the cylinder holds
    the face from chin to forehead).
    """

    half_width_m: float = 0.075
    half_depth_m: float = 0.095
    height_m: float = 0.20

    def checked(self) -> CylinderHead:
        values = []
        for name, value in zip(self._fields, self):
            v = float(value)
            if not math.isfinite(v) or v <= 0:
                raise ValueError(f"CylinderHead.{name} must be a positive finite number of metres, got {value!r}")
            values.append(v)
        return CylinderHead(*values)


# ---------------------------------------------------------------------------
# Rotations and poses


def frontal_rotation(position_optical) -> np.ndarray:
    """``R_optical_from_frontal (3, 3)``: the eye-contact head axes at ``position_optical``.

    Its columns are +x (from the head towards the camera centre), +y (the
    person's left, the image's right) and +z (up), in the optical frame. On the
    optical axis, ``position = (0, 0, D)``, it is ``[[0, 1, 0], [0, 0, −1], [−1, 0, 0]]``.
    """
    p = np.asarray(position_optical, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or p[2] <= 0:
        raise ValueError(f"position_optical must be a finite (3,) point in front of the camera (z > 0), got {p}")
    fwd = -p / np.linalg.norm(p)
    left = np.array([1.0, 0.0, 0.0]) - fwd[0] * fwd
    left /= np.linalg.norm(left)
    up = np.cross(fwd, left)
    return np.stack([fwd, left, up], axis=1)


@jax.jit
def _frontal_from_head(pose):
    """``R_frontal_from_head`` of a ``(pitch, yaw, roll)`` pose (:func:`jaxgaze.geometry.head_pose_to_rotation`)."""
    return head_pose_to_rotation(yaw=pose[..., 1], pitch=pose[..., 0], roll=pose[..., 2])


# ---------------------------------------------------------------------------
# Geometry


def projected_width_px(head: CylinderHead, distance_m: float, focal_px: float) -> float:
    """Image width (pixels) of the cylinder with its axis at depth ``distance_m`` on the optical axis.

    The silhouette's edges are the tangents from the camera centre to the
    ellipse ``(x/a)² + ((z − D)/b)² = 1``: ``x = m z`` with ``m² = a² / (D² − b²)``,
    so the width is ``2 f a / √(D² − b²)`` for the frontal pose (the depth axis
    ``b`` along the optical axis).
    """
    head = head.checked()
    a, b = head.half_width_m, head.half_depth_m
    if not distance_m > b:
        raise ValueError(f"distance_m must exceed the half-depth {b} m, got {distance_m}")
    return 2.0 * focal_px * a / math.sqrt(distance_m**2 - b**2)


def distance_for_width_px(head: CylinderHead, width_px: float, focal_px: float) -> float:
    """Inverse of :func:`projected_width_px`: the axis depth ``D`` at which the head is ``width_px`` wide."""
    head = head.checked()
    a, b = head.half_width_m, head.half_depth_m
    return math.sqrt((2.0 * focal_px * a / width_px) ** 2 + b**2)


def surface_grid(head: CylinderHead, num_angle: int = 48, num_height: int = 48, max_angle: float = math.pi / 2):
    """Points and unit outward normals ``(N, 3)`` in the head frame on the front of the cylinder.

    A regular grid in ``φ ∈ [−max_angle, max_angle]`` and ``z ∈ [−h/2, h/2]``
    (cell centres), ``N = num_angle · num_height``.
    """
    head = head.checked()
    a, b, h = head.half_width_m, head.half_depth_m, head.height_m
    phi = ((np.arange(num_angle) + 0.5) / num_angle * 2.0 - 1.0) * max_angle
    z = ((np.arange(num_height) + 0.5) / num_height - 0.5) * h
    P, Z = np.meshgrid(phi, z, indexing="xy")
    P, Z = P.ravel(), Z.ravel()
    points = np.stack([b * np.cos(P), a * np.sin(P), Z], axis=-1)
    normals = np.stack([np.cos(P) / b, np.sin(P) / a, np.zeros_like(P)], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return points, normals


# ---------------------------------------------------------------------------
# Texture and rendering


def load_face_texture() -> np.ndarray:
    """The packaged face texture, ``(128, 128, 3)`` uint8 RGB (see the module docstring for its source)."""
    return _face_texture().copy()


@functools.lru_cache(maxsize=1)
def _face_texture() -> np.ndarray:
    import importlib.resources

    import cv2

    path = importlib.resources.files("jaxgaze").joinpath("data/face_texture.png")
    with importlib.resources.as_file(path) as file:
        bgr = cv2.imread(str(file), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FileNotFoundError(f"cannot read the face texture {path} (is jaxgaze/data packaged?)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


@functools.lru_cache(maxsize=1)
def _face_texture_float() -> np.ndarray:
    return to_rgb_float(_face_texture(), "texture")


def _bilinear(image, row, col):
    """Bilinear samples of ``image (h, w, C)`` at float ``(row, col)`` array indices, edges replicated."""
    h, w = image.shape[:2]
    row = np.clip(row, 0.0, h - 1.0)
    col = np.clip(col, 0.0, w - 1.0)
    r0 = np.minimum(np.floor(row).astype(np.intp), h - 2) if h > 1 else np.zeros(row.shape, np.intp)
    c0 = np.minimum(np.floor(col).astype(np.intp), w - 2) if w > 1 else np.zeros(col.shape, np.intp)
    fr = (row - r0)[:, None]
    fc = (col - c0)[:, None]
    r1 = np.minimum(r0 + 1, h - 1)
    c1 = np.minimum(c0 + 1, w - 1)
    top = image[r0, c0] * (1 - fc) + image[r0, c1] * fc
    bottom = image[r1, c0] * (1 - fc) + image[r1, c1] * fc
    return top * (1 - fr) + bottom * fr


def _image_size(image_size) -> tuple[int, int]:
    try:
        width, height = (int(s) for s in image_size)
    except (TypeError, ValueError):
        raise ValueError(f"image_size must be (width, height) in pixels, got {image_size!r}") from None
    if width < 1 or height < 1 or (width, height) != tuple(image_size):
        raise ValueError(f"image_size must be two positive integers (width, height), got {image_size!r}")
    return width, height


def render_head(
    pose,
    *,
    head: CylinderHead = CylinderHead(),
    focal_px: float,
    image_size=(320, 240),
    position_optical,
    texture=None,
    background=None,
    R_optical_from_frontal=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast the textured cylinder (Yücel et al. 2013, Sec. IV): ``(image (H, W, 3) uint8 RGB, mask (H, W) bool)``.

    Args:
        pose: ``(pitch, yaw, roll)`` radians relative to the frontal frame.
        head: the cylinder's dimensions.
        focal_px: pinhole focal length; the principal point is the image centre.
        image_size: ``(W, H)`` pixels.
        position_optical: the head centre (cylinder axis, mid-height) in the optical frame, metres.
        texture: face texture image (grey or RGB, uint8 or float in [0, 1]) wrapped on
            the front half by ``(φ, z)``; default :func:`load_face_texture`.
        background: ``(H, W)``/``(H, W, 3)`` image, or an RGB triple, behind the head;
            default a flat blue-grey.
        R_optical_from_frontal: the frontal frame ``pose`` is relative to; default the
            eye-contact frame at ``position_optical`` (:func:`frontal_rotation`). Pass the
            first frame's to render a sequence whose poses share one reference.

    The back and sides (``|φ| > π/2``) and the top cap are hair-coloured, the
    bottom cap skin-coloured. No shading: brightness constancy holds exactly.
    Each pixel is one ray through its centre (no anti-aliasing).
    """
    width, height = _image_size(image_size)
    head = head.checked()
    f = float(focal_px)
    if not math.isfinite(f) or f <= 0:
        raise ValueError(f"focal_px must be a positive finite number, got {focal_px!r}")
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"pose must be a finite (3,) (pitch, yaw, roll) in radians, got {pose}")
    t = np.asarray(position_optical, dtype=np.float64)
    R_of = frontal_rotation(t) if R_optical_from_frontal is None else np.asarray(R_optical_from_frontal, np.float64)
    if R_of.shape != (3, 3) or not np.allclose(R_of @ R_of.T, np.eye(3), atol=1e-6):
        raise ValueError("R_optical_from_frontal must be a (3, 3) rotation matrix")
    R = R_of @ np.asarray(_frontal_from_head(pose), dtype=np.float64)  # R_optical_from_head

    tex = _face_texture_float() if texture is None else to_rgb_float(texture, "texture")
    if background is None:
        image = np.empty((height, width, 3), np.uint8)
        image[:] = BACKGROUND_RGB
    elif np.ndim(background) == 1:
        rgb = np.asarray(background)
        if rgb.shape != (3,):
            raise ValueError(f"background colour must be an RGB triple, got {background!r}")
        image = np.empty((height, width, 3), np.uint8)
        image[:] = np.clip(rgb, 0, 255).astype(np.uint8)
    else:
        bg = to_rgb_float(background, "background")
        if bg.shape[:2] != (height, width):
            raise ValueError(f"background is {bg.shape[1]}x{bg.shape[0]} px, image_size is {width}x{height}")
        image = np.clip(np.rint(bg * 255.0), 0, 255).astype(np.uint8)

    a, b, h = head.half_width_m, head.half_depth_m, head.height_m
    # Only the pixels inside the projected bounding box of the cylinder are cast.
    corners = np.stack(np.meshgrid([-b, b], [-a, a], [-h / 2, h / 2]), -1).reshape(-1, 3) @ R.T + t
    if np.all(corners[:, 2] > 1e-6):
        cu = f * corners[:, 0] / corners[:, 2] + width / 2.0
        cv = f * corners[:, 1] / corners[:, 2] + height / 2.0
        c0, c1 = max(int(np.floor(cu.min())) - 1, 0), min(int(np.ceil(cu.max())) + 1, width)
        r0, r1 = max(int(np.floor(cv.min())) - 1, 0), min(int(np.ceil(cv.max())) + 1, height)
    else:
        c0, c1, r0, r1 = 0, width, 0, height
    mask = np.zeros((height, width), bool)
    if c1 <= c0 or r1 <= r0:
        return image, mask
    # Rays through pixel centres, in the head frame: x(s) = o + s d.
    u = (np.arange(c0, c1) + 0.5 - width / 2.0) / f
    v = (np.arange(r0, r1) + 0.5 - height / 2.0) / f
    U, V = np.meshgrid(u, v)
    d = np.stack([U, V, np.ones_like(U)], axis=-1) @ R  # rows: R^T d_optical
    o = -(t @ R)
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    ox, oy, oz = o

    inf = np.inf
    # Lateral surface (x/b)^2 + (y/a)^2 = 1: the entry point is the smaller root.
    A = (dx / b) ** 2 + (dy / a) ** 2
    B = 2.0 * (ox * dx / b**2 + oy * dy / a**2)
    C = (ox / b) ** 2 + (oy / a) ** 2 - 1.0
    disc = B * B - 4.0 * A * C
    with np.errstate(invalid="ignore", divide="ignore"):
        s_side = (-B - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * A)
        z_side = oz + s_side * dz
        s_side = np.where((disc >= 0) & (s_side > 0) & (np.abs(z_side) <= h / 2), s_side, inf)
        caps = []
        for zc in (h / 2, -h / 2):
            s = (zc - oz) / dz
            x, y = ox + s * dx, oy + s * dy
            caps.append(np.where(np.isfinite(s) & (s > 0) & ((x / b) ** 2 + (y / a) ** 2 <= 1.0), s, inf))
    s_all = np.stack([s_side, caps[0], caps[1]], axis=0)
    which = np.argmin(s_all, axis=0)
    hit = np.isfinite(np.min(s_all, axis=0))
    mask[r0:r1, c0:c1] = hit
    window = image[r0:r1, c0:c1]  # a view: writing to it draws into image

    side = hit & (which == 0)
    xs, ys, zs = (ox + s_side * dx)[side], (oy + s_side * dy)[side], (oz + s_side * dz)[side]
    phi = np.arctan2(ys / a, xs / b)
    front = np.abs(phi) <= math.pi / 2
    th, tw = tex.shape[:2]
    col = ((phi / math.pi + 0.5) * tw - 0.5).astype(np.float32)
    row = ((0.5 - zs / h) * th - 0.5).astype(np.float32)
    looked = _bilinear(tex, row, col)
    colours = np.where(front[:, None], np.clip(np.rint(looked * 255.0), 0, 255), np.asarray(HAIR_RGB, float))
    window[side] = colours.astype(np.uint8)
    window[hit & (which == 1)] = HAIR_RGB
    window[hit & (which == 2)] = NECK_RGB
    return image, mask
