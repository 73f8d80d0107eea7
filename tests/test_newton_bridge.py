"""The Newton bridge (warprt.newton_bridge) against Newton itself: the converted scene, the poses
written from ``state.body_q``, and images where the two renderers' models coincide (depth, shape
index and lit colour against Newton's SensorCamera on the same model and cameras), plus an
update loop that rebuilds, recompiles and copies nothing. Skipped where Newton is not installed.

Tolerances: depth to float32 rounding of two different ray/box, ray/sphere, ray/capsule and
ray/cylinder computations
(measured median 3e-7 relative; 99.9% of pixels within 1e-4, the rest grazing box faces);
colour on lit pixels to float32 (measured median ratio 1 - 1.2e-7; 99.5% within 1e-3, the rest
where the two normals' rounding differs on grazing faces). Pixels on silhouettes may see
another shape in one renderer (counted, 0.1% allowed).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import warp as wp

newton = pytest.importorskip("newton")

import warprt  # noqa: E402
from warprt.newton_bridge import TESSELLATION, NewtonRenderer, look_at_pose, scene_from_model, srgb_to_linear  # noqa: E402

W, C, H, X = 2, 2, 40, 48
FOV = 45.0
BOX = (0.3, 0.2, 0.25)


def model(worlds=W):
    b = newton.ModelBuilder()
    b.add_ground_plane(color=(0.8, 0.8, 0.75))
    sub = newton.ModelBuilder()
    body = sub.add_body(xform=wp.transform((0.0, 0.0, 0.25), wp.quat_from_axis_angle(wp.vec3(0, 0, 1), 0.4)))
    sub.add_shape_box(body, hx=BOX[0], hy=BOX[1], hz=BOX[2], color=(0.9, 0.2, 0.2))
    body = sub.add_body(xform=wp.transform((0.9, 0.5, 0.35), wp.quat_identity()))
    sub.add_shape_sphere(body, radius=0.35, color=(0.2, 0.4, 0.9),
                         xform=wp.transform((0.0, 0.0, 0.1), wp.quat_identity()))  # offset from its body
    b.replicate(sub, worlds)
    return b.finalize(device="cpu")


def moved_state(m):
    """A state whose bodies differ from world to world (as after some simulation)."""
    state = m.state()
    q = state.body_q.numpy()
    rng = np.random.default_rng(4)
    for i in range(len(q)):
        q[i, :2] += rng.uniform(-0.4, 0.4, size=2)
        axis = rng.normal(size=3)
        angle = rng.uniform(0, 1.0)
        rot = np.concatenate([axis / np.linalg.norm(axis) * math.sin(angle / 2), [math.cos(angle / 2)]])
        q[i, 3:] = rot if i % 2 == 0 else q[i, 3:]  # boxes turn, spheres only move
    state.body_q.assign(q)
    return state


def quat_mul(a, b):
    x1, y1, z1, w1 = a
    x2, y2, z2, w2 = b
    return np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])


def rotate(q, v):
    u, w = np.asarray(q[:3]), q[3]
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def test_scene_structure_matches_the_model():
    m = model()
    scene, smap = scene_from_model(m)
    kinds = [type(s).__name__ for s in scene.shapes]
    assert kinds == ["Plane", "Box", "Sphere"]  # the ground (global), then world 0's box and sphere
    assert smap.global_shapes == 1 and smap.newton_shape.shape == (W, 3)
    box = scene.shapes[1]
    np.testing.assert_allclose(box.size, 2 * np.asarray(BOX))  # Newton's are half extents
    assert scene.shapes[2].radius == pytest.approx(0.35)
    assert scene.materials[scene.shapes[1].material].kd == pytest.approx(srgb_to_linear((0.9, 0.2, 0.2)))
    # worlds map to their own Newton shapes
    worlds = m.shape_world.numpy()
    for w in range(W):
        assert (worlds[smap.newton_shape[w, 1:]] == w).all() and worlds[smap.newton_shape[w, 0]] == -1


def test_update_writes_body_times_shape_transform_and_needs_no_host_copy():
    m = model()
    state = moved_state(m)
    r = NewtonRenderer(m, cameras=1, camera=warprt.Camera(width=8, height=8))
    r.update(state)
    poses = r.batch.shape_poses.numpy().astype(np.float64)
    body_q = state.body_q.numpy().astype(np.float64)
    shape_tf = m.shape_transform.numpy().astype(np.float64)
    shape_body = m.shape_body.numpy()
    for w in range(W):
        for j, s in enumerate(r.shape_map.newton_shape[w]):
            b = shape_body[s]
            p, q = shape_tf[s, :3], shape_tf[s, 3:]
            if b >= 0:
                p = body_q[b, :3] + rotate(body_q[b, 3:], p)
                q = quat_mul(body_q[b, 3:], q)
            np.testing.assert_allclose(poses[w, j, :3], p, atol=2e-6)
            assert abs(abs(np.dot(poses[w, j, 3:], q)) - 1) < 1e-6
    r.render()
    before = dict(r.counters)
    for _ in range(3):
        r.update(state)
        r.render()
    assert r.counters == before


def newton_images(m, state, poses, height, width):
    """Newton's SensorCamera on ``m``: HDR colour, depth and shape index, (W, C, H, X) each, one
    view per world and camera (view w·C + c renders world w), with its default directional light
    and shadows (its ambient off: its hemispheric ambient has no warprt counterpart), and its
    render config (``max_distance``)."""
    from newton.sensors import SensorCamera

    worlds, cameras = poses.shape[:2]
    views = worlds * cameras
    sensor = SensorCamera(m)
    cfg = sensor.default_render_config
    cfg.enable_shadows = True
    cfg.enable_ambient_lighting = False
    sensor.create_default_light(enable_shadows=True)
    rays = SensorCamera.compute_camera_rays_pinhole(width, height, camera_fov=math.radians(FOV), device="cpu")
    tf = wp.array(poses.reshape(views, 7).astype(np.float32), dtype=wp.transform, device="cpu")
    world_of_view = wp.array(np.repeat(np.arange(worlds, dtype=np.int32), cameras), dtype=wp.int32, device="cpu")
    hdr = sensor.allocate_image_color_hdr(views, width, height)
    depth = sensor.allocate_image_depth(views, width, height)
    index = sensor.allocate_image_shape_index(views, width, height)
    m.bvh_refit_shapes(state)  # Newton's shape BVH follows the moved bodies
    sensor.update(state, tf, rays, hdr_color_image=hdr, depth_image=depth, shape_index_image=index,
                  world_indices=world_of_view)
    shape = (worlds, cameras, height, width)
    return (hdr.numpy().reshape(shape + (3,)), depth.numpy().reshape(shape),
            index.numpy().astype(np.int64).reshape(shape), cfg)


def warprt_images(m, state, poses, height, width, aovs=("depth", "object_id", "normal", "albedo")):
    r = NewtonRenderer(m, cameras=poses.shape[1], camera=warprt.Camera(fov=FOV, width=width, height=height),
                       render=warprt.RenderSettings(sampler="regular", spp=1))  # the pixel centre, as Newton
    r.set_camera_poses(poses)
    r.update(state)
    out = r.render(aovs=aovs)
    return r, out.numpy(), out.aovs_numpy()


def test_motion_blur_opens_the_shutter_on_the_previous_state():
    m = model()
    s0, s1 = m.state(), moved_state(m)
    r = NewtonRenderer(m, cameras=1, camera=warprt.Camera(width=8, height=8), motion_blur=True)
    still = NewtonRenderer(m, cameras=1, camera=warprt.Camera(width=8, height=8))
    still.update(s0)
    at0 = still.batch.shape_poses.numpy().copy()  # (numpy() shares a CPU array)
    still.update(s1)
    at1 = still.batch.shape_poses.numpy().copy()
    assert not np.allclose(at0, at1)
    r.update(s0)  # the first state: no previous one, the shutter opens and closes on it
    np.testing.assert_array_equal(r.batch.shape_poses.numpy(), at0)
    np.testing.assert_array_equal(r.batch.shape_poses_end.numpy(), at0)
    r.update(s1)
    np.testing.assert_array_equal(r.batch.shape_poses.numpy(), at0)
    np.testing.assert_array_equal(r.batch.shape_poses_end.numpy(), at1)
    r.update(s0)
    np.testing.assert_array_equal(r.batch.shape_poses.numpy(), at1)
    np.testing.assert_array_equal(r.batch.shape_poses_end.numpy(), at0)


@pytest.fixture(scope="module")
def both():
    """Newton's camera and warprt on the same model, cameras and light."""
    m = model()
    state = moved_state(m)
    eyes = [(3.0, -3.0, 2.2), (-2.0, -3.0, 1.5)]
    poses = np.array([[look_at_pose(eyes[c], (0.3, 0.2, 0.3)) for c in range(C)] for _ in range(W)])
    nh, nd, ns, _ = newton_images(m, state, poses, H, X)
    r, img, a = warprt_images(m, state, poses, H, X)
    return r, img, a, nh, nd, ns


def test_depth_and_shape_index_agree_with_newton(both):
    r, img, a, nh, nd, ns = both
    hit_n, hit_w = nd > 0, np.isfinite(a["depth"])
    assert np.mean(hit_n != hit_w) <= 1e-3
    both_hit = hit_n & hit_w
    rel = np.abs(nd - a["depth"])[both_hit] / nd[both_hit]
    assert np.median(rel) < 2e-6 and np.mean(rel < 1e-4) > 0.995
    table = r.shape_map.newton_shape
    w_idx = np.arange(W)[:, None, None, None] * np.ones((1, C, H, X), int)
    mapped = table[w_idx, np.maximum(a["object_id"], 0)]
    assert np.mean(mapped[both_hit] == ns[both_hit]) > 0.999
    assert len(np.unique(ns[both_hit])) == 1 + 2 * W  # the ground and every world's two shapes


def test_lit_colour_agrees_with_newton_and_shadows_coincide(both):
    r, img, a, nh, nd, ns = both
    hit = (nd > 0) & np.isfinite(a["depth"])
    # Newton: albedo · n·l · (1, or 0.3 in shadow); warprt: kd · n·l, or 0 in shadow
    l = -np.array([-1.0, 1.0, -1.0]) / math.sqrt(3)
    unshadowed = a["albedo"] * np.maximum((a["normal"] * l).sum(-1), 0)[..., None]
    lit_w = img.sum(-1) > 1e-6
    facing = hit & (unshadowed.sum(-1) > 1e-3)
    lit = facing & lit_w
    ratio = img.sum(-1)[lit] / nh.sum(-1)[lit]
    assert lit.sum() > 1000
    assert abs(np.median(ratio) - 1) < 1e-5 and np.mean(np.abs(ratio - 1) < 1e-3) > 0.99
    shadowed = facing & ~lit_w
    assert shadowed.sum() > 50  # the boxes and spheres do cast shadows here
    newton_ratio = nh.sum(-1)[shadowed] / unshadowed.sum(-1)[shadowed]
    assert np.mean(np.abs(newton_ratio - 0.3) < 1e-3) > 0.99  # Newton's shadows keep 0.3 of the light


def kinds_model():
    """One shape of each kind warprt converts: the infinite ground, a finite wall (a plane of
    width × length, full extents), a capsule, a cylinder, a cone, an ellipsoid (turned) and a
    scaled mesh."""
    import trimesh

    b = newton.ModelBuilder()
    b.add_ground_plane(color=(0.8, 0.8, 0.75))
    wall = wp.transform((0.0, 1.2, 0.6), wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), math.pi / 2))
    b.add_shape_plane(xform=wall, width=1.6, length=1.0, body=-1, color=(0.5, 0.9, 0.5))
    tilt = wp.quat_from_axis_angle(wp.normalize(wp.vec3(1.0, 0.3, 0.0)), 0.7)

    def body(p):
        return b.add_body(xform=wp.transform(p, tilt))

    b.add_shape_capsule(body((-1.0, -0.3, 0.5)), radius=0.2, half_height=0.3, color=(0.9, 0.2, 0.2))
    b.add_shape_cylinder(body((0.0, -0.6, 0.45)), radius=0.25, half_height=0.3, color=(0.2, 0.9, 0.2))
    b.add_shape_cone(body((0.9, -0.2, 0.4)), radius=0.3, half_height=0.35, color=(0.2, 0.2, 0.9))
    b.add_shape_ellipsoid(body((0.2, 0.5, 0.5)), rx=0.35, ry=0.2, rz=0.15, color=(0.9, 0.9, 0.2))
    ico = trimesh.creation.icosahedron()
    mesh = newton.Mesh(np.asarray(ico.vertices, np.float32), np.asarray(ico.faces, np.int32).ravel())
    b.add_shape_mesh(body((-0.9, 0.6, 0.5)), mesh=mesh, scale=(0.3, 0.2, 0.35), color=(0.9, 0.2, 0.9))
    return b.finalize(device="cpu")


def support(kind: int, size, n: np.ndarray) -> np.ndarray:
    """Support function h(n) = max over the analytic shape of x·n (unit rows n, local frame),
    for Newton's capsule, cylinder and cone (axis z, half height size[1], radius size[0]) and
    ellipsoid (semi-axes size)."""
    r, h = size[0], size[1]
    radial = np.hypot(n[:, 0], n[:, 1])
    if kind == int(newton.GeoType.CAPSULE):
        return h * np.abs(n[:, 2]) + r
    if kind == int(newton.GeoType.CYLINDER):
        return r * radial + h * np.abs(n[:, 2])
    if kind == int(newton.GeoType.CONE):  # tip at +h, base of radius r at -h
        return np.maximum(h * n[:, 2], -h * n[:, 2] + r * radial)
    if kind == int(newton.GeoType.ELLIPSOID):
        return np.sqrt(((np.asarray(size) * n) ** 2).sum(-1))
    raise AssertionError(kind)


def test_every_shape_kind_agrees_with_newton_within_its_tessellation():
    """Exact kinds (planes, finite planes, capsules, cylinders, meshes): depth to float32.
    Tessellated kinds (cones, ellipsoids): the mesh
    is inscribed in the analytic surface, and the surface lies between each facet's plane and the
    parallel plane at the support distance, δ = h(n) - n·v0 beyond it; so along a ray meeting the
    facet at cos θ = |n·d|, warprt's depth exceeds Newton's by at most δ / cos θ and is never
    shorter (beyond float32). The same inscription means a pixel where the two see different
    things is a tessellated shape's silhouette seen by Newton only."""
    m = kinds_model()
    state = m.state()
    eyes = [(3.0, -3.0, 2.2), (-2.0, -3.0, 1.5)]
    poses = np.array([[look_at_pose(e, (0.0, 0.0, 0.4)) for e in eyes]])
    hgt, wid = 40, 48
    _, nd, ns, cfg = newton_images(m, state, poses, hgt, wid)
    r, _, a = warprt_images(m, state, poses, hgt, wid, aovs=("depth", "object_id", "normal"))
    kinds = [type(s).__name__ for s in r.scene.shapes]
    assert kinds == ["Plane", "Rectangle", "Capsule", "Cylinder", "Mesh", "Mesh", "Mesh"]
    types, sizes = m.shape_type.numpy(), m.shape_scale.numpy()
    tessellated = [s for s in range(len(types)) if types[s] in (newton.GeoType.CONE, newton.GeoType.ELLIPSOID)]
    assert len(tessellated) == 2
    delta = np.zeros(len(types))
    for s in tessellated:
        mesh = r.scene.shapes[s]  # one world, no hidden shapes: warprt shape j is Newton shape j
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        gap = support(int(types[s]), sizes[s], n) - (n * v[f[:, 0]]).sum(-1)
        assert gap.min() > -1e-9  # outward facets, inscribed
        delta[s] = gap.max()
    # the documented accuracy: within 1 - cos(π / sections) of the largest radius (0.12% at 64)
    limit = 1 - math.cos(math.pi / TESSELLATION["cylinder_sections"])
    assert (0 < delta[tessellated]).all() and (delta[tessellated] <= limit * sizes[tessellated].max(1)).all()

    wd = a["depth"]
    in_range = ~(np.isfinite(wd) & (wd >= cfg.max_distance))  # Newton misses beyond its max_distance
    hit_n, hit_w = nd > 0, np.isfinite(wd) & in_range
    ids = r.shape_map.newton_shape[0][np.maximum(a["object_id"], 0)]
    ids = np.where(hit_w, ids, -1)
    ns = np.where(hit_n, ns, -1)
    differ = ids != ns
    # every disagreement: Newton sees a tessellated shape's rim that the inscribed mesh misses
    assert np.isin(ns[differ], tessellated).all()
    assert (~hit_w[differ] | (wd[differ] > nd[differ])).all()
    # ... on the silhouette: a pixel next to one where Newton sees something else
    rim = np.zeros_like(differ)
    for axis in (-1, -2):
        step = np.diff(ns, axis=axis) != 0
        pad = [(0, 0)] * ns.ndim
        pad[axis] = (1, 0)
        rim |= np.pad(step, pad)
        pad[axis] = (0, 1)
        rim |= np.pad(step, pad)
    assert rim[differ].all()
    same = ~differ & hit_n
    assert np.unique(ns[same]).tolist() == list(range(len(types)))  # every shape in view
    # depth: exact kinds to float32 (measured at most 9e-6 relative on the grazing ground),
    # tessellated ones within [0, δ / cos θ] (+ the same float32 term)
    d = np.stack([ray_directions(poses[0, c], hgt, wid) for c in range(poses.shape[1])])[None]
    cos = np.abs((a["normal"] * d).sum(-1))
    eps = 2e-5 * nd
    exact = same & ~np.isin(ns, tessellated)
    np.testing.assert_array_less(np.abs(wd - nd)[exact], eps[exact])
    curved = same & np.isin(ns, tessellated)
    bound = delta[np.maximum(ns, 0)] / np.maximum(cos, 1e-6)
    assert (wd[curved] - nd[curved] > -eps[curved]).all()
    assert (wd[curved] - nd[curved] < bound[curved] + eps[curved]).all()


def ray_directions(pose, height, width) -> np.ndarray:
    """(H, W, 3) unit directions of pixel-centre rays of a camera-to-world pose (looking along
    local -z, +y up, vertical field of view FOV)."""
    top = math.tan(math.radians(FOV) / 2)
    x = (2 * (np.arange(width) + 0.5) / width - 1) * top * width / height
    y = (1 - 2 * (np.arange(height) + 0.5) / height) * top
    local = np.stack(np.broadcast_arrays(x[None, :], y[:, None], -np.ones((height, width))), -1)
    world = rotate(pose[3:], local.reshape(-1, 3))
    return (world / np.linalg.norm(world, axis=-1, keepdims=True)).reshape(height, width, 3)


@pytest.mark.parametrize("add, problem", [
    (lambda b, body: b.add_shape_cylinder(body, radius=0.2, half_height=0.3, barrel_radius=0.5), "barrel cylinder"),
    (lambda b, body: b.add_shape_plane(width=2.0, length=0.0, body=-1), "finite along one axis"),
])
def test_shapes_without_a_warprt_counterpart_are_refused_by_index(add, problem):
    b = newton.ModelBuilder()
    body = b.add_body()
    b.add_shape_sphere(body, radius=0.1)
    add(b, body)
    with pytest.raises(warprt.SceneError, match=rf"model\.shapes\[1\].*{problem}"):
        scene_from_model(b.finalize(device="cpu"))


def test_an_exploded_body_is_named_before_the_render():
    """A NaN (or a non-unit quaternion) in ``state.body_q`` of a body that carries a shape: the
    update names the body and its world, on the device, before anything renders; check_inputs=False
    lets it through."""
    m = model()
    state = moved_state(m)
    r = NewtonRenderer(m, cameras=1, camera=warprt.Camera(width=8, height=8))
    r.update(state)
    r.render()
    q = state.body_q.numpy()
    bad = len(q) - 1  # world 1's sphere body
    q[bad, 0] = np.nan
    state.body_q.assign(q)
    with pytest.raises(warprt.RenderError) as info:
        r.update(state)
    assert str(info.value).startswith(f"state.body_q[{bad}] (body 'body_1', world 1): position (nan, ")
    assert "diverged" in str(info.value)
    q[bad, 0] = 0.0
    q[bad, 6] = 2.0
    state.body_q.assign(q)
    with pytest.raises(warprt.RenderError, match=rf"state.body_q\[{bad}\] \(body 'body_1', world 1\): quaternion .* squared length"):
        r.update(state)
    r.check_inputs = False
    r.update(state)
    r.render()


def test_bad_models_and_states_are_named():
    for bad in (None, "model", 3):
        with pytest.raises(warprt.SceneError, match=r"^model: expected a newton.Model \(ModelBuilder.finalize\(\)\), "
                                                    f"got {type(bad).__name__}$"):
            NewtonRenderer(bad)
    with pytest.raises(warprt.SceneError, match="call .finalize"):
        NewtonRenderer(newton.ModelBuilder())
    r = NewtonRenderer(model(), cameras=1, camera=warprt.Camera(width=8, height=8))
    for state, words in ((None, "got NoneType"), (object(), "got NoneType"),
                         (type("S", (), {"body_q": wp.zeros(3, dtype=wp.vec3, device="cpu")})(), "got vec3f (3,)")):
        with pytest.raises(warprt.RenderError, match=rf"^state.body_q: expected a wp.array of wp.transform .*{re.escape(words)}"):
            r.update(state)
    short = type("S", (), {"body_q": wp.zeros(1, dtype=wp.transform, device="cpu")})()
    with pytest.raises(warprt.RenderError, match="state.body_q holds 1 bodies"):
        r.update(short)
