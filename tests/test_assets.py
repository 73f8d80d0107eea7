"""Scene assets and rotations: transforms from matrices and quaternions (float64 closed forms),
slerped keyframes (angle in proportion to time about a fixed axis), a ``trimesh.Trimesh`` as a
mesh, and glTF files / ``trimesh.Scene`` loaded as one shape per node with their PBR materials
(a rendered image against Lambert shading), with the bad input each of them refuses."""

from __future__ import annotations

import math
import textwrap
import warnings

import numpy as np
import pytest
import trimesh
from trimesh.visual.material import PBRMaterial

import warprt
from warprt import Material, Mesh, SceneError, Transform
from warprt.animation import frame_scene
from warprt.scene.assets import GLOSSY_LIMIT, load_assets, pbr_material
from warprt.meshes import asset_key, prepare_mesh
from warprt.scene.transform import quaternion_matrix, slerp

EPS = np.finfo(np.float64).eps
# a handful of float64 operations on O(1) numbers (matrix products, an SVD, a square root):
# measured errors are at most 1e-15; 64 ulps bounds them with room and still catches any mistake
TOL64 = 64 * EPS


def axis_angle(axis, degrees) -> np.ndarray:
    """The closed-form unit quaternion (x, y, z, w) of a rotation about ``axis``."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    h = math.radians(degrees) / 2
    return np.array([*(a * math.sin(h)), math.cos(h)])


def rodrigues(axis, degrees) -> np.ndarray:
    """The closed-form rotation matrix about ``axis`` (Rodrigues' formula)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = math.radians(degrees)
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


def same_rotation(q, ref) -> bool:
    return abs(abs(float(np.dot(q, ref))) - 1.0) < TOL64


# --- matrices and quaternions ----------------------------------------------------------------------


@pytest.mark.parametrize("axis, degrees", [((0, 1, 0), 90), ((1, 2, 3), 37), ((1, -1, 0.5), 179.5), ((0, 0, 1), 0),
                                           ((1, 0, 0), 180)])
def test_quaternion_and_matrix_round_trip_in_float64(axis, degrees):
    q = axis_angle(axis, degrees)
    t = Transform.from_quaternion(q, translate=(1, -2, 3), scale=(0.5, 2, 3))
    np.testing.assert_allclose(t.rotation_matrix(), rodrigues(axis, degrees), atol=TOL64)
    m = np.eye(4)
    m[:3, :3] = rodrigues(axis, degrees) @ np.diag([0.5, 2, 3])
    m[:3, 3] = (1, -2, 3)
    np.testing.assert_allclose(t.matrix(), m, atol=TOL64)
    back = Transform.from_matrix(m)
    assert same_rotation(back.quaternion(), q)
    np.testing.assert_allclose(back.scale, (0.5, 2, 3), rtol=TOL64)
    np.testing.assert_allclose(back.translate, (1, -2, 3), rtol=0, atol=0)
    np.testing.assert_allclose(back.matrix(), m, atol=4 * TOL64)
    np.testing.assert_allclose(Transform.from_matrix(m[:3]).matrix(), m, atol=4 * TOL64)  # 3x4 too


def test_euler_transform_through_a_matrix_keeps_its_pose():
    t = Transform(translate=(1, 2, 3), rotate=(30, -50, 170), scale=(1, 2, 3))
    back = Transform.from_matrix(t.matrix())
    assert same_rotation(back.quaternion(), t.quaternion())
    np.testing.assert_allclose(back.scale, t.scale, rtol=TOL64)
    np.testing.assert_allclose(back.apply_point((0.3, -0.7, 1.1)), t.apply_point((0.3, -0.7, 1.1)), atol=8 * TOL64)


def test_quaternion_order_is_x_y_z_w_and_normalised():
    # 90 degrees about y takes +x to -z (right-handed), as rotate = [0, 90, 0] does
    t = Transform(rotation_quaternion=(0, 2 * math.sin(math.pi / 4), 0, 2 * math.cos(math.pi / 4)))
    np.testing.assert_allclose(t.apply_vector((1, 0, 0)), (0, 0, -1), atol=TOL64)
    assert same_rotation(t.quaternion(), Transform(rotate=(0, 90, 0)).quaternion())
    assert Transform(rotation_quaternion=(0, 0, 0, -3)).rotation_quaternion == (0.0, 0.0, 0.0, 1.0)  # w >= 0


@pytest.mark.parametrize("matrix, words", [
    ([[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], ["shear", "63.43 degrees"]),
    ([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], ["mirror", "negative scale"]),
    ([[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], ["singular"]),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], ["last row"]),
    ([[1, 0, 0, math.nan], [0, 1, 0, 0], [0, 0, 1, 0]], ["finite"]),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], ["4x4 or 3x4"]),
])
def test_bad_matrices_are_refused(matrix, words):
    with pytest.raises(SceneError) as info:
        Transform.from_matrix(matrix)
    assert info.value.field == "matrix" and all(w in str(info.value) for w in words), str(info.value)


@pytest.mark.parametrize("q, words", [((0, 0, 0, 0), ["zero"]), ((0, math.nan, 0, 1), ["finite"]),
                                      ((0, math.inf, 0, 1), ["finite"]), ((0, 1, 0), ["four numbers"])])
def test_bad_quaternions_are_refused(q, words):
    with pytest.raises(SceneError) as info:
        Transform(rotation_quaternion=q)
    assert info.value.field.startswith("rotation_quaternion") and all(w in str(info.value) for w in words)


TRIANGLE = "vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [[0, 1, 2]]"


def test_matrix_and_quaternion_in_scene_files():
    scene = warprt.scene_from_string(f"""
[[shapes]]
type = "mesh"
{TRIANGLE}
transform = {{ matrix = [[0, 0, 2, 1], [0, 3, 0, 2], [-4, 0, 0, 3], [0, 0, 0, 1]] }}

[[shapes]]
type = "mesh"
{TRIANGLE}
transform = {{ quaternion = [0, 0.7071067811865476, 0, 0.7071067811865476], translate = [1, 2, 3], scale = 2 }}
""")
    a, b = scene.shapes
    np.testing.assert_allclose(a.transform.scale, (4, 3, 2), rtol=TOL64)
    np.testing.assert_allclose(a.transform.rotation_matrix(), rodrigues((0, 1, 0), 90), atol=TOL64)
    np.testing.assert_allclose(b.transform.apply_point((1, 0, 0)), (1, 2, 1), atol=8 * TOL64)


@pytest.mark.parametrize("transform, field, words", [
    ("{ matrix = [[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]] }", "shapes[0].transform.matrix",
     ["shear"]),
    ("{ matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], rotate = [0, 90, 0] }",
     "shapes[0].transform.matrix", ["whole transform", "rotate"]),
    ("{ quaternion = [0, 0, 0, 1], rotate = [0, 90, 0] }", "shapes[0].transform.quaternion", ["not both"]),
    ("{ quaternion = [0, 0, 0, 0] }", "shapes[0].transform.quaternion", ["zero"]),
    ("{ quaternion = [0, nan, 0, 1] }", "shapes[0].transform.quaternion[1]", ["finite"]),
])
def test_bad_matrix_and_quaternion_fields_in_files(transform, field, words):
    with pytest.raises(SceneError) as info:
        warprt.scene_from_string(f'[[shapes]]\ntype = "mesh"\n{TRIANGLE}\ntransform = {transform}\n')
    assert info.value.field == field and all(w in str(info.value) for w in words), str(info.value)


# --- keyframes: slerp ----------------------------------------------------------------------------


def _spinning(keyframes, frames=48, fps=24.0) -> warprt.Scene:
    mesh = Mesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]], keyframes=keyframes,
                transform=Transform(translate=(0, 0.65, -1.5)))
    return warprt.Scene(shapes=(mesh,), animation=warprt.Animation(frames=frames, fps=fps))


def test_a_full_euler_turn_between_two_keys_spins_in_proportion_to_time():
    # scenes/anim.toml's torus: 0 to 360 degrees about y over 2 s; slerp alone would stand still
    scene = _spinning([{"time": 0, "rotate": [0, 0, 0]}, {"time": 2, "rotate": [0, 360, 0]}])
    for f in range(48):
        fs = frame_scene(scene, f)
        t0, t1 = fs.shapes[0].transform, fs.shapes[0].transform_end
        assert same_rotation(t0.quaternion(), axis_angle((0, 1, 0), 360 * (f / 24) / 2)), f
        assert same_rotation(t1.quaternion(), axis_angle((0, 1, 0), 360 * ((f + 1) / 24) / 2)), f  # blur end
        assert t0.translate == (0, 0.65, -1.5)


def test_quaternion_keys_take_the_shorter_arc_about_the_fixed_axis():
    axis = (1, 2, -2)
    q0, q1 = axis_angle(axis, 10), axis_angle(axis, 280)  # 270 degrees apart: slerp turns -90
    scene = _spinning([{"time": 0, "quaternion": q0}, {"time": 1, "quaternion": q1}], frames=8, fps=8.0)
    for f in range(8):
        q = frame_scene(scene, f).shapes[0].transform.quaternion()
        assert same_rotation(q, axis_angle(axis, 10 - 90 * f / 8)), f


def test_euler_keys_under_180_degrees_slerp_directly():
    a, b = Transform(rotate=(20, 0, 30)).quaternion(), Transform(rotate=(60, 40, 10)).quaternion()
    scene = _spinning([{"time": 0, "rotate": [20, 0, 30]}, {"time": 1, "rotate": [60, 40, 10]}], frames=4, fps=4.0)
    # closed form: q(t) = a · exp(t · log(a⁻¹ b)), the angle in proportion to t about the fixed axis
    rel = quaternion_matrix(a).T @ quaternion_matrix(b)
    angle = math.degrees(math.acos((np.trace(rel) - 1) / 2))
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    for f in range(4):
        m = frame_scene(scene, f).shapes[0].transform.rotation_matrix()
        np.testing.assert_allclose(m, quaternion_matrix(a) @ rodrigues(axis, angle * f / 4), atol=8 * TOL64)
    assert same_rotation(slerp(a, b, 1.0), b)


def test_bad_rotation_keys():
    with pytest.raises(SceneError) as info:
        Mesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]],
             keyframes=[{"time": 0, "rotate": [0, 0, 0], "quaternion": [0, 0, 0, 1]}])
    assert info.value.field == "keyframes[0].quaternion" and "not both" in str(info.value)


# --- trimesh.Trimesh as a mesh -----------------------------------------------------------------


def test_a_trimesh_is_a_mesh_with_its_arrays_checked():
    box = trimesh.creation.box((1, 2, 3))
    for m in (Mesh(box, material="default"), Mesh.from_trimesh(box, smooth=True)):
        assert m.file is None and np.array_equal(m.vertices, box.vertices) and np.array_equal(m.faces, box.faces)
    bad = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], faces=[[0, 1, 2]], process=False)
    with pytest.raises(SceneError, match="vertices: 1 vertices are NaN"):
        Mesh(bad)
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]], process=False)
    m = Mesh(flat)
    with pytest.raises(SceneError, match="zero area"):
        prepare_mesh(m.vertices, m.faces)
    with pytest.raises(SceneError, match="load_assets"):
        Mesh(trimesh.Scene(box))


# --- glTF assets -----------------------------------------------------------------------------------

RED = (204, 51, 26)  # base colours as 8-bit values: trimesh keeps baseColorFactor as uint8
BLUE = (26, 102, 204)


def _box(name, rgb, metallic, roughness, size=(1, 1, 1), emissive=None):
    box = trimesh.creation.box(size)
    box.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(
        name=name, baseColorFactor=[*(c / 255 for c in rgb), 1.0], metallicFactor=metallic,
        roughnessFactor=roughness, emissiveFactor=emissive))
    return box


def _pose(translate, degrees_about_y=0.0, scale=(1, 1, 1)):
    m = np.eye(4)
    m[:3, :3] = rodrigues((0, 1, 0), degrees_about_y) @ np.diag(scale)
    m[:3, 3] = translate
    return m


# node poses: A and its second instance C share one mesh; B is rotated and scaled
POSES = {"A": _pose((-1.2, 0, -0.3)), "B": _pose((1.0, 0, 0.2), 30, (0.8, 1, 0.6)), "C": _pose((-0.9, 0, 1.3))}
SIZES = {"A": (1, 1, 1), "B": (1, 1, 1.5), "C": (1, 1, 1)}  # B's mesh differs from A's


def _glb(tmp_path):
    scene = trimesh.Scene()
    red = _box("red", RED, metallic=0.0, roughness=1.0)
    scene.add_geometry(red, node_name="A", geom_name="red_box", transform=POSES["A"])
    scene.add_geometry(_box("blue", BLUE, metallic=0.5, roughness=0.0, size=SIZES["B"]), node_name="B", geom_name="blue_box",
                       transform=POSES["B"])
    scene.add_geometry(red, node_name="C", geom_name="red_box", transform=POSES["C"])
    path = tmp_path / "boxes.glb"
    path.write_bytes(scene.export(file_type="glb"))
    return path


def test_pbr_mapping_closed_forms():
    base = np.array([0.8, 0.4, 0.2])
    lambert = pbr_material(base, 0.0, 1.0)
    assert lambert.kd == tuple(base) and lambert.mirror == (0, 0, 0) and lambert.ks == (0, 0, 0)
    mirror = pbr_material(base, 1.0, 0.0)
    assert mirror.kd == (0, 0, 0) and mirror.mirror == tuple(base) and mirror.glossy_exponent == 0.0
    half = pbr_material(base, 0.25, 0.5)  # alpha = 1/4: Blinn-Phong 2/alpha² - 2 = 30, Phong about r 7.5
    np.testing.assert_allclose(half.kd, base * 0.75, rtol=EPS) and np.testing.assert_allclose(half.mirror, base / 4)
    assert half.glossy_exponent == pytest.approx(7.5, rel=4 * EPS)
    assert pbr_material(base, 1.0, 1.0).glossy_exponent == 1.0  # clamped: 0 would mean a perfect mirror
    r = (2 / (4 * GLOSSY_LIMIT + 2)) ** 0.25 * 0.99  # just sharper than the limit: a perfect mirror
    assert pbr_material(base, 1.0, r).glossy_exponent == 0.0


def test_gltf_nodes_become_instances_with_their_poses_and_materials(tmp_path):
    shapes, mats = load_assets(_glb(tmp_path))
    assert sorted(mats) == ["blue", "red"]
    np.testing.assert_allclose(mats["red"].kd, np.array(RED) / 255, rtol=EPS)
    np.testing.assert_allclose(mats["blue"].kd, np.array(BLUE) / 255 * 0.5, rtol=EPS)
    np.testing.assert_allclose(mats["blue"].mirror, np.array(BLUE) / 255 * 0.5, rtol=EPS)
    assert len(shapes) == 3
    by_material = {}
    for s in shapes:
        by_material.setdefault(s.material, []).append(s)
    assert len(by_material["red"]) == 2 and len(by_material["blue"]) == 1
    keys = {asset_key(s) for s in shapes}
    assert len(keys) == 2  # A and C share one asset (one BVH)
    poses = sorted(s.transform.matrix()[:3, 3].round(6).tolist() for s in shapes)
    assert poses == sorted(m[:3, 3].tolist() for m in POSES.values())
    blue = by_material["blue"][0]
    np.testing.assert_allclose(blue.transform.matrix(), POSES["B"], atol=1e-6)  # float32 in the file


def test_asset_transform_applies_to_the_whole_asset(tmp_path):
    outer = Transform(translate=(0, 1, 0), rotate=(0, 90, 0), scale=2)
    shapes, _ = load_assets(_glb(tmp_path), outer, material="default")
    assert {s.material for s in shapes} == {"default"}
    got = [s.transform.matrix() for s in shapes]
    for m in POSES.values():  # each node's pose, then the asset's transform (float32 in the file)
        assert sum(np.allclose(outer.matrix() @ m, g, atol=1e-6) for g in got) == 1


def _ray_box(o, d, pose, half):
    """Float64 slab test of a box of half extents ``half`` under ``pose``: the hit's local point, or None."""
    inv = np.linalg.inv(pose)
    lo, ld = inv[:3, :3] @ o + inv[:3, 3], inv[:3, :3] @ d
    with np.errstate(divide="ignore"):
        t1, t2 = (-half - lo) / ld, (half - lo) / ld
    tn, tf = np.minimum(t1, t2).max(), np.maximum(t1, t2).min()
    return lo + tn * ld if tn <= tf and tf > 0 else None


def test_rendered_gltf_matches_lambert_shading_of_each_material(tmp_path):
    shapes, mats = load_assets(_glb(tmp_path))
    w, h = 48, 36
    cam = warprt.Camera(eye=(0, 6, 0), look_at=(0, 0, 0), up=(0, 0, -1), fov=40, width=w, height=h)
    light = np.array([0.3, 4.0, 0.5])
    scene = warprt.Scene(camera=cam, shapes=tuple(shapes), materials=mats,
                         lights=(warprt.PointLight(position=tuple(light), intensity=1.0),),
                         render=warprt.RenderSettings(spp=1, sampler="regular"))
    renderer = warprt.Renderer(scene, device="cpu", features=warprt.Features.full())
    assert len(renderer.built.meshes) == 2
    image = renderer.render(seed=0, progress=False).image
    # the camera frame of the docs: u = +x, v = -z, w = +y; pixel centres through the image plane
    top = math.tan(math.radians(40) / 2)
    right = top * w / h
    kd = {"A": np.array(RED) / 255, "C": np.array(RED) / 255, "B": np.array(BLUE) / 255 * 0.5}
    checked = {"A": 0, "B": 0, "C": 0}
    worst = 0.0
    eye = np.array([0.0, 6.0, 0.0])
    for j in range(h):
        for i in range(w):
            us, vs = -right + 2 * right * (i + 0.5) / w, top - 2 * top * (j + 0.5) / h
            d = np.array([us, -1.0, -vs])
            d /= np.linalg.norm(d)
            for name, pose in POSES.items():
                half = np.array(SIZES[name]) / 2
                p = _ray_box(eye, d, pose, half)
                # the top face (local y = 0.5), away from its edges (where float32 may pick a side)
                if p is not None and abs(p[1] - 0.5) < 1e-9 and np.all(np.abs(p[[0, 2]]) < half[[0, 2]] - 0.02):
                    world = pose[:3, :3] @ p + pose[:3, 3]
                    l = light - world
                    expected = kd[name] * l[1] / np.linalg.norm(l)  # kd·I·(n·l), n = +y
                    worst = max(worst, float(np.abs(image[j, i] - expected).max()))
                    checked[name] += 1
    assert min(checked.values()) >= 8, checked
    # float32 roundings of the hit point and of kd·I·cos (values below 1, ulp 1.2e-7): measured
    # 8e-8; 8 ulps of 1 bounds it, while a wrong material (kd·m instead of kd·(1 - m)) is off by 0.1
    assert worst < 8 * np.finfo(np.float32).eps, worst


def test_emissive_materials_warn_and_points_are_refused_or_skipped(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(_box("lamp", RED, 0.0, 1.0, emissive=[1.0, 0.5, 0.0]), node_name="lamp")
    with pytest.warns(UserWarning, match="emissive"):
        shapes, mats = load_assets(scene)
    assert mats["lamp"].kd == tuple(np.array(RED) / 255)
    scene.add_geometry(trimesh.PointCloud(np.random.default_rng(0).random((5, 3))), node_name="dots")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SceneError) as info:
            load_assets(scene)
        assert "'dots'" in str(info.value) and "points" in str(info.value) and info.value.field == "file"
        with pytest.warns(UserWarning, match="skipping points"):
            shapes, _ = load_assets(scene, unsupported="skip")
    assert len(shapes) == 1


def test_assets_in_scene_files(tmp_path):
    _glb(tmp_path)
    (tmp_path / "scene.toml").write_text(textwrap.dedent("""
        [materials.floor]
        kd = 0.5

        [[shapes]]
        type = "plane"
        material = "floor"

        [[shapes]]
        type = "assets"
        file = "boxes.glb"
        prefix = "boxes."
        smooth = true
        transform = { translate = [0, 0.5, 0] }
    """))
    scene = warprt.load_scene(tmp_path / "scene.toml")
    assert len(scene.shapes) == 4 and {"boxes.red", "boxes.blue", "floor"} <= set(scene.materials)
    assert all(s.smooth and s.transform.translate[1] == pytest.approx(0.5) for s in scene.shapes[1:])


@pytest.mark.parametrize("entry, field, words", [
    ('file = "missing.glb"', "shapes[0].file", ["asset file not found", "missing.glb"]),
    ('file = "boxes.glb"\ncolour = 1', "shapes[0]", ["unknown field", "colour"]),
    ('file = "boxes.glb"\nunsupported = "maybe"', "shapes[0].unsupported", ["'skip'"]),
])
def test_bad_asset_entries(tmp_path, entry, field, words):
    _glb(tmp_path)
    (tmp_path / "scene.toml").write_text(f'[[shapes]]\ntype = "assets"\n{entry}\n')
    with pytest.raises(SceneError) as info:
        warprt.load_scene(tmp_path / "scene.toml")
    assert info.value.field == field and all(w in str(info.value) for w in words), str(info.value)


def test_an_asset_material_may_not_replace_a_scene_material(tmp_path):
    _glb(tmp_path)
    (tmp_path / "scene.toml").write_text('[materials.red]\nkd = 1\n[[shapes]]\ntype = "assets"\nfile = "boxes.glb"\n')
    with pytest.raises(SceneError, match="clashes"):
        warprt.load_scene(tmp_path / "scene.toml")
    with pytest.raises(SceneError, match="asset file not found"):
        load_assets(tmp_path / "nowhere.glb")
