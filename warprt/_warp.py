"""Import and initialise Warp once, with warprt's settings.

The kernel cache goes where ``WARP_CACHE_PATH`` (or ``WARPRT_CACHE_DIR``) says; the Makefile points
it inside the repository (``.cache/warp``) so a fresh clone compiles into a folder it owns.
Backward (adjoint) code is never generated for warprt's own kernels (each is declared with
``enable_backward=False``: warprt does not differentiate, and skipping it halves compile time);
Warp's process-wide settings are left as the host application set them.

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
        if wp.config.quiet:
            _init_without_native_chatter()
        else:
            wp.init()
        _ready = True


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
