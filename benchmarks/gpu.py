"""warprt's kernels on a CUDA device: the peer scenes rendered there and on the CPU, side by side.

    python -m benchmarks.gpu                     # the six scenes of benchmarks.peers
    python -m benchmarks.gpu --scenes d --timing --json out/gpu_d.json

For each scene of ``benchmarks.peers`` (sampler ``sobol``) and each way of sampling asked for
(``--modes``: ``plain``, ``adaptive``), the CUDA image against the CPU image of the same spp and
seed: relative MSE, largest difference, the share of values that differ, bit-identical or not;
the first build and compile on CUDA. With ``--timing``, whole ``render()`` calls on CUDA at 64 and
1024 spp (min of 3 after a warm-up render at the same spp; the image is copied to the host in
each) and the samples per second they make. ``--packets on`` / ``off`` builds the CUDA kernel
with camera rays in packets or one by one (default: the device's choice, one by one on CUDA:
``warprt.integrator.packets_for``); the images are the same bit for bit either way.

Needs a CUDA device (it prints one line and exits 2 without one); it never runs in CI. Scenes can
run as separate processes at once (one ``--scenes`` each) so that their CUDA compiles overlap.
``--json docs/benchmarks/gpu.json`` also re-renders the ``gpu`` table in docs/benchmarks.md from
that file (``benchmarks.docs``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

import warprt  # noqa: E402
from benchmarks import docs  # noqa: E402
from benchmarks.peers import SCENES, build_scene  # noqa: E402
from warprt.testing import relative_mse  # noqa: E402

MODES = ("plain", "adaptive")


def compare(cpu: np.ndarray, gpu: np.ndarray) -> dict:
    """How far the CUDA image is from the CPU image, value by value."""
    diff = np.abs(gpu.astype(np.float64) - cpu.astype(np.float64))
    return {
        "bit_identical": bool(cpu.tobytes() == gpu.tobytes()),
        "relmse_vs_cpu": float(relative_mse(gpu, cpu)),
        "max_abs_diff": float(diff.max()),
        "frac_values_differ": float((cpu != gpu).mean()),
        "frac_values_differ_1e-4": float((diff > 1e-4).mean()),
        "mean_cuda": float(gpu.mean()),
        "mean_cpu": float(cpu.mean()),
        "finite": bool(np.isfinite(gpu).all()),
    }


def study(key: str, device: str, modes, spp: int, seed: int, timing: bool, repeats: int,
          packets: bool | None = None) -> dict:
    scene = build_scene(key).with_settings(sampler="sobol")
    t0 = time.perf_counter()
    gpu_r = warprt.Renderer(scene, device=device, packets=packets)
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    gpu_r.compile()
    compile_s = time.perf_counter() - t0
    cpu_r = warprt.Renderer(scene, device="cpu")
    row = {"scene": SCENES[key].name, "packets": gpu_r.packets, "build_s": build_s, "compile_s": compile_s,
           "modes": {}}
    for mode in modes:
        adaptive = mode == "adaptive"
        cpu = np.asarray(cpu_r.render(spp=spp, seed=seed, progress=False, adaptive=adaptive).image)
        gpu = np.asarray(gpu_r.render(spp=spp, seed=seed, progress=False, adaptive=adaptive).image)
        row["modes"][mode] = compare(cpu, gpu)
    if timing:
        pixels = scene.camera.width * scene.camera.height
        for n in (64, 1024):
            gpu_r.render(spp=n, seed=seed, progress=False)
            times = []
            for r in range(repeats):
                t0 = time.perf_counter()
                np.asarray(gpu_r.render(spp=n, seed=seed + 1 + r, progress=False).image)
                times.append(time.perf_counter() - t0)
            row[f"t{n}_s"] = min(times)
            row[f"t{n}_all"] = times
            row[f"msamples_s_{n}"] = pixels * n / min(times) / 1e6
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="".join(SCENES), help="scene keys, e.g. abc (default: all six)")
    ap.add_argument("--modes", default=",".join(MODES), help=f"comma-separated, from {', '.join(MODES)}")
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--spp", type=int, default=4, help="spp of the compared images (default 4)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--timing", action="store_true", help="also time renders at 64 and 1024 spp")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--packets", choices=("auto", "on", "off"), default="auto",
                    help="camera rays in packets on CUDA (on), one by one (off), or the device's choice (auto)")
    ap.add_argument("--json", type=Path, help="write every figure here")
    args = ap.parse_args(argv)
    keys = [k for k in args.scenes if k not in ", "]
    unknown = [k for k in keys if k not in SCENES]
    modes = [m for m in args.modes.split(",") if m]
    if unknown or not keys:
        ap.error(f"--scenes: unknown scene {', '.join(unknown) or '(none)'}; expected letters of {''.join(SCENES)}")
    if any(m not in MODES for m in modes) or not modes:
        ap.error(f"--modes {args.modes!r}: expected a comma-separated list from {', '.join(MODES)}")
    wp.init()
    try:
        is_cuda = wp.get_device(args.device).is_cuda
    except (RuntimeError, ValueError):
        is_cuda = False
    if not is_cuda:
        print(f"benchmarks.gpu: no CUDA device {args.device!r} here (Warp sees {', '.join(map(str, wp.get_devices()))})")
        return 2
    result = {"device": wp.get_device(args.device).name, "warp": wp.config.version,
              "host": platform.node(), "spp": args.spp, "seed": args.seed, "scenes": {}}
    for key in keys:
        packets = {"auto": None, "on": True, "off": False}[args.packets]
        row = study(key, args.device, modes, args.spp, args.seed, args.timing, args.repeats, packets)
        result["scenes"][key] = row
        print(key, json.dumps(row), flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.json.with_suffix(".tmp")
        tmp.write_text(json.dumps(result, indent=1))
        tmp.replace(args.json)
        if args.json.resolve() == (docs.DATA / "gpu.json").resolve():
            changed = docs.update(["gpu", "machine"])
            print(f"docs/benchmarks.md: {', '.join(changed) or 'no'} tables changed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
