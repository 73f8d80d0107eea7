"""Timing warprt and Mitsuba 3 side by side: the method ``benchmarks.peers`` and
``benchmarks.corpus`` share.

* ``WarprtSide`` renders a scene in warprt's configurations. A configuration is named
  ``BASE[+split][+adaptive]``: BASE ``defaults`` is the scene as built, rendered by
  ``Renderer.render`` with no option (whatever warprt does without being asked), or a sampler
  name (``sobol``, ``stratified``, ...) set with ``with_settings(sampler=...)``, its area lights
  with ``samples = "auto"`` given 1 and rendered with ``adaptive=False``; ``+split`` gives every
  area light ``samples = "auto"``; ``+adaptive`` renders with ``adaptive=True``.
* ``MitsubaSide`` renders the exported scene (``benchmarks.mitsuba_export``) with Mitsuba's
  samplers (``multijitter``, ``independent``; ``multijitter+split``: with ``emitter_samples``).
* ``render_passes`` averages seeded passes and keeps the two halves for a noise estimate
  (``noise_floor``, ``mean_sigma``); ``compare`` says whether two converged images are the same
  within their noise; ``sweep`` times every side over a ladder of spp, interleaved, after one
  warm-up render per (configuration, spp), with an idle ``SETTLE_S`` before each timed render, the
  repeats as sweeps over the ladder; ``time_to_error`` interpolates a curve (log-log).
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import time

import numpy as np

import warprt
from warprt.testing import relative_mse

THREADS = 2
TARGETS = (1e-2, 1e-3)
# Idle time before every timed render, either renderer's: Dr.Jit's worker threads (nanothread)
# busy-wait for work after each task before they sleep (measured: 1-1.5 cores busy for 20-25 ms
# after a Mitsuba render), and on 2 cores a render started then shares them with the spinning
# threads, or, for Mitsuba after Mitsuba, starts on threads still awake. Long enough for the spin
# to end, short enough not to let the cores fall idle (a 100-200 ms wait slowed both renderers'
# next short render by 5-20%). warprt's pool threads block; nothing spins.
SETTLE_S = 0.04


def parse_config(name: str) -> tuple[str, bool, bool]:
    """(base, split, adaptive) of a configuration name ``BASE[+split][+adaptive]``."""
    parts = name.split("+")
    base, flags = parts[0], set(parts[1:])
    unknown = flags - {"split", "adaptive"}
    if unknown or len(flags) != len(parts) - 1:
        raise ValueError(f"configuration {name!r}: flags are +split and +adaptive")
    if base != "defaults" and base not in ("regular", "independent", "stratified", "sobol"):
        raise ValueError(f"configuration {name!r}: base is 'defaults' or a sampler name")
    return base, "split" in flags, "adaptive" in flags


def has_area_lights(scene: warprt.Scene) -> bool:
    return any(hasattr(light, "samples") for light in scene.lights)


def effective_config(name: str, scene: warprt.Scene) -> str:
    """The configuration that renders the same thing: ``+split`` means nothing without area
    lights (``sobol+split`` is then ``sobol``)."""
    base, split, adaptive = parse_config(name)
    split = split and has_area_lights(scene)
    return base + ("+split" if split else "") + ("+adaptive" if adaptive else "")


class WarprtSide:
    """warprt renderers for a scene's configurations, built and compiled up front.

    ``share``: configurations that differ only in ``+adaptive`` render with one ``Renderer``
    (adaptive sampling is an option of ``render``), so a large mesh is built once per base and
    split rather than once per configuration."""

    name = "warprt"

    def __init__(self, scene: warprt.Scene, configs, threads: int = THREADS, share: bool = True):
        self.threads = threads
        t0 = time.perf_counter()
        split_scene = scene.replace(lights=tuple(dataclasses.replace(light, samples="auto")
                                                 if hasattr(light, "samples") else light for light in scene.lights))
        # (a named configuration says everything: no split and uniform sampling unless it asks)
        one_scene = scene.replace(lights=tuple(dataclasses.replace(light, samples=1)
                                               if getattr(light, "samples", None) == "auto" else light
                                               for light in scene.lights))
        self.renderers, self.adaptive, self.setup = {}, {}, {}
        by_setup = {}
        for c in configs:
            base, split, adaptive = parse_config(c)
            setup = (base, split)
            if setup not in by_setup or not share:
                s = split_scene if split else (scene if base == "defaults" else one_scene)
                if base != "defaults":
                    s = s.with_settings(sampler=base)
                by_setup[setup] = warprt.Renderer(s, device="cpu")
            self.renderers[c] = by_setup[setup]
            # (None: the scene's own choice, for "defaults" without +adaptive)
            self.adaptive[c] = None if base == "defaults" and not adaptive else adaptive
            self.setup[c] = setup
        self.build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        for r in {id(r): r for r in self.renderers.values()}.values():
            r.compile()
        self.compile_s = time.perf_counter() - t0
        # lights with samples = "auto": each renderer's pilot chooses the shadow rays per camera
        # sample once (a set-up cost like the build, timed here and reported, not in the renders)
        t0 = time.perf_counter()
        self.light_samples = {c: r.light_samples(threads) for c, r in self.renderers.items()
                              if r.light_samples(threads) is not None}
        self.split_pilot_s = time.perf_counter() - t0
        # and the split map its uniform renders take (blocks per count), where it has one
        self.light_maps = {c: {int(k): int(v) for k, v in zip(*np.unique(r.light_map, return_counts=True))}
                           for c, r in self.renderers.items()
                           if self.adaptive[c] is False and r.light_samples(threads) and r.light_map is not None}

    @property
    def configs(self):
        return list(self.renderers)

    def render(self, config: str, spp: int, seed: int):
        """(image, wall seconds, spp rendered, CPU seconds of the whole process)."""
        c0, t0 = time.process_time(), time.perf_counter()
        res = self.renderers[config].render(spp=spp, seed=seed, workers=self.threads, progress=False,
                                            **({} if self.adaptive[config] is None else {"adaptive": self.adaptive[config]}))
        image = np.asarray(res.image, dtype=np.float32)
        return image, time.perf_counter() - t0, res.spp, time.process_time() - c0

    def close(self) -> None:
        for r in {id(r): r for r in self.renderers.values()}.values():
            r.close()
        self.renderers.clear()


class MitsubaSide:
    name = "mitsuba"

    def __init__(self, scene: warprt.Scene, mi, dr, samplers=("multijitter", "independent"),
                 emitter_samples: int | None = None, export=None):
        from benchmarks.mitsuba_export import to_mitsuba

        export = export or to_mitsuba
        self.mi, self.dr = mi, dr
        t0 = time.perf_counter()
        self.samplers = tuple(s for s in samplers if not s.endswith("+split")) + tuple(
            s for s in samplers if s.endswith("+split") and emitter_samples and emitter_samples > 1)
        self.scenes = {s: mi.load_dict(export(scene, mi, sampler=s.split("+")[0],
                                              emitter_samples=emitter_samples if s.endswith("+split") else 1))
                       for s in self.samplers}
        self.build_s = time.perf_counter() - t0
        self.compile_s = 0.0  # JIT happens in the first render of each (sampler, spp): see warm-ups

    @property
    def configs(self):
        return list(self.samplers)

    def render(self, sampler: str, spp: int, seed: int):
        sc = self.scenes[sampler]
        c0, t0 = time.process_time(), time.perf_counter()
        image = np.array(self.mi.render(sc, spp=spp, seed=seed), dtype=np.float32)  # evaluates the JIT graph
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        return image, wall, int(sc.sensors()[0].sampler().sample_count()), cpu

    def close(self) -> None:
        self.scenes.clear()


def render_passes(side, config: str, spp: int, seed0: int, pass_spp: int):
    """Average of ceil(spp / pass_spp) renders with their own seeds (bounded memory for Mitsuba's
    wavefront); returns (image, halves, seconds, actual spp). The halves are the means of the
    even and odd passes, for a noise estimate."""
    pass_spp = max(1, min(pass_spp, spp // 2))
    n = max(2, math.ceil(spp / pass_spp))
    n += n % 2
    acc = PassSum()
    for k in range(n):
        img, wall, got, _ = side.render(config, pass_spp, seed0 + 7919 * k)
        acc.add(img, got, wall)
    return acc.image(), acc.halves(), acc.seconds, acc.spp


class PassSum:
    """Passes summed in two halves (even and odd passes), each weighted by its spp."""

    def __init__(self):
        self.sums, self.counts, self.n, self.seconds = [None, None], [0, 0], 0, 0.0

    def add(self, img, spp: int, seconds: float = 0.0) -> None:
        h = self.n % 2
        x = np.asarray(img, dtype=np.float64) * spp
        self.sums[h] = x if self.sums[h] is None else self.sums[h] + x
        self.counts[h] += spp
        self.n += 1
        self.seconds += seconds

    @property
    def spp(self) -> int:
        return self.counts[0] + self.counts[1]

    def halves(self):
        return [self.sums[0] / self.counts[0], self.sums[1] / self.counts[1]]

    def image(self):
        return (self.sums[0] + self.sums[1]) / self.spp


def noise_floor(halves) -> float:
    """relMSE that the average of two independent halves carries: relMSE(h1, h2) / 4."""
    return relative_mse(halves[0], halves[1]) / 4.0


def mean_sigma(halves) -> float:
    """Standard error of the image mean of (h1 + h2) / 2, from the per-pixel half differences."""
    d = np.asarray(halves[0], dtype=np.float64) - np.asarray(halves[1], dtype=np.float64)
    return math.sqrt(float(np.mean(d ** 2)) / 4.0 / d.size)


def compare(image, halves, ref, ref_halves, agree_factor: float = 2.0) -> dict:
    """Whether ``image`` and the reference are the same image within their noise: their relMSE
    within ``agree_factor`` × the sum of the two noise floors, and the image means within 4σ
    (or, where a tiny systematic difference shows, within 0.1%)."""
    floor, w_floor = noise_floor(ref_halves), noise_floor(halves)
    err = relative_mse(image, ref)
    m_ref, m_w = float(np.mean(ref)), float(np.mean(image))
    sigma = math.hypot(mean_sigma(ref_halves), mean_sigma(halves))
    z = (m_w - m_ref) / sigma if sigma > 0 else float("inf") * np.sign(m_w - m_ref)
    ratio = err / (floor + w_floor) if floor + w_floor > 0 else float("inf")
    mean_within_noise = bool(abs(z) < 4.0)
    agree = bool(ratio < agree_factor and (mean_within_noise or abs(m_w - m_ref) < 1e-3 * abs(m_ref)))
    return {"rel_mse": err, "noise_floor_reference": floor, "noise_floor_image": w_floor,
            "expected_from_noise": floor + w_floor, "ratio_to_noise": ratio, "mean_image": m_w,
            "mean_reference": m_ref, "mean_rel_diff": (m_w - m_ref) / m_ref if m_ref else float("nan"),
            "mean_z": float(z), "mean_within_noise": mean_within_noise, "agree": agree}


def time_to_error(points, target):
    """(seconds, how) at which a curve of (seconds, error) points reaches ``target``: log-log
    interpolation between the bracketing points ("interp"), the first point when that is already
    below ("<="), None when never reached (">")."""
    pts = [(t, e) for t, e in points if t > 0 and e is not None]
    if not pts:
        return None, ">"
    if pts[0][1] <= target:
        return pts[0][0], "<="
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e1 <= target < e0:
            if e1 <= 0:
                return t1, "interp"
            f = (math.log(e0) - math.log(target)) / (math.log(e0) - math.log(e1))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))), "interp"
    return None, ">"


def sweep(sides, spps, repeats: int, ref, floor: float, stop, log=None, settle: float = SETTLE_S) -> dict:
    """Time every (side, configuration) of ``sides`` over the spp ladder ``spps``, interleaved.

    The first repeat sweeps the spp up: at each point every curve still going gets one warm-up
    render (seed 99; its time dropped, its image counted in the error: compile and JIT
    excluded), then one timed render each; ``stop(key, curves)`` then says whether curve ``key``
    ("side/config") ends there. The other repeats sweep those points again in turn, alternating
    the order of the renderers, so that a slow spell of the host (seconds long) falls on one
    repeat of several points rather than on every repeat of one. Each timed render comes after
    ``settle`` seconds idle. Returns {key: [point, ...]}: a point's ``seconds`` is the least of
    its repeats' wall times (all in ``seconds_all``, repeat by repeat), its ``rel_mse`` the mean
    over the warm-up and the repeats, ``rel_mse_corrected`` that less the reference's ``floor``."""
    entries = [(f"{side.name}/{c}", side, c) for side, configs in sides for c in configs]
    curves = {k: [] for k, _, _ in entries}
    done = {k: False for k in curves}
    runs = {}
    swept = []
    h, w = ref.shape[:2]

    def timed(k, side, c, spp, r):
        time.sleep(settle)
        img, wall, got, cpu = side.render(c, spp, 1 + r)
        run = runs[(k, spp)]
        run["times"].append(wall)
        run["cpus"].append(cpu)
        run["errs"].append(relative_mse(img, ref))
        run["got"] = got

    def point(k, spp):
        run = runs[(k, spp)]
        e = float(np.mean(run["errs"]))
        t = float(min(run["times"]))
        return {"spp": spp, "spp_actual": run["got"], "seconds": t, "seconds_all": list(run["times"]),
                "cpu_seconds": float(min(run["cpus"])), "cpu_seconds_all": list(run["cpus"]),
                "warmup_s": run["warmup"], "rel_mse": e, "rel_mse_all": list(run["errs"]),
                "rel_mse_corrected": e - floor, "msamples_per_s": w * h * run["got"] / t / 1e6}

    for spp in spps:
        active = [(k, side, c) for k, side, c in entries if not done[k]]
        if not active:
            break
        for k, side, c in active:
            img, wall, got, _ = side.render(c, spp, 99)
            runs[(k, spp)] = {"times": [], "cpus": [], "errs": [relative_mse(img, ref)], "got": got, "warmup": wall}
        for k, side, c in active:
            timed(k, side, c, spp, 0)
        swept.append((spp, active))
        for k, _, _ in active:
            curves[k].append(point(k, spp))
        for k, _, _ in active:
            done[k] = bool(stop(k, curves))
        if log:
            log(f"  spp {spp:5d}: " + "  ".join(f"{k} {curves[k][-1]['seconds']:.3f}s {curves[k][-1]['rel_mse']:.1e}"
                                                for k, _, _ in active))
    for r in range(1, repeats):
        for spp, active in swept:
            for k, side, c in (active if r % 2 == 0 else active[::-1]):
                timed(k, side, c, spp, r)
    return {k: [point(k, p["spp"]) for p in v] for k, v in curves.items()}


def cpu_info() -> dict:
    """The CPU's model and its widest vector extension. Mitsuba's LLVM backend runs its samples in
    vector lanes as wide as the CPU has (16 floats with AVX-512, 8 with AVX2), warprt's kernels one
    sample per thread: the ratios depend on it as much as on either renderer."""
    model, flags = "", set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name") and not model:
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags") and not flags:
                    flags = set(line.split(":", 1)[1].split())
    except OSError:
        pass
    simd = ("AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "AVX" if "avx" in flags
            else "SSE" if flags else "")
    return {"cpu": model or platform.processor() or platform.machine(), "simd": simd}


def machine_info(mi=None, dr=None, variant: str = "", note: str = "") -> dict:
    import warp as wp

    info = {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version(),
            "warprt": warprt.__version__, "warp": wp.config.version, "threads": THREADS, **cpu_info()}
    if mi is not None:
        info.update(mitsuba=mi.__version__, drjit=dr.__version__, variant=variant, variant_note=note,
                    libllvm=os.environ.get("DRJIT_LIBLLVM_PATH"))
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    return info


def pyplot():
    """matplotlib's pyplot on the Agg backend, or None, saying so in a line, where the ``charts``
    extra is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no chart (install the 'charts' extra)")
        return None
    return plt
