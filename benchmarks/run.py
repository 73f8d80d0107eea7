"""warprt benchmarks: speed against accuracy, throughput, scaling and compile cost.

    python -m benchmarks.run            # everything (several minutes on 2 cores)
    python -m benchmarks.run --quick    # smaller sizes, for a smoke run
    python -m benchmarks.run --only error,growth
    python -m benchmarks.run --only specialisation --merge   # re-measure one section in place
    python -m benchmarks.run --only checks --merge           # the device-input checks' cost

Writes under docs/benchmarks/ (``--quick``: out/bench/; or --out): results.json, results.csv (one
row per measurement), and charts (PNG, needs matplotlib: the ``charts`` extra); a run into
docs/benchmarks/ then re-renders this benchmark's tables in docs/benchmarks.md from them
(``benchmarks.docs``; ``--no-docs`` not to, ``python -m benchmarks.docs`` to do it again from the
committed files). Timings are wall-clock medians on the machine it runs on; ratios are taken
within one run, since a shared machine is noisy.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))

import numpy as np  # noqa: E402

import warprt  # noqa: E402
from benchmarks import docs  # noqa: E402
from warprt import Features  # noqa: E402
from warprt.render import default_workers  # noqa: E402

SAMPLERS = ("regular", "independent", "stratified", "sobol")


def median_time(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


# --- scenes ----------------------------------------------------------------------------------------


def soft_shadow_scene(size: int) -> warprt.Scene:
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 2.2, 2.6), look_at=(0, 0.2, 0), fov=45, width=size, height=size),
        shapes=(warprt.Plane(material="m"), warprt.Sphere(center=(0, 0.5, 0), radius=0.4, material="m"),
                warprt.Rectangle(corner=(-1.2, 0.9, -0.2), edge1=(0, 0, 0.4), edge2=(0.6, 0, 0), material="m")),
        materials={"m": warprt.Material(kd=0.8, ka=0.0)},
        lights=(warprt.RectLight(corner=(-0.7, 2.2, -0.7), edge1=(1.4, 0, 0), edge2=(0, 0, 1.4), radiance=2.0),))


def dof_scene(size: int) -> warprt.Scene:
    shapes = tuple(warprt.Sphere(center=(-1.2 + 0.6 * k, 0.3, -1.0 * k), radius=0.3, material=f"m{k % 3}")
                   for k in range(5)) + (warprt.Plane(material="floor"),)
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0.8, 3), look_at=(0, 0.3, 0), fov=40, width=size, height=size,
                             aperture=0.12, focus_distance=3.0),
        shapes=shapes,
        materials={"m0": warprt.Material(kd=(0.8, 0.2, 0.2), ks=0.5, p=60), "m1": warprt.Material(kd=(0.2, 0.7, 0.3)),
                   "m2": warprt.Material(kd=(0.2, 0.3, 0.8), ks=0.3), "floor": warprt.Material(kd=0.6)},
        lights=(warprt.PointLight(position=(2, 4, 3), intensity=0.9),), ambient=0.1, background=(0.5, 0.6, 0.8))


def edge_scene(size: int) -> warprt.Scene:
    stripes = tuple(warprt.Rectangle(corner=(-20, 0, -0.5 - k * 0.5), edge1=(0, 0, 0.12), edge2=(40, 0, 0),
                                     material="white") for k in range(60))
    return warprt.Scene(camera=warprt.Camera(eye=(0, 1.0, 1.0), look_at=(0, 0, -4), fov=50, width=size, height=size),
                        shapes=stripes, materials={"white": warprt.Material(kd=0.0, ka=1.0)}, ambient=1.0)


def glossy_scene(size: int) -> warprt.Scene:
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 1.2, 3), look_at=(0, 0.4, 0), fov=40, width=size, height=size),
        shapes=(warprt.Plane(material="gloss"), warprt.Sphere(center=(0, 0.5, 0), radius=0.5, material="red")),
        materials={"gloss": warprt.Material(kd=0.2, mirror=0.6, glossy_exponent=60),
                   "red": warprt.Material(kd=(0.8, 0.2, 0.1), ks=0.4, p=40)},
        lights=(warprt.PointLight(position=(2, 3, 2), intensity=0.8),), ambient=0.05, background=(0.5, 0.6, 0.8))


def plain_scene(size: int) -> warprt.Scene:
    shapes = tuple(warprt.Sphere(center=(-1.5 + 0.75 * k, 0.35, -0.3 * k), radius=0.35, material="m")
                   for k in range(5)) + (warprt.Plane(material="floor"),)
    return warprt.Scene(camera=warprt.Camera(eye=(0, 1.2, 4), look_at=(0, 0.3, 0), width=size, height=size * 3 // 4),
                        shapes=shapes, materials={"m": warprt.Material(kd=(0.7, 0.4, 0.2), ks=0.3, p=30),
                                                  "floor": warprt.Material(kd=0.7)},
                        lights=(warprt.PointLight(position=(2, 4, 3), intensity=0.7),
                                warprt.PointLight(position=(-3, 3, 2), intensity=0.4)), ambient=0.08)


def motion_scene(size: int) -> warprt.Scene:
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 1.0, 3.2), look_at=(0, 0.4, 0), fov=40, width=size, height=size, shutter=(0.0, 1.0)),
        shapes=(warprt.Plane(material="floor"),
                warprt.Sphere(center=(-0.6, 0.4, 0), center_end=(0.6, 0.6, 0), radius=0.35, material="red")),
        materials={"floor": warprt.Material(kd=0.7), "red": warprt.Material(kd=(0.8, 0.15, 0.1), ks=0.4, p=50)},
        lights=(warprt.PointLight(position=(1.5, 3, 2), intensity=0.9),), ambient=0.1, background=(0.5, 0.6, 0.8))


EFFECT_SCENES = {"soft_shadows": soft_shadow_scene, "depth_of_field": dof_scene, "antialiasing": edge_scene,
                 "glossy": glossy_scene, "motion_blur": motion_scene}


# --- measurements --------------------------------------------------------------------------------


def bench_error_vs_time(rows, charts, quick: bool):
    size = 24 if quick else 64
    spps = [1, 4, 16, 64] if quick else [1, 2, 4, 8, 16, 32, 64, 128, 256]
    ref_spp = 1024 if quick else 4096
    curves = {}
    for effect, make in EFFECT_SCENES.items():
        scene = make(size)
        reference = warprt.Renderer(scene.with_settings(sampler="sobol")).render(spp=ref_spp, seed=12345,
                                                                                progress=False).image
        denom = float(np.mean(reference.astype(np.float64) ** 2)) + 1e-12
        for sampler in SAMPLERS:
            renderer = warprt.Renderer(scene.with_settings(sampler=sampler))
            renderer.compile()
            pts = []
            for spp in spps:
                errs, walls = [], []
                for seed in range(3):  # regular ignores the seed: its 3 runs only time it again
                    res = renderer.render(spp=spp, seed=seed, progress=False)
                    errs.append(float(np.mean((res.image.astype(np.float64) - reference) ** 2)) / denom)
                    walls.append(res.wall_time)
                # error: mean over seeds; time: the fastest run (the least disturbed by machine noise)
                rel_mse, wall = float(np.mean(errs)), float(np.min(walls))
                pts.append((spp, wall, rel_mse))
                rows.append({"benchmark": "error_vs_time", "scene": effect, "sampler": sampler, "spp": spp,
                             "seconds": wall, "rel_mse": rel_mse})
            curves[(effect, sampler)] = pts
        print(f"  error vs time: {effect} done", flush=True)
    # equal-error time ratios: time independent needs for its error at the top spp, vs stratified/sobol
    ratios = {}
    for effect in EFFECT_SCENES:
        target = curves[(effect, "independent")][-1][2]
        t_ind = curves[(effect, "independent")][-1][1]
        for sampler in ("stratified", "sobol"):
            t_s = _time_to_error(curves[(effect, sampler)], target)
            ratios[f"{effect}/{sampler}"] = t_ind / t_s if t_s else float("nan")
            rows.append({"benchmark": "equal_error_speedup", "scene": effect, "sampler": sampler,
                         "value": ratios[f"{effect}/{sampler}"]})
    charts["error_vs_time"] = curves
    return ratios


def _time_to_error(points, target):
    """Wall time at which a curve reaches ``target`` error (log-log interpolation)."""
    for (s0, t0, e0), (s1, t1, e1) in zip(points, points[1:]):
        if e1 <= target <= e0 and e0 > e1 > 0:
            f = (math.log(e0) - math.log(target)) / (math.log(e0) - math.log(e1))
            return math.exp(math.log(max(t0, 1e-9)) + f * (math.log(max(t1, 1e-9)) - math.log(max(t0, 1e-9))))
    if points and points[0][2] <= target:
        return points[0][1]
    return None


def bench_throughput(rows, quick: bool):
    scene = warprt.load_scene(ROOT / "scenes" / "showcase.toml")
    if quick:
        scene = scene.with_camera(width=160, height=90)
    out = {}
    renderer = warprt.Renderer(scene)
    renderer.compile()
    spp = 4 if quick else 8
    for workers in sorted({1, default_workers()}):
        results = [renderer.render(spp=spp, workers=workers, progress=False) for _ in range(3)]
        res = sorted(results, key=lambda r: r.wall_time)[1]
        px = scene.camera.width * scene.camera.height * spp
        out[workers] = {"seconds": res.wall_time, "mrays_per_s": res.mrays_per_s,
                        "mpixel_samples_per_s": px / res.wall_time / 1e6, "rays": res.rays}
        rows.append({"benchmark": "throughput", "scene": "showcase", "workers": workers, "spp": spp,
                     "seconds": res.wall_time, "mrays_per_s": res.mrays_per_s,
                     "mpixel_samples_per_s": px / res.wall_time / 1e6})
    if len(out) > 1:
        out["speedup"] = out[1]["seconds"] / out[max(k for k in out if isinstance(k, int))]["seconds"]
    # primary + shadow rays per core on the plain scene
    plain = warprt.Renderer(plain_scene(160 if quick else 320))
    plain.compile()
    res = sorted((plain.render(spp=4, workers=1, progress=False) for _ in range(3)), key=lambda r: r.wall_time)[1]
    out["plain_primary_shadow_mrays_per_s_per_core"] = res.mrays_per_s
    rows.append({"benchmark": "throughput", "scene": "plain", "workers": 1, "spp": 4, "seconds": res.wall_time,
                 "mrays_per_s": res.mrays_per_s})
    return out


def bench_specialisation(rows, quick: bool, rounds: int = 9):
    """The all-features kernel against the plain scene's own (``basic``) kernel: ``rounds``
    interleaved pairs (specialised, then full, after one warm-up render each), so drift in machine
    load hits both alike. Each pair gives a ratio full / specialised; the result is their median
    and their spread (min, max), which the docs quote together (tests/test_doc_figures.py)."""
    scene = plain_scene(160 if quick else 320)
    spec = warprt.Renderer(scene)
    full = warprt.Renderer(scene, features=Features.full())
    spec.compile()
    full.compile()
    spp = 2 if quick else 16
    spec.render(spp=spp, progress=False)
    full.render(spp=spp, progress=False)
    t_spec, t_full = [], []
    for _ in range(rounds):
        t_spec.append(spec.render(spp=spp, progress=False).wall_time)
        t_full.append(full.render(spp=spp, progress=False).wall_time)
    ratios = [f / s for f, s in zip(t_full, t_spec)]
    ratio = statistics.median(ratios)
    rows.append({"benchmark": "specialisation", "scene": "plain", "seconds_specialised": statistics.median(t_spec),
                 "seconds_full": statistics.median(t_full), "value": ratio})
    return {"specialised_s": statistics.median(t_spec), "full_s": statistics.median(t_full),
            "full_over_specialised": ratio, "full_over_specialised_min": min(ratios),
            "full_over_specialised_max": max(ratios), "rounds": rounds, "spp": spp,
            "ratios": ratios, "specialised_times_s": t_spec, "full_times_s": t_full}


AOV_NAMES = ("depth", "normal", "object_id")  # the case: colour + depth + normal + object id


def aov_scene(size: int) -> warprt.Scene:
    """A plane, 6 spheres and a point light (the AOV benchmark's scene)."""
    shapes = (warprt.Plane(material="floor"),) + tuple(
        warprt.Sphere(center=(-1.5 + 0.6 * k, 0.3 + 0.05 * k, -0.4 * (k % 3)), radius=0.3, material=f"m{k % 2}")
        for k in range(6))
    return warprt.Scene(camera=warprt.Camera(eye=(0, 1.4, 4), look_at=(0, 0.3, 0), width=size, height=size),
                        shapes=shapes, materials={"m0": warprt.Material(kd=(0.7, 0.4, 0.2), ks=0.3, p=30),
                                                  "m1": warprt.Material(kd=(0.2, 0.4, 0.8)),
                                                  "floor": warprt.Material(kd=0.7)},
                        lights=(warprt.PointLight(position=(2, 4, 3), intensity=0.8),), ambient=0.08,
                        render=warprt.RenderSettings(spp=1))


def _interleaved(fns: dict, repeats: int) -> dict:
    """Wall and process CPU seconds of each callable, ``repeats`` rounds interleaved (one call of
    each per round, in turn), after one warm-up call each: {name: {"wall": [...], "cpu": [...]}}."""
    for fn in fns.values():
        fn()
    times = {k: {"wall": [], "cpu": []} for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            cpu, start = time.process_time(), time.perf_counter()
            fn()
            times[k]["wall"].append(time.perf_counter() - start)
            times[k]["cpu"].append(time.process_time() - cpu)
    return times


def _ratio_summary(base: list, other: list) -> dict:
    """min and median seconds of both, min(other) / min(base), and the median and spread of the
    per-round ratios (each round's pair ran back to back)."""
    ratios = [o / b for o, b in zip(other, base)]
    return {"colour_s_min": min(base), "colour_s_median": statistics.median(base),
            "colour_aovs_s_min": min(other), "colour_aovs_s_median": statistics.median(other),
            "ratio_of_minima": min(other) / min(base), "ratio_median": statistics.median(ratios),
            "ratio_spread": [min(ratios), max(ratios)]}


def bench_aovs(rows, quick: bool, repeats: int = 15):
    """Colour alone against colour + depth + normal + object id (``AOV_NAMES``), interleaved,
    ``repeats`` rounds: single renders (``Renderer.render`` at 1 and 8 spp) and a batch
    (``BatchRenderer.render``: 16 worlds x 2 cameras at 128x128, 1 spp). Each is timed on every
    core (wall time of the whole call: passes, AOVs, results) and on one worker (process CPU
    time: the least disturbed measure on a shared machine), warm (compiled, after a warm-up)."""
    from warprt.worlds import camera_quaternion

    out = {}
    size = 96 if quick else 256
    r = warprt.Renderer(aov_scene(size))
    r.compile()
    worlds, cameras, px = (4, 2, 64) if quick else (16, 2, 128)
    br = warprt.BatchRenderer(aov_scene(px), worlds=worlds, cameras=cameras)
    eyes = [(0.0, 1.4, 4.0), (2.5, 2.0, 3.0)]
    poses = [np.concatenate([eye, camera_quaternion(eye, (0.0, 0.3, 0.0), (0.0, 1.0, 0.0))]) for eye in eyes]
    br.set_camera_poses(np.array([[poses[c % 2] for c in range(cameras)] for _ in range(worlds)]))
    cases = {f"single_{size}px_{spp}spp": (lambda aovs, w, spp=spp: r.render(spp=spp, workers=w, progress=False,
                                                                              aovs=aovs))
             for spp in (1, 8)}
    cases[f"batch_{worlds}x{cameras}_{px}px_1spp"] = lambda aovs, w: br.render(spp=1, workers=w, aovs=aovs)
    for name, call in cases.items():
        fns = {(aovs, w): (lambda aovs=aovs, w=w: call(aovs, w))
               for w in (default_workers(), 1) for aovs in ((), AOV_NAMES)}
        times = _interleaved(fns, repeats)
        every = _ratio_summary(times[((), default_workers())]["wall"], times[(AOV_NAMES, default_workers())]["wall"])
        one = _ratio_summary(times[((), 1)]["cpu"], times[(AOV_NAMES, 1)]["cpu"])
        out[name] = {"wall": every, "cpu_1_worker": one, "workers": default_workers()}
        rows.append({"benchmark": "aovs", "scene": name, "workers": default_workers(),
                     "seconds": every["colour_s_min"], "seconds_aovs": every["colour_aovs_s_min"],
                     "value": every["ratio_of_minima"]})
        rows.append({"benchmark": "aovs", "scene": name, "workers": 1, "seconds": one["colour_s_min"],
                     "seconds_aovs": one["colour_aovs_s_min"], "value": one["ratio_of_minima"]})
    out["aovs"] = list(AOV_NAMES)
    out["repeats"] = repeats
    return out


def _icosphere(subdivisions: int):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(m.vertices), np.asarray(m.faces)


def bench_growth(rows, charts, quick: bool):
    size = 96 if quick else 192
    tri_levels = [5, 6, 7] if quick else [5, 6, 7, 8]  # 20k, 82k, 328k, 1.3M triangles
    tris = []
    for level in tri_levels:
        v, f = _icosphere(level)
        # a bumpy sphere, so rays see many triangles at grazing angles too
        v = v * (1.0 + 0.05 * np.sin(7 * v[:, :1]) * np.cos(5 * v[:, 1:2]))
        scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0.5, 3.2), look_at=(0, 0, 0), width=size, height=size),
                             shapes=(warprt.Mesh(vertices=v, faces=f, material="m"), warprt.Plane(point=(0, -1.1, 0))),
                             materials={"m": warprt.Material(kd=0.7, ks=0.3)},
                             lights=(warprt.PointLight(position=(2, 3, 3)),), ambient=0.1)
        start = time.perf_counter()
        r = warprt.Renderer(scene)
        build = time.perf_counter() - start
        r.compile()
        res = sorted((r.render(spp=2, progress=False) for _ in range(3)), key=lambda x: x.wall_time)[1]
        tris.append((len(f), build, res.wall_time, res.mrays_per_s))
        rows.append({"benchmark": "triangles", "count": len(f), "build_seconds": build, "seconds": res.wall_time,
                     "mrays_per_s": res.mrays_per_s})
    print("  triangle growth done", flush=True)
    spheres = []
    rng = np.random.default_rng(0)
    for n in [1, 10, 100, 1000, 10000]:
        c = rng.uniform(-3, 3, (n, 3))
        c[:, 1] = rng.uniform(0.1, 3, n)
        r = rng.uniform(0.05, 0.3, n) * (10.0 / max(n, 10)) ** (1 / 3)
        shapes = tuple(warprt.Sphere(center=tuple(ci), radius=float(ri)) for ci, ri in zip(c, r)) + (warprt.Plane(),)
        scene = warprt.Scene(camera=warprt.Camera(eye=(0, 2, 9), look_at=(0, 1, 0), width=size, height=size),
                             shapes=shapes, lights=(warprt.PointLight(position=(3, 6, 4)),), ambient=0.1)
        rr = warprt.Renderer(scene)
        rr.compile()
        res = sorted((rr.render(spp=2, progress=False) for _ in range(3)), key=lambda x: x.wall_time)[1]
        spheres.append((n, res.wall_time, res.mrays_per_s))
        rows.append({"benchmark": "spheres", "count": n, "seconds": res.wall_time, "mrays_per_s": res.mrays_per_s})
    print("  sphere growth done", flush=True)
    charts["growth"] = (tris, spheres)
    return {"triangles": tris, "spheres": spheres}


_COMPILE_SNIPPET = r"""
import json, sys, time
t0 = time.perf_counter()
import warprt
from warprt import Features
t_import = time.perf_counter() - t0
name = sys.argv[3]  # basic, full, showcase (the scene's own features) or one Features flag
scene = warprt.load_scene(sys.argv[1] if name == "showcase" else sys.argv[2]).with_camera(width=64, height=48)
named = {"basic": Features(), "full": Features.full(), "showcase": None}
feats = named[name] if name in named else Features(**{name: True})
r = warprt.Renderer(scene, device="cpu", features=feats)
compile_s = r.compile()
t2 = time.perf_counter()
r.render(spp=1, progress=False)
print(json.dumps({"import_s": t_import, "compile_s": compile_s, "first_render_s": time.perf_counter() - t2,
                  "key": r.features.key}))
"""

COMPILE_VARIANTS = ("basic", "meshes", "area_lights", "secondary", "refraction", "glossy", "lens", "motion", "full",
                    "showcase")


def bench_compile(rows):
    """Cold compile of each kernel variant, each in a fresh process with an empty kernel cache, so
    every figure includes the one-off start-up of Warp's CPU compiler (what a first render on a
    new machine pays); then a cached load in one more fresh process."""
    out = {}
    scenes = [str(ROOT / "scenes" / "showcase.toml"), str(ROOT / "scenes" / "diffuse.toml")]
    for name in COMPILE_VARIANTS + ("cached",):
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, WARP_CACHE_PATH=cache)
            if name == "cached":  # compile once, then measure a fresh process loading it
                subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET, *scenes, "full"], env=env,
                               capture_output=True, text=True, check=True)
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET, *scenes,
                                   "full" if name == "cached" else name],
                                  env=env, capture_output=True, text=True, check=True)
            wall = time.perf_counter() - start
        rec = json.loads(proc.stdout.strip().splitlines()[-1])
        rec["process_s"] = wall
        out[name] = rec
        rows.append({"benchmark": "compile_cold" if name != "cached" else "compile_cached", "what": name,
                     "key": rec["key"], "seconds": rec["compile_s"], "process_seconds": wall})
    return out


def test_suite_variants():
    path = ROOT / ".cache" / "test-kernel-variants.json"
    if path.exists():
        return json.loads(path.read_text())
    return None


# --- charts --------------------------------------------------------------------------------------


def write_charts(charts, out: Path) -> list[str]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no charts (install the 'charts' extra)")
        return []
    written = []
    if "error_vs_time" in charts:
        curves = charts["error_vs_time"]
        effects = sorted({e for e, _ in curves})
        fig, axes = plt.subplots(2, len(effects), figsize=(4.2 * len(effects), 7.2), squeeze=False)
        for col, effect in enumerate(effects):
            for sampler in SAMPLERS:
                pts = curves.get((effect, sampler))
                if pts:
                    axes[0, col].loglog([p[1] for p in pts], [p[2] for p in pts], "o-", ms=3, label=sampler)
                    axes[1, col].loglog([p[0] for p in pts], [p[2] for p in pts], "o-", ms=3, label=sampler)
            axes[0, col].set_title(effect.replace("_", " "))
            axes[0, col].set_xlabel("wall time (s), 2 worker threads")
            axes[1, col].set_xlabel("samples per pixel")
            for ax in axes[:, col]:
                ax.grid(True, which="both", alpha=0.3)
        axes[0, 0].set_ylabel("relative MSE vs converged reference")
        axes[1, 0].set_ylabel("relative MSE vs converged reference")
        axes[0, 0].legend()
        fig.tight_layout()
        fig.savefig(out / "error_vs_time.png", dpi=90)
        plt.close(fig)
        written.append("error_vs_time.png")
    if "growth" in charts:
        tris, spheres = charts["growth"]
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
        axes[0].semilogx([t[0] for t in tris], [t[2] for t in tris], "o-", label="render")
        axes[0].semilogx([t[0] for t in tris], [t[1] for t in tris], "s--", label="build (BVH)")
        axes[0].set_xlabel("triangles")
        axes[0].set_ylabel("seconds per frame")
        axes[0].legend()
        axes[1].semilogx([s[0] for s in spheres], [s[1] for s in spheres], "o-")
        axes[1].set_xlabel("spheres")
        for ax in axes:
            ax.grid(True, which="both", alpha=0.3)
            ax.set_ylim(bottom=0)
        fig.tight_layout()
        fig.savefig(out / "growth.png", dpi=90)
        plt.close(fig)
        written.append("growth.png")
    if "throughput" in charts or "compile" in charts:
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        tp = charts.get("throughput") or {}
        workers = sorted(k for k in tp if isinstance(k, int))
        if workers:
            axes[0].bar([str(w) for w in workers], [tp[w]["mrays_per_s"] for w in workers], color="tab:blue")
            axes[0].set_xlabel("worker threads (interleaved pixel slices over a thread pool)")
            axes[0].set_ylabel("Mrays/s, showcase scene")
            for i, w in enumerate(workers):
                axes[0].annotate(f"{tp[w]['mrays_per_s']:.2f}", (i, tp[w]["mrays_per_s"]), ha="center", va="bottom")
        cp = charts.get("compile") or {}
        names = [k for k in cp if isinstance(cp[k], dict)]
        if names:
            axes[1].barh(names, [cp[n]["compile_s"] for n in names], color="tab:orange")
            axes[1].set_xlabel("seconds: cold compile, fresh process ('cached': load)")
            axes[1].invert_yaxis()
        for ax in axes:
            ax.grid(True, axis="x" if ax is axes[1] else "y", alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / "throughput_compile.png", dpi=90)
        plt.close(fig)
        written.append("throughput_compile.png")
    return written


def bench_input_checks(rows, quick: bool, pairs: int = 15):
    """The cost of checking a BatchRenderer's device inputs before each render (``warprt.checks``:
    one launch over the pose arrays, light positions and fields of view, one read of six integers):
    renders with ``check_inputs`` on and off, interleaved in ``pairs`` pairs after a warm-up, and
    the check alone. Two batch shapes: many small views (where a fixed cost shows most) and a few
    larger ones."""
    from warprt.checks import check_batch

    scene = plain_scene(16)
    out = {}
    cases = [("one_tiny", 1, 1, 16, 16), ("many_small", 256, 2, 16, 16), ("few_large", 8, 2, 128, 128)]
    if quick:
        cases = [("one_tiny", 1, 1, 16, 16), ("many_small", 32, 2, 16, 16), ("few_large", 2, 1, 64, 64)]
    for name, W, C, H, X in cases:
        b = warprt.BatchRenderer(scene.with_camera(width=X, height=H), worlds=W, cameras=C)
        poses = np.zeros((W, len(scene.shapes), 7))
        poses[..., 6] = 1.0
        poses[..., 0] = np.linspace(-0.5, 0.5, W)[:, None]
        b.set_shape_poses(poses)
        b.render(spp=1)
        on, off = [], []
        for _ in range(pairs):
            for flag, times in ((True, on), (False, off)):
                b.check_inputs = flag
                start = time.perf_counter()
                b.render(spp=1)
                times.append(time.perf_counter() - start)
        alone = []
        for _ in range(pairs):
            start = time.perf_counter()
            check_batch(b, b.shape_poses, b.camera_poses)
            alone.append(time.perf_counter() - start)
        frame = statistics.median(off)
        diffs = [a - b_ for a, b_ in zip(on, off)]
        out[name] = {"worlds": W, "cameras": C, "width": X, "height": H, "elements": W * (len(scene.shapes) * 2 + C * 2)
                     + C, "render_ms_checked": 1e3 * statistics.median(on), "render_ms_unchecked": 1e3 * frame,
                     "check_ms": 1e3 * statistics.median(alone), "check_ms_min": 1e3 * min(alone),
                     "check_share": statistics.median(alone) / frame,
                     "check_percent": 100 * statistics.median(alone) / frame,
                     "pair_difference_ms": [1e3 * min(diffs), 1e3 * statistics.median(diffs), 1e3 * max(diffs)]}
        rows.append({"benchmark": "input_checks", "scene": name, "what": "check", "count": W * C,
                     "seconds": statistics.median(alone)})
        rows.append({"benchmark": "input_checks", "scene": name, "what": "render_1spp_unchecked", "count": W * C,
                     "seconds": frame})
        print(f"  {name}: {W} worlds x {C} cameras at {X}x{H}: check {out[name]['check_ms']:.3f} ms "
              f"(min {out[name]['check_ms_min']:.3f}) = {100 * out[name]['check_share']:.2f}% of a "
              f"{1e3 * frame:.2f} ms 1-spp render; checked - unchecked per pair: "
              f"{', '.join(f'{d:+.3f}' for d in out[name]['pair_difference_ms'])} ms (min, median, max)", flush=True)
    return out


# the results.csv "benchmark" values each step writes (for --merge)
STEP_ROWS = {"compile": ("compile_cold", "compile_cached"), "throughput": ("throughput",),
             "specialisation": ("specialisation",), "growth": ("triangles", "spheres"),
             "error": ("error_vs_time", "equal_error_speedup"), "checks": ("input_checks",), "aovs": ("aovs",)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=None, help="output folder (default docs/benchmarks; with --quick out/bench)")
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    parser.add_argument("--no-docs", action="store_true", help="leave docs/benchmarks.md alone")
    parser.add_argument("--only", default="compile,throughput,specialisation,aovs,growth,error,checks")
    parser.add_argument("--merge", action="store_true",
                        help="update only the measured sections of an existing results.json / results.csv "
                             "(with --only), keeping the others")
    args = parser.parse_args(argv)
    out = Path(args.out or ROOT / ("out/bench" if args.quick else "docs/benchmarks"))
    out.mkdir(parents=True, exist_ok=True)
    only = set(args.only.split(","))
    rows: list[dict] = []
    charts: dict = {}
    results: dict = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                 "workers": default_workers(), "python": platform.python_version()},
                     "quick": args.quick}
    steps = [("compile", lambda: bench_compile(rows)),
             ("throughput", lambda: bench_throughput(rows, args.quick)),
             ("specialisation", lambda: bench_specialisation(rows, args.quick)),
             ("aovs", lambda: bench_aovs(rows, args.quick)),
             ("growth", lambda: bench_growth(rows, charts, args.quick)),
             ("error", lambda: bench_error_vs_time(rows, charts, args.quick)),
             ("checks", lambda: bench_input_checks(rows, args.quick))]
    for name, step in steps:
        if name in only:
            print(f"[{name}]", flush=True)
            start = time.perf_counter()
            results[name] = step()
            if name in ("throughput", "compile"):
                charts[name] = results[name]
            print(f"  {json.dumps(results[name], default=str)[:600]}\n  ({time.perf_counter() - start:.1f} s)", flush=True)
    results["test_suite_kernel_variants"] = test_suite_variants()
    results["charts"] = write_charts(charts, out)
    if args.merge and (out / "results.json").exists():
        old = json.loads((out / "results.json").read_text())
        if old.get("quick") != args.quick:
            raise SystemExit("--merge: the existing results.json has quick = "
                             f"{old.get('quick')}, this run {args.quick}; run everything instead")
        results["charts"] = sorted(set(old.get("charts") or []) | set(results["charts"]))
        if results["test_suite_kernel_variants"] is None:
            del results["test_suite_kernel_variants"]
        results = {**old, **results}
        measured = {b for name in only for b in STEP_ROWS.get(name, ())}
        if (out / "results.csv").exists():
            with open(out / "results.csv", newline="") as f:
                kept = [{k: v for k, v in r.items() if v != ""} for r in csv.DictReader(f)
                        if r["benchmark"] not in measured]
            rows = kept + rows
    (out / "results.json").write_text(json.dumps(results, indent=2, default=str))
    keys = sorted({k for r in rows for k in r})
    with open(out / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out / 'results.json'}, {out / 'results.csv'} and {len(results['charts'])} charts")
    if not (args.quick or args.no_docs) and out.resolve() == docs.DATA.resolve():
        changed = docs.update(docs.RUN_BLOCKS)
        print(f"docs/benchmarks.md: {', '.join(changed) or 'no'} tables changed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
