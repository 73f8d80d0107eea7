"""Import and initialise Warp once, with warprt's settings.

The kernel cache goes where ``WARP_CACHE_PATH`` (or ``WARPRT_CACHE_DIR``) says; the Makefile points
it inside the repository (``.cache/warp``) so a fresh clone compiles into a folder it owns. A
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
"""

from __future__ import annotations

import functools
import os
import threading
from typing import Callable, TypeVar

import warp as wp

T = TypeVar("T")

#: options of every Warp module warprt compiles (see the module docstring)
MODULE_OPTIONS = {"fuse_fp": False}
#: warprt's shared Warp modules (its other kernels have a module of their own, ``module="unique"``,
#: and pass ``module_options=MODULE_OPTIONS``)
SHARED_MODULES = ("warprt_accel", "warprt_aov", "warprt_build", "warprt_film", "warprt_newton",
                  "warprt_query", "warprt_worlds")
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
            if wp.config.quiet:
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
