"""The Mitsuba 3 peer benchmark (benchmarks/peers.py): its scenes are valid warprt scenes, their
Mitsuba exports load, and on the two-point-light scene both renderers give the same image.

The Mitsuba parts skip when Mitsuba is not installed (the ``peers`` extra); they use the
``scalar_rgb`` variant, which needs no LLVM.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import warprt
from warprt.testing import relative_mse

ROOT = Path(__file__).resolve().parents[1]


def _load_peers():
    spec = importlib.util.spec_from_file_location("warprt_bench_peers", ROOT / "benchmarks" / "peers.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module


peers = _load_peers()


@pytest.fixture(scope="module")
def mi():
    mitsuba = pytest.importorskip("mitsuba")
    mitsuba.set_variant("scalar_rgb")
    mitsuba.set_log_level(mitsuba.LogLevel.Error)
    return mitsuba


def _count(scene, cls):
    return sum(isinstance(s, cls) for s in scene.shapes)


def test_scene_builders_make_valid_scenes():
    expect = {"a": (256, 256), "b": (256, 256), "c": (256, 256), "d": (256, 256), "e": (320, 240), "f": (320, 240)}
    assert set(peers.SCENES) == set(expect)
    for key, size in expect.items():
        scene = peers.build_scene(key)
        assert isinstance(scene, warprt.Scene)
        assert (scene.camera.width, scene.camera.height) == size
        # equal physics: Lambert only, no ambient, no background, one sample per area light
        assert np.all(np.asarray(scene.ambient) == 0) and np.all(np.asarray(scene.background) == 0)
        for m in scene.materials.values():
            assert not np.any(m.ks) and not np.any(m.mirror) and not np.any(m.transparency)
        for light in scene.lights:
            assert getattr(light, "samples", 1) == 1
            assert getattr(light, "falloff", "inverse_square") == "inverse_square"
    a = peers.build_scene("a")
    assert _count(a, warprt.Rectangle) == 63 and _count(a, warprt.Sphere) == 120 and len(a.lights) == 1
    b = peers.build_scene("b")
    assert [type(x) for x in b.lights] == [warprt.PointLight, warprt.PointLight]
    c = peers.build_scene("c")
    light = c.lights[0]
    ys = [light.corner[1] + s * light.edge1[1] + t * light.edge2[1] for s in (0, 1) for t in (0, 1)]
    assert min(ys) < 0 < max(ys)  # partly below the ground
    assert np.cross(light.edge1, light.edge2)[2] > 0  # faces the camera (one-sided, visible)
    d = peers.build_scene("d")
    assert sum(len(s.faces) for s in d.shapes if isinstance(s, warprt.Mesh)) == 327_680
    e, f = peers.build_scene("e"), peers.build_scene("f")
    assert sorted(len(s.faces) for s in e.shapes if isinstance(s, warprt.Mesh)) == [1280, 4096]
    assert e.camera.aperture == 0 and f.camera.aperture == pytest.approx(0.35)


def test_bumpy_torus_is_closed_and_consistent():
    v, f = peers.bumpy_torus(16, 8, major=1.0, minor=0.3, bumps=0.1)
    assert v.shape == (128, 3) and f.shape == (256, 3)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # watertight: every edge shared by two triangles


def test_write_ply_round_trip(tmp_path):
    import trimesh

    v, f = peers.bumpy_torus(8, 6, major=1.0, minor=0.25)
    path = tmp_path / "t.ply"
    peers.write_ply(path, v, f)
    mesh = trimesh.load(path, process=False)
    assert np.allclose(mesh.vertices, v, atol=1e-6) and np.array_equal(mesh.faces, f)


def test_main_without_mitsuba_says_so_and_exits_0(monkeypatch, capsys):
    monkeypatch.setattr(peers, "load_mitsuba", lambda variant="llvm_ad_rgb": None)
    assert peers.main(["--quick"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "Mitsuba" in out[0]


def _surface_area(scene) -> float:
    area = 0.0
    for s in scene.shapes:
        if isinstance(s, warprt.Sphere):
            area += 4 * math.pi * s.radius ** 2
        elif isinstance(s, warprt.Rectangle):
            area += float(np.linalg.norm(np.cross(s.edge1, s.edge2)))
        elif isinstance(s, warprt.Plane):
            area += (2 * peers.GROUND_HALF) ** 2
        elif isinstance(s, warprt.Mesh):
            t = np.asarray(s.vertices)[np.asarray(s.faces)]
            area += float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())
    return area + sum(light.area for light in scene.lights if isinstance(light, warprt.RectLight))


def test_mitsuba_dicts_load(mi, tmp_path):
    for key in peers.SCENES:
        scene = peers.build_scene(key, 32, 24)
        for sampler in peers.MITSUBA_SAMPLERS:
            loaded = mi.load_dict(peers.to_mitsuba(scene, mi, sampler=sampler, mesh_dir=tmp_path))
            sensor = loaded.sensors()[0]
            assert tuple(sensor.film().size()) == (32, 24)
            assert len(loaded.emitters()) == len(scene.lights)
            # Mitsuba merges shapes that share a BSDF, so count area, not shapes: every sphere,
            # rectangle, triangle, light and the ground's stand-in square is there, at its size
            area = sum(float(sh.surface_area()) for sh in loaded.shapes())
            assert area == pytest.approx(_surface_area(scene), rel=2e-4), key
        assert ("ThinLens" in str(sensor)) == (scene.camera.aperture > 0)


def test_export_refuses_what_has_no_counterpart(mi):
    from dataclasses import replace

    base = peers.build_scene("b", 8, 8)
    with pytest.raises(peers.ExportError):
        peers.to_mitsuba(replace(base, ambient=0.1), mi)
    with pytest.raises(peers.ExportError):
        peers.to_mitsuba(replace(base, lights=(warprt.PointLight(position=(0, 3, 0)),)), mi)  # no falloff
    with pytest.raises(peers.ExportError):
        peers.to_mitsuba(replace(base, materials={**base.materials, "ball": warprt.Material(kd=0.5, ks=0.3)}), mi)


def test_two_point_lights_agree_with_mitsuba_scalar(mi):
    """Scene (b) at 40x40: warprt (its noise is the pixel integral only) against Mitsuba's
    scalar_rgb direct integrator (which also picks one of the two lights per sample). The
    difference must be the two renders' noise, estimated from half renders."""
    import drjit as dr

    dr.set_thread_count(2)
    scene = peers.build_scene("b", 40, 40)
    mscene = mi.load_dict(peers.to_mitsuba(scene, mi, sampler="independent"))
    halves_m = [np.array(mi.render(mscene, spp=384, seed=s), dtype=np.float64) for s in (11, 12)]
    r = warprt.Renderer(scene.with_settings(sampler="stratified"), device="cpu")
    halves_w = [r.render(spp=64, seed=s, workers=2, progress=False).image.astype(np.float64) for s in (1, 2)]
    m, w = 0.5 * (halves_m[0] + halves_m[1]), 0.5 * (halves_w[0] + halves_w[1])
    noise = (relative_mse(*halves_m) + relative_mse(*halves_w)) / 4
    err = relative_mse(w, m)
    assert err < 2.5 * noise + 1e-6, f"relMSE {err:.2e} vs noise {noise:.2e}"
    sigma = math.sqrt(sum(float(np.mean((h[0] - h[1]) ** 2)) / 4 / h[0].size for h in (halves_m, halves_w)))
    assert abs(w.mean() - m.mean()) < 4 * sigma + 1e-7, (w.mean(), m.mean(), sigma)
    # and the image is not trivially dark: the lights reach the sphere and the ground
    assert m.mean() > 0.05
