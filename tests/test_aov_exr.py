"""AOVs in EXR files, read back through OpenEXR's own API (``OpenEXR.File``, 3.x), not through
``warprt.read_exr``: the standard channel names (``R``, ``G``, ``B`` colour, ``A`` coverage,
``Z`` camera-space depth, ``distance.V`` the ray's, ``N.X/Y/Z`` normal, ``P.X/Y/Z`` position,
``albedo.R/G/B``, ``forward.u/v`` motion with v up...), the pixel types
(FLOAT, 32-bit, and UINT for ids, stored as id + 1 with 0 for none), the header, and the values:
bit for bit what ``render(..., aovs=...)`` returned, and, for a rectangle facing the camera at a
known distance, the closed forms of depth, z, normal, position, albedo, ids and camera motion.
"""

from __future__ import annotations

import math

import numpy as np
import OpenEXR
import pytest

import warprt
from warprt import Features
from warprt.aov import AOV_NAMES, AOVS
from warprt.cli import main
from warprt.query import pixel_samples_1d

W, H, DIST, FOV = 8, 6, 3.0, 40.0
SHIFT = 0.3  # the camera moves by this along +x over the shutter
KD = (0.2, 0.4, 0.6)


def expected_channels(names) -> set[str]:
    out = {"R", "G", "B"}
    for name in names:
        out |= set(AOVS[name].exr)
    return out


def stored(channels, name) -> np.ndarray:
    """AOV ``name`` as render() returns it, from the raw channels (ids: UINT id + 1; the motion's
    v up, the array's y down)."""
    spec = AOVS[name]
    if spec.uint:
        return channels[spec.exr[0]][1].astype(np.int64) - 1
    if len(spec.exr) == 1:
        return channels[spec.exr[0]][1]
    signs = spec.signs or (1.0,) * len(spec.exr)
    return np.stack([channels[c][1] * np.float32(s) for c, s in zip(spec.exr, signs)], axis=-1)


def read_channels(path) -> tuple[dict, dict]:
    """(header, {name: (pixel type, (H, W) array)}) straight from OpenEXR."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        header = dict(f.header())
        channels = {name: (c.type(), np.array(c.pixels)) for name, c in f.channels().items()}
    return header, channels


def facing_scene() -> warprt.Scene:
    """A pinhole camera at the origin looking along -z; a rectangle in the plane z = -DIST facing
    it (normal +z) covers x < 0, so the left half of the image sees it and the right half sees
    nothing. A sphere behind the camera and an unused material make the ids non-trivial (the
    rectangle is shapes[1], its material materials[1]). The camera slides by SHIFT along x
    over the shutter (eye and look-at together)."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), fov=FOV, width=W, height=H,
                             eye_end=(SHIFT, 0, 0), look_at_end=(SHIFT, 0, -1), shutter=(0.0, 1.0)),
        shapes=(warprt.Sphere(center=(0, 0, 5), radius=0.5, material="unused"),
                warprt.Rectangle(corner=(-10, -10, -DIST), edge1=(10, 0, 0), edge2=(0, 20, 0), material="m")),
        materials={"unused": warprt.Material(kd=0.9), "m": warprt.Material(kd=KD)},
        lights=(warprt.PointLight(position=(0, 0, 0), intensity=1.0),),
        render=warprt.RenderSettings(sampler="regular", spp=1))  # one sample: the pixel centre


def pixel_directions() -> np.ndarray:
    """Unit directions (H, W, 3) of the pixel-centre rays at shutter open, in float64, from the
    camera model of docs/scene-format.md (top = D·tan(fov/2), right = top·W/H, D = 1)."""
    top = math.tan(math.radians(FOV / 2))
    right = top * W / H
    us = -right + 2 * right * (np.arange(W) + 0.5) / W
    vs = top - 2 * top * (np.arange(H) + 0.5) / H
    d = np.stack(np.broadcast_arrays(us[None, :], vs[:, None], -1.0), axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def facing(tmp_path_factory):
    """The scene rendered with every AOV (1 regular sample: the pixel-centre ray, at the middle
    of the shutter), saved by save_image, and read back with OpenEXR."""
    out = warprt.Renderer(facing_scene(), device="cpu", features=Features.full()).render(
        spp=1, progress=False, aovs=list(AOV_NAMES))
    arrays = {"color": out.image, **out.aovs}
    path = tmp_path_factory.mktemp("aov") / "facing.exr"
    warprt.save_image(arrays, path, metadata={"warprt_spp": 1})
    header, channels = read_channels(path)
    return arrays, header, channels


def test_channel_names_types_and_header(facing):
    arrays, header, channels = facing
    assert set(channels) == expected_channels(AOV_NAMES)
    for name in ("R", "G", "B", "A", "Z", "distance.V", "N.X", "N.Y", "N.Z", "P.X", "P.Y", "P.Z", "albedo.R",
                 "albedo.G", "albedo.B", "object_id", "material", "forward.u", "forward.v"):
        assert name in channels
    for name, (ptype, pixels) in channels.items():
        uint = name in ("object_id", "material")
        assert ptype == (OpenEXR.UINT if uint else OpenEXR.FLOAT), (name, ptype)  # never HALF
        assert pixels.dtype == (np.uint32 if uint else np.float32) and pixels.shape == (H, W), (name, pixels.dtype)
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    assert header["type"] == OpenEXR.scanlineimage
    assert tuple(header["dataWindow"][0]) == (0, 0) and tuple(header["dataWindow"][1]) == (W - 1, H - 1)
    assert tuple(header["displayWindow"][1]) == (W - 1, H - 1)
    assert header["warprt_spp"] == 1


def test_channels_hold_exactly_the_arrays_render_returned(facing):
    arrays, _, channels = facing
    for k, c in enumerate("RGB"):
        np.testing.assert_array_equal(channels[c][1], arrays["color"][..., k])
    for name in AOV_NAMES:
        np.testing.assert_array_equal(stored(channels, name), arrays[name])  # bit for bit, inf included
    assert (channels["object_id"][1] == 0).any()  # misses: 0 in the UINT channel, -1 returned


def test_stored_values_match_closed_forms_for_a_facing_rectangle(facing):
    _, _, ch = facing
    v = {name: stored(ch, name).astype(np.float64) for name in AOV_NAMES}
    d = pixel_directions()
    ts = float(pixel_samples_1d("regular", [0], 1)[0, 0])  # the sample's time in the shutter
    assert ts == 0.5
    eye = np.array([SHIFT * ts, 0.0, 0.0])
    t = DIST / -d[..., 2]
    p = eye + t[..., None] * d
    hit = p[..., 0] < 0  # the rectangle covers x < 0
    miss = ~hit
    assert hit.sum() > 10 and miss.sum() > 10
    # float32 tolerances: the kernel's t and its products carry a few roundings of 2^-24 ≈ 6e-8;
    # measured worst relative errors: depth 9.9e-8, z 1.2e-7, position 3.8e-8 (of |p|), motion
    # 3.6e-7 pixels (a difference of raster coordinates up to W = 8: ulp 9.5e-7); bounds of 4x
    rel = 2.0 ** -21
    np.testing.assert_allclose(v["depth"][hit], t[hit], rtol=rel)
    np.testing.assert_allclose(v["z"][hit], DIST, rtol=rel)
    for k in range(3):
        np.testing.assert_allclose(v["position"][..., k][hit], p[hit][:, k], rtol=rel, atol=rel * DIST)
        np.testing.assert_array_equal(v["normal"][..., k][hit], (0.0, 0.0, 1.0)[k])
        np.testing.assert_array_equal(v["albedo"][..., k][hit], np.float32(KD[k]))
    assert (v["coverage"][hit] == 1).all() and (v["coverage"][miss] == 0).all()
    assert (v["object_id"][hit] == 1).all() and (v["material"][hit] == 1).all()
    # the camera slides by SHIFT along +x over the whole shutter: a static point moves left on the
    # film by SHIFT / DIST in the image plane at distance 1, i.e. SHIFT / DIST / (2·right) · W pixels
    right = math.tan(math.radians(FOV / 2)) * W / H
    np.testing.assert_allclose(v["motion"][..., 0][hit], -SHIFT / DIST / (2 * right) * W, rtol=0,
                               atol=4 * W * 2.0 ** -24)
    np.testing.assert_array_equal(v["motion"][..., 1][hit], 0.0)
    # misses: infinite depths, zero vectors, id -1
    assert np.isposinf(v["depth"][miss]).all() and np.isposinf(v["z"][miss]).all()
    for layer in ("normal", "albedo", "position"):
        assert (v[layer][miss] == 0).all(), layer
    assert (v["object_id"][miss] == -1).all() and (v["material"][miss] == -1).all()


CLI_SCENE = """\
[camera]
eye = [0, 1, 4]
look_at = [0, 0.5, 0]
width = 12
height = 8

[materials.floor]
kd = 0.5

[materials.ball]
kd = [0.8, 0.3, 0.1]

[[shapes]]
type = "plane"
material = "floor"

[[shapes]]
type = "sphere"
center = [0, 0.5, 0]
radius = 0.5
material = "ball"

[[lights]]
type = "point"
position = [2, 3, 2]
"""


def test_cli_aov_exr_holds_the_renderers_arrays(tmp_path, capsys):
    scene_path = tmp_path / "scene.toml"
    scene_path.write_text(CLI_SCENE)
    exr = tmp_path / "out.exr"
    names = ["depth", "normal", "object_id", "motion"]
    code = main(["render", str(scene_path), "-o", str(exr), "--spp", "2", "--seed", "3", "--no-progress",
                 "--aovs", ",".join(names)])
    capsys.readouterr()
    assert code == 0
    header, channels = read_channels(exr)
    assert set(channels) == expected_channels(names)
    assert all(ptype == (OpenEXR.UINT if name == "object_id" else OpenEXR.FLOAT)
               for name, (ptype, _) in channels.items())
    assert header["warprt_spp"] == 2 and header["warprt_seed"] == 3
    ref = warprt.Renderer(warprt.load_scene(scene_path)).render(spp=2, seed=3, progress=False, aovs=names)
    np.testing.assert_array_equal(np.stack([channels[c][1] for c in "RGB"], axis=-1), ref.image)
    for name in names:
        np.testing.assert_array_equal(stored(channels, name), ref.aovs[name])
    assert set(np.unique(channels["object_id"][1])) == {0, 1, 2}  # sky, the plane, the sphere
