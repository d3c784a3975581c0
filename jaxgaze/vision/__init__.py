"""The image side of joint attention (Yücel et al., T-CYB 2013 and CogSci 2012;
``../shared/METHODS.md`` §2): face detection, cylindrical head-model tracking,
bottom-up saliency and the attended object.

Image conventions are in :mod:`jaxgaze.vision.images` and ``docs/conventions.md``.
"""

from jaxgaze.vision.images import check_image, to_float, to_gray_float, to_gray_uint8, to_rgb_float

__all__ = ["check_image", "to_float", "to_gray_float", "to_gray_uint8", "to_rgb_float"]
