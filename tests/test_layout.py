"""The package's layout: one direction of imports, kernel modules with a fixed content, and
images that a change of layout leaves bit-identical."""

from __future__ import annotations

import ast
import pathlib

import numpy as np
import pytest
import warp as wp

import warprt
from scene_images import DATA, render_all

PACKAGE = pathlib.Path(warprt.__file__).resolve().parent


def _module_name(path: pathlib.Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """warprt module -> the warprt modules it imports, at the top or inside a function."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - node.level + 1]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                # ``from X import Y`` imports the module X.Y where there is one, else X itself
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in modules else stem for a in node.names]
            for t in targets:
                if t in modules and t != name:
                    graph[name].add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_warprt_modules_import_in_one_direction():
    graph = import_graph()
    assert len(graph) > 20 and "warprt.trace" in graph["warprt.integrator"]
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_the_description_does_not_depend_on_the_device_side():
    graph = import_graph()
    for name in ("warprt.scene.description", "warprt.scene.values", "warprt.scene.transform", "warprt.scene.loader"):
        assert all(m.startswith("warprt.scene") or m == "warprt.errors" for m in graph[name]), (name, graph[name])


def test_kernel_modules_hold_a_fixed_content(device):
    """Ray queries, AOVs and the film's kernels (its two images) each live in a Warp module of their
    own, so using one never changes (and recompiles) another, whatever
    the order."""
    scene = warprt.Scene(camera=warprt.Camera(width=8, height=6), shapes=(warprt.Sphere(),),
                         lights=(warprt.PointLight(),))
    warprt.camera_rays(scene, device=device)
    warprt.trace_rays(scene, [[0, 0, 5]], [[0, 0, -1]], device=device)
    warprt.render(scene, spp=1, device=device, aovs=["depth", "object_id"], as_warp=True, progress=False)
    modules = wp._src.context.user_modules
    contents = {name: sorted(k.split("__locals__")[-1].split("_")[0] for k in modules[name].kernels)
                for name in ("warprt_query", "warprt_aov", "warprt_film")}
    assert contents == {"warprt_query": ["camera", "samples", "samples", "trace"], "warprt_aov": ["aov"],
                        "warprt_film": ["counted", "image"]}


def test_every_kernel_module_compiles_without_fma_contraction(device):
    """Each Warp module holding warprt kernels is built with ``fuse_fp=False``: on CUDA the
    compiler otherwise fuses multiply-adds where it likes, and the specialised and full kernels
    stop agreeing bit for bit and mesh vertices leak (``warprt._warp`` says more)."""
    scene = warprt.Scene(camera=warprt.Camera(width=8, height=6), shapes=(warprt.Sphere(),),
                         lights=(warprt.PointLight(),))
    warprt.render(scene, spp=1, device=device, aovs=["depth"], progress=False)
    warprt.BatchRenderer(scene, worlds=2, device=device).render(spp=1)
    named = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.keyword) and node.arg == "module" and isinstance(node.value, ast.Constant):
                named.add(node.value.value)
    named.discard("unique")
    assert named and named <= set(warprt._warp.SHARED_MODULES), named - set(warprt._warp.SHARED_MODULES)
    modules = wp._src.context.user_modules
    ours = {name: m for name, m in modules.items()
            if name in named or any(getattr(k.func, "__module__", "").startswith("warprt") for k in m.kernels.values())}
    # the render kernel's and the batch kernel's own modules (module="unique")
    assert {name.split("__locals__")[0] for name in ours if "__locals__" in name} == {"kernels_for", "batch_kernel_for"}
    assert {name: m.options["fuse_fp"] for name, m in ours.items()} == dict.fromkeys(ours, False)
    for name in named:
        assert wp.get_module_options(name)["fuse_fp"] is False, name


def test_scene_files_render_bit_identical_to_the_saved_images():
    """The scenes/ files at 48 pixels wide, 2 spp, with their own settings (the renderer's defaults
    where they say nothing): bit for bit the images saved in tests/data/scene_images.npz (saved
    before the layout changed; rewrite them with ``python -m tests.scene_images --save`` only for
    a deliberate change of the physics or of the defaults)."""
    saved = np.load(DATA)
    images = render_all()
    assert sorted(images) == sorted(saved.files)
    for name, image in images.items():
        ref = saved[name]
        assert image.shape == ref.shape, name
        same = image.view(np.uint32) == ref.view(np.uint32)
        assert same.all(), f"{name}: {int((~same).sum())} values differ (max {np.abs(image - ref).max():.3g})"
