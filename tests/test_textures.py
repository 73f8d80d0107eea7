"""Textures: bitmaps sampled bilinearly, checkers, UVs from mesh files of each format, triplanar
and cubic projections, per-world textures, colours and light intensities in batches, and bad input.

Every image here is compared with a float64 computation of the same value from the hit points
(numpy bilinear weights, the checker's closed form, the triplanar blend), to float32 precision.
The scenes use two render-kernel variants ("textures" and "meshes+textures") and one batch variant.
"""

from __future__ import annotations

import base64
import json
import os

import numpy as np
import pytest

import warprt
from warprt import (
    BatchRenderer, Camera, Material, Mesh, Plane, PointLight, Rectangle, RenderSettings, Scene, SceneError, Sphere,
    Texture,
)
from warprt.colour import srgb_to_linear
from warprt.query import camera_rays, trace_rays

# float32 precision of a texture value: the hit point's coordinates (a few ulps, times the texture's
# slope of up to one texel range per texel) and the lerps' rounding; measured 3e-7 at most on these
# scenes, 4e-6 leaves room for the slope of a 16-texel map over the image's width
TOL = 4e-6
RNG = np.random.default_rng(57)
IMAGE = RNG.integers(0, 256, size=(6, 7, 3), dtype=np.uint8)  # 7 wide, 6 high: not square, not a power of 2


def bilinear_ref(texels: np.ndarray, u, v, wrap: str = "repeat") -> np.ndarray:
    """The bilinear value of a (H, W, 3) texel array at (u, v) in float64 (v up, row 0 the top)."""
    h, w = texels.shape[:2]
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    if wrap == "repeat":
        u, v = u - np.floor(u), v - np.floor(v)
    else:
        u, v = np.clip(u, 0, 1), np.clip(v, 0, 1)
    x, y = u * w - 0.5, (1.0 - v) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]

    def idx(i, n):
        i = i.astype(np.int64)
        return np.mod(i, n) if wrap == "repeat" else np.clip(i, 0, n - 1)

    i0, i1, j0, j1 = idx(x0, w), idx(x0 + 1, w), idx(y0, h), idx(y0 + 1, h)
    t = texels.astype(np.float64)
    return ((1 - fy) * ((1 - fx) * t[j0, i0] + fx * t[j0, i1]) + fy * ((1 - fx) * t[j1, i0] + fx * t[j1, i1]))


def checker_ref(c0, c1, u, v):
    s = np.floor(u) + np.floor(v)
    return np.where((np.mod(s, 2) == 0)[..., None], np.asarray(c0, np.float64), np.asarray(c1, np.float64))


def head_on(width=24, height=20, half=1.0) -> Camera:
    """A camera on +z looking at the origin whose image spans about [-half, half] at z = 0."""
    return Camera(eye=(0.0, 0.0, 10.0), look_at=(0.0, 0.0, 0.0), fov=2 * np.degrees(np.arctan(half / 10.0)),
                  width=width, height=height)


def ambient_scene(shapes, material: Material, camera: Camera, **kw) -> Scene:
    """The texture alone: ka = 1 (with kd) times the texture, ambient 1, no lights."""
    return Scene(camera=camera, shapes=shapes, materials={"t": material}, ambient=1.0,
                 render=RenderSettings(sampler="regular"), **kw)


def pixel_hits(scene: Scene):
    """The camera rays through the pixel centres and their hits (float32, as the kernel sees them)."""
    o, d = camera_rays(scene)
    hits = trace_rays(scene, o, d)
    return o, d, hits


def render(scene: Scene, **kw) -> np.ndarray:
    """The image of ``scene`` on the general kernel, which every feature set's texture code is
    (the bitmap rectangle's test renders on its scene's own kernel): one kernel for the many
    feature sets of these scenes keeps the suite's compiles few."""
    r = warprt.Renderer(scene, features=warprt.Features.full())
    return np.asarray(r.render(spp=1, progress=False, **kw).image, dtype=np.float64)


# --- bitmaps and checkers on analytic shapes ---------------------------------------------------


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_bitmap_rectangle_is_the_bilinear_value(wrap):
    """A rectangle seen head-on: each pixel centre shows the float64 bilinear value of the sRGB-
    decoded texels at its (u, v); scale 1.7 and an offset corner run u, v past [0, 1] (wrapped or
    clamped). The albedo AOV shows the textured kd."""
    tex = Texture(image=IMAGE, scale=1.7, wrap=wrap)
    rect = Rectangle(corner=(-0.9, -0.8, 0.0), edge1=(2.0, 0.1, 0.0), edge2=(-0.2, 1.9, 0.0), material="t")
    scene = ambient_scene([rect], Material(kd=1.0, texture=tex), head_on())
    o, d, hits = pixel_hits(scene)
    p = hits["position"].astype(np.float64)
    e1, e2 = np.array(rect.edge1), np.array(rect.edge2)
    q = p - np.array(rect.corner)
    g = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    ab = np.linalg.solve(g, np.stack([q @ e1, q @ e2]))
    texels = srgb_to_linear(IMAGE.astype(np.float64) / 255.0)
    want = bilinear_ref(texels, ab[0] * 1.7, ab[1] * 1.7, wrap).reshape(20, 24, 3)
    hit = hits["hit"].reshape(20, 24)
    assert hit.sum() > 200 and (~hit).sum() > 20
    r = warprt.Renderer(scene).render(spp=1, progress=False, aovs=["albedo"])
    got = np.asarray(r.image, np.float64)
    np.testing.assert_allclose(got[hit], want[hit], atol=TOL, rtol=0)
    np.testing.assert_allclose(np.asarray(r.aovs["albedo"])[hit], want[hit], atol=TOL, rtol=0)
    assert np.all(got[~hit] == 0.0)


def test_checker_is_its_closed_form_on_a_sphere():
    """A checker on a sphere: square (⌊u·s⌋ + ⌊v·s⌋) even → c0, odd → c1, with the sphere's uv
    (longitude from +x towards −z, v = 1/2 + asin(d_y)/π) at each hit; pixels within float32
    reach of a square's edge are left out."""
    c0, c1, s = (0.9, 0.2, 0.1), (0.05, 0.3, 0.8), 6.0
    scene = ambient_scene([Sphere(center=(0.1, -0.05, 0.0), radius=0.9, material="t")],
                          Material(kd=1.0, texture=Texture(checker=[c0, c1], scale=s)), head_on(40, 36))
    _, _, hits = pixel_hits(scene)
    dvec = hits["position"].astype(np.float64) - (0.1, -0.05, 0.0)
    dvec /= np.linalg.norm(dvec, axis=1, keepdims=True)
    u = np.mod(np.arctan2(-dvec[:, 2], dvec[:, 0]) / (2 * np.pi), 1.0)
    v = 0.5 + np.arcsin(np.clip(dvec[:, 1], -1, 1)) / np.pi
    want = checker_ref(c0, c1, u * s, v * s).reshape(36, 40, 3)
    edge = lambda x: np.abs(x - np.round(x)) < 1e-4
    ok = (hits["hit"] & ~edge(u * s) & ~edge(v * s)).reshape(36, 40)
    got = render(scene)
    assert ok.sum() > 600
    assert len(np.unique(want[ok][:, 0])) == 2
    np.testing.assert_allclose(got[ok], want[ok], atol=1e-6, rtol=0)


def test_texture_modulates_diffuse_light_and_specular_mirror_maps():
    """kd·T shades the point-light term (Blinn-Phong's diffuse part, here alone): the image is the
    untextured render times the texture value, pixel by pixel."""
    tex = Texture(image=IMAGE)
    rect = Rectangle(corner=(-1, -1, 0), edge1=(2, 0, 0), edge2=(0, 2, 0), material="t")
    lit = dict(lights=[PointLight(position=(0.3, 0.2, 3.0))], ambient=0.0)
    plain = Scene(camera=head_on(), shapes=[rect], materials={"t": Material(kd=0.7)}, **lit,
                  render=RenderSettings(sampler="regular"))
    textured = plain.replace(materials={"t": Material(kd=0.7, texture=tex)})
    _, _, hits = pixel_hits(plain)
    p = hits["position"].astype(np.float64)
    t = bilinear_ref(srgb_to_linear(IMAGE / 255.0), (p[:, 0] + 1) / 2, (p[:, 1] + 1) / 2).reshape(20, 24, 3)
    np.testing.assert_allclose(render(textured), render(plain) * t, atol=TOL, rtol=1e-5)


def test_srgb_decoded_once_at_load(tmp_path):
    """A PNG's 8-bit texels become srgb_to_linear(c / 255) (float64, rounded to float32) when the
    texture is made; 16-bit PNG texels c / 65535; srgb=False keeps them as data; float arrays are
    linear as given."""
    from PIL import Image

    path = tmp_path / "t.png"
    Image.fromarray(IMAGE).save(path)
    tex = Texture(file=str(path))
    np.testing.assert_array_equal(tex.texels, srgb_to_linear(IMAGE / 255.0).astype(np.float32))
    assert Texture(file=str(path), srgb=False).texels[2, 3, 1] == np.float32(IMAGE[2, 3, 1] / 255.0)
    grey = (RNG.integers(0, 65536, size=(3, 4))).astype(np.uint16)
    Image.fromarray(grey).save(tmp_path / "g.png")
    np.testing.assert_allclose(Texture(file=str(tmp_path / "g.png")).texels[..., 0],
                               srgb_to_linear(grey / 65535.0), rtol=1e-6, atol=1e-9)
    lin = RNG.random((2, 3, 3)) * 4.0
    np.testing.assert_array_equal(Texture(image=lin).texels, lin.astype(np.float32))


# --- meshes: UVs from files ----------------------------------------------------------------------

QUAD_V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
QUAD_UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)  # OBJ's convention: v up
PIXEL_TEXELS = RNG.integers(0, 256, size=(4, 4, 3), dtype=np.uint8)  # one texel per pixel of a 4 × 4 image


def write_obj(folder, png: str | None = None) -> str:
    lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in QUAD_V] + [f"vt {u:g} {v:g}" for u, v in QUAD_UV]
    if png:
        lines.insert(0, "mtllib quad.mtl")
        lines.append("usemtl tex")
        (folder / "quad.mtl").write_text(f"newmtl tex\nKd 1 1 1\nmap_Kd {png}\n")
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in QUAD_F]
    (folder / "quad.obj").write_text("\n".join(lines) + "\n")
    return str(folder / "quad.obj")


def write_ply(folder) -> str:
    head = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y", "property float z",
            "property float s", "property float t", "element face 2", "property list uchar int vertex_indices",
            "end_header"]
    body = [f"{x:g} {y:g} {z:g} {u:g} {v:g}" for (x, y, z), (u, v) in zip(QUAD_V, QUAD_UV)]
    body += [f"3 {a} {b} {c}" for a, b, c in QUAD_F]
    (folder / "quad.ply").write_text("\n".join(head + body) + "\n")
    return str(folder / "quad.ply")


def write_gltf(folder, png: str) -> str:
    """A glTF 2.0 quad written by hand: its TEXCOORD_0 in glTF's own convention (v = 0 at the
    image's top), so the image's bottom-left texel lands at the quad's bottom-left corner only if
    the loader flips v."""
    pos = QUAD_V.astype(np.float32).tobytes()
    uv = np.column_stack([QUAD_UV[:, 0], 1.0 - QUAD_UV[:, 1]]).astype(np.float32).tobytes()
    idx = QUAD_F.astype(np.uint16).reshape(-1).tobytes()
    blob = pos + uv + idx
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"name": "tex", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0,
                                                               "roughnessFactor": 1.0}}],
        "textures": [{"source": 0}], "images": [{"uri": png}],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(uv)},
                        {"buffer": 0, "byteOffset": len(pos) + len(uv), "byteLength": len(idx)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                       "min": [-1, -1, 0], "max": [1, 1, 0]},
                      {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                      {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    }
    (folder / "quad.gltf").write_text(json.dumps(doc))
    return str(folder / "quad.gltf")


@pytest.fixture(scope="module")
def quad_files(tmp_path_factory):
    from PIL import Image

    folder = tmp_path_factory.mktemp("uv")
    Image.fromarray(PIXEL_TEXELS).save(folder / "texels.png")
    return folder


def pixel_per_texel(shapes, materials) -> np.ndarray:
    scene = Scene(camera=head_on(4, 4), shapes=shapes, materials=materials, ambient=1.0,
                  render=RenderSettings(sampler="regular"))
    return render(scene)


@pytest.mark.parametrize("kind", ["obj", "ply", "gltf", "obj+mtl"])
def test_mesh_file_uvs_put_the_known_texel_in_its_place(kind, quad_files):
    """A 4 × 4 texture on a quad filling a 4 × 4 image: pixel (i, j) looks at the centre of texel
    (column i, row j), row 0 the image's top, whichever format (and v origin) the UVs came from.
    OBJ and PLY through ``Mesh(file=...)`` with the material's texture, glTF and OBJ + MTL through
    ``load_assets`` with the file's own texture."""
    want = srgb_to_linear(PIXEL_TEXELS / 255.0)
    if kind in ("obj", "ply"):
        path = write_obj(quad_files) if kind == "obj" else write_ply(quad_files)
        got = pixel_per_texel([Mesh(file=path, material="t")],
                              {"t": Material(kd=1.0, texture=str(quad_files / "texels.png"))})
    else:
        path = write_gltf(quad_files, "texels.png") if kind == "gltf" else write_obj(quad_files, "texels.png")
        shapes, mats = warprt.load_assets(path)
        assert len(shapes) == 1 and shapes[0].uv is not None
        (mat,) = mats.values()
        assert mat.texture is not None and mat.mirror == (0.0, 0.0, 0.0)
        got = pixel_per_texel(shapes, mats)
    np.testing.assert_allclose(got, want, atol=TOL, rtol=0)


def test_mesh_uv_interpolation_is_affine_on_a_planar_quad():
    """Inline UVs (an affine map of the quad's corners, not aligned with its edges) interpolated by
    the hit's barycentric weights: on a planar quad uv is that affine map of the hit point."""
    A = np.array([[0.31, -0.12], [0.08, 0.27]])
    b = np.array([0.4, 0.55])
    uv = QUAD_V[:, :2] @ A.T + b
    mesh = Mesh(vertices=QUAD_V, faces=QUAD_F, uv=uv, material="t")
    scene = ambient_scene([mesh], Material(kd=1.0, texture=Texture(image=IMAGE)), head_on(24, 20, half=1.2))
    _, _, hits = pixel_hits(scene)
    want_uv = hits["position"][:, :2].astype(np.float64) @ A.T + b
    want = bilinear_ref(srgb_to_linear(IMAGE / 255.0), want_uv[:, 0], want_uv[:, 1]).reshape(20, 24, 3)
    hit = hits["hit"].reshape(20, 24)
    assert 100 < hit.sum() < hit.size
    np.testing.assert_allclose(render(scene)[hit], want[hit], atol=TOL, rtol=0)


# --- triplanar and cubic projection -------------------------------------------------------------


@pytest.mark.parametrize("projection", ["triplanar", "cubic"])
def test_projection_on_a_mesh_without_uvs(projection):
    """An icosphere (no UVs, turned and moved by its transform) with a bitmap projected in its
    object space: the blend Σ_k w_k·T(map_k(x))/Σ w_k with w_k = |n_k|^sharpness of the face
    normal n (triplanar), or the map of n's largest component (cubic)."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    transform = warprt.Transform(rotate=(20.0, 35.0, 0.0), translate=(0.05, -0.02, 0.3))
    mesh = Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces), transform=transform, material="t")
    tex = Texture(image=IMAGE, projection=projection, scale=1.3, sharpness=3.0)
    scene = ambient_scene([mesh], Material(kd=1.0, texture=tex), head_on(32, 30))
    _, _, hits = pixel_hits(scene)
    hit = hits["hit"]
    m = transform.matrix()
    x = (hits["position"][hit].astype(np.float64) - m[:3, 3]) @ np.linalg.inv(m[:3, :3]).T
    n = hits["normal"][hit].astype(np.float64) @ m[:3, :3]  # (a rotation: normals turn back with it)
    texels = srgb_to_linear(IMAGE / 255.0)
    maps = [bilinear_ref(texels, 1.3 * x[:, 2], 1.3 * x[:, 1]), bilinear_ref(texels, 1.3 * x[:, 0], 1.3 * x[:, 2]),
            bilinear_ref(texels, 1.3 * x[:, 0], 1.3 * x[:, 1])]
    a = np.abs(n)
    if projection == "triplanar":
        w = a ** 3.0
        want = sum(w[:, k:k + 1] * maps[k] for k in range(3)) / w.sum(axis=1, keepdims=True)
        keep = np.ones(len(x), bool)
    else:
        axis = np.argmax(a, axis=1)
        want = np.choose(axis[:, None], maps)
        srt = np.sort(a, axis=1)
        keep = srt[:, 2] - srt[:, 1] > 1e-5  # (a tie within float32 picks either map)
    got = render(scene).reshape(-1, 3)[hit]
    assert hit.sum() > 300
    np.testing.assert_allclose(got[keep], want[keep], atol=2e-5, rtol=0)


# --- batches: per-world looks -------------------------------------------------------------------


def test_batch_switches_textures_colours_and_intensities_without_recompile_or_rebuild():
    """A batch of 3 worlds: after the first render, each world gets another texture (one added to
    the pool), colour and light intensity; the next render uses the same kernel, no rebuild, and
    every world's image is what a single render of that world's scene gives (the direct light
    scales with the intensity)."""
    rect = Rectangle(corner=(-1, -1, 0), edge1=(2, 0, 0), edge2=(0, 2, 0), material="t")
    checker = Texture(checker=[(0.9, 0.8, 0.1), (0.1, 0.2, 0.9)], scale=3.0)
    bitmap = Texture(image=IMAGE)
    base = Scene(camera=head_on(16, 12), shapes=[rect], materials={"t": Material(kd=0.8, texture=checker)},
                 lights=[PointLight(position=(0.2, 0.3, 4.0), intensity=1.5)], ambient=0.1,
                 render=RenderSettings(sampler="regular"))
    batch = BatchRenderer(base, worlds=3, textures=[bitmap])
    first = batch.render(spp=1).numpy()
    kernel, counters = batch._kernel, dict(batch.counters)
    single = render(base)
    for w in range(3):
        np.testing.assert_allclose(first[w, 0], single, atol=TOL, rtol=1e-5)
    third = batch.add_texture({"checker": [0.3, 1.0], "scale": 5.0})
    assert batch.textures[third].checker == ((0.3,) * 3, (1.0,) * 3)
    batch.set_material_textures([[1, -1], [third, -1], [-1, -1]])
    colors = [(0.8, 0.8, 0.8), (0.2, 0.9, 0.4), (0.5, 0.1, 0.1)]
    batch.set_material_colors([[c, (0.8, 0.8, 0.8)] for c in colors])
    batch.set_light_intensities([[(1.5,) * 3], [(3.0, 2.0, 1.0)], [(0.5,) * 3]])
    second = batch.render(spp=1).numpy()
    assert batch._kernel is kernel and batch.counters["rebuilds"] == counters["rebuilds"]
    assert batch.counters["compiles"] == counters["compiles"]
    looks = [(bitmap, 1.5), (batch.textures[third], (3.0, 2.0, 1.0)), (None, 0.5)]
    for w, (tex, intensity) in enumerate(looks):
        scene = base.replace(materials={"t": Material(kd=colors[w], texture=tex)},
                             lights=[PointLight(position=(0.2, 0.3, 4.0), intensity=intensity)])
        np.testing.assert_allclose(second[w, 0], render(scene), atol=TOL, rtol=1e-5)
    assert not np.allclose(second[0, 0], first[0, 0])
    with pytest.raises(warprt.RenderError, match=r"material_textures\[0, 0\]"):
        batch.set_material_textures([[7, -1]] * 3)
    with pytest.raises(warprt.RenderError, match=r"material_colors\[1, 0\]"):
        batch.set_material_colors([[c, (0.8,) * 3] for c in [(1, 1, 1), (np.nan, 0, 0), (1, 1, 1)]])
    batch.material_textures.fill_(9)  # written on the device: refused before the render
    with pytest.raises(warprt.RenderError, match=r"material_textures\[0, 0\]: a texture index"):
        batch.render(spp=1)


def test_batch_without_textures_says_how_to_get_them():
    scene = Scene(shapes=[Sphere(material="default")], camera=Camera(width=8, height=8))
    batch = BatchRenderer(scene, worlds=2)
    with pytest.raises(warprt.RenderError, match="textures="):
        batch.add_texture(Texture(checker=[0, 1]))


# --- the description: TOML and Python, bad input ------------------------------------------------


def test_toml_and_python_give_the_same_material(tmp_path):
    from PIL import Image

    Image.fromarray(IMAGE).save(tmp_path / "wood.png")
    text = """
    [materials.floor]
    kd = 0.8
    texture = {checker = [[0.1, 0.1, 0.1], [0.9, 0.9, 0.9]], scale = 8, projection = "triplanar"}
    [materials.wood]
    texture = "wood.png"
    mirror = 0.5
    mirror_texture = {file = "wood.png", wrap = "clamp", srgb = false}
    [[shapes]]
    type = "plane"
    material = "floor"
    [[shapes]]
    type = "sphere"
    material = "wood"
    """
    scene = warprt.scene_from_string(text, base_dir=str(tmp_path))
    floor = scene.materials["floor"].texture
    py = Material(kd=0.8, texture=Texture(checker=[[0.1] * 3, [0.9] * 3], scale=8, projection="triplanar")).texture
    assert (floor.checker, floor.scale, floor.projection) == (py.checker, py.scale, py.projection)
    wood = scene.materials["wood"]
    assert wood.texture.file == str(tmp_path / "wood.png") and wood.texture.projection == "uv"
    assert wood.mirror_texture.wrap == "clamp" and wood.mirror_texture.srgb is False
    np.testing.assert_array_equal(wood.mirror_texture.texels, (IMAGE / 255.0).astype(np.float32))


def test_bad_textures_and_uvs_are_refused_when_the_scene_is_made(tmp_path):
    with pytest.raises(SceneError, match="texture file not found.*missing.png") as e:
        Material(texture="missing.png")
    assert e.value.field == "texture.file"
    with pytest.raises(SceneError) as e:
        warprt.scene_from_string('[materials.m]\ntexture = {file = "missing.png"}', base_dir=str(tmp_path))
    assert e.value.field == "materials.m.texture.file" and "missing.png" in str(e.value)
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(SceneError, match="cannot read texture file 'junk.png'") as e:
        warprt.scene_from_string('[materials.m]\nmirror_texture = "junk.png"', base_dir=str(tmp_path))
    assert e.value.field == "materials.m.mirror_texture.file"
    with pytest.raises(SceneError, match=r"shape \(4, 2\).*\(4, 3\)") as e:
        Mesh(vertices=QUAD_V, faces=QUAD_F, uv=np.zeros((4, 3)))
    assert e.value.field == "uv"
    with pytest.raises(SceneError, match=r"uv\[2\]") as e:
        Mesh(vertices=QUAD_V, faces=QUAD_F, uv=[[0, 0], [1, 0], [np.nan, 1], [0, 1]])
    with pytest.raises(SceneError) as e:
        warprt.scene_from_string('[[shapes]]\ntype = "mesh"\nvertices = [[0,0,0],[1,0,0],[0,1,0]]\n'
                                 'faces = [[0,1,2]]\nuv = [[0,0],[1,0]]')
    assert e.value.field == "shapes[0].uv"
    with pytest.raises(SceneError, match="give one of file, image"):
        Texture(checker=[0, 1], image=IMAGE)
    with pytest.raises(SceneError, match="checker"):
        Texture(checker=[0, 1, 2])
    with pytest.raises(SceneError, match="projection") as e:
        Material(texture={"checker": [0, 1], "projection": "spherical"})
    assert e.value.field == "texture.projection"
    # a uv map on a shape without uvs: named, with the way out
    with pytest.raises(SceneError, match="triplanar") as e:
        Scene(shapes=[Plane(material="m")], materials={"m": Material(texture=Texture(checker=[0, 1]))})
    assert e.value.field == "shapes[0].material"
    with pytest.raises(SceneError, match="no texture coordinates"):
        Scene(shapes=[Mesh(vertices=QUAD_V, faces=QUAD_F, material="m")],
              materials={"m": Material(texture=Texture(checker=[0, 1]))})
    Scene(shapes=[Plane(material="m")], materials={"m": Material(texture=Texture(checker=[0, 1], projection="cubic"))})


def test_specular_texture_modulates_the_highlight():
    """ks·T: a glossy-only rectangle (kd = 0) under a point light is the untextured image times
    the specular texture's value at each pixel."""
    rect = Rectangle(corner=(-1, -1, 0), edge1=(2, 0, 0), edge2=(0, 2, 0), material="t")
    plain = Scene(camera=head_on(), shapes=[rect], materials={"t": Material(kd=0.0, ks=0.9, p=2.0)},
                  lights=[PointLight(position=(0.3, 0.2, 3.0))], render=RenderSettings(sampler="regular"))
    tex = Texture(image=IMAGE, scale=2.0)
    textured = plain.replace(materials={"t": Material(kd=0.0, ks=0.9, p=2.0, specular_texture=tex)})
    _, _, hits = pixel_hits(plain)
    p = hits["position"].astype(np.float64)
    t = bilinear_ref(srgb_to_linear(IMAGE / 255.0), p[:, 0] + 1, p[:, 1] + 1).reshape(20, 24, 3)
    base = render(plain)
    hit = hits["hit"].reshape(20, 24)
    assert base[hit].min() > 0.05
    np.testing.assert_allclose(render(textured), base * t, atol=TOL, rtol=1e-5)


def test_gltf_metallic_map_splits_diffuse_and_mirror(quad_files):
    """A glTF material with a base-colour texture B, a metallic factor m and a metallic map M (the
    blue channel of metallicRoughnessTexture): kd·T_d = b·B·(1 − m·M) and mirror·T_m = b·B·m·M,
    texel by texel. Seen head-on with ambient 1 and a background of 0.5 that the mirror part
    reflects: b·B·(1 − m·M) + 0.5·b·B·m·M at each texel centre."""
    from PIL import Image

    metal = RNG.integers(0, 256, size=(4, 4, 3), dtype=np.uint8)
    Image.fromarray(metal).save(quad_files / "metal.png")
    path = write_gltf(quad_files, "texels.png")
    doc = json.loads(open(path).read())
    b, m = [0.8, 0.6, 0.4], 0.6  # (8-bit exact: trimesh keeps baseColorFactor as uint8)
    doc["materials"][0]["pbrMetallicRoughness"].update(baseColorFactor=b + [1.0], metallicFactor=m,
                                                        roughnessFactor=0.0, metallicRoughnessTexture={"index": 1})
    doc["textures"].append({"source": 1})
    doc["images"].append({"uri": "metal.png"})
    (quad_files / "metal.gltf").write_text(json.dumps(doc))
    shapes, mats = warprt.load_assets(str(quad_files / "metal.gltf"))
    scene = Scene(camera=head_on(4, 4), shapes=shapes, materials=mats, ambient=1.0, background=0.5,
                  render=RenderSettings(sampler="regular"))
    B = srgb_to_linear(PIXEL_TEXELS / 255.0)
    mM = m * (metal[..., 2:3] / 255.0)
    want = np.array(b) * B * (1 - mM) + 0.5 * np.array(b) * B * mM
    np.testing.assert_allclose(render(scene), want, atol=TOL, rtol=0)


def test_newton_bridge_sets_each_worlds_shape_colours_textures_and_lights():
    """The bridge's per-shape looks land in the batch's per-material arrays (shape j is material
    j); a new colour for one shape in one world scales that shape's pixels there (Lambert: the
    colour is a factor) and leaves every other pixel and world as it was, with no rebuild or
    recompile (the colours need no texture code: the bridge tests' own kernel)."""
    pytest.importorskip("newton")
    from tests.test_newton_bridge import FOV, model, moved_state
    from warprt.newton_bridge import NewtonRenderer, look_at_pose

    m = model()
    r = NewtonRenderer(m, cameras=1, camera=warprt.Camera(fov=FOV, width=48, height=40),
                       render=RenderSettings(sampler="regular", spp=1))
    r.set_camera_poses(np.array([[look_at_pose((3.0, -3.0, 2.2), (0.3, 0.2, 0.3))]] * 2))
    r.update(moved_state(m))
    before = r.render().numpy()
    counters = dict(r.counters)
    S = len(r.scene.shapes)
    colors = r.batch.material_colors.numpy()[:, :S].copy()
    colors[1, 1] *= 2.0  # world 1's box (shape 1; shape 0 is the ground)
    r.set_shape_colors(colors)
    r.set_light_intensities(np.ones((2, 1, 3)))
    after = r.render().numpy()
    assert r.counters["rebuilds"] == counters["rebuilds"] and r.counters["compiles"] == counters["compiles"]
    np.testing.assert_array_equal(after[0], before[0])
    changed = np.any(after[1] != before[1], axis=-1)
    assert changed.sum() > 20
    np.testing.assert_allclose(after[1][changed], 2.0 * before[1][changed], rtol=1e-6)
    with pytest.raises(warprt.RenderError, match="textures="):
        r.set_shape_textures(np.zeros((2, S), int))
    textured = NewtonRenderer(m, textures=[Texture(checker=[0.2, 1.0], scale=4.0, projection="cubic")])
    marble = textured.add_texture(Texture(checker=[0.5, 0.9], projection="triplanar"))
    textured.set_shape_textures([[-1, 0, marble], [marble, -1, 0]])
    np.testing.assert_array_equal(textured.batch.material_textures.numpy()[:, :S], [[-1, 0, marble], [marble, -1, 0]])
    assert len(textured.textures) == 2 and marble == 1


def test_projection_on_analytic_shapes():
    """A plane seen from above with a cubic checker (its normal +y: the y map, (x_x, x_z)) and a
    sphere with a triplanar bitmap in its frame (the offset from its centre, the normal d): both
    the closed forms, pixel by pixel (checker edges within float32 reach left out)."""
    c0, c1 = (0.9, 0.6, 0.2), (0.1, 0.2, 0.5)
    centre = np.array([0.4, 0.5, -0.3])
    scene = Scene(camera=Camera(eye=(0.3, 4.0, 2.5), look_at=(0.2, 0.0, 0.0), width=40, height=30),
                  shapes=[Plane(material="floor"), Sphere(center=tuple(centre), radius=0.6, material="ball")],
                  materials={"floor": Material(kd=1.0, texture=Texture(checker=[c0, c1], scale=3.0, projection="cubic")),
                             "ball": Material(kd=1.0, texture=Texture(image=IMAGE, projection="triplanar", scale=0.7,
                                                                      sharpness=2.0))},
                  ambient=1.0, render=RenderSettings(sampler="regular"))
    _, _, hits = pixel_hits(scene)
    got = render(scene).reshape(-1, 3)
    p = hits["position"].astype(np.float64)
    floor = hits["shape"] == 0
    u, v = 3.0 * p[:, 0], 3.0 * p[:, 2]
    edge = (np.abs(u - np.round(u)) < 1e-4) | (np.abs(v - np.round(v)) < 1e-4)
    keep = floor & ~edge
    assert keep.sum() > 400
    np.testing.assert_allclose(got[keep], checker_ref(c0, c1, u, v)[keep], atol=1e-6, rtol=0)
    ball = hits["shape"] == 1
    x = p[ball] - centre
    n = np.abs(x / np.linalg.norm(x, axis=1, keepdims=True))
    texels = srgb_to_linear(IMAGE / 255.0)
    maps = [bilinear_ref(texels, 0.7 * x[:, 2], 0.7 * x[:, 1]), bilinear_ref(texels, 0.7 * x[:, 0], 0.7 * x[:, 2]),
            bilinear_ref(texels, 0.7 * x[:, 0], 0.7 * x[:, 1])]
    w = n ** 2.0
    want = sum(w[:, k:k + 1] * maps[k] for k in range(3)) / w.sum(axis=1, keepdims=True)
    assert ball.sum() > 50
    np.testing.assert_allclose(got[ball], want, atol=2e-5, rtol=0)
