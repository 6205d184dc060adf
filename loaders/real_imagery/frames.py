"""From a real AVD camera pose to the COIL photograph it sees (pure functions, no I/O).

The object frame is the GP models' (``pipeline.method.geometry``): a camera at ``p`` sees an object
at ``o`` with yaw ``psi`` from the bearing of ``Rot(-psi)(p - o)``. A COIL view at turntable angle
``a`` is the object seen from bearing ``a`` (the training side writes its NP1 camera there,
``loaders.real_imagery.training``), so the frame of a camera shows the HELD-OUT view (an angle not
in training) nearest that bearing: at most half the spacing of the held-out views away. With
10-degree training the held-out views are 5, 15, 25, ... (10 degrees apart), so up to 5 degrees;
where a held-out view is missing the gap doubles (up to 10 degrees). ``view_error_deg`` measures it;
the writer refuses frames beyond ``data.real_imagery.max_view_error_deg`` and records the distribution.

The view is scaled UNIFORMLY so that its object fits the real box (the side that reaches the box
first fills it; the object keeps its own aspect ratio, never stretched: ``fit_in_box``) and is
centred in it; the written box annotation is the object's own box (tight, centred on the real
box), so the crop the features stage takes frames the object as the training crops do (a tight
mask box plus the crop margin) and not the real box's padding. The real box decides the frame's
position and size; its centre, which locates the instance, moves by at most half a pixel.
``fit_in_box`` also gives the scale and the box's fill (the object box's share of the real box),
which the writer records per frame. The object is pasted by its mask (``paste_cutout``: its
photograph's ground never reaches the frame), so the surround of every crop is the frame's own:
black, or the clutter ``clutter.render_category_frame`` lays under the objects first. The
sensor model acts on a window around each pasted box (the crop the features stage takes lies
inside it): Gaussian optical blur (``blur_sigma_px``), Gaussian read noise (``noise_std`` grey
levels), then the whole frame is JPEG-encoded (``jpeg_quality``) by the writer.
"""
from __future__ import annotations

import cv2
import numpy as np

from pipeline.method.geometry import bearing, relative_inputs

CONTEXT = 0.5   # surround kept around the object's box, as a fraction of its longer side


def object_bearing_deg(cam_xy, obj_xy, yaw_deg) -> np.ndarray:
    """Bearing (degrees in [0, 360)) of each camera in the object frame: the GP input's angle."""
    u = relative_inputs(np.asarray(cam_xy, float), np.asarray(obj_xy, float), np.radians(yaw_deg))
    return np.degrees(bearing(u)) % 360.0


def heldout_angles(angles, train_step_deg: int) -> list[int]:
    """The angles of ``angles`` that are not training views (not multiples of ``train_step_deg``)."""
    return sorted(int(a) for a in angles if int(a) % int(train_step_deg))


def nearest_view(bearing_deg: float, angles) -> int:
    """The angle of ``angles`` circularly nearest ``bearing_deg`` (ties: the smaller angle)."""
    a = np.asarray(sorted(angles), float)
    if a.size == 0:
        raise ValueError("no held-out view to choose from")
    d = np.abs((a - float(bearing_deg) + 180.0) % 360.0 - 180.0)
    return int(a[int(np.argmin(d))])


def view_error_deg(bearing_deg, angle_deg):
    """Circular distance (degrees, in [0, 180]) between a bearing and the view shown for it."""
    return np.abs((np.asarray(angle_deg, float) - np.asarray(bearing_deg, float) + 180.0) % 360.0 - 180.0)


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), exclusive ends, of the mask's pixels."""
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def fit_in_box(mask: np.ndarray, box) -> tuple[tuple[int, int, int, int], float, float]:
    """The object's box in the frame for a real ``box`` (x0, y0, x1, y1): the mask box scaled by
    one factor so it fits ``box`` (the tighter side fills it), centred; (object box, scale =
    frame pixels per photograph pixel, fill = object box area / real box area)."""
    x0, y0, x1, y1 = (int(v) for v in box)
    bw, bh = x1 - x0, y1 - y0
    mx0, my0, mx1, my1 = mask_bbox(mask)
    cw, ch = mx1 - mx0, my1 - my0
    s = min(bw / cw, bh / ch)
    ow, oh = min(max(int(round(cw * s)), 1), bw), min(max(int(round(ch * s)), 1), bh)
    ox, oy = x0 + (bw - ow) // 2, y0 + (bh - oh) // 2
    return (ox, oy, ox + ow, oy + oh), float(s), (ow * oh) / float(bw * bh)


def resampled_view(rgb: np.ndarray, mask: np.ndarray, box_w: int, box_h: int):
    """The view scaled so its mask box is ``box_w`` x ``box_h`` pixels (callers pass the object's
    own aspect ratio, ``fit_in_box``), with a surround of CONTEXT times the longer output side:
    (patch uint8, (dx, dy) of the object box inside the patch)."""
    x0, y0, x1, y1 = mask_bbox(mask)
    cw, ch = x1 - x0, y1 - y0
    sx, sy = box_w / cw, box_h / ch
    m = CONTEXT * max(box_w, box_h)          # output pixels of surround, the same on every side
    ex, ey = int(round(m / sx)), int(round(m / sy))
    pad = max(ex, ey) + 1
    src = cv2.copyMakeBorder(np.ascontiguousarray(rgb), pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    region = src[y0 + pad - ey:y1 + pad + ey, x0 + pad - ex:x1 + pad + ex]
    dx, dy = round(ex * sx), round(ey * sy)
    size = (box_w + 2 * dx, box_h + 2 * dy)
    shrink = sx * sy < 1.0
    patch = cv2.resize(region, size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return patch, (dx, dy)


def _placement(frame_shape, patch_shape, offset: tuple[int, int], box):
    """(frame rows, frame cols, patch rows, patch cols) where a patch whose object box sits at
    ``offset`` lands with that box on ``box``, clipped to the frame; None when it misses it."""
    H, W = frame_shape[:2]
    px, py = int(box[0]) - offset[0], int(box[1]) - offset[1]
    fx0, fy0 = max(px, 0), max(py, 0)
    fx1, fy1 = min(px + patch_shape[1], W), min(py + patch_shape[0], H)
    if fx1 <= fx0 or fy1 <= fy0:
        return None
    return slice(fy0, fy1), slice(fx0, fx1), slice(fy0 - py, fy1 - py), slice(fx0 - px, fx1 - px)


def paste(frame: np.ndarray, patch: np.ndarray, offset: tuple[int, int], box) -> None:
    """Put the whole ``patch`` into ``frame`` so its object box lands on ``box`` (x0, y0, x1, y1);
    clipped. Only backgrounds are pasted whole: an object goes in by its mask (``paste_cutout``)."""
    at = _placement(frame.shape, patch.shape, offset, box)
    if at is not None:
        frame[at[0], at[1]] = patch[at[2], at[3]]


def alpha_of(mask: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray:
    """The uint8 alpha (0-255) of a photograph: its soft map where it has one, else its mask."""
    a = mask.astype(np.float32) if alpha is None else np.clip(alpha, 0.0, 1.0)
    return np.round(a * 255).astype(np.uint8)


def paste_cutout(frame: np.ndarray, rgb: np.ndarray, mask: np.ndarray, alpha: np.ndarray | None, box) -> None:
    """Blend the object of a photograph into ``frame`` by its alpha (``alpha_of``), its mask box
    scaled to ``box``: only the object's own pixels change the frame (its ground never does), so
    an object pasted later covers an earlier one only where its own silhouette overlaps it."""
    bw, bh = int(box[2]) - int(box[0]), int(box[3]) - int(box[1])
    a8 = alpha_of(mask, alpha)
    # premultiplied: the colour resampled with its alpha, so an edge pixel is the object's share
    # of the photograph's colour over the frame, never its ground's
    pre = rgb.astype(np.float32) * (a8.astype(np.float32)[:, :, None] / 255.0)
    patch, off = resampled_view(pre, mask, bw, bh)
    a, _ = resampled_view(a8, mask, bw, bh)
    at = _placement(frame.shape, patch.shape, off, box)
    if at is None:
        return
    w = a[at[2], at[3]].astype(np.float32)[:, :, None] / 255.0
    under = frame[at[0], at[1]].astype(np.float32)
    frame[at[0], at[1]] = np.clip(np.round(patch[at[2], at[3]] + (1.0 - w) * under), 0, 255).astype(np.uint8)


def sensor_window(box, shape) -> tuple[slice, slice]:
    """Rows and columns around a box that the sensor model acts on: one box side beyond each edge."""
    x0, y0, x1, y1 = (int(v) for v in box)
    m = max(x1 - x0, y1 - y0)
    H, W = shape[:2]
    return slice(max(y0 - m, 0), min(y1 + m, H)), slice(max(x0 - m, 0), min(x1 + m, W))


def apply_sensor(frame: np.ndarray, box, noise_std: float, blur_sigma_px: float, rng: np.random.Generator) -> None:
    """Blur, then read noise, on the box's window of ``frame`` (in place, uint8)."""
    rows, cols = sensor_window(box, frame.shape)
    win = frame[rows, cols].astype(np.float32)
    if blur_sigma_px > 0:
        win = cv2.GaussianBlur(win, (0, 0), blur_sigma_px)
    if noise_std > 0:
        win += rng.normal(0.0, noise_std, win.shape).astype(np.float32)
    # in place (a window is up to 9 box areas of float32): the same values as clip(round(win))
    np.round(win, out=win)
    np.clip(win, 0, 255, out=win)
    frame[rows, cols] = win


def render_frame(size: tuple[int, int], items, noise_std: float, blur_sigma_px: float,
                 rng: np.random.Generator) -> np.ndarray:
    """A black (H, W, 3) frame of ``size`` = (W, H) with each (rgb, mask, box) cut out by its mask
    and pasted in the given order (the caller's: the farthest object first, so a nearer one covers
    it where the real boxes overlap), then the sensor model on each box's window. ``box`` is where
    the object's mask box lands (``fit_in_box``'s object box: the caller decides the aspect ratio)."""
    frame = np.zeros((size[1], size[0], 3), np.uint8)
    for rgb, mask, box in items:
        paste_cutout(frame, rgb, mask, None, box)
    for _, _, box in items:
        apply_sensor(frame, box, noise_std, blur_sigma_px, rng)
    return frame
