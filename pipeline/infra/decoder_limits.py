"""OpenCV's own decoder limits, set before OpenCV is loaded.

The image gate (``loaders.image_gate``) reads each header beside the decoder, and a header the two
read differently (a TIFF listing ImageWidth twice, a Radiance HDR whose 127-character line OpenCV
splits) once reached a 20000 x 20000 allocation. OpenCV checks every decoded size
against ``OPENCV_IO_MAX_IMAGE_PIXELS``, ``_WIDTH`` and ``_HEIGHT`` after its own header read and
before it allocates, so the decoder's view of the size is bounded whatever the gate read. OpenCV
reads these variables once, when ``cv2`` is loaded (checked: set after ``import cv2`` they have no
effect), so ``pipeline/__init__.py`` sets them, which runs before any of the project's modules
imports ``cv2``. ``data.max_image_megapixels`` arrives later, with the config: the gate applies it
from the header, and a value above this process cap is refused (``loaders.files``), since OpenCV
would refuse those images anyway. ``VIEWFUSE_MAX_IMAGE_MEGAPIXELS`` raises the cap for a process.
"""
from __future__ import annotations

import os
import sys

DEFAULT_CAP_MEGAPIXELS = 64.0   # data.max_image_megapixels' default (loaders.files)
MAX_SIDE = 1 << 16              # JPEG's own limit; wider images are not dataset views
ENV = "VIEWFUSE_MAX_IMAGE_MEGAPIXELS"


def cap_megapixels() -> float:
    try:
        return max(float(os.environ.get(ENV, DEFAULT_CAP_MEGAPIXELS)), 0.01)
    except ValueError:
        return DEFAULT_CAP_MEGAPIXELS


def install() -> bool:
    """Set OpenCV's limits in the environment (lowering, never raising, a value already there);
    False when ``cv2`` is already loaded and they can no longer take effect."""
    limits = {"OPENCV_IO_MAX_IMAGE_PIXELS": int(cap_megapixels() * 1e6),
              "OPENCV_IO_MAX_IMAGE_WIDTH": MAX_SIDE, "OPENCV_IO_MAX_IMAGE_HEIGHT": MAX_SIDE}
    for key, value in limits.items():
        try:
            have = int(os.environ[key])
        except (KeyError, ValueError):
            have = value
        os.environ[key] = str(min(have, value))
    return "cv2" not in sys.modules
