"""Render a scene: build it on a device, pick its kernel, run passes over the frame, return the image.

Parallelism: a Warp launch on the CPU runs on one core, so each pass is one launch per worker
thread (a pool, one per core, kept by the renderer), and the launches take blocks of SLICE_BLOCK
consecutive rows in turn from a counter in the film (``film.claim_block``) until the frame is
done: a core slowed down by other work takes fewer blocks, and the workers finish within a block
of each other. With ``slices=S`` a pass is instead S fixed interleaved sets of blocks (slice j
holds blocks j, j + S, j + 2S, ...) that the workers take from a queue. The rows of a block,
taken in turn by one thread (in scenes with meshes a block of 4 rows column by column:
``integrator.render_kernel``), find in the caches the tree nodes and triangles the pixels
before brought there; each launch is recorded once per render and
replayed with new sample bounds, so a pass costs a few microseconds of Python. On CUDA each pass
is one launch over the whole frame. A thread owns a pixel for the whole pass and adds its
samples in order, and every random number depends only on (seed, pixel, sample, dimension): the
image is bit-identical for any worker count, slices or pass split, whichever thread takes a block.

Progressive rendering: the samples are split into passes (a renderer's very first pass is one
sample per pixel, to time one; every later pass, in that render or the next, is sized to take
about half a second from the time per sample last measured). ``time_budget`` stops after the pass that reaches
the budget, ``target_error`` after the pass whose estimated relative standard error falls below
it; Ctrl-C finishes the running pass and returns what was accumulated (during the passes, SIGINT
only sets a flag read between passes: see ``_CtrlC``). ``RenderResult.spp`` says
how many samples per pixel the image holds.
"""

from __future__ import annotations

import os
import sys
import threading
import time as _time
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import _warp, fast, kernels, splitting
from .aov import AovTarget, no_aovs
from .build import DeviceScene, render_params
from .camera import camera_data
from .errors import RenderError
from .film import NO_LIMIT, Film, adaptive_counts
from .integrator import kernels_for, packets_for
from .trace import PACKET
from .memory import check_memory
from .records import GENERAL_FEATURES, Features
from .results import Displayed, RenderLayers, scene_camera_matrices, scene_metadata
from .scene.description import SPP_LIMIT, SPP_LIMIT_HINT, Scene
from .sensor import apply_depth_sensor, eye_poses, split_aovs
from .signals import Deferred


SEED_LIMIT = 1 << 32  # seeds are 32-bit: 0 <= seed < 2^32


def check_seed(seed, name: str = "seed") -> int:
    """``seed`` if it is an integer in [0, 2^32): the kernels hash a 32-bit seed, and taking a
    larger or negative one modulo 2^32 would silently give another seed's image."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise RenderError(f"{name} must be an integer, got {seed!r}")
    if not 0 <= seed < SEED_LIMIT:
        raise RenderError(f"{name} must be in [0, 2^32 - 1 = {SEED_LIMIT - 1}], got {seed}")
    return int(seed)


@dataclass
class RenderResult(Displayed):
    """One render: the image, its AOVs, the samples per pixel, the statistics and what
    reproduces it; ``metadata`` is what :func:`warprt.save_image` writes with it (see
    :mod:`warprt.results`), and a notebook shows it as its image."""

    image: np.ndarray  # (H, W, 3) float32 linear radiance, row 0 at the top (a wp.array with as_warp)
    spp: int  # samples per pixel in the image
    wall_time: float  # seconds spent in the passes (excludes build and compile)
    rays: int  # camera, secondary and shadow rays traced
    stack_overflows: int  # rays dropped because a pixel's ray stack was full
    features: Features
    device: str
    interrupted: bool = False  # stopped by Ctrl-C
    relative_error: float | None = None  # estimated relative standard error of the mean
    aovs: dict = field(default_factory=dict)  # requested AOVs (see warprt.aov), averaged over the image's samples
    # what reproduces the image bit for bit (see ``reproduction``): the sample count the sampler's
    # pattern was laid out for (``render(planned_spp=...)``), the samples of each pass in order,
    # and why the passes stopped before ``planned_spp`` ("time_budget", "target_error",
    # "interrupt"; None when they ran to the end)
    planned_spp: int = 0
    passes: tuple = ()
    stopped_by: str | None = None
    seed: int = 0
    sampler: str = ""
    adaptive: bool = False
    kernel_load: float = 0.0  # seconds spent loading (or compiling) a kernel before the first pass
    general_passes: int = 0  # passes run on the general kernel while the scene's own compiled
    scene: Scene | None = field(default=None, repr=False, compare=False)  # the scene rendered (for metadata)

    @property
    def metadata(self) -> dict:
        """What :func:`warprt.save_image` writes with the image (:mod:`warprt.results`): the
        reproduction keys, ``warprt:partial`` for an interrupted render, and from the scene the
        camera matrices, the background and the id AOVs' name tables."""
        meta = self.reproduction()
        if self.interrupted:
            meta["warprt:partial"] = "true"
        if self.scene is not None:
            to_camera, to_ndc = scene_camera_matrices(self.scene.camera)
            meta.update(worldToCamera=to_camera, worldToNDC=to_ndc)
            meta.update(scene_metadata(self.scene, self.aovs))
        return meta

    def reproduction(self) -> dict:
        """What reproduces this image bit for bit, as image metadata (``warprt_*`` keys; the CLI
        writes them into every file): seed, sampler, samples per pixel, the pattern's planned
        count, the pass sizes (they never change the image) and why it stopped; with
        ``warprt_reproduce`` the ``warprt render`` options that give the same bits from the same
        scene file (``--spp N --planned-spp P --no-adaptive --seed S --sampler X`` for a uniform
        image stopped by a time budget, a target error or Ctrl-C; ``--spp N --adaptive ...`` for a
        complete adaptive one). An adaptive image stopped part way (Ctrl-C, ``stop``) also depends on
        the counts its pilot chose and when it stopped, which no options name: it has no
        ``warprt_reproduce``."""
        meta = {"warprt_spp": self.spp, "warprt_seed": self.seed, "warprt_sampler": self.sampler,
                "warprt_planned_spp": self.planned_spp,
                "warprt_passes": "+".join(str(p) for p in self.passes),
                "warprt_interrupted": int(self.interrupted)}
        if self.stopped_by:
            meta["warprt_stopped_by"] = self.stopped_by
        if not self.adaptive:  # (an adaptive image stopped part way depends on its counts too)
            args = f"--spp {self.spp}"
            if self.planned_spp != self.spp:
                args += f" --planned-spp {self.planned_spp}"
            meta["warprt_reproduce"] = f"{args} --no-adaptive --seed {self.seed} --sampler {self.sampler}"
        elif not self.stopped_by:
            meta["warprt_reproduce"] = f"--spp {self.planned_spp} --adaptive --seed {self.seed} --sampler {self.sampler}"
        return meta

    @property
    def mrays_per_s(self) -> float:
        return self.rays / self.wall_time / 1e6 if self.wall_time > 0 else float("nan")


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


S0_ARG = 5  # position of s0 (then s1) among the render kernel's arguments
PARAMS_ARG = 2  # position of the render's parameters (RenderParams)
AOV_ARG = 10  # position of the render's AOV buffers (aov.AovData)
ADAPTIVE_MIN_SPP = 2  # below this budget adaptive sampling renders uniformly (1 spp: nothing to share)
ADAPTIVE_PILOT_FRACTION = 2  # the pilot is the first spp / 2 samples of every pixel
# interleaved sets of rows per worker where a pass is cut into fixed slices: the light-splitting
# pilot's (Renderer.light_samples), and a render's (or a batch's) whose threads take less than a
# row each (spare slices absorb a slow core)
SLICES_PER_WORKER = 4
# consecutive rows a thread takes at a time: one after another on one thread, a block's rows find
# the tree nodes and triangles the row above used still in the caches, which rows taken far apart
# do not (``row_blocks`` in ``warprt.fast``)
SLICE_BLOCK = 4


def pixels_per_thread(device, width: int) -> int:
    """Pixels one thread of a render launch takes, consecutive in a row: a whole row on the CPU
    (a CPU launch copies its arguments, the ~1 KB scene record among them, for every thread:
    once per row instead of once per pixel; ``row_threads`` in ``warprt.fast``), one on CUDA
    (every pixel its own GPU thread)."""
    return width if device.is_cpu else 1


def _slices(width: int, height: int, count: int, most: int = SLICE_BLOCK) -> list[tuple[int, int, int, int]]:
    """(first row, stride, block, pixels) of each of ``count`` interleaved slices of the frame:
    slice j holds blocks j, j + count, ... of ``block`` consecutive rows (``most``, fewer
    where the frame has too few rows for a block per slice), its first rows ``stride`` rows apart
    (the render kernels' ``row0``, ``stride``, ``block``)."""
    count = max(1, min(count, height))
    block = max(1, min(most, height // count))
    n_blocks = -(-height // block)
    count = min(count, n_blocks)
    out = []
    for j in range(count):
        rows = sum(min(block, height - b * block) for b in range(j, n_blocks, count))
        out.append((j * block, count * block, block, width * rows))
    return out


def run_pass(pool: ThreadPoolExecutor, launches: list, workers: int, s0: int, s1: int) -> None:
    """Run samples [s0, s1) on every recorded slice launch (whose sample bounds are arguments
    S0_ARG and S0_ARG + 1), from the pool's worker threads (also with one worker, so that a Ctrl-C
    reaching the main thread never splits a launch). A KeyboardInterrupt (only raised here when
    the SIGINT handler could not be installed, see _CtrlC) is held until the pass is complete, so
    every pixel holds the same number of samples."""
    stop_now = False
    next_slice = iter(launches)
    lock = threading.Lock()
    errors: list[BaseException] = []

    def work():
        while True:
            with lock:
                cmd = next(next_slice, None)
            if cmd is None or errors:
                return
            try:
                cmd.set_param_at_index(S0_ARG, s0)
                cmd.set_param_at_index(S0_ARG + 1, s1)
                cmd.launch()
            except BaseException as e:  # surfaced in the caller
                errors.append(e)
                return

    futures = [pool.submit(work) for _ in range(min(workers, len(launches)))]
    for f in futures:
        while True:
            try:
                f.result(timeout=0.1)
                break
            except FuturesTimeout:
                continue
            except KeyboardInterrupt:
                stop_now = True
    if errors:
        raise errors[0]
    if stop_now:
        raise KeyboardInterrupt


class WorkerPool:
    """A pool of worker threads kept from one render to the next (remade when the worker count
    changes); its threads stop on ``close()`` or when the pool is garbage-collected."""

    def __init__(self, prefix: str):
        self._prefix = prefix
        self._pool: ThreadPoolExecutor | None = None
        self._size = 0

    def get(self, workers: int) -> ThreadPoolExecutor:
        if self._pool is None or self._size != workers:
            self.close()
            self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=self._prefix)
            self._size = workers
        return self._pool

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __del__(self):
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False)


class _CtrlC(Deferred):
    """Ctrl-C during the pass loop, race-free: while the block runs, a SIGINT (and, in the command
    line, a SIGTERM) only sets ``pressed``, read by the loop after each pass, so no
    KeyboardInterrupt can arrive between a pass and its bookkeeping and lose the samples
    (:class:`warprt.signals.Deferred`: installed only from the main thread and only over Python's
    default handler or the command line's; a host application's handler, or an ignored SIGINT,
    is left alone; the previous handler is restored on exit)."""


class Renderer:
    """A scene built on one device, ready to render any number of times.

    ``features`` may name a superset of what the scene needs (e.g. ``Features.full()``) to run
    a more general kernel; by default the kernel is specialised to the scene. ``packets``: camera
    rays 8 at a time (the CPU's default) or one by one (CUDA's), see
    :func:`warprt.integrator.packets_for`; the images are the same bit for bit, only the speed
    differs. ``fast_off``: names of CPU speed mechanisms to switch off (``warprt.fast``), besides
    those the environment (``WARPRT_FAST_OFF``) and any enclosing ``warprt.fast.disabled`` switch
    off; the renderer keeps the set it starts with (``fast_off``). The images are the same bit for
    bit.

    ``background_compile`` (default: on, unless ``WARPRT_BACKGROUND_COMPILE=0``): when the
    scene's kernel is not in Warp's cache yet but the general kernel (``Features.full()``) is, a
    render starts at once on the general kernel while the scene's own compiles in a background
    thread, and the passes after it is ready run on it (``warprt.kernels``). The image is the
    same bit for bit. Off, or with neither kernel cached, the first render waits for the scene's
    kernel to compile (announced on stderr after a second). :meth:`compile` always loads the
    scene's own kernel.
    """

    def __init__(self, scene: Scene, device: str | None = None, features: Features | None = None,
                 packets: bool | None = None, background_compile: bool | None = None, fast_off=()):
        if not isinstance(scene, Scene):
            raise RenderError(f"render() needs a warprt.Scene, got {type(scene).__name__}")
        if packets is not None and not isinstance(packets, bool):
            raise RenderError(f"packets must be True, False or None (the device's choice), got {packets!r}")
        if features is not None and not isinstance(features, Features):
            raise RenderError(f"features must be a warprt.Features (e.g. Features.full()), got {features!r:.60}")
        if device is not None and not isinstance(device, str) and not hasattr(device, "is_cpu"):
            raise RenderError(f"device must be a name such as 'cpu' or 'cuda:0', got {device!r:.60}")
        if background_compile is not None and not isinstance(background_compile, bool):
            raise RenderError(f"background_compile must be True, False or None, got {background_compile!r:.60}")
        #: the speed mechanisms switched off (warprt.fast), with those that run inside them
        self.fast_off: frozenset = fast.current(fast_off)
        self.device = _warp.resolve_device(device)
        #: camera rays in packets (the CPU's default) or one by one (CUDA's): the same images
        self.packets = packets_for(self.device) if packets is None else packets
        if packets is None and "camera_packets" in self.fast_off:  # (warprt.fast: the one-by-one kernel)
            self.packets = False
        self.scene = scene
        self.built = DeviceScene(scene, self.device, fast_off=self.fast_off)
        self.built.refresh_bins()  # (the camera's bins of large meshes, built with the scene)
        self.features = self.built.features if features is None else self.built.features.union(features)
        self.kernel = kernels_for(self.features, self.packets).render  # the scene's own kernel
        self._loaded = None  # the kernel loaded on the device by compile() (or in the background)
        self._running = None  # the kernel the passes launch: the scene's own, or the general one meanwhile
        self._background = None  # the scene's kernel compiling in the background (kernels.Background)
        self._general_passes = 0  # the last render's passes on the general kernel
        self._background_compile = (kernels.background_default() if background_compile is None
                                    else background_compile)
        self._pool = WorkerPool("warprt-render")
        # seconds a sample of every pixel took in the last passes, per (workers, slices): sizes the
        # passes of the next render (one pass where they fit in half a second, not a 1-spp one first)
        self._sample_time: dict[tuple[int, int], float] = {}
        self._light_samples = None  # what samples = "auto" became (light_samples())
        self._light_map = None  # and its split map, where it has one
        self._film: Film | None = None  # kept between renders (_film_for)
        self._film_lock = threading.Lock()
        self._launches = None  # (what they were recorded for, the slices' recorded launches): _passes
        self._aovs = None  # the AOV buffers kept with the film for the next render (_aovs_for)

    def update(self, scene: Scene) -> None:
        """Switch to a changed scene (moved objects, new materials, lights or camera...) without
        rebuilding mesh BVHs: assets are reused by file or content. The compiled kernel is kept
        while the new scene needs no feature it lacks (else the wider kernel is used)."""
        if not isinstance(scene, Scene):
            raise RenderError(f"update() needs a warprt.Scene, got {type(scene).__name__}")
        self.built = DeviceScene(scene, self.device, assets=self.built.assets, fast_off=self.fast_off)
        self.scene = scene
        self._light_samples = None
        self._light_map = None
        self._sample_time.clear()
        needed = self.built.features
        if needed.union(self.features) != self.features:
            self.features = self.features.union(needed)
            self.kernel = kernels_for(self.features, self.packets).render
            self._running = None

    def set_camera(self, camera) -> None:
        """Replace the camera (same or different resolution); no rebuild of anything else."""
        from .scene.description import Camera

        if not isinstance(camera, Camera):
            raise RenderError(f"set_camera() needs a warprt.Camera, got {type(camera).__name__}")
        self.scene = self.scene.replace(camera=camera)
        self.built.scene = self.scene
        self.built.camera = camera_data(self.scene)
        self.built.refresh_balls()  # the interior balls' rule looks at where the camera is
        self.built.drop_bins()  # and the bins are the camera's view
        self._light_samples = None  # what the camera sees changes the split
        self._light_map = None
        self._sample_time.clear()  # and the time per sample
        if camera.moves and not self.features.motion or camera.aperture > 0 and not self.features.lens:
            self.update(self.scene)

    def set_mesh_points(self, shape_index: int, points) -> None:
        """New vertex positions (numpy (N, 3) or a ``wp.array`` of vec3 on this device, e.g. from
        a Warp simulation) for a mesh; its BVH is refitted, not rebuilt."""
        self.built.set_mesh_points(shape_index, points)

    def light_samples(self, workers: int | None = None) -> int | None:
        """The shadow rays per camera sample that area lights with ``samples = "auto"`` take
        (None when there are none): chosen from the variance split a small pilot measures
        (``warprt.splitting``), once per renderer and scene, and the same for any seed or spp.
        The pilot also chooses the split map (``light_map``), which uniform renders take instead
        where there is one."""
        if not self.built.auto_lights:
            return None
        if self._light_samples is None:
            kernel = self._start_kernel()
            workers = default_workers() if workers is None else workers
            cam = self.scene.camera
            first, step = splitting.pilot_rows(cam.height)
            rows = list(range(first, cam.height, step))
            count = max(1, min(len(rows), SLICES_PER_WORKER * workers)) if self.device.is_cpu else 1
            run = pixels_per_thread(self.device, cam.width)
            pilot_pixels = (np.asarray(rows)[:, None] * cam.width + np.arange(cam.width)).reshape(-1)
            # one film and one set of recorded launches per seed, replayed for each light count (the
            # count is read from the scene's light rows, which set_auto_light_samples rewrites)
            pilots = []
            for seed in splitting.PILOT_SEEDS:
                params = render_params(self.scene, splitting.PILOT_SPP, seed, self.built.features)
                film = Film(cam.width, cam.height, self.device)
                pilots.append((film, [wp.launch(kernel, dim=cam.width * len(rows[j::count]) // run,
                                                device=self.device, record_cmd=True,
                                                inputs=[self.built.data, self.built.camera, params, rows[j],
                                                        step * count, 0, 0, film.data, run, 1,
                                                        no_aovs(self.device)])
                                      for j in range(count)]))
            self.built.set_light_map(None)  # (the pilot's counts are the rows')
            errors, tiles = [], []
            for n in (1, splitting.PROBE):
                self.built.set_auto_light_samples(n)
                means = []
                for film, launches in pilots:
                    run_pass(self._pool.get(workers), launches, workers, 0, splitting.PILOT_SPP)
                    wp.synchronize_device(self.device)
                    means.append(film.luminance_stats(splitting.PILOT_SPP)[0][pilot_pixels])
                errors.append(splitting.pixel_error(*means))
                tiles.append(splitting.tile_errors(*means, np.asarray(rows), cam.width, cam.height))
            rate = 1.0 if self.scene.render.sampler == "independent" else splitting.RATE
            e_cam, e_light = splitting.error_split(*errors, rate=rate)
            self._light_samples = splitting.best_samples(e_cam, e_light, self.built.auto_lights, rate=rate)
            self._light_map = splitting.light_map(*tiles, cam.width, cam.height, self.built.auto_lights, rate=rate,
                                                  one=self._light_samples)
            self._use_light_map(False)  # (the rows hold the one count; a uniform render sets the map)
        return self._light_samples

    def _use_light_map(self, on: bool) -> None:
        """The "auto" lights' counts for the next launches: the split map where there is one and
        ``on`` (uniform renders), else the one count. Adaptive renders take the one count: their
        samples already go where the noise is, and with the map as well they take longer to reach
        the same error."""
        if on and self._light_map is not None:
            if self.built.data.split_tile == 0:
                self.built.set_light_map(self._light_map, splitting.MAP_TILE)
        else:
            if self.built.data.split_tile != 0:
                self.built.set_light_map(None)
            self.built.set_auto_light_samples(self._light_samples)

    @property
    def light_map(self) -> np.ndarray | None:
        """The split map (``warprt.splitting.light_map``): shadow rays per camera sample of area
        lights with ``samples = "auto"`` for each ``splitting.MAP_TILE``-pixel block of the image
        (rows of blocks), or None where one count serves the whole image (``light_samples()``).
        Chosen with ``light_samples()``, which runs the pilot when needed."""
        self.light_samples()
        return self._light_map

    def compile(self) -> float:
        """Load the scene's own kernel on this device, compiling it now when Warp's cache lacks it
        (announced on stderr after a second); returns seconds. Renders use it from then on.

        Done from the calling thread, so that the worker threads never race to build the same
        module."""
        if self._background is not None and self._background.module is self.kernel.module:
            self._background.wait()  # (the same compile, already under way)
        seconds = kernels.load(self.kernel, self.device)
        self._loaded = self._running = self.kernel
        return seconds

    def _start_kernel(self):
        """The kernel a render starts on (``_running``): the scene's own when it is loaded or in
        Warp's cache; else, with background compiles on, the general kernel (``Features.full()``,
        the same image bit for bit) when it is in the cache, while the scene's own compiles in the
        background (``_switch_kernel`` takes it up between passes). Otherwise the scene's own,
        compiled now (and the general kernel in the background, for the next new feature set)."""
        own = self.kernel
        if self._running is own or self._loaded is own:
            self._running = own
            return own
        self._switch_kernel()
        if self._running is own:
            return own
        general = kernels_for(GENERAL_FEATURES, self.packets).render
        if (not self._background_compile or own is general or kernels.module_cached(own, self.device)
                or not kernels.module_cached(general, self.device)):
            if self._background_compile and own is not general:
                kernels.compile_general(general, self.device, (GENERAL_FEATURES.key, self.packets))
            self.compile()
            return own
        if self._background is None or self._background.module is not own.module:
            self._background = kernels.Background(own, self.device, render=(self.features.key, self.packets))
        kernels.load(general, self.device)
        self._running = general
        return general

    def _switch_kernel(self) -> bool:
        """Take up the scene's own kernel once its background compile is done; True when the
        kernel changed. (A failed background compile leaves the general kernel running.)"""
        bg = self._background
        if bg is None or self._running is self.kernel or bg.module is not self.kernel.module or not bg.ready():
            return False
        self._loaded = self._running = self.kernel
        self._background = None
        return True

    def close(self) -> None:
        """Stop the worker threads (they also stop when the renderer is garbage-collected) and
        free the film kept between renders."""
        self._pool.close()
        self._film = None
        self._launches = None
        self._aovs = None

    def _aovs_for(self, names: list, count: int, end: int, keep: bool) -> AovTarget | None:
        """The AOV buffers of a render (None without AOVs). With ``keep`` (the render holds the
        renderer's film and copies the AOVs out), those of the last such render are reused when
        they fit: their allocation and the scene's id map cost a tenth of a small one-sample
        render; AOVs handed out as ``wp.array``s get buffers of their own."""
        if not names:
            return None
        target = self._aovs if keep else None
        if target is None or target.names != names or target.count != count or target.built is not self.built:
            target = AovTarget(self.built, names, count, end)
            if keep:
                self._aovs = target
        target.data.end = int(end)
        return target

    def _film_for(self, width: int, height: int) -> tuple[Film, bool]:
        """(film, held): the film a render accumulates into. The renderer keeps one between
        renders, left as the last render wrote it: the first pass of a render starts every pixel's
        sums instead of adding to them, so it needs no clearing, and its memory stays mapped (a new
        film's zeroing and first-touch page faults cost about 1 ms a render at 256 × 256, much of
        a small render at 1 spp). A render in another thread holding it gets a film of its own."""
        if not self._film_lock.acquire(blocking=False):
            return Film(width, height, self.device, zeroed=False), False
        film = self._film
        if film is None or (film.width, film.height) != (width, height):
            film = self._film = None  # free the old one before the new one is allocated
            film = self._film = Film(width, height, self.device, zeroed=False)
        film.clear_counts()
        return film, True

    def render(self, spp: int | None = None, seed: int = 0, *, workers: int | None = None,
               slices: int | None = None, pass_spp: int | None = None, time_budget: float | None = None,
               target_error: float | None = None, progress: bool | None = None,
               aovs=None, as_warp: bool = False, stop=None, adaptive: bool | None = None,
               planned_spp: int | None = None) -> RenderResult:
        """Render ``spp`` samples per pixel (default: the scene's). See the module docstring for
        passes, slices, ``time_budget``, ``target_error`` and Ctrl-C; ``aovs`` names extra outputs
        (``depth``, ``z``, ``normal``, ``albedo``, ``position``, ``coverage``, ``object_id``,
        ``material``, ``motion``; averaged over the image's own samples, see ``warprt.aov``;
        ``sensor_z`` and ``sensor_depth`` with the scene's ``depth_sensor``, see ``warprt.sensor``)
        returned in ``RenderResult.aovs``. With ``as_warp=True`` the image and the AOVs stay on the
        device: ``RenderResult.image`` is a (H, W, 3) float32 ``wp.array`` (DLPack-ready for torch
        or JAX), with no copy to the host. ``slices``: on the CPU, cut each pass into that many
        fixed interleaved sets of rows (default: none; the workers take blocks of rows in turn
        until the frame is done); it changes the speed, never the image. ``stop``: an
        event (anything with ``is_set()``, e.g. ``threading.Event``) read after each pass like Ctrl-C:
        once set, the render returns what it has, marked ``interrupted`` (how a Ctrl-C reaches
        renders in worker threads and processes, where no SIGINT handler can be installed).
        ``adaptive``: adaptive sampling (default: the scene's ``render.adaptive``, on unless it
        says false, wherever the render takes a sample budget: not with ``time_budget``,
        ``target_error`` or ``planned_spp``, which then render uniformly). The first spp/2
        samples of every pixel (the pilot) measure the noise, and the ``spp × pixels`` budget,
        pilot included, is shared out in proportion to it (every pixel at least spp/2, at most 8 ×
        spp, what a capped pixel would take beyond going to the others). A pixel's count comes
        from its neighbours' pilots, never its own (``film.adaptive_counts``), so its image keeps
        every sample, pilot included, and stays unbiased. ``RenderResult.spp`` is then the mean
        count. At 1 spp it renders uniformly; ``adaptive=True`` does not combine with
        ``time_budget``, ``target_error`` or ``planned_spp``, ``adaptive=False`` renders
        uniformly. ``planned_spp`` (default ``spp``): the sample count the sampler lays its
        pattern out for (the ``stratified`` grid, the ``regular`` centres, the shutter's
        intervals); the first ``spp`` of those samples are run. A render stopped early (time
        budget, target error, Ctrl-C) holds the first N samples of its planned pattern, so
        ``render(spp=N, planned_spp=P, seed=S)`` gives it again bit for bit
        (``RenderResult.reproduction``)."""
        spp = self.scene.render.spp if spp is None else spp
        if adaptive is not None and not isinstance(adaptive, bool):
            raise RenderError("adaptive must be True, False or None (the scene's render.adaptive), "
                              f"got {adaptive!r:.60}")
        if adaptive is None:  # the scene's choice, where the render takes a sample budget
            adaptive = (self.scene.render.adaptive and planned_spp is None and time_budget is None
                        and target_error is None)
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
            raise RenderError(f"spp must be a positive integer, got {spp!r}")
        if spp > SPP_LIMIT:
            raise RenderError(f"spp must be <= {SPP_LIMIT} (2^20), got {spp}; {SPP_LIMIT_HINT}")
        check_seed(seed)
        if slices is not None and (isinstance(slices, bool) or not isinstance(slices, (int, np.integer)) or slices < 1):
            raise RenderError(f"slices must be a positive integer, got {slices!r}")
        for name, value in (("time_budget", time_budget), ("target_error", target_error)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float, np.integer,
                                                                                           np.floating))
                                      or not value > 0):
                raise RenderError(f"{name} must be a positive number{' of seconds' if name == 'time_budget' else ''}, "
                                  f"got {value!r}")
        if stop is not None and not callable(getattr(stop, "is_set", None)):
            raise RenderError(f"stop must be an event with is_set() (e.g. threading.Event), got {stop!r:.60}")
        if pass_spp is not None and (not isinstance(pass_spp, (int, np.integer)) or pass_spp < 1):
            raise RenderError(f"pass_spp must be a positive integer, got {pass_spp!r}")
        if planned_spp is not None:
            if isinstance(planned_spp, bool) or not isinstance(planned_spp, (int, np.integer)) or planned_spp < spp:
                raise RenderError(f"planned_spp must be an integer >= spp ({spp}), got {planned_spp!r}")
            if planned_spp > SPP_LIMIT:
                raise RenderError(f"planned_spp must be <= {SPP_LIMIT} (2^20), got {planned_spp}")
            if adaptive:
                raise RenderError("planned_spp does not combine with adaptive sampling (its counts come from spp)")
        # (the depth sensor's outputs are made from the render's own AOVs: warprt.sensor)
        asked, aovs, sensor_names = split_aovs(aovs, self.scene)
        check_memory(self.scene.camera.width, self.scene.camera.height, aovs, formats=(),
                     film_on_host=self.device.is_cpu)  # before anything is allocated or compiled
        workers = default_workers() if workers is None else workers
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise RenderError(f"workers must be a positive integer, got {workers!r}")

        if adaptive and (time_budget is not None or target_error is not None):
            raise RenderError("adaptive sampling takes a sample budget (spp), not time_budget or target_error")

        cam = self.scene.camera
        width, height, dev = cam.width, cam.height, self.device
        film, held = self._film_for(width, height)
        quiet = kernels.set_quiet(progress is False)  # (compile notices follow the progress output)
        try:
            loading = _time.perf_counter()
            self._start_kernel()
            kernel_load = _time.perf_counter() - loading
            self._general_passes = 0
            # a Ctrl-C from here on (the "auto" lights' pilot included) is held until the next
            # pass is done, and the render returns what it has
            ctrl_c = _CtrlC()
            with ctrl_c:
                self.light_samples(int(workers))  # samples = "auto": chosen once, then set for every render
                if self._light_samples is not None:
                    self._use_light_map(not adaptive)  # (the split map for uniform renders only)
                self.built.rendering()  # (a view rendered often enough gets its bins)
                # (None: the CPU workers claim blocks of rows; see the module docstring)
                n_slices = (None if slices is None else int(slices)) if dev.is_cpu else 1
                # the AOVs, from the passes' own samples (warprt.aov): the pass that completes the planned
                # samples writes them, unless adaptive sampling decides the counts after its pilot
                counted = adaptive and spp >= ADAPTIVE_MIN_SPP
                target = self._aovs_for(aovs, width * height, NO_LIMIT if counted else int(spp), held and not as_warp)
                run = dict(workers=int(workers), n_slices=n_slices, pass_spp=pass_spp, stop=stop,
                           aov=no_aovs(dev) if target is None else target.data)

                show = (sys.stderr.isatty() if progress is None else progress)
                bar = None
                if show:
                    from tqdm import tqdm

                    bar = tqdm(total=int(spp), unit="spp", desc="render", delay=0.5, leave=False, file=sys.stderr)
                start = _time.perf_counter()
                try:
                    planned = int(spp)
                    interrupted = False
                    pattern = int(spp if planned_spp is None else planned_spp)
                    params = render_params(self.scene, pattern, int(seed), self.built.features)
                    if target is not None:
                        params.aovs = target.mask
                    done, rel_err = 0, None
                    passes: list[int] = []
                    run["passes"] = passes
                    if counted:
                        # the pilot: the first n0 samples of every pixel, which then decide the other
                        # pixels' counts (never their own, see film.adaptive_counts) and stay in the image
                        n0 = max(1, int(spp) // ADAPTIVE_PILOT_FRACTION)  # 2 spp: one sample, then counts
                        done, interrupted, _ = self._passes(film, params, 0, n0, ctrl_c, bar, None, None, **run)
                        if not interrupted:
                            counts = adaptive_counts(film, done, int(spp))
                            film.set_counts(counts)
                            planned = int(counts.max())
                            if bar is not None:
                                bar.total = planned  # the main passes run to the largest count
                                bar.refresh()
                    if not interrupted:
                        done, interrupted, rel_err = self._passes(film, params, done, planned, ctrl_c, bar, time_budget,
                                                                  target_error, **run)
                finally:
                    if bar is not None:
                        bar.close()
            wall = _time.perf_counter() - start
            if target_error is not None and rel_err is None and done >= 2:
                rel_err = film.relative_error(done)
            image = film.device_image(done) if as_warp else film.image(done)
            aov_maps = {}
            if target is not None:  # the AOVs of the samples the image holds
                target.finish(film.data, done)
                aov_maps = target.maps((height, width), as_warp)
                if sensor_names:
                    made = apply_depth_sensor(self.scene.depth_sensor,
                                              {n: getattr(target.data.out, n) for n in target.names},
                                              eye_poses(cam, dev), width * height, int(seed), sensor_names,
                                              ortho=(cam.model == "orthographic",))
                    for name, a in made.items():
                        aov_maps[name] = a.reshape((height, width)) if as_warp else \
                            np.array(a.numpy(), np.float32, copy=True).reshape(height, width)
                    aov_maps = {name: aov_maps[name] for name in asked}
            # adaptive: the mean count over pixels (the budget asked for, give or take rounding)
            spp_done = done if film.counts is None else int(round(float(np.minimum(film.counts, done).mean())))
            stopped_by = None
            if interrupted:
                stopped_by = "interrupt"
            elif done < planned:
                stopped_by = "time_budget" if time_budget is not None and (
                    target_error is None or rel_err is None or rel_err > target_error) else "target_error"
            return RenderResult(image=image, spp=spp_done, wall_time=wall, rays=film.rays(),
                                stack_overflows=film.overflows() if self.features.secondary else 0,  # (no stack: none)
                                features=self.features,
                                device=str(dev), interrupted=interrupted, relative_error=rel_err, aovs=aov_maps,
                                planned_spp=pattern, passes=tuple(passes), stopped_by=stopped_by, seed=int(seed),
                                sampler=self.scene.render.sampler, adaptive=bool(adaptive and spp >= ADAPTIVE_MIN_SPP),
                                kernel_load=kernel_load, general_passes=self._general_passes, scene=self.scene)
        finally:
            kernels.reset_quiet(quiet)
            if held:
                self._film_lock.release()

    def _launches_for(self, film: Film, params, aov, n_slices: int | None, workers: int, run: int,
                      claims: bool) -> list:
        """One recorded launch of the running kernel per worker (or slice), replayed every pass
        with the pass's sample range; kept for the next call while kernel, scene (its record is
        made once, with it), camera and film are the same objects and slices and workers the same
        numbers, with only the render's parameters and AOV buffers set again (recording packs every
        argument, the scene's record among them: about 0.3 ms for 8 launches)."""
        cam = self.scene.camera
        dev = self.device
        kernel = self._running
        rows_per_block = SLICE_BLOCK if "row_blocks" not in self.fast_off else 1  # (warprt.fast)
        key = (kernel, self.built, self.built.camera, film, n_slices, workers, run)
        kept = self._launches
        if kept is not None and all(a is b for a, b in zip(kept[0][:4], key[:4])) and kept[0][4:] == key[4:]:
            launches = kept[1]
            for cmd in launches:
                cmd.set_param_at_index(PARAMS_ARG, params)
                cmd.set_param_at_index(AOV_ARG, aov)
            return launches
        if claims:
            # one launch per worker, each claiming blocks of rows until none is left (stride 0):
            # as many threads as blocks, in case one launch takes them all
            n_blocks = -(-cam.height // rows_per_block)
            launches = [wp.launch(kernel, dim=n_blocks, device=dev, record_cmd=True,
                                  inputs=[self.built.data, self.built.camera, params, 0, 0, 0, 0, film.data,
                                          cam.width, rows_per_block, aov])
                        for _ in range(workers)]
        else:
            # (with meshes a CPU thread takes a block of rows, else ``run`` pixels of a row:
            # integrator.render_kernel)
            blocks = run >= cam.width and self.features.meshes
            launches = [wp.launch(kernel, dim=-(-count // (cam.width * block)) if blocks else count // run,
                                  device=dev, record_cmd=True,
                                  inputs=[self.built.data, self.built.camera, params, first, stride, 0, 0,
                                          film.data, run, block, aov])
                        for first, stride, block, count in _slices(
                            cam.width, cam.height, SLICES_PER_WORKER * workers if n_slices is None else n_slices,
                            rows_per_block)]
        if film is self._film:  # (a film of a render in another thread is not kept)
            self._launches = (key, launches)
        return launches

    def _passes(self, film: Film, params, start: int, spp: int, ctrl_c: "_CtrlC", bar, time_budget, target_error,
                *, workers: int, n_slices: int | None, pass_spp, stop, aov,
                passes: list | None = None) -> tuple[int, bool, float | None]:
        """Run passes of samples [start, spp) into ``film``, which holds samples [0, start) (stopping
        early for Ctrl-C, ``stop``, ``time_budget`` or ``target_error``): (samples run, interrupted,
        relative error or None). The renderer's first pass is one sample (to time one); every
        later pass takes about half a second, sized from the time per sample last measured with
        these workers and slices and, with per-pixel counts, from how many pixels still sample at
        each index. ``aov``: the render's ``aov.AovData``."""
        dev = self.device
        run = pixels_per_thread(dev, self.scene.camera.width) if "row_threads" not in self.fast_off else 1
        # by default (n_slices None: the CPU) each worker's launch claims blocks of rows; threads
        # of fewer pixels than a row (tests that render pixel by pixel) take fixed slices instead
        claims = n_slices is None and run >= self.scene.camera.width
        claims = claims and "row_claims" not in self.fast_off  # (warprt.fast: fixed slices instead)
        launches = self._launches_for(film, params, aov, n_slices, workers, run, claims)
        pool = self._pool.get(workers)

        # the work of sample indices [0, s) in samples of every pixel: s itself, unless the film has
        # per-pixel counts (adaptive sampling), where index s runs only where the count exceeds s
        if film.counts is None:
            work_at = np.arange(spp + 1, dtype=np.float64)
        else:
            n_pix = film.counts.size
            active = n_pix - np.cumsum(np.bincount(np.minimum(film.counts, spp), minlength=spp + 1))[:-1]
            work_at = np.concatenate(([0.0], np.cumsum(active) / n_pix))

        done, interrupted, rel_err = start, False, None
        elapsed = 0.0
        timing = (workers, n_slices)
        t_start = _time.perf_counter()
        while done < spp:
            if pass_spp is not None:
                size = 1 if done == 0 else pass_spp
            elif done > start or self._sample_time.get(timing, 0.0) > 0.0:
                # about half a second of work (or what is left of the time budget) at the time per
                # sample of every pixel measured so far, in this call or an earlier one
                per = elapsed / (work_at[done] - work_at[start]) if done > start else self._sample_time[timing]
                target = 0.5 if time_budget is None else min(0.5, max(time_budget - elapsed, 0.0) + 1e-3)
                goal = work_at[done] + target / max(per, 1e-9)
                size = max(1, int(np.searchsorted(work_at, goal, side="right")) - 1 - done)
                # with camera-ray packets, a pass short of the end takes whole packets (the
                # integrator takes a pixel's samples PACKET at a time from the pass's first on)
                if self.packets and done + size < spp and size > PACKET:
                    size -= size % PACKET
            else:
                size = 1  # the renderer's first pass: one sample, to time one
            size = min(size, spp - done)
            if self._switch_kernel():  # the scene's own kernel, compiled in the background: from this pass on
                launches = self._launches_for(film, params, aov, n_slices, workers, run, claims)
            if self._running is not self.kernel:
                self._general_passes += 1
            if claims:  # (each pass's launches claim the blocks from the first again)
                film.reset_claims()
            try:
                run_pass(pool, launches, workers, done, done + size)
            except KeyboardInterrupt:
                interrupted = True
            wp.synchronize_device(dev)
            done += size
            if passes is not None:
                passes.append(size)
            elapsed = _time.perf_counter() - t_start
            if work_at[done] > work_at[start]:
                self._sample_time[timing] = elapsed / (work_at[done] - work_at[start])
            if bar is not None:
                bar.update(size)
            if ctrl_c.pressed or (stop is not None and stop.is_set()):
                interrupted = True
            if interrupted or (time_budget is not None and elapsed >= time_budget):
                break
            if target_error is not None and done >= 2:
                rel_err = film.relative_error(done)
                if rel_err <= target_error:
                    break
        return done, interrupted, rel_err


def render(scene: Scene, spp: int | None = None, seed: int = 0, device: str | None = None, **options):
    """Render ``scene`` and return linear radiance as a float32 (H, W, 3) array, row 0 at the top.

    With ``aovs=[...]`` the result is a dict: ``{"color": image, "depth": ..., ...}`` (a
    :class:`warprt.results.RenderLayers`, which also has the result's ``.spp`` and ``.metadata``,
    so that ``save_image`` writes them).

    ``spp`` defaults to the scene's ``render.spp``; ``seed`` picks the noise (the same seed gives
    the same image bit for bit). Further options (``workers``, ``slices``, ``time_budget``,
    ``target_error``, ``progress``...) are those of :meth:`Renderer.render`; use
    :class:`Renderer` directly for the statistics (:class:`RenderResult`).
    """
    result = Renderer(scene, device=device).render(spp=spp, seed=seed, **options)
    if options.get("aovs"):
        return RenderLayers({"color": result.image, **result.aovs}, result)
    return result.image
