"""Files a compositor and a notebook take as they are, read back with OpenEXR and Pillow.

* EXR: premultiplied RGBA (the background counted once by an "over"), the channel names
  compositors read (``Z`` camera-space depth, ``forward.u``/``forward.v`` motion with v up), the
  ids' name tables, OpenEXR's standard ``worldToCamera``/``worldToNDC`` checked against the
  renderer's own hits, half floats on request, and warprt's earlier layout still read.
* PNG (8 and 16 bits) and JPEG: the sRGB view with exposure, decoded independently.
* One sRGB curve (``warprt.linear_to_srgb`` / ``srgb_to_linear``) against IEC 61966-2-1.
* Results of one shape: ``save_image`` takes a RenderResult, the dict ``render`` returns, a
  batch frame or an array, with their metadata; each shows itself in a notebook (``_repr_png_``).

Renders use the feature sets other tests compile (``basic``, ``Features.full()``).
"""

from __future__ import annotations

import io
import json
import math
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

import warprt
from warprt import Features, read_exr, save_image
from warprt.cli import main

ROOT = Path(__file__).resolve().parents[1]
BACKGROUND = (0.2, 0.5, 0.8)


def read_channels(path) -> tuple[dict, dict]:
    """(header, {name: (pixel type, (H, W) array)}) straight from OpenEXR."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        header = dict(f.header())
        channels = {name: (c.type(), np.array(c.pixels)) for name, c in f.channels().items()}
    return header, channels


def ball_scene(background=BACKGROUND, width=16, height=12) -> warprt.Scene:
    """A lit sphere in the middle of the frame over a coloured background; the regular 2×2
    samples of the edge pixels split between sphere and background (coverage 1/4, 1/2, 3/4), in
    every pixel (uniform: adaptive counts would follow the background's contrast)."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 4), look_at=(0, 0, 0), fov=40, width=width, height=height),
        shapes=(warprt.Sphere(center=(0, 0, 0), radius=0.8, material="red"),),
        materials={"red": warprt.Material(kd=(0.7, 0.2, 0.1))},
        lights=(warprt.PointLight(position=(2, 3, 4), intensity=1.0),), ambient=0.05,
        background=background, render=warprt.RenderSettings(sampler="regular", spp=4, adaptive=False))


@pytest.fixture(scope="module")
def ball():
    """The ball over the coloured background and over black, with the same samples."""
    aovs = ["coverage", "object_id", "material"]
    coloured = warprt.Renderer(ball_scene(), device="cpu").render(progress=False, aovs=aovs)
    black = warprt.Renderer(ball_scene(background=(0, 0, 0)), device="cpu").render(progress=False, aovs=aovs)
    return coloured, black


# --- premultiplied RGBA ----------------------------------------------------------------------------


def test_rgba_is_premultiplied_and_an_over_counts_the_background_once(ball, tmp_path):
    """A = coverage; RGB = the light of the samples that hit alone: the same render over a black
    background (a miss adds the background, nothing else; a hit's light does not depend on it).
    Composited "over" the scene's own background the file gives the render back; over another
    plate the background is gone."""
    coloured, black = ball
    cov = coloured.aovs["coverage"]
    assert ((cov > 0) & (cov < 1)).sum() >= 8 and (cov == 0).sum() >= 8 and (cov == 1).sum() >= 8
    path = tmp_path / "ball.exr"
    save_image(coloured, path)
    header, ch = read_channels(path)
    rgb = np.stack([ch[c][1] for c in "RGB"], axis=-1)
    alpha = ch["A"][1]
    np.testing.assert_array_equal(alpha, cov)
    # float32 rounding of the film's sums and of the subtraction: a few ulps of the values
    np.testing.assert_allclose(rgb, black.image, rtol=0, atol=4e-7)
    assert (rgb[cov == 0] == 0).all()  # nothing hit: nothing there, exactly
    over_background = rgb + (1 - alpha[..., None]) * np.float32(BACKGROUND)
    np.testing.assert_allclose(over_background, coloured.image, rtol=0, atol=4e-7)
    plate = np.float32((0.0, 1.0, 0.0))
    over_plate = rgb + (1 - alpha[..., None]) * plate
    np.testing.assert_allclose(over_plate[cov == 0], np.broadcast_to(plate, over_plate[cov == 0].shape), atol=0)
    np.testing.assert_allclose(header["warprt_background"], BACKGROUND, rtol=1e-7)
    assert header["warprt_exr_layout"] == 2


def test_read_exr_gives_the_render_back_from_a_premultiplied_file(ball, tmp_path):
    coloured, _ = ball
    save_image(coloured, tmp_path / "ball.exr")
    rgb, _, layers = read_exr(tmp_path / "ball.exr", layers=True)
    np.testing.assert_allclose(rgb, coloured.image, rtol=0, atol=4e-7)
    full = coloured.aovs["coverage"] == 1
    np.testing.assert_array_equal(rgb[full], coloured.image[full])  # nothing added where covered
    np.testing.assert_array_equal(layers["coverage"], coloured.aovs["coverage"])
    np.testing.assert_array_equal(layers["object_id"], coloured.aovs["object_id"])


def test_a_black_background_leaves_the_colour_bit_for_bit(ball, tmp_path):
    _, black = ball
    save_image(black, tmp_path / "b.exr")
    _, ch = read_channels(tmp_path / "b.exr")
    np.testing.assert_array_equal(np.stack([ch[c][1] for c in "RGB"], axis=-1), black.image)
    np.testing.assert_array_equal(read_exr(tmp_path / "b.exr")[0], black.image)


def test_the_dict_render_returns_saves_like_the_result(tmp_path):
    """``warprt.render(..., aovs=[...])`` still returns a dict (equal to the plain one), and it
    carries the result's spp and metadata: save_image premultiplies it the same way."""
    scene = ball_scene()
    layers = warprt.render(scene, aovs=["coverage"], progress=False, device="cpu")
    assert isinstance(layers, dict) and set(layers) == {"color", "coverage"}
    assert layers.spp == 4 and layers.image is layers["color"] and set(layers.aovs) == {"coverage"}
    save_image(layers, tmp_path / "d.exr")
    result = warprt.Renderer(scene, device="cpu").render(aovs=["coverage"], progress=False)
    save_image(result, tmp_path / "r.exr")
    (_, a), (_, b) = read_channels(tmp_path / "d.exr"), read_channels(tmp_path / "r.exr")
    for c in "RGBA":
        np.testing.assert_array_equal(a[c][1], b[c][1])
    # a plain dict has no background to take out: its colour is written as it is
    save_image({"color": result.image, "coverage": result.aovs["coverage"]}, tmp_path / "p.exr")
    _, plain = read_channels(tmp_path / "p.exr")
    np.testing.assert_array_equal(plain["R"][1], result.image[..., 0])


# --- channel names and their values ----------------------------------------------------------------


W, H, DIST, FOV, SHIFT = 8, 6, 3.0, 40.0, 0.3


def facing(camera_end=None, eye=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0)) -> warprt.Scene:
    """test_aov_exr's scene: a rectangle at z = -DIST covering x < 0 (shapes[1], material m),
    seen from a pinhole, with one regular sample (the pixel centre, at mid-shutter)."""
    cam = dict(eye=eye, look_at=look_at, fov=FOV, width=W, height=H)
    if camera_end is not None:
        cam.update(eye_end=camera_end[0], look_at_end=camera_end[1], shutter=(0.0, 1.0))
    return warprt.Scene(
        camera=warprt.Camera(**cam),
        shapes=(warprt.Sphere(center=(0, 0, 5), radius=0.5, material="unused"),
                warprt.Rectangle(corner=(-10, -10, -DIST), edge1=(10, 0, 0), edge2=(0, 20, 0), material="m")),
        materials={"unused": warprt.Material(kd=0.9), "m": warprt.Material(kd=(0.2, 0.4, 0.6))},
        lights=(warprt.PointLight(position=(0, 0, 0), intensity=1.0),),
        render=warprt.RenderSettings(sampler="regular", spp=1))


def render_full(scene, aovs):
    return warprt.Renderer(scene, device="cpu", features=Features.full()).render(spp=1, progress=False, aovs=aovs)


def test_depth_is_z_and_the_ray_distance_is_distance_v(tmp_path):
    """``Z`` holds the camera-space depth (the ``z`` AOV: DIST for the facing rectangle, as
    compositors take depth), ``distance.V`` the distance along the ray (``depth``)."""
    r = render_full(facing(), ["depth", "z"])
    save_image(r, tmp_path / "d.exr")
    _, ch = read_channels(tmp_path / "d.exr")
    assert {"Z", "distance.V"} <= set(ch) and "z.V" not in ch and "depth.V" not in ch
    np.testing.assert_array_equal(ch["Z"][1], r.aovs["z"])
    np.testing.assert_array_equal(ch["distance.V"][1], r.aovs["depth"])
    hit = np.isfinite(r.aovs["z"])
    np.testing.assert_allclose(ch["Z"][1][hit], DIST, rtol=2.0 ** -21)
    assert (ch["distance.V"][1][hit] > ch["Z"][1][hit] * (1 + 1e-3)).any()  # off-axis: further along the ray


def test_motion_is_nukes_forward_layer_with_v_up(tmp_path):
    """The camera rises by SHIFT over the shutter: a static point moves down the image by
    SHIFT / DIST / (2·top) · H pixels (the array's y runs down); ``forward.v`` (v up) holds the
    negative of that, ``forward.u`` the x motion (0 here)."""
    r = render_full(facing(camera_end=((0.0, SHIFT, 0.0), (0.0, SHIFT, -1.0))), ["motion", "coverage"])
    save_image(r, tmp_path / "m.exr")
    _, ch = read_channels(tmp_path / "m.exr")
    assert {"forward.u", "forward.v"} <= set(ch) and "motion.X" not in ch
    hit = r.aovs["coverage"] == 1
    top = math.tan(math.radians(FOV / 2))
    down = SHIFT / DIST / (2 * top) * H
    np.testing.assert_allclose(r.aovs["motion"][..., 1][hit], down, rtol=2.0 ** -20)
    np.testing.assert_array_equal(ch["forward.v"][1], -r.aovs["motion"][..., 1])
    np.testing.assert_array_equal(ch["forward.u"][1], r.aovs["motion"][..., 0])
    np.testing.assert_allclose(ch["forward.v"][1][hit], -down, rtol=2.0 ** -20)
    _, _, layers = read_exr(tmp_path / "m.exr", layers=True)
    np.testing.assert_array_equal(layers["motion"], r.aovs["motion"])  # y down again


def test_ids_carry_a_name_table(tmp_path):
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 1, 4), look_at=(0, 0.5, 0), width=12, height=8),
        shapes=(warprt.Plane(material="floor"), warprt.Sphere(center=(0, 0.5, 0), radius=0.5, material="ball")),
        materials={"floor": warprt.Material(kd=0.5), "ball": warprt.Material(kd=(0.8, 0.3, 0.1))},
        lights=(warprt.PointLight(position=(2, 3, 2)),
                warprt.RectLight(corner=(-0.3, 2, -0.3), edge1=(0.6, 0, 0), edge2=(0, 0, 0.6), radiance=2.0)))
    r = warprt.Renderer(scene, device="cpu", features=Features.full()).render(spp=1, progress=False,
                                                                            aovs=["object_id", "material"])
    save_image(r, tmp_path / "ids.exr")
    header, ch = read_channels(tmp_path / "ids.exr")
    objects = json.loads(header["warprt_object_id_names"])
    materials = json.loads(header["warprt_material_names"])
    assert objects == {"0": "(nothing)", "1": "shapes[0] plane", "2": "shapes[1] sphere",
                       "4": "lights[1] rectangle light"}
    assert materials == {"0": "(nothing)", "1": "floor", "2": "ball", "3": "default"}
    assert set(np.unique(ch["object_id"][1])) <= {int(k) for k in objects}
    assert {1, 2} <= set(np.unique(ch["object_id"][1]))
    names = np.vectorize(lambda v: objects[str(v)])(ch["object_id"][1])
    assert (names[r.aovs["object_id"] == 1] == "shapes[1] sphere").all()
    # a file without id channels carries no tables
    save_image(r.image, tmp_path / "plain.exr")
    assert "warprt_object_id_names" not in read_channels(tmp_path / "plain.exr")[0]


# --- the camera in the header ----------------------------------------------------------------------


@pytest.mark.parametrize("optics", [dict(fov=40), dict(fx=30.0, fy=33.0, cx=0.3 * W, cy=0.65 * H)],
                         ids=["fov", "intrinsics off centre"])
def test_world_to_camera_and_ndc_follow_openexr_and_place_every_hit_in_its_pixel(tmp_path, optics):
    """OpenEXR's worldToCamera and worldToNDC (Imath: row vector times matrix): the visible point
    of each pixel (the position AOV, from the renderer's own hits) lands in camera space at the
    renderer's own camera-space depth (the z AOV) and in NDC at its pixel's centre, ((i + 0.5) /
    W, (j + 0.5) / H), y down; the eye is the origin and the look-at point in front (z > 0). The
    same for a camera from intrinsics whose principal point is off centre."""
    eye, look = (1.0, 2.0, 3.0), (-0.5, -1.0, -1.0)
    scene = warprt.Scene(camera=warprt.Camera(eye=eye, look_at=look, width=W, height=H, **optics),
                         shapes=(warprt.Plane(point=(0, -1, 0), normal=(0, 1, 0)),),
                         render=warprt.RenderSettings(sampler="regular", spp=1))
    r = render_full(scene, ["position", "z", "coverage"])
    assert (r.aovs["coverage"] == 1).all()
    save_image(r, tmp_path / "cam.exr")
    header, _ = read_channels(tmp_path / "cam.exr")
    to_camera, to_ndc = header["worldToCamera"], header["worldToNDC"]
    assert to_camera.shape == (4, 4) and to_camera.dtype == np.float32 and to_ndc.shape == (4, 4)
    np.testing.assert_allclose(np.array([*eye, 1.0]) @ to_camera, (0, 0, 0, 1), atol=1e-6)
    front = np.array([*look, 1.0]) @ to_camera
    np.testing.assert_allclose(front[:3], (0, 0, np.linalg.norm(np.subtract(look, eye))), atol=1e-5)
    rot = to_camera[:3, :3].astype(np.float64)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-6)
    assert np.linalg.det(rot) < 0  # (a right-handed world into OpenEXR's left-handed camera space)
    p = np.concatenate([r.aovs["position"].astype(np.float64), np.ones((H, W, 1))], axis=-1)
    cam = p @ to_camera
    np.testing.assert_allclose(cam[..., 2], r.aovs["z"], rtol=1e-5)
    ndc = p @ to_ndc
    ndc = ndc[..., :2] / ndc[..., 3:]
    centres = np.stack(np.meshgrid((np.arange(W) + 0.5) / W, (np.arange(H) + 0.5) / H), axis=-1)
    np.testing.assert_allclose(ndc, centres, atol=1e-5)
    # x right and y up in camera space: the right column is further right, the top row higher
    assert (cam[:, -1, 0] > cam[:, 0, 0]).all() and (cam[0, :, 1] / cam[0, :, 2] > cam[-1, :, 1] / cam[-1, :, 2]).all()


def test_a_batch_frame_carries_its_own_cameras_matrices(tmp_path):
    """Camera c of a batch is its pose array's camera: its frame's matrices equal those of a
    single render through the same camera."""
    scene = ball_scene()
    batch = warprt.BatchRenderer(scene, worlds=2, cameras=2, device="cpu")
    other = warprt.Camera(eye=(1.5, 0.5, 3.5), look_at=(0, 0, 0), fov=40, width=16, height=12)
    from warprt.worlds import camera_quaternion

    pose = np.concatenate([other.eye, camera_quaternion(other.eye, other.look_at, other.up)])
    poses = batch.camera_poses.numpy()
    poses[:, 1] = pose
    batch.set_camera_poses(poses)
    result = batch.render(spp=1, seed=3, aovs=["object_id"])
    frame = result.frame(1, 1)
    single = warprt.Renderer(scene.replace(camera=other), device="cpu").render(spp=1, progress=False)
    for key in ("worldToCamera", "worldToNDC"):
        np.testing.assert_allclose(frame.metadata[key], single.metadata[key], atol=2e-6)
        assert not np.allclose(result.frame(1, 0).metadata[key], single.metadata[key], atol=1e-3)
    assert frame.metadata["warprt_seed"] == 3 and frame.metadata["warprt_world"] == 1 and frame.spp == 1
    np.testing.assert_array_equal(frame.image, result.numpy()[1, 1])
    np.testing.assert_array_equal(frame.aovs["object_id"], result.aovs_numpy()["object_id"][1, 1])
    save_image(frame, tmp_path / "f.exr")
    header, ch = read_channels(tmp_path / "f.exr")
    np.testing.assert_array_equal(header["worldToNDC"], frame.metadata["worldToNDC"])
    assert "warprt_object_id_names" in header and "object_id" in ch
    with pytest.raises(warprt.RenderError, match=r"2 worlds x 2 cameras.*frame\(world, camera\)"):
        save_image(result, tmp_path / "all.exr")
    with pytest.raises(warprt.RenderError, match="world must be an integer index below 2"):
        result.frame(2, 0)
    assert result.image is result.color and result.metadata["warprt_spp"] == 1
    grid = Image.open(io.BytesIO(result._repr_png_()))
    assert grid.size == (2 * 16 + 2, 2 * 12 + 2)
    one = warprt.BatchRenderer(scene, device="cpu").render(spp=1)  # a batch of one image saves as it is
    save_image(one, tmp_path / "one.exr")
    np.testing.assert_array_equal(read_exr(tmp_path / "one.exr")[0], one.numpy()[0, 0])


# --- half floats -------------------------------------------------------------------------------------


def test_half_float_exr_on_request(tmp_path):
    """``bits=16``: colour, alpha, normals, albedo and motion as HALF (each value float16's
    rounding of the float32 one, beyond 65504 clipped), camera-space depth, ray distance and
    positions kept FLOAT, ids UINT."""
    r = render_full(facing(), ["coverage", "z", "depth", "position", "normal", "albedo", "motion", "object_id"])
    image = r.image.copy()
    image[0, 0] = (1e6, 0.1, 3.0)
    save_image({"color": image, **r.aovs}, tmp_path / "h.exr", bits=16)
    _, ch = read_channels(tmp_path / "h.exr")
    half = {"R", "G", "B", "A", "N.X", "N.Y", "N.Z", "albedo.R", "albedo.G", "albedo.B", "forward.u", "forward.v"}
    full = {"Z", "distance.V", "P.X", "P.Y", "P.Z"}
    assert set(ch) == half | full | {"object_id"}
    for name, (ptype, pixels) in ch.items():
        expected = OpenEXR.HALF if name in half else OpenEXR.UINT if name == "object_id" else OpenEXR.FLOAT
        assert ptype == expected, name
    np.testing.assert_array_equal(ch["G"][1], image[..., 1].astype(np.float16))
    assert ch["R"][1][0, 0] == np.float16(65504)
    np.testing.assert_array_equal(ch["Z"][1], r.aovs["z"])
    back, _, layers = read_exr(tmp_path / "h.exr", layers=True)
    assert back.dtype == np.float32 and layers["normal"].dtype == np.float32
    np.testing.assert_allclose(layers["normal"], r.aovs["normal"], atol=2.0 ** -11)


# --- PNG, 16-bit PNG, JPEG ---------------------------------------------------------------------------


def srgb(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1's encoding in float64, on values clipped to [0, 1]."""
    x = np.clip(np.asarray(x, np.float64), 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def decode_png16(path) -> tuple[np.ndarray, dict]:
    """A 16-bit RGB PNG decoded by the PNG specification (chunks, zlib, the five row filters),
    independently of the writer: (H, W, 3) uint16 and the tEXt chunks."""
    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, text, ihdr = 8, b"", {}, None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        assert struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])[0] == zlib.crc32(kind + body)
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        elif kind == b"tEXt":
            k, v = body.split(b"\0", 1)
            text[k.decode("latin-1")] = v.decode("latin-1")
        pos += 12 + n
    w, h, depth, colour_type, _, _, interlace = ihdr
    assert (depth, colour_type, interlace) == (16, 2, 0)
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 6 * w)
    bpp, out, prev = 6, np.zeros((h, 6 * w), np.int64), np.zeros(6 * w, np.int64)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int64)
        row = np.zeros(6 * w, np.int64)
        for x in range(6 * w):
            a = row[x - bpp] if x >= bpp else 0
            c = prev[x - bpp] if x >= bpp else 0
            b = prev[x]
            pred = {0: 0, 1: a, 2: b, 3: (a + b) // 2}.get(int(f))
            if f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            row[x] = (line[x] + pred) & 0xFF
        out[y], prev = row, row
    pixels = (out[:, 0::2] << 8 | out[:, 1::2]).reshape(h, w, 3).astype(np.uint16)
    return pixels, text


def ramp(width=257) -> np.ndarray:
    x = np.linspace(0, 1.2, width, dtype=np.float32)
    x[3] = 0.0031308  # the knee of the curve
    return np.stack([x, x[::-1], np.full_like(x, 0.18)], axis=-1)[None].repeat(3, axis=0)


def test_png_16_bit_holds_the_srgb_curve_in_16_bits(tmp_path):
    image = ramp()
    save_image(image, tmp_path / "a.png", bits=16, metadata={"note": "ramp"})
    pixels, text = decode_png16(tmp_path / "a.png")
    expected = np.round(srgb(image) * 65535).astype(np.int64)
    assert np.abs(pixels.astype(np.int64) - expected).max() <= 1  # float32 input: one level at most
    assert (pixels.astype(np.int64) == expected).mean() > 0.99
    assert pixels.max() == 65535 and pixels.min() == 0 and text["note"] == "ramp"
    with Image.open(tmp_path / "a.png") as im:  # Pillow reads it (as 8 bits: the high bytes)
        assert im.size == (257, 3) and im.info.get("note") == "ramp"
        np.testing.assert_array_equal(np.asarray(im.convert("RGB")), (pixels >> 8).astype(np.uint8))
    # 8 and 16 bits are the same curve: within half an 8-bit level of each other
    save_image(image, tmp_path / "b.png")
    eight = np.asarray(Image.open(tmp_path / "b.png")).astype(np.float64) / 255
    assert np.abs(eight - pixels / 65535).max() <= 0.5 / 255 + 1e-6


def test_jpeg_through_pillow_with_its_metadata(tmp_path):
    """A JPEG is the 8-bit sRGB view (quality 95, no chroma subsampling: a smooth image comes
    back within a level on average), with the result's metadata as a JSON comment."""
    r = warprt.Renderer(ball_scene(), device="cpu").render(progress=False)
    save_image(r, tmp_path / "a.jpg")
    save_image(r, tmp_path / "a.jpeg", exposure=1.0)
    with Image.open(tmp_path / "a.jpg") as im:
        assert im.format == "JPEG" and im.mode == "RGB" and im.size == (16, 12)
        meta = json.loads(im.info["comment"])
    assert meta["warprt_spp"] == "4" and json.loads(meta["worldToCamera"])[3][2] == pytest.approx(4.0)
    with Image.open(tmp_path / "a.jpeg") as im:
        assert json.loads(im.info["comment"])["warprt_exposure"] == "1.0"
    y, x = np.mgrid[0:48, 0:64] / 64.0
    smooth = np.stack([x, y, 0.5 * (x + y)], axis=-1).astype(np.float32) * 0.6  # (below 1 after exposure)
    save_image(smooth, tmp_path / "s.jpg", exposure=0.5)
    pixels = np.asarray(Image.open(tmp_path / "s.jpg")).astype(int)
    error = np.abs(pixels - np.round(srgb(smooth * 2 ** 0.5) * 255))
    assert error.mean() < 1.0 and error.max() <= 8  # measured: mean 0.63, max 6 (the dark corner)
    with pytest.raises(warprt.RenderError, match="8 bits per channel"):
        save_image(r, tmp_path / "b.jpg", bits=16)
    assert not (tmp_path / "b.jpg").exists()


def test_exposure_scales_display_outputs_and_leaves_the_exr(tmp_path):
    """``exposure`` e multiplies by 2^e before the curve (here exactly: a float32 times 2 is
    exact), in PNG and JPEG alike; an EXR keeps the radiance."""
    image = ramp()
    save_image(image, tmp_path / "e.png", exposure=1.0)
    save_image(image * 2, tmp_path / "x2.png")
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "e.png")), np.asarray(Image.open(tmp_path / "x2.png")))
    save_image(image, tmp_path / "d.png", exposure=-2.0, bits=16)
    np.testing.assert_array_equal(decode_png16(tmp_path / "d.png")[0], np.round(srgb(image / 4) * 65535))
    save_image(image, tmp_path / "e.exr", exposure=3.0)
    np.testing.assert_array_equal(read_exr(tmp_path / "e.exr")[0], image)
    for bad in (float("nan"), "1", True):
        with pytest.raises(warprt.RenderError, match="exposure"):
            save_image(image, tmp_path / "bad.png", exposure=bad)
    with pytest.raises(warprt.RenderError, match="bits must be 16 or 32"):
        save_image(image, tmp_path / "bad.exr", bits=8)
    with pytest.raises(warprt.RenderError, match="bits must be 8 or 16"):
        save_image(image, tmp_path / "bad.png", bits=32)


# --- the sRGB curve --------------------------------------------------------------------------------


@pytest.mark.parametrize("linear, encoded", [
    (0.0, 0.0), (1.0, 1.0), (0.0031308, 12.92 * 0.0031308), (0.5, 1.055 * 0.5 ** (1 / 2.4) - 0.055),
    (0.18, 1.055 * 0.18 ** (1 / 2.4) - 0.055), (0.001, 0.01292), (2.0, 1.0), (-1.0, 0.0),
])
def test_linear_to_srgb_and_back(linear, encoded):
    assert warprt.linear_to_srgb(linear) == pytest.approx(encoded, rel=1e-12, abs=1e-15)
    if 0 <= linear <= 1:
        assert warprt.srgb_to_linear(encoded) == pytest.approx(linear, rel=1e-12, abs=1e-15)


def test_the_srgb_curves_are_inverse_continuous_and_keep_float32():
    x = np.linspace(0, 1, 100001)
    np.testing.assert_allclose(warprt.srgb_to_linear(warprt.linear_to_srgb(x)), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(warprt.srgb_to_linear(x), ((x + 0.055) / 1.055) ** 2.4 * (x > 0.04045)
                               + x / 12.92 * (x <= 0.04045), rtol=1e-12, atol=0)
    assert abs(warprt.linear_to_srgb(0.0031308 + 1e-12) - warprt.linear_to_srgb(0.0031308)) < 1e-7  # continuous knee
    f = np.linspace(0, 1, 1001, dtype=np.float32)
    assert warprt.linear_to_srgb(f).dtype == np.float32 and warprt.srgb_to_linear(f).dtype == np.float32
    np.testing.assert_allclose(warprt.linear_to_srgb(f), srgb(f), atol=2e-7)
    np.testing.assert_allclose(warprt.linear_to_srgb(np.array([np.nan, np.inf, -np.inf])), [0.0, 1.0, 0.0], atol=1e-15)


def test_the_srgb_curve_is_written_once():
    """Every sRGB conversion of the package goes through warprt.colour (the PNG writer, the
    Newton bridge's colours, glTF textures): its constants appear nowhere else."""
    sources = [p for p in (ROOT / "warprt").rglob("*.py") if p.name != "colour.py"]
    offenders = [p.relative_to(ROOT).as_posix() for p in sources if "12.92" in p.read_text() or "0.04045" in p.read_text()]
    assert offenders == []


# --- results in notebooks --------------------------------------------------------------------------


def test_results_show_themselves_in_notebooks(ball):
    coloured, _ = ball
    png = coloured._repr_png_()
    with Image.open(io.BytesIO(png)) as im:
        assert im.format == "PNG" and im.size == (16, 12)
        np.testing.assert_array_equal(np.asarray(im), warprt.image.linear_to_srgb8(coloured.image))
    layers = warprt.results.RenderLayers({"color": coloured.image}, coloured)
    assert layers._repr_png_() == png


# --- warprt's earlier EXR layout ---------------------------------------------------------------------


def test_the_earlier_layout_is_still_read(tmp_path):
    """A file of warprt's earlier layout (no warprt_exr_layout: Z the ray distance, z.V the
    camera-space depth, motion.X/Y with y down, RGB not premultiplied) reads as it was written."""
    rng = np.random.default_rng(0)
    rgb = rng.random((3, 4, 3)).astype(np.float32)
    depth, z, cov = (rng.random((3, 4)).astype(np.float32) for _ in range(3))
    motion = rng.normal(size=(3, 4, 2)).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "warprt_spp": 4}
    channels = {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2], "A": cov, "Z": depth, "z.V": z,
                "motion.X": motion[..., 0], "motion.Y": motion[..., 1], "object_id": np.full((3, 4), 3, np.uint32)}
    channels = {k: np.ascontiguousarray(v) for k, v in channels.items()}  # (OpenEXR takes contiguous arrays)
    with OpenEXR.File(header, channels) as f:
        f.write(str(tmp_path / "old.exr"))
    back, head, layers = read_exr(tmp_path / "old.exr", layers=True)
    np.testing.assert_array_equal(back, rgb)
    np.testing.assert_array_equal(layers["depth"], depth)
    np.testing.assert_array_equal(layers["z"], z)
    np.testing.assert_array_equal(layers["motion"], motion)
    np.testing.assert_array_equal(layers["coverage"], cov)
    assert (layers["object_id"] == 2).all() and head["warprt_spp"] == 4


# --- the command line ------------------------------------------------------------------------------


CLI_SCENE = """\
[camera]
eye = [0, 0, 4]
look_at = [0, 0, 0]
fov = 40
width = 16
height = 12

[world]
background = [0.2, 0.5, 0.8]

[materials.red]
kd = [0.7, 0.2, 0.1]

[[shapes]]
type = "sphere"
radius = 0.8
material = "red"

[[lights]]
type = "point"
position = [2, 3, 4]
"""


def test_cli_writes_jpeg_16_bit_png_half_exr_and_exposure(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(CLI_SCENE)
    outs = [tmp_path / n for n in ("a.exr", "a.png", "a.jpg")]
    code = main(["render", str(scene), *sum((["-o", str(o)] for o in outs), []), "--spp", "2", "--exposure", "1",
                 "--aovs", "coverage,z", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    ref = warprt.Renderer(warprt.load_scene(scene)).render(spp=2, progress=False, aovs=["coverage", "z"])
    header, ch = read_channels(outs[0])
    np.testing.assert_array_equal(ch["A"][1], ref.aovs["coverage"])
    np.testing.assert_array_equal(ch["Z"][1], ref.aovs["z"])
    assert "worldToCamera" in header and header["warprt_spp"] == 2
    np.testing.assert_array_equal(read_exr(outs[0])[0][ref.aovs["coverage"] == 1],
                                  ref.image[ref.aovs["coverage"] == 1])  # no exposure in the EXR
    np.testing.assert_array_equal(np.asarray(Image.open(outs[1])), warprt.image.linear_to_srgb8(ref.image * 2))
    assert Image.open(outs[2]).format == "JPEG"
    code = main(["render", str(scene), "-o", str(tmp_path / "h.exr"), "-o", str(tmp_path / "h.png"), "--bits", "16",
                 "--spp", "2", "--no-progress"])
    assert code == 0
    assert read_channels(tmp_path / "h.exr")[1]["R"][0] == OpenEXR.HALF
    np.testing.assert_array_equal(decode_png16(tmp_path / "h.png")[0], np.round(srgb(ref.image) * 65535))
    capsys.readouterr()
    code = main(["render", str(scene), "-o", str(tmp_path / "x.png"), "-o", str(tmp_path / "x.jpg"), "--bits", "16",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "x.jpg" in err and "8 bits" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()  # refused before rendering
