"""Signal fuzzing: SIGINT and SIGTERM at random moments of real ``python -m warprt`` runs.

    python -m tests.fuzz_signals                 # 100 trials (make fuzz-signals)
    python -m tests.fuzz_signals --trials 20 --seed 3 -v

Each trial starts one command and sends it one signal, or two (a second Ctrl-C 0.05-0.6 s after
the first), at a time drawn uniformly over that command's run (timed once, without a signal, at
the start; ``--no-calibrate`` takes the lengths below instead), so the signals land in every
phase: Python's start, the imports of NumPy and Warp, the scene, a kernel compile (a
private kernel cache without the render kernels), the render's passes, the writing of the images
and the frames of a sequence. The commands:

* ``render``: a 64x48 scene at 2^14 spp to an EXR and a PNG (seconds of passes);
* ``write``: a 1200x900 image at 1 spp to an EXR and a PNG (the writes are a good part of it);
* ``compile``: the render kernel compiled into a private cache (the cache is emptied again after);
* ``sequence``: ``render-sequence`` of 6 frames, each written as it finishes.

A trial holds when: no traceback and nothing on stderr but warprt's own lines; the exit status is
0, 130 (a first SIGINT) or 143 (a first SIGTERM), or the process ended by the signal itself with
nothing on stderr and nothing written (a signal in the first few tens of milliseconds, while
Python starts and before warprt's code runs, takes the signal's default action: a shell shows
143 for SIGTERM as well); no temporary image file (``*.partial``) and no
build folder of the process is left; every image present is complete and readable, an EXR and its
PNG hold the same samples, a partial image is marked so and a complete one is not; once an
image's write has begun (its temporary file seen) the image exists at the end, unless a second
signal abandoned it and stderr says so; and a sequence's report lists as complete exactly the
frames on disk. Exits 1 if any trial failed, printing why.
"""

from __future__ import annotations

import argparse
import glob
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCENE = '[camera]\nwidth = 64\nheight = 48\n[[shapes]]\ntype = "sphere"\n[[lights]]\ntype = "point"\n'
ANIMATED = SCENE + ('[animation]\nframes = 6\n[render]\nspp = 64\n')
RENDER_KERNELS = "wp_kernels_for__locals__render_kernel"

KINDS = {
    # kind: (arguments, the run's usual length in seconds, over which the signal time is drawn)
    "render": (["render", "scene.toml", "-o", "out/img.exr", "-o", "out/img.png", "--spp", "16384"], 6.0),
    "write": (["render", "scene.toml", "-o", "out/img.exr", "-o", "out/img.png", "--width", "1200", "--height", "900",
               "--spp", "1"], 4.0),
    "compile": (["render", "scene.toml", "-o", "out/img.exr", "-o", "out/img.png", "--spp", "4"], 9.0),
    "sequence": (["render-sequence", "anim.toml", "-o", "out/f_####.exr", "--spp", "256"], 6.0),
}


def environment(cache: Path) -> dict:
    env = dict(os.environ)
    env["WARP_CACHE_PATH"] = str(cache)
    env.pop("WARPRT_CACHE_DIR", None)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def private_cache(root: Path, shared: Path) -> Path:
    """A kernel cache of links to the shared cache's entries, without the render kernels."""
    cache = root / "cache"
    for version in (d for d in shared.iterdir() if d.is_dir()):
        (cache / version.name).mkdir(parents=True, exist_ok=True)
        for entry in version.iterdir():
            if not entry.name.startswith(RENDER_KERNELS) and not re.search(r"_p\d+_t\d+$", entry.name):
                (cache / version.name / entry.name).symlink_to(entry)
    return cache


def forget_compiled(cache: Path) -> None:
    """Remove what a compile trial added (real folders among the links), so the next compiles again."""
    for version in cache.iterdir():
        for entry in version.iterdir():
            if entry.name.startswith(RENDER_KERNELS) and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)


def read_image(path: Path) -> dict:
    """The samples and marks an image records; raises if it is not a complete image."""
    if path.suffix == ".exr":
        import warprt

        rgb, header = warprt.read_exr(path)
        assert rgb.ndim == 3
        return {"spp": int(header["warprt_spp"]), "partial": header.get("warprt:partial") == "true"}
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        return {"spp": int(im.text["warprt_spp"]), "partial": im.text.get("warprt:partial") == "true"}


def run_trial(kind: str, rng: random.Random, work: Path, cache: Path, shared_cache: Path,
              length: float | None = None) -> dict:
    """One run of ``kind``, signalled at a time drawn from [0, length) (None: no signal)."""
    args = KINDS[kind][0]
    folder = work / f"t{rng.randrange(1 << 30)}"
    folder.mkdir()
    (folder / "scene.toml").write_text(SCENE)
    (folder / "anim.toml").write_text(ANIMATED)
    use_cache = cache if kind == "compile" else shared_cache
    first = rng.choice([signal.SIGINT, signal.SIGTERM])
    double = rng.random() < 0.3
    at = rng.uniform(0.0, length) if length is not None else float("inf")
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "warprt", *args, "--no-progress"], cwd=folder,
                            env=environment(use_cache), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out = folder / "out"
    writes_seen: set[str] = set()
    sent: list[tuple[int, float]] = []
    deadline = start + 300
    while proc.poll() is None and time.monotonic() < deadline:
        now = time.monotonic() - start
        if out.is_dir():
            for p in out.iterdir():
                if p.name.endswith(".partial"):
                    writes_seen.add(re.sub(r"^\.(.*)\.\d+\.[a-z0-9_]{8}\.partial$", r"\1", p.name))
        if not sent and now >= at:
            proc.send_signal(first)
            sent.append((first, now))
            if double:
                at2 = now + rng.uniform(0.05, 0.6)
        elif double and len(sent) == 1 and now >= at2:
            proc.send_signal(signal.SIGINT)
            sent.append((signal.SIGINT, now))
        time.sleep(0.001)
    if proc.poll() is None:
        proc.kill()
    stdout, stderr = proc.communicate()
    end = time.monotonic() - start
    result = {"kind": kind, "signals": [(signal.Signals(s).name, round(t, 3)) for s, t in sent],
              "status": proc.returncode, "stdout": stdout, "stderr": stderr, "folder": folder, "pid": proc.pid,
              "writes_seen": writes_seen, "elapsed": end,
              "latency": end - sent[0][1] if sent else None, "cache": use_cache}
    return result


def problems(r: dict) -> list[str]:
    """What is wrong with a trial's outcome (empty: it held)."""
    bad = []
    stderr, stdout, status = r["stderr"], r["stdout"], r["status"]
    if "Traceback" in stderr or "Exception ignored" in stderr:
        bad.append("a traceback on stderr")
    foreign = [line for line in stderr.splitlines() if line.strip() and not line.startswith("warprt:")]
    if foreign:
        bad.append(f"stderr lines not warprt's: {foreign[:3]}")
    first = r["signals"][0][0] if r["signals"] else None
    expected = {0} | ({130} if first == "SIGINT" else {143} if first == "SIGTERM" else set())
    out = r["folder"] / "out"
    files = sorted(out.iterdir()) if out.is_dir() else []
    if first and status == -int(signal.Signals[first]) and not stderr.strip() and not files:
        return bad  # ended by the signal's default action before warprt's handlers existed: nothing to lose
    if status not in expected:
        bad.append(f"exit status {status} (signals {r['signals']})")
    temps = [p.name for p in files if p.name.startswith(".")]
    if temps:
        bad.append(f"temporary files left: {temps}")
    builds = glob.glob(str(r["cache"] / "*" / f"*_p{r['pid']}_t*"))
    if builds:
        bad.append(f"build folders left: {builds}")
    images = {p.name: p for p in files if not p.name.startswith(".")}
    info = {}
    for name, path in images.items():
        try:
            info[name] = read_image(path)
        except Exception as e:  # noqa: BLE001 (any failure to read is the finding)
            bad.append(f"{name} is not a complete image ({type(e).__name__}: {e})")
    abandoned = "abandoned" in stderr
    if r["kind"] == "sequence":
        m = re.search(r"interrupted: (\d+) of 6 frames complete \(([^):]*)", stdout)
        if m:
            complete = [] if m[2] == "none" else [
                f for part in m[2].split(", ") for f in range(int(part.split("-")[0]), int(part.split("-")[-1]) + 1)]
            if sorted(images) != [f"f_{f:04d}.exr" for f in complete]:
                bad.append(f"the report lists frames {complete}, the disk holds {sorted(images)}")
        elif status == 0:
            if len(images) != 6:
                bad.append(f"a complete sequence with {len(images)} frames on disk")
        elif images and "interrupted" not in stderr:
            bad.append("frames on disk without a report")
        for name, i in info.items():
            if i["partial"] or i["spp"] != 256:
                bad.append(f"{name}: a frame marked partial or short ({i})")
        return bad
    # a single render to an EXR and a PNG
    for name in r["writes_seen"]:
        if name not in images and not abandoned:
            bad.append(f"{name}'s write had begun, but the image is missing and nothing says it was abandoned")
    if not abandoned and len(images) == 1:
        bad.append(f"one image of two written: {sorted(images)}")
    if "img.exr" in info and "img.png" in info and info["img.exr"] != info["img.png"]:
        bad.append(f"the EXR and the PNG differ: {info['img.exr']} against {info['img.png']}")
    line = stdout.strip().splitlines()[-1] if stdout.strip() else ""
    for name, i in info.items():
        if i["partial"] != ("partial image" in line) and line:
            bad.append(f"{name}: partial mark {i['partial']} against the output line {line!r}")
    if status == 0 and len(images) != 2:
        bad.append("exit 0 without both images")
    return bad


def phase(r: dict) -> str:
    """Where the (first) signal landed, as far as the outcome shows."""
    if not r["signals"]:
        return "after the end"
    if r["status"] < 0:
        return "Python's start (default action)"
    line = r["stdout"].strip().splitlines()[-1] if r["stdout"].strip() else ""
    if r["kind"] == "sequence":
        if "interrupted" in r["stdout"]:
            return "frames"
        return "after the end" if r["status"] == 0 else "start, import, compile or set-up"
    if "writing" in r["stderr"] or "abandoned" in r["stderr"] or "while writing" in line:
        return "writing"
    if "partial image" in line:
        return "render passes"
    if r["status"] == 0:
        return "after the end"
    return "start, import, compile or set-up"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--kinds", default=",".join(KINDS), help="comma separated: " + ", ".join(KINDS))
    ap.add_argument("--no-calibrate", action="store_true", help="draw the signal times over fixed lengths")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    kinds = args.kinds.split(",")
    rng = random.Random(args.seed)
    shared = Path(os.environ.get("WARP_CACHE_PATH", ROOT / ".cache" / "warp"))
    failed, phases, latencies = [], {}, {}
    with tempfile.TemporaryDirectory(prefix="warprt-fuzz-") as tmp:
        work = Path(tmp)
        cache = private_cache(work, shared)
        lengths = {kind: KINDS[kind][1] for kind in kinds}
        if not args.no_calibrate:  # each command's run, timed once without a signal
            for kind in dict.fromkeys(kinds):
                r = run_trial(kind, rng, work, cache, shared, length=None)
                if kind == "compile":
                    forget_compiled(cache)
                why = problems(r)
                if why:
                    print(f"calibration run of {kind} failed: {why}\n{r['stderr']}")
                    return 1
                lengths[kind] = r["elapsed"]
                shutil.rmtree(r["folder"], ignore_errors=True)
            print("signal times drawn over: " + ", ".join(f"{k} {v:.2f} s" for k, v in lengths.items()), flush=True)
        for t in range(args.trials):
            kind = kinds[t % len(kinds)]
            r = run_trial(kind, rng, work, cache, shared, length=lengths[kind])
            if kind == "compile":
                forget_compiled(cache)
            why = problems(r)
            where = phase(r)
            phases[(kind, where)] = phases.get((kind, where), 0) + 1
            if r["latency"] is not None:
                latencies.setdefault(kind, []).append(r["latency"])
            verdict = "held" if not why else "FAILED"
            if why or args.verbose:
                print(f"trial {t:3d} {kind:8s} signals {r['signals']} -> status {r['status']} ({where}), "
                      f"{r['elapsed']:.2f} s: {verdict}" + ("".join(f"\n    {w}" for w in why)), flush=True)
                if why:
                    print("    stderr: " + r["stderr"].strip().replace("\n", "\n            ")[-2000:])
            if why:
                failed.append(t)
            else:
                shutil.rmtree(r["folder"], ignore_errors=True)
    held = args.trials - len(failed)
    print(f"\n{args.trials} trials, {held} held, {len(failed)} failed" + (f" (trials {failed})" if failed else ""))
    for (kind, where), n in sorted(phases.items()):
        print(f"  {kind:8s} {where:34s} {n}")
    for kind, ls in sorted(latencies.items()):
        print(f"  {kind:8s} signal to exit: median {sorted(ls)[len(ls) // 2]:.2f} s, max {max(ls):.2f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
