"""warprt against Newton's SensorCamera on Newton's own kind of scene, side by side.

    python -m benchmarks.newton_bench [--repeats 5] [--quick]

Both render the same ``newton.Model`` (a ground plane and, per world, boxes, spheres and a
capsule on the ground, one directional light with hard shadows) on the CPU device in one
process, interleaved, after a warm-up that compiles everything:

* (a) 64 worlds × 2 cameras at 128×128, (b) 1 world × 1 camera at 512×512;
* Newton: ``SensorCamera.update`` with the HDR colour output (shadows on, as its docs set them
  up), one view per world and camera (``world_indices``), one Warp launch (a CPU launch runs on
  one core);
* warprt: ``newton_bridge.NewtonRenderer`` (a ``BatchRenderer``) at 1 sample per pixel with the
  ``regular`` sampler (the pixel centre, Newton's own ray), on every core (``workers=2`` here)
  and on one (``workers=1``), so the ratio per core is in the table too.

Each side renders the colour alone and the colour with depth (Newton's ``depth_image``, warprt's
``depth`` AOV, from the same samples in the same launch); warprt also the colour with depth,
normal and object id (its AOVs' cost against the colour alone).

Reported: seconds per frame (min and median over the repeats), Mpix/s, warprt / Newton speed
(wall time, and per core as process CPU time with one warprt worker against Newton's one), for
the colour and for colour + depth;
agreement where the two models coincide (hit mask, depth, shape index, lit colour: Newton keeps
0.3 of the light in shadow and adds a hemispheric ambient term, so the colour is compared with
its ambient off on lit pixels); and the per-step cost of updating poses from ``state.body_q`` on
the device (with and without the device check of ``body_q``, ``check_inputs``), with the batch's
counters (rebuilds, compiles, host copies) over the steps.
Figures go to docs/benchmarks/newton.json (``--quick``: nowhere); a run written there also
re-renders the ``newton`` tables in docs/benchmarks.md from it (``benchmarks.docs``; ``--no-docs``
not to).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.environ.setdefault("WARP_CACHE_PATH", os.path.join(ROOT, ".cache", "warp"))

import warp as wp  # noqa: E402

import warprt  # noqa: E402
from benchmarks import docs  # noqa: E402

FOV = 45.0
DEPTH = ("depth",)
AOVS = ("depth", "normal", "object_id")  # warprt's outputs beside the colour in the AOV timing
LIGHT_DIRECTION = np.array([-1.0, 1.0, -1.0])  # Newton's default light, the way it travels (both sides)


def build_model(worlds: int):
    import newton

    b = newton.ModelBuilder()
    b.add_ground_plane(color=(0.8, 0.8, 0.75))
    sub = newton.ModelBuilder()
    rng = np.random.default_rng(0)
    for k in range(4):
        body = sub.add_body(xform=wp.transform((float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-1.5, 1.5)), 0.3),
                                               wp.quat_from_axis_angle(wp.vec3(0, 0, 1), float(rng.uniform(0, 3)))))
        sub.add_shape_box(body, hx=0.3, hy=0.2, hz=0.3, color=(0.9, 0.3 + 0.1 * k, 0.2))
    for k in range(2):
        body = sub.add_body(xform=wp.transform((float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-1.5, 1.5)), 0.35),
                                               wp.quat_identity()))
        sub.add_shape_sphere(body, radius=0.35, color=(0.2, 0.4, 0.9))
    body = sub.add_body(xform=wp.transform((0.0, 0.0, 0.25), wp.quat_from_axis_angle(wp.vec3(1, 0, 0), math.pi / 2)))
    sub.add_shape_capsule(body, radius=0.25, half_height=0.5, color=(0.3, 0.8, 0.3))
    b.replicate(sub, worlds)
    return b.finalize(device="cpu")


def camera_poses(worlds: int, cameras: int) -> np.ndarray:
    eyes = np.array([(5.0, -5.0, 3.5), (-4.0, -5.5, 2.5)])
    return warprt.look_at(np.broadcast_to(eyes[np.arange(cameras) % 2], (worlds, cameras, 3)), (0.0, 0.0, 0.3), "z")


class NewtonSide:
    def __init__(self, model, cameras, width, height, ambient: bool = True):
        from newton.sensors import SensorCamera

        self.sensor = SensorCamera(model)
        cfg = self.sensor.default_render_config
        cfg.enable_shadows = True
        cfg.enable_ambient_lighting = ambient
        d = LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)
        self.sensor.create_default_light(enable_shadows=True, direction=wp.vec3(*d))
        self.rays = SensorCamera.compute_camera_rays_pinhole(width, height, camera_fov=math.radians(FOV), device="cpu")
        W = model.world_count
        views = W * cameras  # view w·C + c renders world w through camera c
        self.tf = wp.array(camera_poses(W, cameras).reshape(views, 7).astype(np.float32), dtype=wp.transform,
                           device="cpu")
        self.worlds = wp.array(np.repeat(np.arange(W, dtype=np.int32), cameras), dtype=wp.int32, device="cpu")
        self.shape = (W, cameras, height, width)
        self.hdr = self.sensor.allocate_image_color_hdr(views, width, height)
        self.depth = self.sensor.allocate_image_depth(views, width, height)
        self.index = self.sensor.allocate_image_shape_index(views, width, height)
        self.model = model

    def frame(self, state, aovs: bool = False, depth: bool = False):
        kw = dict(hdr_color_image=self.hdr)
        if aovs or depth:
            kw.update(depth_image=self.depth)
        if aovs:
            kw.update(shape_index_image=self.index)
        self.model.bvh_refit_shapes(state)  # as warprt's update(state): the frame follows the state
        self.sensor.update(state, self.tf, self.rays, world_indices=self.worlds, **kw)
        wp.synchronize_device("cpu")


class WarprtSide:
    def __init__(self, model, cameras, width, height, workers):
        from warprt.newton_bridge import NewtonRenderer

        cam = warprt.Camera(eye=(5, -5, 3.5), look_at=(0, 0, 0.3), up=(0, 0, 1), fov=FOV, width=width, height=height)
        light = warprt.DirectionalLight(direction=tuple(LIGHT_DIRECTION), intensity=1.0)  # Newton's, equal
        self.r = NewtonRenderer(model, cameras=cameras, camera=cam, lights=(light,),
                                render=warprt.RenderSettings(sampler="regular", spp=1))
        self.r.set_camera_poses(camera_poses(model.world_count, cameras))
        self.workers = workers
        self.out = None

    def frame(self, state, aovs=False):
        """``aovs``: True for those the agreement reads, or a tuple of names."""
        self.r.update(state)
        names = ("depth", "object_id", "normal", "albedo") if aovs is True else tuple(aovs or ())
        self.out = self.r.batch.render(spp=1, workers=self.workers, aovs=names)


def timed(fn, state) -> tuple[float, float]:
    """(wall, process CPU) seconds of one frame: CPU time is the least disturbed measure on a
    shared machine (all threads of the process, so per core only with one worker)."""
    c, t = time.process_time(), time.perf_counter()
    fn(state)
    return time.perf_counter() - t, time.process_time() - c


def agreement(model, cameras, width, height) -> dict:
    """Where the models coincide (Newton's ambient off): hit mask, depth, shape index; lit colour
    (warprt kd·n·l against Newton's albedo·n·l on pixels both light); and the shadow masks: on
    pixels facing the light, warprt's shadow is black and Newton's keeps 0.3 of the light, so
    each renderer's shadowed set is read off its own image and the two sets compared."""
    state = model.state()
    n = NewtonSide(model, cameras, width, height, ambient=False)
    n.frame(state, aovs=True)
    w = WarprtSide(model, cameras, width, height, workers=2)
    w.frame(state, aovs=True)
    a = w.out.aovs_numpy()
    nd, ns = n.depth.numpy().reshape(n.shape), n.index.numpy().astype(np.int64).reshape(n.shape)
    nh = n.hdr.numpy().reshape(n.shape + (3,))
    hit_n, hit_w = nd > 0, np.isfinite(a["depth"]) & (a["depth"] < n.sensor.default_render_config.max_distance)
    both = hit_n & hit_w
    table = w.r.shape_map.newton_shape  # (W, S): the Newton shape of warprt shape j in world w
    world = np.arange(table.shape[0])[:, None, None, None]
    mapped = table[world, np.maximum(a["object_id"], 0)]
    img, nsum = w.out.numpy().sum(-1), nh.sum(-1)
    to_light = -LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)
    unshadowed = (a["albedo"] * np.maximum((a["normal"] * to_light).sum(-1), 0)[..., None]).sum(-1)
    facing = both & (unshadowed > 1e-3)
    dark_w = img <= 1e-6 * unshadowed
    dark_n = np.abs(nsum - 0.3 * unshadowed) <= 1e-3 * unshadowed  # Newton: 0.3 of the light in shadow
    lit = facing & ~dark_w & ~dark_n & (nsum > 0)
    ratio = img[lit] / nsum[lit]
    rel = np.abs(nd[both] - a["depth"][both]) / nd[both]
    return {
        "pixels": int(hit_n.size),
        "hit_mask_agree": float(np.mean(hit_n == hit_w)),
        "depth_rel_err_median": float(np.median(rel)),
        "depth_within_1e-4": float(np.mean(rel <= 1e-4)),
        "shape_index_agree": float(np.mean(mapped[both] == ns[both])),
        "lit_pixels": int(lit.sum()),
        "lit_colour_ratio_median": float(np.median(ratio)),
        "lit_colour_within_1e-3": float(np.mean(np.abs(ratio - 1) < 1e-3)),
        "facing_pixels": int(facing.sum()),
        "shadowed_pixels_warprt": int((facing & dark_w).sum()),
        "shadow_mask_agree": float(np.mean(dark_w[facing] == dark_n[facing])),
    }


def pose_update_cost(model, cameras, width, height, steps: int = 50) -> dict:
    import newton

    w = WarprtSide(model, cameras, width, height, workers=2)
    state = model.state()
    w.frame(state)
    before = dict(w.r.counters)
    # a real simulation step between frames: Newton's semi-implicit Euler solver
    solver = newton.solvers.SolverSemiImplicit(model)
    s0, s1 = model.state(), model.state()
    control = model.control()
    times, unchecked = [], []
    for step in range(steps):
        s0.clear_forces()
        solver.step(s0, s1, control, None, 1.0 / 240.0)
        s0, s1 = s1, s0
        # every other step without the device check of body_q (warprt.checks), to price it
        w.r.check_inputs = step % 2 == 0
        t = time.perf_counter()
        w.r.update(s0)
        wp.synchronize_device("cpu")
        (times if w.r.check_inputs else unchecked).append(time.perf_counter() - t)
    w.r.check_inputs = True
    after = dict(w.r.counters)
    return {"update_ms_median": 1e3 * statistics.median(times), "update_ms_min": 1e3 * min(times),
            "update_ms_median_unchecked": 1e3 * statistics.median(unchecked),
            "update_ms_min_unchecked": 1e3 * min(unchecked),
            "counters_before": before, "counters_after": after, "steps": steps}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke test of the harness)")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "benchmarks", "newton.json"))
    ap.add_argument("--no-docs", action="store_true", help="leave docs/benchmarks.md alone")
    args = ap.parse_args(argv)
    try:
        import newton  # noqa: F401
    except ImportError:
        print("Newton is not installed: pip install 'warprt[newton]'", file=sys.stderr)
        return 2
    cases = [("a", 64, 2, 128, 128), ("b", 1, 1, 512, 512)]
    if args.quick:
        cases = [("a", 4, 2, 32, 32), ("b", 1, 1, 64, 64)]
    results = {"device": "cpu", "cores": os.cpu_count(), "repeats": args.repeats, "cases": {}}
    for key, W, C, H, X in cases:
        model = build_model(W)
        state = model.state()
        newton, w2, w1 = NewtonSide(model, C, X, H), WarprtSide(model, C, X, H, workers=2), \
            WarprtSide(model, C, X, H, workers=1)
        # what each timed frame renders: the colour; the colour and depth; warprt's colour, depth,
        # normal and object id
        sides = {"newton": newton.frame, "newton_depth": lambda st: newton.frame(st, depth=True),
                 "warprt": w2.frame, "warprt_depth": lambda st: w2.frame(st, aovs=DEPTH),
                 "warprt_aovs": lambda st: w2.frame(st, aovs=AOVS),
                 "warprt_1core": w1.frame, "warprt_1core_depth": lambda st: w1.frame(st, aovs=DEPTH)}
        for frame in sides.values():  # warm-up: compiles and first loads
            frame(state)
        times, cpu = {k: [] for k in sides}, {k: [] for k in sides}
        for _ in range(args.repeats):
            for k, frame in sides.items():
                wall, cpu_s = timed(frame, state)
                times[k].append(wall)
                cpu[k].append(cpu_s)
        pix = W * C * H * X
        case = {"worlds": W, "cameras": C, "width": X, "height": H}
        for k, t in times.items():
            case[k] = {"s_min": min(t), "s_median": statistics.median(t), "mpix_s": pix / min(t) / 1e6,
                       "mpix_s_median": pix / statistics.median(t) / 1e6, "cpu_s_min": min(cpu[k])}
        case["speed_ratio"] = case["warprt"]["mpix_s"] / case["newton"]["mpix_s"]
        case["speed_ratio_median"] = case["warprt"]["mpix_s_median"] / case["newton"]["mpix_s_median"]
        ratios = [tn / tw for tn, tw in zip(times["newton"], times["warprt"])]
        case["speed_ratio_spread"] = [min(ratios), max(ratios)]
        case["speed_ratio_1core"] = case["warprt_1core"]["mpix_s"] / case["newton"]["mpix_s"]
        case["speed_ratio_cpu"] = case["newton"]["cpu_s_min"] / case["warprt_1core"]["cpu_s_min"]
        # with depth on both sides
        case["speed_ratio_depth"] = case["newton_depth"]["s_min"] / case["warprt_depth"]["s_min"]
        ratios_d = [tn / tw for tn, tw in zip(times["newton_depth"], times["warprt_depth"])]
        case["speed_ratio_depth_spread"] = [min(ratios_d), max(ratios_d)]
        case["speed_ratio_depth_1core"] = case["newton_depth"]["s_min"] / case["warprt_1core_depth"]["s_min"]
        case["speed_ratio_depth_cpu"] = case["newton_depth"]["cpu_s_min"] / case["warprt_1core_depth"]["cpu_s_min"]
        # what the outputs beside the colour cost each side (per round: the pair ran back to back)
        for k, base in (("newton_depth", "newton"), ("warprt_depth", "warprt"), ("warprt_aovs", "warprt"),
                        ("warprt_1core_depth", "warprt_1core")):
            r = [a / b for a, b in zip(times[k], times[base])]
            case[f"{k}_over_colour"] = {"of_minima": case[k]["s_min"] / case[base]["s_min"],
                                        "median": statistics.median(r), "spread": [min(r), max(r)]}
        case["agreement"] = agreement(model, C, X, H)
        if key == "a":
            case["pose_update"] = pose_update_cost(model, C, X, H, steps=10 if args.quick else 50)
        results["cases"][key] = case
        print(f"({key}) {W} worlds x {C} cameras at {X}x{H}: Newton {case['newton']['mpix_s']:.2f} Mpix/s, "
              f"warprt {case['warprt']['mpix_s']:.2f} (2 threads), {case['warprt_1core']['mpix_s']:.2f} (1); "
              f"warprt/Newton {case['speed_ratio']:.2f}x (per-repeat {ratios and min(ratios):.2f}-"
              f"{max(ratios):.2f}), per core {case['speed_ratio_1core']:.2f}x (CPU time {case['speed_ratio_cpu']:.2f}x)")
        print(f"    colour + depth: Newton {case['newton_depth']['mpix_s']:.2f} Mpix/s, warprt "
              f"{case['warprt_depth']['mpix_s']:.2f}; warprt/Newton {case['speed_ratio_depth']:.2f}x (per-repeat "
              f"{ratios_d and min(ratios_d):.2f}-{max(ratios_d):.2f}), per core {case['speed_ratio_depth_1core']:.2f}x "
              f"(CPU time {case['speed_ratio_depth_cpu']:.2f}x)")
        print("    over the colour alone: " + ", ".join(
            f"{k} {v['of_minima']:.3f} (median {v['median']:.3f}, {v['spread'][0]:.3f}-{v['spread'][1]:.3f})"
            for k, v in ((k, case[f"{k}_over_colour"]) for k in ("newton_depth", "warprt_depth", "warprt_aovs",
                                                                  "warprt_1core_depth"))))
        print(f"    agreement: {json.dumps(case['agreement'])}")
        if "pose_update" in case:
            print(f"    pose update from body_q: {case['pose_update']['update_ms_median']:.3f} ms median "
                  f"({case['pose_update']['update_ms_median_unchecked']:.3f} without the body_q check); counters "
                  f"{case['pose_update']['counters_before']} -> {case['pose_update']['counters_after']}")
    if not args.quick:
        os.makedirs(os.path.dirname(args.out), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(results, f, indent=1)
        print(f"wrote {os.path.relpath(args.out, ROOT)}")
        if not args.no_docs and os.path.realpath(args.out) == os.path.realpath(docs.DATA / "newton.json"):
            changed = docs.update(["newton", "machine"])
            print(f"docs/benchmarks.md: {', '.join(changed) or 'no'} tables changed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
