"""The CPU's speed mechanisms (``warprt.fast``): every one has a registry entry and an off switch,
and switched off, with everything else on, it leaves the image bit-identical, on a small scene
where it is in use (checked from the records the build wrote and the kernel's choices)."""

from __future__ import annotations

import ast
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

import warprt
from benchmarks.corpus_scenes import torus
from warprt import accel, fast
from warprt.fast.usage import in_use

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "warprt"


def _torus(n_major: int = 32, n_minor: int = 16, major: float = 0.5, minor: float = 0.2):
    """A closed torus of 2 · n_major · n_minor triangles around the y axis (1024 by default: the
    threshold of the bins and the shadow packets)."""
    return torus(n_major, n_minor, major, minor)


def _scene(**camera) -> warprt.Scene:
    """Every mechanism at work at once (the kernel of scenes/soft_shadows.toml: meshes, area lights,
    the analytic BVH): a plane, a sphere and a long bar (the BVH, the bar in pieces) and a
    1024-triangle torus at rest (its tree, bins, balls, cones, escape horizons, packets), a point
    light (its light buffer) and a rectangle light of 4 samples (Sobol draws in quadrant order, whose
    sums' order a wrong draw would change)."""
    v, f = _torus()
    cam = dict(eye=(0.0, 2.0, 5.0), look_at=(0.0, 0.6, 0.0), fov=45, width=40, height=28)
    cam.update(camera)
    return warprt.Scene(
        camera=warprt.Camera(**cam),
        shapes=(warprt.Plane(material="floor"), warprt.Sphere(center=(-1.6, 0.4, 0.3), radius=0.4, material="red"),
                warprt.Rectangle(corner=(-2.5, 0.0, -1.0), edge1=(5.0, 0.0, 0.0), edge2=(0.0, 0.25, 0.0),
                                 material="red"),
                warprt.Mesh(vertices=v, faces=f, material="white", transform=warprt.Transform(translate=(0.3, 0.62, 0.0)))),
        materials={"floor": warprt.Material(kd=0.7), "red": warprt.Material(kd=(0.8, 0.2, 0.1)),
                   "white": warprt.Material(kd=0.8, ks=0.3, p=20)},
        lights=(warprt.PointLight(position=(1.5, 3.0, 2.0), intensity=2.0),
                warprt.RectLight(corner=(-1.0, 2.5, -0.5), edge1=(1.0, 0.0, 0.0), edge2=(0.0, 0.0, 1.0), radiance=4.0,
                                 samples=4)),
        ambient=0.02).with_settings(sampler="sobol")


def _render(r: warprt.Renderer):
    # adaptive: packets over several pixels, passes of a few samples, the counts between them
    return r.render(spp=8, seed=3, workers=2, progress=False, adaptive=True)


@pytest.fixture(scope="module")
def reference():
    r = warprt.Renderer(_scene(), device="cpu")
    return r, _render(r)


SWITCHES = [name for name, m in fast.MECHANISMS.items() if m.stage != "import"]


@pytest.mark.parametrize("name", SWITCHES)
def test_each_mechanism_switched_off_gives_the_same_image(reference, name):
    base, ref = reference
    assert base.fast_off == frozenset()
    assert in_use(base)[name], f"{name} is not used by the test scene"
    r = warprt.Renderer(_scene(), device="cpu", fast_off=[name])
    assert name in r.fast_off and not in_use(r)[name]
    if fast.MECHANISMS[name].stage == "build":  # (the table not built, the record field left 0)
        assert not in_use(_with_all_on(r))[name]
    out = _render(r)
    assert ref.image.mean() > 0.05
    assert out.image.tobytes() == ref.image.tobytes(), name
    assert out.rays == ref.rays and out.spp == ref.spp


def _with_all_on(r: warprt.Renderer) -> warprt.Renderer:
    """``r`` seen as if nothing were switched off: ``in_use`` then reads only what its build wrote."""
    view = object.__new__(warprt.Renderer)
    view.__dict__.update(r.__dict__)
    view.fast_off = frozenset()
    return view


def test_lens_and_full_kernels_give_the_same_image():
    """A thin lens's packet rays (``camera.lens_packet``) and the Sobol packets in the all-features
    kernel, where secondary rays leave the shading to each lane: switched off, the same image."""
    scene = _scene(aperture=0.08, focus_distance=4.5)
    images = {}
    for off in ((), ("camera_packet_rays",), ("sobol_packets",), ("analytic_packets", "mesh_packets")):
        r = warprt.Renderer(scene, device="cpu", features=warprt.Features.full(), fast_off=off)
        use = in_use(_with_all_on(r))
        assert use["camera_packet_rays"] and use["sobol_packets"] and not use["shading_packets"]
        images[off] = r.render(spp=5, seed=1, workers=2, progress=False).image
    first = images[()]
    assert first.mean() > 0.05
    for off, image in images.items():
        assert image.tobytes() == first.tobytes(), off


def test_switches_combine_from_the_environment_the_context_and_the_renderer(monkeypatch):
    monkeypatch.setenv(fast.ENV, "camera_bins")
    with fast.disabled("light_buffers"):
        with fast.disabled("row_claims"):
            r = warprt.Renderer(_scene(width=8, height=6), device="cpu", fast_off=["interior_balls"])
        assert fast.current() == {"camera_bins", "light_buffers"}
    assert r.fast_off == {"camera_bins", "light_buffers", "row_claims", "interior_balls"}
    assert fast.current() == {"camera_bins"}
    use = in_use(_with_all_on(r))
    assert not use["camera_bins"] and not use["light_buffers"] and not use["interior_balls"] and use["normal_cones"]
    # a mechanism takes those that run inside it with it (Mechanism.requires)
    monkeypatch.setenv(fast.ENV, "")
    r = warprt.Renderer(_scene(), device="cpu", fast_off=["mesh_trees", "shading_packets"])
    assert {"wide_tree", "normal_cones", "mesh_shadow_packets", "shadow_packets", "light_buffers",
            "escaping_faces", "escape_horizons", "node_prefetch"} <= r.fast_off
    rows = r.built.data.insts.numpy()
    assert rows["tree_nodes"][0] == 0 and rows["wide"][0] == 0 and rows["cones"][0] == 0 and rows["escape"][0] == 0
    assert rows["tree_tris"][0] != 0 and rows["bins"][0] != 0 and rows["n_balls"][0] > 0  # (theirs: still there)
    assert warprt.Renderer(_scene(width=8, height=6), device="cpu").fast_off == frozenset()


def test_unknown_names_are_errors(monkeypatch):
    scene = _scene(width=8, height=6)
    with pytest.raises(warprt.RenderError, match="fast_off: unknown speed mechanism 'light_buffer'; known: camera_pack"):
        warprt.Renderer(scene, device="cpu", fast_off=["light_buffer"])
    with pytest.raises(warprt.RenderError, match="warprt.fast.disabled: unknown speed mechanisms 'a', 'b'"):
        with fast.disabled("b", "a"):
            pass
    monkeypatch.setenv(fast.ENV, "bins")
    with pytest.raises(warprt.RenderError, match="WARPRT_FAST_OFF: unknown speed mechanism 'bins'"):
        warprt.Renderer(scene, device="cpu")
    monkeypatch.setenv(fast.ENV, "")
    # an import-stage switch cannot be thrown once its code is compiled in
    with pytest.raises(warprt.RenderError, match="node_prefetch is compiled in when warprt is imported"):
        warprt.Renderer(scene, device="cpu", fast_off=["node_prefetch"])


def test_the_registry_covers_every_switch_in_the_code():
    """Each entry is complete and its switch is read somewhere in warprt; every switch the code
    reads (a name looked up in a set of switched-off mechanisms, a FAST_* bit) is registered."""
    stages = {"build", "kernel", "variant", "render", "import"}
    bits = [m.bit for m in fast.MECHANISMS.values() if m.stage == "kernel"]
    assert all(b and b & (b - 1) == 0 for b in bits) and len(set(bits)) == len(bits)
    constants = {k: v for k, v in vars(fast).items() if k.startswith("FAST_")}
    assert sorted(constants.values()) == sorted(bits)
    sources = {p: p.read_text(encoding="utf-8") for p in PACKAGE.rglob("*.py") if p.parent.name != "fast"}
    read: set[str] = set()  # the names the code looks up
    for path, text in sources.items():
        for node in ast.walk(ast.parse(text)):
            if (isinstance(node, ast.Compare) and isinstance(node.left, ast.Constant)
                    and isinstance(node.left.value, str) and any(isinstance(o, (ast.In, ast.NotIn)) for o in node.ops)
                    and "off" in ast.unparse(node.comparators[0])):
                read.add(node.left.value)
            if isinstance(node, ast.Call) and ast.unparse(node.func).endswith("import_off"):
                read.add(node.args[0].value)
            if isinstance(node, ast.Name) and node.id.startswith("FAST_"):
                assert node.id in constants, (path, node.id)
                read.add(node.id[len("FAST_"):].lower())
    unknown = read - set(fast.MECHANISMS)
    assert not unknown, f"switches read in the code but not registered: {sorted(unknown)}"
    for name, m in fast.MECHANISMS.items():
        assert m.description and m.applies and m.switch and m.stage in stages, name
        assert all(r in fast.MECHANISMS for r in m.requires), name
        assert (m.bit != 0) == (m.stage == "kernel") and (m.stage != "kernel" or constants[f"FAST_{name.upper()}"] == m.bit)
        # (camera_packets: the Renderer's packets, also read in render.py under its name)
        assert name in read, f"{name} is registered but no code reads its switch"


# --- the import-stage switches (node_prefetch, shadow_packets), compiled in as warprt is imported --


def _mesh_scene() -> warprt.Scene:
    """A torus on a plane under a point light (the kernel of meshes alone): camera packets through
    its wide tree, its shadow rays in packets through it, and alone through its binary tree."""
    v, f = _torus()
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.6, 2.2), look_at=(0.0, 0.4, 0.0), fov=45, width=32, height=24),
        shapes=(warprt.Plane(material="floor"),
                warprt.Mesh(vertices=v, faces=f, material="white", transform=warprt.Transform(translate=(0.0, 0.3, 0.0)))),
        materials={"floor": warprt.Material(kd=0.7), "white": warprt.Material(kd=0.8)},
        lights=(warprt.PointLight(position=(1.0, 2.5, 1.0), intensity=1.5),), ambient=0.02).with_settings(sampler="sobol")


def mesh_render() -> list:
    r = warprt.Renderer(_mesh_scene(), device="cpu")
    res = r.render(spp=6, seed=2, workers=2, progress=False, adaptive=True)
    return [res.image.view(np.uint32).ravel().tolist(), int(res.rays), sorted(r.fast_off)]


def test_import_stage_switches_compile_out_and_give_the_same_image():
    """node_prefetch and shadow_packets are set by WARPRT_FAST_OFF when warprt is imported: a
    process started with them off has traversal snippets without the node prefetches (the hits'
    prefetches stay: another switch) and a kernel whose packets' shadow rays go each alone, and it
    renders the same image bit for bit."""
    r = warprt.Renderer(_mesh_scene(), device="cpu")
    use = in_use(r)
    assert use["node_prefetch"] and use["shadow_packets"] and use["mesh_shadow_packets"] and use["mesh_packets"]
    env = dict(os.environ, **{fast.ENV: "node_prefetch,shadow_packets"})
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); import test_fast_switches as t; "
            "from warprt import accel, trace; "
            "print(json.dumps([[s.count('__builtin_prefetch') for s in (accel._TREE_RAY, accel._TREE_OCCLUDED, "
            "accel._TREE_OCCLUDED_PACKET, accel._TREE_PACKET)], trace.SHADOW_LANES_ALONE, t.mesh_render()]))")
    done = subprocess.run([sys.executable, "-c", code, str(ROOT / "tests")], env=env, capture_output=True, text=True,
                          timeout=500)
    assert done.returncode == 0, done.stderr[-2000:]
    counts, alone, (image, rays, off) = json.loads(done.stdout.strip().splitlines()[-1])
    assert counts == [0, 0, 0, 3] and alone  # (mesh_tree_packet keeps its hits' prefetch)
    assert {"node_prefetch", "shadow_packets", "mesh_shadow_packets", "light_buffers"} <= set(off)
    on = [s.count("__builtin_prefetch") for s in (accel._TREE_RAY, accel._TREE_OCCLUDED, accel._TREE_OCCLUDED_PACKET,
                                                   accel._TREE_PACKET)]
    assert all(c > 0 for c in on[:3]) and on[3] > 3
    mine, my_rays, my_off = mesh_render()
    assert my_off == [] and np.array(mine, np.uint32).view(np.float32).mean() > 0.05
    assert image == mine and rays == my_rays
