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

Ctrl-C (local, thread and process executors): the frames in flight stop within a pass, frames not
started are dropped, every frame that had finished is kept (with ``output``, written as it
finished), frames cut short are neither written nor returned, and
:class:`warprt.errors.FramesInterrupted` (a ``KeyboardInterrupt``) is raised, listing the complete
frames (``.frames``) with their images or paths (``.results``). Process-pool workers ignore SIGINT
themselves (a terminal sends it to them too); the parent tells them to stop.

Every executor gives the same images bit for bit: frame f is rendered with seed ``seed + f``
(:func:`warprt.animation.frame_seed`) and the image depends only on the scene, the seed and spp.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed

from .animation import check_frames, check_pattern, frame_path, frame_scene, frame_seed, frame_write_failed, keep_frame, render_sequence
from .errors import FramesInterrupted, RenderError, WriteError
from .image import check_output
from .render import Renderer, _CtrlC, check_seed
from .scene.description import Scene

EXECUTORS = ("local", "thread", "process", "ray")


_STOP = None  # in a process-pool worker: the parent's stop event


def _init_process_worker(stop) -> None:
    """A process-pool worker ignores SIGINT (a terminal's Ctrl-C reaches the whole process group)
    and SIGTERM (Slurm sends it to every process of the job), and stops its render when the
    parent sets ``stop``: the parent decides what is kept."""
    import signal

    global _STOP
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _STOP = stop


def _render_frame(scene: Scene, frame: int, spp, seed: int, device, workers, stop=None):
    """Render one frame (runs inside a worker: thread, process or Ray task): (image, spp,
    interrupted, metadata)."""
    r = Renderer(frame_scene(scene, frame), device=device).render(
        spp=spp, seed=frame_seed(seed, frame), workers=workers, progress=False,
        stop=stop if stop is not None else _STOP)
    return r.image, r.spp, r.interrupted, r.metadata


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def render_frames(scene: Scene, frames=None, spp: int | None = None, seed: int = 0, executor: str = "local",
                  max_workers: int | None = None, device: str | None = None,
                  render_workers: int | None = None, output: str | None = None) -> list:
    """Render ``frames`` (default: all of ``scene.animation``) and return their images in order.

    ``max_workers`` bounds frames in flight for thread/process pools; ``render_workers`` sets the
    tile threads inside each render (default: all cores; with several frames in flight on one
    machine, 1 avoids oversubscription). With ``output`` (a pattern such as ``out/f_####.png``,
    see :func:`warprt.animation.frame_path`) each frame is written as soon as it finishes and the
    paths are returned. Ctrl-C raises :class:`warprt.errors.FramesInterrupted` after keeping the
    finished frames (see the module docstring).
    """
    if not isinstance(scene, Scene):
        raise RenderError(f"render_frames() needs a warprt.Scene, got {type(scene).__name__}")
    if executor not in EXECUTORS:
        raise RenderError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if executor == "local":  # (it checks the frames, the seed and the output itself)
        return render_sequence(scene, output=output, frames=frames, spp=spp, seed=seed, device=device,
                               progress=False)
    frames = check_frames(scene, frames)
    check_seed(seed)
    for name, value in (("max_workers", max_workers), ("render_workers", render_workers)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise RenderError(f"{name} must be a positive integer, got {value!r:.60}")
    if output is not None:
        check_pattern(output)
        check_output(frame_path(output, frames[0]), create_folders=True)  # before any rendering
    if executor == "ray":
        if not ray_available():
            raise RenderError("executor='ray' needs Ray: pip install 'warprt[ray]'")
        import ray

        if not ray.is_initialized():
            ray.init(num_cpus=max_workers, include_dashboard=False, log_to_driver=False)
        env = {k: os.environ[k] for k in ("WARP_CACHE_PATH", "WARPRT_CACHE_DIR") if k in os.environ}
        task = ray.remote(_render_frame).options(runtime_env={"env_vars": env} if env else None)
        scene_ref = ray.put(scene)
        rendered = ray.get([task.remote(scene_ref, f, spp, seed, device, render_workers) for f in frames])
        return [keep_frame(output, f, image, n, meta) for f, (image, n, _, meta) in zip(frames, rendered)]
    if executor == "thread":
        stop = threading.Event()
        pool = ThreadPoolExecutor(max_workers=max_workers)
    else:  # fresh interpreters: no forked copy of this process's Warp runtime or threads
        ctx = multiprocessing.get_context("spawn")
        stop = ctx.Event()
        pool = ProcessPoolExecutor(max_workers=max_workers, mp_context=ctx, initializer=_init_process_worker,
                                   initargs=(stop,))
    kept: dict[int, object] = {}
    cut_short: list[int] = []

    def collect(fut, f) -> None:
        image, n, interrupted, meta = fut.result()
        if interrupted:
            cut_short.append(f)
            return
        with _CtrlC() as ctrl_c:  # a Ctrl-C while writing lets the frame be written (and kept) first
            try:
                kept[f] = keep_frame(output, f, image, n, meta)
            except WriteError as e:  # a full disk: stop (the next frames would fail too)
                raise frame_write_failed(e, f, frames, [g for g in frames if g in kept]) from None
        if ctrl_c.pressed:
            raise KeyboardInterrupt

    futures = {}
    try:
        for f in frames:
            futures[pool.submit(_render_frame, scene, f, spp, seed, device, render_workers,
                                stop if executor == "thread" else None)] = f
        for fut in as_completed(futures):
            collect(fut, futures[fut])
            if cut_short:  # a worker's render stopped by itself: treat it as Ctrl-C
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        stop.set()
        with _CtrlC():  # the renders in flight stop within a pass; keep those that had finished
            pool.shutdown(wait=True, cancel_futures=True)
            for fut, f in futures.items():
                if f in kept or f in cut_short or fut.cancelled() or fut.exception() is not None:
                    continue
                collect(fut, f)
        complete = [f for f in frames if f in kept]
        not_started = [f for f in frames if f not in kept and f not in cut_short]
        raise FramesInterrupted(complete, [kept[f] for f in complete], cut_short, total=len(frames),
                                not_started=not_started) from None
    finally:
        stop.set()  # on an error too: no frame keeps rendering for nothing
        pool.shutdown(wait=True, cancel_futures=True)
    return [kept[f] for f in frames]
