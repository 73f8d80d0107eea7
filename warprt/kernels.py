"""Compiling warprt's Warp modules: a notice for every long compile, and specialised render
kernels built in the background while a general one renders.

Warp compiles a module the first time it is loaded on a device and keeps the binary in its
kernel cache (``WARP_CACHE_PATH``); later loads take milliseconds. warprt's render kernel is
specialised per :class:`~warprt.records.Features` value, so every new combination of features
used to cost a compile before its first pixel. Two mechanisms keep that wait off the user:

* **Notices.** Every compile of a warprt module that takes longer than :data:`NOTICE_AFTER`
  seconds says so on stderr while it runs ("compiling the render kernel for meshes+area_lights
  (first time on this machine)... 4 s"), and how long it took when it is done, whoever asked for
  it: the CLI, ``render()``, ``Renderer``, ``BatchRenderer`` or the Newton bridge. A call with
  ``progress=False`` (or ``WARPRT_QUIET=1`` in the environment) keeps them quiet.
* **The general kernel.** ``Features.full()`` has every feature, each behind a run-time check,
  so it renders any scene, and gives the same image bit for bit as the scene's own variant (a
  feature switched off at compile time only removes code that the run-time checks would skip).
  It is compiled once per machine. A renderer whose own variant is not in the cache yet renders
  on the general kernel at once while its variant compiles in a background thread
  (:class:`Background`), and switches to it between two passes when it is ready: the image is the
  same whichever kernel ran which pass.

Both hang on warprt's wrapper of Warp's module load (``warprt._warp``), which calls
:func:`compiling` around every load that compiles. Warp's module cache is safe for concurrent
builds (a module is built in a private folder and renamed into place), and its native compile
runs without the GIL, so a background compile takes a core of its own. The compile thread runs
at a lower priority (nice +10, Linux) so that the render's worker threads keep theirs.
"""

from __future__ import annotations

import atexit
import contextvars
import os
import subprocess
import sys
import threading
import time
from contextlib import contextmanager

import warp as wp

NOTICE_AFTER = 1.0  # seconds a compile may take before it is announced
BACKGROUND_NICE = 10  # added niceness of a background compile's thread (Linux)

# human names of warprt's modules, by Warp module name; the render kernels' modules register
# themselves (``label``) as their factories build them
_LABELS = {
    "warprt_accel": "the acceleration-structure kernels",
    "warprt_aov": "the AOV kernel",
    "warprt_build": "the scene-building kernels",
    "warprt_checks": "the input-check kernels",
    "warprt_film": "the film kernels",
    "warprt_newton": "the Newton bridge's kernels",
    "warprt_query": "the ray-query kernels",
    "warprt_worlds": "the batch posing kernels",
}
_quiet = contextvars.ContextVar("warprt_quiet_compiles", default=False)
_where = contextvars.ContextVar("warprt_compile_where", default="")  # " in the background"
_print_lock = threading.Lock()


def label(module, text: str) -> None:
    """Name ``module`` (a Warp module, or anything with ``.module``: a kernel) in notices."""
    module = getattr(module, "module", module)
    _LABELS[module.name] = text


def quiet() -> bool:
    return _quiet.get() or os.environ.get("WARPRT_QUIET", "") not in ("", "0")


def set_quiet(on: bool):
    """No compile notices from this thread (and its context) from now on when ``on``; returns the
    token that ``reset_quiet`` takes to undo it."""
    return _quiet.set(bool(on) or _quiet.get())


def reset_quiet(token) -> None:
    _quiet.reset(token)


@contextmanager
def quiet_compiles(on: bool = True):
    """No compile notices from this thread while the block runs (``progress=False``)."""
    token = _quiet.set(bool(on) or _quiet.get())
    try:
        yield
    finally:
        _quiet.reset(token)


class Notice:
    """Announces a compile on stderr once it has taken ``NOTICE_AFTER`` seconds: one line then,
    the elapsed seconds kept up to date on a terminal, and the total when it ends."""

    def __init__(self, text: str, stream=None):
        self.text = text
        self.stream = sys.stderr if stream is None else stream
        self.start = time.perf_counter()
        self.shown = False
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="warprt-compile-notice", daemon=True)

    def _tty(self) -> bool:
        try:
            return self.stream.isatty()
        except (AttributeError, ValueError):
            return False

    def _write(self, s: str) -> None:
        with _print_lock:
            try:
                self.stream.write(s)
                self.stream.flush()
            except (OSError, ValueError):  # a closed or broken stream: notices are best effort
                pass

    def _run(self) -> None:
        if self._done.wait(NOTICE_AFTER):
            return
        self.shown = True
        tty = self._tty()
        self._write(f"warprt: {self.text}... " + ("" if tty else "\n"))
        while tty and not self._done.wait(1.0):
            self._write(f"\rwarprt: {self.text}... {time.perf_counter() - self.start:.0f} s")

    def __enter__(self) -> "Notice":
        self._thread.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._done.set()
        self._thread.join()
        if self.shown:
            if exc_type is not None and not issubclass(exc_type, Exception):
                # an interrupt: its own line says so (the compile's line ends here)
                self._write("\n" if self._tty() else "")
                return
            took = time.perf_counter() - self.start
            end = "failed" if exc_type is not None else "done"
            prefix = "\r" if self._tty() else ""
            self._write(f"{prefix}warprt: {self.text}: {end} in {took:.1f} s\n")


def _describe(module, device, waiting: bool = False) -> str:
    what = _LABELS.get(module.name, f"warprt's module {module.name}")
    where = "" if device is None or getattr(device, "is_cpu", False) else f" on {device}"
    if waiting:
        return f"waiting for {what}{where}, compiling in another thread (first time on this machine)"
    return f"compiling {what}{where}{_where.get()} (first time on this machine)"


@contextmanager
def compiling(module, device, block_dim):
    """Around a load of ``module`` that compiles it (``_warp._load``, whose binary is not in the
    cache): the notice, and one compile per module at a time. A module that another thread is
    compiling already is waited for, and the block then finds it in the cache."""
    key = (module.name, str(device), block_dim)
    with _inflight_lock:
        running = _inflight.get(key)
        mine = running is None
        if mine:
            running = _inflight[key] = threading.Event()
    announce = not quiet()
    if not mine:  # compiled by another thread right now: wait for it
        with Notice(_describe(module, device, waiting=True)) if announce else _nothing():
            running.wait()
        yield
        return
    try:
        with Notice(_describe(module, device)) if announce else _nothing():
            yield
    finally:
        with _inflight_lock:
            del _inflight[key]
        running.set()


@contextmanager
def _nothing():
    yield


_inflight: dict = {}  # (module name, device, block_dim) -> an Event set when its compile ends
_inflight_lock = threading.Lock()


def _block_dim(module, device) -> int:
    """The module variant a launch on ``device`` uses: a CPU launch runs blocks of one thread
    (Warp keeps a module variant per block size, each with its own binary)."""
    return 1 if device.is_cpu else module.options["block_dim"]


def _binary_cached(module, device, block_dim) -> bool:

    try:
        folder, binary, meta = cache_entry(module, device, block_dim)
        return os.path.exists(os.path.join(folder, binary)) and os.path.exists(os.path.join(folder, meta))
    except Exception:  # a Warp without these internals: say "not cached", which only costs a compile
        return False


def module_cached(module, device) -> bool:
    """Whether ``module`` (or a kernel's module) is loaded on ``device`` already, or its binary is in
    Warp's kernel cache (a load then takes milliseconds)."""
    module = getattr(module, "module", module)
    device = wp.get_device(device)
    block_dim = _block_dim(module, device)
    if module.execs.get((None if device.is_cpu else device.context, block_dim)) is not None:
        return True
    return _binary_cached(module, device, block_dim)


def load(module, device) -> float:
    """Load ``module`` on ``device`` as a launch there would (compiling it, with a notice, when
    the cache lacks it); returns the seconds it took."""
    module = getattr(module, "module", module)
    device = wp.get_device(device)
    start = time.perf_counter()
    module.load(device, _block_dim(module, device))
    return time.perf_counter() - start


def background_default() -> bool:
    """Whether renderers compile their own kernels in the background while the general kernel
    renders (``WARPRT_BACKGROUND_COMPILE=0`` turns it off: the first render then waits)."""
    return os.environ.get("WARPRT_BACKGROUND_COMPILE", "1").strip().lower() not in ("0", "false", "no", "off")


_general: dict = {}  # (module name, device) -> the general kernel's Background compile
_general_lock = threading.Lock()


def compile_general(module, device, render: tuple[str, bool] | None = None) -> None:
    """Compile the general kernel in the background (once per process and device) when Warp's
    cache lacks it, so that the next renderer with a new feature set finds it there. ``render``:
    (feature key, packets) of a render kernel (``integrator.kernels_for``), for the hand-over at
    exit (``_hand_over_compiles``)."""
    module = getattr(module, "module", module)
    device = wp.get_device(device)
    with _general_lock:
        key = (module.name, str(device))
        if key in _general or module_cached(module, device):
            return
        _general[key] = Background(module, device, render=render)


_unfinished: list = []  # render kernels' Background compiles, for the hand-over at exit
_unfinished_lock = threading.Lock()


@atexit.register
def _hand_over_compiles() -> None:
    """At exit, a render kernel still compiling in the background (the general one, or a scene's
    own while the general one renders) is compiled again by a detached process of low priority
    (``python -m warprt.compile``), which outlives this one and leaves it in Warp's kernel cache
    for the next run: a short process (one command-line render) would otherwise abandon it every
    time, and run on the general kernel every time after."""
    with _unfinished_lock:  # (emptied: the command line's exit and the exit handlers both call it)
        pending = {(bg.render, str(bg.device)) for bg in _unfinished if not bg.done()}
        _unfinished.clear()
    env = {**os.environ, "WARPRT_QUIET": "1"}
    cache = str(wp.config.kernel_cache_dir)  # (Warp's folder for its version under the cache path)
    if os.path.basename(cache) == wp.config.version:
        env["WARP_CACHE_PATH"] = os.path.dirname(cache)
    for (features, packets), device in sorted(pending):
        try:
            subprocess.Popen([sys.executable, "-m", "warprt.compile", features, str(int(packets)), device],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             env=env, start_new_session=True)
        except OSError:  # (no process to spare: the next run compiles it)
            pass


class Background:
    """``module`` compiled and loaded for ``device`` in a daemon thread of lower priority (Warp
    loads modules from several threads at once itself: ``wp.force_load``). ``ready()`` says when
    it can be launched. A compile error is kept in ``error``, and the caller stays on the kernel
    it has."""

    def __init__(self, module, device, *, notices: bool = True, render: tuple[str, bool] | None = None):
        self.module = getattr(module, "module", module)
        self.device = wp.get_device(device)
        self.render = render  # (feature key, packets) of a render kernel: handed over at exit unfinished
        if render is not None:
            with _unfinished_lock:
                _unfinished[:] = [bg for bg in _unfinished if not bg.done()] + [self]
        self.error: BaseException | None = None
        self.seconds: float | None = None
        self._notices = notices and not quiet()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="warprt-background-compile", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        start = time.perf_counter()
        try:
            if hasattr(os, "setpriority") and hasattr(threading, "get_native_id"):
                try:  # a thread is a task of its own to Linux: lower its priority alone
                    os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BACKGROUND_NICE)
                except OSError:
                    pass
            _where.set(" in the background")
            with quiet_compiles(not self._notices):
                load(self.module, self.device)
        except BaseException as e:  # kept for the caller, which keeps rendering on what it has
            self.error = e
        finally:
            self.seconds = time.perf_counter() - start
            self._done.set()

    def ready(self) -> bool:
        return self._done.is_set() and self.error is None

    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._done.wait(timeout)


def cache_entry(module, device, block_dim):
    """(folder, binary name, meta name) of ``module``'s cache entry for ``device``."""
    dev = wp.get_device(device)
    active = block_dim if block_dim is not None else module.options["block_dim"]
    folder = os.path.join(wp.config.kernel_cache_dir, module.get_module_identifier(active))
    return folder, module._get_compile_output_name(dev, block_dim=active), module._get_meta_name(block_dim=active)
