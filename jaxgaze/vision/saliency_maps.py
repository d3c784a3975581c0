"""Bottom-up saliency, winner-take-all with inhibition of return, and the attended region.

Yücel et al., T-CYB 2013, Sec. VI: the pooled target-point
estimates of the gaze regression place Gaussian masks (σ = 10 px) on the 320 × 240
image; bottom-up saliency inside the masks and a winner-take-all pick the attended
location, and inhibition of return offers the next candidates. The object at the
chosen location is segmented by region growing on the saliency map.

- :func:`saliency` — ``"itti"`` (Itti, Koch & Niebur, PAMI 1998) or
  ``"spectral_residual"`` (Hou & Zhang, CVPR 2007). Every map is float32 ``(H, W)`` at
  the input resolution, scaled to ``[0, 1]``; an image with nothing to tell apart
  (e.g. a uniform image) gives **all zeros**.
- :func:`gaussian_mask` — the search envelope around target-point estimates.
- :func:`winner_take_all` — fixations in order of decreasing saliency, with inhibition
  of return.
- :func:`salient_region` — the bounding box of the salient blob at a fixation.

Coordinates are image coordinates (:mod:`jaxgaze.vision.images`, ``docs/conventions.md``):
``x`` right, ``y`` down, origin at the top-left pixel's **outer corner**, so the pixel
``map[i, j]`` (row ``i``, column ``j``) covers ``[j, j + 1] × [i, i + 1]`` and has its
centre at ``(j + ½, i + ½)``. Inputs (mask centres, fixations passed back in) and
outputs (fixations at pixel centres, region boxes on pixel edges) are floats in
these coordinates, the same as :mod:`jaxgaze.simulate.tabletop`'s boxes and centres.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from scipy import ndimage

from jaxgaze.vision.images import to_float

__all__ = [
    "SALIENCY_METHODS",
    "Fixations",
    "gaussian_mask",
    "itti_normalize",
    "salient_region",
    "saliency",
    "winner_take_all",
]

SALIENCY_METHODS = ("itti", "spectral_residual")

# A map whose range is below this (in image units, 0..1) is treated as flat: the
# float32 round-off of pyramids and filters on a uniform image is ~1e-7.
_FLAT_RANGE = 1e-5


# ----------------------------------------------------------------------------- public


def saliency(image, method: str = "itti") -> np.ndarray:
    """Bottom-up saliency map, float32 ``(H, W)`` in ``[0, 1]`` (Itti, Koch & Niebur 1998; Hou & Zhang 2007).

    ``image`` is ``(H, W, 3)`` RGB or ``(H, W)`` grey, uint8 (0..255) or float (0..1);
    it is checked by :func:`jaxgaze.vision.images.check_image` (``TypeError`` for other
    dtypes, ``ValueError`` for empty images, NaN/inf, bad shapes).

    ``method``:

    - ``"itti"`` — Itti, Koch & Niebur (1998): intensity, red–green and blue–yellow
      opponency and Gabor orientation (0, 45, 90, 135°) on a dyadic Gaussian pyramid
      (scales 0..8), centre–surround differences at ``c ∈ {2, 3, 4}``, ``s = c + δ``,
      ``δ ∈ {3, 4}``, the normalisation operator :func:`itti_normalize`, conspicuity
      maps summed at scale 4 and averaged. A grey image uses intensity and orientation
      only. The map is computed at scale 4 (1/16 of the input) and resized back
      (bicubic), so it is smooth on the scale of ~16 px: objects of 20 px or more get
      the maximum on them; smaller ones can have it up to ~8 px off. The pyramid
      decimates pixel-centre aligned (see ``_pyramid``), so rotating the image by 90°
      rotates the map (correlation > 0.99).
    - ``"spectral_residual"`` — Hou & Zhang (2007): the luminance resized to 64 px wide,
      log-amplitude spectrum minus its 3 × 3 local mean, phase kept, squared inverse
      transform, Gaussian smoothing (σ = 2.5 working px), resized back. The mean is
      removed and amplitudes are floored at 1e-3 of the largest (choice: exact spectral
      zeros of synthetic images would otherwise dominate). Luminance only: an object
      that differs from its background in hue alone is invisible to it. Its resolution
      is one working pixel (``W/64``); peaks sit on object boundaries, and because the
      transform is periodic a thin background strip between an object and the image
      edge (≲ 20 px at 320 px wide) can outshine the object.

    A flat result (nothing stands out, e.g. a uniform image) is returned as all zeros,
    not as NaN. Unknown ``method``: ``ValueError`` naming the valid ones.
    """
    if method not in SALIENCY_METHODS:
        raise ValueError(f"unknown saliency method {method!r}; choose one of {', '.join(SALIENCY_METHODS)}")
    array = to_float(image, "image")
    if method == "itti":
        raw = _itti(array)
    else:
        raw = _spectral_residual(array)
    return _to_unit_range(raw, array.shape[:2])


def itti_normalize(feature_map, *, threshold: float = 0.1) -> np.ndarray:
    """Itti's map normalisation operator N(·) (Itti, Koch & Niebur 1998, Sec. 2, Fig. 2).

    1. Scale the map to the fixed range ``[0, 1]`` (``M = 1``; the minimum goes to 0).
    2. Find its local maxima: 8-connected plateaus that equal their 3 × 3 neighbourhood
       maximum and exceed ``threshold`` × M (weak ripples are not peaks); each plateau
       counts once.
    3. Multiply the map by ``(M − m̄)²``, ``m̄`` the mean of all local maxima other than
       the global one (``m̄ = 0`` when there is no other).

    A map with one strong peak keeps its height; a map with many equal peaks is
    suppressed towards zero. A flat map (range below 1e-5) returns zeros. Returns
    float32 of the same shape.
    """
    m = np.asarray(feature_map, dtype=np.float32)
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"feature_map must be a non-empty 2-D array, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError("feature_map contains NaN or inf")
    lo, hi = float(m.min()), float(m.max())
    if hi - lo <= _FLAT_RANGE:
        return np.zeros_like(m)
    m = (m - lo) / (hi - lo)
    dilated = cv2.dilate(m, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REFLECT)
    peaks = ((m >= dilated) & (m > threshold)).astype(np.uint8)
    count, labels = cv2.connectedComponents(peaks, connectivity=8)
    # one value per plateau (the map is constant on each); label 0 is the background
    values = np.zeros(count, dtype=np.float64)
    values[labels[peaks > 0]] = m[peaks > 0]
    values = np.sort(values[1:])
    mean_others = float(values[:-1].mean()) if values.size > 1 else 0.0
    return (m * (1.0 - mean_others) ** 2).astype(np.float32)


def gaussian_mask(shape, centres_xy, sigma_px: float = 10.0) -> np.ndarray:
    """Search envelope (Yücel et al. 2013, Sec. VI): the pointwise **maximum** of unit-height isotropic Gaussians.

    ``shape`` is ``(H, W)`` (or an image shape ``(H, W, 3)``, whose first two entries
    are used). ``centres_xy`` is ``(2,)`` or ``(n, 2)`` points ``(x, y)`` in image
    coordinates (corner origin; may be fractional or outside the image, whose tails
    then show). The value of pixel ``[i, j]`` is evaluated at its centre
    ``p = (j + ½, i + ½)``: ``max_k exp(−‖p − c_k‖² / (2 σ²))``, so the mask is 1 at a
    pixel whose centre is a centre ``c_k`` and ``exp(−1/2)`` at distance σ from an
    isolated centre, never above 1 where Gaussians overlap. No centres (``(0, 2)``)
    gives zeros.
    Returns float32 ``(H, W)``. The paper uses σ = 10 px on 320 × 240 images.
    """
    try:
        height, width = (int(s) for s in tuple(shape)[:2])
    except (TypeError, ValueError):
        raise ValueError(f"shape must be (H, W), got {shape!r}") from None
    if len(tuple(shape)) not in (2, 3) or height < 1 or width < 1:
        raise ValueError(f"shape must be (H, W) with H, W >= 1, got {tuple(shape)}")
    sigma = float(sigma_px)
    if not np.isfinite(sigma) or sigma <= 0.0:
        raise ValueError(f"sigma_px must be finite and > 0, got {sigma_px}")
    centres = np.asarray(centres_xy, dtype=np.float64)
    if centres.ndim == 1:
        centres = centres[None, :]
    if centres.ndim != 2 or centres.shape[1] != 2:
        raise ValueError(f"centres_xy must have shape (2,) or (n, 2) as (x, y), got {np.shape(centres_xy)}")
    if not np.all(np.isfinite(centres)):
        raise ValueError("centres_xy contains NaN or inf")
    xs = np.arange(width, dtype=np.float64) + 0.5  # pixel centres, image coordinates
    ys = np.arange(height, dtype=np.float64) + 0.5
    mask = np.zeros((height, width), dtype=np.float64)
    for cx, cy in centres:  # separable: one outer product per centre
        gx = np.exp(-0.5 * ((xs - cx) / sigma) ** 2)
        gy = np.exp(-0.5 * ((ys - cy) / sigma) ** 2)
        np.maximum(mask, gy[:, None] * gx[None, :], out=mask)
    return mask.astype(np.float32)


class Fixations(NamedTuple):
    """Winner-take-all fixations, in the order they were taken (decreasing saliency).

    ``xy``: ``(n, 2)`` float64 image coordinates ``(x, y)`` of the winning pixels'
    centres: the pixel ``map[i, j]`` gives ``(j + ½, i + ½)``;
    ``value``: ``(n,)`` float64, the (masked) saliency at each, non-increasing.
    """

    xy: np.ndarray
    value: np.ndarray


def winner_take_all(saliency_map, num_fixations: int, *, ior_radius_px: float = 20.0, mask=None) -> Fixations:
    """Pick up to ``num_fixations`` locations: winner-take-all, inhibition of return (Yücel et al. 2013, Sec. VI).

    The map (times ``mask``, if given — e.g. :func:`gaussian_mask` around pooled
    target-point estimates) is searched for its maximum; the winner is recorded and
    the disc of radius ``ior_radius_px`` around it (pixels with ``‖p − winner‖ ≤ r``) is
    inhibited, i.e. excluded from later picks (distances between pixel centres). So
    values are non-increasing and no two fixations are within ``ior_radius_px`` of each
    other. Ties go to the first pixel in row-major order (top-most, then left-most).
    The default radius, 20 px, is about an object's size in the paper's 320 × 240
    scenes. Fixations are returned at the winning pixels' centres (:class:`Fixations`).

    Stops early, returning fewer fixations, when the pixels not yet inhibited are flat
    (range below 1e-6 of the initial peak), e.g. all zero, or all are inhibited.
    Raises ``ValueError`` if the (masked) map is flat from the start ("no location
    stands out"), for a map that is not a finite, non-negative 2-D array, a mask of
    another shape or with negative/non-finite values, ``num_fixations < 1`` or a
    negative radius.
    """
    smap = _check_map(saliency_map)
    if int(num_fixations) != num_fixations or num_fixations < 1:
        raise ValueError(f"num_fixations must be an integer >= 1, got {num_fixations}")
    radius = float(ior_radius_px)
    if not np.isfinite(radius) or radius < 0.0:
        raise ValueError(f"ior_radius_px must be finite and >= 0, got {ior_radius_px}")
    values = smap.astype(np.float64)
    if mask is not None:
        m = np.asarray(mask, dtype=np.float64)
        if m.shape != smap.shape:
            raise ValueError(f"mask has shape {m.shape}, but saliency_map has shape {smap.shape}")
        if not np.all(np.isfinite(m)) or float(m.min()) < 0.0:
            raise ValueError("mask must be finite and non-negative")
        values = values * m
    peak = float(values.max())
    tol = 1e-6 * peak
    if peak <= 0.0 or peak - float(values.min()) <= tol:
        raise ValueError("no location stands out: the (masked) saliency map is flat")
    height, width = values.shape
    ys, xs = np.ogrid[:height, :width]
    available = np.ones(values.shape, dtype=bool)
    picked_xy: list[tuple[float, float]] = []
    picked_value: list[float] = []
    for _ in range(int(num_fixations)):
        if not available.any():
            break
        remaining = values[available]
        if float(remaining.max()) - float(remaining.min()) <= tol:
            break
        candidates = np.where(available, values, -np.inf)
        flat_index = int(np.argmax(candidates))
        y, x = divmod(flat_index, width)
        picked_xy.append((x + 0.5, y + 0.5))  # the pixel's centre in image coordinates
        picked_value.append(float(values[y, x]))
        available &= (xs - x) ** 2 + (ys - y) ** 2 > radius**2
    return Fixations(
        xy=np.asarray(picked_xy, dtype=np.float64).reshape(-1, 2),
        value=np.asarray(picked_value, dtype=np.float64),
    )


def salient_region(saliency_map, xy, *, threshold_fraction: float = 0.5) -> tuple[float, float, float, float]:
    """Bounding box ``(x_min, y_min, x_max, y_max)`` of the salient blob at ``xy`` (Yücel et al. 2013, Sec. VI).

    Region growing (Yücel et al. Sec. VI): the pixels whose saliency is at least
    ``threshold_fraction × s`` form a binary image, ``s`` the saliency of the pixel that
    contains ``xy``; the 8-connected component that contains that pixel is the object.
    ``xy`` is ``(x, y)`` in image coordinates (corner origin): it lies in the pixel
    ``map[⌊y⌋, ⌊x⌋]``, so a fixation of :func:`winner_take_all` (a pixel centre) names
    its own pixel. The box is returned in image coordinates and covers whole pixels:
    columns ``c0 … c1`` and rows ``r0 … r1`` (inclusive indices) give
    ``(c0, r0, c1 + 1, r1 + 1)``, so it is ``x_max − x_min`` px wide (floats, like the
    simulator's object boxes). Raises ``ValueError`` when ``xy`` is outside the map
    (``0 ≤ x < W``, ``0 ≤ y < H``), the saliency there is not positive (nothing to
    segment), ``threshold_fraction`` is not in ``(0, 1]``, or the map is not a finite,
    non-negative 2-D array.
    """
    smap = _check_map(saliency_map)
    fraction = float(threshold_fraction)
    if not (0.0 < fraction <= 1.0):
        raise ValueError(f"threshold_fraction must be in (0, 1], got {threshold_fraction}")
    point = np.asarray(xy, dtype=np.float64).reshape(-1)
    if point.shape != (2,) or not np.all(np.isfinite(point)):
        raise ValueError(f"xy must be a finite (x, y) pair, got {xy!r}")
    height, width = smap.shape
    if not (0.0 <= point[0] < width and 0.0 <= point[1] < height):
        raise ValueError(f"xy = ({point[0]:g}, {point[1]:g}) is outside the {width}x{height} map")
    col, row = (int(v) for v in np.floor(point))
    level = float(smap[row, col])
    if level <= 0.0:
        raise ValueError(f"the saliency at xy = ({point[0]:g}, {point[1]:g}) is {level:g}; nothing to segment there")
    binary = (smap >= fraction * level).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    left, top, box_w, box_h = (int(v) for v in stats[labels[row, col], :4])
    return (float(left), float(top), float(left + box_w), float(top + box_h))


# ----------------------------------------------------------------------------- helpers


def _check_map(saliency_map) -> np.ndarray:
    smap = np.asarray(saliency_map)
    if smap.dtype == object or smap.dtype == bool or not np.issubdtype(smap.dtype, np.number):
        raise TypeError(f"saliency_map must be a numeric array, got dtype {smap.dtype}")
    if smap.ndim != 2 or smap.size == 0:
        raise ValueError(f"saliency_map must be a non-empty (H, W) array, got shape {smap.shape}")
    if not np.all(np.isfinite(smap)):
        raise ValueError("saliency_map contains NaN or inf")
    if float(smap.min()) < 0.0:
        raise ValueError("saliency_map must be non-negative")
    return smap


def _to_unit_range(raw: np.ndarray, shape) -> np.ndarray:
    """Resize to ``shape`` and scale to [0, 1]; a flat map becomes zeros."""
    height, width = shape
    # bicubic keeps a peak between grid nodes of the coarse map where it was (bilinear
    # would snap it to a node, up to 8 px off at Itti's scale 4); its overshoot is clipped
    out = cv2.resize(raw.astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC)
    out = np.maximum(out, 0.0)
    lo, hi = float(out.min()), float(out.max())
    if hi <= 0.0 or hi - lo <= 1e-6 * hi:
        return np.zeros((height, width), dtype=np.float32)
    return ((out - lo) / (hi - lo)).astype(np.float32)


# Itti, Koch & Niebur 1998 ---------------------------------------------------------

_LEVELS = 9  # scales 0..8
_CENTRES = (2, 3, 4)
_DELTAS = (3, 4)
_SUM_SCALE = 4
_ORIENTATIONS = (0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4)


def _gabor_pair(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """Even and odd zero-mean Gabor kernels (SaliencyToolbox's: 9 px, period 7, σ = 7/3)."""
    kernels = []
    for psi in (0.0, np.pi / 2):
        k = cv2.getGaborKernel((9, 9), 7.0 / 3.0, theta, 7.0, 1.0, psi, ktype=cv2.CV_32F)
        k = k - k.mean()  # no response to a uniform patch
        kernels.append(k / np.abs(k).sum())
    return kernels[0], kernels[1]


_GABORS = tuple(_gabor_pair(theta) for theta in _ORIENTATIONS)


_BINOMIAL = np.asarray([1, 4, 6, 4, 1], dtype=np.float32) / 16.0  # cv2.pyrDown's kernel


def _pyramid(channel: np.ndarray) -> list[np.ndarray]:
    """Dyadic Gaussian pyramid, scales 0..8 (level ``σ`` is ``1/2^σ`` of the input).

    (choice) Each level is the previous one smoothed with ``cv2.pyrDown``'s 5-tap
    binomial kernel and halved by ``cv2.resize`` (area, pixel-centre aligned), not
    ``cv2.pyrDown`` itself: pyrDown keeps the even pixels, which a flip or a 90°
    rotation of the image turns into the odd ones, so the maps would change with the
    image's orientation (correlation ~0.75 between a rotated image's map and the
    rotated map, > 0.99 this way). Sizes are the same as pyrDown's, ``⌈n/2⌉``.
    """
    levels = [np.ascontiguousarray(channel, dtype=np.float32)]
    for _ in range(1, _LEVELS):
        previous = levels[-1]
        smooth = cv2.sepFilter2D(previous, -1, _BINOMIAL, _BINOMIAL, borderType=cv2.BORDER_REFLECT_101)
        size = ((previous.shape[1] + 1) // 2, (previous.shape[0] + 1) // 2)
        levels.append(cv2.resize(smooth, size, interpolation=cv2.INTER_AREA))
    return levels


def _resize_to(m: np.ndarray, like: np.ndarray) -> np.ndarray:
    if m.shape == like.shape:
        return m
    interpolation = cv2.INTER_AREA if m.shape[0] >= like.shape[0] else cv2.INTER_LINEAR
    return cv2.resize(m, (like.shape[1], like.shape[0]), interpolation=interpolation)


def _centre_surround(pyr: list[np.ndarray]) -> list[np.ndarray]:
    """``|P(c) ⊖ P(s)|``: the surround interpolated to the centre's scale, then subtracted."""
    return [np.abs(pyr[c] - _resize_to(pyr[c + d], pyr[c])) for c in _CENTRES for d in _DELTAS]


def _across_scale_sum(maps: list[np.ndarray], like: np.ndarray) -> np.ndarray:
    """``⊕``: every map brought to scale 4 and added."""
    total = np.zeros_like(like)
    for m in maps:
        total += _resize_to(m, like)
    return total


def _itti(image: np.ndarray) -> np.ndarray:
    colour = image.ndim == 3
    if colour:
        r, g, b = (np.ascontiguousarray(image[..., i]) for i in range(3))
        intensity = (r + g + b) / 3.0
    else:
        intensity = image
    i_pyr = _pyramid(intensity)
    like = i_pyr[_SUM_SCALE]

    conspicuity = [_across_scale_sum([itti_normalize(m) for m in _centre_surround(i_pyr)], like)]

    if colour:
        # hue decoupled from intensity, only where I > max(I)/10 (else 0)
        lit = intensity > 0.1 * float(intensity.max())
        safe = np.where(lit, intensity, 1.0)
        r, g, b = (np.where(lit, c / safe, 0.0).astype(np.float32) for c in (r, g, b))
        red = np.maximum(r - (g + b) / 2, 0)
        green = np.maximum(g - (r + b) / 2, 0)
        blue = np.maximum(b - (r + g) / 2, 0)
        yellow = np.maximum((r + g) / 2 - np.abs(r - g) / 2 - b, 0)
        # (choice) double opponency as |(R−G)(c) − (R−G)(s)|, as SaliencyToolbox does;
        # the paper's printed (R(c)−G(c)) ⊖ (G(s)−R(s)) read literally adds the two.
        rg_pyr = _pyramid(red - green)
        by_pyr = _pyramid(blue - yellow)
        pairs = zip(_centre_surround(rg_pyr), _centre_surround(by_pyr))
        maps = [itti_normalize(rg) + itti_normalize(by) for rg, by in pairs]
        conspicuity.append(_across_scale_sum(maps, like))

    orientation = np.zeros_like(like)
    for even, odd in _GABORS:
        # Gabor energy (even² + odd²)^½; scales 0 and 1 are never a centre or surround
        o_pyr = [
            np.hypot(cv2.filter2D(level, -1, even), cv2.filter2D(level, -1, odd)) if scale >= _CENTRES[0] else None
            for scale, level in enumerate(i_pyr)
        ]
        orientation += itti_normalize(_across_scale_sum([itti_normalize(m) for m in _centre_surround(o_pyr)], like))
    conspicuity.append(orientation)

    return sum(itti_normalize(c) for c in conspicuity) / len(conspicuity)


# Hou & Zhang 2007 -------------------------------------------------------------------

_SR_WIDTH = 64
_SR_SIGMA = 2.5
_SR_FLOOR = 1e-3


def _spectral_residual(image: np.ndarray) -> np.ndarray:
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    height, width = grey.shape
    work_w = min(_SR_WIDTH, width)
    work_h = max(1, int(round(height * work_w / width)))
    small = cv2.resize(grey, (work_w, work_h), interpolation=cv2.INTER_AREA).astype(np.float64)
    if float(small.max() - small.min()) <= _FLAT_RANGE:
        return np.zeros((work_h, work_w), dtype=np.float32)  # a uniform image has no residual
    spectrum = np.fft.fft2(small - small.mean())
    amplitude = np.abs(spectrum)
    # (choice) floor the amplitude at 1e-3 of its maximum: synthetic images have exact
    # spectral zeros, whose log (−inf or −27) would dominate the residual with ringing
    log_amplitude = np.log(amplitude + _SR_FLOOR * amplitude.max())
    residual = log_amplitude - ndimage.uniform_filter(log_amplitude, size=3, mode="wrap")
    recon = np.fft.ifft2(np.exp(residual + 1j * np.angle(spectrum)))
    power = (np.abs(recon) ** 2).astype(np.float32)
    return cv2.GaussianBlur(power, (0, 0), _SR_SIGMA)
