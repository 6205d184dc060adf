"""A small numpy/OpenCV renderer for convex textured solids, shared by both writers.

Pinhole camera (OpenCV axes: x right, y down, z forward; pixel centres at integer coordinates)
with world->camera rotation ``R`` and translation ``t``. Per face: back-face culling, clipping
against the near plane (room walls can be behind the camera), projection, a polygon mask
(``cv2.fillConvexPoly``, sub-pixel), and for a textured face the exact plane -> image homography
``K [R u/W | R v/H | R p0 + t]`` applied with ``cv2.warpPerspective`` to the face's bounding
rectangle only. Flat Lambert + ambient shading with one directional light.

Visibility: ``shell`` meshes (the room's walls/floor, seen from inside) are drawn first and never
occlude; the other parts are drawn farthest first (painter's order) with a per-pixel test on
1/z of the face plane (affine in pixel coordinates for a plane), so stacked or touching parts
(a bottle's neck on its body, an object on a table) come out right from any viewpoint. The same
1/z buffer gives the optional depth map and the instance-ID buffer (which instance covers each
pixel after occlusion) that masks and boxes are computed from.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from loaders.synthetic.objects import Face

NEAR = 0.02  # metres: near clipping plane


@dataclass(frozen=True)
class Camera:
    K: np.ndarray       # 3x3 intrinsics
    R: np.ndarray       # 3x3 world -> camera rotation
    t: np.ndarray       # (3,) world -> camera translation: X_cam = R X + t
    width: int
    height: int

    @property
    def centre(self) -> np.ndarray:
        return -self.R.T @ self.t

    @classmethod
    def from_pose(cls, H_world_from_cam: np.ndarray, K: np.ndarray, width: int, height: int) -> "Camera":
        """From a 4x4 camera -> world transform (e.g. BigBIRD's H_table_from_NPc)."""
        H = np.asarray(H_world_from_cam, dtype=np.float64)
        R = H[:3, :3].T
        return cls(np.asarray(K, float), R, -R @ H[:3, 3], int(width), int(height))

    @classmethod
    def look_at(cls, eye, target, K, width: int, height: int, up=(0.0, 0.0, 1.0)) -> "Camera":
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
        f = target - eye
        f /= np.linalg.norm(f)
        right = np.cross(f, up)
        nr = np.linalg.norm(right)
        if nr < 1e-9:
            raise ValueError("look_at: viewing direction is parallel to 'up'")
        right /= nr
        down = np.cross(f, right)
        R = np.stack([right, down, f])
        return cls(np.asarray(K, float), R, -R @ eye, int(width), int(height))

    def pose(self) -> np.ndarray:
        """4x4 camera -> world transform."""
        H = np.eye(4)
        H[:3, :3] = self.R.T
        H[:3, 3] = self.centre
        return H


@dataclass(frozen=True)
class Light:
    direction: tuple = (0.0, 0.0, 1.0)   # from the scene towards the light (normalised here)
    color: tuple = (1.0, 1.0, 1.0)
    ambient: float = 0.5
    diffuse: float = 0.5

    def shade(self, normal: np.ndarray) -> np.ndarray:
        d = np.asarray(self.direction, float)
        lam = max(0.0, float(normal @ d) / float(np.linalg.norm(d)))
        return np.asarray(self.color, float) * (self.ambient + self.diffuse * lam)


@dataclass(frozen=True, eq=False)  # holds arrays: identity, not value, equality
class Mesh:
    """A convex solid (or a room shell) in world coordinates."""
    faces: tuple[Face, ...]
    label: int = 0          # written to the ID buffer (instance id; 0 = scenery)
    shell: bool = False     # enclosing surfaces seen from inside: drawn first, never occlude

    def __post_init__(self):
        # Bounding sphere, computed once: every render tests it against the view frustum.
        pts = np.concatenate([f.vertices for f in self.faces])
        c = 0.5 * (pts.min(0) + pts.max(0))
        object.__setattr__(self, "_bounds", (c, float(np.linalg.norm(pts - c, axis=1).max())))

    def bounds(self) -> tuple[np.ndarray, float]:
        return self._bounds


@dataclass
class RenderResult:
    rgb: np.ndarray          # (H, W, 3) uint8
    ids: np.ndarray          # (H, W) int32: mesh label (or face label + 1) per pixel, 0 = none
    depth: np.ndarray | None  # (H, W) float32 metres along the optical axis, 0 = nothing


def clip_near(P: np.ndarray, near: float = NEAR) -> np.ndarray | None:
    """Sutherland-Hodgman clip of a camera-frame polygon against z >= near."""
    inside = P[:, 2] >= near
    if inside.all():
        return P
    if not inside.any():
        return None
    out = []
    n = len(P)
    for i in range(n):
        a, b = P[i], P[(i + 1) % n]
        ia, ib = inside[i], inside[(i + 1) % n]
        if ia:
            out.append(a)
        if ia != ib:
            s = (near - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out) if len(out) >= 3 else None


def _side_planes(cam: Camera, Kinv: np.ndarray) -> np.ndarray:
    """(4, 3) unit normals of the frustum's side planes (through the optical centre), inward:
    the image corners run clockwise (y down), so corner_i x corner_i+1 points inside."""
    w, h = cam.width, cam.height
    corners = (Kinv @ np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1],
                                [-0.5, h - 0.5, 1]]).T).T
    n = np.cross(corners, np.roll(corners, -1, axis=0))
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _in_frustum(cam: Camera, planes: np.ndarray, centre: np.ndarray, radius: float) -> bool:
    """Conservative bounding-sphere test against the near plane and the four image sides."""
    c = cam.R @ centre + cam.t
    if c[2] + radius < NEAR:
        return False
    return bool((planes @ c >= -radius).all())


def render(cam: Camera, meshes, light: Light, background=(0, 0, 0), *, face_labels: bool = False,
           want_depth: bool = False, depth_only: bool = False) -> RenderResult:
    """Render meshes; ``background``: an (H, W, 3) uint8 image or an RGB colour (0-255)."""
    H, W = cam.height, cam.width
    if depth_only:
        want_depth = True
        rgb = None
    elif isinstance(background, np.ndarray) and background.ndim == 3:
        if background.shape[:2] != (H, W):
            raise ValueError(f"background is {background.shape[1]}x{background.shape[0]}, camera is {W}x{H}")
        rgb = background.copy()
    else:
        rgb = np.empty((H, W, 3), np.uint8)
        rgb[:] = np.asarray(background, np.uint8)
    ids = np.zeros((H, W), np.int32)
    invz = np.zeros((H, W), np.float32)
    K, R, t = cam.K, cam.R, cam.t
    Kinv = np.linalg.inv(K)
    C = cam.centre

    planes = _side_planes(cam, Kinv)
    visible = []
    for m in meshes:
        c, r = m.bounds()
        if _in_frustum(cam, planes, c, r):
            visible.append((m, float(np.linalg.norm(c - C))))
    # Shells first; then painter's order, farthest first (the 1/z test settles the rest).
    order = [m for m, _ in visible if m.shell] + \
            [m for m, _ in sorted((v for v in visible if not v[0].shell), key=lambda v: -v[1])]

    for mesh in order:
        for f in mesh.faces:
            if f.normal @ (C - f.vertices[0]) <= 1e-12:
                continue  # back face
            Xc = f.vertices @ R.T + t
            poly = clip_near(Xc)
            if poly is None:
                continue
            uv = poly @ K.T
            uv = uv[:, :2] / uv[:, 2:3]
            x0 = max(0, int(np.floor(uv[:, 0].min())))
            y0 = max(0, int(np.floor(uv[:, 1].min())))
            x1 = min(W, int(np.ceil(uv[:, 0].max())) + 1)
            y1 = min(H, int(np.ceil(uv[:, 1].max())) + 1)
            if x1 <= x0 or y1 <= y0:
                continue
            w, h = x1 - x0, y1 - y0
            mask = np.zeros((h, w), np.uint8)
            pts = np.round((uv - (x0, y0)) * 16).astype(np.int32)
            cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=4)
            draw = mask.view(bool)
            need_z = want_depth or not mesh.shell
            if need_z:
                # Plane n.X = d in camera coordinates; on the ray X = z K^-1 [u, v, 1]:
                # 1/z = (n . K^-1 [u, v, 1]) / d, affine in (u, v).
                nc = R @ f.normal
                d = float(nc @ Xc[0])
                if abs(d) < 1e-12:
                    continue  # plane through the optical centre: seen edge-on
                a = (Kinv.T @ nc) / d
                us = np.arange(x0, x1, dtype=np.float32)
                vs = np.arange(y0, y1, dtype=np.float32)
                iz = (a[0] * us)[None, :] + (a[1] * vs + a[2])[:, None]
                zr = invz[y0:y1, x0:x1]
                if not mesh.shell:
                    draw = draw & (iz > zr)
                    if not draw.any():
                        continue
                np.copyto(zr, iz, where=draw)
            np.copyto(ids[y0:y1, x0:x1], (f.label + 1) if face_labels else mesh.label, where=draw)
            if rgb is None:
                continue
            s = light.shade(f.normal)
            if f.texture is not None:
                tex = f.texture
                th, tw = tex.shape[:2]
                M = np.column_stack([R @ f.u_axis / tw, R @ f.v_axis / th,
                                     R @ (f.origin + 0.5 * f.u_axis / tw + 0.5 * f.v_axis / th) + t])
                Hm = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]]) @ K @ M
                patch = cv2.warpPerspective(tex, Hm, (w, h), flags=cv2.INTER_LINEAR,
                                            borderMode=cv2.BORDER_REPLICATE)
                patch = cv2.multiply(patch, (float(s[0]), float(s[1]), float(s[2]), 0.0))
            else:
                col = np.clip(np.asarray(f.color, float) * s * 255.0 + 0.5, 0, 255).astype(np.uint8)
                patch = np.empty((h, w, 3), np.uint8)
                cv2.rectangle(patch, (0, 0), (w, h), tuple(int(v) for v in col), -1)
            _paste(rgb[y0:y1, x0:x1], patch, draw)
    depth = None
    if want_depth:
        depth = np.zeros((H, W), np.float32)
        hit = invz > 0
        depth[hit] = 1.0 / invz[hit]
    return RenderResult(rgb if rgb is not None else np.zeros((H, W, 3), np.uint8), ids, depth)


def _paste(dst: np.ndarray, patch: np.ndarray, draw: np.ndarray) -> None:
    """dst[draw] = patch[draw] for an (h, w, 3) view of the image: OpenCV's masked copy writes
    the same bytes as numpy's boolean assignment at a thirtieth of its CPU time (a BigBIRD view's
    turntable and caps cover a third of its 1.3 million pixels)."""
    out = cv2.copyTo(patch, draw.view(np.uint8), dst)
    if not np.shares_memory(out, dst):  # pragma: no cover - OpenCV copied the view after all
        np.copyto(dst, out)


def project(cam: Camera, X: np.ndarray) -> np.ndarray:
    """Pixel coordinates (n, 2) of world points (n, 3) in front of the camera."""
    Xc = np.asarray(X, float) @ cam.R.T + cam.t
    uv = Xc @ cam.K.T
    return uv[:, :2] / uv[:, 2:3]
