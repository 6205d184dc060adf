"""The small renderer: projection, texture mapping, visibility, clipping, depth."""
from __future__ import annotations

import numpy as np
import pytest

from loaders.synthetic.objects import Face, make_instance, prism_faces, rot_z, transform_faces
from loaders.synthetic.render import Camera, Light, Mesh, clip_near, project, render

K = np.array([[100.0, 0.0, 79.5], [0.0, 100.0, 59.5], [0.0, 0.0, 1.0]])
FLAT = Light(ambient=1.0, diffuse=0.0)  # shading factor exactly 1: colours pass through


def box(x0, y0, x1, y1, z0, z1, color=(0.5, 0.5, 0.5)) -> tuple[Face, ...]:
    foot = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
    return tuple(prism_faces(foot, z0, z1, side_color=color))


def test_look_at_is_a_proper_rotation_and_projects_the_target_to_the_principal_point():
    cam = Camera.look_at([1.0, -2.0, 0.7], [0.2, 0.3, 0.1], K, 160, 120)
    assert np.allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(cam.R), 1.0)
    assert np.allclose(cam.centre, [1.0, -2.0, 0.7])
    assert np.allclose(project(cam, np.array([[0.2, 0.3, 0.1]])), [[79.5, 59.5]])
    # Image y points down: a point above the target projects above the principal point.
    assert project(cam, np.array([[0.2, 0.3, 0.3]]))[0, 1] < 59.5
    assert np.allclose(Camera.from_pose(cam.pose(), K, 160, 120).t, cam.t)


def test_box_silhouette_matches_projected_vertices():
    faces = box(-0.1, -0.15, 0.1, 0.15, 0.0, 0.3)
    cam = Camera.look_at([1.2, 0.5, 0.6], [0.0, 0.0, 0.15], K, 160, 120)
    res = render(cam, [Mesh(faces, label=7)], FLAT)
    ys, xs = np.nonzero(res.ids == 7)
    uv = project(cam, np.concatenate([f.vertices for f in faces]))
    # Pixel centres inside the polygon: the silhouette lies within a pixel of the projected hull.
    assert abs(xs.min() - uv[:, 0].min()) <= 1.0 and abs(xs.max() - uv[:, 0].max()) <= 1.0
    assert abs(ys.min() - uv[:, 1].min()) <= 1.0 and abs(ys.max() - uv[:, 1].max()) <= 1.0
    assert set(np.unique(res.ids)) == {0, 7}


def test_texture_is_mapped_by_the_exact_plane_homography():
    # A 2x2 texture of four colours on a 0.4 m square facing the camera at an oblique angle.
    tex = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 0]]], np.uint8)
    tex = np.repeat(np.repeat(tex, 32, 0), 32, 1)
    tl = np.array([0.0, -0.2, 0.4])
    u, v = np.array([0.0, 0.4, 0.0]), np.array([0.0, 0.0, -0.4])
    verts = np.array([tl + v, tl + u + v, tl + u, tl])
    face = Face(verts, np.array([1.0, 0, 0]), texture=tex, origin=tl, u_axis=u, v_axis=v)
    cam = Camera.look_at([1.0, 0.35, 0.45], [0.0, 0.0, 0.2], K, 160, 120)
    res = render(cam, [Mesh((face,), 1)], FLAT)
    for (qu, qv), colour in {(0.25, 0.25): (255, 0, 0), (0.75, 0.25): (0, 255, 0),
                             (0.25, 0.75): (0, 0, 255), (0.75, 0.75): (255, 255, 0)}.items():
        x, y = np.round(project(cam, (tl + qu * u + qv * v)[None])[0]).astype(int)
        assert tuple(res.rgb[y, x]) == colour


def test_occlusion_is_per_pixel_not_by_list_order():
    # A small box standing on the far edge of a big slab, seen from above: its centroid is farther
    # from the camera than the slab's, so painter's order alone would hide it.
    slab = Mesh(box(-0.6, -0.6, 0.6, 0.6, 0.4, 0.45), 1)
    item = Mesh(box(-0.55, -0.05, -0.45, 0.05, 0.45, 0.6), 2)
    cam = Camera.look_at([1.2, 0.0, 1.3], [-0.2, 0.0, 0.45], K, 160, 120)
    top = np.array([[-0.5, 0.0, 0.6]])
    x, y = np.round(project(cam, top)[0]).astype(int)
    for order in ([slab, item], [item, slab]):
        res = render(cam, order, FLAT)
        assert res.ids[y, x] == 2
        assert (res.ids == 2).sum() > 20 and (res.ids == 1).sum() > 1000
    # And a near box hides a far one where they overlap on screen.
    near, far = Mesh(box(0.3, -0.1, 0.5, 0.1, 0.0, 0.2), 3), Mesh(box(-0.3, -0.1, -0.1, 0.1, 0.0, 0.2), 4)
    cam2 = Camera.look_at([2.0, 0.0, 0.1], [0.0, 0.0, 0.1], K, 160, 120)
    for order in ([near, far], [far, near]):
        ids = render(cam2, order, FLAT).ids
        assert ids[60, 80] == 3 and not (ids == 4).any()


def test_bottle_neck_hidden_behind_body_from_below_and_visible_from_above():
    inst = make_instance("aunt_jemima_original_syrup", 0)
    body, neck = inst.parts
    meshes = [Mesh(body.faces, 1), Mesh(neck.faces, 2)]
    # Camera below the shoulder, close: the body hides the neck's lower end.
    low = Camera.look_at([0.25, 0.0, 0.12], [0.0, 0.0, 0.2], K, 160, 120)
    base = np.array([[0.0, 0.0, 0.19]])  # neck base = centre of the body's top cap
    x, y = np.round(project(low, base)[0]).astype(int)
    assert render(low, meshes[::-1], FLAT).ids[y, x] == 1
    high = Camera.look_at([0.25, 0.0, 0.6], [0.0, 0.0, 0.19], K, 160, 120)
    x, y = np.round(project(high, base)[0]).astype(int)
    assert render(high, meshes, FLAT).ids[y, x] == 2


def test_back_faces_are_culled_and_faces_have_flat_lambert_shading():
    quad = np.array([[0, -0.2, 0], [0, 0.2, 0], [0, 0.2, 0.4], [0, -0.2, 0.4]], float)
    front = Face(quad, np.array([1.0, 0, 0]), color=(1.0, 1.0, 1.0))
    back = Face(quad[::-1], np.array([-1.0, 0, 0]), color=(1.0, 1.0, 1.0))
    cam = Camera.look_at([1.0, 0, 0.2], [0, 0, 0.2], K, 160, 120)
    assert not render(cam, [Mesh((back,), 1)], FLAT).ids.any()
    light = Light(direction=(1.0, 0.0, 1.0), color=(1.0, 0.5, 0.25), ambient=0.2, diffuse=0.6)
    rgb = render(cam, [Mesh((front,), 1)], light).rgb[60, 80].astype(float)
    expected = np.array([1.0, 0.5, 0.25]) * (0.2 + 0.6 / np.sqrt(2)) * 255
    assert np.allclose(rgb, expected, atol=1.0)


def test_near_plane_clipping_of_a_floor_that_extends_behind_the_camera():
    floor = Face(np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float), np.array([0, 0, 1.0]))
    cam = Camera.look_at([0, 0, 1.0], [1.0, 0, 1.0], K, 160, 120)  # level: horizon at the centre row
    res = render(cam, [Mesh((floor,), 5)], FLAT, want_depth=True)
    covered = (res.ids == 5)
    # Rows below the horizon see floor up to the far edge (5 m ahead: 20 px below the horizon).
    assert covered[81:].all() and not covered[:59].any()
    # Depth along the optical axis of a floor point seen at row v: z = f * h / (v - cy).
    v = 100
    assert np.isclose(res.depth[v, 80], 100.0 * 1.0 / (v - 59.5), rtol=1e-4)


def test_clip_near_keeps_the_part_in_front():
    P = np.array([[-1.0, 0, -1.0], [1.0, 0, -1.0], [1.0, 0, 3.0], [-1.0, 0, 3.0]])
    C = clip_near(P, 0.5)
    assert (C[:, 2] >= 0.5 - 1e-12).all()
    assert np.isclose(C[:, 2].min(), 0.5) and len(C) == 4
    assert clip_near(P - [0, 0, 10.0], 0.5) is None
    ahead = P + [0, 0, 10.0]
    assert clip_near(ahead, 0.5) is ahead


def test_depth_of_a_plane_and_face_labels():
    inst = make_instance("mahatma_rice", 0)
    faces = transform_faces(inst.faces, rot_z(0.0), np.zeros(3))
    cam = Camera.look_at([0.8, 0.0, 0.125], [0.0, 0.0, 0.125], K, 160, 120)
    res = render(cam, [Mesh(faces, 14)], FLAT, face_labels=True, want_depth=True)
    # Looking straight at the front (+x) face, 0.8 - 0.035 m away.
    front = next(f for f in inst.faces if f.region == "front")
    assert res.ids[60, 80] == front.label + 1
    assert np.isclose(res.depth[60, 80], 0.8 - 0.035, atol=1e-5)
    assert (res.depth[res.ids == 0] == 0).all()
    only = render(cam, [Mesh(faces, 14)], FLAT, depth_only=True)
    assert np.array_equal(only.ids, render(cam, [Mesh(faces, 14)], FLAT).ids)


@pytest.mark.parametrize("yaw", [0.0, 37.0, 200.0])
def test_transform_faces_moves_textures_with_the_geometry(yaw):
    inst = make_instance("honey_bunches_of_oats_honey_roasted", 0)
    R, t = rot_z(yaw), np.array([1.0, 2.0, 0.5])
    moved = transform_faces(inst.faces, R, t)
    for a, b in zip(inst.faces, moved):
        assert np.allclose(b.vertices, a.vertices @ R.T + t)
        assert np.allclose(b.normal, R @ a.normal)
        if a.origin is not None:
            assert np.allclose(b.origin, R @ a.origin + t)


def _paste_by_boolean_index(dst, patch, draw):
    dst[draw] = patch[draw]


@pytest.mark.parametrize("face_labels", [False, True])
def test_masked_paste_writes_what_boolean_assignment_writes(monkeypatch, face_labels):
    # A room-like shell, a textured face and colour boxes that occlude one another, rendered with
    # OpenCV's masked copy (the renderer's) and with numpy's boolean assignment: the same bytes.
    import loaders.synthetic.render as R

    tex = np.random.default_rng(3).integers(0, 256, (40, 60, 3), dtype=np.uint8)
    tl = np.array([0.25, -0.45, 0.5])    # in front of part of the grey box
    u, v = np.array([0.0, 0.5, 0.0]), np.array([0.0, 0.0, -0.4])
    poster = Face(np.array([tl + v, tl + u + v, tl + u, tl]), np.array([1.0, 0, 0]), texture=tex,
                  origin=tl, u_axis=u, v_axis=v)
    floor = box(-2.0, -2.0, 2.0, 2.0, -0.05, 0.0, color=(0.3, 0.6, 0.2))
    meshes = [Mesh(floor, 0, shell=True), Mesh((poster,), 3), Mesh(box(-0.1, -0.1, 0.1, 0.1, 0.0, 0.3), 7),
              Mesh(box(-0.3, 0.05, -0.15, 0.2, 0.0, 0.5, color=(0.9, 0.1, 0.4)), 9)]
    cam = Camera.look_at([1.3, 0.6, 0.8], [0.0, 0.0, 0.15], K, 160, 120)
    light = Light((0.3, 0.2, 1.0), ambient=0.6, diffuse=0.5)
    fast = render(cam, meshes, light, (20, 30, 40), face_labels=face_labels, want_depth=True)
    monkeypatch.setattr(R, "_paste", _paste_by_boolean_index)
    slow = render(cam, meshes, light, (20, 30, 40), face_labels=face_labels, want_depth=True)
    assert face_labels or len(np.unique(fast.ids)) == 4   # every mesh shows
    np.testing.assert_array_equal(fast.rgb, slow.rgb)
    np.testing.assert_array_equal(fast.ids, slow.ids)
    np.testing.assert_array_equal(fast.depth, slow.depth)


def test_masked_paste_writes_into_a_view_of_the_image():
    from loaders.synthetic.render import _paste

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (50, 70, 3), dtype=np.uint8)
    want = img.copy()
    patch = rng.integers(0, 256, (20, 31, 3), dtype=np.uint8)
    draw = rng.random((20, 31)) < 0.4
    _paste(img[7:27, 13:44], patch, draw)
    _paste_by_boolean_index(want[7:27, 13:44], patch, draw)
    np.testing.assert_array_equal(img, want)
