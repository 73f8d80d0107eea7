"""What each CPU speed mechanism saves: every mechanism of ``warprt.fast`` switched off in turn, with
everything else on, timed against everything on at a fixed spp.

    python -m benchmarks.ablation                        # the six peer scenes (benchmarks.peers)
    python -m benchmarks.ablation --scenes a,d --repeats 7 --workers 2
    python -m benchmarks.ablation --split train          # the corpus's training half (benchmarks.corpus)
    python -m benchmarks.ablation --only light_buffers,camera_bins --config stratified

Method: per scene, one renderer with everything on and one per mechanism the scene uses
(``warprt.fast.usage.in_use``), each with that mechanism switched off (``Renderer(fast_off=...)``;
an import-stage one, compiled into native code when warprt is imported, in a process of its own
started with ``WARPRT_FAST_OFF`` and driven over a pipe). Every renderer compiles and renders once
before timing (compile, the light-sample pilot and the first pass's timing excluded); then each
repeat renders every renderer once, in an order rotated from repeat to repeat, with 1 and with 2
worker threads. The time is the wall time of ``Renderer.render`` (passes and, adaptive, the counts
between them); the ratio off/on is the ratio of the minima over the repeats, the spread the least and
largest of the repeats' paired ratios (off over on in the same repeat). The process CPU time of
each render is kept too (its ratio of minima: less sensitive to other work on a shared machine,
blind to how evenly the workers share the rows). Every render's image is
compared with the all-on image: a mechanism must change no bit. The geometric means over the scenes
take 1 where a mechanism does not apply. The host build time of the mechanisms that build tables
(``warprt.fast.build_times``: the BVH, light buffers, balls, escaping faces, horizons, cones, bins) is
that of the all-on renderer's build.

``--config`` is a sampler with options, as in benchmarks.peers: ``sobol+split+adaptive`` (the
default: Sobol points, area lights with ``samples = "auto"``, adaptive sampling) or e.g.
``stratified`` (today's defaults), or ``defaults`` (the scene's own settings). Writes
out/ablation/ablation.json and ablation.md (``--out``). A run over every peer scene and mechanism
into that folder (no ``--scenes``, ``--only``, ``--split`` or ``--out``) whose images all stayed
the same also copies ablation.json to docs/benchmarks/ and re-renders the ``ablation`` table in
docs/benchmarks.md from it (``benchmarks.docs``; ``--no-docs`` not to).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))

import numpy as np  # noqa: E402

import warprt  # noqa: E402
from benchmarks import docs  # noqa: E402
from warprt import fast  # noqa: E402
from warprt.fast.usage import in_use  # noqa: E402

MARK = "ABLATION "  # the server's answers on its stdout start with this


# --- scenes ------------------------------------------------------------------------------------


@dataclasses.dataclass
class SceneSpec:
    label: str  # how the table names it
    kind: str
    source: str  # "peers" or "corpus"
    key: str  # the peer scene's key or the corpus entry's name

    def build(self) -> warprt.Scene:
        if self.source == "peers":
            from benchmarks.peers import build_scene

            return build_scene(self.key)
        return {e.name: e for e in _corpus_entries()}[self.key].build()


def _corpus_entries() -> list:
    """benchmarks.corpus's entries (``.name``, ``.kind``, ``.split``, ``.build()``)."""
    try:
        from benchmarks import corpus
    except ImportError as e:
        raise SystemExit(f"--split needs benchmarks/corpus.py, which is not here: {e}")
    return list(getattr(corpus, "SCENES", None) or corpus.CORPUS)


def scene_specs(args) -> list[SceneSpec]:
    if args.split is not None:
        entries = [e for e in _corpus_entries() if args.split == "all" or e.split == args.split]
        specs = [SceneSpec(e.name, e.kind, "corpus", e.name) for e in entries]
    else:
        from benchmarks.peers import SCENES

        specs = [SceneSpec(f"({k}) {s.name}", s.name, "peers", k) for k, s in SCENES.items()]
    if args.scenes:
        wanted = args.scenes.split(",")
        specs = [s for s in specs if s.key in wanted]
        missing = set(wanted) - {s.key for s in specs}
        if missing:
            raise SystemExit(f"--scenes: unknown {', '.join(sorted(missing))}")
    return specs


def configured(scene: warprt.Scene, config: str) -> tuple[warprt.Scene, bool]:
    """The scene with the render configuration ``config`` (see the module docstring) and whether
    its renders are adaptive."""
    if config in ("scene", "defaults"):
        return scene, False
    sampler, *options = config.split("+")
    unknown = set(options) - {"split", "adaptive"}
    if unknown:
        raise SystemExit(f"--config {config}: unknown option(s) {', '.join(sorted(unknown))}")
    scene = scene.with_settings(sampler=sampler)
    if "split" in options:
        scene = scene.replace(lights=tuple(dataclasses.replace(light, samples="auto") if hasattr(light, "samples")
                                           else light for light in scene.lights))
    return scene, "adaptive" in options


# --- the renderers: in this process, or in a server process for import-stage switches ----------


def digest(image: np.ndarray) -> str:
    image = np.ascontiguousarray(image, dtype=np.float32)
    return hashlib.sha256(repr(image.shape).encode() + image.tobytes()).hexdigest()


class Local:
    """A renderer in this process with ``off`` switched off."""

    def __init__(self, scene: warprt.Scene, adaptive: bool, off: tuple[str, ...]):
        before = dict(fast.build_times)
        t0 = time.perf_counter()
        self.renderer = warprt.Renderer(scene, device="cpu", fast_off=off)
        self.build_s = time.perf_counter() - t0
        self.build_times = {k: v - before.get(k, 0.0) for k, v in fast.build_times.items() if v != before.get(k, 0.0)}
        t0 = time.perf_counter()
        self.renderer.compile()
        self.compile_s = time.perf_counter() - t0
        self.adaptive = adaptive

    def render(self, spp: int, seed: int, workers: int) -> dict:
        c0, t0 = time.process_time(), time.perf_counter()
        res = self.renderer.render(spp=spp, seed=seed, workers=workers, progress=False, adaptive=self.adaptive)
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        return dict(seconds=seconds, cpu=cpu, digest=digest(res.image), rays=int(res.rays), spp=int(res.spp))

    def close(self) -> None:
        self.renderer.close()


class Remote:
    """A renderer in a process of its own started with ``WARPRT_FAST_OFF`` (import-stage switches)."""

    def __init__(self, spec: SceneSpec, config: str, off: tuple[str, ...]):
        env = dict(os.environ, **{fast.ENV: ",".join(off)})
        self.proc = subprocess.Popen([sys.executable, "-m", "benchmarks.ablation", "--serve"], cwd=ROOT, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        ready = self._ask(dict(spec=dataclasses.asdict(spec), config=config))
        self.build_s, self.compile_s, self.build_times = ready["build_s"], ready["compile_s"], ready["build_times"]

    def _ask(self, msg: dict) -> dict:
        self.proc.stdin.write(json.dumps(msg) + "\n")
        self.proc.stdin.flush()
        while True:
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"the ablation server stopped (exit {self.proc.wait()})")
            if line.startswith(MARK):
                return json.loads(line[len(MARK):])

    def render(self, spp: int, seed: int, workers: int) -> dict:
        return self._ask(dict(spp=spp, seed=seed, workers=workers))

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            self.proc.wait(timeout=60)


def serve() -> int:
    """The server's side of ``Remote``: a scene and config, then renders until stdin closes."""
    first = json.loads(sys.stdin.readline())
    spec = SceneSpec(**first["spec"])
    scene, adaptive = configured(spec.build(), first["config"])
    local = Local(scene, adaptive, ())
    print(MARK + json.dumps(dict(build_s=local.build_s, compile_s=local.compile_s, build_times=local.build_times)),
          flush=True)
    for line in sys.stdin:
        q = json.loads(line)
        print(MARK + json.dumps(local.render(q["spp"], q["seed"], q["workers"])), flush=True)
    return 0


# --- the study ------------------------------------------------------------------------------------


def calibrate(base: Local, target_s: float, workers: int, spp0: int = 8, cap: int = 1024) -> int:
    """The least power of two from spp0 at which a render takes ``target_s`` (2 workers)."""
    spp = spp0
    base.render(spp, 1, workers)  # (warm-up: compile, pilot)
    while spp < cap and base.render(spp, 1, workers)["seconds"] < target_s:
        spp *= 2
    return spp


def study_scene(spec: SceneSpec, args, log) -> dict:
    scene, adaptive = configured(spec.build(), args.config)
    base = Local(scene, adaptive, ())
    use = in_use(base.renderer)
    names = [n for n in fast.names() if use[n] and (not args.only or n in args.only)]
    log(f"{spec.label}: {scene.camera.width}x{scene.camera.height}, features {base.renderer.features.key}, "
        f"build {base.build_s:.2f} s; mechanisms in use: {', '.join(names)}")
    variants = {"all on": base}
    for n in names:
        off = (n,)
        variants[n] = Remote(spec, args.config, off) if fast.MECHANISMS[n].stage == "import" else Local(scene, adaptive, off)
    spp = args.spp or calibrate(base, args.target, max(args.workers), args.min_spp)
    log(f"  {spp} spp ({'adaptive, ' if adaptive else ''}{args.config})")
    rec = dict(label=spec.label, kind=spec.kind, source=spec.source, key=spec.key, spp=spp, adaptive=adaptive,
               width=scene.camera.width, height=scene.camera.height, features=base.renderer.features.key,
               in_use=use, build_s={k: v.build_s for k, v in variants.items()},
               compile_s={k: v.compile_s for k, v in variants.items()},
               build_times=base.build_times, workers={})
    seed = 1
    for workers in args.workers:
        ref = base.render(spp, seed, workers)  # (warm-up)
        differs = {}
        for name, v in variants.items():
            got = v.render(spp, seed, workers)  # (warm-up)
            if got["digest"] != ref["digest"] or got["rays"] != ref["rays"]:
                differs[name] = differs.get(name, 0) + 1
        times = {name: [] for name in variants}
        cpus = {name: [] for name in variants}
        order = list(variants)
        for r in range(args.repeats):
            k = r % len(order)
            for name in order[k:] + order[:k]:
                got = variants[name].render(spp, seed, workers)
                times[name].append(got["seconds"])
                cpus[name].append(got["cpu"])
                if got["digest"] != ref["digest"] or got["rays"] != ref["rays"]:
                    differs[name] = differs.get(name, 0) + 1
        on, on_cpu = times["all on"], cpus["all on"]
        rows = {}
        for name in names:
            paired = [a / b for a, b in zip(times[name], on)]
            rows[name] = dict(ratio=min(times[name]) / min(on), spread=[min(paired), max(paired)],
                              cpu_ratio=min(cpus[name]) / min(on_cpu), seconds=times[name], cpu_seconds=cpus[name],
                              identical=name not in differs)
        rec["workers"][str(workers)] = dict(on_seconds=on, on_min=min(on), on_cpu=on_cpu, mechanisms=rows,
                                            differ=sorted(differs))
        log(f"  {workers} worker{'s' if workers > 1 else ''}: all on {min(on) * 1e3:.1f} ms (min of {len(on)}); "
            + ", ".join(f"{n} {rows[n]['ratio']:.3f}" for n in names))
        for name in differs:
            log(f"  !! {name}: the image or the ray count changed ({differs[name]} renders)")
    for v in variants.values():
        v.close()
    return rec


def geomean(values) -> float:
    values = list(values)
    return math.exp(sum(math.log(v) for v in values) / len(values)) if values else float("nan")


def summary(records: list[dict], workers: list[int]) -> dict:
    """Per mechanism and worker count, the geometric mean of the ratios over the scenes (1 where it
    does not apply), over the scenes where it applies, and over each kind of scene it applies to
    (1 for the kind's scenes where it does not): ``best_kind`` is the kind it saves most on."""
    out = {}
    for name in fast.names():
        row = {}
        for w in workers:
            ratios = [r["workers"][str(w)]["mechanisms"][name]["ratio"] if name in r["workers"][str(w)]["mechanisms"]
                      else None for r in records]
            applied = [x for x in ratios if x is not None]
            kinds = {}
            for r, x in zip(records, ratios):
                kinds.setdefault(r["kind"], []).append(x)
            by_kind = {k: geomean(1.0 if x is None else x for x in v) for k, v in kinds.items()
                       if any(x is not None for x in v)}
            best = max(by_kind, key=by_kind.get) if by_kind else None
            row[str(w)] = dict(all=geomean(x if x is not None else 1.0 for x in ratios), applied=geomean(applied),
                               scenes=len(applied), by_kind=by_kind, best_kind=best)
        out[name] = row
    return out


def table(records: list[dict], summ: dict, workers: list[int]) -> str:
    """The ratios off/on (spread of the repeats' paired ratios) per scene and the geometric means."""
    keys = [r["key"] for r in records]
    lines = []
    for w in workers:
        lines.append(f"\n{w} worker{'s' if w > 1 else ''}: time with the mechanism off / all on (min of repeats; "
                     "paired spread); geometric mean over all scenes (1 where not used) and over those using it")
        head = ["mechanism"] + keys + ["geomean all", "geomean used", "best kind"]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "---|" * len(head))
        for name in fast.names():
            cells = [name]
            for r in records:
                m = r["workers"][str(w)]["mechanisms"].get(name)
                if m is None:
                    cells.append("—")
                else:
                    flag = "" if m["identical"] else " DIFFERS"
                    cells.append(f"{m['ratio']:.3f} ({m['spread'][0]:.2f}–{m['spread'][1]:.2f}){flag}")
            s = summ[name][str(w)]
            cells += [f"{s['all']:.3f}", f"{s['applied']:.3f} ({s['scenes']})" if s["scenes"] else "—",
                      f"{s['best_kind']}: {s['by_kind'][s['best_kind']]:.3f}" if s["scenes"] else "—"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("| all on (ms) | " + " | ".join(f"{r['workers'][str(w)]['on_min'] * 1e3:.0f}" for r in records)
                     + " | | | |")
        lines.append(f"\n{w} worker{'s' if w > 1 else ''}: process CPU time off / all on (min of repeats); geometric "
                     "mean over all scenes")
        lines.append("| mechanism | " + " | ".join(keys) + " | geomean all |")
        lines.append("|" + "---|" * (len(keys) + 2))
        for name in fast.names():
            cells, logs = [name], []
            for r in records:
                m = r["workers"][str(w)]["mechanisms"].get(name)
                cells.append("—" if m is None else f"{m['cpu_ratio']:.3f}")
                logs.append(0.0 if m is None else math.log(m["cpu_ratio"]))
            cells.append(f"{math.exp(sum(logs) / len(logs)):.3f}")
            lines.append("| " + " | ".join(cells) + " |")
    lines.append("\nhost build of the all-on renderer (s): total, then per mechanism")
    names = sorted({k for r in records for k in r["build_times"]})
    lines.append("| scene | total | " + " | ".join(names) + " |")
    lines.append("|" + "---|" * (len(names) + 2))
    for r in records:
        lines.append(f"| {r['key']} | {r['build_s']['all on']:.3f} | "
                     + " | ".join(f"{r['build_times'].get(n, 0.0):.3f}" for n in names) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default="", help="comma-separated peer keys (a-f) or corpus names (default: all)")
    parser.add_argument("--split", default=None, choices=("train", "validation", "all"),
                        help="scenes from benchmarks.corpus (its training or validation half, or all) instead of the "
                        "peer scenes")
    parser.add_argument("--config", default="sobol+split+adaptive",
                        help="sampler[+split][+adaptive], or 'defaults' (the scene's own settings; default "
                        "sobol+split+adaptive)")
    parser.add_argument("--spp", type=int, default=0, help="samples per pixel (default: per scene, the least power "
                        "of two from --min-spp whose all-on render takes --target seconds)")
    parser.add_argument("--target", type=float, default=0.25, help="seconds of an all-on render for the spp choice")
    parser.add_argument("--min-spp", type=int, default=8, help="the least spp the choice starts from (default 8)")
    parser.add_argument("--repeats", type=int, default=5, help="timed renders per renderer and worker count")
    parser.add_argument("--workers", default="1,2", help="worker counts (default 1,2)")
    parser.add_argument("--only", default="", help="comma-separated mechanisms (default: every one a scene uses)")
    parser.add_argument("--out", default=None, help="output folder (default out/ablation)")
    parser.add_argument("--no-docs", action="store_true", help="leave docs/benchmarks.md alone")
    parser.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.serve:
        return serve()
    args.workers = [int(w) for w in args.workers.split(",")]
    args.only = set(fast.check(args.only.split(","), "--only")) if args.only else set()
    specs = scene_specs(args)
    whole = not (args.scenes or args.only or args.split or args.out)
    out = Path(args.out or ROOT / "out" / "ablation")
    out.mkdir(parents=True, exist_ok=True)

    def log(msg: str) -> None:
        print(msg, flush=True)

    log(f"ablation: {len(specs)} scenes, config {args.config}, workers {args.workers}, {args.repeats} repeats")
    records = []
    t0 = time.perf_counter()
    for spec in specs:
        records.append(study_scene(spec, args, log))
        summ = summary(records, args.workers)
        result = dict(config=args.config, repeats=args.repeats, workers=args.workers,
                      host=dict(platform=platform.platform(), python=platform.python_version(), cpus=os.cpu_count(),
                                warp=__import__("warp").config.version),
                      mechanisms={n: dataclasses.asdict(m) for n, m in fast.MECHANISMS.items()},
                      scenes=records, summary=summ, seconds=time.perf_counter() - t0)
        (out / "ablation.json").write_text(json.dumps(result, indent=1))
    text = table(records, summary(records, args.workers), args.workers)
    (out / "ablation.md").write_text(text + "\n")
    log(text)
    bad = [(r["key"], w, n) for r in records for w, x in r["workers"].items() for n in x["differ"]]
    if bad:
        log(f"\nimages that changed (a bug): {bad}")
        return 1
    if whole and not args.no_docs:
        shutil.copyfile(out / "ablation.json", docs.DATA / "ablation.json")
        changed = docs.update(["ablation", "machine"])
        log(f"docs/benchmarks/ablation.json; docs/benchmarks.md: {', '.join(changed) or 'no'} tables changed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
