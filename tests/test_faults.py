"""Nothing lost, nothing silent: signals at every moment of a run (import, compile, render,
writing), full disks, damaged kernel caches. The command line is run in this process where a
signal can be placed exactly (``os.kill`` from inside a patched writer), and as a real
``python -m warprt`` where the moment comes from outside (a file appearing, a thread starting, a
library being loaded); every scene here compiles the ``basic`` kernel the suite builds anyway."""

from __future__ import annotations

import glob
import importlib
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from PIL import Image

import warprt
from warprt.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]
POSIX = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
LINUX = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

BASIC = '[camera]\nwidth = 64\nheight = 48\n[[shapes]]\ntype = "sphere"\n[[lights]]\ntype = "point"\n'
image_module = importlib.import_module("warprt.image")


@pytest.fixture
def basic(tmp_path) -> pathlib.Path:
    path = tmp_path / "basic.toml"
    path.write_text(BASIC)
    return path


def env_for(cache: str | os.PathLike | None = None) -> dict:
    env = dict(os.environ)
    env["WARP_CACHE_PATH"] = str(cache) if cache else env.get("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))
    env.pop("WARPRT_CACHE_DIR", None)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def start(args, cwd, cache=None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "warprt", *map(str, args)], cwd=cwd, env=env_for(cache),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(proc: subprocess.Popen, ready, what: str, timeout: float = 120.0, poll: float = 0.002) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the process ended (status {proc.returncode}) before {what}: {out}{err}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(poll)


def finish(proc: subprocess.Popen, timeout: float = 120.0) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, err


def progress_reader(proc: subprocess.Popen) -> list[str]:
    """Read the process's stderr as it comes (the progress bar shows half a second into a render)
    into the returned list, from a thread."""
    import threading

    seen: list[str] = []

    def read():
        while True:
            c = proc.stderr.read(1)
            if not c:
                return
            seen.append(c)

    threading.Thread(target=read, daemon=True).start()
    return seen


def mapped(pid: int, name: str) -> bool:
    try:
        return name in pathlib.Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def run_cli(argv, capsys) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def complete_image(path: pathlib.Path, spp: int) -> None:
    """``path`` is a finished (not partial) image of ``spp`` samples."""
    if path.suffix == ".exr":
        rgb, header = warprt.read_exr(path)
        assert rgb.shape[2] == 3 and np.isfinite(rgb).all() and rgb.max() > 0
        assert header["warprt_spp"] == spp and "warprt:partial" not in header
    else:
        with Image.open(path) as im:
            im.load()
            assert im.text["warprt_spp"] == str(spp) and "warprt:partial" not in im.text


def leftovers(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*") if p.name.endswith((".partial", ".probe")))


# --- a signal while the images are written -----------------------------------------------------------


def signal_during_writes(monkeypatch, signals_at: dict[int, list[int]]) -> list[str]:
    """Patch the atomic writer: during write number k (from 0) send ``signals_at[k]`` to this
    process (handled before the file is renamed into place). Returns the targets written."""
    real = image_module._atomic_write
    calls: list[str] = []

    def write(path, writer):
        k = len(calls)
        calls.append(path)

        def slow(tmp):
            writer(tmp)
            for s in signals_at.get(k, []):
                os.kill(os.getpid(), s)
                time.sleep(0.05)  # (the handler runs here, in the main thread)

        real(path, slow)

    monkeypatch.setattr(image_module, "_atomic_write", write)
    return calls


@POSIX
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_while_writing_waits_for_every_file(basic, tmp_path, capsys, monkeypatch, sig, code):
    """The render is finished when the EXR is being written: a Ctrl-C (or SIGTERM) then lets the
    EXR and the PNG be written, complete and unmarked, says so in one line, and exits 130 (143)."""
    calls = signal_during_writes(monkeypatch, {0: [sig]})
    exr, png = tmp_path / "w" / "img.exr", tmp_path / "w" / "img.png"
    status, out, err = run_cli(["render", basic, "-o", exr, "-o", png, "--spp", "2", "--no-progress"], capsys)
    assert status == code, err
    assert len(calls) == 2
    complete_image(exr, 2)
    complete_image(png, 2)
    name = signal.Signals(sig).name
    assert err.splitlines() == [f"warprt: {name}: writing {exr}, {png} first; press Ctrl-C again to abandon"]
    assert f"(interrupted by {name} while writing: the files are complete)" in out
    assert leftovers(tmp_path) == [] and signal.getsignal(signal.SIGINT) is signal.default_int_handler


@POSIX
def test_a_second_ctrl_c_while_writing_abandons_the_files_not_yet_written(basic, tmp_path, capsys, monkeypatch):
    signal_during_writes(monkeypatch, {0: [signal.SIGINT, signal.SIGINT]})
    exr, png = tmp_path / "img.exr", tmp_path / "img.png"
    exr.write_bytes(b"the previous image")
    status, out, err = run_cli(["render", basic, "-o", exr, "-o", png, "--spp", "2", "--no-progress"], capsys)
    assert status == 130
    lines = err.splitlines()
    assert lines[-1] == f"warprt: interrupted while writing: {exr}, {png} abandoned (not written)", err
    assert "press Ctrl-C again to abandon" in lines[0] and "Traceback" not in err
    assert exr.read_bytes() == b"the previous image" and not png.exists() and leftovers(tmp_path) == []


@POSIX
def test_save_image_holds_a_ctrl_c_until_the_file_is_complete(tmp_path, monkeypatch):
    """The Python API: a Ctrl-C during save_image finishes the file, then raises KeyboardInterrupt."""
    signal_during_writes(monkeypatch, {0: [signal.SIGINT]})
    with pytest.raises(KeyboardInterrupt):
        warprt.save_image(np.full((4, 5, 3), 0.5, np.float32), tmp_path / "a.exr")
    np.testing.assert_array_equal(warprt.read_exr(tmp_path / "a.exr")[0], 0.5)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_writers_are_imported_before_rendering(basic, tmp_path):
    """OpenEXR and Pillow are loaded by the time the render starts (an import takes long enough
    for a Ctrl-C to land in it, after the samples are done)."""
    code = ("import importlib, sys\n"
            "render = importlib.import_module('warprt.render')\n"
            "real = render.Renderer.render\n"
            "def spy(self, *a, **k):\n"
            "    print('writers', 'OpenEXR' in sys.modules, 'PIL.PngImagePlugin' in sys.modules, flush=True)\n"
            "    return real(self, *a, **k)\n"
            "render.Renderer.render = spy\n"
            "from warprt.cli import main\n"
            f"sys.exit(main(['render', {str(basic)!r}, '-o', 'a.exr', '-o', 'a.png', '--no-progress']))\n")
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env_for(), capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    assert "writers True True" in p.stdout.splitlines()


@POSIX
@LINUX
def test_ctrl_c_as_the_exr_is_written_keeps_both_files(basic, tmp_path):
    """The issue's case, with a real process: SIGINT as soon as the EXR's temporary file appears.
    Both images are written complete; exit 130; no traceback."""
    out = tmp_path / "w"
    proc = start(["render", basic, "-o", out / "img.exr", "-o", out / "img.png", "--width", 1000, "--height", 750,
                  "--no-progress"], tmp_path)
    wait_for(proc, lambda: bool(glob.glob(str(out / ".img.exr.*.partial"))), "the EXR's temporary file", poll=0.001)
    proc.send_signal(signal.SIGINT)
    status, stdout, stderr = finish(proc)
    assert status == 130 and "Traceback" not in stderr, stderr
    complete_image(out / "img.exr", 1)
    complete_image(out / "img.png", 1)
    assert leftovers(tmp_path) == []


@POSIX
@LINUX
def test_sigterm_during_the_render_writes_the_partial_image_and_exits_143(basic, tmp_path):
    """SIGTERM (timeout, Slurm, docker stop) is handled as Ctrl-C: the passes stop, the samples
    reached are written, marked partial, and the process exits 143."""
    exr, png = tmp_path / "p.exr", tmp_path / "p.png"
    proc = start(["render", basic, "-o", exr, "-o", png, "--spp", 1 << 20], tmp_path)  # (with a progress bar)
    seen = progress_reader(proc)
    wait_for(proc, lambda: "spp" in "".join(seen), "the progress bar (half a second into the render)")
    sent = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    status, stdout, stderr = finish(proc)
    stderr = "".join(seen) + stderr
    assert time.monotonic() - sent < 10, "did not stop promptly"
    assert status == 143 and "Traceback" not in stderr, stderr
    assert "interrupted: partial image" in stdout.strip().splitlines()[-1]
    _, header = warprt.read_exr(exr)
    assert header["warprt:partial"] == "true" and 1 <= header["warprt_spp"] < 1 << 20
    assert header["warprt_stopped_by"] == "interrupt"
    assert Image.open(png).text["warprt:partial"] == "true"


@POSIX
@LINUX
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_while_numpy_and_warp_load_exits_in_one_line(basic, tmp_path, sig, code):
    """A signal in the first second, while the command imports NumPy and Warp: one line, no
    traceback, nothing written."""
    proc = start(["render", basic, "-o", tmp_path / "a.png", "--no-progress"], tmp_path)
    wait_for(proc, lambda: mapped(proc.pid, "_multiarray_umath"), "NumPy's extension to load", poll=0.0005)
    proc.send_signal(sig)
    status, stdout, stderr = finish(proc)
    assert status == code, stderr
    assert stderr.splitlines() == ["warprt: interrupted" + ("" if sig == signal.SIGINT else " (SIGTERM)")]
    assert stdout == "" and not (tmp_path / "a.png").exists()


def private_cache(tmp_path: pathlib.Path, without: str) -> pathlib.Path:
    """A kernel cache holding the shared cache's entries (as links) except those whose name
    starts with ``without`` (those compile, into this folder only)."""
    shared = pathlib.Path(os.environ.get("WARP_CACHE_PATH", ROOT / ".cache" / "warp"))
    versions = [d for d in shared.iterdir() if d.is_dir()] if shared.is_dir() else []
    cache = tmp_path / "cache"
    for version in versions:
        (cache / version.name).mkdir(parents=True)
        for entry in version.iterdir():
            if not entry.name.startswith(without):
                (cache / version.name / entry.name).symlink_to(entry)
    return cache


def warp_cache_dir(cache: pathlib.Path) -> pathlib.Path:
    import warp as wp

    return cache / pathlib.Path(wp.config.kernel_cache_dir).name


RENDER_KERNELS = "wp_kernels_for__locals__render_kernel"


@POSIX
def test_ctrl_c_during_a_compile_stops_at_once_in_one_line_and_leaves_no_build_folder(basic, tmp_path):
    """A Ctrl-C while Warp compiles the render kernel (missing from a private cache): the command
    stops within a fraction of a second (it does not wait out the compile), prints one line,
    exits 130, and Warp's temporary build folder is removed."""
    cache = private_cache(tmp_path, RENDER_KERNELS)
    folder = warp_cache_dir(cache)
    proc = start(["render", basic, "-o", tmp_path / "a.png", "--no-progress"], tmp_path, cache=cache)
    wait_for(proc, lambda: bool(glob.glob(str(folder / f"{RENDER_KERNELS}*_p{proc.pid}_t*"))), "the build folder")
    time.sleep(0.5)  # (into the native compile)
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    status, stdout, stderr = finish(proc)
    assert time.monotonic() - sent < 2.0, "waited for the compile"
    assert status == 130 and stderr.splitlines() == ["warprt: interrupted"], stderr
    time.sleep(0.5)
    assert not glob.glob(str(folder / f"*_p{proc.pid}_t*")) and not (tmp_path / "a.png").exists()


# --- damaged kernel cache -------------------------------------------------------------------------------


def damage(entry: pathlib.Path, kind: str) -> None:
    obj = next(entry.glob("*.o"))
    meta = next(entry.glob("*.meta"))
    if kind == "truncated object":
        with open(obj, "r+b") as f:
            f.truncate(obj.stat().st_size // 3)
    elif kind == "empty object":
        obj.write_bytes(b"")
    elif kind == "empty meta":
        meta.write_text("")
    elif kind == "invalid meta":
        meta.write_text('{"kernel": ')


def test_a_damaged_kernel_cache_entry_is_moved_aside_and_compiled_again(basic, tmp_path):
    """The issue's case: the basic render kernel's object file truncated in the cache (a private
    copy). The command warns in one line, compiles the kernel again, renders the same image, and
    the next run is silent."""
    renderer = warprt.Renderer(warprt.load_scene(basic))
    renderer.compile()
    expected = renderer.render(progress=False).image
    binary = pathlib.Path(next(iter(renderer.kernel.module.execs.values())).binary_path)
    cache = private_cache(tmp_path, binary.parent.name)
    folder = warp_cache_dir(cache)
    shutil.copytree(binary.parent, folder / binary.parent.name)
    damage(folder / binary.parent.name, "truncated object")
    p = subprocess.run([sys.executable, "-m", "warprt", "render", str(basic), "-o", "a.exr", "--no-progress"],
                       cwd=tmp_path, env=env_for(cache), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("warprt: warning: Warp's kernel cache entry "), p.stderr
    assert "is truncated" in lines[0] and "moved to" in lines[0] and lines[0].endswith("compiled again")
    np.testing.assert_array_equal(warprt.read_exr(tmp_path / "a.exr")[0], expected)
    assert (folder / (binary.parent.name + ".damaged")).is_dir()
    again = subprocess.run([sys.executable, "-m", "warprt", "render", str(basic), "-o", "b.exr", "--no-progress"],
                           cwd=tmp_path, env=env_for(cache), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and again.stderr == "", again.stderr


def test_cache_damage_tells_a_whole_entry_from_a_damaged_one(tmp_path):
    from warprt._warp import cache_damage

    shared = pathlib.Path(os.environ.get("WARP_CACHE_PATH", ROOT / ".cache" / "warp"))
    entry = next(e for e in sorted(shared.glob("*/wp_warprt_film_*")) if next(e.glob("*.o"), None)
                 and next(e.glob("*.meta"), None))
    obj, meta = next(entry.glob("*.o")).name, next(entry.glob("*.meta")).name
    good = tmp_path / "good"
    shutil.copytree(entry, good)
    assert cache_damage(str(good), obj, meta) is None
    assert cache_damage(str(tmp_path / "absent"), obj, meta) is None  # nothing there: Warp compiles
    (good / obj).rename(good / "x")
    assert cache_damage(str(good), obj, meta) is None  # a missing binary is compiled by Warp
    (good / "x").rename(good / obj)
    with open(good / obj, "r+b") as f:
        f.truncate((good / obj).stat().st_size - 1)
    assert "truncated" in cache_damage(str(good), obj, meta)
    for kind, words in (("empty object", "is empty"), ("empty meta", "not valid JSON"),
                        ("invalid meta", "not valid JSON")):
        entry_copy = tmp_path / kind.replace(" ", "_")
        shutil.copytree(entry, entry_copy)
        damage(entry_copy, kind)
        assert words in cache_damage(str(entry_copy), obj, meta), kind
    (good / meta).write_text("[]")
    assert "no module metadata" in cache_damage(str(good), obj, meta)
