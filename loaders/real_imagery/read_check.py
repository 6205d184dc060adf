"""The one check of what a turntable source's ``read(cfg, skips)`` returns, before any of it is
written: {object name: {angle in whole degrees: (rgb uint8 (H, W, 3), mask bool (H, W))}}. Object
names become folder names, so each is a plain name (``pipeline.infra.extension.plain_name``).
A breach is an ``ExtensionError`` naming the source, ``read`` and the cause (the object and angle
where it is), not a TypeError from deep in the scan writer."""
from __future__ import annotations

import numbers
from collections.abc import Mapping

import numpy as np

from pipeline.infra.extension import ExtensionError, plain_name_problem


def _views(source: str, obj: str, views) -> None:
    bad = lambda cause: ExtensionError.of("dataset source", source, "read", f"object {obj!r}: {cause}")  # noqa: E731
    if not isinstance(views, Mapping):
        raise bad(f"must map angles to (rgb, mask), got {type(views).__name__}")
    for a, pair in views.items():
        if isinstance(a, (bool, np.bool_)) or not isinstance(a, numbers.Integral):
            raise bad(f"angle {a!r:.40} is {type(a).__name__}, not a whole number of degrees (int)")
        if not 0 <= int(a) < 360:
            raise bad(f"angle {int(a)} is outside [0, 360) degrees")
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise bad(f"angle {int(a)}: must be a pair (rgb, mask), got {type(pair).__name__}")
        rgb, mask = pair
        if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            what = f"{rgb.dtype} {rgb.shape}" if isinstance(rgb, np.ndarray) else type(rgb).__name__
            raise bad(f"angle {int(a)}: rgb must be a uint8 array (H, W, 3), got {what}")
        if not isinstance(mask, np.ndarray) or mask.dtype != bool or mask.shape != rgb.shape[:2]:
            what = f"{mask.dtype} {mask.shape}" if isinstance(mask, np.ndarray) else type(mask).__name__
            raise bad(f"angle {int(a)}: mask must be a bool array {rgb.shape[:2]} (the rgb's height and width), "
                      f"got {what}")


def check_photos(source: str, photos) -> dict:
    """``photos`` when it is what ``read`` must return; else ``ExtensionError``."""
    if not isinstance(photos, Mapping):
        raise ExtensionError.of("dataset source", source, "read",
                                f"must return {{object name: {{angle: (rgb, mask)}}}}, got {type(photos).__name__}")
    for obj, views in photos.items():
        bad = plain_name_problem(obj)
        if bad is not None:
            raise ExtensionError.of("dataset source", source, "read", f"object name {bad}")
        _views(source, obj, views)
    return {o: {int(a): v for a, v in views.items()} for o, views in photos.items()}
