"""Compiles: notices for long ones, the cache check, background compiles, and renders that start on
the general kernel and switch to the scene's own between passes (``warprt.kernels``)."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
import uuid

import numpy as np
import pytest
import warp as wp

import warprt
from warprt import kernels
from warprt.integrator import kernels_for
from warprt.records import Features
from warprt.worlds import batch_kernel_for


def _tiny_module(tmp_path, monkeypatch):
    """A labelled one-kernel module of its own, compiled into a private kernel cache."""
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))
    name = f"warprt_test_{uuid.uuid4().hex[:8]}"

    @wp.kernel(module=name, enable_backward=False)
    def double(a: wp.array(dtype=float)):
        i = wp.tid()
        a[i] = 2.0 * a[i]

    kernels.label(double, "the test kernel")
    return double


def test_a_long_compile_is_announced_with_its_time(tmp_path, monkeypatch):
    k = _tiny_module(tmp_path, monkeypatch)
    monkeypatch.setattr(kernels, "NOTICE_AFTER", 0.0)
    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    assert not kernels.module_cached(k, "cpu")
    kernels.load(k, "cpu")
    lines = err.getvalue().splitlines()
    assert lines[0] == "warprt: compiling the test kernel (first time on this machine)... "
    assert lines[-1].startswith("warprt: compiling the test kernel (first time on this machine): done in ")
    assert lines[-1].endswith(" s")
    assert kernels.module_cached(k, "cpu")


def test_no_notice_when_cached_quiet_or_quick(tmp_path, monkeypatch):
    k = _tiny_module(tmp_path, monkeypatch)
    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    monkeypatch.setattr(kernels, "NOTICE_AFTER", 0.0)
    with kernels.quiet_compiles():
        kernels.load(k, "cpu")  # compiled, quietly
    k.module.unload()
    kernels.load(k, "cpu")  # from the cache: nothing to announce
    assert err.getvalue() == ""
    # a compile shorter than NOTICE_AFTER says nothing either
    k2 = _tiny_module(tmp_path / "b", monkeypatch)
    monkeypatch.setattr(kernels, "NOTICE_AFTER", 60.0)
    kernels.load(k2, "cpu")
    assert err.getvalue() == ""


def test_background_compile_loads_the_module(tmp_path, monkeypatch):
    k = _tiny_module(tmp_path, monkeypatch)
    bg = kernels.Background(k, "cpu", notices=False)
    assert bg.wait(120.0) and bg.ready() and bg.error is None
    assert kernels.module_cached(k, "cpu")
    a = wp.array(np.arange(4, dtype=np.float32), device="cpu")
    wp.launch(k, dim=4, inputs=[a], device="cpu")
    assert a.numpy().tolist() == [0.0, 2.0, 4.0, 6.0]


def test_one_compile_for_two_threads_asking_at_once(tmp_path, monkeypatch):
    k = _tiny_module(tmp_path, monkeypatch)
    from warp._src.context import Module

    calls = []
    real_codegen = Module._run_codegen

    def counted(self, *args, **kwargs):
        calls.append(self.name)
        return real_codegen(self, *args, **kwargs)

    monkeypatch.setattr(Module, "_run_codegen", counted)
    threads = [threading.Thread(target=kernels.load, args=(k, "cpu")) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert calls == [k.module.name]


class _ReadyAfter:
    """Stands in for kernels.Background: ready from its ``n``-th ``ready()`` call on (one call a
    pass), its module loaded from the shared cache as the real one would have."""

    def __init__(self, n):
        self.n = n
        self.asked = 0

    def __call__(self, module, device, **kwargs):
        self.module = getattr(module, "module", module)
        kernels.load(self.module, device)
        self.error = None
        return self

    def ready(self):
        self.asked += 1
        return self.asked >= self.n

    def done(self):
        return self.ready()

    def wait(self, timeout=None):
        return True


def _pretend_uncached(monkeypatch, own_module):
    """The scene's own kernel counts as not in the cache, the general one as cached."""
    real = kernels.module_cached
    monkeypatch.setattr(kernels, "module_cached", lambda m, d: False if getattr(m, "module", m) is own_module
                        else real(m, d))


def _scene():
    return warprt.load_scene("scenes/soft_shadows.toml").with_camera(width=32, height=24)


def test_a_render_starts_on_the_general_kernel_and_switches_with_the_same_bits(monkeypatch):
    scene = _scene()
    own = warprt.Renderer(scene, device="cpu", background_compile=False)
    ref = own.render(spp=6, seed=2, pass_spp=1, progress=False).image
    assert own.features != Features.full()

    r = warprt.Renderer(scene, device="cpu", background_compile=True)
    _pretend_uncached(monkeypatch, r.kernel.module)
    fake = _ReadyAfter(3)
    monkeypatch.setattr(kernels, "Background", fake)
    general = kernels_for(Features.full(), r.packets).render
    kernels.load(general, "cpu")  # (in the cache whatever ran before)
    seen = []
    real_launches = r._launches_for

    def spy(*args, **kwargs):
        seen.append(r._running)
        return real_launches(*args, **kwargs)

    monkeypatch.setattr(r, "_launches_for", spy)
    img = r.render(spp=6, seed=2, pass_spp=1, progress=False).image
    assert seen[0] is general and seen[-1] is r.kernel  # started on the general kernel, ended on its own
    assert img.tobytes() == ref.tobytes()
    # the next render starts on its own kernel
    assert r._start_kernel() is r.kernel


def test_no_background_compile_without_a_cached_general_kernel(monkeypatch):
    scene = _scene()
    r = warprt.Renderer(scene, device="cpu", background_compile=True)
    general = kernels_for(Features.full(), r.packets).render
    monkeypatch.setattr(kernels, "module_cached", lambda m, d: False)
    started = []
    monkeypatch.setattr(kernels, "compile_general", lambda m, d, r=None: started.append((getattr(m, "module", m), r)))
    monkeypatch.setattr(kernels, "Background", lambda *a, **k: pytest.fail("own kernel compiled in the background"))
    r.render(spp=1, progress=False)
    assert r._running is r.kernel  # compiled (here: loaded) in the foreground
    # and the general kernel asked for, for the next feature set
    assert started == [(general.module, (Features.full().key, r.packets))]


def test_a_batch_starts_on_the_general_kernel_and_switches_with_the_same_bits(monkeypatch):
    # (a general kernel of the batch variants the suite builds anyway: the scene's own and with motion)
    monkeypatch.setattr("warprt.worlds.GENERAL_FEATURES", Features(motion=True))
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 1, 4), look_at=(0, 0.5, 0), fov=40, width=24, height=16),
                         shapes=(warprt.Sphere(center=(0, 0.5, 0), radius=0.5),),
                         lights=(warprt.PointLight(position=(1, 3, 3)),))
    ref = warprt.BatchRenderer(scene, worlds=2, cameras=1, device="cpu", background_compile=False)
    a = ref.render(spp=2, seed=1).color.numpy()
    b = warprt.BatchRenderer(scene, worlds=2, cameras=1, device="cpu", background_compile=True)
    _pretend_uncached(monkeypatch, b._own.module)
    monkeypatch.setattr(kernels, "Background", _ReadyAfter(1))  # (asked once a render)
    general = batch_kernel_for(Features(motion=True), True)
    kernels.load(general, "cpu")  # (in the cache whatever ran before)
    first = b.render(spp=2, seed=1).color.numpy()
    assert b._kernel is general
    second = b.render(spp=2, seed=1).color.numpy()
    assert b._kernel is b._own
    assert first.tobytes() == a.tobytes() and second.tobytes() == a.tobytes()


def test_compile_notices_follow_the_progress_setting(monkeypatch):
    r = warprt.Renderer(_scene(), device="cpu", background_compile=False)
    seen = []
    real = kernels.load
    monkeypatch.setattr(kernels, "load", lambda m, d: (seen.append(kernels.quiet()), real(m, d))[1])
    r.render(spp=1, progress=False)
    r._loaded = r._running = None  # (as a new feature set would: the kernel loads again)
    r.render(spp=1)
    assert seen == [True, False]


class _Running:
    """Stands in for a background compile's thread still under way (``done`` False)."""

    running = True

    def done(self):
        return not self.running


def test_a_compile_cut_short_by_the_exit_goes_on_in_a_process_of_its_own(monkeypatch):
    """A process that ends while render kernels compile in the background (a command-line
    render: the general kernel, or the scene's own while the general one renders) starts
    ``python -m warprt.compile`` detached for each, with its feature key and the kernel cache it
    used, so that the next run finds them; finished compiles, and compiles of other modules,
    start nothing."""
    monkeypatch.setattr(kernels, "_unfinished", [])
    monkeypatch.setattr(kernels.Background, "_run", lambda self: None)  # (no thread does any work)
    monkeypatch.setattr(kernels.Background, "done", _Running.done)
    monkeypatch.setattr(kernels.Background, "running", True, raising=False)
    started = []
    monkeypatch.setattr(kernels.subprocess, "Popen", lambda args, **kw: started.append((args, kw)))
    general = kernels_for(Features.full(), True).render
    kernels.Background(general, "cpu", render=(Features.full().key, True))
    kernels.Background(general, "cpu", render=("meshes+area_lights", False))
    kernels.Background(general, "cpu")  # (not a render kernel's: not handed over)
    kernels._hand_over_compiles()
    assert sorted(a[1:] for a, _ in started) == sorted([["-m", "warprt.compile", Features.full().key, "1", "cpu"],
                                                         ["-m", "warprt.compile", "meshes+area_lights", "0", "cpu"]])
    for _, kw in started:
        assert kw["start_new_session"]
        assert os.path.join(kw["env"]["WARP_CACHE_PATH"], wp.config.version) == str(wp.config.kernel_cache_dir)
    started.clear()
    monkeypatch.setattr(kernels.Background, "running", False, raising=False)
    kernels._hand_over_compiles()
    assert started == []


def test_the_compile_process_loads_the_render_kernel_of_its_feature_key():
    """``python -m warprt.compile FEATURES PACKETS DEVICE``, with the cache path the exit hand-over
    gives it, loads the render kernel of that feature key (here ``basic``, from the shared cache
    where the tests compiled it before; an empty folder would take a compile), and no other, from
    the same folder as this process's, and exits 0."""
    kernels.load(kernels_for(Features(), True).render, "cpu")  # (in the cache whatever ran before)
    cache = str(wp.config.kernel_cache_dir)
    env = {**os.environ, "WARP_CACHE_PATH": os.path.dirname(cache)}
    code = ("import sys, warprt.compile as c, warp as wp\n"
            "from warprt.integrator import kernels_for\n"
            "from warprt.records import Features\n"
            "c.main(sys.argv[1:])\n"
            "print(wp.config.kernel_cache_dir)\n"
            "print([bool(kernels_for(f, True).render.module.execs) for f in (Features(), Features.full())])")
    done = subprocess.run([sys.executable, "-c", code, "basic", "1", "cpu"], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    folder, loaded = done.stdout.strip().splitlines()[-2:]
    assert os.path.realpath(folder) == os.path.realpath(cache)
    assert loaded == "[True, False]"


def test_the_command_line_hands_the_general_compile_over_before_it_leaves(monkeypatch):
    """The command line ends with ``os._exit`` (no exit handlers run): it hands a general compile
    still under way to its own process first."""
    from warprt import cli

    calls = []
    monkeypatch.setattr(kernels, "_hand_over_compiles", lambda: calls.append("handed over"))
    monkeypatch.setattr(cli.os, "_exit", lambda code: calls.append(code))
    cli._leave(3)
    assert calls == ["handed over", 3]
