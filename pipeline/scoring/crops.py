"""The crop policy shared by BigBIRD and AVD views: box -> margin -> square -> resize -> normalise.

Boxes are ``(x0, y0, x1, y1)`` in pixels with exclusive ends (``img[y0:y1, x0:x1]``). The crop box
may extend past the image; the outside is filled per ``pad`` ("mean" = the normalisation mean, i.e.
a zero network input that carries no signal; "edge" = replicate border pixels; "reflect").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

PAD_MODES = ("mean", "edge", "reflect")
INTERPOLATIONS = ("auto", "area", "linear", "cubic")


@dataclass(frozen=True)
class CropPolicy:
    margin: float = 0.10            # fraction of the box's longer side added on every side
    square: bool = True             # grow the crop to a square around the box centre
    size: int = 128                 # output side (the network input)
    pad: str = "mean"
    interpolation: str = "auto"     # auto = area when shrinking, linear when enlarging
    mean: tuple[float, ...] = IMAGENET_MEAN
    std: tuple[float, ...] = IMAGENET_STD

    def __post_init__(self) -> None:
        if self.margin < 0 or not math.isfinite(self.margin):
            raise ValueError(f"crop margin must be a finite number >= 0, got {self.margin}")
        if self.size < 1:
            raise ValueError(f"crop size must be >= 1, got {self.size}")
        if self.pad not in PAD_MODES:
            raise ValueError(f"crop pad must be one of {PAD_MODES}, got {self.pad!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"crop interpolation must be one of {INTERPOLATIONS}, got {self.interpolation!r}")
        if len(self.mean) != 3 or len(self.std) != 3 or min(self.std) <= 0:
            raise ValueError("crop mean/std must be three numbers each, std > 0")

    @classmethod
    def from_config(cls, cfg) -> "CropPolicy":
        """Policy from ``[features]`` (geometry) and ``[classifier]`` (input size, normalisation)."""
        f, c = cfg.features, cfg.classifier
        return cls(margin=f.margin, square=f.square, size=c.input_size, pad=f.pad,
                   interpolation=f.interpolation, mean=tuple(c.mean), std=tuple(c.std))

    def as_dict(self) -> dict:
        return {"margin": self.margin, "square": self.square, "size": self.size, "pad": self.pad,
                "interpolation": self.interpolation, "mean": list(self.mean), "std": list(self.std)}

    def crop_box(self, box) -> tuple[int, int, int, int]:
        return crop_box(box, self.margin, self.square)

    def crop(self, image: np.ndarray, box) -> tuple[np.ndarray, tuple[int, int, int, int]]:
        """(uint8 crop (size, size, 3), the integer crop box actually used)."""
        cb = self.crop_box(box)
        return extract(image, cb, self.size, pad=self.pad, interpolation=self.interpolation,
                       fill=self.fill_value), cb

    @property
    def fill_value(self) -> tuple[int, int, int]:
        return tuple(int(round(255 * m)) for m in self.mean)  # type: ignore[return-value]

    def to_tensor(self, crops: np.ndarray):
        return to_tensor(crops, self.mean, self.std)


def check_box(box, where: str = "box") -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = (int(v) for v in box)
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"{where}: degenerate box {(x0, y0, x1, y1)} (need x1 > x0 and y1 > y0)")
    return x0, y0, x1, y1


def crop_box(box, margin: float, square: bool) -> tuple[int, int, int, int]:
    """Integer crop box (exclusive ends) for an object box.

    The margin is ``margin * max(w, h)`` on every side. Square crops have side
    ``round(max(w, h) * (1 + 2 margin))`` and are centred on the box centre (to within half a
    pixel); otherwise each side moves out by the margin, rounded to the nearest pixel.
    """
    x0, y0, x1, y1 = check_box(box)
    w, h = x1 - x0, y1 - y0
    m = margin * max(w, h)
    if square:
        side = max(1, int(round(max(w, h) + 2 * m)))
        cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
        # floor(c - side/2 + 0.5): the square's centre is within half a pixel of the box centre.
        ox, oy = math.floor(cx - side / 2 + 0.5), math.floor(cy - side / 2 + 0.5)
        return ox, oy, ox + side, oy + side
    mi = int(round(m))
    return x0 - mi, y0 - mi, x1 + mi, y1 + mi


def extract(image: np.ndarray, cbox, size: int, *, pad: str = "mean", interpolation: str = "auto",
            fill=(124, 116, 104)) -> np.ndarray:
    """Cut ``cbox`` out of ``image`` (padding where it leaves the image) and resize to size x size."""
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    H, W = image.shape[:2]
    x0, y0, x1, y1 = check_box(cbox, "crop box")
    ix0, iy0, ix1, iy1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if ix1 <= ix0 or iy1 <= iy0:
        raise ValueError(f"crop box {(x0, y0, x1, y1)} does not overlap the {W}x{H} image")
    part = image[iy0:iy1, ix0:ix1]
    top, left, bottom, right = iy0 - y0, ix0 - x0, y1 - iy1, x1 - ix1
    if top or left or bottom or right:
        if pad == "mean":
            part = cv2.copyMakeBorder(part, top, bottom, left, right, cv2.BORDER_CONSTANT,
                                      value=tuple(int(v) for v in fill))
        elif pad == "edge":
            part = cv2.copyMakeBorder(part, top, bottom, left, right, cv2.BORDER_REPLICATE)
        elif pad == "reflect":
            # BORDER_REFLECT_101 needs the border smaller than the part; fall back to replicate.
            if max(top, bottom) < part.shape[0] and max(left, right) < part.shape[1]:
                part = cv2.copyMakeBorder(part, top, bottom, left, right, cv2.BORDER_REFLECT_101)
            else:
                part = cv2.copyMakeBorder(part, top, bottom, left, right, cv2.BORDER_REPLICATE)
        else:
            raise ValueError(f"unknown pad mode {pad!r}")
    h, w = part.shape[:2]
    if (h, w) == (size, size):
        return np.ascontiguousarray(part)
    if interpolation == "auto":
        flag = cv2.INTER_AREA if max(h, w) > size else cv2.INTER_LINEAR
    else:
        flag = {"area": cv2.INTER_AREA, "linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}[interpolation]
    return cv2.resize(np.ascontiguousarray(part), (size, size), interpolation=flag)


def to_tensor(crops: np.ndarray, mean=IMAGENET_MEAN, std=IMAGENET_STD):
    """uint8 (N, H, W, 3) RGB -> float32 torch (N, 3, H, W), ``(x/255 - mean) / std``."""
    import torch

    crops = np.asarray(crops)
    if crops.ndim == 3:
        crops = crops[None]
    if crops.ndim != 4 or crops.shape[-1] != 3 or crops.dtype != np.uint8:
        raise ValueError(f"expected uint8 crops (N, H, W, 3), got {crops.dtype} {crops.shape}")
    t = torch.from_numpy(np.ascontiguousarray(crops)).permute(0, 3, 1, 2).float().div_(255.0)
    m = torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1)
    s = torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1)
    return t.sub_(m).div_(s).contiguous()
