"""Image output: float32 linear EXR with metadata, 8-bit sRGB PNG, shape checks, atomic writes."""

from __future__ import annotations

import os
from pathlib import Path
import stat

import numpy as np
import OpenEXR
import pytest
from PIL import Image

import warprt
from warprt import RenderError, read_exr, save_image
from warprt.errors import WriteError
from warprt import image as image_module


def srgb8(x: float) -> int:
    """The sRGB transfer curve of a linear value in [0, 1], rounded to 8 bits (IEC 61966-2-1)."""
    s = 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055
    return int(np.floor(s * 255 + 0.5))


def random_image(h=5, w=7, scale=10.0, seed=0):
    return (np.random.default_rng(seed).random((h, w, 3)) * scale).astype(np.float32)


# --- EXR ---------------------------------------------------------------------------------------


def test_exr_round_trip_is_exact_float32_including_values_above_one(tmp_path):
    a = random_image()
    a[0, 0] = (1e6, 1.0 + 2 ** -23, 0.0)
    a[1, 1] = (-0.5, 3.4e38, 1e-40)  # negative, near float32 max, subnormal
    path = tmp_path / "a.exr"
    save_image(a, path)
    b, header = read_exr(path)
    assert b.dtype == np.float32 and b.shape == a.shape
    np.testing.assert_array_equal(b, a)
    assert (b > 1).any()


def test_exr_stores_full_float_channels_r_g_b(tmp_path):
    path = tmp_path / "a.exr"
    save_image(random_image(3, 4), path)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        channels = f.channels()
        assert set(channels) == {"R", "G", "B"}
        for c in channels.values():
            assert c.type() == OpenEXR.FLOAT and c.pixels.shape == (3, 4)
    # row 0 is the top of the image, column 0 the left (the data window is width x height)
    a = np.zeros((3, 4, 3), np.float32)
    a[0, 3] = (1, 2, 3)
    save_image(a, path)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        assert ch["R"].pixels[0, 3] == 1 and ch["G"].pixels[0, 3] == 2 and ch["B"].pixels[0, 3] == 3
        assert ch["R"].pixels.sum() == 1


def test_exr_float64_input_is_stored_as_float32(tmp_path):
    a = np.random.default_rng(1).random((4, 4, 3))  # float64
    save_image(a, tmp_path / "a.exr")
    b, _ = read_exr(tmp_path / "a.exr")
    np.testing.assert_array_equal(b, a.astype(np.float32))


def test_exr_metadata_goes_in_the_header(tmp_path):
    meta = {"warprt_spp": 16, "warprt_seed": 7, "note": "lecture 3", "exposure": 1.5,
            "warprt_interrupted": False, "tags": ["a", "b"]}
    save_image(random_image(), tmp_path / "a.exr", metadata=meta)
    _, header = read_exr(tmp_path / "a.exr")
    assert header["warprt_spp"] == 16 and header["warprt_seed"] == 7
    assert header["note"] == "lecture 3"
    assert header["exposure"] == pytest.approx(1.5)
    assert header["warprt_interrupted"] == 0  # booleans become integers
    assert header["tags"] == str(["a", "b"])  # anything else becomes its string
    assert tuple(header["dataWindow"][1]) == (6, 4)  # (x max, y max) = (width - 1, height - 1)


def test_grey_and_rgba_images(tmp_path):
    grey = np.arange(12, dtype=np.float32).reshape(3, 4)
    save_image(grey, tmp_path / "g.exr")
    g, _ = read_exr(tmp_path / "g.exr")
    assert g.shape == (3, 4, 3)
    for c in range(3):
        np.testing.assert_array_equal(g[:, :, c], grey)
    rgba = np.concatenate([random_image(3, 4), np.full((3, 4, 1), 0.25, np.float32)], axis=2)
    save_image(rgba, tmp_path / "rgba.exr")
    np.testing.assert_array_equal(read_exr(tmp_path / "rgba.exr")[0], rgba[:, :, :3])


# --- PNG ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("linear, expected", [
    (0.0, 0), (1.0, 255), (0.5, 188), (0.18, 118), (0.0031308, 10), (0.001, 3), (0.2, 124),
    (1.0001, 255), (7.5, 255), (1e30, 255), (np.inf, 255), (-0.3, 0), (-np.inf, 0), (np.nan, 0),
])
def test_png_is_srgb_encoded_and_clamped(tmp_path, linear, expected):
    if np.isfinite(linear) and 0 <= linear <= 1:
        assert srgb8(linear) == expected  # the table agrees with the sRGB formula
    a = np.full((2, 3, 3), linear, np.float32)
    save_image(a, tmp_path / "a.png")
    with Image.open(tmp_path / "a.png") as im:
        assert im.format == "PNG" and im.mode == "RGB" and im.size == (3, 2)
        px = np.asarray(im)
    assert px.dtype == np.uint8
    assert (px == expected).all(), (linear, px[0, 0])


def test_png_encodes_every_8_bit_level_like_the_srgb_formula(tmp_path):
    x = np.linspace(0, 1, 1021, dtype=np.float32)
    save_image(np.repeat(x[None, :, None], 3, axis=2), tmp_path / "ramp.png")
    px = np.asarray(Image.open(tmp_path / "ramp.png"))[0, :, 0].astype(int)
    expected = np.array([srgb8(float(v)) for v in x])
    assert np.abs(px - expected).max() <= 1  # rounding of values exactly between levels may differ
    assert (px == expected).mean() > 0.99
    assert (np.diff(px) >= 0).all() and px[0] == 0 and px[-1] == 255


def test_png_keeps_channels_and_orientation(tmp_path):
    a = np.zeros((4, 6, 3), np.float32)
    a[0, 5] = (1, 0, 0)  # top right red
    a[3, 0] = (0, 0, 1)  # bottom left blue
    a[1, 2] = (0.5, 0.5, 0.5)  # a NaN channel becomes 0, the others are kept
    a[2, 2] = (np.nan, 1.0, 0.5)
    save_image(a, tmp_path / "a.png")
    px = np.asarray(Image.open(tmp_path / "a.png"))
    assert px[0, 5].tolist() == [255, 0, 0] and px[3, 0].tolist() == [0, 0, 255]
    assert px[1, 2].tolist() == [188, 188, 188] and px[2, 2].tolist() == [0, 255, 188]
    assert px.sum() == 255 + 255 + 3 * 188 + (255 + 188)  # and nothing else is lit


def test_png_extension_is_case_insensitive(tmp_path):
    save_image(np.zeros((2, 2, 3)), tmp_path / "A.PNG")
    save_image(np.zeros((2, 2, 3)), tmp_path / "A.EXR")
    assert Image.open(tmp_path / "A.PNG").format == "PNG"
    assert read_exr(tmp_path / "A.EXR")[0].shape == (2, 2, 3)


# --- bad arguments --------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(5,), (2, 3, 2), (2, 3, 5), (2, 3, 1), (1, 2, 3, 3), (0, 4, 3), (4, 0, 3), (0, 0, 0)])
@pytest.mark.parametrize("ext", [".png", ".exr"])
def test_wrong_shapes_are_render_errors(tmp_path, shape, ext):
    path = tmp_path / f"a{ext}"
    with pytest.raises(RenderError, match=r"shape") as info:
        save_image(np.zeros(shape, np.float32), path)
    assert str(shape).replace(" ", "") in str(info.value).replace(" ", "")
    assert not path.exists() and list(tmp_path.iterdir()) == []


def test_non_numeric_images_are_render_errors(tmp_path):
    with pytest.raises(RenderError, match="numbers"):
        save_image(np.full((2, 2, 3), "x"), tmp_path / "a.png")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["a.tiff", "a", "a.exr.bak", "a.jpg2"])
def test_unsupported_formats_are_render_errors(tmp_path, name):
    with pytest.raises(RenderError, match=r"unsupported image format.*\.exr, \.png or \.jpg") as info:
        save_image(np.zeros((2, 2, 3)), tmp_path / name)
    assert name in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_a_missing_folder_is_a_render_error(tmp_path):
    with pytest.raises(RenderError, match="does not exist"):
        save_image(np.zeros((2, 2, 3)), tmp_path / "no" / "a.png")


# --- atomic writes ------------------------------------------------------------------------------------


def _png_writer_that_fails(exc):
    def save(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"\x89PNG\r\n\x1a\n truncated")  # half a file, then the failure
        raise exc
    return save


class _ExrFileThatFails:
    exc: BaseException = OSError("disk full")

    def __init__(self, header, channels):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def write(self, path):
        with open(path, "wb") as f:
            f.write(b"v/1\x01 truncated")
        raise self.exc


@pytest.mark.parametrize("exc", [OSError("disk full"), KeyboardInterrupt()], ids=["error", "ctrl-c"])
@pytest.mark.parametrize("ext", [".png", ".exr"])
@pytest.mark.parametrize("existing", [False, True], ids=["new", "replace"])
def test_a_failed_write_leaves_no_file_and_no_temp_file(tmp_path, monkeypatch, exc, ext, existing):
    path = tmp_path / f"out{ext}"
    old = random_image(3, 3, scale=1.0, seed=5)
    if existing:
        save_image(old, path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    if ext == ".png":
        monkeypatch.setattr(Image.Image, "save", _png_writer_that_fails(exc))
    else:
        monkeypatch.setattr(_ExrFileThatFails, "exc", exc)
        monkeypatch.setattr(OpenEXR, "File", _ExrFileThatFails)
    with pytest.raises(WriteError if isinstance(exc, OSError) else type(exc)) as info:  # (a named, one-line error)
        save_image(random_image(4, 4, seed=6), path)
    if isinstance(exc, OSError):
        assert str(info.value).startswith(f"{path}: cannot be written: disk full (") and info.value.path == str(path)
    monkeypatch.undo()
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert after == before  # nothing new (no temp file), an existing image byte for byte unchanged
    if existing:
        if ext == ".exr":
            np.testing.assert_array_equal(read_exr(path)[0], old)
        else:
            assert np.asarray(Image.open(path)).shape == (3, 3, 3)


def test_a_successful_write_replaces_the_file_and_leaves_no_temp_file(tmp_path):
    path = tmp_path / "out.exr"
    save_image(np.zeros((2, 2, 3)), path)
    save_image(np.ones((3, 5, 3)), path)
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]
    np.testing.assert_array_equal(read_exr(path)[0], np.ones((3, 5, 3), np.float32))


def test_the_temp_file_is_in_the_destination_folder(tmp_path, monkeypatch):
    """os.replace is atomic only within one file system: the temp file must sit next to the target."""
    seen = []
    real_replace = os.replace

    def spy(src, dst):
        seen.append((os.path.dirname(os.path.abspath(src)), os.path.abspath(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(image_module.os, "replace", spy)
    save_image(np.zeros((2, 2, 3)), tmp_path / "a.png")
    save_image(np.zeros((2, 2, 3)), tmp_path / "a.exr")
    assert seen == [(str(tmp_path), str(tmp_path / "a.png")), (str(tmp_path), str(tmp_path / "a.exr"))]


def test_save_image_writes_what_render_returns(tmp_path):
    scene = warprt.scene_from_string("""
        [camera]
        width = 12
        height = 8
        [world]
        ambient = 0.5
        [[shapes]]
        type = "sphere"
    """)
    image = warprt.render(scene, progress=False)
    save_image(image, tmp_path / "r.exr", metadata={"warprt_spp": 1})
    back, header = read_exr(tmp_path / "r.exr")
    np.testing.assert_array_equal(back, image)
    assert header["warprt_spp"] == 1 and back.max() == np.float32(0.8) * np.float32(0.5)


@pytest.mark.skipif(os.name != "posix", reason="POSIX file modes")
@pytest.mark.parametrize("ext", [".png", ".exr"])
def test_written_images_get_the_permissions_of_a_plain_open(tmp_path, ext):
    """The atomic write goes through a private temp file; the finished image must not stay
    0600 but get 0666 less the umask, like any file the user's tools create."""
    path = tmp_path / ("img" + ext)
    save_image(np.zeros((2, 3, 3), np.float32), path)
    probe = tmp_path / "probe"
    probe.write_bytes(b"")
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(probe.stat().st_mode)


# --- temporary files, modes and symbolic links ----------------------------------------------------


_KILLED_WRITER = """
import os, signal, sys
import numpy as np
import OpenEXR
from PIL import Image
from warprt import save_image

def half_then_kill(path):
    with open(path, "wb") as f:
        f.write(b"truncated image")
        f.flush()
    os.kill(os.getpid(), signal.SIGKILL)

class File:
    def __init__(self, header, channels):
        pass
    def __enter__(self):
        return self
    def __exit__(self, *exc):
        return False
    def write(self, path):
        half_then_kill(path)

OpenEXR.File = File
Image.Image.save = lambda self, fp, *a, **k: half_then_kill(fp)
save_image(np.zeros((2, 2, 3), np.float32), sys.argv[1])
"""


def _killed_during_write(path):
    import subprocess
    import sys

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                         *filter(None, [env.get("PYTHONPATH")])])
    p = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(path)], env=env, capture_output=True, timeout=120)
    assert p.returncode == -9, p.stderr


@pytest.mark.skipif(os.name != "posix", reason="SIGKILL")
@pytest.mark.parametrize("ext", [".exr", ".png"])
def test_a_write_killed_midway_leaves_no_file_matching_the_image_glob_and_the_next_write_cleans_up(tmp_path, ext):
    from fnmatch import fnmatch

    path = tmp_path / f"out{ext}"
    _killed_during_write(path)
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 1 and left[0].startswith(".out" + ext + ".")  # the truncated temporary file
    assert not [n for n in left if fnmatch(n, "*" + ext) or fnmatch(n, "*.exr") or fnmatch(n, "*.png")]
    # not ours, or of another output, or of a live process: kept
    others = [f".out{ext}.x.partial", f"out{ext}.bak", f".other{ext}.999999999.abcdefgh.partial",
              f".out{ext}.1.abcdefgh.partial", f".out{ext}.999999999.abcdefgh.partial.keep"]
    for name in others:
        (tmp_path / name).write_bytes(b"keep")
    save_image(np.ones((2, 2, 3), np.float32), path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([path.name, *others])


@pytest.mark.skipif(os.name != "posix", reason="POSIX file modes")
@pytest.mark.parametrize("ext", [".png", ".exr"])
@pytest.mark.parametrize("mode", [0o600, 0o640, 0o664])
def test_replacing_an_image_keeps_its_mode(tmp_path, ext, mode):
    path = tmp_path / ("img" + ext)
    save_image(np.zeros((2, 3, 3), np.float32), path)
    path.chmod(mode)
    save_image(np.ones((2, 3, 3), np.float32), path)
    assert stat.S_IMODE(path.stat().st_mode) == mode


@pytest.mark.skipif(os.name != "posix", reason="symbolic links")
@pytest.mark.parametrize("ext", [".png", ".exr"])
def test_writing_to_a_symbolic_link_writes_its_target(tmp_path, ext):
    (tmp_path / "store").mkdir()
    (tmp_path / "view").mkdir()
    target = tmp_path / "store" / ("real" + ext)
    save_image(np.zeros((2, 3, 3), np.float32), target)
    target.chmod(0o600)
    link = tmp_path / "view" / ("img" + ext)
    link.symlink_to(os.path.join("..", "store", "real" + ext))  # relative, resolved from the link's folder
    chain = tmp_path / ("chain" + ext)
    chain.symlink_to(link)
    for i, through in enumerate([link, chain, tmp_path / "view" / ".." / "view" / ("img" + ext)]):
        save_image(np.full((2, 3, 3), 0.25 * (i + 1), np.float32), through)
        assert link.is_symlink() and chain.is_symlink() and target.is_file() and not target.is_symlink()
        if ext == ".exr":
            np.testing.assert_array_equal(read_exr(target)[0], np.full((2, 3, 3), 0.25 * (i + 1), np.float32))
        assert stat.S_IMODE(target.stat().st_mode) == 0o600
        assert sorted(p.name for p in (tmp_path / "view").iterdir()) == [link.name]  # temp went next to the target
        assert sorted(p.name for p in (tmp_path / "store").iterdir()) == [target.name]
    dangling = tmp_path / ("dangling" + ext)
    dangling.symlink_to(tmp_path / "store" / ("new" + ext))
    save_image(np.zeros((2, 2, 3), np.float32), dangling)
    assert dangling.is_symlink() and (tmp_path / "store" / ("new" + ext)).is_file()


def test_png_metadata_goes_in_text_chunks(tmp_path):
    save_image(random_image(), tmp_path / "a.png", metadata={"warprt:partial": "true", "warprt_spp": 7, "flag": True})
    assert Image.open(tmp_path / "a.png").text == {"warprt:partial": "true", "warprt_spp": "7", "flag": "1"}
