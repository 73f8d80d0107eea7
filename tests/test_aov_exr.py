"""AOVs in EXR files, read back through OpenEXR's own API (``OpenEXR.File``, 3.x), not through
``warprt.read_exr``: the channel names (``layer.V`` for one channel, ``layer.X/.Y/.Z`` for
vectors, ``R``, ``G``, ``B`` for the colour), the pixel type (FLOAT, 32-bit, for every channel,
ids included, as warprt.image documents: "EXR float32"), the header, and the values: bit for bit
what ``render(..., aovs=...)`` returned, and, for a rectangle facing the camera at a known
distance, the closed forms of depth, z, normal, position, albedo, ids and camera motion.
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

W, H, DIST, FOV = 8, 6, 3.0, 40.0
SHIFT = 0.3  # the camera moves by this along +x over the shutter
KD = (0.2, 0.4, 0.6)


def expected_channels(names) -> set[str]:
    out = {"R", "G", "B"}
    for name in names:
        k = AOVS[name].channels
        out |= {f"{name}.V"} if k == 1 else {f"{name}.{c}" for c in "XYZ"[:k]}
    return out


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
        lights=(warprt.PointLight(position=(0, 0, 0), intensity=1.0),))


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
    """The scene rendered with every AOV (1 spp: the AOVs do not depend on it), saved by
    save_image, and read back with OpenEXR."""
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
    for name, (ptype, pixels) in channels.items():
        assert ptype == OpenEXR.FLOAT, (name, ptype)  # 32-bit float, never HALF or UINT
        assert pixels.dtype == np.float32 and pixels.shape == (H, W), (name, pixels.dtype, pixels.shape)
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
        a = arrays[name]
        if a.ndim == 2:
            stored = channels[f"{name}.V"][1]
        else:
            stored = np.stack([channels[f"{name}.{c}"][1] for c in "XYZ"[:a.shape[2]]], axis=-1)
        if np.issubdtype(a.dtype, np.integer):
            # integer ids are stored as float32: exact while |id| < 2^24
            assert np.abs(a).max() < 2 ** 24
            np.testing.assert_array_equal(stored.astype(np.int64), a)
            np.testing.assert_array_equal(stored, a.astype(np.float32))
        else:
            np.testing.assert_array_equal(stored, a)  # bit for bit, inf included


def test_stored_values_match_closed_forms_for_a_facing_rectangle(facing):
    _, _, ch = facing
    v = {name: c[1].astype(np.float64) for name, c in ch.items()}
    d = pixel_directions()
    hit = d[..., 0] < 0  # the rectangle covers x < 0 (no pixel centre is on x = 0: W is even)
    miss = ~hit
    assert hit.sum() == miss.sum() == W * H // 2
    # float32 tolerances: the kernel's t and its products carry a few roundings of 2^-24 ≈ 6e-8;
    # measured worst relative errors: depth 9.9e-8, z 1.2e-7, position 3.8e-8 (of |p|), motion
    # 3.6e-7 pixels (a difference of raster coordinates up to W = 8: ulp 9.5e-7); bounds of 4x
    rel = 2.0 ** -21
    t = DIST / -d[..., 2]
    np.testing.assert_allclose(v["depth.V"][hit], t[hit], rtol=rel)
    np.testing.assert_allclose(v["z.V"][hit], DIST, rtol=rel)
    p = t[..., None] * d
    for k, c in enumerate("XYZ"):
        np.testing.assert_allclose(v[f"position.{c}"][hit], p[hit][:, k], rtol=rel, atol=rel * DIST)
        np.testing.assert_array_equal(v[f"normal.{c}"][hit], (0.0, 0.0, 1.0)[k])
        np.testing.assert_array_equal(v[f"albedo.{c}"][hit], np.float32(KD[k]))
    assert (v["object_id.V"][hit] == 1).all() and (v["material.V"][hit] == 1).all()
    # the camera slides by SHIFT along +x: a static point moves left on the film by
    # SHIFT / DIST in the image plane at distance 1, i.e. SHIFT / DIST / (2·right) · W pixels
    right = math.tan(math.radians(FOV / 2)) * W / H
    np.testing.assert_allclose(v["motion.X"][hit], -SHIFT / DIST / (2 * right) * W, rtol=0, atol=4 * W * 2.0 ** -24)
    np.testing.assert_array_equal(v["motion.Y"][hit], 0.0)
    # misses: infinite depths, zero vectors, id -1
    assert np.isposinf(v["depth.V"][miss]).all() and np.isposinf(v["z.V"][miss]).all()
    for layer in ("normal", "albedo", "position"):
        for c in "XYZ":
            assert (v[f"{layer}.{c}"][miss] == 0).all(), layer
    assert (v["object_id.V"][miss] == -1).all() and (v["material.V"][miss] == -1).all()


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
    assert all(ptype == OpenEXR.FLOAT for ptype, _ in channels.values())
    assert header["warprt_spp"] == 2 and header["warprt_seed"] == 3
    ref = warprt.Renderer(warprt.load_scene(scene_path)).render(spp=2, seed=3, progress=False, aovs=names)
    np.testing.assert_array_equal(np.stack([channels[c][1] for c in "RGB"], axis=-1), ref.image)
    np.testing.assert_array_equal(channels["depth.V"][1], ref.aovs["depth"])
    np.testing.assert_array_equal(np.stack([channels[f"normal.{c}"][1] for c in "XYZ"], axis=-1),
                                  ref.aovs["normal"])
    np.testing.assert_array_equal(np.stack([channels[f"motion.{c}"][1] for c in "XY"], axis=-1),
                                  ref.aovs["motion"])
    ids = channels["object_id.V"][1]
    np.testing.assert_array_equal(ids, ref.aovs["object_id"].astype(np.float32))
    assert set(np.unique(ids)) == {-1.0, 0.0, 1.0}  # sky, the plane, the sphere
