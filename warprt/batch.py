"""Batch rendering: many frames (or many scenes) on an executor.

Frames are independent, so batches go to an existing engine rather than a home-made scheduler:

* ``executor="ray"``: one Ray task per frame (``pip install warprt[ray]``). Call ``ray.init()``
  first to choose the cluster (``ray.init(address="ray://head:10001")`` for a remote one, or
  ``address="auto"`` on a cluster node); without an initialised Ray, a local instance is started.
  The workers need warprt installed in the same environment.
* ``executor="process"``: a local process pool (one process per frame in flight).
* ``executor="thread"``: a local thread pool.
* ``executor="local"``: frames one after another in this process, reusing one Renderer (the
  fastest choice on one machine: each render already spreads its tiles over every core).

Every executor gives the same images bit for bit: frame f is rendered with seed ``seed + f``
(:func:`warprt.animation.frame_seed`) and the image depends only on the scene, the seed and spp.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

import numpy as np

from .animation import check_frames, frame_scene, frame_seed, render_sequence
from .errors import RenderError
from .render import Renderer, check_seed
from .scene.description import Scene

EXECUTORS = ("local", "thread", "process", "ray")


def _render_frame(scene: Scene, frame: int, spp, seed: int, device, workers) -> np.ndarray:
    """Render one frame (runs inside a worker: thread, process or Ray task)."""
    return Renderer(frame_scene(scene, frame), device=device).render(
        spp=spp, seed=frame_seed(seed, frame), workers=workers, progress=False).image


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def render_frames(scene: Scene, frames=None, spp: int | None = None, seed: int = 0, executor: str = "local",
                  max_workers: int | None = None, device: str | None = None,
                  render_workers: int | None = None) -> list[np.ndarray]:
    """Render ``frames`` (default: all of ``scene.animation``) and return their images in order.

    ``max_workers`` bounds frames in flight for thread/process pools; ``render_workers`` sets the
    tile threads inside each render (default: all cores; with several frames in flight on one
    machine, 1 avoids oversubscription).
    """
    if not isinstance(scene, Scene):
        raise RenderError(f"render_frames() needs a warprt.Scene, got {type(scene).__name__}")
    if executor not in EXECUTORS:
        raise RenderError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    frames = check_frames(scene, frames)
    check_seed(seed)
    if executor == "local":
        return render_sequence(scene, frames=frames, spp=spp, seed=seed, device=device, progress=False)
    if executor == "ray":
        if not ray_available():
            raise RenderError("executor='ray' needs Ray: pip install 'warprt[ray]'")
        import ray

        if not ray.is_initialized():
            ray.init(num_cpus=max_workers, include_dashboard=False, log_to_driver=False)
        env = {k: os.environ[k] for k in ("WARP_CACHE_PATH", "WARPRT_CACHE_DIR") if k in os.environ}
        task = ray.remote(_render_frame).options(runtime_env={"env_vars": env} if env else None)
        scene_ref = ray.put(scene)
        return ray.get([task.remote(scene_ref, f, spp, seed, device, render_workers) for f in frames])
    if executor == "thread":
        pool = ThreadPoolExecutor(max_workers=max_workers)
    else:  # fresh interpreters: no forked copy of this process's Warp runtime or threads
        pool = ProcessPoolExecutor(max_workers=max_workers, mp_context=multiprocessing.get_context("spawn"))
    with pool:
        futures = [pool.submit(_render_frame, scene, f, spp, seed, device, render_workers) for f in frames]
        return [fut.result() for fut in futures]
