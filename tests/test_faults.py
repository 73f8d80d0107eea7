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
import re
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


@pytest.fixture(autouse=True)
def default_sigint():
    """Python's own SIGINT handler for each test (a run started in the background, as by a
    non-interactive shell, inherits SIGINT ignored), the one found put back after."""
    before = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


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
            try:
                c = proc.stderr.read(1)
            except ValueError:  # the test's communicate() read the rest and closed the pipe
                return
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


@POSIX
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupt_that_a_library_turns_into_its_own_error_is_still_an_interrupt(basic, tmp_path, capsys,
                                                                                    monkeypatch, sig, code):
    """NumPy turns a KeyboardInterrupt inside its C import of datetime into an ImportError (seen in
    a real run): once a signal has come, the error of the step it cut is reported as the
    interrupt, in one line, with the signal's status. Without a signal an error stays an error."""
    loader = importlib.import_module("warprt.scene.loader")

    def cut_import(path):  # the interrupt lands inside, and comes out as another error
        try:
            os.kill(os.getpid(), sig)
            time.sleep(0.05)
        except KeyboardInterrupt:
            raise ImportError("PyCapsule_Import could not import module \"datetime\"") from None
        pytest.fail("the signal did not interrupt")

    monkeypatch.setattr(loader, "load_scene", cut_import)
    status, out, err = run_cli(["render", basic, "-o", tmp_path / "a.png"], capsys)
    assert status == code and err.splitlines() == [
        "warprt: interrupted" + ("" if sig == signal.SIGINT else " (SIGTERM)")]
    monkeypatch.setattr(loader, "load_scene", lambda path: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        main(["render", str(basic), "-o", str(tmp_path / "a.png")])


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


COMPILE_THEN_WAIT = """
import signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)  # (a script's own; a background run inherits it ignored)
import numpy as np
import warp as wp
import warprt
from warprt.checks import check_points
warprt._warp.init()
try:
    check_points(wp.array(np.zeros((2, 3), np.float32), dtype=wp.vec3))  # compiles warprt_checks
    print("compiled", flush=True)
except KeyboardInterrupt:
    print("interrupted", flush=True)
"""


@POSIX
def test_ctrl_c_during_a_compile_in_the_python_api_leaves_no_build_folder(tmp_path):
    """In a script (Python's default SIGINT handler) the KeyboardInterrupt comes when Warp's
    native compile returns, between the build and the rename into the cache: the build folder
    Warp leaves there is removed (warprt._warp._load), and nothing half-built enters the cache."""
    cache = private_cache(tmp_path, "wp_warprt_checks")
    folder = warp_cache_dir(cache)
    proc = subprocess.Popen([sys.executable, "-c", COMPILE_THEN_WAIT], cwd=tmp_path, env=env_for(cache),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for(proc, lambda: bool(glob.glob(str(folder / f"wp_warprt_checks*_p{proc.pid}_t*"))), "the build folder")
    proc.send_signal(signal.SIGINT)
    status, stdout, stderr = finish(proc)
    assert status == 0 and stdout.strip() == "interrupted", stdout + stderr
    assert not glob.glob(str(folder / f"*_p{proc.pid}_t*"))
    assert not [e for e in folder.glob("wp_warprt_checks_*") if not e.is_symlink()]


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


DAMAGED_RUN = """
import json, sys, warnings
import numpy as np
import warp as wp
import warprt
from warprt.checks import check_points
warprt._warp.init()
with warnings.catch_warnings(record=True) as seen:
    warnings.simplefilter("always")
    check_points(wp.array(np.zeros((4, 3), np.float32), dtype=wp.vec3))  # loads warprt_checks
    try:
        check_points(wp.array(np.array([[0, 0, 0], [0, np.nan, 0]], np.float32), dtype=wp.vec3))
        answer = "none"
    except warprt.RenderError as e:
        answer = str(e)
print(json.dumps({"warnings": [str(w.message) for w in seen], "answer": answer}))
"""


def test_a_damaged_kernel_cache_entry_is_moved_aside_and_compiled_again(tmp_path):
    """The issue's case (a truncated object file in the cache; a private copy) on warprt's
    smallest module, the input checks': one warning, the module compiled again and working, the
    entry moved aside; the next run is silent. (The other kinds of damage are found by the same
    function, tested below on their own.)"""
    cache = private_cache(tmp_path, "wp_warprt_checks")
    folder = warp_cache_dir(cache)
    shared = pathlib.Path(os.environ.get("WARP_CACHE_PATH", ROOT / ".cache" / "warp")) / folder.name
    run = lambda: subprocess.run([sys.executable, "-c", DAMAGED_RUN], cwd=tmp_path, env=env_for(cache),
                                 capture_output=True, text=True, timeout=300)
    entries = [e for e in shared.glob("wp_warprt_checks_*") if e.is_dir() and next(e.glob("*.o"), None)
               and not re.search(r"_p\d+_t\d+$", e.name)]
    if not entries:  # (a cold shared cache: compile it here once)
        first = run()
        assert first.returncode == 0, first.stderr
        entries = [e for e in folder.glob("wp_warprt_checks_*") if e.is_dir()]
    for entry in entries:
        target = folder / entry.name
        if target.is_symlink() or not target.exists():
            target.unlink(missing_ok=True)
            shutil.copytree(entry, target)
        damage(target, "truncated object")
    p = run()
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["answer"].startswith("points[1]: position (0, nan, 0) is not finite")
    [warning] = out["warnings"]
    assert warning.startswith("Warp's kernel cache entry ") and "is truncated" in warning
    assert "moved to" in warning and warning.endswith("compiled again")
    assert glob.glob(str(folder / "wp_warprt_checks_*.damaged"))
    again = json.loads(run().stdout)
    assert again["warnings"] == [] and again["answer"] == out["answer"]


def test_the_command_line_shows_a_cache_warning_in_one_line(basic, tmp_path, capsys, monkeypatch):
    import warnings

    real = importlib.import_module("warprt.render").Renderer.compile

    def compile_with_warning(self):
        warnings.warn("Warp's kernel cache entry X was damaged (x.o is empty): moved to X.damaged and compiled "
                      "again", RuntimeWarning)
        return real(self)

    monkeypatch.setattr(importlib.import_module("warprt.render").Renderer, "compile", compile_with_warning)
    status, out, err = run_cli(["render", basic, "-o", tmp_path / "a.png", "--no-progress"], capsys)
    assert status == 0 and err.splitlines() == [
        "warprt: warning: Warp's kernel cache entry X was damaged (x.o is empty): moved to X.damaged and compiled again"]


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


# --- full disks -------------------------------------------------------------------------------------------


def fail_writes_under(monkeypatch, folder: pathlib.Path, err: int = 28) -> None:
    """Writes of images into ``folder`` fail as a full disk does (ENOSPC from the writer, after
    part of the file is written); writes elsewhere (the fallback) succeed."""
    real = image_module._atomic_write

    def write(path, writer):
        if pathlib.Path(path).resolve().is_relative_to(folder.resolve()):
            def full(tmp):
                with open(tmp, "wb") as f:
                    f.write(b"part of an image")
                raise OSError(err, os.strerror(err))

            return real(path, full)
        return real(path, writer)

    monkeypatch.setattr(image_module, "_atomic_write", write)


@pytest.fixture
def temp_folder(tmp_path, monkeypatch) -> pathlib.Path:
    """The system's temporary folder, for this test: where a full disk's images go."""
    import tempfile

    folder = tmp_path / "systemp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


@pytest.mark.parametrize("err, words", [(28, "No space left on device"), (122, "Disk quota exceeded"),
                                        (5, "Input/output error")])
def test_a_full_disk_is_one_line_exit_2_and_the_image_goes_to_the_temp_folder(basic, tmp_path, capsys, monkeypatch,
                                                                             temp_folder, err, words):
    disk = tmp_path / "disk"
    disk.mkdir()
    (disk / "img.exr").write_bytes(b"the previous image")
    fail_writes_under(monkeypatch, disk, err)
    status, out, stderr = run_cli(["render", basic, "-o", disk / "img.exr", "--spp", "2", "--no-progress"], capsys)
    assert status == 2
    [line] = stderr.splitlines()
    fallback = next(temp_folder.glob("img.*.exr"))
    free = image_module.size_text(image_module.free_bytes(str(disk)))
    assert line == (f"warprt: error: {disk / 'img.exr'}: cannot be written: {words} ({free} free on its disk); "
                    f"the image was written to {fallback} instead")
    rgb, header = warprt.read_exr(fallback)
    np.testing.assert_array_equal(rgb, warprt.render(warprt.load_scene(basic), spp=2, progress=False))
    assert header["warprt_spp"] == 2
    assert (disk / "img.exr").read_bytes() == b"the previous image" and leftovers(tmp_path) == []
    assert out == ""


def test_an_output_on_a_full_disk_does_not_stop_the_others(basic, tmp_path, capsys, monkeypatch, temp_folder):
    disk = tmp_path / "disk"
    disk.mkdir()
    fail_writes_under(monkeypatch, disk)
    status, out, stderr = run_cli(["render", basic, "-o", disk / "a.exr", "-o", tmp_path / "a.png", "--no-progress"],
                                  capsys)
    assert status == 2 and len(stderr.splitlines()) == 1 and str(disk / "a.exr") in stderr
    complete_image(tmp_path / "a.png", 1)
    assert out.startswith(f"{tmp_path / 'a.png'}: 64x48")


def test_when_the_temp_folder_is_full_too_the_line_says_so(tmp_path, monkeypatch, temp_folder):
    fail_writes_under(monkeypatch, tmp_path)  # (the temporary folder is inside it)
    with pytest.raises(warprt.errors.WriteError) as info:
        image_module.save_image_or_fallback(np.zeros((2, 2, 3), np.float32), tmp_path / "a.png")
    assert "the image could not be written to" in str(info.value) and info.value.fallback is None
    assert list(temp_folder.iterdir()) == []


def test_outputs_that_cannot_fit_are_refused_before_rendering(basic, tmp_path, capsys, monkeypatch):
    """Like memory: the largest size the files can take (no compression) against the space free
    on their disk, checked before the scene is built."""
    monkeypatch.setattr(image_module, "free_bytes", lambda folder: 100_000)
    built = []
    monkeypatch.setattr(importlib.import_module("warprt.render").Renderer, "__init__",
                        lambda self, *a, **k: built.append(1))
    exr, png = tmp_path / "a.exr", tmp_path / "a.png"
    status, out, stderr = run_cli(["render", basic, "-o", exr, "-o", png, "--width", 200, "--height", 100], capsys)
    need = image_module.estimate_file_bytes("a.exr", 200, 100) + image_module.estimate_file_bytes("a.png", 200, 100)
    assert status == 2 and not built
    assert stderr.splitlines() == [f"warprt: error: {exr}, {png}: need up to {image_module.size_text(need)} of disk "
                                   "space, but only 100.0 kB is free there; free some space or write elsewhere"]
    assert image_module.estimate_file_bytes("a.exr", 200, 100, aov_channels=4) == int(
        (12 + 16) * 200 * 100 * 1.01) + 64 * 1024
    # a sequence: every frame counted
    (tmp_path / "anim.toml").write_text(BASIC + "[animation]\nframes = 8\n")
    status, out, stderr = run_cli(["render-sequence", tmp_path / "anim.toml", "-o", tmp_path / "f_#.png",
                                   "--width", 100, "--height", 100], capsys)
    assert status == 2 and "f_0.png, " in stderr and "f_7.png: need up to" in stderr and not built


def test_a_sequence_on_a_full_disk_stops_with_one_line_naming_the_frames(tmp_path, capsys, monkeypatch, temp_folder):
    (tmp_path / "anim.toml").write_text(BASIC.replace("64", "16").replace("48", "12") + "[animation]\nframes = 4\n")
    disk = tmp_path / "disk"
    disk.mkdir()
    real = image_module._atomic_write

    def write(path, writer):  # frame 1 does not fit
        def full(tmp):
            raise OSError(28, os.strerror(28))

        return real(path, full if path == str(disk / "f_1.png") else writer)

    monkeypatch.setattr(image_module, "_atomic_write", write)
    status, out, stderr = run_cli(["render-sequence", tmp_path / "anim.toml", "-o", disk / "f_#.png",
                                   "--no-progress"], capsys)
    assert status == 2
    [line] = stderr.splitlines()
    fallback = next(temp_folder.glob("f_1.*.png"))
    assert line.startswith(f"warprt: error: frame 1: {disk / 'f_1.png'}: cannot be written: No space left on device (")
    assert line.endswith(f"the image was written to {fallback} instead; frame 0 was written; "
                         "frames 2-3 were not rendered")
    assert sorted(p.name for p in disk.iterdir()) == ["f_0.png"]


UNSHARE_DRIVER = r'''
import json, os, subprocess, sys, time
scene, disk = sys.argv[1], sys.argv[2]
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", disk], check=True)
cmd = [sys.executable, "-m", "warprt", "render", scene]
out = {}
p = subprocess.run(cmd + ["-o", disk + "/big.exr", "--width", "1024", "--height", "768", "--no-progress"],
                   capture_output=True, text=True)
out["refused"] = [p.returncode, p.stdout, p.stderr]
proc = subprocess.Popen(cmd + ["-o", disk + "/img.exr", "--width", "256", "--height", "192", "--spp", "1048576",
                               "--time-budget", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
seen = ""
while "spp" not in seen:  # the progress bar: the render has begun, the free space was checked
    c = proc.stderr.read(1)
    if not c:
        break
    seen += c
with open(disk + "/filler", "wb") as f:  # another writer fills the disk
    try:
        while True:
            f.write(b"\0" * 65536)
            f.flush()
    except OSError:
        pass
stdout, stderr = proc.communicate()
out["filled"] = [proc.returncode, stdout, stderr.replace("\r", "\n")]
print(json.dumps(out))
'''


def unshare_available() -> bool:
    if not sys.platform.startswith("linux") or not shutil.which("unshare") or not shutil.which("mount"):
        return False
    probe = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
                            "d=$(mktemp -d) && mount -t tmpfs -o size=64k tmpfs $d && umount $d && rmdir $d"],
                           capture_output=True, timeout=30)
    return probe.returncode == 0


@pytest.mark.skipif(not unshare_available(), reason="needs unshare and mount (a tmpfs in a user namespace)")
def test_a_real_full_tmpfs(basic, tmp_path):
    """A 2 MB tmpfs (in a user namespace: no root needed): a 1024x768 EXR is refused before
    rendering; a 256x192 one fits when checked, then another writer fills the disk during the
    render: one line, exit 2, and the image, in the temporary folder, is the one its header
    says how to reproduce."""
    import tempfile

    disk = tmp_path / "disk"
    disk.mkdir()
    before = set(pathlib.Path(tempfile.gettempdir()).glob("img.*.exr"))
    p = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", sys.executable, "-c", UNSHARE_DRIVER,
                        str(basic), str(disk)], cwd=tmp_path, env=env_for(), capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    result = json.loads(p.stdout)
    code, out, err = result["refused"]
    assert code == 2 and err.splitlines() == [
        f"warprt: error: {disk}/big.exr: needs up to 9.6 MB of disk space, but only 2.1 MB is free there; "
        "free some space or write elsewhere"]
    code, out, err = result["filled"]
    lines = [x for x in err.splitlines() if x.startswith("warprt")]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"warprt: error: {disk}/img.exr: cannot be written: No space left on device (")
    [fallback] = set(pathlib.Path(tempfile.gettempdir()).glob("img.*.exr")) - before
    try:
        assert lines[0].endswith(f"; the image was written to {fallback} instead")
        rgb, header = warprt.read_exr(fallback)
        assert header["warprt_stopped_by"] == "time_budget"
        again = warprt.Renderer(warprt.load_scene(basic).with_camera(width=256, height=192)).render(
            spp=header["warprt_spp"], planned_spp=header["warprt_planned_spp"], seed=header["warprt_seed"],
            progress=False)
        assert rgb.tobytes() == again.image.tobytes()
    finally:
        fallback.unlink()


# --- a stopped image says what reproduces it ----------------------------------------------------------------


class StopAfter:
    """A ``stop`` event set after ``n`` passes (how Ctrl-C reaches a render)."""

    def __init__(self, n: int):
        self.n, self.calls = n, 0

    def is_set(self) -> bool:
        self.calls += 1
        return self.calls >= self.n


SAMPLERS = ["regular", "independent", "stratified", "sobol"]


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_an_image_stopped_early_is_reproduced_bit_for_bit_from_what_it_records(basic, sampler):
    """A render of a 64-sample pattern stopped after 5 samples (passes 1 + 2 + 2) holds the first
    5 samples of that pattern: render(spp=5, planned_spp=64) gives the same bits, in one pass or
    another split, and its record says so. (Without planned_spp the strata of a 5-sample pattern
    differ, for the samplers that lay their samples out for the count.) This is a uniform render's
    record; an adaptive render (the default) stopped part way depends on its pixels' counts as well,
    and its record leaves ``warprt_reproduce`` out rather than name options that would not give it
    again."""
    renderer = warprt.Renderer(warprt.load_scene(basic).with_settings(sampler=sampler, spp=64))
    stopped = renderer.render(pass_spp=2, stop=StopAfter(3), progress=False, adaptive=False)
    assert (stopped.spp, stopped.planned_spp, stopped.passes, stopped.stopped_by) == (5, 64, (1, 2, 2), "interrupt")
    meta = stopped.reproduction()
    assert meta["warprt_reproduce"] == f"--spp 5 --planned-spp 64 --no-adaptive --seed 0 --sampler {sampler}"
    assert (meta["warprt_passes"], meta["warprt_sampler"], meta["warprt_planned_spp"]) == ("1+2+2", sampler, 64)
    for pass_spp in (None, 3):
        again = renderer.render(spp=5, planned_spp=64, pass_spp=pass_spp, progress=False)
        assert again.image.tobytes() == stopped.image.tobytes() and again.stopped_by is None
    fresh = renderer.render(spp=5, progress=False, adaptive=False)
    assert (fresh.image.tobytes() == stopped.image.tobytes()) == (sampler in ("independent", "sobol"))
    default = renderer.render(pass_spp=2, stop=StopAfter(3), progress=False)  # the scene's: adaptive
    assert default.adaptive and default.stopped_by == "interrupt"
    assert "warprt_reproduce" not in default.reproduction()


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_the_cli_reproduces_a_time_budget_image_from_its_header(basic, tmp_path, capsys, sampler):
    a, b = tmp_path / "budget.exr", tmp_path / "again.exr"
    status, out, err = run_cli(["render", basic, "-o", a, "--spp", 1 << 20, "--time-budget", 0.3, "--sampler", sampler,
                                "--seed", 7, "--no-progress"], capsys)
    assert status == 0, err
    rgb, header = warprt.read_exr(a)
    assert header["warprt_stopped_by"] == "time_budget" and header["warprt_planned_spp"] == 1 << 20
    assert 1 <= header["warprt_spp"] < 1 << 20
    assert sum(int(x) for x in header["warprt_passes"].split("+")) == header["warprt_spp"]
    args = header["warprt_reproduce"].split()
    # (a time budget renders uniformly, whatever the scene's render.adaptive: the record says so)
    assert args == ["--spp", str(header["warprt_spp"]), "--planned-spp", str(1 << 20), "--no-adaptive", "--seed", "7",
                    "--sampler", sampler]
    status, out, err = run_cli(["render", basic, "-o", b, *args, "--no-progress"], capsys)
    assert status == 0, err
    again, header2 = warprt.read_exr(b)
    assert again.tobytes() == rgb.tobytes() and "warprt_stopped_by" not in header2


def test_planned_spp_is_checked(basic, capsys, tmp_path):
    renderer = warprt.Renderer(warprt.load_scene(basic))
    for bad in (2, 0, True, 2.5, (1 << 20) + 1):
        with pytest.raises(warprt.RenderError, match="planned_spp"):
            renderer.render(spp=4, planned_spp=bad, progress=False)
    with pytest.raises(warprt.RenderError, match="adaptive"):
        renderer.render(spp=4, planned_spp=8, adaptive=True, progress=False)
    status, out, err = run_cli(["render", basic, "-o", tmp_path / "a.png", "--spp", 8, "--planned-spp", 4], capsys)
    assert status == 2 and "--planned-spp (4) must be at least --spp (8)" in err


# --- every public function names the argument it refuses -----------------------------------------------------


def _api_calls():
    from warprt.animation import render_sequence
    from warprt.batch import render_frames
    from warprt.query import pixel_samples, pixel_samples_1d

    scene = warprt.scene_from_string(BASIC.replace("64", "8").replace("48", "6"))
    animated = warprt.scene_from_string(BASIC.replace("64", "8").replace("48", "6") + "[animation]\nframes = 2\n")
    renderer = warprt.Renderer(scene, device="cpu")
    return {
        "camera_rays (N, 3) points": (lambda: warprt.camera_rays(scene, np.zeros((4, 3))),
                                      "points: expected raster points (x, y) in pixels shaped (N, 2), got shape (4, 3)"),
        "camera_rays NaN points": (lambda: warprt.camera_rays(scene, [[1, 1], [np.nan, 1]]),
                                   "points[1]: (nan, 1.0) is not finite"),
        "camera_rays text points": (lambda: warprt.camera_rays(scene, "abc"), "points: expected raster points"),
        "camera_rays lens count": (lambda: warprt.camera_rays(scene, np.zeros((4, 2)), lens=np.zeros((3, 2))),
                                   "lens: 3 samples for 4 points"),
        "camera_rays lens range": (lambda: warprt.camera_rays(scene, [[0, 0]], lens=[[2, 0]]),
                                   "lens[0]: (2.0, 0.0) is outside [0, 1]^2"),
        "camera_rays time": (lambda: warprt.camera_rays(scene, time=np.nan), "time must be finite"),
        "camera_rays scene": (lambda: warprt.camera_rays(None), "camera_rays expects a warprt.Scene or Renderer"),
        "trace_rays (N, 6)": (lambda: warprt.trace_rays(scene, np.zeros((2, 6)), np.ones((2, 6))),
                              "origins: expected ray origins (x, y, z) shaped (N, 3), got shape (2, 6)"),
        "trace_rays zero direction": (lambda: warprt.trace_rays(scene, np.zeros((2, 3)), [[0, 0, 1], [0, 0, 0]]),
                                      "directions[1]: every direction must be non-zero"),
        "trace_rays t_min": (lambda: warprt.trace_rays(scene, [0, 0, 5], [0, 0, -1], t_min=-1), "t_min must be >= 0"),
        "trace_rays t_max": (lambda: warprt.trace_rays(scene, [0, 0, 5], [0, 0, -1], t_min=2, t_max=1),
                             "t_max (1) must exceed t_min (2)"),
        "trace_rays t_max text": (lambda: warprt.trace_rays(scene, [0, 0, 5], [0, 0, -1], t_max="far"),
                                  "t_max must be a number"),
        "trace_rays scene": (lambda: warprt.trace_rays(3, [0, 0, 5], [0, 0, -1]), "trace_rays expects a warprt.Scene"),
        "pixel_samples spp": (lambda: pixel_samples("sobol", [0], 0), "spp must be an integer from 1"),
        "pixel_samples pixels": (lambda: pixel_samples("sobol", [0.5], 4), "pixels: expected a 1-D list of integer"),
        "pixel_samples count": (lambda: pixel_samples("sobol", [0], 4, count=-1), "count must be an integer from 1"),
        "pixel_samples_1d dim": (lambda: pixel_samples_1d("sobol", [0], 4, dim="x"), "dim must be an integer"),
        "save_image path": (lambda: warprt.save_image(np.zeros((2, 2, 3)), 5), "expected an image path"),
        "save_image metadata": (lambda: warprt.save_image(np.zeros((2, 2, 3)), "x.png", metadata=[1]),
                                "x.png: metadata must be a dict"),
        "read_exr missing": (lambda: warprt.read_exr("missing.exr"), "missing.exr: cannot be read (No such file"),
        "read_exr not an EXR": (lambda: warprt.read_exr(__file__), f"{__file__}: not an OpenEXR file"),
        "Scene(shapes=Sphere())": (lambda: warprt.Scene(shapes=warprt.Sphere()),
                                   "shapes: expected a list of shapes, got one Sphere (write shapes=[Sphere(...)])"),
        "Scene(lights=PointLight())": (lambda: warprt.Scene(lights=warprt.PointLight()),
                                       "lights: expected a list of lights, got one PointLight"),
        "Scene(shapes=None)": (lambda: warprt.Scene(shapes=None), "shapes: expected a list of shapes, got NoneType"),
        "Scene(materials=[...])": (lambda: warprt.Scene(materials=[warprt.Material()]),
                                   "materials: expected a dict of name: Material, got list"),
        "load_scene(123)": (lambda: warprt.load_scene(123), "load_scene expects a file path"),
        "scene_from_string(path)": (lambda: warprt.scene_from_string(pathlib.Path("a.toml")),
                                    "scene_from_string expects TOML text (a str), got PosixPath; for a file use load_scene"),
        "Renderer features": (lambda: warprt.Renderer(scene, features="full"), "features must be a warprt.Features"),
        "Renderer.set_camera": (lambda: renderer.set_camera("camera"), "set_camera() needs a warprt.Camera, got str"),
        "Renderer.render time_budget": (lambda: renderer.render(time_budget="1"), "time_budget must be a positive number"),
        "Renderer.render stop": (lambda: renderer.render(stop=True), "stop must be an event with is_set()"),
        "Renderer.set_mesh_points index": (lambda: renderer.set_mesh_points(0, np.zeros((3, 3))),
                                           "shape 0 is not a mesh"),
        "render_sequence scene": (lambda: render_sequence(None), "expected a warprt.Scene, got NoneType"),
        "render_sequence frames": (lambda: render_sequence(animated, frames="01"), "frames: expected a list or range"),
        "render_sequence output": (lambda: render_sequence(animated, output=5), "output: expected a path pattern"),
        "render_frames max_workers": (lambda: render_frames(animated, executor="thread", max_workers="2"),
                                      "max_workers must be a positive integer"),
        "BatchRenderer motion_blur": (lambda: warprt.BatchRenderer(scene, motion_blur="yes"),
                                      "motion_blur must be True or False"),
        "BatchRenderer.set_shape_poses('abc')": (lambda: warprt.BatchRenderer(scene).set_shape_poses("abc"),
                                                 "shape_poses: expected poses shaped (1, 1, 7)"),
        "BatchRenderer.render aovs": (lambda: warprt.BatchRenderer(scene).render(aovs=5),
                                      "aovs: expected a list of AOV names"),
        "check_output": (lambda: warprt.check_output(5), "expected an image path (str or os.PathLike), got int"),
    }


def test_every_public_function_refuses_bad_arrays_and_values_by_name(tmp_path, monkeypatch):
    """A bad argument to any public function is a SceneError or RenderError whose message names
    the argument (and the index, for arrays), never a bare TypeError, ValueError or
    AttributeError from NumPy or Warp, nor silently reinterpreted memory."""
    monkeypatch.chdir(tmp_path)
    failures = []
    for call, (fn, words) in _api_calls().items():
        try:
            fn()
            failures.append(f"{call}: accepted")
        except (warprt.SceneError, warprt.RenderError) as e:
            if words not in str(e):
                failures.append(f"{call}: {type(e).__name__}: {e!s} (expected {words!r})")
        except Exception as e:  # noqa: BLE001 (what the test is about)
            failures.append(f"{call}: bare {type(e).__name__}: {e}")
    assert not failures, "\n".join(failures)


# --- the signal fuzzer, small -----------------------------------------------------------------------------------


@POSIX
def test_the_signal_fuzzer_runs_and_its_trials_hold(capsys):
    """Three trials of ``make fuzz-signals`` (which runs 100): a render's passes, a large write
    and a sequence, each signalled at a random moment, must hold (see tests/fuzz_signals.py)."""
    from fuzz_signals import main as fuzz

    status = fuzz(["--trials", "3", "--kinds", "render,write,sequence", "--no-calibrate", "--seed", "5"])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "3 trials, 3 held, 0 failed" in out
