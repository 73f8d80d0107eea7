"""The command line: ``warprt render SCENE -o OUT ...``, in-process through ``warprt.cli.main`` and
as a real ``python -m warprt`` subprocess."""

from __future__ import annotations

import os
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import warprt
from warprt.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]

SCENE = """\
# a small plain diffuse scene: one sphere on a plane, one point light
[camera]
eye = [0, 1, 4]
look_at = [0, 0.5, 0]
width = 24
height = 16

[render]
spp = 2

[world]
ambient = 0.05

[[shapes]]
type = "plane"

[[shapes]]
type = "sphere"
center = [0, 0.5, 0]
radius = 0.5

[[lights]]
type = "point"
position = [2, 3, 2]
"""

LAST_LINE = re.compile(
    r"^(?P<outs>.+): (?P<w>\d+)x(?P<h>\d+), (?P<spp>\d+) spp, render (?P<wall>\d+\.\d+) s "
    r"\(total \d+\.\d+ s, kernel load \d+\.\d+ s\), \d+\.\d+ Mrays, (?P<mrays>\d+\.\d+) Mrays/s on \S+$")


@pytest.fixture
def scene_file(tmp_path) -> pathlib.Path:
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def run(argv, capsys) -> tuple[int, str, str]:
    """main(argv) in this process: (exit code, stdout, stderr); argparse errors exit through SystemExit."""
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def render_ok(argv, capsys) -> re.Match:
    code, out, err = run([*argv, "--no-progress"], capsys)
    assert code == 0, err
    last = out.strip().splitlines()[-1]
    m = LAST_LINE.match(last)
    assert m, last
    return m


# --- success -----------------------------------------------------------------------------------------


def test_png_and_exr_written_with_the_scene_size(scene_file, tmp_path, capsys):
    png, exr = tmp_path / "out.png", tmp_path / "out.exr"
    m = render_ok(["render", str(scene_file), "-o", str(png), "-o", str(exr)], capsys)
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size == (24, 16) and im.mode == "RGB"
    rgb, header = warprt.read_exr(exr)
    assert rgb.shape == (16, 24, 3) and rgb.dtype == np.float32
    assert (m["w"], m["h"], m["spp"]) == ("24", "16", "2")
    assert m["outs"] == f"{png}, {exr}"
    assert float(m["wall"]) >= 0 and float(m["mrays"]) > 0
    assert header["warprt_spp"] == 2 and header["warprt_seed"] == 0 and header["warprt_interrupted"] == 0
    # the PNG is the sRGB encoding of the same image
    assert np.array_equal(np.asarray(Image.open(png)), warprt.image.linear_to_srgb8(rgb))


def test_exr_holds_the_linear_float_image_that_render_returns(scene_file, tmp_path, capsys):
    exr = tmp_path / "out.exr"
    render_ok(["render", str(scene_file), "-o", str(exr)], capsys)
    rgb, _ = warprt.read_exr(exr)
    expected = warprt.render(warprt.load_scene(scene_file), progress=False)
    np.testing.assert_array_equal(rgb, expected)
    assert rgb.max() > 0 and 0 < np.count_nonzero(rgb) < rgb.size  # lit pixels and a black sky


@pytest.mark.parametrize("args, camera, settings, spp, seed", [
    (["--width", "10", "--height", "6"], dict(width=10, height=6), {}, None, 0),
    (["--spp", "3"], {}, {}, 3, 0),
    (["--seed", "42"], {}, {}, None, 42),
    (["--sampler", "regular"], {}, dict(sampler="regular"), None, 0),
    (["--sampler", "independent", "--spp", "1", "--seed", "5", "--width", "9"],
     dict(width=9), dict(sampler="independent"), 1, 5),
])
def test_overrides_match_the_python_api(scene_file, tmp_path, capsys, args, camera, settings, spp, seed):
    exr = tmp_path / "out.exr"
    m = render_ok(["render", str(scene_file), "-o", str(exr), *args], capsys)
    scene = warprt.load_scene(scene_file)
    if camera:
        scene = scene.with_camera(**camera)
    if settings:
        scene = scene.with_settings(**settings)
    expected = warprt.render(scene, spp=spp, seed=seed, progress=False)
    rgb, header = warprt.read_exr(exr)
    np.testing.assert_array_equal(rgb, expected)
    assert header["warprt_spp"] == (spp or 2) and header["warprt_seed"] == seed
    assert int(m["spp"]) == (spp or 2) and (int(m["w"]), int(m["h"])) == (expected.shape[1], expected.shape[0])


def test_seed_and_sampler_change_the_noise(scene_file, tmp_path, capsys):
    images = {}
    for name, args in {"a": [], "b": ["--seed", "1"], "c": ["--sampler", "regular"]}.items():
        render_ok(["render", str(scene_file), "-o", str(tmp_path / f"{name}.exr"), *args], capsys)
        images[name] = warprt.read_exr(tmp_path / f"{name}.exr")[0]
    assert not np.array_equal(images["a"], images["b"])
    assert not np.array_equal(images["a"], images["c"])


def test_max_depth_override(tmp_path, capsys):
    """In the mirror scene, depth 0 stops reflections: the mirror sphere shows only its own shading."""
    exr0, exr = tmp_path / "d0.exr", tmp_path / "d.exr"
    scene_path = ROOT / "scenes" / "mirror.toml"
    common = ["render", str(scene_path), "--width", "16", "--height", "12", "--spp", "1"]
    render_ok([*common, "-o", str(exr0), "--max-depth", "0"], capsys)
    render_ok([*common, "-o", str(exr)], capsys)
    scene = warprt.load_scene(scene_path).with_camera(width=16, height=12)
    np.testing.assert_array_equal(warprt.read_exr(exr0)[0],
                                  warprt.render(scene.with_settings(max_depth=0), spp=1, progress=False))
    assert warprt.read_exr(exr)[0].sum() > warprt.read_exr(exr0)[0].sum()


def test_output_folder_is_created(scene_file, tmp_path, capsys):
    out = tmp_path / "new" / "dir" / "out.png"
    render_ok(["render", str(scene_file), "-o", str(out), "--width", "4", "--height", "4"], capsys)
    assert Image.open(out).size == (4, 4)


# --- failures: exit 2, one line, no output ---------------------------------------------------------------


BAD_SCENES = [
    ('[[shapes]]\ntype = "sphere"\nradius = "big"\n', "shapes[0].radius", "big"),
    ('[camera]\neye = [1, 2]\n', "camera.eye", "three numbers"),
    ('[camera]\nwidth = 0\n', "camera.width", ">= 1"),
    ('[camera]\nfov = 180\n', "camera.fov", "< 180"),
    ('[camera]\neye = [0, 0, 1e39]\n', "camera.eye[2]", "float32"),
    ('[camera]\ndistance = 1e-46\n', "camera.distance", "float32"),
    ('[materials.red]\ncolour = 1\n', "materials.red", "colour"),
    ('[[shapes]]\ntype = "sphere"\nmaterial = "gold"\n', "shapes[0].material", "gold"),
    ('[[lights]]\ntype = "spot"\n', "lights[0].type", "spot"),
    ('[[shapes]]\ntype = "mesh"\nfile = "missing.obj"\n', "shapes[0].file", "not found"),
    ('[[shapes]]\ntype = "mesh"\nfile = "nan.obj"\n', "shapes[0].vertices", "NaN"),
    ('[camera\n', None, "not valid TOML"),
]


@pytest.mark.parametrize("existing", [False, True], ids=["new", "existing"])
@pytest.mark.parametrize("text, field, problem", BAD_SCENES, ids=[b[1] or "toml" for b in BAD_SCENES])
def test_bad_scene_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, text, field, problem, existing):
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    scene = tmp_path / "bad.toml"
    scene.write_text(text)
    png, exr = tmp_path / "out.png", tmp_path / "out.exr"
    if existing:
        png.write_bytes(b"old png")
        exr.write_bytes(b"old exr")
    before = sorted(p.name for p in tmp_path.iterdir())
    code, out, err = run(["render", str(scene), "-o", str(png), "-o", str(exr), "--no-progress"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"warprt: error: {scene}: ")
    if field:
        assert f": {field}: " in lines[0]
    assert problem in lines[0]
    assert out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    if existing:
        assert png.read_bytes() == b"old png" and exr.read_bytes() == b"old exr"


def test_missing_scene_file(tmp_path, capsys):
    code, _, err = run(["render", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "a.png")], capsys)
    assert code == 2 and err.strip() == f"warprt: error: {tmp_path / 'nope.toml'}: scene file not found"
    assert list(tmp_path.iterdir()) == []


def test_a_huge_scene_warns_in_one_line(tmp_path, capsys):
    scene = tmp_path / "huge.toml"
    scene.write_text("[camera]\neye = [0, 0, 5e20]\nwidth = 8\nheight = 6\n"
                     "[[shapes]]\ntype = \"sphere\"\nradius = 1e20\n")
    code, out, err = run(["render", str(scene), "-o", str(tmp_path / "a.png"), "--no-progress"], capsys)
    assert code == 0
    assert err.strip().splitlines() == [
        f"warprt: warning: {scene}: scene coordinates reach 5e+20: beyond about 1e+19 the renderer's float32 "
        "squared distances overflow and surfaces or lights may vanish; scale the scene down"], err


def test_a_scene_file_that_is_not_utf8_exits_2_with_one_line(tmp_path, capsys):
    scene = tmp_path / "latin1.toml"
    scene.write_bytes('# caméra\n[camera]\nwidth = 8\n'.encode("latin-1"))
    code, out, err = run(["render", str(scene), "-o", str(tmp_path / "a.png"), "--no-progress"], capsys)
    assert code == 2 and out == ""
    assert err.strip().splitlines() == [f"warprt: error: {scene}: not UTF-8 text (byte 0xe9 on line 1); "
                                        "TOML scene files must be UTF-8"], err
    assert not (tmp_path / "a.png").exists()


ANIMATION = "[camera]\nwidth = 8\nheight = 6\n[animation]\nframes = 3\n[[shapes]]\ntype = \"sphere\"\n"


@pytest.mark.parametrize("frames, words", [
    ("-1", ["--frames", "-1"]),
    ("-3:2", ["--frames", "non-negative"]),
    ("3", ["outside the animation", "frames 0 to 2", "frames = 3"]),
    ("1:5", ["frame 3 is outside the animation"]),
    ("2:2", ["no frames"]),
])
def test_render_sequence_refuses_negative_frames_and_frames_past_the_end(tmp_path, capsys, frames, words):
    scene = tmp_path / "anim.toml"
    scene.write_text(ANIMATION)
    code, out, err = run(["render-sequence", str(scene), "-o", str(tmp_path / "f_##.png"), f"--frames={frames}",
                          "--no-progress"], capsys)
    assert code == 2 and out == ""
    last = err.strip().splitlines()[-1]
    assert "error" in last and all(w in last for w in words), last
    if not frames.startswith("-"):  # checked by us, not argparse: one line naming the file
        assert err.strip() == last and last.startswith(f"warprt: error: {scene}: --frames: ")
    assert not list(tmp_path.glob("f_*"))


@pytest.mark.parametrize("args, words", [
    (["--spp", "0"], ["--spp", "positive integer"]),
    (["--spp", "many"], ["--spp", "many"]),
    (["--spp", "10000000"], ["--spp", "1048576", "--time-budget"]),
    (["--spp", "1048577"], ["--spp", "1048576"]),
    (["--width", "0"], ["--width", "positive integer"]),
    (["--height", "-3"], ["--height"]),
    (["--max-depth", "-1"], ["--max-depth", ">= 0"]),
    (["--sampler", "halton"], ["--sampler", "halton"]),
    (["--workers", "0"], ["--workers"]),
    (["--time-budget", "0"], ["--time-budget", "positive"]),
    (["--seed", "x"], ["--seed"]),
    (["--seed", "-1"], ["--seed", "4294967295", "-1"]),
    (["--seed", "4294967296"], ["--seed", "4294967295"]),
    (["--colour", "red"], ["--colour"]),
    (["--adaptive", "--time-budget", "1"], ["--adaptive", "--time-budget"]),
])
def test_bad_arguments_exit_2_and_write_nothing(scene_file, tmp_path, capsys, args, words):
    out = tmp_path / "out.png"
    out.write_bytes(b"old")
    code, stdout, err = run(["render", str(scene_file), "-o", str(out), *args], capsys)
    assert code == 2
    last = err.strip().splitlines()[-1]
    assert "error" in last and all(w in last for w in words), last
    assert out.read_bytes() == b"old" and stdout == ""


def test_an_unavailable_device_exits_2(scene_file, tmp_path, capsys):
    code, _, err = run(["render", str(scene_file), "-o", str(tmp_path / "a.png"), "--device", "tpu"], capsys)
    assert code == 2 and err.startswith("warprt: error: ") and "tpu" in err
    assert not (tmp_path / "a.png").exists()


@pytest.mark.parametrize("name", ["out.tif", "out", "out.PNG.txt"])
def test_unsupported_extension_exits_2_before_rendering(scene_file, tmp_path, capsys, name):
    good = tmp_path / "good.png"
    code, out, err = run(["render", str(scene_file), "-o", str(good), "-o", str(tmp_path / name)], capsys)
    assert code == 2
    assert err.strip().splitlines() == [err.strip()] and "unsupported image format" in err and name in err
    assert not good.exists() and not (tmp_path / name).exists()  # checked before anything is written
    assert out == ""


def _unwritable(tmp_path, kind) -> str:
    if kind == "under-a-file":
        (tmp_path / "plain.txt").write_text("x")
        return str(tmp_path / "plain.txt" / "sub" / "out.png")
    if kind == "proc":
        return "/proc/warprt-test-out.exr"
    if kind == "a-folder":
        (tmp_path / "dir.png").mkdir()
        return str(tmp_path / "dir.png")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    return str(ro / "out.png")


UNWRITABLE = ["under-a-file", "proc", "a-folder", pytest.param(
    "read-only", marks=pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0,
                                          reason="root writes into read-only folders"))]


@pytest.mark.parametrize("kind", UNWRITABLE)
def test_an_unwritable_output_exits_2_before_the_scene_is_built(scene_file, tmp_path, capsys, monkeypatch, kind):
    """Every -o is checked before the render (and before the kernel is compiled): one line naming
    the output, not a traceback about a hidden temporary file after minutes of rendering."""
    def never(*a, **k):
        raise AssertionError("the renderer was built before the output was checked")

    monkeypatch.setattr(warprt.Renderer, "__init__", never)
    bad = _unwritable(tmp_path, kind)
    good = tmp_path / "good.png"
    code, out, err = run(["render", str(scene_file), "-o", str(good), "-o", bad, "--no-progress"], capsys)
    assert code == 2, err
    assert err.strip().splitlines() == [err.strip()] and err.startswith(f"warprt: error: {bad}: ")
    assert "cannot be written" in err or "is a folder" in err
    assert ".tmp" not in err and ".probe" not in err and out == ""
    assert not good.exists()
    assert not [p for p in tmp_path.rglob(".*") if p.is_file()]  # no probe or temporary file left


@pytest.mark.parametrize("kind", ["under-a-file", "proc"])
def test_render_sequence_checks_its_pattern_before_rendering(tmp_path, capsys, monkeypatch, kind):
    def never(*a, **k):
        raise AssertionError("the renderer was built before the output was checked")

    monkeypatch.setattr(warprt.Renderer, "__init__", never)
    (tmp_path / "anim.toml").write_text('[animation]\nframes = 2\n[[shapes]]\ntype = "sphere"\n')
    pattern = _unwritable(tmp_path, kind).replace("out.", "f_##.").replace("warprt-test-out.", "f_##.")
    for executor in ("local", "thread"):
        code, out, err = run(["render-sequence", str(tmp_path / "anim.toml"), "-o", pattern, "--executor", executor,
                              "--no-progress"], capsys)
        assert code == 2 and err.strip().splitlines() == [err.strip()] and "cannot be written" in err, err
    with pytest.raises(warprt.RenderError, match="cannot be written"):
        warprt.animation.render_sequence(warprt.load_scene(tmp_path / "anim.toml"), output=pattern)


def test_check_output_in_the_python_api(tmp_path):
    assert warprt.check_output(tmp_path / "a.exr") == str(tmp_path / "a.exr")
    assert warprt.check_output(tmp_path / "new" / "a.png", create_folders=True)
    with pytest.raises(warprt.RenderError, match="does not exist"):
        warprt.check_output(tmp_path / "new" / "a.png")
    with pytest.raises(warprt.RenderError, match="unsupported image format"):
        warprt.check_output(tmp_path / "a.tif")
    assert warprt.check_output(tmp_path / "a.jpg") == str(tmp_path / "a.jpg")
    (tmp_path / "f").write_text("")
    with pytest.raises(warprt.RenderError, match="is not a folder"):
        warprt.check_output(tmp_path / "f" / "a.png", create_folders=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]  # nothing created, no probe left


def test_no_output_is_a_usage_error(scene_file, capsys):
    code, _, err = run(["render", str(scene_file)], capsys)
    assert code == 2 and "-o" in err


# --- a real process ---------------------------------------------------------------------------------------


def _subprocess(args, cwd):
    env = dict(os.environ)
    env.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))
    # the warprt of this checkout, wherever the process starts
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return subprocess.run([sys.executable, "-m", "warprt", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


def test_python_m_warprt_renders(scene_file, tmp_path):
    p = _subprocess(["render", "scene.toml", "-o", "out/img.png", "-o", "img.exr", "--spp", "1"], tmp_path)
    assert p.returncode == 0, p.stderr
    m = LAST_LINE.match(p.stdout.strip().splitlines()[-1])
    assert m and m["spp"] == "1" and float(m["mrays"]) > 0
    assert Image.open(tmp_path / "out" / "img.png").size == (24, 16)
    rgb, header = warprt.read_exr(tmp_path / "img.exr")
    np.testing.assert_array_equal(rgb, warprt.render(warprt.load_scene(scene_file), spp=1, progress=False))


def test_a_complete_png_carries_its_spp_and_no_partial_mark(scene_file, tmp_path, capsys):
    render_ok(["render", str(scene_file), "-o", str(tmp_path / "a.png"), "-o", str(tmp_path / "a.exr")], capsys)
    text = Image.open(tmp_path / "a.png").text
    assert text["warprt_spp"] == "2" and text["warprt_interrupted"] == "0" and "warprt:partial" not in text
    assert "warprt:partial" not in warprt.read_exr(tmp_path / "a.exr")[1]


def test_python_m_warprt_reports_a_bad_scene_in_one_line(tmp_path):
    (tmp_path / "bad.toml").write_text('[[shapes]]\ntype = "sphere"\n[[shapes]]\ntype = "sphere"\nradius = "big"\n')
    (tmp_path / "out.png").write_bytes(b"old")
    p = _subprocess(["render", "bad.toml", "-o", "out.png", "--no-progress"], tmp_path)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [
        "warprt: error: bad.toml: shapes[1].radius: expected a number, got 'big'"]
    assert "Traceback" not in p.stderr and p.stdout == ""
    assert (tmp_path / "out.png").read_bytes() == b"old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["bad.toml", "out.png"]


# --- Ctrl-C during render-sequence ----------------------------------------------------------------------

ANIMATED = """\
[camera]
width = 32
height = 24
[animation]
frames = 8
[[shapes]]
type = "sphere"
keyframes = [{time = 0, center = [0, 0, 0]}, {time = 1, center = [0.5, 0, 0]}]
[[lights]]
type = "point"
"""


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("executor", ["local", "thread", "process"])
def test_render_sequence_interrupted_keeps_the_finished_frames_and_exits_130(tmp_path, executor):
    """A real SIGINT once the first frame file appears: the run stops promptly (not every frame is
    rendered), exits 130, prints the complete frames, and exactly those files exist, none marked
    partial (the frame cut short is not written)."""
    import signal
    import time

    (tmp_path / "anim.toml").write_text(ANIMATED)
    env = dict(os.environ)
    env.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    args = ["render-sequence", "anim.toml", "-o", "out/f_####.png", "--spp", "1000", "--no-progress",
            "--executor", executor] + ([] if executor == "local" else ["--jobs", "1"])
    proc = subprocess.Popen([sys.executable, "-m", "warprt", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("out/*.png")):
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else ""
            time.sleep(0.02)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert time.monotonic() - sent < 15, "did not stop promptly"
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    written = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert 1 <= len(written) < 8, written  # stopped before the end
    complete, not_written = _sequence_report(stdout.strip().splitlines()[-1], 8)
    # the report lists as complete exactly the frames written, and as not written exactly the others
    assert written == [f"f_{f:04d}.png" for f in complete]
    assert sorted(complete + not_written) == list(range(8))
    for name in written:  # complete frames: full spp, no partial mark
        text = Image.open(tmp_path / "out" / name).text
        assert text["warprt_spp"] == "1000" and "warprt:partial" not in text


def _frames(text: str) -> list[int]:
    """ "0-3, 7" -> [0, 1, 2, 3, 7]"""
    out = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def _sequence_report(line: str, total: int) -> tuple[list[int], list[int]]:
    """(complete frames, frames not written) from the report line of an interrupted sequence."""
    m = re.match(rf"interrupted: (\d+) of {total} frames complete \(([\d, -]+|none)(?:: [^)]*)?\)"
                 r"(?:; not written: (.*))?$", line)
    assert m, line
    complete = [] if m[2] == "none" else _frames(m[2])
    assert int(m[1]) == len(complete)
    not_written = []
    for part in re.findall(r"([\d, -]+) \((?:cut short|not started)\)", m[3] or ""):
        not_written += _frames(part)
    return complete, not_written


def test_the_interrupted_sequence_report_lists_as_not_written_only_the_frames_not_written():
    from warprt.errors import FramesInterrupted

    e = FramesInterrupted(range(8), [f"seq/t/f_{f:04d}.exr" for f in range(8)], cut_short=[8], total=20,
                          not_started=range(9, 20))
    line = e.summary()
    assert line == ("interrupted: 8 of 20 frames complete (0-7: seq/t/f_0000.exr ... seq/t/f_0007.exr); "
                    "not written: 8 (cut short), 9-19 (not started)")
    complete, not_written = _sequence_report(line, 20)
    assert complete == list(range(8)) and not_written == list(range(8, 20))


def test_render_frames_interrupted_raises_with_the_finished_frames(tmp_path, monkeypatch):
    """Python API: a Ctrl-C (here: the render of frame 1 reports an interruption) gives a
    FramesInterrupted listing frame 0 with its written path; frame 1 is not written, frame 2 not rendered."""
    from warprt.batch import render_frames
    from warprt.errors import FramesInterrupted
    from warprt.render import Renderer

    scene = warprt.scene_from_string(ANIMATED.replace("32", "8").replace("24", "6"))
    calls = []
    real = Renderer.render

    def render(self, *a, **k):
        r = real(self, *a, **k)
        calls.append(1)
        r.interrupted = len(calls) == 2
        return r

    monkeypatch.setattr(Renderer, "render", render)
    with pytest.raises(FramesInterrupted) as info:
        render_frames(scene, frames=[0, 1, 2], spp=1, output=str(tmp_path / "f_#.png"))
    e = info.value
    assert isinstance(e, KeyboardInterrupt)
    assert e.frames == [0] and e.results == [str(tmp_path / "f_0.png")] and e.cut_short == [1]
    assert e.not_started == [2]
    assert str(e) == (f"interrupted: 1 of 3 frames complete (0: {tmp_path / 'f_0.png'}); "
                      "not written: 1 (cut short), 2 (not started)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_0.png"] and len(calls) == 2


# --- an unusable kernel cache folder ---------------------------------------------------------------------


def _with_cache(path, args, cwd, module=True):
    env = dict(os.environ)
    env["WARP_CACHE_PATH"] = str(path)
    env.pop("WARPRT_CACHE_DIR", None)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    argv = [sys.executable, "-m", "warprt", *args] if module else [sys.executable, "-c", *args]
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_an_unusable_warp_cache_path_exits_2_with_one_line(scene_file, tmp_path):
    (tmp_path / "a_file").write_text("not a folder")
    bad = tmp_path / "a_file" / "cache"  # under a regular file (root may write into read-only folders)
    p = _with_cache(bad, ["render", "scene.toml", "-o", "out.png", "--no-progress"], tmp_path)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert str(bad) in lines[0] and "WARP_CACHE_PATH" in lines[0] and "Not a directory" in lines[0]
    assert not (tmp_path / "out.png").exists()


def test_an_unusable_warp_cache_path_is_a_render_error_in_the_python_api(tmp_path):
    (tmp_path / "a_file").write_text("not a folder")
    code = ("import warprt\ntry:\n    warprt.render(warprt.scene_from_string('[camera]\\nwidth = 4\\nheight = 4\\n'), spp=1)\n"
            "except warprt.RenderError as e:\n    print('RenderError:', e)\n")
    p = _with_cache(tmp_path / "a_file" / "cache", [code], tmp_path, module=False)
    assert p.returncode == 0 and "Traceback" not in p.stderr, p.stderr
    assert p.stdout.startswith("RenderError: ") and "WARP_CACHE_PATH" in p.stdout, p.stdout


def test_adaptive_flag_renders_with_the_budget_as_mean_spp(scene_file, tmp_path, capsys):
    out = tmp_path / "a.exr"
    code, stdout, err = run(["render", str(scene_file), "-o", str(out), "--spp", "16", "--adaptive", "--no-progress"],
                            capsys)
    assert code == 0, err
    rgb, header = warprt.read_exr(out)
    assert np.isfinite(rgb).all() and rgb.mean() > 0
    assert "16 spp" in stdout
