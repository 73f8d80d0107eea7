"""Import and initialise Warp once, with warprt's settings.

The kernel cache goes where ``WARP_CACHE_PATH`` (or ``WARPRT_CACHE_DIR``) says; the Makefile points
it inside the repository (``.cache/warp``) so a clone compiles into a folder it owns. A
cache folder that cannot be created or written to is a :class:`warprt.RenderError` naming it (the
CLI prints it in one line and exits 2), raised before anything is built or compiled.
Backward (adjoint) code is never generated for warprt's own kernels (each is declared with
``enable_backward=False``: warprt does not differentiate, and skipping it halves compile time);
Warp's process-wide settings are left as the host application set them.

Every warprt module compiles with ``fuse_fp=False`` (:data:`MODULE_OPTIONS`): no multiply-add
contraction into FMAs. Warp's CPU compiler contracts nothing in its generated code either way,
but NVRTC's default (``--fmad=true``) fuses across statements, and on CUDA that made a kernel's
rounding depend on what the compiler chose to fuse: a scene-specialised kernel no longer matched
the full one bit for bit, and rays aimed exactly at mesh vertices and axis-aligned edges leaked
through Warp's mesh query 2-4x as often as it let them through on the CPU (the same rates come
back on the CPU when its compiler is told ``-ffp-contract=fast``). Without contraction every
operation rounds once, as the CPU does, on every device.

``build_once`` is the one way kernels and device-function sets are cached: per argument value,
built under a lock so that threads never build the same module twice.

Warp's loading of warprt's own modules is wrapped (:func:`_load`, over ``Module.load``; other
modules are left to Warp): a compile is announced after a second and done once however many
threads ask (``warprt.kernels.compiling``); a damaged cache entry (a truncated or empty binary, an empty or
invalid ``.meta``: a disk that filled up, a copy cut short) is moved aside, compiled again and
reported in one warning line, instead of failing every later run; and a compile cut short by
Ctrl-C removes the temporary build folder Warp leaves behind (``<entry>_p<pid>_t<thread>``).
"""

from __future__ import annotations

import functools
import os
import threading
from typing import Callable, TypeVar

import warp as wp

from . import kernels

T = TypeVar("T")

#: options of every Warp module warprt compiles (see the module docstring)
MODULE_OPTIONS = {"fuse_fp": False}
#: warprt's shared Warp modules (its other kernels have a module of their own, ``module="unique"``,
#: and pass ``module_options=MODULE_OPTIONS``)
SHARED_MODULES = ("warprt_accel", "warprt_aov", "warprt_build", "warprt_checks", "warprt_film", "warprt_newton",
                  "warprt_query", "warprt_sensor", "warprt_worlds")
for _name in SHARED_MODULES:
    wp.set_module_options(MODULE_OPTIONS, module=_name)

_lock = threading.Lock()
_ready = False
if os.environ.get("WARPRT_VERBOSE") is None:
    wp.config.quiet = True
    wp.config.log_level = wp.LOG_ERROR


def init() -> None:
    global _ready
    if _ready:
        return
    with _lock:
        if _ready:
            return
        cache = os.environ.get("WARPRT_CACHE_DIR")
        if cache and wp.config.kernel_cache_dir is None:
            wp.config.kernel_cache_dir = cache
        try:
            if getattr(wp.config, "quiet", False):  # (unset unless warprt set it)
                _init_without_native_chatter()
            else:
                wp.init()
        except OSError as e:  # Warp creates its kernel cache folder during init
            raise _cache_error(e.filename or wp.config.kernel_cache_dir or os.environ.get("WARP_CACHE_PATH"),
                               e) from None
        _check_cache_writable(wp.config.kernel_cache_dir)
        _ready = True


def _cache_error(folder, e: OSError):
    from .errors import RenderError

    return RenderError(f"Warp's kernel cache folder {os.fspath(folder)!r} cannot be used "
                       f"({e.strerror or e}); set WARP_CACHE_PATH to a folder you can write to")


def _check_cache_writable(folder) -> None:
    """Kernels are compiled into ``folder``: create a file there now (the only sure test), rather
    than fail inside Warp's build at the first compile."""
    import tempfile

    if not folder:
        return
    try:
        fd, probe = tempfile.mkstemp(prefix=".warprt.", suffix=".probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise _cache_error(folder, e) from None


def _init_without_native_chatter() -> None:
    """wp.init() with the native library's start-up notes (e.g. "no CUDA driver") kept off stderr.
    Python exceptions still propagate; only file descriptor 2 is silenced during the call."""
    import sys

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        wp.init()
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


# --- the kernel cache: damaged entries, compiles cut short ------------------------------------------

_ELF_MAGIC = b"\x7fELF"


def _is_ours(module) -> bool:
    """A module of warprt's (shared ``warprt_*`` modules, or unique ones of warprt's kernels)."""
    if str(getattr(module, "name", "")).startswith("warprt"):
        return True
    kernels = list(getattr(module, "kernels", {}).values())
    return any(str(getattr(getattr(k, "func", None), "__module__", "")).startswith("warprt.") for k in kernels)


def cache_damage(folder: str, binary: str, meta: str) -> str | None:
    """What is wrong with the cache entry ``folder`` (its ``binary`` and ``meta`` file names), or
    None if nothing visible: an empty or truncated binary (an ELF object or cubin whose section
    table lies past the end of the file), an empty or invalid ``.meta``. A missing file is no
    damage: Warp compiles what an entry lacks (one entry holds a binary per device kind)."""
    import json
    import struct

    if not os.path.isdir(folder):
        return None
    try:
        with open(os.path.join(folder, meta), encoding="utf-8") as f:
            data = json.load(f)
        if not isinstance(data, dict):
            return f"{meta} holds no module metadata"
    except FileNotFoundError:
        return None
    except (ValueError, OSError, UnicodeDecodeError) as e:
        return f"{meta} is not valid JSON ({e.__class__.__name__})"
    path = os.path.join(folder, binary)
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(64)
    except FileNotFoundError:
        return None
    except OSError as e:
        return f"{binary} cannot be read ({e.strerror or e})"
    if size == 0:
        return f"{binary} is empty"
    if binary.endswith((".o", ".cubin")):
        if head[:4] != _ELF_MAGIC or len(head) < 64:
            return f"{binary} is not an object file"
        if head[4] == 2:  # ELFCLASS64: e_shoff at 0x28, e_shentsize and e_shnum at 0x3A
            order = "<" if head[5] == 1 else ">"
            shoff = struct.unpack_from(order + "Q", head, 0x28)[0]
            shentsize, shnum = struct.unpack_from(order + "HH", head, 0x3A)
            if shoff + shentsize * shnum > size:
                return f"{binary} is truncated ({size} bytes, its section table ends at {shoff + shentsize * shnum})"
    return None


def _remove_build_folders() -> None:
    """Remove the temporary build folders of this thread's compiles (Warp builds module M in
    ``M_p<pid>_t<thread>`` and renames it into place when done; an interrupt between leaves it)."""
    import glob
    import shutil

    cache = wp.config.kernel_cache_dir
    if not cache:
        return
    for folder in glob.glob(os.path.join(glob.escape(cache), f"*_p{os.getpid()}_t{threading.get_ident()}")):
        shutil.rmtree(folder, ignore_errors=True)


def _move_aside(folder: str) -> str:
    from .errors import RenderError

    for n in range(100):
        aside = f"{folder}.damaged{'' if n == 0 else f'.{n}'}"
        if os.path.lexists(aside):
            continue
        try:
            os.rename(folder, aside)
            return aside
        except FileNotFoundError:  # another process moved it first
            return aside
        except OSError as e:
            raise RenderError(f"Warp's kernel cache entry {folder!r} is damaged and cannot be moved aside "
                              f"({e.strerror or e}); delete it") from None
    raise RenderError(f"Warp's kernel cache entry {folder!r} is damaged; delete it and its .damaged copies")


_warp_load = None  # Warp's own Module.load, wrapped by _load


def _set_aside(folder: str, damage: str) -> None:
    import warnings

    aside = _move_aside(folder)
    warnings.warn(f"Warp's kernel cache entry {folder} was damaged ({damage}): moved to {aside} and "
                  "compiled again", RuntimeWarning, stacklevel=4)


def _load(self, device, block_dim=None, binary_path=None, output_arch=None, meta_path=None):
    """``Module.load`` for warprt's modules: a damaged cache entry is moved aside and compiled
    again (one warning), a compile cut short leaves no build folder (see the module docstring).
    A module already loaded (every launch asks) goes straight to Warp."""
    ours = self.__dict__.get("_warprt_ours")
    if ours is None:
        ours = self._warprt_ours = _is_ours(self)
    if binary_path is not None or not ours or not wp.config.kernel_cache_dir:
        return _warp_load(self, device, block_dim, binary_path, output_arch, meta_path)
    try:
        dev = wp.get_device(device)
        if self.execs.get((dev.context, block_dim if block_dim is not None else self.options["block_dim"])):
            return _warp_load(self, device, block_dim)
        # about to load from the cache (or compile): look at the entry first, so that a damaged one
        # is compiled again rather than handed to the native loader
        folder, binary, meta = kernels.cache_entry(self, dev, block_dim)
        damage = cache_damage(folder, binary, meta)
        if damage is not None:
            _set_aside(folder, damage)
        compiles = not (os.path.isfile(os.path.join(folder, binary)) and os.path.isfile(os.path.join(folder, meta)))
        try:
            if compiles:
                # announced after a second, and compiled once however many threads ask
                with kernels.compiling(self, dev, block_dim):
                    if dev.is_cpu and _interruptible():
                        return _compile_in_thread(self, device, block_dim)
                    return _warp_load(self, device, block_dim)
            return _warp_load(self, device, block_dim)
        except Exception as e:
            # a binary the loader refused although it looked whole
            if not (os.path.isdir(folder) and str(e).startswith(("Failed to load CPU module",
                                                                 "Failed to load CUDA module"))):
                raise
            _set_aside(folder, f"{binary} could not be loaded")
            return _warp_load(self, device, block_dim)
    except BaseException as e:  # KeyboardInterrupt, SystemExit: a compile cut short leaves its build folder
        if not isinstance(e, Exception):
            _remove_build_folders()
        raise


_abandoned: list[threading.Event] = []  # compiles the command line stopped waiting for (set: done)


def _interruptible() -> bool:
    """Whether a compile may run in a thread of its own, the main thread waiting for it ready to
    take a Ctrl-C: only in the command line (an interrupt then ends the process, see
    :func:`abandoned_compiles`), from its main thread."""
    from .signals import in_program

    return in_program() and threading.current_thread() is threading.main_thread()


def _compile_in_thread(module, device, block_dim):
    """Warp's load (a compile: seconds of native code that no signal interrupts) in a daemon
    thread; the main thread waits in steps of 50 ms, so a Ctrl-C stops the command at once. The
    compile is then abandoned: the process exits next, without waiting for it."""
    box: dict = {}
    done = threading.Event()  # (not Thread.join: a KeyboardInterrupt inside join makes Python 3.11
    # mark the thread stopped while it still runs)

    def work():
        try:
            box["exec"] = _warp_load(module, device, block_dim)
        except BaseException as e:  # (handed to the waiting thread)
            box["error"] = e
        finally:
            done.set()

    threading.Thread(target=work, name="warprt-compile", daemon=True).start()
    try:
        while not done.wait(0.05):
            pass
    except BaseException:
        _abandoned.append(done)
        raise
    if "error" in box:
        raise box["error"]
    return box["exec"]


def abandoned_compiles() -> bool:
    """Whether a compile is still running that the command line stopped waiting for; if so, its
    build folders are removed now (the command exits next, with ``os._exit``: a normal exit would
    wait for the compile, or tear the runtime down under it)."""
    import glob
    import shutil

    running = [done for done in _abandoned if not done.is_set()]
    if not running:
        return False
    cache = wp.config.kernel_cache_dir
    if cache:
        for _ in range(3):  # (a file the compile creates meanwhile: another pass)
            folders = glob.glob(os.path.join(glob.escape(cache), f"*_p{os.getpid()}_t*"))
            if not folders:
                break
            for folder in folders:
                shutil.rmtree(folder, ignore_errors=True)
    return True


def _install_load_hook() -> None:
    global _warp_load
    from warp._src.context import Module

    if getattr(Module.load, "_warprt", False):
        return
    _warp_load = Module.load
    _load._warprt = True  # type: ignore[attr-defined]
    Module.load = _load


_install_load_hook()


def resolve_device(device: str | None) -> "wp.context.Device":
    """The Warp device for a ``device=`` argument, with a clear error when it is not available."""
    from .errors import RenderError

    init()
    if device is None:
        return wp.get_device("cpu") if not wp.is_cuda_available() else wp.get_device("cuda:0")
    try:
        return wp.get_device(device)
    except Exception as e:  # Warp raises RuntimeError/ValueError depending on the name
        available = ", ".join(d.alias for d in wp.get_devices())
        raise RenderError(f"device {device!r} is not available ({e}); available: {available}") from None


def build_once(factory: Callable[..., T]) -> Callable[..., T]:
    """Cache ``factory``'s result per (hashable) arguments, built once even when threads ask at
    the same time. Kernel factories are keyed by a small finite set (``Features`` values, or
    nothing), so the cache is bounded by construction. ``.built()`` lists the keys built so far."""
    cache: dict = {}
    lock = threading.Lock()

    @functools.wraps(factory)
    def get(*key):
        with lock:
            if key not in cache:
                cache[key] = factory(*key)
            return cache[key]

    get.built = lambda: list(cache)  # type: ignore[attr-defined]
    return get
