"""warprt against Mitsuba 3, side by side: time to equal error on six scenes with the same physics.

    python -m benchmarks.peers                    # the full study (about 13 minutes on 2 busy cores)
    python -m benchmarks.peers --quick            # fewer spp points, 1 repeat, smaller references
    python -m benchmarks.peers --scenes a,b --repeats 5
    python -m benchmarks.peers --replot           # chart, table and docs again from peers.json

Needs the ``peers`` extra (``pip install -e ".[peers]"``: Mitsuba 3 and Dr.Jit); without Mitsuba
it prints one line and exits 0. The vectorised ``llvm_ad_rgb`` variant needs the LLVM shared
library (``DRJIT_LIBLLVM_PATH``, found with ``ldconfig`` when unset); without it the script falls
back to ``scalar_rgb`` and says so.

Method (details in docs/benchmarks.md, "Side by side with Mitsuba 3"):

1. Six scenes are built with warprt's public Python API and exported to Mitsuba scene dicts with
   the same physics: Mitsuba's ``direct`` integrator with one emitter sample and no BSDF sample,
   a box pixel filter, Lambert (``twosided(diffuse)``) materials, inverse-square point lights
   (warprt ``intensity = I/pi`` is Mitsuba ``intensity = I``), one-sided rectangle lights, flat
   shaded ``ply`` meshes, a pinhole or thin-lens camera with the vertical field of view.
2. A converged Mitsuba reference per scene (its own noise estimated from two half renders);
   warprt at high spp must converge to the same image before any time is compared.
3. Both renderers on 2 threads, spp 1, 2, 4, ... 1024, with their samplers (warprt ``sobol``,
   ``stratified``, ``sobol+adaptive`` (adaptive sampling with spp as the mean budget),
   ``sobol+split`` (area lights with ``samples = "auto"``) and ``sobol+split+adaptive``;
   Mitsuba ``multijitter`` and ``independent``, and ``multijitter+split``), one warm-up render per
   (scene, sampler, spp) so kernel compile and JIT are excluded, renders interleaved between the
   renderers (each timed render after ``SETTLE_S`` idle, so that neither renderer's idle threads
   share the cores with the other's render), each repeat a sweep over every spp point in turn (so
   that a slow spell of the host, seconds long, falls on one repeat of a few points, not on all
   the repeats of one), the minimum wall time of the repeats (process CPU time too), the mean
   error of the warm-up and the repeats less the reference's own noise.
   Time to relative MSE 1e-2 and 1e-3 is interpolated (log-log) for each renderer's best
   sampler. From 64 spp on, a curve stops once each target is reached, or lost to another
   sampler of the same renderer (``--full-curves`` runs them all to the end).

Writes peers.json (every number), peers.png (error against time, one panel per scene) and
peers.md (the summary table) under docs/benchmarks/ (``--quick``: under out/peers/), and with a
full run also re-renders the ``peers`` tables in docs/benchmarks.md from peers.json
(``benchmarks.docs``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))

import numpy as np  # noqa: E402

import warprt  # noqa: E402
from benchmarks import docs  # noqa: E402
from benchmarks.corpus_scenes import torus  # noqa: E402
from benchmarks.mitsuba_export import (  # noqa: E402,F401  (to_mitsuba, write_ply, ExportError: this module's API too)
    GROUND_HALF, ExportError, load_mitsuba, plane_beyond_extent, to_mitsuba, write_ply,
)
from benchmarks.sidebyside import (  # noqa: E402
    SETTLE_S, TARGETS, THREADS, MitsubaSide, WarprtSide, compare, has_area_lights, machine_info, pyplot,
    render_passes, sweep, time_to_error,
)

# +adaptive: Renderer.render(adaptive=True); +split: the area lights with samples = "auto" (the
# renderer picks the shadow rays per camera sample from the error split, warprt.splitting)
WARPRT_SAMPLERS = ("sobol", "stratified", "sobol+adaptive", "sobol+split", "sobol+split+adaptive")
MITSUBA_SAMPLERS = ("multijitter", "independent")
# Mitsuba with warprt's light-sample split (emitter_samples = the N warprt's samples = "auto" chose),
# run where that N is above 1: the same splitting, hand-set, for an even comparison
MITSUBA_SPLIT = "multijitter+split"


# --- scenes: warprt's public API only ---------------------------------------------------------


def _ground(material: str = "ground") -> warprt.Plane:
    """The ground y = 0. Mitsuba has no infinite plane: the export makes it a square of half side
    GROUND_HALF, and the study checks that no pixel sees the plane beyond that square."""
    return warprt.Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), material=material)


def _point_light(position, intensity_w_per_sr) -> warprt.PointLight:
    """A point light of intensity I (W/sr, Mitsuba's convention: E = I cos / d^2). warprt's point
    light has no 1/pi in its shading (kd * I' * cos), so I' = I/pi is the same light."""
    i = np.broadcast_to(np.asarray(intensity_w_per_sr, dtype=float), (3,))
    return warprt.PointLight(position=position, intensity=tuple(float(c) / math.pi for c in i),
                             falloff="inverse_square")


def _camera_basis(eye, look_at, up=(0.0, 1.0, 0.0)):
    eye, look_at, up = (np.asarray(x, dtype=float) for x in (eye, look_at, up))
    w = eye - look_at
    w /= np.linalg.norm(w)
    u = np.cross(up, w)
    u /= np.linalg.norm(u)
    return u, np.cross(w, u), -w  # right, up, forward


def scene_edges(width: int = 256, height: int = 256) -> warprt.Scene:
    """Edge antialiasing: thin tilted bars receding to sub-pixel width, two rails one pixel wide,
    a parallelogram and ~120 small spheres under one point light (only the pixel integral is
    sampled: hard shadows)."""
    eye, look_at, fov = (0.0, 1.0, 1.0), (0.0, 0.0, -4.0), 50.0
    a = math.radians(8.0)  # bars tilted in the ground plane: no edge is parallel to a pixel row
    long_dir = np.array([math.cos(a), 0.0, -math.sin(a)])
    short_dir = np.array([math.sin(a), 0.0, math.cos(a)])  # short x long = +y
    shapes = []
    for k in range(60):
        centre = np.array([0.0, 0.0, -0.6 - 0.5 * k])
        e1, e2 = 0.12 * short_dir, 40.0 * long_dir
        corner = centre - 0.5 * e1 - 0.5 * e2
        shapes.append(warprt.Rectangle(corner=tuple(corner), edge1=tuple(e1), edge2=tuple(e2), material="bars"))
    # two upright rails facing the camera, one pixel wide where they stand, leaning 3 degrees
    right, up, fwd = _camera_basis(eye, look_at)
    pix = 2.0 * math.tan(math.radians(fov / 2)) / height  # pixel footprint per unit of depth
    for x in (-0.45, 0.5):
        base = np.array([x, 0.0, -1.6])
        depth = float(np.dot(base - np.array(eye), fwd))
        lean = math.radians(3.0 if x < 0 else -3.0)
        e2 = 0.9 * np.array([math.sin(lean), math.cos(lean), 0.0])
        e1 = pix * depth * np.array([math.cos(lean), -math.sin(lean), 0.0])  # e1 x e2 = +z (towards the camera)
        shapes.append(warprt.Rectangle(corner=tuple(base), edge1=tuple(e1), edge2=tuple(e2), material="rails"))
    # a parallelogram (edges 62 degrees apart) facing up towards the light and the camera
    shapes.append(warprt.Rectangle(corner=(-0.35, 0.3, -2.6), edge1=(0.55, 0.0, 0.1), edge2=(0.25, 0.35, -0.3),
                                   material="parallelogram"))
    rng = np.random.default_rng(7)
    spheres = []
    while len(spheres) < 120:
        d = rng.uniform(1.6, 9.0)
        sx, sy = rng.uniform(-0.42, 0.42, 2) * d
        c = np.array(eye) + d * fwd + sx * right + sy * up
        r = rng.uniform(0.004, 0.011) * d  # 1 to 3 pixels in radius
        if c[1] > r + 0.02:
            spheres.append(warprt.Sphere(center=tuple(c), radius=float(r), material=f"ball{len(spheres) % 3}"))
    shapes.extend(spheres)
    materials = {"bars": warprt.Material(kd=0.8, ka=0.0), "rails": warprt.Material(kd=(0.9, 0.85, 0.5), ka=0.0),
                 "parallelogram": warprt.Material(kd=(0.3, 0.6, 0.9), ka=0.0),
                 "ball0": warprt.Material(kd=(0.85, 0.3, 0.25), ka=0.0),
                 "ball1": warprt.Material(kd=(0.3, 0.8, 0.35), ka=0.0),
                 "ball2": warprt.Material(kd=(0.9, 0.9, 0.9), ka=0.0)}
    return warprt.Scene(camera=warprt.Camera(eye=eye, look_at=look_at, fov=fov, width=width, height=height),
                        shapes=tuple(shapes), materials=materials,
                        lights=(_point_light((1.5, 6.0, -4.0), 60.0),))


def scene_two_points(width: int = 256, height: int = 256) -> warprt.Scene:
    """A Lambert sphere over a plane under two inverse-square point lights."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.3, 4.0), look_at=(0.0, 0.5, 0.0), fov=40.0, width=width, height=height),
        shapes=(_ground(), warprt.Sphere(center=(0.0, 0.75, 0.0), radius=0.6, material="ball")),
        materials={"ground": warprt.Material(kd=0.6, ka=0.0), "ball": warprt.Material(kd=(0.75, 0.35, 0.2), ka=0.0)},
        lights=(_point_light((2.5, 4.0, 2.5), (30.0, 28.0, 24.0)), _point_light((-3.0, 2.5, 1.0), (8.0, 10.0, 14.0))))


def scene_visible_light(width: int = 256, height: int = 256) -> warprt.Scene:
    """A visible, tilted, one-sided rectangle light over a plane, its lower edge below the plane."""
    tilt = math.radians(35.0)  # from vertical, leaning back: it faces the camera and the ground in front
    e1 = (1.6, 0.0, 0.0)
    e2 = tuple(1.6 * np.array([0.0, math.cos(tilt), -math.sin(tilt)]))  # e1 x e2 points to +z and down
    centre = np.array([0.0, 0.5, -0.6])
    corner = centre - 0.5 * np.array(e1) - 0.5 * np.array(e2)  # lower edge at y = 0.5 - 0.8 cos 35 < 0
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.6, 4.2), look_at=(0.0, 0.4, -0.3), fov=42.0, width=width, height=height),
        shapes=(_ground(),),
        materials={"ground": warprt.Material(kd=(0.7, 0.65, 0.6), ka=0.0)},
        lights=(warprt.RectLight(corner=tuple(corner), edge1=e1, edge2=e2, radiance=(3.0, 2.8, 2.5), samples=1),))


def bumpy_torus(n_major: int, n_minor: int, major: float, minor: float, bumps: float = 0.0):
    """A torus around the y axis as an (n_major x n_minor) quad grid, 2 triangles per quad, with
    optional bumps on the tube radius (``benchmarks.corpus_scenes.torus``)."""
    return torus(n_major, n_minor, major, minor, bumps)


def scene_big_mesh(width: int = 256, height: int = 256) -> warprt.Scene:
    """A 327,680-triangle bumpy torus on a ground plane under a rectangle light."""
    v, f = bumpy_torus(640, 256, major=0.9, minor=0.35, bumps=0.06)
    v = v + np.array([0.0, 0.35 * 1.06 + 0.02, 0.0])
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 2.2, 3.0), look_at=(0.0, 0.25, 0.0), fov=45.0, width=width, height=height),
        shapes=(_ground(), warprt.Mesh(vertices=v, faces=f, material="torus")),
        materials={"ground": warprt.Material(kd=0.6, ka=0.0), "torus": warprt.Material(kd=(0.8, 0.55, 0.3), ka=0.0)},
        lights=(warprt.RectLight(corner=(-1.5, 3.0, -1.0), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 0.0, 2.0),
                                 radiance=3.0, samples=1),))


def _penumbra_shapes():
    import trimesh

    v, f = bumpy_torus(64, 32, major=0.55, minor=0.2)  # 4,096 triangles
    rot = math.radians(60.0)  # stood up about x
    rx = np.array([[1, 0, 0], [0, math.cos(rot), -math.sin(rot)], [0, math.sin(rot), math.cos(rot)]])
    torus_centre = np.array([-0.75, 0.75, 0.0])
    v = v @ rx.T + torus_centre
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.45)  # 1,280 triangles
    iv = np.asarray(ico.vertices) + np.array([0.85, 0.45, 0.35])
    shapes = (_ground(), warprt.Mesh(vertices=v, faces=f, material="torus"),
              warprt.Mesh(vertices=iv, faces=np.asarray(ico.faces), material="ball"))
    return shapes, torus_centre


def _penumbra_scene(width: int, height: int, aperture: float) -> warprt.Scene:
    shapes, torus_centre = _penumbra_shapes()
    eye, look_at = (0.3, 1.6, 4.0), (0.0, 0.4, 0.0)
    focus = None
    if aperture > 0:  # focus on the torus: its centre's distance along the view axis (a focus plane)
        _, _, fwd = _camera_basis(eye, look_at)
        focus = float(np.dot(torus_centre - np.array(eye), fwd))
    return warprt.Scene(
        camera=warprt.Camera(eye=eye, look_at=look_at, fov=40.0, width=width, height=height, aperture=aperture,
                             focus_distance=focus),
        shapes=shapes,
        materials={"ground": warprt.Material(kd=0.65, ka=0.0), "torus": warprt.Material(kd=(0.3, 0.55, 0.85), ka=0.0),
                   "ball": warprt.Material(kd=(0.85, 0.4, 0.3), ka=0.0)},
        # out of view above the camera; large and close, so the shadows are mostly penumbra
        lights=(warprt.RectLight(corner=(-1.6, 2.6, -0.2), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 0.3, 1.6),
                                 radiance=2.5, samples=1),))


def scene_penumbrae(width: int = 320, height: int = 240) -> warprt.Scene:
    """Rectangle-light penumbrae: a 4k-triangle torus and a 1.3k-triangle icosphere on the ground,
    the light out of view."""
    return _penumbra_scene(width, height, aperture=0.0)


def scene_thin_lens(width: int = 320, height: int = 240) -> warprt.Scene:
    """The penumbra scene through a thin lens of radius 0.35, focused on the torus."""
    return _penumbra_scene(width, height, aperture=0.35)


@dataclass(frozen=True)
class SceneKind:
    key: str
    name: str
    build: object  # (width, height) -> warprt.Scene
    size: tuple[int, int]


SCENES = {s.key: s for s in (
    SceneKind("a", "edges", scene_edges, (256, 256)),
    SceneKind("b", "two point lights", scene_two_points, (256, 256)),
    SceneKind("c", "visible area light", scene_visible_light, (256, 256)),
    SceneKind("d", "328k-triangle mesh", scene_big_mesh, (256, 256)),
    SceneKind("e", "penumbrae", scene_penumbrae, (320, 240)),
    SceneKind("f", "penumbrae, thin lens", scene_thin_lens, (320, 240)),
)}


def build_scene(key: str, width: int | None = None, height: int | None = None) -> warprt.Scene:
    kind = SCENES[key]
    w, h = kind.size
    return kind.build(width or w, height or h)


# --- the study ---------------------------------------------------------------------------------


def _settled(curve, siblings) -> bool:
    """A curve need not go on once every target is either reached or lost: another sampler of
    the same renderer reached it in less time than this one has already spent."""
    pts = [(p["seconds"], p["rel_mse_corrected"]) for p in curve]
    for target in TARGETS:
        if time_to_error(pts, target)[0] is not None:
            continue
        t_sib = [time_to_error([(p["seconds"], p["rel_mse_corrected"]) for p in sib], target)[0] for sib in siblings]
        t_sib = [t for t in t_sib if t is not None]
        if not t_sib or pts[-1][0] <= min(t_sib):
            return False
    return True


def study_scene(key: str, mi, dr, args, log) -> dict:
    kind = SCENES[key]
    scene = build_scene(key)
    w, h = kind.size
    rec = {"key": key, "name": kind.name, "width": w, "height": h, "triangles": int(sum(
        len(s.faces) for s in scene.shapes if isinstance(s, warprt.Mesh))), "shapes": len(scene.shapes),
        "lights": len(scene.lights)}
    log(f"[{key}] {kind.name}: {w}x{h}, {rec['shapes']} shapes, {rec['triangles']} triangles, {rec['lights']} lights")
    t0 = time.perf_counter()
    # one renderer per configuration (share=False), as in this study's earlier runs
    ws = WarprtSide(scene, [s for s in WARPRT_SAMPLERS if "+split" not in s or has_area_lights(scene)], share=False)
    ms = MitsubaSide(scene, mi, dr, samplers=MITSUBA_SAMPLERS + (MITSUBA_SPLIT,),
                     emitter_samples=ws.light_samples.get("sobol+split"))
    rec["setup"] = {"warprt_build_s": ws.build_s, "warprt_compile_s": ws.compile_s, "mitsuba_load_s": ms.build_s,
                    "warprt_light_samples": ws.light_samples, "warprt_light_maps": ws.light_maps,
                    "warprt_split_pilot_s": ws.split_pilot_s}
    log(f"  set-up: warprt build {ws.build_s:.2f} s + kernel load/compile {ws.compile_s:.2f} s; "
        f"mitsuba load_dict {ms.build_s:.2f} s ({len(ms.samplers)} samplers)")
    if any(ws.light_samples.values()):
        log(f"  warprt light samples per camera sample (samples = \"auto\"): {ws.light_samples}, "
            f"pilots {ws.split_pilot_s:.2f} s in all; split maps (uniform renders; blocks per count): {ws.light_maps}")

    # 1. reference (Mitsuba) and convergence of warprt to it
    t_ref = time.perf_counter()
    ref_sampler = "multijitter"
    ref, ref_halves, ref_s, ref_spp = render_passes(ms, ref_sampler, args.ref_spp, 1_000_003, args.ref_pass)
    t_chk = time.perf_counter()
    wimg, w_halves, w_s, w_spp = render_passes(ws, "sobol", args.check_spp, 2_000_003, args.check_pass)
    t_end = time.perf_counter()
    c = compare(wimg, w_halves, ref, ref_halves, args.agree_factor)
    floor, err, ratio, agree = c["noise_floor_reference"], c["rel_mse"], c["ratio_to_noise"], c["agree"]
    m_w, m_ref, z = c["mean_image"], c["mean_reference"], c["mean_z"]
    rec["reference"] = {"renderer": "mitsuba", "sampler": ref_sampler, "spp": ref_spp, "seconds": ref_s,
                        "wall_s": t_chk - t_ref, "noise_floor_rel_mse": floor, "mean": m_ref}
    rec["convergence"] = {"warprt_sampler": "sobol", "warprt_spp": w_spp, "warprt_seconds": w_s,
                          "wall_s": t_end - t_chk, "warprt_noise_floor_rel_mse": c["noise_floor_image"],
                          "rel_mse_warprt_vs_reference": err, "expected_from_noise": c["expected_from_noise"],
                          "ratio_to_noise": ratio, "mean_warprt": m_w, "mean_reference": m_ref,
                          "mean_rel_diff": c["mean_rel_diff"], "mean_z": z,
                          "mean_within_noise": c["mean_within_noise"], "agree": agree}
    log(f"  reference: mitsuba {ref_sampler} {ref_spp} spp in {ref_s:.1f} s, own noise relMSE {floor:.2e}")
    log(f"  warprt sobol {w_spp} spp in {w_s:.1f} s, own noise {c['noise_floor_image']:.2e}: relMSE vs reference "
        f"{err:.2e} ({ratio:.2f}x the noise of the two), mean {m_w:.5f} vs {m_ref:.5f} "
        f"({100 * (m_w - m_ref) / m_ref:+.3f}%, z = {z:+.1f}): {'AGREE' if agree else 'DIFFER'}"
        f"{'' if c['mean_within_noise'] or not agree else ' (mean beyond noise)'}")
    beyond = plane_beyond_extent(scene, wimg)
    rec["convergence"]["plane_beyond_extent"] = beyond
    if beyond["pixels"]:
        log(f"  ground: {beyond['pixels']} pixels see the plane farther than {GROUND_HALF:g} (where Mitsuba's square "
            f"may end), radiance there <= {beyond['radiance_bound']:.1e}: relMSE <= {beyond['rel_mse_bound']:.1e}")
    if args.save_images:
        d = Path(args.out) / "images"
        d.mkdir(parents=True, exist_ok=True)
        np.save(d / f"{key}-mitsuba-ref.npy", ref.astype(np.float32))
        np.save(d / f"{key}-warprt-check.npy", wimg.astype(np.float32))

    # 2. timing sweep, interleaved (benchmarks.sidebyside.sweep); from min_spp on a curve stops
    # once each target is reached, or lost to the same renderer's other sampler
    def stop(k, curves):
        side = k.split("/", 1)[0]
        siblings = [v for o, v in curves.items() if o.startswith(side + "/") and o != k]
        return args.early_stop and curves[k][-1]["spp"] >= args.min_spp and _settled(curves[k], siblings)

    t_sweep = time.perf_counter()
    curves = sweep([(ws, ws.configs), (ms, ms.configs)], args.spps, args.repeats, ref, floor, stop, log=log,
                   settle=SETTLE_S)
    rec["sweep_wall_s"] = time.perf_counter() - t_sweep
    rec["curves"] = curves
    rec["warmup_total_s"] = {k: sum(p["warmup_s"] for p in v) for k, v in curves.items()}

    # 3. time to error, each renderer's best sampler
    summary = {}
    for target in TARGETS:
        row = {}
        for renderer, samplers in (("warprt", ws.configs), ("mitsuba", ms.samplers)):
            best = None
            for s in samplers:
                pts = [(p["seconds"], p["rel_mse_corrected"]) for p in curves[f"{renderer}/{s}"]]
                t, how = time_to_error(pts, target)
                row[f"{renderer}/{s}"] = {"seconds": t, "how": how}
                if t is not None and (best is None or t < best[1]):
                    best = (s, t, how)
            row[renderer] = {"sampler": best[0], "seconds": best[1], "how": best[2]} if best else None
        if row["warprt"] and row["mitsuba"]:
            row["ratio_warprt_over_mitsuba"] = row["warprt"]["seconds"] / row["mitsuba"]["seconds"]
            # the same on process CPU seconds (both renderers' best samplers as chosen on wall time):
            # less sensitive to other load on a shared machine, blind to idle threads
            cpu = {}
            for renderer in ("warprt", "mitsuba"):
                pts = [(p["cpu_seconds"], p["rel_mse_corrected"]) for p in curves[f"{renderer}/{row[renderer]['sampler']}"]]
                cpu[renderer] = time_to_error(pts, target)[0]
            row["cpu_seconds"] = cpu
            row["cpu_ratio_warprt_over_mitsuba"] = (cpu["warprt"] / cpu["mitsuba"]
                                                    if cpu["warprt"] and cpu["mitsuba"] else None)
        else:
            row["ratio_warprt_over_mitsuba"] = None
            row["cpu_ratio_warprt_over_mitsuba"] = None
        summary[f"{target:g}"] = row
    rec["time_to_error"] = summary
    # throughput: each sampler at the highest spp that every curve reached (the same work size)
    common = min(v[-1]["spp"] for v in curves.values() if v)
    rec["throughput_spp"] = common
    rec["msamples_per_s"] = {k: next(p["msamples_per_s"] for p in v if p["spp"] == common)
                             for k, v in curves.items() if v}
    rec["mitsuba_jit_s"] = {k: max(0.0, p["warmup_s"] - p["seconds"]) for k in curves if k.startswith("mitsuba")
                            for p in curves[k][:1]}
    rec["wall_s"] = time.perf_counter() - t0
    log(f"  scene done in {rec['wall_s']:.0f} s (reference {rec['reference']['wall_s']:.0f} s, "
        f"check {rec['convergence']['wall_s']:.0f} s, sweep {rec['sweep_wall_s']:.0f} s)")
    ws.close()
    ms.close()
    return rec


# --- output ------------------------------------------------------------------------------------


def _fmt_t(entry) -> str:
    if not entry:
        return "not reached"
    t = entry["seconds"]
    s = f"{t:.3f} s" if t < 10 else f"{t:.1f} s"
    return ("≤ " if entry["how"] == "<=" else "") + s + f" ({entry['sampler']})"


def _fmt_ratio(row) -> str:
    r = row.get("ratio_warprt_over_mitsuba")
    if r is None:
        return "n/a"
    bound = (row["warprt"]["how"] == "<=") or (row["mitsuba"]["how"] == "<=")
    return ("~" if bound else "") + f"{r:.2f}×"


def _fmt_cpu_ratio(row) -> str:
    r = row.get("cpu_ratio_warprt_over_mitsuba")
    return "n/a" if r is None else f"{r:.2f}×"


def _llvm_note(machine: dict) -> str:
    """Which LLVM library Dr.Jit's LLVM backend ran on (its code generation, hence Mitsuba's
    speed, depends on the version): " (libLLVM-15.so)"; empty for other variants or older runs."""
    lib = machine.get("libllvm")
    return f" ({os.path.basename(lib)})" if lib and machine.get("variant", "").startswith("llvm") else ""


def _cpu_note(machine: dict) -> str:
    """" (AMD EPYC, AVX-512)" after the core count; empty for runs that did not record it."""
    cpu = ", ".join(x for x in (machine.get("cpu"), machine.get("simd")) if x)
    return f" ({cpu})" if cpu else ""


def markdown_table(results: dict) -> str:
    lines = ["| scene | size | same image? | warprt → 1e-2 | Mitsuba → 1e-2 | ratio | warprt → 1e-3 | "
             "Mitsuba → 1e-3 | ratio | ratio on CPU s | Msamples/s warprt | Msamples/s Mitsuba |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for rec in results["scenes"].values():
        c = rec["convergence"]
        mean = f"mean {100 * c['mean_rel_diff']:+.3f}%" + ("" if c["mean_within_noise"] else f" ({abs(c['mean_z']):.0f}σ)")
        same = (f"yes: {c['ratio_to_noise']:.2f}× noise, {mean}" if c["agree"]
                else f"**no**: {c['ratio_to_noise']:.1f}× noise, {mean}")
        t2, t3 = rec["time_to_error"]["0.01"], rec["time_to_error"]["0.001"]
        best_w = (t3.get("warprt") or t2.get("warprt") or {"sampler": "sobol"})["sampler"]
        best_m = (t3.get("mitsuba") or t2.get("mitsuba") or {"sampler": "independent"})["sampler"]
        tp = rec["msamples_per_s"]
        lines.append(f"| ({rec['key']}) {rec['name']} | {rec['width']}×{rec['height']} | {same} | "
                     f"{_fmt_t(t2['warprt'])} | {_fmt_t(t2['mitsuba'])} | {_fmt_ratio(t2)} | "
                     f"{_fmt_t(t3['warprt'])} | {_fmt_t(t3['mitsuba'])} | {_fmt_ratio(t3)} | "
                     f"{_fmt_cpu_ratio(t3)} | "
                     f"{tp.get('warprt/' + best_w, float('nan')):.1f} ({best_w}) | "
                     f"{tp.get('mitsuba/' + best_m, float('nan')):.1f} ({best_m}) |")
    m = results["machine"]
    lines.append("")
    lines.append(f"Ratio = warprt wall time / Mitsuba wall time to the same relative MSE (below 1: warprt is faster), "
                 f"each with its best sampler; \"≤\": below the target already at 1 spp, an upper bound, and \"~\" a ratio "
                 f"from one; \"ratio on CPU s\": "
                 f"the same at 1e-3 on process CPU seconds. Mitsuba {m['mitsuba']} "
                 f"`{m['variant']}`{_llvm_note(m)}, warprt {m['warprt']} on the CPU device, {THREADS} threads each, "
                 f"{results['repeats']} repeats (each a sweep over the spp points, the renderers interleaved), "
                 f"min time; {m['cpus']} CPU cores{_cpu_note(m)}, Python {m['python']}. "
                 f"Msamples/s: pixel samples per second at the highest spp all four curves reached "
                 f"({', '.join(sorted({str(r['throughput_spp']) for r in results['scenes'].values()}))} spp).")
    return "\n".join(lines)


def write_chart(results: dict, path: Path) -> bool:
    plt = pyplot()
    if plt is None:
        return False
    import matplotlib.ticker
    recs = list(results["scenes"].values())
    cols = min(3, len(recs))
    rows = math.ceil(len(recs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.9 * rows), squeeze=False)
    style = {"warprt/sobol": ("tab:blue", "o-"), "warprt/stratified": ("tab:blue", "s--"),
             "warprt/sobol+adaptive": ("tab:cyan", "^-"), "warprt/sobol+split": ("tab:purple", "v-"),
             "warprt/sobol+split+adaptive": ("tab:pink", "D-"),
             "mitsuba/multijitter": ("tab:red", "o-"), "mitsuba/independent": ("tab:red", "s--"),
             "mitsuba/multijitter+split": ("tab:orange", "^-")}
    for ax, rec in zip(axes.flat, recs):
        for k, pts in rec["curves"].items():
            if pts:
                color, fmt = style.get(k, ("k", "o-"))
                ax.loglog([p["seconds"] for p in pts], [p["rel_mse"] for p in pts], fmt, color=color, ms=3, label=k)
        for t in TARGETS:
            ax.axhline(t, color="0.6", lw=0.8, ls=":")
        ax.axhline(rec["reference"]["noise_floor_rel_mse"], color="0.3", lw=0.8, ls="-.", label="reference noise")
        r3 = rec["time_to_error"]["0.001"].get("ratio_warprt_over_mitsuba")
        ax.set_title(f"({rec['key']}) {rec['name']}" + (f": {r3:.2f}× at 1e-3" if r3 else ""), fontsize=10)
        ax.set_xlabel(f"wall time (s), {THREADS} threads")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_ylabel("relative MSE vs reference")
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[len(recs):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("warprt (blue) and Mitsuba 3 (red): error against time; ratio = warprt / Mitsuba time to 1e-3",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def print_table(results: dict) -> None:
    print()
    print(f"{'scene':28s} {'same image':>10s} {'w->1e-2':>9s} {'m->1e-2':>9s} {'ratio':>6s} {'w->1e-3':>9s} "
          f"{'m->1e-3':>9s} {'ratio':>6s} {'cpu':>6s} {'Ms/s w':>7s} {'Ms/s m':>7s}")
    for rec in results["scenes"].values():
        t2, t3 = rec["time_to_error"]["0.01"], rec["time_to_error"]["0.001"]

        def t(e):
            return f"{e['seconds']:.3f}" if e else "-"

        def r(row):
            return f"{row['ratio_warprt_over_mitsuba']:.2f}" if row.get("ratio_warprt_over_mitsuba") else "-"

        bw = (t3.get("warprt") or t2.get("warprt") or {"sampler": "sobol"})["sampler"]
        bm = (t3.get("mitsuba") or t2.get("mitsuba") or {"sampler": "independent"})["sampler"]
        tp = rec["msamples_per_s"]
        print(f"({rec['key']}) {rec['name']:24s} {'yes' if rec['convergence']['agree'] else 'NO':>10s} "
              f"{t(t2['warprt']):>9s} {t(t2['mitsuba']):>9s} {r(t2):>6s} {t(t3['warprt']):>9s} "
              f"{t(t3['mitsuba']):>9s} {r(t3):>6s} {_fmt_cpu_ratio(t3).rstrip('×'):>6s} "
              f"{tp.get('warprt/' + bw, float('nan')):7.1f} "
              f"{tp.get('mitsuba/' + bm, float('nan')):7.1f}")
    print("wall seconds to relative MSE 1e-2 / 1e-3, best sampler each; ratio = warprt / Mitsuba; cpu: the 1e-3 "
          "ratio on process CPU seconds; Ms/s = Msamples/s")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer spp points, 1 repeat, smaller references")
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated scene keys (default: all)")
    parser.add_argument("--repeats", type=int, default=None, help="timed repeats per point (default 3, quick 1)")
    parser.add_argument("--out", default=None, help="output folder (default docs/benchmarks, quick: out/peers)")
    parser.add_argument("--ref-spp", type=int, default=None, help="Mitsuba reference spp (default 4096, quick 512)")
    parser.add_argument("--check-spp", type=int, default=None, help="warprt convergence check spp (default 1024)")
    parser.add_argument("--max-spp", type=int, default=None, help="largest spp of the sweep (default 1024, quick 64)")
    parser.add_argument("--full-curves", action="store_true",
                        help="run every curve to the largest spp (default: a curve stops, from 64 spp on, once "
                             "each target is reached, or lost to the renderer's other sampler)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant to try first")
    parser.add_argument("--save-images", action="store_true", help="keep the reference and check images (npy)")
    parser.add_argument("--no-docs", action="store_true", help="do not update docs/benchmarks.md")
    parser.add_argument("--replot", action="store_true",
                        help="render nothing: rewrite the chart, table and docs from the output folder's peers.json")
    args = parser.parse_args(argv)
    if args.replot:
        out = Path(args.out or ROOT / ("out/peers" if args.quick else "docs/benchmarks"))
        results = json.loads((out / "peers.json").read_text())
        return _write_outputs(results, out, args, results.get("quick", False))

    loaded = load_mitsuba(args.variant)
    if loaded is None:
        print("benchmarks.peers: Mitsuba 3 is not installed (pip install -e \".[peers]\"); nothing to compare, skipping.")
        return 0
    mi, dr, variant, note = loaded
    if note:
        print(f"note: {note}")
    scalar = variant.startswith("scalar")
    q = args.quick
    args.repeats = args.repeats or (1 if q else 3)
    args.ref_spp = args.ref_spp or (512 if q or scalar else 4096)
    args.check_spp = args.check_spp or (64 if q else 256)
    args.ref_pass = 64 if scalar else 256
    args.check_pass = 128
    max_spp = args.max_spp or (64 if q else 1024)
    args.spps = [1 << k for k in range(0, 21) if (1 << k) <= max_spp]
    if q:
        args.spps = [s for s in args.spps if s in (1, 4, 16, 64) or s == max_spp]
    args.early_stop = not args.full_curves
    args.min_spp = min(16 if q else 64, max_spp)
    args.agree_factor = 2.0
    args.out = args.out or str(ROOT / ("out/peers" if q else "docs/benchmarks"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = [k.strip() for k in args.scenes.split(",") if k.strip()]
    bad = [k for k in keys if k not in SCENES]
    if bad:
        parser.error(f"unknown scene(s) {', '.join(bad)}; choose from {', '.join(SCENES)}")

    results = {"machine": machine_info(mi, dr, variant, note),
               "quick": q, "repeats": args.repeats, "spps": args.spps, "ref_spp": args.ref_spp,
               "check_spp": args.check_spp, "early_stop": args.early_stop, "min_spp": args.min_spp,
               "targets": list(TARGETS),
               "error": "warprt.testing.relative_mse(image, reference) = mean((a - ref)^2) / mean(ref^2); "
                        "rel_mse is the mean over the warm-up and the repeats (seeds 99, 1..repeats); rel_mse_corrected subtracts the "
                        "reference's own noise (noise_floor_rel_mse) and is what time_to_error interpolates",
               "scenes": {}}
    print(f"warprt {warprt.__version__} (Warp {results['machine']['warp']}, cpu, {THREADS} workers) vs Mitsuba {mi.__version__} "
          f"{variant} ({THREADS} threads); repeats {args.repeats}, spp {args.spps[0]}..{args.spps[-1]}, "
          f"reference {args.ref_spp} spp", flush=True)

    def log(msg):
        print(msg, flush=True)

    start = time.perf_counter()
    for key in keys:
        results["scenes"][key] = study_scene(key, mi, dr, args, log)
        (out / "peers.json").write_text(json.dumps(results, indent=1, default=str))  # partial results survive
    results["wall_s"] = time.perf_counter() - start
    (out / "peers.json").write_text(json.dumps(results, indent=1, default=str))
    return _write_outputs(results, out, args, q)


def _write_outputs(results: dict, out: Path, args, quick: bool) -> int:
    table = markdown_table(results)
    (out / "peers.md").write_text(table + "\n")
    charted = write_chart(results, out / "peers.png")
    print_table(results)
    print()
    print(table)
    updated = False
    if not quick and not args.no_docs and out.resolve() == docs.DATA.resolve():
        updated = bool(docs.update(["peers", "machine"]))
    print(f"\nwrote {out / 'peers.json'}, {out / 'peers.md'}{', ' + str(out / 'peers.png') if charted else ''}"
          f"{' and the tables in docs/benchmarks.md' if updated else ''}; total {results.get('wall_s', 0):.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
