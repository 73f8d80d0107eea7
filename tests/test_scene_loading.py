"""The TOML scene loader and the description dataclasses: defaults, colours, transforms, every
shape and light type, and bad input.

Every error must be a :class:`warprt.SceneError` whose message names the scene file, the field
(``shapes[1].radius``) and the problem, so that a user can fix the file without a traceback.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import textwrap

import numpy as np
import pytest

import warprt
from warprt import (
    Animation, Camera, Disk, DiskLight, Material, Mesh, Plane, PointLight, Rectangle, RectLight, RenderSettings, Scene,
    SceneError, Sphere, SphereLight, Transform,
)
from warprt.scene.description import Box
from warprt._warp import resolve_device
from warprt.build import DeviceScene, prepare_mesh

TRIANGLE = "vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [[0, 1, 2]]"


def write(tmp_path, text: str, name: str = "scene.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def load(tmp_path, text: str, name: str = "scene.toml") -> Scene:
    return warprt.load_scene(write(tmp_path, text, name))


def build(scene: Scene) -> DeviceScene:
    """The scene's device tables on the CPU (no render kernel is made)."""
    return DeviceScene(scene, resolve_device("cpu"))


def load_and_build(path) -> DeviceScene:
    """Load and build on the CPU (mesh files are read and checked when the scene is built)."""
    return build(warprt.load_scene(path))


def expect_error(tmp_path, text: str, field: str, *problem: str, build: bool = False) -> SceneError:
    """The scene file must fail with a SceneError naming the file, ``field`` and each ``problem`` word."""
    path = write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        if build:
            load_and_build(path)
        else:
            warprt.load_scene(path)
    err = info.value
    msg = str(err)
    assert "\n" not in msg
    assert err.source == str(path) and msg.startswith(f"{path}: "), msg
    assert err.field == field, msg
    assert f": {field}: " in msg, msg
    for word in problem:
        assert word.lower() in msg.lower(), f"{word!r} not in {msg!r}"
    return err


# --- defaults -----------------------------------------------------------------------------------


def test_an_empty_file_is_the_default_scene(tmp_path):
    scene = load(tmp_path, "")
    assert scene.shapes == () and scene.lights == ()
    assert scene.ambient == (0.0, 0.0, 0.0) and scene.background == (0.0, 0.0, 0.0)
    cam = scene.camera
    assert cam.eye == (0.0, 0.0, 5.0) and cam.look_at == (0.0, 0.0, 0.0) and cam.up == (0.0, 1.0, 0.0)
    assert (cam.fov, cam.width, cam.height, cam.distance, cam.aperture) == (45.0, 320, 240, 1.0, 0.0)
    assert cam.focus_distance is None and cam.focus == pytest.approx(5.0)
    assert cam.shutter == (0.0, 1.0) and cam.eye_end is None and cam.look_at_end is None
    r = scene.render
    # (the best settings on the benchmark corpus: Sobol samples, adaptive where a render takes a budget)
    assert (r.spp, r.sampler, r.max_depth, r.min_weight, r.t_min, r.t_max, r.clamp, r.light_sampling, r.adaptive) == (
        1, "sobol", 5, 1e-4, 0.0, math.inf, 1e20, "cosine", True)
    assert set(scene.materials) == {"default"}
    m = scene.materials["default"]
    assert m.kd == (0.8, 0.8, 0.8) and m.ka == m.kd and m.ks == (0.0, 0.0, 0.0) and m.p == 32.0
    assert m.mirror == (0.0, 0.0, 0.0) and m.transparency == (0.0, 0.0, 0.0)
    assert (m.ior, m.fresnel, m.glossy_exponent, m.frosted_exponent) == (1.5, "none", 0.0, 0.0)
    assert (scene.animation.frames, scene.animation.fps) == (1, 24.0) and cam.keyframes == ()
    assert load(tmp_path, "[render]\nadaptive = false").render.adaptive is False
    # the loader and the Python API agree on every default
    assert cam == Camera() and r == RenderSettings() and m == Material() and scene.animation == Animation()


def test_a_scene_stating_almost_nothing_loads_and_renders(tmp_path):
    """A default sphere (radius 1 at the origin) under a default point light (0, 5, 5), seen
    from the default camera: the pixel at the image centre sees the point (0, 0, 1) with normal
    +z, so it shows kd * I * n.l = 0.8 * 4/sqrt(41)."""
    scene = load(tmp_path, """
        [[shapes]]
        type = "sphere"

        [[lights]]
        type = "point"
    """)
    assert scene.shapes == (Sphere(),) and scene.lights == (PointLight(),)
    small = scene.with_camera(width=17, height=13).with_settings(sampler="regular")
    image = warprt.render(small, progress=False)
    assert image.shape == (13, 17, 3) and image.dtype == np.float32
    np.testing.assert_allclose(image[6, 8], 0.8 * 4 / math.sqrt(41), rtol=1e-5)
    assert (image[0, 0] == 0).all()  # the corner misses: default background is black


def test_material_defaults_ka_to_kd(tmp_path):
    scene = load(tmp_path, """
        [materials.a]
        kd = 0.25
        [materials.b]
        kd = [0.1, 0.2, 0.3]
        ka = 0.5
    """)
    assert scene.materials["a"].ka == (0.25, 0.25, 0.25)
    assert scene.materials["b"].ka == (0.5, 0.5, 0.5) and scene.materials["b"].kd == (0.1, 0.2, 0.3)
    assert scene.materials["default"] == Material()


def test_a_material_named_default_replaces_the_default(tmp_path):
    scene = load(tmp_path, """
        [materials.default]
        kd = 0.2
        [[shapes]]
        type = "sphere"
    """)
    assert scene.materials["default"].kd == (0.2, 0.2, 0.2)


# --- colours --------------------------------------------------------------------------------------


@pytest.mark.parametrize("value, expected", [
    ("0.5", (0.5, 0.5, 0.5)), ("1", (1.0, 1.0, 1.0)), ("0", (0.0, 0.0, 0.0)),
    ("[0.1, 0.2, 0.3]", (0.1, 0.2, 0.3)), ("[1, 0, 2]", (1.0, 0.0, 2.0)),
])
def test_a_colour_is_one_number_or_three(tmp_path, value, expected):
    scene = load(tmp_path, f"""
        [world]
        ambient = {value}
        background = {value}
        [materials.m]
        kd = {value}
        ks = {value}
        mirror = {value}
        transparency = {value}
        [[lights]]
        type = "point"
        intensity = {value}
        [[lights]]
        type = "sphere"
        radiance = {value}
    """)
    m = scene.materials["m"]
    for c in (scene.ambient, scene.background, m.kd, m.ka, m.ks, m.mirror, m.transparency,
              scene.lights[0].intensity, scene.lights[1].radiance):
        assert c == expected and all(type(x) is float for x in c)


@pytest.mark.parametrize("value, field, words", [
    ("-0.5", "materials.m.kd", [">= 0", "-0.5"]),
    ("[0.1, -0.2, 0.3]", "materials.m.kd[1]", [">= 0"]),
    ("[0.1, 0.2]", "materials.m.kd", ["one number or three"]),
    ("[0.1, 0.2, 0.3, 0.4]", "materials.m.kd", ["one number or three"]),
    ('"red"', "materials.m.kd", ["one number or three", "red"]),
    ("true", "materials.m.kd", ["one number or three"]),
    ("nan", "materials.m.kd", ["finite"]),
    ("inf", "materials.m.kd", ["finite"]),
    ('[0.1, "x", 0.3]', "materials.m.kd[1]", ["number", "x"]),
])
def test_bad_colours(tmp_path, value, field, words):
    expect_error(tmp_path, f"[materials.m]\nkd = {value}\n", field, *words)


def test_bad_world_colours_name_the_world_table(tmp_path):
    expect_error(tmp_path, "[world]\nambient = -1\n", "world.ambient", ">= 0")
    expect_error(tmp_path, "[world]\nbackground = [1, 2]\n", "world.background", "one number or three")


def test_bad_light_colour(tmp_path):
    expect_error(tmp_path, '[[lights]]\ntype = "point"\n[[lights]]\ntype = "point"\nintensity = -2\n',
                 "lights[1].intensity", ">= 0")


# --- transforms -----------------------------------------------------------------------------------


def test_transform_scales_then_rotates_then_translates():
    t = Transform(translate=(0, 0, 1), rotate=(0, 0, 90), scale=2)
    assert t.scale == (2.0, 2.0, 2.0)
    np.testing.assert_allclose(t.apply_point((1, 0, 0)), (0, 2, 1), atol=1e-12)
    np.testing.assert_allclose(t.apply_vector((1, 0, 0)), (0, 2, 0), atol=1e-12)


def test_rotation_is_about_x_then_y_then_z():
    # x first: (0,1,0) -> (0,0,1); then y by 90: (0,0,1) -> (1,0,0). The other order gives (0,0,1).
    np.testing.assert_allclose(Transform(rotate=(90, 90, 0)).apply_point((0, 1, 0)), (1, 0, 0), atol=1e-12)
    # right-handed: 90 degrees about y takes +x to -z, about x takes +y to +z, about z takes +x to +y
    np.testing.assert_allclose(Transform(rotate=(0, 90, 0)).apply_vector((1, 0, 0)), (0, 0, -1), atol=1e-12)
    np.testing.assert_allclose(Transform(rotate=(90, 0, 0)).apply_vector((0, 1, 0)), (0, 0, 1), atol=1e-12)
    np.testing.assert_allclose(Transform(rotate=(0, 0, 90)).apply_vector((1, 0, 0)), (0, 1, 0), atol=1e-12)


def test_transform_quaternion_matches_the_matrix():
    t = Transform(rotate=(30, -50, 170))
    x, y, z, w = t.quaternion()
    q = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(q, t.rotation_matrix(), atol=1e-12)


def test_normals_transform_with_the_inverse_transpose():
    t = Transform(scale=(1, 4, 1))
    # a plane tilted 45 degrees, stretched along y, becomes steeper: its normal tilts towards x
    n = np.array(t.apply_normal((1, 1, 0)))
    np.testing.assert_allclose(n, np.array([4, 1, 0]) / math.sqrt(17), atol=1e-12)


def test_transforms_in_files(tmp_path):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    scene = load(tmp_path, """
        [[shapes]]
        type = "mesh"
        file = "tri.obj"
        transform = { translate = [1, 2, 3], rotate = [0, 90, 0], scale = [1, 2, 3] }
        transform_end = { translate = [2, 2, 3] }

        [[shapes]]
        type = "sphere"
        center = [1, 0, 0]
        radius = 0.5
        [shapes.transform]
        translate = [0, 1, 0]
        scale = 2

        [[shapes]]
        type = "plane"
        transform = { rotate = [90, 0, 0] }

        [[shapes]]
        type = "rectangle"
        transform = { translate = [0, 0, -1] }
    """)
    mesh, sphere, plane, rect = scene.shapes
    assert mesh.transform == Transform(translate=(1, 2, 3), rotate=(0, 90, 0), scale=(1, 2, 3))
    assert mesh.transform_end == Transform(translate=(2, 2, 3)) and mesh.moves
    c0, c1, r = sphere.world()
    np.testing.assert_allclose(c0, (2, 1, 0)) and np.testing.assert_allclose(c1, (2, 1, 0))
    assert r == 1.0
    p, n = plane.world()
    np.testing.assert_allclose(n, (0, 0, 1), atol=1e-12)
    corner, e1, e2 = rect.world()
    np.testing.assert_allclose(corner, (-0.5, 0, -1.5))


@pytest.mark.parametrize("transform, field, words", [
    ("{ spin = [1, 0, 0] }", "shapes[0].transform", ["spin"]),
    ("{ scale = 0 }", "shapes[0].transform.scale", ["non-zero"]),
    ("{ scale = [1, 0, 1] }", "shapes[0].transform.scale", ["non-zero"]),
    ("{ rotate = [90, 0] }", "shapes[0].transform.rotate", ["three numbers"]),
    ('{ translate = "up" }', "shapes[0].transform.translate", ["three numbers"]),
    ("3", "shapes[0].transform", ["translate", "rotate", "scale"]),
])
def test_bad_transforms(tmp_path, transform, field, words):
    expect_error(tmp_path, f'[[shapes]]\ntype = "mesh"\n{TRIANGLE}\ntransform = {transform}\n', field, *words)


def test_a_sphere_takes_only_a_uniform_positive_scale(tmp_path):
    expect_error(tmp_path, '[[shapes]]\ntype = "sphere"\ntransform = { scale = [1, 2, 1] }\n',
                 "shapes[0].transform.scale", "uniform")
    expect_error(tmp_path, '[[shapes]]\ntype = "sphere"\ntransform = { scale = -1 }\n',
                 "shapes[0].transform.scale", "uniform")


# --- every shape and light type --------------------------------------------------------------------


def test_every_shape_type_loads_with_its_fields(tmp_path):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    scene = load(tmp_path, f"""
        [materials.red]
        kd = [0.9, 0.1, 0.1]

        [[shapes]]
        type = "sphere"
        center = [1, 2, 3]
        radius = 0.5
        material = "red"
        center_end = [1, 3, 3]

        [[shapes]]
        type = "plane"
        point = [0, -1, 0]
        normal = [0, 2, 0]

        [[shapes]]
        type = "rectangle"
        corner = [0, 0, 0]
        edge1 = [2, 0, 0]
        edge2 = [0, 3, 0]

        [[shapes]]
        type = "disk"
        center = [0, 1, 0]
        normal = [0, 0, 1]
        radius = 2

        [[shapes]]
        type = "mesh"
        file = "models/tri.obj"
        smooth = true

        [[shapes]]
        type = "mesh"
        {TRIANGLE}
        degenerate = "drop"
    """)
    assert scene.shapes[:4] == (
        Sphere(center=(1, 2, 3), radius=0.5, material="red", center_end=(1, 3, 3)),
        Plane(point=(0, -1, 0), normal=(0, 2, 0)),
        Rectangle(corner=(0, 0, 0), edge1=(2, 0, 0), edge2=(0, 3, 0)),
        Disk(center=(0, 1, 0), normal=(0, 0, 1), radius=2.0),
    )
    mesh_file, mesh_inline = scene.shapes[4:]
    # a mesh path is relative to the scene file, stored absolute
    assert mesh_file.file == str((tmp_path / "models" / "tri.obj").resolve()) and mesh_file.smooth
    assert mesh_inline.file is None and mesh_inline.degenerate == "drop"
    np.testing.assert_array_equal(mesh_inline.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh_inline.faces, [[0, 1, 2]])
    built = build(scene)
    assert built.features.meshes and built.features.motion and len(built.meshes) == 2


def test_mesh_path_is_relative_to_the_scene_file_not_the_working_directory(tmp_path, monkeypatch):
    sub = tmp_path / "deep" / "er"
    sub.mkdir(parents=True)
    (sub / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    path = write(sub, '[[shapes]]\ntype = "mesh"\nfile = "tri.obj"\n')
    monkeypatch.chdir(tmp_path)
    scene = warprt.load_scene("deep/er/scene.toml")
    assert scene.shapes[0].file == str((sub / "tri.obj").resolve())
    assert path.exists()


def test_every_light_type_loads_with_its_fields(tmp_path):
    scene = load(tmp_path, """
        [[lights]]
        type = "point"
        position = [1, 2, 3]
        intensity = [0.5, 0.6, 0.7]
        falloff = "inverse_square"

        [[lights]]
        type = "rectangle"
        corner = [0, 4, 0]
        edge1 = [0, 0, 1]
        edge2 = [1, 0, 0]
        radiance = 3
        samples = 4

        [[lights]]
        type = "sphere"
        center = [0, 5, 0]
        radius = 0.25
        radiance = [1, 2, 3]

        [[lights]]
        type = "disk"
        center = [0, 3, 0]
        normal = [0, -1, 0]
        radius = 0.5
        samples = 2
    """)
    assert scene.lights == (
        PointLight(position=(1, 2, 3), intensity=(0.5, 0.6, 0.7), falloff="inverse_square"),
        RectLight(corner=(0, 4, 0), edge1=(0, 0, 1), edge2=(1, 0, 0), radiance=3.0, samples=4),
        SphereLight(center=(0, 5, 0), radius=0.25, radiance=(1, 2, 3)),
        DiskLight(center=(0, 3, 0), normal=(0, -1, 0), radius=0.5, samples=2),
    )
    assert scene.lights[1].area == pytest.approx(1.0)


def test_animation_and_keyframes(tmp_path):
    scene = load(tmp_path, f"""
        [animation]
        frames = 10
        fps = 30

        [camera]
        keyframes = [{{ time = 0, eye = [0, 0, 5] }}, {{ time = 1, eye = [1, 0, 5], look_at = [1, 0, 0] }}]

        [[shapes]]
        type = "sphere"
        keyframes = [{{ time = 0, center = [0, 0, 0] }}, {{ time = 2, center = [1, 0, 0] }}]

        [[shapes]]
        type = "mesh"
        {TRIANGLE}
        keyframes = [{{ time = 0.5, scale = 2, rotate = [0, 90, 0] }}]
    """)
    assert scene.animation == Animation(frames=10, fps=30)
    assert scene.camera.keyframes == ({"time": 0.0, "eye": (0.0, 0.0, 5.0)},
                                      {"time": 1.0, "eye": (1.0, 0.0, 5.0), "look_at": (1.0, 0.0, 0.0)})
    assert scene.shapes[0].keyframes[1] == {"time": 2.0, "center": (1.0, 0.0, 0.0)}
    assert scene.shapes[1].keyframes == ({"time": 0.5, "rotate": (0.0, 90.0, 0.0), "scale": (2.0, 2.0, 2.0)},)


def test_camera_and_render_fields(tmp_path):
    scene = load(tmp_path, """
        [camera]
        eye = [1, 2, 3]
        look_at = [0, 1, 0]
        up = [0, 0.5, 0]
        fov = 30
        width = 64
        height = 48.0
        distance = 2
        aperture = 0.1
        focus_distance = 4
        shutter = [0.25, 0.75]
        eye_end = [1, 2, 4]
        look_at_end = [0, 1, 0]

        [render]
        spp = 8
        sampler = "sobol"
        max_depth = 0
        min_weight = 0.01
        t_min = 0.5
        t_max = 100
        clamp = 10
    """)
    assert scene.camera == Camera(eye=(1, 2, 3), look_at=(0, 1, 0), up=(0, 0.5, 0), fov=30, width=64, height=48,
                                  distance=2, aperture=0.1, focus_distance=4, shutter=(0.25, 0.75),
                                  eye_end=(1, 2, 4), look_at_end=(0, 1, 0))
    assert type(scene.camera.height) is int and scene.camera.moves and scene.camera.focus == 4.0
    assert scene.render == RenderSettings(spp=8, sampler="sobol", max_depth=0, min_weight=0.01, t_min=0.5,
                                          t_max=100, clamp=10)
    assert load(tmp_path, "[render]\nt_max = inf\n").render.t_max == math.inf


# --- bad input: types and values --------------------------------------------------------------------


@pytest.mark.parametrize("text, field, words", [
    ('[[shapes]]\ntype = "sphere"\nradius = "big"', "shapes[0].radius", ["expected a number", "big"]),
    ('[[shapes]]\ntype = "sphere"\nradius = -1', "shapes[0].radius", [">= 0"]),
    ('[[shapes]]\ntype = "sphere"\nradius = nan', "shapes[0].radius", ["finite"]),
    ('[[shapes]]\ntype = "sphere"\nradius = true', "shapes[0].radius", ["expected a number"]),
    ('[[shapes]]\ntype = "sphere"\ncenter = [0, 0]', "shapes[0].center", ["three numbers"]),
    ('[[shapes]]\ntype = "sphere"\ncenter = [0, 0, inf]', "shapes[0].center[2]", ["finite"]),
    ('[[shapes]]\ntype = "sphere"\nmaterial = 3', "shapes[0].material", ["material name"]),
    ('[[shapes]]\ntype = "plane"\nnormal = [0, 0, 0]', "shapes[0].normal", ["non-zero"]),
    ('[[shapes]]\ntype = "rectangle"\nedge1 = [1, 0, 0]\nedge2 = [2, 0, 0]', "shapes[0].edge2", ["parallel"]),
    ('[[shapes]]\ntype = "disk"\nradius = "wide"', "shapes[0].radius", ["number"]),
    ('[[shapes]]\ntype = "mesh"\n' + TRIANGLE + '\nsmooth = 1', "shapes[0].smooth", ["true or false"]),
    ('[[shapes]]\ntype = "mesh"\n' + TRIANGLE + '\ndegenerate = "fix"', "shapes[0].degenerate", ["error", "drop"]),
    ('[camera]\neye = [1, 2]', "camera.eye", ["three numbers", "[1, 2]"]),
    ('[camera]\neye = [1, 2, "3"]', "camera.eye[2]", ["expected a number"]),
    ('[camera]\nwidth = 0', "camera.width", [">= 1", "0"]),
    ('[camera]\nheight = 0', "camera.height", [">= 1"]),
    ('[camera]\nwidth = -5', "camera.width", [">= 1"]),
    ('[camera]\nwidth = 12.5', "camera.width", ["integer"]),
    ('[camera]\nwidth = 100000', "camera.width", ["<="]),
    ('[camera]\nfov = 0', "camera.fov", ["> 0"]),
    ('[camera]\nfov = -10', "camera.fov", ["> 0"]),
    ('[camera]\nfov = 180', "camera.fov", ["< 180"]),
    ('[camera]\nfov = 200', "camera.fov", ["< 180"]),
    ('[camera]\nfov = "wide"', "camera.fov", ["number"]),
    ('[camera]\ndistance = 0', "camera.distance", ["> 0"]),
    ('[camera]\naperture = -0.1', "camera.aperture", [">= 0"]),
    ('[camera]\nfocus_distance = 0', "camera.focus_distance", ["> 0"]),
    ('[camera]\nshutter = [1, 0]', "camera.shutter", ["before"]),
    ('[camera]\nshutter = 1', "camera.shutter", ["[open, close]"]),
    ('[camera]\neye = [1, 2, 3]\nlook_at = [1, 2, 3]', "camera.look_at", ["coincide"]),
    ('[camera]\nup = [0, 0, 1]', "camera.up", ["parallel"]),
    ('[camera]\nup = [0, 0, -3]', "camera.up", ["parallel"]),
    ('[camera]\nup = [0, 0, 0]', "camera.up", ["non-zero"]),
    ('[camera]\neye_end = [0, 0, 0]', "camera.look_at", ["coincide"]),
    ('[render]\nspp = 0', "render.spp", [">= 1"]),
    ('[render]\nspp = "many"', "render.spp", ["integer"]),
    ('[render]\nspp = 1048577', "render.spp", ["<= 1048576", "time_budget"]),
    ('[camera]\neye = [0, 0, 1e39]', "camera.eye[2]", ["1e+39", "float32"]),
    ('[camera]\nlook_at_end = [-4e38, 0, 0]', "camera.look_at_end[0]", ["float32"]),
    ('[camera]\ndistance = 1e-46', "camera.distance", ["1e-46", "float32", "normal"]),
    ('[camera]\nfocus_distance = 1e-39', "camera.focus_distance", ["float32"]),
    ('[[shapes]]\ntype = "sphere"\nradius = 1e39', "shapes[0].radius", ["float32"]),
    ('[[shapes]]\ntype = "sphere"\ntransform = { scale = 1e39 }', "shapes[0].transform.scale[0]", ["float32"]),
    ('[[shapes]]\ntype = "plane"\nnormal = [0, 1e39, 0]', "shapes[0].normal[1]", ["float32"]),
    ('[[lights]]\ntype = "point"\nposition = [0, 1e39, 0]', "lights[0].position[1]", ["float32"]),
    ('[render]\nt_max = 1e39', "render.t_max", ["float32"]),
    ('[render]\nsampler = "halton"', "render.sampler", ["halton", "stratified", "sobol"]),
    ('[render]\nmax_depth = -1', "render.max_depth", [">= 0"]),
    ('[render]\nmax_depth = 1000', "render.max_depth", ["<= 64"]),
    ('[render]\nmin_weight = 2', "render.min_weight", ["<= 1"]),
    ('[render]\nt_min = 5\nt_max = 1', "render.t_max", ["exceed"]),
    ('[render]\nclamp = 0', "render.clamp", ["> 0"]),
    ('[render]\nadaptive = "yes"', "render.adaptive", ["true or false", "yes"]),
    ('[materials.m]\np = -1', "materials.m.p", [">= 0"]),
    ('[materials.m]\nior = 0', "materials.m.ior", ["> 0"]),
    ('[materials.m]\nfresnel = "fast"', "materials.m.fresnel", ["schlick", "exact"]),
    ('[materials.m]\nglossy_exponent = -1', "materials.m.glossy_exponent", [">= 0"]),
    ('[materials]\nm = 3', "materials.m", ["expected a table"]),
    ('materials = 3', "materials", ["[materials.NAME]"]),
    ('[[lights]]\ntype = "point"\nposition = "above"', "lights[0].position", ["three numbers"]),
    ('[[lights]]\ntype = "point"\nfalloff = "linear"', "lights[0].falloff", ["inverse_square"]),
    ('[[lights]]\ntype = "sphere"\nsamples = 0', "lights[0].samples", [">= 1"]),
    ('[[lights]]\ntype = "disk"\nnormal = [0, 0, 0]', "lights[0].normal", ["non-zero"]),
    ('[[lights]]\ntype = "rectangle"\nedge1 = [1, 0, 0]\nedge2 = [3, 0, 0]', "lights[0].edge2", ["parallel"]),
    ('[[lights]]\ntype = "sphere"\nradius = -1', "lights[0].radius", [">= 0"]),
    ('[animation]\nframes = 0', "animation.frames", [">= 1"]),
    ('[animation]\nfps = 0', "animation.fps", ["> 0"]),
    ('[[shapes]]\ntype = "sphere"\nkeyframes = [{ time = 1, center = [0, 0, 0] }, { time = 0, center = [1, 0, 0] }]',
     "shapes[0].keyframes[1].time", ["increase"]),
    ('[[shapes]]\ntype = "sphere"\nkeyframes = [{ center = [0, 0, 0] }]', "shapes[0].keyframes[0].time",
     ["needs a time"]),
    ('[[shapes]]\ntype = "sphere"\nkeyframes = [{ time = 0, center = [1, 2] }]', "shapes[0].keyframes[0].center",
     ["three numbers"]),
    ('[[shapes]]\ntype = "sphere"\nkeyframes = 3', "shapes[0].keyframes", ["list of tables"]),
    ('camera = 3', "camera", ["expected a table"]),
    ('world = [1, 2]', "world", ["table"]),
    ('shapes = 3', "shapes", ["[[shapes]]"]),
    ('[shapes]\ntype = "sphere"', "shapes", ["[[shapes]]"]),
    ('shapes = [1]', "shapes[0]", ["expected a table"]),
])
def test_bad_values_name_the_file_field_and_problem(tmp_path, text, field, words):
    expect_error(tmp_path, text + "\n", field, *words)


def test_the_field_index_counts_within_its_array(tmp_path):
    text = """
        [[shapes]]
        type = "plane"
        [[shapes]]
        type = "sphere"
        [[shapes]]
        type = "sphere"
        radius = "big"
        [[lights]]
        type = "point"
    """
    expect_error(tmp_path, text, "shapes[2].radius", "big")


# --- bad input: unknown names (typos) -----------------------------------------------------------------


@pytest.mark.parametrize("text, field, typo", [
    ("[camera]\neyes = [0, 0, 1]", "camera", "eyes"),
    ("[render]\nsamples = 4", "render", "samples"),
    ("[world]\nambiant = 0.1", "world", "ambiant"),
    ("[materials.red]\ncolour = 0.5", "materials.red", "colour"),
    ("[materials.red]\nKd = 0.5", "materials.red", "Kd"),
    ('[[shapes]]\ntype = "sphere"\nraduis = 2', "shapes[0]", "raduis"),
    ('[[shapes]]\ntype = "plane"\nradius = 2', "shapes[0]", "radius"),
    ('[[shapes]]\ntype = "disk"\ntransform = { translate = [0, 1, 0] }', "shapes[0]", "transform"),
    ('[[lights]]\ntype = "point"\ncolor = 1', "lights[0]", "color"),
    ('[[lights]]\ntype = "point"\nradiance = 1', "lights[0]", "radiance"),
    ("[camrea]\nfov = 30", "camrea", "camrea"),
    ("[[light]]\ntype = \"point\"", "light", "light"),
    ("spp = 4", "spp", "spp"),
    ("[animation]\nlength = 3", "animation", "length"),
    ('[[shapes]]\ntype = "sphere"\nkeyframes = [{ time = 0, radius = 2 }]', "shapes[0].keyframes[0]", "radius"),
    ("[camera]\nkeyframes = [{ time = 0, up = [1, 0, 0] }]", "camera.keyframes[0]", "up"),
])
def test_unknown_fields_and_tables_are_errors(tmp_path, text, field, typo):
    err = expect_error(tmp_path, text + "\n", field, typo, "unknown")
    # the message lists what is allowed, to help fix the typo
    assert "expected" in err.problem


def test_unknown_material_names_the_shape_and_lists_the_known_ones(tmp_path):
    err = expect_error(tmp_path, """
        [materials.red]
        kd = [1, 0, 0]
        [[shapes]]
        type = "sphere"
        material = "red"
        [[shapes]]
        type = "sphere"
        material = "gold"
    """, "shapes[1].material", "gold", "unknown material")
    assert "red" in err.problem and "default" in err.problem


@pytest.mark.parametrize("text, field, value", [
    ('[[shapes]]\ntype = "cube"', "shapes[0].type", "cube"),
    ('[[shapes]]\ntype = "Sphere"', "shapes[0].type", "Sphere"),
    ('[[shapes]]\nradius = 1', "shapes[0].type", "None"),
    ('[[shapes]]\ntype = 3', "shapes[0].type", "3"),
    ('[[lights]]\ntype = "spot"', "lights[0].type", "spot"),
    ('[[lights]]\ntype = "plane"', "lights[0].type", "plane"),
    ('[[lights]]\nposition = [0, 1, 0]', "lights[0].type", "None"),
])
def test_unknown_shape_or_light_type(tmp_path, text, field, value):
    err = expect_error(tmp_path, text + "\n", field, value)
    kinds = ("sphere", "plane", "rectangle", "disk", "mesh") if field.startswith("shapes") else (
        "point", "rectangle", "sphere", "disk")
    for kind in kinds:
        assert repr(kind) in err.problem


@pytest.mark.parametrize("value", ['["sphere"]', "{ kind = 1 }"])
def test_a_type_that_is_not_a_string_is_a_scene_error(tmp_path, value):
    # once a TypeError ("unhashable type") escaped from the loader here
    expect_error(tmp_path, f"[[shapes]]\ntype = {value}\n", "shapes[0].type", "type must be one of")


# --- bad input: TOML syntax and files ------------------------------------------------------------------


@pytest.mark.parametrize("text", [
    "[camera\nfov = 30",
    "[camera]\nfov = ",
    "[camera]\nfov = 30\nfov = 40",
    "[camera]\neye = [0, 0, 5\n",
    '[[shapes]]\ntype = sphere',
])
def test_invalid_toml_names_the_file_and_the_position(tmp_path, text):
    path = write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        warprt.load_scene(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: not valid TOML") and "\n" not in msg
    assert re.search(r"line \d+", msg), msg  # where in the file, also for errors at the end


def test_scene_from_string_names_its_source():
    with pytest.raises(SceneError, match=r"^<string>: camera\.fov: "):
        warprt.scene_from_string("[camera]\nfov = 0")
    with pytest.raises(SceneError, match=r"^lecture\.toml: not valid TOML"):
        warprt.scene_from_string("[camera", source="lecture.toml")


def test_missing_scene_file_and_directory(tmp_path):
    with pytest.raises(SceneError, match="not found") as info:
        warprt.load_scene(tmp_path / "nope.toml")
    assert str(tmp_path / "nope.toml") in str(info.value)
    with pytest.raises(SceneError, match="directory"):
        warprt.load_scene(tmp_path)


def test_missing_mesh_file(tmp_path):
    err = expect_error(tmp_path, '[[shapes]]\ntype = "sphere"\n[[shapes]]\ntype = "mesh"\nfile = "bunny.obj"\n',
                       "shapes[1].file", "not found", "bunny.obj")
    # it says where it looked: next to the scene file
    assert str(tmp_path) in err.problem


def test_a_mesh_needs_a_file_or_vertices_and_faces(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    expect_error(tmp_path, '[[shapes]]\ntype = "mesh"\n', "shapes[0].file", "either file or vertices")
    expect_error(tmp_path, '[[shapes]]\ntype = "mesh"\nfile = "a.obj"\n' + TRIANGLE,
                 "shapes[0].file", "either file or vertices")
    expect_error(tmp_path, '[[shapes]]\ntype = "mesh"\nvertices = [[0, 0, 0]]\n', "shapes[0].faces", "faces")
    expect_error(tmp_path, '[[shapes]]\ntype = "mesh"\nfile = 3\n', "shapes[0].file", "path")


@pytest.mark.parametrize("name, content, field, words", [
    ("text.obj", "hello world\nthis is not a mesh\n", "shapes[0].file", ["text.obj", "no triangles"]),
    ("empty.obj", "", "shapes[0].file", ["empty.obj", "no triangles"]),
    ("points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "shapes[0].file", ["points.obj", "no triangles"]),
    ("junk.ply", "\x00\x01garbage\xff" * 20, "shapes[0].file", ["junk.ply", "cannot read"]),
    ("nan.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "shapes[0].vertices", ["NaN or infinite"]),
    ("inf.obj", "v 0 0 0\nv 1 0 0\nv 0 inf 0\nf 1 2 3\n", "shapes[0].vertices", ["NaN or infinite"]),
    ("huge.obj", "v 0 0 0\nv 1e31 0 0\nv 0 1 0\nf 1 2 3\n", "shapes[0].vertices", ["1e30"]),
    ("nan.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                "0 0 0\n1 0 0\nnan 1 0\n3 0 1 2\n", "shapes[0].vertices", ["NaN or infinite"]),
    ("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 5\n", "shapes[0].file", ["range.obj"]),
    ("flat.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n", "shapes[0].faces",
     ["1 of 2 faces", "zero area", "degenerate"]),
])
def test_bad_mesh_files_fail_when_the_scene_is_built(tmp_path, name, content, field, words):
    (tmp_path / name).write_bytes(content.encode("latin-1"))
    expect_error(tmp_path, f'[[shapes]]\ntype = "mesh"\nfile = "{name}"\n', field, *words, build=True)


# --- bad input: inline meshes ----------------------------------------------------------------------------


@pytest.mark.parametrize("arrays, field, words", [
    ("vertices = [[0, 0, 0], [1, 0, 0], [nan, 1, 0]]\nfaces = [[0, 1, 2]]", "shapes[0].vertices",
     ["NaN or infinite", "vertex 2"]),
    ("vertices = [[0, 0, 0], [1, -inf, 0], [0, 1, 0]]\nfaces = [[0, 1, 2]]", "shapes[0].vertices",
     ["NaN or infinite", "vertex 1"]),
    ("vertices = []\nfaces = []", "shapes[0].vertices", ["(N, 3)"]),
    ("vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = []", "shapes[0].faces", ["no faces"]),
    ("vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [[0, 1, 3]]", "shapes[0].faces", ["[0, 2]"]),
    ("vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [[0, -1, 2]]", "shapes[0].faces", ["[0, 2]"]),
    ("vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [[0, 1, 2.5]]", "shapes[0].faces", ["integer"]),
    ('vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [["a", "b", "c"]]', "shapes[0].faces", ["integer"]),
    ("vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nfaces = [0, 1, 2]", "shapes[0].faces", ["(M, 3)"]),
    ("vertices = [[0, 0], [1, 0], [0, 1]]\nfaces = [[0, 1, 2]]", "shapes[0].vertices", ["(N, 3)"]),
    ("vertices = [[0, 0, 0], [1, 0, 0], [0, 1]]\nfaces = [[0, 1, 2]]", "shapes[0].vertices", ["numbers"]),
    ('vertices = "cube"\nfaces = [[0, 1, 2]]', "shapes[0].vertices", ["numbers"]),
])
def test_bad_inline_meshes(tmp_path, arrays, field, words):
    expect_error(tmp_path, f'[[shapes]]\ntype = "mesh"\n{arrays}\n', field, *words)


def test_quad_faces_are_a_scene_error(tmp_path):
    # once numpy's ValueError ("cannot reshape array") escaped here
    expect_error(tmp_path, '[[shapes]]\ntype = "mesh"\nvertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\n'
                           'faces = [[0, 1, 2, 3]]\n', "shapes[0].faces", "(M, 3)")


FLAT = """
    [[shapes]]
    type = "mesh"
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]]
    faces = [[0, 1, 2], [0, 1, 3], [1, 1, 2]]
"""


def test_zero_area_faces_are_an_error_by_default(tmp_path):
    expect_error(tmp_path, FLAT, "shapes[0].faces", "2 of 3 faces", "zero area", 'degenerate = "drop"', build=True)


def test_zero_area_faces_are_dropped_on_request(tmp_path):
    path = write(tmp_path, FLAT + 'degenerate = "drop"\n')
    with pytest.warns(UserWarning, match="dropping 2 zero-area faces of 3"):
        built = load_and_build(path)
    assert built.meshes[0].indices.numpy().tolist() == [0, 1, 2]


def test_a_mesh_left_with_no_faces_after_dropping_is_an_error(tmp_path):
    text = '[[shapes]]\ntype = "mesh"\nvertices = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]\nfaces = [[0, 1, 2]]\n'
    with pytest.warns(UserWarning):
        expect_error(tmp_path, text + 'degenerate = "drop"\n', "shapes[0].faces", "nothing is left", build=True)


def test_prepare_mesh_checks_and_converts():
    v, f = prepare_mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    assert v.dtype == np.float32 and f.dtype == np.int32 and f.tolist() == [[0, 1, 2]]
    # a sliver is not degenerate, a repeated index is
    sliver = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-4, 0]])
    assert prepare_mesh(sliver, [[0, 1, 2]])[1].shape == (1, 3)
    with pytest.raises(SceneError, match="zero area") as info:
        prepare_mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), [[0, 1, 2], [2, 2, 1]])
    assert info.value.field == "faces"
    with pytest.raises(SceneError) as info:
        prepare_mesh(np.array([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]]), [[0, 1, 2]])
    assert info.value.field == "vertices"


def test_a_mesh_error_inside_a_scene_names_the_shape(tmp_path):
    (tmp_path / "ok.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    text = """
        [[shapes]]
        type = "mesh"
        file = "ok.obj"
        [[shapes]]
        type = "sphere"
        [[shapes]]
        type = "mesh"
        file = "bad.obj"
    """
    expect_error(tmp_path, text, "shapes[2].vertices", "NaN", build=True)


# --- the Python API -------------------------------------------------------------------------------------


@pytest.mark.parametrize("make, field, words", [
    (lambda: Sphere(radius="big"), "radius", ["big"]),
    (lambda: Sphere(center=(0, 0)), "center", ["three numbers"]),
    (lambda: Sphere(transform=Transform(scale=(1, 2, 1))), "transform.scale", ["uniform"]),
    (lambda: Sphere(transform={"spin": 1}), "transform", ["spin"]),
    (lambda: Sphere(transform={"scale": 0}), "transform.scale", ["non-zero"]),
    (lambda: Sphere(material=""), "material", ["material name"]),
    (lambda: Plane(normal=(0, 0, 0)), "normal", ["non-zero"]),
    (lambda: Rectangle(edge1=(1, 1, 0), edge2=(-2, -2, 0)), "edge2", ["parallel"]),
    (lambda: Disk(radius=-1), "radius", [">= 0"]),
    (lambda: Mesh(), "file", ["either"]),
    (lambda: Mesh(vertices=[[0, 0, 0]]), "faces", ["faces"]),
    (lambda: Mesh(vertices=np.zeros((3, 3)) + [[0, 0, 0], [1, 0, 0], [np.inf, 0, 0]], faces=[[0, 1, 2]]),
     "vertices", ["NaN or infinite"]),
    (lambda: Mesh(file="a.obj", smooth="yes"), "smooth", ["true or false"]),
    (lambda: Camera(eye=(1, 2)), "eye", ["three numbers"]),
    (lambda: Camera(width=0), "width", [">= 1"]),
    (lambda: Camera(fov=180), "fov", ["< 180"]),
    (lambda: Camera(eye=(0, 0, 0), look_at=(0, 0, 0)), "look_at", ["coincide"]),
    (lambda: Camera(up=(0, 0, 1)), "up", ["parallel"]),
    (lambda: Camera(look_at_end=(0, 0, 5)), "look_at", ["coincide"]),
    (lambda: Material(kd=-1), "kd", [">= 0"]),
    (lambda: Material(ks=(1, 1)), "ks", ["one number or three"]),
    (lambda: Material(fresnel="yes"), "fresnel", ["exact"]),
    (lambda: PointLight(intensity="bright"), "intensity", ["one number or three"]),
    (lambda: RectLight(edge1=(1, 0, 0), edge2=(1, 0, 0)), "edge2", ["parallel"]),
    (lambda: SphereLight(samples=0), "samples", [">= 1"]),
    (lambda: SphereLight(samples=1.5), "samples", ["integer"]),
    (lambda: DiskLight(normal=(0, 0, 0)), "normal", ["non-zero"]),
    (lambda: RenderSettings(sampler="random"), "sampler", ["stratified"]),
    (lambda: RenderSettings(t_min=2, t_max=1), "t_max", ["exceed"]),
    (lambda: Transform(scale=(1, 0, 1)), "scale", ["non-zero"]),
    (lambda: Scene(shapes=(Sphere(material="gold"),)), "shapes[0].material", ["gold"]),
    (lambda: Scene(shapes=(Sphere(), "sphere")), "shapes[1]", ["expected a shape"]),
    (lambda: Scene(lights=(Sphere(),)), "lights[0]", ["expected a light"]),
    (lambda: Scene(materials={"m": {"kd": 1}}), "materials.m", ["expected a Material"]),
    (lambda: Scene(materials={"": Material()}), "materials", ["non-empty"]),
    (lambda: Scene(camera="front"), "camera", ["Camera"]),
    (lambda: Scene(ambient=-0.1), "ambient", [">= 0"]),
    (lambda: Scene().with_camera(width=0), "width", [">= 1"]),
    (lambda: Scene().with_settings(spp=0), "spp", [">= 1"]),
])
def test_python_api_construction_errors_name_the_field(make, field, words):
    with pytest.raises(SceneError) as info:
        make()
    err = info.value
    assert err.field == field, str(err)
    assert str(err).startswith(f"{field}: ")
    for word in words:
        assert word in str(err)


@pytest.mark.parametrize("scale", [1e-10, 1e-30, 1e10])
def test_the_up_vector_is_judged_by_its_direction_not_its_length(scale):
    """The parallel test is relative: up = (0, 1e-10, 0) is the same camera as (0, 1, 0)."""
    ref = Camera().basis()
    for got, want in zip(Camera(up=(0, scale, 0)).basis(), ref):
        np.testing.assert_allclose(got, want, atol=1e-15)
    with pytest.raises(SceneError) as info:
        Camera(up=(0, 0, scale))
    assert info.value.field == "up" and "parallel" in str(info.value)


@pytest.mark.parametrize("make, cls, typo, hint", [
    (lambda: Sphere(radisu=1), "Sphere", "radisu", "did you mean 'radius'?"),
    (lambda: Camera(fvo=30), "Camera", "fvo", "did you mean 'fov'?"),
    (lambda: Scene().with_camera(widht=8), "Camera", "widht", "did you mean 'width'?"),
    (lambda: Scene().with_settings(sampels=8), "RenderSettings", "sampels", "did you mean 'sampler'?"),
    (lambda: Transform(translat=(1, 0, 0)), "Transform", "translat", "did you mean 'translate'?"),
    (lambda: RectLight(radiance=1, samplse=2), "RectLight", "samplse", "did you mean 'samples'?"),
    (lambda: Material(zzzz=1), "Material", "zzzz", "fields: kd, ka, ks"),
    (lambda: Scene(shape=()), "Scene", "shape", "did you mean 'shapes'?"),
])
def test_a_misspelt_keyword_names_the_class_and_the_closest_field(make, cls, typo, hint):
    with pytest.raises(SceneError) as info:
        make()
    assert info.value.field == typo
    assert str(info.value).startswith(f"{typo}: {cls} has no field {typo!r}; {hint}")


def test_keyword_checks_keep_signatures_defaults_and_replace():
    import inspect

    assert list(inspect.signature(Sphere).parameters) == [
        "center", "radius", "material", "center_end", "transform", "keyframes"]
    assert inspect.signature(Camera).parameters["width"].default == 320
    assert inspect.signature(Camera).parameters["fov"].default is None and Camera().fov == 45.0  # (unless fx is given)
    s = Sphere((1, 2, 3), 2.0)
    assert dataclasses.replace(s, radius=3).radius == 3.0 and dataclasses.replace(s, radius=3).center == (1, 2, 3)
    with pytest.raises(SceneError, match="did you mean 'radius'"):
        dataclasses.replace(s, radus=3)


def test_quaternion_is_one_name_in_files_and_in_python(tmp_path):
    """``quaternion`` (the scene files' name) is a keyword of Transform, and
    ``rotation_quaternion`` (Python's older one, the field that holds it) is accepted in files,
    transform tables and keyframes alike: the four spellings give the same transform."""
    q = (0.0, 0.3826834, 0.0, 0.9238795)
    python_new = Transform(quaternion=q, translate=(1, 0, 0))
    python_old = Transform(rotation_quaternion=q, translate=(1, 0, 0))
    files = [load(tmp_path, f'[[shapes]]\ntype = "box"\ntransform = {{ translate = [1, 0, 0], {key} = {list(q)} }}\n')
             .shapes[0].transform for key in ("quaternion", "rotation_quaternion")]
    assert python_new == python_old == files[0] == files[1]
    np.testing.assert_allclose(python_new.quaternion(), np.array(q) / np.linalg.norm(q), atol=1e-15)
    table = Box(transform={"rotation_quaternion": q}).transform
    assert table == Box(transform={"quaternion": q}).transform == Transform(quaternion=q)
    keys = [Box(keyframes=[{"time": 0.0, name: q}]).keyframes[0] for name in ("quaternion", "rotation_quaternion")]
    assert keys[0] == keys[1] and "quaternion" in keys[0]
    # errors name the spelling given, and both at once is refused
    with pytest.raises(SceneError, match="must not be zero") as info:
        Transform(quaternion=(0, 0, 0, 0))
    assert info.value.field == "quaternion"
    with pytest.raises(SceneError, match="must not be zero") as info:
        Transform(rotation_quaternion=(0, 0, 0, 0))
    assert info.value.field == "rotation_quaternion"
    with pytest.raises(SceneError, match="same field"):
        Transform(quaternion=q, rotation_quaternion=q)
    with pytest.raises(SceneError, match="same field"):
        Box(transform={"quaternion": q, "rotation_quaternion": q})
    with pytest.raises(SceneError, match="rotate .*or.* quaternion, not both"):
        Transform(quaternion=q, rotate=(0, 10, 0))


def test_a_missing_mesh_file_is_refused_when_the_mesh_is_made(tmp_path, monkeypatch):
    """``Mesh(file=...)`` names a missing file (and where it looked) at once, not when a render
    builds the scene; a folder is not a mesh file either. A file that exists is accepted, with a
    relative path taken from the current folder as the build reads it."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SceneError, match=r"mesh file not found: 'missing\.ply'") as info:
        Mesh(file="missing.ply")
    assert info.value.field == "file" and str(tmp_path / "missing.ply") in str(info.value)
    (tmp_path / "meshes").mkdir()
    with pytest.raises(SceneError, match="is a folder") as info:
        Mesh(file="meshes")
    assert info.value.field == "file"
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    mesh = Mesh(file="meshes/tri.obj")
    assert mesh.file == "meshes/tri.obj"
    assert DeviceScene(Scene(shapes=(mesh,)), resolve_device("cpu")).data.n_inst == 1


def test_python_api_errors_carry_the_scene_source():
    with pytest.raises(SceneError) as info:
        Scene(shapes=(Sphere(material="gold"),), source="lecture.toml")
    assert str(info.value).startswith("lecture.toml: shapes[0].material: unknown material 'gold'")
    assert info.value.source == "lecture.toml" and info.value.problem.startswith("unknown material")


def test_scene_errors_are_value_errors():
    assert issubclass(SceneError, ValueError)
    err = SceneError("must be > 0", "radius").within("shapes[3]").within(source="a.toml")
    assert (err.field, err.source, str(err)) == ("shapes[3].radius", "a.toml", "a.toml: shapes[3].radius: must be > 0")
    assert SceneError("bad", "[2]").within("shapes").field == "shapes[2]"


def test_python_api_coerces_like_the_loader(tmp_path):
    s = Sphere(center=np.array([1, 2, 3]), radius=np.float32(0.5))
    assert s.center == (1.0, 2.0, 3.0) and type(s.radius) is float
    assert Material(kd=np.array([0.1, 0.2, 0.3])).kd == pytest.approx((0.1, 0.2, 0.3))
    assert Camera(width=64.0).width == 64
    scene = Scene(shapes=[Sphere()], lights=[PointLight()], ambient=0.1)
    assert scene.shapes == (Sphere(),) and scene.ambient == (0.1, 0.1, 0.1)
    assert scene.with_settings(spp=4).render.spp == 4 and scene.render.spp == 1
    assert scene.with_camera(width=8).camera.width == 8 and scene.camera.width == 320


# --- the format reference -------------------------------------------------------------------------------

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "scene-format.md"


def test_every_toml_example_in_the_format_reference_loads():
    text = DOC.read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 3
    for block in blocks:
        scene = warprt.scene_from_string(block, base_dir=str(DOC.parents[1] / "scenes"), source="doc")
        assert scene.shapes


def test_the_format_reference_names_every_field():
    text = DOC.read_text()
    classes = [Camera, RenderSettings, Material, Sphere, Plane, Rectangle, Disk, Mesh, PointLight, RectLight,
               SphereLight, DiskLight, Transform, Animation, warprt.DepthSensor]
    missing = [f"{cls.__name__}.{f.name}" for cls in classes for f in dataclasses.fields(cls)
               if f"`{f.name}`" not in text]
    assert not missing
    for name in ("ambient", "background", "type"):
        assert f"`{name}`" in text
