"""The benchmark corpus: 31 scenes of the kinds users render, warprt against Mitsuba 3, training
and validation halves apart.

    python -m benchmarks.corpus                       # every scene (docs/benchmarks.md: the last run's time)
    python -m benchmarks.corpus --split train --quick # the training half, 1 repeat, a smaller check
    python -m benchmarks.corpus --scenes fence,bars --configs defaults,sobol+split+adaptive
    python -m benchmarks.corpus --list                # the corpus: name, kind, split
    python -m benchmarks.corpus --check-only          # references and convergence checks, no timing
    python -m benchmarks.corpus --replot              # tables, chart and docs again from corpus.json

**The split.** ``CORPUS`` fixes, scene by scene, a training half and a validation half, balanced
by kind (every kind has scenes on both sides). The training half is where warprt's constants,
thresholds and defaults are chosen; **the validation half is for reporting only: never tune a
constant on it**, nor choose between two designs by it. The split is part of the code, not drawn
at run time, so it is the same on every run and every machine.

**The method** (``benchmarks.sidebyside``, shared with ``benchmarks.peers``): every scene is built
with warprt's public API (``benchmarks.corpus_scenes``) and exported with the same physics to
Mitsuba 3 (``benchmarks.mitsuba_export``: its ``direct`` integrator, or a Whitted integrator
written for it where mirrors and glass need the recursion). Per scene:

1. a Mitsuba reference (``multijitter``) in seeded passes until its own noise (relMSE of its two
   halves / 4) is below ``--ref-floor`` (or its spp or time cap), cached on disk under
   ``.cache/corpus/`` keyed by the scene's content, the reference settings and the Mitsuba
   version, so reruns do not render it again. Mitsuba 3 has no motion blur (no animated
   transforms): for a moving scene the reference is the mean of still Mitsuba renders (8 spp
   each) at shutter times drawn in rounds, each round two independent stratified sets of 64
   times (one per half: an unbiased estimate of the motion-blurred image whose halves stay
   independent, so its noise estimate holds), to a noise goal 5 times the others'; such scenes
   get warprt's times but no peer ratio;
2. the check that both converge to the same image: warprt (``sobol``, ``--check-spp``) against
   the reference, their relMSE within 2× the sum of the two noise floors and the image means
   within 4σ (or 0.1%);
3. the timing sweep: warprt's configurations (``--configs``; ``defaults`` is ``Renderer.render``
   with no option, whatever warprt does by default; ``+split`` gives area lights ``samples =
   "auto"``, ``+adaptive`` renders with ``adaptive=True``; a configuration that renders the same
   as another on a scene, ``+split`` without area lights, shares its curve) and Mitsuba's
   ``multijitter``, both on 2 threads, spp 1, 2, 4, ..., one warm-up render per (configuration,
   spp) excluded from the times (kernel compile, JIT), the renderers interleaved with an idle
   settle before each timed render, each repeat a sweep over the spp points, the minimum of the
   repeats; a curve stops once its error (less the reference's noise) is below 1e-3, or a render
   took longer than ``--max-render-s``, or at ``--max-spp``;
4. time to relMSE 1e-2 and 1e-3 (log-log interpolation), the ratio warprt / Mitsuba per
   configuration, per repeat (their spread) and from the repeats' minima.

Per split and configuration: the geometric mean and the worst ratio over the scenes with a peer,
and the spread of the geometric mean over the repeats. Writes ``corpus.json`` (every number),
``corpus.md`` (the tables) and ``corpus.png`` (the ratios, one panel per split) under
``out/corpus/``; a run over the whole corpus (not ``--quick``, no ``--scenes``/``--kinds``/
``--split`` filter) also copies corpus.json and corpus.png to docs/benchmarks/ and re-renders the
``corpus`` tables in docs/benchmarks.md from them (``benchmarks.docs``; ``--no-docs`` not to).

Emitters are kept out of the camera's direct view (or behind it): the relative MSE of an image
with a visible light is dominated by the few very bright pixels of its silhouette and would
measure those edges only.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))

import numpy as np  # noqa: E402

import warprt  # noqa: E402
from benchmarks import corpus_scenes as cs  # noqa: E402
from benchmarks import docs  # noqa: E402
from benchmarks.mitsuba_export import (  # noqa: E402
    GROUND_HALF, ExportError, ground_half, load_mitsuba, moves, plane_beyond_extent, scene_at_time, scene_digest, to_mitsuba,
)
from benchmarks.sidebyside import (  # noqa: E402
    SETTLE_S, TARGETS, THREADS, MitsubaSide, PassSum, WarprtSide, compare, effective_config, machine_info,
    noise_floor, parse_config, pyplot, render_passes, sweep, time_to_error,
)

TRAIN, VALIDATION = "train", "validation"
DEFAULT_CONFIGS = ("defaults", "sobol", "stratified", "sobol+split", "sobol+adaptive", "sobol+split+adaptive")
MITSUBA_SAMPLER = "multijitter"
# bump when the export or the reference method changes what a reference image is (cache key)
REFERENCE_VERSION = 2
MARK_BEGIN = docs.begin_marker("corpus")  # where docs/benchmarks.md holds the tables
MARK_END = docs.end_marker("corpus")
MOVING_FLOOR_FACTOR = 5  # a moving scene's reference noise goal: this times --ref-floor
TIME_STRATA = 64  # shutter times per half and round of a moving scene's reference


@dataclass(frozen=True)
class Entry:
    name: str
    kind: str
    build: object  # (width=None, height=None) -> warprt.Scene
    split: str


# The corpus and its split, fixed once: the training half is for tuning, the validation half for
# reporting only (never tune a constant on it). Every kind has scenes on both sides.
CORPUS = tuple(Entry(*e) for e in (
    ("room-two-boxes", "room lit from the ceiling", cs.room_two_boxes, TRAIN),
    ("room-shelves", "room lit from the ceiling", cs.room_shelves, VALIDATION),
    ("instances-tori-48", "instances", cs.instances_tori, TRAIN),
    ("instances-mixed-200", "instances", cs.instances_mixed, VALIDATION),
    ("sphere-and-disk", "sphere and disk lights", cs.sphere_and_disk, TRAIN),
    ("three-sphere-lights", "sphere and disk lights", cs.three_sphere_lights, VALIDATION),
    ("points-16", "many lights", cs.points_16, TRAIN),
    ("mixed-32", "many lights", cs.mixed_32, VALIDATION),
    ("spheres-64", "many lights", cs.spheres_64, TRAIN),
    ("mirror-spheres", "mirrors", cs.mirror_spheres, TRAIN),
    ("mirror-room", "mirrors", cs.mirror_room, VALIDATION),
    ("glass-ball", "glass", cs.glass_ball, TRAIN),
    ("glass-mesh", "glass", cs.glass_mesh, VALIDATION),
    ("mesh-1k", "meshes", cs.mesh_1k, TRAIN),
    ("mesh-80k", "meshes", cs.mesh_80k, VALIDATION),
    ("mesh-500k", "meshes", cs.mesh_500k, TRAIN),
    ("mesh-2m", "meshes", cs.mesh_2m, VALIDATION),
    ("lens-row", "thin lens", cs.lens_row, TRAIN),
    ("lens-instances", "thin lens", cs.lens_instances, VALIDATION),
    ("moving-spheres", "motion blur", cs.moving_spheres, TRAIN),
    ("moving-mesh-camera", "motion blur", cs.moving_mesh_camera, VALIDATION),
    ("spheres-720p", "high resolution", cs.spheres_720p, TRAIN),
    ("street-1080p", "high resolution", cs.street_1080p, VALIDATION),
    ("tabletop-64", "robot camera", cs.tabletop_64, TRAIN),
    ("bin-128", "robot camera", cs.bin_128, VALIDATION),
    ("contact-blocks", "contact shadows", cs.contact_blocks, TRAIN),
    ("contact-figures", "contact shadows", cs.contact_figures, VALIDATION),
    ("fence", "edges", cs.fence, TRAIN),
    ("checker", "edges", cs.checker, VALIDATION),
    ("bars", "penumbrae", cs.bars, TRAIN),
    ("disk-penumbrae", "penumbrae", cs.disk_penumbrae, VALIDATION),
))
BY_NAME = {e.name: e for e in CORPUS}
KINDS = tuple(dict.fromkeys(e.kind for e in CORPUS))


def entries(split: str = "all", names=None, kinds=None) -> list[Entry]:
    out = [e for e in CORPUS if split == "all" or e.split == split]
    if names:
        out = [BY_NAME[n] for n in names]
    if kinds:
        out = [e for e in out if e.kind in kinds]
    return out


# --- references ----------------------------------------------------------------------------------------


def pass_spp_for(width: int, height: int, cap: int = 256) -> int:
    """The spp of one reference pass: at most 2^24 camera samples (Mitsuba's wavefront) and cap."""
    spp = cap
    while spp > 1 and width * height * spp > (1 << 24):
        spp //= 2
    return spp


def reference_key(scene: warprt.Scene, mi, settings: dict) -> str:
    import hashlib

    h = hashlib.blake2b(digest_size=12)
    h.update(scene_digest(scene).encode())
    h.update(json.dumps({**settings, "version": REFERENCE_VERSION, "mitsuba": mi.__version__,
                         "variant": mi.variant()}, sort_keys=True).encode())
    return h.hexdigest()


def render_reference(scene: warprt.Scene, mi, args, log) -> dict:
    """The Mitsuba reference of ``scene`` (see the module docstring), from the cache when there."""
    cam = scene.camera
    moving = moves(scene)
    pass_spp = pass_spp_for(cam.width, cam.height, 8 if moving else 256)
    # a moving scene's reference converges slowly (one shutter time per pass): its noise need
    # only be small beside the targets, since it has no peer ratio
    floor_goal = args.ref_floor * (MOVING_FLOOR_FACTOR if moving else 1)
    settings = {"sampler": MITSUBA_SAMPLER, "pass_spp": pass_spp, "floor": floor_goal,
                "min_spp": args.ref_min_spp, "max_spp": args.ref_max_spp, "max_s": args.ref_max_s, "seed": 1_000_003,
                "time_slices": moving, "time_strata": TIME_STRATA if moving else 0}
    if ground_half(scene) != GROUND_HALF:  # (a key of its own under a directional light)
        settings["ground_half"] = ground_half(scene)
    key = reference_key(scene, mi, settings)
    path = Path(args.cache_dir) / f"ref-{key}.npz"
    if path.exists():
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            return {**meta, "image": z["image"], "halves": [z["half0"], z["half1"]], "cached": True}
    t0 = time.perf_counter()
    acc = PassSum()
    if moving:
        open_, close = cam.shutter
        rng = np.random.default_rng(settings["seed"])
        times = []

        def one_pass(k):
            if k >= len(times):  # the next round: two independent stratified sets of shutter times
                for _ in range(2):
                    u = (rng.permutation(TIME_STRATA) + rng.random(TIME_STRATA)) / TIME_STRATA
                    times.append(u)
                times[-2:] = [np.ravel(np.stack(times[-2:], axis=1))]  # interleaved: even passes one set
            t = open_ + (close - open_) * float(np.concatenate(times)[k])
            sc = mi.load_dict(to_mitsuba(scene_at_time(scene, t), mi, sampler=MITSUBA_SAMPLER, spp=pass_spp))
            img = np.array(mi.render(sc, spp=pass_spp, seed=settings["seed"] + 7919 * k), dtype=np.float64)
            return img, int(sc.sensors()[0].sampler().sample_count())  # (multijitter may round spp up)
    else:
        sc = mi.load_dict(to_mitsuba(scene, mi, sampler=MITSUBA_SAMPLER, spp=pass_spp))

        def one_pass(k):
            img = np.array(mi.render(sc, spp=pass_spp, seed=settings["seed"] + 7919 * k), dtype=np.float64)
            return img, int(sc.sensors()[0].sampler().sample_count())
    goal = args.ref_min_spp
    k = 0
    while True:
        while acc.spp < goal or acc.n % (2 * TIME_STRATA if moving else 2):
            img, got = one_pass(k)
            acc.add(img, got)
            k += 1
        floor = noise_floor(acc.halves())
        elapsed = time.perf_counter() - t0
        if floor <= floor_goal or acc.spp >= args.ref_max_spp or elapsed >= args.ref_max_s:
            break
        # the floor falls as 1/spp: aim a little beyond the spp that reaches it, within the caps
        need = acc.spp * floor / floor_goal * 1.1
        per_spp = elapsed / acc.spp
        goal = int(min(need, args.ref_max_spp, acc.spp + (args.ref_max_s - elapsed) / per_spp))
        if goal <= acc.spp:
            break
    meta = {"renderer": "mitsuba", "sampler": MITSUBA_SAMPLER, "spp": acc.spp, "passes": acc.n,
            "pass_spp": pass_spp, "seconds": time.perf_counter() - t0, "noise_floor_rel_mse": noise_floor(acc.halves()),
            "time_slices": acc.n if moving else 0, "floor_goal": floor_goal, "floor_goal_met": bool(noise_floor(acc.halves()) <= floor_goal),
            "key": key}
    image, halves = acc.image(), acc.halves()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, image=image.astype(np.float32), half0=halves[0].astype(np.float32),
                        half1=halves[1].astype(np.float32), meta=json.dumps(meta))
    os.replace(tmp, path)
    return {**meta, "image": image.astype(np.float32), "halves": [h.astype(np.float32) for h in halves],
            "cached": False}


# --- one scene --------------------------------------------------------------------------------------------


def _scene_facts(entry: Entry, scene: warprt.Scene) -> dict:
    cam = scene.camera
    return {"name": entry.name, "kind": entry.kind, "split": entry.split, "width": cam.width, "height": cam.height,
            "triangles": cs.tri_count(scene), "shapes": len(scene.shapes), "lights": len(scene.lights),
            "light_types": sorted({type(light).__name__ for light in scene.lights}),
            "moving": moves(scene), "aperture": cam.aperture,
            "materials": sorted({_material_kind(scene.materials[s.material]) for s in scene.shapes})}


def _material_kind(m) -> str:
    from benchmarks.mitsuba_export import material_kind

    try:
        return material_kind(m)
    except ExportError:
        return "other"


def study_scene(entry: Entry, mi, dr, args, log) -> dict:
    t_start = time.perf_counter()
    scene = entry.build()
    rec = _scene_facts(entry, scene)
    rec["peer"] = not rec["moving"]
    log(f"[{entry.name}] {entry.kind} ({entry.split}): {rec['width']}x{rec['height']}, {rec['shapes']} shapes, "
        f"{rec['triangles']} triangles, {rec['lights']} lights{', moving' if rec['moving'] else ''}")

    # 1. reference
    ref = render_reference(scene, mi, args, log)
    rec["reference"] = {k: v for k, v in ref.items() if k not in ("image", "halves")}
    log(f"  reference: mitsuba {ref['sampler']} {ref['spp']} spp"
        f"{' over ' + str(ref['time_slices']) + ' shutter times' if ref['time_slices'] else ''}"
        f"{' (cached)' if ref['cached'] else ' in %.0f s' % ref['seconds']}, own noise relMSE "
        f"{ref['noise_floor_rel_mse']:.1e}{'' if ref['floor_goal_met'] else ' (cap reached before the goal)'}")

    # 2. warprt's configurations; the same render under two names shares one curve
    effective = {c: effective_config(c, scene) for c in args.configs}
    unique = ["sobol"] if args.check_only else list(dict.fromkeys(effective.values()))
    ws = WarprtSide(scene, unique)
    rec["setup"] = {"warprt_build_s": ws.build_s, "warprt_compile_s": ws.compile_s,
                    "warprt_light_samples": ws.light_samples, "warprt_light_maps": ws.light_maps,
                    "warprt_split_pilot_s": ws.split_pilot_s, "effective_configs": effective}
    ms = None
    if rec["peer"]:
        ms = MitsubaSide(scene, mi, dr, samplers=(MITSUBA_SAMPLER,))
        rec["setup"]["mitsuba_load_s"] = ms.build_s
    log(f"  set-up: warprt build {ws.build_s:.2f} s + kernel load/compile {ws.compile_s:.2f} s"
        + (f"; mitsuba load_dict {ms.build_s:.2f} s" if ms else "; no Mitsuba counterpart (motion)")
        + (f"; light samples (\"auto\"): {ws.light_samples}" if ws.light_samples else ""))

    # 3. convergence: warprt at high spp against the reference
    t_chk = time.perf_counter()
    wimg, w_halves, w_s, w_spp = render_passes(ws, "sobol" if "sobol" in ws.configs else ws.configs[0],
                                               args.check_spp, 2_000_003, 128)
    c = compare(wimg, w_halves, ref["image"], ref["halves"])
    c.update(warprt_spp=w_spp, warprt_seconds=w_s, wall_s=time.perf_counter() - t_chk,
             warprt_config="sobol" if "sobol" in ws.configs else ws.configs[0])
    c["plane_beyond_extent"] = plane_beyond_extent(scene_at_time(scene, 0.5) if rec["moving"] else scene, wimg)
    rec["convergence"] = c
    log(f"  check: warprt {c['warprt_config']} {w_spp} spp ({w_s:.1f} s), own noise {c['noise_floor_image']:.1e}: "
        f"relMSE vs reference {c['rel_mse']:.2e} ({c['ratio_to_noise']:.2f}x the two noises), mean "
        f"{100 * c['mean_rel_diff']:+.3f}% (z = {c['mean_z']:+.1f}): {'AGREE' if c['agree'] else 'DIFFER'}")
    if args.save_images:
        d = Path(args.out) / "images"
        d.mkdir(parents=True, exist_ok=True)
        np.save(d / f"{entry.name}-reference.npy", ref["image"])
        np.save(d / f"{entry.name}-warprt-check.npy", wimg.astype(np.float32))
    if args.check_only:
        ws.close()
        rec["wall_s"] = time.perf_counter() - t_start
        return rec

    # 4. the timing sweep
    floor = ref["noise_floor_rel_mse"]
    lowest = min(TARGETS)

    def stop(k, curves):
        last = curves[k][-1]
        return (last["rel_mse_corrected"] <= lowest or last["seconds"] > args.max_render_s
                or last["spp"] >= args.max_spp)

    sides = [(ws, ws.configs)] + ([(ms, ms.configs)] if ms else [])
    t_sweep = time.perf_counter()
    curves = sweep(sides, args.spps, args.repeats, ref["image"], floor, stop, log=log, settle=SETTLE_S)
    rec["sweep_wall_s"] = time.perf_counter() - t_sweep
    rec["curves"] = curves
    ws.close()
    if ms:
        ms.close()

    # 5. time to error, per configuration and per repeat, and the ratios
    rec["time_to_error"], rec["ratios"] = {}, {}
    for target in TARGETS:
        tte = {k: _time_to(curve, target, args.repeats) for k, curve in curves.items()}
        rec["time_to_error"][f"{target:g}"] = tte
        m = tte.get(f"mitsuba/{MITSUBA_SAMPLER}")
        rec["ratios"][f"{target:g}"] = {c: _ratio(tte[f"warprt/{effective[c]}"], m) for c in args.configs} if m else {}
    rec["msamples_per_s"] = {k: v[-1]["msamples_per_s"] for k, v in curves.items() if v}
    rec["wall_s"] = time.perf_counter() - t_start
    r3 = rec["ratios"].get("0.001", {})
    log(f"  to 1e-3, warprt / Mitsuba: " + (", ".join(f"{c} {_fmt_ratio(r)}" for c, r in r3.items()) if r3 else
        "no peer; warprt " + ", ".join(f"{c} {_fmt_seconds(rec['time_to_error']['0.001'][f'warprt/{effective[c]}'])}"
                                       for c in args.configs))
        + f"  (scene {rec['wall_s']:.0f} s, sweep {rec['sweep_wall_s']:.0f} s)")
    return rec


def _time_to(curve, target, repeats) -> dict:
    """Time to ``target`` from the repeats' minima, and from each repeat's own times."""
    t, how = time_to_error([(p["seconds"], p["rel_mse_corrected"]) for p in curve], target)
    per = []
    for r in range(repeats):
        pts = [(p["seconds_all"][r], p["rel_mse_corrected"]) for p in curve if len(p["seconds_all"]) > r]
        per.append(time_to_error(pts, target)[0])
    last = curve[-1]["seconds"] if curve else None
    return {"seconds": t, "how": how, "per_repeat": per, "last_seconds": last}


def _ratio(w: dict, m: dict) -> dict:
    """warprt / Mitsuba time to one target; ``bound``: "~" where either reached it at its first
    point (an upper bound on that time), ">" where warprt never reached it (its last time over
    Mitsuba's: a lower bound), "<" where Mitsuba never did."""
    if w["seconds"] is not None and m["seconds"] is not None:
        r = w["seconds"] / m["seconds"]
        bound = "~" if "<=" in (w["how"], m["how"]) else ""
    elif w["seconds"] is None and m["seconds"] is not None and w["last_seconds"]:
        r, bound = w["last_seconds"] / m["seconds"], ">"
    elif m["seconds"] is None and w["seconds"] is not None and m["last_seconds"]:
        r, bound = w["seconds"] / m["last_seconds"], "<"
    else:
        return {"ratio": None, "bound": "", "per_repeat": []}
    per = [a / b for a, b in zip(w["per_repeat"], m["per_repeat"]) if a and b]
    return {"ratio": r, "bound": bound, "per_repeat": per}


# --- summaries, tables, chart ------------------------------------------------------------------------------


def _geomean(xs):
    xs = [x for x in xs if x]
    return math.exp(sum(math.log(x) for x in xs) / len(xs)) if xs else None


def summarise(results: dict) -> dict:
    """Per split, configuration and target: geometric mean and worst ratio over the scenes with a
    peer, the number of bounds among them, and the geometric mean of each repeat's own ratios
    (their spread)."""
    out = {}
    configs = results["configs"]
    for split in (TRAIN, VALIDATION):
        recs = [r for r in results["scenes"].values() if r["split"] == split and r.get("ratios")]
        out[split] = {}
        for c in configs:
            out[split][c] = {}
            for target in TARGETS:
                t = f"{target:g}"
                rows = [(r["name"], r["ratios"][t].get(c)) for r in recs if r["ratios"].get(t, {}).get(c)]
                rows = [(n, x) for n, x in rows if x["ratio"]]
                if not rows:
                    continue
                worst = max(rows, key=lambda nx: nx[1]["ratio"])
                reps = min((len(x["per_repeat"]) for _, x in rows), default=0)
                per_rep = [_geomean([x["per_repeat"][i] for _, x in rows]) for i in range(reps)
                           if all(len(x["per_repeat"]) > i for _, x in rows)]
                out[split][c][t] = {"geomean": _geomean([x["ratio"] for _, x in rows]), "scenes": len(rows),
                                    "worst": worst[1]["ratio"], "worst_scene": worst[0],
                                    "bounds": sum(1 for _, x in rows if x["bound"]),
                                    "not_reached": sum(1 for _, x in rows if x["bound"] == ">"),
                                    "geomean_per_repeat": per_rep}
    return out


def _fmt_ratio(x) -> str:
    if not x or x.get("ratio") is None:
        return "n/a"
    return f"{x['bound']}{x['ratio']:.2f}"


def _fmt_spread(x) -> str:
    p = [v for v in x.get("per_repeat", []) if v]
    return f" ({min(p):.2f}–{max(p):.2f})" if len(p) > 1 else ""


def _fmt_seconds(t) -> str:
    if not t or t.get("seconds") is None:
        return "not reached"
    s = t["seconds"]
    return ("≤ " if t["how"] == "<=" else "") + (f"{s:.3f} s" if s < 10 else f"{s:.1f} s")


def _same(rec) -> str:
    c = rec.get("convergence")
    if not c:
        return "–"
    mean = f"{100 * c['mean_rel_diff']:+.3f}%" + ("" if c["mean_within_noise"] else f" ({abs(c['mean_z']):.0f}σ)")
    return (f"yes: {c['ratio_to_noise']:.2f}×, {mean}" if c["agree"] else f"**no**: {c['ratio_to_noise']:.1f}×, {mean}")


def markdown_split(results: dict, split: str) -> str:
    configs = results["configs"]
    recs = [r for r in results["scenes"].values() if r["split"] == split]
    title = "Training half (tune here)" if split == TRAIN else "Validation half (report only: never tune on it)"
    lines = [f"#### {title}: {len(recs)} scenes", ""]
    if not recs:
        return "\n".join(lines + ["(not run)", ""])
    summary = results.get("summary", {}).get(split, {})
    for target in reversed(TARGETS):
        t = f"{target:g}"
        label = f"{target:.0e}".replace("e-0", "e-")
        lines.append(f"Time to relMSE {label}, warprt / Mitsuba (below 1: warprt is faster)"
                     + (", in brackets the range of the repeats' own ratios:" if target == min(TARGETS) else ":"))
        lines.append("")
        head = ["scene", "kind", "size"] + (["same image?"] if target == min(TARGETS) else []) + [
            f"Mitsuba → {label}"] + [f"`{c}`" for c in configs]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + " --- |" * len(head))
        for r in recs:
            tte = r.get("time_to_error", {}).get(t, {})
            cells = [r["name"], r["kind"], f"{r['width']}×{r['height']}"]
            if target == min(TARGETS):
                cells.append(_same(r))
            if r.get("peer"):
                cells.append(_fmt_seconds(tte.get(f"mitsuba/{MITSUBA_SAMPLER}")))
                for c in configs:
                    x = r.get("ratios", {}).get(t, {}).get(c)
                    cells.append(_fmt_ratio(x) + (_fmt_spread(x) if x and target == min(TARGETS) else ""))
            else:
                cells.append("no peer (motion)")
                eff = r.get("setup", {}).get("effective_configs", {})
                for c in configs:
                    cells.append(f"*{_fmt_seconds(tte.get(f'warprt/{eff.get(c, c)}'))}*")
            lines.append("| " + " | ".join(cells) + " |")
        for label, key in (("geometric mean", "geomean"), ("worst", "worst")):
            cells = [f"**{label}**", "", ""] + ([""] if target == min(TARGETS) else []) + [""]
            for c in configs:
                s = summary.get(c, {}).get(t)
                if not s:
                    cells.append("n/a")
                elif key == "geomean":
                    reps = [v for v in s["geomean_per_repeat"] if v]
                    spread = f" ({min(reps):.2f}–{max(reps):.2f})" if len(reps) > 1 and target == min(TARGETS) else ""
                    cells.append(f"**{s['geomean']:.2f}**{spread}")
                else:
                    cells.append(f"{s['worst']:.2f} ({s['worst_scene']})")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _llvm(machine) -> str:
    lib = machine.get("libllvm")
    return f" ({os.path.basename(lib)})" if lib else ""


def markdown(results: dict) -> str:
    m = results["machine"]
    s = results["settings"]
    parts = [markdown_split(results, TRAIN), markdown_split(results, VALIDATION)]
    load = m.get("load_average")
    parts.append(
        f"Mitsuba {m.get('mitsuba')} `{m.get('variant')}`{_llvm(m)} `{MITSUBA_SAMPLER}` "
        f"(its `direct` integrator, or the Whitted one for mirrors and glass), warprt {m['warprt']} (Warp "
        f"{m['warp']}) on the CPU device, {THREADS} threads each, {s['repeats']} repeat(s) (each a sweep over the spp "
        f"points, the renderers interleaved, {int(SETTLE_S * 1000)} ms idle before each timed render), the minimum "
        f"time of the repeats; {m['cpus']} CPU cores ({m.get('cpu')}, {m.get('simd')}), Python {m['python']}"
        + (f", load average {load[0]:.1f} at the start (the machine is shared: only ratios from one run compare)"
           if load else "") + ". "
        "\"~\": one renderer was below the target at its first point (1 spp), a bound; \">\": warprt did not "
        "reach it (a lower bound from its last point); a configuration that renders the same as another on a scene "
        "(`+split` without area lights) has that one's curve; motion-blur scenes have no Mitsuba counterpart "
        "(their warprt times in italics, outside the means)."
        + (" **Quick run** (one repeat, a smaller convergence check)." if results.get("quick") else ""))
    return "\n\n".join(parts)


def write_chart(results: dict, path: Path) -> bool:
    plt = pyplot()
    if plt is None:
        return False
    configs = results["configs"]
    splits = [s for s in (TRAIN, VALIDATION) if any(r["split"] == s for r in results["scenes"].values())]
    if not splits:
        return False
    n = max(sum(1 for r in results["scenes"].values() if r["split"] == s) for s in splits)
    fig, axes = plt.subplots(1, len(splits), figsize=(6.2 * len(splits), 1.0 + 0.32 * n), squeeze=False)
    markers = "osD^v<>p*"
    for ax, split in zip(axes.flat, splits):
        recs = [r for r in results["scenes"].values() if r["split"] == split and r.get("ratios", {}).get("0.001")]
        for j, c in enumerate(configs):
            xs, ys = [], []
            for i, r in enumerate(recs):
                x = r["ratios"]["0.001"].get(c)
                if x and x["ratio"]:
                    xs.append(x["ratio"])
                    ys.append(i + (j - len(configs) / 2) * 0.08)
            ax.semilogx(xs, ys, markers[j % len(markers)], ms=5, alpha=0.85, label=c)
        ax.axvline(1.0, color="0.3", lw=1)
        ax.axvline(0.5, color="0.6", lw=0.8, ls=":")
        ax.set_yticks(range(len(recs)))
        ax.set_yticklabels([r["name"] for r in recs], fontsize=8)
        ax.invert_yaxis()
        ax.grid(True, which="both", axis="x", alpha=0.3)
        ax.set_xlabel("time to relMSE 1e-3, warprt / Mitsuba (log)")
        gm = results.get("summary", {}).get(split, {})
        ax.set_title(f"{'training' if split == TRAIN else 'validation'} half; geometric means: " + ", ".join(
            f"{c} {gm[c]['0.001']['geomean']:.2f}" for c in configs[:3] if gm.get(c, {}).get("0.001")), fontsize=8)
    axes.flat[0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def write_outputs(results: dict, out: Path, to_docs: bool) -> None:
    results["summary"] = summarise(results)
    (out / "corpus.json").write_text(json.dumps(results, indent=1, default=str))
    table = markdown(results)
    (out / "corpus.md").write_text(table + "\n")
    charted = write_chart(results, out / "corpus.png")
    print()
    print(table)
    updated = False
    if to_docs:
        shutil.copyfile(out / "corpus.json", docs.DATA / "corpus.json")
        if charted:
            shutil.copyfile(out / "corpus.png", docs.DATA / "corpus.png")
        docs.update(["corpus", "machine"])
        updated = True
    print(f"\nwrote {out / 'corpus.json'}, {out / 'corpus.md'}{', ' + str(out / 'corpus.png') if charted else ''}"
          f"{'; docs/benchmarks/corpus.json, corpus.png and the tables in docs/benchmarks.md' if updated else ''}"
          f"; total {results.get('wall_s', 0) / 60:.1f} min")


# --- main ----------------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--split", choices=(TRAIN, VALIDATION, "all"), default="all")
    p.add_argument("--scenes", default=None, help="comma-separated scene names (default: the split's)")
    p.add_argument("--kinds", default=None, help="comma-separated kinds")
    p.add_argument("--configs", default=",".join(DEFAULT_CONFIGS),
                   help="warprt configurations, BASE[+split][+adaptive], BASE 'defaults' or a sampler")
    p.add_argument("--quick", action="store_true", help="1 repeat and a 64-spp check (the references are the same)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats (default 3, quick 1)")
    p.add_argument("--check-spp", type=int, default=None, help="warprt convergence check spp (default 256, quick 64)")
    p.add_argument("--max-spp", type=int, default=1024, help="largest spp of the sweep")
    p.add_argument("--max-render-s", type=float, default=None,
                   help="a curve stops after a render this long (default 20 s, quick 8 s)")
    p.add_argument("--ref-floor", type=float, default=2e-5, help="reference noise (relMSE) to reach")
    p.add_argument("--ref-min-spp", type=int, default=1024)
    p.add_argument("--ref-max-spp", type=int, default=16384)
    p.add_argument("--ref-max-s", type=float, default=900.0, help="reference render time cap, seconds")
    p.add_argument("--cache-dir", default=str(ROOT / ".cache" / "corpus"), help="where references are kept")
    p.add_argument("--out", default=str(ROOT / "out" / "corpus"))
    p.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant to try first")
    p.add_argument("--check-only", action="store_true", help="references and convergence checks only")
    p.add_argument("--save-images", action="store_true", help="keep the reference and check images (npy)")
    p.add_argument("--no-docs", action="store_true", help="leave docs/benchmarks.md alone")
    p.add_argument("--list", action="store_true", help="print the corpus and exit")
    p.add_argument("--replot", action="store_true", help="tables, chart (and docs) again from the out folder's JSON")
    args = p.parse_args(argv)

    if args.list:
        for e in CORPUS:
            print(f"{e.name:22s} {e.kind:26s} {e.split}")
        counts = {s: sum(e.split == s for e in CORPUS) for s in (TRAIN, VALIDATION)}
        print(f"{len(CORPUS)} scenes, {len(KINDS)} kinds; {counts[TRAIN]} training, {counts[VALIDATION]} validation")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = [n.strip() for n in args.scenes.split(",") if n.strip()] if args.scenes else None
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()] if args.kinds else None
    bad = [n for n in (names or []) if n not in BY_NAME] + [k for k in (kinds or []) if k not in KINDS]
    if bad:
        p.error(f"unknown scene(s) or kind(s): {', '.join(bad)} (see --list)")
    args.configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    for c in args.configs:
        try:
            parse_config(c)
        except ValueError as e:
            p.error(str(e))
    whole = not (args.quick or names or kinds or args.split != "all" or args.check_only)
    to_docs = whole and not args.no_docs
    if args.replot:
        results = json.loads((out / "corpus.json").read_text())
        write_outputs(results, out, to_docs=not args.no_docs and not results.get("quick") and results.get("whole", False))
        return 0

    loaded = load_mitsuba(args.variant, threads=THREADS)
    if loaded is None:
        print("benchmarks.corpus: Mitsuba 3 is not installed (pip install -e \".[peers]\"); no references, skipping.")
        return 0
    mi, dr, variant, note = loaded
    if note:
        print(f"note: {note}")
    q = args.quick
    args.repeats = args.repeats or (1 if q else 3)
    args.check_spp = args.check_spp or (64 if q else 256)
    args.max_render_s = args.max_render_s or (8.0 if q else 20.0)
    args.spps = [1 << k for k in range(0, 21) if (1 << k) <= args.max_spp]
    todo = entries(args.split, names, kinds)
    results = {"machine": machine_info(mi, dr, variant, note), "quick": q, "whole": whole, "configs": args.configs,
               "settings": {"repeats": args.repeats, "check_spp": args.check_spp, "max_spp": args.max_spp,
                            "max_render_s": args.max_render_s, "ref_floor": args.ref_floor,
                            "ref_min_spp": args.ref_min_spp, "ref_max_spp": args.ref_max_spp,
                            "ref_max_s": args.ref_max_s, "targets": list(TARGETS), "settle_s": SETTLE_S,
                            "split": args.split, "check_only": args.check_only},
               "error": "warprt.testing.relative_mse(image, reference) = mean((a - ref)^2) / mean(ref^2); a point's "
                        "rel_mse is the mean over its warm-up and repeats, rel_mse_corrected that less the "
                        "reference's own noise (noise_floor_rel_mse), which time_to_error interpolates",
               "scenes": {}}
    print(f"warprt {warprt.__version__} vs Mitsuba {mi.__version__} {variant}, {THREADS} threads each; "
          f"{len(todo)} scenes, configurations {', '.join(args.configs)}; repeats {args.repeats}", flush=True)

    def log(msg):
        print(msg, flush=True)

    start = time.perf_counter()
    for e in todo:
        results["scenes"][e.name] = study_scene(e, mi, dr, args, log)
        results["wall_s"] = time.perf_counter() - start
        results["summary"] = summarise(results)
        # partial results survive (a check-only run keeps its own file)
        (out / ("corpus-check.json" if args.check_only else "corpus.json")).write_text(
            json.dumps(results, indent=1, default=str))
    results["wall_s"] = time.perf_counter() - start
    if args.check_only:
        bad = [n for n, r in results["scenes"].items() if not r["convergence"]["agree"]]
        print(f"\n{len(results['scenes']) - len(bad)} of {len(results['scenes'])} scenes agree with their reference"
              + (f"; differ: {', '.join(bad)}" if bad else "") + f"; {results['wall_s'] / 60:.1f} min")
        return 0
    write_outputs(results, out, to_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
